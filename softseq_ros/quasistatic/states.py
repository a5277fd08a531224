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

from softseq_ros.quasistatic.branches import Branch
from softseq_ros.quasistatic.numerics import FloatArray, SegmentNumerics


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
        # 'below' and 'above' are the pressures whose totals are below and above the target.
        below, above = branch.pressure[i].copy(), branch.pressure[i + 1].copy()
        t0, t1 = branch.total[i], branch.total[i + 1]
        pressure = below + (above - below) * (total - t0) / (t1 - t0)
        tolerances = self.numerics.tolerances
        ulps = tolerances.round_off_ulps
        converged = False
        for _ in range(tolerances.polish_steps):
            volumes = self.numerics.volumes_at(branch.pieces, pressure)
            excess = volumes.sum(axis=1) - total
            short = excess < 0.0
            below = np.where(short, pressure, below)
            above = np.where(short, above, pressure)
            done = (np.abs(excess) <= ulps * np.finfo(float).eps * self.numerics.v_scale) | (
                np.abs(above - below) <= ulps * np.spacing(np.abs(above)))
            if np.all(done):
                converged = True
                break
            k = np.stack([s.stiffness(volumes[:, j])
                          for j, s in enumerate(self.numerics.segments)], axis=1)
            with np.errstate(divide='ignore', invalid='ignore'):
                step = pressure - excess / np.sum(1.0 / k, axis=1)
            inside = (np.isfinite(step) & (step > np.minimum(below, above))
                      & (step < np.maximum(below, above)))
            pressure = np.where(done, pressure, np.where(inside, step, 0.5 * (below + above)))
        self.numerics.convergence.record('polish', converged)
        volumes = self.numerics.volumes_at(branch.pieces, pressure)
        # The bisection leaves the volume balance off by round-off; the largest volume takes it.
        largest = np.argmax(volumes, axis=1)
        volumes[np.arange(volumes.shape[0]), largest] += total - volumes.sum(axis=1)
        return np.concatenate([volumes, pressure[:, None], self.numerics.curvatures(volumes)],
                              axis=1)
