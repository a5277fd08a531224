"""
The segment library: simulate each segment once, assemble every combination on one supply.

``softseq library DIR`` takes a folder of segment tables (CSV as in the README; a ``# length_m:``
comment line gives a table's length, else ``--length-m``) or a scene file listing segments, and
assembles every ordered pair (base, tip), and with ``--triples`` every ordered triple. Each
assembly is classified by the solver (:func:`softseq_ros.quasistatic.equilibrium.classify`)
and swept quasi-statically over its whole range and back; the sweep is measured with the same
metrics as a recording (:mod:`softseq_ros.analysis.metrics`): switch and snap volumes, pressure
range, hysteresis and how far the tip reaches. More than a handful of assemblies run in worker
processes (:func:`softseq_ros.parallel.run_jobs`).
"""

from dataclasses import dataclass
import itertools
import json
import math
import os
from pathlib import Path
import re
import sys
from typing import TextIO

import numpy as np

from softseq_ros.analysis.figures import (
    GAUGE,
    INJECTED,
    KPA,
    ML,
    PAGE_IN,
    PAPER,
    STYLE,
    FigureStyle,
    darker,
    direction_key,
    legend_below,
    new_figure,
    save_figure,
)
from softseq_ros.analysis.metrics import sweep_metrics
from softseq_ros.analysis.recording import DEFLATION, INFLATION
from softseq_ros.analysis.text import millijoules_text
from softseq_ros.errors import (
    NotRegularFileError,
    UserError,
    file_kind,
    read_regular_file,
    write_text,
    writing,
)
from softseq_ros.parallel import run_jobs

SWEEP_POINTS = 2001
PV_CURVE_EVERY = 20   # the sweep's rows kept for the figure (and the snaps' neighbours)
POOL_FROM = 5  # assemblies; below this a pool costs more than it saves
_LENGTH_LINE = re.compile(r'^\s*#\s*length_m\s*:\s*([0-9.eE+-]+)', re.MULTILINE)


class LibraryError(UserError):
    """A library folder or scene that cannot be assembled."""


@dataclass(frozen=True)
class Entry:
    """One segment of the library: where its table is and how long it is."""

    name: str
    table: str | None
    length_m: float
    scene: str | None = None   # a scene file holding it, with its index there
    index: int = 0


def _regular_text(path: Path) -> str | None:
    """The text of ``path`` if it is a regular file (a FIFO named like a table: None)."""
    try:
        data = read_regular_file(path)
    except NotRegularFileError:
        return None
    try:
        return data.decode('utf-8-sig')
    except UnicodeDecodeError as err:
        raise LibraryError(f'{path}: not UTF-8 text (byte {err.start}); save the table as '
                           'UTF-8 CSV') from None


def _kind(path: Path) -> str:
    return file_kind(path.stat().st_mode)


def library_entries(source: str | os.PathLike, length_m: float | None = None,
                    notes: TextIO | None = sys.stderr) -> list[Entry]:
    """
    The segments of a folder of tables or of a scene file.

    Only regular files are read: a FIFO, folder, socket or device named ``*.csv`` is skipped
    with a note on ``notes``.
    """
    path = Path(source)
    if length_m is not None and not (math.isfinite(length_m) and length_m > 0.0):
        raise LibraryError(f'--length-m: must be a finite length > 0 (m), got {length_m}')
    if path.is_file():
        from softseq_ros.quasistatic.solve import segments_graph
        from softseq_ros.scene.loader import load_scene

        scene = load_scene(path, segments_graph)
        return [Entry(s.name, None, s.length, str(path), i) for i, s in enumerate(scene.segments)]
    if not path.is_dir():
        raise LibraryError(f'{path}: neither a folder of segment tables nor a scene file')
    texts = {}
    for table in sorted(path.glob('*.csv')):
        text = _regular_text(table)
        if text is None:
            if notes is not None:
                notes.write(f'library: note: {table} is {_kind(table)}, not a table file; '
                            'skipped\n')
            continue
        texts[table] = text
    if len(texts) < 1:
        raise LibraryError(f'{path}: no segment tables (*.csv regular files) in this folder')
    entries = []
    for table, text in texts.items():
        found = _LENGTH_LINE.search(text)
        length = _length_line(table, found.group(1)) if found else length_m
        if length is None:
            raise LibraryError(f'{table}: no "# length_m:" line; give the length with '
                               '--length-m')
        entries.append(Entry(table.stem, str(table), length))
    for entry in entries:
        # Read once here: a table no assembly can use is refused before any job starts.
        _segment(entry)
    return entries


