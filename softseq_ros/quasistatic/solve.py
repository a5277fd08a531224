"""
From a scene to its inflation sequence: the solver as a researcher calls it.

This is the one place that turns a scene into an :class:`EquilibriumMap` (so the command line, the
nodes and the batch runner configure the solver the same way) and that reads and writes the
volume-history CSV files of ``softseq solve``.
"""

from pathlib import Path
from typing import Sequence

import numpy as np
from numpy.typing import NDArray

from softseq_ros.errors import UserError
from softseq_ros.quasistatic.equilibrium import EquilibriumMap, SolvedPath
from softseq_ros.scene.csv_columns import read_columns, write_rows
from softseq_ros.segments.models import Segment

INJECTED_COLUMN = 'injected_m3'


class HistoryError(UserError):
    """A volume-history file that cannot be used; the message starts with the file name."""


def build_map(segments: Sequence[Segment], resolution: int | None = None) -> EquilibriumMap:
    """Assemble the equilibrium set of a scene's segments (``None`` keeps the default)."""
    if resolution is None:
        return EquilibriumMap(segments)
    return EquilibriumMap(segments, resolution=resolution)


def read_history(path: str | Path) -> NDArray[np.float64]:
    """Commanded injected volumes, in order, from the ``injected_m3`` column of a CSV file."""
    return read_columns(path, (INJECTED_COLUMN,), HistoryError, 'volume history')[
        INJECTED_COLUMN]


def path_columns(names: Sequence[str]) -> list[str]:
    """Column names of a solved-path CSV for segments ``names`` (base to tip)."""
    return (['injected_m3', 'pressure_pa'] + [f'volume_{n}_m3' for n in names]
            + [f'curvature_{n}_per_m' for n in names] + ['event'])


def write_path(path: str | Path, solved: SolvedPath, names: Sequence[str]) -> None:
    """Write one row per commanded volume: injected, pressure, volumes, curvatures, event."""
    write_rows(path, path_columns(names), (
        ((solved.injected[i], solved.pressure[i], *solved.volumes[i], *solved.curvatures[i]),
         'snap' if solved.snap[i] else '') for i in range(solved.injected.size)))
