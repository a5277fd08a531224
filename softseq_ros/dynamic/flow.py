"""
Segments joined by tubes and fed by the syringe: the network integrated in time.

Segment i holds volume v_i at pressure p_i(v_i) (its model: table or law). The syringe imposes
the volume flow Q(t) into the segment f it feeds (the base unless the scene says otherwise)
through the supply line; channel j carries q_j from segment j to segment j + 1 with a pressure
drop ``L_j dq_j/dt + R_j q_j + a_j q_j |q_j|`` (softseq_ros.dynamic.network). So

    dv_i/dt = [i = f] Q + q_(i-1) - q_i   (q_(-1) = 0),   and the tip's volume follows from
    mass: v_tip = (rest volumes) + (injected volume) - (the other volumes),

which keeps the sum of the volumes equal to the injected volume to round-off at every instant.
Behind a compliant supply line (a scene's ``supply``: trapped gas and the line's compliance,
softseq_ros.segments.supply) the pump pushes Q into the line instead, which holds s at its
pressure p_s(s), and the supply tube carries q_s from it into segment f, driven by p_s - p_f:
ds/dt = Q - q_s and q_s replaces Q above; s (and q_s, when the tube's inertia counts) joins
the state, and the tip's volume is the injected volume less s and the others'.
A channel without inertance carries the flow its pressure drop drives at once; one with it
has its flow as a state. The state (the volumes but the tip's, the inertial flows) is stiff
where the channels are short and wide, so it is integrated by scipy's Radau (implicit,
error-controlled, its step chosen by the error, never fixed), one integration across as many
commands as keep the flow the same: a pump ramp costs a few steps once the transients decay.
The network's state has a handful of entries, so scipy's general wrappers cost more than the
arithmetic: by default (``integrator='radau'``) scipy's Radau IIA runs without them
(softseq_ros.dynamic.integrators); ``integrator='scipy-radau'`` is scipy's Radau as it comes,
kept for comparison. :meth:`NetworkFlow.advance_through` reads many output times at once, each
step's outputs from one evaluation of its interpolant.

What happens within a step (a segment leaving its range or passing a fold of its curve, each
channel's peak flow, the snap-throughs) is found on the step's collocation polynomial, located
in time (softseq_ros.dynamic.events), and only up to the time asked. A segment pushed past the
end of its curve ends the integration with :class:`NetworkDomainError` at the located instant
(the quasi-static solver refuses such a volume too). A segment drawn below its rest volume
collapses (a stiff line below its rest pressure), so a fast withdrawal pulls the far segments'
fluid through the channels instead of failing; only suction beyond vacuum is refused.
"""

import math
from typing import Sequence

import numpy as np
from numpy.typing import NDArray

from softseq_ros.dynamic.events import (
    EMPTYING,
    EXCHANGE_TOLERANCES,
    FILLING,
    DynamicSnap,
    ExchangeWatcher,
    FoldCrossing,
    StepCurve,
    crossings,
    exchange_flow,
    first_beyond,
    segment_folds,
    unstable_stiffness,
)
from softseq_ros.dynamic.integrators import (
    METHODS,
    Integrator,
    ScalarRadau,
    StepInterpolant,
    new_integrator,
)
from softseq_ros.dynamic.network import TubeLaw, tube_law
from softseq_ros.errors import UserError
from softseq_ros.scene.network import NO_SUPPLY_TUBE, NetworkSettings
from softseq_ros.segments.models import Segment
from softseq_ros.segments.supply import CompliantSupply

FloatArray = NDArray[np.float64]
# Absolute tolerances: this share of the volume scale for a volume, of the volume scale per
# second for a flow (with the relative tolerance on top).
ATOL_SHARE = 1e-3
# A volume within this share of the volume scale past the end of a curve is at its end.
END_SLACK = 1e-9
# Flows closer than this share of their size are the same (a ramp's commands, to round-off).
SAME_FLOW = 1e-9
# The solver is never asked to step beyond this horizon [s] at once.
HORIZON_S = 1.0e9
# A segment drawn below its rest volume (the syringe withdrawing faster than the channels let
# the far segments' fluid follow) collapses: its pressure falls below its rest pressure along
# a line this many times as steep as its curve is on average. Stiff, so the undershoot stays
# small, and finite, so the suction pulls the others' fluid through the channels.
COLLAPSE_STIFFENING = 1.0e3
# Suction beyond vacuum (gauge below minus one standard atmosphere) the water cannot follow:
# it would boil. A collapse that deep is refused.
VACUUM_GAUGE_PA = -101325.0
# The fluid moves between the segments (a transient runs) while the exchange beyond the pump's
# flow exceeds this share of the pump's flow and the integrator's absolute tolerance per second.
QUIET_SHARE_OF_FLOW = 1.0e-6
# An interpolant the last step has and the outputs have not yet asked for.
_PENDING = object()


class NetworkDomainError(UserError):
    """
    A segment's volume left the range its model covers while fluid moved.

    ``located``: at an instant found on the step's polynomial (the network is left there).
    """

    def __init__(self, message: str, located: bool = False) -> None:
        super().__init__(message)
        self.located = located
        self.rows: FloatArray | None = None


