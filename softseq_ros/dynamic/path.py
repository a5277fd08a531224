"""
A scene's fluid network along a pump programme: the dynamic path, sampled where asked.

The quasi-static solver answers "where is the equilibrium at this injected volume"; with a
network the answer depends on how fast the volume got there. Here the syringe's flow is
piecewise constant in time (a :class:`FlowSchedule`): the legs of a pump programme (inflate
and deflate at the pump's flow rate, hold at zero flow), or a history of injected volumes
pushed at one flow rate. :func:`run_schedule` integrates the network
(:class:`softseq_ros.dynamic.flow.NetworkFlow`, through its public methods only) across the
legs and reads the state at the asked times: time, injected volume, the syringe's gauge
pressure, the segment volumes and curvatures, the channel flows; with the snap-throughs the
network lived (:class:`softseq_ros.dynamic.events.DynamicSnap`: start, fluid moved, peak exchange
flow, 10-90 % duration) and each channel's peak Reynolds number over the samples.
:func:`write_path` and :func:`write_snaps` write both as the CSV files of ``softseq solve``.

Every value is SI (s, m^3, m^3/s, Pa gauge, 1/m).
"""

import csv
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from softseq_ros.dynamic.events import DynamicSnap, FoldCrossing
from softseq_ros.dynamic.flow import NetworkDomainError, NetworkFlow
from softseq_ros.errors import UserError
from softseq_ros.scene.csv_columns import write_rows
from softseq_ros.scene.network import NetworkSettings
from softseq_ros.scene.programme import PumpProfile
from softseq_ros.segments.models import Segment
from softseq_ros.segments.supply import CompliantSupply

FloatArray = NDArray[np.float64]


class PathError(UserError):
    """Sample times or a volume history the network cannot be run along."""


@dataclass(frozen=True)
class FlowSchedule:
    """
    The syringe's flow in time: ``flows[k]`` [m^3/s] from ``times[k]`` to ``times[k + 1]`` [s].

    Time 0 is where the network starts at rest, nothing injected; the flow is zero after the
    last time.
    """

    times: FloatArray
    flows: FloatArray

    def injected_at(self, t: ArrayLike) -> FloatArray:
        """The injected volume [m^3] the schedule has pushed by times ``t`` [s]."""
        volumes = np.concatenate([[0.0], np.cumsum(self.flows * np.diff(self.times))])
        return np.interp(np.asarray(t, dtype=float), self.times, volumes)

    @property
    def end_s(self) -> float:
        """When the last leg ends [s]."""
        return float(self.times[-1])


@dataclass
class DynamicPath:
    """
    The network's state at the sample times, in time order (one row per sample).

    ``pressure`` is the syringe's gauge pressure [Pa] (the fed segment's plus the supply
    line's drop; behind a compliant line, the line's), ``segment_pressure[:, i]`` segment i's
    own [Pa, gauge];
    ``channel_flows[:, j]`` flows from segment j to j + 1 [m^3/s]; ``snap[i]`` says a
    snap-through started after sample i - 1 and by sample i; ``snaps`` are all the
    exchanges of fluid between the segments (snap-throughs or not), one still under way at the
    last sample cut short there (``cut_short``); ``peak_reynolds[j]`` is channel
    j's largest Reynolds number over the samples; ``steps`` the integrator's steps.

    ``folds``: each segment's passages through the folds of its own curve by the last sample
    (:class:`softseq_ros.dynamic.events.FoldCrossing`, located in time).

    ``drained`` (None when every sample was reached) says why the path ends before the last
    sample time: the syringe drew so fast that a segment, collapsing below its rest volume,
    pulled a suction beyond vacuum while the others still held fluid the channels had not yet
    let through (softseq_ros.dynamic.flow: a collapse short of that is followed), so the rows
    end at the last sample before it.

    Behind a compliant supply line (a scene's ``supply``), per sample: ``line_volume`` the
    fluid the line holds [m^3], ``line_pressure`` its gauge pressure [Pa] and
    ``supply_flow`` the supply tube's flow into the fed segment [m^3/s]; None without a line.

    Behind a pressure regulator (softseq_ros.dynamic.regulated): ``pressure`` is its outlet's
    gauge pressure, ``target_pressure`` its programme's target [Pa, gauge], ``supply_flow``
    the supply tube's flow into the fed segment, ``injected`` what it let in since rest.
    """

    time_s: FloatArray
    injected: FloatArray
    pressure: FloatArray
    volumes: FloatArray
    curvatures: FloatArray
    channel_flows: FloatArray
    snap: NDArray[np.bool_]
    snaps: list[DynamicSnap]
    peak_reynolds: list[float]
    steps: int
    drained: str | None = None
    folds: list[FoldCrossing] = field(default_factory=list)
    segment_pressure: FloatArray = field(default_factory=lambda: np.empty((0, 0)))
    line_volume: FloatArray | None = None
    line_pressure: FloatArray | None = None
    supply_flow: FloatArray | None = None
    target_pressure: FloatArray | None = None


