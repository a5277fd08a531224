"""
How long the equilibrium map and the transition graph of N peaked segments take, old and new.

    python bench/bench_graph.py [--quick] [--max-n N] [--baseline-max-n N] [--out FILE]

N = 2 to 8 Gent balloons (shear modulus 60 kPa, radius 6 mm), each with a peak and a valley,
base to tip with decreasing Gent limits, wall thicknesses and stretch ranges (the nested-loop
scene of test/test_graph.py, spread over N): once as 600-row tables sampled from the law
(uniform in stretch), once as the closed-form law. Each case is built in a fresh process:
``EquilibriumMap`` (resolution 2000) and ``transition_graph``, timed from inside (wall and
CPU). The baseline is the same code at commit ``BASELINE`` (before the enumeration and the
snap landings were sped up), exported with ``git archive`` into a temporary folder and
imported from there in its own process; it is run up to ``--baseline-max-n`` segments (it
takes minutes beyond). The table gives the configurations of monotone pieces the assembly
examined against the brute-force count (the product of every segment's piece count), the
branches and snaps, and whether old and new give the same branches and branch ends.

``--quick``: N = 2 and 3, tables only, baseline for N = 2; prints its table, writes nothing.
The full mode writes ``bench/graph_results.md``. Timings on a shared machine vary with its
load: the CPU column and the ratio within one run say more than the wall times.
"""

import argparse
import json
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import time

REPO = Path(__file__).resolve().parents[1]
BASELINE = 'd39ee5f'   # the transition graph as it landed, before this speed-up
RESULTS = REPO / 'bench' / 'graph_results.md'
ROWS = 600


def segments(count: int, law: str) -> list:
    """``count`` peaked Gent balloons, base to tip; as tables (``law='table'``) or closed form."""
    import numpy as np

    from softseq_ros.segments.materials import Gent
    from softseq_ros.segments.models import BalloonSegment, TabulatedSegment

    built = []
    for i in range(count):
        share = i / (count - 1)
        balloon = BalloonSegment(f's{i}', 0.074, Gent(60.0e3, 40.0 - 10.0 * share), 0.006,
                                 (0.600 - 0.036 * share) * 1e-3, 4.0 - 0.4 * share, 5.0e5)
        if law == 'table':
            stretch = np.linspace(1.0, (balloon.max_volume / balloon.rest_volume) ** (1 / 3),
                                  ROWS)
            volume = balloon.rest_volume * stretch**3
            balloon = TabulatedSegment(balloon.name, balloon.length, volume,
                                       balloon.pressure(volume), balloon.curvature(volume))
        built.append(balloon)
    return built


def child(count: int, law: str) -> None:
    """Build one case with the ``softseq_ros`` on sys.path; print its numbers as JSON."""
    from softseq_ros.quasistatic.equilibrium import EquilibriumMap
    from softseq_ros.quasistatic.graph import transition_graph

    built = segments(count, law)
    for segment in built:     # the models' own set-up is not the map's
        segment.monotone_pieces()
    wall, cpu = time.perf_counter(), time.process_time()
    emap = EquilibriumMap(built)
    graph = transition_graph(emap)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    ends = [[b.lower.kind, b.lower.target, b.upper.kind, b.upper.target] for b in emap.branches]
    print(json.dumps({
        'wall': wall, 'cpu': cpu, 'branches': len(emap.branches),
        'snaps': sum(t.kind == 'snap' for t in graph.transitions),
        'tried': getattr(emap, 'configurations_tried', None),
        'possible': getattr(emap, 'configurations_possible', None),
        'ends': ends, 'lo': [b.lo for b in emap.branches], 'hi': [b.hi for b in emap.branches]}))


def run(tree: Path, count: int, law: str) -> dict:
    """One case in a fresh process importing ``softseq_ros`` from ``tree``."""
    environment = dict(os.environ, PYTHONPATH=str(tree), MPLBACKEND='Agg')
    done = subprocess.run([sys.executable, str(Path(__file__).resolve()), '--child', str(count),
                           law, str(tree)], cwd=tree, env=environment, capture_output=True,
                          text=True, check=False)
    if done.returncode != 0:
        raise SystemExit(f'{tree}: {count} {law} segments failed: {done.stderr.strip()[-600:]}')
    return json.loads(done.stdout.strip().splitlines()[-1])


