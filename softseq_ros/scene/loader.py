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
      start_injected_m3: 0.0          # or start_history_m3: [...], or start_branch: N
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
    network:                          # optional: time in the physics (scene/network.py)
      channels: [{length_m: 0.01, radius_m: 0.25e-3}]   # one per neighbouring pair

Every key with its unit, default and range: docs/scene_reference.md (softseq_ros.scene.reference).
Every mistake raises ``SceneError`` with one line ``<file>: <key path>: <what is wrong>``, e.g.
``config/x.yaml: segments[1].length_m: must be > 0, got -0.1``.
"""

from dataclasses import dataclass
import math
from pathlib import Path
from typing import Callable, Protocol, Sequence

from softseq_ros.errors import UserError, not_a_file
from softseq_ros.scene.csv_columns import read_columns
from softseq_ros.scene.design import (
    SAME_LENGTH_RTOL,
    DesignError,
    cached_table,
    design_path,
    load_design,
)
from softseq_ros.scene.network import (
    NO_REGULATOR_TUBE,
    NO_SUPPLY_TUBE,
    NetworkSettings,
    read_network,
)
from softseq_ros.scene.outputs import DEFAULT_OUTPUTS, OUTPUT_NAMES
from softseq_ros.scene.paths import scene_path
from softseq_ros.scene.plausibility import segment_problem
from softseq_ros.scene.programme import (
    DEFAULT_FLOW_RATE,
    Leg,
    ProgrammeError,
    PumpProfile,
    breakpoints_problem,
    check_capacity,
)
from softseq_ros.scene.regulator import Regulator, read_regulator
from softseq_ros.scene.tables import read_table
from softseq_ros.scene.validation import (
    SCENE_NAME,
    SEGMENT_NAME,
    Context,
    SceneError,
    join,
    parse_yaml,
    read_yaml,
)
from softseq_ros.segments.models import BalloonSegment, LinearSegment, Segment, TabulatedSegment
from softseq_ros.segments.smoothing import smooth_table
from softseq_ros.segments.supply import STANDARD_AMBIENT_PA, CompliantSupply

DEFAULT_PUMP_RATE_HZ = 50.0
DEFAULT_CAMERA_RATE_HZ = 10.0
DEFAULT_POINTS_PER_SEGMENT = 20
DEFAULT_IMAGE_SIZE_PX = (640, 480)

_MODELS = ('table', 'design', 'linear', 'balloon')
_NUMBER = (int, float)


class BranchReach(Protocol):
    """How a volume history from rest reaches a branch (quasistatic.graph.Reach)."""

    reversals: int | None        # None: no history reaches the branch
    history: tuple[float, ...]   # injected volumes [m^3], from rest, ending on the branch
    reason: str


class BranchGraph(Protocol):
    """What the loader reads of a transition graph (quasistatic.graph.TransitionGraph)."""

    branches: Sequence[object]

    def history_to(self, target: int) -> BranchReach:
        """One shortest volume history from rest onto branch ``target``, or why none."""


# The transition graph of segments at a solver resolution behind a supply line, numbered as
# `softseq graph` numbers it (softseq_ros.quasistatic.solve.segments_graph). The scene layer
# knows no solver, so whoever reads a scene that may name a branch hands this in.
GraphOf = Callable[[tuple[Segment, ...], int | None, CompliantSupply | None], BranchGraph]

_START_BRANCH_KEY = 'pump.start_branch'
REGULATOR_KEY = 'regulator'

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
    pump: PumpSettings | None
    camera: CameraSettings
    outputs: frozenset[str]
    solver: SolverSettings
    network: NetworkSettings | None = None
    supply: CompliantSupply | None = None
    # A pressure regulator in place of the syringe (its programme from the ``pump`` block);
    # ``pump`` is then None.
    regulator: Regulator | None = None

    @property
    def segment_names(self) -> tuple[str, ...]:
        """Segment names, base to tip."""
        return tuple(segment.name for segment in self.segments)

    @property
    def members(self) -> tuple[Segment, ...]:
        """
        What the physics is made of: the segments, and the supply line when there is one.

        Their digest (softseq_ros.segments.identity.segments_sha256) names the physics a bag
        was recorded with.
        """
        return self.segments + (() if self.supply is None else (self.supply,))

    @property
    def lengths(self) -> tuple[float, ...]:
        """Segment lengths [m], base to tip."""
        return tuple(segment.length for segment in self.segments)

    @property
    def capacity(self) -> float:
        """Largest injected volume the segments can hold together [m^3]."""
        return sum(segment.max_volume - segment.rest_volume for segment in self.segments)


# ----------------------------------------------------------------------------------------------
# Sections


def _segment(ctx: Context, value: object, key_path: str) -> Segment:
    raw = ctx.mapping(value, key_path, ('name', 'length_m'), _MODELS + ('smoothing',))
    name = ctx.text(raw['name'], join(key_path, 'name'))
    if not SEGMENT_NAME.match(name):
        raise ctx.error(join(key_path, 'name'),
                        f'must start with a letter and hold only letters, digits and _, '
                        f'got {name!r}')
    length = ctx.limited(raw['length_m'], join(key_path, 'length_m'), 'segments.length_m')
    models = [model for model in _MODELS if model in raw]
    if len(models) != 1:
        found = ', '.join(models) if models else 'none'
        raise ctx.error(key_path, f'needs exactly one model key out of {", ".join(_MODELS)}; '
                                  f'found {found}')
    model = models[0]
    where = join(key_path, model)
    spec = raw[model]
    if 'smoothing' in raw and model != 'table':
        raise ctx.error(join(key_path, 'smoothing'), 'only a table can be smoothed')
    try:
        if model == 'table':
            relative = ctx.text(spec, where)
            table = (ctx.folder / relative) if not Path(relative).is_absolute() else Path(relative)
            if not table.is_file():
                why = not_a_file(table, 'file')
                raise ctx.error(where, f'file not found: {table}' if why == 'file not found'
                                else f'{table}: {why}')
            segment = read_table(table, name=name, length=length)
            if 'smoothing' not in raw:
                return segment
            return _smoothed(ctx, raw['smoothing'], join(key_path, 'smoothing'), segment)
        if model == 'design':
            return _designed(ctx, ctx.text(spec, where), where, name, length,
                             join(key_path, 'length_m'))
        gain_key = 'curvature_per_m_per_m3'
        if model == 'linear':
            params = ctx.mapping(spec, where,
                              ('rest_volume_m3', 'stiffness_pa_per_m3', 'max_volume_m3'),
                              (gain_key,))
            rest = ctx.number(params['rest_volume_m3'], join(where, 'rest_volume_m3'), ge=0.0)
            stiffness = ctx.number(params['stiffness_pa_per_m3'],
                                join(where, 'stiffness_pa_per_m3'), gt=0.0)
            max_volume = ctx.number(params['max_volume_m3'], join(where, 'max_volume_m3'),
                                 gt=rest)
            gain = ctx.number(params.get(gain_key, 0.0), join(where, gain_key))
            return _plausible(ctx, where, LinearSegment(name, length, rest, stiffness, max_volume,
                                                        curvature_gain=gain))
        params = ctx.mapping(spec, where,
                          ('material', 'radius_m', 'thickness_m', 'max_stretch'), (gain_key,))
        material = ctx.material(params['material'], join(where, 'material'))
        radius = ctx.number(params['radius_m'], join(where, 'radius_m'), gt=0.0)
        thickness = ctx.number(params['thickness_m'], join(where, 'thickness_m'), gt=0.0)
        max_stretch = ctx.number(params['max_stretch'], join(where, 'max_stretch'), gt=1.0)
        if max_stretch >= material.max_stretch:
            raise ctx.error(join(where, 'max_stretch'),
                            f'must be below the stretch at which the material locks '
                            f'({material.max_stretch:.6g}), got {max_stretch:g}')
        gain = ctx.number(params.get(gain_key, 0.0), join(where, gain_key))
        return _plausible(ctx, where, BalloonSegment(name, length, material, radius, thickness,
                                                     max_stretch, curvature_gain=gain))
    except SceneError:
        raise
    except ValueError as err:
        # The segment models check their own consistency; keep their words, add the key path.
        raise ctx.error(where, str(err)) from None


def _plausible(ctx: Context, where: str, segment: Segment) -> Segment:
    """``segment``, unless its volumes or its curve are no soft segment's in SI units."""
    problem = segment_problem(segment)
    if problem is not None:
        raise ctx.error(where, problem)
    return segment


