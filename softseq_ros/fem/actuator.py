"""
The whole actuator on one cavity: all its segments' membranes and walls, base clamped.

The paper checks its assembly of segment tables against an Abaqus model of the whole
bi-segmented actuator (its Fig. 6A and 7B). This is that model: the segments' whole-segment
meshes in a row, base to tip, on one cavity (where two segments meet, their end caps are one
wall band over the shared cavity), half the width, the base clamped, one volume constraint. The
fluid's volume is ramped as the syringe does; each segment's share is read from the cavity's
parts: the cavity faces of that segment's length, integrated as the whole cavity is
(:mod:`softseq_ros.fem.cavity`; the plane between two parts holds no solid face, and with the
weight diag(0, 1, 0) a plane across the cavity adds nothing, so the parts add up to the whole
exactly). Each segment's curvature is the least-squares slope of its beam mid-line's tangent
angle, as in the segment tables; the backbone is the deformed mid-line itself (no constant
radius assumed), the tip its last point.
"""

from dataclasses import dataclass, field
import hashlib
import json
from pathlib import Path
import time
from typing import Callable

import numpy as np
from numpy.typing import NDArray

from softseq_ros.fem.cavity import Cavity
from softseq_ros.scene.design import Design, DesignError, default_cache_dir

COLUMNS_HEAD = ('injected_m3', 'pressure_pa')


def check_actuator(designs: list[Design]) -> None:
    """Refuse designs that cannot share one cavity (one line naming the design and key)."""
    if len(designs) < 2:
        raise DesignError('--model actuator: give the segment designs base to tip, at least '
                          f'two (got {len(designs)})')
    first = designs[0]
    from softseq_ros.fem.segment import SHARED_SECTION

    for design in designs[1:]:
        where = design.path or design.name
        for key in SHARED_SECTION:
            a, b = getattr(first.geometry, key), getattr(design.geometry, key)
            if not np.isclose(a, b, rtol=1e-12, atol=0.0):
                raise DesignError(f'{where}: geometry.{key}: {b:g} differs from {a:g} of '
                                  f'{first.path or first.name}; segments on one cavity share '
                                  'their cross-section')
        if (design.material.law, design.material.params) != (first.material.law,
                                                             first.material.params):
            raise DesignError(f'{where}: material: differs from that of '
                              f'{first.path or first.name}; the actuator is cast in one '
                              'material')
    for design in designs:
        if design.geometry.membrane_thickness_factors is not None:
            raise DesignError(f'{design.path or design.name}: '
                              'geometry.membrane_thickness_factors: not with --model actuator')


@dataclass
class ActuatorResult:
    """A finished run of the whole actuator (volumes of the whole width, SI units)."""

    designs: list[Design]
    injected: NDArray[np.float64]        # fluid injected into the actuator [m^3]
    pressures: NDArray[np.float64]       # gauge [Pa]
    volumes: NDArray[np.float64]         # (rows, segments): each segment's fluid [m^3]
    curvatures: NDArray[np.float64]      # (rows, segments) [1/m]
    ends: NDArray[np.float64]            # (rows, segments, 2): each segment's end (x, z) [m]
    lines: list[NDArray[np.float64]]     # each row's deformed beam mid-line (x, z) [m]
    stop_reason: str
    dofs: int
    cells: int
    newton_iterations: int
    wall_s: float
    snaps: list[float] = field(default_factory=list)  # injected volumes [m^3] of snaps

    @property
    def names(self) -> list[str]:
        """Segment names, base to tip (the designs' names)."""
        return [d.name for d in self.designs]

    def injected_by_segment(self) -> NDArray[np.float64]:
        """Fluid injected into each segment [m^3] (rows, segments)."""
        return self.volumes - self.volumes[0]

    def at(self, injected_m3: float) -> dict[str, NDArray[np.float64] | float]:
        """Pressure, volumes, curvatures and tip linearly between the rows around a volume."""
        x = self.injected
        return {'pressure_pa': float(np.interp(injected_m3, x, self.pressures)),
                'injected_by_segment_m3': np.array(
                    [np.interp(injected_m3, x, c) for c in self.injected_by_segment().T]),
                'curvatures_per_m': np.array([np.interp(injected_m3, x, c)
                                              for c in self.curvatures.T]),
                'tip_m': np.array([np.interp(injected_m3, x, self.ends[:, -1, k])
                                   for k in range(2)])}


