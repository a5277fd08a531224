"""
Assembling the equilibrium set: monotone pieces, configurations, stable branches as cubics.

Each segment's PV curve splits into monotone pieces; choosing one piece per segment (a
*configuration*) makes every volume a function of the common pressure p, so the equilibrium set
is a union of curves parametrised by p (the paper's "assembling algorithm"). Along a stable
stretch the total volume is strictly monotone in p, so each stable stretch is stored as a
:class:`Branch`: Hermite cubics of the state in the total volume V, checked against the exact
state and refined where they miss. How branches end (continue, snap, limit) is decided
afterwards (softseq_ros.quasistatic.branch_ends).
"""

from bisect import bisect_right
from dataclasses import dataclass, field
from functools import cached_property
import math
from typing import Generator, Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.interpolate import PPoly
from scipy.optimize import brentq

from softseq_ros.segments.models import (
    Piece,
    Segment,
    at_piece_ends,
    evaluate_cubics,
    newton_start,
)
from softseq_ros.tolerances import DEFAULT_TOLERANCES, ConvergenceLog, Tolerances

FloatArray = NDArray[np.float64]
# A branch being fitted: yields (configuration, pressures) for volumes, returns the branch.
Refinement = Generator[tuple[tuple['Piece', ...], FloatArray], FloatArray, 'Branch | None']

# Largest error of a branch's cubics at an interval's middle, as a fraction of the volume
# range, and how many times an interval that misses it is split in two at assembly.
CUBIC_TOLERANCE = 1e-10
REFINEMENTS = 16
# Up to this many pressures, a table's piece is inverted on Python floats, one at a time.
SCALAR_INVERSIONS = 16
EPS = float(np.finfo(float).eps)


@dataclass
class EquilibriumCurve:
    """One configuration's equilibria (stable and unstable), for plotting."""

    injected: FloatArray
    volumes: FloatArray
    pressure: FloatArray
    stable: NDArray[np.bool_]


@dataclass
class BranchEnd:
    """How a branch ends: it continues on ``target``, snaps to ``target`` or ends the domain."""

    kind: str  # 'continue', 'snap' or 'limit'
    target: int = -1
    target_volumes: FloatArray | None = None


@dataclass
class Branch:
    """One stable stretch: exact samples and the cubics of the state (v_i, p, k_i) in V."""

    total: FloatArray       # (n,) strictly increasing total volume
    volumes: FloatArray     # (n, N)
    pressure: FloatArray    # (n,)
    pieces: tuple[Piece, ...]
    spline: PPoly | None = None      # (v_i, p, k_i) as piecewise cubics of V
    knots: list[float] | None = None  # total as a list, for scalar lookups
    rough: NDArray[np.bool_] | None = None  # per interval: solved exactly (next to folds)
    lower: BranchEnd = field(default_factory=lambda: BranchEnd('limit'))
    upper: BranchEnd = field(default_factory=lambda: BranchEnd('limit'))

    def __post_init__(self) -> None:
        self.any_rough = bool(self.rough is not None and self.rough.any())
        # The same flags as Python bools: the per-command path reads one at a time.
        self.rough_list: list[bool] = [] if self.rough is None else self.rough.tolist()
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


def cofactor_sum(k: FloatArray) -> FloatArray:
    """D = sum_i prod_{j != i} k_j along the last axis, without dividing by a k that may be 0."""
    return np.sum(cofactors(k), axis=-1)


def cofactors(k: FloatArray) -> FloatArray:
    """W_i = prod_{j != i} k_j (proportional to 1/k_i, finite where a k is 0)."""
    ones = np.ones(k.shape[:-1] + (1,))
    prefix = np.concatenate([ones, np.cumprod(k[..., :-1], axis=-1)], axis=-1)
    suffix = np.concatenate([np.cumprod(k[..., :0:-1], axis=-1)[..., ::-1], ones], axis=-1)
    return prefix * suffix


