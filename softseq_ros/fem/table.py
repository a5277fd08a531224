"""
From a segment design to a segment table: run the FEM, write the CSV, cache it by its hash.

The table has the columns scenes read (``volume_m3, pressure_pa, curvature_per_m``: the whole
segment's fluid volume, gauge pressure, curvature of the beam) plus ``injected_m3`` and, for a
unit cell, ``cut_curvature_per_m`` (from the turning of the mid-wall cut, a check of the fitted
curvature). The comment lines say where every number comes from.
"""

from dataclasses import dataclass, field
from pathlib import Path
import shutil
import sys
import time
from typing import Callable, TextIO

import numpy as np

from softseq_ros.progress import end_progress, write_progress
from softseq_ros.scene.design import FEM_CODE_VERSION, Design, cache_path

COLUMNS = ('volume_m3', 'pressure_pa', 'curvature_per_m', 'injected_m3', 'cut_curvature_per_m')


@dataclass
class FemResult:
    """A finished FEM run of one design."""

    design: Design
    volumes: np.ndarray
    pressures: np.ndarray
    curvatures: np.ndarray
    cut_curvatures: np.ndarray
    stop_reason: str
    contact: bool
    dofs: int
    cells: int
    points: int
    newton_iterations: int
    wall_s: float
    # Snap-throughs at constant volume: (row, the membrane that bulged, by how much [m]), the
    # row being the first state after it.
    snaps: list[tuple[int, int, float]] = field(default_factory=list)
    # The largest last Newton correction of the pressure over the rows [Pa]: a bound of the
    # solver's scatter, which the table declares as its noise (the mesh's error is smooth).
    solver_noise_pa: float = 0.0

    @property
    def injected(self) -> np.ndarray:
        """Fluid injected into the segment [m^3]."""
        return self.volumes - self.volumes[0]

    @property
    def peak(self) -> tuple[float, float]:
        """Largest pressure [Pa] and the injected volume [m^3] where it is reached."""
        index = int(np.argmax(self.pressures))
        return float(self.pressures[index]), float(self.injected[index])


def run_design(design: Design, progress: Callable[[str], None] | None = None) -> FemResult:
    """Inflate a design's segment under volume control and collect its table."""
    from softseq_ros.fem.segment import build_segment

    start = time.perf_counter()
    segment = build_segment(design)
    model = segment.model
    factor = segment.volume_factor
    rows: list[tuple[float, float, float, float]] = []
    corrections: list[float] = []
    heights: list[np.ndarray] = []
    contact = {'hit': False}
    pitch = design.geometry.pitch_m

    def on_state(state: object) -> str | None:
        x = model.positions(state.q)
        if segment.contact(x, state.q):
            contact['hit'] = True
            return (f'stopped where neighbouring membranes touch, before '
                    f'{(state.volume - model.rest_volume) * factor * 1e6:.2f} mL injected '
                    f'(contact is not modelled)')
        cut = -2.0 * model.space.plane_angle(state.q) / pitch if model.space.has_plane else 0.0
        rows.append((state.volume * factor, state.pressure, segment.curvature(x), cut))
        corrections.append(state.pressure_correction)
        heights.append(segment.membrane_heights(x))
        if progress is not None:
            injected = (state.volume - model.rest_volume) * factor
            progress(f'{design.name}: {injected * 1e6:6.2f} mL injected, '
                     f'{state.pressure / 1e3:7.3f} kPa, curvature {rows[-1][2]:6.2f} 1/m '
                     f'({time.perf_counter() - start:5.1f} s)')
        return None

    def on_motion(q: np.ndarray) -> str | None:
        if segment.contact(model.positions(q), q):
            contact['hit'] = True
            return 'neighbouring membranes touch (contact is not modelled)'
        return None

    volume = design.volume
    result = model.ramp_volume(
        max_volume=model.rest_volume + volume.max_injected_m3 / factor,
        first_step=volume.first_step_m3 / factor, max_step=volume.max_step_m3 / factor,
        min_step=volume.first_step_m3 / factor / 256, on_state=on_state, on_motion=on_motion)
    data = np.array(rows)
    snaps = []
    for snap in result.snaps:
        if snap.index < len(rows):  # not the state where contact stopped the run
            growth = heights[snap.index] - heights[snap.index - 1]
            snaps.append((snap.index, int(np.argmax(growth)), float(np.max(growth))))
    stop_reason = result.stop_reason
    # Where, in the table's terms.
    reached = f'{(data[-1, 0] - data[0, 0]) * 1e6:.2f} mL injected'
    stop_reason = stop_reason.replace('the last state', reached).replace(
        'at the next volume', f'just beyond {reached}')
    return FemResult(design=design, volumes=data[:, 0], pressures=data[:, 1],
                     curvatures=data[:, 2], cut_curvatures=data[:, 3],
                     stop_reason=stop_reason, contact=contact['hit'], dofs=segment.dofs,
                     cells=segment.mesh.ncells, points=segment.mesh.npoints,
                     newton_iterations=result.newton_iterations,
                     wall_s=time.perf_counter() - start, snaps=snaps,
                     solver_noise_pa=max(corrections))


