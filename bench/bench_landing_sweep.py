"""
Where snaps land on random sets of stepped and smooth tables: every snap checked, 0 failures.

    python bench/bench_landing_sweep.py [--quick] [--sets N] [--seed S] [--limit SECONDS]
                                        [--only I,J,...] [--out FILE]

70 seeded sets (``--sets``) of 2 to 4 Gent-balloon tables each: the thin-walled sphere's
closed form (docs/DESIGN: p = 2 mu H / R (1/l - 1/l^7) / (1 - (2 l^2 + l^-4 - 3) / Jm)),
sampled at 40 to 600 rows uniform in stretch, with the physical parameters drawn from the
ranges of the faults found so far (shear modulus 45 to 80 kPa, Gent limit 20 to 40, wall
0.4 to 0.8 mm, stretched to 3.5 to 4.3 but never past 97 % of the Gent limit's stretch;
radius 6 mm). Each set's pressures are quantised to nothing, 10 Pa or 100 Pa (a logger's
resolution: runs of rows at one pressure, flat pieces); in 40 % of the sets the tables are
identical (the same parameters and rows for every segment: flats at the same pressures,
pitchforks, saddles and plateaus shared by several segments).

Each set's ``EquilibriumMap`` and ``transition_graph`` are built in a forked process with a
time limit (``--limit``, 600 s), one set at a time, and every snap is checked as
test/test_graph.py's ``assert_snaps_land_on_balanced_stable_states`` checks it (the tie
between identical segments not asserted: the mirror landings are equally stable): the total
volume conserved (1e-9), the pressures after it balanced (1e-4 Pa), a stable or neutral
state (at most one segment falling and a stiffness cofactor sum >= 0, to 1e-9 of the
steepest table's stiffness scale), and the energy released >= 0 within round-off
(1e-12 of pressure times volume). A set fails when the map or the graph raises, runs past
its limit, or any snap fails a check; the results file gives the first reason.

``--quick``: a few sets that finish in well under a minute together (two of them stepped
identical tables); prints the table, writes nothing. The full mode writes
``bench/landing_sweep_results.md`` and exits 1 when any set fails.
``test/test_landing_sweep.py`` runs the quick sets through :func:`run_set`.
"""

import argparse
from dataclasses import dataclass
import math
import multiprocessing
import os
from pathlib import Path
import sys
import time

import numpy as np

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / 'bench' / 'landing_sweep_results.md'
SEED = 20261204
SETS = 70
LIMIT_S = 600.0
RADIUS = 0.006
V0 = 4.0 / 3.0 * math.pi * RADIUS**3
STEPS = (0.0, 10.0, 100.0)
IDENTICAL_SHARE = 0.4
# Quick sets, about 8 s together: smooth and stepped, different and identical (2 to 4 identical
# stepped tables: pitchforks, shared plateaus and saddles).
QUICK = (0, 1, 2, 3, 5, 7, 16, 62)


@dataclass(frozen=True)
class Table:
    """One Gent balloon's table: its law's parameters and how it is sampled."""

    shear_modulus: float
    gent_limit: float
    wall: float
    max_stretch: float
    rows: int


@dataclass(frozen=True)
class SweepSet:
    """One set of tables, base to tip, with its pressures quantised to ``step`` Pa (0: not)."""

    index: int
    step: float
    identical: bool
    tables: tuple[Table, ...]

    def describe(self) -> str:
        kind = 'identical' if self.identical else 'different'
        step = 'smooth' if self.step == 0.0 else f'{self.step:g} Pa'
        return f'{len(self.tables)} {kind}, {step}'


def _table(rng: np.random.Generator) -> Table:
    gent_limit = float(rng.uniform(20.0, 40.0))
    # The stretch where 2 l^2 + l^-4 - 3 reaches 97 % of the limit (l^-4 is negligible there).
    ceiling = math.sqrt((0.97 * gent_limit + 3.0) / 2.0)
    return Table(shear_modulus=float(rng.uniform(45e3, 80e3)), gent_limit=gent_limit,
                 wall=float(rng.uniform(0.4e-3, 0.8e-3)),
                 max_stretch=float(min(rng.uniform(3.5, 4.3), ceiling)),
                 rows=int(rng.integers(40, 601)))


