"""
Segments joined by tubes and fed by the syringe: the network integrated in time.

Segment i holds volume v_i at pressure p_i(v_i) (its model: table or law). The syringe imposes
the volume flow Q(t) into the segment f it feeds (the base unless the scene says otherwise)
through the supply line; channel j carries q_j from segment j to segment j + 1 with a pressure
drop ``L_j dq_j/dt + R_j q_j + a_j q_j |q_j|`` (softseq_ros.dynamic.network). So

    dv_i/dt = [i = f] Q + q_(i-1) - q_i   (q_(-1) = 0),   and the tip's volume follows from
    mass: v_tip = (rest volumes) + (injected volume) - (the other volumes),

which keeps the sum of the volumes equal to the injected volume to round-off at every instant.
A channel without inertance carries the flow its pressure drop drives at once; one with it
has its flow as a state. The state (the volumes but the tip's, the inertial flows) is stiff
where the channels are short and wide, so it is integrated by scipy's Radau (implicit,
error-controlled, its step chosen by the error, never fixed), one integration across as many
commands as keep the flow the same: a pump ramp costs a few steps once the transients decay.
The network's state has a handful of entries, so scipy's general wrappers cost more than the
arithmetic: by default (``integrator='radau'``) scipy's Radau IIA runs without them (ported to
plain floats for a state of one entry, :class:`_ScalarRadau`; with direct calls otherwise,
:class:`_LeanRadau`); ``integrator='scipy-radau'`` is scipy's Radau as it comes, kept for
comparison. :meth:`NetworkFlow.advance_through` reads many output times at once, each step's
outputs from one evaluation of its interpolant.

What happens within a step (a segment leaving its range or passing a fold of its curve, each
channel's peak flow, the snap-throughs) is found on the step's collocation polynomial, located
in time (softseq_ros.dynamic.events), and only up to the time asked. A segment pushed past the
end of its curve ends the integration with :class:`NetworkDomainError` at the located instant
(the quasi-static solver refuses such a volume too). A segment drawn below its rest volume
collapses (a stiff line below its rest pressure), so a fast withdrawal pulls the far segments'
fluid through the channels instead of failing; only suction beyond vacuum is refused.
"""

import math
from typing import Callable, Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.integrate import DenseOutput, Radau
from scipy.linalg.lapack import dgetrf, dgetrs, zgetrf, zgetrs

from softseq_ros.dynamic.events import (
    EMPTYING,
    FILLING,
    DynamicSnap,
    FoldCrossing,
    SnapWatcher,
    StepCurve,
    crossings,
    exchange_flow,
    first_beyond,
    segment_folds,
)
from softseq_ros.dynamic.network import TubeLaw, tube_law
from softseq_ros.errors import UserError
from softseq_ros.scene.network import NetworkSettings
from softseq_ros.segments.models import Segment

