"""
Scene files: one YAML file describes an emulated rig run.

A scene names its segments (base to tip), the pump programme, the camera and the outputs to
publish. Every quantity is SI and every key that carries a unit says so in its suffix
(``length_m``, ``flow_rate_m3_per_s``, ``rate_hz``, ...). Schema (optional keys show defaults)::

    name: paper                       # letters, digits, '_', '-', '.'
    description: free text            # optional
    segments:                         # base to tip, at least 2
      - name: bottom                  # letters, digits, '_'; unique
        length_m: 0.111
        table: segments/paper_bottom.csv        # CSV relative to this file, or:
        # design: designs/paper_bottom.yaml     # a segment design (file or shipped name):
        #                                       # its FEM table from `softseq fem`'s cache
        # smoothing: {noise_std_pa, prominence_pa}  # opt-in, tables only (measured rig data)
        # linear: {rest_volume_m3, stiffness_pa_per_m3, max_volume_m3,
        #          curvature_per_m_per_m3: 0.0}
        # balloon: {material: {law: gent, shear_modulus_pa: ..., jm: ...}, radius_m,
        #           thickness_m, max_stretch, curvature_per_m_per_m3: 0.0}
    pump:
      flow_rate_m3_per_s: 5.0e-8
      rate_hz: 50.0
      cycles: 1
      start_injected_m3: 0.0
      legs: [{inflate_to_m3: 6.5e-5}, {hold_s: 10}, {deflate_to_m3: 0.0}]
    camera:                           # optional, all keys optional
      rate_hz: 10.0
      noise_std_m: 0.0
      seed: 0
      trigger_injected_m3: []         # increasing, reached by the pump
      points_per_segment: 20
      image_width_px: 640
      image_height_px: 480
    outputs: [pressure, volumes, curvature, poses, markers, events]   # optional
    solver: {resolution: null}        # optional; null keeps the solver's default

Every mistake raises ``SceneError`` with one line ``<file>: <key path>: <what is wrong>``, e.g.
``config/x.yaml: segments[1].length_m: must be > 0, got -0.1``.
"""

from dataclasses import dataclass
import math
import os
from pathlib import Path
import re
import sys
from typing import Any

import yaml

from softseq_ros.scene.limits import LIMITS
from softseq_ros.scene.outputs import DEFAULT_OUTPUTS, OUTPUT_NAMES
from softseq_ros.scene.programme import (
    DEFAULT_FLOW_RATE,
    Leg,
    ProgrammeError,
    PumpProfile,
    check_capacity,
)
from softseq_ros.scene.tables import read_table
from softseq_ros.segments.materials import LAW_NAMES, make_material, material_parameter_names
from softseq_ros.segments.models import BalloonSegment, LinearSegment, Segment, TabulatedSegment
from softseq_ros.segments.smoothing import smooth_table

PACKAGE = 'softseq_ros'

DEFAULT_PUMP_RATE_HZ = 50.0
DEFAULT_CAMERA_RATE_HZ = 10.0
DEFAULT_POINTS_PER_SEGMENT = 20
DEFAULT_IMAGE_SIZE_PX = (640, 480)

_SEGMENT_NAME = re.compile(r'^[A-Za-z][A-Za-z0-9_]*$')
_SCENE_NAME = re.compile(r'^[A-Za-z0-9][A-Za-z0-9_.-]*$')
# Tokens that mark where a key's unit suffix starts (``flow_rate_m3_per_s`` -> ``flow_rate``).
_UNIT_TOKENS = frozenset({
    'm', 'mm', 'cm', 'um', 'km', 'm3', 'mm3', 'cm3', 'ml', 'l', 'cc', 'pa', 'kpa', 'mpa', 'gpa',
    'bar', 'mbar', 'psi', 's', 'ms', 'min', 'h', 'hz', 'khz', 'per', 'deg', 'rad', 'px',
})
_MODELS = ('table', 'design', 'linear', 'balloon')
_NUMBER = (int, float)


class SceneError(ValueError):
    """A scene file that cannot be used; the message is ``<file>: <key path>: <problem>``."""


@dataclass(frozen=True)
class PumpSettings:
    """The pump programme and the rate [Hz] at which the pump node publishes."""

    profile: PumpProfile
    rate_hz: float


