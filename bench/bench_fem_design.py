"""
`softseq design` on the README's targets: FEM calls and wall time to meet each, on one local
worker, two local workers and a local Dask cluster of two workers, each from an empty cache.

    python bench/bench_fem_design.py            # both targets (tens of minutes on 2 cores)
    python bench/bench_fem_design.py --quick    # config/design_targets/tiny.yaml, seconds
    python bench/bench_fem_design.py --refresh-quick-cache   # after a change of FEM code

The targets are config/design_targets/paper_partial.yaml (the paper's: partial, the top
leading, switch near 30 mL, levelled off from 40 mL, from ranges around Table I) and
symmetric_pair.yaml (a target the paper did not build, with the material fit as a parameter).
Results go to bench/fem_design_results.json and .md; the designs found to bench/fem_design/.

``--quick`` checks that the benchmark runs, in a few seconds of CPU: the tiny problem on two
local workers, its three grid tables from bench/fem_design/tiny_cache (the same tables every
run would compute first; test/test_fem_design_search.py computes one of them again and compares),
so only the verification is a FEM run. When the FEM code or felupe changes, the tables' design
hashes change with it: the quick mode then says so and computes them (tens of seconds), and
``--refresh-quick-cache`` writes the new ones.
"""

import argparse
import json
import os
from pathlib import Path
import sys
import tempfile
import time

os.environ.setdefault('OMP_NUM_THREADS', '1')
os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from softseq_ros.fem.design_grid import ensure_tables, grid_designs  # noqa: E402
from softseq_ros.fem.design_output import (  # noqa: E402
    numbers_text,
    values_text,
    write_result_files,
)
from softseq_ros.fem.design_problem import load_problem  # noqa: E402
from softseq_ros.fem.design_search import search  # noqa: E402
from softseq_ros.scene.design import cache_path  # noqa: E402

TARGETS = REPO / 'config' / 'design_targets'
# --quick: the shipped tiny problem (also the one test/test_fem_design_search.py runs) and its
# grid's tables.
QUICK_PROBLEM = TARGETS / 'tiny.yaml'
QUICK_CACHE = REPO / 'bench' / 'fem_design' / 'tiny_cache'


def quick_grid(problem: object) -> list:
    """The tiny problem's grid designs (their tables are what QUICK_CACHE holds)."""
    return [design for *_, design in grid_designs(problem)]


def refresh_quick_cache() -> None:
    """Compute the tiny problem's grid tables into QUICK_CACHE (stale ones removed)."""
    problem = load_problem(QUICK_PROBLEM)
    designs = quick_grid(problem)
    keep = {cache_path(d, QUICK_CACHE).name for d in designs}
    for stale in QUICK_CACHE.glob('*.csv'):
        if stale.name not in keep:
            stale.unlink()
    _, runs = ensure_tables(designs, QUICK_CACHE, 2, None, print, 'tiny grid')
    print(f'{QUICK_CACHE.relative_to(REPO)}: {len(designs)} tables ({runs} computed now)')


def run_once(problem: object, how: str, out: Path | None, seed: Path | None = None) -> dict:
    """One search from an empty cache (or one holding ``seed``'s tables): 'local1', 'local2'
    or 'dask2'."""
    import shutil

    with tempfile.TemporaryDirectory(prefix='bench_fem_design_') as folder:
        cache = Path(folder) / 'cache'
        if seed is not None:
            shutil.copytree(seed, cache)
        start = time.perf_counter()
        if how == 'dask2':
            from distributed import LocalCluster

            with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                              dashboard_address=':0') as cluster:
                result = search(problem, cache_dir=cache, scheduler=cluster.scheduler_address,
                                progress=print, announce=print)
        else:
            result = search(problem, cache_dir=cache, workers=int(how[-1]), progress=print,
                            announce=print)
        wall = time.perf_counter() - start
        if out is not None:
            write_result_files(result, out)
    best = result.ranked[0] if result.ranked else None
    return {'how': how, 'wall_s': round(wall, 1), 'fem_runs': result.fem_runs,
            'grid_tables': result.grid_tables, 'assembled_pairs': result.evaluations,
            'met': len(result.ranked), 'verified': result.verified,
            'timings_s': {k: round(v, 1) for k, v in result.timings.items()},
            'best': None if best is None else
            '; '.join(f'{s.name}: {values_text(v)}' for s, v in
                      zip(problem.segments, best.values))
            + (f'; {problem.materials[best.material].law}' if len(problem.materials) > 1
               else ''),
            'predicted': None if best is None else numbers_text(best.metrics, problem.target),
            'verification': None if result.verification is None else
            numbers_text(result.verification.metrics, problem.target)}


