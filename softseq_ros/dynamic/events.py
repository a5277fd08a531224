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
  sign), positive exactly where some member moves against the pump. An exchange episode
  (:class:`ExchangeWatcher`) is where it is under way, ringing included; its start and end
  are roots, its fluid moved is the exchange's integral (piecewise cubic), its 10 % and 90 %
  times invert that integral, and its peak is found where the quadratic peaks (its value
  there from the equations themselves, at the state the step's cubic gives);
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

import numpy as np
from scipy.optimize import brentq

from softseq_ros.segments.models import Segment

# An exchange episode must move more than this many times the volume tolerance the integrator
# holds a volume of the volume scale to (its relative tolerance times the volume scale): less
# is within the solution's own error, no exchange the volumes show. The same fluid ends an
# exchange's tail: what is left of it at the pace it falls.
EXCHANGE_TOLERANCES = 10.0
# A segment gives (takes) fluid in an exchange when it loses (gains), beyond the pump's
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


# ---------------------------------------------------------------------- exchanges

@dataclass
class DynamicSnap:
    """
    An exchange of fluid between the segments in time, a snap-through or not.

    Where it started and ended, the fluid it moved, how fast, how long:

    ``injected`` [m^3] and ``start_s`` [s]: where fluid began to move between the segments
    (some member against the pump's direction); ``end_s``: where the exchange, its ringing
    included, stopped; ``duration_s``: from 10 % to 90 % of the fluid moved;
    ``peak_exchange_m3_per_s`` and ``peak_s``: the fastest exchange and when;
    ``fluid_moved_m3``: the fluid exchanged between the segments beyond what the pump pushed;
    volumes and pressures (gauge, at the segment the pump feeds) before and after;
    ``exchanged_m3``: per segment, the fluid it gained from the others (negative: gave), its
    volume's change less the pump's push into it. ``snap_through``: the state passed where
    the segments' equilibrium is unstable (the stored energy's Hessian on the plane of
    constant volume is not positive definite): the exchange an instability drives, not the
    fluid lagging the pump or evening out.

    Behind a compliant supply line the line is one more member (the pump pushes into it, not
    into the fed segment): ``exchanged_line_m3`` is what the line gained from the segments
    beyond the pump's push (negative: its gas expanded into them), and the fluid moved counts
    its share; None without a line.

    ``cut_short``: the run ended while the exchange was still under way; ``end_s`` is then the
    run's end and the fluid moved, the duration and the peak are those up to there.
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
    snap_through: bool = True
    cut_short: bool = False

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
    line's; ``supply_flow``: the pump's flow into them all. Positive exactly when some member
    moves against the pump (any member moves, with the pump stopped).
    """
    return 0.5 * max(sum(abs(r) for r in volume_rates) - abs(supply_flow), 0.0)


def unstable_stiffness(k: Sequence[float]) -> bool:
    """
    True when the members' stiffnesses dp_i/dv_i make their equilibrium unstable.

    The Hessian of the stored energy, diag(k), on sum dv = 0 is positive definite exactly when
    at most one k_i is negative and D = sum_i prod_(j != i) k_j > 0
    (softseq_ros.quasistatic.equilibrium).
    """
    if sum(1 for x in k if x < 0.0) > 1:
        return True
    d = 0.0
    for i in range(len(k)):
        d += math.prod(x for j, x in enumerate(k) if j != i)
    return not d > 0.0


@dataclass
class _Episode:
    """An exchange episode under way or paused: its start, its pieces, its last end."""

    start_s: float
    injected: float
    volumes: list[float]
    pressure: float
    line_held: float | None
    # (t at x = 0, h, lo, hi, (a, b, c) of the exchange in x, integral before lo [m^3])
    pieces: list[tuple[float, float, float, float, tuple[float, float, float], float]] = \
        field(default_factory=list)
    moved: float = 0.0
    polynomial_peak: float = 0.0
    peak: float = 0.0
    peak_s: float = math.nan
    unstable: bool = False
    # Where its last stretch ended: time, injected volume, volumes, pressure, line's fluid.
    end_s: float = math.nan
    end_state: tuple[float, list[float], float, float | None] | None = None
    feed: int = 0
    cut_short: bool = False


def _integral(e: tuple[float, float, float], lo: float, x: float) -> float:
    """The integral over [lo, x] of a + b x + c x^2 (in x)."""
    a, b, c = e
    return a * (x - lo) + 0.5 * b * (x * x - lo * lo) + c * (x ** 3 - lo ** 3) / 3.0


# The state at a point of a step: injected volume [m^3], volumes [m^3], gauge pressure [Pa] at
# the segment the pump feeds.
StateAt = Callable[[StepCurve, float], tuple[float, list[float], float]]
# The exchange [m^3/s] from the equations' rates at the state at a point of the step watched.
ExchangeAt = Callable[[StepCurve, float], float]
# Whether the members' equilibrium is unstable at the state at a point of the step watched.
UnstableAt = Callable[[StepCurve, float], bool]
# Whether the network rings at a point of the step watched: some channel's inertia, not the
# pressures, sets how its flow changes (its inertial drop outweighs its steady one).
RingingAt = Callable[[StepCurve, float], bool]


def _real_roots(descending: Sequence[float], lo: float, hi: float) -> list[float]:
    """The real roots of a polynomial (coefficients highest first) strictly inside (lo, hi)."""
    coefficients = list(descending)
    while coefficients and coefficients[0] == 0.0:
        coefficients.pop(0)
    if len(coefficients) < 2:
        return []
    found = []
    for root in np.roots(coefficients):
        if abs(root.imag) <= 1e-9 * (1.0 + abs(root.real)) and lo < root.real < hi:
            found.append(float(root.real))
    return found


class ExchangeWatcher:
    """
    Finds the exchanges of fluid between the segments on the continuous solution, timed.

    The exchange e(t) (:func:`exchange_flow`) is under way while e > 0 and, where it falls,
    the fluid its fall would still move at the present pace, e^2 / |de/dt|, exceeds the
    tolerance (an exponential tail ends where what is left of it is within the tolerance);
    once a tail is let go, it is under way again only where e rises above where it was let
    go, or after it stopped (every member moving with the pump). An episode is a run of such
    stretches joined across pauses in which the network rings all through (a channel's inertia
    carries its flow through the pump's own range: the next swing is the same exchange), each
    shorter than the episode had lasted, with no change of the pump's flow. It is reported
    once its exchange stops and the network does not ring, its pause outlasts it, the pump's
    flow changes, or a stretch starts that cannot join it, when it moved more than the
    tolerance.
    """

    def __init__(self, tolerance_m3: float) -> None:
        """Episodes must move more than ``tolerance_m3`` [m^3]."""
        self.tolerance = tolerance_m3
        self.found: list[DynamicSnap] = []
        self._episode: _Episode | None = None
        self._active = False
        # The exchange [m^3/s] a let-go tail must rise above to be under way again (until every
        # member moves with the pump, or the pump's flow changes).
        self._floor = 0.0

    @property
    def pending(self) -> bool:
        """Whether an episode is under way or paused (not yet reported)."""
        return self._episode is not None

    def flow_changed(self) -> list[DynamicSnap]:
        """The pump's flow changed at once (or the state jumped): a paused episode is reported."""
        self._floor = 0.0
        if self._episode is None or self._active:
            return []
        return self._publish()

    def finish(self, end_s: float,
               state: tuple[float, list[float], float, float | None]) -> list[DynamicSnap]:
        """
        The run ends at ``end_s``: report the episode paused or under way.

        ``state``: injected volume, volumes, the fed segment's gauge pressure and the line's
        fluid (None without a line) at ``end_s``. An episode still under way ends there, cut
        short (:attr:`DynamicSnap.cut_short`).
        """
        episode = self._episode
        if episode is None:
            return []
        if self._active:
            self._active = False
            episode.end_s, episode.end_state = end_s, state
            episode.cut_short = True
        return self._publish()

    def watch(self, curve: StepCurve, lo: float, hi: float, state_at: StateAt,
              exchange_at: ExchangeAt, unstable_at: UnstableAt,
              ringing_at: RingingAt) -> list[DynamicSnap]:
        """The stretch [lo, hi] of a step; the episodes reported in it."""
        if hi <= lo:
            return []
        ended: list[DynamicSnap] = []
        rates = curve.member_rates()
        breaks = [lo, hi]
        for a, b, c in rates:
            breaks += quadratic_roots(a, b, c, lo, hi)
        breaks.sort()
        if self._episode is None and len(breaks) == 2 and \
                _with_pump(rates, curve.flow, 0.5 * (lo + hi)):
            # Every member moves with the pump all through: the usual step.
            self._floor = 0.0
            return ended
        flow = abs(curve.flow)
        for a_x, b_x in zip(breaks, breaks[1:]):
            if b_x <= a_x:
                continue
            middle = 0.5 * (a_x + b_x)
            if _with_pump(rates, curve.flow, middle):
                # The exchange is zero (by mass), not round-off above it: it stopped, and a
                # tail let go is over.
                self._floor = 0.0
                self._off(curve, a_x, b_x, state_at, ringing_at, ended)
                continue
            e = [-0.5 * flow, 0.0, 0.0]
            for a, b, c in rates:
                sign = 0.5 if a + b * middle + c * middle * middle >= 0.0 else -0.5
                e[0] += sign * a
                e[1] += sign * b
                e[2] += sign * c
            exchange = (e[0], e[1], e[2])
            for u, w, on in self._spans(exchange, a_x, b_x, curve.h):
                if on:
                    if not self._active:
                        self._begin(curve, u, state_at, ended)
                    self._extend(curve, u, w, exchange, exchange_at, unstable_at)
                else:
                    self._off(curve, u, w, state_at, ringing_at, ended)
        return ended

    def _spans(self, e: tuple[float, float, float], lo: float, hi: float,
               h: float) -> list[tuple[float, float, bool]]:
        """[lo, hi] cut where the exchange ``e`` (in x) starts or stops being under way."""
        scale = max(abs(e[0]), abs(e[1]), abs(e[2]))
        if scale == 0.0:
            self._floor = 0.0
            return [(lo, hi, False)]
        a, b, c = (x / scale for x in e)
        f = self.tolerance / (h * scale)
        # The tail's rest, e^2 / |de/dt|, exceeds the tolerance where g >= 0 (g: quartic in x).
        tail = (c * c, 2.0 * b * c, b * b + 2.0 * a * c, 2.0 * a * b + 2.0 * f * c, a * a + f * b)
        spans: list[tuple[float, float, bool]] = []
        was_on = self._active
        start = lo
        while start < hi:
            floor = self._floor / scale
            cuts = sorted({start, hi, *quadratic_roots(a - floor, b, c, start, hi),
                           *quadratic_roots(a, b, c, start, hi), *_real_roots(tail, start, hi)})
            restart = None
            for u, w in zip(cuts, cuts[1:]):
                x = 0.5 * (u + w)
                value = a + x * (b + x * c)
                on = value > floor and value * value + f * (b + 2.0 * c * x) >= 0.0
                if was_on and not on and value > 0.0:
                    # A tail let go here: under way again only above this exchange.
                    self._floor, restart = max(scale * (a + u * (b + u * c)), 0.0), u
                if restart is not None:
                    was_on = False
                    break
                spans.append((u, w, on))
                was_on = on
            start = hi if restart is None else restart
        merged: list[tuple[float, float, bool]] = []
        for u, w, on in spans:
            if merged and merged[-1][2] == on:
                merged[-1] = (merged[-1][0], w, on)
            else:
                merged.append((u, w, on))
        return merged

    def _begin(self, curve: StepCurve, x: float, state_at: StateAt,
               ended: list[DynamicSnap]) -> None:
        """
        A stretch starts at ``x``: it resumes the paused episode, or starts one.

        A paused episode is still there only while the network rang all through the pause; it
        is resumed when the pause was shorter than the episode.
        """
        self._active = True
        episode = self._episode
        t = curve.time(x)
        if episode is not None and t - episode.end_s < episode.end_s - episode.start_s:
            return
        if episode is not None:
            ended.extend(self._publish())
        injected, volumes, pressure = state_at(curve, x)
        line_held = None if curve.line_cubic is None else curve.line_held(x)
        self._episode = _Episode(t, injected, volumes, pressure, line_held, feed=curve.feed)

    def _extend(self, curve: StepCurve, lo: float, hi: float,
                exchange: tuple[float, float, float], exchange_at: ExchangeAt,
                unstable_at: UnstableAt) -> None:
        episode = self._episode
        episode.pieces.append((curve.t_old, curve.h, lo, hi, exchange, episode.moved))
        episode.moved += curve.h * _integral(exchange, lo, hi)
        peak, where = quadratic_extreme(*exchange, lo, hi)
        if peak > episode.polynomial_peak:
            # Where the polynomial's exchange peaks, the equations' own: the state there is
            # accurate to a higher order than the polynomial's slope, and at a peak an error
            # of its place changes the value to second order only.
            episode.polynomial_peak = peak
            episode.peak, episode.peak_s = exchange_at(curve, where), curve.time(where)
        if not episode.unstable:
            episode.unstable = any(unstable_at(curve, x) for x in (lo, 0.5 * (lo + hi), hi))

    def _off(self, curve: StepCurve, lo: float, hi: float, state_at: StateAt,
             ringing_at: RingingAt, ended: list[DynamicSnap]) -> None:
        """
        No exchange under way on [lo, hi]: a stretch ends at ``lo``.

        The episode is reported unless the network rings there (a channel's inertia carries
        its flow through the pump's range) and the pause is still shorter than the episode.
        """
        episode = self._episode
        if episode is None:
            return
        if self._active:
            self._active = False
            injected, volumes, pressure = state_at(curve, lo)
            line_held = None if curve.line_cubic is None else curve.line_held(lo)
            episode.end_s = curve.time(lo)
            episode.end_state = (injected, volumes, pressure, line_held)
            episode.feed = curve.feed
        if curve.time(hi) - episode.end_s >= episode.end_s - episode.start_s \
                or not ringing_at(curve, 0.5 * (lo + hi)):
            ended.extend(self._publish())

    def _publish(self) -> list[DynamicSnap]:
        episode, self._episode = self._episode, None
        self._active = False
        if episode is None or episode.end_state is None or episode.moved <= self.tolerance:
            return []
        injected, volumes, pressure, line_held = episode.end_state
        pumped = injected - episode.injected
        exchanged = [after - before for after, before in zip(volumes, episode.volumes)]
        line_exchanged = None
        if episode.line_held is None:
            exchanged[episode.feed] -= pumped
        else:
            # The pump pushed into the line: what the line gained beyond that came from the
            # segments (the segments' own changes are all exchange).
            line_exchanged = line_held - episode.line_held - pumped
        total = episode.moved
        t10, t90 = (_time_at_share(episode, share * total) for share in (0.1, 0.9))
        snap = DynamicSnap(episode.injected, episode.start_s, episode.end_s, t90 - t10, total,
                           episode.peak, episode.volumes, volumes, episode.pressure, pressure,
                           exchanged, episode.peak_s, line_exchanged, episode.unstable,
                           episode.cut_short)
        self.found.append(snap)
        return [snap]


def _with_pump(rates: Sequence[tuple[float, float, float]], flow: float, x: float) -> bool:
    """Every member's rate at ``x`` has the pump's sign or is zero: no exchange, by mass."""
    for a, b, c in rates:
        r = a + x * (b + x * c)
        if r != 0.0 and (flow == 0.0 or (r > 0.0) != (flow > 0.0)):
            return False
    return True


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