@dataclass(frozen=True)
class StartState:
    """A balanced state the network starts from at rest: what is injected and where it sits."""

    injected_m3: float
    volumes_m3: tuple[float, ...]


def programme_schedule(profile: PumpProfile,
                       from_rest: bool = True) -> tuple[FlowSchedule, float]:
    """
    The flow schedule of a pump programme, and the programme's time 0 on the schedule's clock.

    A programme that starts with fluid already injected is reached first at the pump's flow
    rate from rest (so the offset is that ramp's duration; 0 otherwise), unless it starts
    where it is (``from_rest`` False: the network already holds that fluid, at rest).
    """
    times, volumes = profile.breakpoints()
    lead = profile.start_injected / profile.flow_rate if from_rest else 0.0
    flows = np.diff(volumes) / np.diff(times)
    if lead > 0.0:
        times = np.concatenate([[-lead], times])
        flows = np.concatenate([[profile.flow_rate], flows])
    return FlowSchedule(times + lead, flows), lead


def history_schedule(history: ArrayLike, flow_rate: float) -> tuple[FlowSchedule, FloatArray]:
    """
    A volume history pushed at ``flow_rate`` [m^3/s]: the schedule and the time of each row.

    The syringe moves from rest to the first row and then from row to row at the flow rate,
    inflating or deflating as the volumes go; a repeated volume takes no time.
    """
    volumes = np.asarray(history, dtype=float)
    if volumes.ndim != 1 or volumes.size == 0:
        raise PathError('a volume history needs at least one injected volume')
    if not np.all(np.isfinite(volumes)) or np.any(volumes < 0.0):
        raise PathError('injected volumes must be finite and >= 0 m^3')
    if not flow_rate > 0.0:
        raise PathError(f'the flow rate must be > 0 m^3/s, got {flow_rate:g}')
    steps = np.diff(np.concatenate([[0.0], volumes]))
    row_times = np.cumsum(np.abs(steps)) / flow_rate
    moving = steps != 0.0
    starts = np.concatenate([[0.0], row_times[moving]])
    return FlowSchedule(starts, np.sign(steps[moving]) * flow_rate), row_times


def timed_history_schedule(times: ArrayLike, history: ArrayLike) -> FlowSchedule:
    """
    A history in time: the syringe at ``history[k]`` [m^3] at ``times[k]`` [s], linear between.

    The network is at rest, nothing injected, at time 0; a first row later than 0 is reached
    by a steady push from there (a first row at time 0 must be at 0 m^3). Times increase
    strictly; a row at the volume of the one before is a hold.
    """
    t = np.asarray(times, dtype=float)
    volumes = np.asarray(history, dtype=float)
    if t.ndim != 1 or t.shape != volumes.shape or t.size == 0:
        raise PathError('a history in time needs as many times as injected volumes, at least one')
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(volumes))) or np.any(volumes < 0.0):
        raise PathError('times and injected volumes must be finite, the volumes >= 0 m^3')
    if t[0] < 0.0:
        raise PathError(f'time_s in data row 1: {t[0]:g} s is before the start at 0 s')
    if t[0] == 0.0 and volumes[0] != 0.0:
        raise PathError(f'time_s in data row 1: the network starts at rest at 0 s, so the '
                        f'first row at 0 s must be at 0 m^3 injected, got {volumes[0]:g} m^3')
    steps = np.diff(t)
    if np.any(steps <= 0.0):
        row = int(np.argmax(steps <= 0.0)) + 2
        raise PathError(f'time_s in data row {row}: {t[row - 1]:g} s does not come after the '
                        f'row before ({t[row - 2]:g} s); times must increase')
    if t[0] > 0.0:
        t, volumes = np.concatenate([[0.0], t]), np.concatenate([[0.0], volumes])
    return FlowSchedule(t, np.diff(volumes) / np.diff(t))