def _length_line(table: Path, text: str) -> float:
    """The length a table's ``# length_m:`` line gives; LibraryError naming it when none."""
    try:
        length = float(text)
    except ValueError:
        length = math.nan
    if not (math.isfinite(length) and length > 0.0):
        raise LibraryError(f'{table}: "# length_m: {text}": must be a finite length > 0 (m)')
    return length


def _segment(entry: Entry) -> object:
    # The segment models pull scipy in: imported where a worker needs them, not at start.
    if entry.table is not None:
        from softseq_ros.scene.tables import read_table

        return read_table(entry.table, entry.name, entry.length_m)
    from softseq_ros.quasistatic.solve import segments_graph
    from softseq_ros.scene.loader import load_scene

    return load_scene(entry.scene, segments_graph).segments[entry.index]


def assemble(entries: tuple[Entry, ...]) -> dict:
    """Classify and sweep one assembly (base to tip); every number SI, pressures gauge."""
    from softseq_ros.quasistatic.equilibrium import classify, inflate_and_deflate
    from softseq_ros.quasistatic.solve import equilibrium_map
    from softseq_ros.segments.kinematics import backbone_batch

    segments = []
    for k, entry in enumerate(entries):
        segment = _segment(entry)
        # The same table may sit twice in one assembly: the names must differ.
        segment.name = f'{entry.name}_{k + 1}' if entries.count(entry) > 1 else entry.name
        segments.append(segment)
    emap = equilibrium_map(segments)
    kind = classify(emap)
    lo, hi = emap.injected_range
    rising, falling = inflate_and_deflate(emap, SWEEP_POINTS)
    metrics = sweep_metrics(rising, falling, tuple(s.name for s in segments), hi - lo)
    lengths = [e.length_m for e in entries]
    points, _ = backbone_batch(rising.curvatures, lengths, points_per_segment=8)
    tip = points[:, -1, :]
    reach = np.hypot(tip[:, 0], tip[:, 1])
    switch = metrics['switch']
    return {
        'segments': [e.name for e in entries],
        'sequence_type': kind,
        'sequence_type_of_sweep': metrics['sequence_type'],
        'injected_range_m3': [float(lo), float(hi)],
        'pressure_range_pa': [float(min(rising.pressure.min(), falling.pressure.min())),
                              float(max(rising.pressure.max(), falling.pressure.max()))],
        'switch_injected_m3': switch['injected_m3'] if switch else None,
        'switch_segment': switch['segment_taking_over'] if switch else None,
        'snaps': [_snap(e, 'inflation') for e in rising.events]
        + [_snap(e, 'deflation') for e in falling.events],
        'hysteresis_area_j': metrics['hysteresis_area_j'],
        'tip_at_full_inflation_m': [float(x) for x in tip[-1]],
        'tip_reach_min_m': float(reach.min()),
        'pv_curve': _pv_curve(rising, falling),
    }


def _snap(event: object, direction: str) -> dict:
    """A snap-through of a sweep (SI, gauge): where, which way, the pressure either side."""
    return {'injected_m3': event.injected, 'direction': direction,
            'fluid_moved_m3': float(0.5 * np.abs(event.to_volumes - event.from_volumes).sum()),
            'pressure_before_pa': float(event.from_pressure),
            'pressure_after_pa': float(event.to_pressure)}