def _designed(ctx: Context, text: str, where: str, name: str, length: float,
              length_key: str) -> TabulatedSegment:
    """The segment of a design file (softseq_ros.scene.design): its FEM table, cached."""
    relative = Path(text)
    beside = relative if relative.is_absolute() else ctx.folder / relative
    try:
        design = load_design(beside if beside.is_file() else design_path(text))
        table = cached_table(design)
    except DesignError as err:
        raise ctx.error(where, str(err)) from None
    if not math.isclose(length, design.geometry.length_m, rel_tol=SAME_LENGTH_RTOL):
        raise ctx.error(length_key, f"{length:g} m differs from the design's geometry.length_m "
                                    f'({design.geometry.length_m:g} m)')
    return read_table(table, name=name, length=length, design=design.identity())


def _smoothed(ctx: Context, value: object, key_path: str,
              segment: TabulatedSegment) -> TabulatedSegment:
    """
    A measured table with its noise smoothed (opt-in: ``smoothing: {}`` or with parameters).

    See :func:`softseq_ros.segments.smoothing.smooth_table`: ``noise_std_pa`` (estimated from
    the rows when absent) and ``prominence_pa``, the smallest peak or valley kept (6 noise
    deviations when absent).
    """
    options = ctx.mapping({} if value is None else value, key_path, (),
                       ('noise_std_pa', 'prominence_pa'))
    noise = options.get('noise_std_pa')
    prominence = options.get('prominence_pa')
    try:
        pressures = smooth_table(
            segment.volumes, segment.pressures,
            noise_std=None if noise is None else ctx.number(
                noise, join(key_path, 'noise_std_pa'), ge=0.0),
            prominence=None if prominence is None else ctx.number(
                prominence, join(key_path, 'prominence_pa'), ge=0.0))
    except SceneError:
        raise
    except ValueError as err:
        raise ctx.error(key_path, str(err)) from None
    return segment.smoothed(pressures, noise_std_pa=noise, prominence_pa=prominence)


