"""
The hardware-encoded inflation sequence: equilibria of connected segments and their history.

Segments share one fluid supply, so at quasi-static equilibrium all pressures are equal and the
volumes add up to the total V. Each segment's PV curve splits into monotone pieces; choosing one
piece per segment (a *configuration*) makes every volume a function of the common pressure p, so
the equilibrium set is a union of curves parametrised by p. This is the paper's "assembling
algorithm", done once per scene in :class:`EquilibriumMap`.

Stability is the positive definiteness of the Hessian of the stored energy, diag(dp_i/dv_i),
restricted to sum(dv_i) = 0. With k_i = dp_i/dv_i it holds exactly when at most one k_i is negative
and D = sum_i prod_{j != i} k_j > 0. Along a stable stretch the total volume is strictly monotone
in p, so each stable stretch is stored as a *branch*: a function of V on an interval. A branch ends
where it joins another stable branch (a segment passes a peak or valley: the walk continues), at a
fold (D = 0: the state snaps through to the stable state that the fluid exchange between the
segments reaches at that volume), or where a segment leaves its table (the end of the domain).

:class:`Tracker` follows any history of commanded volumes. It moves along the current branch and
applies the branch-end rules in order, so a jump from V_a to V_b lands where a walk through every
volume in between lands: a dropped command cannot change the physics. Looking up a state costs a
binary search on the branch's samples and a cubic; states next to a fold are solved exactly.
"""

from bisect import bisect_right
from dataclasses import dataclass, field
from functools import cached_property
import math
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.integrate import solve_ivp
from scipy.interpolate import PPoly
from scipy.optimize import brentq

from softseq_ros.physics.segments import Piece, Segment

FloatArray = NDArray[np.float64]

SEQUENCE_TYPES = ('none', 'partial', 'symmetric', 'asymmetric')

# Largest error of a branch's cubics at an interval's middle, as a fraction of the volume
# range, and how many times an interval that misses it is split in two at assembly.
CUBIC_TOLERANCE = 1e-10
REFINEMENTS = 16


class DomainError(ValueError):
    """A commanded volume outside what the segments' models cover."""


@dataclass(frozen=True)
class SnapEvent:
    """A snap-through: at ``injected`` the fluid redistributes from one state to another."""

    injected: float
    from_volumes: FloatArray
    to_volumes: FloatArray
    from_pressure: float
    to_pressure: float


@dataclass
class State:
    """The actuator at one commanded volume."""

    injected: float
    pressure: float
    volumes: FloatArray
    curvatures: FloatArray
    branch: int
    snaps: list[SnapEvent] = field(default_factory=list)


@dataclass
class Path:
    """States along a history of commanded volumes, one row per command."""

    injected: FloatArray
    pressure: FloatArray
    volumes: FloatArray
    curvatures: FloatArray
    branch: NDArray[np.int64]
    snap: NDArray[np.bool_]
    events: list[SnapEvent]


@dataclass
class EquilibriumCurve:
    """One configuration's equilibria (stable and unstable), for plotting."""

    injected: FloatArray
    volumes: FloatArray
    pressure: FloatArray
    stable: NDArray[np.bool_]


@dataclass
class _End:
    kind: str  # 'continue', 'snap' or 'limit'
    target: int = -1
    target_volumes: FloatArray | None = None


@dataclass
class _Branch:
    total: FloatArray       # (n,) strictly increasing total volume
    volumes: FloatArray     # (n, N)
    pressure: FloatArray    # (n,)
    pieces: tuple[Piece, ...]
    spline: PPoly | None = None      # (v_i, p, k_i) as piecewise cubics of V
    knots: list[float] | None = None  # total as a list, for scalar lookups
    rough: NDArray[np.bool_] | None = None  # per interval: solved exactly (next to folds)
    lower: _End = field(default_factory=lambda: _End('limit'))
    upper: _End = field(default_factory=lambda: _End('limit'))

    def __post_init__(self) -> None:
        self.any_rough = bool(self.rough is not None and self.rough.any())
        # Per interval, the cubics' coefficients as Python floats, filled on first use: the
        # per-command path evaluates 2N + 1 cubics, which plain floats do faster than numpy.
        self.rows: list[list[list[float]] | None] = []

    @cached_property
    def lo(self) -> float:
        return float(self.total[0])

    @cached_property
    def hi(self) -> float:
        return float(self.total[-1])


