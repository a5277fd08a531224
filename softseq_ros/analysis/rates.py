"""
Rate maps: which sequence a scene with a fluid network shows at each pump flow and channel size.

``softseq rates SCENE --flows ... --radii ...`` runs the scene's pump programme (inflate, hold,
deflate) at every pump flow rate of the grid, with every channel of the scene's network set to
every radius of the grid, on the package's parallel executor (:func:`softseq_ros.parallel.
run_jobs`: local processes, or a Dask scheduler). Each run is the dynamic path
(:mod:`softseq_ros.dynamic.path`), measured with the same metrics as a recording
(:func:`softseq_ros.analysis.metrics.analyse`), so its sequence type comes from the one
classifier (:func:`softseq_ros.quasistatic.sequence.sequence_type`) with the tolerance of a
sampled path. Who takes the inflow is said twice, as the report says it (the same definitions,
:mod:`softseq_ros.analysis.metrics`): the *leading segment* is the first to take 90 % of the
inflow ("leads from": who fills first), the *switch* is where a segment's share changes most
("takes over at": where the filling changes hands). The quasi-static path along the same
programme is measured the same way, for reference.

The table (``rates.csv``) has one row per grid point: flow [m^3/s], radius [m], sequence type,
leading segment and where it leads from, the segment taking over at the switch and where, the
snap-throughs the network lived (start [m^3 injected],
direction, 10-90 % duration [s], fluid moved [m^3], peak exchange flow [m^3/s]; several
snap-throughs of one run are separated by ``;`` in the same order in each column), the largest
Reynolds number of any channel, and where a deflation drew a suction beyond vacuum in a
collapsing segment while the others still held fluid (the run ends there; see
:class:`softseq_ros.dynamic.path.DynamicPath`), or why the point was refused (the pump filled a
segment past its curve before the channels let the fluid on). The figure (``rates.png``)
colours the flow x radius grid by the leading segment and writes the sequence type and the
inflation snap-throughs' durations in each cell.
"""

import csv
from dataclasses import dataclass, replace
import math
from pathlib import Path
import sys
import time
from typing import TYPE_CHECKING, Any, Sequence, TextIO

import numpy as np
from numpy.typing import NDArray

from softseq_ros.analysis.metrics import Trace, analyse
from softseq_ros.errors import UserError
from softseq_ros.parallel import run_jobs

if TYPE_CHECKING:
    from softseq_ros.analysis.figures import FigureStyle

FloatArray = NDArray[np.float64]
# Samples of the path per leg of the programme: 2 % of the shares' bins each at the least
# (analysis.metrics takes the shares on 200 bins of the inflation leg).
SAMPLES_PER_LEG = 600
COLUMNS = ('flow_rate_m3_per_s', 'channel_radius_m', 'sequence_type', 'leading_segment',
           'lead_injected_m3', 'switch_injected_m3', 'switch_segment', 'snap_injected_m3',
           'snap_direction', 'snap_duration_s',
           'snap_fluid_moved_m3', 'snap_peak_exchange_m3_per_s', 'peak_reynolds',
           'drained_at_injected_m3', 'refused', 'integrator_steps', 'wall_s')


# The most samples of the path per leg a rate map takes (each worker holds them all: 1e6
# take about 0.5 GB, 1e9 would take 24 GB; the default is SAMPLES_PER_LEG).
MAX_SAMPLES_PER_LEG = 100_000


class RatesError(UserError):
    """A rate map that cannot be run: the message names the option or the scene."""


@dataclass(frozen=True)
class RatePoint:
    """One grid point: the scene, the pump's flow rate [m^3/s], every channel's radius [m]."""

    scene: Any
    flow_rate_m3_per_s: float
    channel_radius_m: float
    samples_per_leg: int = SAMPLES_PER_LEG


def scene_at(scene: Any, flow_rate: float, radius: float) -> Any:
    """The scene with its pump at ``flow_rate`` [m^3/s] and every channel of ``radius`` [m]."""
    profile = replace(scene.pump.profile, flow_rate=flow_rate)
    channels = tuple(replace(tube, radius_m=radius) for tube in scene.network.channels)
    return replace(scene, pump=replace(scene.pump, profile=profile),
                   network=replace(scene.network, channels=channels))