def _segments(ctx: Context, value: object) -> tuple[Segment, ...]:
    items = ctx.sequence(value, 'segments')
    if len(items) < 2:
        raise ctx.error('segments', f'needs at least 2 segments (base to tip), got {len(items)}')
    segments = []
    seen: dict[str, int] = {}
    for index, item in enumerate(items):
        key_path = f'segments[{index}]'
        segment = _segment(ctx, item, key_path)
        if segment.name in seen:
            raise ctx.error(join(key_path, 'name'),
                            f'{segment.name!r} is already used by segments[{seen[segment.name]}]')
        seen[segment.name] = index
        segments.append(segment)
    return tuple(segments)


LEG_KEYS = ('inflate_to_m3', 'deflate_to_m3', 'hold_s', 'profile')
LEG_RATE_KEY = 'flow_rate_m3_per_s'
PROFILE_COLUMNS = ('time_s', 'injected_m3')


def _profile_leg(ctx: Context, value: object, key_path: str) -> Leg:
    """A ``profile`` leg: a CSV of time_s against injected_m3, relative to the scene's folder."""
    relative = Path(ctx.text(value, key_path))
    path = relative if relative.is_absolute() else ctx.folder / relative
    try:
        columns = read_columns(path, PROFILE_COLUMNS, ProfileError, 'pump profile')
        return Leg.profile(columns['time_s'].tolist(), columns['injected_m3'].tolist(),
                           source=str(path))
    except ValueError as err:
        raise ctx.error(key_path, str(err)) from None


class ProfileError(UserError):
    """A pump profile file that cannot be read."""


