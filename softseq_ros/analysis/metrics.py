"""
The numbers of an inflation sequence, from a recording or from a solved path.

Everything here works on a :class:`Trace`: the states of one run in command order (injected
volume, gauge pressure, segment volumes and curvatures, and whether each was on an inflation or
a deflation leg), so a bag and a quasi-static sweep of the solver are measured the same way.
Metrics are taken over the first inflation leg and the deflation leg that follows it (the first
cycle); every value is SI (m^3, Pa, J, m) and every pressure is gauge.
"""

from dataclasses import dataclass, field
import math

import numpy as np
from numpy.typing import NDArray

from softseq_ros.errors import UserError
from softseq_ros.quasistatic.sequence import RECORDED_HYSTERESIS_TOLERANCE, sequence_type

FloatArray = NDArray[np.float64]

# Grid on which shares of the inflow are taken (bins over the first inflation leg).
SHARE_BINS = 200
# The switch is the largest change of a share across this many bins (a tenth of the leg).
SWITCH_WINDOW_BINS = SHARE_BINS // 10
# A share change smaller than this over the whole leg names no switch.
MIN_SWITCH_CHANGE = 0.05
# A snap moves more fluid between segments at one command than this many times the command's
# step, and more than this share of the injected range.
SNAP_EXCHANGE_PER_STEP = 5.0
SNAP_SHARE_OF_RANGE = 1e-3
# The plateau is reached where the pressure first comes within this share of its final value.
PLATEAU_SHARE = 0.95


class TraceError(UserError):
    """A recorded or swept trace that holds nothing the metrics can measure."""


@dataclass
class Trace:
    """States in command order; ``sign`` is +1 on inflation legs and -1 on deflation legs."""

    injected: FloatArray
    pressure: FloatArray
    volumes: FloatArray
    sign: NDArray[np.int8]
    curvatures: FloatArray | None = None
    events: list[dict] = field(default_factory=list)
    segment_names: tuple[str, ...] = ()

    def legs(self) -> tuple[slice, slice | None]:
        """The first inflation leg and the deflation leg after it (None when there is none)."""
        sign = self.sign
        rising = np.flatnonzero(sign > 0)
        if not rising.size:
            raise TraceError('the pump never inflates in this recording: nothing to measure')
        start = int(rising[0])
        falling = np.flatnonzero(sign[start:] < 0)
        if not falling.size:
            return slice(start, sign.size), None
        end = start + int(falling[0])
        after = np.flatnonzero(sign[end:] > 0)
        stop = end + int(after[0]) if after.size else sign.size
        return slice(start, end), slice(end, stop)


def monotone_leg(u: FloatArray, columns: FloatArray,
                 increasing: bool) -> tuple[FloatArray, FloatArray]:
    """Rows of a leg with strictly monotone u (a repeated command keeps its last state)."""
    if u.size == 0:
        return u, columns
    if not increasing:
        u, columns = u[::-1], columns[::-1]
    # The last state at each volume: after a snap at u the state is the landed one.
    keep = np.append(np.diff(u) > 0, True)
    u, columns = u[keep], columns[keep]
    best = np.maximum.accumulate(u)
    fresh = np.append(True, u[1:] > best[:-1])
    return u[fresh], columns[fresh]


def snap_rows(injected: FloatArray, volumes: FloatArray,
              v_range: float) -> tuple[NDArray[np.intp], FloatArray]:
    """
    Rows that a snap-through lands on, and the fluid each moved between segments.

    Between two commands the fluid moves by |du|; a snap moves fluid between segments at one
    command: exchanged = (sum_i |dv_i| - |du|) / 2, several times |du| and a visible share of
    the range (a continuous exchange, as in a symmetric sequence, moves about |du| per command).
    """
    rows, moved = [], []
    block = 1 << 18  # bounded temporaries on long recordings
    for start in range(0, max(injected.size - 1, 0), block):
        part = slice(start, min(start + block + 1, injected.size))
        du = np.abs(np.diff(injected[part]))
        dv = np.abs(np.diff(volumes[part], axis=0)).sum(axis=1)
        exchanged = 0.5 * np.maximum(dv - du, 0.0)
        found = np.flatnonzero((exchanged > SNAP_EXCHANGE_PER_STEP * du)
                               & (exchanged > SNAP_SHARE_OF_RANGE * v_range))
        rows.append(found + start + 1)
        moved.append(exchanged[found])
    if not rows:
        return np.zeros(0, np.intp), np.zeros(0)
    return np.concatenate(rows), np.concatenate(moved)


