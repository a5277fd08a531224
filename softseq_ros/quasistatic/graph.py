"""
The transition graph of an actuator: its stable branches, how each ends, and how to reach them.

Built from an :class:`~softseq_ros.quasistatic.equilibrium.EquilibriumMap`, which already holds
every stable branch of every configuration of monotone pieces and how each branch ends. Here a
branch gets its state label (per segment, the monotone piece of its curve it sits on), each end
becomes a transition (join, snap or end of the domain) with the fluid it moves between the
segments and the stored energy it releases, and a breadth-first search over (branch, direction)
says which branches a volume history reaches from rest with at most K reversals, and by which
turning volumes. docs/graph.md explains the labels, the energy and the search.
"""

from collections import deque
from dataclasses import dataclass, field
import json
from pathlib import Path
from typing import Sequence

import numpy as np
from numpy.typing import NDArray

from softseq_ros.quasistatic.equilibrium import EquilibriumMap, inflate_and_deflate
from softseq_ros.quasistatic.numerics import FloatArray
from softseq_ros.segments.models import Piece, Segment

INFLATION = 'inflation'
DEFLATION = 'deflation'
# The kinds of a branch end, named for a designer: the map's 'continue' and 'limit'.
JOIN, SNAP, END = 'join', 'snap', 'end'
_KINDS = {'continue': JOIN, 'snap': SNAP, 'limit': END}
_DIRECTION_WORDS = {1: 'rising', -1: 'falling'}
# Gauss-Legendre nodes per sub-interval of the energy quadrature and the fewest sub-intervals:
# a smooth curve's energy comes out to round-off, a table's (cubic between its rows, which are
# sub-interval ends) exactly.
_GAUSS_NODES = 8
_MIN_SUBINTERVALS = 64
_GAUSS_X, _GAUSS_W = np.polynomial.legendre.leggauss(_GAUSS_NODES)


def piece_labels(segment: Segment) -> list[str]:
    """
    Names of a segment's monotone pieces, base of the curve to top.

    'rising' or 'falling', numbered from 1 along the curve when the segment has more
    than one piece of that kind: a peak-valley curve is rising-1, falling, rising-2.
    """
    pieces = segment.monotone_pieces()
    counts = {d: sum(p.direction == d for p in pieces) for d in _DIRECTION_WORDS}
    labels, seen = [], dict.fromkeys(_DIRECTION_WORDS, 0)
    for piece in pieces:
        seen[piece.direction] += 1
        word = _DIRECTION_WORDS[piece.direction]
        labels.append(word if counts[piece.direction] == 1 else f'{word}-{seen[piece.direction]}')
    return labels


def _piece_index(segment: Segment, piece: Piece) -> int:
    pieces = segment.monotone_pieces()
    for i, candidate in enumerate(pieces):
        if candidate is piece:
            return i
    return pieces.index(piece)


def stored_energy(segments: Sequence[Segment], volumes: FloatArray) -> float:
    """
    E = sum_i integral of p_i dv from rest to v_i [J] (gauge pressures), by quadrature.

    Composite Gauss-Legendre on each segment's pressure function, split at the model's own
    knots, so the energy comes from the same curves the equilibria do; for a table, whose
    curve is cubics, their exact antiderivative (what the quadrature gives, to round-off, at a
    fraction of the cost).
    """
    return stored_energies(segments, np.asarray(volumes, dtype=float)[None, :])[0]


def stored_energies(segments: Sequence[Segment], volumes: FloatArray) -> list[float]:
    """
    :func:`stored_energy` of many states (rows of ``volumes``).

    Each segment's quadrature is built for all states at once and its pressure evaluated in
    one call: the same sub-intervals, points and sums as one state at a time.
    """
    integrals = np.zeros(volumes.shape)
    for i, segment in enumerate(segments):
        rows = np.flatnonzero(volumes[:, i] != segment.rest_volume)
        if rows.size == 0:
            continue
        if segment.pressure_cubics() is not None:
            integrals[rows, i] = (segment.energy(volumes[rows, i])
                                  - segment.energy(segment.rest_volume))
        else:
            integrals[rows, i] = _pressure_integrals(segment, volumes[rows, i])
    return [sum(row) for row in integrals.tolist()]


