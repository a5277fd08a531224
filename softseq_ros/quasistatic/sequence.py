"""
The paper's sequence types (its Fig. 1), decided in one place for solved paths and recordings.

An actuator's sequence is *asymmetric* when it snaps through, or when its deflation path leaves
its inflation path (hysteresis); otherwise, with r_i = dv_i/dV the share of the inflow each
segment takes on inflation, *symmetric* when some segment loses volume while the total grows
(the inflation turns from one segment to another), *partial* when a share changes by more than
a quarter over the range (one segment takes over) and *none* otherwise.

Only the hysteresis tolerance depends on where the paths come from: a solved path is exact to
round-off, so a gap of a millionth of the volume scale is real; a recording is sampled at the
pump's rate and its deflation is interpolated onto its inflation, so its gap must exceed a
ten-thousandth of the injected range to count.
"""

import numpy as np
from numpy.typing import ArrayLike

SEQUENCE_TYPES = ('none', 'partial', 'symmetric', 'asymmetric')
# A segment whose share of the inflow falls below this loses volume while the total grows.
SYMMETRIC_SHARE = -0.02
# A share that changes by more than this over the inflation: one segment takes over.
PARTIAL_SHARE_CHANGE = 0.25
# Deflation and inflation paths apart by more than this share of the volume scale: hysteresis.
SOLVED_HYSTERESIS_TOLERANCE = 1e-6
RECORDED_HYSTERESIS_TOLERANCE = 1e-4


def sequence_type(snapped: bool, hysteresis_gap: float, tolerance: float,
                  shares: ArrayLike) -> str:
    """
    The sequence type of one inflation and deflation.

    ``snapped``: a snap-through happened on either leg; ``hysteresis_gap``: the largest
    distance between the deflation and the inflation path (any unit) and ``tolerance`` the
    largest that still counts as one path (same unit); ``shares``: dv_i/dV on inflation, one
    row per volume step and one column per segment (snap steps may be left out).
    """
    if snapped or hysteresis_gap > tolerance:
        return 'asymmetric'
    share = np.asarray(shares, dtype=float)
    if share.size and np.min(share) < SYMMETRIC_SHARE:
        return 'symmetric'
    if share.size and np.max(np.ptp(share, axis=0)) > PARTIAL_SHARE_CHANGE:
        return 'partial'
    return 'none'
