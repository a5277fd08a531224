"""
Events on the network's continuous solution, located in time within the integrator's steps.

Radau IIA is a collocation method: within a step from t_old to t_old + h the state follows a
cubic in x = (t - t_old) / h, the collocation polynomial (the solver's dense output), whose
slope is the right-hand side at the three collocation nodes and whose increment over the step
is the step's own. Every segment's volume is a cubic there too (the tip's from mass), its rate
dv_i/dt a quadratic, and each channel's flow, by mass, a sum of them. So what this module finds
is found on those polynomials, not on the step points, and converges with the solution as the
tolerance tightens instead of depending on where the steps fall:

- a segment's volume crossing a level (the end of its curve, the volume where its collapse
  reaches vacuum, a fold of its curve): the root of a cubic (:func:`first_beyond`,
  :func:`crossings`);
- the exchange between the segments, half of sum_i |dv_i/dt| less the pump's |Q| (behind a
  compliant supply line the line is one more member, its ds/dt in the sum, as it is in the
  quasi-static equilibrium): a piecewise quadratic (the pieces end where a rate changes
  sign); a snap-through is an episode where it exceeds SNAP_EXCHANGE_PER_FLOW |Q|
  (:class:`SnapWatcher`), whose start and end are roots, whose fluid moved is the exchange's
  integral (piecewise cubic), whose 10 % and 90 % times invert that integral, and whose peak
  is found where the quadratic peaks (its value there from the equations themselves, at the
  state the step's cubic gives);
- each channel's peak flow (for its Reynolds number): a quadratic's largest magnitude.

Unlike event location that tests a function's sign at the step points (scipy's solve_ivp
events), the polynomials are solved, not sampled: a level the state crosses and crosses back
within one step is found. What a step's polynomial does not show (a wiggle narrower than the
step that the error control let through) no output of the integrator shows either.

Pure floats: a network has a handful of segments, and this runs once per step.
"""

from dataclasses import dataclass, field
import math
from typing import Callable, Sequence

from scipy.optimize import brentq

from softseq_ros.segments.models import Segment

# A snap-through, as the network lives it: fluid exchanged between the segments faster than
# this many times the pump's flow, and more of it than this share of the volume scale.
SNAP_EXCHANGE_PER_FLOW = 5.0
SNAP_SHARE_OF_SCALE = 1e-3
# An episode that begins with a change of the pump's flow is a snap-through only if its
# exchange then rises to more than this many times where it began (an instability gathers
# speed; fluid evening out after the change does not).
SNAP_ACCELERATION = 2.0
# A segment gives (takes) fluid in a snap-through when it loses (gains), beyond the pump's
# own push, more than this share of the fluid moved: a segment the fluid only passes
# through is neither.
SNAP_PARTY_SHARE = 0.01
PEAK, VALLEY = 'peak', 'valley'
FILLING, EMPTYING = 'filling', 'emptying'
_ROOT_XTOL = 4.0 * 2.0 ** -52


# ---------------------------------------------------------------------- polynomials in x

def quadratic_roots(a: float, b: float, c: float, lo: float, hi: float) -> list[float]:
    """The roots of a + b x + c x^2 strictly inside (lo, hi), in order."""
    if c == 0.0:
        if b == 0.0:
            return []
        roots = [-a / b]
    else:
        disc = b * b - 4.0 * a * c
        if disc < 0.0:
            return []
        # The stable pair: no cancellation between -b and the root of the discriminant.
        q = -0.5 * (b + math.copysign(math.sqrt(disc), b))
        roots = [q / c] if q == 0.0 else [q / c, a / q]
    return sorted(x for x in roots if lo < x < hi)


def quadratic_extreme(a: float, b: float, c: float, lo: float,
                      hi: float) -> tuple[float, float]:
    """The largest value of a + b x + c x^2 on [lo, hi] and where it is."""
    best = max(((a + b * x + c * x * x), x) for x in (lo, hi))
    if c < 0.0:
        vertex = -b / (2.0 * c)
        if lo < vertex < hi:
            best = max(best, (a + b * vertex + c * vertex * vertex, vertex))
    return best


def _largest_magnitude(a: float, b: float, c: float, lo: float, hi: float) -> float:
    """The largest |a + b x + c x^2| on [lo, hi]: at an end or at the vertex."""
    largest = max(abs(a + lo * (b + lo * c)), abs(a + hi * (b + hi * c)))
    if c != 0.0:
        vertex = -b / (2.0 * c)
        if lo < vertex < hi:
            largest = max(largest, abs(a + vertex * (b + vertex * c)))
    return largest


