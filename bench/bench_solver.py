"""
Run time against error for the equilibrium tracker, with independent references.

    python bench/bench_solver.py [--fewer-repeats] [--skip-noise] [--out docs]
    python bench/bench_solver.py --quick [--out FOLDER]

Writes docs/benchmarks.md (tables) and docs/bench_solver.png (figure). Every ratio is measured
in this one process; times are the best of several repeats (the machine may be shared).

``--quick`` checks that the benchmark runs, in about 30 s: two scenes (fig1_asymmetric, two
segments with snap-throughs; a 3-segment Gent chain), 401 commands, resolution 2000 only, a
reference at 4000, one dynamic slowness, a small scaling and noise study, fewer repeats. Its
numbers mean little; the report and the figure go to a temporary folder (or ``--out``) and the
report is printed. The test suite runs it (test/test_bench_quick.py).

Error of a path, against a high-precision reference (our tracker at resolution 32000 with every
state Newton-polished to round-off by bench/reference_solvers.polish_states; for two segments it
is cross-checked against the naive brentq tracker with xtol 1e-14 of the volume range):
  split   max |v_i - v_i,ref| / volume range (sum of the segments' volume ranges)
  snap    max |snap volume - exact fold volume| / volume range (two segments: exact folds from
          reference_solvers.fold_totals_pair; more: the reference tracker's snaps)
  press   max |p - p_ref| / pressure scale (largest |p| on any PV curve)
The history is an inflation from 0 to 0.9999 of the injected range and back, 4001 commands.
"""

import argparse
from dataclasses import dataclass
import math
from pathlib import Path
import signal
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from reference_solvers import (  # noqa: E402
    NaiveTracker,
    OutOfRangeError,
    dynamic_path,
    fold_totals_pair,
    interp_floor,
    polish_states,
)

from softseq_ros.quasistatic.equilibrium import EquilibriumMap, Tracker  # noqa: E402
from softseq_ros.scene.loader import load_scene  # noqa: E402
from softseq_ros.scene.tables import read_table  # noqa: E402
from softseq_ros.segments.materials import Gent  # noqa: E402
from softseq_ros.segments.models import BalloonSegment, TabulatedSegment  # noqa: E402
from softseq_ros.segments.smoothing import smooth_table  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
RESOLUTIONS = (250, 500, 1000, 2000, 4000)
POLISH = (0, 2)  # off, on (EquilibriumMap takes polish as a flag)
REFERENCE_RESOLUTION = 32000
SWEEP_STEPS = 100_000


@dataclass(frozen=True)
class Sizes:
    """What a run covers: the benchmark, or a quick check that it runs (``--quick``)."""

    scenes: tuple[str, ...] | None       # None: every scene of scenes()
    history_commands: int
    resolutions: tuple[int, ...]
    reference_resolution: int
    slownesses: tuple[float, ...]
    scaling_steps: tuple[int, ...]
    monotone_chains: tuple[int, ...]
    peaked_chains: tuple[int, ...]
    table_rows: tuple[int, ...]
    noise_rows: tuple[int, ...]
    noise_levels: tuple[float, ...] | None   # None: all of them (200 rows: the first four)
    noise_seeds: int | None                  # None: 5 (3 with fewer repeats)
    noise_alarm_s: int


FULL = Sizes(None, 4001, RESOLUTIONS, REFERENCE_RESOLUTION, (1e-3, 1e-4, 1e-5, 1e-6),
             (10**3, 10**4, 10**5, 10**6), (2, 3, 4, 5), (2, 3), (50, 200, 1000, 5000),
             (60, 200), None, None, 120)
QUICK = Sizes(('fig1_asymmetric', 'chain3'), 401, (2000,), 4000, (1e-3,), (10**3, 10**4),
              (2, 3), (2,), (50,), (60,), (2e-3,), 2, 30)


def best_of(fn, repeats):
    best = math.inf
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


# ---------------------------------------------------------------------------------- scenes

def peak_valley_pair():
    """Two Gent balloons, each with a peak and a valley: snap-throughs on both legs."""
    return [BalloonSegment('bottom', 0.1, Gent(60e3, 35.0), 0.006, 0.6e-3, 3.6),
            BalloonSegment('top', 0.1, Gent(60e3, 25.0), 0.006, 0.55e-3, 3.4)]


