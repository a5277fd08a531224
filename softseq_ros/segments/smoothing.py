"""
Opt-in smoothing of measured pressure-volume tables (rig data with sensor noise).

Noise on a table row makes local peaks and valleys that the solver takes for real: each becomes a
monotone piece, and where a segment's curve is nearly flat (a plateau) a noise valley steep
enough to outweigh the other segments' stiffness is a fold, i.e. a spurious snap-through.
:func:`smooth_table` removes them in two steps:

1. Each row's pressure is estimated by a least-squares quadratic through the rows around it, in
   a window chosen for that row (local polynomial fits with the intersection-of-confidence-
   intervals rule, Katkovnik 1999; Goldenshluger & Nemirovski 1997). Windows of 5, 7, 9, 13, ...
   rows (about 1.45 times wider each) give estimates whose deviation, from the noise and the
   fit, is known; the widest window whose confidence interval (CONFIDENCE deviations either
   side) still meets those of all narrower ones is where the curve's bend first shows against
   the noise, and the window one step narrower is taken: a quadratic's error on a smooth curve
   grows as the fourth power of its width (the third where the window is shifted at a table's
   end), so one step divides it by 3 to 4, below the estimate's own deviation. Each row then
   takes the median of the windows chosen over SCALE_MEDIAN rows around it, so that the lowest
   of a flat valley's many rows is not the one where chance picked a narrow window. Where the
   curve is flat the windows grow wide and the noise
   averages out; at a rounded peak, a steep first rise or a sharp knee they stay narrow (down
   to the row itself), so the height of a peak or valley is not bent by a penalty that the
   rest of the curve sets.
2. Turning points are kept only where they are real: a peak or valley whose prominence (pressure
   rise or fall to the neighbouring turning point) is below ``prominence`` Pa is dropped, and
   each stretch between the kept turning points is made strictly monotone (pool-adjacent-
   violators isotonic regression of the smoothed rows, then linear interpolation between the
   pooled blocks' centres so that no exactly flat stretch is invented).

The default ``prominence`` is 6 times the noise standard deviation, estimated from the rows
themselves (:func:`estimate_noise`) unless ``noise_std`` is given. A real feature smaller than
that cannot be told apart from noise in a single table.

What it keeps (test/test_smoothing.py): on Gent and Ogden balloon curves of 200 and 600 rows
with Gaussian noise of 0.25 to 1 % of the peak, a peak or valley with at least 15 rows on
either side of it comes out within one noise deviation of the noise-free rows' on every seed
tried. A peak with fewer rows before it (a balloon sampled evenly in volume peaks within its
first few rows at 60 or 200 rows) is not resolved by the rows, by this or any smoothing. A
sharp knee is biased by less than 1 % of the pressure range up to 1 % noise on the project's
bulge tables. The replaced method, a cubic smoothing spline with one penalty for the whole table
chosen by generalised cross-validation, could not follow a balloon's steep first rise and its
rounded peak at once: it raised a 3.8 kPa Gent peak by 35 to 110 Pa whatever the noise, or
lost it.
"""

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.ndimage import median_filter

FloatArray = NDArray[np.float64]

# The local fits: quadratics (a rounded peak or valley is one, to leading order).
DEGREE = 2
# The narrowest window: 2 rows either side (5 rows; 3 would pass through every row).
FIRST_HALF_WIDTH = 2
# The widest window: about 200 rows either side (an estimate's deviation is then below a
# twentieth of the noise; wider ones would cost time on long tables for nothing the solver sees).
LAST_HALF_WIDTH = 200
# Each window about this much wider than the one before.
WIDTH_RATIO = 1.45
# A window's confidence interval: its estimate +- this many of its deviations.
CONFIDENCE = 2.0
# Windows stepped back from the widest consistent one (see the module's notes).
BACK_OFF = 1
# Each row takes the median of the windows chosen over this many rows around it: a choice made
# narrow by a chance run of noise would stand out of a flat stretch, and the lowest (or highest)
# of a valley's (or peak's) many rows picks exactly such outliers.
SCALE_MEDIAN = 5
# Rows x window entries worked on at once (memory, not results).
CHUNK_ENTRIES = 1 << 18

