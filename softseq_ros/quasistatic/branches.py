"""
Stable branches: exact samples of the state and its Hermite cubics in the total volume V.

Along a stable stretch the total volume is strictly monotone in the common pressure, so the state
(v_1..v_N, p, k_1..k_N) is a function of V. A :class:`Branch` keeps exact samples of it; its
cubics use the exact slopes dv_i/dV = prod_{j != i} k_j / D, dp/dV = prod k / D and
dk_i/dV = dk_i/dv_i dv_i/dV, and are computed when a state on an interval is first read (a
branch of an eight-segment map has thousands of intervals, most never read).

:func:`fit_branches` checks every interval of every branch at once: the cubic against the exact
state halfway in pressure, and splits the intervals that miss, up to :data:`REFINEMENTS` times
(next to a fold the state goes like a square root of the volume, so the samples crowd there;
the last interval touching the fold stays 'rough', is read as the chord, and its states are
solved exactly by the reader). The splits are run round by round for all branches together,
each round inverting each segment's piece once for every interval that asks.
"""

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from numpy.typing import NDArray
from scipy.interpolate import PPoly

from softseq_ros.quasistatic.numerics import (
    FloatArray,
    SegmentNumerics,
    cofactors,
)
from softseq_ros.segments.models import Piece

# Largest error of a branch's cubics at an interval's middle, as a fraction of the volume
# range, and how many times an interval that misses it is split in two at assembly.
CUBIC_TOLERANCE = 1e-10
REFINEMENTS = 16
# Intervals checked in one go in the first round (bounds the memory of an 8-segment map).
CHUNK_INTERVALS = 1 << 15
# Up to this many intervals of a branch read at once, their cubics are computed one by one
# and kept; beyond, all of the branch's at once.
FEW_INTERVALS = 64
# Beyond this many volumes read at once, a branch is read through one piecewise polynomial of
# all its cubics (built once) instead of gathering each volume's coefficients.
MANY_READS = 4096
_POWERS = np.arange(3, -1, -1)[:, None, None]


@dataclass
class BranchEnd:
    """How a branch ends: it continues on ``target``, snaps to ``target`` or ends the domain."""

    kind: str  # 'continue', 'snap' or 'limit'
    target: int = -1
    target_volumes: FloatArray | None = None


@dataclass
class BranchSamples:
    """A stable stretch's exact samples, sorted by pressure, before fitting."""

    pressure: FloatArray     # (n,)
    volumes: FloatArray      # (n, N)
    stiffness: FloatArray    # (n, N) scaled and clipped (SegmentNumerics.stiffness)
    curvature_slope: FloatArray  # (n, N) dk_i/dv_i [1/m per m^3]
    pieces: tuple[Piece, ...]


