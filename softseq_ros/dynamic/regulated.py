"""
The network driven by a pressure regulator: the source holds a pressure, the fluid follows.

The regulator's outlet pressure p_r follows its programme's target P(t)
(softseq_ros.scene.regulator) as a first-order lag of time constant tau (at once when
tau = 0), and drives the supply tube's flow q_s into the fed segment f, at most the
regulator's q_max either way:

    tau dp_r/dt = P(t) - p_r                     (tau = 0: p_r = P(t))
    q_s = clip(drop_s^-1(p_r - p_f), -q_max, q_max)
          (with the tube's inertance: L_s dq_s/dt = p_r - p_f - drop_s(q_s), held at +-q_max)
    dI/dt = q_s,   dv_i/dt = [i = f] q_s + q_(i-1) - q_i

I is what the regulator has let in since rest; the tip's volume follows from mass, I less the
others' fluid, so the segments hold what the regulator let in to round-off. The segments'
curves, the channels and their laws are the syringe network's (softseq_ros.dynamic.flow,
whose :class:`NetworkFlow` evaluates them here too). The state is stiff where the channels are
short and wide, so it is integrated by scipy's Radau, one integration per leg of the programme
(where the target's slope jumps; a profile's rows within a leg are corners no step passes
over), each segment's passages through
the folds of its curve located by the integrator's events. A segment pushed past the end of its
curve stops the path there with :class:`NetworkDomainError`, as the syringe's network does.
"""

from dataclasses import dataclass, field
import math
from typing import Callable, Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.integrate import Radau, solve_ivp
from scipy.optimize import brentq

from softseq_ros.dynamic.events import EMPTYING, FILLING, FoldCrossing, segment_folds
from softseq_ros.dynamic.flow import ATOL_SHARE, END_SLACK, NetworkDomainError, NetworkFlow
from softseq_ros.dynamic.path import DynamicPath
from softseq_ros.scene.network import NO_REGULATOR_TUBE, NetworkSettings
from softseq_ros.scene.regulator import Regulator
from softseq_ros.segments.models import Segment, piece_holding, rising_pieces

FloatArray = NDArray[np.float64]
Event = Callable[[float, FloatArray], float]
# The programme's target gauge pressure [Pa] at a time [s].
Target = Callable[[float], float]


