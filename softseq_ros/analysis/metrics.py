"""
The numbers of an inflation sequence, from a recording or from a solved path.

Everything here works on a :class:`Trace`: the states of one run in command order (injected
volume, gauge pressure, segment volumes and curvatures, and whether each was on an inflation or
a deflation leg), so a bag and a quasi-static sweep of the solver are measured the same way.
Metrics are taken over the first inflation leg and the deflation leg that follows it (the first
cycle); every value is SI (m^3, Pa, J, m) and every pressure is gauge.

A metric that does not apply to a run is None, never a number, and ``not_applicable`` names it
with the reason: a switch in a sequence where no segment takes over, a plateau on a straight,
peaked or still steepening curve, a hysteresis area without a deflation.

Two numbers say who takes the inflow, both from its shares (dv_i/du on bins of the first
inflation leg): the *lead* is where a segment first takes LEAD_SHARE of the inflow or more over
one of LEAD_BINS bins (who fills first: ``lead``, "leads from"), the *switch* where a segment's
share changes most over a tenth of the leg (where the filling changes hands: ``switch``, "takes
over at"). A segment can lead from the start and another take over late: both are said.
"""

from dataclasses import dataclass, field
import math

import numpy as np
from numpy.typing import NDArray

from softseq_ros.errors import UserError
from softseq_ros.quasistatic.sequence import (
    PARTIAL_SHARE_CHANGE,
    RECORDED_HYSTERESIS_TOLERANCE,
    sequence_type,
)

FloatArray = NDArray[np.float64]

# Grid on which shares of the inflow are taken (bins over the first inflation leg).
SHARE_BINS = 200
# The switch is the largest change of a share across this many bins (a tenth of the leg).
SWITCH_WINDOW_BINS = SHARE_BINS // 10
# A switch is where one segment takes over: a share that changes by more than the partial
# sequence's threshold over the leg (quasistatic.sequence), the rule that names the type.
# A snap moves more fluid between segments at one command than this many times the command's
# step, and more than this share of the injected range.
SNAP_EXCHANGE_PER_STEP = 5.0
SNAP_SHARE_OF_RANGE = 1e-3
# A chord turning less than this [rad] is straight: its arc is its chord.
STRAIGHT_RAD = 1e-9
# A segment leads the inflow once it takes this share of it (or more: the others give fluid
# back) over one of this many equal bins of the first inflation leg.
LEAD_SHARE = 0.9
LEAD_BINS = 100
# The plateau is reached where the pressure first comes within this share of its level.
PLATEAU_SHARE = 0.95
# A plateau is level: somewhere after its steepest rise the pressure's slope (over a tenth of
# the leg) falls below this share of that steepest slope. A straight line (1.0) or a
# square-root-like softening curve (0.16) has none; the paper's combined curve reaches 0.03.
PLATEAU_SLOPE_SHARE = 0.1
# The slope is taken over this many bins of the leg (a tenth of it, as the switch's window).
PLATEAU_WINDOW_BINS = SWITCH_WINDOW_BINS


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