def _cofactor_sum(k: FloatArray) -> FloatArray:
    """D = sum_i prod_{j != i} k_j along the last axis, without dividing by a k that may be 0."""
    return np.sum(_cofactors(k), axis=-1)


def _cofactors(k: FloatArray) -> FloatArray:
    """W_i = prod_{j != i} k_j (proportional to 1/k_i, finite where a k is 0)."""
    ones = np.ones(k.shape[:-1] + (1,))
    prefix = np.concatenate([ones, np.cumprod(k[..., :-1], axis=-1)], axis=-1)
    suffix = np.concatenate([np.cumprod(k[..., :0:-1], axis=-1)[..., ::-1], ones], axis=-1)
    return prefix * suffix


def _soft_direction(k: FloatArray) -> FloatArray:
    """Unit redistribution (sum 0) along which the restricted Hessian diag(k) is softest."""
    n = k.size
    basis = np.linalg.qr(np.eye(n) - 1.0 / n, mode='reduced')[0][:, : n - 1]
    _, vectors = np.linalg.eigh(basis.T @ np.diag(k) @ basis)
    direction = basis @ vectors[:, 0]
    return direction / np.linalg.norm(direction)


class EquilibriumMap:
    """
    The equilibrium set of connected segments, assembled once.

    ``resolution`` is the number of samples that each segment's PV curve contributes across its
    whole volume range (more samples: smaller interpolation error, longer assembly).
    ``polish`` (default on) solves the states next to folds exactly; off, they are
    interpolated linearly between the branch's samples.
    """

    def __init__(self, segments: Sequence[Segment], resolution: int = 2000,
                 polish: bool = True) -> None:
        """Assemble the equilibrium set of ``segments`` (base to tip)."""
        if len(segments) < 2:
            raise ValueError(f'an actuator needs at least 2 segments, got {len(segments)}')
        if resolution < 16:
            raise ValueError(f'resolution must be >= 16, got {resolution}')
        self.segments = list(segments)
        self.resolution = int(resolution)
        self.polish = bool(polish)
        self.rest_volumes = np.array([s.rest_volume for s in self.segments])
        self.max_volumes = np.array([s.max_volume for s in self.segments])
        self.total_rest_volume = float(self.rest_volumes.sum())
        self.v_scale = float(np.sum(self.max_volumes - self.rest_volumes))
        self._pieces = [s.monotone_pieces() for s in self.segments]
        p_extent = max(max(abs(pc.p_at_lo), abs(pc.p_at_hi))
                       for pieces in self._pieces for pc in pieces)
        self.p_scale = p_extent if p_extent > 0.0 else 1.0
        self._k_scale = self.p_scale / self.v_scale
        self._tol_v = 1e-9 * self.v_scale
        self._curves: list[EquilibriumCurve] = []
        self.branches: list[_Branch] = []
        for config in self._configurations():
            self._assemble(config)
        if not self.branches:
            raise ValueError('these segments have no stable equilibrium at all')
        self._lo = np.array([b.lo for b in self.branches])
        self._hi = np.array([b.hi for b in self.branches])
        for index in range(len(self.branches)):
            self._connect(index)
        self.start_branch = int(np.argmin(self._lo))
        self.injected_range = (self.branches[self.start_branch].lo - self.total_rest_volume,
                               self._inflation_limit() - self.total_rest_volume)

    # ------------------------------------------------------------------ assembly

    def _configurations(self) -> list[tuple[Piece, ...]]:
        """Piece tuples that can hold a stable equilibrium: at most one falling piece."""
        found = []

        def extend(prefix: tuple[Piece, ...], p_lo: float, p_hi: float, falling: int) -> None:
            if len(prefix) == len(self._pieces):
                found.append(prefix)
                return
            for piece in self._pieces[len(prefix)]:
                lo, hi = max(p_lo, piece.p_min), min(p_hi, piece.p_max)
                fall = falling + (piece.direction < 0)
                if lo <= hi and fall <= 1:
                    extend(prefix + (piece,), lo, hi, fall)

        extend((), -math.inf, math.inf, 0)
        return found

    def _volumes_at(self, config: tuple[Piece, ...], p: FloatArray) -> FloatArray:
        return np.stack([seg.invert(piece, p) for seg, piece in zip(self.segments, config)],
                        axis=-1)

    def _stiffness(self, config: tuple[Piece, ...], volumes: FloatArray) -> FloatArray:
        """Scaled dp/dv, clipped to the sign its piece promises (exactly 0 on a flat piece)."""
        columns = []
        for i, (seg, piece) in enumerate(zip(self.segments, config)):
            v = volumes[..., i]
            k = seg.stiffness(v) / self._k_scale
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

    def _assemble(self, config: tuple[Piece, ...]) -> None:
        flats = [i for i, pc in enumerate(config) if pc.direction == 0]
        if flats:
            self._assemble_plateau(config, flats)
            return
        p_lo = max(pc.p_min for pc in config)
        p_hi = min(pc.p_max for pc in config)
        if not p_hi > p_lo:
            return
        grids = [np.array([p_lo, p_hi])]
        for seg, piece in zip(self.segments, config):
            count = max(32, int(math.ceil(self.resolution * seg.arclength_share(piece))))
            # The model's own knots are samples too, so the cubics never straddle a kink.
            knots = seg.knots()
            knots = knots[(knots > piece.v_lo) & (knots < piece.v_hi)]
            p_samples = seg.pressure(np.concatenate([seg.arclength_samples(piece, count),
                                                     knots]))
            grids.append(p_samples[(p_samples > p_lo) & (p_samples < p_hi)])
        p = np.unique(np.concatenate(grids))
        volumes = self._volumes_at(config, p)
        k = self._stiffness(config, volumes)
        d = _cofactor_sum(k)
        stable = d > 0.0
        total = volumes.sum(axis=1)
        self._curves.append(EquilibriumCurve(total - self.total_rest_volume, volumes, p, stable))
        if not stable.any():
            return
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
            run_v = self._volumes_at(config, run_p)
            self._add_branch(run_v, run_p, config)

    def _fold(self, config: tuple[Piece, ...], p_a: float, p_b: float) -> float:
        """Pressure where D = 0 between two samples of opposite stability."""
        def cofactor_sum(p: float) -> float:
            v = self._volumes_at(config, np.array([p]))
            return float(_cofactor_sum(self._stiffness(config, v))[0])

        d_a, d_b = cofactor_sum(p_a), cofactor_sum(p_b)
        if d_a == 0.0:
            return p_a
        if d_b == 0.0 or d_a * d_b > 0.0:
            return p_b
        return brentq(cofactor_sum, p_a, p_b, xtol=1e-14 * self.p_scale, rtol=1e-15)

    def _assemble_plateau(self, config: tuple[Piece, ...], flats: list[int]) -> None:
        """
        Flat pieces at one common pressure: the flat segments absorb the volume.

        Several flat segments at the same pressure are neutral (any split is an equilibrium): they
        fill one after the other, base first, and empty in the reverse order, so the path is
        deterministic and the same both ways.
        """
        p_flat = config[flats[0]].p_at_lo
        if any(abs(config[i].p_at_lo - p_flat) > 1e-12 * self.p_scale for i in flats):
            return
        others = [i for i in range(len(config)) if i not in flats]
        base = np.zeros(len(config))
        for i in others:
            piece = config[i]
            if not piece.p_min <= p_flat <= piece.p_max or piece.direction < 0:
                return
            base[i] = self.segments[i].invert(piece, np.array([p_flat]))[0]
        k_others = self._stiffness(config, base[None, :])[0, others]
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
            self._curves.append(EquilibriumCurve(volumes.sum(axis=1) - self.total_rest_volume,
                                                 volumes, pressure, np.ones(lo_hi.size, bool)))
            self._add_branch(volumes, pressure, config)

    def _add_branch(self, volumes: FloatArray, pressure: FloatArray,
                    config: tuple[Piece, ...]) -> None:
        """
        Store one stable stretch as a branch: Hermite cubics of the state in total volume.

        Every interval is checked against the exact state at its middle and split there where
        the cubic misses it, a few times over: next to a fold or bifurcation the state goes like
        a square root of the volume, so the samples crowd there. The last interval touching
        the singular point stays 'rough', now tiny, and its states are solved exactly.
        """
        flat = any(pc.direction == 0 for pc in config)
        passed: set[tuple[float, float]] = set()
        fitted = self._fit(volumes, pressure, config, flat, passed)
        for _ in range(0 if flat else REFINEMENTS):
            if fitted is None:
                return
            total, volumes, pressure, _, split = fitted
            if not split.any():
                break
            passed.update(zip(total[:-1][~split].tolist(), total[1:][~split].tolist()))
            middle = 0.5 * (pressure[:-1][split] + pressure[1:][split])
            fitted = self._fit(np.concatenate([volumes, self._volumes_at(config, middle)]),
                               np.concatenate([pressure, middle]), config, flat, passed)
        if fitted is None:
            return
        total, volumes, pressure, coefficients, rough = fitted
        h = np.diff(total)[:, None]
        # From powers of t = (V - V_k) / h to powers of (V - V_k), as PPoly evaluates them.
        coefficients = coefficients / h[None, :, :] ** np.arange(3, -1, -1)[:, None, None]
        spline = PPoly(coefficients, total, extrapolate=True)
        self.branches.append(_Branch(total, volumes, pressure, config, spline, total.tolist(),
                                     rough))

    def _fit(self, volumes: FloatArray, pressure: FloatArray, config: tuple[Piece, ...],
             flat: bool, passed: set[tuple[float, float]]) -> tuple | None:
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
        k = self._stiffness(config, volumes)
        d = _cofactor_sum(k)
        with np.errstate(divide='ignore', invalid='ignore'):
            # dv_i/dV = prod_{j != i} k_j / D and dp/dV = prod k / D, both finite off folds.
            slopes = np.concatenate([_cofactors(k), np.prod(k, axis=1, keepdims=True)
                                     * self._k_scale], axis=1) / d[:, None]
        # Curvatures ride along: dk_i/dV = dk_i/dv_i dv_i/dV.
        curvature_slope = np.stack([s.curvature_slope(volumes[:, j])
                                    for j, s in enumerate(self.segments)], axis=1)
        slopes = np.concatenate([slopes, curvature_slope * slopes[:, :n]], axis=1)
        values = np.concatenate([volumes, pressure[:, None], self.curvatures(volumes)], axis=1)
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
                misses[unchecked] = self._cubic_misses(
                    config, total[:-1][unchecked], np.diff(total)[unchecked],
                    pressure[:-1][unchecked], pressure[1:][unchecked],
                    coefficients[:, unchecked, :n])
        rough |= misses
        chord = np.stack([np.zeros_like(y0), np.zeros_like(y0), y1 - y0, y0])
        coefficients = np.where(rough[None, :, None], chord, coefficients)
        return total, volumes, pressure, coefficients, rough

    def _cubic_misses(self, config: tuple[Piece, ...], start: FloatArray, width: FloatArray,
                      p_start: FloatArray, p_end: FloatArray,
                      cubic: FloatArray) -> NDArray[np.bool_]:
        """
        Intervals whose volume cubic misses the exact state at their middle.

        An a-posteriori check: the exact state halfway in pressure against the cubic at the
        same total volume. Misses cluster next to folds and bifurcations.
        """
        middle = self._volumes_at(config, 0.5 * (p_start + p_end))
        t = ((middle.sum(axis=1) - start) / width)[:, None]
        guess = ((cubic[0] * t + cubic[1]) * t + cubic[2]) * t + cubic[3]
        return ~(np.max(np.abs(guess - middle), axis=1) <= CUBIC_TOLERANCE * self.v_scale)

    # ------------------------------------------------------------------ connections

    def _connect(self, index: int) -> None:
        branch = self.branches[index]
        branch.upper = self._end_rule(index, upward=True)
        branch.lower = self._end_rule(index, upward=False)

    def _end_rule(self, index: int, upward: bool) -> _End:
        branch = self.branches[index]
        end = -1 if upward else 0
        v_end, total_end = branch.volumes[end], branch.total[end]
        candidates = []
        for j, other in enumerate(self.branches):
            if j == index:
                continue
            start = 0 if upward else -1
            if (abs(other.total[start] - total_end) <= self._tol_v
                    and np.max(np.abs(other.volumes[start] - v_end)) <= self._tol_v):
                candidates.append(j)
        if candidates:
            # A bifurcation (identical segments) offers several continuations: the tie is broken
            # deterministically, the segment nearest the base taking the larger share.
            step = 1 if upward else -2
            best = max(candidates, key=lambda j: tuple(self.branches[j].volumes[step]))
            return _End('continue', best)
        # A segment at the edge of its model's range ends the domain: going on would take it
        # outside its table (any continuation inside the range was found above).
        if self._at_edge(v_end):
            return _End('limit')
        snap = self._snap(index, upward)
        if snap is None:
            return _End('limit')
        return _End('snap', *snap)

    def _at_edge(self, volumes: FloatArray) -> bool:
        return bool(np.any(volumes >= self.max_volumes - self._tol_v)
                    or np.any(volumes <= self.rest_volumes + self._tol_v))

    def _snap(self, index: int, upward: bool) -> tuple[int, FloatArray] | None:
        """
        Where the fold at a branch end snaps to, at the same total volume.

        The fluid redistributes along the gradient flow of the stored energy on sum v = V with
        equal conductances, dv_i/dt = -(p_i - mean p): the state rolls downhill from the fold to
        the stable equilibrium whose basin it is in. The flow starts a small step off the fold,
        on the side the flow itself points to. None when the flow leaves a segment's range.
        """
        branch = self.branches[index]
        end = -1 if upward else 0
        v_fold = branch.volumes[end]
        total = float(branch.total[end])
        k = self._stiffness(branch.pieces, v_fold[None, :])[0]
        null = _soft_direction(k)
        eps = 1e-6 * self.v_scale

        def drift(v: FloatArray) -> float:
            p = np.array([s.pressure(x) for s, x in zip(self.segments, v)])
            return float(-np.dot(p - p.mean(), null))

        direction = math.copysign(1.0, drift(v_fold + eps * null) + drift(v_fold - eps * null))
        start = v_fold + direction * eps * null
        landed = self._flow(start)
        if self._at_edge(landed):
            return None
        target = self._nearest_branch(total, landed, exclude=index)
        return target, self.lookup(target, np.array([total]))[0][0]

    def _flow(self, start: FloatArray) -> FloatArray:
        """
        Integrate the redistribution flow from ``start`` until it comes to rest.

        Scaled by the volume and pressure ranges; stiff near walls, so Radau with the exact
        Jacobian, d(dv_i/dt)/dv_j = k_j / N - k_i delta_ij. The flow only has to reach the
        right basin (the landing state is then read off its branch exactly), so the
        tolerances are modest and the horizon grows until the state is balanced and stable.
        """
        scale_v, scale_p = self.v_scale, self.p_scale
        lo, hi = self.rest_volumes, self.max_volumes
        n = len(self.segments)

        def rhs(_t: float, y: FloatArray) -> FloatArray:
            v = np.clip(y * scale_v, lo, hi)
            p = np.array([s.pressure(x) for s, x in zip(self.segments, v)]) / scale_p
            return -(p - p.mean())

        def jacobian(_t: float, y: FloatArray) -> FloatArray:
            v = np.clip(y * scale_v, lo, hi)
            k = np.array([s.stiffness(x) for s, x in zip(self.segments, v)]) / self._k_scale
            return np.outer(np.ones(n), k) / n - np.diag(k)

        def leaves_range(_t: float, y: FloatArray) -> float:
            # Crosses zero when a segment leaves its model's range: the domain ends there.
            v = y * scale_v
            return float(np.min(np.minimum(v - lo, hi - v)) / scale_v)

        leaves_range.terminal = True
        y = start / scale_v
        t = 0.0
        for horizon in np.logspace(2, 14, 13):
            sol = solve_ivp(rhs, (t, horizon), y, method='Radau', jac=jacobian, rtol=1e-7,
                            atol=1e-12, events=leaves_range)
            y, t = sol.y[:, -1], horizon
            if sol.status == 1:
                break
            # At rest means balanced pressures at a stable state: a fold is balanced too.
            if np.max(np.abs(rhs(t, y))) < 1e-9 and self._is_stable(y * scale_v):
                break
        return np.clip(y * scale_v, lo, hi)

    def _is_stable(self, volumes: FloatArray) -> bool:
        k = np.array([s.stiffness(x) for s, x in zip(self.segments, volumes)]) / self._k_scale
        return bool(np.sum(k < 0.0) <= 1 and _cofactor_sum(k) > 1e-6)

    def _nearest_branch(self, total: float, volumes: FloatArray, exclude: int) -> int:
        best, best_distance = -1, math.inf
        for j, other in enumerate(self.branches):
            if j == exclude or not other.lo - self._tol_v <= total <= other.hi + self._tol_v:
                continue
            state = self.lookup(j, np.array([min(max(total, other.lo), other.hi)]))[0][0]
            distance = float(np.max(np.abs(state - volumes)))
            if distance < best_distance:
                best, best_distance = j, distance
        if best < 0 or best_distance > 1e-3 * self.v_scale:
            raise RuntimeError(f'snap-through at total volume {total:.9g} m^3 found no stable '
                               f'state to land on (nearest {best_distance:.3g} m^3 away)')
        return best

    def _inflation_limit(self) -> float:
        index, seen = self.start_branch, set()
        while index not in seen:
            seen.add(index)
            upper = self.branches[index].upper
            if upper.kind == 'limit':
                break
            index = upper.target
        return self.branches[index].hi

    # ------------------------------------------------------------------ lookups

    def lookup(self, index: int, total: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Volumes (n, N) and pressures (n,) on branch ``index`` at total volumes ``total``."""
        values = self.evaluate(index, total)
        n = len(self.segments)
        return values[:, :n], values[:, n]

    def evaluate(self, index: int, total: FloatArray) -> FloatArray:
        """
        States on branch ``index`` at total volumes ``total``: rows (v_1..v_N, p, k_1..k_N).

        Cubic Hermite interpolation between the branch's exact samples, with the exact slopes
        dv_i/dV, dp/dV and dk_i/dV: no segment model is evaluated. Only intervals next to a
        fold, where the state varies like a square root of the volume, are solved exactly.
        """
        branch = self.branches[index]
        total = np.clip(np.asarray(total, dtype=float), branch.lo, branch.hi)
        values = branch.spline(total)
        if self.polish and branch.any_rough:
            interval = np.clip(np.searchsorted(branch.total, total, side='right') - 1, 0,
                               branch.total.size - 2)
            rows = np.flatnonzero(branch.rough[interval])
            if rows.size:
                values[rows] = self._polish(branch, total[rows], values[rows])
        return values

    def evaluate_one(self, index: int, total: float) -> FloatArray:
        """One state (v_1..v_N, p, k_1..k_N) on branch ``index``: the per-command fast path."""
        return np.array(self.values_at(index, total))

    def values_at(self, index: int, total: float) -> list[float]:
        """``evaluate_one`` as a list of Python floats (for callers that want floats)."""
        branch = self.branches[index]
        total = min(max(total, branch.lo), branch.hi)
        i = min(max(bisect_right(branch.knots, total) - 1, 0), len(branch.knots) - 2)
        if self.polish and branch.rough[i]:
            return self.evaluate(index, np.array([total]))[0].tolist()
        rows = branch.rows
        if not rows:
            rows.extend([None] * (len(branch.knots) - 1))
        coefficients = rows[i]
        if coefficients is None:
            coefficients = rows[i] = branch.spline.c[:, i, :].T.tolist()
        dt = total - branch.knots[i]
        # The same Horner steps as numpy's on the arrays, so the same numbers.
        return [((a * dt + b) * dt + c) * dt + d for a, b, c, d in coefficients]

    def _polish(self, branch: _Branch, total: FloatArray, values: FloatArray) -> FloatArray:
        """
        Exact states next to a fold or bifurcation, where no cubic in V follows the state.

        Inside one sample interval the total volume is monotone in the common pressure, with
        dV/dp = sum 1/k_i. A safeguarded Newton on the pressure (a halving where the step would
        leave the interval), with every segment's volume from its own monotone piece, cannot
        fail and reaches round-off in a few steps.
        """
        i = np.clip(np.searchsorted(branch.total, total, side='right') - 1, 0,
                    branch.total.size - 2)
        # 'below' and 'above' are the pressures whose totals are below and above the target.
        below, above = branch.pressure[i].copy(), branch.pressure[i + 1].copy()
        t0, t1 = branch.total[i], branch.total[i + 1]
        pressure = below + (above - below) * (total - t0) / (t1 - t0)
        for _ in range(64):
            volumes = self._volumes_at(branch.pieces, pressure)
            excess = volumes.sum(axis=1) - total
            short = excess < 0.0
            below = np.where(short, pressure, below)
            above = np.where(short, above, pressure)
            done = (np.abs(excess) <= 4.0 * np.finfo(float).eps * self.v_scale) | (
                np.abs(above - below) <= 4.0 * np.spacing(np.abs(above)))
            if np.all(done):
                break
            k = np.stack([s.stiffness(volumes[:, j]) for j, s in enumerate(self.segments)],
                         axis=1)
            with np.errstate(divide='ignore', invalid='ignore'):
                step = pressure - excess / np.sum(1.0 / k, axis=1)
            inside = (np.isfinite(step) & (step > np.minimum(below, above))
                      & (step < np.maximum(below, above)))
            pressure = np.where(done, pressure, np.where(inside, step, 0.5 * (below + above)))
        volumes = self._volumes_at(branch.pieces, pressure)
        # The bisection leaves the volume balance off by round-off; the largest volume takes it.
        largest = np.argmax(volumes, axis=1)
        volumes[np.arange(volumes.shape[0]), largest] += total - volumes.sum(axis=1)
        return np.concatenate([volumes, pressure[:, None], self.curvatures(volumes)], axis=1)

    def curvatures(self, volumes: FloatArray) -> FloatArray:
        """Per-segment curvature for volumes (n, N), in 1/m."""
        return np.stack([s.curvature(volumes[:, j]) for j, s in enumerate(self.segments)],
                        axis=1)

    def equilibrium_set(self) -> list[EquilibriumCurve]:
        """Every configuration's equilibria, stable and unstable (Fig. 1B / 4B)."""
        return list(self._curves)

    def branch_at(self, injected: float, volumes: ArrayLike | None = None) -> int:
        """
        The stable branch holding ``injected``, nearest to ``volumes`` when several do.

        This lets a restarted node resume on the branch its last published state was on.
        """
        total = float(injected) + self.total_rest_volume
        holding = np.flatnonzero((self._lo - self._tol_v <= total) & (total <= self._hi
                                                                     + self._tol_v))
        if holding.size == 0:
            raise DomainError(f'injected volume {injected:.6g} m^3 is outside every stable '
                              f'branch ({self.injected_range[0]:.6g} to '
                              f'{self.injected_range[1]:.6g} m^3 on inflation)')
        if volumes is None or holding.size == 1:
            return int(holding[0])
        target = np.asarray(volumes, dtype=float)
        distances = [np.max(np.abs(self.lookup(int(j), np.array([total]))[0][0] - target))
                     for j in holding]
        return int(holding[int(np.argmin(distances))])


class Tracker:
    """Follows a history of commanded injected volumes on the equilibrium set."""

    def __init__(self, emap: EquilibriumMap, injected: float | None = None,
                 volumes: ArrayLike | None = None) -> None:
        """Start at rest, or at ``injected`` on the branch nearest ``volumes`` (a resume)."""
        self.emap = emap
        if injected is not None and volumes is not None:
            self.branch = emap.branch_at(injected, volumes)
            self.total = float(injected) + emap.total_rest_volume
            return
        self.branch = emap.start_branch
        self.total = emap.branches[self.branch].lo
        if injected is not None:
            self._walk(float(injected) + emap.total_rest_volume)

    def _walk(self, total: float) -> list[SnapEvent]:
        """
        Move to ``total``, applying branch-end rules; return the snaps on the way.

        A command beyond the domain raises DomainError and leaves the state as it was.
        """
        emap = self.emap
        events: list[SnapEvent] = []
        before = self.branch, self.total
        for _ in range(4 * len(emap.branches) + 4):
            branch = emap.branches[self.branch]
            if branch.lo <= total <= branch.hi:
                self.total = total
                return events
            upward = total > branch.hi
            end = branch.upper if upward else branch.lower
            edge = branch.hi if upward else branch.lo
            if end.kind == 'limit':
                if abs(total - edge) <= emap._tol_v:
                    # The domain's edge itself (reached up to round-off, e.g. its own
                    # injected_range) is inside it: stay on the edge.
                    self.total = edge
                    return events
                self.branch, self.total = before
                raise DomainError(
                    f'injected volume {total - emap.total_rest_volume:.6g} m^3 is beyond what '
                    f'the segment models cover on this branch (it ends at '
                    f'{edge - emap.total_rest_volume:.6g} m^3)')
            if end.kind == 'snap':
                from_v = branch.volumes[-1 if upward else 0]
                from_p = float(branch.pressure[-1 if upward else 0])
                to_v, to_p = emap.lookup(end.target, np.array([edge]))
                events.append(SnapEvent(edge - emap.total_rest_volume, from_v.copy(),
                                        to_v[0], from_p, float(to_p[0])))
            self.branch = end.target
            self.total = edge
        raise RuntimeError('branch-end rules form a cycle; the equilibrium set is inconsistent')

    @property
    def state(self) -> State:
        """The current state."""
        values = self.emap.evaluate_one(self.branch, self.total)
        n = len(self.emap.segments)
        return State(self.total - self.emap.total_rest_volume, float(values[n]), values[:n],
                     values[n + 1:], self.branch)

    def step(self, injected: float) -> State:
        """Go to a commanded injected volume; the state reports the snaps on the way."""
        snaps = self.move(injected)
        state = self.state
        state.snaps = snaps
        return state

    def move(self, injected: float) -> list[SnapEvent]:
        """
        ``step`` without building the State: go there, return the snaps on the way.

        ``emap.values_at(tracker.branch, tracker.total)`` then gives the state's numbers.
        """
        if not math.isfinite(injected):
            raise DomainError(f'commanded injected volume must be finite, got {injected}')
        return self._walk(float(injected) + self.emap.total_rest_volume)

    def sweep(self, injected: ArrayLike) -> Path:
        """Follow a whole history at once (the same rules as repeated ``step``)."""
        emap = self.emap
        commands = np.asarray(injected, dtype=float).ravel()
        if not np.all(np.isfinite(commands)):
            bad = int(np.flatnonzero(~np.isfinite(commands))[0])
            raise DomainError(f'commanded injected volume in row {bad} is not finite')
        totals = commands + emap.total_rest_volume
        n = totals.size
        branch_ids = np.empty(n, dtype=np.int64)
        snap = np.zeros(n, dtype=bool)
        events: list[SnapEvent] = []
        i, window = 0, 256
        while i < n:
            branch = emap.branches[self.branch]
            chunk = totals[i:i + window]
            outside = np.flatnonzero((chunk < branch.lo) | (chunk > branch.hi))
            if outside.size == 0:
                branch_ids[i:i + chunk.size] = self.branch
                self.total = float(chunk[-1])
                i += chunk.size
                window = min(window * 2, 1 << 16)
                continue
            j = int(outside[0])
            branch_ids[i:i + j] = self.branch
            new_events = self._walk(float(totals[i + j]))
            if new_events:
                snap[i + j] = True
                events.extend(new_events)
            branch_ids[i + j] = self.branch
            i += j + 1
            window = 256
        segments = len(emap.segments)
        if np.all(branch_ids == branch_ids[0]) if n else True:
            values = (emap.evaluate(int(branch_ids[0]), self._on_branch(int(branch_ids[0]),
                                                                        totals)) if n
                      else np.empty((0, 2 * segments + 1)))
        else:
            values = np.empty((n, 2 * segments + 1))
            for b in np.unique(branch_ids):
                rows = np.flatnonzero(branch_ids == b)
                values[rows] = emap.evaluate(int(b), self._on_branch(int(b), totals[rows]))
        return Path(commands, values[:, segments], values[:, :segments],
                    values[:, segments + 1:], branch_ids, snap, events)

    def _on_branch(self, index: int, totals: FloatArray) -> FloatArray:
        """Totals clipped to a branch: a command at a domain edge may pass it by round-off."""
        branch = self.emap.branches[index]
        return np.clip(totals, branch.lo, branch.hi)


def classify(emap: EquilibriumMap, samples: int = 4001) -> str:
    """
    The paper's sequence type of an actuator (Fig. 1): none, partial, symmetric or asymmetric.

    Inflate over the whole range and deflate back. A snap-through or a deflation path that
    differs from the inflation path is *asymmetric*. Otherwise, with r_i = dv_i/dV the share of
    the inflow each segment takes: some segment losing volume while the total grows
    (r_i < -0.02) is *symmetric* (the inflation turns from one segment to another); a share that
    changes by more than 0.25 over the range is *partial* (one segment takes over); otherwise
    *none*.
    """
    lo, hi = emap.injected_range
    up = np.linspace(lo, hi, samples)
    inflation = Tracker(emap).sweep(up)
    deflation = Tracker(emap, injected=hi, volumes=inflation.volumes[-1]).sweep(up[::-1])
    gap = np.max(np.abs(inflation.volumes - deflation.volumes[::-1]))
    if inflation.events or deflation.events or gap > 1e-6 * emap.v_scale:
        return 'asymmetric'
    share = np.diff(inflation.volumes, axis=0) / np.diff(up)[:, None]
    if np.min(share) < -0.02:
        return 'symmetric'
    if np.max(np.ptp(share, axis=0)) > 0.25:
        return 'partial'
    return 'none'