class RegulatedNetwork:
    """The segments and channels of a network, fed through its supply tube by a regulator."""

    def __init__(self, segments: Sequence[Segment], network: NetworkSettings,
                 regulator: Regulator, rtol: float | None = None) -> None:
        """At rest at time 0, the outlet at 0 Pa gauge; ``rtol`` overrides the network's."""
        if network.supply is None:
            raise ValueError(NO_REGULATOR_TUBE)
        self.members = NetworkFlow(segments, network, rtol)
        self.segments = list(segments)
        self.regulator = regulator
        members = self.members
        self.n = members.n
        self.tube = members.supply
        self.feed = members.feed
        self.lagged = regulator.time_constant_s > 0.0
        self.tube_inertial = self.tube.inertance > 0.0
        # The state: the volumes but the tip's, the inertial channels' flows (as the syringe's
        # network has them), then what the regulator let in, its outlet pressure when it lags
        # and the supply tube's flow when its inertia counts.
        self.at_injected = self.n - 1 + len(members.inertial)
        self.at_outlet = self.at_injected + 1
        self.at_tube = self.at_outlet + int(self.lagged)
        size = self.at_tube + int(self.tube_inertial)
        volume_atol = members.rtol * ATOL_SHARE * members.v_scale
        pressure_scale = max(abs(regulator.programme.highest()), 1.0)
        self.atol = np.full(size, volume_atol)
        if self.lagged:
            self.atol[self.at_outlet] = members.rtol * ATOL_SHARE * pressure_scale
        self.rtol = members.rtol
        self.rest_total = members.rest_total
        self.upper = [s.max_volume + END_SLACK * members.v_scale for s in self.segments]

    # ------------------------------------------------------------------ the equations

    def _outlet(self, t: float, state: Sequence[float], target: Target) -> float:
        return state[self.at_outlet] if self.lagged else target(t)

    def _tube_flow(self, state: Sequence[float], drop: float) -> float:
        limit = self.regulator.max_flow_m3_per_s
        flow = state[self.at_tube] if self.tube_inertial else self.tube.flow(drop)
        return min(max(flow, -limit), limit)

    def balance(self, t: float, y: FloatArray, target: Target) -> tuple[
            FloatArray, FloatArray, FloatArray, float, float, FloatArray]:
        """
        Volumes, pressures, channel flows, outlet pressure, tube flow and rates at time ``t``.

        ``target``: the programme's target [Pa] at a time [s] of the leg the time lies in.
        """
        members = self.members
        state = y.tolist()
        volumes = members.volumes_of(y[:self.at_injected], state[self.at_injected])
        pressures = members.pressures(volumes)
        flows = members.channel_flows(y[:self.at_injected], pressures)
        outlet = self._outlet(t, state, target)
        drop = outlet - float(pressures[self.feed])
        supply = self._tube_flow(state, drop)
        rates = members.segment_rates(flows.tolist(), pressures.tolist(), supply)
        rates.append(supply)
        if self.lagged:
            rates.append((target(t) - outlet) / self.regulator.time_constant_s)
        if self.tube_inertial:
            push = (drop - self.tube.drop(supply)) / self.tube.inertance
            limit = self.regulator.max_flow_m3_per_s
            held = (supply >= limit and push > 0.0) or (supply <= -limit and push < 0.0)
            rates.append(0.0 if held else push)
        return volumes, pressures, flows, outlet, supply, np.array(rates)

    def rest_state(self) -> FloatArray:
        """The state at rest with nothing let in, the outlet at 0 Pa gauge."""
        y = np.zeros(self.at_tube + int(self.tube_inertial))
        y[:self.n - 1] = [s.rest_volume for s in self.segments[:-1]]
        return y

    def _volume_of(self, i: int) -> Callable[[FloatArray], float]:
        if i < self.n - 1:
            return lambda y: float(y[i])
        last = self.n - 1
        return lambda y: float(self.rest_total + y[self.at_injected] - np.sum(y[:last]))

    def _events(self) -> tuple[list[Event], list[tuple[int, object]], list[Event]]:
        """The folds' events (each with its segment and fold) and the curves' ends' events."""
        folds: list[Event] = []
        which: list[tuple[int, object]] = []
        ends: list[Event] = []
        for i, segment in enumerate(self.segments):
            volume = self._volume_of(i)
            for fold in segment_folds(segment):
                folds.append(lambda t, y, volume=volume, level=fold.volume: volume(y) - level)
                which.append((i, fold))

            def end(t: float, y: FloatArray, volume: Callable[[FloatArray], float] = volume,
                    level: float = self.upper[i]) -> float:
                return volume(y) - level
            end.terminal, end.direction = True, 1.0
            ends.append(end)
        return folds, which, ends

    # ------------------------------------------------------------------ the path

    def path(self, times: Sequence[float] | FloatArray | None = None) -> DynamicPath:
        """
        The network's state at ``times`` [s], in order, from rest at time 0.

        By default the programme sampled at the regulator's rate. A segment pushed past the
        end of its curve raises :class:`NetworkDomainError` at the located instant, the rows
        before it in ``error.rows``.
        """
        programme = self.regulator.programme
        if times is None:
            times = programme.sample_times(self.regulator.rate_hz)
        times = np.asarray(times, dtype=float).reshape(-1)
        if times.size and (times[0] < 0.0 or np.any(np.diff(times) < 0.0)):
            raise ValueError('times must be in order, from 0 s on')
        corners = np.asarray(programme.corners or programme.times)
        end = float(times[-1]) if times.size else 0.0
        # The legs up to the last time (held beyond the programme's end).
        starts = corners[corners < end].tolist() or [0.0]
        stops = starts[1:] + [end]
        folds, which, ends = self._events()
        y = self.rest_state()
        rows = np.empty((times.size, y.size))
        crossings: list[FoldCrossing] = []
        steps = 0
        k = int(np.searchsorted(times, 0.0, side='right'))
        rows[:k] = y
        for start, stop in zip(starts, stops):
            if stop <= start:
                continue
            target, max_step = self._leg_target(start, stop)
            solved = solve_ivp(lambda t, state, target=target: self.balance(t, state, target)[5],
                               (start, stop), y, method='Radau', rtol=self.rtol,
                               atol=self.atol, dense_output=True, events=folds + ends,
                               max_step=max_step)
            if solved.status < 0:
                raise NetworkDomainError(f'the regulated network integration failed at '
                                         f'{solved.t[-1]:.6g} s: {solved.message}')
            steps += len(solved.t) - 1
            for index, (event_times, event_states) in enumerate(zip(solved.t_events[:len(folds)],
                                                                    solved.y_events)):
                i, fold = which[index]
                for t_event, state in zip(event_times, event_states):
                    rates = self.balance(t_event, state, target)[5]
                    direction = self._volume_rate(i, rates)
                    crossings.append(FoldCrossing(
                        self.segments[i].name, fold.volume, fold.pressure, fold.kind,
                        FILLING if direction > 0.0 else EMPTYING, float(t_event),
                        float(state[self.at_injected])))
            reached = float(solved.t[-1])
            inside = int(np.searchsorted(times, reached, side='right'))
            if inside > k:
                rows[k:inside] = solved.sol(times[k:inside]).T
                k = inside
            y = solved.y[:, -1]
            if solved.status == 1:
                ended = next(i for i, hits in enumerate(solved.t_events[len(folds):]) if hits.size)
                error = NetworkDomainError(
                    f'segment {self.segments[ended].name} passes the end of its curve at '
                    f'{reached:.6g} s ({self._volume_of(ended)(y):.6g} m^3, let in '
                    f'{y[self.at_injected]:.6g} m^3)', located=True)
                error.rows = rows[:k]
                raise error
        rows[k:] = y
        crossings.sort(key=lambda c: c.time_s)
        return self._read(times, rows, crossings, steps)

    def _leg_target(self, start: float, stop: float) -> tuple[Target, float]:
        """
        The target within a leg from ``start`` to ``stop`` [s], and the longest step in it.

        A straight leg (a ramp, a hold) has its line; a profile its rows, followed linearly,
        and no step longer than its shortest row, so that no step passes over a row's corner.
        """
        programme = self.regulator.programme
        times = np.asarray(programme.times)
        inside = (times > start) & (times < stop)
        start_p = float(programme.target_at(start))
        if not np.any(inside):
            slope = (float(programme.target_at(stop)) - start_p) / (stop - start)
            return (lambda t: start_p + slope * (t - start)), math.inf
        knots = np.concatenate([[start], times[inside], [stop]])
        values = programme.target_at(knots)
        return ((lambda t: float(np.interp(t, knots, values))), float(np.min(np.diff(knots))))

    def _volume_rate(self, i: int, rates: FloatArray) -> float:
        if i < self.n - 1:
            return float(rates[i])
        return float(rates[self.at_injected] - np.sum(rates[:self.n - 1]))

    def _read(self, times: FloatArray, rows: FloatArray, crossings: list[FoldCrossing],
              steps: int) -> DynamicPath:
        """The path's arrays from the states at ``times``, as :meth:`balance` reads one."""
        members = self.members
        injected = rows[:, self.at_injected].copy()
        volumes = members.states_volumes(rows[:, :self.at_injected], injected)
        pressures = members.row_pressures(volumes)
        flows = members.channel_flow_rows(rows[:, :self.at_injected], pressures)
        target = self.regulator.programme.target_at(times)
        outlets = rows[:, self.at_outlet].copy() if self.lagged else target
        if self.tube_inertial:
            supply = rows[:, self.at_tube].copy()
        else:
            supply = self.tube.flow_rows(outlets - pressures[:, self.feed])
        limit = self.regulator.max_flow_m3_per_s
        supply = np.clip(supply, -limit, limit)
        curvatures = np.column_stack([np.asarray(s.curvature(volumes[:, i]), dtype=float)
                                      for i, s in enumerate(self.segments)])
        peak_reynolds = [max((law.reynolds(q) for q in (float(np.max(flows[:, j], initial=0.0)),
                                                         float(np.min(flows[:, j], initial=0.0)))),
                             default=0.0) for j, law in enumerate(members.laws)]
        return DynamicPath(
            time_s=times, injected=injected, pressure=outlets, volumes=volumes,
            curvatures=curvatures, channel_flows=flows, snap=np.zeros(times.size, dtype=bool),
            snaps=[], peak_reynolds=peak_reynolds, steps=steps, folds=crossings,
            segment_pressure=pressures, supply_flow=supply, target_pressure=target)