def generate_sets(count: int = SETS, seed: int = SEED) -> list[SweepSet]:
    """The seeded sets: sizes 2 to 4, steps cycling through STEPS, 40 % identical."""
    rng = np.random.default_rng(seed)
    identical = np.zeros(count, dtype=bool)
    identical[:round(IDENTICAL_SHARE * count)] = True
    rng.shuffle(identical)
    sets = []
    for index in range(count):
        n = int(rng.integers(2, 5))
        if identical[index]:
            tables = (_table(rng),) * n
        else:
            tables = tuple(_table(rng) for _ in range(n))
        sets.append(SweepSet(index, STEPS[index % len(STEPS)], bool(identical[index]), tables))
    return sets


def segments_of(sweep_set: SweepSet) -> list:
    """The set's segments, base to tip (TabulatedSegment, curvature 0)."""
    from softseq_ros.segments.models import TabulatedSegment

    segments = []
    for i, table in enumerate(sweep_set.tables):
        stretch = np.linspace(1.0, table.max_stretch, table.rows)
        pressure = (2.0 * table.shear_modulus * table.wall / RADIUS
                    * (1.0 / stretch - stretch**-7)
                    / (1.0 - (2.0 * stretch**2 + stretch**-4 - 3.0) / table.gent_limit))
        if sweep_set.step:
            pressure = np.round(pressure / sweep_set.step) * sweep_set.step
        segments.append(TabulatedSegment(f's{i}', 0.074, V0 * stretch**3, pressure,
                                         np.zeros(table.rows)))
    return segments


def snap_faults(segments: list, graph: object) -> list[str]:
    """
    Why snaps of ``graph`` fail the landing checks (empty: none does).

    The checks of test/test_graph.py's assert_snaps_land_on_balanced_stable_states, without
    its tie-break between identical segments.
    """
    faults = []
    k_scale = max(np.ptp(s.pressure(v)) / np.ptp(v) for s, v in
                  ((s, np.linspace(s.rest_volume, s.max_volume, 201)) for s in segments))
    for snap in graph.snaps():
        after, before = np.array(snap.volumes_after), np.array(snap.volumes_before)
        where = f'snap from branch {snap.source} ({snap.direction}) to {snap.target}'
        if abs(after.sum() - before.sum()) > 1e-9 * abs(before.sum()):
            faults.append(f'{where}: volume not conserved ({after.sum() - before.sum():.3g})')
        pressures = np.array([float(s.pressure(v)) for s, v in zip(segments, after)])
        if not np.ptp(pressures) < 1e-6 * 100.0:
            faults.append(f'{where}: pressures unbalanced by {np.ptp(pressures):.3g} Pa')
        k = np.array([float(s.stiffness(v)) for s, v in zip(segments, after)]) / k_scale
        if np.sum(k < -1e-9) > 1 or sum(np.prod(np.delete(k, i)) for i in range(k.size)) < -1e-9:
            faults.append(f'{where}: lands on an unstable state (k {np.round(k, 6).tolist()})')
        if snap.energy_released < -1e-12 * abs(snap.pressure_before) * after.sum():
            faults.append(f'{where}: releases {snap.energy_released:.3g} J')
    return faults


def run_set(sweep_set: SweepSet) -> dict:
    """Build the set's map and graph and check every snap: branches, snaps, seconds, faults."""
    from softseq_ros.quasistatic.equilibrium import EquilibriumMap
    from softseq_ros.quasistatic.graph import transition_graph

    segments = segments_of(sweep_set)
    start = time.perf_counter()
    try:
        graph = transition_graph(EquilibriumMap(segments))
    except Exception as err:   # noqa: BLE001 - any error fails the set, with its message
        return {'branches': None, 'snaps': None, 'seconds': time.perf_counter() - start,
                'faults': [f'{type(err).__name__}: {err}']}
    seconds = time.perf_counter() - start
    return {'branches': len(graph.branches), 'snaps': len(graph.snaps()), 'seconds': seconds,
            'faults': snap_faults(segments, graph)}


