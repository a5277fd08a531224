"""
The transients of a dynamic bag: its snap-throughs in time, how far it lags the quasi-static path.

A bag of a scene with a fluid network (docs/dynamic.md) holds the channel flows and snap-through
events that carry their start, duration (10 % to 90 % of the fluid moved), fluid moved and peak
exchange. From those and the recorded states this module finds, for each timed snap, the peak
channel flow and pressure drop around it; given the scene's network, each channel's peak Reynolds
number over the recorded flows; given the scene's equilibrium map, it also measures the
lag: how far the recorded segment volumes are from the quasi-static ones at the same injected
volume, off the snaps and at them, and how much later than the quasi-static path each snap
starts (in injected volume). A quasi-static bag has no transients: :func:`analyse_transients`
returns None. Everything here is SI; pressures are gauge. No ROS, no drawing.

Definitions (docs/analysis.md, "Transients of a dynamic bag"):

- a snap's window runs from WINDOW_BEFORE durations before its start to WINDOW_AFTER durations
  after it (at least WINDOW_MIN_SAMPLES recorded states either side, so that a snap shorter than
  the output interval still shows);
- the distance of a state from the quasi-static path is the largest difference of one segment's
  volume from its quasi-static volume at the same injected volume (the segments' volumes less
  their rest volumes: exact, by mass);
- *at the snaps* are the states in a recorded snap's window, and those from the approach to the
  fold the quasi-static path snaps from, as far before its snap as the recorded snap came after
  it (in injected volume: near the fold the quasi-static volumes run away like the square root
  of the distance to it, and the lag there is the fold passage's, which scales as the delay
  does); a quasi-static snap the recording never follows counts to the end of the recording.
  Every other state is *off the snaps*, where the lag is the steady one of a pumped
  network (about its time constant times the pump's flow).
"""

from dataclasses import dataclass
import math

import numpy as np
from numpy.typing import NDArray

from softseq_ros.analysis.recording import DEFLATION, INFLATION, FloatArray, Recording
from softseq_ros.wire.contract import NS_PER_S

WINDOW_BEFORE = 2.0
WINDOW_AFTER = 5.0
WINDOW_MIN_SAMPLES = 10


@dataclass(frozen=True)
class TimedSnap:
    """A snap-through in time as the actuator reported it, with its window in the recording."""

    number: int                  # 1-based, in the order reported
    start_s: float               # from the first pump command
    injected: float              # injected volume at its start [m^3]
    direction: str
    duration_s: float            # 10 % to 90 % of the fluid moved
    fluid_moved: float           # [m^3]
    peak_exchange: float         # [m^3/s]
    from_pressure: float         # gauge [Pa]
    to_pressure: float
    window_s: tuple[float, float]
    volume_change: tuple[float, ...]   # per segment, after less before [m^3]
    giving: tuple[str, ...] | None = None   # the segments that gave the fluid (None: unsaid)
    taking: tuple[str, ...] | None = None   # the segments that took it
    from_volumes: tuple[float, ...] = ()    # per segment, at its start and end [m^3]
    to_volumes: tuple[float, ...] = ()
    snap_through: bool = True    # False: an exchange without instability (lag, evening out)
    peak_injected: float = math.nan   # the pump's injected volume where its exchange peaked
    cut_short: bool = False      # the run ended while it was under way: numbers up to there


@dataclass(frozen=True)
class QuasiStaticSnap:
    """A snap of the quasi-static path along the recording's injected volumes."""

    row: int                     # the first state past it
    injected: float              # where it happens [m^3]
    direction: str
    volume_change: tuple[float, ...]   # per segment, after less before [m^3]


@dataclass
class Transients:
    """What a dynamic recording shows in time; ``metrics`` is its block of metrics.json."""

    snaps: list[TimedSnap]
    channel_names: tuple[str, ...]
    # Per recorded state, when the scene's map was given: the quasi-static volumes (n, N) at
    # the same injected volume.
    quasi_static_volumes: FloatArray | None
    metrics: dict
    warnings: list[str]


@dataclass(frozen=True)
class TransientWindow:
    """One snap's stretch of the recording, as plain arrays (what a figure worker gets)."""

    snap: TimedSnap
    time_s: FloatArray                        # from the snap's start
    pressure: FloatArray                      # gauge [Pa]
    volumes: FloatArray                       # (n, N) [m^3]
    quasi_static_volumes: FloatArray | None   # (n, N) [m^3]
    flow_time_s: FloatArray                   # from the snap's start
    flow: FloatArray                          # (m, channels) [m^3/s], towards the tip


