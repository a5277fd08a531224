"""
What a box of segment designs can reach: sound bounds on the pressure of any pair in the box.

``softseq design`` refuses a target the parameter ranges cannot reach before it searches. The
bounds here rest on one premise, which is physics and is checked where it can be (at the
corners before the search, on the whole grid after it): at the same fluid volume per unit cell,
a thicker membrane or wall needs at least as much pressure, a longer membrane at most as much.
Each segment's box then has a softest corner (thinnest, longest membrane) whose cell curve lies
below every other design's and a stiffest one whose curve lies above.

Two things keep the bounds sound where the curves are not monotone:

- **Membrane count.** A segment is its unit cell times four times its membrane count n, which
  jumps where a longer membrane leaves room for one fewer (the pressure at a segment volume is
  then not monotone in the membrane length). A design holding U has its cells at U / (4 n),
  somewhere in [U / (4 n_most), U / (4 n_fewest)].
- **Envelopes.** A segment's pressure along its volume may have peaks and valleys. The upper
  bound M(U) is the stiff cell's largest pressure at cell volumes up to U / (4 n_fewest); the
  lower bound at an equilibrium of total volume V, where no segment holds more than V, is the
  soft cell's least pressure at cell volumes from U / (4 n_most) to V / (4 n_fewest): m_V(U).
  Both are nondecreasing in U. Between table rows the tables are read with PCHIP, which keeps
  each interval between its two rows' values but may bulge past the straight line between
  them: so the rows bracketing a range count whole.

For any equilibrium of the pair at total injected volume V with pressure P and volumes U_i:
m_V,i(U_i) <= P <= M_i(U_i) and sum U_i = V. Hence V <= sum_i A_i(P), A_i(P) =
sup{U <= V : m_V,i(U) <= P}, and V >= sum_i B_i(P), B_i(P) = inf{U : M_i(U) >= P}: the pressure
at V lies between P_low(V) = inf{P : sum A_i(P) >= V} and P_high(V) = sup{P : sum B_i(P) <= V},
whichever branch the path is on, snaps included. Every rounding (volumes on a grid) is taken
to the side that widens the band.

What follows for the target's numbers (:mod:`softseq_ros.fem.design_reach`): the plateau
(the largest pressure on the path up to V_end) lies in [P_low(V_end), P_high(V_max)]; the volume
from which the pressure is within 1 % of its plateau lies between the first V where P_high
reaches 99 % of the lowest plateau and the first where P_low reaches 99 % of the highest. The
switch volume, the leader and the sequence type depend on the slopes of both curves, not on
their levels, and are bounded by nothing here.
"""

from dataclasses import dataclass

import numpy as np

# Samples of a segment's volume range.
VOLUME_SAMPLES = 2001
# A corner pair contradicts the premise when the stiff cell's pressure falls below the soft
# one's by more than this (Pa, or this share of the pressure, whichever is larger).
PREMISE_TOLERANCE_PA = 1.0
PREMISE_TOLERANCE_SHARE = 2e-3


@dataclass(frozen=True)
class SegmentEnvelope:
    """
    Bounds on the pressure of every design of a segment's box (see the module).

    Its cells lie between ``soft_*`` and the stiff table behind ``upper`` (cell injected volume
    [m^3], pressure [Pa]), its membrane count in [``fewest``, ``most``].
    """

    volumes: np.ndarray   # samples of the segment's injected volume [m^3], 0 to v_max
    upper: np.ndarray     # M(U) at the samples, nondecreasing; inf past the stiff table
    soft_u: np.ndarray    # the soft cell's rows: injected volume [m^3]
    soft_p: np.ndarray    # and pressure [Pa]
    fewest: int
    most: int

    def lower(self, total: float) -> np.ndarray:
        """
        m_V(U) at the samples for an equilibrium of total volume ``total`` (V), nondecreasing.

        The least row pressure from the last row below U / (4 n_most) to the first row beyond
        V / (4 n_fewest); 0 (nothing known) when V / (4 n_fewest) lies past the soft table.
        """
        u, p = self.soft_u, self.soft_p
        reach = total / (4 * self.fewest)
        if reach > u[-1]:
            return np.zeros(self.volumes.size)
        last = min(int(np.searchsorted(u, reach, side='right')), u.size - 1)
        suffix = np.minimum.accumulate(p[:last + 1][::-1])[::-1]
        first = np.searchsorted(u, self.volumes / (4 * self.most), side='left') - 1
        return suffix[np.clip(first, 0, last)]