def _pressure_integrals(segment: Segment, ends: FloatArray) -> list[float]:
    """
    The integrals of ``segment``'s pressure from its rest volume to each of ``ends``.

    Per integral: composite Gauss-Legendre on 64 equal sub-intervals, further split at the
    model's knots inside (the sorted, distinct union of both, as one integral alone builds
    them), summed by np.sum over its (sub-intervals, nodes) block. A sub-interval from one
    knot to the next is the same in every integral: its terms are computed once.
    """
    rest = segment.rest_volume
    lo, hi = np.minimum(rest, ends), np.maximum(rest, ends)
    sign = np.where(ends > rest, 1.0, -1.0)
    even = np.linspace(lo, hi, _MIN_SUBINTERVALS + 1, axis=1)
    knots = segment.knots()
    first = np.searchsorted(knots, lo, side='right')
    count = np.searchsorted(knots, hi, side='left') - first
    # Each integral's edges in a row, sorted, padded with inf; a repeated edge is dropped.
    table = np.full((ends.size, even.shape[1] + int(count.max(initial=0))), np.inf)
    table[:, :even.shape[1]] = even
    column = np.arange(table.shape[1] - even.shape[1])
    within = column[None, :] < count[:, None]
    table[:, even.shape[1]:][within] = knots[(first[:, None] + column[None, :])[within]]
    table.sort(axis=1, kind='stable')
    keep = np.isfinite(table)
    keep[:, 1:] &= table[:, 1:] != table[:, :-1]
    row, place = np.nonzero(keep)
    edges = table[row, place]
    inner = np.flatnonzero(row[:-1] == row[1:])
    left, right = edges[inner], edges[inner + 1]
    weighted = np.empty((inner.size, _GAUSS_NODES))
    # Sub-intervals between neighbouring knots: their terms once per knot interval.
    at = np.minimum(np.searchsorted(knots, left), max(knots.size - 2, 0))
    whole = ((knots.size > 1) & (knots[at] == left) & (knots[np.minimum(at + 1, knots.size - 1)]
                                                        == right)) if knots.size else \
        np.zeros(inner.size, dtype=bool)
    used = np.unique(at[whole])
    if used.size:
        weighted[whole] = _weighted_terms(segment, knots[used], knots[used + 1])[
            np.searchsorted(used, at[whole])]
    rest_rows = np.flatnonzero(~whole)
    weighted[rest_rows] = _weighted_terms(segment, left[rest_rows], right[rest_rows])
    stops = np.cumsum(np.bincount(row[inner], minlength=ends.size))
    return [s * float(np.sum(weighted[a:b])) for s, a, b in
            zip(sign.tolist(), np.concatenate([[0], stops[:-1]]).tolist(), stops.tolist())]


def _weighted_terms(segment: Segment, left: FloatArray, right: FloatArray) -> FloatArray:
    """Gauss-Legendre terms w_k (b - a) / 2 p(x_k) of sub-intervals [a, b]: (m, nodes)."""
    left, width = left[:, None], (right - left)[:, None]
    points = left + 0.5 * width * (_GAUSS_X[None, :] + 1.0)
    return 0.5 * width * _GAUSS_W[None, :] * np.asarray(
        segment.pressure(points.ravel()), dtype=float).reshape(points.shape)


@dataclass(frozen=True)
class GraphBranch:
    """One stable branch: its injected-volume interval [m^3] and the piece of each segment."""

    index: int
    injected_lo: float
    injected_hi: float
    pieces: tuple[str, ...]      # per segment, base to tip (see piece_labels)
    pressure_lo: float           # gauge pressure at injected_lo [Pa]
    pressure_hi: float           # gauge pressure at injected_hi [Pa]
    default_path: bool

    @property
    def label(self) -> str:
        """The state in one line: the segments' pieces, base to tip."""
        return ' | '.join(self.pieces)


