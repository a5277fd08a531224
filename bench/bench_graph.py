"""
How long the equilibrium map and the transition graph of N peaked segments take, new and former.

    python bench/bench_graph.py [--quick] [--max-n N] [--repeats R] [--former-max-n N]
                                [--original-max-n N] [--out FILE]

N = 2 to 8 Gent balloons (shear modulus 60 kPa, radius 6 mm), each with a peak and a valley,
base to tip with decreasing Gent limits, wall thicknesses and stretch ranges (the nested-loop
scene of test/test_graph.py, spread over N): once as 600-row tables sampled from the law
(uniform in stretch), once as the closed-form law. Each case is built in a fresh process:
``EquilibriumMap`` (resolution 2000) and ``transition_graph``, timed from inside (wall and
CPU); the new code ``--repeats`` times, best of them.

Baselines, each exported with ``git archive`` into a temporary folder and imported from there
in its own process: ``FORMER`` (the code before the map was built side by side, up to
``--former-max-n``) and ``ORIGINAL`` (the transition graph as it first landed, before any
speed-up, up to ``--original-max-n``). Each baseline case runs once: it takes minutes at
N = 8. "same result" compares every branch's samples, rough intervals and ends, every snap's
landing state and every transition's fluid and energy with the former code's: "bit-identical"
when all of them are equal to the bit; else, when every branch ends as before and every
transition lands where it did, the largest deviation of a branch end (a share of the range).

``--quick``: N = 2 and 3, tables only, former baseline for N = 2, no original; prints its
table, writes nothing. The full mode writes ``bench/graph_results.md``. Timings on a shared
machine vary with its load (the results file gives the load average before and after): the
ratios of CPU times within one run say more than the wall times.
"""

import argparse
import hashlib
import json
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import time

REPO = Path(__file__).resolve().parents[1]
FORMER = '9885cc0'     # the map before it was built side by side (main before this change)
ORIGINAL = 'd39ee5f'   # the transition graph as it landed, before any speed-up
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


def digest(emap: object, graph: object) -> str:
    """SHA-256 of every branch's samples, rough flags and ends, and every transition."""
    import numpy as np

    hasher = hashlib.sha256()
    for branch in emap.branches:
        for array in (branch.total, branch.volumes, branch.pressure, branch.rough):
            hasher.update(np.ascontiguousarray(array).tobytes())
        for end in (branch.lower, branch.upper):
            hasher.update(f'{end.kind} {end.target}'.encode())
            if end.target_volumes is not None:
                hasher.update(np.ascontiguousarray(end.target_volumes).tobytes())
    for transition in graph.transitions:
        hasher.update(repr((transition.source, transition.direction, transition.kind,
                            transition.target, transition.fluid_moved,
                            transition.energy_released)).encode())
    return hasher.hexdigest()


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
        'ends': ends, 'lo': [b.lo for b in emap.branches], 'hi': [b.hi for b in emap.branches],
        'landings': [[t.source, t.direction, t.kind, t.target] for t in graph.transitions],
        'digest': digest(emap, graph)}))


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
    """Whether old and new give the same map and graph: to the bit, or how close."""
    if new['digest'] == old['digest']:
        return 'bit-identical'
    if new['ends'] != old['ends']:
        return 'no (other ends)'
    if old.get('landings', new['landings']) != new['landings']:
        return 'no (other landings)'
    scale = max(max(map(abs, new['hi'])), 1e-300)
    worst = max(abs(a - b) for a, b in zip(new['lo'] + new['hi'], old['lo'] + old['hi']))
    return f'same ends and landings, intervals to {worst / scale:.0e}'


def export(commit: str, folder: Path) -> Path:
    """The package at ``commit`` in ``folder``."""
    folder.mkdir()
    archive = subprocess.run(['git', 'archive', commit, 'softseq_ros'], cwd=REPO,
                             capture_output=True, check=True).stdout
    subprocess.run(['tar', '-x', '-C', str(folder)], input=archive, check=True)
    return folder