def _fit_curvature(reference: NDArray, current: NDArray) -> float:
    """Least-squares slope of the tangent angle over the undeformed length (toward the beam)."""
    dx = np.diff(current, axis=0)
    angle = np.unwrap(np.arctan2(dx[:, 1], dx[:, 0]))
    s_ref = 0.5 * (reference[1:] + reference[:-1])
    return float(-np.polyfit(s_ref, angle, 1)[0])


def actuator_digest(designs: list[Design], max_injected_m3: float) -> str:
    """The cache key of an actuator run: its designs' identities and its volume range."""
    text = json.dumps({'designs': [d.identity() for d in designs],
                       'max_injected_m3': max_injected_m3}, sort_keys=True,
                      separators=(',', ':'))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def run_actuator(designs: list[Design], max_injected_m3: float | None = None,
                 progress: Callable[[str], None] | None = None) -> ActuatorResult:
    """Inflate the whole actuator under volume control to ``max_injected_m3`` [m^3]."""
    from softseq_ros.fem.segment import build_chain

    check_actuator(designs)
    start = time.perf_counter()
    if max_injected_m3 is None:
        max_injected_m3 = max(d.volume.max_injected_m3 for d in designs)
    chain = build_chain(list(designs), 'whole_segment')
    model = chain.model
    factor = chain.volume_factor
    points = model.reference
    centres_x = points[model.cavity.faces].mean(axis=1)[:, 0]
    bounds = np.asarray(chain.bounds)
    owner = np.clip(np.searchsorted(bounds, centres_x) - 1, 0, len(designs) - 1)
    parts = [Cavity(faces=model.cavity.faces[owner == i], weights=model.cavity.weights)
             for i in range(len(designs))]
    line = chain.neutral_line
    line_x = points[line, 0]
    # The mid-line points of each segment, with the point at its start (shared with the last).
    spans = [np.nonzero((line_x >= lo - 1e-9) & (line_x <= hi + 1e-9))[0]
             for lo, hi in zip(bounds[:-1], bounds[1:])]
    ends = [int(np.argmin(np.abs(line_x - hi))) for hi in bounds[1:]]
    rows: list[tuple] = []
    lines: list[NDArray] = []

    def on_state(state: object) -> str | None:
        x = model.positions(state.q)
        if chain.contact(x, state.q):
            return (f'stopped where neighbouring membranes touch, before '
                    f'{(state.volume - model.rest_volume) * factor * 1e6:.2f} mL injected '
                    '(contact is not modelled)')
        mid = x[line][:, [0, 2]]
        volumes = [factor * part.volume(x) for part in parts]
        curvatures = [_fit_curvature(line_x[span], mid[span]) for span in spans]
        rows.append((state.volume * factor, state.pressure, volumes, curvatures,
                     [mid[i] for i in ends]))
        lines.append(mid)
        if progress is not None:
            progress(f'actuator: {(state.volume - model.rest_volume) * factor * 1e6:6.2f} mL '
                     f'injected, {state.pressure / 1e3:7.3f} kPa, split '
                     + ' / '.join(f'{(v - v0) * 1e6:.1f}' for v, v0 in
                                  zip(volumes, rows[0][2])) + ' mL, curvature '
                     + ' / '.join(f'{k:.1f}' for k in curvatures)
                     + f' 1/m ({time.perf_counter() - start:5.1f} s)')
        return None

    def on_motion(q: NDArray) -> str | None:
        if chain.contact(model.positions(q), q):
            return 'neighbouring membranes touch (contact is not modelled)'
        return None

    volume = designs[0].volume
    result = model.ramp_volume(
        max_volume=model.rest_volume + max_injected_m3 / factor,
        first_step=volume.first_step_m3 / factor, max_step=volume.max_step_m3 / factor,
        min_step=volume.first_step_m3 / factor / 256, on_state=on_state, on_motion=on_motion)
    total = np.array([r[0] for r in rows])
    injected = total - total[0]
    reached = f'{injected[-1] * 1e6:.2f} mL injected'
    stop = result.stop_reason.replace('the last state', reached).replace(
        'at the next volume', f'just beyond {reached}')
    return ActuatorResult(
        designs=list(designs), injected=injected, pressures=np.array([r[1] for r in rows]),
        volumes=np.array([r[2] for r in rows]), curvatures=np.array([r[3] for r in rows]),
        ends=np.array([r[4] for r in rows]), lines=lines, stop_reason=stop, dofs=chain.dofs,
        cells=chain.mesh.ncells, newton_iterations=result.newton_iterations,
        wall_s=time.perf_counter() - start,
        snaps=[float(injected[s.index]) for s in result.snaps if s.index < len(rows)])