@dataclass
class RegulatedFlip:
    """
    A segment's flip in time behind the regulator: from a fold of its curve to where it ends.

    It starts where the segment passes a peak filling (or a valley emptying) and ends where
    its volume reaches the next rising piece of its curve at that fold's pressure, as the
    hysteron's jump does (softseq_ros.quasistatic.regulator), or turns back before (the
    target fell before the tube let enough water through), whichever comes first.
    ``duration_s`` is from 10 % to 90 % of its volume's change, ``peak_rate_m3_per_s`` its
    fastest change (sampled along each step), at ``peak_s``. ``from_volumes``/``to_volumes``
    are every segment's, ``from_pressure``/``to_pressure`` the regulator's outlet's (gauge),
    ``injected`` what it had let in at the start. ``cut_short``: the run ended before it
    did (its numbers up to there).
    """

    segment: int
    filling: bool
    start_s: float
    injected: float
    from_volumes: list[float]
    from_pressure: float
    fold_volume: float
    landing_volume: float
    end_s: float = math.nan
    to_volumes: list[float] = field(default_factory=list)
    to_pressure: float = math.nan
    duration_s: float = math.nan
    peak_rate_m3_per_s: float = 0.0
    peak_s: float = math.nan
    cut_short: bool = False
    # The stretches it ran over: (from, to, the step's polynomial).
    stretches: list = field(default_factory=list, repr=False)

    @property
    def moved_m3(self) -> float:
        """What the segment took (filling) or gave (emptying) [m^3]."""
        return abs(self.to_volumes[self.segment] - self.from_volumes[self.segment])