FloatArray = NDArray[np.float64]
# Absolute tolerances: this share of the volume scale for a volume, of the volume scale per
# second for a flow (with the relative tolerance on top).
ATOL_SHARE = 1e-3
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
# 'radau': scipy's Radau IIA without scipy's general wrappers (the default): _ScalarRadau for a
# state of one entry (two segments, one channel without inertance), _LeanRadau otherwise;
# 'scipy-radau': scipy's Radau as it comes, for comparison.
INTEGRATORS = ('radau', 'scipy-radau')


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
                 rtol: float | None = None, integrator: str = 'radau') -> None:
        """
        At rest at time 0, no supply flow; ``rtol`` overrides the network's tolerance.

        ``integrator``: one of INTEGRATORS.
        """
        if len(network.channels) != len(segments) - 1:
            raise ValueError(f'{len(segments)} segments need {len(segments) - 1} channels, got '
                             f'{len(network.channels)}')
        if integrator not in INTEGRATORS:
            raise ValueError(f'integrator must be one of {", ".join(INTEGRATORS)}, got '
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
        size = self.n - 1 + len(self.inertial)
        self.atol = np.full(size, self.rtol * ATOL_SHARE * self.v_scale)
        self.t = 0.0
        self.injected = 0.0
        self.flow = 0.0
        self._y_pending = False
        self.y = np.concatenate([self.rest[:-1], np.zeros(len(self.inertial))])
        self.peak_reynolds = [0.0] * len(self.laws)
        self.steps = 0
        self.snaps = SnapWatcher(self.v_scale)
        self.new_snaps: list[DynamicSnap] = []
        self.new_fold_crossings: list[FoldCrossing] = []
        self._origin = (0.0, 0.0)   # (time, injected) where the current supply flow began
        self._solver: Radau | None = None
        self._dense = None
        # Plain floats and bound methods: with a handful of segments, numpy's cost per call on
        # tiny arrays outweighs the arithmetic, and the right-hand side runs thousands of times.
        self._pressure_of = [s.pressure for s in self.segments]
        self._bounds = list(zip(self.rest.tolist(), self.full.tolist()))
        self._collapse = [COLLAPSE_STIFFENING * _mean_stiffness(s) for s in self.segments]
        # The levels a segment's volume must not pass: the end of its curve (with round-off's
        # slack: a programme may end exactly there) and, below its rest volume, where its
        # collapse reaches vacuum; and the folds of its curve, which are reported.
        slack = 1e-9 * self.v_scale
        self._upper = [hi + slack for _, hi in self._bounds]
        self._lower = [lo + min(VACUUM_GAUGE_PA - float(pressure(lo)), 0.0) / collapse
                       for pressure, (lo, _), collapse in zip(self._pressure_of, self._bounds,
                                                              self._collapse)]
        self._folds = [segment_folds(s) for s in self.segments]
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
        # The next stretch watched starts where the flow or the state changed at once.
        self._fresh = False
        self._steady = [None if law.inertance > 0.0 else law.flow for law in self.laws]
        # The last two balances computed, keyed by (t, state): Radau evaluates the rates at
        # each accepted step's end, which the step's checks need again (the other entry
        # survives a numerical Jacobian's probe in between).
        self._recent: list[tuple[float, list[float], tuple]] = []
        # Volumes, pressures and flows of the state now, computed once per state: the rig
        # asks for them several times per output.
        self._now: tuple[list[float], list[float], list[float]] | None = None

    # ------------------------------------------------------------------ the equations

    def volumes_of(self, y: FloatArray, injected: float) -> FloatArray:
        """All segment volumes from a state and the injected volume (mass fixes the tip's)."""
        return np.array(self._volume_list(y.tolist(), injected))

    def _volume_list(self, state: list[float], injected: float) -> list[float]:
        others = state[:self.n - 1]
        return others + [self.rest_total + injected - sum(others)]

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
        state = y.tolist()
        for key_t, key_state, found in self._recent:
            if key_t == t and key_state == state:
                return found
        volumes = self._volume_list(state, self._injected_at(t))
        pressures = self._pressure_list(volumes)
        flows = self._flow_list(state, pressures)
        last = self.n - 1
        rates = [-flows[0]] + [flows[i - 1] - flows[i] for i in range(1, last)]
        if self.feed < last:
            rates[self.feed] += self.flow
        for j in self.inertial:
            law = self.laws[j]
            rates.append((pressures[j] - pressures[j + 1] - law.drop(flows[j])) / law.inertance)
        found = (np.array(volumes), np.array(pressures), np.array(flows), np.array(rates))
        self._recent = [self._recent[-1], (t, state, found)] if self._recent \
            else [(t, state, found)]
        return found

    def _rhs(self, t: float, y: FloatArray) -> FloatArray:
        # A copy: the solver may work on the array it is given, and the balance is kept.
        return self._balance(t, y)[3].copy()

    def _rates(self, t: float, y: FloatArray) -> FloatArray:
        """
        The state's rates alone, as :meth:`_balance` computes them (the same numbers).

        What the integrator asks for, a dozen times per step: nothing kept, nothing but the
        rates built. The step's checks ask :meth:`_balance` at its end.
        """
        state = y.tolist()
        start_t, start_injected = self._origin
        last = self.n - 1
        others = state[:last]
        volumes = others + [self.rest_total + (start_injected + self.flow * (t - start_t))
                            - sum(others)]
        pressures = self._pressure_list(volumes)
        flows = self._flow_list(state, pressures)
        rates = [-flows[0]]
        rates += [flows[i - 1] - flows[i] for i in range(1, last)]
        if self.feed < last:
            rates[self.feed] += self.flow
        for j in self.inertial:
            law = self.laws[j]
            rates.append((pressures[j] - pressures[j + 1] - law.drop(flows[j])) / law.inertance)
        return np.array(rates)

    def _new_solver(self) -> 'Radau | _ScalarRadau':
        if self.integrator == 'scipy-radau':
            return Radau(self._rhs, self.t, self.y, self.t + HORIZON_S, rtol=self.rtol,
                         atol=self.atol)
        if self.n == 2 and not self.inertial:
            return _ScalarRadau(self._rate_of_one, self.t, float(self.y[0]),
                                self.t + HORIZON_S, self.rtol, float(self.atol[0]))
        return _LeanRadau(self._rates, self.t, self.y, self.t + HORIZON_S, self.rtol,
                          self.atol)

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
        if self.feed < self.n - 1:
            # The tip's volume follows from the injected volume by mass.
            self.y[self.feed] += volume
        self.injected += volume
        self._origin = (self.t, self.injected)
        self._now = None
        if abs(volume) > JUMP_SHARE * self.v_scale:
            self._restart_watch()

    def set_volumes(self, volumes: Sequence[float], injected: float) -> None:
        """Put the segments at ``volumes`` at rest (no channel flow): a resume."""
        self._end_integration()
        self.y = np.concatenate([np.asarray(volumes[:-1], dtype=float),
                                 np.zeros(len(self.inertial))])
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

    def _current_solver(self) -> 'Radau | _ScalarRadau':
        """The integrator of the current flow, started afresh after a change of flow."""
        if self._solver is None:
            self._solver = self._new_solver()
            self._dense = None
            self._recent = []
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

    def _step(self, solver: 'Radau | _ScalarRadau') -> None:
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

    def _step_curve(self, solver: 'Radau | _ScalarRadau') -> StepCurve:
        """The last step's continuous solution (its collocation cubic), as segment volumes."""
        if isinstance(solver, _ScalarRadau):
            t_old, h, start, cubic = solver.sol
            starts, cubics = [start], [cubic]
        else:
            if self._dense is _PENDING:
                self._dense = _Interpolant(solver.dense_output())
            dense = self._dense
            t_old, h = dense.dense.t_old, dense.dense.h
            starts = dense.start[:self.n - 1]
            cubics = [tuple(row) for row in dense.rows[:self.n - 1]]
        # The tip's volume by mass: the rest volumes and what was injected, less the others.
        injected = self._injected_at(t_old)
        tip_start = self.rest_total + injected - sum(starts)
        tip = (self.flow * h - sum(q[0] for q in cubics), -sum(q[1] for q in cubics),
               -sum(q[2] for q in cubics))
        return StepCurve(t_old, h, (*starts, tip_start), (*cubics, tip), self.flow, self.feed,
                         injected)

    def _first_exit(self, curve: StepCurve) -> tuple[float, str]:
        """The first instant in a step where a segment leaves its range (inf: none), and why."""
        first, why = math.inf, ''
        for i, (start, cubic) in enumerate(zip(curve.starts, curve.cubics)):
            for level, sign, kind in ((self._upper[i], 1.0, 'end'),
                                      (self._lower[i], -1.0, 'vacuum')):
                x = first_beyond(start, cubic, 0.0, 1.0, level, sign)
                if x is not None and curve.time(x) < first:
                    first, why = curve.time(x), f'{kind} {i}'
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
            self._dense = _Interpolant(self._solver.dense_output())
        self.y = np.asarray(self._dense(t), dtype=float)
        self.t = t
        self.injected = curve.injected_at(x)
        self._origin = (self.t, self.injected)
        self._now = None
        kind, i = self._leaves_why.split()
        segment = self.segments[int(i)]
        volume = curve.volumes(x)[int(i)]
        self._solver = None
        self._curve = None
        self._leaves_at = math.inf
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
                        self._dense = _Interpolant(solver.dense_output())
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
        return np.column_stack([others, tip])

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
        pressures = np.empty_like(volumes)
        for i, (segment, (lo, hi), collapse) in enumerate(zip(self.segments, self._bounds,
                                                                self._collapse)):
            v = volumes[:, i]
            inside = np.asarray(segment.pressure(np.clip(v, lo, hi)), dtype=float)
            below = float(segment.pressure(lo)) + collapse * (v - lo)
            pressures[:, i] = np.where(v < lo, below, inside)
        flows = np.empty((times.size, len(self.laws)))
        inertial = iter(range(self.n - 1, states.shape[1]))
        for j, law in enumerate(self.laws):
            if self._steady[j] is None:
                flows[:, j] = states[:, next(inertial)]
                continue
            drops = pressures[:, j] - pressures[:, j + 1]
            if law.quadratic == 0.0 and law.turbulent == 0.0:
                flows[:, j] = drops / law.resistance
            else:
                flows[:, j] = [law.flow(d) for d in drops.tolist()]
        syringe = pressures[:, self.feed] + (self.supply.drop(self.flow)
                                             if self.supply is not None else 0.0)
        return injected, volumes, flows, syringe

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

        What the exchange was before (a calm step long ago, say) says nothing about it after:
        an episode that is fast where the next stretch starts starts there.
        """
        self._recent = []
        self._fresh = True
        _, _, flows, rates = self._balance(self.t, self.y)
        for j, flow in enumerate(flows.tolist()):
            self.peak_reynolds[j] = max(self.peak_reynolds[j], self.laws[j].reynolds(flow))
        self._note_exchange(rates.tolist())

    def _watch_step(self, solver: 'Radau | _ScalarRadau') -> None:
        """The rest of the last step, now that time has reached its end."""
        self._watch(solver.t, 1.0)
        # The state's rates at the step's end: the solver's own last evaluation of them (the
        # channels' flows there are in the step's peak flows).
        rates = [solver.f] if isinstance(solver, _ScalarRadau) else solver.f.tolist()
        self._note_exchange(rates)

    def _note_exchange(self, rates: list[float]) -> None:
        """Whether fluid moves between the segments at an instant (a transient runs)."""
        # The tip's rate from mass: the pump's flow less the others'.
        volume_rates = rates[:self.n - 1]
        volume_rates.append(self.flow - sum(volume_rates))
        exchange = exchange_flow(volume_rates, self.flow)
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
        fresh, self._fresh = self._fresh, False
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
        self.new_snaps.extend(self.snaps.watch(curve, lo, x_until, fresh, self._state_at,
                                               self._exchange_at))

    def _exchange_at(self, curve: StepCurve, x: float) -> float:
        """The exchange the equations give at the state at ``x`` in the last step."""
        if self._dense is _PENDING:
            self._dense = _Interpolant(self._solver.dense_output())
        t = curve.time(x)
        rates = self._rates(t, np.asarray(self._dense(t), dtype=float)).tolist()[:self.n - 1]
        rates.append(curve.flow - sum(rates))
        return exchange_flow(rates, curve.flow)

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
            self._dense = _Interpolant(self._solver.dense_output())
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
        """The gauge pressure [Pa] at the syringe: the fed segment's plus the supply line's."""
        fed = self.now()[1][self.feed]
        return fed + (self.supply.drop(self.flow) if self.supply is not None else 0.0)


# An interpolant the last step has and the outputs have not yet asked for.
_PENDING = object()


class _LeanRadau(Radau):
    """
    scipy's Radau IIA, step for step and to the bit, for a system of a handful of equations.

    The method, its error estimate, step-size control, Newton iteration and finite-difference
    Jacobian are scipy's own (its ``_step_impl`` runs unchanged). What changes is around them:
    the right-hand side is called without scipy's argument checks and copies, and the LU
    factorisations and solves go to LAPACK's getrf / getrs directly (what scipy's lu_factor /
    lu_solve call, so the same numbers), without the checks of finiteness and the array
    conversions that cost more than the solve of a 2 x 2 system.
    """

    def __init__(self, fun: Callable[[float, FloatArray], FloatArray], t0: float,
                 y0: FloatArray, t_bound: float, rtol: float, atol: FloatArray) -> None:
        super().__init__(fun, t0, y0, t_bound, rtol=rtol, atol=atol)
        self.fun = fun
        self.lu = self._factor
        self.solve_lu = _lu_solve

    def _factor(self, matrix: NDArray) -> tuple:
        self.nlu += 1
        getrf = zgetrf if np.iscomplexobj(matrix) else dgetrf
        lu, pivots, info = getrf(matrix, overwrite_a=True)
        if info < 0:
            raise ValueError(f'illegal value in argument {-info} of getrf')
        return lu, pivots, np.iscomplexobj(lu)


def _lu_solve(factors: tuple, rhs: NDArray) -> NDArray:
    lu, pivots, complex_ = factors
    solution, info = (zgetrs if complex_ else dgetrs)(lu, pivots, rhs, overwrite_b=True)
    if info != 0:
        raise ValueError(f'illegal value in argument {-info} of getrs')
    return solution


# scipy's Radau IIA (scipy.integrate._ivp.radau, Hairer & Wanner, Solving ODEs II, IV.8): the
# collocation nodes, the error estimate's weights, the eigenvalues and eigenvectors of the
# method's matrix, the dense output's coefficients, its Newton and step-size constants.
_S6 = 6.0 ** 0.5
_C = ((4.0 - _S6) / 10.0, (4.0 + _S6) / 10.0, 1.0)
_E = ((-13.0 - 7.0 * _S6) / 3.0, (-13.0 + 7.0 * _S6) / 3.0, -1.0 / 3.0)
_MU_REAL = 3.0 + 3.0 ** (2.0 / 3.0) - 3.0 ** (1.0 / 3.0)
_MU_COMPLEX = (3.0 + 0.5 * (3.0 ** (1.0 / 3.0) - 3.0 ** (2.0 / 3.0))
               - 0.5j * (3.0 ** (5.0 / 6.0) + 3.0 ** (7.0 / 6.0)))
_T = ((0.09443876248897524, -0.14125529502095421, 0.03002919410514742),
      (0.25021312296533332, 0.20412935229379994, -0.38294211275726192),
      (1.0, 1.0, 0.0))
_TI = ((4.17871859155190428, 0.32768282076106237, 0.52337644549944951),
       (-4.17871859155190428, -0.32768282076106237, 0.47662355450055044),
       (0.50287263494578682, -2.57192694985560522, 0.59603920482822492))
_TI_COMPLEX = tuple(a + 1j * b for a, b in zip(_TI[1], _TI[2]))
_P = ((13.0 / 3.0 + 7.0 * _S6 / 3.0, -23.0 / 3.0 - 22.0 * _S6 / 3.0, 10.0 / 3.0 + 5.0 * _S6),
      (13.0 / 3.0 - 7.0 * _S6 / 3.0, -23.0 / 3.0 + 22.0 * _S6 / 3.0, 10.0 / 3.0 - 5.0 * _S6),
      (1.0 / 3.0, -8.0 / 3.0, 10.0 / 3.0))
_NEWTON_MAXITER = 6
_MIN_FACTOR = 0.2
_MAX_FACTOR = 10.0
_EPS = float(np.finfo(float).eps)
# scipy's finite-difference Jacobian (scipy.integrate._ivp.common.num_jac): its step control.
_DIFF_REJECT = _EPS ** 0.875
_DIFF_SMALL = _EPS ** 0.75
_DIFF_BIG = _EPS ** 0.25
_MIN_JAC_FACTOR = 1e3 * _EPS


def _predict_factor(h_abs: float, h_abs_old: float | None, error_norm: float,
                    error_norm_old: float | None) -> float:
    """The step-size factor of scipy's Radau (Hairer & Wanner's predictive controller)."""
    if error_norm_old is None or h_abs_old is None or error_norm == 0.0:
        multiplier = 1.0
    else:
        multiplier = h_abs / h_abs_old * (error_norm_old / error_norm) ** 0.25
    if error_norm == 0.0:
        return math.inf
    return min(1.0, multiplier) * error_norm ** -0.25


class _ScalarDense:
    """One step's interpolant in the layout of scipy's RadauDenseOutput (one equation)."""

    order = 2

    def __init__(self, t_old: float, t: float, y_old: float, q: tuple[float, ...]) -> None:
        self.t_old, self.t, self.h = t_old, t, t - t_old
        self.y_old = np.array([y_old])
        self.Q = np.array([q])

    def __call__(self, t: float | FloatArray) -> FloatArray:
        x = (np.asarray(t, dtype=float) - self.t_old) / self.h
        q0, q1, q2 = self.Q[0]
        return np.asarray(q0 * x + q1 * (x * x) + q2 * (x * x * x) + self.y_old[0])[None]


class _ScalarRadau:
    """
    scipy's Radau IIA for one equation, on plain floats.

    Two segments joined by one channel without inertance have one state (the base's
    volume; mass gives the tip's), and scipy's Radau spends on that one number far more in
    array handling than in arithmetic. This is its algorithm, line for line (the step,
    the simplified Newton iteration on the collocation system, the error estimate and its
    refinement after a rejection, the predictive step-size control, the finite-difference
    Jacobian and its adaptive increment, the initial step), with the 1 x 1 and complex
    1 x 1 linear systems solved by division. Its sums are not in scipy's order to the last
    bit, and the error estimate (a small difference of large numbers) magnifies that: its
    step sizes leave scipy's by about 1e-8 relative, its results differ from scipy's by
    what the tolerance allows.
    ``solver.y``, ``t``, ``status``, ``step()`` and ``dense_output()`` as scipy's solvers.
    """

    TOO_SMALL_STEP = 'Required step size is less than spacing between numbers.'

    def __init__(self, fun: Callable[[float, float], float], t0: float, y0: float,
                 t_bound: float, rtol: float, atol: float) -> None:
        self.fun = fun
        self.t, self._y, self.t_bound = float(t0), float(y0), float(t_bound)
        self.rtol, self.atol = max(float(rtol), 100.0 * _EPS), float(atol)
        self.status = 'running'
        self.f = fun(self.t, self._y)
        self.h_abs = self._initial_step()
        self.h_abs_old: float | None = None
        self.error_norm_old: float | None = None
        self.newton_tol = max(10.0 * _EPS / self.rtol, min(0.03, self.rtol ** 0.5))
        self.sol: tuple[float, float, float, tuple[float, ...]] | None = None
        self.jac_factor: float | None = None
        self.njev = self.nlu = 0
        self.J = self._jacobian(self.t, self._y, self.f)
        self.current_jac = True
        self.lu_real: float | None = None
        self.lu_complex: complex | None = None

    @property
    def y(self) -> FloatArray:
        return np.array([self._y])

    def dense_output(self) -> _ScalarDense:
        t_old, h, y_old, q = self.sol
        return _ScalarDense(t_old, t_old + h, y_old, q)

    def step(self) -> str | None:
        if self.t == self.t_bound:
            self.status = 'finished'
            return None
        success, message = self._step_impl()
        if not success:
            self.status = 'failed'
        elif self.t >= self.t_bound:
            self.status = 'finished'
        return message

    def _initial_step(self) -> float:
        """The initial step of scipy (select_initial_step) for one equation, order 3."""
        t0, y0, f0 = self.t, self._y, self.f
        interval = abs(self.t_bound - t0)
        if interval == 0.0:
            return 0.0
        scale = self.atol + abs(y0) * self.rtol
        d0, d1 = abs(y0 / scale), abs(f0 / scale)
        h0 = 1e-6 if d0 < 1e-5 or d1 < 1e-5 else 0.01 * d0 / d1
        h0 = min(h0, interval)
        f1 = self.fun(t0 + h0, y0 + h0 * f0)
        d2 = abs((f1 - f0) / scale) / h0
        if d1 <= 1e-15 and d2 <= 1e-15:
            h1 = max(1e-6, h0 * 1e-3)
        else:
            h1 = (0.01 / max(d1, d2)) ** 0.25
        return min(100.0 * h0, h1, interval)

    def _jacobian(self, t: float, y: float, f: float) -> float:
        """The finite-difference Jacobian of scipy (num_jac) for one equation."""
        self.njev += 1
        factor = _EPS ** 0.5 if self.jac_factor is None else self.jac_factor
        y_scale = (1.0 if f >= 0.0 else -1.0) * max(self.atol, abs(y))
        h = (y + factor * y_scale) - y
        while h == 0.0:
            factor *= 10.0
            h = (y + factor * y_scale) - y
        f_new = self.fun(t, y + h)
        diff = f_new - f
        max_diff = abs(diff)
        scale = max(abs(f), abs(f_new))
        if max_diff < _DIFF_REJECT * scale:
            new_factor = 10.0 * factor
            h_new = (y + new_factor * y_scale) - y
            f_new = self.fun(t, y + h_new)
            diff_new = f_new - f
            max_diff_new = abs(diff_new)
            scale_new = max(abs(f), abs(f_new))
            if max_diff * scale_new < max_diff_new * scale:
                factor, h, diff = new_factor, h_new, diff_new
                scale, max_diff = scale_new, max_diff_new
        jac = diff / h
        if max_diff < _DIFF_SMALL * scale:
            factor *= 10.0
        if max_diff > _DIFF_BIG * scale:
            factor *= 0.1
        self.jac_factor = max(factor, _MIN_JAC_FACTOR)
        return jac

    def _predicted(self, t: float) -> float:
        t_old, h, y_old, (q0, q1, q2) = self.sol
        x = (t - t_old) / h
        return q0 * x + q1 * (x * x) + q2 * (x * x * x) + y_old

    def _collocation(self, t: float, y: float, h: float, z0: tuple[float, float, float],
                     scale: float, lu_real: float, lu_complex: complex
                     ) -> tuple[bool, int, tuple[float, float, float], float | None]:
        """The simplified Newton iteration on the collocation system, as scipy has it."""
        fun, tol = self.fun, self.newton_tol
        m_real, m_complex = _MU_REAL / h, _MU_COMPLEX / h
        (a0, a1, a2), (b0, b1, b2), (c0, c1, c2) = _TI
        w0 = a0 * z0[0] + a1 * z0[1] + a2 * z0[2]
        w1 = b0 * z0[0] + b1 * z0[1] + b2 * z0[2]
        w2 = c0 * z0[0] + c1 * z0[1] + c2 * z0[2]
        z = z0
        ch = (h * _C[0], h * _C[1], h * _C[2])
        k1, k2, k3 = _TI_COMPLEX
        (t00, t01, t02), (t10, t11, t12), _ = _T
        dw_norm_old = None
        rate = None
        converged = False
        k = 0
        for k in range(_NEWTON_MAXITER):
            f0 = fun(t + ch[0], y + z[0])
            f1 = fun(t + ch[1], y + z[1])
            f2 = fun(t + ch[2], y + z[2])
            if not (math.isfinite(f0) and math.isfinite(f1) and math.isfinite(f2)):
                break
            f_real = a0 * f0 + a1 * f1 + a2 * f2 - m_real * w0
            f_complex = k1 * f0 + k2 * f1 + k3 * f2 - m_complex * (w1 + 1j * w2)
            d0 = f_real / lu_real
            d_complex = f_complex / lu_complex
            d1, d2 = d_complex.real, d_complex.imag
            dw_norm = math.sqrt(((d0 / scale) ** 2 + (d1 / scale) ** 2 + (d2 / scale) ** 2)
                                / 3.0)
            if dw_norm_old is not None:
                rate = dw_norm / dw_norm_old
            if rate is not None and (rate >= 1.0 or rate ** (_NEWTON_MAXITER - k)
                                     / (1.0 - rate) * dw_norm > tol):
                break
            w0, w1, w2 = w0 + d0, w1 + d1, w2 + d2
            z = (t00 * w0 + t01 * w1 + t02 * w2, t10 * w0 + t11 * w1 + t12 * w2, w0 + w1)
            if dw_norm == 0.0 or rate is not None and rate / (1.0 - rate) * dw_norm < tol:
                converged = True
                break
            dw_norm_old = dw_norm
        return converged, k + 1, z, rate

    def _step_impl(self) -> tuple[bool, str | None]:
        t, y, f = self.t, self._y, self.f
        rtol, atol = self.rtol, self.atol
        min_step = 10.0 * abs(math.nextafter(t, math.inf) - t)
        if self.h_abs < min_step:
            h_abs, h_abs_old, error_norm_old = min_step, None, None
        else:
            h_abs, h_abs_old, error_norm_old = self.h_abs, self.h_abs_old, self.error_norm_old
        jac, lu_real, lu_complex = self.J, self.lu_real, self.lu_complex
        current_jac = self.current_jac
        rejected = False
        while True:
            if h_abs < min_step:
                return False, self.TOO_SMALL_STEP
            t_new = min(t + h_abs, self.t_bound)
            h = t_new - t
            h_abs = abs(h)
            if self.sol is None:
                z0 = (0.0, 0.0, 0.0)
            else:
                z0 = tuple(self._predicted(t + h * c) - y for c in _C)
            scale = atol + abs(y) * rtol
            converged = False
            while not converged:
                if lu_real is None or lu_complex is None:
                    self.nlu += 2
                    lu_real = _MU_REAL / h - jac
                    lu_complex = _MU_COMPLEX / h - jac
                converged, n_iter, z, rate = self._collocation(t, y, h, z0, scale, lu_real,
                                                               lu_complex)
                if not converged:
                    if current_jac:
                        break
                    jac = self._jacobian(t, y, f)
                    current_jac = True
                    lu_real = lu_complex = None
            if not converged:
                h_abs *= 0.5
                lu_real = lu_complex = None
                continue
            y_new = y + z[2]
            ze = (z[0] * _E[0] + z[1] * _E[1] + z[2] * _E[2]) / h
            error = (f + ze) / lu_real
            scale = atol + max(abs(y), abs(y_new)) * rtol
            error_norm = abs(error / scale)
            safety = 0.9 * (2 * _NEWTON_MAXITER + 1) / (2 * _NEWTON_MAXITER + n_iter)
            if rejected and error_norm > 1.0:
                error = (self.fun(t, y + error) + ze) / lu_real
                error_norm = abs(error / scale)
            if error_norm > 1.0:
                factor = _predict_factor(h_abs, h_abs_old, error_norm, error_norm_old)
                h_abs *= max(_MIN_FACTOR, safety * factor)
                lu_real = lu_complex = None
                rejected = True
            else:
                break
        recompute_jac = n_iter > 2 and rate > 1e-3
        factor = min(_MAX_FACTOR, safety * _predict_factor(h_abs, h_abs_old, error_norm,
                                                           error_norm_old))
        if not recompute_jac and factor < 1.2:
            factor = 1.0
        else:
            lu_real = lu_complex = None
        f_new = self.fun(t_new, y_new)
        if recompute_jac:
            jac = self._jacobian(t_new, y_new, f_new)
            current_jac = True
        else:
            current_jac = False
        self.h_abs_old = self.h_abs
        self.error_norm_old = error_norm
        self.h_abs = h_abs * factor
        self.t, self._y, self.f = t_new, y_new, f_new
        self.lu_real, self.lu_complex = lu_real, lu_complex
        self.current_jac, self.J = current_jac, jac
        # The dense output's cubic: Q = Z^T P.
        self.sol = (t, h, y, tuple(z[0] * _P[0][m] + z[1] * _P[1][m] + z[2] * _P[2][m]
                                   for m in range(3)))
        return True, None


class _Interpolant:
    """
    The solver's dense output of one step, evaluated at one instant at a time.

    scipy's generic call checks and reshapes its argument on every call, which costs more
    than the cubic itself; the rig asks for one instant per output. Radau's interpolant is
    y_old + Q [x, x^2, x^3], x = (t - t_old) / h, evaluated here on plain floats (the same
    terms, summed in another order: equal to round-off). Another interpolant is called as it
    is.
    """

    def __init__(self, dense: DenseOutput) -> None:
        self.dense = dense
        self.fast = all(hasattr(dense, name) for name in ('t_old', 'h', 'Q', 'order', 'y_old'))
        if self.fast:
            # Plain floats: a network's state has a handful of entries.
            self.rows = dense.Q.tolist()
            self.start = dense.y_old.tolist()

    def __call__(self, t: float) -> FloatArray:
        if not self.fast:
            return self.dense(t)
        return np.array(self.at(t))

    def at(self, t: float) -> list[float]:
        """The state at ``t`` as plain floats (the numbers a call gives)."""
        dense = self.dense
        if not self.fast:
            return np.asarray(dense(t), dtype=float).tolist()
        x = (t - dense.t_old) / dense.h
        powers = [x]
        for _ in range(dense.order):
            powers.append(powers[-1] * x)
        return [start + sum(q * p for q, p in zip(row, powers))
                for start, row in zip(self.start, self.rows)]

    def many(self, times: FloatArray) -> FloatArray:
        """The state at each of ``times`` (rows): the same operations as a call, per time."""
        dense = self.dense
        if not self.fast:
            return np.asarray(dense(times), dtype=float).T.reshape(times.size, -1)
        x = (times - dense.t_old) / dense.h
        power = x
        total = np.multiply.outer(x, dense.Q[:, 0])
        for m in range(1, dense.order + 1):
            power = power * x
            total = total + np.multiply.outer(power, dense.Q[:, m])
        return dense.y_old + total


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