def _cubic(start: float, q: Sequence[float], x: float) -> float:
    return start + x * (q[0] + x * (q[1] + x * q[2]))


def _monotone_breaks(q: Sequence[float], lo: float, hi: float) -> list[float]:
    """[lo, the cubic's turning points inside, hi]: the cubic is monotone between them."""
    return [lo, *quadratic_roots(q[0], 2.0 * q[1], 3.0 * q[2], lo, hi), hi]


def _may_reach(start: float, q: Sequence[float], level: float) -> bool:
    """False when the cubic cannot reach ``level`` anywhere on [0, 1] (a cheap bound)."""
    return abs(level - start) <= abs(q[0]) + abs(q[1]) + abs(q[2])


def first_beyond(start: float, q: Sequence[float], lo: float, hi: float, level: float,
                 sign: float) -> float | None:
    """
    The first x in [lo, hi] from which sign * (cubic(x) - level) > 0; None if none.

    The cubic is start + q0 x + q1 x^2 + q2 x^3; ``sign`` +1 looks above ``level``, -1 below.
    """
    if not _may_reach(start, q, level) and sign * (start - level) <= 0.0:
        return None
    breaks = _monotone_breaks(q, lo, hi)
    values = [sign * (_cubic(start, q, x) - level) for x in breaks]
    for (a, b), (ga, gb) in zip(zip(breaks, breaks[1:]), zip(values, values[1:])):
        if ga > 0.0:
            return a
        if gb > 0.0:
            if ga == 0.0:
                return a
            return brentq(lambda x: sign * (_cubic(start, q, x) - level), a, b,
                          xtol=_ROOT_XTOL * max(1.0, abs(b)), rtol=_ROOT_XTOL)
    return None


def crossings(start: float, q: Sequence[float], lo: float, hi: float,
              level: float) -> list[tuple[float, int]]:
    """
    Where the cubic passes ``level`` in (lo, hi]: (x, +1 rising through it or -1 falling).

    Half-open, so that a crossing at a step's end is counted once, in that step.
    """
    if not _may_reach(start, q, level):
        return []
    breaks = _monotone_breaks(q, lo, hi)
    above = [_cubic(start, q, x) >= level for x in breaks]
    found = []
    for (a, b), (ua, ub) in zip(zip(breaks, breaks[1:]), zip(above, above[1:])):
        if ua == ub:
            continue
        x = brentq(lambda x: _cubic(start, q, x) - level, a, b,
                   xtol=_ROOT_XTOL * max(1.0, abs(b)), rtol=_ROOT_XTOL)
        found.append((x, 1 if ub else -1))
    return found