@dataclass(eq=False)
class Branch:
    """One stable stretch: exact samples of the state (v_i, p, k_i), read as cubics in V."""

    total: FloatArray       # (n,) strictly increasing total volume
    volumes: FloatArray     # (n, N)
    pressure: FloatArray    # (n,)
    pieces: tuple[Piece, ...]
    rough: NDArray[np.bool_]          # per interval: the chord, states solved exactly
    numerics: SegmentNumerics = field(repr=False)
    lower: BranchEnd = field(default_factory=lambda: BranchEnd('limit'))
    upper: BranchEnd = field(default_factory=lambda: BranchEnd('limit'))

    def __post_init__(self) -> None:
        self.any_rough = bool(self.rough.any())
        self._few: dict[int, FloatArray] = {}
        self._all: FloatArray | None = None
        # Per interval, the cubics' coefficients as Python floats, filled on first use: the
        # per-command path evaluates 2N + 1 cubics, which plain floats do faster than numpy.
        self.rows: list[list[list[float]] | None] = []

    @cached_property
    def lo(self) -> float:
        """The smallest total volume on the branch [m^3]."""
        return float(self.total[0])

    @cached_property
    def hi(self) -> float:
        """The largest total volume on the branch [m^3]."""
        return float(self.total[-1])

    @cached_property
    def knots(self) -> list[float]:
        """The total volumes of the samples as a list, for scalar lookups."""
        return self.total.tolist()

    @cached_property
    def rough_list(self) -> list[bool]:
        """The rough flags as Python bools: the per-command path reads one at a time."""
        return self.rough.tolist()

    @cached_property
    def spline(self) -> PPoly:
        """All the branch's cubics as one piecewise polynomial of V."""
        return PPoly(self.coefficients(np.arange(self.total.size - 1)), self.total,
                     extrapolate=True)

    def coefficients(self, intervals: NDArray[np.intp]) -> FloatArray:
        """The cubics of ``intervals`` in scipy's PPoly layout: (4, m, 2N + 1)."""
        intervals = np.asarray(intervals, dtype=np.intp)
        if self._all is not None:
            return self._all[:, intervals]
        wanted = np.unique(intervals)
        if wanted.size > FEW_INTERVALS:
            self._all = interval_cubics(self, np.arange(self.total.size - 1))
            self._few.clear()
            return self._all[:, intervals]
        missing = [i for i in wanted.tolist() if i not in self._few]
        if missing:
            computed = interval_cubics(self, np.array(missing, dtype=np.intp))
            for column, i in enumerate(missing):
                self._few[i] = computed[:, column]
        return np.stack([self._few[i] for i in intervals.tolist()], axis=1)

    def coefficient_rows(self, interval: int) -> list[list[float]]:
        """One interval's cubics as Python floats, per column highest power first."""
        if not self.rows:
            self.rows.extend([None] * (self.total.size - 1))
        found = self.rows[interval]
        if found is None:
            found = self.rows[interval] = self.coefficients(
                np.array([interval]))[:, 0, :].T.tolist()
        return found

    def evaluate(self, total: FloatArray) -> FloatArray:
        """
        The cubics at total volumes ``total`` (inside the branch): rows (v_1..v_N, p, k_1..k_N).

        The interval and the floating-point operations of scipy's PPoly, so its numbers.
        """
        shape = np.shape(total)
        x = np.asarray(total, dtype=float).ravel()
        if x.size > MANY_READS:
            # A long history: scipy's PPoly of all the cubics, which evaluates in place.
            return self.spline(x).reshape(shape + (self.volumes.shape[1] * 2 + 1,))
        i = np.clip(np.searchsorted(self.total, x, side='right') - 1, 0, self.total.size - 2)
        c = self.coefficients(i)
        offset = (x - self.total[i])[:, None]
        power = offset * offset
        values = c[3] + c[2] * offset + c[1] * power + c[0] * (power * offset)
        return values.reshape(shape + values.shape[-1:])


def sample_slopes(numerics: SegmentNumerics, stiffness: FloatArray, volumes: FloatArray,
                  curvature_slope: FloatArray | None = None) -> FloatArray:
    """
    d(v_1..v_N, p, k_1..k_N)/dV at samples (n, 2N + 1): inf or NaN at a fold (D = 0).

    dv_i/dV = prod_{j != i} k_j / D and dp/dV = prod k / D; the curvatures ride along.
    """
    n = volumes.shape[1]
    weights = cofactors(stiffness)
    d = np.sum(weights, axis=-1)     # cofactor_sum, its cofactors computed once
    with np.errstate(divide='ignore', invalid='ignore', over='ignore'):
        slopes = np.concatenate([weights, np.prod(stiffness, axis=1, keepdims=True)
                                 * numerics.k_scale], axis=1) / d[:, None]
        if curvature_slope is None:
            curvature_slope = numerics.curvature_slopes(volumes)
        return np.concatenate([slopes, curvature_slope * slopes[:, :n]], axis=1)