@dataclass(frozen=True)
class Transition:
    """
    How a branch ends in one direction of the injected volume.

    ``kind``: 'join' (the walk goes on, on ``target``: a segment passes a peak or valley
    smoothly), 'snap' (a fold: the fluid redistributes at constant total volume and lands on
    ``target``), 'end' (a segment reaches the end of its model: the domain ends; ``target``
    is None). Volumes in m^3, gauge pressures in Pa, energy in J.
    """

    source: int
    direction: str               # 'inflation' (the upper end) or 'deflation' (the lower end)
    kind: str
    target: int | None
    injected: float
    volumes_before: tuple[float, ...]
    volumes_after: tuple[float, ...]
    pressure_before: float
    pressure_after: float
    fluid_moved: float           # sum_i |dv_i| / 2
    energy_released: float       # E(before) - E(after), at the same total volume
    default_path: bool


@dataclass(frozen=True)
class Reach:
    """
    How a volume history reaches ``target`` from rest, or why none does.

    ``history``: turning volumes [m^3 injected], starting at 0 (rest): inflate to the second,
    deflate to the third and so on; the last is where to stop, on the target. ``reversals``
    counts the turns in between (None: unreachable). ``steps``: the (branch, direction) states
    on the way. ``reason``: how the answer was found.
    """

    target: int
    reversals: int | None
    history: tuple[float, ...]
    steps: tuple[tuple[int, str], ...]
    reason: str


