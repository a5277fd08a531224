"""
Opt-in smoothing of measured pressure-volume tables (rig data with sensor noise).

Noise on a table row makes local peaks and valleys that the solver takes for real: each becomes a
monotone piece, and where a segment's curve is nearly flat (a plateau) a noise valley steep
enough to outweigh the other segments' stiffness is a fold, i.e. a spurious snap-through.
:func:`smooth_table` removes them in two steps:

1. A cubic smoothing spline (``scipy.interpolate.make_smoothing_spline``) through the rows, its
   penalty chosen by generalised cross-validation unless ``lam`` is given. This removes most of
   the noise without assuming a shape.
2. Turning points are kept only where they are real: a peak or valley whose prominence (pressure
   rise or fall to the neighbouring turning point) is below ``prominence`` Pa is dropped, and
   each stretch between the kept turning points is made strictly monotone (pool-adjacent-
   violators isotonic regression of the smoothed rows, then linear interpolation between the
   pooled blocks' centres so that no exactly flat stretch is invented).

The default ``prominence`` is 6 times the noise standard deviation, estimated from the rows
themselves (the median absolute deviation of second differences) unless ``noise_std`` is given.
A real feature smaller than that cannot be told apart from noise in a single table.
"""

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import make_smoothing_spline

FloatArray = NDArray[np.float64]


def estimate_noise(volume: ArrayLike, pressure: ArrayLike) -> float:
    """
    Standard deviation of row noise, from each row's deviation from its neighbours' chord.

    For independent noise of deviation s, r_i = p_i - (w p_{i-1} + (1 - w) p_{i+1}) has deviation
    s sqrt(1 + w^2 + (1 - w)^2); the median absolute deviation makes it robust to the curve's
    own bends (few rows) and to outliers.
    """
    v = np.asarray(volume, dtype=float)
    p = np.asarray(pressure, dtype=float)
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


def smooth_table(volume: ArrayLike, pressure: ArrayLike, noise_std: float | None = None,
                 prominence: float | None = None, lam: float | None = None,
                 keep_first: bool = True) -> FloatArray:
    """
    Smoothed pressures for the rows of a measured PV table (same length as ``pressure``).

    ``noise_std`` [Pa]: the sensor noise (estimated from the rows when None). ``prominence`` [Pa]:
    the smallest peak or valley kept (6 * noise_std when None). ``lam``: the smoothing spline's
    penalty (generalised cross-validation when None). ``keep_first`` keeps the first row's
    pressure (the unpressurised state) as measured. Raises ValueError for fewer than 5 rows,
    non-finite values or volumes that do not increase strictly.
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
    # The spline works on volumes scaled to [0, 1]: the GCV search is then scale-free.
    x = (v - v[0]) / (v[-1] - v[0])
    smoothed = make_smoothing_spline(x, p, lam=lam)(x)
    if keep_first:
        smoothed[0] = p[0]
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
    return out