def hermite(y0: FloatArray, y1: FloatArray, s0: FloatArray, s1: FloatArray,
            h: FloatArray) -> FloatArray:
    """Cubic Hermite per interval in t = (V - V_k) / h: (c0, c1, c2, c3), c3 + t (c2 + ...)."""
    with np.errstate(invalid='ignore', over='ignore'):
        m0, m1 = s0 * h, s1 * h
        return np.stack([2.0 * (y0 - y1) + m0 + m1, 3.0 * (y1 - y0) - 2.0 * m0 - m1, m0, y0])


def interval_cubics(branch: Branch, intervals: NDArray[np.intp]) -> FloatArray:
    """The PPoly coefficients (4, m, 2N + 1) of some intervals of a branch: Hermite or chord."""
    numerics = branch.numerics
    rows, where = np.unique(np.concatenate([intervals, intervals + 1]), return_inverse=True)
    left, right = where[:intervals.size], where[intervals.size:]
    volumes = branch.volumes[rows]
    slopes = sample_slopes(numerics, numerics.stiffness(branch.pieces, volumes), volumes)
    values = np.concatenate([volumes, branch.pressure[rows][:, None],
                             numerics.curvatures(volumes)], axis=1)
    h = (branch.total[intervals + 1] - branch.total[intervals])[:, None]
    y0, y1 = values[left], values[right]
    chord = np.stack([np.zeros_like(y0), np.zeros_like(y0), y1 - y0, y0])
    cubic = np.where(branch.rough[intervals][None, :, None], chord,
                     hermite(y0, y1, slopes[left], slopes[right], h))
    return cubic / h[None, :, :] ** _POWERS


@dataclass
class _Ends:
    """Samples at the ends of intervals (one row per interval): what a check needs."""

    branch: NDArray[np.intp]
    total: FloatArray
    pressure: FloatArray
    volumes: FloatArray
    stiffness: FloatArray
    slopes: FloatArray          # dv_i/dV (n, N)
    finite: NDArray[np.bool_]   # every slope of the sample finite

    def take(self, rows: NDArray[np.intp]) -> '_Ends':
        return _Ends(self.branch[rows], self.total[rows], self.pressure[rows],
                     self.volumes[rows], self.stiffness[rows], self.slopes[rows],
                     self.finite[rows])


