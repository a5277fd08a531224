"""
Inverse design: segment designs whose assembled sequence meets a target (``softseq design``).

The paper's conclusion is that a library of simulated segments makes design fast. This module
is that library, searched (the steps before the search have modules of their own):

1. **Reach** (:mod:`.design_reach`). Before the grid and the search, the target is checked
   against what the ranges can reach, and refused naming the bound and the parameter to widen:
   the tip's reach needs no FEM (at most the actuator's length); the plateau pressure and the
   plateau's start are bounded soundly from each segment's softest and stiffest corner
   (:mod:`.bounds`: the premise that thicker membranes and walls stiffen and a longer membrane
   softens, and envelopes for curves with peaks). The corners are grid points: when some are
   not cached the command says so before computing them, and the search reuses them. The
   switch, the leader and the sequence type are not bounded (they follow from slopes, not
   levels); what the corner pairs do is shown beside the bounds.
2. **Grid** (:mod:`.design_grid`). Unit-cell FEM tables on a coarse grid of each segment's
   varied parameters and material fits, cached by their design hash, run on the shared
   executor (:func:`softseq_ros.parallel.run_jobs`: local processes or a Dask scheduler).
3. **Interpolation** (:mod:`.design_interpolation`). Between grid points a segment's curve is
   interpolated multilinearly at fixed fluid volume per unit cell (pressure, curvature, and
   the cell's rest volume, which is multilinear in the thicknesses and lengths itself); the
   segment is its cells times four times its membrane count. ``test_fem_design_search.py``
   checks it against direct FEM runs off the grid.
4. **Search.** The assembly of the two interpolated segments
   (:func:`softseq_ros.fem.assembly.pair_metrics`) is the inner model; scipy's differential
   evolution minimises the sum of squared errors over their tolerances, plus a penalty for a
   wrong sequence type or leader, for each material fit (:mod:`.design_evaluation`). Every
   design it evaluated that meets the target is kept; they are ranked by that sum.
5. **Verification.** The best design's two segments are run by FEM directly (unit cells at
   their exact parameters, same mesh), assembled and classified; the command says whether that
   meets the target.

The problem file and its checks: :mod:`.design_problem`; what the command prints and writes:
:mod:`.design_output`; the command itself: :mod:`.design_command`.
"""

from dataclasses import dataclass
from pathlib import Path
import time
from typing import Any, Callable

import numpy as np

from softseq_ros.fem.design_evaluation import MISMATCH_PENALTY, Evaluation, judge, predict
from softseq_ros.fem.design_grid import cell_design, ensure_tables, grid_axes, grid_designs
from softseq_ros.fem.design_interpolation import SegmentFamily
from softseq_ros.fem.design_problem import Problem
from softseq_ros.fem.design_reach import Reach, check_reach


@dataclass
class SearchResult:
    """What ``softseq design`` found."""

    problem: Problem
    ranked: list[Evaluation]
    evaluations: int
    fem_runs: int
    grid_tables: int
    verification: Evaluation | None
    verified: bool
    timings: dict[str, float]
    reach: Reach


def _vector_to_values(problem: Problem, x: np.ndarray) -> list[dict[str, float]]:
    values, i = [], 0
    for segment in problem.segments:
        current = {}
        for k in segment.varied:
            current[k] = float(x[i])
            i += 1
        values.append(current)
    return values


def _watcher(problem: Problem, evaluations: list[Evaluation], label: str,
             progress: Callable[[str], None] | None) -> Callable[[Any], bool]:
    """Differential evolution's callback: progress, and a stop once the target is well met."""
    generation = {'n': 0}

    def callback(intermediate_result: Any) -> bool:
        generation['n'] += 1
        met = sum(e.meets for e in evaluations)
        if progress is not None:
            progress(f'search ({label}): generation {generation["n"]}, best score '
                     f'{float(intermediate_result.fun):.3g}, {len(evaluations)} pairs '
                     f'assembled, {met} meet the target')
        # Enough designs meet the target and the best is well inside every tolerance.
        return float(intermediate_result.fun) < 0.05 and met >= problem.keep

    return callback


