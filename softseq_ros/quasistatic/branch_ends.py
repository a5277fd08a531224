"""
How stable branches end: a walk continues on another branch, snaps through, or ends the domain.

A branch ends where it joins another stable branch (a segment passes a peak or valley: the
walk continues), at a fold (D = 0: the state snaps through to the stable state that the fluid
exchange between the segments reaches at that volume), or where a segment leaves its table
(the end of the domain). Where a snap lands is the landing's business
(softseq_ros.quasistatic.landing: the redistribution flow of the stored energy, the flows of
all folds integrated together); this module only finds which ends are folds.
"""

import numpy as np

from softseq_ros.quasistatic.branches import Branch, BranchEnd
from softseq_ros.quasistatic.landing import SnapLandings
from softseq_ros.quasistatic.numerics import SegmentNumerics
from softseq_ros.quasistatic.states import StateReader


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
        landed = SnapLandings(self.numerics, self.branches, self.reader).land(snaps)
        for (index, upward), end in zip(snaps, landed):
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
        if self.numerics.at_edge(v_end):
            return BranchEnd('limit')
        return None
