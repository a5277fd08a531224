"""
Where snaps land: the redistribution flow from every fold of a map, integrated side by side.

At a fold the fluid redistributes between the segments at constant total volume, along the
gradient flow of the stored energy on sum v = V with equal conductances,
dv_i/dt = -(p_i - mean p), until it rests on a stable state: the one whose basin the flow is in.
The flow only has to reach the right basin (the landing state is then read off its branch
exactly), so it stops as soon as the basin is certain: the state lies within a ball around a
stable branch's state on which the energy is convex (:func:`certified_radius`); a gradient flow
never leaves such a ball and ends at its centre.

All the folds' flows are integrated at once, each with its own step, by the Rosenbrock method
RODAS4 (6 stages, order 4, stiffly accurate, with an embedded order-3 error estimate; Hairer
and Wanner, Solving ODEs II): stiff near a segment's stiff end, so implicit,
and linearly implicit, so each step costs four solves of an N x N system with the exact
Jacobian d(dv_i/dt)/dv_j = k_j / N - k_i delta_ij, done for every fold in one array call.
One flow at a time cost a few hundred steps of scipy's LSODA, each several Python calls per
segment; side by side a step is a few dozen array calls for all of them.
"""

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from softseq_ros.quasistatic.branches import Branch
from softseq_ros.quasistatic.numerics import FloatArray, SegmentNumerics, cofactor_sum
from softseq_ros.quasistatic.states import StateReader

# RODAS4 (Hairer and Wanner) in the form G K_i = f(Y_i) + sum_j C_ij K_j / h with
# G = I / (h gamma) - J, Y_i = y + sum_j A_ij K_j, y_new = y + sum_j M_j K_j; the last stage
# is the error estimate.
GAMMA = 0.25
_A7 = (1.221224509226641, 6.019134481288629, 12.53708332932087, -0.6878860361058950)
A = ((), (1.544,), (0.9466785280815826, 0.2557011698983284),
     (3.314825187068521, 2.896124015972201, 0.9986419139977817), _A7, (*_A7, 1.0))
C = ((), (-5.6688,), (-2.430093356833875, -0.2063599157091915),
     (-0.1073529058151375, -9.594562251023355, -20.47028614809616),
     (7.496443313967647, -10.24680431464352, -33.99990352819905, 11.70890893206160),
     (8.083246795921522, -7.981132988064893, -31.52159432874371, 16.31930543123136,
      -6.058818238834054))
M = (*_A7, 1.0, 1.0)
ORDER = 4        # of the error estimate's leading term: the step grows as err^(-1/4)
SAFETY, GROWTH, SHRINK = 0.9, 6.0, 0.2
MAX_STEPS = 20_000
HORIZON = 1e14
# Radii of the balls tried around a stable state, as shares of the volume scale, and how
# many stiffness samples per segment span a ball's box.
RADII = (1e-1, 3e-2, 1e-2, 3e-3, 1e-3, 3e-4, 1e-4, 1e-5, 1e-6)
PROBES = 33


@dataclass
class Landing:
    """Where one fold's flow went: the branch whose basin it reached (-1: none certain)."""

    branch: int
    volumes: FloatArray    # that branch's state at the fold's total, or where the flow stopped
    why: str = 'basin'     # or why none is certain: 'range', 'rest', 'stalled', 'horizon', 'steps'