def search(problem: Problem, cache_dir: Path | None = None, workers: int = 1,
           scheduler: str | None = None, progress: Callable[[str], None] | None = None,
           verify: bool = True, announce: Callable[[str], None] | None = None
           ) -> SearchResult:
    """
    Reach, grid, interpolation, optimisation and verification (see the module notes).

    ``progress`` sees passing progress lines; ``announce`` the lines a user must read before
    the work they speak of starts (the corners to compute before the reach can be checked).
    """
    from scipy.optimize import differential_evolution

    timings: dict[str, float] = {}
    start = time.perf_counter()
    reach = check_reach(problem, cache_dir, workers, scheduler, progress, announce)
    timings['reach_s'] = time.perf_counter() - start

    start = time.perf_counter()
    grid = grid_designs(problem)
    paths, grid_runs = ensure_tables([d for *_, d in grid], cache_dir, workers, scheduler,
                                     progress, 'grid')
    timings['grid_s'] = time.perf_counter() - start

    families: dict[tuple[int, int], SegmentFamily] = {}
    for s, segment in enumerate(problem.segments):
        axes = grid_axes(problem, segment)
        for m in range(len(problem.materials)):
            tables = {index: (paths[d.digest()], d) for s2, m2, index, d in grid
                      if s2 == s and m2 == m}
            families[(s, m)] = SegmentFamily.from_tables(segment, axes, tables)
            excess, where = families[(s, m)].ordering_violation()
            if excess > 0:
                note = (f'the premise fails on the grid of {segment.name} '
                        f'({problem.materials[m].law}): {where}, {excess:.0f} Pa beyond the '
                        'tolerance; the reach bounds may not hold')
                reach.notes.insert(0, note)
                if progress is not None:
                    progress(f'warning: {note}')

    bounds = [segment.ranges[k] for segment in problem.segments for k in segment.varied]
    evaluations: list[Evaluation] = []
    start = time.perf_counter()

    def evaluate(material: int, values: list[dict[str, float]]) -> Evaluation:
        segments = [families[(s, material)].build(v) for s, v in enumerate(values)]
        try:
            metrics = predict(problem.target, segments)
        except Exception as err:  # noqa: BLE001 (a pair the assembly cannot solve: no design)
            return Evaluation(material, values, {'error': str(err)}, 10 * MISMATCH_PENALTY,
                              False)
        score, meets, errors = judge(problem.target, metrics, metrics['sequence'])
        evaluation = Evaluation(material, values, metrics, score, meets, errors)
        evaluations.append(evaluation)
        return evaluation

    for m, material in enumerate(problem.materials):
        label = f'{material.law} ' + ', '.join(f'{k} {v:g}' for k, v in material.params.items())
        if not bounds:
            evaluate(m, [{} for _ in problem.segments])
            continue
        def objective(x: np.ndarray, m: int = m) -> float:
            return evaluate(m, _vector_to_values(problem, x)).score

        differential_evolution(objective, bounds, seed=problem.seed + m,
                               popsize=problem.population, maxiter=problem.generations,
                               init='sobol', polish=False, tol=0.0, atol=0.0,
                               callback=_watcher(problem, evaluations, label, progress),
                               updating='immediate')
    timings['search_s'] = time.perf_counter() - start

    ranked: list[Evaluation] = []
    seen = set()
    for evaluation in sorted((e for e in evaluations if e.meets), key=lambda e: e.score):
        key = (evaluation.material, tuple(round(v, 7) for values in evaluation.values
                                          for v in values.values()))
        if key not in seen:
            seen.add(key)
            ranked.append(evaluation)
        if len(ranked) == problem.keep:
            break

    verification, verified, verify_runs = None, False, 0
    start = time.perf_counter()
    candidate = ranked[0] if ranked else (min(evaluations, key=lambda e: e.score)
                                          if evaluations else None)
    if verify and candidate is not None:
        designs = [cell_design(problem, segment, problem.materials[candidate.material],
                               candidate.values[s])
                   for s, segment in enumerate(problem.segments)]
        direct, verify_runs = ensure_tables(designs, cache_dir, workers, scheduler, progress,
                                            'verification')
        from softseq_ros.scene.tables import read_table

        segments = [read_table(direct[d.digest()], name=segment.name,
                               length=d.geometry.length_m)
                    for d, segment in zip(designs, problem.segments)]
        metrics = predict(problem.target, segments, full=True)
        score, meets, errors = judge(problem.target, metrics, metrics['sequence'])
        verification = Evaluation(candidate.material, candidate.values, metrics, score, meets,
                                  errors)
        verified = meets
    timings['verify_s'] = time.perf_counter() - start
    return SearchResult(problem=problem, ranked=ranked, evaluations=len(evaluations),
                        fem_runs=reach.fem_runs + grid_runs + verify_runs,
                        grid_tables=len(grid), verification=verification, verified=verified,
                        timings=timings, reach=reach)