def analyse(trace: Trace, v_range: float | None = None,
            snaps: list[dict] | None = None) -> dict:
    """
    Sequence type, switch, snaps, hysteresis and plateau of a trace (first cycle).

    ``snaps``: the recording's own snap-throughs when it says them (a recording in time: the
    actuator's events, each an exchange of fluid that takes time, which the states between
    two commands do not show as a jump); otherwise they are found in the volumes.
    """
    up, down = trace.legs()
    u_all = trace.injected
    v_range = float(v_range if v_range else max(np.ptp(u_all), 1e-300))
    cycle = slice(up.start, (down or up).stop)
    if snaps is None:
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
    not_applicable: dict[str, str] = {}
    if has_deflation:
        result['hysteresis_area_j'] = float(hysteresis)
        result['hysteresis_volume_gap_m3'] = gap
    else:
        result['hysteresis_area_j'] = result['hysteresis_volume_gap_m3'] = None
        not_applicable['hysteresis_area_j'] = ('no deflation was recorded after the first '
                                               'inflation: there is no loop to measure')
    result['snaps'] = snaps
    result['snap_count'] = len(snaps)

    middle, share = _shares(u_up, v_up, snap_volumes) if u_up.size > 2 else \
        (np.zeros(0), np.zeros((0, v_up.shape[1])))
    result['sequence_type'] = sequence_type(bool(snaps), gap,
                                            RECORDED_HYSTERESIS_TOLERANCE * v_range, share)
    result['deflation_recorded'] = bool(has_deflation)
    result['switch'], why = _switch(middle, share, trace.segment_names)
    if why:
        not_applicable['switch'] = why
    result['lead'], why = _lead(u_up, v_up, trace.segment_names)
    if why:
        not_applicable['lead'] = why
    result['plateau'], why = _plateau(u_up, p_up)
    if why:
        not_applicable['plateau'] = why
    result['not_applicable'] = not_applicable
    return result


def sweep_metrics(rising: object, falling: object, names: tuple[str, ...],
                  v_range: float) -> dict:
    """
    :func:`analyse` of a solver's sweep: an inflation path and the deflation path after it.

    ``rising`` and ``falling`` are :class:`~softseq_ros.quasistatic.equilibrium.SolvedPath`
    (``inflate_and_deflate``), ``names`` the segments', ``v_range`` the injected range [m^3].
    """
    rows = rising.injected.size
    trace = Trace(np.concatenate([rising.injected, falling.injected]),
                  np.concatenate([rising.pressure, falling.pressure]),
                  np.vstack([rising.volumes, falling.volumes]),
                  np.concatenate([np.ones(rows, np.int8), -np.ones(falling.injected.size,
                                                                np.int8)]),
                  segment_names=names)
    return analyse(trace, v_range=v_range)


def _area(u: FloatArray, p: FloatArray, lo: float, hi: float) -> float:
    """Integral of p du from lo to hi over a monotone curve [J]."""
    inside = (u > lo) & (u < hi)
    uu = np.concatenate([[lo], u[inside], [hi]])
    pp = np.concatenate([[np.interp(lo, u, p)], p[inside], [np.interp(hi, u, p)]])
    return float(np.trapezoid(pp, uu))


def _switch(middle: FloatArray, share: FloatArray,
            names: tuple[str, ...]) -> tuple[dict | None, str]:
    """
    Where a segment's share of the inflow changes most, or None and why it does not apply.

    That is the largest change of a share across a window of a tenth of the leg, placed at the
    window's centre. It applies only where a segment takes over: where some share changes by
    more than the partial sequence's threshold over the leg (the rule that names the type).
    """
    half = SWITCH_WINDOW_BINS // 2
    if share.shape[1] < 2:
        return None, 'one segment: there is nothing to switch between'
    if middle.size <= 2 * half + 1:
        return None, (f'the inflation leg has too few distinct volumes ({middle.size} bins '
                      'of the inflow left) to follow the shares of the inflow')
    overall = float(np.max(np.ptp(share, axis=0)))
    if overall <= PARTIAL_SHARE_CHANGE:
        return None, (f"no segment's share of the inflow changes by more than "
                      f'{PARTIAL_SHARE_CHANGE:g} over inflation (at most {overall:.2f}): the '
                      'segments fill together, none takes over')
    change = share[2 * half:] - share[:-2 * half]
    centre = middle[half:-half]
    size = np.abs(change)
    row, _ = np.unravel_index(int(np.argmax(size)), size.shape)
    gainer = int(np.argmax(change[row]))
    return {
        'injected_m3': float(centre[row]),
        'segment_taking_over': names[gainer] if gainer < len(names) else gainer,
        'shares_before': [float(x) for x in share[row]],
        'shares_after': [float(x) for x in share[row + 2 * half]],
        'window_m3': float(middle[2 * half] - middle[0]),
    }, ''