def _pv_curve(rising: object, falling: object) -> dict:
    """
    The sweep's PV curve for the figure: every PV_CURVE_EVERY-th row of each direction.

    The rows either side of each snap-through are kept, so the curve ends where it snaps.
    """
    columns: dict = {'injected_m3': [], 'pressure_pa': []}
    for path in (rising, falling):
        snaps = np.flatnonzero(path.snap)
        rows = np.union1d(np.arange(0, path.injected.size, PV_CURVE_EVERY),
                          np.concatenate([snaps - 1, snaps, [path.injected.size - 1]]))
        rows = rows[rows >= 0]
        columns['injected_m3'] += path.injected[rows].tolist()
        columns['pressure_pa'] += path.pressure[rows].tolist()
        columns.setdefault('inflation_rows', len(rows))
    return columns


def run_library(entries: list[Entry], triples: bool = False, processes: int | None = None,
                progress: TextIO | None = sys.stderr) -> list[dict]:
    """Every ordered pair (and triple) of the entries, in a stable order."""
    combos = list(itertools.product(entries, repeat=2))
    if triples:
        combos += list(itertools.product(entries, repeat=3))

    def report(done: int, total: int, result: dict) -> None:
        if progress is not None:
            progress.write(f'library: {done}/{total} assembled ('
                           f'{" + ".join(result["segments"])}: {result["sequence_type"]})\n')
            progress.flush()

    # Below POOL_FROM assemblies, or with one process asked for, they run here.
    return run_jobs(assemble, combos, workers=max(processes, 1) if processes is not None else None,
                    backend='processes' if len(combos) >= POOL_FROM else 'serial',
                    progress=report, name=_combo_name)


def _combo_name(combo: tuple[Entry, ...]) -> str:
    return f'assembly {" + ".join(entry.name for entry in combo)}'


def library_markdown(results: list[dict]) -> str:
    """The library's table (mL, kPa, mJ, mm)."""
    lines = ['| base -> tip | type | switch | snaps (injected, i: inflation, d: deflation; '
             'fluid moved) | pressure range (gauge) | hysteresis | tip at full inflation (x, z) |',
             '|---|---|---|---|---|---|---|']
    for r in results:
        switch = (f'{r["switch_injected_m3"] * 1e6:.1f} mL ({r["switch_segment"]})'
                  if r['switch_injected_m3'] is not None else '-')
        snaps = '; '.join(f'{s["injected_m3"] * 1e6:.1f} mL {s["direction"][0]} '
                          f'({s["fluid_moved_m3"] * 1e6:.1f} mL)' for s in r['snaps']) or '-'
        lo, hi = r['pressure_range_pa']
        tip = r['tip_at_full_inflation_m']
        lines.append(f'| {" -> ".join(r["segments"])} | {r["sequence_type"]} | {switch} | '
                     f'{snaps} | {lo / 1e3:.2f} to {hi / 1e3:.2f} kPa | '
                     f'{millijoules_text(r["hysteresis_area_j"], 3)} | {tip[0] * 1e3:.0f}, '
                     f'{tip[1] * 1e3:.0f} mm |')
    return '\n'.join(lines) + '\n'


# The sequence types' colours (Okabe-Ito): a panel's curve and its type, written in it.
TYPE_COLOURS = {'none': '0.3', 'partial': '#009E73', 'symmetric': '#0072B2',
                'asymmetric': '#D55E00'}


def library_figure(results: list[dict], names: list[str], out: Path,
                   style: FigureStyle = PAPER) -> list[Path]:
    """
    The pairs' PV curves in a grid: base segment by row, tip segment by column.

    Each panel's curve and its sequence type (written in its corner) take the type's colour;
    inflation solid, deflation dashed in a darker shade on top, snap-throughs as arrows, as in
    a report's figures. One gauge pressure scale for every panel, so the pairs compare.
    """
    with style.context():
        return _library_figure(results, names, out, style)


