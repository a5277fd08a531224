"""
The numbers every stage of the equilibrium map shares: pieces, scales, inversions, stiffnesses.

A segment's volume on one monotone piece of its curve at a given pressure (the inversion) is the
map's innermost operation. :meth:`SegmentNumerics.invert_rows` does it by a safeguarded Newton
iteration, for many pressures at once and elementwise: a volume does not depend on which other
pressures were inverted with it, so stages that batch their inversions differently get the same
numbers. Once a piece has been sampled, every later inversion on it starts between the two known
volumes around its pressure (:meth:`SegmentNumerics.remember_inversions`).
"""

from typing import Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from softseq_ros.segments.models import Piece, Segment, polynomial_at
from softseq_ros.tolerances import DEFAULT_TOLERANCES, ConvergenceLog, Tolerances

FloatArray = NDArray[np.float64]
EPS = float(np.finfo(float).eps)


def cofactor_sum(k: FloatArray) -> FloatArray:
    """D = sum_i prod_{j != i} k_j along the last axis, without dividing by a k that may be 0."""
    return np.sum(cofactors(k), axis=-1)


def cofactors(k: FloatArray) -> FloatArray:
    """W_i = prod_{j != i} k_j (proportional to 1/k_i, finite where a k is 0)."""
    if k.ndim == 2 and k.shape[0] > 64:
        # Many rows: the running products along the segments as whole-column products (the
        # same products in the same order; numpy's cumprod along a short last axis is slow).
        columns = k.T
        prefix = np.ones(columns.shape)
        suffix = np.ones(columns.shape)
        for i in range(1, columns.shape[0]):
            prefix[i] = prefix[i - 1] * columns[i - 1] if i > 1 else columns[0]
            j = columns.shape[0] - 1 - i
            suffix[j] = suffix[j + 1] * columns[j + 1] if i > 1 else columns[-1]
        return np.ascontiguousarray((prefix * suffix).T)
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
        self._inverted: dict[tuple[int, int], tuple[FloatArray, FloatArray]] = {}
        self._least_stiffness: dict[int, FloatArray | None] = {}
        self._stiffness_extremes: dict[int, FloatArray] = {}
        self._piece_ids = [{piece: a for a, piece in enumerate(pieces)} for pieces in self.pieces]
        # Every piece's numbers in one array (6, N, most pieces), for per-element lookups.
        most = max(len(pieces) for pieces in self.pieces)
        self._piece_table = np.full((6, len(self.segments), most), np.nan)
        ulps = tolerances.round_off_ulps
        for i, pieces in enumerate(self.pieces):
            for a, pc in enumerate(pieces):
                self._piece_table[:, i, a] = (
                    pc.v_lo, pc.v_hi, pc.p_at_lo, pc.p_at_hi, float(pc.direction),
                    ulps * EPS * max(abs(pc.p_at_lo), abs(pc.p_at_hi), 1e-300))
        # Pressure and stiffness of each segment for arrays of volumes inside its range: for a
        # table, scipy's PPoly calls (the numbers of polynomial_at, and faster for arrays).
        self._curve = [(seg.pressure, seg.stiffness) for seg in self.segments]
        self._side_by_side = _SideBySideCubics(self.segments)

    def piece_indices(self, config: tuple[Piece, ...]) -> list[int]:
        """The index of each segment's piece of ``config`` among the segment's pieces."""
        return [self._piece_ids[i][piece] for i, piece in enumerate(config)]

    def states_at(self, piece_index: NDArray[np.intp], p: FloatArray,
                  stiffness: bool = True) -> tuple[FloatArray, FloatArray | None]:
        """
        Volumes and scaled stiffnesses (m, N) at pressures ``p`` (m,), each row on its own pieces.

        ``piece_index`` (m, N) gives each row's piece per segment (:meth:`piece_indices`).
        """
        volumes = self.invert_rows(piece_index, p)
        if not stiffness:
            return volumes, None
        return volumes, self.stiffness_at(piece_index, volumes)

    def stiffness_at(self, piece_index: NDArray[np.intp], volumes: FloatArray) -> FloatArray:
        """Scaled stiffnesses (m, N) at volumes (m, N), each row on its own pieces."""
        return np.stack([self._element_stiffness(i, piece_index[:, i], volumes[:, i])
                         for i in range(volumes.shape[1])], axis=1)

    def invert_rows(self, piece_index: NDArray[np.intp], p: FloatArray,
                    bracket: tuple[FloatArray, FloatArray, FloatArray] | None = None
                    ) -> FloatArray:
        """
        :meth:`invert` of whole rows: each segment's volume (m, N) at pressures ``p`` (m,).

        ``piece_index`` (m, N) gives each row's piece per segment; ``bracket`` (lo, hi,
        start), each (m, N), as :meth:`invert`'s.
        """
        volumes = np.empty(piece_index.shape)
        converged = True
        for i in range(piece_index.shape[1]):
            guess = None if bracket is None else tuple(a[:, i] for a in bracket)
            volumes[:, i], done = self._invert_segment(i, piece_index[:, i], p, guess)
            converged &= done
        self.convergence.record('inversion', converged)
        return volumes

    def _invert_segment(self, index: int, piece: NDArray[np.intp], goal: FloatArray,
                        bracket: tuple[FloatArray, FloatArray, FloatArray] | None
                        ) -> tuple[FloatArray, bool]:
        """:meth:`invert` for elements of one segment; whether all converged."""
        v_lo, v_hi, p_lo, p_hi, sign, floor = self._piece_table[:, index][:, piece]
        if bracket is None:
            bracket = self._sampled_bracket(index, piece, goal)
        if bracket is None:
            lo, hi, x = self._piece_wide(index, piece, goal)
            pressure, stiffness = self._curve[index]
            within = None
        else:
            lo, hi, x = (np.array(a, dtype=float) for a in bracket)
            within = self._curve_within(index, lo, hi)
        ulps = self.tolerances.round_off_ulps
        active = np.arange(goal.size)
        for _ in range(self.tolerances.inversion_steps):
            if active.size == 0:
                break
            xa, sa = x[active], sign[active]
            if within is not None:
                p_a = within[0](xa, active)
            else:
                p_a = pressure(xa)
            residual = sa * (p_a - goal[active])
            above = residual > 0.0
            ha = np.where(above, xa, hi[active])
            la = np.where(above, lo[active], xa)
            going = ~((np.abs(residual) <= floor[active]) | (
                ha - la <= ulps * np.spacing(np.maximum(np.abs(ha), 1e-300))))
            active, xa, sa, la, ha = (active[going], xa[going], sa[going], la[going],
                                      ha[going])
            with np.errstate(divide='ignore', invalid='ignore'):
                slope = within[1](xa, active) if within is not None else stiffness(xa)
                step = xa - residual[going] / (sa * slope)
            inside = np.isfinite(step) & (step > la) & (step < ha)
            x[active] = np.where(inside, step, 0.5 * (la + ha))
            lo[active], hi[active] = la, ha
        x = np.where(goal == p_lo, v_lo, x)
        return np.where(goal == p_hi, v_hi, x), active.size == 0

    def invert_piece(self, index: int, piece: Piece, p: FloatArray) -> FloatArray:
        """Volumes of segment ``index`` on ``piece`` at pressures ``p`` (:meth:`invert_rows`)."""
        indices = np.full(np.shape(p), self._piece_ids[index][piece], dtype=np.intp)
        volumes, converged = self._invert_segment(index, indices, np.asarray(p, dtype=float),
                                                  None)
        self.convergence.record('inversion', converged)
        return volumes

    def remember_inversions(self, index: int, piece: Piece, p: FloatArray,
                            volumes: FloatArray) -> None:
        """
        Volumes of segment ``index`` on ``piece`` already inverted at sorted pressures ``p``.

        Later inversions on that piece start from the two of them around their pressure: the
        volume lies between theirs (the piece is monotone), so the safeguarded Newton stops
        after two or three steps instead of narrowing the whole piece first.
        """
        if p.size >= 2:
            self._inverted[(index, self._piece_ids[index][piece])] = (p, volumes)

    def _piece_wide(self, index: int, piece: NDArray[np.intp], goal: FloatArray
                    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(lo, hi, start) per element: its piece's ends, and linear in pressure between them."""
        v_lo, v_hi, p_lo, p_hi, _, _ = self._piece_table[:, index][:, piece]
        span = p_hi - p_lo
        with np.errstate(divide='ignore', invalid='ignore'):
            start = v_lo + (v_hi - v_lo) * np.clip((goal - p_lo) / span, 0.0, 1.0)
        return v_lo, v_hi, np.where(span != 0.0, start, 0.5 * (v_lo + v_hi))

    def _sampled_bracket(self, index: int, piece: NDArray[np.intp], goal: FloatArray
                         ) -> tuple[FloatArray, FloatArray, FloatArray] | None:
        """(lo, hi, start) per element from :meth:`remember_inversions`; None: none known."""
        found = [(a, self._inverted.get((index, a)))
                 for a in np.flatnonzero(np.bincount(piece)).tolist()]
        if not any(known is not None for _, known in found):
            return None
        lo, hi, start = self._piece_wide(index, piece, goal)
        for a, known in found:
            if known is None:
                continue
            p, volumes = known
            rows = np.flatnonzero(piece == a) if len(found) > 1 else slice(None)
            target = goal[rows]
            k = np.clip(np.searchsorted(p, target, side='right') - 1, 0, p.size - 2)
            below, above = volumes[k], volumes[k + 1]
            rise = p[k + 1] - p[k]
            with np.errstate(divide='ignore', invalid='ignore'):
                share = np.where(rise > 0.0, np.clip((target - p[k]) / rise, 0.0, 1.0), 0.0)
            start[rows] = below + (above - below) * share
            lo[rows] = np.minimum(below, above)
            hi[rows] = np.maximum(below, above)
        return lo, hi, start

    def _curve_within(self, index: int, lo: FloatArray, hi: FloatArray) -> tuple:
        """
        Pressure and stiffness of segment ``index`` for volumes known to stay in [lo, hi].

        For a table, each bracket inside one interval of its rows has its cubic evaluated
        there directly (:func:`~softseq_ros.segments.models.polynomial_at`, without a search
        per call); a bracket across a row (by round-off, its end at a row) goes through the
        model's calls.
        """
        cubics = self.segments[index].pressure_cubics()
        if cubics is None or lo.size == 0:
            pressure, stiffness = self._curve[index]
            return (lambda v, rows: pressure(v)), (lambda v, rows: stiffness(v))
        breaks, pressure_c, stiffness_c = cubics
        interval = np.clip(np.searchsorted(breaks, lo, side='right') - 1, 0, breaks.size - 2)
        across = ~(hi <= breaks[interval + 1])
        some_across = bool(across.any())
        left = breaks[interval]
        pressure, stiffness = self._curve[index]

        def on_interval(coefficients: FloatArray, model: Callable[[FloatArray], FloatArray]
                        ) -> Callable[[FloatArray, NDArray[np.intp]], FloatArray]:
            # Each element's cubic gathered once; the iteration narrows to fewer rows.
            own = coefficients[:, interval]

            def evaluate(v: FloatArray, rows: NDArray[np.intp]) -> FloatArray:
                every = rows.size == interval.size
                value = polynomial_at(own if every else own[:, rows],
                                      v - (left if every else left[rows]))
                if some_across:
                    other = np.flatnonzero(across[rows])
                    if other.size:
                        value[other] = model(v[other])
                return value
            return evaluate

        return on_interval(pressure_c, pressure), on_interval(stiffness_c, stiffness)

    def element_stiffness(self, segment: NDArray[np.intp], piece: NDArray[np.intp],
                          volumes: FloatArray) -> FloatArray:
        """:meth:`piece_stiffness` of each element on its segment's piece (by index)."""
        k = np.empty_like(volumes)
        for i in range(len(self.segments)):
            rows = np.flatnonzero(segment == i)
            if rows.size:
                k[rows] = self._element_stiffness(i, piece[rows], volumes[rows])
        return k

    def _element_stiffness(self, index: int, piece: NDArray[np.intp],
                           volumes: FloatArray) -> FloatArray:
        """:meth:`element_stiffness` for elements of one segment."""
        seg = self.segments[index]
        k = seg.stiffness(volumes) / self.k_scale
        v_lo, v_hi, _, _, sign, _ = self._piece_table[:, index][:, piece]
        turning = (((v_lo > seg.rest_volume) & (volumes == v_lo))
                   | ((v_hi < seg.max_volume) & (volumes == v_hi)))
        k = np.where(turning, 0.0, k)
        return np.where(sign > 0, np.maximum(k, 0.0), np.minimum(k, 0.0))

    def stiffness(self, config: tuple[Piece, ...], volumes: FloatArray) -> FloatArray:
        """Scaled dp/dv, clipped to the sign its piece promises."""
        return np.stack([self.piece_stiffness(i, piece, volumes[..., i])
                         for i, piece in enumerate(config)], axis=-1)

    def piece_stiffness(self, index: int, piece: Piece, v: FloatArray) -> FloatArray:
        """:meth:`stiffness` of one segment on one piece at volumes ``v``."""
        seg = self.segments[index]
        k = seg.stiffness(v) / self.k_scale
        # A piece end inside the model's range is a peak or a valley: the slope there is
        # zero by definition, not the round-off of a numerical derivative.
        turning = np.zeros(np.shape(v), dtype=bool)
        if piece.v_lo > seg.rest_volume:
            turning |= v == piece.v_lo
        if piece.v_hi < seg.max_volume:
            turning |= v == piece.v_hi
        k = np.where(turning, 0.0, k)
        return np.maximum(k, 0.0) if piece.direction > 0 else np.minimum(k, 0.0)

    def least_stiffness_per_interval(self, index: int) -> FloatArray | None:
        """
        The exact least dp/dv [Pa/m^3] of a table's cubic on each interval between its rows.

        Its derivative is a quadratic on each interval: the least value is at an end or at
        the quadratic's vertex. None for a closed-form model. Computed once per segment.
        """
        if index not in self._least_stiffness:
            cubics = self.segments[index].pressure_cubics()
            least = None
            if cubics is not None:
                breaks, _, slope = cubics
                width = np.diff(breaks)
                a, b, c = slope[-3], slope[-2], slope[-1]   # a s^2 + b s + c, s in [0, width]
                with np.errstate(divide='ignore', invalid='ignore'):
                    vertex = np.where(a > 0.0, -b / (2.0 * a), -1.0)
                inside = (vertex > 0.0) & (vertex < width)
                at_vertex = np.where(inside, (a * vertex + b) * vertex + c, np.inf)
                least = np.minimum(np.minimum(c, (a * width + b) * width + c), at_vertex)
            self._least_stiffness[index] = least
        return self._least_stiffness[index]

    def stiffness_extremes(self, index: int) -> FloatArray:
        """
        Volumes where a table's stiffness is extreme inside an interval between its rows.

        Its cubic's derivative is a quadratic on each interval, extreme at its vertex when that
        lies inside. Empty for a closed-form model. Computed once per segment.
        """
        if index not in self._stiffness_extremes:
            cubics = self.segments[index].pressure_cubics()
            found = np.empty(0)
            if cubics is not None:
                breaks, _, slope = cubics
                a, b = slope[-3], slope[-2]   # a s^2 + b s + c, s in [0, width]
                with np.errstate(divide='ignore', invalid='ignore'):
                    vertex = np.where(a != 0.0, -b / (2.0 * a), -1.0)
                inside = (vertex > 0.0) & (vertex < np.diff(breaks))
                found = breaks[:-1][inside] + vertex[inside]
            self._stiffness_extremes[index] = found
        return self._stiffness_extremes[index]

    def at_edge(self, volumes: FloatArray) -> bool:
        """Whether a segment's volume is at an end of its model's range (to tol_v)."""
        return bool(np.any(volumes >= self.max_volumes - self.tol_v)
                    or np.any(volumes <= self.rest_volumes + self.tol_v))

    def model_pressures(self, volumes: FloatArray) -> FloatArray:
        """Each segment's gauge pressure at volumes (m, N) inside its range [Pa]."""
        return self._side_by_side.evaluate(volumes, 0, [c[0] for c in self._curve])

    def model_stiffnesses(self, volumes: FloatArray) -> FloatArray:
        """Each segment's dp/dv at volumes (m, N) inside its range [Pa/m^3], unclipped."""
        return self._side_by_side.evaluate(volumes, 1, [c[1] for c in self._curve])

    def curvatures(self, volumes: FloatArray) -> FloatArray:
        """
        Per-segment curvature for volumes (n, N), in 1/m.

        Of the first N members: all of them, or the segments alone (a supply line comes last).
        """
        return np.stack([s.curvature(volumes[:, j])
                         for j, s in enumerate(self.segments[:volumes.shape[1]])], axis=1)

    def curvature_slopes(self, volumes: FloatArray) -> FloatArray:
        """Per-segment d(curvature)/dv for volumes (n, N), in 1/m per m^3."""
        return np.stack([s.curvature_slope(volumes[:, j]) for j, s in enumerate(self.segments)],
                        axis=1)


class _SideBySideCubics:
    """
    Every table's pressure (or stiffness) cubics in one array, to evaluate all at once.

    A flow's state is one volume per segment, and the landings evaluate every segment at a
    few dozen states at a time, thousands of times: one PPoly call per segment costs more than
    the arithmetic. Here each table only looks up its intervals, and one set of array
    operations (:func:`~softseq_ros.segments.models.polynomial_at`: PPoly's numbers to the bit)
    evaluates them all.
    A closed-form segment is called as it is.
    """

    def __init__(self, segments: Sequence[Segment]) -> None:
        self.tables: list[int] = []
        self.breaks: list[FloatArray] = []
        first: list[int] = []
        left_ends: list[FloatArray] = []
        coefficients: tuple[list[FloatArray], list[FloatArray]] = ([], [])
        count = 0
        for i, segment in enumerate(segments):
            cubics = segment.pressure_cubics()
            if cubics is None:
                continue
            breaks, pressure, stiffness = cubics
            self.tables.append(i)
            self.breaks.append(breaks)
            first.append(count)
            count += breaks.size - 1
            left_ends.append(breaks[:-1])
            coefficients[0].append(pressure)
            coefficients[1].append(stiffness)
        self.others = [i for i in range(len(segments)) if i not in self.tables]
        self.first = np.array(first, dtype=np.intp)
        self.lows = np.array([segments[i].rest_volume for i in self.tables])
        self.highs = np.array([segments[i].max_volume for i in self.tables])
        if self.tables:
            self.left_ends = np.concatenate(left_ends)
            self.coefficients = tuple(np.concatenate(c, axis=1) for c in coefficients)

    def evaluate(self, volumes: FloatArray, which: int,
                 models: list[Callable[[FloatArray], FloatArray]]) -> FloatArray:
        """Pressures (``which`` 0) or stiffnesses (1) at volumes (m, N); ``models``: the calls."""
        values = np.empty(volumes.shape)
        for i in self.others:
            values[:, i] = models[i](volumes[:, i])
        if not self.tables:
            return values
        v = np.minimum(np.maximum(volumes[:, self.tables], self.lows), self.highs)
        interval = np.empty(v.shape, dtype=np.intp)
        for column, breaks in enumerate(self.breaks):
            interval[:, column] = np.searchsorted(breaks, v[:, column], side='right')
        interval = self.first + np.minimum(np.maximum(interval - 1, 0),
                                           np.array([b.size - 2 for b in self.breaks]))
        values[:, self.tables] = polynomial_at(self.coefficients[which][:, interval],
                                               v - self.left_ends[interval])
        return values
