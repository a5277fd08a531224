"""
How stable branches end: a walk continues on another branch, snaps through, or ends the domain.

A branch ends where it joins another stable branch (a segment passes a peak or valley: the
walk continues), at a fold (D = 0: the state snaps through to the stable state that the fluid
exchange between the segments reaches at that volume), or where a segment leaves its table
(the end of the domain). The snap's landing state comes from the redistribution flow of the
stored energy, the flows of all folds integrated together until each one's basin is certain
(softseq_ros.quasistatic.landing).
"""

import math

import numpy as np
from scipy.integrate import solve_ivp

from softseq_ros.quasistatic.branches import Branch, BranchEnd
from softseq_ros.quasistatic.landing import FlowLandings, Landing
from softseq_ros.quasistatic.numerics import (
    FloatArray,
    SegmentNumerics,
    cofactor_sum,
    soft_direction,
)
from softseq_ros.quasistatic.states import StateReader

# The flow's drifts on the two sides of a branch end cancel to this share of the larger: a
# pitchfork (mirror images up to round-off, or both zero), not a fold.
PITCHFORK = 1e-6
# The balance (of the pressure scale) a flow that rested where no branch is goes on to.
ROUND_OFF_REST = 1e-13


class UnplacedLandingError(RuntimeError):
    """
    A snap's flow came to rest where no branch is: ``pressure`` is the state's (its mean).

    ``came_back``: nearer the branch the flow leaves than any other (it has not left it).

    The samples can step over a stable stretch shorter than their spacing (0.0014 Pa long,
    next to a single-row peak that two identical stepped tables share): the map is then
    assembled again with that pressure sampled (softseq_ros.quasistatic.equilibrium).
    """

    def __init__(self, message: str, pressure: float, came_back: bool = False) -> None:
        super().__init__(message)
        self.pressure = pressure
        self.came_back = came_back


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