def _lead(u: FloatArray, volumes: FloatArray,
          names: tuple[str, ...]) -> tuple[dict | None, str]:
    """
    The segment that first takes LEAD_SHARE of the inflow, and where; or None and why not.

    Over one of LEAD_BINS equal bins of the leg's injected volume (more than all of it when the
    others give fluid back; a snap it gains by counts), placed at the bin's centre.
    """
    if u.size < 2 or not np.ptp(u) > 0.0:
        return None, (f'the inflation leg has {u.size} distinct volumes, too few to follow the '
                      'shares of the inflow')
    grid = np.linspace(u[0], u[-1], LEAD_BINS + 1)
    sampled = np.column_stack([np.interp(grid, u, volumes[:, k])
                               for k in range(volumes.shape[1])])
    share = np.diff(sampled, axis=0) / np.diff(grid)[:, None]
    taking = np.argwhere(share >= LEAD_SHARE)
    if not taking.size:
        return None, (f'no segment takes {LEAD_SHARE * 100:.0f} % of the inflow over any '
                      f'{LEAD_BINS}th of the inflation: the inflow stays split')
    row, segment = (int(x) for x in taking[0])
    return {'segment_leading': names[segment] if segment < len(names) else segment,
            'injected_m3': float(0.5 * (grid[row] + grid[row + 1])),
            'share': float(share[row, segment]),
            'bin_m3': float(grid[1] - grid[0])}, ''


def _plateau(u: FloatArray, p: FloatArray) -> tuple[dict | None, str]:
    """
    The level the inflation's pressure settles at, or None and why there is none.

    The curve's slope is taken over windows of a tenth of the leg. A plateau needs the pressure
    never to fall on the way (a fall of more than 5 % of the highest pressure so far is a peak,
    not a plateau), and a level stretch after the steepest rise: a window whose slope is below
    PLATEAU_SLOPE_SHARE of the steepest. Its pressure is the pressure at the flattest window's
    centre; ``onset_injected_m3`` is where the pressure first reached 95 % of it, ``level_m3``
    the stretch around it that stays level.
    """
    if u.size < 4 or np.ptp(u) <= 0:
        return None, f'the inflation leg has {u.size} distinct volumes, too few for a plateau'
    highest = np.maximum.accumulate(p)
    fall = highest - p
    worst = int(np.argmax(fall))
    if highest[worst] > 0 and fall[worst] > (1 - PLATEAU_SHARE) * highest[worst]:
        top = int(np.argmax(p[:worst + 1]))
        return None, (f'the pressure falls during inflation, from {p[top] * 1e-3:.4g} kPa at '
                      f'{u[top] * 1e6:.4g} mL to {p[worst] * 1e-3:.4g} kPa at '
                      f'{u[worst] * 1e6:.4g} mL: a peak, not a plateau')
    grid = np.linspace(u[0], u[-1], SHARE_BINS + 1)
    sampled = np.interp(grid, u, p)
    width = PLATEAU_WINDOW_BINS
    slope = (sampled[width:] - sampled[:-width]) / (grid[width:] - grid[:-width])
    centre = 0.5 * (grid[width:] + grid[:-width])
    steepest = int(np.argmax(slope))
    if slope[steepest] <= 0:
        return None, 'the gauge pressure does not rise during inflation'
    after = np.abs(slope[steepest:])
    flattest = steepest + int(np.argmin(after))
    share = float(abs(slope[flattest]) / slope[steepest])
    if share > PLATEAU_SLOPE_SHARE:
        return None, (f'the pressure does not level off: after its steepest rise '
                      f'({slope[steepest] * 1e-9:.3g} kPa/mL) its slope never falls below '
                      f"{share * 100:.0f} % of it, where a plateau's falls below "
                      f'{PLATEAU_SLOPE_SHARE * 100:.0f} %')
    level = np.abs(slope) <= PLATEAU_SLOPE_SHARE * slope[steepest]
    first = last = flattest
    while first > 0 and level[first - 1]:
        first -= 1
    while last < level.size - 1 and level[last + 1]:
        last += 1
    pressure = float(np.interp(centre[flattest], u, p))
    if flattest == slope.size - 1:
        pressure = float(p[-1])   # level to the end: the pressure the inflation ends at
    reached = np.flatnonzero(p >= PLATEAU_SHARE * pressure)
    first_window = u <= u[0] + 0.1 * (u[-1] - u[0])
    last_window = u >= u[-1] - 0.2 * (u[-1] - u[0])
    slope_first = _slope(u[first_window], p[first_window])
    slope_last = _slope(u[last_window], p[last_window])
    return {
        'pressure_pa': pressure,
        'onset_injected_m3': float(u[reached[0]]),
        'level_m3': [float(grid[first]), float(grid[last + width])],
        'slope_share_of_steepest': share,
        'slope_ratio_end_to_start': (slope_last / slope_first
                                     if slope_first and math.isfinite(slope_last) else None),
    }, ''


