"""
Reading states off the stable branches: the one place that knows a state's layout.

A branch stores the state (v_1..v_N, p, k_1..k_N) as cubics in the total volume V. Reading one
costs a binary search and 2N + 1 cubics; only intervals next to a fold, where the state varies
like a square root of the volume, are solved exactly (``polish``). :meth:`StateReader.read`
gives named fields, for one total volume (Python floats: the per-command path) or many (arrays).
"""

from bisect import bisect_right
from typing import NamedTuple, overload

import numpy as np
from numpy.typing import NDArray

from softseq_ros.quasistatic.branches import Branch, hermite, sample_slopes
from softseq_ros.quasistatic.numerics import EPS, FloatArray, SegmentNumerics

# Rows read by rows_many in one go.
MANY_ROWS = 1 << 15


class StatePoint(NamedTuple):
    """One state as Python floats: volumes [m^3], gauge pressure [Pa], curvatures [1/m]."""

    volumes: list[float]
    pressure: float
    curvatures: list[float]


class StateRows(NamedTuple):
    """States as arrays: volumes (n, N) [m^3], gauge pressures (n,) [Pa], curvatures (n, N)."""

    volumes: FloatArray
    pressure: FloatArray
    curvatures: FloatArray


class StateReader:
    """Reads states on ``branches`` (of ``numerics``' segments)."""

    def __init__(self, numerics: SegmentNumerics, branches: list[Branch], polish: bool) -> None:
        """``polish``: solve the states next to folds exactly (else the chord between samples)."""
        self.numerics = numerics
        self.branches = branches
        self.polish = bool(polish)
        self._n = len(numerics.segments)

    @overload
    def read(self, index: int, total: float) -> StatePoint: ...

    @overload
    def read(self, index: int, total: FloatArray) -> StateRows: ...

    def read(self, index: int, total: float | FloatArray) -> StatePoint | StateRows:
        """
        The state(s) on branch ``index`` at total volume(s) ``total`` [m^3], clipped to it.

        A float gives a :class:`StatePoint`, an array a :class:`StateRows`.
        """
        n = self._n
        if isinstance(total, (float, int)):   # numpy's float64 is a float too
            row = self.row(index, float(total))
            return StatePoint(row[:n], row[n], row[n + 1:])
        rows = self.rows(index, total)
        return StateRows(rows[:, :n], rows[:, n], rows[:, n + 1:])

    def rows_many(self, index: NDArray[np.intp], total: FloatArray) -> FloatArray:
        """
        States on many branches at once: row r on branch ``index[r]`` at ``total[r]``.

        The numbers :meth:`rows` gives branch by branch (every step is elementwise), with each
        kind of work done once for all the branches: the cubics of the intervals read, and
        the exact states next to folds.
        """
        index = np.asarray(index, dtype=np.intp)
        total = np.asarray(total, dtype=float).copy()
        count = index.size
        if count > MANY_ROWS:
            # In parts: the cubics of each row are gathered, (4, rows, 2N + 1) at a time.
            return np.concatenate([self.rows_many(index[i:i + MANY_ROWS],
                                                  total[i:i + MANY_ROWS])
                                   for i in range(0, count, MANY_ROWS)])
        interval = np.empty(count, dtype=np.intp)
        rough = np.zeros(count, dtype=bool)
        for b in np.unique(index).tolist():
            rows = np.flatnonzero(index == b)
            branch = self.branches[b]
            total[rows] = np.clip(total[rows], branch.lo, branch.hi)
            interval[rows] = np.clip(np.searchsorted(branch.total, total[rows], side='right')
                                     - 1, 0, branch.total.size - 2)
            if self.polish and branch.any_rough:
                rough[rows] = branch.rough[interval[rows]]
        values = self._cubics_at(index, interval, total)
        if rough.any():
            rows = np.flatnonzero(rough)
            values[rows] = self._polish_many(index[rows], interval[rows], total[rows])
        return values

    def _cubics_at(self, index: NDArray[np.intp], interval: NDArray[np.intp],
                   total: FloatArray) -> FloatArray:
        """The branches' cubics at ``total``: :func:`interval_cubics` and PPoly's arithmetic."""
        numerics, n = self.numerics, self._n
        a = np.empty((index.size, n))
        b = np.empty_like(a)
        pressure = np.empty((index.size, 2))
        knots = np.empty((index.size, 2))
        chord = np.zeros(index.size, dtype=bool)
        pieces = np.empty((index.size, n), dtype=np.intp)
        for branch_index in np.unique(index).tolist():
            rows = np.flatnonzero(index == branch_index)
            branch, at = self.branches[branch_index], interval[rows]
            a[rows], b[rows] = branch.volumes[at], branch.volumes[at + 1]
            pressure[rows] = np.stack([branch.pressure[at], branch.pressure[at + 1]], axis=1)
            knots[rows] = np.stack([branch.total[at], branch.total[at + 1]], axis=1)
            chord[rows] = branch.rough[at]
            pieces[rows] = numerics.piece_indices(branch.pieces)
        segment = np.tile(np.arange(n), 2 * index.size)
        volumes = np.concatenate([a, b])
        stiffness = numerics.element_stiffness(
            segment, np.concatenate([pieces, pieces]).ravel(),
            volumes.ravel()).reshape(volumes.shape)
        slopes = sample_slopes(numerics, stiffness, volumes)
        values = np.concatenate([volumes, pressure.T.reshape(-1, 1),
                                 numerics.curvatures(volumes)], axis=1)
        m = index.size
        h = (knots[:, 1] - knots[:, 0])[:, None]
        y0, y1 = values[:m], values[m:]
        zero = np.zeros_like(y0)
        cubic = np.where(chord[None, :, None], np.stack([zero, zero, y1 - y0, y0]),
                         hermite(y0, y1, slopes[:m], slopes[m:], h))
        c = cubic / h[None, :, :] ** np.arange(3, -1, -1)[:, None, None]
        offset = (total - knots[:, 0])[:, None]
        power = offset * offset
        return c[3] + c[2] * offset + c[1] * power + c[0] * (power * offset)

    def _polish_many(self, index: NDArray[np.intp], interval: NDArray[np.intp],
                     total: FloatArray) -> FloatArray:
        """:meth:`_polish` of rows on many branches: one Newton for all of them."""
        numerics, n = self.numerics, self._n
        below = np.empty(index.size)
        above = np.empty(index.size)
        t0, t1 = np.empty(index.size), np.empty(index.size)
        pieces = np.empty((index.size, n), dtype=np.intp)
        for branch_index in np.unique(index).tolist():
            rows = np.flatnonzero(index == branch_index)
            branch, at = self.branches[branch_index], interval[rows]
            below[rows], above[rows] = branch.pressure[at], branch.pressure[at + 1]
            t0[rows], t1[rows] = branch.total[at], branch.total[at + 1]
            pieces[rows] = numerics.piece_indices(branch.pieces)
        return self._polish_rows(pieces, total, below, above, t0, t1)

    def rows(self, index: int, total: FloatArray) -> FloatArray:
        """
        States on branch ``index`` at total volumes ``total``: rows (v_1..v_N, p, k_1..k_N).

        Cubic Hermite interpolation between the branch's exact samples, with the exact slopes
        dv_i/dV, dp/dV and dk_i/dV: no segment model is evaluated. Only intervals next to a
        fold, where the state varies like a square root of the volume, are solved exactly.
        """
        branch = self.branches[index]
        total = np.clip(np.asarray(total, dtype=float), branch.lo, branch.hi)
        values = branch.evaluate(total)
        if self.polish and branch.any_rough:
            interval = np.clip(np.searchsorted(branch.total, total, side='right') - 1, 0,
                               branch.total.size - 2)
            rows = np.flatnonzero(branch.rough[interval])
            if rows.size:
                values[rows] = self._polish(branch, total[rows], values[rows])
        return values

    def row(self, index: int, total: float) -> list[float]:
        """One state's row (v_1..v_N, p, k_1..k_N) as Python floats: the per-command path."""
        branch = self.branches[index]
        total = min(max(total, branch.lo), branch.hi)
        i = min(max(bisect_right(branch.knots, total) - 1, 0), len(branch.knots) - 2)
        if self.polish and branch.rough_list[i]:
            return self.rows(index, np.array([total]))[0].tolist()
        coefficients = branch.coefficient_rows(i)
        dt = total - branch.knots[i]
        # The same Horner steps as numpy's on the arrays, so the same numbers.
        return [((a * dt + b) * dt + c) * dt + d for a, b, c, d in coefficients]

    def rows_per_command(self, index: NDArray[np.intp], total: FloatArray) -> FloatArray:
        """
        :meth:`row` of many states at once, to the last bit: row r on branch ``index[r]``.

        The batch rig answers a block of commands with the numbers the per-command path gives
        (:meth:`rows_many` may differ from :meth:`row` in the last bit): the same clamping, the
        same cubics (every step of the interval cubics is elementwise, so all the intervals
        read are computed at once), the same Horner steps, and :meth:`row` itself next to a
        fold.
        """
        values = np.empty((total.size, 2 * self._n + 1))
        for b in np.unique(index).tolist():
            rows = np.flatnonzero(index == b)
            branch = self.branches[b]
            clamped = np.minimum(np.maximum(total[rows], branch.lo), branch.hi)
            interval = np.clip(np.searchsorted(branch.total, clamped, side='right') - 1, 0,
                               branch.total.size - 2)
            rough = (np.asarray(branch.rough_list, dtype=bool)[interval] if self.polish
                     else np.zeros(rows.size, dtype=bool))
            unique, where = np.unique(interval, return_inverse=True)
            table = branch.coefficients(unique)
            a, b_, c, d = (table[k][where] for k in range(4))
            dt = (clamped - branch.total[interval])[:, None]
            values[rows] = ((a * dt + b_) * dt + c) * dt + d
            for r in np.flatnonzero(rough).tolist():
                values[rows[r]] = self.row(b, float(clamped[r]))
        return values

    def _polish(self, branch: Branch, total: FloatArray, values: FloatArray) -> FloatArray:
        """
        Exact states next to a fold or bifurcation, where no cubic in V follows the state.

        Inside one sample interval the total volume is monotone in the common pressure, with
        dV/dp = sum 1/k_i. A safeguarded Newton on the pressure (a halving where the step would
        leave the interval), with every segment's volume from its own monotone piece, cannot
        fail and reaches round-off in a few steps.
        """
        i = np.clip(np.searchsorted(branch.total, total, side='right') - 1, 0,
                    branch.total.size - 2)
        pieces = np.tile(self.numerics.piece_indices(branch.pieces), (total.size, 1))
        return self._polish_rows(pieces, total, branch.pressure[i].copy(),
                                 branch.pressure[i + 1].copy(), branch.total[i],
                                 branch.total[i + 1])

    def _polish_rows(self, pieces: NDArray[np.intp], total: FloatArray, below: FloatArray,
                     above: FloatArray, t0: FloatArray, t1: FloatArray) -> FloatArray:
        """
        The Newton of :meth:`_polish`, each row on its own pieces (``pieces``: (m, N)).

        'below' and 'above' are the pressures whose totals are below and above the target.
        """
        numerics = self.numerics
        pressure = below + (above - below) * (total - t0) / (t1 - t0)
        tolerances = numerics.tolerances
        ulps = tolerances.round_off_ulps
        converged = False
        for _ in range(tolerances.polish_steps):
            volumes, _ = numerics.states_at(pieces, pressure, stiffness=False)
            excess = volumes.sum(axis=1) - total
            short = excess < 0.0
            below = np.where(short, pressure, below)
            above = np.where(short, above, pressure)
            done = (np.abs(excess) <= ulps * EPS * numerics.v_scale) | (
                np.abs(above - below) <= ulps * np.spacing(np.abs(above)))
            if np.all(done):
                converged = True
                break
            k = numerics.model_stiffnesses(volumes)
            with np.errstate(divide='ignore', invalid='ignore'):
                step = pressure - excess / np.sum(1.0 / k, axis=1)
            inside = (np.isfinite(step) & (step > np.minimum(below, above))
                      & (step < np.maximum(below, above)))
            pressure = np.where(done, pressure, np.where(inside, step, 0.5 * (below + above)))
        numerics.convergence.record('polish', converged)
        volumes, _ = numerics.states_at(pieces, pressure, stiffness=False)
        # The bisection leaves the volume balance off by round-off; the largest volume takes it.
        largest = np.argmax(volumes, axis=1)
        volumes[np.arange(volumes.shape[0]), largest] += total - volumes.sum(axis=1)
        return np.concatenate([volumes, pressure[:, None], numerics.curvatures(volumes)],
                              axis=1)