@dataclass(frozen=True)
class CameraSettings:
    """
    The emulated camera.

    It publishes poses at ``rate_hz`` [Hz] with Gaussian noise of ``noise_std_m`` [m] on every
    backbone point (seeded by ``seed``), and takes one extra snapshot each time the injected
    volume crosses a value of ``trigger_injected_m3`` [m^3] (the paper's numbered steps).
    """

    rate_hz: float = DEFAULT_CAMERA_RATE_HZ
    noise_std_m: float = 0.0
    seed: int = 0
    trigger_injected_m3: tuple[float, ...] = ()
    points_per_segment: int = DEFAULT_POINTS_PER_SEGMENT
    image_width_px: int = DEFAULT_IMAGE_SIZE_PX[0]
    image_height_px: int = DEFAULT_IMAGE_SIZE_PX[1]


@dataclass(frozen=True)
class SolverSettings:
    """Equilibrium solver options; ``resolution`` None keeps the solver's default."""

    resolution: int | None = None


@dataclass(frozen=True)
class Scene:
    """A loaded, validated scene. ``segments`` run from the base to the tip."""

    name: str
    description: str
    path: Path | None
    segments: tuple[Segment, ...]
    pump: PumpSettings
    camera: CameraSettings
    outputs: frozenset[str]
    solver: SolverSettings

    @property
    def segment_names(self) -> tuple[str, ...]:
        """Segment names, base to tip."""
        return tuple(segment.name for segment in self.segments)

    @property
    def lengths(self) -> tuple[float, ...]:
        """Segment lengths [m], base to tip."""
        return tuple(segment.length for segment in self.segments)

    @property
    def capacity(self) -> float:
        """Largest injected volume the segments can hold together [m^3]."""
        return sum(segment.max_volume - segment.rest_volume for segment in self.segments)


# ----------------------------------------------------------------------------------------------
# Finding scenes


def config_dir_candidates() -> list[Path]:
    """Folders searched for shipped scenes: source checkout, ament prefixes, sys.prefix."""
    candidates = [Path(__file__).resolve().parents[2] / 'config']
    for prefix in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep):
        if prefix:
            candidates.append(Path(prefix) / 'share' / PACKAGE / 'config')
    candidates.append(Path(sys.prefix) / 'share' / PACKAGE / 'config')
    return candidates


def config_dir() -> Path:
    """
    The folder of the shipped scenes.

    In a source checkout this is ``<repo>/config``; in an installed package it is
    ``<prefix>/share/softseq_ros/config``. Raises SceneError when neither exists.
    """
    candidates = config_dir_candidates()
    for candidate in candidates:
        if (candidate / 'paper.yaml').is_file():
            return candidate
    looked = ', '.join(str(c) for c in candidates)
    raise SceneError(f'no shipped config folder found (looked in {looked})')


def shipped_scenes() -> list[str]:
    """Names of the shipped scenes (``paper``, ...), sorted."""
    return sorted(path.stem for path in config_dir().glob('*.yaml'))


def scene_path(name_or_path: str | Path) -> Path:
    """
    Resolve a scene argument: an existing file, or a bare name like ``paper``.

    A bare name (no folder, no suffix) means ``<config_dir()>/<name>.yaml``.
    """
    path = Path(name_or_path)
    if path.is_file():
        return path
    text = str(name_or_path)
    is_bare = path.suffix == '' and os.sep not in text and '/' not in text
    if is_bare and text:
        shipped = config_dir() / f'{text}.yaml'
        if shipped.is_file():
            return shipped
        known = ', '.join(shipped_scenes())
        raise SceneError(f'{text}: no such scene file and no shipped scene of that name '
                         f'(shipped: {known})')
    raise SceneError(f'{text}: scene file not found')


# ----------------------------------------------------------------------------------------------
# YAML reading