class BranchEnds:
    """Sets every branch's ``upper`` and ``lower`` end; ``reader`` reads states on branches."""

    def __init__(self, numerics: SegmentNumerics, branches: list[Branch],
                 reader: StateReader) -> None:
        """Ends of ``branches``; call :meth:`connect_all`."""
        self.numerics = numerics
        self.branches = branches
        self.reader = reader

    def connect_all(self) -> None:
        """Decide how every branch ends, upward and downward; the snaps' flows run together."""
        snaps: list[tuple[int, bool]] = []
        for index, branch in enumerate(self.branches):
            for upward in (True, False):
                end = self._joins(index, upward)
                if end is None:
                    snaps.append((index, upward))
                elif upward:
                    branch.upper = end
                else:
                    branch.lower = end
        for (index, upward), end in zip(snaps, self._snaps(snaps)):
            if upward:
                self.branches[index].upper = end
            else:
                self.branches[index].lower = end

    def _joins(self, index: int, upward: bool) -> BranchEnd | None:
        """A continuation or the end of the domain, or None: the end is a fold (a snap)."""
        if not hasattr(self, '_starts'):
            self._starts = (np.array([b.total[0] for b in self.branches]),
                            np.array([b.volumes[0] for b in self.branches]))
            self._stops = (np.array([b.total[-1] for b in self.branches]),
                           np.array([b.volumes[-1] for b in self.branches]))
        branch = self.branches[index]
        end = -1 if upward else 0
        v_end, total_end = branch.volumes[end], branch.total[end]
        totals, volumes = self._starts if upward else self._stops
        tol = self.numerics.tol_v
        near = (np.abs(totals - total_end) <= tol) & (
            np.max(np.abs(volumes - v_end), axis=1) <= tol)
        near[index] = False
        candidates = np.flatnonzero(near).tolist()
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
        return None

    def _at_edge(self, volumes: FloatArray) -> bool:
        return bool(np.any(volumes >= self.numerics.max_volumes - self.numerics.tol_v)
                    or np.any(volumes <= self.numerics.rest_volumes + self.numerics.tol_v))

    def _snaps(self, ends: list[tuple[int, bool]]) -> list[BranchEnd]:
        """
        Where the folds at some branch ends snap to, each at its own total volume.

        The fluid redistributes along the gradient flow of the stored energy on sum v = V with
        equal conductances, dv_i/dt = -(p_i - mean p): the state rolls downhill from the fold to
        the stable equilibrium whose basin it is in. The flow starts a small step off the fold,
        on the side the flow itself points to. All folds' flows run together until each basin
        is certain (softseq_ros.quasistatic.landing); a flow for which none becomes certain
        (it leaves the domain, stalls or comes to rest first) is integrated as before, alone,
        and that integration decides. The end of the domain when the flow leaves a
        segment's range.
        """
        if not ends:
            return []
        folds, starts, totals = [], [], []
        for index, upward in ends:
            branch = self.branches[index]
            end = -1 if upward else 0
            folds.append(branch.volumes[end])
            starts.append(self._flow_start(branch, branch.volumes[end]))
            totals.append(float(branch.total[end]))
        landings = FlowLandings(self.numerics, self.branches, self.reader).land(
            [index for index, _ in ends], np.array(totals), np.array(folds), np.array(starts))
        found = []
        for (index, upward), total, start, landing in zip(ends, totals, starts, landings):
            if landing.branch >= 0:
                found.append(BranchEnd('snap', landing.branch, landing.volumes))
                continue
            try:
                found.append(self._land_alone(index, total, start, landing))
            except RuntimeError as err:
                came_back = isinstance(err, UnplacedLandingError) and err.came_back
                end = self._land_stopped(index, upward, total, start, folds[len(found)],
                                         landing, came_back)
                if end is None:
                    raise
                found.append(end)
        return found

    def _land_stopped(self, index: int, upward: bool, total: float, start: FloatArray,
                      fold: FloatArray, landing: Landing, came_back: bool) -> BranchEnd | None:
        """
        The landing of a flow that stopped where no other branch holds it (None: none found).

        In turn: where the end is a corner of a plateau (_corner_starts), the steps that leave
        it; the flow on to a tighter rest; the flow integrated alone from its start (the
        flows run together can rest beside a fold where the state barely moves: a branch
        whose total changes by 3e-11 m^3 over 4 Pa); the step on the fold's other side (on a
        branch a few fold offsets long, as next to two identical tables' common valley, the
        drift's sign is round-off, and the flow can go back onto the branch it left). A flow
        that ``came_back`` to the branch it leaves is integrated alone before it goes on to a
        tighter rest: beside such a fold it would creep there (72 s on four identical stepped
        tables, against 4 s in all).
        """
        def corner() -> BranchEnd | None:
            return self._leave_corner(index, upward, total)

        def tighter_rest() -> BranchEnd | None:
            return self._go_on_from_rest(index, total, landing)

        def alone() -> BranchEnd | None:
            if landing.why not in ('rest', 'horizon'):
                return None
            return self._placed(index, total, self._flow(start))

        def other_side() -> BranchEnd | None:
            return self._placed(index, total, self._flow(2.0 * fold - start))

        steps = ((corner, alone, tighter_rest, other_side) if came_back
                 else (corner, tighter_rest, alone, other_side))
        for step in steps:
            end = step()
            if end is not None:
                return end
        return None

    def _land_alone(self, index: int, total: float, start: FloatArray,
                    landing: Landing) -> BranchEnd:
        """Where a flow that no certain basin took lands: its own end, or its integration."""
        if landing.why in ('rest', 'horizon') and not self._is_saddle(landing.volumes):
            # At rest where no ball is certain: next to a flat piece, or on a plateau (flat
            # pieces at one pressure: a neutral set, where a flow stays wherever it arrives).
            # The flow's own end says where; integrating it again with looser error control
            # would only move it along the set.
            landed = landing.volumes
        else:
            landed = self._flow(start)
            if self._at_edge(landed):
                return BranchEnd('limit')
        return self._snap_to(index, total, landed)

    def _snap_to(self, index: int, total: float, landed: FloatArray) -> BranchEnd:
        """The snap onto the branch holding ``landed`` at ``total`` (else UnplacedLandingError)."""
        target = self._nearest_branch(total, landed, exclude=index)
        return BranchEnd('snap', target, self.reader.read(target, np.array([total])).volumes[0])

    def _placed(self, index: int, total: float, landed: FloatArray) -> BranchEnd | None:
        """The domain's end where ``landed`` is at a range's edge, else its snap (None: none)."""
        if self._at_edge(landed):
            return BranchEnd('limit')
        try:
            return self._snap_to(index, total, landed)
        except RuntimeError:
            return None

    def _leave_corner(self, index: int, upward: bool, total: float) -> BranchEnd | None:
        """The first landing from the corner's steps (None: the end is no such corner)."""
        branch = self.branches[index]
        fold = branch.volumes[-1 if upward else 0]
        for start in self._corner_starts(branch, fold, upward):
            end = self._placed(index, total, self._flow(start))
            if end is not None:
                return end
        return None

    def _go_on_from_rest(self, index: int, total: float, landing: Landing) -> BranchEnd | None:
        """
        The landing of a flow that rested where no branch is, integrated on to a tighter rest.

        A balance to ``flow_rest`` counts as rest; next to a segment whose slope is nearly 0
        (a plateau's corner, in a table in steps) the flow can still be on its way there,
        slowly, with no equilibrium where it stopped. It goes on until the pressures balance
        to round-off (None: it cannot be placed then either).
        """
        return self._placed(index, total, self._integrate(landing.volumes, rest=ROUND_OFF_REST))

    def _corner_starts(self, branch: Branch, fold: FloatArray, upward: bool) -> list[FloatArray]:
        """
        Steps off a branch end where a flat segment reaches the end of its flat.

        A branch on a plateau (flat pieces at one pressure) can end at a corner of the
        neutral set rather than at a fold: every direction along the flats is as soft as any
        (stiffness 0), and the step along the soft direction may only slide the state back
        onto the set, to rest where it started. What makes the end unstable is the piece
        beyond each flat's end, the way the sweep goes (a segment that would go on down a
        falling piece runs away). Two steps push into it: along the soft direction of the
        stiffnesses with each such flat counted as the piece after it (its secant slope),
        the way the flow points; and the sweep's own, a little more fluid (or less) in every
        segment alike.
        """
        numerics = self.numerics
        k = numerics.stiffness(branch.pieces, fold[None, :])[0]
        at_end = False
        for i, (piece, a) in enumerate(zip(branch.pieces, numerics.piece_indices(branch.pieces))):
            edge = piece.v_hi if upward else piece.v_lo
            if piece.direction != 0 or abs(fold[i] - edge) > numerics.tol_v:
                continue
            pieces = numerics.pieces[i]
            beyond = a + (1 if upward else -1)
            if 0 <= beyond < len(pieces):
                at_end = True
                after = pieces[beyond]
                k[i] = (after.p_at_hi - after.p_at_lo) / (after.v_hi - after.v_lo) / \
                    numerics.k_scale
        if not at_end:
            return []
        eps = numerics.tolerances.fold_offset * numerics.v_scale
        null = soft_direction(k)
        return [fold + self._drift_sign(fold, null, eps) * eps * null,
                fold + (eps if upward else -eps) / len(numerics.segments)]

    def _flow_start(self, branch: Branch, v_fold: FloatArray) -> FloatArray:
        """
        A small step off the fold along its soft direction, the way the flow points.

        At a fold the flow points the same way on both sides (the energy along the soft
        direction is a cubic there). Where it points away on both sides alike, or nowhere
        (on flat pieces), the end is a pitchfork: identical segments at the same state, as
        on the flat rows of two identical quantised tables, where either may take the fluid.
        The tie is broken as at a join (:func:`base_first`).
        """
        k = self.numerics.stiffness(branch.pieces, v_fold[None, :])[0]
        null = soft_direction(k)
        eps = self.numerics.tolerances.fold_offset * self.numerics.v_scale
        return v_fold + self._drift_sign(v_fold, null, eps) * eps * null

    def _drift_sign(self, v_fold: FloatArray, null: FloatArray, eps: float) -> float:
        """The way the flow points along ``null`` on both sides of ``v_fold`` (ties as joins)."""

        def drift(v: FloatArray) -> float:
            p = np.array([s.pressure(x) for s, x in zip(self.numerics.segments, v)])
            return float(-np.dot(p - p.mean(), null))

        ahead, behind = drift(v_fold + eps * null), drift(v_fold - eps * null)
        if abs(ahead + behind) <= PITCHFORK * max(abs(ahead), abs(behind)):
            return base_first(null, v_fold, self.numerics.tol_v)
        return math.copysign(1.0, ahead + behind)

    def _is_saddle(self, volumes: FloatArray) -> bool:
        """
        Balanced pressures at a clearly unstable state: two falling pieces, or D < 0.

        Asked only where a flow has run to its horizon, long past the fold it started next to
        (near a fold D is about 0 and the pressures balance too).
        """
        numerics = self.numerics
        p = numerics.model_pressures(volumes[None, :])[0] / numerics.p_scale
        k = numerics.model_stiffnesses(volumes[None, :])[0] / numerics.k_scale
        return bool(np.max(np.abs(p - p.mean())) < numerics.tolerances.flow_rest
                    and (np.sum(k < 0.0) >= 2
                         or cofactor_sum(k) < -numerics.tolerances.stable_cofactor))

    def _flow(self, start: FloatArray) -> FloatArray:
        """
        The redistribution flow from ``start`` to rest, past any saddle it stops on.

        Identical segments at the same state stay identical along the flow (their equations
        are the same to the bit), so a flow from a fold where they share the fluid alike can
        only reach states where they still do: on three identical stepped tables, two of them
        past their peak together, balanced on two falling pieces (a saddle). Any real
        actuator leaves it: the flow goes on from a small step along the saddle's unstable
        direction, the tie broken as at a join (:func:`base_first`). Each saddle passed
        lowers the stored energy; at most one per segment.
        """
        eps = self.numerics.tolerances.fold_offset * self.numerics.v_scale
        landed = self._integrate(start)
        for _ in range(len(self.numerics.segments)):
            if not self._is_saddle(landed):
                break
            k = self.numerics.model_stiffnesses(landed[None, :])[0] / self.numerics.k_scale
            null = soft_direction(k)
            landed = self._integrate(
                landed + base_first(null, landed, self.numerics.tol_v) * eps * null)
        return landed

    def _integrate(self, start: FloatArray, rest: float | None = None) -> FloatArray:
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
            with np.errstate(divide='ignore'):   # a step of zero error (on flat pieces)
                sol = solve_ivp(rhs, (t, horizon), y, method='Radau', jac=jacobian,
                                rtol=tolerances.flow_rtol, atol=tolerances.flow_atol,
                                events=leaves_range)
            y, t = sol.y[:, -1], horizon
            if sol.status == 1:
                break
            # At rest means balanced pressures at a stable state (a fold is balanced too), or
            # on a plateau, where the flow has nowhere to go.
            if np.max(np.abs(rhs(t, y))) < (tolerances.flow_rest if rest is None else rest) and (
                    self._is_stable(y * scale_v) or self._on_plateau(y * scale_v)):
                break
        return np.clip(y * scale_v, lo, hi)

    def _is_stable(self, volumes: FloatArray) -> bool:
        numerics = self.numerics
        k = np.array([s.stiffness(x) for s, x in zip(numerics.segments, volumes)])
        k /= numerics.k_scale
        return bool(np.sum(k < 0.0) <= 1
                    and cofactor_sum(k) > numerics.tolerances.stable_cofactor)

    def _on_plateau(self, volumes: FloatArray) -> bool:
        """
        A neutral state (:meth:`SegmentNumerics.neutral`), where a balanced flow stays.

        Integrating on towards ever longer horizons there only lets round-off walk the state
        along the plateau, at a cost that grows tenfold per decade of time.
        """
        numerics = self.numerics
        k = numerics.model_stiffnesses(volumes[None, :]) / numerics.k_scale
        return bool(numerics.neutral(volumes[None, :], k)[0])

    def _nearest_branch(self, total: float, volumes: FloatArray, exclude: int) -> int:
        """
        The branch whose state at ``total`` is where the flow came to rest (``volumes``).

        On a plateau (segments on flat pieces at one pressure) every split of the flat
        segments' fluid is an equilibrium of the same energy; the map keeps one of them per
        total (they fill base first), and a flow comes to rest anywhere in the set, or creeps
        towards a flat's end, where the curve's slope goes to zero. So a flat segment's
        volume counts as the branch's when it lies on the branch's flat piece, and is as far
        from it as from the piece when within the landing distance of it at the flat's
        pressure (to ``plateau_pressure`` of the pressure scale): two identical tables with
        quantised pressures (flat rows at the same pressures in both) snap onto such sets.
        A table run up to its limit stretch can make that tolerance as large as a step of
        its pressures, and the distance then tells a plateau from the one a step away.
        """
        tolerances = self.numerics.tolerances
        landing = tolerances.landing_distance * self.numerics.v_scale
        on_flat = tolerances.plateau_pressure * self.numerics.p_scale
        best, best_distance, back = -1, math.inf, math.inf
        for j, other in enumerate(self.branches):
            tol = self.numerics.tol_v
            if not other.lo - tol <= total <= other.hi + tol:
                continue
            state = self.reader.read(j, np.array([min(max(total, other.lo), other.hi)])).volumes[0]
            gap = np.abs(state - volumes)
            if other.flat:
                for i, piece in enumerate(other.pieces):
                    if (piece.direction == 0
                            and piece.v_lo - landing <= volumes[i] <= piece.v_hi + landing
                            and abs(float(self.numerics.segments[i].pressure(volumes[i]))
                                    - piece.p_at_lo) <= on_flat):
                        gap[i] = max(piece.v_lo - volumes[i], volumes[i] - piece.v_hi, 0.0)
            distance = float(np.max(gap))
            if j == exclude:
                back = distance
            elif distance < best_distance:
                best, best_distance = j, distance
        # A flow that rests nearer the branch it leaves than any other has not left it (a
        # fold so flat that the flow barely moves); another branch within the landing
        # distance is then no landing.
        came_back = back < best_distance
        if best < 0 or best_distance > landing or came_back:
            raise UnplacedLandingError(
                f'snap-through at total volume {total:.9g} m^3 found no stable state to land '
                f'on (nearest {best_distance:.3g} m^3 away)',
                float(np.mean(self.numerics.model_pressures(volumes[None, :]))),
                came_back=came_back)
        return best
