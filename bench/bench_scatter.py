"""
``softseq scatter``: what 1,000 samples of a closed-form pair cost, locally and on Dask.

    python bench/bench_scatter.py [--quick] [--out FILE]

The scene is the closed-form pair of test/test_scatter.py: a linear bottom segment that ends
at 8 kPa and a neo-Hookean balloon top (R = 10 mm, mu = 34 kPa) whose thickness decides
between a symmetric and a partial sequence; the balloon's thickness is normal (mean 0.97 of
the flip's, deviation 5 %) and the bottom's stiffness uniform +-2 %. Every sample assembles the
equilibrium map, sweeps it up and down (4001 volumes) and measures it. The same samples run

1. in this process (one worker),
2. on local worker processes (``--workers 2``, the shared executor's default backend),
3. on a local Dask cluster of two one-thread worker processes (``LocalCluster``, started and
   closed inside the timed call),
4. on such a cluster already running, by its scheduler's address (started before the timer
   and closed after it), as ``softseq scatter --scheduler tcp://...`` uses a running one,

each timed once from outside the call (wall time, with the start of its workers), and the
samples checked identical across the four. The Sobol design is left out (``sobol=0``): it is
the same work, more samples. The full mode (1,000 samples) writes ``bench/scatter_results.md``
(or ``--out``); ``--quick`` (100 samples) prints the table and writes nothing.
"""

import argparse
import os
from pathlib import Path
import sys
import tempfile
import time

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / 'test'))   # the closed-form pair of test_scatter.py

from scenes import FLIP_H, flip_document  # noqa: E402

from softseq_ros.analysis import scatter  # noqa: E402
from softseq_ros.scene.loader import scene_from_dict  # noqa: E402

RESULTS = REPO / 'bench' / 'scatter_results.md'
TARGET_S = 60.0


def flip_scene():  # noqa: ANN201
    return scene_from_dict(flip_document())


def timed(scene, parameters, samples: int, **how):  # noqa: ANN001, ANN201
    start = time.perf_counter()
    cpu = time.process_time()
    result = scatter.run_scatter(scene, parameters, samples=samples, sobol=0, **how)
    return result, time.perf_counter() - start, time.process_time() - cpu


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--quick', action='store_true', help='100 samples; writes nothing')
    parser.add_argument('--out', type=Path, help=f'results file (default {RESULTS})')
    args = parser.parse_args()
    samples = 100 if args.quick else 1000
    scene = flip_scene()
    parameters = scatter.parameters_of(scene, {
        'top.thickness_m': f'normal:{0.97 * FLIP_H!r},{0.05 * FLIP_H!r}',
        'bottom.stiffness_pa_per_m3': 'uniform:2%'})
    runs = [('this process (1 worker)', {'workers': 1}),
            ('local processes (2 workers)', {'workers': 2}),
            ('local Dask cluster (2 workers x 1 thread)', {'workers': 2, 'backend': 'dask'})]
    rows, results = [], []
    import dask

    # The Dask workers' scratch space in a folder of our own, removed after the runs.
    with tempfile.TemporaryDirectory(prefix='bench_scatter_') as scratch, \
            dask.config.set({'temporary-directory': scratch}):
        for label, how in runs:
            result, wall, cpu = timed(scene, parameters, samples, **how)
            results.append(result)
            rows.append((label, wall, cpu))
        from distributed import LocalCluster

        with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                          dashboard_address=':0') as cluster:
            result, wall, cpu = timed(scene, parameters, samples, backend='dask',
                                      scheduler=cluster.scheduler_address)
        results.append(result)
        rows.append(('running local Dask cluster, by its address (2 workers x 1 thread)', wall,
                     cpu))
    same = all(r.samples == results[0].samples for r in results[1:])
    serial = rows[0][1]
    chance = results[0].summary['sequence_type']['symmetric']
    lines = ['# softseq scatter: samples per second, locally and on Dask', '',
             f'{samples} samples of the closed-form pair (linear + neo-Hookean balloon, '
             'thickness normal, stiffness uniform), no Sobol design; machine: '
             f'{os.cpu_count()} cores, load average '
             f'{", ".join(f"{x:.1f}" for x in os.getloadavg())} at the end.', '',
             '| where | wall [s] | CPU here [s] | samples / s | wall / one worker | '
             f'under {TARGET_S:g} s |',
             '|---|---:|---:|---:|---:|---|']
    for label, wall, cpu in rows:
        lines.append(f'| {label} | {wall:.2f} | {cpu:.2f} | {samples / wall:.0f} | '
                     f'{wall / serial:.2f} | {"yes" if wall < TARGET_S else "no"} |')
    low, high = chance['interval']
    lines += ['', f'Identical samples on the four: {"yes" if same else "NO"}. '
              f'P(symmetric) = {chance["probability"]:.3f} (95 % interval {low:.3f} to '
              f'{high:.3f}); the closed form gives 0.726.']
    text = '\n'.join(lines) + '\n'
    print(text)
    out = args.out or (None if args.quick else RESULTS)
    if out is not None:
        out.write_text(text)
        print(f'written: {out}')
    return 0 if same else 1


if __name__ == '__main__':
    sys.exit(main())
