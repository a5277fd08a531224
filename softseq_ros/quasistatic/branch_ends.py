"""
How stable branches end: a walk continues on another branch, snaps through, or ends the domain.

A branch ends where it joins another stable branch (a segment passes a peak or valley: the
walk continues), at a fold (D = 0: the state snaps through to the stable state that the fluid
exchange between the segments reaches at that volume), or where a segment leaves its table
(the end of the domain). The snap's landing state comes from the redistribution flow of the
stored energy, integrated until it comes to rest.
"""

import math
import warnings

import numpy as np
from scipy.integrate import LSODA, Radau, solve_ivp

from softseq_ros.quasistatic.assembly import (
    Branch,
    BranchEnd,
    FloatArray,
    SegmentNumerics,
    cofactor_sum,
    soft_direction,
)
from softseq_ros.quasistatic.states import StateReader
from softseq_ros.segments.models import Segment


class BranchEnds:
    """Sets every branch's ``upper`` and ``lower`` end; ``reader`` reads states on branches."""

    def __init__(self, numerics: SegmentNumerics, branches: list[Branch],
                 reader: StateReader) -> None:
        """Ends of ``branches``; call :meth:`connect` for each."""
        self.numerics = numerics
        self.branches = branches
        self.reader = reader

    def connect(self, index: int) -> None:
        """Decide how branch ``index`` ends, upward and downward."""
        branch = self.branches[index]
        branch.upper = self._end_rule(index, upward=True)
        branch.lower = self._end_rule(index, upward=False)

    def _end_rule(self, index: int, upward: bool) -> BranchEnd:
        branch = self.branches[index]
        end = -1 if upward else 0
        v_end, total_end = branch.volumes[end], branch.total[end]
        candidates = []
        for j, other in enumerate(self.branches):
            if j == index:
                continue
            start = 0 if upward else -1
            if (abs(other.total[start] - total_end) <= self.numerics.tol_v
                    and np.max(np.abs(other.volumes[start] - v_end)) <= self.numerics.tol_v):
                candidates.append(j)
        if candidates:
            # A bifurcation (identical segments) offers several continuations: the tie is broken
            # deterministically, the segment nearest the base taking the larger share.
            step = 1 if upward else -2
            best = max(candidates, key=lambda j: tuple(self.branches[j].volumes[step]))
            return BranchEnd('continue', best)
        # A segment at the edge of its model's range ends the domain: going on would take it
        # outside its table (any continuation inside the range was found above).
        if self._at_edge(v_end):
            return BranchEnd('limit')
        snap = self._snap(index, upward)
        if snap is None:
            return BranchEnd('limit')
        return BranchEnd('snap', *snap)

    def _at_edge(self, volumes: FloatArray) -> bool:
        return bool(np.any(volumes >= self.numerics.max_volumes - self.numerics.tol_v)
                    or np.any(volumes <= self.numerics.rest_volumes + self.numerics.tol_v))

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
        k = self.numerics.stiffness(branch.pieces, v_fold[None, :])[0]
        null = soft_direction(k)
        eps = self.numerics.tolerances.fold_offset * self.numerics.v_scale

        def drift(v: FloatArray) -> float:
            p = np.array([s.pressure(x) for s, x in zip(self.numerics.segments, v)])
            return float(-np.dot(p - p.mean(), null))

        direction = math.copysign(1.0, drift(v_fold + eps * null) + drift(v_fold - eps * null))
        start = v_fold + direction * eps * null
        landed, target = self._certified_flow(start, total, index)
        if target >= 0:
            return target, landed
        # No basin certain (the flow leaves the domain, stalls or comes to rest elsewhere):
        # the full integration decides.
        landed = self._flow(start)
        if self._at_edge(landed):
            return None
        target = self._nearest_branch(total, landed, exclude=index)
        return target, self.reader.read(target, np.array([total])).volumes[0]

    def _flow(self, start: FloatArray) -> FloatArray:
        """
        Integrate the redistribution flow from ``start`` until it comes to rest.

        Scaled by the volume and pressure ranges; stiff near walls, so Radau with the exact
        Jacobian, d(dv_i/dt)/dv_j = k_j / N - k_i delta_ij. The flow only has to reach the
        right basin (the landing state is then read off its branch exactly), so the
        tolerances are modest and the horizon grows until the state is balanced and stable.
        """
        scale_v, scale_p = self.numerics.v_scale, self.numerics.p_scale
        segments, k_scale = self.numerics.segments, self.numerics.k_scale
        lo, hi = self.numerics.rest_volumes, self.numerics.max_volumes
        n = len(self.numerics.segments)

        def rhs(_t: float, y: FloatArray) -> FloatArray:
            v = np.clip(y * scale_v, lo, hi)
            p = np.array([s.pressure(x) for s, x in zip(self.numerics.segments, v)]) / scale_p
            return -(p - p.mean())

        def jacobian(_t: float, y: FloatArray) -> FloatArray:
            v = np.clip(y * scale_v, lo, hi)
            k = np.array([s.stiffness(x) for s, x in zip(segments, v)]) / k_scale
            return np.outer(np.ones(n), k) / n - np.diag(k)

        def leaves_range(_t: float, y: FloatArray) -> float:
            # Crosses zero when a segment leaves its model's range: the domain ends there.
            v = y * scale_v
            return float(np.min(np.minimum(v - lo, hi - v)) / scale_v)

        leaves_range.terminal = True
        tolerances = self.numerics.tolerances
        y = start / scale_v
        t = 0.0
        for horizon in np.logspace(2, 14, 13):
            sol = solve_ivp(rhs, (t, horizon), y, method='Radau', jac=jacobian,
                            rtol=tolerances.flow_rtol, atol=tolerances.flow_atol,
                            events=leaves_range)
            y, t = sol.y[:, -1], horizon
            if sol.status == 1:
                break
            # At rest means balanced pressures at a stable state: a fold is balanced too.
            if np.max(np.abs(rhs(t, y))) < tolerances.flow_rest and self._is_stable(y * scale_v):
                break
        return np.clip(y * scale_v, lo, hi)

    def _certified_flow(self, start: FloatArray, total: float, exclude: int
                        ) -> tuple[FloatArray, int]:
        """
        The redistribution flow from ``start``, as far as its landing branch is certain.

        The flow only has to reach the right basin (the landing state is then read off its
        branch exactly), so it stops as soon as the basin is certain: the state lies within a
        ball around a stable branch's state on which the energy is convex (:class:`_Basins`);
        a gradient flow never leaves such a ball and ends at its centre. Integrated like
        :meth:`_flow`, but with LSODA (its steps are compiled, where Radau's Newton iterations
        cost Python calls), checking the state after every step. Returns (landing state,
        branch), or (state, -1) when it leaves a segment's range, comes to rest or stalls
        first: :meth:`_flow` then decides, as it always did.
        """
        scale_v, scale_p = self.numerics.v_scale, self.numerics.p_scale
        segments, k_scale = self.numerics.segments, self.numerics.k_scale
        lo, hi = self.numerics.rest_volumes, self.numerics.max_volumes
        n = len(self.numerics.segments)
        lo_list, hi_list = lo.tolist(), hi.tolist()
        pressures = [s.pressure for s in segments]

        def rhs(_t: float, y: FloatArray) -> FloatArray:
            p = [f(min(max(x * scale_v, a), b)) / scale_p
                 for f, x, a, b in zip(pressures, y.tolist(), lo_list, hi_list)]
            mean = math.fsum(p) / n
            return np.array([mean - x for x in p])

        def jacobian(_t: float, y: FloatArray) -> FloatArray:
            v = np.clip(y * scale_v, lo, hi)
            k = np.array([s.stiffness(x) for s, x in zip(segments, v)]) / k_scale
            return np.outer(np.ones(n), k) / n - np.diag(k)

        tolerances = self.numerics.tolerances
        basins = _Basins(self, total, exclude)
        y, t = start / scale_v, 0.0
        next_rest_check = 100.0
        # Next to the fold the flow is nearly at rest, so LSODA's own first step would be far
        # too long for the fast directions (its corrector then fails): start at a small share
        # of the fastest relaxation time.
        first = 1e-3 / max(1.0, float(np.max(np.abs(np.diag(jacobian(0.0, y))))))
        # Should LSODA still give up (its corrector failing where a table's stiffness jumps
        # at its rows), Radau takes over from where it stopped.
        for method in (LSODA, Radau):
            solver = method(rhs, t, y, 1e14, rtol=tolerances.flow_rtol,
                            atol=tolerances.flow_atol, jac=jacobian, first_step=first)
            while solver.status == 'running':
                with warnings.catch_warnings():
                    warnings.simplefilter('ignore', UserWarning)
                    solver.step()
                if solver.status == 'failed':
                    break
                y, t = solver.y, solver.t
                v = y * scale_v
                # A segment out of its model's range: the domain ends there.
                if np.any(v <= lo) or np.any(v >= hi):
                    return np.clip(v, lo, hi), -1
                found = basins.holding(v)
                if found >= 0:
                    return basins.state(found), found
                # At rest means balanced pressures at a stable state: a fold is balanced too
                # (so the flow's start is). Looked at once per decade of time.
                if t >= next_rest_check:
                    while next_rest_check <= t:
                        next_rest_check *= 10.0
                    if (np.max(np.abs(rhs(0.0, y))) < tolerances.flow_rest
                            and self._is_stable(v)):
                        return np.clip(v, lo, hi), -1
            if solver.status == 'finished':
                break
        return np.clip(y * scale_v, lo, hi), -1

    def _is_stable(self, volumes: FloatArray) -> bool:
        numerics = self.numerics
        k = np.array([s.stiffness(x) for s, x in zip(numerics.segments, volumes)])
        k /= numerics.k_scale
        return bool(np.sum(k < 0.0) <= 1
                    and cofactor_sum(k) > numerics.tolerances.stable_cofactor)

    def _nearest_branch(self, total: float, volumes: FloatArray, exclude: int) -> int:
        best, best_distance = -1, math.inf
        for j, other in enumerate(self.branches):
            tol = self.numerics.tol_v
            if j == exclude or not other.lo - tol <= total <= other.hi + tol:
                continue
            state = self.reader.read(j, np.array([min(max(total, other.lo), other.hi)])).volumes[0]
            distance = float(np.max(np.abs(state - volumes)))
            if distance < best_distance:
                best, best_distance = j, distance
        landing = self.numerics.tolerances.landing_distance * self.numerics.v_scale
        if best < 0 or best_distance > landing:
            raise RuntimeError(f'snap-through at total volume {total:.9g} m^3 found no stable '
                               f'state to land on (nearest {best_distance:.3g} m^3 away)')
        return best