@dataclass(slots=True)
class StepCurve:
    """
    One integrator step's continuous solution, as the segments' volumes.

    Segment i holds ``starts[i] + q0 x + q1 x^2 + q2 x^3`` ([m^3]) at t = t_old + h x, x in
    [0, 1], with ``cubics[i] = (q0, q1, q2)``; ``flow`` is the pump's flow in the step,
    ``feed`` the segment the syringe feeds and ``injected`` the injected volume at the step's
    start. Behind a compliant supply line the pump pushes into the line, which holds
    ``line_start`` plus ``line_cubic`` in x, and the supply tube passes the rest on to the fed
    segment (None: no line, the pump's flow enters the fed segment).
    """

    t_old: float
    h: float
    starts: tuple[float, ...]
    cubics: tuple[tuple[float, float, float], ...]
    flow: float
    feed: int
    injected: float
    line_start: float | None = None
    line_cubic: tuple[float, float, float] | None = None

    def injected_at(self, x: float) -> float:
        """The injected volume [m^3] at ``x``."""
        return self.injected + self.flow * self.h * x

    def x_of(self, t: float) -> float:
        """Where ``t`` [s] lies in the step (0 at its start, 1 at its end)."""
        return (t - self.t_old) / self.h

    def time(self, x: float) -> float:
        """The time [s] at ``x``."""
        return self.t_old + self.h * x

    def volumes(self, x: float) -> list[float]:
        """The segments' volumes [m^3] at ``x``."""
        return [_cubic(s, q, x) for s, q in zip(self.starts, self.cubics)]

    def line_held(self, x: float) -> float:
        """The fluid [m^3] the supply line holds at ``x`` (a step behind a compliant line)."""
        return _cubic(self.line_start, self.line_cubic, x)

    def rates(self) -> list[tuple[float, float, float]]:
        """Each segment's dv_i/dt [m^3/s] as (a, b, c): a + b x + c x^2."""
        h = self.h
        return [(q0 / h, 2.0 * q1 / h, 3.0 * q2 / h) for q0, q1, q2 in self.cubics]

    def member_rates(self) -> list[tuple[float, float, float]]:
        """The segments' rates and, behind a compliant line, the line's ds/dt last."""
        rates = self.rates()
        if self.line_cubic is not None:
            q0, q1, q2 = self.line_cubic
            h = self.h
            rates.append((q0 / h, 2.0 * q1 / h, 3.0 * q2 / h))
        return rates

    def channel_flows(self) -> list[tuple[float, float, float]]:
        """Each channel's flow [m^3/s] towards the tip as a quadratic, by mass."""
        flows, carried = [], (0.0, 0.0, 0.0)
        if self.line_cubic is not None:
            # What enters the fed segment is the supply tube's flow, the pump's less what the
            # line takes up: Q - ds/dt.
            line = self.member_rates()[-1]
            fed = (self.flow - line[0], -line[1], -line[2])
            for i, (a, b, c) in enumerate(self.rates()[:-1]):
                entering = fed if i == self.feed else (0.0, 0.0, 0.0)
                carried = (carried[0] + entering[0] - a, carried[1] + entering[1] - b,
                           carried[2] + entering[2] - c)
                flows.append(carried)
            return flows
        for i, (a, b, c) in enumerate(self.rates()[:-1]):
            pumped = self.flow if i == self.feed else 0.0
            carried = (carried[0] + pumped - a, carried[1] - b, carried[2] - c)
            flows.append(carried)
        return flows

    def peak_flows(self, lo: float, hi: float) -> list[float]:
        """Each channel's largest flow magnitude [m^3/s] on [lo, hi]."""
        return [_largest_magnitude(a, b, c, lo, hi) for a, b, c in self.channel_flows()]


# ---------------------------------------------------------------------- folds

@dataclass(frozen=True)
class Fold:
    """A turning point of a segment's curve: its volume [m^3], pressure [Pa], peak or valley."""

    volume: float
    pressure: float
    kind: str


def segment_folds(segment: Segment) -> tuple[Fold, ...]:
    """The folds of a segment's pressure-volume curve, base to top (its monotone pieces' joins)."""
    pieces = segment.monotone_pieces()
    folds = []
    for before, after in zip(pieces, pieces[1:]):
        kind = PEAK if before.direction > after.direction else VALLEY
        folds.append(Fold(after.v_lo, after.p_at_lo, kind))
    return tuple(folds)


@dataclass(frozen=True)
class FoldCrossing:
    """
    A segment passing a fold of its own curve, located in time.

    ``direction``: FILLING (its volume rising through the fold) or EMPTYING; ``injected``:
    the injected volume then [m^3]; ``time_s`` on the network's clock.
    """

    segment: str
    fold_volume_m3: float
    fold_pressure_pa: float
    kind: str
    direction: str
    time_s: float
    injected: float


def fold_crossing_line(crossing: FoldCrossing, clock_s: float = 0.0) -> str:
    """One line saying a fold crossing; ``clock_s`` is added to its time (a driver's clock)."""
    return (f'segment {crossing.segment} passes the {crossing.kind} of its curve '
            f'({crossing.fold_pressure_pa * 1e-3:.4g} kPa gauge at '
            f'{crossing.fold_volume_m3 * 1e6:.4g} mL), {crossing.direction}, at '
            f'{crossing.time_s + clock_s:.6g} s, {crossing.injected * 1e6:.4f} mL injected')


# ---------------------------------------------------------------------- snap-throughs