# The local fits of the noise estimate: a cubic through this many rows either side of a row
# (the row itself left out), so a smooth curve's residual is of the order h^4 p''''.
FIT_SIDE = 3
FIT_DEGREE = 3
# Residuals beyond this many deviations are the curve's own sharp corners, not noise: they are
# left out, and the deviation of what remains is scaled to a normal distribution's (3-sigma
# clipping keeps 0.9866 of its deviation).
CLIP_DEVIATIONS = 3.0
CLIPPED_DEVIATION_SHARE = 0.9866
# The clipping has converged when the deviation changes by less than this share of itself.
CLIP_CONVERGED = 1e-12


def estimated_noise(volumes: ArrayLike, pressures: ArrayLike) -> float | None:
    """
    The deviation of a table's pressure noise [Pa], from leave-one-out local cubic fits.

    Each row's pressure is predicted by a cubic through the FIT_SIDE rows either side of it; the
    residual, divided by its standard deviation in units of the noise's (the fit's own
    uncertainty included, for rows spaced however unevenly), is noise plus what the cubic
    cannot follow. A smooth curve leaves next to nothing (of the order h^4 p''''); its sharpest
    corners, a few rows, are clipped at CLIP_DEVIATIONS. None with too few rows.
    """
    v = np.asarray(volumes, dtype=float)
    p = np.asarray(pressures, dtype=float)
    if v.size < 2 * FIT_SIDE + 3:
        return None
    rows = np.arange(FIT_SIDE, v.size - FIT_SIDE)
    offsets = np.concatenate([np.arange(-FIT_SIDE, 0), np.arange(1, FIT_SIDE + 1)])
    neighbours = rows[:, None] + offsets[None, :]
    half_span = 0.5 * (v[rows + FIT_SIDE] - v[rows - FIT_SIDE])[:, None]
    x = (v[neighbours] - v[rows][:, None]) / half_span
    design = x[..., None] ** np.arange(FIT_DEGREE + 1)
    normal = np.einsum('nki,nkj->nij', design, design)
    inverse = np.linalg.inv(normal)
    coefficients = np.einsum('nij,nkj,nk->ni', inverse, design, p[neighbours])
    # Var(p_i - fit(v_i)) = s^2 (1 + [(X^T X)^-1]_00): the row's noise and the fit's.
    residual = (p[rows] - coefficients[:, 0]) / np.sqrt(1.0 + inverse[:, 0, 0])
    deviation = 1.4826 * float(np.median(np.abs(residual)))
    for _ in range(50):
        kept = residual[np.abs(residual) <= CLIP_DEVIATIONS * deviation]
        if not kept.size:
            break
        clipped = float(np.sqrt(np.mean(kept**2))) / CLIPPED_DEVIATION_SHARE
        if abs(clipped - deviation) <= CLIP_CONVERGED * max(deviation, 1e-300):
            deviation = clipped
            break
        deviation = clipped
    return deviation


def estimate_noise(volume: ArrayLike, pressure: ArrayLike) -> float:
    """
    Standard deviation of row noise: :func:`estimated_noise` where there are rows enough.

    With fewer rows, from each row's deviation from its neighbours' chord: for independent
    noise of deviation s, r_i = p_i - (w p_{i-1} + (1 - w) p_{i+1}) has deviation
    s sqrt(1 + w^2 + (1 - w)^2); the median absolute deviation makes it robust to outliers
    (the curve's own bend reads as noise there, which the local fits avoid).
    """
    v = np.asarray(volume, dtype=float)
    p = np.asarray(pressure, dtype=float)
    fitted = estimated_noise(v, p)
    if fitted is not None:
        return fitted
    if v.size < 5:
        return 0.0
    w = (v[2:] - v[1:-1]) / (v[2:] - v[:-2])
    r = (p[1:-1] - (w * p[:-2] + (1.0 - w) * p[2:])) / np.sqrt(1.0 + w**2 + (1.0 - w)**2)
    return float(1.4826 * np.median(np.abs(r - np.median(r))))


def _turning_points(p: FloatArray) -> list[int]:
    """Indices of strict local extrema of a sequence (plateaus count once, at their start)."""
    slope = np.sign(np.diff(p))
    nonzero = np.flatnonzero(slope)
    turns = []
    for a, b in zip(nonzero[:-1], nonzero[1:]):
        if slope[a] != slope[b]:
            turns.append(int(b))
    return turns


