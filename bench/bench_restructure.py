"""
The restructured physics and the actuator's model seam cost no speed: old against new.

    python bench/bench_restructure.py [--baseline REF] [--pairs N] [--quick] [--out FILE]

Checks the baseline (default: main before the restructuring) out into a temporary git
worktree and runs the same ``softseq`` commands from both trees in turn, A B A B ..., each in
its own process, timed from outside (wall clock): ``batch`` (``softseq run paper`` without
its report, the whole rig into a bag at a fixed start time), ``report`` (``softseq report`` of
that bag), ``sweep`` (``softseq classify fig1_asymmetric``: assembly and the inflate-then-
deflate sweep) and ``assembly`` (``softseq classify three_segments``, three peaked tables),
and ``library`` (``softseq library config/library``: every pair assembled and swept, on the
process pool). The ratio new / old is taken pair by pair and its median quoted: a machine
whose speed drifts moves both runs of a pair alike. ``--quick`` runs one pair of the two
shortest commands against the last commit (``HEAD``, unless ``--baseline`` is given) and
writes nothing: it keeps the script itself working.
"""

import argparse
from pathlib import Path
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

REPO = Path(__file__).resolve().parents[1]
BASELINE = '6b18066'   # main before the physics was split and the model seam added
RESULTS = REPO / 'bench' / 'restructure_results.md'
START_TIME = '1795000000'
ALL_JOBS = ('batch', 'report', 'sweep', 'assembly', 'library')


def commands(bags: Path) -> dict[str, list[str]]:
    """Each timed job as ``softseq`` arguments (bags go under ``bags``)."""
    return {
        'batch': ['run', 'paper', '--out', str(bags / 'paper'), '--quiet', '--no-report',
                  '--start-time', START_TIME],
        'report': ['report', str(bags / 'paper_report_source'), '--out',
                   str(bags / 'report'), '--no-svg'],
        'sweep': ['classify', 'fig1_asymmetric'],
        'assembly': ['classify', 'three_segments'],
        'library': ['library', 'config/library', '--out', str(bags / 'library')],
    }


def run_once(tree: Path, arguments: list[str], scratch: list[Path]) -> float:
    """Wall time [s] of one ``softseq`` command run from ``tree``; its outputs are removed."""
    for path in scratch:
        shutil.rmtree(path, ignore_errors=True)
    environment = {'PYTHONPATH': str(tree), 'PATH': '/usr/bin:/bin', 'MPLBACKEND': 'Agg',
                   'HOME': str(Path.home())}
    start = time.perf_counter()
    result = subprocess.run([sys.executable, '-m', 'softseq_ros.cli', *arguments], cwd=tree,
                            env=environment, capture_output=True, text=True, check=False)
    elapsed = time.perf_counter() - start
    if result.returncode != 0:
        raise SystemExit(f'{tree}: softseq {" ".join(arguments)} failed '
                         f'(exit {result.returncode}): {result.stderr.strip()[-400:]}')
    return elapsed


def prepare_report_bag(tree: Path, bags: Path) -> None:
    """One bag both trees report on (the report reads bags of either version alike)."""
    subprocess.run([sys.executable, '-m', 'softseq_ros.cli', 'run', 'paper', '--out',
                    str(bags / 'paper_report_source'), '--quiet', '--no-report',
                    '--start-time', START_TIME], cwd=tree, env={'PYTHONPATH': str(tree),
                   'PATH': '/usr/bin:/bin', 'HOME': str(Path.home())}, check=True,
                   capture_output=True)


def measure(old: Path, new: Path, bags: Path, jobs: list[str], pairs: int) -> dict:
    table = commands(bags)
    results = {}
    for job in jobs:
        arguments = table[job]
        scratch = [Path(a) for a in arguments if a.startswith(str(bags))
                   and 'report_source' not in a]
        run_once(old, arguments, scratch)   # warm-up: imports compiled, files cached
        run_once(new, arguments, scratch)
        old_times, new_times = [], []
        for _ in range(pairs):
            old_times.append(run_once(old, arguments, scratch))
            new_times.append(run_once(new, arguments, scratch))
        ratios = [n / o for n, o in zip(new_times, old_times)]
        results[job] = {'old': statistics.median(old_times), 'new': statistics.median(new_times),
                        'ratio': statistics.median(ratios), 'min': min(ratios),
                        'max': max(ratios)}
        print(f'{job:9s} old {results[job]["old"]:7.2f} s  new {results[job]["new"]:7.2f} s  '
              f'new/old {results[job]["ratio"]:.3f} ({min(ratios):.3f} to {max(ratios):.3f})',
              flush=True)
    return results


def markdown(results: dict, baseline: str, head: str, pairs: int) -> str:
    lines = ['# Restructuring: speed old against new', '',
             f'`python bench/bench_restructure.py` (baseline `{baseline}`, new `{head}`, '
             f'{pairs} alternated pairs per job, wall time of whole `softseq` processes, '
             'median). A ratio below 1 is faster.', '',
             '| job | command | old [s] | new [s] | new / old (median, min to max) |',
             '|---|---|---:|---:|---:|']
    shown = {'batch': '`softseq run paper --no-report`', 'report': '`softseq report`',
             'sweep': '`softseq classify fig1_asymmetric`',
             'assembly': '`softseq classify three_segments`',
             'library': '`softseq library config/library`'}
    for job, row in results.items():
        lines.append(f'| {job} | {shown[job]} | {row["old"]:.2f} | {row["new"]:.2f} | '
                     f'{row["ratio"]:.3f} ({row["min"]:.3f} to {row["max"]:.3f}) |')
    return '\n'.join(lines) + '\n'


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--baseline', default=None,
                        help=f'git ref of the old tree (default {BASELINE}; HEAD with --quick)')
    parser.add_argument('--pairs', type=int, default=5, help='alternated pairs per job')
    parser.add_argument('--quick', action='store_true',
                        help='one pair of the two shortest jobs, nothing written')
    parser.add_argument('--out', type=Path, default=RESULTS)
    parser.add_argument('--jobs', nargs='+', choices=ALL_JOBS, default=None,
                        help='only these jobs (default: all; printed, not written)')
    options = parser.parse_args()
    jobs = options.jobs or (['sweep', 'assembly'] if options.quick else list(ALL_JOBS))
    pairs = 1 if options.quick else options.pairs
    baseline = options.baseline or ('HEAD' if options.quick else BASELINE)
    head = subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], cwd=REPO, check=True,
                          capture_output=True, text=True).stdout.strip()
    if subprocess.run(['git', 'status', '--porcelain', '--untracked-files=no'], cwd=REPO,
                      check=True, capture_output=True, text=True).stdout.strip():
        head += ' with uncommitted changes'
    with tempfile.TemporaryDirectory(prefix='bench_restructure_') as folder:
        old = Path(folder) / 'old'
        bags = Path(folder) / 'bags'
        bags.mkdir()
        subprocess.run(['git', 'worktree', 'add', '--detach', str(old), baseline],
                       cwd=REPO, check=True, capture_output=True)
        try:
            if 'report' in jobs:
                prepare_report_bag(REPO, bags)
            results = measure(old, REPO, bags, jobs, pairs)
        finally:
            subprocess.run(['git', 'worktree', 'remove', '--force', str(old)], cwd=REPO,
                           check=False, capture_output=True)
    text = markdown(results, baseline, head, pairs)
    if options.quick or options.jobs:
        print(text)
    else:
        options.out.write_text(text)
        print(f'wrote {options.out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