def is_dynamic(recording: Recording) -> bool:
    """True for a bag of a scene with a fluid network: channel flows or snaps in time."""
    return recording.channel_flows is not None or any(_timed(event)
                                                      for event in recording.events)


def _timed(event: dict) -> bool:
    return event.get('start_ns') is not None and event.get('duration_s') is not None


def analyse_transients(recording: Recording, emap: object | None = None,
                       network: object | None = None) -> Transients | None:
    """
    The transients of a dynamic recording (None for a quasi-static one).

    ``emap``: the scene's :class:`softseq_ros.quasistatic.equilibrium.EquilibriumMap`; without
    it there is no quasi-static path to measure the lag against, and ``lag`` is None.
    ``network``: the scene's :class:`softseq_ros.scene.network.NetworkSettings`; without it
    the channels' sizes are unknown, and ``peak_reynolds`` is None.
    """
    if not is_dynamic(recording):
        return None
    exchanges = timed_snaps(recording, every_exchange=True)
    snaps = [snap for snap in exchanges if snap.snap_through]
    warnings = []
    earlier = sum(_timed(event) for event in recording.events) - len(exchanges)
    if earlier:
        warnings.append(f'left out of the transients: {earlier} snap-through(s) in time that '
                        'started before the first pump command (latched from an earlier run)')
    flows = recording.channel_flows
    names = flows.names if flows is not None else ()
    entries = [_snap_entry(snap, recording) for snap in snaps]
    reynolds = _peak_reynolds(flows, network)
    if reynolds is not None:
        from softseq_ros.dynamic.network import laminar_range_warning
        from softseq_ros.scene.network import BLASIUS

        for (name, peak), tube in zip(reynolds.items(), network.channels):
            line = laminar_range_warning(name, peak, tube.friction == BLASIUS)
            if line is not None:
                warnings.append(line)
    quasi_static = lag = None
    if emap is not None:
        from softseq_ros.quasistatic.equilibrium import DomainError

        try:
            quasi_static, lag = _lag(recording, emap, snaps, entries)
        except DomainError as err:
            warnings.append(f'no lag: the quasi-static path cannot follow the recording ({err})')
    metrics = {
        'definition': 'duration: 10 % to 90 % of the fluid moved; peaks within '
                      f'{WINDOW_BEFORE:g} durations before to {WINDOW_AFTER:g} after the start; '
                      'lag: largest difference of a segment volume from the quasi-static one '
                      'at the same injected volume',
        'channels': list(names),
        'snaps': entries,
        'exchanges': [_exchange_entry(snap) for snap in exchanges if not snap.snap_through],
        'peak_reynolds': reynolds,
        'lag': lag,
    }
    return Transients(snaps, names, quasi_static, metrics, warnings)


def _peak_reynolds(flows: object | None, network: object | None) -> dict | None:
    """
    Each channel's largest Reynolds number over the recorded flows, by name.

    None without the scene's network, or when the recording's channels are not its channels.
    The actuator's states come at the network's rate while fluid moves, so the recorded peak is
    the peak of those samples (the model's own, between them, can be a little higher).
    """
    if network is None or flows is None or len(network.channels) != len(flows.names):
        return None
    from softseq_ros.dynamic.network import tube_law

    peaks = np.max(np.abs(flows.flow), axis=0) if flows.flow.shape[0] else \
        np.zeros(len(flows.names))
    return {name: tube_law(tube, network.fluid).reynolds(float(peak))
            for name, tube, peak in zip(flows.names, network.channels, peaks)}


def timed_snaps(recording: Recording, every_exchange: bool = False) -> list[TimedSnap]:
    """
    The snap-throughs in time that ``actuator/events`` reported for this run, in order.

    ``every_exchange``: every exchange of fluid between the segments it reported, the
    snap-throughs and the others (``snap_through`` False: no instability drove them).
    """
    times = recording.state_time_s
    snaps = []
    for event in recording.events:
        # Only a snap in time carries its start: one from before this run can be told apart.
        if not _timed(event) or int(event['start_ns']) < recording.start_ns:
            continue
        # An exchange in time without the key (an older bag) was reported as a snap-through.
        snap_through = event.get('snap_through') is not False
        if not (snap_through or every_exchange):
            continue
        number = len(snaps) + 1
        start = (int(event['start_ns']) - recording.start_ns) / NS_PER_S
        duration = float(event['duration_s'])
        row = min(int(np.searchsorted(times, start)), times.size - 1)
        sign = recording.state_flow_sign[row] if recording.state_flow_sign.size else 1
        snaps.append(TimedSnap(
            number, start, float(event['injected_m3']), DEFLATION if sign < 0 else INFLATION,
            duration, _float(event.get('fluid_moved_m3')),
            _float(event.get('peak_exchange_m3_per_s')), float(event['from_pressure_pa']),
            float(event['to_pressure_pa']), _window(times, row, start, duration),
            tuple(float(after) - float(before) for before, after in
                  zip(event['from_volumes_m3'], event['to_volumes_m3'])),
            _names(event.get('giving_segments')), _names(event.get('taking_segments')),
            tuple(float(v) for v in event['from_volumes_m3']),
            tuple(float(v) for v in event['to_volumes_m3']), snap_through,
            _peak_injected(recording, event.get('peak_ns')), event.get('cut_short') is True))
    return snaps


