"""
Segment design files: the geometry, material, mesh and volume range of one FEM run.

Schema (SI units; optional keys show their defaults)::

    name: paper_top
    description: free text                  # optional
    geometry:                               # Table I of Milana et al. 2018, in metres
      length_m: 0.111                       # segment length (L / 2 for each of two segments)
      height_m: 0.015                       # h, beam side to membrane side
      width_m: 0.015                        # w
      beam_thickness_m: 0.005               # e, the solid beam on the concave side
      cavity_width_m: 0.011                 # g
      wall_length_m: 0.004                  # a, along the segment
      membrane_length_m: 0.006              # b, along the segment
      membrane_thickness_m: 0.0005          # t
      wall_thickness_m: 0.002               # d (what it is depends on wall_reading)
      wall_reading: skin_bands              # or side_walls
      # skin_band_thickness_m: ...          # side_walls only: skin between the membranes
      # membrane_thickness_factors: [1.0, 0.98, ...]   # whole_segment only: one per membrane
    material: {law: yeoh, c1_pa: 7830.0, c2_pa: 103.0, c3_pa: -1.0}   # as in scenes
    mesh:
      model: unit_cell                      # or whole_segment
      element_size_m: 0.00075               # target edge length of the hexahedra
      thin_layer_cells: 2                   # at least this many through membranes and skins
      bulk_ratio: 5000.0                    # bulk / shear modulus (nearly incompressible)
    volume:
      max_injected_m3: 4.0e-5               # fluid injected into this segment at the end
      first_step_m3: 5.0e-7                 # first volume step (then adaptive)
      max_step_m3: 2.0e-6                   # largest volume step

``wall_reading: skin_bands`` (the default) reads Table I's walls as the thicker bands of the
skin between the membranes (thickness d from the flat outer surface into the cavity); the side
walls are then (w - g) / 2 thick. ``side_walls`` reads d as the side walls' thickness, so the
cavity is w - 2 d wide (the file's cavity_width_m must say so) and the skin between membranes
needs its own ``skin_band_thickness_m``. docs/fem.md explains the choice.

``membrane_thickness_factors`` (whole segment only) scales each membrane's thickness, base to
tip: real membranes are never quite equal, and eleven equal ones on one cavity reach their
pressure peak together, a bifurcation no path can be followed through; a 1 % scatter picks the
membranes that run away, as in the experiment.

Every mistake raises ``DesignError`` with one line ``<file>: <key path>: <what is wrong>``.
"""

from dataclasses import asdict, dataclass
import hashlib
from importlib.metadata import PackageNotFoundError
import json
import math
import os
from pathlib import Path
from typing import Any

from softseq_ros.errors import not_a_file
from softseq_ros.scene.paths import config_dir
from softseq_ros.scene.validation import SCENE_NAME, Context, SceneError, read_yaml

WALL_READINGS = ('skin_bands', 'side_walls')
MODELS = ('unit_cell', 'whole_segment')
# Bump when a change to the FEM code changes its results, so cached tables are recomputed.
FEM_CODE_VERSION = '4'
# Hexahedra of the mesh's box at element_size_m, before the cavity is cut out: refused before
# meshing above this. 2e6 cells are some 6e6 unknowns, a sparse system beyond a workstation's
# memory; the shipped designs use 1e3 (unit cell) to 3e4 (whole segment at 0.75 mm).
MAX_MESH_CELLS = 2_000_000
# Cells through a thin layer: each adds a plane of cells across the whole mesh.
MAX_THIN_CELLS = 64
# Two ways of giving one length agree when they differ by round-off (a decimal in YAML).
SAME_LENGTH_RTOL = 1e-9
SAME_LENGTH_ATOL_M = 1e-12


class DesignError(SceneError):
    """A design file that cannot be used; the message is ``<file>: <key path>: <problem>``."""


