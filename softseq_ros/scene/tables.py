"""
Segment tables from CSV files: the header ``volume_m3,pressure_pa,curvature_per_m``, SI units.

The one place that reads a table file into a :class:`TabulatedSegment` (scenes, the library,
the FEM's own tables alike); a table that looks like it is in mL or kPa is refused with the fix.
"""

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from softseq_ros.scene.csv_columns import read_columns
from softseq_ros.segments.models import TableError, TabulatedSegment

TABLE_COLUMNS = ('volume_m3', 'pressure_pa', 'curvature_per_m')

# Beyond these a table is almost surely in other units: a segment holding more than a cubic
# metre of fluid, or one whose pressures all stay within a pascal of zero.
MAX_PLAUSIBLE_VOLUME_M3 = 1.0
MIN_PLAUSIBLE_PRESSURE_PA = 1.0


def _check_si(path: Path, volumes: NDArray[np.float64], pressures: NDArray[np.float64]) -> None:
    """Refuse a table whose numbers are implausible in SI units, naming the likely fix."""
    if volumes.size and volumes[0] > MAX_PLAUSIBLE_VOLUME_M3:
        raise TableError(f'{path}: column volume_m3: the rest volume is {volumes[0]:.6g} m^3, '
                         f'more than {MAX_PLAUSIBLE_VOLUME_M3:g} m^3: is the table in mL? '
                         'Volumes are in m^3 (1 mL = 1e-6 m^3)')
    if pressures.size and np.max(np.abs(pressures)) < MIN_PLAUSIBLE_PRESSURE_PA:
        raise TableError(f'{path}: column pressure_pa: every pressure is within '
                         f'{MIN_PLAUSIBLE_PRESSURE_PA:g} Pa of zero: is the table in kPa or MPa? '
                         'Pressures are gauge, in Pa (1 kPa = 1000 Pa)')


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
    segment = TabulatedSegment(name or path.stem, length, columns['volume_m3'],
                               columns['pressure_pa'], columns['curvature_per_m'],
                               source=str(path))
    _check_si(path, segment.volumes, segment.pressures)
    segment.design = design
    return segment