def landing_volume(segment: Segment, fold: object, filling: bool) -> float | None:
    """
    Where a segment passing ``fold`` lands: its next rising piece at the fold's pressure.

    Above for a peak passed filling, below for a valley passed emptying; None when no rising
    piece there reaches the pressure (the curve ends).
    """
    rising = rising_pieces(segment)
    order = range(len(rising)) if filling else range(len(rising) - 1, -1, -1)
    beyond = [k for k in order if (rising[k].v_lo >= fold.volume if filling
                                   else rising[k].v_hi <= fold.volume)]
    k = piece_holding(rising, fold.pressure, beyond)
    return None if k is None else float(segment.invert(rising[k], np.array([fold.pressure]))[0])


class RegulatedRun:
    """
    The network behind the regulator driven one target at a time, as the rig drives it.

    The target follows a line (its value at a time, its slope) up to where the line ends,
    then holds; :meth:`follow` sets the next line, :meth:`advance` integrates to a time. The
    integrator (scipy's Radau, on :meth:`RegulatedNetwork.balance`) steps on the line as if
    it went on, and goes on across a new line that continues it (a ramp commanded tick by
    tick); where the target's slope changes (a new slope, or the line's end) it starts afresh
    from the state there, so no step's polynomial is used across a corner. Everything a step
    says (folds passed, a segment off its curve, peak flows) is read on its polynomial up to
    where the line holds so far only. A segment pushed past the end of its curve raises
    NetworkDomainError; the state stays where the last advance left it.
    """

    def __init__(self, network: RegulatedNetwork) -> None:
        """At rest at time 0, the target at 0 Pa and held."""
        self.network = network
        self.t = 0.0
        self.y = network.rest_state()
        self._line = (0.0, 0.0, 0.0, math.inf)   # (time, value there, slope, end) of the target
        self._solver: Radau | None = None
        # The last step's polynomial, and up to where what it says has been read.
        self._dense: Callable[[float], FloatArray] | None = None
        self._step_from = 0.0
        self._read_to = 0.0
        self._folds, self._which, self._ends = network._events()
        self._fold_crossings: list[FoldCrossing] = []
        self.peak_flows = [0.0] * len(network.members.laws)
        # Per fold event: where a segment passing it fills or empties to (None: nowhere).
        self._landings = [(landing_volume(network.segments[i], fold, True),
                           landing_volume(network.segments[i], fold, False))
                          for i, fold in self._which]
        self._open: dict[int, RegulatedFlip] = {}      # per segment, a flip under way
        self._flips: list[RegulatedFlip] = []

    def take_flips(self) -> list[RegulatedFlip]:
        """The flips that landed since the last call."""
        found, self._flips = self._flips, []
        return found

    def finish(self) -> list[RegulatedFlip]:
        """The run ends now: the flips landed, and those still under way cut short here."""
        for i, flip in list(self._open.items()):
            flip.cut_short = True
            self._end_flip(i, self.t)
        return self.take_flips()

    def target(self, t: float) -> float:
        """The target gauge pressure [Pa] at ``t`` [s] on the present line (held at its end)."""
        t0, value, slope, end = self._line
        return value + slope * (min(t, end) - t0) if slope else value

    def _line_target(self, t: float) -> float:
        """The present line as if it went on: what the integrator steps on."""
        t0, value, slope, _ = self._line
        return value + slope * (t - t0)

    def follow(self, value: float, slope: float, until: float) -> None:
        """From now the target is ``value`` [Pa] rising at ``slope`` [Pa/s] until ``until`` [s]."""
        if not slope or until <= self.t:
            slope, until = 0.0, math.inf
        # A ramp commanded tick by tick gives slopes equal but for the last bits of its rows.
        continues = (math.isclose(slope, self._line[2], rel_tol=1e-9, abs_tol=1e-12)
                     and math.isclose(value, self.target(self.t), rel_tol=1e-9, abs_tol=1e-9))
        if continues:
            # The same line: its time and value stay, so the integrator's steps hold.
            self._line = self._line[:3] + (until,)
            return
        self._line = (self.t, value, slope, until)
        self._restart()

    def _restart(self) -> None:
        self._solver = self._dense = None
        self._read_to = self._step_from = self.t

    def set_rest(self, volumes: Sequence[float], injected: float) -> None:
        """At rest at these volumes [m^3] with ``injected`` let in; the target at the fed one's."""
        network = self.network
        y = np.zeros_like(self.y)
        y[:network.n - 1] = list(volumes)[:network.n - 1]
        y[network.at_injected] = injected
        fed = float(network.members.pressures(np.asarray(volumes, dtype=float))[network.feed])
        if network.lagged:
            y[network.at_outlet] = fed
        self.y = y
        self._line = (self.t, fed, 0.0, math.inf)
        self._restart()

    def state(self) -> tuple[FloatArray, FloatArray, FloatArray, float, float]:
        """Volumes, gauge pressures, channel flows, outlet pressure and tube flow now."""
        volumes, pressures, flows, outlet, supply, _ = self.network.balance(
            self.t, self.y, self.target)
        return volumes, pressures, flows, outlet, supply

    def take_fold_crossings(self) -> list[FoldCrossing]:
        """The segments' passages through folds of their curves since the last call."""
        found, self._fold_crossings = self._fold_crossings, []
        return found

    def advance(self, t: float) -> None:
        """Integrate to ``t`` [s], the target on its line (held where the line ends)."""
        while self.t < t:
            t0, value, slope, end = self._line
            if slope and end <= self.t:
                # The line ran out: the target holds from here, a corner.
                self._line = (self.t, self.target(self.t), 0.0, math.inf)
                self._restart()
                continue
            self._integrate_to(min(t, end))

    def _integrate_to(self, stop: float) -> None:
        network = self.network
        if self._solver is None:
            def rates(t: float, y: FloatArray) -> FloatArray:
                return network.balance(t, y, self._line_target)[5]

            self._solver = Radau(rates, self.t, self.y, self.t + 1.0e12, rtol=network.rtol,
                                 atol=network.atol)
        solver = self._solver
        # What the last step says beyond where it was read, up to here.
        if self._dense is not None and self._read_to < min(solver.t, stop):
            self._read(min(solver.t, stop))
        while solver.t < stop:
            self._step_from = solver.t
            message = solver.step()
            if solver.status == 'failed':
                self._restart()
                raise NetworkDomainError(f'the regulated network integration failed at '
                                         f'{solver.t:.6g} s: {message}')
            self._dense = solver.dense_output()
            self._read(min(solver.t, stop))
        self.y = np.asarray(self._dense(stop), dtype=float) if solver.t > stop \
            else solver.y.copy()
        self.t = stop

    def _read(self, upto: float) -> None:
        """What the last step says from where it was read to ``upto``: folds, ends, flows."""
        network, dense = self.network, self._dense
        lo = max(self._read_to, self._step_from)
        y_lo, y_hi = dense(lo), dense(upto)
        for index, end in enumerate(self._ends):
            if end(upto, y_hi) > 0.0:
                at = brentq(lambda s, end=end: end(s, dense(s)), lo, upto,
                            xtol=1e-12 * max(1.0, upto))
                self._restart()
                raise NetworkDomainError(
                    f'segment {network.segments[index].name} passes the end of its curve at '
                    f'{at:.6g} s (let in {float(dense(at)[network.at_injected]):.6g} m^3)',
                    located=True)
        self._read_flips(lo, upto, dense)
        found = []
        for index, (event, (i, fold)) in enumerate(zip(self._folds, self._which)):
            before, after = event(lo, y_lo), event(upto, y_hi)
            if (before < 0.0) == (after < 0.0):
                continue
            at = brentq(lambda s, event=event: event(s, dense(s)), lo, upto,
                        xtol=1e-12 * max(1.0, upto))
            filling = after > before
            crossing = FoldCrossing(
                network.segments[i].name, fold.volume, fold.pressure, fold.kind,
                FILLING if filling else EMPTYING, float(at),
                float(dense(at)[network.at_injected]))
            found.append(crossing)
            landing = self._landings[index][0 if filling else 1]
            starts = (fold.kind == 'peak') == filling
            if starts and landing is not None and i not in self._open:
                self._begin_flip(i, filling, float(at), fold.volume, landing, dense)
                self._read_flips(float(at), upto, dense)
        self._fold_crossings.extend(sorted(found, key=lambda c: c.time_s))
        balance = network.balance(upto, y_hi, self._line_target)
        for j, flow in enumerate(balance[2].tolist()):
            self.peak_flows[j] = max(self.peak_flows[j], abs(flow))
        self._read_to = upto

    def _begin_flip(self, i: int, filling: bool, at: float, fold_volume: float,
                    landing: float, dense: Callable[[float], FloatArray]) -> None:
        volumes, _, _, outlet, _, _ = self.network.balance(at, dense(at), self._line_target)
        self._open[i] = RegulatedFlip(
            i, filling, at, float(dense(at)[self.network.at_injected]), volumes.tolist(),
            float(outlet), fold_volume, landing)

    def _rate_of(self, i: int, t: float, dense: Callable[[float], FloatArray]) -> float:
        """Segment ``i``'s volume rate [m^3/s] at ``t`` on a step's polynomial."""
        rates = self.network.balance(t, dense(t), self._line_target)[5]
        return self.network._volume_rate(i, rates)

    def _read_flips(self, lo: float, upto: float, dense: Callable[[float], FloatArray]) -> None:
        """The flips under way on [lo, upto]: where each lands or turns back."""
        network = self.network
        for i, flip in list(self._open.items()):
            lo_i = max(lo, flip.start_s)
            if upto <= lo_i:
                continue
            flip.stretches.append((lo_i, upto, dense))
            volume = network._volume_of(i)
            sign = 1.0 if flip.filling else -1.0
            ends = []

            def short(s: float, volume: Callable = volume, sign: float = sign,
                      level: float = flip.landing_volume) -> float:
                return (volume(dense(s)) - level) * sign

            if short(upto) >= 0.0:
                ends.append(brentq(short, lo_i, upto, xtol=1e-12 * max(1.0, upto))
                            if short(lo_i) < 0.0 else lo_i)

            def onward(s: float, i: int = i, sign: float = sign) -> float:
                return self._rate_of(i, s, dense) * sign

            if onward(upto) <= 0.0 < onward(lo_i):
                ends.append(brentq(onward, lo_i, upto, xtol=1e-12 * max(1.0, upto)))
            if ends:
                self._end_flip(i, min(ends))

    def _end_flip(self, i: int, at: float) -> None:
        """Flip ``i`` ends at ``at``: its end state, 10 % to 90 % and peak rate, from its steps."""
        network = self.network
        flip = self._open.pop(i)
        stretches = [(lo, min(hi, at), dense) for lo, hi, dense in flip.stretches if lo < at]
        if stretches:
            dense = stretches[-1][2]
            state = dense(at)
        else:
            state = self.y
        volumes, _, _, outlet, _, _ = network.balance(at, state, self._line_target)
        flip.end_s, flip.to_volumes, flip.to_pressure = at, volumes.tolist(), float(outlet)
        volume = network._volume_of(i)
        change = flip.to_volumes[i] - flip.from_volumes[i]
        times = []
        for share in (0.1, 0.9):
            level = flip.from_volumes[i] + share * change
            found = at
            for lo, hi, dense in stretches:
                def beyond(s: float, dense: Callable = dense, level: float = level) -> float:
                    return (volume(dense(s)) - level) * (1.0 if change >= 0.0 else -1.0)
                if hi > lo and beyond(hi) >= 0.0:
                    found = brentq(beyond, lo, hi, xtol=1e-12 * max(1.0, hi)) \
                        if beyond(lo) < 0.0 else lo
                    break
            times.append(found)
        flip.duration_s = times[1] - times[0]
        for lo, hi, dense in stretches:
            for s in np.linspace(lo, hi, 9).tolist():
                rate = abs(self._rate_of(i, s, dense))
                if rate > flip.peak_rate_m3_per_s:
                    flip.peak_rate_m3_per_s, flip.peak_s = rate, s
        flip.stretches = []
        self._flips.append(flip)

def regulated_network_path(segments: Sequence[Segment], network: NetworkSettings,
                           regulator: Regulator,
                   times: Sequence[float] | FloatArray | None = None,
                   rtol: float | None = None) -> DynamicPath:
    """The network behind ``regulator`` at ``times`` (default: its programme at its rate)."""
    return RegulatedNetwork(segments, network, regulator, rtol).path(times)