@dataclass(frozen=True)
class Geometry:
    """Table I dimensions [m] and how the walls are read."""

    length_m: float
    height_m: float
    width_m: float
    beam_thickness_m: float
    cavity_width_m: float
    wall_length_m: float
    membrane_length_m: float
    membrane_thickness_m: float
    wall_thickness_m: float
    wall_reading: str = 'skin_bands'
    skin_band_thickness_m: float = 0.0
    membrane_thickness_factors: tuple[float, ...] | None = None  # base to tip; None: all 1

    @property
    def side_wall_thickness_m(self) -> float:
        """Thickness of each side wall [m]."""
        return (self.width_m - self.cavity_width_m) / 2

    @property
    def pitch_m(self) -> float:
        """Length of one wall plus one membrane [m]."""
        return self.wall_length_m + self.membrane_length_m

    @property
    def membranes(self) -> int:
        """Number of membranes along the segment (its length over the pitch, rounded)."""
        return max(1, round(self.length_m / self.pitch_m))

    @property
    def end_cap_length_m(self) -> float:
        """Solid end at each end of the whole-segment model [m]."""
        n = self.membranes
        return (self.length_m - n * self.membrane_length_m - (n - 1) * self.wall_length_m) / 2


@dataclass(frozen=True)
class Material:
    """A material block: law name and parameters in Pa (as in scene files)."""

    law: str
    params: dict[str, Any]


@dataclass(frozen=True)
class MeshSettings:
    """Which model, how fine, how incompressible."""

    model: str = 'unit_cell'
    element_size_m: float = 0.00075
    thin_layer_cells: int = 2
    bulk_ratio: float = 5000.0


@dataclass(frozen=True)
class VolumeRange:
    """Fluid injected into the segment [m^3], and the volume steps."""

    max_injected_m3: float
    first_step_m3: float = 5.0e-7
    max_step_m3: float = 2.0e-6


@dataclass(frozen=True)
class Design:
    """A loaded, validated segment design."""

    name: str
    description: str
    geometry: Geometry
    material: Material
    mesh: MeshSettings
    volume: VolumeRange
    path: Path | None = None

    def identity(self) -> dict[str, Any]:
        """What decides the FEM result: geometry, material, mesh, volume range, code versions."""
        from importlib.metadata import version

        geometry = asdict(self.geometry)
        if geometry['membrane_thickness_factors'] is None:
            del geometry['membrane_thickness_factors']  # designs without it keep their hash
        return {'geometry': geometry, 'material': asdict(self.material),
                'mesh': asdict(self.mesh), 'volume': asdict(self.volume),
                'fem_code': FEM_CODE_VERSION, 'felupe': version('felupe')}

    def digest(self) -> str:
        """Hash of :meth:`identity` (16 hex digits): the cache key of its table."""
        text = json.dumps(self.identity(), sort_keys=True, separators=(',', ':'))
        return hashlib.sha256(text.encode()).hexdigest()[:16]


_GEOMETRY_KEYS = ('length_m', 'height_m', 'width_m', 'beam_thickness_m', 'cavity_width_m',
                  'wall_length_m', 'membrane_length_m', 'membrane_thickness_m',
                  'wall_thickness_m')