class SegmentStates(StateReader):
    """
    The states of a map's segments alone, where the map has one more member (the supply).

    The same rows as the map's own reader, with the member's volume and curvature left out:
    (v_1..v_N, p, k_1..k_N) for the N segments. The member stays in the map's branches, its
    stability and its landings (softseq_ros.quasistatic.equilibrium).
    """

    def __init__(self, states: StateReader, segments: int) -> None:
        """The rows of ``states`` for its first ``segments`` members."""
        members = states._n
        self.numerics = states.numerics
        self.branches = states.branches
        self.polish = states.polish
        self._n = int(segments)
        self._states = states
        self._columns = np.r_[0:segments, members, members + 1:members + 1 + segments]

    def rows(self, index: int, total: FloatArray) -> FloatArray:
        """:meth:`StateReader.rows`, the segments' columns."""
        return self._states.rows(index, total)[:, self._columns]

    def row(self, index: int, total: float) -> list[float]:
        """:meth:`StateReader.row`, the segments' columns."""
        full = self._states.row(index, total)
        return [full[c] for c in self._columns.tolist()]

    def rows_many(self, index: NDArray[np.intp], total: FloatArray) -> FloatArray:
        """:meth:`StateReader.rows_many`, the segments' columns."""
        return self._states.rows_many(index, total)[:, self._columns]

    def rows_per_command(self, index: NDArray[np.intp], total: FloatArray) -> FloatArray:
        """:meth:`StateReader.rows_per_command`, the segments' columns."""
        return self._states.rows_per_command(index, total)[:, self._columns]