def read_legs(ctx: Context, value: object, key_path: str) -> list[Leg]:
    """
    The legs of a pump programme from parsed YAML: a non-empty list of mappings.

    Each names one of :data:`LEG_KEYS`; an inflate or deflate leg may give its own
    ``flow_rate_m3_per_s`` beside it (the pump's otherwise).
    """
    items = ctx.sequence(value, key_path)
    if not items:
        raise ctx.error(key_path, 'needs at least one leg')
    legs = []
    for index, item in enumerate(items):
        where = f'{key_path}[{index}]'
        leg = ctx.mapping(item, where, (), LEG_KEYS + (LEG_RATE_KEY,))
        actions = [key for key in leg if key != LEG_RATE_KEY]
        if not actions:
            raise ctx.error(where, f'needs exactly one of {", ".join(LEG_KEYS)}')
        if len(actions) != 1:
            raise ctx.error(where, f'needs exactly one of {", ".join(LEG_KEYS)}, '
                                   f'got {len(actions)} keys ({", ".join(actions)})')
        key = actions[0]
        at = join(where, key)
        if key == 'profile':
            if LEG_RATE_KEY in leg:
                raise ctx.error(join(where, LEG_RATE_KEY),
                                'a profile leg moves at the rates of its own rows')
            legs.append(_profile_leg(ctx, leg[key], at))
            continue
        if key == 'hold_s':
            if LEG_RATE_KEY in leg:
                raise ctx.error(join(where, LEG_RATE_KEY),
                                'a hold leg moves nothing: give the rate on an inflate or '
                                'deflate leg')
            legs.append(Leg.hold(ctx.limited(leg[key], at, 'pump.legs.hold_s')))
            continue
        target = ctx.number(leg[key], at, ge=0.0)
        rate = (ctx.limited(leg[LEG_RATE_KEY], join(where, LEG_RATE_KEY),
                            'pump.flow_rate_m3_per_s') if LEG_RATE_KEY in leg else None)
        legs.append(Leg.inflate(target, rate) if key == 'inflate_to_m3'
                    else Leg.deflate(target, rate))
    return legs


def legs_from_text(text: str, key_path: str = 'legs') -> tuple[Leg, ...]:
    """
    Legs from YAML text in the scene's syntax, e.g. ``[{inflate_to_m3: 5e-6}, {hold_s: 2}]``.

    For settings given as text (the pump node's ``legs`` parameter); SceneError names the leg
    and key at fault (``legs[1].hold_s: ...``).
    """
    return tuple(read_legs(Context('', Path('.')), parse_yaml(text, key_path), key_path))


def _pump(ctx: Context, value: object, capacity: float,
          history_onto: Callable[[int], tuple[float, ...]]) -> PumpSettings:
    """
    The ``pump`` block; ``history_onto(branch)`` is the volume history a ``start_branch`` names.

    The programme starts from rest at ``start_injected_m3``, or where ``start_history_m3`` or
    the history onto ``start_branch`` leads: its legs are checked from there.
    """
    raw = ctx.mapping(value, 'pump', ('legs',),
                   ('flow_rate_m3_per_s', 'rate_hz', 'cycles', 'start_injected_m3',
                    'start_history_m3', 'start_branch'))
    flow = ctx.limited(raw.get('flow_rate_m3_per_s', DEFAULT_FLOW_RATE),
                    'pump.flow_rate_m3_per_s')
    rate = ctx.limited(raw.get('rate_hz', DEFAULT_PUMP_RATE_HZ), 'pump.rate_hz')
    cycles = int(ctx.limited(raw.get('cycles', 1), 'pump.cycles', integer=True))
    if 'start_branch' in raw:
        given = [key for key in ('start_injected_m3', 'start_history_m3') if key in raw]
        if given:
            raise ctx.error(_START_BRANCH_KEY,
                            f'the programme starts on the branch: give {given[0]} or this, '
                            'not both')
    start = ctx.number(raw.get('start_injected_m3', 0.0), 'pump.start_injected_m3', ge=0.0)
    history: tuple[float, ...] = ()
    if 'start_history_m3' in raw:
        if 'start_injected_m3' in raw:
            raise ctx.error('pump.start_history_m3', 'the programme starts where the history '
                                                    'ends: give start_injected_m3 or this, '
                                                    'not both')
        items = ctx.sequence(raw['start_history_m3'], 'pump.start_history_m3')
        if not items:
            raise ctx.error('pump.start_history_m3', 'needs at least one injected volume')
        history = tuple(ctx.number(v, f'pump.start_history_m3[{i}]', ge=0.0)
                        for i, v in enumerate(items))
        start = history[-1]
    if 'start_branch' in raw:
        history = history_onto(ctx.integer(raw['start_branch'], _START_BRANCH_KEY, ge=0))
        start = history[-1]
    legs = read_legs(ctx, raw['legs'], 'pump.legs')
    # Walk the programme as the pump will, so a leg that cannot run names its own key. Every
    # cycle after the first starts where the one before ended, so two cycles show them all.
    now = start
    for cycle in range(1, min(cycles, 2) + 1):
        for index, leg in enumerate(legs):
            if leg.action == 'hold':
                continue
            if leg.action == 'profile':
                if leg.volumes[0] != now:
                    raise ctx.error(f'pump.legs[{index}].profile',
                                    f'{leg.source}: the profile starts at {leg.volumes[0]:g} '
                                    f'm^3, not at the injected volume the leg starts from '
                                    f'({now:g} m^3{" in cycle 2" if cycle > 1 else ""})')
                now = leg.volumes[-1]
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
    too_long = breakpoints_problem(
        [len(leg.times) - 1 if leg.action == 'profile' else 1 for leg in legs], cycles)
    if too_long is not None:
        raise ctx.error('pump.cycles', too_long)
    try:
        profile = PumpProfile(legs=tuple(legs), flow_rate=flow, cycles=cycles,
                              start_injected=start, start_history=history)
    except ValueError as err:
        raise ctx.error('pump', str(err)) from None
    try:
        check_capacity(profile, capacity, 'pump.')
    except ProgrammeError as err:
        raise ctx.error(err.key, err.reason) from None
    return PumpSettings(profile=profile, rate_hz=rate)