def detect_snaps(trace: Trace, v_range: float) -> list[dict]:
    """
    Snap-throughs found in the recorded volumes themselves (not from the events topic).

    A run of consecutive snap rows is one snap-through: a recording in time (a scene with a
    network) holds many states while the fluid moves; a quasi-static one lands at one command.
    """
    rows, moved = snap_rows(trace.injected, trace.volumes, v_range)
    runs: list[tuple[int, int, float]] = []   # (first row, last row, fluid moved)
    for row, fluid in zip(rows.tolist(), moved.tolist()):
        if runs and row == runs[-1][1] + 1:
            runs[-1] = (runs[-1][0], row, runs[-1][2] + fluid)
        else:
            runs.append((row, row, fluid))
    snaps = []
    for first, last, fluid in runs:
        snaps.append({
            'injected_m3': float(trace.injected[first]),
            'direction': 'inflation' if trace.sign[first] > 0 else 'deflation',
            'fluid_moved_m3': float(fluid),
            'from_volumes_m3': trace.volumes[first - 1].tolist(),
            'to_volumes_m3': trace.volumes[last].tolist(),
            'from_pressure_pa': float(trace.pressure[first - 1]),
            'to_pressure_pa': float(trace.pressure[last]),
        })
    return snaps


def _shares(u: FloatArray, volumes: FloatArray, snaps: list[float]) -> tuple[FloatArray,
                                                                               FloatArray]:
    """Each segment's share of the inflow dv_i/du on bins of the leg, snap bins dropped."""
    grid = np.linspace(u[0], u[-1], SHARE_BINS + 1)
    sampled = np.column_stack([np.interp(grid, u, volumes[:, j])
                               for j in range(volumes.shape[1])])
    share = np.diff(sampled, axis=0) / np.diff(grid)[:, None]
    middle = 0.5 * (grid[1:] + grid[:-1])
    keep = np.ones(middle.size, dtype=bool)
    width = grid[1] - grid[0]
    for snap in snaps:
        keep &= np.abs(middle - snap) > 1.5 * width
    return middle[keep], share[keep]


def analyse(trace: Trace, v_range: float | None = None) -> dict:
    """Sequence type, switch, snaps, hysteresis and plateau of a trace (first cycle)."""
    up, down = trace.legs()
    u_all = trace.injected
    v_range = float(v_range if v_range else max(np.ptp(u_all), 1e-300))
    cycle = slice(up.start, (down or up).stop)
    snaps = detect_snaps(Trace(u_all[cycle], trace.pressure[cycle], trace.volumes[cycle],
                               trace.sign[cycle]), v_range)
    u_up, cols_up = monotone_leg(u_all[up], np.column_stack([trace.pressure[up],
                                                          trace.volumes[up]]), True)
    p_up, v_up = cols_up[:, 0], cols_up[:, 1:]
    result: dict = {'injected_range_m3': [float(u_all.min()), float(u_all.max())]}
    snap_volumes = [s['injected_m3'] for s in snaps]
    gap = 0.0
    hysteresis = 0.0
    has_deflation = down is not None and trace.injected[down].size > 2
    if has_deflation:
        u_dn, cols_dn = monotone_leg(u_all[down], np.column_stack([trace.pressure[down],
                                                                trace.volumes[down]]), False)
        lo, hi = max(u_up[0], u_dn[0]), min(u_up[-1], u_dn[-1])
        inside = (u_up >= lo) & (u_up <= hi)
        if inside.sum() > 1:
            v_dn_at = np.column_stack([np.interp(u_up[inside], u_dn, cols_dn[:, 1 + j])
                                       for j in range(v_up.shape[1])])
            gap = float(np.max(np.abs(v_dn_at - v_up[inside])))
            hysteresis = _area(u_up, p_up, lo, hi) - _area(u_dn, cols_dn[:, 0], lo, hi)
    result['hysteresis_area_j'] = float(hysteresis)
    result['hysteresis_volume_gap_m3'] = gap
    result['snaps'] = snaps
    result['snap_count'] = len(snaps)

    middle, share = _shares(u_up, v_up, snap_volumes) if u_up.size > 2 else \
        (np.zeros(0), np.zeros((0, v_up.shape[1])))
    result['sequence_type'] = sequence_type(bool(snaps), gap,
                                            RECORDED_HYSTERESIS_TOLERANCE * v_range, share)
    result['deflation_recorded'] = bool(has_deflation)
    result['switch'] = _switch(middle, share, trace.segment_names)
    result['plateau'] = _plateau(u_up, p_up)
    return result