def soft_direction(k: FloatArray) -> FloatArray:
    """Unit redistribution (sum 0) along which the restricted Hessian diag(k) is softest."""
    n = k.size
    basis = np.linalg.qr(np.eye(n) - 1.0 / n, mode='reduced')[0][:, : n - 1]
    _, vectors = np.linalg.eigh(basis.T @ np.diag(k) @ basis)
    direction = basis @ vectors[:, 0]
    return direction / np.linalg.norm(direction)


class PieceInverse:
    """
    Volumes on one monotone piece of one segment where the pressure equals given values.

    :meth:`Segment.invert`'s safeguarded Newton iteration, step for step. For a table, the
    PCHIP cubics are evaluated here with array arithmetic (:func:`evaluate_cubics`: the same
    numbers as the model's own calls, to the bit) instead of through two interpolator calls
    per step, which cost several times the arithmetic on the few hundred pressures an
    assembly inverts at once.
    """

    def __init__(self, segment: Segment, piece: Piece, tolerances: Tolerances,
                 log: ConvergenceLog) -> None:
        """``log`` records whether each inversion converged."""
        self.segment, self.piece = segment, piece
        self.tolerances, self.log = tolerances, log
        self.cubics = segment.pressure_cubics() if piece.direction != 0 else None
        if self.cubics is not None:
            breaks, pressure, stiffness = self.cubics
            # The same cubics as Python floats, for a few pressures at a time.
            self.breaks_list = breaks.tolist()
            self.pressure_rows = pressure.T.tolist()
            self.stiffness_rows = stiffness.T.tolist()

    def __call__(self, p: FloatArray) -> FloatArray:
        """The volumes at pressures ``p`` (those outside the piece's range: its nearer end)."""
        if self.cubics is None:
            return self.segment.invert(self.piece, p, self.tolerances, self.log)
        target = np.asarray(p, dtype=float)
        if target.size <= SCALAR_INVERSIONS:
            volumes, converged = [], True
            for value in target.ravel().tolist():
                volume, done = self._one(value)
                volumes.append(volume)
                converged &= done
            self.log.record('inversion', converged)
            return np.array(volumes).reshape(target.shape)
        breaks, pressure, stiffness = self.cubics
        piece = self.piece
        sign = float(piece.direction)
        ulps = self.tolerances.round_off_ulps
        lo, hi, x, floor = newton_start(piece, target, ulps)
        converged = False
        # Only the pressures not done yet are iterated: a done one no longer moves.
        x, lo, hi = x.ravel().copy(), lo.ravel(), hi.ravel()
        active = np.arange(x.size)
        goal = target.ravel()
        for _ in range(self.tolerances.inversion_steps):
            xa, ta = x[active], goal[active]
            residual = sign * (evaluate_cubics(breaks, pressure, xa) - ta)
            above = residual > 0.0
            ha = np.where(above, xa, hi[active])
            la = np.where(above, lo[active], xa)
            done = (np.abs(residual) <= floor) | (
                ha - la <= ulps * np.spacing(np.maximum(np.abs(ha), 1e-300)))
            if np.all(done):
                converged = True
                break
            slope = sign * evaluate_cubics(breaks, stiffness, xa)
            with np.errstate(divide='ignore', invalid='ignore'):
                step = xa - residual / slope
            inside = np.isfinite(step) & (step > la) & (step < ha)
            going = ~done
            active, xa, la, ha = active[going], xa[going], la[going], ha[going]
            x[active] = np.where(inside[going], step[going], 0.5 * (la + ha))
            lo[active], hi[active] = la, ha
        x = x.reshape(target.shape)
        self.log.record('inversion', converged)
        return at_piece_ends(piece, target, x)

    def _cubic(self, rows: list[list[float]], v: float) -> float:
        """One cubic at one volume: :func:`evaluate_cubics`' operations on Python floats."""
        breaks = self.breaks_list
        i = min(max(bisect_right(breaks, v) - 1, 0), len(breaks) - 2)
        offset = v - breaks[i]
        row = rows[i]
        value = row[-1]
        power = offset
        value = value + row[-2] * power
        for coefficient in row[-3::-1]:
            power = power * offset
            value = value + coefficient * power
        return value

    def _one(self, target: float) -> tuple[float, bool]:
        """
        One pressure's volume and whether it converged: the array iteration's steps on floats.

        IEEE arithmetic on Python floats and on numpy's elements gives the same numbers, and
        an element of the array iteration stops moving once it is done, so the volume is the
        one the arrays give; a few pressures at a time cost a fraction of the array calls.
        """
        piece = self.piece
        sign = float(piece.direction)
        lo, hi = piece.v_lo, piece.v_hi
        span = piece.p_at_hi - piece.p_at_lo
        x = (piece.v_lo + (piece.v_hi - piece.v_lo)
             * min(max((target - piece.p_at_lo) / span, 0.0), 1.0)) if span else 0.5 * (lo + hi)
        ulps = self.tolerances.round_off_ulps
        floor = ulps * EPS * max(abs(piece.p_at_lo), abs(piece.p_at_hi), 1e-300)
        converged = False
        for _ in range(self.tolerances.inversion_steps):
            residual = sign * (self._cubic(self.pressure_rows, x) - target)
            if residual > 0.0:
                hi = x
            else:
                lo = x
            if abs(residual) <= floor or hi - lo <= ulps * math.ulp(max(abs(hi), 1e-300)):
                converged = True
                break
            slope = sign * self._cubic(self.stiffness_rows, x)
            step = x - residual / slope if slope != 0.0 else math.nan
            x = step if (math.isfinite(step) and lo < step < hi) else 0.5 * (lo + hi)
        if target == piece.p_at_lo:
            x = piece.v_lo
        if target == piece.p_at_hi:
            x = piece.v_hi
        return x, converged