def certified_radii(numerics: SegmentNumerics, centres: FloatArray) -> FloatArray:
    """
    Per centre (rows of ``centres``), the largest radius of :data:`RADII` certified convex.

    The largest radius around the centre on whose box the energy is convex, 0 when none is.
    On sum v = V the energy's Hessian is diag(k_i(v_i)) restricted to sum dv = 0; it is
    positive definite on a box of volumes when it is at each segment's smallest stiffness over
    the box (the quadratic form grows with every k_i). The smallest stiffness over a box's side
    is sampled at evenly spaced volumes and, for a table, bounded by the exact least stiffness
    of every interval between rows that the side reaches (a steep step between two flat rows
    falls inside one interval, where samples can miss it). Every centre and radius at once:
    one stiffness call per segment.
    """
    centres = np.atleast_2d(np.asarray(centres, dtype=float))
    count, n = centres.shape
    radii = np.array([share * numerics.v_scale for share in RADII])
    room = np.min(np.minimum(centres - numerics.rest_volumes, numerics.max_volumes - centres),
                  axis=1)
    offsets = np.linspace(-1.0, 1.0, PROBES)
    smallest = np.empty((count, radii.size, n))
    for i, segment in enumerate(numerics.segments):
        c = centres[:, i]
        probes = (c[:, None, None] + radii[None, :, None] * offsets).ravel()
        smallest[:, :, i] = np.min(segment.stiffness(probes).reshape(count, radii.size, -1),
                                   axis=2)
        knots = segment.knots()
        per_interval = numerics.least_stiffness_per_interval(i)
        if per_interval is not None:
            # The intervals the side [c - r, c + r] reaches, first to last.
            last = per_interval.size - 1
            lo = np.clip(np.searchsorted(knots, c[:, None] - radii[None, :], side='right') - 1,
                         0, last)
            hi = np.clip(np.searchsorted(knots, c[:, None] + radii[None, :], side='left'),
                         lo + 1, last + 1)
            bounds = np.stack([lo.ravel(), hi.ravel()], axis=1).ravel()
            least = np.minimum.reduceat(np.append(per_interval, np.inf), bounds)[::2]
            smallest[:, :, i] = np.minimum(smallest[:, :, i], least.reshape(lo.shape))
        elif knots.size:
            at_knots = segment.stiffness(knots)
            lo = np.searchsorted(knots, c[:, None] - radii[None, :], side='right')
            hi = np.searchsorted(knots, c[:, None] + radii[None, :], side='left')
            some = hi > lo
            if some.any():
                bounds = np.stack([lo[some], hi[some]], axis=1).ravel()
                padded = np.append(at_knots, np.inf)
                least = np.minimum.reduceat(padded, bounds)[::2]
                smallest[:, :, i][some] = np.minimum(smallest[:, :, i][some], least)
    k = smallest / numerics.k_scale
    passes = ((np.sum(k < 0.0, axis=2) <= 1)
              & (cofactor_sum(k) > numerics.tolerances.stable_cofactor)
              & (radii[None, :] < room[:, None]))
    return np.where(passes.any(axis=1), radii[np.argmax(passes, axis=1)], 0.0)