def _peak_injected(recording: Recording, peak_ns: object) -> float:
    """The pump's injected volume [m^3] when an exchange peaked (nan: an older bag's event)."""
    if peak_ns is None or not recording.pump_time_s.size:
        return math.nan
    at = (int(peak_ns) - recording.start_ns) / NS_PER_S
    return float(np.interp(at, recording.pump_time_s, recording.pump_injected))


def _names(value: object) -> tuple[str, ...] | None:
    return None if value is None else tuple(str(name) for name in value)


def _float(value: object) -> float:
    return math.nan if value is None else float(value)


def _window(times: FloatArray, row: int, start: float, duration: float) -> tuple[float, float]:
    """WINDOW_BEFORE to WINDOW_AFTER durations around the start, and enough states to see."""
    near = times[max(row - 50, 0):row + 50]
    step = float(np.median(np.diff(near))) if near.size > 1 else 0.0
    return (start - max(WINDOW_BEFORE * duration, WINDOW_MIN_SAMPLES * step),
            start + max(WINDOW_AFTER * duration, WINDOW_MIN_SAMPLES * step))


def _exchange_entry(snap: TimedSnap) -> dict:
    """An exchange of fluid that was no snap-through, as metrics.json holds it."""
    return {'start_time_s': snap.start_s, 'injected_m3': snap.injected,
            'direction': snap.direction, 'duration_s': snap.duration_s,
            'fluid_moved_m3': snap.fluid_moved, 'peak_exchange_m3_per_s': snap.peak_exchange,
            'giving_segments': None if snap.giving is None else list(snap.giving),
            'taking_segments': None if snap.taking is None else list(snap.taking),
            'cut_short': snap.cut_short}


def _snap_entry(snap: TimedSnap, recording: Recording) -> dict:
    entry = {'start_time_s': snap.start_s, 'injected_m3': snap.injected,
             'direction': snap.direction, 'duration_s': snap.duration_s,
             'fluid_moved_m3': snap.fluid_moved,
             'peak_exchange_m3_per_s': snap.peak_exchange,
             'from_pressure_pa': snap.from_pressure, 'to_pressure_pa': snap.to_pressure,
             'giving_segments': None if snap.giving is None else list(snap.giving),
             'taking_segments': None if snap.taking is None else list(snap.taking),
             'window_s': list(snap.window_s),
             'peak_channel_flow_m3_per_s': {}, 'peak_pressure_drop_pa': {},
             'quasi_static_injected_m3': None, 'delay_injected_m3': None,
             'cut_short': snap.cut_short}
    flows = recording.channel_flows
    if flows is not None:
        inside = (flows.time_s >= snap.window_s[0]) & (flows.time_s <= snap.window_s[1])
        for j, name in enumerate(flows.names):
            entry['peak_channel_flow_m3_per_s'][name] = _largest(flows.flow[inside, j])
            entry['peak_pressure_drop_pa'][name] = _largest(flows.drop[inside, j])
    return entry


def _largest(values: FloatArray) -> float | None:
    """The value of largest magnitude, with its sign (None when there is none)."""
    if not values.size:
        return None
    return float(values[int(np.argmax(np.abs(values)))])