def _geometry(ctx: Context, value: object) -> Geometry:
    raw = ctx.mapping(value, 'geometry', _GEOMETRY_KEYS,
                   ('wall_reading', 'skin_band_thickness_m', 'membrane_thickness_factors'))
    dims = {key: ctx.number(raw[key], f'geometry.{key}', gt=0.0) for key in _GEOMETRY_KEYS}
    reading = ctx.text(raw.get('wall_reading', 'skin_bands'), 'geometry.wall_reading')
    if reading not in WALL_READINGS:
        raise ctx.error('geometry.wall_reading',
                        f'unknown reading {reading!r}; expected one of {", ".join(WALL_READINGS)}')
    w, g, d = dims['width_m'], dims['cavity_width_m'], dims['wall_thickness_m']
    if not g < w:
        raise ctx.error('geometry.cavity_width_m', f'must be below width_m ({w:g} m), got {g:g}')
    if reading == 'skin_bands':
        if 'skin_band_thickness_m' in raw:
            raise ctx.error('geometry.skin_band_thickness_m',
                            'only for wall_reading side_walls (with skin_bands the skin between '
                            'membranes is wall_thickness_m thick)')
        band = d
    else:
        if 'skin_band_thickness_m' not in raw:
            raise ctx.error('geometry.skin_band_thickness_m',
                            'required with wall_reading side_walls')
        band = ctx.number(raw['skin_band_thickness_m'], 'geometry.skin_band_thickness_m',
                       gt=0.0)
        if not math.isclose(g, w - 2 * d, rel_tol=SAME_LENGTH_RTOL, abs_tol=SAME_LENGTH_ATOL_M):
            raise ctx.error('geometry.cavity_width_m',
                            f'with side walls {d:g} m thick the cavity is width_m - 2 '
                            f'wall_thickness_m = {w - 2 * d:g} m wide, got {g:g}')
    room = dims['height_m'] - dims['beam_thickness_m']
    for key, thickness in (('membrane_thickness_m', dims['membrane_thickness_m']),
                           ('skin_band_thickness_m' if reading == 'side_walls'
                            else 'wall_thickness_m', band)):
        if not thickness < room:
            raise ctx.error(f'geometry.{key}', f'must leave a cavity: below height_m - '
                                               f'beam_thickness_m ({room:g} m), got {thickness:g}')
    geometry = Geometry(**dims, wall_reading=reading, skin_band_thickness_m=band)
    if not geometry.end_cap_length_m > 0:
        raise ctx.error('geometry.length_m',
                        f'{geometry.length_m:g} m holds no end caps around {geometry.membranes} '
                        f'membranes of pitch {geometry.pitch_m:g} m')
    factors = raw.get('membrane_thickness_factors')
    if factors is not None:
        key = 'geometry.membrane_thickness_factors'
        if not isinstance(factors, (list, tuple)) or len(factors) != geometry.membranes:
            raise ctx.error(key, f'must be a list of {geometry.membranes} numbers (one per '
                                 f'membrane, base to tip), got {factors!r}')
        values = tuple(ctx.number(f, f'{key}[{i}]', ge=0.5) for i, f in enumerate(factors))
        for i, factor in enumerate(values):
            if factor > 1.5:
                raise ctx.error(f'{key}[{i}]', f'must be <= 1.5 (a scatter of the thickness, '
                                               f'not another design), got {factor:g}')
            if not factor * dims['membrane_thickness_m'] < room:
                raise ctx.error(f'{key}[{i}]', f'{factor:g} x membrane_thickness_m leaves no '
                                               f'cavity (room {room:g} m)')
        geometry = Geometry(**{**asdict(geometry), 'membrane_thickness_factors': values})
    return geometry


def model_extent_m(geometry: Geometry, model: str) -> tuple[float, float, float]:
    """The box the mesh fills [m]: along the segment, half the width (symmetry), the height."""
    along = geometry.pitch_m / 2 if model == 'unit_cell' else geometry.length_m
    return along, geometry.width_m / 2, geometry.height_m