class SegmentNumerics:
    """The numbers every stage shares: segments, their pieces, scales and tolerances."""

    def __init__(self, segments: Sequence[Segment],
                 tolerances: Tolerances = DEFAULT_TOLERANCES) -> None:
        """Pieces and scales of ``segments`` (base to tip); ``convergence`` logs the solves."""
        self.segments = list(segments)
        self.tolerances = tolerances
        self.convergence = ConvergenceLog()
        self.rest_volumes = np.array([s.rest_volume for s in self.segments])
        self.max_volumes = np.array([s.max_volume for s in self.segments])
        self.total_rest_volume = float(self.rest_volumes.sum())
        self.v_scale = float(np.sum(self.max_volumes - self.rest_volumes))
        self.pieces = [s.monotone_pieces() for s in self.segments]
        p_extent = max(max(abs(pc.p_at_lo), abs(pc.p_at_hi))
                       for pieces in self.pieces for pc in pieces)
        self.p_scale = p_extent if p_extent > 0.0 else 1.0
        self.k_scale = self.p_scale / self.v_scale
        self.tol_v = tolerances.same_volume * self.v_scale
        self._inverses: dict[tuple[int, Piece], PieceInverse] = {}

    def volumes_at(self, config: tuple[Piece, ...], p: FloatArray) -> FloatArray:
        """Each segment's volume on its piece of ``config`` at the pressures ``p``."""
        return np.stack([self.inverse(i, piece)(p) for i, piece in enumerate(config)], axis=-1)

    def inverse(self, index: int, piece: Piece) -> 'PieceInverse':
        """The inversion of segment ``index`` on ``piece`` (built once, then reused)."""
        key = (index, piece)
        found = self._inverses.get(key)
        if found is None:
            found = self._inverses[key] = PieceInverse(self.segments[index], piece,
                                                       self.tolerances, self.convergence)
        return found

    def stiffness(self, config: tuple[Piece, ...], volumes: FloatArray) -> FloatArray:
        """Scaled dp/dv, clipped to the sign its piece promises (exactly 0 on a flat piece)."""
        columns = []
        for i, (seg, piece) in enumerate(zip(self.segments, config)):
            v = volumes[..., i]
            k = seg.stiffness(v) / self.k_scale
            # A piece end inside the model's range is a peak or a valley: the slope there is
            # zero by definition, not the round-off of a numerical derivative.
            turning = np.zeros(np.shape(v), dtype=bool)
            if piece.v_lo > seg.rest_volume:
                turning |= v == piece.v_lo
            if piece.v_hi < seg.max_volume:
                turning |= v == piece.v_hi
            k = np.where(turning, 0.0, k)
            if piece.direction > 0:
                k = np.maximum(k, 0.0)
            elif piece.direction < 0:
                k = np.minimum(k, 0.0)
            else:
                k = np.zeros_like(k)
            columns.append(k)
        return np.stack(columns, axis=-1)

    def curvatures(self, volumes: FloatArray) -> FloatArray:
        """Per-segment curvature for volumes (n, N), in 1/m."""
        return np.stack([s.curvature(volumes[:, j]) for j, s in enumerate(self.segments)],
                        axis=1)



