"""
Where snaps land: the redistribution flow of the stored energy, written once, from every fold.

At a fold the fluid redistributes between the segments at constant total volume, along the
gradient flow of the stored energy on sum v = V with equal conductances,
dv_i/dt = -(p_i - mean p), until it rests on a stable state: the one whose basin the flow is in.
:class:`RedistributionFlow` is that flow and nothing else: its forcing, its Jacobian, its rest
test and its stability test, each written once, and its two integrators (every fold's flow side
by side; one flow alone). No other module of the solver evaluates the flow: the branch ends
(softseq_ros.quasistatic.branch_ends) hand their folds to :class:`SnapLandings` and get back
where each snap lands.

The flow only has to reach the right basin (the landing state is then read off its branch
exactly), so it stops as soon as the basin is certain: the state lies within a ball around a
stable branch's state on which the energy is convex (:func:`certified_radii`); a gradient flow
never leaves such a ball and ends at its centre.

All the folds' flows are integrated at once, each with its own step, by the Rosenbrock method
RODAS4 (6 stages, order 4, stiffly accurate, with an embedded order-3 error estimate; Hairer
and Wanner, Solving ODEs II): stiff near a segment's stiff end, so implicit,
and linearly implicit, so each step costs four solves of an N x N system with the exact
Jacobian d(dv_i/dt)/dv_j = k_j / N - k_i delta_ij, done for every fold in one array call.
A flow for which no basin becomes certain (it leaves a segment's range, comes to rest where
no ball is certain, stalls or runs out of steps) is integrated alone, with Radau and the same
equations, and that integration decides (:meth:`SnapLandings.land`).
"""

from dataclasses import dataclass
import math

import numpy as np
from numpy.typing import NDArray
from scipy.integrate import solve_ivp

from softseq_ros.quasistatic.branches import Branch, BranchEnd
from softseq_ros.quasistatic.numerics import (
    FloatArray,
    SegmentNumerics,
    cofactor_sum,
    soft_direction,
)
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
# The flows side by side start with this step (scaled time, shortened where the state is stiff)
# and count as stalled when their step falls below this share of the time they have run.
FIRST_STEP = 1e-3
STALLED_STEP = 1e-14
# Radii of the balls tried around a stable state, as shares of the volume scale, and how
# many stiffness samples per segment span a ball's box.
RADII = (1e-1, 3e-2, 1e-2, 3e-3, 1e-3, 3e-4, 1e-4, 1e-5, 1e-6)
PROBES = 33

# The flow's drifts on the two sides of a branch end cancel to this share of the larger: a
# pitchfork (mirror images up to round-off, or both zero), not a fold.
PITCHFORK = 1e-6


@dataclass
class Landing:
    """Where one fold's flow went: the branch whose basin it reached (-1: none certain)."""

    branch: int
    volumes: FloatArray    # that branch's state at the fold's total, or where the flow stopped
    why: str = 'basin'     # or why none is certain: 'range', 'rest', 'stalled', 'horizon', 'steps'


class UnplacedLandingError(RuntimeError):
    """
    A snap's flow came to rest where no branch is: a stable stretch the assembly missed.

    A fault of the solver, not of the input: the assembly samples the stretches it would
    otherwise step over (softseq_ros.quasistatic.assembly), and the tests and the landing
    sweep (bench/bench_landing_sweep.py) check that every snap lands.
    """


def base_first(direction: FloatArray, volumes: FloatArray, tol: float) -> float:
    """
    The sign of ``direction`` that gives the segment nearer the base the larger share.

    The tie-break wherever the physics leaves mirror continuations (identical segments at the
    same state), the same rule as a join's: of the first two segments at the same volume
    (to ``tol``) that ``direction`` moves apart, the one nearer the base gains; else the first
    segment it moves at all.
    """
    n = direction.size
    for i in range(n):
        for j in range(i + 1, n):
            apart = direction[i] - direction[j]
            if abs(volumes[i] - volumes[j]) <= tol and abs(apart) > PITCHFORK:
                return math.copysign(1.0, apart)
    base = int(np.argmax(np.abs(direction) > PITCHFORK))
    return math.copysign(1.0, direction[base])