def segment_envelope(soft: tuple[np.ndarray, np.ndarray], stiff: tuple[np.ndarray, np.ndarray],
                     fewest: int, most: int, v_max: float) -> SegmentEnvelope:
    """
    The bounds of a segment of the box, over 0 to ``v_max`` injected into it.

    Its cells lie between ``soft`` and ``stiff`` (cell injected volume [m^3], pressure [Pa]),
    its membrane count in [``fewest``, ``most``].
    """
    volumes = np.linspace(0.0, v_max, VOLUME_SAMPLES)
    cell_u, pressures = stiff
    w = volumes / (4 * fewest)
    after = np.clip(np.searchsorted(cell_u, w, side='right'), 0, cell_u.size - 1)
    upper = np.where(w > cell_u[-1], np.inf, np.maximum.accumulate(pressures)[after])
    return SegmentEnvelope(volumes, upper, np.asarray(soft[0]), np.asarray(soft[1]), fewest,
                           most)


def premise_violation(soft: tuple[np.ndarray, np.ndarray],
                      stiff: tuple[np.ndarray, np.ndarray]) -> tuple[float, float]:
    """
    How far the stiff cell's pressure falls below the soft one's, and where.

    The excess beyond the tolerance [Pa] (0 when there is none) and the cell volume [m^3];
    compared at both tables' rows within their common range.
    """
    end = min(soft[0][-1], stiff[0][-1])
    at = np.unique(np.concatenate([soft[0], stiff[0]]))
    at = at[at <= end]
    p_soft = np.interp(at, *soft)
    p_stiff = np.interp(at, *stiff)
    allowed = np.maximum(PREMISE_TOLERANCE_PA, PREMISE_TOLERANCE_SHARE * np.abs(p_soft))
    excess = p_soft - p_stiff - allowed
    worst = int(np.argmax(excess))
    return (float(excess[worst]), float(at[worst])) if excess[worst] > 0 else (0.0, 0.0)


def pressure_band(envelopes: list[SegmentEnvelope], totals: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """
    P_low and P_high [Pa] at each total injected volume of ``totals`` [m^3] (see the module).

    The pressure of any equilibrium of segments within these envelopes lies between them;
    P_high is inf where the stiff tables end before they bound it.
    """
    totals = np.atleast_1d(np.asarray(totals, dtype=float))
    p_low = np.empty(totals.size)
    for index, total in enumerate(totals):
        lowers = [e.lower(total) for e in envelopes]
        candidates = np.unique(np.concatenate(lowers + [[0.0]]))
        holds = np.zeros(candidates.size)     # sum A_i(P): the most the segments hold at P
        for e, lower in zip(envelopes, lowers):
            # A_i(P): beyond the last sample where m <= P lies at most the next sample; no
            # segment holds more than the total.
            k = np.searchsorted(lower, candidates, side='right') - 1
            holds += np.minimum(e.volumes[np.clip(k + 1, 0, e.volumes.size - 1)], total)
        # A steps at the lower bound's values, so the infimum is one of them.
        first = int(np.searchsorted(holds, total, side='left'))
        p_low[index] = candidates[min(first, candidates.size - 1)]

    candidates = np.unique(np.concatenate([e.upper[np.isfinite(e.upper)] for e in envelopes]
                                          + [[0.0]]))
    needs = np.zeros(candidates.size)         # sum B_i(P): the least they need to reach P
    needs_beyond = 0.0                        # the same above every candidate
    for e in envelopes:
        last = e.volumes.size - 1
        # B_i(P): before the first sample where M >= P lies at least the one before it; a
        # pressure M never reaches within the range needs more fluid than there is.
        k = np.searchsorted(e.upper, candidates, side='left')
        needs += np.where(k > last, np.inf, e.volumes[np.clip(k - 1, 0, last)])
        unknown = np.nonzero(np.isinf(e.upper))[0]
        needs_beyond += e.volumes[max(unknown[0] - 1, 0)] if unknown.size else np.inf
    # B is constant between candidates and steps just above one, so the supremum is the
    # largest candidate whose need still fits; above them all, unbounded if it fits there.
    fits = np.searchsorted(needs, totals, side='right') - 1
    top = np.where(needs_beyond <= totals, np.inf, candidates[-1])
    p_high = np.where(fits >= candidates.size - 1, top, candidates[np.clip(fits, 0, None)])
    return p_low, p_high