def table(cases: list[tuple[int, str]], repeats: int, former: tuple[Path, int],
          original: tuple[Path | None, int]) -> list[str]:
    """The table's lines, each case printed as it is done."""
    lines = ['| N | law | configurations tried / brute force | branches | snaps | '
             'map + graph [s] | CPU [s] | former [s] | former CPU [s] | speed-up (CPU) | '
             'same result as former | original CPU [s] | speed-up (CPU) |',
             '|---|---|---|---|---|---|---|---|---|---|---|---|---|']
    print('\n'.join(lines), flush=True)
    for count, law in cases:
        runs = [run(REPO, count, law) for _ in range(repeats)]
        new = min(runs, key=lambda r: r['cpu'])
        wall = min(r['wall'] for r in runs)
        line = (f'| {count} | {law} | {new["tried"]} / {new["possible"]} | {new["branches"]} | '
                f'{new["snaps"]} | {wall:.2f} | {new["cpu"]:.2f} | ')
        if count <= former[1]:
            old = run(former[0], count, law)
            line += (f'{old["wall"]:.2f} | {old["cpu"]:.2f} | '
                     f'{old["cpu"] / new["cpu"]:.1f}x | {same(new, old)} | ')
        else:
            line += '- | - | - | - | '
        if original[0] is not None and count <= original[1]:
            first = run(original[0], count, law)
            line += f'{first["cpu"]:.2f} | {first["cpu"] / new["cpu"]:.1f}x |'
        else:
            line += '- | - |'
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
    parser.add_argument('--repeats', type=int, default=3, help='runs of the new code per case')
    parser.add_argument('--former-max-n', type=int, default=8,
                        help=f'largest N the former code ({FORMER}) runs for')
    parser.add_argument('--original-max-n', type=int, default=3,
                        help=f'largest N the original code ({ORIGINAL}) runs for')
    parser.add_argument('--out', type=Path, default=RESULTS)
    args = parser.parse_args()
    if args.quick:
        cases = [(2, 'table'), (3, 'table')]
        repeats, former_max, original_max = 1, 2, 0
    else:
        cases = [(n, law) for n in range(2, args.max_n + 1) for law in ('table', 'closed')]
        repeats, former_max, original_max = (args.repeats, args.former_max_n,
                                             args.original_max_n)
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as scratch:
        former = export(FORMER, Path(scratch) / 'former')
        original = export(ORIGINAL, Path(scratch) / 'original') if original_max else None
        print(f'# Equilibrium map and transition graph: N peaked segments\n\n'
              f'Former code: commit {FORMER}, up to N = {former_max}; original: commit '
              f'{ORIGINAL}, up to N = {original_max}.\n', flush=True)
        lines = table(cases, repeats, (former, former_max), (original, original_max))
    load_after = os.getloadavg()
    if not args.quick:
        args.out.write_text(
            '# Equilibrium map and transition graph of N peaked segments\n\n'
            'Written by `python bench/bench_graph.py` (see its docstring for the scenes). '
            f'N = 2 to {cases[-1][0]}. Wall and CPU time of `EquilibriumMap` (resolution 2000) '
            f'plus `transition_graph`, each case in a fresh process, the new code best of '
            f'{repeats}. Former code: commit {FORMER} (before the map was built side by side), '
            f'run once per case up to N = {former_max}; original: commit {ORIGINAL} (the '
            f'graph as it first landed), up to N = {original_max}. 2 cores shared with other '
            f'work: load average {load_before[0]:.1f} before the run, {load_after[0]:.1f} '
            'after; compare CPU times within this run.\n\n' + '\n'.join(lines) + '\n',
            encoding='utf-8')
        shown = args.out.resolve()
        print(f'\nwrote {shown.relative_to(REPO) if shown.is_relative_to(REPO) else shown}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
