"""
A segment between the grid points: its unit-cell curves interpolated multilinearly.

At fixed fluid volume per unit cell the pressure, the curvature and the cell's rest volume
(which is multilinear in the thicknesses and lengths itself) are interpolated; the segment is
its cells times four times its membrane count. ``test_fem_design_search.py`` checks it against
direct FEM runs off the grid.
"""

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from softseq_ros.fem.design_problem import SegmentSpace
from softseq_ros.scene.design import Design

# Volume samples per unit-cell curve when it is interpolated.
CURVE_SAMPLES = 241


def membrane_count(design: Design, values: dict[str, float]) -> int:
    """How many membranes a segment of this design has at these parameter values."""
    g = design.geometry
    length = values.get('membrane_length_m', g.membrane_length_m)
    return max(1, round(g.length_m / (g.wall_length_m + length)))


def read_cell(path: Path, design: Design) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """A unit-cell table as (cell rest volume, cell injected volumes, pressures, curvatures)."""
    from softseq_ros.scene.tables import read_table

    table = read_table(path, name='cell', length=design.geometry.length_m)
    factor = 4.0 * design.geometry.membranes
    volumes = table.volumes / factor
    return volumes[0], volumes - volumes[0], table.pressures, table.curvatures


@dataclass
class SegmentFamily:
    """A segment's unit-cell curves over its parameter grid (one material), interpolated."""

    segment: SegmentSpace
    axes: dict[str, np.ndarray]
    rest: Any        # interpolant of the cell's rest volume
    curves: Any      # interpolant of (pressures, curvatures) at the cell volumes ``cell_u``
    cell_u: np.ndarray
    pressures: np.ndarray | None = None   # the grid's pressures at ``cell_u`` (grid, samples)

    @classmethod
    def from_tables(cls, segment: SegmentSpace, axes: dict[str, np.ndarray],
                    tables: dict[tuple[int, ...], tuple[Path, Design]]) -> 'SegmentFamily':
        """Build from the grid's tables (index -> (path, design))."""
        from scipy.interpolate import RegularGridInterpolator

        cells = {index: read_cell(path, design) for index, (path, design) in tables.items()}
        reach = min(u[-1] for _, u, _, _ in cells.values())
        cell_u = np.linspace(0.0, reach, CURVE_SAMPLES)
        shape = tuple(len(v) for v in axes.values())
        rest = np.zeros(shape)
        curves = np.zeros(shape + (2 * CURVE_SAMPLES,))
        for index, (v0, u, p, k) in cells.items():
            rest[index] = v0
            curves[index] = np.concatenate([np.interp(cell_u, u, p), np.interp(cell_u, u, k)])
        pressures = curves[..., :CURVE_SAMPLES]
        if not shape:   # nothing varied: one table
            return cls(segment, axes, lambda x: np.array([rest]),
                       lambda x: curves[None, :], cell_u, pressures)
        grid = tuple(axes.values())
        return cls(segment, axes, RegularGridInterpolator(grid, rest),
                   RegularGridInterpolator(grid, curves), cell_u, pressures)

    def ordering_violation(self) -> tuple[float, str]:
        """
        The largest step against the reach's premise on this grid [Pa] (0 if none), and where.

        The premise: at each cell volume the pressure rises with every thickness and falls
        with the membrane length, from grid point to grid point (beyond the tolerance).
        """
        from softseq_ros.fem.bounds import PREMISE_TOLERANCE_PA, PREMISE_TOLERANCE_SHARE

        worst, where = 0.0, ''
        if self.pressures is None:
            return worst, where
        for axis, key in enumerate(self.axes):
            step = np.diff(self.pressures, axis=axis)
            against = step if key == 'membrane_length_m' else -step
            level = np.abs(np.take(self.pressures, range(step.shape[axis]), axis=axis))
            excess = against - np.maximum(PREMISE_TOLERANCE_PA, PREMISE_TOLERANCE_SHARE * level)
            index = np.unravel_index(int(np.argmax(excess)), excess.shape)
            if excess[index] > worst:
                worst = float(excess[index])
                where = (f'{key} {self.axes[key][index[axis]]:g} -> '
                         f'{self.axes[key][index[axis] + 1]:g} at '
                         f'{self.cell_u[index[-1]] * 1e9:.0f} uL per cell')
        return worst, where

    def build(self, values: dict[str, float], name: str | None = None) -> Any:
        """The interpolated segment (a TabulatedSegment) at these parameter values."""
        from softseq_ros.segments.models import TabulatedSegment

        point = np.array([[values[k] for k in self.axes]]) if self.axes else None
        rest = float(self.rest(point)[0])
        curves = self.curves(point)[0]
        factor = 4.0 * membrane_count(self.segment.design, values)
        n = self.cell_u.size
        return TabulatedSegment(name or self.segment.name, self.segment.design.geometry.length_m,
                                factor * (rest + self.cell_u), curves[:n], curves[n:],
                                source=f'interpolated {self.segment.name}')