def _history_onto_branch(ctx: Context, branch: int, graph_of: GraphOf | None,
                         segments: tuple[Segment, ...], solver: SolverSettings,
                         supply: CompliantSupply | None,
                         network: NetworkSettings | None) -> tuple[float, ...]:
    """
    The graph's shortest volume history from rest onto ``branch`` (``pump.start_branch``).

    It ends halfway between where it enters the branch and the end of the branch it moves
    towards (TransitionGraph.history_to, graph.json's ``history_injected_m3``): inside the
    branch, away from the joins and snaps at its ends. The graph is that of the scene's own
    map (its solver resolution and supply line), as ``softseq graph`` numbers it.
    """
    if graph_of is None:
        raise ctx.error(_START_BRANCH_KEY,
                        'names a branch of the transition graph, which this reader of scenes '
                        'cannot build: load the scene with softseq_ros.load_scene')
    graph = graph_of(segments, solver.resolution, supply)
    count = len(graph.branches)
    if branch >= count:
        numbers = '0' if count == 1 else f'0 to {count - 1}'
        raise ctx.error(_START_BRANCH_KEY,
                        f'branch {branch} does not exist: the graph of this scene has {count} '
                        f'branch{"" if count == 1 else "es"} ({numbers}), see softseq graph')
    reach = graph.history_to(branch)
    if reach.reversals is None:
        raise ctx.error(_START_BRANCH_KEY,
                        f'{reach.reason}; a programme cannot start there, see softseq graph')
    return tuple(reach.history)


