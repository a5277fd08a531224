"""
Segment tables from CSV files: the header ``volume_m3,pressure_pa,curvature_per_m``, SI units.

The one place that reads a table file into a :class:`TabulatedSegment` (scenes, the library,
the FEM's own tables alike), and a measured inflation into an
:class:`~softseq_ros.segments.fit.Inflation` (``softseq fit``); a table that looks like it is
in mL or kPa, or holds pressures beyond any material, is refused with the fix
(softseq_ros.scene.plausibility).
"""

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from softseq_ros.scene.csv_columns import read_columns
from softseq_ros.scene.plausibility import (
    MAX_PRESSURE_PA,
    MAX_VOLUME_M3,
    ML_HINT,
    rising_problem,
    small_pressure_problem,
    volume_problem,
)
from softseq_ros.segments.models import TableError, TabulatedSegment

if TYPE_CHECKING:
    # For the annotation only: the fit pulls in more of scipy than a scene needs.
    from softseq_ros.segments.fit import Cycle, Inflation

TABLE_COLUMNS = ('volume_m3', 'pressure_pa', 'curvature_per_m')
INFLATION_COLUMNS = ('volume_m3', 'pressure_pa')


def _check_units(path: Path, volumes: NDArray[np.float64], pressures: NDArray[np.float64],
                 length: float | None) -> None:
    """
    Refuse a table whose numbers no soft segment has in SI units, naming the likely fix.

    ``length`` [m]: the segment's, which bounds its volume; None: 1 m^3 bounds it.
    """
    if volumes.size < 2:
        return   # too few rows: the segment says so
    largest_volume = float(np.max(volumes))
    if length is not None:
        problem = volume_problem(largest_volume, length)
    elif largest_volume > MAX_VOLUME_M3:
        problem = f'the largest volume is {largest_volume:.6g} m^3, more than 1 m^3: {ML_HINT}'
    else:
        problem = None
    if problem is not None:
        raise TableError(f'{path}: column volume_m3: {problem}')
    largest = float(np.max(np.abs(pressures)))
    if largest > MAX_PRESSURE_PA:
        raise TableError(f'{path}: column pressure_pa: a pressure of {largest:.3g} Pa is beyond '
                         f'{MAX_PRESSURE_PA:.0e} Pa: no soft segment holds a GPa; pressures are '
                         'gauge, in Pa')
    problem = small_pressure_problem(pressures)
    if problem is not None:
        raise TableError(f'{path}: column pressure_pa: {problem}')


def read_table(path: str | Path, name: str | None = None, length: float | None = None,
               design: dict[str, object] | None = None) -> TabulatedSegment:
    """
    A segment from a table with header volume_m3,pressure_pa,curvature_per_m.

    ``design``: the identity of the segment design whose FEM table this is (see
    :attr:`TabulatedSegment.design`), when it is one.
    """
    path = Path(path)
    columns = read_columns(path, TABLE_COLUMNS, TableError, 'segment table')
    if length is None:
        raise TableError(f'{path}: the segment length must be given (m)')
    # Before the curves are built: a table in other units, or one beyond any material, makes
    # no sense to interpolate (pressures of 1e300 overflow its energy).
    _check_units(path, columns['volume_m3'], columns['pressure_pa'], length)
    segment = TabulatedSegment(name or path.stem, length, columns['volume_m3'],
                               columns['pressure_pa'], columns['curvature_per_m'],
                               source=str(path))
    problem = rising_problem(segment)
    if problem is not None:
        raise TableError(f'{path}: column pressure_pa: {problem}')
    segment.design = design
    return segment


def read_inflation(path: str | Path, length: float | None = None) -> 'Inflation':
    """
    One measured inflation of a segment, from a CSV file with the header volume_m3,pressure_pa.

    More columns and ``#`` comment lines are allowed; rows in rising volume (the segment's
    whole volume), gauge pressures, SI units. ``length`` [m]: the segment's, when known, for
    the check of the volumes' unit. The rows are kept as read: the fit estimates the noise
    from them.
    """
    from softseq_ros.segments.fit import Inflation

    path = Path(path)
    columns = read_columns(path, INFLATION_COLUMNS, TableError, 'measured inflation')
    _check_units(path, columns['volume_m3'], columns['pressure_pa'], length)
    return Inflation(columns['volume_m3'], columns['pressure_pa'], source=str(path))


def read_cycle(path: str | Path, length: float | None = None) -> 'Cycle':
    """
    One measured cycle of a segment: an inflation, and its deflation when the volume falls.

    The file is :func:`read_inflation`'s; rows whose volume rises to the end are an inflation
    alone, rows whose volume rises and then falls are an inflation up to the largest volume
    and a deflation from it (:func:`~softseq_ros.segments.fit.split_cycle`). A
    ``curvature_per_m`` column, where there is one, stays with its rows: not fitted, carried
    into the cleaned table.
    """
    from softseq_ros.segments.fit import split_cycle

    path = Path(path)
    columns = read_columns(path, INFLATION_COLUMNS, TableError, 'measured inflation',
                           optional=('curvature_per_m',))
    _check_units(path, columns['volume_m3'], columns['pressure_pa'], length)
    return split_cycle(columns['volume_m3'], columns['pressure_pa'], source=str(path),
                       curvature=columns.get('curvature_per_m'))