def same(new: dict, old: dict) -> str:
    """Whether old and new give the same branches (ends and volume intervals to 1e-12)."""
    if new['ends'] != old['ends']:
        return 'no'
    scale = max(max(map(abs, new['hi'])), 1e-300)
    worst = max(abs(a - b) for a, b in zip(new['lo'] + new['hi'], old['lo'] + old['hi']))
    return 'yes' if worst <= 1e-12 * scale else f'no ({worst / scale:.1e})'


def table(cases: list[tuple[int, str]], baseline_max: int, old_tree: Path | None) -> list[str]:
    """The table's lines, each case printed as it is done."""
    lines = ['| N | law | configurations tried / brute force | branches | snaps | '
             'map + graph [s] | CPU [s] | old [s] | old CPU [s] | new / old (CPU) | '
             'same result |',
             '|---|---|---|---|---|---|---|---|---|---|---|']
    print('\n'.join(lines), flush=True)
    for count, law in cases:
        new = run(REPO, count, law)
        old = run(old_tree, count, law) if old_tree is not None and count <= baseline_max \
            else None
        line = (f'| {count} | {law} | {new["tried"]} / {new["possible"]} | {new["branches"]} | '
                f'{new["snaps"]} | {new["wall"]:.2f} | {new["cpu"]:.2f} | ')
        if old is None:
            line += '- | - | - | - |'
        else:
            line += (f'{old["wall"]:.2f} | {old["cpu"]:.2f} | '
                     f'{new["cpu"] / old["cpu"]:.3f} ({old["cpu"] / new["cpu"]:.1f}x) | '
                     f'{same(new, old)} |')
        lines.append(line)
        print(line, flush=True)
    return lines


def main() -> int:
    """Run the cases; the full mode writes the results file."""
    if len(sys.argv) > 1 and sys.argv[1] == '--child':
        sys.path.insert(0, sys.argv[4])
        child(int(sys.argv[2]), sys.argv[3])
        return 0
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--quick', action='store_true', help='N = 2, 3 (tables), print only')
    parser.add_argument('--max-n', type=int, default=8, help='largest N (full mode)')
    parser.add_argument('--baseline-max-n', type=int, default=4,
                        help='largest N the baseline runs for')
    parser.add_argument('--out', type=Path, default=RESULTS)
    args = parser.parse_args()
    if args.quick:
        cases = [(2, 'table'), (3, 'table')]
        baseline_max = 2
    else:
        cases = [(n, law) for n in range(2, args.max_n + 1) for law in ('table', 'closed')]
        baseline_max = args.baseline_max_n
    with tempfile.TemporaryDirectory() as scratch:
        old_tree = Path(scratch) / 'baseline'
        old_tree.mkdir()
        archive = subprocess.run(['git', 'archive', BASELINE, 'softseq_ros'], cwd=REPO,
                                 capture_output=True, check=True).stdout
        subprocess.run(['tar', '-x', '-C', str(old_tree)], input=archive, check=True)
        print(f'# Equilibrium map and transition graph: N peaked segments\n\n'
              f'Baseline: commit {BASELINE}, up to N = {baseline_max}.\n', flush=True)
        lines = table(cases, baseline_max, old_tree)
    if not args.quick:
        args.out.write_text(
            '# Equilibrium map and transition graph of N peaked segments\n\n'
            'Written by `python bench/bench_graph.py` (see its docstring for the scenes). '
            f'N = 2 to {cases[-1][0]}. Baseline: commit {BASELINE} (before the speed-up), '
            f'run up to N = {baseline_max}. Wall and CPU time of `EquilibriumMap` '
            '(resolution 2000) plus `transition_graph`, each case in a fresh process; the '
            'machine is shared, so compare CPU times within this run.\n\n'
            + '\n'.join(lines) + '\n',
            encoding='utf-8')
        print(f'\nwrote {args.out.relative_to(REPO)}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