@dataclass
class DynamicSnap:
    """
    A snap-through in time: where it started and ended, the fluid it moved, how fast, how long.

    ``injected`` [m^3] and ``start_s`` [s]: where the exchange first outran the pump
    SNAP_EXCHANGE_PER_FLOW-fold; ``end_s``: where it stopped doing so; ``duration_s``: from
    10 % to 90 % of the fluid moved; ``peak_exchange_m3_per_s`` and ``peak_s``: the fastest
    exchange and when; ``fluid_moved_m3``: the fluid exchanged between the segments beyond
    what the pump pushed; volumes and pressures (gauge, at the segment the pump feeds) before
    and after; ``exchanged_m3``: per segment, the fluid it gained from the others (negative:
    gave), its volume's change less the pump's push into it.

    Behind a compliant supply line the line is one more member (the pump pushes into it, not
    into the fed segment): ``exchanged_line_m3`` is what the line gained from the segments
    beyond the pump's push (negative: its gas expanded into them), and the fluid moved counts
    its share; None without a line.
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
    exchanged_m3: list[float] = field(default_factory=list)
    peak_s: float = math.nan
    exchanged_line_m3: float | None = None

    def giving(self) -> list[int]:
        """The segments (indices) that gave fluid to the others."""
        return [i for i, d in enumerate(self.exchanged_m3)
                if d < -SNAP_PARTY_SHARE * self.fluid_moved_m3]

    def taking(self) -> list[int]:
        """The segments (indices) that took fluid from the others."""
        return [i for i, d in enumerate(self.exchanged_m3)
                if d > SNAP_PARTY_SHARE * self.fluid_moved_m3]


def exchange_flow(volume_rates: Sequence[float], supply_flow: float) -> float:
    """
    Fluid moving between the members beyond the pump's flow [m^3/s].

    ``volume_rates``: every member's rate, the segments' and, behind a compliant line, the
    line's; ``supply_flow``: the pump's flow into them all.
    """
    return 0.5 * max(sum(abs(r) for r in volume_rates) - abs(supply_flow), 0.0)


@dataclass
class _Episode:
    """An episode of fast exchange under way: its start and the exchange's pieces so far."""

    start_s: float
    injected: float
    volumes: list[float]
    pressure: float
    fresh: bool
    first_exchange: float
    line_held: float | None
    # (t at x = 0, h, lo, hi, (a, b, c) of the exchange in x, integral before lo [m^3])
    pieces: list[tuple[float, float, float, float, tuple[float, float, float], float]] = \
        field(default_factory=list)
    moved: float = 0.0
    polynomial_peak: float = 0.0
    peak: float = 0.0
    peak_s: float = math.nan


def _integral(e: tuple[float, float, float], lo: float, x: float) -> float:
    """The integral over [lo, x] of a + b x + c x^2 (in x)."""
    a, b, c = e
    return a * (x - lo) + 0.5 * b * (x * x - lo * lo) + c * (x ** 3 - lo ** 3) / 3.0


# The state at a point of a step: injected volume [m^3], volumes [m^3], gauge pressure [Pa] at
# the segment the pump feeds.
StateAt = Callable[[StepCurve, float], tuple[float, list[float], float]]
# The exchange [m^3/s] from the equations' rates at the state at a point of the step watched.
ExchangeAt = Callable[[StepCurve, float], float]


