"""
The hardware-encoded inflation sequence: equilibria of connected segments and their history.

Segments share one fluid supply, so at quasi-static equilibrium all pressures are equal and the
volumes add up to the total V. Each segment's PV curve splits into monotone pieces; choosing one
piece per segment (a *configuration*) makes every volume a function of the common pressure p, so
the equilibrium set is a union of curves parametrised by p. This is the paper's "assembling
algorithm", done once per scene in :class:`EquilibriumMap` from these stages: the stable
stretches of every configuration (softseq_ros.quasistatic.assembly), fitted as branches
(softseq_ros.quasistatic.branches), how each branch ends and where a snap lands
(softseq_ros.quasistatic.branch_ends, softseq_ros.quasistatic.landing), and reading states off
the branches (softseq_ros.quasistatic.states).

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

from dataclasses import dataclass, field, replace
import math
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from softseq_ros.errors import UserError
from softseq_ros.quasistatic.assembly import Assembly, EquilibriumCurve
from softseq_ros.quasistatic.branch_ends import BranchEnds
from softseq_ros.quasistatic.branches import Branch
from softseq_ros.quasistatic.numerics import FloatArray, SegmentNumerics
from softseq_ros.quasistatic.sequence import (
    SEQUENCE_TYPES,
    SOLVED_HYSTERESIS_TOLERANCE,
    sequence_type,
)
from softseq_ros.quasistatic.states import SegmentStates, StatePoint, StateReader, StateRows
from softseq_ros.segments.models import Segment
from softseq_ros.tolerances import DEFAULT_TOLERANCES, Tolerances

__all__ = ['DomainError', 'EquilibriumCurve', 'EquilibriumMap', 'SEQUENCE_TYPES', 'SnapEvent',
           'SolvedPath', 'State', 'StatePoint', 'StateRows', 'Tracker', 'classify',
           'inflate_and_deflate']



class DomainError(UserError):
    """
    A commanded volume outside what the segments' models cover.

    Raised at the end of a branch, it says where: ``edge_injected`` [m^3] and
    ``edge_volumes`` [m^3], the state at the edge (one segment is at the end of its model).
    """

    def __init__(self, message: str, edge_injected: float | None = None,
                 edge_volumes: FloatArray | None = None, row: int | None = None) -> None:
        """The message, the domain's edge when known, and the history row (a sweep's)."""
        super().__init__(message)
        self.edge_injected = edge_injected
        self.edge_volumes = edge_volumes
        self.row = row


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
class SolvedPath:
    """
    States along a history of commanded volumes, one row per command.

    ``converged``: every iterative solve of the map so far (its assembly and every read,
    this path's included) reached round-off within its budget (softseq_ros.tolerances).
    """

    injected: FloatArray
    pressure: FloatArray
    volumes: FloatArray
    curvatures: FloatArray
    branch: NDArray[np.int64]
    snap: NDArray[np.bool_]
    events: list[SnapEvent]
    converged: bool = True


class EquilibriumMap:
    """
    The equilibrium set of connected segments, assembled once.

    ``resolution`` is the number of samples that each segment's PV curve contributes across its
    whole volume range (more samples: smaller interpolation error, longer assembly).
    ``polish`` (default on) solves the states next to folds exactly; off, they are
    interpolated linearly between the branch's samples. ``tolerances`` are the iterative
    solves' budgets (softseq_ros.tolerances); ``convergence`` logs whether they converged, in
    the assembly and in every read since.

    ``supply`` (softseq_ros.segments.supply): a compliant syringe line, one more member of the
    equilibrium after the segments. The injected volume is then the piston's displacement,
    the segments' fluid plus what the line takes up. ``members`` are the segments and the
    supply; ``segments``, the states read (:attr:`reader`, :meth:`read`, :meth:`curvatures`)
    and the volume ranges are the segments' alone, while the branches, their stability, the
    landings and :attr:`member_reader` hold every member.
    """

    def __init__(self, segments: Sequence[Segment], resolution: int = 2000,
                 polish: bool = True, tolerances: Tolerances = DEFAULT_TOLERANCES,
                 supply: Segment | None = None) -> None:
        """Assemble the equilibrium set of ``segments`` (base to tip) and the ``supply``."""
        if len(segments) < 2:
            raise ValueError(f'an actuator needs at least 2 segments, got {len(segments)}')
        if resolution < 16:
            raise ValueError(f'resolution must be >= 16, got {resolution}')
        members = (*segments, *(() if supply is None else (supply,)))
        numerics = SegmentNumerics(members, tolerances)
        count = len(segments)
        self.numerics = numerics
        self.tolerances = tolerances
        self.convergence = numerics.convergence
        self.members = tuple(numerics.segments)
        self.segments = self.members[:count]
        self.supply = supply
        self.resolution = int(resolution)
        self.polish = bool(polish)
        self.rest_volumes = numerics.rest_volumes[:count]
        self.max_volumes = numerics.max_volumes[:count]
        self.total_rest_volume = numerics.total_rest_volume
        self.v_scale = numerics.v_scale
        self.p_scale = numerics.p_scale
        self._tol_v = numerics.tol_v
        assembly = Assembly(numerics, self.resolution)
        self.branches: list[Branch] = assembly.branches
        if not self.branches:
            falling = [segment.name for segment in segments
                       if not segment.monotone_pieces()
                       or segment.monotone_pieces()[0].direction < 0]
            why = (f': the pressure of {", ".join(falling)} falls from rest' if falling
                   else '')
            raise UserError(f'these segments have no stable equilibrium at all{why}')
        self.member_reader = StateReader(numerics, self.branches, self.polish)
        BranchEnds(numerics, self.branches, self.member_reader).connect_all()
        self.reader = (self.member_reader if supply is None
                       else SegmentStates(self.member_reader, count))
        # How many piece configurations the assembly examined, of the product of every
        # segment's piece count (a brute-force enumeration's).
        self.configurations_tried = len(assembly.configurations)
        self.configurations_possible = math.prod(len(p) for p in numerics.pieces)
        self._assembly = assembly
        self.read = self.reader.read
        self._lo = np.array([b.lo for b in self.branches])
        self._hi = np.array([b.hi for b in self.branches])
        self.start_branch = int(np.argmin(self._lo))
        self.injected_range = (self.branches[self.start_branch].lo - self.total_rest_volume,
                               self._inflation_limit() - self.total_rest_volume)

    def _inflation_limit(self) -> float:
        index, seen = self.start_branch, set()
        while index not in seen:
            seen.add(index)
            upper = self.branches[index].upper
            if upper.kind == 'limit':
                break
            index = upper.target
        return self.branches[index].hi

    # ------------------------------------------------------------------ queries

    def curvatures(self, volumes: FloatArray) -> FloatArray:
        """Per-segment curvature for volumes (n, N) of the segments, in 1/m."""
        return self.numerics.curvatures(volumes)

    def equilibrium_set(self) -> list[EquilibriumCurve]:
        """Every configuration's equilibria, stable and unstable (Fig. 1B / 4B): the segments'."""
        count = len(self.segments)
        return [replace(curve, volumes=curve.volumes[:, :count])
                for curve in self._assembly.curves()]

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
        distances = [np.max(np.abs(self.read(int(j), np.array([total])).volumes[0] - target))
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
                edge_volumes = emap.read(self.branch, edge).volumes
                self.branch, self.total = before
                raise DomainError(
                    f'injected volume {total - emap.total_rest_volume:.6g} m^3 is beyond what '
                    f'the segment models cover on this branch (it ends at '
                    f'{edge - emap.total_rest_volume:.6g} m^3)',
                    edge - emap.total_rest_volume, np.array(edge_volumes, dtype=float))
            if end.kind == 'snap':
                from_v = branch.volumes[-1 if upward else 0, :len(emap.segments)]
                from_p = float(branch.pressure[-1 if upward else 0])
                landed = emap.read(end.target, np.array([edge]))
                events.append(SnapEvent(edge - emap.total_rest_volume, from_v.copy(),
                                        landed.volumes[0], from_p, float(landed.pressure[0])))
            self.branch = end.target
            self.total = edge
        raise RuntimeError('branch-end rules form a cycle; the equilibrium set is inconsistent')

    @property
    def state(self) -> State:
        """The current state."""
        point = self.emap.read(self.branch, self.total)
        return State(self.total - self.emap.total_rest_volume, point.pressure,
                     np.array(point.volumes), np.array(point.curvatures), self.branch)

    def step(self, injected: float) -> State:
        """Go to a commanded injected volume; the state reports the snaps on the way."""
        snaps = self.move(injected)
        state = self.state
        state.snaps = snaps
        return state

    def move(self, injected: float) -> list[SnapEvent]:
        """
        ``step`` without building the State: go there, return the snaps on the way.

        ``emap.read(tracker.branch, tracker.total)`` then gives the state's numbers.
        """
        if not math.isfinite(injected):
            raise DomainError(f'commanded injected volume must be finite, got {injected}')
        return self._walk(float(injected) + self.emap.total_rest_volume)

    def sweep(self, injected: ArrayLike) -> SolvedPath:
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
            try:
                new_events = self._walk(float(totals[i + j]))
            except DomainError as err:
                raise DomainError(f'row {i + j}: {err}', err.edge_injected, err.edge_volumes,
                                  i + j) from None
            if new_events:
                snap[i + j] = True
                events.extend(new_events)
            branch_ids[i + j] = self.branch
            i += j + 1
            window = 256
        segments = len(emap.segments)
        if np.all(branch_ids == branch_ids[0]) if n else True:
            values = (emap.reader.rows(int(branch_ids[0]),
                                       self._on_branch(int(branch_ids[0]), totals)) if n
                      else np.empty((0, 2 * segments + 1)))
        else:
            values = np.empty((n, 2 * segments + 1))
            for b in np.unique(branch_ids):
                rows = np.flatnonzero(branch_ids == b)
                values[rows] = emap.reader.rows(int(b), self._on_branch(int(b), totals[rows]))
        return SolvedPath(commands, values[:, segments], values[:, :segments],
                          values[:, segments + 1:], branch_ids, snap, events,
                          emap.convergence.converged)

    def _on_branch(self, index: int, totals: FloatArray) -> FloatArray:
        """Totals clipped to a branch: a command at a domain edge may pass it by round-off."""
        branch = self.emap.branches[index]
        return np.clip(totals, branch.lo, branch.hi)


def inflate_and_deflate(emap: EquilibriumMap, samples: int = 4001) -> tuple[SolvedPath,
                                                                              SolvedPath]:
    """
    Sweep an assembly from rest to the end of its range and back down: (inflation, deflation).

    Inflation follows ``samples`` evenly spaced injected volumes over ``emap.injected_range``
    from rest; deflation starts where it ended and follows the same volumes in reverse, so row
    ``i`` of the deflation is at the volume of row ``samples - 1 - i`` of the inflation.
    """
    lo, hi = emap.injected_range
    up = np.linspace(lo, hi, samples)
    inflation = Tracker(emap).sweep(up)
    deflation = Tracker(emap, injected=hi, volumes=inflation.volumes[-1]).sweep(up[::-1])
    return inflation, deflation


def classify(emap: EquilibriumMap, samples: int = 4001) -> str:
    """
    The paper's sequence type of an actuator (Fig. 1): none, partial, symmetric or asymmetric.

    Inflate over the whole range and deflate back, then apply the rules of
    :func:`softseq_ros.quasistatic.sequence.sequence_type` to the solved paths.
    """
    return sweep_sequence_type(emap, *inflate_and_deflate(emap, samples))


def sweep_sequence_type(emap: EquilibriumMap, inflation: SolvedPath,
                        deflation: SolvedPath) -> str:
    """
    The sequence type of a sweep of :func:`inflate_and_deflate` (what :func:`classify` returns).

    For a caller that keeps the sweep's paths for other numbers: one sweep, not two.
    """
    gap = np.max(np.abs(inflation.volumes - deflation.volumes[::-1]))
    share = np.diff(inflation.volumes, axis=0) / np.diff(inflation.injected)[:, None]
    return sequence_type(bool(inflation.events or deflation.events), float(gap),
                         SOLVED_HYSTERESIS_TOLERANCE * emap.v_scale, share)