class _Basins:
    """
    The stable states at one total volume, and balls around them that only they can flow to.

    On sum v = V the energy's Hessian is diag(k_i(v_i)) restricted to sum dv = 0. It is
    positive definite on a box of volumes when it is at each segment's smallest stiffness
    over the box (the quadratic form grows with every k_i). Inside a ball around a stable
    state v* on which that holds, the energy is strictly convex, so the gradient flow brings
    every state in the ball closer to v* and ends there: a state inside has landed. The
    smallest stiffness over a box's side is sampled (evenly spaced volumes and a table's
    rows inside it), and the radius is the largest of a ladder whose box passes, inside the
    segments' ranges; a state outside every ball flows on.
    """

    RADII = (1e-1, 3e-2, 1e-2, 3e-3, 1e-3, 3e-4, 1e-4, 1e-5, 1e-6)  # shares of the volume scale
    PROBES = 33   # stiffness samples per segment across a box's side

    def __init__(self, ends: BranchEnds, total: float, exclude: int) -> None:
        numerics = ends.numerics
        self.numerics = numerics
        tol = numerics.tol_v
        self.indices = [j for j, b in enumerate(ends.branches)
                        if j != exclude and b.lo - tol <= total <= b.hi + tol]
        self.states = np.array([ends.reader.read(j, np.array([min(max(total, ends.branches[j].lo),
                                                                      ends.branches[j].hi)]))
                                .volumes[0] for j in self.indices]).reshape(-1, len(
                                    numerics.segments))
        self.radii: dict[int, float] = {}

    def holding(self, volumes: FloatArray) -> int:
        """The branch whose certified ball holds ``volumes``, or -1."""
        if not self.indices:
            return -1
        distance = np.sqrt(np.sum((self.states - volumes) ** 2, axis=1))
        nearest = int(np.argmin(distance))
        if distance[nearest] < self._radius(nearest):
            return self.indices[nearest]
        return -1

    def state(self, branch: int) -> FloatArray:
        """The stable state of ``branch`` at this total volume."""
        return self.states[self.indices.index(branch)].copy()

    def _radius(self, slot: int) -> float:
        if slot not in self.radii:
            self.radii[slot] = self._certify(self.states[slot])
        return self.radii[slot]

    def _certify(self, centre: FloatArray) -> float:
        """The largest radius of the ladder on whose box the energy is convex (0 if none)."""
        numerics = self.numerics
        room = float(np.min(np.minimum(centre - numerics.rest_volumes,
                                       numerics.max_volumes - centre)))
        offsets = np.linspace(-1.0, 1.0, self.PROBES)
        for share in self.RADII:
            radius = share * numerics.v_scale
            if radius >= room:
                continue
            k = np.array([np.min(s.stiffness(self._probes(s, c, radius, offsets)))
                          for s, c in zip(numerics.segments, centre)]) / numerics.k_scale
            if np.sum(k < 0.0) <= 1 and cofactor_sum(k) > numerics.tolerances.stable_cofactor:
                return radius
        return 0.0

    @staticmethod
    def _probes(segment: Segment, centre: float, radius: float, offsets: FloatArray
                ) -> FloatArray:
        """Volumes across a box's side: evenly spaced, and a table's rows inside it."""
        knots = segment.knots()
        inside = knots[(knots > centre - radius) & (knots < centre + radius)]
        return np.concatenate([centre + radius * offsets, inside])