class FlowLandings:
    """The redistribution flows of many folds, integrated together until each basin is certain."""

    def __init__(self, numerics: SegmentNumerics, branches: list[Branch],
                 reader: StateReader) -> None:
        """The flows run on the map's ``branches``; ``reader`` reads their states."""
        self.numerics = numerics
        self.branches = branches
        self.reader = reader

    def land(self, sources: list[int], totals: FloatArray, folds: FloatArray,
             starts: FloatArray) -> list[Landing]:
        """
        Integrate every flow from ``starts`` (S, N) at ``totals`` until its basin is certain.

        ``folds``: the fold each flow starts next to; the error is measured against how far
        the flow has moved from it.

        ``sources``: the branch each fold ends, which no flow lands back on. A flow that
        leaves a segment's range, comes to rest first, stalls or runs out of steps gets
        branch -1 and the state where it stopped.
        """
        count = len(sources)
        basins = _Basins(self, np.asarray(sources), np.asarray(totals, dtype=float))
        numerics = self.numerics
        scale_v = numerics.v_scale
        lo, hi = numerics.rest_volumes, numerics.max_volumes
        tolerances = numerics.tolerances
        y = np.asarray(starts, dtype=float) / scale_v
        origin = np.asarray(folds, dtype=float) / scale_v
        t = np.zeros(count)
        results: list[Landing | None] = [None] * count
        _, k = self._forces(y)
        h = 1e-3 / np.maximum(1.0, np.max(np.abs(k - k / k.shape[1]), axis=1))
        next_rest_check = np.full(count, 100.0)
        active = np.arange(count)
        for _ in range(MAX_STEPS):
            if active.size == 0:
                break
            y_new, error = self._step(y[active], h[active])
            scale = tolerances.flow_atol + np.maximum(
                tolerances.flow_rtol * np.maximum(np.abs(y[active]), np.abs(y_new)),
                tolerances.flow_rtol_moved * np.maximum(np.abs(y[active] - origin[active]),
                                                        np.abs(y_new - origin[active])))
            with np.errstate(invalid='ignore', over='ignore'):
                err = np.sqrt(np.mean((error / scale) ** 2, axis=1))
            err = np.where(np.isfinite(err) & np.all(np.isfinite(y_new), axis=1), err, np.inf)
            accept = err <= 1.0
            with np.errstate(divide='ignore'):
                factor = np.clip(SAFETY * err ** (-1.0 / ORDER), SHRINK, GROWTH)
            factor = np.where(accept, factor, np.minimum(factor, 1.0))
            moved = active[accept]
            t[moved] += h[moved]
            y[moved] = y_new[accept]
            h[active] *= factor
            stalled = active[h[active] <= 1e-14 * np.maximum(t[active], 1.0)]
            for index in stalled.tolist():
                results[index] = Landing(-1, np.clip(y[index] * scale_v, lo, hi), 'stalled')
            for index in moved[t[moved] >= HORIZON].tolist():
                results[index] = Landing(-1, np.clip(y[index] * scale_v, lo, hi), 'horizon')
            v = y[moved] * scale_v
            # A segment out of its model's range: the domain ends there.
            out = np.any((v <= lo) | (v >= hi), axis=1)
            for index, volumes in zip(moved[out].tolist(), v[out]):
                results[index] = Landing(-1, np.clip(volumes, lo, hi), 'range')
            inside = moved[~out]
            for index, branch in zip(inside.tolist(), basins.holding(inside, v[~out])):
                if branch >= 0 and results[index] is None:
                    results[index] = Landing(branch, basins.state(index, branch))
            # At rest means balanced pressures at a stable state: a fold is balanced too
            # (so the flow's start is). Looked at once per decade of time.
            due = inside[t[inside] >= next_rest_check[inside]]
            while True:
                late = due[next_rest_check[due] <= t[due]]
                if late.size == 0:
                    break
                next_rest_check[late] *= 10.0
            due = np.array([i for i in due.tolist() if results[i] is None], dtype=np.intp)
            if due.size:
                force, k = self._forces(y[due])
                # Or balanced on a plateau (flat pieces), where the flow has nowhere to go:
                # stepping on only walks it along the plateau by round-off.
                rest = ((np.max(np.abs(force), axis=1) < tolerances.flow_rest)
                        & (((np.sum(k < 0.0, axis=1) <= 1)
                            & (cofactor_sum(k) > tolerances.stable_cofactor))
                           | numerics.neutral(y[due] * scale_v, k)))
                for index in due[rest].tolist():
                    results[index] = Landing(-1, np.clip(y[index] * scale_v, lo, hi), 'rest')
            active = np.array([i for i in active.tolist() if results[i] is None], dtype=np.intp)
        for index in active.tolist():
            results[index] = Landing(-1, np.clip(y[index] * scale_v, lo, hi), 'steps')
        return [r for r in results if r is not None]

    def _forces(self, y: FloatArray) -> tuple[FloatArray, FloatArray]:
        """dy/dt (the flow, scaled) and the scaled stiffnesses at scaled volumes ``y`` (m, N)."""
        numerics = self.numerics
        v = np.minimum(np.maximum(y * numerics.v_scale, numerics.rest_volumes),
                       numerics.max_volumes)     # np.clip's numbers, without its dispatch
        p = numerics.model_pressures(v) / numerics.p_scale
        return (np.mean(p, axis=1, keepdims=True) - p,
                numerics.model_stiffnesses(v) / numerics.k_scale)

    def _flow(self, y: FloatArray) -> FloatArray:
        """dy/dt alone (no stiffness): the stages' evaluations."""
        numerics = self.numerics
        v = np.minimum(np.maximum(y * numerics.v_scale, numerics.rest_volumes),
                       numerics.max_volumes)     # np.clip's numbers, without its dispatch
        p = numerics.model_pressures(v) / numerics.p_scale
        return np.mean(p, axis=1, keepdims=True) - p

    def _step(self, y: FloatArray, h: FloatArray) -> tuple[FloatArray, FloatArray]:
        """One RODAS3 step of every flow (its own h): the new state and the error estimate."""
        force, k = self._forces(y)
        n = y.shape[1]
        hh = h[:, None]
        # G = I / (h gamma) - J with J = 1 k^T / N - diag(k).
        g = np.broadcast_to(-k[:, None, :] / n, (y.shape[0], n, n)).copy()
        g[:, np.arange(n), np.arange(n)] += 1.0 / (hh * GAMMA) + k
        try:
            inverse = np.linalg.inv(g)
        except np.linalg.LinAlgError:
            inverse = np.linalg.pinv(g)
        stages: list[FloatArray] = []
        for i in range(len(M)):
            f = self._flow(y + sum(a * s for a, s in zip(A[i], stages))) if i else force
            rhs = f + sum(c * s for c, s in zip(C[i], stages)) / hh if i else f
            stages.append(np.einsum('mij,mj->mi', inverse, rhs))
        return y + sum(m * s for m, s in zip(M, stages)), stages[-1]