def actuator_columns(names: list[str]) -> list[str]:
    """The CSV columns of an actuator table (segments named base to tip)."""
    return [*COLUMNS_HEAD, *(f'volume_{n}_m3' for n in names),
            *(f'curvature_{n}_per_m' for n in names),
            *(f'end_{n}_{axis}_m' for n in names for axis in ('x', 'z'))]


def write_actuator_table(result: ActuatorResult, path: Path, max_injected_m3: float) -> Path:
    """The whole actuator's table: PV curve, volume split, curvatures and backbone ends."""
    from importlib.metadata import version

    from softseq_ros.scene.design import FEM_CODE_VERSION

    names = [f's{i}' for i in range(len(result.designs))]
    d0 = result.designs[0]
    params = ', '.join(f'{k} = {v}' for k, v in d0.material.params.items())
    lines = [
        'FEM table of the whole actuator (one cavity), made by `softseq fem --model actuator`.',
        'Segments base to tip: ' + ', '.join(
            f's{i} = {d.name!r} (membrane {d.geometry.membrane_thickness_m * 1e3:g} mm, wall '
            f'{d.geometry.wall_thickness_m * 1e3:g} mm, {d.geometry.membranes} membranes)'
            for i, d in enumerate(result.designs)) + '.',
        'Model: the segments in a row on one cavity, half the width, base clamped, tip free;',
        "  each segment's volume from the cavity faces along its length (whole width).",
        f'Material: {d0.material.law} ({params}); '
        f'mesh about {d0.mesh.element_size_m * 1e3:g} mm, {result.cells} cells, {result.dofs} '
        f'unknowns; {result.newton_iterations} Newton iterations.',
        "Curvature: least-squares slope of each segment's beam mid-line tangent angle; end_*:",
        "  each segment's end on the deformed mid-line (x along the unbent actuator, z toward "
        'the membranes).',
        f'felupe {version("felupe")}, FEM code {FEM_CODE_VERSION}, actuator hash '
        f'{actuator_digest(result.designs, max_injected_m3)}.',
        f'Range: {result.injected[-1] * 1e6:.2f} mL injected of the {max_injected_m3 * 1e6:g} '
        f'mL asked; {result.stop_reason}. SI units; pressures are gauge.',
    ]
    if result.snaps:
        lines.append('Snap-throughs at constant volume at ' + ', '.join(
            f'{v * 1e6:.3f}' for v in result.snaps) + ' mL injected.')
    out = [f'# {line}' for line in lines]
    out.append(','.join(actuator_columns(names)))
    for i in range(result.injected.size):
        values = [result.injected[i], result.pressures[i], *result.volumes[i],
                  *result.curvatures[i], *result.ends[i].ravel()]
        out.append(','.join(f'{v + 0.0:.9e}' for v in values))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + '.tmp')
    tmp.write_text('\n'.join(out) + '\n')
    tmp.replace(path)
    return path


def actuator_cache_path(designs: list[Design], max_injected_m3: float,
                        cache_dir: Path | None = None) -> Path:
    """Where an actuator table is cached: its segments' names and its hash."""
    name = '+'.join(d.name for d in designs)
    return (cache_dir or default_cache_dir()) / \
        f'actuator-{name}-{actuator_digest(designs, max_injected_m3)}.csv'


def actuator_table_for(designs: list[Design], out: Path | None = None,
                       cache_dir: Path | None = None, use_cache: bool = True,
                       progress: Callable[[str], None] | None = None
                       ) -> tuple[Path, bool, ActuatorResult | None]:
    """
    The whole actuator's table: from the cache when present, else computed and cached.

    Returns the path written (``out`` or the cache file), whether it was computed now, and the
    result when it was.
    """
    import shutil

    check_actuator(designs)
    top = max(d.volume.max_injected_m3 for d in designs)
    cached = actuator_cache_path(designs, top, cache_dir)
    result = None
    computed = not (use_cache and cached.is_file())
    if computed:
        result = run_actuator(designs, top, progress)
        write_actuator_table(result, cached, top)
    if out is None:
        return cached, computed, result
    if Path(out).resolve() != cached.resolve():
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(cached, out)
    return Path(out), computed, result