def chain(count, peaks=True):
    """A chain of Gent balloons, thinner towards the tip; the first two have peaks."""
    segments = []
    for i in range(count):
        jm = 34.0 + 2.0 * i if (peaks and i < 2) else 14.0
        segments.append(BalloonSegment(f's{i}', 0.05, Gent(60e3, jm), 0.006,
                                       (0.6 - 0.04 * i) * 1e-3, 2.8))
    return segments


def scenes(names=None):
    """(name, segment builder) of the benchmark's scenes, or of those ``names`` (and chainN)."""
    if names is not None:
        every = dict(scenes())
        return [(name, every.get(name) or (lambda count=int(name[5:]): chain(count)))
                for name in names]
    found = []
    for name in ('fig1_none', 'fig1_partial', 'fig1_symmetric', 'fig1_asymmetric', 'paper'):
        path = ROOT / 'config' / f'{name}.yaml'
        if path.exists():
            found.append((name, lambda p=path: list(load_scene(p).segments)))
    found.append(('peak_valley_pair', peak_valley_pair))
    found.append(('chain5', lambda: chain(5)))
    return found


def history(emap, count=4001):
    lo, hi = emap.injected_range
    top = lo + 0.9999 * (hi - lo)
    up = np.linspace(lo, top, count // 2 + 1)
    return np.concatenate([up, up[::-1][1:]])


# ---------------------------------------------------------------------------------- errors

class Reference:
    def __init__(self, segments, commands, resolution=REFERENCE_RESOLUTION):
        self.segments = segments
        self.emap = EquilibriumMap(segments, resolution=resolution, polish=6)
        path = Tracker(self.emap).sweep(commands)
        totals = commands + self.emap.total_rest_volume
        self.volumes = polish_states(segments, path.volumes, totals)
        self.pressure = np.mean([s.pressure(self.volumes[:, i])
                                 for i, s in enumerate(segments)], axis=0)
        self.v_scale, self.p_scale = self.emap.v_scale, self.emap.p_scale
        if len(segments) == 2:
            self.folds = fold_totals_pair(*segments) - self.emap.total_rest_volume
            naive = NaiveTracker(segments, xtol_fraction=1e-14, walk_fraction=1e-4)
            volumes, _ = naive.sweep(commands)
            self.cross_check = float(np.max(np.abs(volumes - self.volumes)) / self.v_scale)
        else:
            self.folds = np.array([e.injected for e in path.events])
            self.cross_check = math.nan
        self.snap_count = len(path.events)
        # Rows within 1% of the range after a snap (in the direction of travel) are where a
        # dynamic model is still moving; 'off' errors leave them out.
        near = np.zeros(commands.size, dtype=bool)
        for row in np.flatnonzero(path.snap):
            direction = np.sign(commands[row] - commands[max(row - 1, 0)])
            reach = (commands - commands[row]) * direction
            near |= (reach >= 0) & (reach <= 0.01 * self.v_scale) & (
                np.abs(np.arange(commands.size) - row) < commands.size // 4)
        self.off_snap = ~near

    def errors(self, volumes, pressure, snaps):
        deviation = np.max(np.abs(volumes - self.volumes[: volumes.shape[0]]), axis=1)
        self.last_off = float(np.max(deviation[self.off_snap[: volumes.shape[0]]])
                              / self.v_scale)
        split = float(np.max(np.abs(volumes - self.volumes[: volumes.shape[0]])) / self.v_scale)
        pressure = pressure if pressure is not None else self.pressure
        if pressure.size < self.pressure.size:
            press = float(np.max(np.abs(pressure - self.pressure[: pressure.size]))
                          / self.p_scale)
            return split, math.nan, press
        press = float(np.max(np.abs(pressure - self.pressure)) / self.p_scale)
        if snaps is None:
            return split, math.nan, press
        if len(snaps) and self.folds.size:
            snap = max(float(np.min(np.abs(self.folds - s))) for s in snaps) / self.v_scale
        elif len(snaps) or self.snap_count:
            snap = math.inf if len(snaps) != self.snap_count else 0.0
        else:
            snap = math.nan
        return split, snap, press


# ---------------------------------------------------------------------------------- methods

def bench_ours(segments, ref, commands, sweep_commands, few, resolutions=RESOLUTIONS):
    rows = []
    for resolution in resolutions:
        for polish in POLISH:
            start = time.perf_counter()
            emap = EquilibriumMap(segments, resolution=resolution, polish=polish)
            assembly = time.perf_counter() - start
            path = Tracker(emap).sweep(commands)
            split, snap, press = ref.errors(path.volumes, path.pressure,
                                            [e.injected for e in path.events])
            steps = commands[:: 2 if few else 1][:2000]

            def stepping(emap=emap, steps=steps):
                tracker = Tracker(emap)
                for u in steps:
                    tracker.step(u)

            per_step = best_of(stepping, 2 if few else 3) / steps.size
            sweep = best_of(lambda emap=emap: Tracker(emap).sweep(sweep_commands),
                            3 if few else 7)
            rows.append({'method': f'ours r={resolution} polish={polish}', 'split': split,
                         'off': ref.last_off,
                             'snap': snap, 'press': press, 'assembly': assembly, 'step': per_step,
                             'sweep': sweep, 'resolution': resolution, 'polish': polish})
    return rows


def bench_naive(segments, ref, commands):
    tracker = NaiveTracker(segments)
    start = time.perf_counter()
    try:
        volumes, pressure = tracker.sweep(commands)
    except OutOfRangeError as error:
        return {'method': 'naive root-finding', 'failed': str(error)}
    per_step = (time.perf_counter() - start) / commands.size
    split, snap, press = ref.errors(volumes, pressure, tracker.snaps)
    return {'method': 'naive root-finding', 'split': split, 'off': ref.last_off, 'snap': snap,
            'press': press, 'assembly': 0.0, 'step': per_step, 'sweep': per_step * SWEEP_STEPS,
                'extrapolated': True}


def bench_dynamic(segments, ref, commands, slowness):
    start = time.perf_counter()
    try:
        volumes = dynamic_path(segments, commands, slowness, ref.p_scale)
    except RuntimeError as error:
        return {'method': f'dynamic Radau QR/p={slowness:g}', 'failed': str(error)}
    per_step = (time.perf_counter() - start) / commands.size
    pressure = np.mean([s.pressure(volumes[:, i]) for i, s in enumerate(segments)], axis=0)
    split, _, press = ref.errors(volumes, pressure, None)
    return {'method': f'dynamic Radau QR/p={slowness:g}', 'split': split, 'off': ref.last_off,
            'snap': math.nan, 'press': press, 'assembly': 0.0, 'step': per_step,
            'sweep': per_step * SWEEP_STEPS, 'extrapolated': True, 'slowness': slowness}


def bench_interp(segments, ref, commands, sweep_commands, points, few):
    """np.interp of every output column (N volumes, pressure, N curvatures) on a table of
    ``points`` rows along the inflation leg: the floor of any table lookup."""
    emap = ref.emap
    up = commands[: commands.size // 2 + 1]
    grid = np.linspace(up[0], up[-1], points)
    path = Tracker(emap).sweep(grid)
    columns = [path.volumes[:, i] for i in range(len(segments))] + [path.pressure] + \
        [path.curvatures[:, i] for i in range(len(segments))]
    tables = [(grid, c) for c in columns]
    sweep = best_of(lambda: interp_floor(tables, sweep_commands), 3 if few else 7)
    single = best_of(lambda: np.interp(sweep_commands, grid, columns[0]), 3 if few else 7)
    got = interp_floor(tables, up)
    volumes = np.stack(got[: len(segments)], axis=1)
    split, _, press = ref.errors(volumes, got[len(segments)], None)
    return {'off': ref.last_off,
            'method': f'numpy.interp {2 * len(segments) + 1} columns, {points} rows '
                      '(inflation leg only)', 'split': split, 'snap': math.nan, 'press': press,
                'assembly': 0.0, 'step': sweep / SWEEP_STEPS, 'sweep': sweep, 'single': single}


# ---------------------------------------------------------------------------------- scaling

def bench_scaling(few, sizes=FULL):
    lines = ['| work | assembly [s] | 100k-step sweep [ms] | per step (sweep) [us] |',
             '|---|---:|---:|---:|']
    emap = EquilibriumMap(peak_valley_pair())
    lo, hi = emap.injected_range
    for steps in sizes.scaling_steps:
        commands = lo + (hi - lo) * np.abs(np.sin(np.linspace(0, 20, steps)))
        t = best_of(lambda c=commands, m=emap: Tracker(m).sweep(c), 2 if few else 3)
        lines.append(f'| peak-valley pair, {steps} steps | - | {t * 1e3 * 1e5 / steps:.1f} '
                     f'(scaled) | {t / steps * 1e6:.3f} |')
    for count in sizes.monotone_chains:
        start = time.perf_counter()
        emap = EquilibriumMap(chain(count, peaks=False))
        assembly = time.perf_counter() - start
        lo, hi = emap.injected_range
        commands = lo + (hi - lo) * np.abs(np.sin(np.linspace(0, 20, SWEEP_STEPS)))
        t = best_of(lambda c=commands, m=emap: Tracker(m).sweep(c), 2 if few else 3)
        lines.append(f'| monotone chain, {count} segments | {assembly:.2f} | {t * 1e3:.1f} | '
                     f'{t / SWEEP_STEPS * 1e6:.3f} |')
    for count in sizes.peaked_chains:
        start = time.perf_counter()
        emap = EquilibriumMap(chain(count, peaks=True))
        assembly = time.perf_counter() - start
        lines.append(f'| chain with 2 peaked segments, {count} segments | {assembly:.2f} '
                     '| - | - |')
    pair = peak_valley_pair()
    for rows in sizes.table_rows:
        tabulated = []
        for s in pair:
            lam = np.linspace(1.0, (s.max_volume / s.rest_volume) ** (1 / 3), rows)
            v = s.rest_volume * lam**3
            tabulated.append(TabulatedSegment(s.name, 0.1, v, s.pressure(v), s.curvature(v)))
        start = time.perf_counter()
        emap = EquilibriumMap(tabulated)
        assembly = time.perf_counter() - start
        lo, hi = emap.injected_range
        commands = lo + (hi - lo) * np.abs(np.sin(np.linspace(0, 20, SWEEP_STEPS)))
        t = best_of(lambda c=commands, m=emap: Tracker(m).sweep(c), 2 if few else 3)
        lines.append(f'| peak-valley pair as tables, {rows} rows | {assembly:.2f} | '
                     f'{t * 1e3:.1f} | {t / SWEEP_STEPS * 1e6:.3f} |')
    return lines


# ---------------------------------------------------------------------------------- noise

class _SlowError(Exception):
    pass


def _alarm(*_):
    raise _SlowError


def noise_study(few, sizes=FULL):
    """Spurious snap-throughs on the paper's partial-sequence tables with Gaussian noise."""
    base = [read_table(ROOT / 'config' / 'segments' / f'paper_{n}.csv',
                                      length=0.111) for n in ('bottom', 'top')]
    levels = (1e-4, 1e-3, 2e-3, 5e-3, 1e-2, 2e-2)
    seeds = range(sizes.noise_seeds or (3 if few else 5))
    alarm_s = sizes.noise_alarm_s
    signal.signal(signal.SIGALRM, _alarm)
    lines = ['| rows | noise / p range | smoothing | runs with spurious snaps | pieces (mean) '
             '| max pressure error / p range | max split error / range |',
             '|---:|---:|---|---:|---:|---:|---:|']
    results = []
    for rows in sizes.noise_rows:
        clean = []
        for s in base:
            v = np.linspace(s.rest_volume, s.max_volume, rows)
            clean.append((v, s.pressure(v), s.curvature(v)))
        clean_map = EquilibriumMap([TabulatedSegment(f'c{i}', 0.111, *t)
                                    for i, t in enumerate(clean)])
        commands = history(clean_map, min(2001, sizes.history_commands))
        clean_path = Tracker(clean_map).sweep(commands)
        # Past the level where every run snaps, 200-row tables have hundreds of pieces and the
        # assembly takes minutes: nothing more to learn there.
        for level in sizes.noise_levels or (levels if rows < 200 else levels[:4]):
            for smooth in (False, True):
                snapped, pieces, p_err, v_err, slow = 0, [], 0.0, 0.0, 0
                for seed in seeds:
                    rng = np.random.default_rng(seed)
                    segments = []
                    for i, (v, p, c) in enumerate(clean):
                        noisy = p + rng.normal(0.0, level * np.ptp(p), p.size)
                        noisy[0] = p[0]  # the unpressurised row is known exactly
                        if smooth:
                            noisy = smooth_table(v, noisy)
                        p_err = max(p_err, float(np.max(np.abs(noisy - p)) / np.ptp(p)))
                        segments.append(TabulatedSegment(f'n{i}', 0.111, v, noisy, c))
                    pieces.append(np.mean([len(s.monotone_pieces()) for s in segments]))
                    signal.alarm(alarm_s)
                    try:
                        emap = EquilibriumMap(segments)
                        path = Tracker(emap).sweep(np.clip(commands, *emap.injected_range))
                        snapped += bool(path.events)
                        v_err = max(v_err, float(np.max(np.abs(path.volumes - clean_path.volumes))
                                                 / clean_map.v_scale))
                    except _SlowError:
                        slow += 1
                    except (ValueError, RuntimeError):
                        snapped += 1
                    finally:
                        signal.alarm(0)
                note = f' ({slow} assemblies > {alarm_s} s)' if slow else ''
                lines.append(f'| {rows} | {level:g} | {"yes" if smooth else "no"} | '
                             f'{snapped}/{len(seeds)}{note} | {np.mean(pieces):.1f} | '
                             f'{p_err:.2e} | {v_err:.2e} |')
                results.append((rows, level, smooth, snapped / len(seeds)))
                print(lines[-1], flush=True)
    return lines, results


# ---------------------------------------------------------------------------------- main

def fmt(x, digits=2):
    if isinstance(x, float) and math.isnan(x):
        return '-'
    if isinstance(x, float) and math.isinf(x):
        return 'missed'
    return f'{x:.{digits}e}'


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--quick', action='store_true',
                        help='a check that the benchmark runs: small inputs, about 30 s, the '
                        'results in a temporary folder (unless --out) and printed')
    parser.add_argument('--fewer-repeats', action='store_true',
                        help='the whole benchmark with fewer repeats of each timing')
    parser.add_argument('--out', default=None,
                        help='folder for the results (default docs/; with --quick a temporary '
                        'one)')
    parser.add_argument('--skip-noise', action='store_true')
    args = parser.parse_args()
    if args.quick and args.out is None:
        with tempfile.TemporaryDirectory(prefix='bench_solver_') as folder:
            report = run(args, Path(folder), QUICK)
    else:
        report = run(args, Path(args.out or ROOT / 'docs'), QUICK if args.quick else FULL)
    if args.quick:
        print('\n' + report)


def run(args, out, sizes):
    """The whole benchmark into the folder ``out``; the report's text."""
    few = args.quick or args.fewer_repeats
    out.mkdir(parents=True, exist_ok=True)
    report = ['# Solver benchmark: run time against error', '',
              'Written by `python bench/bench_solver.py` (see bench/README.md for the method).',
              '']
    all_rows = {}
    for name, build in scenes(sizes.scenes):
        segments = build()
        print(f'== {name}', flush=True)
        try:
            probe = EquilibriumMap(segments)
        except Exception as error:  # noqa: BLE001 - a scene the solver cannot assemble
            report += [f'## {name}', '', f'Assembly failed: {error}', '']
            continue
        commands = history(probe, sizes.history_commands)
        lo, hi = probe.injected_range
        sweep_commands = lo + (hi - lo) * 0.9999 * np.abs(np.sin(np.linspace(0, 12,
                                                                              SWEEP_STEPS)))
        ref = Reference(segments, commands, sizes.reference_resolution)
        rows = bench_ours(segments, ref, commands, sweep_commands, few, sizes.resolutions)
        rows.append(bench_naive(segments, ref, commands))
        for slowness in sizes.slownesses:
            rows.append(bench_dynamic(segments, ref, commands, slowness))
        rows.append(bench_interp(segments, ref, commands, sweep_commands, 2000, few))
        all_rows[name] = (rows, ref)
        report += [f'## {name}', '',
                   f'{len(segments)} segments; volume range {ref.v_scale * 1e6:.4g} mL, '
                   f'pressure scale {ref.p_scale / 1e3:.4g} kPa; {ref.snap_count} snap-throughs '
                   'on the reference path.' + (
                       f' Reference cross-check (naive brentq, xtol 1e-14): max split '
                       f'difference {ref.cross_check:.1e} of the range.'
                       if not math.isnan(ref.cross_check) else ''), '',
                   '| method | split err | split err off snaps | snap err | pressure err '
                   '| assembly [s] | per step() [us] | 100k sweep [ms] |',
                   '|---|---:|---:|---:|---:|---:|---:|---:|']
        for row in rows:
            if 'failed' in row:
                report.append(f'| {row["method"]} | failed: {row["failed"]} | | | | | | |')
                continue
            sweep = f'{row["sweep"] * 1e3:.1f}' + (' (x steps)' if row.get('extrapolated')
                                                  else '')
            report.append(f'| {row["method"]} | {fmt(row["split"])} | {fmt(row["off"])} | '
                          f'{fmt(row["snap"])} | '
                          f'{fmt(row["press"])} | {row["assembly"]:.3f} | '
                          f'{row["step"] * 1e6:.2f} | {sweep} |')
        report.append('')
        for row in rows:
            print(row, flush=True)
        # Written after every scene, so an interrupted run still leaves its tables.
        (out / 'benchmarks.md').write_text('\n'.join(report) + '\n')
    report += summarise(all_rows)
    report += ['## Scaling', '', *bench_scaling(few, sizes), '']
    if not args.skip_noise:
        lines, results = noise_study(few, sizes)
        report += ['## Noisy tables (paper scene, Gaussian noise on every row but the first)',
                   '', *lines, '']
    figure(all_rows, out / 'bench_solver.png', sizes.resolutions[0])
    (out / 'benchmarks.md').write_text('\n'.join(report) + '\n')
    print(f'wrote {out / "benchmarks.md"} and {out / "bench_solver.png"}')
    return '\n'.join(report)


def summarise(all_rows):
    lines = ['## Targets', '',
             '| scene | naive per step / our sweep per step (error ratio) | naive / our step() '
             '| 100k sweep / numpy.interp (all columns; one column) | default split err '
             '| default snap err |', '|---|---:|---:|---:|---:|---:|']
    for name, (rows, _) in all_rows.items():
        ours = next(r for r in rows if r['method'] == 'ours r=2000 polish=2')
        naive = next(r for r in rows if r['method'] == 'naive root-finding')
        floor = next(r for r in rows if r['method'].startswith('numpy.interp'))
        if 'failed' in naive:
            speed = step_speed = 'naive failed'
        else:
            speed = (f'{naive["step"] / (ours["sweep"] / SWEEP_STEPS):.0f}x '
                     f'({ours["split"] / max(naive["split"], 1e-300):.1g})')
            step_speed = f'{naive["step"] / ours["step"]:.1f}x'
        lines.append(f'| {name} | {speed} | {step_speed} | {ours["sweep"] / floor["sweep"]:.1f}x;'
                     f' {ours["sweep"] / floor["single"]:.0f}x | {fmt(ours["split"])} | '
                     f'{fmt(ours["snap"])} |')
    return lines + ['']


def figure(all_rows, path, label_resolution=RESOLUTIONS[0]):
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 5))
    markers = {'ours': 'o', 'naive': 's', 'dynamic': '^', 'numpy': 'x'}
    colours = plt.rcParams['axes.prop_cycle'].by_key()['color']
    for (name, (rows, _)), colour in zip(all_rows.items(), colours):
        for row in rows:
            if 'failed' in row:
                continue
            kind = row['method'].split()[0].split('.')[0]
            x = row['sweep'] / SWEEP_STEPS
            left.scatter(x, max(row['split'], 1e-17), marker=markers[kind], color=colour,
                         label=name if kind == 'ours'
                         and row.get('resolution') == label_resolution
                         and row.get('polish') == 0 else None)
        dyn = [r for r in rows if r.get('slowness') and 'failed' not in r]
        if dyn:
            right.loglog([r['slowness'] for r in dyn], [r['off'] for r in dyn], 'o-',
                         color=colour, label=name)
    left.set(xscale='log', yscale='log', xlabel='time per step in a 100k-step sweep [s]',
             ylabel='max volume-split error / volume range',
             title='o ours (resolutions, polish)  s naive  ^ dynamic  x numpy.interp')
    left.legend(fontsize=8)
    right.set(xlabel='slowness Q R / p_scale (pump flow x resistance)',
              ylabel='max split error / range, away from snaps',
              title='dynamic reference approaches the quasi-static path')
    right.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


if __name__ == '__main__':
    main()