def _child(sweep_set: SweepSet, connection: object) -> None:
    connection.send(run_set(sweep_set))
    connection.close()


def run_limited(sweep_set: SweepSet, limit: float) -> dict:
    """:func:`run_set` in a forked process, stopped after ``limit`` seconds (a fault)."""
    context = multiprocessing.get_context('fork')
    receiving, sending = context.Pipe(duplex=False)
    process = context.Process(target=_child, args=(sweep_set, sending))
    start = time.perf_counter()
    process.start()
    sending.close()
    result = None
    if receiving.poll(limit):
        try:
            result = receiving.recv()
        except EOFError:
            result = None
    if process.is_alive():
        process.kill()
    process.join()
    if result is None:
        seconds = time.perf_counter() - start
        reason = (f'stopped at the time limit ({limit:g} s)' if seconds >= limit
                  else f'the process died (exit code {process.exitcode})')
        result = {'branches': None, 'snaps': None, 'seconds': seconds, 'faults': [reason]}
    return result


def _row(sweep_set: SweepSet, result: dict) -> str:
    tables = '; '.join(f'{t.rows} rows, mu {t.shear_modulus / 1e3:.1f} kPa, Jm '
                       f'{t.gent_limit:.2f}, H {t.wall * 1e3:.3f} mm, l {t.max_stretch:.3f}'
                       for t in (sweep_set.tables[:1] if sweep_set.identical
                                 else sweep_set.tables))
    verdict = 'pass' if not result['faults'] else (
        f'FAIL: {result["faults"][0]}' + (f' (and {len(result["faults"]) - 1} more)'
                                          if len(result['faults']) > 1 else ''))

    def number(x: int | None) -> str:
        return '-' if x is None else str(x)

    return (f'| {sweep_set.index} | {sweep_set.describe()} | {tables} | '
            f'{number(result["branches"])} | {number(result["snaps"])} | '
            f'{result["seconds"]:.1f} | {verdict} |')


HEADER = ('| set | tables | parameters (each table; one for identical) | branches | snaps | '
          'seconds | result |\n|---|---|---|---|---|---|---|')


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--quick', action='store_true', help='a few sets; write nothing')
    parser.add_argument('--sets', type=int, default=SETS)
    parser.add_argument('--seed', type=int, default=SEED)
    parser.add_argument('--limit', type=float, default=LIMIT_S, help='seconds per set')
    parser.add_argument('--only', default='', help='comma-separated set indices')
    parser.add_argument('--out', type=Path, default=None, help='results file (full mode)')
    parser.add_argument('--note', default='', help='a line written above the table')
    args = parser.parse_args(argv)
    sys.path.insert(0, str(REPO))
    sets = generate_sets(args.sets, args.seed)
    if args.quick:
        sets = [sets[i] for i in QUICK if i < len(sets)]
    elif args.only:
        sets = [sets[int(i)] for i in args.only.split(',')]
    rows, failed, total = [], 0, 0.0
    print(HEADER)
    for sweep_set in sets:
        result = run_limited(sweep_set, args.limit)
        total += result['seconds']
        failed += bool(result['faults'])
        rows.append(_row(sweep_set, result))
        print(rows[-1], flush=True)
        for fault in result['faults'][1:5]:
            print(f'    also: {fault}', flush=True)
    summary = (f'{len(sets)} sets, {failed} failed, {total:.0f} s in all (seed {args.seed}, '
               f'limit {args.limit:g} s per set)')
    print(summary)
    if not args.quick:
        out = args.out or RESULTS
        load = os.getloadavg()
        text = ('# Landing sweep\n\n`python bench/bench_landing_sweep.py` '
                '(bench/bench_landing_sweep.py says what is generated and checked).\n\n'
                + (f'{args.note}\n\n' if args.note else '')
                + f'**{summary}**; load average at the end {load[0]:.1f}.\n\n'
                + HEADER + '\n' + '\n'.join(rows) + '\n')
        out.write_text(text, encoding='utf-8')
        print(f'wrote {out}')
    return 1 if failed else 0


if __name__ == '__main__':
    sys.exit(main())