def stable(k: FloatArray, cofactor: float) -> NDArray[np.bool_]:
    """
    The stability test, along the last axis of scaled stiffnesses ``k``.

    The Hessian of the stored energy on sum v = V, diag(k) restricted to sum dv = 0, is
    positive definite: at most one k_i negative and the cofactor sum D above ``cofactor``.
    """
    return (np.sum(k < 0.0, axis=-1) <= 1) & (cofactor_sum(k) > cofactor)


def certified_radii(numerics: SegmentNumerics, centres: FloatArray) -> FloatArray:
    """
    Per centre (rows of ``centres``), the largest radius of :data:`RADII` certified convex.

    The largest radius around the centre on whose box the energy is convex, 0 when none is.
    On sum v = V the energy's Hessian is diag(k_i(v_i)) restricted to sum dv = 0; it is
    positive definite on a box of volumes when it is at each segment's smallest stiffness over
    the box (the quadratic form grows with every k_i). The smallest stiffness over a box's side
    is sampled at evenly spaced volumes and, for a table, bounded by the exact least stiffness
    of every interval between rows that the side reaches (a steep rise between two rows of
    gentle slope falls inside one interval, where samples can miss it). Every centre and
    radius at once: one stiffness call per segment.
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
    passes = (stable(k, numerics.tolerances.stable_cofactor)
              & (radii[None, :] < room[:, None]))
    return np.where(passes.any(axis=1), radii[np.argmax(passes, axis=1)], 0.0)


class RedistributionFlow:
    """
    The gradient flow of the stored energy on sum v = V: the one place its equations live.

    In scaled variables y = v / v_scale and pressures over p_scale, with equal conductances,
    dy_i/dt = mean p - p_i (:meth:`forcing`); its Jacobian is k_j / N - k_i delta_ij with the
    scaled stiffnesses k (:meth:`shifted`). A flow is at rest where the pressures balance
    (to ``flow_rest``) at a stable state (:func:`stable`). A saddle is balanced and clearly
    unstable.
    """

    def __init__(self, numerics: SegmentNumerics) -> None:
        """The flow of ``numerics``' segments, at its scales and tolerances."""
        self.numerics = numerics

    def _inside(self, v: FloatArray) -> FloatArray:
        numerics = self.numerics
        return np.minimum(np.maximum(v, numerics.rest_volumes),
                          numerics.max_volumes)     # np.clip's numbers, without its dispatch

    def forcing(self, y: FloatArray) -> FloatArray:
        """dy/dt at scaled volumes ``y`` (m, N): mean p - p_i, over the pressure scale."""
        return self._forcing_at(self._inside(y * self.numerics.v_scale))

    def _forcing_at(self, v: FloatArray) -> FloatArray:
        return self._balance(self.numerics.model_pressures(v))

    def _forcing_one(self, v: FloatArray) -> FloatArray:
        """
        :meth:`forcing` at one state's volumes ``v`` (N,), inside the ranges, evaluated alone.

        Each segment's own call at its volume (for a table, its cubic on plain floats): the
        lone integration's numbers, equal to the side-by-side evaluation to round-off, and
        cheaper for a single state.
        """
        p = np.array([s.pressure(x) for s, x in zip(self.numerics.segments, v)])
        return self._balance(p[None, :])[0]

    def _balance(self, p: FloatArray) -> FloatArray:
        """The forcing from the pressures ``p`` (m, N) [Pa]: mean p - p_i, scaled."""
        p = p / self.numerics.p_scale
        # np.mean's numbers (its sum, then a division by the count), without its overhead.
        return np.add.reduce(p, axis=1, keepdims=True) / p.shape[1] - p

    def stiffnesses(self, y: FloatArray) -> FloatArray:
        """The scaled stiffnesses dp_i/dv_i at scaled volumes ``y`` (m, N)."""
        return self._stiffnesses_at(self._inside(y * self.numerics.v_scale))

    def _stiffnesses_at(self, v: FloatArray) -> FloatArray:
        return self.numerics.model_stiffnesses(v) / self.numerics.k_scale

    def forces(self, y: FloatArray) -> tuple[FloatArray, FloatArray]:
        """:meth:`forcing` and :meth:`stiffnesses` at once."""
        return self.forcing(y), self.stiffnesses(y)

    @staticmethod
    def shifted(k: FloatArray, shift: FloatArray | float) -> FloatArray:
        """
        The matrix shift I - J, J the flow's Jacobian d(dy_i/dt)/dy_j = k_j / N - k_i delta_ij.

        From scaled stiffnesses ``k`` (..., N); ``shift`` 0 gives -J (Radau's), 1 / (h gamma)
        a Rosenbrock step's matrix.
        """
        n = k.shape[-1]
        g = np.broadcast_to(-k[..., None, :] / n, k.shape[:-1] + (n, n)).copy()
        g[..., np.arange(n), np.arange(n)] += shift + k
        return g

    def drift(self, volumes: FloatArray, direction: FloatArray) -> FloatArray:
        """How fast the flow moves along ``direction`` at ``volumes`` (m, N) [m^3]."""
        return self._forcing_at(self._inside(volumes)) @ direction

    def at_rest(self, force: FloatArray, k: FloatArray) -> NDArray[np.bool_]:
        """Per row: balanced to ``flow_rest`` at a stable state."""
        tolerances = self.numerics.tolerances
        balanced = np.max(np.abs(force), axis=1) < tolerances.flow_rest
        return balanced & stable(k, tolerances.stable_cofactor)

    def saddle(self, volumes: FloatArray) -> bool:
        """
        Balanced pressures at a clearly unstable state (two falling pieces, or D < 0).

        Asked only where a flow has run to its horizon, long past the fold it started next to
        (near a fold D is about 0 and the pressures balance too).
        """
        v = self._inside(volumes[None, :])
        force, k = self._forcing_at(v), self._stiffnesses_at(v)
        tolerances = self.numerics.tolerances
        return bool(np.max(np.abs(force)) < tolerances.flow_rest
                    and (np.sum(k < 0.0) >= 2
                         or cofactor_sum(k[0]) < -tolerances.stable_cofactor))

    def direction(self, volumes: FloatArray, along: FloatArray, eps: float) -> float:
        """
        The way the flow points along ``along`` on both sides of ``volumes`` (ties as joins).

        At a fold the flow points the same way on both sides (the energy along the soft
        direction is a cubic there). Where it points away on both sides alike, or nowhere,
        the end is a pitchfork: identical segments at the same state,
        where either may take the fluid; the tie is broken as at a join (:func:`base_first`).
        """
        ahead, behind = self.drift(np.stack([volumes + eps * along, volumes - eps * along]),
                                   along).tolist()
        if abs(ahead + behind) <= PITCHFORK * max(abs(ahead), abs(behind)):
            return base_first(along, volumes, self.numerics.tol_v)
        return math.copysign(1.0, ahead + behind)

    def step(self, y: FloatArray, h: FloatArray) -> tuple[FloatArray, FloatArray]:
        """One RODAS4 step of every flow (its own h): the new state and the error estimate."""
        force, k = self.forces(y)
        hh = h[:, None]
        g = self.shifted(k, 1.0 / (hh * GAMMA))
        try:
            inverse = np.linalg.inv(g)
        except np.linalg.LinAlgError:
            inverse = np.linalg.pinv(g)
        stages: list[FloatArray] = []
        for i in range(len(M)):
            f = self.forcing(y + sum(a * s for a, s in zip(A[i], stages))) if i else force
            rhs = f + sum(c * s for c, s in zip(C[i], stages)) / hh if i else f
            stages.append(np.einsum('mij,mj->mi', inverse, rhs))
        return y + sum(m * s for m, s in zip(M, stages)), stages[-1]

    def integrate(self, start: FloatArray) -> FloatArray:
        """
        One flow from ``start`` [m^3] until it comes to rest (:meth:`at_rest`), alone.

        Stiff near walls, so Radau with the exact Jacobian. The flow only has to reach the
        right basin (the landing state is then read off its branch exactly), so the
        tolerances are modest and the horizon grows until the flow is at rest or leaves a
        segment's range.
        """
        numerics = self.numerics
        scale_v = numerics.v_scale
        lo, hi = numerics.rest_volumes, numerics.max_volumes

        def rhs(_t: float, y: FloatArray) -> FloatArray:
            return self._forcing_one(np.clip(y * scale_v, lo, hi))

        def jacobian(_t: float, y: FloatArray) -> FloatArray:
            return -self.shifted(self.stiffnesses(y[None, :])[0], 0.0)

        def leaves_range(_t: float, y: FloatArray) -> float:
            # Crosses zero when a segment leaves its model's range: the domain ends there.
            v = y * scale_v
            return float(np.min(np.minimum(v - lo, hi - v)) / scale_v)

        leaves_range.terminal = True
        tolerances = numerics.tolerances
        y = start / scale_v
        t = 0.0
        for horizon in np.logspace(2, 14, 13):
            with np.errstate(divide='ignore'):   # a step of zero error
                sol = solve_ivp(rhs, (t, horizon), y, method='Radau', jac=jacobian,
                                rtol=tolerances.flow_rtol, atol=tolerances.flow_atol,
                                events=leaves_range)
            y, t = sol.y[:, -1], horizon
            if sol.status == 1:
                break
            force = rhs(t, y)[None, :]
            if self.at_rest(force, self.stiffnesses(y[None, :]))[0]:
                break
        return np.clip(y * scale_v, lo, hi)

    def run(self, start: FloatArray) -> FloatArray:
        """
        :meth:`integrate` from ``start``, past any saddle it stops on.

        Identical segments at the same state stay identical along the flow (their equations
        are the same to the bit), so a flow from a fold where they share the fluid alike can
        only reach states where they still do: on three identical stepped tables, two of them
        past their peak together, balanced on two falling pieces (a saddle). Any real
        actuator leaves it: the flow goes on from a small step along the saddle's unstable
        direction, the tie broken as at a join (:func:`base_first`). Each saddle passed
        lowers the stored energy; at most one per segment.
        """
        numerics = self.numerics
        eps = numerics.tolerances.fold_offset * numerics.v_scale
        landed = self.integrate(start)
        for _ in range(len(numerics.segments)):
            if not self.saddle(landed):
                break
            null = soft_direction(self._stiffnesses_at(self._inside(landed[None, :]))[0])
            landed = self.integrate(
                landed + base_first(null, landed, numerics.tol_v) * eps * null)
        return landed