class _SceneLoader(yaml.SafeLoader):
    """Safe loader that reads ``5e-8`` as a number and refuses duplicate keys."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:
        """Build a mapping, raising on a key given twice (YAML would keep the last silently)."""
        seen = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=True)
            if isinstance(key, (str, int, float, bool)) and key in seen:
                raise yaml.constructor.ConstructorError(
                    None, None, f'duplicate key {key!r}', key_node.start_mark)
            if isinstance(key, (str, int, float, bool)):
                seen.add(key)
        return super().construct_mapping(node, deep=deep)


# YAML 1.1 needs a dot in a float (5.0e-8); scene authors write 5e-8, so accept that too.
_SceneLoader.add_implicit_resolver(
    'tag:yaml.org,2002:float',
    re.compile(r'^[-+]?[0-9][0-9_]*(?:\.[0-9_]*)?[eE][-+]?[0-9]+$'),
    list('-+0123456789'))


def _read_yaml(path: Path, shown: str) -> Any:
    try:
        text = path.read_text(encoding='utf-8')
    except OSError as err:
        raise SceneError(f'{shown}: cannot read the scene file ({err.strerror})') from None
    except UnicodeDecodeError:
        raise SceneError(f'{shown}: not a UTF-8 text file') from None
    try:
        return yaml.load(text, Loader=_SceneLoader)  # noqa: S506 (a SafeLoader subclass)
    except yaml.MarkedYAMLError as err:
        mark = err.problem_mark or err.context_mark
        where = f'line {mark.line + 1}, column {mark.column + 1}' if mark else 'YAML'
        problem = err.problem or err.context or 'invalid YAML'
        raise SceneError(f'{shown}: {where}: {problem}') from None
    except yaml.YAMLError as err:
        raise SceneError(f'{shown}: YAML: {" ".join(str(err).split())}') from None


# ----------------------------------------------------------------------------------------------
# Typed access with key paths


class _Context:
    """The file being read, for error messages and relative paths."""

    def __init__(self, shown: str, folder: Path) -> None:
        self.shown = shown
        self.folder = folder

    def error(self, key_path: str, problem: str) -> SceneError:
        one_line = ' '.join(str(problem).split())
        return SceneError(f'{self.shown}: {key_path or "(top level)"}: {one_line}')


def _join(key_path: str, key: str) -> str:
    return f'{key_path}.{key}' if key_path else key


def _unit_stem(key: str) -> str:
    tokens = key.lower().split('_')
    for index, token in enumerate(tokens[1:], start=1):
        if token in _UNIT_TOKENS:
            return '_'.join(tokens[:index])
    return '_'.join(tokens)


def _type_name(value: object) -> str:
    return 'null' if value is None else type(value).__name__


def _mapping(ctx: _Context, value: object, key_path: str, required: tuple[str, ...],
             optional: tuple[str, ...] = ()) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise ctx.error(key_path, f'must be a mapping, got {_type_name(value)}')
    allowed = required + optional
    for key in value:
        if not isinstance(key, str):
            raise ctx.error(key_path, f'keys must be text, got {key!r} ({_type_name(key)}); '
                                      'quote it')
        if key in allowed:
            continue
        stem = _unit_stem(key)
        same_quantity = [name for name in allowed if _unit_stem(name) == stem]
        if same_quantity:
            raise ctx.error(_join(key_path, key),
                            f'wrong or missing unit suffix; scene files use SI units, write '
                            f'{same_quantity[0]}')
        raise ctx.error(_join(key_path, key), f'unknown key; expected one of {", ".join(allowed)}')
    for key in required:
        if key not in value:
            raise ctx.error(_join(key_path, key), 'required key is missing')
    return value


def _number(ctx: _Context, value: object, key_path: str, *, gt: float | None = None,
            ge: float | None = None) -> float:
    if isinstance(value, bool) or not isinstance(value, _NUMBER):
        raise ctx.error(key_path, f'must be a number, got {_type_name(value)} {value!r}')
    number = float(value)
    if not math.isfinite(number):
        raise ctx.error(key_path, f'must be finite, got {number}')
    if gt is not None and not number > gt:
        raise ctx.error(key_path, f'must be > {gt:g}, got {number:g}')
    if ge is not None and not number >= ge:
        raise ctx.error(key_path, f'must be >= {ge:g}, got {number:g}')
    return number


def _integer(ctx: _Context, value: object, key_path: str, *, ge: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ctx.error(key_path, f'must be an integer, got {_type_name(value)} {value!r}')
    if ge is not None and value < ge:
        raise ctx.error(key_path, f'must be >= {ge}, got {value}')
    return value


def _limited(ctx: _Context, value: object, key_path: str, limit_key: str | None = None, *,
             integer: bool = False) -> float:
    """A number within its entry of LIMITS (by default the entry of ``key_path`` itself)."""
    number = _integer(ctx, value, key_path) if integer else _number(ctx, value, key_path)
    reason = LIMITS[limit_key or key_path].reason(number)
    if reason is not None:
        raise ctx.error(key_path, reason)
    return number


def _text(ctx: _Context, value: object, key_path: str) -> str:
    if not isinstance(value, str):
        raise ctx.error(key_path, f'must be text, got {_type_name(value)} {value!r}')
    return value


def _list(ctx: _Context, value: object, key_path: str) -> list:
    if not isinstance(value, list):
        raise ctx.error(key_path, f'must be a list, got {_type_name(value)}')
    return value


# ----------------------------------------------------------------------------------------------
# Sections


def _material(ctx: _Context, value: object, key_path: str) -> Any:
    if not isinstance(value, dict):
        raise ctx.error(key_path, f'must be a mapping, got {_type_name(value)}')
    if 'law' not in value:
        raise ctx.error(_join(key_path, 'law'), f'required key is missing; one of '
                                                f'{", ".join(LAW_NAMES)}')
    law = _text(ctx, value['law'], _join(key_path, 'law'))
    if law not in LAW_NAMES:
        raise ctx.error(_join(key_path, 'law'),
                        f'unknown material law {law!r}; expected one of {", ".join(LAW_NAMES)}')
    names = material_parameter_names(law)
    required = tuple(n for n in names if not (law == 'yeoh' and n == 'c3_pa'))
    optional = tuple(n for n in names if n not in required)
    params = _mapping(ctx, value, key_path, ('law',) + required, optional)
    checked: dict[str, object] = {}
    for key in names:
        if key not in params:
            continue
        where = _join(key_path, key)
        if law == 'ogden':
            items = _list(ctx, params[key], where)
            if not items:
                raise ctx.error(where, 'must list at least one value')
            checked[key] = [_number(ctx, item, f'{where}[{i}]') for i, item in enumerate(items)]
        elif key == 'jm' or key == 'lambda_m':
            checked[key] = _number(ctx, params[key], where, gt=0.0)
        elif key in ('shear_modulus_pa', 'c1_pa'):
            checked[key] = _number(ctx, params[key], where, gt=0.0)
        else:
            checked[key] = _number(ctx, params[key], where)
    if law == 'ogden' and len(checked['mu_pa']) != len(checked['alpha']):
        raise ctx.error(_join(key_path, 'alpha'),
                        f'needs as many values as mu_pa ({len(checked["mu_pa"])}), '
                        f'got {len(checked["alpha"])}')
    try:
        return make_material(law, checked)
    except ValueError as err:
        raise ctx.error(key_path, str(err)) from None


def _segment(ctx: _Context, value: object, key_path: str) -> Segment:
    raw = _mapping(ctx, value, key_path, ('name', 'length_m'), _MODELS + ('smoothing',))
    name = _text(ctx, raw['name'], _join(key_path, 'name'))
    if not _SEGMENT_NAME.match(name):
        raise ctx.error(_join(key_path, 'name'),
                        f'must start with a letter and hold only letters, digits and _, '
                        f'got {name!r}')
    length = _number(ctx, raw['length_m'], _join(key_path, 'length_m'), gt=0.0)
    models = [model for model in _MODELS if model in raw]
    if len(models) != 1:
        found = ', '.join(models) if models else 'none'
        raise ctx.error(key_path, f'needs exactly one model key out of {", ".join(_MODELS)}; '
                                  f'found {found}')
    model = models[0]
    where = _join(key_path, model)
    spec = raw[model]
    if 'smoothing' in raw and model != 'table':
        raise ctx.error(_join(key_path, 'smoothing'), 'only a table can be smoothed')
    try:
        if model == 'table':
            relative = _text(ctx, spec, where)
            table = (ctx.folder / relative) if not Path(relative).is_absolute() else Path(relative)
            if not table.is_file():
                raise ctx.error(where, f'file not found: {table}')
            segment = read_table(table, name=name, length=length)
            if 'smoothing' not in raw:
                return segment
            return _smoothed(ctx, raw['smoothing'], _join(key_path, 'smoothing'), segment)
        if model == 'design':
            return _designed(ctx, _text(ctx, spec, where), where, name, length,
                             _join(key_path, 'length_m'))
        gain_key = 'curvature_per_m_per_m3'
        if model == 'linear':
            params = _mapping(ctx, spec, where,
                              ('rest_volume_m3', 'stiffness_pa_per_m3', 'max_volume_m3'),
                              (gain_key,))
            rest = _number(ctx, params['rest_volume_m3'], _join(where, 'rest_volume_m3'), ge=0.0)
            stiffness = _number(ctx, params['stiffness_pa_per_m3'],
                                _join(where, 'stiffness_pa_per_m3'), gt=0.0)
            max_volume = _number(ctx, params['max_volume_m3'], _join(where, 'max_volume_m3'),
                                 gt=rest)
            gain = _number(ctx, params.get(gain_key, 0.0), _join(where, gain_key))
            return LinearSegment(name, length, rest, stiffness, max_volume, curvature_gain=gain)
        params = _mapping(ctx, spec, where,
                          ('material', 'radius_m', 'thickness_m', 'max_stretch'), (gain_key,))
        material = _material(ctx, params['material'], _join(where, 'material'))
        radius = _number(ctx, params['radius_m'], _join(where, 'radius_m'), gt=0.0)
        thickness = _number(ctx, params['thickness_m'], _join(where, 'thickness_m'), gt=0.0)
        max_stretch = _number(ctx, params['max_stretch'], _join(where, 'max_stretch'), gt=1.0)
        if max_stretch >= material.max_stretch:
            raise ctx.error(_join(where, 'max_stretch'),
                            f'must be below the stretch at which the material locks '
                            f'({material.max_stretch:.6g}), got {max_stretch:g}')
        gain = _number(ctx, params.get(gain_key, 0.0), _join(where, gain_key))
        return BalloonSegment(name, length, material, radius, thickness, max_stretch,
                              curvature_gain=gain)
    except SceneError:
        raise
    except ValueError as err:
        # The segment models check their own consistency; keep their words, add the key path.
        raise ctx.error(where, str(err)) from None


def _designed(ctx: _Context, text: str, where: str, name: str, length: float,
              length_key: str) -> TabulatedSegment:
    """The segment of a design file (softseq_ros.scene.design): its FEM table, cached."""
    # Imported here: the design module reads its files with this module's helpers.
    from softseq_ros.scene.design import DesignError, cached_table, design_path, load_design

    relative = Path(text)
    beside = relative if relative.is_absolute() else ctx.folder / relative
    try:
        design = load_design(beside if beside.is_file() else design_path(text))
        table = cached_table(design)
    except DesignError as err:
        raise ctx.error(where, str(err)) from None
    if not math.isclose(length, design.geometry.length_m, rel_tol=1e-9):
        raise ctx.error(length_key, f"{length:g} m differs from the design's geometry.length_m "
                                    f'({design.geometry.length_m:g} m)')
    return read_table(table, name=name, length=length, design=design.identity())


def _smoothed(ctx: _Context, value: object, key_path: str,
              segment: TabulatedSegment) -> TabulatedSegment:
    """
    A measured table with its noise smoothed (opt-in: ``smoothing: {}`` or with parameters).

    See :func:`softseq_ros.segments.smoothing.smooth_table`: ``noise_std_pa`` (estimated from
    the rows when absent) and ``prominence_pa``, the smallest peak or valley kept (6 noise
    deviations when absent).
    """
    options = _mapping(ctx, {} if value is None else value, key_path, (),
                       ('noise_std_pa', 'prominence_pa'))
    noise = options.get('noise_std_pa')
    prominence = options.get('prominence_pa')
    try:
        pressures = smooth_table(
            segment.volumes, segment.pressures,
            noise_std=None if noise is None else _number(
                ctx, noise, _join(key_path, 'noise_std_pa'), ge=0.0),
            prominence=None if prominence is None else _number(
                ctx, prominence, _join(key_path, 'prominence_pa'), ge=0.0))
    except SceneError:
        raise
    except ValueError as err:
        raise ctx.error(key_path, str(err)) from None
    return segment.smoothed(pressures, noise_std_pa=noise, prominence_pa=prominence)


def _segments(ctx: _Context, value: object) -> tuple[Segment, ...]:
    items = _list(ctx, value, 'segments')
    if len(items) < 2:
        raise ctx.error('segments', f'needs at least 2 segments (base to tip), got {len(items)}')
    segments = []
    seen: dict[str, int] = {}
    for index, item in enumerate(items):
        key_path = f'segments[{index}]'
        segment = _segment(ctx, item, key_path)
        if segment.name in seen:
            raise ctx.error(_join(key_path, 'name'),
                            f'{segment.name!r} is already used by segments[{seen[segment.name]}]')
        seen[segment.name] = index
        segments.append(segment)
    return tuple(segments)


def _pump(ctx: _Context, value: object, capacity: float) -> PumpSettings:
    raw = _mapping(ctx, value, 'pump', ('legs',),
                   ('flow_rate_m3_per_s', 'rate_hz', 'cycles', 'start_injected_m3'))
    flow = _limited(ctx, raw.get('flow_rate_m3_per_s', DEFAULT_FLOW_RATE),
                    'pump.flow_rate_m3_per_s')
    rate = _limited(ctx, raw.get('rate_hz', DEFAULT_PUMP_RATE_HZ), 'pump.rate_hz')
    cycles = int(_limited(ctx, raw.get('cycles', 1), 'pump.cycles', integer=True))
    start = _number(ctx, raw.get('start_injected_m3', 0.0), 'pump.start_injected_m3', ge=0.0)
    items = _list(ctx, raw['legs'], 'pump.legs')
    if not items:
        raise ctx.error('pump.legs', 'needs at least one leg')
    legs = []
    for index, item in enumerate(items):
        key_path = f'pump.legs[{index}]'
        leg_keys = ('inflate_to_m3', 'deflate_to_m3', 'hold_s')
        if isinstance(item, dict) and len(item) != 1:
            raise ctx.error(key_path, f'needs exactly one of {", ".join(leg_keys)}, '
                                      f'got {len(item)} keys')
        leg = _mapping(ctx, item, key_path, (), leg_keys)
        if not leg:
            raise ctx.error(key_path, f'needs exactly one of {", ".join(leg_keys)}')
        (key, amount), = leg.items()
        where = _join(key_path, key)
        if key == 'hold_s':
            legs.append(Leg.hold(_limited(ctx, amount, where, 'pump.legs.hold_s')))
            continue
        target = _number(ctx, amount, where, ge=0.0)
        legs.append(Leg.inflate(target) if key == 'inflate_to_m3' else Leg.deflate(target))
    # Walk the programme as the pump will, so a leg that cannot run names its own key. Every
    # cycle after the first starts where the one before ended, so two cycles show them all.
    now = start
    for cycle in range(1, min(cycles, 2) + 1):
        for index, leg in enumerate(legs):
            if leg.action == 'hold':
                continue
            where = f'pump.legs[{index}].{leg.action}_to_m3'
            in_cycle = f' in cycle {cycle}' if cycles > 1 else ''
            if leg.action == 'inflate' and not leg.to_m3 > now:
                raise ctx.error(where, f'{leg.to_m3:g} m^3 must be above the injected volume '
                                       f'the leg starts from ({now:g} m^3{in_cycle})')
            if leg.action == 'deflate' and not leg.to_m3 < now:
                raise ctx.error(where, f'{leg.to_m3:g} m^3 must be below the injected volume '
                                       f'the leg starts from ({now:g} m^3{in_cycle})')
            now = leg.to_m3
    try:
        profile = PumpProfile(legs=tuple(legs), flow_rate=flow, cycles=cycles,
                              start_injected=start)
    except ValueError as err:
        raise ctx.error('pump', str(err)) from None
    try:
        check_capacity(profile, capacity, 'pump.')
    except ProgrammeError as err:
        raise ctx.error(err.key, err.reason) from None
    return PumpSettings(profile=profile, rate_hz=rate)


def _camera(ctx: _Context, value: object, pump: PumpProfile) -> CameraSettings:
    if value is None:
        return CameraSettings()
    raw = _mapping(ctx, value, 'camera', (),
                   ('rate_hz', 'noise_std_m', 'seed', 'trigger_injected_m3', 'points_per_segment',
                    'image_width_px', 'image_height_px'))
    defaults = CameraSettings()
    rate = _limited(ctx, raw.get('rate_hz', defaults.rate_hz), 'camera.rate_hz')
    noise = _limited(ctx, raw.get('noise_std_m', defaults.noise_std_m), 'camera.noise_std_m')
    seed = int(_limited(ctx, raw.get('seed', defaults.seed), 'camera.seed', integer=True))
    triggers = []
    items = _list(ctx, raw.get('trigger_injected_m3', []), 'camera.trigger_injected_m3')
    reach = pump.max_injected()
    for index, item in enumerate(items):
        where = f'camera.trigger_injected_m3[{index}]'
        trigger = _number(ctx, item, where, ge=0.0)
        if triggers and not trigger > triggers[-1]:
            raise ctx.error(where, f'triggers must increase; {trigger:g} does not exceed '
                                   f'{triggers[-1]:g}')
        if trigger > reach:
            raise ctx.error(where, f'{trigger:g} m^3 is never reached: the pump goes up to '
                                   f'{reach:g} m^3')
        triggers.append(trigger)
    points = int(_limited(ctx, raw.get('points_per_segment', defaults.points_per_segment),
                          'camera.points_per_segment', integer=True))
    width = int(_limited(ctx, raw.get('image_width_px', defaults.image_width_px),
                         'camera.image_width_px', integer=True))
    height = int(_limited(ctx, raw.get('image_height_px', defaults.image_height_px),
                          'camera.image_height_px', integer=True))
    return CameraSettings(rate_hz=rate, noise_std_m=noise, seed=seed,
                          trigger_injected_m3=tuple(triggers), points_per_segment=points,
                          image_width_px=width, image_height_px=height)


def _outputs(ctx: _Context, value: object) -> frozenset[str]:
    if value is None:
        return DEFAULT_OUTPUTS
    items = _list(ctx, value, 'outputs')
    names: list[str] = []
    for index, item in enumerate(items):
        where = f'outputs[{index}]'
        name = _text(ctx, item, where)
        if name not in OUTPUT_NAMES:
            raise ctx.error(where, f'unknown output {name!r}; expected some of '
                                   f'{", ".join(OUTPUT_NAMES)}')
        if name in names:
            raise ctx.error(where, f'{name!r} is listed twice')
        names.append(name)
    return frozenset(names)


def _solver(ctx: _Context, value: object) -> SolverSettings:
    if value is None:
        return SolverSettings()
    raw = _mapping(ctx, value, 'solver', (), ('resolution',))
    resolution = raw.get('resolution')
    if resolution is None:
        return SolverSettings()
    return SolverSettings(resolution=int(_limited(ctx, resolution, 'solver.resolution',
                                                  integer=True)))


# ----------------------------------------------------------------------------------------------
# Entry points


def scene_from_dict(data: object, path: str | Path | None = None) -> Scene:
    """
    Build a scene from already parsed YAML.

    ``path`` is the scene file the data came from: it names the file in errors and table paths
    are relative to its folder (the current folder when ``path`` is None).
    """
    shown = str(path) if path is not None else '<scene>'
    folder = Path(path).parent if path is not None else Path('.')
    ctx = _Context(shown, folder)
    raw = _mapping(ctx, data, '', ('name', 'segments', 'pump'),
                   ('description', 'camera', 'outputs', 'solver'))
    name = _text(ctx, raw['name'], 'name')
    if not _SCENE_NAME.match(name):
        raise ctx.error('name', f'must start with a letter or digit and hold only letters, '
                                f'digits, _, - and ., got {name!r}')
    description = raw.get('description', '')
    description = ' '.join(_text(ctx, description, 'description').split()) if description else ''
    segments = _segments(ctx, raw['segments'])
    capacity = sum(segment.max_volume - segment.rest_volume for segment in segments)
    pump = _pump(ctx, raw['pump'], capacity)
    camera = _camera(ctx, raw.get('camera'), pump.profile)
    outputs = _outputs(ctx, raw.get('outputs'))
    solver = _solver(ctx, raw.get('solver'))
    return Scene(name=name, description=description,
                 path=Path(path) if path is not None else None, segments=segments, pump=pump,
                 camera=camera, outputs=outputs, solver=solver)


def load_scene(path: str | Path) -> Scene:
    """
    Load and validate a scene file, or a shipped scene by its bare name (``paper``).

    Raises SceneError with one line ``<file>: <key path>: <problem>``.
    """
    resolved = scene_path(path)
    return scene_from_dict(_read_yaml(resolved, str(resolved)), resolved)