def _significant_turns(p: FloatArray, prominence: float) -> list[int]:
    """Turning points left after repeatedly dropping the least prominent peak-valley pair."""
    turns = [0, *_turning_points(p), p.size - 1]
    while len(turns) > 2:
        drops = np.abs(np.diff(p[turns]))
        i = int(np.argmin(drops))
        if drops[i] >= prominence:
            break
        # Remove the pair around the smallest swing; at an end, only the interior point goes.
        if i == 0:
            del turns[1]
        elif i == len(turns) - 2:
            del turns[-2]
        else:
            del turns[i:i + 2]
    return turns


def _monotone_fit(x: FloatArray, y: FloatArray, rising: bool) -> FloatArray:
    """Isotonic regression (pool adjacent violators), then strict by interpolating blocks."""
    sign = 1.0 if rising else -1.0
    values, weights, starts = [], [], []
    for i, value in enumerate(sign * y):
        values.append(value)
        weights.append(1.0)
        starts.append(i)
        while len(values) > 1 and values[-2] >= values[-1]:
            w = weights[-2] + weights[-1]
            values[-2] = (weights[-2] * values[-2] + weights[-1] * values[-1]) / w
            weights[-2] = w
            del values[-1], weights[-1], starts[-1]
    if len(values) == y.size:
        return y.copy()
    ends = starts[1:] + [y.size]
    centres = np.array([x[a:b].mean() for a, b in zip(starts, ends)])
    fitted = np.interp(x, centres, np.asarray(values))
    # Outside the first and last block centres np.interp is flat: continue the end slopes.
    if len(values) > 1:
        left = (values[1] - values[0]) / (centres[1] - centres[0])
        right = (values[-1] - values[-2]) / (centres[-1] - centres[-2])
        fitted = np.where(x < centres[0], values[0] + left * (x - centres[0]), fitted)
        fitted = np.where(x > centres[-1], values[-1] + right * (x - centres[-1]), fitted)
    else:
        fitted = np.full_like(y, values[0])
    return sign * fitted


