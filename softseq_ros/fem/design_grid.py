"""
The search's unit cells: the grid and corner designs of a problem, and their cached tables.

Unit-cell FEM tables on a coarse grid of each segment's varied parameters and material fits,
cached by their design hash, run on the shared executor
(:func:`softseq_ros.parallel.run_jobs`: local processes or a Dask scheduler). The corners
(each segment's softest and stiffest design) are grid points all.
"""

from dataclasses import replace
import itertools
from pathlib import Path
from typing import Callable

import numpy as np

from softseq_ros.fem.design_problem import Problem, SegmentSpace
from softseq_ros.scene.design import Design, Material, cache_path, with_changes


def cell_design(problem: Problem, segment: SegmentSpace, material: Material,
                values: dict[str, float]) -> Design:
    """The unit-cell design of a segment at these parameter values, on the search's mesh."""
    base = replace(segment.design, material=material)
    changes = {f'geometry.{k}': float(v) for k, v in values.items()}
    changes.update({'mesh.model': 'unit_cell', 'mesh.element_size_m': problem.element_size_m,
                    'mesh.thin_layer_cells': problem.thin_layer_cells,
                    'volume.max_injected_m3': problem.target.max_injected_m3})
    return with_changes(base, changes)


def grid_axes(problem: Problem, segment: SegmentSpace) -> dict[str, np.ndarray]:
    """Grid values of each varied parameter of a segment."""
    return {k: np.linspace(*segment.ranges[k], problem.points) for k in segment.varied}


def grid_designs(problem: Problem) -> list[tuple[int, int, tuple[int, ...], Design]]:
    """Every grid point: (segment index, material index, grid index, unit-cell design)."""
    out = []
    for s, segment in enumerate(problem.segments):
        axes = grid_axes(problem, segment)
        for m, material in enumerate(problem.materials):
            for index in itertools.product(*(range(len(v)) for v in axes.values())):
                values = {k: axes[k][i] for k, i in zip(axes, index)}
                out.append((s, m, index, cell_design(problem, segment, material, values)))
    return out


def corner_values(segment: SegmentSpace, which: str) -> dict[str, float]:
    """A segment's ``soft`` or ``stiff`` corner (thicker membranes and walls stiffen)."""
    values = {}
    for k in segment.varied:
        lo, hi = segment.ranges[k]
        stiff = (which == 'stiff') != (k == 'membrane_length_m')
        values[k] = hi if stiff else lo
    return values


def corner_designs(problem: Problem) -> list[tuple[int, int, str, Design]]:
    """
    Each segment's soft and stiff corner, per material: (segment, material, which, design).

    Grid points all (the grid spans each range), so the search reuses their tables.
    """
    return [(s, m, which, cell_design(problem, segment, material, corner_values(segment, which)))
            for s, segment in enumerate(problem.segments)
            for m, material in enumerate(problem.materials) for which in ('soft', 'stiff')]


def grid_table_job(design: Design) -> str:
    """Run one unit cell (in a worker): its table's text."""
    import os
    import tempfile

    from softseq_ros.fem.table import run_design, write_table

    os.environ.setdefault('OMP_NUM_THREADS', '1')
    result = run_design(design)
    with tempfile.TemporaryDirectory() as folder:
        return write_table(result, Path(folder) / 'table.csv').read_text()


def ensure_tables(designs: list[Design], cache_dir: Path | None, workers: int,
                  scheduler: str | None, progress: Callable[[str], None] | None,
                  what: str) -> tuple[dict[str, Path], int]:
    """The cached table of every design, computing the missing ones; (paths, FEM runs)."""
    from softseq_ros.parallel import run_jobs

    paths = {d.digest(): cache_path(d, cache_dir) for d in designs}
    missing = {d.digest(): d for d in designs if not paths[d.digest()].is_file()}
    todo = list(missing.values())
    if todo:
        def on_done(done: int, total: int, text: str) -> None:
            if progress is not None:
                progress(f'{what}: {done}/{total} unit-cell tables computed')

        texts = run_jobs(grid_table_job, todo, workers=workers,
                         backend='dask' if scheduler else 'processes', scheduler=scheduler,
                         progress=on_done, name=lambda d: f'design {d.name} ({d.digest()})')
        for design, text in zip(todo, texts):
            path = paths[design.digest()]
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_suffix('.csv.tmp')
            tmp.write_text(text)
            tmp.replace(path)
    elif progress is not None:
        progress(f'{what}: {len(designs)} unit-cell tables from the cache')
    return paths, len(todo)