class _Basins:
    """Per fold, the stable states at its total volume and the certified balls around them."""

    def __init__(self, flows: FlowLandings, sources: NDArray[np.intp],
                 totals: FloatArray) -> None:
        numerics = flows.numerics
        branches = flows.branches
        tol = numerics.tol_v
        lo = np.array([b.lo for b in branches])
        hi = np.array([b.hi for b in branches])
        holds = (lo[None, :] - tol <= totals[:, None]) & (totals[:, None] <= hi[None, :] + tol)
        holds[np.arange(sources.size), sources] = False
        most = max(int(holds.sum(axis=1).max()) if holds.size else 0, 1)
        n = len(numerics.segments)
        self.numerics = numerics
        self.branch = np.full((sources.size, most), -1, dtype=np.intp)
        self.states = np.full((sources.size, most, n), np.inf)
        self.radius = np.full((sources.size, most), np.nan)
        # Every fold's candidates read at once (the same numbers as one read each).
        fold, branch = np.nonzero(holds)
        lo_b, hi_b = lo[branch], hi[branch]
        states = flows.reader.rows_many(branch, np.minimum(np.maximum(totals[fold], lo_b),
                                                           hi_b))[:, :n]
        slot = np.arange(fold.size) - np.searchsorted(fold, fold)
        self.branch[fold, slot] = branch
        self.states[fold, slot] = states

    def holding(self, folds: NDArray[np.intp], volumes: FloatArray) -> list[int]:
        """Per fold, the branch whose certified ball holds its state ``volumes``, or -1."""
        with np.errstate(invalid='ignore'):
            distance = np.sqrt(np.sum((self.states[folds] - volumes[:, None, :]) ** 2, axis=2))
        nearest = np.argmin(distance, axis=1)
        closest = distance[np.arange(folds.size), nearest]
        branch = self.branch[folds, nearest]
        radius = self.radius[folds, nearest]
        missing = np.flatnonzero(np.isnan(radius) & (branch >= 0))
        if missing.size:
            fold, slot = folds[missing], nearest[missing]
            radius[missing] = self.radius[fold, slot] = certified_radii(
                self.numerics, self.states[fold, slot])
        return np.where((branch >= 0) & (closest < radius), branch, -1).tolist()

    def state(self, fold: int, branch: int) -> FloatArray:
        """The stable state of ``branch`` at fold ``fold``'s total volume."""
        return self.states[fold, int(np.flatnonzero(self.branch[fold] == branch)[0])].copy()
