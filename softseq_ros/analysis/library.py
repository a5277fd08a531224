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
import os
from pathlib import Path
import re
import stat
import sys
from typing import TextIO

import numpy as np

from softseq_ros.analysis.metrics import Trace, analyse
from softseq_ros.errors import UserError, write_text, writing
from softseq_ros.parallel import run_jobs

SWEEP_POINTS = 2001
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
    """
    The text of ``path`` if it is a regular file, else None.

    Opened without blocking and checked on the open descriptor: a FIFO named like a table
    would block ``open`` until a writer appears, and a check before opening could be raced.
    """
    descriptor = os.open(path, os.O_RDONLY | getattr(os, 'O_NONBLOCK', 0))
    try:
        if not stat.S_ISREG(os.fstat(descriptor).st_mode):
            return None
        os.set_blocking(descriptor, True)
        with open(descriptor, 'rb', closefd=False) as stream:
            data = stream.read()
    finally:
        os.close(descriptor)
    try:
        return data.decode('utf-8-sig')
    except UnicodeDecodeError as err:
        raise LibraryError(f'{path}: not UTF-8 text (byte {err.start}); save the table as '
                           'UTF-8 CSV') from None


def _kind(path: Path) -> str:
    mode = path.stat().st_mode
    for test, name in ((stat.S_ISFIFO, 'a FIFO'), (stat.S_ISDIR, 'a folder'),
                       (stat.S_ISSOCK, 'a socket'), (stat.S_ISCHR, 'a character device'),
                       (stat.S_ISBLK, 'a block device')):
        if test(mode):
            return name
    return 'not a regular file'


def library_entries(source: str | os.PathLike, length_m: float | None = None,
                    notes: TextIO | None = sys.stderr) -> list[Entry]:
    """
    The segments of a folder of tables or of a scene file.

    Only regular files are read: a FIFO, folder, socket or device named ``*.csv`` is skipped
    with a note on ``notes``.
    """
    path = Path(source)
    if path.is_file():
        from softseq_ros.scene.loader import load_scene

        scene = load_scene(path)
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
        length = float(found.group(1)) if found else length_m
        if length is None:
            raise LibraryError(f'{table}: no "# length_m:" line; give the length with '
                               '--length-m')
        entries.append(Entry(table.stem, str(table), length))
    return entries


def _segment(entry: Entry) -> object:
    # The segment models pull scipy in: imported where a worker needs them, not at start.
    if entry.table is not None:
        from softseq_ros.scene.tables import read_table

        return read_table(entry.table, entry.name, entry.length_m)
    from softseq_ros.scene.loader import load_scene

    return load_scene(entry.scene).segments[entry.index]


def assemble(entries: tuple[Entry, ...]) -> dict:
    """Classify and sweep one assembly (base to tip); every number SI, pressures gauge."""
    from softseq_ros.quasistatic.equilibrium import classify, inflate_and_deflate
    from softseq_ros.quasistatic.solve import build_map
    from softseq_ros.segments.kinematics import backbone_batch

    segments = []
    for k, entry in enumerate(entries):
        segment = _segment(entry)
        # The same table may sit twice in one assembly: the names must differ.
        segment.name = f'{entry.name}_{k + 1}' if entries.count(entry) > 1 else entry.name
        segments.append(segment)
    emap = build_map(segments)
    kind = classify(emap)
    lo, hi = emap.injected_range
    rising, falling = inflate_and_deflate(emap, SWEEP_POINTS)
    rows = rising.injected.size
    trace = Trace(np.concatenate([rising.injected, falling.injected]),
                  np.concatenate([rising.pressure, falling.pressure]),
                  np.vstack([rising.volumes, falling.volumes]),
                  np.concatenate([np.ones(rows, np.int8), -np.ones(rows, np.int8)]),
                  segment_names=tuple(s.name for s in segments))
    metrics = analyse(trace, v_range=hi - lo)
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
        'snaps': [{'injected_m3': e.injected, 'direction': 'inflation',
                   'fluid_moved_m3': float(0.5 * np.abs(e.to_volumes - e.from_volumes).sum())}
                  for e in rising.events]
        + [{'injected_m3': e.injected, 'direction': 'deflation',
            'fluid_moved_m3': float(0.5 * np.abs(e.to_volumes - e.from_volumes).sum())}
           for e in falling.events],
        'hysteresis_area_j': metrics['hysteresis_area_j'],
        'tip_at_full_inflation_m': [float(x) for x in tip[-1]],
        'tip_reach_min_m': float(reach.min()),
        'pv_curve': {'injected_m3': rising.injected[::20].tolist() + falling.injected[::20]
                     .tolist(), 'pressure_pa': rising.pressure[::20].tolist()
                     + falling.pressure[::20].tolist(), 'inflation_rows':
                     len(rising.injected[::20])},
    }


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
                     f'{r["hysteresis_area_j"] * 1e3:.3f} mJ | {tip[0] * 1e3:.0f}, '
                     f'{tip[1] * 1e3:.0f} mm |')
    return '\n'.join(lines) + '\n'