def run_schedule(segments: Sequence[Segment], network: NetworkSettings,
                 schedule: FlowSchedule, sample_times: ArrayLike,
                 rtol: float | None = None, line: CompliantSupply | None = None,
                 start: StartState | None = None) -> DynamicPath:
    """
    Integrate the network along ``schedule`` and read its state at ``sample_times`` [s].

    The network starts at rest with nothing injected, or at rest in ``start`` (the injected
    volume and the segments' volumes of a balanced state, as a history left it).

    The sample times must be >= 0 and in order; each leg's flow is set exactly at its start,
    so a sample at a leg's boundary sees the flow of the leg that starts there. ``rtol``
    overrides the network's tolerance; ``line`` is the syringe line's trapped gas and
    compliance (a scene's ``supply``). A segment pushed beyond its curve raises
    :class:`softseq_ros.dynamic.flow.NetworkDomainError` (a UserError).
    """
    samples = np.asarray(sample_times, dtype=float)
    if samples.ndim != 1 or samples.size == 0:
        raise PathError('at least one sample time is needed')
    if not np.all(np.isfinite(samples)) or samples[0] < 0.0 or np.any(np.diff(samples) < 0.0):
        raise PathError('sample times must be finite, >= 0 s and in order')
    fluid = NetworkFlow(segments, network, rtol=rtol, line=line)
    if start is not None:
        fluid.set_volumes(start.volumes_m3, start.injected_m3)
    n, channels = len(fluid.segments), len(fluid.laws)
    volumes = np.empty((samples.size, n))
    # The line's fluid, pressure and the supply tube's flow (columns), behind a line.
    line_rows = np.empty((samples.size, 3 if line is not None else 0))
    flows = np.empty((samples.size, channels))
    pressure = np.empty(samples.size)
    injected = np.empty(samples.size)
    snaps: list[DynamicSnap] = []
    folds: list[FoldCrossing] = []
    legs = list(zip(schedule.times[:-1], schedule.times[1:], schedule.flows))
    leg = 0
    drained = None
    reached = samples.size
    # The flow of the leg under way, or zero once the schedule has run out.
    fluid.set_flow(float(legs[0][2]) if legs and schedule.times[0] <= 0.0 else 0.0)
    i = 0
    while i < samples.size:
        try:
            while leg < len(legs) and legs[leg][1] <= samples[i]:
                fluid.advance(float(legs[leg][1]))
                snaps.extend(fluid.take_snaps())
                folds.extend(fluid.take_fold_crossings())
                leg += 1
                fluid.set_flow(float(legs[leg][2]) if leg < len(legs) else 0.0)
        except NetworkDomainError as err:
            if fluid.flow >= 0.0:
                raise
            drained, reached = str(err), i
            break
        # The samples of the leg under way, read at once.
        stop = int(np.searchsorted(samples, legs[leg][1], side='left')) if leg < len(legs) \
            else samples.size
        times = samples[i:stop]
        try:
            states = fluid.advance_through(times)
        except NetworkDomainError as err:
            if fluid.flow >= 0.0:
                raise
            states = err.rows
            drained, reached = str(err), i + states.shape[0]
            # What a sample-by-sample run had taken by its last sample.
            last = times[states.shape[0] - 1] if states.shape[0] else -np.inf
            snaps.extend(s for s in fluid.take_snaps() if s.end_s <= last)
            folds.extend(c for c in fluid.take_fold_crossings() if c.time_s <= last)
        else:
            snaps.extend(fluid.take_snaps())
            folds.extend(fluid.take_fold_crossings())
        rows = slice(i, i + states.shape[0])
        injected[rows], volumes[rows], flows[rows], pressure[rows] = fluid.read_states(
            times[:states.shape[0]], states)
        if line is not None:
            line_rows[rows] = np.column_stack(fluid.read_line(states, volumes[rows]))
        if drained is not None:
            break
        i = stop
    if drained is None:
        # The last exchange, if its ringing paused it, has run its course by the end.
        fluid.finish_exchanges()
        snaps.extend(fluid.take_snaps())
    samples, volumes, flows = samples[:reached], volumes[:reached], flows[:reached]
    line_rows = line_rows[:reached]
    pressure, injected = pressure[:reached], injected[:reached]
    curvatures = np.column_stack([np.asarray(s.curvature(volumes[:, k]), dtype=float)
                                  for k, s in enumerate(fluid.segments)])
    snap = np.zeros(samples.size, dtype=bool)
    for found in snaps:
        if not found.snap_through:
            continue
        row = int(np.searchsorted(samples, found.start_s, side='left'))
        if row < samples.size:
            snap[row] = True
    path = DynamicPath(samples, injected, pressure, volumes, curvatures, flows, snap, snaps,
                       [float(x) for x in fluid.peak_reynolds], fluid.steps, drained, folds,
                       fluid.row_pressures(volumes))
    if line is not None:
        path.line_volume, path.line_pressure, path.supply_flow = line_rows.T.copy()
    return path