@dataclass
class TransitionGraph:
    """Every stable branch of a scene and every transition between them."""

    segment_names: tuple[str, ...]
    piece_names: tuple[tuple[str, ...], ...]
    branches: list[GraphBranch]
    transitions: list[Transition]
    start_branch: int
    injected_range: tuple[float, float]
    _ends: dict[tuple[int, str], Transition] = field(default_factory=dict, repr=False)
    _search: dict | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        self._ends = {(t.source, t.direction): t for t in self.transitions}

    def end(self, branch: int, direction: str) -> Transition:
        """The transition where ``branch`` ends on inflation or deflation."""
        return self._ends[(branch, direction)]

    def snaps(self) -> list[Transition]:
        """The snap transitions, in the order of the branches."""
        return [t for t in self.transitions if t.kind == SNAP]

    def next_snap(self, branch: int, direction: str) -> Transition | None:
        """The first snap a monotone history meets from ``branch`` on (through joins)."""
        seen = set()
        while (branch, direction) not in seen:
            seen.add((branch, direction))
            end = self.end(branch, direction)
            if end.kind == SNAP:
                return end
            if end.kind == END:
                return None
            branch = end.target
        return None

    # ------------------------------------------------------------------ reachability

    def _explore(self) -> dict:
        """
        0-1 breadth-first search over (branch, direction) from rest, once.

        Moving on in the same direction (a join or a snap at the branch's end) costs nothing;
        turning (inflating after deflating, or back) costs one reversal. Each state keeps the
        part of its branch a history covers on arrival: from where it entered to the end it
        moves towards. The states are finite (two per branch), so the search exhausts them.
        """
        if self._search is not None:
            return self._search
        start = (self.start_branch, INFLATION)
        first = self.branches[self.start_branch]
        cost = {start: 0}
        entry = {start: first.injected_lo}
        parent: dict[tuple[int, str], tuple[tuple[int, str], str] | None] = {start: None}
        queue = deque([start])
        done = set()
        while queue:
            node = queue.popleft()
            if node in done:
                continue
            done.add(node)
            branch, direction = node
            moves = []
            end = self.end(branch, direction)
            if end.kind != END:
                moves.append(((end.target, direction), 0, end.injected, end.kind))
            turned = DEFLATION if direction == INFLATION else INFLATION
            moves.append(((branch, turned), 1, self._turning_volume(node, entry[node]),
                          'reversal'))
            for nxt, weight, where, how in moves:
                new = cost[node] + weight
                if nxt not in cost or new < cost[nxt]:
                    cost[nxt], entry[nxt], parent[nxt] = new, where, (node, how)
                    if weight == 0:
                        queue.appendleft(nxt)
                    else:
                        queue.append(nxt)
        self._search = {'cost': cost, 'entry': entry, 'parent': parent}
        return self._search

    def _turning_volume(self, node: tuple[int, str], entered: float) -> float:
        """Halfway between where a history enters the branch and the end it moves towards."""
        branch = self.branches[node[0]]
        far = branch.injected_hi if node[1] == INFLATION else branch.injected_lo
        return entered + 0.5 * (far - entered)

    def min_reversals(self) -> dict[int, int | None]:
        """Per branch, the fewest reversals of a history from rest that reaches it (None: none)."""
        cost = self._explore()['cost']
        best: dict[int, int | None] = {b.index: None for b in self.branches}
        for (branch, _), c in cost.items():
            if best[branch] is None or c < best[branch]:
                best[branch] = c
        return best

    def reachable(self, max_reversals: int) -> set[int]:
        """The branches a history from rest with at most ``max_reversals`` reversals reaches."""
        return {b for b, c in self.min_reversals().items()
                if c is not None and c <= max_reversals}

    def history_to(self, target: int, direction: str | None = None) -> Reach:
        """
        One shortest history (fewest reversals) from rest onto branch ``target``, or why not.

        With ``direction`` ('inflation' or 'deflation') the history's last leg moves that way.
        """
        if not 0 <= target < len(self.branches):
            raise ValueError(f'branch {target} does not exist (0 to {len(self.branches) - 1})')
        if direction not in (None, INFLATION, DEFLATION):
            raise ValueError(f"direction must be 'inflation' or 'deflation', got {direction!r}")
        search = self._explore()
        cost, entry, parent = search['cost'], search['entry'], search['parent']
        ends = [(target, d) for d in (INFLATION, DEFLATION)
                if (target, d) in cost and direction in (None, d)]
        if not ends:
            return Reach(target, None, (), (), (
                f'no history reaches branch {target}: all {len(cost)} (branch, direction) '
                f'states a history from rest can be in (of {2 * len(self.branches)}), closed '
                'under joins, snaps and reversals, were explored and none is on it'))
        node = min(ends, key=lambda n: cost[n])
        steps, turns = [node], []
        while parent[steps[-1]] is not None:
            before, how = parent[steps[-1]]
            if how == 'reversal':
                turns.append(entry[steps[-1]])
            steps.append(before)
        steps.reverse()
        turns.reverse()
        last = self._turning_volume(node, entry[node])
        history = (self.branches[self.start_branch].injected_lo, *turns, last)
        return Reach(target, cost[node], tuple(float(v) for v in history), tuple(steps),
                     f'fewest reversals by a breadth-first search over {len(cost)} '
                     '(branch, direction) states')

    def history_across(self, transition: Transition) -> Reach | None:
        """
        A shortest history from rest that passes ``transition`` and stops just beyond it.

        It reaches the transition's branch moving its way, then goes on to halfway between the
        transition's volume and the far end of the branch it leads to. None when no history
        reaches it, or for the end of the domain (nothing lies beyond).
        """
        if transition.target is None:
            return None
        reach = self.history_to(transition.source, transition.direction)
        if reach.reversals is None:
            return None
        target = self.branches[transition.target]
        far = (target.injected_hi if transition.direction == INFLATION
               else target.injected_lo)
        beyond = transition.injected + 0.5 * (far - transition.injected)
        return Reach(transition.target, reach.reversals, (*reach.history[:-1], beyond),
                     (*reach.steps, (transition.target, transition.direction)), reach.reason)

    # ------------------------------------------------------------------ output

    def to_dict(self, max_reversals: int | None = None) -> dict:
        """The graph as JSON-ready data: SI units named in the keys (m3, pa, j)."""
        least = self.min_reversals()
        branches = []
        for b in self.branches:
            reach = self.history_to(b.index)
            entry = {
                'index': b.index, 'label': b.label,
                'pieces': dict(zip(self.segment_names, b.pieces)),
                'injected_lo_m3': b.injected_lo, 'injected_hi_m3': b.injected_hi,
                'gauge_pressure_lo_pa': b.pressure_lo, 'gauge_pressure_hi_pa': b.pressure_hi,
                'default_path': b.default_path,
                'min_reversals': least[b.index],
                'history_injected_m3': list(reach.history) if reach.reversals is not None
                else None,
                'reach': reach.reason,
            }
            if max_reversals is not None:
                entry['reachable_within_reversals'] = (least[b.index] is not None
                                                       and least[b.index] <= max_reversals)
            branches.append(entry)
        transitions = [{
            'source': t.source, 'direction': t.direction, 'kind': t.kind, 'target': t.target,
            'injected_m3': t.injected,
            'volumes_before_m3': dict(zip(self.segment_names, t.volumes_before)),
            'volumes_after_m3': dict(zip(self.segment_names, t.volumes_after)),
            'gauge_pressure_before_pa': t.pressure_before,
            'gauge_pressure_after_pa': t.pressure_after,
            'fluid_moved_m3': t.fluid_moved, 'energy_released_j': t.energy_released,
            'default_path': t.default_path,
        } for t in self.transitions]
        return {
            'segments': list(self.segment_names),
            'pieces': {n: list(p) for n, p in zip(self.segment_names, self.piece_names)},
            'start_branch': self.start_branch,
            'injected_range_m3': list(self.injected_range),
            'max_reversals': max_reversals,
            'branches': branches,
            'transitions': transitions,
        }