@dataclass
class _Regions:
    """
    Runs of consecutive samples around the intervals being split, all branches side by side.

    Sorted by region, then total; ``pending`` flags the interval from a sample to the next one
    of its region as split. A region reaches a few samples beyond its split intervals, so a
    new sample that round-off puts just outside its interval still falls inside the region.
    As rounds go, a region is cut down to pieces around the intervals still split (its
    ``origin`` is the region it came from; the pieces' samples join again at the end).
    """

    samples: _Ends
    region: NDArray[np.intp]
    pending: NDArray[np.bool_]
    owner: NDArray[np.intp]     # per region: its branch
    first: NDArray[np.intp]     # ... its origin's first sample's index among its branch's
    last: NDArray[np.intp]      # ... and its last's
    open_lo: NDArray[np.bool_]  # ... it starts at its branch's first sample
    open_hi: NDArray[np.bool_]  # ... it ends at its branch's last
    origin: NDArray[np.intp]    # ... the region of the first round it is part of

    def take(self, rows: NDArray[np.intp]) -> '_Regions':
        """The samples ``rows`` (whole regions), regions renumbered in order."""
        kept, region = np.unique(self.region[rows], return_inverse=True)
        return _Regions(self.samples.take(rows), region, self.pending[rows],
                        *(getattr(self, name)[kept] for name in _PER_REGION))

    def cut(self, margin: int) -> tuple['_Regions', '_Regions']:
        """
        (pieces around the intervals still split, the other samples).

        A piece holds a split interval's samples and ``margin`` more on each side, overlaps
        merged, within its region.
        """
        size = self.region.size
        near = np.zeros(size, dtype=bool)
        at = np.flatnonzero(self.pending)
        for shift in range(-margin, margin + 2):
            rows = at + shift
            rows = rows[(rows >= 0) & (rows < size)]
            near[rows[self.region[rows] == self.region[rows - shift]]] = True
        rows = np.flatnonzero(near)
        if rows.size == 0:
            return self.take(rows), self
        # A piece starts where a near sample follows a far one or opens a region.
        starts = np.ones(rows.size, dtype=bool)
        starts[1:] = (np.diff(rows) > 1) | (np.diff(self.region[rows]) != 0)
        piece = np.cumsum(starts) - 1
        heads, tails = rows[starts], rows[np.append(np.flatnonzero(starts)[1:] - 1,
                                                   rows.size - 1)]
        region_heads = np.flatnonzero(np.diff(self.region, prepend=-1))
        region_tails = np.append(region_heads[1:], size) - 1
        of = self.region[heads]
        pieces = _Regions(self.samples.take(rows), piece, self.pending[rows], self.owner[of],
                          self.first[of], self.last[of],
                          self.open_lo[of] & (heads == region_heads[of]),
                          self.open_hi[of] & (tails == region_tails[of]), self.origin[of])
        return pieces, self.take(np.flatnonzero(~near))

    @staticmethod
    def join(parts: list['_Regions']) -> '_Regions':
        """The pieces of all parts as their regions of origin, by branch and place in it."""
        parts = [p for p in parts if p.region.size]
        if not parts:
            return _Regions(_concatenate([]), *(np.empty(0, dtype=dtype) for dtype in (
                np.intp, bool, np.intp, np.intp, np.intp, bool, bool, np.intp)))
        origin = np.concatenate([p.origin[p.region] for p in parts])
        samples = _concatenate([p.samples for p in parts])
        pending = np.concatenate([p.pending for p in parts])
        table = {name: np.concatenate([getattr(p, name) for p in parts])
                 for name in _PER_REGION}
        kept, first_piece = np.unique(table['origin'], return_index=True)
        ranks = np.lexsort((table['first'][first_piece], table['owner'][first_piece]))
        rank = np.empty_like(ranks)
        rank[ranks] = np.arange(ranks.size)
        region = rank[np.searchsorted(kept, origin)]
        rows = np.lexsort((samples.total, region))
        ordered = first_piece[ranks]
        return _Regions(samples.take(rows), region[rows], pending[rows],
                        table['owner'][ordered], table['first'][ordered],
                        table['last'][ordered], table['open_lo'][ordered],
                        table['open_hi'][ordered], table['origin'][ordered])


_PER_REGION = ('owner', 'first', 'last', 'open_lo', 'open_hi', 'origin')


# Samples a region reaches beyond the intervals it splits, on each side.
REGION_MARGIN = 4