def library_figure(results: list[dict], names: list[str], out: Path) -> Path:
    """The pairs' PV curves in a grid: base segment by row, tip segment by column."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    pairs = {tuple(r['segments']): r for r in results if len(r['segments']) == 2}
    n = len(names)
    fig = Figure(figsize=(2.6 * n + 0.6, 2.2 * n + 0.6))
    FigureCanvasAgg(fig)
    fig.subplots_adjust(left=0.1, right=0.98, bottom=0.08, top=0.9, hspace=0.45, wspace=0.3)
    axes = fig.subplots(n, n, squeeze=False)
    colours = {'none': '0.3', 'partial': 'tab:green', 'symmetric': 'tab:blue',
               'asymmetric': 'tab:red'}
    for i, base in enumerate(names):
        for j, tip in enumerate(names):
            ax = axes[i, j]
            r = pairs.get((base, tip))
            if r is None:
                ax.set_visible(False)
                continue
            curve = r['pv_curve']
            k = curve['inflation_rows']
            u = np.asarray(curve['injected_m3']) * 1e6
            p = np.asarray(curve['pressure_pa']) * 1e-3
            colour = colours[r['sequence_type']]
            ax.plot(u[:k], p[:k], '-', color=colour, lw=1.2)
            ax.plot(u[k:], p[k:], '--', color=colour, lw=1.0)
            for snap in r['snaps']:
                ax.axvline(snap['injected_m3'] * 1e6, color=colour, lw=0.5, alpha=0.5)
            ax.set_title(f'{base} -> {tip}\n{r["sequence_type"]}', fontsize=7, color=colour)
            ax.tick_params(labelsize=6)
            ax.grid(alpha=0.3)
            if i == n - 1:
                ax.set_xlabel('injected volume [mL]', fontsize=7)
            if j == 0:
                ax.set_ylabel('gauge pressure [kPa]', fontsize=7)
    fig.suptitle('Segment library: every ordered pair on one supply (row: base, column: tip; '
                 'solid inflation, dashed deflation)', fontsize=8)
    fig.savefig(out, dpi=110)
    return out


def write_library(source: str | os.PathLike, out: str | os.PathLike, triples: bool = False,
                  length_m: float | None = None, processes: int | None = None,
                  progress: TextIO | None = sys.stderr) -> tuple[list[dict], str]:
    """Run the library and write library.md, library.json and library.png into ``out``."""
    entries = library_entries(source, length_m, progress)
    out = Path(out)
    results = run_library(entries, triples, processes, progress)

    with writing(out):
        out.mkdir(parents=True, exist_ok=True)
    table = library_markdown(results)
    write_text(out / 'library.md', f'# Segment library `{source}`\n\nPressures are gauge.\n\n'
               + table + '\n![library](library.png)\n')
    write_text(out / 'library.json', json.dumps(results, indent=2) + '\n')
    with writing(out / 'library.png'):
        library_figure(results, [e.name for e in entries], out / 'library.png')
    return results, table