def _mesh(ctx: Context, value: object, geometry: Geometry) -> MeshSettings:
    defaults = MeshSettings()
    raw = ctx.mapping({} if value is None else value, 'mesh', (),
                   ('model', 'element_size_m', 'thin_layer_cells', 'bulk_ratio'))
    model = ctx.text(raw.get('model', defaults.model), 'mesh.model')
    if model not in MODELS:
        raise ctx.error('mesh.model', f'unknown model {model!r}; expected one of '
                                      f'{", ".join(MODELS)}')
    size = ctx.number(raw.get('element_size_m', defaults.element_size_m),
                   'mesh.element_size_m', gt=0.0)
    if size > geometry.height_m / 4:
        raise ctx.error('mesh.element_size_m', f'must be at most a quarter of height_m '
                                               f'({geometry.height_m / 4:g} m), got {size:g}')
    extent = model_extent_m(geometry, model)
    cells = math.prod(math.ceil(side / size) for side in extent)
    if cells > MAX_MESH_CELLS:
        smallest = (math.prod(extent) / MAX_MESH_CELLS) ** (1 / 3)
        raise ctx.error('mesh.element_size_m',
                        f'{size:g} m gives about {cells:.2g} hexahedra over the {model} '
                        f'({" x ".join(f"{side * 1e3:g}" for side in extent)} mm), more than '
                        f'{MAX_MESH_CELLS:.0e}: use at least {smallest:.2g} m')
    thin = raw.get('thin_layer_cells', defaults.thin_layer_cells)
    if isinstance(thin, bool) or not isinstance(thin, int) or not 1 <= thin <= MAX_THIN_CELLS:
        raise ctx.error('mesh.thin_layer_cells', f'must be an integer from 1 to '
                                                 f'{MAX_THIN_CELLS}, got {thin!r:.40}')
    bulk = ctx.number(raw.get('bulk_ratio', defaults.bulk_ratio), 'mesh.bulk_ratio', ge=100.0)
    return MeshSettings(model=model, element_size_m=size, thin_layer_cells=thin,
                        bulk_ratio=bulk)


def _volume(ctx: Context, value: object) -> VolumeRange:
    defaults_first, defaults_max = VolumeRange(1.0).first_step_m3, VolumeRange(1.0).max_step_m3
    raw = ctx.mapping(value, 'volume', ('max_injected_m3',), ('first_step_m3', 'max_step_m3'))
    top = ctx.number(raw['max_injected_m3'], 'volume.max_injected_m3', gt=0.0)
    first = ctx.number(raw.get('first_step_m3', defaults_first), 'volume.first_step_m3',
                    gt=0.0)
    largest = ctx.number(raw.get('max_step_m3', defaults_max), 'volume.max_step_m3', gt=0.0)
    if first > top:
        raise ctx.error('volume.first_step_m3', f'must not exceed max_injected_m3 ({top:g}), '
                                                f'got {first:g}')
    if largest < first:
        raise ctx.error('volume.max_step_m3', f'must be >= first_step_m3 ({first:g}), '
                                              f'got {largest:g}')
    return VolumeRange(max_injected_m3=top, first_step_m3=first, max_step_m3=largest)


def design_from_dict(data: object, path: str | Path | None = None) -> Design:
    """Build a design from parsed YAML; ``path`` names the file in errors."""
    shown = str(path) if path is not None else '<design>'
    ctx = Context(shown, Path(path).parent if path is not None else Path('.'))
    try:
        raw = ctx.mapping(data, '', ('name', 'geometry', 'material', 'volume'),
                       ('description', 'mesh'))
        name = ctx.text(raw['name'], 'name')
        if not SCENE_NAME.match(name):
            raise ctx.error('name', f'must start with a letter or digit and hold only letters, '
                                    f'digits, _, - and ., got {name!r}')
        description = ' '.join(ctx.text(raw.get('description', ''), 'description').split())
        geometry = _geometry(ctx, raw['geometry'])
        ctx.material(raw['material'], 'material')   # the scene checks, with their messages
        material = Material(law=raw['material']['law'],
                            params={k: v for k, v in raw['material'].items() if k != 'law'})
        mesh = _mesh(ctx, raw.get('mesh'), geometry)
        if geometry.membrane_thickness_factors is not None and mesh.model != 'whole_segment':
            raise ctx.error('geometry.membrane_thickness_factors',
                            'only for mesh.model whole_segment (a unit cell has one membrane, '
                            'repeated)')
        volume = _volume(ctx, raw['volume'])
    except DesignError:
        raise
    except SceneError as err:
        raise DesignError(str(err)) from None
    return Design(name=name, description=description, geometry=geometry, material=material,
                  mesh=mesh, volume=volume, path=Path(path) if path is not None else None)