def _provenance(result: FemResult) -> list[str]:
    from importlib.metadata import version

    d = result.design
    g = d.geometry
    mm = 1e3
    params = ', '.join(f'{k} = {v}' for k, v in d.material.params.items())
    if g.wall_reading == 'skin_bands':
        walls = (f'walls read as skin bands: skin {g.skin_band_thickness_m * mm:g} mm thick '
                 f'between the membranes, side walls (w - g)/2 = '
                 f'{g.side_wall_thickness_m * mm:g} mm')
    else:
        walls = (f'walls read as side walls {g.side_wall_thickness_m * mm:g} mm thick; skin '
                 f'between membranes {g.skin_band_thickness_m * mm:g} mm')
    model = ('unit cell: half a pitch and half the width with mirror planes; the mid-wall '
             f'cut stays plane and turns; the segment is {g.membranes} such pitches (x 4 cells)'
             if d.mesh.model == 'unit_cell' else
             f'whole segment: {g.membranes} membranes between end caps of '
             f'{g.end_cap_length_m * mm:g} mm, half the width, base clamped')
    peak_p, peak_v = result.peak
    lines = [
        f'FEM table of the segment design {d.name!r} '
        f'({d.path.name if d.path else "in memory"}), made by `softseq fem`.',
        f'{d.description}' if d.description else None,
        'Method: nonlinear hyperelastic FEM (felupe), cavity filled with an incompressible fluid',
        '  whose volume is prescribed; the gauge pressure is the Lagrange multiplier of the',
        '  volume constraint (bordered Newton), so it may follow peaks and valleys.',
        f'Geometry [mm]: L {g.length_m * mm:g}, h {g.height_m * mm:g}, w {g.width_m * mm:g}, '
        f'beam e {g.beam_thickness_m * mm:g}, cavity g {g.cavity_width_m * mm:g},',
        f'  wall a {g.wall_length_m * mm:g}, membrane b {g.membrane_length_m * mm:g}, '
        f'membrane t {g.membrane_thickness_m * mm:g}, wall d {g.wall_thickness_m * mm:g};',
        f'  {walls}.',
        f'Model: {model}.',
        f'Material: {d.material.law} ({params}), distortional part; nearly incompressible with',
        f'  bulk modulus {d.mesh.bulk_ratio:g} x the initial shear modulus (u/p/J, cell-wise p).',
        f'Mesh: linear hexahedra of about {d.mesh.element_size_m * mm:g} mm, at least '
        f'{d.mesh.thin_layer_cells} through thin layers; {result.cells} cells, '
        f'{result.points} points, {result.dofs} unknowns.',
        f'Solver: adaptive volume steps (first {d.volume.first_step_m3 * 1e6:g} mL, at most '
        f'{d.volume.max_step_m3 * 1e6:g} mL), {result.newton_iterations} Newton iterations; '
        f'felupe {version("felupe")},',
        f'  softseq_ros {version("softseq_ros")}, FEM code {FEM_CODE_VERSION}, design hash '
        f'{d.digest()}.',
        'Curvature: least-squares slope of the beam mid-line tangent angle over its undeformed',
        '  length (positive toward the beam); cut_curvature_per_m: twice the turn of the mid-wall',
        '  cut over the pitch (unit cell only).',
        f'Range: {result.injected[-1] * 1e6:.2f} mL injected of the '
        f'{d.volume.max_injected_m3 * 1e6:g} mL asked; {result.stop_reason}.',
        f'Peak pressure {peak_p:.1f} Pa at {peak_v * 1e6:.2f} mL injected. SI units; '
        'pressures are gauge.',
        'Noise: the rows scatter by no more than the largest last Newton correction of the',
        '  pressure (the mesh error is smooth: it shifts the curve, it makes no wiggles):',
        f'noise_std_pa: {max(result.solver_noise_pa, 1e-9):.3g}',
    ]
    if result.snaps:
        lines.append('Snap-throughs at constant volume (the quasi-static path ends or goes on '
                     'only unstably; the')
        lines.append('  solid settles, damped, on a stable state of the same volume):')
        for row, membrane, growth in result.snaps:
            which = ('every membrane (a unit cell)' if d.mesh.model == 'unit_cell' else
                     f'membrane {membrane + 1} of {g.membranes} (from the base)')
            lines.append(
                f'  at {result.injected[row] * 1e6:.3f} mL injected, '
                f'{result.pressures[row - 1]:.1f} -> {result.pressures[row]:.1f} Pa; {which} '
                f'bulges {growth * mm:.2f} mm more.')
    if d.geometry.membrane_thickness_factors is not None:
        lines.append('Membrane thickness factors, base to tip: '
                     + ', '.join(f'{f:g}' for f in d.geometry.membrane_thickness_factors) + '.')
    return [line for line in lines if line is not None]


def write_table(result: FemResult, path: Path) -> Path:
    """Write the table CSV with its provenance comments."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    lines = [f'# {line}' for line in _provenance(result)]
    lines.append(','.join(COLUMNS))
    for row in zip(result.volumes, result.pressures, result.curvatures, result.injected,
                   result.cut_curvatures):
        # + 0.0 writes a negative zero (the rest state's fitted curvature) as 0.
        lines.append(','.join(f'{value + 0.0:.9e}' for value in row))
    tmp = path.with_suffix(path.suffix + '.tmp')
    tmp.write_text('\n'.join(lines) + '\n')
    tmp.replace(path)
    return path


def table_for(design: Design, out: Path | None = None, cache_dir: Path | None = None,
              use_cache: bool = True, stream: TextIO | None = sys.stderr) -> tuple[Path, bool]:
    """
    The table of a design: from the cache when present, else computed and cached.

    Returns the path written (``out`` or the cache file) and whether it was computed now.
    """
    cached = cache_path(design, cache_dir)
    if use_cache and cached.is_file():
        if out is not None and Path(out).resolve() != cached.resolve():
            Path(out).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(cached, out)
            return Path(out), False
        return cached, False

    result = run_design(design, progress=lambda line: write_progress(stream, line))
    end_progress(stream)
    write_table(result, cached)
    if out is not None:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(cached, out)
        return Path(out), True
    return cached, True