class Assembly:
    """The stable branches and the whole equilibrium set (for plots) of some segments."""

    def __init__(self, numerics: SegmentNumerics, resolution: int) -> None:
        """Assemble every configuration's branches at ``resolution`` samples per segment."""
        self.numerics = numerics
        self.resolution = int(resolution)
        self.curves: list[EquilibriumCurve] = []
        self.branches: list[Branch] = []
        self.configurations = self._configurations()
        self._samples: dict[tuple[int, Piece], FloatArray] = {}
        # The configurations are sampled side by side, and then every stable stretch is
        # fitted and refined side by side, round by round (:meth:`_run`); curves and branches
        # keep the order of their configurations.
        jobs: list[Refinement] = []
        for curves, found in self._run([self._assemble(c) for c in self.configurations]):
            self.curves.extend(curves)
            jobs.extend(found)
        self.branches = [b for b in self._run(jobs) if b is not None]

    def _configurations(self) -> list[tuple[Piece, ...]]:
        """Piece tuples that can hold a stable equilibrium: at most one falling piece."""
        found = []

        def extend(prefix: tuple[Piece, ...], p_lo: float, p_hi: float, falling: int) -> None:
            if len(prefix) == len(self.numerics.pieces):
                found.append(prefix)
                return
            for piece in self.numerics.pieces[len(prefix)]:
                lo, hi = max(p_lo, piece.p_min), min(p_hi, piece.p_max)
                fall = falling + (piece.direction < 0)
                if lo <= hi and fall <= 1:
                    extend(prefix + (piece,), lo, hi, fall)

        extend((), -math.inf, math.inf, 0)
        return found

    def _assemble(self, config: tuple[Piece, ...]) -> Generator[
            tuple[tuple[Piece, ...], FloatArray], FloatArray,
            tuple[list[EquilibriumCurve], list['Refinement']]]:
        """A configuration's equilibria (for plots) and the refinements of its stable stretches."""
        curves: list[EquilibriumCurve] = []
        jobs: list[Refinement] = []
        flats = [i for i, pc in enumerate(config) if pc.direction == 0]
        if flats:
            self._assemble_plateau(config, flats, curves, jobs)
            return curves, jobs
        p_lo = max(pc.p_min for pc in config)
        p_hi = min(pc.p_max for pc in config)
        if not p_hi > p_lo:
            return curves, jobs
        grids = [np.array([p_lo, p_hi])]
        for i, piece in enumerate(config):
            p_samples = self._piece_samples(i, piece)
            grids.append(p_samples[(p_samples > p_lo) & (p_samples < p_hi)])
        p = np.unique(np.concatenate(grids))
        volumes = yield config, p
        k = self.numerics.stiffness(config, volumes)
        d = cofactor_sum(k)
        stable = d > 0.0
        total = volumes.sum(axis=1)
        curves.append(EquilibriumCurve(total - self.numerics.total_rest_volume, volumes, p,
                                       stable))
        if not stable.any():
            return curves, jobs
        edges = np.flatnonzero(np.diff(stable.astype(np.int8)))
        starts = [0] + list(edges + 1)
        stops = list(edges + 1) + [p.size]
        for start, stop in zip(starts, stops):
            if not stable[start]:
                continue
            run_p = p[start:stop]
            extra = []
            if start > 0:
                extra.append(self._fold(config, p[start - 1], p[start]))
            if stop < p.size:
                extra.append(self._fold(config, p[stop - 1], p[stop]))
            run_p = np.unique(np.concatenate([run_p, extra]))
            run_v = yield config, run_p
            jobs.append(self._add_branch(run_v, run_p, config))
        return curves, jobs

    def _piece_samples(self, index: int, piece: Piece) -> FloatArray:
        """
        The pressures segment ``index`` contributes on ``piece``, computed once.

        They are the same in every configuration: samples evenly spaced along its curve, and
        the model's own knots, so the cubics never straddle a kink.
        """
        key = (index, piece)
        if key not in self._samples:
            seg = self.numerics.segments[index]
            count = max(32, int(math.ceil(self.resolution * seg.arclength_share(piece))))
            knots = seg.knots()
            knots = knots[(knots > piece.v_lo) & (knots < piece.v_hi)]
            self._samples[key] = seg.pressure(np.concatenate([seg.arclength_samples(piece, count),
                                                              knots]))
        return self._samples[key]

    def _fold(self, config: tuple[Piece, ...], p_a: float, p_b: float) -> float:
        """Pressure where D = 0 between two samples of opposite stability."""
        def d_at(p: float) -> float:
            v = self.numerics.volumes_at(config, np.array([p]))
            return float(cofactor_sum(self.numerics.stiffness(config, v))[0])

        d_a, d_b = d_at(p_a), d_at(p_b)
        if d_a == 0.0:
            return p_a
        if d_b == 0.0 or d_a * d_b > 0.0:
            return p_b
        return brentq(d_at, p_a, p_b, xtol=1e-14 * self.numerics.p_scale, rtol=1e-15)

    def _assemble_plateau(self, config: tuple[Piece, ...], flats: list[int],
                          curves: list[EquilibriumCurve], jobs: list['Refinement']) -> None:
        """
        Flat pieces at one common pressure: the flat segments absorb the volume.

        Several flat segments at the same pressure are neutral (any split is an equilibrium): they
        fill one after the other, base first, and empty in the reverse order, so the path is
        deterministic and the same both ways.
        """
        p_flat = config[flats[0]].p_at_lo
        if any(abs(config[i].p_at_lo - p_flat) > 1e-12 * self.numerics.p_scale for i in flats):
            return
        others = [i for i in range(len(config)) if i not in flats]
        base = np.zeros(len(config))
        for i in others:
            piece = config[i]
            if not piece.p_min <= p_flat <= piece.p_max or piece.direction < 0:
                return
            base[i] = self.numerics.segments[i].invert(
                piece, np.array([p_flat]), self.numerics.tolerances, self.numerics.convergence)[0]
        k_others = self.numerics.stiffness(config, base[None, :])[0, others]
        if np.any(k_others <= 0.0):
            return
        for order, i in enumerate(flats):
            lo_hi = np.linspace(config[i].v_lo, config[i].v_hi, 3)
            volumes = np.tile(base, (lo_hi.size, 1))
            for j in flats[:order]:
                volumes[:, j] = config[j].v_hi
            for j in flats[order + 1:]:
                volumes[:, j] = config[j].v_lo
            volumes[:, i] = lo_hi
            pressure = np.full(lo_hi.size, p_flat)
            injected = volumes.sum(axis=1) - self.numerics.total_rest_volume
            curves.append(EquilibriumCurve(injected, volumes, pressure,
                                           np.ones(lo_hi.size, bool)))
            jobs.append(self._add_branch(volumes, pressure, config))

    def _run(self, jobs: list[Generator]) -> list:
        """
        Run jobs side by side, each round's inversions of all of them at once; their results.

        A job (a configuration's sampling, a branch's refinement) yields (configuration,
        pressures) whenever it needs volumes; the requests of one round are grouped by
        segment and piece, so each piece is inverted once per round for every job that asks,
        instead of once per job. The inversion is elementwise, so the volumes are the ones
        separate calls give.
        """
        results: list = [None] * len(jobs)
        active: dict[int, tuple[tuple[Piece, ...], FloatArray]] = {}

        def advance(index: int, volumes: FloatArray | None) -> None:
            try:
                request = jobs[index].send(volumes)  # type: ignore[arg-type]
            except StopIteration as stop:
                results[index] = stop.value
                active.pop(index, None)
            else:
                active[index] = (request[0], np.asarray(request[1], dtype=float))

        for index in range(len(jobs)):
            advance(index, None)
        while active:
            groups: dict[tuple[int, Piece], list[int]] = {}
            for index, (config, _) in active.items():
                for segment, piece in enumerate(config):
                    groups.setdefault((segment, piece), []).append(index)
            answers: dict[int, list[FloatArray]] = {i: [np.empty(0)] * len(config)
                                                    for i, (config, _) in active.items()}
            for (segment, piece), asking in groups.items():
                pressures = [active[i][1] for i in asking]
                volumes = self.numerics.inverse(segment, piece)(np.concatenate(pressures))
                start = 0
                for i, p in zip(asking, pressures):
                    answers[i][segment] = volumes[start:start + p.size]
                    start += p.size
            for index in list(active):
                advance(index, np.stack(answers[index], axis=-1))
        return results

    def _add_branch(self, volumes: FloatArray, pressure: FloatArray,
                    config: tuple[Piece, ...]) -> 'Refinement':
        """
        Store one stable stretch as a branch: Hermite cubics of the state in total volume.

        Every interval is checked against the exact state at its middle and split there where
        the cubic misses it, a few times over: next to a fold or bifurcation the state goes like
        a square root of the volume, so the samples crowd there. The last interval touching
        the singular point stays 'rough', now tiny, and its states are solved exactly.
        """
        flat = any(pc.direction == 0 for pc in config)
        passed: set[tuple[float, float]] = set()
        fitted = yield from self._fit(volumes, pressure, config, flat, passed)
        for _ in range(0 if flat else REFINEMENTS):
            if fitted is None:
                return None
            total, volumes, pressure, _, split = fitted
            if not split.any():
                break
            passed.update(zip(total[:-1][~split].tolist(), total[1:][~split].tolist()))
            middle = 0.5 * (pressure[:-1][split] + pressure[1:][split])
            fitted = yield from self._fit(np.concatenate([volumes, (yield config, middle)]),
                                          np.concatenate([pressure, middle]), config, flat,
                                          passed)
        if fitted is None:
            return None
        total, volumes, pressure, coefficients, rough = fitted
        h = np.diff(total)[:, None]
        # From powers of t = (V - V_k) / h to powers of (V - V_k), as PPoly evaluates them.
        coefficients = coefficients / h[None, :, :] ** np.arange(3, -1, -1)[:, None, None]
        spline = PPoly(coefficients, total, extrapolate=True)
        return Branch(total, volumes, pressure, config, spline, total.tolist(), rough)

    def _fit(self, volumes: FloatArray, pressure: FloatArray, config: tuple[Piece, ...],
             flat: bool, passed: set[tuple[float, float]]
             ) -> Generator[tuple[tuple[Piece, ...], FloatArray], FloatArray, tuple | None]:
        """
        Sorted samples, their cubics in t, and the intervals the Hermite cubics cannot take.

        Those 'rough' intervals (a fold at an end, or a miss at the middle) get the chord.
        """
        total = volumes.sum(axis=1)
        order = np.argsort(total, kind='stable')
        total, volumes, pressure = total[order], volumes[order], pressure[order]
        keep = np.concatenate([[True], np.diff(total) > 0.0])
        if keep.sum() < 2:
            return None
        total, volumes, pressure = total[keep], volumes[keep], pressure[keep]
        n = volumes.shape[1]
        k = self.numerics.stiffness(config, volumes)
        d = cofactor_sum(k)
        with np.errstate(divide='ignore', invalid='ignore'):
            # dv_i/dV = prod_{j != i} k_j / D and dp/dV = prod k / D, both finite off folds.
            slopes = np.concatenate([cofactors(k), np.prod(k, axis=1, keepdims=True)
                                     * self.numerics.k_scale], axis=1) / d[:, None]
        # Curvatures ride along: dk_i/dV = dk_i/dv_i dv_i/dV.
        curvature_slope = np.stack([s.curvature_slope(volumes[:, j])
                                    for j, s in enumerate(self.numerics.segments)], axis=1)
        slopes = np.concatenate([slopes, curvature_slope * slopes[:, :n]], axis=1)
        values = np.concatenate([volumes, pressure[:, None], self.numerics.curvatures(volumes)],
                                axis=1)
        h = np.diff(total)[:, None]
        if flat:
            slopes = np.nan_to_num(slopes)
        rough = ~np.all(np.isfinite(slopes[:-1]) & np.isfinite(slopes[1:]), axis=1)
        # Hermite cubic per interval in t = (V - V_k) / h: c3 + t (c2 + t (c1 + t c0)).
        m0 = np.where(rough[:, None], 0.0, slopes[:-1] * h)
        m1 = np.where(rough[:, None], 0.0, slopes[1:] * h)
        y0, y1 = values[:-1], values[1:]
        coefficients = np.stack([2.0 * (y0 - y1) + m0 + m1, 3.0 * (y1 - y0) - 2.0 * m0 - m1,
                                 m0, y0])
        misses = np.zeros_like(rough)
        if not flat:
            unchecked = np.array([pair not in passed for pair in
                                  zip(total[:-1].tolist(), total[1:].tolist())])
            if unchecked.any():
                misses[unchecked] = yield from self._cubic_misses(
                    config, total[:-1][unchecked], np.diff(total)[unchecked],
                    pressure[:-1][unchecked], pressure[1:][unchecked],
                    coefficients[:, unchecked, :n])
        rough |= misses
        chord = np.stack([np.zeros_like(y0), np.zeros_like(y0), y1 - y0, y0])
        coefficients = np.where(rough[None, :, None], chord, coefficients)
        return total, volumes, pressure, coefficients, rough

    def _cubic_misses(self, config: tuple[Piece, ...], start: FloatArray, width: FloatArray,
                      p_start: FloatArray, p_end: FloatArray,
                      cubic: FloatArray
                      ) -> Generator[tuple[tuple[Piece, ...], FloatArray], FloatArray,
                                     NDArray[np.bool_]]:
        """
        Intervals whose volume cubic misses the exact state at their middle.

        An a-posteriori check: the exact state halfway in pressure against the cubic at the
        same total volume. Misses cluster next to folds and bifurcations.
        """
        middle = yield config, 0.5 * (p_start + p_end)
        t = ((middle.sum(axis=1) - start) / width)[:, None]
        guess = ((cubic[0] * t + cubic[1]) * t + cubic[2]) * t + cubic[3]
        return ~(np.max(np.abs(guess - middle), axis=1) <= CUBIC_TOLERANCE * self.numerics.v_scale)