def transition_graph(emap: EquilibriumMap) -> TransitionGraph:
    """The transition graph of an assembled map; marks the default inflate-then-deflate path."""
    segments = emap.segments
    rest = emap.total_rest_volume
    on_path = _default_path(emap)
    visited = {b for b, _ in on_path} | {t for _, t in on_path.values() if t is not None}
    branches = []
    for i, branch in enumerate(emap.branches):
        labels = tuple(piece_labels(s)[_piece_index(s, pc)]
                       for s, pc in zip(segments, branch.pieces))
        branches.append(GraphBranch(i, branch.lo - rest, branch.hi - rest, labels,
                                    float(branch.pressure[0]), float(branch.pressure[-1]),
                                    i in visited))
    transitions = _transitions(emap, on_path)
    return TransitionGraph(tuple(s.name for s in segments),
                           tuple(tuple(piece_labels(s)) for s in segments), branches,
                           transitions, emap.start_branch,
                           (float(emap.injected_range[0]), float(emap.injected_range[1])))


def _default_path(emap: EquilibriumMap) -> dict[tuple[int, str], tuple[str, int | None]]:
    """
    The branch ends inflate_and_deflate passes, each with its kind and target.

    A walk through the ends (a sweep's samples could step over a short branch), from where
    the sweep's two legs start.
    """
    inflation, deflation = inflate_and_deflate(emap, samples=2)
    passed: dict[tuple[int, str], tuple[str, int | None]] = {}
    for start, direction in ((int(inflation.branch[0]), INFLATION),
                             (int(deflation.branch[0]), DEFLATION)):
        index = start
        while (index, direction) not in passed:
            branch = emap.branches[index]
            end = branch.upper if direction == INFLATION else branch.lower
            target = None if end.kind == 'limit' else end.target
            passed[(index, direction)] = (end.kind, target)
            if target is None:
                break
            index = target
    return passed


def _transitions(emap: EquilibriumMap, on_path: dict) -> list[Transition]:
    """Both ends of every branch as transitions; the states they read, read once per branch."""
    ends = []
    wanted: dict[int, list[float]] = {}
    for index, branch in enumerate(emap.branches):
        for direction in (INFLATION, DEFLATION):
            upward = direction == INFLATION
            end = branch.upper if upward else branch.lower
            total = branch.hi if upward else branch.lo
            kind = _KINDS[end.kind]
            target = None if kind == END else end.target
            ends.append((index, direction, kind, target, total))
            wanted.setdefault(index, []).append(total)
            if kind == SNAP:
                wanted.setdefault(target, []).append(total)
    pairs = [(index, total) for index, totals in wanted.items() for total in totals]
    rows = emap.member_reader.rows_many(np.array([p[0] for p in pairs], dtype=np.intp),
                                        np.array([p[1] for p in pairs]))
    members, n = len(emap.members), len(emap.segments)
    states = {pair: (row[:members], float(row[members])) for pair, row in zip(pairs, rows)}
    snaps = [(states[(i, total)][0], states[(target, total)][0])
             for i, _, kind, target, total in ends if kind == SNAP]
    # Both states of a snap hold the same total volume (the piston stands still), so the
    # released energy is the drop of the members' stored energy: the segments', and a
    # compliant supply line's (its gas expands into the segments, or is compressed).
    energies = iter(stored_energies(emap.members, np.array([v for pair in snaps
                                                            for v in pair]))
                    if snaps else [])
    transitions = []
    for index, direction, kind, target, total in ends:
        v_before, p_before = states[(index, total)]
        v_after, p_after = v_before, p_before
        moved = released = 0.0
        if kind == SNAP:
            v_after, p_after = states[(target, total)]
            moved = 0.5 * float(np.sum(np.abs(v_after - v_before)))
            released = next(energies) - next(energies)
        transitions.append(Transition(
            index, direction, kind, target, total - emap.total_rest_volume,
            tuple(float(v) for v in v_before[:n]), tuple(float(v) for v in v_after[:n]), p_before,
            p_after, moved, released, (index, direction) in on_path))
    return transitions