def load_design(path: str | Path) -> Design:
    """Load and validate a design file; raises DesignError with one line."""
    path = Path(path)
    if not path.is_file():
        raise DesignError(f'{path}: {not_a_file(path, "design file")}')
    try:
        data = read_yaml(path, str(path))
    except SceneError as err:
        raise DesignError(str(err).replace('scene file', 'design file')) from None
    return design_from_dict(data, path)


# Keys a design may leave out that a change may still set.
_OPTIONAL_KEYS = ('geometry.membrane_thickness_factors', 'geometry.skin_band_thickness_m')


def with_changes(design: Design, changes: dict[str, Any]) -> Design:
    """A copy of a design with dotted keys replaced (``geometry.membrane_thickness_m``)."""
    data = {'name': design.name, 'description': design.description,
            'geometry': asdict(design.geometry), 'material': {'law': design.material.law,
                                                             **design.material.params},
            'mesh': asdict(design.mesh), 'volume': asdict(design.volume)}
    if data['geometry']['wall_reading'] == 'skin_bands':
        data['geometry'].pop('skin_band_thickness_m')
    if data['geometry']['membrane_thickness_factors'] is None:
        data['geometry'].pop('membrane_thickness_factors')
    for dotted, value in changes.items():
        node = data
        *parents, leaf = dotted.split('.')
        for key in parents:
            if not isinstance(node.get(key), dict):
                raise DesignError(f'{design.path or "<design>"}: {dotted}: no such key')
            node = node[key]
        if leaf not in node and parents != ['material'] and dotted not in _OPTIONAL_KEYS:
            raise DesignError(f'{design.path or "<design>"}: {dotted}: no such key')
        node[leaf] = value
    shown = f'{design.path or "<design>"} with {", ".join(f"{k}={v}" for k, v in changes.items())}'
    return design_from_dict(data, shown)


def default_cache_dir() -> Path:
    """Where tables are cached: $SOFTSEQ_FEM_CACHE, else $XDG_CACHE_HOME/softseq/fem."""
    explicit = os.environ.get('SOFTSEQ_FEM_CACHE')
    if explicit:
        return Path(explicit)
    base = os.environ.get('XDG_CACHE_HOME') or str(Path.home() / '.cache')
    return Path(base) / 'softseq' / 'fem'


def cache_path(design: Design, cache_dir: Path | None = None) -> Path:
    """The cache file of a design's table (its name and hash)."""
    return (cache_dir or default_cache_dir()) / f'{design.name}-{design.digest()}.csv'


def design_path(name_or_path: str) -> Path:
    """A design file, or the shipped design of that bare name (``paper_top``)."""
    path = Path(name_or_path)
    if path.is_file():
        return path
    if path.suffix == '' and '/' not in name_or_path and os.sep not in name_or_path:
        shipped = config_dir() / 'designs' / f'{name_or_path}.yaml'
        if shipped.is_file():
            return shipped
        known = ', '.join(sorted(p.stem for p in (config_dir() / 'designs').glob('*.yaml')))
        raise DesignError(f'{name_or_path}: no such design file and no shipped design of that '
                          f'name (shipped: {known})')
    raise DesignError(f'{name_or_path}: {not_a_file(path, "design file")}')


def cached_table(design: Design, cache_dir: Path | None = None) -> Path:
    """
    The table `softseq fem` made of this design, from the cache; DesignError when there is none.

    A scene that names a design gets its table here without recomputing it; the error says
    how to make it (the FEM takes minutes and needs the ``fem`` extra, so no scene load
    starts it).
    """
    try:
        path = cache_path(design, cache_dir)
    except PackageNotFoundError:
        raise DesignError(f"{design.path or design.name}: its table's cache key names the FEM "
                          'library, which is not installed: pip install "softseq_ros[fem]"') \
            from None
    if not path.is_file():
        source = design.path if design.path is not None else design.name
        raise DesignError(f'{source}: no FEM table of this design in {path.parent} (hash '
                          f'{path.stem.rsplit("-", 1)[-1]}); make it once with '
                          f'`softseq fem {source}`')
    return path
