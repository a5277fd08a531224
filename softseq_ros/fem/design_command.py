"""The ``softseq design`` command: a problem file searched, its designs reported and written."""

from pathlib import Path
import time
from typing import Any

from softseq_ros.fem.design_output import (
    numbers_text,
    values_text,
    write_best_scene,
    write_result_files,
)
from softseq_ros.fem.design_problem import load_problem
from softseq_ros.fem.design_reach import reach_text
from softseq_ros.fem.design_search import search
from softseq_ros.scene.design import DesignError


def run_design_command(args: Any) -> int:
    """``softseq design PROBLEM.yaml``: exit 0 when the best design is verified, else 1."""
    import sys

    from softseq_ros.parallel import workers_or_scheduler
    from softseq_ros.progress import end_progress, write_progress

    problem = load_problem(args.problem)
    workers = workers_or_scheduler(args.workers, args.scheduler, DesignError)
    out = args.out if args.out is not None else Path('bags') / f'design_{problem.name}'
    stream = None if args.quiet else sys.stderr
    start = time.perf_counter()

    def announce(line: str) -> None:
        end_progress(stream)
        print(line, flush=True)

    result = search(problem, cache_dir=args.cache_dir, workers=workers,
                    scheduler=args.scheduler,
                    progress=None if stream is None else
                    (lambda line: write_progress(stream, line)), announce=announce)
    end_progress(stream)
    wall = time.perf_counter() - start
    target = problem.target
    print(f'{problem.name}: {result.evaluations} pairs assembled on {result.grid_tables} '
          f'grid tables ({result.fem_runs} FEM runs now, the rest from the cache) in '
          f'{wall:.1f} s')
    print(reach_text(result.reach))
    if not result.ranked:
        print('no design met the target; the closest:')
    for rank, evaluation in enumerate(result.ranked, start=1):
        material = problem.materials[evaluation.material]
        print(f'{rank}. ' + '; '.join(f'{s.name}: {values_text(v)}' for s, v in
                                      zip(problem.segments, evaluation.values))
              + (f'; {material.law}' if len(problem.materials) > 1 else '')
              + f' -> predicted {numbers_text(evaluation.metrics, target)}')
    if result.verification is not None:
        verdict = 'meets the target' if result.verified else 'does NOT meet the target'
        print(f'verification (direct FEM of the best design): '
              f'{numbers_text(result.verification.metrics, target)}: {verdict}')
    written = write_result_files(result, Path(out))
    print(f'designs and results.yaml in {Path(out)} ({len(written)} files)')
    # The search's FEM ran on the coarse grid mesh; a design file keeps its own, finer one.
    meshes = sorted({segment.design.mesh.element_size_m for segment in problem.segments})
    print(f'the search meshed its grid tables at grid.element_size_m '
          f'{problem.element_size_m * 1e3:g} mm; the design files keep their own mesh '
          f'({", ".join(f"{size * 1e3:g} mm" for size in meshes)}): softseq fem on a design '
          'file computes its table at that resolution')
    scene = write_best_scene(result, Path(out))
    if scene is not None:
        designs = [Path(out) / f'{problem.name}_1_{segment.name}.yaml'
                   for segment in problem.segments]
        print(f'a scene of the best design: {scene}; to run it, make its tables once '
              f'({" and ".join(f"softseq fem {design}" for design in designs)}), then '
              f'softseq run {scene}')
    return 0 if result.verified else 1
