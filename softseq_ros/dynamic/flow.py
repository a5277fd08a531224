"""
Segments joined by tubes and fed at the base by the syringe: the network integrated in time.

Segment i holds volume v_i at pressure p_i(v_i) (its model: table or law). The syringe imposes
the volume flow Q(t) into the base segment through the supply line; channel j carries q_j from
segment j to segment j + 1 with a pressure drop ``L_j dq_j/dt + R_j q_j + a_j q_j |q_j|``
(softseq_ros.dynamic.network). So

    dv_0/dt = Q - q_0,   dv_i/dt = q_(i-1) - q_i,   and the tip's volume follows from mass:
    v_tip = (rest volumes) + (injected volume) - (the other volumes),

which keeps the sum of the volumes equal to the injected volume to round-off at every instant.
A channel without inertance carries the flow its pressure drop drives at once; one with it
has its flow as a state. The state (the volumes but the tip's, the inertial flows) is stiff
where the channels are short and wide, so it is integrated by scipy's Radau (implicit,
error-controlled, its step chosen by the error, never fixed), one integration across as many
commands as keep the flow the same: a pump ramp costs a few steps once the transients decay.

Volumes are checked after every step: a segment pushed past the end of its curve ends the
integration with :class:`NetworkDomainError` (the quasi-static solver refuses such a volume too).
A segment drawn below its rest volume collapses (a stiff line below its rest pressure), so a
fast withdrawal pulls the far segments' fluid through the channels instead of failing; only
suction beyond vacuum is refused.
"""

from dataclasses import dataclass
import math
from typing import Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.integrate import DenseOutput, Radau

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


class NetworkDomainError(UserError):
    """A segment's volume left the range its model covers while fluid moved."""