class NetworkFlow:
    """The network's state in time: volumes, channel flows, and the supply flow now."""

    def __init__(self, segments: Sequence[Segment], network: NetworkSettings,
                 rtol: float | None = None, integrator: str = 'radau',
                 line: CompliantSupply | None = None) -> None:
        """
        At rest at time 0, no supply flow; ``rtol`` overrides the network's tolerance.

        ``integrator``: one of softseq_ros.dynamic.integrators.METHODS ('radau', the default,
        or 'scipy-radau'). ``line``: the syringe line's trapped gas and compliance (a scene's
        ``supply``), between the piston and the supply tube, which the network then needs.
        """
        if line is not None and network.supply is None:
            raise ValueError(NO_SUPPLY_TUBE)
        if len(network.channels) != len(segments) - 1:
            raise ValueError(f'{len(segments)} segments need {len(segments) - 1} channels, got '
                             f'{len(network.channels)}')
        if integrator not in METHODS:
            raise ValueError(f'integrator must be one of {", ".join(METHODS)}, got '
                             f'{integrator!r}')
        self.integrator = integrator
        self.segments = list(segments)
        self.n = len(self.segments)
        self.laws: list[TubeLaw] = [tube_law(c, network.fluid) for c in network.channels]
        self.supply = None if network.supply is None else tube_law(network.supply,
                                                                   network.fluid)
        self.inertial = [j for j, law in enumerate(self.laws) if law.inertance > 0.0]
        # The segment the syringe feeds (through the supply line, if any).
        self.feed = network.feed
        if not 0 <= self.feed < self.n:
            raise ValueError(f'the syringe feeds segment {self.feed}, one of {self.n} segments?')
        self.rest = np.array([s.rest_volume for s in self.segments])
        self.full = np.array([s.max_volume for s in self.segments])
        self.rest_total = float(self.rest.sum())
        self.v_scale = float(np.sum(self.full - self.rest))
        self.rtol = float(network.rtol if rtol is None else rtol)
        # The line: the fluid it holds after the volumes and the inertial channels' flows, then
        # the supply tube's flow when its inertia counts (else the tube carries the flow its
        # drop drives at once).
        self.line = line
        self._line_pressure_of = None if line is None else line.line_pressure
        self._line_at = self.n - 1 + len(self.inertial)
        self._supply_inertial = line is not None and self.supply.inertance > 0.0
        self._line_size = 0 if line is None else 1 + int(self._supply_inertial)
        size = self._line_at + self._line_size
        self.atol = np.full(size, self.rtol * ATOL_SHARE * self.v_scale)
        self.t = 0.0
        self.injected = 0.0
        self.flow = 0.0
        self._y_pending = False
        self.y = np.concatenate([self.rest[:-1], np.zeros(len(self.inertial) + self._line_size)])
        self.peak_reynolds = [0.0] * len(self.laws)
        self.steps = 0
        self.snaps = ExchangeWatcher(EXCHANGE_TOLERANCES * self.rtol * self.v_scale)
        self.new_snaps: list[DynamicSnap] = []
        self.new_fold_crossings: list[FoldCrossing] = []
        self._origin = (0.0, 0.0)   # (time, injected) where the current supply flow began
        self._solver: Integrator | None = None
        self._dense = None
        # Plain floats and bound methods: with a handful of segments, numpy's cost per call on
        # tiny arrays outweighs the arithmetic, and the right-hand side runs thousands of times.
        self._pressure_of = [s.pressure for s in self.segments]
        self._bounds = list(zip(self.rest.tolist(), self.full.tolist()))
        self._collapse = [COLLAPSE_STIFFENING * _mean_stiffness(s) for s in self.segments]
        # The levels a segment's volume must not pass: the end of its curve (with round-off's
        # slack: a programme may end exactly there) and, below its rest volume, where its
        # collapse reaches vacuum; and the folds of its curve, which are reported.
        slack = END_SLACK * self.v_scale
        self._upper = [hi + slack for _, hi in self._bounds]
        self._lower = [lo + min(VACUUM_GAUGE_PA - float(pressure(lo)), 0.0) / collapse
                       for pressure, (lo, _), collapse in zip(self._pressure_of, self._bounds,
                                                              self._collapse)]
        self._folds = [segment_folds(s) for s in self.segments]
        # Nor does the line draw a suction beyond vacuum (absolute zero at its ambient): a line
        # of compliance alone can reach it, the fluid it holds then C times that suction; gas
        # expands without bound short of it (no level).
        self._line_lower = -math.inf
        if line is not None and line.gas_volume == 0.0:
            self._line_lower = -line.compliance * line.ambient
        # Whether the last watched step had fluid moving between the segments (a transient).
        self.exchanging = False
        # The integrator's last step as the segments' volume cubics, how far it has been
        # watched (up to the time asked: beyond it the flow may change first, and then that
        # part of the step never happens), and the first instant in it where a segment leaves
        # its range (inf: none), with why.
        self._curve: StepCurve | None = None
        self._watched_to = 0.0
        self._leaves_at = math.inf
        self._leaves_why = ''
        self._steady = [None if law.inertance > 0.0 else law.flow for law in self.laws]
        # Volumes, pressures and flows of the state now, computed once per state: the rig
        # asks for them several times per output.
        self._now: tuple[list[float], list[float], list[float]] | None = None

    # ------------------------------------------------------------------ the equations

    def volumes_of(self, y: FloatArray, injected: float) -> FloatArray:
        """All segment volumes from a state and the injected volume (mass fixes the tip's)."""
        return np.array(self._volume_list(y.tolist(), injected))

    def _volume_list(self, state: list[float], injected: float) -> list[float]:
        others = state[:self.n - 1]
        tip = self.rest_total + injected - sum(others)
        if self.line is not None:
            tip -= state[self._line_at]
        return others + [tip]

    def pressures(self, volumes: FloatArray) -> FloatArray:
        """
        Each segment's gauge pressure [Pa] at ``volumes`` [m^3].

        Above a segment's curve its last pressure (the integration refuses such a volume);
        below its rest volume, collapsing under suction (COLLAPSE_STIFFENING).
        """
        asked = np.asarray(volumes, dtype=float).tolist()
        # The rig asks for the pressures of the volumes now, which are known already.
        if self._now is not None and asked == self._now[0]:
            return np.array(self._now[1])
        return np.array(self._pressure_list(asked))

    def _pressure_list(self, volumes: list[float]) -> list[float]:
        pressures = []
        for pressure, v, (lo, hi), collapse in zip(self._pressure_of, volumes, self._bounds,
                                                   self._collapse):
            if v < lo:
                pressures.append(float(pressure(lo)) + collapse * (v - lo))
            else:
                pressures.append(float(pressure(min(v, hi))))
        return pressures

    def channel_flows(self, y: FloatArray, pressures: FloatArray) -> FloatArray:
        """Each channel's flow [m^3/s], segment j to j + 1."""
        return np.array(self._flow_list(np.asarray(y, dtype=float).tolist(),
                                        np.asarray(pressures, dtype=float).tolist()))

    def _flow_list(self, state: list[float], pressures: list[float]) -> list[float]:
        flows = []
        inertial = iter(state[self.n - 1:])
        for j, steady in enumerate(self._steady):
            flows.append(next(inertial) if steady is None
                         else steady(pressures[j] - pressures[j + 1]))
        return flows

    def _injected_at(self, t: float) -> float:
        start_t, start_injected = self._origin
        return start_injected + self.flow * (t - start_t)

    def _balance(self, t: float, y: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray,
                                                              FloatArray]:
        """Volumes, pressures, channel flows and the state's rates at time ``t``."""
        if self.line is not None:
            volumes, pressures, flows, _, _, rates = self._line_balance(t, y.tolist())
            return np.array(volumes), np.array(pressures), np.array(flows), np.array(rates)
        state = y.tolist()
        volumes = self._volume_list(state, self._injected_at(t))
        pressures = self._pressure_list(volumes)
        flows = self._flow_list(state, pressures)
        rates = self.segment_rates(flows, pressures, self.flow)
        return np.array(volumes), np.array(pressures), np.array(flows), np.array(rates)

    def segment_rates(self, flows: list[float], pressures: list[float],
                      inflow: float) -> list[float]:
        """
        The state's rates of the volumes but the tip's, then of the inertial channels' flows.

        ``inflow`` [m^3/s] enters the fed segment (the pump's flow, the supply tube's, or a
        regulator's); each channel carries ``flows`` between the segments at ``pressures``.
        """
        last = self.n - 1
        rates = [(flows[i - 1] if i else 0.0) - flows[i] for i in range(last)]
        if self.feed < last:
            rates[self.feed] += inflow
        for j in self.inertial:
            law = self.laws[j]
            rates.append((pressures[j] - pressures[j + 1] - law.drop(flows[j])) / law.inertance)
        return rates

    def _rates(self, t: float, y: FloatArray) -> FloatArray:
        """
        The state's rates alone, as :meth:`_balance` computes them (the same numbers).

        What the integrator asks for, a dozen times per step: nothing but the rates built.
        """
        state = y.tolist()
        start_t, start_injected = self._origin
        last = self.n - 1
        others = state[:last]
        volumes = others + [self.rest_total + (start_injected + self.flow * (t - start_t))
                            - sum(others)]
        pressures = self._pressure_list(volumes)
        return np.array(self.segment_rates(self._flow_list(state, pressures), pressures,
                                           self.flow))

    def _line_balance(self, t: float, state: list[float]) -> tuple[
            list[float], list[float], list[float], float, float, list[float]]:
        """
        Volumes, pressures, channel flows, line pressure, supply flow and rates behind a line.

        At time ``t``. The piston pushes Q into the line, which holds s at gauge pressure
        p_s(s) (softseq_ros.segments.supply); the supply tube carries q_s from the line into
        the fed segment, driven by p_s - p_f:

            ds/dt = Q - q_s,   dv_i/dt = [i = f] q_s + q_(i-1) - q_i,
            L_s dq_s/dt = p_s - p_f - drop_s(q_s)   (or q_s = drop_s^-1(p_s - p_f) at once),

        and the tip's volume from mass, the injected volume less the line's fluid and the
        others' (so the segments and the line hold what the piston pushed, to round-off).
        """
        last = self.n - 1
        others = state[:last]
        held = state[self._line_at]
        volumes = others + [self.rest_total + self._injected_at(t) - sum(others) - held]
        pressures = self._pressure_list(volumes)
        flows = self._flow_list(state, pressures)
        line_pressure = self._line_pressure_of(held)
        feed_drop = line_pressure - pressures[self.feed]
        supply_flow = (state[self._line_at + 1] if self._supply_inertial
                       else self._supply_flow(feed_drop))
        rates = self.segment_rates(flows, pressures, supply_flow)
        rates.append(self.flow - supply_flow)
        if self._supply_inertial:
            rates.append((feed_drop - self.supply.drop(supply_flow)) / self.supply.inertance)
        return volumes, pressures, flows, line_pressure, supply_flow, rates

    def _line_rates(self, t: float, y: FloatArray) -> FloatArray:
        """The state's rates behind a compliant line (what the integrator asks for)."""
        return np.array(self._line_balance(t, y.tolist())[5])

    def _line_rate_of_one(self, t: float, held: float) -> float:
        """One segment behind a line and a tube without inertance: ds/dt on a float."""
        start_t, start_injected = self._origin
        volume = self.rest_total + (start_injected + self.flow * (t - start_t)) - held
        fed = self._pressure_list([volume])[0]
        return self.flow - self._supply_flow(self._line_pressure_of(held) - fed)

    def _supply_flow(self, drop: float) -> float:
        """The supply tube's flow [m^3/s] from the line into the fed segment at ``drop`` [Pa]."""
        if not math.isfinite(drop):
            # A line of gas alone asked to hold its own volume (an integrator's trial stage):
            # no flow answers it, and the integrator shortens the step.
            return math.nan
        return self.supply.flow(drop)

    def _new_solver(self) -> Integrator:
        if self.line is not None:
            return new_integrator(self.integrator, self._line_rates, self._line_rate_of_one,
                                  self.t, self.y, self.t + HORIZON_S, self.rtol, self.atol)
        return new_integrator(self.integrator, self._rates, self._rate_of_one, self.t, self.y,
                              self.t + HORIZON_S, self.rtol, self.atol)

    def _rate_of_one(self, t: float, v: float) -> float:
        """Two segments, one channel without inertance: the base's rate, as _rates has it."""
        start_t, start_injected = self._origin
        pressures = self._pressure_list([v, self.rest_total + (start_injected + self.flow
                                                                * (t - start_t)) - v])
        # The pump's flow into the base, unless the syringe feeds the tip.
        return (self.flow if self.feed == 0 else 0.0) - self._steady[0](pressures[0]
                                                                         - pressures[1])

    # ------------------------------------------------------------------ time

    def set_flow(self, flow: float) -> None:
        """
        From now on the syringe pushes ``flow`` [m^3/s] (negative: it draws).

        A flow within round-off of the present one (a ramp's next command) keeps the present
        integration going; another one starts a new one from the state now.
        """
        changed = abs(flow - self.flow) > SAME_FLOW * max(abs(flow), abs(self.flow))
        if changed or self._solver is None:
            self._materialise()
            self._end_integration()
            self.flow = float(flow)
            self._origin = (self.t, self.injected)
            if changed:
                self._restart_watch()

    def inject_now(self, volume: float) -> None:
        """Put ``volume`` [m^3] into the segment the pump feeds at once (a late command)."""
        self._materialise()
        self._end_integration()
        self.y = self.y.copy()
        if self.line is not None:
            # The piston pushes into the line; the supply tube passes it on in time.
            self.y[self._line_at] += volume
        elif self.feed < self.n - 1:
            # The tip's volume follows from the injected volume by mass.
            self.y[self.feed] += volume
        self.injected += volume
        self._origin = (self.t, self.injected)
        self._now = None
        if abs(volume) > JUMP_SHARE * self.v_scale:
            self._restart_watch()

    def set_volumes(self, volumes: Sequence[float], injected: float) -> None:
        """
        Put the segments at ``volumes`` at rest (no channel flow): a resume.

        Behind a compliant line, the line holds what the segments do not of ``injected``.
        """
        self._end_integration()
        line_state = []
        if self.line is not None:
            held = float(injected) - float(np.sum(np.asarray(volumes, dtype=float) - self.rest))
            line_state = [held] + [0.0] * int(self._supply_inertial)
        self.y = np.concatenate([np.asarray(volumes[:-1], dtype=float),
                                 np.zeros(len(self.inertial)), line_state])
        self.injected = float(injected)
        self._origin = (self.t, self.injected)
        self._now = None
        self._restart_watch()

    def advance(self, t: float) -> None:
        """
        Integrate to time ``t`` [s] with the current supply flow.

        The steps are watched (fold crossings, snap-throughs, Reynolds numbers) up to ``t``
        only: the integrator's last step may end beyond it, with a flow that a command at
        ``t`` changes. A segment that leaves its range before ``t`` raises
        :class:`NetworkDomainError` at the instant located on the step's polynomial, and
        leaves the network there.
        """
        if t <= self.t:
            return
        solver = self._solver
        if solver is not None and t < solver.t and t < self._leaves_at and \
                self._dense is not None:
            # Within the last step, short of anything it holds: the rig's tick between two
            # steps. Interpolated when someone asks: a tick with nothing to say needs no state.
            self._y, self._y_pending = None, True
            self.t = t
            self.injected = self._injected_at(t)
            self._now = None
            return
        solver = self._current_solver()
        if solver.t < t:
            # The state now lies in the step about to be left behind.
            self._materialise()
        try:
            if self._leaves_at <= t:
                self._refuse_at_exit()
            if self._watched_to < solver.t <= t:
                self._watch_step(solver)
            while solver.t < t:
                self._step(solver)
                if self._leaves_at <= t:
                    self._refuse_at_exit()
                if solver.t <= t:
                    self._watch_step(solver)
        except NetworkDomainError:
            # The next call starts again from the last instant reached.
            self._solver = None
            raise
        if self._dense is not None and solver.t > t:
            # Interpolated when someone asks: a tick in which nothing is said needs no state.
            self._y, self._y_pending = None, True
        else:
            self._y, self._y_pending = np.asarray(solver.y, dtype=float), False
        self.t = t
        self.injected = self._injected_at(t)
        self._now = None

    def _current_solver(self) -> Integrator:
        """The integrator of the current flow, started afresh after a change of flow."""
        if self._solver is None:
            self._solver = self._new_solver()
            self._dense = None
            self._curve = None
            self._watched_to = self.t
            self._leaves_at = math.inf
        return self._solver

    def _end_integration(self) -> None:
        """The present integration ends now: the part of its last step up to now happened."""
        if self._curve is not None and self._watched_to < self.t:
            self._watch(self.t, self._curve.x_of(self.t))
        self._solver = None
        self._curve = None
        self._leaves_at = math.inf

    def _step(self, solver: Integrator) -> None:
        """One integrator step, its volumes as cubics, and where a segment leaves its range."""
        message = solver.step()
        if solver.status == 'failed':
            raise NetworkDomainError(f'the network integration failed at {solver.t:.6g} s: '
                                     f'{message}')
        self.steps += 1
        # A step that passes no output, or whose end is the output, needs no interpolant.
        self._dense = _PENDING
        curve = self._curve = self._step_curve(solver)
        self._watched_to = curve.t_old
        self._leaves_at, self._leaves_why = self._first_exit(curve)

    def _step_curve(self, solver: Integrator) -> StepCurve:
        """The last step's continuous solution (its collocation cubic), as segment volumes."""
        if isinstance(solver, ScalarRadau):
            t_old, h, start, cubic = solver.sol
            state_starts, state_cubics = [start], [cubic]
        else:
            if self._dense is _PENDING:
                self._dense = StepInterpolant(solver.dense_output())
            dense = self._dense
            t_old, h = dense.dense.t_old, dense.dense.h
            state_starts, state_cubics = dense.start, dense.rows
        starts = state_starts[:self.n - 1]
        cubics = [tuple(row) for row in state_cubics[:self.n - 1]]
        # The tip's volume by mass: the rest volumes and what was injected, less the others
        # (and less what the line holds).
        injected = self._injected_at(t_old)
        tip_start = self.rest_total + injected - sum(starts)
        tip = (self.flow * h - sum(q[0] for q in cubics), -sum(q[1] for q in cubics),
               -sum(q[2] for q in cubics))
        if self.line is None:
            return StepCurve(t_old, h, (*starts, tip_start), (*cubics, tip), self.flow,
                             self.feed, injected)
        line_start = state_starts[self._line_at]
        line_cubic = tuple(state_cubics[self._line_at])
        tip_start -= line_start
        tip = tuple(q - s for q, s in zip(tip, line_cubic))
        return StepCurve(t_old, h, (*starts, tip_start), (*cubics, tip), self.flow, self.feed,
                         injected, line_start, line_cubic)

    def _first_exit(self, curve: StepCurve) -> tuple[float, str]:
        """The first instant in a step where a segment leaves its range (inf: none), and why."""
        first, why = math.inf, ''
        for i, (start, cubic) in enumerate(zip(curve.starts, curve.cubics)):
            for level, sign, kind in ((self._upper[i], 1.0, 'end'),
                                      (self._lower[i], -1.0, 'vacuum')):
                x = first_beyond(start, cubic, 0.0, 1.0, level, sign)
                if x is not None and curve.time(x) < first:
                    first, why = curve.time(x), f'{kind} {i}'
        if curve.line_cubic is not None and self._line_lower > -math.inf:
            x = first_beyond(curve.line_start, curve.line_cubic, 0.0, 1.0, self._line_lower,
                             -1.0)
            if x is not None and curve.time(x) < first:
                first, why = curve.time(x), 'vacuum line'
        return first, why

    def _refuse_at_exit(self) -> None:
        """
        A segment leaves its range at the located instant: the network stops there, refusing.

        What happened up to that instant is watched; the state is the one at that instant.
        """
        t, curve = self._leaves_at, self._curve
        x = curve.x_of(t)
        self._watch(t, x)
        if self._dense is _PENDING:
            self._dense = StepInterpolant(self._solver.dense_output())
        self.y = np.asarray(self._dense(t), dtype=float)
        self.t = t
        self.injected = curve.injected_at(x)
        self._origin = (self.t, self.injected)
        self._now = None
        kind, i = self._leaves_why.split()
        self._solver = None
        self._curve = None
        self._leaves_at = math.inf
        if i == 'line':
            raise NetworkDomainError(
                f'the supply line draws a suction beyond vacuum at {t:.6g} s '
                f'({curve.line_held(x):.6g} m^3 held, injected {self.injected:.6g} m^3): the '
                'syringe draws faster than the supply tube lets the fluid follow', located=True)
        segment = self.segments[int(i)]
        volume = curve.volumes(x)[int(i)]
        if kind == 'end':
            raise NetworkDomainError(
                f'segment {segment.name} passes the end of its curve at {t:.6g} s '
                f'({volume:.6g} m^3, injected {self.injected:.6g} m^3)', located=True)
        raise NetworkDomainError(
            f'segment {segment.name} collapses under suction beyond vacuum at {t:.6g} s '
            f'({volume:.6g} m^3, rest {self.rest[int(i)]:.6g} m^3, injected '
            f'{self.injected:.6g} m^3): the syringe draws faster than the channels let the '
            'fluid follow', located=True)

    def advance_through(self, times: Sequence[float] | FloatArray) -> FloatArray:
        """
        Integrate through ``times`` [s] (in order) and return the state at each (one row each).

        The same steps, watching and states as :meth:`advance` to each time in turn, to the
        bit, without a call per time: the times a step passes are read from its interpolant
        at once. Times at or before now read the state now; afterwards the network is at the
        last time. A :class:`NetworkDomainError` holds in ``error.rows`` the states of the
        times before it; a segment leaving its range leaves the network at the located
        instant, a failed step at the last time reached before it.
        """
        times = np.asarray(times, dtype=float).reshape(-1)
        if times.size > 1 and np.any(np.diff(times) < 0.0):
            raise ValueError('times must be in order')
        rows = np.empty((times.size, self.y.shape[0]))
        k = int(np.searchsorted(times, self.t, side='right'))
        rows[:k] = self.y
        if k == times.size:
            return rows
        end = float(times[-1])
        solver = self._current_solver()
        # The state now lies in a step that is about to be left behind.
        self._materialise()
        try:
            while True:
                # The times inside the last step (before a segment leaves its range in it),
                # then its end (watched first, as advance watches a step before it says
                # anything at or beyond its end).
                inside = int(np.searchsorted(times, min(solver.t, self._leaves_at),
                                             side='left'))
                if inside > k:
                    if self._dense is _PENDING:
                        self._dense = StepInterpolant(solver.dense_output())
                    rows[k:inside] = self._dense.many(times[k:inside])
                    k = inside
                if self._leaves_at <= end:
                    self._refuse_at_exit()
                if self._watched_to < solver.t <= end:
                    self._watch_step(solver)
                at_end = int(np.searchsorted(times, solver.t, side='right'))
                rows[k:at_end] = solver.y
                k = at_end
                if k == times.size:
                    break
                self._step(solver)
        except NetworkDomainError as err:
            self._solver = None
            if not err.located and k > 0 and times[k - 1] > self.t:
                self.t = float(times[k - 1])
                self.injected = self._injected_at(self.t)
                self.y = rows[k - 1].copy()
                self._origin = (self.t, self.injected)
                self._now = None
            err.rows = rows[:k]
            raise
        self.t = end
        self.injected = self._injected_at(end)
        self.y = rows[-1].copy()
        self._now = None
        return rows

    def states_volumes(self, states: FloatArray, injected: FloatArray) -> FloatArray:
        """All segment volumes (rows) of states (rows) at injected volumes (mass: the tip's)."""
        others = states[:, :self.n - 1]
        tip = self.rest_total + injected - others.sum(axis=1)
        if self.line is not None:
            tip = tip - states[:, self._line_at]
        return np.column_stack([others, tip])

    def row_pressures(self, volumes: FloatArray) -> FloatArray:
        """:meth:`pressures` of many states at once: rows of segment volumes (m, N) [m^3]."""
        pressures = np.empty_like(volumes)
        for i, (segment, (lo, hi), collapse) in enumerate(zip(self.segments, self._bounds,
                                                                self._collapse)):
            v = volumes[:, i]
            inside = np.asarray(segment.pressure(np.clip(v, lo, hi)), dtype=float)
            below = float(segment.pressure(lo)) + collapse * (v - lo)
            pressures[:, i] = np.where(v < lo, below, inside)
        return pressures

    def read_states(self, times: FloatArray, states: FloatArray) -> tuple[
            FloatArray, FloatArray, FloatArray, FloatArray]:
        """
        Injected volume, segment volumes, channel flows and syringe pressure at ``times``.

        ``states``: rows of :meth:`advance_through` since the supply flow was last set. What
        :meth:`volumes`, :meth:`flows` and :meth:`syringe_pressure` say at each time, on
        arrays (equal to round-off).
        """
        times = np.asarray(times, dtype=float)
        start_t, start_injected = self._origin
        injected = start_injected + self.flow * (times - start_t)
        volumes = self.states_volumes(states, injected)
        pressures = self.row_pressures(volumes)
        flows = self.channel_flow_rows(states, pressures)
        if self.line is not None:
            # The piston pushes on the line: the syringe's pressure is the line's.
            return injected, volumes, flows, self.read_line(states, volumes)[1]
        syringe = pressures[:, self.feed] + (self.supply.drop(self.flow)
                                             if self.supply is not None else 0.0)
        return injected, volumes, flows, syringe

    def channel_flow_rows(self, states: FloatArray, pressures: FloatArray) -> FloatArray:
        """:meth:`channel_flows` of many states (rows) at their segments' pressures (rows)."""
        flows = np.empty((states.shape[0], len(self.laws)))
        inertial = iter(range(self.n - 1, states.shape[1]))
        for j, law in enumerate(self.laws):
            if self._steady[j] is None:
                flows[:, j] = states[:, next(inertial)]
                continue
            flows[:, j] = law.flow_rows(pressures[:, j] - pressures[:, j + 1])
        return flows

    def read_line(self, states: FloatArray, volumes: FloatArray) -> tuple[
            FloatArray, FloatArray, FloatArray]:
        """
        The line's fluid [m^3], its gauge pressure [Pa] and the supply tube's flow [m^3/s].

        ``states``: rows of :meth:`advance_through`; ``volumes``: their segment volumes
        (:meth:`states_volumes`). Only behind a compliant line (``line``).
        """
        if self.line is None:
            raise ValueError('this network has no compliant supply line')
        held = states[:, self._line_at]
        pressure = np.array([self._line_pressure_of(s) for s in held.tolist()])
        if self._supply_inertial:
            return held, pressure, states[:, self._line_at + 1]
        drops = pressure - self.row_pressures(volumes)[:, self.feed]
        return held, pressure, np.array([self._supply_flow(d) for d in drops.tolist()])

    def take_snaps(self) -> list[DynamicSnap]:
        """The snap-throughs completed since the last call."""
        found, self.new_snaps = self.new_snaps, []
        return found

    def take_fold_crossings(self) -> list[FoldCrossing]:
        """The segments' passages through folds of their own curves since the last call."""
        found, self.new_fold_crossings = self.new_fold_crossings, []
        return found

    def _restart_watch(self) -> None:
        """
        The flow or the state changed at once: the rates now are new.

        What the exchange was before (a calm step long ago, say) says nothing about it after,
        and a paused exchange episode cannot go on across the change: it is reported.
        """
        self.new_snaps.extend(self.snaps.flow_changed())
        _, _, flows, rates = self._balance(self.t, self.y)
        for j, flow in enumerate(flows.tolist()):
            self.peak_reynolds[j] = max(self.peak_reynolds[j], self.laws[j].reynolds(flow))
        self._note_exchange(rates.tolist())

    def finish_exchanges(self) -> None:
        """
        The run ends now: the exchange episode paused or still under way is reported.

        One still under way is cut short here (:attr:`DynamicSnap.cut_short`): a run that
        ends while fluid still moves between the segments says so, and how much moved.
        """
        if self._curve is not None and self._watched_to < self.t:
            self._watch(self.t, self._curve.x_of(self.t))
        if not self.snaps.pending:
            return
        volumes, pressures, _ = self.now()
        line_held = None if self.line is None else float(self._state_list()[self._line_at])
        self.new_snaps.extend(self.snaps.finish(
            self.t, (self.injected, list(volumes), pressures[self.feed], line_held)))

    def _watch_step(self, solver: Integrator) -> None:
        """The rest of the last step, now that time has reached its end."""
        self._watch(solver.t, 1.0)
        # The state's rates at the step's end: the solver's own last evaluation of them (the
        # channels' flows there are in the step's peak flows).
        rates = [solver.f] if isinstance(solver, ScalarRadau) else solver.f.tolist()
        self._note_exchange(rates)

    def _member_rates(self, rates: list[float], flow: float) -> list[float]:
        """
        How fast each member's fluid changes [m^3/s], from the state's rates at a pump flow.

        The segments' volumes, the tip's from mass (the pump's flow less the others'), and
        behind a compliant line, last, the line's fluid: the line is a member the pump feeds,
        as in the quasi-static equilibrium, so fluid the line gives a segment faster than the
        pump refills it (its gas expanding into a snapping segment) is exchange, and the
        exchange beyond the pump's own flow is counted on them all
        (softseq_ros.dynamic.events.exchange_flow).
        """
        volume_rates = rates[:self.n - 1]
        if self.line is None:
            volume_rates.append(flow - sum(volume_rates))
            return volume_rates
        line_rate = rates[self._line_at]
        volume_rates.append(flow - sum(volume_rates) - line_rate)
        volume_rates.append(line_rate)
        return volume_rates

    def _note_exchange(self, rates: list[float]) -> None:
        """Whether fluid moves between the members at an instant (a transient runs)."""
        exchange = exchange_flow(self._member_rates(rates, self.flow), self.flow)
        self.exchanging = exchange > max(QUIET_SHARE_OF_FLOW * abs(self.flow),
                                         float(self.atol[0]))

    def _watch(self, until: float, x_until: float) -> None:
        """
        Watch the last step from where its watching stopped to ``until`` (``x_until`` in it).

        On its polynomial: the channels' peak flows (Reynolds numbers), the segments' passages
        through folds of their curves, and the snap-throughs.
        """
        curve = self._curve
        lo = curve.x_of(self._watched_to)
        self._watched_to = until
        if not x_until > lo:
            return
        for j, peak in enumerate(curve.peak_flows(lo, x_until)):
            self.peak_reynolds[j] = max(self.peak_reynolds[j], self.laws[j].reynolds(peak))
        passed = []
        for i, folds in enumerate(self._folds):
            for fold in folds:
                for x, rising in crossings(curve.starts[i], curve.cubics[i], lo, x_until,
                                           fold.volume):
                    passed.append(FoldCrossing(
                        self.segments[i].name, fold.volume, fold.pressure, fold.kind,
                        FILLING if rising > 0 else EMPTYING, curve.time(x),
                        curve.injected_at(x)))
        self.new_fold_crossings.extend(sorted(passed, key=lambda c: c.time_s))
        self.new_snaps.extend(self.snaps.watch(curve, lo, x_until, self._state_at,
                                               self._exchange_at, self._unstable_at,
                                               self._ringing_at))

    def _exchange_at(self, curve: StepCurve, x: float) -> float:
        """The exchange the equations give at the state at ``x`` in the last step."""
        if self._dense is _PENDING:
            self._dense = StepInterpolant(self._solver.dense_output())
        t = curve.time(x)
        rates_of = self._rates if self.line is None else self._line_rates
        rates = rates_of(t, np.asarray(self._dense(t), dtype=float)).tolist()
        return exchange_flow(self._member_rates(rates, curve.flow), curve.flow)

    def _unstable_at(self, curve: StepCurve, x: float) -> bool:
        """Whether the members' equilibrium is unstable at the state at ``x`` in a step."""
        stiffness = [float(s.stiffness(v)) for s, v in zip(self.segments, curve.volumes(x))]
        if self.line is not None:
            stiffness.append(float(self.line.stiffness(max(curve.line_held(x), 0.0))))
        return unstable_stiffness(stiffness)

    def _ringing_at(self, curve: StepCurve, x: float) -> bool:
        """Whether an inertial channel's inertia outweighs its steady drop at ``x`` in a step."""
        if not self.inertial:
            return False
        flows = curve.channel_flows()
        for j in self.inertial:
            a, b, c = flows[j]
            law = self.laws[j]
            q, slope = a + x * (b + x * c), (b + 2.0 * c * x) / curve.h
            if law.inertance * abs(slope) > abs(law.drop(q)):
                return True
        return False

    def _state_at(self, curve: StepCurve, x: float) -> tuple[float, list[float], float]:
        """Injected volume, volumes and the fed segment's gauge pressure at ``x`` in a step."""
        volumes = curve.volumes(x)
        return curve.injected_at(x), volumes, self._pressure_list(volumes)[self.feed]

    # ------------------------------------------------------------------ the state now

    @property
    def y(self) -> FloatArray:
        """The state now: the volumes but the tip's, then the inertial channels' flows."""
        self._materialise()
        return self._y

    @y.setter
    def y(self, value: FloatArray) -> None:
        self._y, self._y_pending = value, False

    def _materialise(self) -> None:
        """Interpolate the state at ``t`` within the integrator's last step, if not yet done."""
        if self._y_pending:
            self._state_list()

    def _state_list(self) -> list[float]:
        """The state now as plain floats (interpolated once, if it has not been yet)."""
        if not self._y_pending:
            return self._y.tolist()
        if self._dense is _PENDING:
            self._dense = StepInterpolant(self._solver.dense_output())
        state = self._dense.at(self.t)
        self._y, self._y_pending = np.array(state), False
        return state

    def now(self) -> tuple[list[float], list[float], list[float]]:
        """
        Volumes [m^3], gauge pressures [Pa] and channel flows [m^3/s] now, as plain floats.

        Computed once per state: the rig asks for them several times per output. Not to be
        changed by the caller.
        """
        if self._now is None:
            state = self._state_list()
            volumes = self._volume_list(state, self.injected)
            pressures = self._pressure_list(volumes)
            self._now = (volumes, pressures, self._flow_list(state, pressures))
        return self._now

    def volumes(self) -> FloatArray:
        """The segment volumes [m^3] now."""
        if self._now is not None:
            return np.array(self._now[0])
        # No segment's pressure is needed for the volumes alone.
        return np.array(self._volume_list(self._state_list(), self.injected))

    def flows(self) -> FloatArray:
        """The channel flows [m^3/s] now."""
        return np.array(self.now()[2])

    def syringe_pressure(self) -> float:
        """
        The gauge pressure [Pa] at the syringe: the fed segment's plus the supply line's drop.

        Behind a compliant line, the line's own (the piston pushes on it).
        """
        if self.line is not None:
            return self.line_state()[1]
        fed = self.now()[1][self.feed]
        return fed + (self.supply.drop(self.flow) if self.supply is not None else 0.0)

    def line_state(self) -> tuple[float, float, float]:
        """
        The line's fluid [m^3], gauge pressure [Pa] and supply tube's flow [m^3/s] now.

        Behind a compliant line only; the flow is the one into the fed segment.
        """
        if self.line is None:
            raise ValueError('this network has no compliant supply line')
        state = self._state_list()
        held = state[self._line_at]
        pressure = self._line_pressure_of(held)
        if self._supply_inertial:
            return held, pressure, state[self._line_at + 1]
        return held, pressure, self._supply_flow(pressure - self.now()[1][self.feed])


def _mean_stiffness(segment: Segment) -> float:
    """The segment's largest pressure over its volume range [Pa/m^3]: its average stiffness."""
    volumes = np.linspace(segment.rest_volume, segment.max_volume, 65)
    largest = float(np.max(np.abs(segment.pressure(volumes))))
    return max(largest, 1.0) / (segment.max_volume - segment.rest_volume)


def time_constant(resistance: float, compliances: Sequence[float]) -> float:
    """R C1 C2 / (C1 + C2): how fast two compliant segments joined by R even out [s]."""
    c1, c2 = compliances
    return resistance * c1 * c2 / (c1 + c2)


def damping_ratio(resistance: float, inertance: float, compliances: Sequence[float]) -> float:
    """Zeta = (R / 2) sqrt(C / L) of the series RLC the two segments and the channel form."""
    c1, c2 = compliances
    return 0.5 * resistance * math.sqrt(c1 * c2 / (c1 + c2) / inertance)


# An injection smaller than this share of the volume scale is round-off (a command that names
# the volume the integration reached), not a jump of the state.
JUMP_SHARE = 1e-9