class _Fitter:
    """Fits every stable stretch of a map: first all intervals, then the splits, round by round."""

    def __init__(self, numerics: SegmentNumerics, stretches: list[BranchSamples]) -> None:
        self.numerics = numerics
        self.stretches = stretches
        self.n = len(numerics.segments)
        # The middles of intervals found to miss, inverted exactly: (branch, left and right
        # totals) -> volumes; the next round's new samples.
        self._middles: dict[tuple[int, float, float], FloatArray] = {}
        # Per stretch, the index of each segment's piece: rows are grouped by it.
        self.piece_index = np.array([numerics.piece_indices(s.pieces) for s in stretches],
                                    dtype=np.intp).reshape(-1, self.n)

    def fit(self) -> list[Branch | None]:
        """The branches (None for a stretch with fewer than two distinct totals)."""
        samples: list[tuple[FloatArray, FloatArray, FloatArray] | None] = [None] * len(
            self.stretches)
        chunks: list[list[int]] = [[]]
        size = 0
        for index, stretch in enumerate(self.stretches):
            chunks[-1].append(index)
            size += stretch.pressure.size
            if size >= CHUNK_INTERVALS and index < len(self.stretches) - 1:
                chunks.append([])
                size = 0
        parts = [self._first_round(chunk, samples) for chunk in chunks]
        offset = 0
        for part in parts:
            part.origin = part.origin + offset
            offset += part.origin.size
        regions, alone = self._refine(_Regions.join(parts))
        starts = np.flatnonzero(np.diff(regions.region, prepend=-1))
        owner = regions.owner
        branches: list[Branch | None] = []
        for index in range(len(self.stretches)):
            if samples[index] is None:
                branches.append(None)
            elif index in alone:
                branches.append(self._fit_alone(index))
            else:
                lo, hi = np.searchsorted(owner, [index, index + 1])
                stops = np.append(starts[1:], regions.region.size)
                branches.append(self._branch(index, samples[index], regions, starts[lo:hi],
                                             stops[lo:hi], np.arange(lo, hi)))
        return branches

    # ------------------------------------------------------------------ first round

    def _first_round(self, chunk: list[int], samples: list) -> _Regions:
        """Sort and check the stretches of ``chunk``; store their samples; the regions to split."""
        stretches = [self.stretches[i] for i in chunk]
        sizes = np.array([s.pressure.size for s in stretches])
        branch = np.repeat(np.array(chunk, dtype=np.intp), sizes)
        pressure = np.concatenate([s.pressure for s in stretches])
        volumes = np.concatenate([s.volumes for s in stretches])
        stiffness = np.concatenate([s.stiffness for s in stretches])
        curvature_slope = np.concatenate([s.curvature_slope for s in stretches])
        total = volumes.sum(axis=1)
        # Sorted by total within each stretch, ties in their order (a stable sort); a sample
        # whose total does not exceed the one before is dropped.
        order = np.lexsort((np.arange(total.size), total, branch))
        keep = np.ones(total.size, dtype=bool)
        keep[1:] = (branch[order][1:] != branch[order][:-1]) | (np.diff(total[order]) > 0.0)
        order = order[keep]
        branch, pressure, volumes, stiffness, curvature_slope, total = (
            branch[order], pressure[order], volumes[order], stiffness[order],
            curvature_slope[order], total[order])
        starts = np.flatnonzero(np.concatenate([[True], branch[1:] != branch[:-1]]))
        stops = np.append(starts[1:], total.size)
        full = sample_slopes(self.numerics, stiffness, volumes, curvature_slope)
        slopes = full[:, :self.n]
        finite = np.all(np.isfinite(full), axis=1)
        for start, stop in zip(starts.tolist(), stops.tolist()):
            if stop - start >= 2:
                samples[int(branch[start])] = (total[start:stop], pressure[start:stop],
                                               volumes[start:stop])
        ends = _Ends(branch, total, pressure, volumes, stiffness, slopes, finite)
        left = np.flatnonzero(branch[:-1] == branch[1:])
        split = ~(finite[left] & finite[left + 1])
        checked = np.flatnonzero(~split)
        split[checked] = self._misses(ends.take(left[checked]), ends.take(left[checked] + 1))
        # Regions: the split intervals and a margin, within their branch, overlaps merged.
        at = left[split]
        owner = np.searchsorted(starts, at, side='right') - 1
        lo = np.maximum(at - REGION_MARGIN, starts[owner])
        hi = np.minimum(at + 1 + REGION_MARGIN, stops[owner] - 1)
        new = np.ones(at.size, dtype=bool)
        new[1:] = lo[1:] > np.maximum.accumulate(hi)[:-1]
        heads = np.flatnonzero(new)
        lo = lo[heads]
        hi = np.maximum.reduceat(hi, heads) if heads.size else hi[heads]
        size = hi - lo + 1
        rows = (np.arange(size.sum()) - np.repeat(np.cumsum(size) - size, size)
                + np.repeat(lo, size))
        region = np.repeat(np.arange(lo.size), size)
        split_at = np.zeros(total.size, dtype=bool)
        split_at[at] = True
        pending = split_at[rows] & (rows < np.repeat(hi, size))
        first = lo - starts[owner[heads]]
        return _Regions(ends.take(rows), region, pending, branch[starts[owner[heads]]], first,
                        first + size - 1, lo == starts[owner[heads]],
                        hi == stops[owner[heads]] - 1, np.arange(heads.size))

    # ------------------------------------------------------------------ the check

    def _misses(self, a: _Ends, b: _Ends) -> NDArray[np.bool_]:
        """
        Intervals whose volume cubic misses the exact state at their middle (in pressure).

        The middle's volumes come from Newton started close by (:meth:`_middle_volumes`); an
        interval that misses is split at this very middle next round.
        """
        if a.total.size == 0:
            return np.zeros(0, dtype=bool)
        h = (b.total - a.total)[:, None]
        cubic = hermite(a.volumes, b.volumes, a.slopes, b.slopes, h)
        middle = self._middle_volumes(a, b)
        c0, c1, c2, c3 = cubic
        t = ((middle.sum(axis=1) - a.total) / h[:, 0])[:, None]
        distance = np.max(np.abs(((c0 * t + c1) * t + c2) * t + c3 - middle), axis=1)
        miss = ~(distance <= CUBIC_TOLERANCE * self.numerics.v_scale)
        for row in np.flatnonzero(miss).tolist():
            key = (int(a.branch[row]), float(a.total[row]), float(b.total[row]))
            self._middles[key] = middle[row]
        return miss

    def _middle_volumes(self, a: _Ends, b: _Ends) -> FloatArray:
        """
        The volumes halfway in pressure between two samples, started close by.

        Each lies between its two samples' volumes on its piece: Newton from the cubic
        Hermite guess in p (the slopes dv/dp = 1/k are known at both ends) reaches round-off
        in a step or two, where the piece-wide start takes several.
        """
        numerics = self.numerics
        target = 0.5 * (a.pressure + b.pressure)
        span = (b.pressure - a.pressure)[:, None]
        lo, hi = np.minimum(a.volumes, b.volumes), np.maximum(a.volumes, b.volumes)
        with np.errstate(divide='ignore', invalid='ignore', over='ignore'):
            guess = (0.5 * (a.volumes + b.volumes) + 0.125 * span / numerics.k_scale
                     * (1.0 / a.stiffness - 1.0 / b.stiffness))
        start = np.where(np.isfinite(guess) & (guess > lo) & (guess < hi), guess,
                         0.5 * (lo + hi))
        return numerics.invert_rows(self.piece_index[a.branch], target, (lo, hi, start))

    def _exact(self, branch: NDArray[np.intp], pressure: FloatArray,
               volumes: FloatArray) -> _Ends:
        """Samples at new pressures, from their volumes there (inverted to round-off)."""
        stiffness = self.numerics.stiffness_at(self.piece_index[branch], volumes)
        full = sample_slopes(self.numerics, stiffness, volumes, False)
        return _Ends(branch, volumes.sum(axis=1), pressure, volumes, stiffness,
                     full[:, :self.n], np.all(np.isfinite(full), axis=1))

    def _new_samples(self, a: _Ends, b: _Ends) -> _Ends:
        """The samples halfway in pressure of intervals that split; inversions done are reused."""
        pressure = 0.5 * (a.pressure + b.pressure)
        known = [self._middles.pop((branch, left, right), None) for branch, left, right in
                 zip(a.branch.tolist(), a.total.tolist(), b.total.tolist())]
        volumes = np.empty((pressure.size, self.n))
        missing = np.array([v is None for v in known], dtype=bool)
        if missing.any():
            volumes[missing] = self.numerics.invert_rows(self.piece_index[a.branch[missing]],
                                                         pressure[missing])
        if not missing.all():
            volumes[~missing] = np.array([v for v in known if v is not None])
        return self._exact(a.branch, pressure, volumes)

    # ------------------------------------------------------------------ the splits

    def _refine(self, regions: _Regions) -> tuple[_Regions, set[int]]:
        """
        Split the intervals that miss, up to REFINEMENTS times, all branches together.

        Each split interval gets the sample halfway in pressure, sorted in by its total
        among its region's samples (a stable sort: on a tie the earlier sample stays, the
        new one is dropped); an interval between two samples that followed each other before
        keeps its state, every other is new and checked. A new sample outside its region's
        totals (round-off next to a fold) sends its branch to :meth:`_fit_alone`; their
        numbers are returned with the regions.
        """
        alone: set[int] = set()
        settled: list[_Regions] = []
        for _ in range(REFINEMENTS):
            # Only the samples around intervals still to split take part in the round.
            regions, done = regions.cut(REGION_MARGIN)
            settled.append(done)
            rows = np.flatnonzero(regions.pending)
            if rows.size == 0:
                break
            a, b = regions.samples.take(rows), regions.samples.take(rows + 1)
            middle = self._new_samples(a, b)
            owner = regions.region[rows]
            heads = np.flatnonzero(np.diff(regions.region, prepend=-1))
            tails = np.append(heads[1:], regions.region.size) - 1
            total = regions.samples.total
            # Beyond a region's end inside its branch, a new sample would go between samples
            # the region does not hold; beyond the branch's own end it is the new end.
            outside = (((middle.total < total[heads[owner]]) & ~regions.open_lo[owner])
                       | ((middle.total > total[tails[owner]]) & ~regions.open_hi[owner]))
            if outside.any():
                alone.update(middle.branch[outside].tolist())
                keep = np.flatnonzero(~np.isin(regions.samples.branch, list(alone)))
                rows_kept = ~np.isin(middle.branch, list(alone))
                middle, owner = middle.take(np.flatnonzero(rows_kept)), owner[rows_kept]
                old_to_new = np.cumsum(np.isin(np.arange(regions.first.size),
                                               regions.region[keep])) - 1
                owner = old_to_new[owner]
                regions = regions.take(keep)
            count = regions.region.size
            merged = _concatenate([regions.samples, middle])
            region = np.concatenate([regions.region, owner])
            order = np.lexsort((np.arange(region.size), merged.total, region))
            region, merged = region[order], merged.take(order)
            keep = np.ones(order.size, dtype=bool)
            keep[1:] = (region[1:] != region[:-1]) | (np.diff(merged.total) > 0.0)
            order, region, merged = order[keep], region[keep], merged.take(np.flatnonzero(keep))
            same = region[:-1] == region[1:]
            before, after = order[:-1], order[1:]
            old = same & (before < count) & (after == before + 1)
            pending = np.zeros(order.size, dtype=bool)
            pending[:-1][old] = regions.pending[before[old]]
            fresh = np.flatnonzero(same & ~old)
            halves = merged.take(fresh), merged.take(fresh + 1)
            split = ~(halves[0].finite & halves[1].finite)
            checked = np.flatnonzero(~split)
            split[checked] = self._misses(halves[0].take(checked), halves[1].take(checked))
            pending[fresh] = split
            regions = _Regions(merged, region, pending,
                               *(getattr(regions, name) for name in _PER_REGION))
        regions = _Regions.join([*settled, regions])
        if alone:
            regions = regions.take(np.flatnonzero(~np.isin(regions.owner[regions.region],
                                                           list(alone))))
        return regions, alone

    def _branch(self, index: int, samples: tuple[FloatArray, FloatArray, FloatArray],
                regions: _Regions, starts: NDArray[np.intp], stops: NDArray[np.intp],
                which: NDArray[np.intp]) -> Branch:
        """A branch: its first-round samples with its regions' samples in their place."""
        total, pressure, volumes = samples
        rough = np.zeros(total.size - 1, dtype=bool)
        if which.size:
            parts: list[tuple[FloatArray, FloatArray, FloatArray, NDArray[np.bool_]]] = []
            done = 0
            for start, stop, region in zip(starts.tolist(), stops.tolist(), which.tolist()):
                first, last = int(regions.first[region]), int(regions.last[region])
                parts.append((total[done:first], pressure[done:first], volumes[done:first],
                              rough[done:first]))
                inside = regions.samples.take(np.arange(start, stop))
                parts.append((inside.total, inside.pressure, inside.volumes,
                              regions.pending[start:stop]))
                done = last + 1
            parts.append((total[done:], pressure[done:], volumes[done:], rough[done:]))
            total = np.concatenate([p[0] for p in parts])
            pressure = np.concatenate([p[1] for p in parts])
            volumes = np.concatenate([p[2] for p in parts])
            # Each part's flags are for the intervals from its samples to the next.
            rough = np.concatenate([p[3] for p in parts])[:total.size - 1]
        stretch = self.stretches[index]
        return Branch(total, volumes, pressure, stretch.pieces, rough, self.numerics)

    def _fit_alone(self, index: int) -> Branch | None:
        """
        One branch, its splits merged by sorting all samples each round (any order of totals).

        For a branch where a new sample's total fell outside its interval (round-off next to
        a fold): sorted in among the others, it changes which intervals are new; the others,
        checked before and not split, stay as they were.
        """
        stretch = self.stretches[index]
        branch = np.full(stretch.pressure.size, index, dtype=np.intp)
        full = sample_slopes(self.numerics, stretch.stiffness, stretch.volumes,
                             stretch.curvature_slope)
        ends = _Ends(branch, stretch.volumes.sum(axis=1), stretch.pressure, stretch.volumes,
                     stretch.stiffness, full[:, :self.n], np.all(np.isfinite(full), axis=1))
        ends = ends.take(np.argsort(ends.total, kind='stable'))
        keep = np.concatenate([[True], np.diff(ends.total) > 0.0])
        ends = ends.take(np.flatnonzero(keep))
        if ends.total.size < 2:
            return None
        split = self._check(ends, np.ones(ends.total.size - 1, dtype=bool))
        for _ in range(REFINEMENTS):
            if not split.any():
                break
            where = np.flatnonzero(split)
            middle = self._new_samples(ends.take(where), ends.take(where + 1))
            count = ends.total.size
            merged = _concatenate([ends, middle])
            order = np.argsort(merged.total, kind='stable')
            merged = merged.take(order)
            keep = np.concatenate([[True], np.diff(merged.total) > 0.0])
            merged, order = merged.take(np.flatnonzero(keep)), order[keep]
            # An interval between two old samples that followed each other keeps its state.
            a, b = order[:-1], order[1:]
            old = (a < count) & (b < count) & (b == a + 1)
            fresh = np.zeros(a.size, dtype=bool)
            fresh[~old] = True
            new_split = np.zeros(a.size, dtype=bool)
            new_split[old] = split[a[old]]
            new_split[fresh] = self._check(merged, fresh)[fresh]
            ends, split = merged, new_split
        return Branch(ends.total, ends.volumes, ends.pressure, stretch.pieces, split,
                      self.numerics)

    def _check(self, ends: _Ends, which: NDArray[np.bool_]) -> NDArray[np.bool_]:
        """Split flags of the intervals ``which`` of one branch's sorted samples."""
        rows = np.flatnonzero(which)
        a, b = ends.take(rows), ends.take(rows + 1)
        split = np.zeros(which.size, dtype=bool)
        rough = ~(a.finite & b.finite)
        split[rows] = rough
        checked = np.flatnonzero(~rough)
        split[rows[checked]] = self._misses(a.take(checked), b.take(checked))
        return split


def _concatenate(parts: list[_Ends]) -> _Ends:
    """Rows of several :class:`_Ends` one after the other."""
    if not parts:
        return _Ends(np.empty(0, dtype=np.intp), np.empty(0), np.empty(0), np.empty((0, 0)),
                     np.empty((0, 0)), np.empty((0, 0)), np.empty(0, dtype=bool))
    return _Ends(*(np.concatenate([getattr(p, name) for p in parts])
                   for name in ('branch', 'total', 'pressure', 'volumes', 'stiffness', 'slopes',
                                'finite')))


def fit_branches(numerics: SegmentNumerics,
                 stretches: list[BranchSamples]) -> list[Branch | None]:
    """Fit every stable stretch as a branch (None where fewer than two totals differ)."""
    if not stretches:
        return []
    return _Fitter(numerics, stretches).fit()
