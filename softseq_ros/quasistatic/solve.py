"""
From a scene to its inflation sequence: the solver as a researcher calls it.

This is the one place that turns a scene into an :class:`EquilibriumMap` (:func:`scene_map`:
the API, the command line, the rig's model seam and the analysis configure the solver the same
way and share one map per process) and that reads and writes the volume-history CSV files of
``softseq solve``.
"""

from collections import OrderedDict
from pathlib import Path
from typing import TYPE_CHECKING, Sequence

import numpy as np
from numpy.typing import NDArray

from softseq_ros.errors import UserError
from softseq_ros.quasistatic.equilibrium import EquilibriumMap, SolvedPath
from softseq_ros.quasistatic.graph import TransitionGraph, transition_graph
from softseq_ros.quasistatic.regulator import RegulatedPath
from softseq_ros.scene.csv_columns import read_columns, write_rows
from softseq_ros.segments.identity import segments_sha256
from softseq_ros.segments.models import Segment

if TYPE_CHECKING:
    from softseq_ros.scene.loader import Scene

INJECTED_COLUMN = 'injected_m3'
TIME_COLUMN = 'time_s'


class HistoryError(UserError):
    """A volume-history file that cannot be used; the message starts with the file name."""


# The maps a process keeps: enough for the rigs of a few scenes side by side, bounded so that a
# notebook running many scenes one after another does not keep them all.
SHARED_MAPS = 8
_MAPS: OrderedDict[tuple[str, int | None], EquilibriumMap] = OrderedDict()


def equilibrium_map(segments: Sequence[Segment], resolution: int | None = None,
                    supply: Segment | None = None) -> EquilibriumMap:
    """
    The equilibrium map of these segments at this resolution (``None``: the default).

    With a ``supply`` line as one more member (softseq_ros.segments.supply). Assembled once
    per process (the same segments and line by their digest): it is the expensive part, and it
    holds no actuator's state. The :data:`SHARED_MAPS` most recently used are kept.
    """
    key = (segments_sha256(segments), resolution,
           None if supply is None else segments_sha256([supply]))
    emap = _MAPS.get(key)
    if emap is None:
        emap = (EquilibriumMap(segments, supply=supply) if resolution is None
                else EquilibriumMap(segments, resolution=resolution, supply=supply))
        _MAPS[key] = emap
        while len(_MAPS) > SHARED_MAPS:
            _MAPS.popitem(last=False)
    else:
        _MAPS.move_to_end(key)
    return emap


def scene_map(scene: 'Scene') -> EquilibriumMap:
    """The equilibrium map of a scene's segments at the scene's solver resolution."""
    return equilibrium_map(scene.segments, scene.solver.resolution, scene.supply)


def segments_graph(segments: Sequence[Segment], resolution: int | None = None,
                   supply: Segment | None = None) -> TransitionGraph:
    """
    The transition graph of these segments, on the process's shared :func:`equilibrium_map`.

    What a scene is loaded with (``load_scene(path, segments_graph)``) to find the branch its
    ``pump.start_branch`` names, numbered as ``softseq graph`` numbers them.
    """
    return transition_graph(equilibrium_map(segments, resolution, supply))


def read_history(path: str | Path) -> NDArray[np.float64]:
    """Commanded injected volumes, in order, from the ``injected_m3`` column of a CSV file."""
    return read_timed_history(path)[1]


def read_timed_history(path: str | Path) -> tuple[NDArray[np.float64] | None, NDArray[np.float64]]:
    """
    The ``time_s`` column [s] when the file has one (else None) and the ``injected_m3`` column.

    A history in time is what a dynamic scene follows as it is, holds included
    (softseq_ros.dynamic.path.timed_history_schedule says what it must be).
    """
    columns = read_columns(path, (INJECTED_COLUMN,), HistoryError, 'volume history',
                           optional=(TIME_COLUMN,))
    return columns.get(TIME_COLUMN), columns[INJECTED_COLUMN]


def path_columns(names: Sequence[str]) -> list[str]:
    """Column names of a solved-path CSV for segments ``names`` (base to tip)."""
    return (['injected_m3', 'pressure_pa'] + [f'volume_{n}_m3' for n in names]
            + [f'curvature_{n}_per_m' for n in names] + ['event'])


def write_path(path: str | Path, solved: SolvedPath, names: Sequence[str]) -> None:
    """Write one row per commanded volume: injected, pressure, volumes, curvatures, event."""
    write_rows(path, path_columns(names), (
        ((solved.injected[i], solved.pressure[i], *solved.volumes[i], *solved.curvatures[i]),
         'snap' if solved.snap[i] else '') for i in range(solved.injected.size)))


GAUGE_COLUMN = 'gauge_pa'


def read_pressure_history(path: str | Path) -> NDArray[np.float64]:
    """Regulated gauge pressures [Pa], in order, from the ``gauge_pa`` column of a CSV file."""
    return read_columns(path, (GAUGE_COLUMN,), HistoryError, 'pressure history',
                        optional=(TIME_COLUMN,))[GAUGE_COLUMN]


def regulated_columns(names: Sequence[str], timed: bool = False) -> list[str]:
    """Column names of a regulated-path CSV for segments ``names``; ``timed``: time first."""
    return ((['time_s'] if timed else []) + [GAUGE_COLUMN, 'injected_m3']
            + [f'volume_{n}_m3' for n in names]
            + [f'curvature_{n}_per_m' for n in names] + ['event'])


def write_regulated_path(path: str | Path, solved: RegulatedPath,
                         names: Sequence[str]) -> None:
    """One row per regulated pressure: gauge, let in, volumes, curvatures, the flips on the way."""
    flipped: dict[int, list[str]] = {}
    for flip in solved.flips:
        flipped.setdefault(flip.row, []).append(f'flip {names[flip.segment]}')
    injected = solved.injected
    timed = solved.time_s is not None
    times = solved.time_s if timed else np.empty((solved.pressure.size, 0))
    write_rows(path, regulated_columns(names, timed), (
        ((*np.atleast_1d(times[i]), solved.pressure[i], injected[i], *solved.volumes[i],
          *solved.curvatures[i]), ' '.join(flipped.get(i, ())))
        for i in range(solved.pressure.size)))