def check_grid(scene: Any, flows: Sequence[float], radii: Sequence[float]) -> None:
    """Refuse a grid the scene cannot run, naming the option; before anything runs."""
    if scene.network is None:
        where = scene.path if scene.path is not None else scene.name
        raise RatesError(f'{where}: the scene has no network block, so its sequence does not '
                         'depend on the pump rate (docs/dynamic.md)')
    for option, values in (('--flows', flows), ('--radii', radii)):
        if not values:
            raise RatesError(f'{option}: give at least one value')
        bad = [v for v in values if not (math.isfinite(v) and v > 0.0)]
        if bad:
            raise RatesError(f'{option}: every value must be finite and > 0, got {bad[0]:g}')
    shortest = min(tube.length_m for tube in scene.network.channels)
    too_wide = [r for r in radii if r > shortest]
    if too_wide:
        raise RatesError(f'--radii: {too_wide[0]:g} m exceeds the shortest channel '
                         f'({shortest:g} m long): not a tube')


def programme_times(profile: Any, samples_per_leg: int) -> FloatArray:
    """Sample times [s]: ``samples_per_leg`` evenly over every leg, each boundary once."""
    times, _ = profile.breakpoints()
    pieces = [np.linspace(a, b, samples_per_leg, endpoint=False)
              for a, b in zip(times[:-1], times[1:])]
    return np.concatenate(pieces + [times[-1:]])


def leg_signs(profile: Any, times: FloatArray) -> NDArray[np.int8]:
    """+1 where the pump inflates, -1 where it deflates, 0 in a hold (and after the end)."""
    return np.sign(profile.flow_at(times)).astype(np.int8)


def sequence_of(injected: FloatArray, pressure: FloatArray, volumes: FloatArray,
                signs: NDArray[np.int8], names: Sequence[str],
                snaps: list[dict] | None = None) -> dict:
    """
    Sequence type, leading segment and switch of a path, measured as a recording's.

    The path's rows are in time order; holds (sign 0) count with the inflation before them,
    so what the fluid does while the pump stands still is part of the sequence. ``snaps``: the
    snap-throughs in time of a dynamic path, as a recording's report takes its actuator's
    (None: found in the volumes, as quasi-statically).
    """
    span = float(np.ptp(injected)) if injected.size else 0.0
    metrics = analyse(Trace(injected, pressure, volumes, signs, segment_names=tuple(names)),
                      v_range=span if span > 0.0 else None, snaps=snaps)
    switch, lead = metrics['switch'], metrics['lead']
    return {'sequence_type': metrics['sequence_type'],
            'leading_segment': lead['segment_leading'] if lead else '',
            'lead_injected_m3': lead['injected_m3'] if lead else None,
            'switch_injected_m3': switch['injected_m3'] if switch else None,
            'switch_segment': switch['segment_taking_over'] if switch else ''}


def rate_point(point: RatePoint) -> dict:
    """Run one grid point: its row of the table (SI)."""
    from softseq_ros.dynamic.flow import NetworkDomainError
    from softseq_ros.dynamic.path import programme_path

    start = time.perf_counter()
    scene = scene_at(point.scene, point.flow_rate_m3_per_s, point.channel_radius_m)
    profile = scene.pump.profile
    times = programme_times(profile, point.samples_per_leg)
    row: dict[str, Any] = {'flow_rate_m3_per_s': point.flow_rate_m3_per_s,
                           'channel_radius_m': point.channel_radius_m, 'refused': ''}
    try:
        path = programme_path(scene.segments, scene.network, profile, times=times,
                              line=scene.supply)
    except NetworkDomainError as err:
        # One point of the map out of reach (the pump outruns the channel and fills the base
        # past its curve) says so in its row; the others still run.
        row.update({'sequence_type': 'refused', 'leading_segment': '', 'lead_injected_m3': None,
                    'switch_injected_m3': None, 'switch_segment': '', 'snaps': [],
                    'peak_reynolds': float('nan'), 'drained_at_injected_m3': None,
                    'refused': str(err), 'integrator_steps': 0,
                    'wall_s': time.perf_counter() - start})
        return row
    signs = leg_signs(profile, path.time_s)
    # The snap-throughs in time, as the report of a recording of this run takes them.
    in_time = [{'injected_m3': s.injected,
                'direction': 'deflation' if leg_signs(profile, np.array([s.start_s]))[0] < 0
                else 'inflation',
                'fluid_moved_m3': s.fluid_moved_m3, 'from_volumes_m3': list(s.from_volumes),
                'to_volumes_m3': list(s.to_volumes), 'from_pressure_pa': s.from_pressure,
                'to_pressure_pa': s.to_pressure, 'start_time_s': s.start_s,
                'duration_s': s.duration_s} for s in path.snaps if s.snap_through]
    row.update(sequence_of(path.injected, path.pressure, path.volumes, signs,
                           scene.segment_names, in_time or None))
    directions = {1: 'inflation', -1: 'deflation', 0: 'hold'}
    peaks = profile.injected_at(np.array([s.peak_s for s in path.snaps]))
    row['snaps'] = [{'injected_m3': s.injected, 'start_s': s.start_s,
                     'peak_injected_m3': float(peak),
                     'direction': directions[int(leg_signs(profile, np.array([s.start_s]))[0])],
                     'duration_s': s.duration_s, 'fluid_moved_m3': s.fluid_moved_m3,
                     'peak_exchange_m3_per_s': s.peak_exchange_m3_per_s}
                    for s, peak in zip(path.snaps, peaks) if s.snap_through]
    row['peak_reynolds'] = max(path.peak_reynolds) if path.peak_reynolds else 0.0
    row['drained_at_injected_m3'] = float(path.injected[-1]) if path.drained else None
    row['integrator_steps'] = path.steps
    row['wall_s'] = time.perf_counter() - start
    return row