def programme_path(segments: Sequence[Segment], network: NetworkSettings,
                   profile: PumpProfile, times: ArrayLike | None = None,
                   rate_hz: float | None = None, rtol: float | None = None,
                   line: CompliantSupply | None = None,
                   start: StartState | None = None) -> DynamicPath:
    """
    The dynamic path along a pump programme, at ``times`` [s] or at ``rate_hz`` [Hz].

    Times are on the programme's clock (0 at the start of its first leg); by default the
    programme is sampled as the pump publishes it (``rate_hz``, its end included). ``line``:
    the syringe line behind the network (:func:`run_schedule`); ``start``: the state the
    programme starts from, at rest (where its start history led), instead of a push from rest.
    """
    schedule, lead = programme_schedule(profile, from_rest=start is None)
    if times is None:
        if rate_hz is None:
            raise PathError('give the sample times or the rate to sample at')
        times, _ = profile.sample(rate_hz)
    path = run_schedule(segments, network, schedule, np.asarray(times, dtype=float) + lead,
                        rtol, line, start)
    if lead > 0.0:
        path.time_s = path.time_s - lead
        path.snaps = [replace(s, start_s=s.start_s - lead, end_s=s.end_s - lead,
                              peak_s=s.peak_s - lead) for s in path.snaps]
        path.folds = [replace(c, time_s=c.time_s - lead) for c in path.folds]
    return path


def history_path(segments: Sequence[Segment], network: NetworkSettings, history: ArrayLike,
                 flow_rate: float, rtol: float | None = None,
                 times: ArrayLike | None = None,
                 line: CompliantSupply | None = None) -> DynamicPath:
    """
    The dynamic path along a volume history, row by row.

    Pushed at ``flow_rate`` [m^3/s] from row to row, or, with ``times`` [s], at each row's
    time (:func:`timed_history_schedule`: holds included). ``line``: the syringe line behind
    the network (:func:`run_schedule`).
    """
    if times is None:
        schedule, row_times = history_schedule(history, flow_rate)
    else:
        schedule, row_times = timed_history_schedule(times, history), np.asarray(times, float)
    return run_schedule(segments, network, schedule, row_times, rtol, line)


# Behind a compliant supply line: the line's gauge pressure, the fluid it holds and the supply
# tube's flow into the fed segment. Named apart from the per-segment columns (which start with
# pressure_, volume_, curvature_ and flow_), so no segment's name can make a column twice.
LINE_COLUMNS = ['supply_pressure_pa', 'supply_volume_m3', 'supply_flow_m3_per_s']
# Behind a pressure regulator: its target and the supply tube's flow (pressure_pa is its
# outlet's pressure, injected_m3 what it let in).
REGULATOR_COLUMNS = ['target_pa', 'supply_flow_m3_per_s']


def path_columns(names: Sequence[str], line: bool = False,
                 regulator: bool = False) -> list[str]:
    """
    Column names of a dynamic path's CSV for segments ``names`` (base to tip).

    The quasi-static path's columns (``pressure_pa`` is the syringe's gauge pressure here),
    with the time first, each segment's own gauge pressure after the syringe's, and each
    channel's flow before the event column; behind a compliant supply line (``line``),
    LINE_COLUMNS after the channels' flows, behind a regulator (``regulator``),
    REGULATOR_COLUMNS.
    """
    flows = [f'flow_{a}_to_{b}_m3_per_s' for a, b in zip(names[:-1], names[1:])]
    return (['time_s', 'injected_m3', 'pressure_pa'] + [f'pressure_{n}_pa' for n in names]
            + [f'volume_{n}_m3' for n in names]
            + [f'curvature_{n}_per_m' for n in names] + flows
            + (LINE_COLUMNS if line else []) + (REGULATOR_COLUMNS if regulator else [])
            + ['event'])