def _camera(ctx: Context, value: object, reach: float) -> CameraSettings:
    """The camera; ``reach``: the most the programme injects [m^3], past every trigger."""
    if value is None:
        return CameraSettings()
    raw = ctx.mapping(value, 'camera', (),
                   ('rate_hz', 'noise_std_m', 'seed', 'trigger_injected_m3', 'points_per_segment',
                    'image_width_px', 'image_height_px'))
    defaults = CameraSettings()
    rate = ctx.limited(raw.get('rate_hz', defaults.rate_hz), 'camera.rate_hz')
    noise = ctx.limited(raw.get('noise_std_m', defaults.noise_std_m), 'camera.noise_std_m')
    seed = int(ctx.limited(raw.get('seed', defaults.seed), 'camera.seed', integer=True))
    triggers = []
    items = ctx.sequence(raw.get('trigger_injected_m3', []), 'camera.trigger_injected_m3')
    for index, item in enumerate(items):
        where = f'camera.trigger_injected_m3[{index}]'
        trigger = ctx.number(item, where, ge=0.0)
        if triggers and not trigger > triggers[-1]:
            raise ctx.error(where, f'triggers must increase; {trigger:g} does not exceed '
                                   f'{triggers[-1]:g}')
        if trigger > reach:
            raise ctx.error(where, f'{trigger:g} m^3 is never reached: the pump goes up to '
                                   f'{reach:g} m^3')
        triggers.append(trigger)
    points = int(ctx.limited(raw.get('points_per_segment', defaults.points_per_segment),
                          'camera.points_per_segment', integer=True))
    width = int(ctx.limited(raw.get('image_width_px', defaults.image_width_px),
                         'camera.image_width_px', integer=True))
    height = int(ctx.limited(raw.get('image_height_px', defaults.image_height_px),
                          'camera.image_height_px', integer=True))
    return CameraSettings(rate_hz=rate, noise_std_m=noise, seed=seed,
                          trigger_injected_m3=tuple(triggers), points_per_segment=points,
                          image_width_px=width, image_height_px=height)


def _outputs(ctx: Context, value: object) -> frozenset[str]:
    if value is None:
        return DEFAULT_OUTPUTS
    items = ctx.sequence(value, 'outputs')
    names: list[str] = []
    for index, item in enumerate(items):
        where = f'outputs[{index}]'
        name = ctx.text(item, where)
        if name not in OUTPUT_NAMES:
            raise ctx.error(where, f'unknown output {name!r}; expected some of '
                                   f'{", ".join(OUTPUT_NAMES)}')
        if name in names:
            raise ctx.error(where, f'{name!r} is listed twice')
        names.append(name)
    return frozenset(names)


# The supply line's member reaches this multiple of the highest pressure on any segment's
# curve: beyond every equilibrium of the segments, so it never ends the domain first.
SUPPLY_PRESSURE_MARGIN = 2.0


def _supply(ctx: Context, value: object, segments: tuple[Segment, ...]) -> CompliantSupply | None:
    """The ``supply`` block: the syringe line's trapped gas and compliance (docs/supply.md)."""
    if value is None:
        return None
    keys = ('trapped_gas_m3', 'line_compliance_m3_per_pa', 'ambient_pa', 'polytropic_exponent')
    raw = ctx.mapping(value, 'supply', (), keys + (REGULATOR_KEY,))
    numbers = {key: ctx.limited(raw[key], f'supply.{key}') for key in keys if key in raw}
    gas = numbers.get('trapped_gas_m3', 0.0)
    compliance = numbers.get('line_compliance_m3_per_pa', 0.0)
    if not gas > 0.0 and not compliance > 0.0:
        raise ctx.error('supply', 'give trapped_gas_m3 or line_compliance_m3_per_pa above 0, '
                                  'or a supply.regulator instead of the syringe (without any '
                                  'the syringe is ideal: leave the block out)')
    highest = max(max(abs(pc.p_at_lo), abs(pc.p_at_hi)) for s in segments
                  for pc in s.monotone_pieces())
    return CompliantSupply(gas, ambient_pa=numbers.get('ambient_pa', STANDARD_AMBIENT_PA),
                           polytropic_exponent=numbers.get('polytropic_exponent', 1.0),
                           line_compliance_m3_per_pa=compliance,
                           max_pressure_pa=SUPPLY_PRESSURE_MARGIN * highest)


def _solver(ctx: Context, value: object) -> SolverSettings:
    if value is None:
        return SolverSettings()
    raw = ctx.mapping(value, 'solver', (), ('resolution',))
    resolution = raw.get('resolution')
    if resolution is None:
        return SolverSettings()
    return SolverSettings(resolution=int(ctx.limited(resolution, 'solver.resolution',
                                                  integer=True)))


# ----------------------------------------------------------------------------------------------
# Entry points


