"""
From a scene to its inflation sequence: the solver as a researcher calls it.

This is the one place that turns a scene into an :class:`EquilibriumMap` (so the command line, the
nodes and the batch runner configure the solver the same way) and that reads and writes the
volume-history CSV files of ``softseq solve``.
"""

import csv
import math
from pathlib import Path
from typing import Sequence

import numpy as np
from numpy.typing import NDArray

from softseq_ros.physics.equilibrium import EquilibriumMap
from softseq_ros.physics.equilibrium import Path as SolvedPath
from softseq_ros.physics.segments import Segment

INJECTED_COLUMN = 'injected_m3'


class HistoryError(ValueError):
    """A volume-history file that cannot be used; the message starts with the file name."""


def build_map(segments: Sequence[Segment], resolution: int | None = None) -> EquilibriumMap:
    """Assemble the equilibrium set of a scene's segments (``None`` keeps the default)."""
    if resolution is None:
        return EquilibriumMap(segments)
    return EquilibriumMap(segments, resolution=resolution)


def read_history(path: str | Path) -> NDArray[np.float64]:
    """Commanded injected volumes, in order, from the ``injected_m3`` column of a CSV file."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as err:
        raise HistoryError(f'{path}: cannot read the volume history ({err.strerror})') from None
    lines = [line for line in text.splitlines()
             if line.strip() and not line.lstrip().startswith('#')]
    if not lines:
        raise HistoryError(f'{path}: empty file, expected a header with {INJECTED_COLUMN}')
    reader = csv.reader(lines)
    header = [h.strip() for h in next(reader)]
    if INJECTED_COLUMN not in header:
        raise HistoryError(f'{path}: no column {INJECTED_COLUMN} in the header '
                           f'({",".join(header)})')
    column = header.index(INJECTED_COLUMN)
    values = []
    for row_number, row in enumerate(reader, start=1):
        cell = row[column].strip() if column < len(row) else ''
        try:
            value = float(cell)
        except ValueError:
            raise HistoryError(f'{path}: row {row_number}, column {INJECTED_COLUMN}: not a '
                               f'number: {cell!r}') from None
        if not math.isfinite(value):
            raise HistoryError(f'{path}: row {row_number}, column {INJECTED_COLUMN}: must be '
                               f'finite, got {cell}')
        values.append(value)
    if not values:
        raise HistoryError(f'{path}: no rows below the header')
    return np.asarray(values)


def path_columns(names: Sequence[str]) -> list[str]:
    """Column names of a solved-path CSV for segments ``names`` (base to tip)."""
    return (['injected_m3', 'pressure_pa'] + [f'volume_{n}_m3' for n in names]
            + [f'curvature_{n}_per_m' for n in names] + ['event'])


def write_path(path: str | Path, solved: SolvedPath, names: Sequence[str]) -> None:
    """Write one row per commanded volume: injected, pressure, volumes, curvatures, event."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open('w', newline='') as handle:
        writer = csv.writer(handle)
        writer.writerow(path_columns(names))
        for i in range(solved.injected.size):
            writer.writerow([repr(float(solved.injected[i])), repr(float(solved.pressure[i])),
                             *(repr(float(x)) for x in solved.volumes[i]),
                             *(repr(float(x)) for x in solved.curvatures[i]),
                             'snap' if solved.snap[i] else ''])