def _local_fits(x: FloatArray, y: FloatArray, half_width: int) -> tuple[FloatArray, FloatArray]:
    """
    Every row's value from a least-squares quadratic through 2 half_width + 1 rows around it.

    The window is centred on the row, shifted inwards at the ends to keep its rows. Returns the
    values and their deviations in units of the rows' noise (sqrt([(X^T X)^-1]_00)).
    """
    n = x.size
    width = min(2 * half_width + 1, n)
    values = np.empty(n)
    deviations = np.empty(n)
    step = max(1, CHUNK_ENTRIES // width)
    for first in range(0, n, step):
        rows = np.arange(first, min(first + step, n))
        start = np.clip(rows - half_width, 0, n - width)
        window = start[:, None] + np.arange(width)[None, :]
        # Distances scaled by the window's span: the normal equations stay well conditioned.
        span = (x[window[:, -1]] - x[window[:, 0]])[:, None]
        u = (x[window] - x[rows][:, None]) / span
        design = u[..., None] ** np.arange(DEGREE + 1)
        inverse = np.linalg.inv(np.einsum('nki,nkj->nij', design, design))
        weights = np.einsum('ni,nki->nk', inverse[:, 0, :], design)
        values[rows] = np.einsum('nk,nk->n', weights, y[window])
        deviations[rows] = np.sqrt(inverse[:, 0, 0])
    return values, deviations


def adaptive_fit(x: ArrayLike, y: ArrayLike, noise_std: float) -> FloatArray:
    """Each row's value from a local quadratic in its own window (adaptive_fit_deviation)."""
    return adaptive_fit_deviation(x, y, noise_std)[0]


def adaptive_fit_deviation(x: ArrayLike, y: ArrayLike,
                           noise_std: float) -> tuple[FloatArray, FloatArray]:
    """
    Each row's value from a local quadratic in the window the rows themselves choose.

    The windows widen by WIDTH_RATIO from FIRST_HALF_WIDTH rows either side, the row as read
    being the first estimate (deviation ``noise_std``). A row's widest consistent window is the
    last whose interval (estimate +- CONFIDENCE deviations) meets those of every narrower one;
    the window BACK_OFF steps narrower is taken (the narrowest fitted one at least, when one is
    consistent at all), then the median of the windows taken over SCALE_MEDIAN rows around the
    row, and its estimate returned with its deviation [the unit of ``noise_std``]: the noise
    times the chosen window's leverage, sqrt([(X^T X)^-1]_00), which leaves out the window's
    bias (the back-off step keeps that below the deviation). ``x`` must increase
    strictly. With no noise (``noise_std`` 0) the rows come back as they are.
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    half_widths = []
    k = FIRST_HALF_WIDTH
    while 2 * k + 1 <= x.size and k <= LAST_HALF_WIDTH:
        half_widths.append(k)
        k = max(k + 1, int(round(k * WIDTH_RATIO)))
    estimates = np.empty((len(half_widths) + 1, x.size))
    deviations = np.empty_like(estimates)
    estimates[0], deviations[0] = y, noise_std
    for j, k in enumerate(half_widths, start=1):
        estimates[j], deviations[j] = _local_fits(x, y, k)
        deviations[j] *= noise_std
    lower = np.maximum.accumulate(estimates - CONFIDENCE * deviations, axis=0)
    upper = np.minimum.accumulate(estimates + CONFIDENCE * deviations, axis=0)
    meets = lower <= upper
    # The last window whose interval meets all narrower ones (the row's own always does).
    widest = np.where(meets.all(axis=0), len(half_widths), np.argmin(meets, axis=0) - 1)
    # Stepped back, but not from a fitted window to the row as read.
    chosen = np.maximum(widest - BACK_OFF, np.minimum(widest, 1))
    chosen = median_filter(chosen, size=SCALE_MEDIAN, mode='nearest')
    rows = np.arange(x.size)
    return estimates[chosen, rows], deviations[chosen, rows]


def smooth_table(volume: ArrayLike, pressure: ArrayLike, noise_std: float | None = None,
                 prominence: float | None = None, keep_first: bool = True) -> FloatArray:
    """
    Smoothed pressures for the rows of a measured PV table (same length as ``pressure``).

    ``noise_std`` [Pa]: the sensor noise (estimated from the rows when None). ``prominence`` [Pa]:
    the smallest peak or valley kept (6 * noise_std when None). ``keep_first`` keeps the first
    row's pressure (the unpressurised state) as measured. Raises ValueError for fewer than 5
    rows, non-finite values or volumes that do not increase strictly.
    """
    return smooth_table_deviation(volume, pressure, noise_std, prominence, keep_first)[0]


def smooth_table_deviation(volume: ArrayLike, pressure: ArrayLike,
                           noise_std: float | None = None, prominence: float | None = None,
                           keep_first: bool = True) -> tuple[FloatArray, FloatArray]:
    """
    :func:`smooth_table`'s pressures, and each row's standard deviation [Pa] beside them.

    The deviation is the noise times the leverage of the window the row's local quadratic was
    fitted in (:func:`adaptive_fit_deviation`): how much of the noise is left in the row. The
    monotone pass that follows is not counted in it; a row kept as measured (``keep_first``)
    has the noise's own deviation.
    """
    v = np.asarray(volume, dtype=float)
    p = np.asarray(pressure, dtype=float)
    if v.ndim != 1 or v.shape != p.shape:
        raise ValueError('smooth_table: volume and pressure must be 1-D arrays of one length')
    if v.size < 5:
        raise ValueError(f'smooth_table: needs at least 5 rows to smooth, got {v.size}')
    if not (np.all(np.isfinite(v)) and np.all(np.isfinite(p))):
        raise ValueError('smooth_table: volume and pressure must be finite')
    if np.any(np.diff(v) <= 0.0):
        raise ValueError('smooth_table: volumes must increase strictly')
    sigma = estimate_noise(v, p) if noise_std is None else float(noise_std)
    if not sigma >= 0.0:
        raise ValueError(f'smooth_table: noise_std must be >= 0 Pa, got {noise_std}')
    threshold = 6.0 * sigma if prominence is None else float(prominence)
    x = (v - v[0]) / (v[-1] - v[0])
    smoothed, deviation = adaptive_fit_deviation(x, p, sigma)
    if keep_first:
        smoothed[0] = p[0]
        deviation[0] = sigma
    turns = _significant_turns(smoothed, threshold)
    out = smoothed.copy()
    for a, b in zip(turns[:-1], turns[1:]):
        rising = smoothed[b] > smoothed[a]
        fitted = _monotone_fit(x[a:b + 1], smoothed[a:b + 1], rising)
        # Neighbouring stretches share their turning row: a peak takes the higher of the two
        # fits and a valley the lower, which keeps both stretches strictly monotone.
        if a > turns[0]:
            fitted[0] = max(fitted[0], out[a]) if not rising else min(fitted[0], out[a])
        out[a:b + 1] = fitted
    if keep_first:
        out[0] = p[0]
    return out, deviation