def scene_from_dict(data: object, path: str | Path | None = None,
                    graph_of: GraphOf | None = None) -> Scene:
    """
    Build a scene from already parsed YAML.

    ``path`` is the scene file the data came from: it names the file in errors and table paths
    are relative to its folder (the current folder when ``path`` is None). ``graph_of`` builds
    the transition graph a ``pump.start_branch`` is looked up in; without it such a scene is
    refused.
    """
    shown = str(path) if path is not None else '<scene>'
    folder = Path(path).parent if path is not None else Path('.')
    ctx = Context(shown, folder)
    raw = ctx.mapping(data, '', ('name', 'segments', 'pump'),
                      ('description', 'camera', 'outputs', 'solver', 'network', 'supply'))
    name = ctx.text(raw['name'], 'name')
    if not SCENE_NAME.match(name):
        raise ctx.error('name', f'must start with a letter or digit and hold only letters, '
                                f'digits, _, - and ., got {name!r}')
    description = raw.get('description', '')
    description = ' '.join(ctx.text(description, 'description').split()) if description else ''
    segments = _segments(ctx, raw['segments'])
    capacity = sum(segment.max_volume - segment.rest_volume for segment in segments)
    # Before the pump: a start branch is looked up on the map these three settle.
    solver = _solver(ctx, raw.get('solver'))
    network = read_network(ctx, raw.get('network'), tuple(s.name for s in segments))
    supply_raw = raw.get('supply')
    if isinstance(supply_raw, dict) and REGULATOR_KEY in supply_raw:
        others = [key for key in supply_raw if key != REGULATOR_KEY]
        if others:
            raise ctx.error(join('supply', str(others[0])),
                            'a pressure regulator replaces the syringe and its line: give '
                            'supply.regulator alone')
        regulator = read_regulator(ctx, supply_raw[REGULATOR_KEY], raw['pump'], segments)
        if network is not None and network.supply is None:
            raise ctx.error('network.supply', NO_REGULATOR_TUBE)
        return Scene(name=name, description=description, network=network,
                     path=Path(path) if path is not None else None, segments=segments,
                     pump=None, camera=_camera(ctx, raw.get('camera'), capacity),
                     outputs=_outputs(ctx, raw.get('outputs')), solver=solver,
                     regulator=regulator)
    supply = _supply(ctx, supply_raw, segments)

    def history_onto(branch: int) -> tuple[float, ...]:
        return _history_onto_branch(ctx, branch, graph_of, segments, solver, supply, network)

    pump = _pump(ctx, raw['pump'], capacity, history_onto)
    camera = _camera(ctx, raw.get('camera'), pump.profile.max_injected())
    outputs = _outputs(ctx, raw.get('outputs'))
    if supply is not None and network is not None and network.supply is None:
        raise ctx.error('network.supply', NO_SUPPLY_TUBE)
    return Scene(name=name, description=description, network=network,
                 path=Path(path) if path is not None else None, segments=segments, pump=pump,
                 camera=camera, outputs=outputs, solver=solver, supply=supply)


def require_syringe(scene: Scene, job: str) -> PumpSettings:
    """
    The scene's syringe pump, for a ``job`` that needs one (the rig, a recording's analysis).

    A scene behind a pressure regulator has none: refused in one line naming the scene file
    and ``supply.regulator``, before anything runs.
    """
    if scene.pump is None:
        where = scene.path if scene.path is not None else '<scene>'
        raise SceneError(f'{where}: supply.regulator: {job} drives a syringe pump; a scene '
                         'behind a pressure regulator runs in softseq solve and softseq graph '
                         '(docs/supply.md)')
    return scene.pump


def segment_from_entry(entry: object, key_path: str = 'segment') -> Segment:
    """
    One segment from its entry as a scene lists it (``{name, length_m, balloon: {...}}``).

    Checked as the loader checks a scene's segments; SceneError names ``key_path`` and the
    key. Table paths are relative to the current folder. For a closed-form segment built from
    its scene entry with some of its numbers changed (``softseq scatter``).
    """
    return _segment(Context('', Path('.')), entry, key_path)


def load_scene(path: str | Path, graph_of: GraphOf | None = None) -> Scene:
    """
    Load and validate a scene file, or a shipped scene by its bare name (``paper``).

    ``graph_of`` as :func:`scene_from_dict` takes it. Raises SceneError with one line
    ``<file>: <key path>: <problem>``.
    """
    resolved = scene_path(path)
    return scene_from_dict(read_yaml(resolved, str(resolved)), resolved, graph_of)