def quasistatic_reference(scene: Any, samples_per_leg: int = SAMPLES_PER_LEG) -> dict:
    """The quasi-static path along the scene's programme, measured as a grid point is."""
    from softseq_ros.quasistatic.equilibrium import Tracker
    from softseq_ros.quasistatic.solve import scene_map

    profile = scene.pump.profile
    times = programme_times(profile, samples_per_leg)
    emap = scene_map(scene)
    solved = Tracker(emap).sweep(profile.injected_at(times))
    row = sequence_of(solved.injected, solved.pressure, solved.volumes,
                      leg_signs(profile, times), scene.segment_names)
    row['snaps'] = [{'injected_m3': e.injected,
                     'fluid_moved_m3': float(0.5 * np.abs(e.to_volumes - e.from_volumes).sum())}
                    for e in solved.events]
    return row


def run_rates(scene: Any, flows: Sequence[float], radii: Sequence[float],
              workers: int | None = None, scheduler: str | None = None,
              samples_per_leg: int = SAMPLES_PER_LEG,
              progress: TextIO | None = sys.stderr) -> list[dict]:
    """Every grid point (flows outer, radii inner), on local processes or a Dask scheduler."""
    check_grid(scene, flows, radii)
    points = [RatePoint(scene, float(q), float(r), samples_per_leg)
              for q in flows for r in radii]

    def report(done: int, total: int, row: dict) -> None:
        if progress is not None:
            progress.write(f'rates: {done}/{total} {_point_text(row)}: '
                           f'{row["sequence_type"]}, {_who(row)}\n')
            progress.flush()

    return run_jobs(rate_point, points, workers=workers,
                    backend='dask' if scheduler is not None else 'processes',
                    scheduler=scheduler, progress=report, name=_point_name)


def _point_text(row: dict) -> str:
    return (f'{row["flow_rate_m3_per_s"] * 1e6:g} mL/s, radius '
            f'{row["channel_radius_m"] * 1e3:g} mm')


def _point_name(point: RatePoint) -> str:
    return (f'flow {point.flow_rate_m3_per_s:g} m^3/s, radius '
            f'{point.channel_radius_m:g} m')


def _joined(values: Sequence[Any]) -> str:
    return ';'.join(v if isinstance(v, str) else repr(float(v)) for v in values)


def csv_row(row: dict) -> dict:
    """A result as the table's cells: SI numbers, several snap-throughs joined by ``;``."""
    snaps = row['snaps']
    cells = {'flow_rate_m3_per_s': repr(row['flow_rate_m3_per_s']),
             'channel_radius_m': repr(row['channel_radius_m']),
             'sequence_type': row['sequence_type'],
             'leading_segment': row['leading_segment'],
             'lead_injected_m3': ('' if row['lead_injected_m3'] is None
                                  else repr(row['lead_injected_m3'])),
             'switch_injected_m3': ('' if row['switch_injected_m3'] is None
                                    else repr(row['switch_injected_m3'])),
             'switch_segment': row['switch_segment'],
             'peak_reynolds': repr(float(row['peak_reynolds'])),
             'drained_at_injected_m3': ('' if row['drained_at_injected_m3'] is None
                                        else repr(row['drained_at_injected_m3'])),
             'refused': row['refused'],
             'integrator_steps': str(row['integrator_steps']),
             'wall_s': f'{row["wall_s"]:.3f}'}
    for column, key in (('snap_injected_m3', 'injected_m3'), ('snap_direction', 'direction'),
                        ('snap_duration_s', 'duration_s'),
                        ('snap_fluid_moved_m3', 'fluid_moved_m3'),
                        ('snap_peak_exchange_m3_per_s', 'peak_exchange_m3_per_s')):
        cells[column] = _joined([s[key] for s in snaps])
    return cells