def _area(u: FloatArray, p: FloatArray, lo: float, hi: float) -> float:
    """Integral of p du from lo to hi over a monotone curve [J]."""
    inside = (u > lo) & (u < hi)
    uu = np.concatenate([[lo], u[inside], [hi]])
    pp = np.concatenate([[np.interp(lo, u, p)], p[inside], [np.interp(hi, u, p)]])
    return float(np.trapezoid(pp, uu))


def _switch(middle: FloatArray, share: FloatArray, names: tuple[str, ...]) -> dict | None:
    """
    Where a segment's share of the inflow changes most.

    That is the largest change of a share across a window of a tenth of the leg, placed at the
    window's centre.
    """
    half = SWITCH_WINDOW_BINS // 2
    if middle.size <= 2 * half + 1:
        return None
    change = share[2 * half:] - share[:-2 * half]
    centre = middle[half:-half]
    size = np.abs(change)
    if float(np.max(size)) < MIN_SWITCH_CHANGE:
        return None
    row, _ = np.unravel_index(int(np.argmax(size)), size.shape)
    gainer = int(np.argmax(change[row]))
    return {
        'injected_m3': float(centre[row]),
        'segment_taking_over': names[gainer] if gainer < len(names) else gainer,
        'shares_before': [float(x) for x in share[row]],
        'shares_after': [float(x) for x in share[row + 2 * half]],
        'window_m3': float(middle[2 * half] - middle[0]),
    }


def _plateau(u: FloatArray, p: FloatArray) -> dict | None:
    """The pressure at the end of inflation and where it first came within 5 % of it."""
    if u.size < 4:
        return None
    final = float(p[-1])
    reached = np.flatnonzero(p >= PLATEAU_SHARE * final) if final > 0 else np.zeros(0, int)
    span = u[-1] - u[0]
    first = u <= u[0] + 0.1 * span
    last = u >= u[-1] - 0.2 * span
    slope_first = _slope(u[first], p[first])
    slope_last = _slope(u[last], p[last])
    return {
        'pressure_pa': final,
        'onset_injected_m3': float(u[reached[0]]) if reached.size else None,
        'slope_ratio_end_to_start': (slope_last / slope_first
                                     if slope_first and math.isfinite(slope_last) else None),
    }


def _slope(u: FloatArray, p: FloatArray) -> float:
    if u.size < 2 or np.ptp(u) == 0:
        return float('nan')
    return float(np.polyfit(u, p, 1)[0])


def segment_limits(segments: list, names: tuple[str, ...]) -> dict[str, float]:
    """Per segment: the highest pressure its curve holds (its peak or plateau) [Pa, gauge]."""
    limits = {}
    for name, segment in zip(names, segments):
        v = np.linspace(segment.rest_volume, segment.max_volume, 2001)
        limits[name] = float(np.max(segment.pressure(v)))
    return limits