def _lag(recording: Recording, emap: object, snaps: list[TimedSnap],
         entries: list[dict]) -> tuple[FloatArray, dict]:
    """The quasi-static volumes per state and the lag block; fills each entry's delay."""
    from softseq_ros.quasistatic.equilibrium import Tracker

    volumes = recording.volumes
    # What the segments hold, by mass: the actuator's outputs come at its own rate, between the
    # pump's commands.
    injected = volumes.sum(axis=1) - emap.total_rest_volume
    path = Tracker(emap).sweep(injected)
    distance = np.max(np.abs(volumes - path.volumes), axis=1)
    span = float(np.ptp(injected)) or 1.0
    at_snaps = np.zeros(distance.size, dtype=bool)
    unpaired = _quasi_static_snaps(recording, emap, injected, path)
    times = recording.state_time_s
    for snap, entry in zip(snaps, entries):
        first = int(np.searchsorted(times, snap.window_s[0]))
        last = int(np.searchsorted(times, snap.window_s[1], side='right'))
        # Where its exchange peaked: an exchange in time starts where a segment first gives
        # fluid, which can be before the fold; it peaks past it, by the fold passage's delay.
        at = snap.injected if math.isnan(snap.peak_injected) else snap.peak_injected
        # The quasi-static snap this one follows moves fluid the same way, and came first
        # (or within the window: a path can also snap early).
        candidates = [q for q in unpaired if q.direction == snap.direction and q.row < last
                      and np.dot(q.volume_change, snap.volume_change) > 0]
        if candidates:
            partner = min(candidates, key=lambda q: abs(q.injected - at))
            unpaired.remove(partner)
            later = 1.0 if snap.direction == INFLATION else -1.0
            entry['quasi_static_injected_m3'] = partner.injected
            entry['delay_injected_m3'] = later * (at - partner.injected)
            first = min(first, _approach(injected, partner, later, abs(at - partner.injected)))
        at_snaps[first:last] = True
    for never_followed in unpaired:
        at_snaps[never_followed.row:] = True
    return path.volumes, {
        'volume_range_m3': span,
        'off_snaps': _spread(distance[~at_snaps], span),
        'at_snaps': _spread(distance[at_snaps], span),
        'quasi_static_snaps_not_followed_m3': [q.injected for q in unpaired],
    }


def _approach(injected: FloatArray, partner: QuasiStaticSnap, later: float,
              delay: float) -> int:
    """
    The first row of the fold passage's approach to a quasi-static snap.

    As far before the quasi-static snap as the recorded snap came after it, in injected
    volume, along the leg that reaches the fold. Near a fold the quasi-static volumes run away
    like the square root of the distance to it while the recorded state lags: the lag there is
    the fold passage's (its width and the delay both scale as the flow to the 2/3), not the
    steady lag of a pumped network.
    """
    row = partner.row
    reach = partner.injected - later * delay
    while row > 0 and later * (injected[row - 1] - reach) >= 0.0 \
            and later * (injected[row - 1] - injected[row]) <= 0.0:
        row -= 1
    return row


def _quasi_static_snaps(recording: Recording, emap: object, injected: FloatArray,
                        path: object) -> list[QuasiStaticSnap]:
    """Each snap of the quasi-static path with the state row it lands on."""
    from softseq_ros.quasistatic.equilibrium import Tracker

    found = []
    for row in np.flatnonzero(path.snap).tolist():
        # One row can pass several snaps (a cascade): walk just that row again, from the
        # branch the path was on, to learn which.
        before = Tracker(emap, float(injected[row - 1]), path.volumes[row - 1]) if row else \
            Tracker(emap)
        direction = DEFLATION if recording.state_flow_sign[row] < 0 else INFLATION
        found.extend(QuasiStaticSnap(row, float(event.injected), direction,
                                     tuple(np.subtract(event.to_volumes, event.from_volumes)))
                     for event in before.move(float(injected[row])))
    return found


def _spread(distance: FloatArray, span: float) -> dict | None:
    if not distance.size:
        return None
    largest, median = float(np.max(distance)), float(np.median(distance))
    return {'largest_m3': largest, 'median_m3': median, 'largest_share_of_range': largest / span,
            'median_share_of_range': median / span, 'states': int(distance.size)}


def transient_windows(recording: Recording, found: Transients, limit: int,
                      points: int) -> list[TransientWindow]:
    """The first ``limit`` snaps' windows, each thinned to at most about ``points`` states."""
    windows = []
    flows = recording.channel_flows
    for snap in found.snaps[:limit]:
        rows = _rows_within(recording.state_time_s, snap.window_s, points)
        if flows is not None:
            flow_rows = _rows_within(flows.time_s, snap.window_s, points)
            flow_time, flow = flows.time_s[flow_rows] - snap.start_s, flows.flow[flow_rows]
        else:
            flow_time, flow = np.zeros(0), np.zeros((0, 0))
        quasi_static = found.quasi_static_volumes
        windows.append(TransientWindow(
            snap, recording.state_time_s[rows] - snap.start_s, recording.pressure[rows],
            recording.volumes[rows], None if quasi_static is None else quasi_static[rows],
            flow_time, flow))
    return windows


def _rows_within(times: FloatArray, window: tuple[float, float], points: int) -> NDArray[np.intp]:
    lo, hi = np.searchsorted(times, window[0]), np.searchsorted(times, window[1], side='right')
    stride = max(1, -(-(hi - lo) // points))
    return np.arange(lo, hi, stride)