def _slope(u: FloatArray, p: FloatArray) -> float:
    if u.size < 2 or np.ptp(u) == 0:
        return float('nan')
    return float(np.polyfit(u, p, 1)[0])


def _segment_chords(points: FloatArray, count: int) -> list[tuple[FloatArray, FloatArray]]:
    """Per segment of a backbone, its chords' lengths and directions (unwrapped) [m, rad]."""
    per, left = divmod(points.shape[0] - 1, count)
    if left or per < 2:
        return []
    found = []
    for j in range(count):
        steps = np.diff(points[j * per:(j + 1) * per + 1], axis=0)
        found.append((np.hypot(steps[:, 0], steps[:, 1]),
                      np.unwrap(np.arctan2(steps[:, 1], steps[:, 0]))))
    return found


def bend_angles(points: FloatArray, count: int) -> list[float]:
    """
    Each segment's bend angle [rad] from a camera backbone of ``count`` segments (base first).

    The backbone holds 1 + count x k points, k per segment, equally spaced along each arc
    (softseq_ros.segments.kinematics). On a constant-curvature arc every chord turns by the
    same angle d from the one before, and the tangents at the arc's ends lie d / 2 outside its
    first and last chord: the bend angle is the turn from the first chord to the last times
    k / (k - 1), exact for the model's arcs. Empty when the backbone has no such layout.
    """
    angles = []
    for _, direction in _segment_chords(points, count):
        turns = direction.size - 1
        angles.append(float((direction[-1] - direction[0]) * (turns + 1) / turns))
    return angles


def segment_lengths(snapshots: list, count: int) -> FloatArray | None:
    """
    Each segment's length [m] from the first camera snapshot that has the backbone's layout.

    An arc of chords c_k each turning by d is sum(c_k) x (d / 2) / sin(d / 2) long (exact for
    the model's constant-curvature arcs). None without such a snapshot.
    """
    for shot in snapshots:
        chords = _segment_chords(shot.points, count)
        if not chords:
            continue
        lengths = []
        for length, direction in chords:
            turn = (direction[-1] - direction[0]) / max(direction.size - 1, 1)
            half = 0.5 * abs(turn)
            lengths.append(float(np.sum(length) * (half / np.sin(half) if half > STRAIGHT_RAD
                                                      else 1)))
        return np.array(lengths)
    return None


def segment_limits(segments: list, names: tuple[str, ...]) -> dict[str, float]:
    """Per segment: the highest pressure its curve holds (its peak or plateau) [Pa, gauge]."""
    limits = {}
    for name, segment in zip(names, segments):
        v = np.linspace(segment.rest_volume, segment.max_volume, 2001)
        limits[name] = float(np.max(segment.pressure(v)))
    return limits