class SnapWatcher:
    """Finds snap-throughs on the continuous solution: episodes of fast exchange, timed."""

    def __init__(self, v_scale: float) -> None:
        """Episodes must move more than SNAP_SHARE_OF_SCALE of ``v_scale``."""
        self.v_scale = v_scale
        self.found: list[DynamicSnap] = []
        self._episode: _Episode | None = None

    def watch(self, curve: StepCurve, lo: float, hi: float, fresh: bool,
              state_at: StateAt, exchange_at: ExchangeAt) -> list[DynamicSnap]:
        """
        The stretch [lo, hi] of a step; the snap-throughs that ended in it.

        ``fresh``: the flow or the state changed at once where the stretch starts, so an
        episode that is fast there begins there (and must then gather speed to count).
        """
        if hi <= lo:
            return []
        flow = abs(curve.flow)
        threshold = SNAP_EXCHANGE_PER_FLOW * flow
        rates = curve.member_rates()
        if self._episode is None:
            # Nothing under way and no exchange anywhere near the threshold: the usual step.
            bound = sum(_largest_magnitude(a, b, c, lo, hi) for a, b, c in rates)
            if 0.5 * (bound - flow) <= threshold:
                return []
        breaks = [lo, hi]
        for a, b, c in rates:
            breaks += quadratic_roots(a, b, c, lo, hi)
        breaks.sort()
        ended = []
        for a_x, b_x in zip(breaks, breaks[1:]):
            if b_x <= a_x:
                continue
            middle = 0.5 * (a_x + b_x)
            e = [-0.5 * flow, 0.0, 0.0]
            for a, b, c in rates:
                sign = 0.5 if a + b * middle + c * middle * middle >= 0.0 else -0.5
                e[0] += sign * a
                e[1] += sign * b
                e[2] += sign * c
            exchange = (e[0], e[1], e[2])
            cuts = [a_x, *quadratic_roots(e[0] - threshold, e[1], e[2], a_x, b_x), b_x]
            for u, w in zip(cuts, cuts[1:]):
                if w <= u:
                    continue
                mid = 0.5 * (u + w)
                value = e[0] + e[1] * mid + e[2] * mid * mid
                fast = value > threshold and value > 0.0
                if fast:
                    self._extend(curve, u, w, exchange, fresh and u == lo, state_at,
                                 exchange_at)
                elif self._episode is not None:
                    snap = self._close(curve, u, state_at)
                    if snap is not None:
                        ended.append(snap)
        return ended

    def _extend(self, curve: StepCurve, lo: float, hi: float,
                exchange: tuple[float, float, float], fresh: bool, state_at: StateAt,
                exchange_at: ExchangeAt) -> None:
        episode = self._episode
        if episode is None:
            injected, volumes, pressure = state_at(curve, lo)
            a, b, c = exchange
            line_held = None if curve.line_cubic is None else curve.line_held(lo)
            episode = self._episode = _Episode(curve.time(lo), injected, volumes, pressure,
                                               fresh, a + b * lo + c * lo * lo, line_held)
        episode.pieces.append((curve.t_old, curve.h, lo, hi, exchange, episode.moved))
        episode.moved += curve.h * _integral(exchange, lo, hi)
        peak, where = quadratic_extreme(*exchange, lo, hi)
        if peak > episode.polynomial_peak:
            # Where the polynomial's exchange peaks, the equations' own: the state there is
            # accurate to a higher order than the polynomial's slope, and at a peak an error
            # of its place changes the value to second order only.
            episode.polynomial_peak = peak
            episode.peak, episode.peak_s = exchange_at(curve, where), curve.time(where)

    def _close(self, curve: StepCurve, x: float, state_at: StateAt) -> DynamicSnap | None:
        episode, self._episode = self._episode, None
        total = episode.moved
        if total <= SNAP_SHARE_OF_SCALE * self.v_scale:
            return None
        # An episode that began with a change of the flow (or a jump of the state) is the
        # fluid evening out, fastest where it begins, unless its exchange then gathers speed
        # as an instability's does. One that began while the flow stayed is a snap-through.
        if episode.fresh and episode.peak <= SNAP_ACCELERATION * episode.first_exchange:
            return None
        injected, volumes, pressure = state_at(curve, x)
        pumped = injected - episode.injected
        exchanged = [after - before for after, before in zip(volumes, episode.volumes)]
        line_exchanged = None
        if episode.line_held is None:
            exchanged[curve.feed] -= pumped
        else:
            # The pump pushed into the line: what the line gained beyond that came from the
            # segments (the segments' own changes are all exchange).
            line_exchanged = curve.line_held(x) - episode.line_held - pumped
        t10, t90 = (_time_at_share(episode, share * total) for share in (0.1, 0.9))
        snap = DynamicSnap(episode.injected, episode.start_s, curve.time(x), t90 - t10, total,
                           episode.peak, episode.volumes, volumes, episode.pressure, pressure,
                           exchanged, episode.peak_s, line_exchanged)
        self.found.append(snap)
        return snap


def _time_at_share(episode: _Episode, target: float) -> float:
    """When the episode's integral of the exchange reaches ``target`` [m^3]."""
    for t_old, h, lo, hi, exchange, before in episode.pieces:
        whole = before + h * _integral(exchange, lo, hi)
        if whole < target:
            continue
        if before >= target:
            return t_old + h * lo
        x = brentq(_short_of, lo, hi, args=(exchange, lo, h, target - before),
                   xtol=_ROOT_XTOL * max(1.0, abs(hi)), rtol=_ROOT_XTOL)
        return t_old + h * x
    t_old, h, _, hi, _, _ = episode.pieces[-1]
    return t_old + h * hi


def _short_of(x: float, exchange: tuple[float, float, float], lo: float, h: float,
              target: float) -> float:
    return h * _integral(exchange, lo, x) - target