def write_graph_json(path: str | Path, graph: TransitionGraph,
                     max_reversals: int | None = None) -> None:
    """Write :meth:`TransitionGraph.to_dict` as JSON."""
    Path(path).write_text(json.dumps(graph.to_dict(max_reversals), indent=1) + '\n',
                          encoding='utf-8')


def branch_labels(emap: EquilibriumMap) -> list[str]:
    """Each branch's state label (as :attr:`GraphBranch.label`), without building the graph."""
    per_segment = [piece_labels(s) for s in emap.segments]
    return [' | '.join(labels[_piece_index(s, piece)]
                       for labels, s, piece in zip(per_segment, emap.segments, branch.pieces))
            for branch in emap.branches]


def nearest_branches(emap: EquilibriumMap, volumes: FloatArray,
                     pressures: FloatArray | None = None) -> NDArray[np.int64]:
    """
    For each recorded state (segment volumes, one row each), the stable branch nearest to it.

    Only the branches whose total-volume interval holds the row's total are candidates; among
    them the one whose state at that total is nearest (largest difference of a segment's
    volume). -1 where no branch holds the total (a state outside the map's range). A rig's
    quasi-static states lie on their branch; a dynamic run's states between equilibria are
    given the branch they are closest to.

    With a supply line (``emap.supply``) a state's total is the segments' fluid and what the
    line holds at the state's gauge pressure (``pressures``, one per row, needed then).
    """
    volumes = np.atleast_2d(np.asarray(volumes, dtype=float))
    totals = volumes.sum(axis=1)
    if emap.supply is not None:
        if pressures is None:
            raise ValueError("with a supply line the states' pressures are needed too")
        totals = totals + emap.supply.taken_up(np.asarray(pressures, dtype=float))
    lo, hi = emap.injected_range
    slack = 1e-9 * max(hi - lo, 1e-300)
    best = np.full(len(totals), np.inf)
    nearest = np.full(len(totals), -1, dtype=np.int64)
    for index, branch in enumerate(emap.branches):
        holds = np.flatnonzero((branch.lo - slack <= totals) & (totals <= branch.hi + slack))
        if holds.size == 0:
            continue
        states = emap.read(index, np.clip(totals[holds], branch.lo, branch.hi)).volumes
        distance = np.max(np.abs(states - volumes[holds]), axis=1)
        closer = distance < best[holds]
        best[holds[closer]] = distance[closer]
        nearest[holds[closer]] = index
    return nearest


def visits(emap: EquilibriumMap, time_s: FloatArray, volumes: FloatArray,
           pressures: FloatArray | None = None) -> list[dict]:
    """
    The branches a recording visited, in order: each stay with its start and end time [s].

    ``pressures`` (gauge) as :func:`nearest_branches` needs them with a supply line.
    """
    nearest = nearest_branches(emap, volumes, pressures)
    labels = branch_labels(emap)
    stays: list[dict] = []
    for row, branch in enumerate(nearest):
        if branch < 0:
            continue
        if stays and stays[-1]['branch'] == branch:
            stays[-1]['until_s'] = float(time_s[row])
            continue
        stays.append({'branch': int(branch), 'state': labels[branch],
                      'from_s': float(time_s[row]), 'until_s': float(time_s[row])})
    return stays
