"""
Sweeps over design parameters: every combination of the given values, run in parallel.

Locally the designs run in worker processes (one per core by default); given a Dask scheduler
address they run on that cluster's workers instead (``distributed``), for studies that outgrow
one machine (both through :func:`softseq_ros.parallel.run_jobs`). A worker returns its table
as text, so workers need no shared file system; the tables land in one folder, each as soon as
it is done, with a ``summary.csv`` of one row per design.
"""

import csv
from dataclasses import dataclass
import itertools
import os
from pathlib import Path
import re
import tempfile
from typing import Any, Callable

from softseq_ros.parallel import run_jobs
from softseq_ros.scene.design import Design, DesignError, with_changes

SUMMARY_COLUMNS = ('table', 'design', 'parameters', 'peak_pressure_pa', 'peak_injected_m3',
                   'final_pressure_pa', 'final_injected_m3', 'final_curvature_per_m',
                   'contact', 'stop_reason', 'dofs', 'newton_iterations', 'wall_s')


@dataclass(frozen=True)
class SweepCase:
    """One design of a sweep and the parameter values that made it."""

    label: str
    changes: dict[str, Any]
    design: Design


def _label_value(value: Any) -> str:
    text = f'{value:g}' if isinstance(value, float) else str(value)
    return re.sub(r'[^A-Za-z0-9.+-]', '_', text)


def sweep_cases(base: Design, grid: dict[str, list[Any]]) -> list[SweepCase]:
    """Every combination of ``grid`` (dotted key -> values) applied to ``base``; checked now."""
    if not grid:
        raise DesignError(f'{base.path or "<design>"}: --sweep: give at least one KEY=V1,V2,...')
    keys = list(grid)
    cases = []
    for values in itertools.product(*(grid[key] for key in keys)):
        changes = dict(zip(keys, values))
        design = with_changes(base, changes)
        label = base.name + ''.join(f'__{key.split(".")[-1]}={_label_value(v)}'
                                    for key, v in changes.items())
        cases.append(SweepCase(label=label, changes=changes, design=design))
    return cases


def run_case(case: SweepCase) -> tuple[dict[str, Any], str]:
    """Run one case (in a worker): its summary row and its table's text."""
    from softseq_ros.fem.table import run_design, write_table

    os.environ.setdefault('OMP_NUM_THREADS', '1')
    result = run_design(case.design)
    with tempfile.TemporaryDirectory() as folder:
        path = write_table(result, Path(folder) / f'{case.label}.csv')
        text = path.read_text()
    peak_p, peak_v = result.peak
    row = {'table': f'{case.label}.csv', 'design': case.design.name,
           'parameters': ';'.join(f'{k}={v}' for k, v in case.changes.items()),
           'peak_pressure_pa': peak_p, 'peak_injected_m3': peak_v,
           'final_pressure_pa': float(result.pressures[-1]),
           'final_injected_m3': float(result.injected[-1]),
           'final_curvature_per_m': float(result.curvatures[-1]),
           'contact': result.contact, 'stop_reason': result.stop_reason, 'dofs': result.dofs,
           'newton_iterations': result.newton_iterations, 'wall_s': round(result.wall_s, 2)}
    return row, text


def _case_name(case: SweepCase) -> str:
    return f'design {case.label}'


def run_sweep(cases: list[SweepCase], out_dir: Path, workers: int = 1,
              scheduler: str | None = None,
              progress: Callable[[str], None] | None = None) -> Path:
    """Run the cases locally on ``workers`` processes or on a Dask scheduler; summary path."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)

    def collect(done: int, total: int, result: tuple[dict[str, Any], str]) -> None:
        row, text = result
        (out_dir / row['table']).write_text(text)
        if progress is not None:
            progress(f'{done}/{total} {row["table"]}: peak '
                     f'{row["peak_pressure_pa"] / 1e3:.3f} kPa, {row["wall_s"]:.1f} s')

    if scheduler is not None:
        results = run_jobs(run_case, cases, backend='dask', scheduler=scheduler,
                           progress=collect, name=_case_name)
    else:
        results = run_jobs(run_case, cases, workers=workers, backend='processes',
                           progress=collect, name=_case_name)
    rows = [row for row, _ in results]
    summary = out_dir / 'summary.csv'
    with summary.open('w', newline='') as handle:
        handle.write('# One row per design of the sweep; SI units, gauge pressures.\n')
        writer = csv.DictWriter(handle, fieldnames=SUMMARY_COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    return summary