class FlowLandings:
    """The redistribution flows of many folds, integrated together until each basin is certain."""

    def __init__(self, numerics: SegmentNumerics, branches: list[Branch],
                 reader: StateReader) -> None:
        """The flows run on the map's ``branches``; ``reader`` reads their states."""
        self.numerics = numerics
        self.branches = branches
        self.reader = reader
        self.flow = RedistributionFlow(numerics)

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
        k = self.flow.stiffnesses(y)
        h = FIRST_STEP / np.maximum(1.0, np.max(np.abs(k - k / k.shape[1]), axis=1))
        next_rest_check = np.full(count, 100.0)
        active = np.arange(count)
        for _ in range(MAX_STEPS):
            if active.size == 0:
                break
            y_new, error = self.flow.step(y[active], h[active])
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
            stalled = active[h[active] <= STALLED_STEP * np.maximum(t[active], 1.0)]
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
                force, k = self.flow.forces(y[due])
                rest = self.flow.at_rest(force, k)
                for index in due[rest].tolist():
                    results[index] = Landing(-1, np.clip(y[index] * scale_v, lo, hi), 'rest')
            active = np.array([i for i in active.tolist() if results[i] is None], dtype=np.intp)
        for index in active.tolist():
            results[index] = Landing(-1, np.clip(y[index] * scale_v, lo, hi), 'steps')
        return [r for r in results if r is not None]