def _library_figure(results: list[dict], names: list[str], out: Path,
                    style: FigureStyle) -> list[Path]:
    pairs = {tuple(r['segments']): r for r in results if len(r['segments']) == 2}
    n = len(names)
    # A page wide from three segments on, a panel of about 2.2 x 1.5 in below that.
    width = min(PAGE_IN, 0.7 + 2.2 * n)
    panel = (width - 0.7) / n
    height = 0.55 + 0.68 * panel * n
    fig, axes = new_figure(*style.size(width, height), n, n,
                           {'left': 0.6 / width, 'right': 0.99, 'bottom': 0.45 / height,
                            'top': 1 - 0.18 / height, 'hspace': 0.18, 'wspace': 0.08},
                           sharey=True)
    for i, base in enumerate(names):
        for j, tip in enumerate(names):
            ax = axes[i, j]
            r = pairs.get((base, tip))
            if r is None:
                ax.set_visible(False)
                continue
            _draw_pair(ax, r)
            ax.grid(alpha=0.3)
            if i == n - 1:
                ax.set_xlabel(INJECTED)
            if j == 0:
                ax.set_ylabel(f'base: {base}\n{GAUGE}')
            if i == 0:
                # The tip's name heads its column (a label of the grid, not a title).
                ax.annotate(f'tip: {tip}', (0.5, 1.0), xycoords='axes fraction',
                            xytext=(0, 3), textcoords='offset points', ha='center',
                            va='bottom')
    axes[0, 0].set_ylim(bottom=0.0)
    direction_key(axes[0, 0])
    legend_below(fig, axes[0, 0].get_legend_handles_labels()[0])
    style.title(axes[0, 0], 'Segment library: every ordered pair (row: base, column: tip)')
    return save_figure(fig, out, False, style)


def _draw_pair(ax: object, result: dict) -> None:
    """One pair's PV curve: each direction in its style, broken and arrowed at its snaps."""
    curve = result['pv_curve']
    k = curve['inflation_rows']
    u = np.asarray(curve['injected_m3']) * ML
    p = np.asarray(curve['pressure_pa']) * KPA
    colour = TYPE_COLOURS[result['sequence_type']]
    for direction, rows, sign in ((INFLATION, slice(0, k), 1.0), (DEFLATION, slice(k, None),
                                                                   -1.0)):
        x, y = u[rows], p[rows]
        snaps = [s for s in result['snaps'] if s['direction'] == direction]
        # No line across a snap: the curve stops before it and goes on after it.
        cuts = sorted(int(np.argmax(sign * (x - s['injected_m3'] * ML) >= 0)) for s in snaps)
        x, y = np.insert(x, cuts, np.nan), np.insert(y, cuts, np.nan)
        style = dict(STYLE[direction])
        style['color'] = colour if direction == INFLATION else darker(colour)
        ax.plot(x, y, **style)
        for s in snaps:
            at = s['injected_m3'] * ML
            ax.annotate('', xy=(at, s['pressure_after_pa'] * KPA),
                        xytext=(at, s['pressure_before_pa'] * KPA), zorder=4,
                        arrowprops={'arrowstyle': '->', 'color': style['color'], 'lw': 1.0,
                                    'shrinkA': 0, 'shrinkB': 0})
    ax.text(0.97, 0.05, result['sequence_type'], transform=ax.transAxes, ha='right',
            va='bottom', color=colour, fontweight='bold')


def write_library(source: str | os.PathLike, out: str | os.PathLike, triples: bool = False,
                  length_m: float | None = None, processes: int | None = None,
                  progress: TextIO | None = sys.stderr,
                  style: FigureStyle = PAPER) -> tuple[list[dict], str]:
    """Run the library; write library.md, library.json and library.png (in ``style``)."""
    entries = library_entries(source, length_m, progress)
    out = Path(out)
    results = run_library(entries, triples, processes, progress)

    with writing(out):
        out.mkdir(parents=True, exist_ok=True)
    table = library_markdown(results)
    write_text(out / 'library.md', f'# Segment library `{source}`\n\nPressures are gauge.\n\n'
               + table + '\n![library](library.png)\n')
    write_text(out / 'library.json', json.dumps(results, indent=2) + '\n')
    library_figure(results, [e.name for e in entries], out / 'library.png', style)
    return results, table