def report(rows: list[dict], machine: dict, note: str = '',
           cache: str = 'Each run from an empty cache.') -> str:
    lines = ['# softseq design: FEM calls and wall time to meet a target', '',
             f'Written by `python bench/bench_fem_design.py`{note}. {cache} Machine: {machine}.',
             '',
             '| target | executor | FEM runs | grid tables | pairs assembled | designs met | '
             'reach / grid / search / verify [s] | wall [s] | verified |',
             '|---|---|---:|---:|---:|---:|---|---:|---|']
    for row in rows:
        t = row['timings_s']
        lines.append(f'| {row["target"]} | {row["how"]} | {row["fem_runs"]} | '
                     f'{row["grid_tables"]} | {row["assembled_pairs"]} | {row["met"]} | '
                     f'{t["reach_s"]} / {t["grid_s"]} / {t["search_s"]} / {t["verify_s"]} | '
                     f'{row["wall_s"]} | {row["verified"]} |')
    lines += ['', '| target | best design | predicted (assembly of interpolated tables) | '
              'verified (direct FEM) |', '|---|---|---|---|']
    seen = set()
    for row in rows:
        if row['target'] in seen:
            continue
        seen.add(row['target'])
        lines.append(f'| {row["target"]} | {row["best"]} | {row["predicted"]} | '
                     f'{row["verification"]} |')
    base = {r['target']: r['wall_s'] for r in rows if r['how'] == 'local1'}
    speedups = [f'{r["target"]} {r["how"]}: {base[r["target"]] / r["wall_s"]:.2f}x'
                for r in rows if r['how'] != 'local1' and r['target'] in base]
    if speedups:
        lines += ['', 'Speed-up over one worker: ' + ', '.join(speedups) + '.']
    return '\n'.join(lines) + '\n'


def _machine() -> dict:
    return {'cores': os.cpu_count(), 'load_average': [round(v, 2) for v in os.getloadavg()],
            'date_utc': time.strftime('%Y-%m-%d %H:%M', time.gmtime())}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--quick', action='store_true', help='the tiny problem on 2 local '
                        'workers, its grid from bench/fem_design/tiny_cache; nothing written '
                        'into the repository')
    parser.add_argument('--refresh-quick-cache', action='store_true', help="compute the tiny "
                        "problem's grid tables into bench/fem_design/tiny_cache")
    args = parser.parse_args()
    if args.refresh_quick_cache:
        refresh_quick_cache()
        return
    if args.quick:
        problem = load_problem(QUICK_PROBLEM)
        designs = quick_grid(problem)
        held = sum(cache_path(d, QUICK_CACHE).is_file() for d in designs)
        where = QUICK_CACHE.relative_to(REPO)
        print(f'quick: {held} of the {len(designs)} grid tables from {where}'
              + ('' if held == len(designs) else
                 ' (the others are computed now: the FEM code or felupe changed; python '
                 'bench/bench_fem_design.py --refresh-quick-cache writes them)'), flush=True)
        rows = [{'target': problem.name, **run_once(problem, 'local2', None, QUICK_CACHE)}]
        print(report(rows, _machine(), ' --quick (the tiny problem: the numbers show that it '
                                       'runs)', f'The grid tables from {where}.'))
        return
    rows = []
    for name, modes in (('paper_partial', ('local1', 'local2', 'dask2')),
                        ('symmetric_pair', ('local2',))):
        problem = load_problem(TARGETS / f'{name}.yaml')
        for how in modes:
            out = REPO / 'bench' / 'fem_design' / name if how == 'local2' else None
            rows.append({'target': name, **run_once(problem, how, out)})
            print(rows[-1], flush=True)
    machine = _machine()
    (REPO / 'bench' / 'fem_design_results.json').write_text(
        json.dumps({'machine': machine, 'rows': rows}, indent=1) + '\n')
    text = report(rows, machine)
    (REPO / 'bench' / 'fem_design_results.md').write_text(text)
    print(text)


if __name__ == '__main__':
    main()