class SnapLandings:
    """
    Where the snaps at some branch ends land: every fold's flow together, then alone.

    The flow starts a small step off the fold, on the side the flow itself points to, and a
    step past it (:meth:`_flow_start`). All
    folds' flows run together until each basin is certain (:class:`FlowLandings`); a flow for
    which none becomes certain (it leaves the domain, stalls or comes to rest first) is
    integrated alone (:meth:`RedistributionFlow.run`), and that decides. The end of the
    domain when the flow leaves a segment's range.
    """

    def __init__(self, numerics: SegmentNumerics, branches: list[Branch],
                 reader: StateReader) -> None:
        """Landings on the map's ``branches``; ``reader`` reads their states."""
        self.together = FlowLandings(numerics, branches, reader)
        self.numerics, self.branches, self.reader = numerics, branches, reader
        self.flow = self.together.flow

    def land(self, ends: list[tuple[int, bool]]) -> list[BranchEnd]:
        """
        Where the folds at the branch ends ``ends`` ((branch, upward) pairs) snap to.

        Each at its own total volume: the state rolls downhill from the fold to the stable
        equilibrium whose basin it is in.
        """
        if not ends:
            return []
        folds, starts, totals = [], [], []
        for index, upward in ends:
            branch = self.branches[index]
            end = -1 if upward else 0
            folds.append(branch.volumes[end])
            starts.append(self._flow_start(branch, branch.volumes[end], upward))
            totals.append(float(branch.total[end]))
        landings = self.together.land(
            [index for index, _ in ends], np.array(totals), np.array(folds), np.array(starts))
        found = []
        for (index, upward), total, start, fold, landing in zip(ends, totals, starts, folds,
                                                               landings):
            if landing.branch >= 0:
                found.append(BranchEnd('snap', landing.branch, landing.volumes))
            else:
                found.append(self._land_alone(index, upward, total, start, fold, landing))
        return found

    def _land_alone(self, index: int, upward: bool, total: float, start: FloatArray,
                    fold: FloatArray, landing: Landing) -> BranchEnd:
        """
        Where a flow that no certain basin took lands: where it rests, placed on a branch.

        Where the side-by-side flow came to rest (balanced at a stable state, not on a
        saddle), that is where; else the flow integrated alone from its start, with Radau's
        error control and past any saddle it stops on (:meth:`RedistributionFlow.run`). The
        state is placed on the branch holding it at the snap's total (:meth:`_nearest_branch`),
        or on the domain's end where a segment reaches the end of its range.

        None placed: :class:`UnplacedLandingError`, which says where the nearest branch is.
        """
        rested = landing.why in ('rest', 'horizon') and not self.flow.saddle(landing.volumes)
        landed = landing.volumes if rested else self.flow.run(start)
        if self.numerics.at_edge(landed):
            return BranchEnd('limit')
        target, distance = self._nearest_branch(total, landed, exclude=index)
        if target >= 0:
            return BranchEnd('snap', target,
                             self.reader.read(target, np.array([total])).volumes[0])
        raise UnplacedLandingError(
            f'snap-through at total volume {total:.9g} m^3 found no stable state to land on '
            f'(nearest {distance:.3g} m^3 away)')

    def _flow_start(self, branch: Branch, v_fold: FloatArray, upward: bool) -> FloatArray:
        """
        A small step off the fold along its soft direction, the way the flow points, and past it.

        The way the flow points there (:meth:`RedistributionFlow.direction`: a pitchfork's
        tie, as at the common peak of identical tables, broken as at a join). Past it: as much
        fluid again added (inflating) or taken (deflating), shared alike, so the flow starts at
        a total the branch does not reach. At the fold's own total the fold is itself a
        balanced state, and where the branch's total barely turns (2e-12 m^3 over 0.5 Pa next
        to the common valley of three identical tables) the flow met balanced pressures at
        once, back on the branch it left. The landing is read at the fold's total all the same.
        """
        k = self.numerics.stiffness(branch.pieces, v_fold[None, :])[0]
        null = soft_direction(k)
        eps = self.numerics.tolerances.fold_offset * self.numerics.v_scale
        past = (eps if upward else -eps) / len(self.numerics.segments)
        return v_fold + self.flow.direction(v_fold, null, eps) * eps * null + past

    def _nearest_branch(self, total: float, volumes: FloatArray,
                        exclude: int) -> tuple[int, float]:
        """
        The branch whose state at ``total`` is where the flow came to rest (``volumes``).

        With its distance; -1 when none is within the landing distance, or when the branch
        the flow leaves (``exclude``) is nearer than any other.

        The distance is the largest of the segments' volume differences.
        """
        landing = self.numerics.tolerances.landing_distance * self.numerics.v_scale
        best, best_distance, back = -1, math.inf, math.inf
        for j, other in enumerate(self.branches):
            tol = self.numerics.tol_v
            if not other.lo - tol <= total <= other.hi + tol:
                continue
            state = self.reader.read(j, np.array([min(max(total, other.lo), other.hi)])).volumes[0]
            distance = float(np.max(np.abs(state - volumes)))
            if j == exclude:
                back = distance
            elif distance < best_distance:
                best, best_distance = j, distance
        # A flow that rests nearer the branch it leaves than any other has not left it (a
        # fold so flat that the flow barely moves); another branch within the landing
        # distance is then no landing.
        if best < 0 or best_distance > landing or back < best_distance:
            return -1, best_distance
        return best, best_distance


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