def _who(row: dict, digits: int = 2) -> str:
    """'tip leads from 2.70 mL, base takes over at 45.10 mL' (the report's two numbers)."""
    lead, switch = row['lead_injected_m3'], row['switch_injected_m3']
    return ((f'{row["leading_segment"]} leads from {lead * 1e6:.{digits}f} mL'
             if lead is not None else 'no segment leads')
            + (f', {row["switch_segment"]} takes over at {switch * 1e6:.{digits}f} mL'
               if switch is not None else ', none takes over'))


def reference_line(reference: dict) -> str:
    """The quasi-static reference in one line (mL for humans)."""
    snaps = ', '.join(f'{s["injected_m3"] * 1e6:.2f} mL' for s in reference['snaps']) or 'none'
    return (f'quasi-static along the same programme: {reference["sequence_type"]}, '
            f'{_who(reference)}, snap-throughs at {snaps}')


def write_rates_csv(path: Path, rows: list[dict], scene_name: str, reference: dict) -> Path:
    """The table, one row per grid point, under comment lines naming the scene and reference."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open('w', newline='') as handle:
        handle.write(f'# Rate map of scene {scene_name}: one row per pump flow rate and '
                     'channel radius; SI units; several snap-throughs of a run are separated '
                     'by ";".\n')
        handle.write(f'# {reference_line(reference)}\n')
        writer = csv.DictWriter(handle, fieldnames=COLUMNS)
        writer.writeheader()
        for row in rows:
            writer.writerow(csv_row(row))
    return path


def rates_markdown(rows: list[dict]) -> str:
    """The table for humans (mL/s, mm, mL, s)."""
    lines = ['| pump flow | channel radius | sequence | leads (from) | takes over (at) | '
             'snap-throughs (start, i: inflation, h: hold, d: deflation; duration; fluid '
             'moved) | peak Reynolds |',
             '|---:|---:|---|---|---|---|---:|']
    for row in rows:
        point = (f'| {row["flow_rate_m3_per_s"] * 1e6:g} mL/s | '
                 f'{row["channel_radius_m"] * 1e3:g} mm |')
        if row['refused']:
            lines.append(f'{point} refused: {row["refused"]} | | | | |')
            continue
        lead, switch = row['lead_injected_m3'], row['switch_injected_m3']
        leads = f'{row["leading_segment"]} ({lead * 1e6:.1f} mL)' if lead is not None else '-'
        takes = (f'{row["switch_segment"]} ({switch * 1e6:.1f} mL)' if switch is not None
                 else '-')
        snaps = '; '.join(f'{s["injected_m3"] * 1e6:.1f} mL {s["direction"][0]}, '
                          f'{_seconds(s["duration_s"])}, {s["fluid_moved_m3"] * 1e6:.1f} mL'
                          for s in row['snaps']) or '-'
        lines.append(f'{point} {row["sequence_type"]} | {leads} | {takes} | {snaps} | '
                     f'{row["peak_reynolds"]:.0f} |')
    return '\n'.join(lines) + '\n'


def _seconds(value: float) -> str:
    return f'{value:.0f} s' if value >= 10.0 else f'{value:.2g} s'


def rates_figure(rows: list[dict], names: Sequence[str], reference: dict, title: str,
                 out: Path, style: 'FigureStyle | None' = None) -> Path:
    """
    The flow x radius grid coloured by the leading segment, annotated per cell.

    Each cell says the sequence type and its inflation snap-throughs' 10-90 % durations; a
    column left of the grid, apart, holds the quasi-static path along the same programme (the
    limit of a slow pump, whatever the channel). ``style``: a
    :class:`softseq_ros.analysis.figures.FigureStyle` (the paper style by default), as the
    report's figures; ``title`` names the scene in the screen style's title.
    """
    from softseq_ros.analysis.figures import PAPER

    style = style or PAPER
    with style.context():
        return _rates_figure(rows, names, reference, title, out, style)


def _rates_figure(rows: list[dict], names: Sequence[str], reference: dict, title: str,
                  out: Path, style: 'FigureStyle') -> Path:
    from matplotlib.patches import Patch, Rectangle

    from softseq_ros.analysis.figures import (
        PAGE_IN,
        SEGMENT_COLOURS,
        legend_below,
        new_figure,
        save_figure,
    )

    flows = sorted({row['flow_rate_m3_per_s'] for row in rows})
    radii = sorted({row['channel_radius_m'] for row in rows})
    colours = {name: SEGMENT_COLOURS[k % len(SEGMENT_COLOURS)] for k, name in enumerate(names)}
    # A cell of about 0.9 x 0.4 in (two lines of 6.7 pt), a page wide at most; the grid at
    # least as tall as the radius axis's label on two lines.
    width = min(PAGE_IN, 1.0 + 0.9 * (len(flows) + 1))
    height = 0.75 + max(0.4 * len(radii), 0.8)
    fig, axes = new_figure(*style.size(width, height),
                           margins={'left': 0.6 / width, 'right': 0.99, 'top': 0.98,
                                    'bottom': 0.75 / height})
    ax = axes[0, 0]
    shade = {'alpha': 0.55, 'edgecolor': 'white', 'lw': 1.0}
    refused = False
    for row in rows:
        i, j = flows.index(row['flow_rate_m3_per_s']), radii.index(row['channel_radius_m'])
        if row['refused']:
            refused = True
            ax.add_patch(Rectangle((i, j), 1, 1, facecolor='white', hatch='////',
                                   **{**shade, 'edgecolor': '0.75', 'alpha': 1.0}))
            text = 'refused:\nbeyond a curve'
        else:
            ax.add_patch(Rectangle((i, j), 1, 1, facecolor=colours.get(row['leading_segment'],
                                                                       '0.85'), **shade))
            rising = [s for s in row['snaps'] if s['direction'] == 'inflation']
            snaps = ', '.join(_seconds(s['duration_s']) for s in rising[:2])
            text = f'{row["sequence_type"]}\n' + (f'snap {snaps}' if snaps else 'no snap')
        ax.text(i + 0.5, j + 0.5, text, ha='center', va='center', fontsize='small',
                linespacing=1.15, zorder=3)
    # The quasi-static path: one cell over every radius, apart from the grid.
    left = -1.12
    ax.add_patch(Rectangle((left, 0), 1, len(radii), facecolor=colours.get(
        reference['leading_segment'], '0.85'), **shade))
    ax.text(left + 0.5, 0.5 * len(radii), f'{reference["sequence_type"]}\n'
            + ('instant snaps' if reference['snaps'] else 'no snap'), ha='center',
            va='center', fontsize='small', linespacing=1.15)
    ax.set_xlim(left, len(flows))
    ax.set_ylim(0, len(radii))
    ax.set_xticks(np.concatenate([[left + 0.5], np.arange(len(flows)) + 0.5]),
                  ['quasi-static'] + [f'{q * 1e6:g}' for q in flows])
    ax.set_yticks(np.arange(len(radii)) + 0.5, [f'{r * 1e3:g}' for r in radii])
    ax.tick_params(length=0)
    for side in ax.spines.values():
        side.set_visible(False)
    ax.set_xlabel('pump flow rate [mL/s]')
    # Under the flows' columns, not under the quasi-static one.
    ax.xaxis.label.set_x((0.5 * len(flows) - left) / (len(flows) - left))
    ax.set_ylabel('channel\nradius [mm]')
    handles = [Patch(facecolor=colours[name], alpha=0.55, label=f'{name} leads')
               for name in names]
    if any(not row['leading_segment'] and not row['refused'] for row in rows) \
            or not reference['leading_segment']:
        handles.append(Patch(facecolor='0.85', alpha=0.55, label='no segment leads'))
    if refused:
        handles.append(Patch(facecolor='white', edgecolor='0.75', hatch='////',
                             label='refused (a segment filled beyond its curve)'))
    legend_below(fig, handles, ncol=len(handles))
    style.title(ax, f'{title}: who takes over the inflow, the sequence type and the '
                "inflation snap-throughs' 10-90 % durations")
    save_figure(fig, out, False, style)
    return out