class NetworkFlow:
    """The network's state in time: volumes, channel flows, and the supply flow now."""

    def __init__(self, segments: Sequence[Segment], network: NetworkSettings,
                 rtol: float | None = None) -> None:
        """At rest at time 0, no supply flow; ``rtol`` overrides the network's tolerance."""
        if len(network.channels) != len(segments) - 1:
            raise ValueError(f'{len(segments)} segments need {len(segments) - 1} channels, got '
                             f'{len(network.channels)}')
        self.segments = list(segments)
        self.n = len(self.segments)
        self.laws: list[TubeLaw] = [tube_law(c, network.fluid) for c in network.channels]
        self.supply = None if network.supply is None else tube_law(network.supply,
                                                                   network.fluid)
        self.inertial = [j for j, law in enumerate(self.laws) if law.inertance > 0.0]
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
        self._origin = (0.0, 0.0)   # (time, injected) where the current supply flow began
        self._solver: Radau | None = None
        self._dense = None
        # Plain floats and bound methods: with a handful of segments, numpy's cost per call on
        # tiny arrays outweighs the arithmetic, and the right-hand side runs thousands of times.
        self._pressure_of = [s.pressure for s in self.segments]
        self._bounds = list(zip(self.rest.tolist(), self.full.tolist()))
        self._collapse = [COLLAPSE_STIFFENING * _mean_stiffness(s) for s in self.segments]
        # Whether the last watched step had fluid moving between the segments (a transient),
        # and a step end the integrator reached beyond the time asked, watched once time gets
        # there (unless the flow changes first: then that step never happens).
        self.exchanging = False
        self._unwatched = False
        self._steady = [None if law.inertance > 0.0 else law.flow for law in self.laws]
        # The last two balances computed, keyed by (t, state): Radau evaluates the rates at
        # each accepted step's end, which the step's checks need again (the other entry
        # survives a numerical Jacobian's probe in between).
        self._recent: list[tuple[float, list[float], tuple]] = []
        # Volumes, pressures and flows of the state now, computed once per state: the rig
        # asks for them several times per output.
        self._now: tuple[FloatArray, FloatArray, FloatArray] | None = None

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
        if self._now is not None and asked == self._now[0].tolist():
            return self._now[1].copy()
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
        rates = [(self.flow if i == 0 else flows[i - 1]) - flows[i] for i in range(last)]
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
            self.flow = float(flow)
            self._origin = (self.t, self.injected)
            self._solver = None
            if changed:
                self._restart_watch()

    def inject_now(self, volume: float) -> None:
        """Put ``volume`` [m^3] into the base segment at once (a command that came late)."""
        self._materialise()
        self.y = self.y.copy()
        self.y[0] += volume
        self.injected += volume
        self._origin = (self.t, self.injected)
        self._solver = None
        self._now = None
        if abs(volume) > JUMP_SHARE * self.v_scale:
            self._restart_watch()

    def set_volumes(self, volumes: Sequence[float], injected: float) -> None:
        """Put the segments at ``volumes`` at rest (no channel flow): a resume."""
        self.y = np.concatenate([np.asarray(volumes[:-1], dtype=float),
                                 np.zeros(len(self.inertial))])
        self.injected = float(injected)
        self._origin = (self.t, self.injected)
        self._solver = None
        self._now = None
        self._restart_watch()

    def advance(self, t: float) -> None:
        """
        Integrate to time ``t`` [s] with the current supply flow.

        The steps are watched (domain, snap-throughs, Reynolds numbers) up to ``t`` only: the
        integrator's last step may end beyond it, with a flow that a command at ``t`` changes.
        A :class:`NetworkDomainError` leaves the state at the last instant reached.
        """
        if t <= self.t:
            return
        if self._solver is None:
            self._solver = Radau(self._rhs, self.t, self.y, self.t + HORIZON_S,
                                 rtol=self.rtol, atol=self.atol)
            self._dense = None
            self._recent = []
            self._unwatched = False
        solver = self._solver
        if solver.t < t:
            # The state now lies in the step about to be left behind.
            self._materialise()
        try:
            if self._unwatched and solver.t <= t:
                self._unwatched = False
                self._after_step(solver.t, solver.y)
            while solver.t < t:
                message = solver.step()
                if solver.status == 'failed':
                    raise NetworkDomainError(f'the network integration failed at '
                                             f'{solver.t:.6g} s: {message}')
                self.steps += 1
                # Fetched only when an output falls inside the step: a step that passes no
                # output, or one whose end is the output, needs no interpolant.
                self._dense = _PENDING
                if solver.t <= t:
                    self._after_step(solver.t, solver.y)
                else:
                    self._unwatched = True
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

    def take_snaps(self) -> list['DynamicSnap']:
        """The snap-throughs completed since the last call."""
        found, self.new_snaps = self.new_snaps, []
        return found

    def _restart_watch(self) -> None:
        """
        The flow or the state changed at once: watch the state now with its new rates.

        What the exchange was before (a calm step long ago, say) says nothing about it after:
        an episode that starts now starts here.
        """
        self._recent = []
        self._unwatched = False
        self._after_step(self.t, self.y, fresh=True)

    def _after_step(self, t: float, y: FloatArray, fresh: bool = False) -> None:
        """
        Check one step's end, watch it, keep each channel's peak Reynolds number.

        A volume beyond its segment's curve, or suction beyond vacuum, is refused; the
        exchange between the segments says whether a transient runs and finds snap-throughs.
        ``fresh``: the rates changed at once at ``t`` (see :meth:`_restart_watch`).
        """
        volumes, pressures, flows, rates = self._balance(t, y)
        injected = self._injected_at(t)
        slack = 1e-9 * self.v_scale
        beyond = np.flatnonzero(volumes > self.full + slack)
        if beyond.size:
            i = int(beyond[0])
            raise NetworkDomainError(
                f'segment {self.segments[i].name} passes the end of its curve at {t:.6g} s '
                f'({volumes[i]:.6g} m^3, injected {injected:.6g} m^3)')
        sucked = np.flatnonzero(pressures < VACUUM_GAUGE_PA)
        if sucked.size:
            i = int(sucked[0])
            raise NetworkDomainError(
                f'segment {self.segments[i].name} collapses under suction beyond vacuum at '
                f'{t:.6g} s ({volumes[i]:.6g} m^3, rest {self.rest[i]:.6g} m^3, injected '
                f'{injected:.6g} m^3): the syringe draws faster than the channels let the '
                'fluid follow')
        for j, flow in enumerate(flows.tolist()):
            self.peak_reynolds[j] = max(self.peak_reynolds[j], self.laws[j].reynolds(flow))
        # The tip's rate from mass: the pump's flow less the others'.
        volume_rates = np.append(rates[:self.n - 1], self.flow - float(np.sum(rates[:self.n - 1])))
        exchange = exchange_flow(volume_rates, self.flow)
        self.exchanging = exchange > max(QUIET_SHARE_OF_FLOW * abs(self.flow),
                                         float(self.atol[0]))
        snap = self.snaps.observe(t, injected, volumes, float(pressures[0]), exchange,
                                  self.flow, fresh)
        if snap is not None:
            self.new_snaps.append(snap)

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
            if self._dense is _PENDING:
                self._dense = _Interpolant(self._solver.dense_output())
            self._y, self._y_pending = np.asarray(self._dense(self.t), dtype=float), False

    def _current(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Volumes, pressures and channel flows of the state now (computed once per state)."""
        if self._now is None:
            state = self.y.tolist()
            volumes = self._volume_list(state, self.injected)
            pressures = self._pressure_list(volumes)
            self._now = (np.array(volumes), np.array(pressures),
                         np.array(self._flow_list(state, pressures)))
        return self._now

    def volumes(self) -> FloatArray:
        """The segment volumes [m^3] now."""
        if self._now is not None:
            return self._now[0].copy()
        # No segment's pressure is needed for the volumes alone.
        return np.array(self._volume_list(self.y.tolist(), self.injected))

    def flows(self) -> FloatArray:
        """The channel flows [m^3/s] now."""
        return self._current()[2].copy()

    def syringe_pressure(self) -> float:
        """The gauge pressure [Pa] at the syringe: the base segment's plus the supply line's."""
        base = float(self._current()[1][0])
        return base + (self.supply.drop(self.flow) if self.supply is not None else 0.0)


# An interpolant the last step has and the outputs have not yet asked for.
_PENDING = object()


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
        dense = self.dense
        if not self.fast:
            return dense(t)
        x = (t - dense.t_old) / dense.h
        powers = [x]
        for _ in range(dense.order):
            powers.append(powers[-1] * x)
        return np.array([start + sum(q * p for q, p in zip(row, powers))
                         for start, row in zip(self.start, self.rows)])


def _mean_stiffness(segment: Segment) -> float:
    """The segment's largest pressure over its volume range [Pa/m^3]: its average stiffness."""
    volumes = np.linspace(segment.rest_volume, segment.max_volume, 65)
    largest = max(abs(float(segment.pressure(v))) for v in volumes)
    return max(largest, 1.0) / (segment.max_volume - segment.rest_volume)


def time_constant(resistance: float, compliances: Sequence[float]) -> float:
    """R C1 C2 / (C1 + C2): how fast two compliant segments joined by R even out [s]."""
    c1, c2 = compliances
    return resistance * c1 * c2 / (c1 + c2)


def damping_ratio(resistance: float, inertance: float, compliances: Sequence[float]) -> float:
    """Zeta = (R / 2) sqrt(C / L) of the series RLC the two segments and the channel form."""
    c1, c2 = compliances
    return 0.5 * resistance * math.sqrt(c1 * c2 / (c1 + c2) / inertance)


# A snap-through, as the network lives it: fluid exchanged between the segments faster than
# this many times the pump's flow, and more of it than this share of the volume scale.
SNAP_EXCHANGE_PER_FLOW = 5.0
SNAP_SHARE_OF_SCALE = 1e-3
# An episode that begins with a change of the pump's flow is a snap-through only if its
# exchange then rises to more than this many times where it began (an instability gathers
# speed; fluid evening out after the change does not).
SNAP_ACCELERATION = 2.0
# An injection smaller than this share of the volume scale is round-off (a command that names
# the volume the integration reached), not a jump of the state.
JUMP_SHARE = 1e-9


@dataclass
class DynamicSnap:
    """
    A snap-through in time: where it started and ended, the fluid it moved, how fast, how long.

    ``injected`` [m^3] and ``start_s`` [s]: where the exchange first outran the pump;
    ``duration_s``: from 10 % to 90 % of the fluid moved; ``peak_exchange_m3_per_s``: the
    fastest exchange; ``fluid_moved_m3``: the fluid exchanged between the segments beyond
    what the pump pushed; volumes and pressures (gauge, at the base) before and after.
    """

    injected: float
    start_s: float
    end_s: float
    duration_s: float
    fluid_moved_m3: float
    peak_exchange_m3_per_s: float
    from_volumes: list[float]
    to_volumes: list[float]
    from_pressure: float
    to_pressure: float


def exchange_flow(volume_rates: FloatArray, supply_flow: float) -> float:
    """Fluid moving between the segments beyond the pump's flow [m^3/s]."""
    return 0.5 * max(float(np.sum(np.abs(volume_rates))) - abs(supply_flow), 0.0)


class SnapWatcher:
    """Finds snap-throughs in the network's steps: episodes of fast exchange, timed."""

    def __init__(self, v_scale: float) -> None:
        """Episodes must move more than SNAP_SHARE_OF_SCALE of ``v_scale``."""
        self.v_scale = v_scale
        self.found: list[DynamicSnap] = []
        # (time, injected, exchange, volumes, pressure) of the steps of the episode under way
        self._episode: list[tuple[float, float, float, FloatArray, float]] | None = None
        self._last: tuple[float, float, float, FloatArray, float] | None = None
        self._fresh_start = False   # the episode under way began with a change of flow

    def observe(self, t: float, injected: float, volumes: FloatArray, pressure: float,
                exchange: float, supply_flow: float, fresh: bool = False) -> DynamicSnap | None:
        """
        One step's state; a snap when an episode of fast exchange has just ended.

        ``fresh``: the flow or the state changed at once at ``t``, so an episode begins here,
        not at the last calm step before.
        """
        fast = exchange > SNAP_EXCHANGE_PER_FLOW * abs(supply_flow) and exchange > 0.0
        sample = (t, injected, exchange, volumes.copy(), pressure)
        if fast:
            if self._episode is None:
                # The episode starts at the last calm step: the state before the snap.
                self._episode = [self._last] if self._last is not None and not fresh else []
                self._fresh_start = fresh
            self._episode.append(sample)
            self._last = sample
            return None
        self._last = sample
        if self._episode is None:
            return None
        episode, self._episode = self._episode + [sample], None
        return self._close(episode)

    def _close(self, episode: list) -> DynamicSnap | None:
        times = np.array([s[0] for s in episode])
        rates = np.array([s[2] for s in episode])
        # The fluid moved: the exchange integrated over the episode (trapezoids on the steps).
        moved = np.concatenate([[0.0], np.cumsum(0.5 * (rates[1:] + rates[:-1])
                                                 * np.diff(times))])
        total = float(moved[-1])
        if total <= SNAP_SHARE_OF_SCALE * self.v_scale:
            return None
        # An episode that began with a change of the flow (or a jump of the state) is the
        # fluid evening out, fastest where it begins, unless its exchange then gathers speed
        # as an instability's does. One that began while the flow stayed is a snap-through.
        if self._fresh_start and rates.max() <= SNAP_ACCELERATION * rates[0]:
            return None
        t10, t90 = np.interp([0.1 * total, 0.9 * total], moved, times)
        first, last = episode[0], episode[-1]
        snap = DynamicSnap(float(first[1]), float(first[0]), float(last[0]), float(t90 - t10),
                           total, float(rates.max()), [float(v) for v in first[3]],
                           [float(v) for v in last[3]], float(first[4]), float(last[4]))
        self.found.append(snap)
        return snap