def write_path(out: str | Path, path: DynamicPath, names: Sequence[str]) -> None:
    """One row per sample; ``event`` is ``snap`` where a snap-through started."""
    line = path.line_volume is not None
    regulator = path.target_pressure is not None
    if line:
        line_rows = np.column_stack([path.line_pressure, path.line_volume, path.supply_flow])
    elif regulator:
        line_rows = np.column_stack([path.target_pressure, path.supply_flow])
    else:
        line_rows = np.empty((path.time_s.size, 0))
    write_rows(out, path_columns(names, line, regulator), (
        ((path.time_s[i], path.injected[i], path.pressure[i], *path.segment_pressure[i],
          *path.volumes[i],
          *path.curvatures[i], *path.channel_flows[i], *line_rows[i]),
         'snap' if path.snap[i] else '')
        for i in range(path.time_s.size)))


def snaps_file(out: str | Path) -> Path:
    """Where the snap-throughs of a path written to ``out`` go: ``NAME_snaps.csv`` beside it."""
    out = Path(out)
    return out.with_name(f'{out.stem}_snaps.csv')


def snap_columns(names: Sequence[str], line: bool = False) -> list[str]:
    """
    Column names of the exchanges' CSV for segments ``names`` (base to tip).

    One row per exchange of fluid between the segments (docs/dynamic.md). Numbers, then
    ``giving`` and ``taking``: the names of the segments that gave and took the fluid,
    separated by spaces, ``snap_through``: 1 when the state passed where the equilibrium
    is unstable (a snap-through), 0 for an exchange without instability, and ``cut_short``: 1
    when the path ended while the exchange was still under way (its numbers up to there).
    ``exchanged_<name>_m3`` is what a segment gained from the others (its volume's change
    less the pump's push into it; negative: it gave). Behind a compliant supply line
    (``line``) the pump pushes into the line, and ``supply_exchanged_m3``, after the
    segments', is what the line gained from them beyond that push (negative: its gas expanded
    into them).
    """
    return (['start_s', 'end_s', 'injected_m3', 'duration_s', 'fluid_moved_m3',
             'peak_exchange_m3_per_s', 'peak_s', 'from_pressure_pa', 'to_pressure_pa']
            + [f'from_volume_{n}_m3' for n in names] + [f'to_volume_{n}_m3' for n in names]
            + [f'exchanged_{n}_m3' for n in names]
            + (['supply_exchanged_m3'] if line else [])
            + ['giving', 'taking', 'snap_through', 'cut_short'])


def _write_table(out: str | Path, header: Sequence[str], rows: Iterable[list[str]]) -> None:
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with out.open('w', newline='') as handle:
        writer = csv.writer(handle)
        writer.writerow(header)
        writer.writerows(rows)


def write_snaps(out: str | Path, snaps: Sequence[DynamicSnap], names: Sequence[str],
                line: bool = False) -> None:
    """One row per exchange (the header alone when there was none); ``line``: behind one."""
    _write_table(out, snap_columns(names, line), ([repr(float(x)) for x in (
        snap.start_s, snap.end_s, snap.injected, snap.duration_s, snap.fluid_moved_m3,
        snap.peak_exchange_m3_per_s, snap.peak_s, snap.from_pressure, snap.to_pressure,
        *snap.from_volumes, *snap.to_volumes, *snap.exchanged_m3,
        *([snap.exchanged_line_m3] if line else []))]
        + [' '.join(names[i] for i in snap.giving()), ' '.join(names[i] for i in snap.taking()),
           str(int(snap.snap_through)), str(int(snap.cut_short))]
        for snap in snaps))


def folds_file(out: str | Path) -> Path:
    """Where the fold crossings of a path written to ``out`` go: ``NAME_folds.csv`` beside it."""
    out = Path(out)
    return out.with_name(f'{out.stem}_folds.csv')


FOLD_COLUMNS = ['time_s', 'injected_m3', 'segment', 'kind', 'direction', 'fold_volume_m3',
                'fold_pressure_pa']


def write_folds(out: str | Path, folds: Sequence[FoldCrossing]) -> None:
    """One row per passage of a segment through a fold of its curve (the header alone: none)."""
    _write_table(out, FOLD_COLUMNS, ([
        repr(float(c.time_s)), repr(float(c.injected)), c.segment, c.kind, c.direction,
        repr(float(c.fold_volume_m3)), repr(float(c.fold_pressure_pa))] for c in folds))
