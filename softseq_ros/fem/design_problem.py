"""
The problem file of ``softseq design``: what may vary, the target, the grid and the search.

Problem file (YAML, SI units)::

    name: paper_partial
    segments:                              # base to tip
      - name: bottom
        design: paper_bottom               # a shipped design or a design file
        vary:                              # [low, high] for what may change (others fixed)
          membrane_thickness_m: [0.0008, 0.0012]
      - name: top
        design: paper_top
        vary:
          membrane_thickness_m: [0.0004, 0.0006]
          wall_thickness_m: [0.0015, 0.0025]
    materials:                             # optional: fits to choose from (one for both)
      - {law: arruda_boyce, shear_modulus_pa: 16300.0, lambda_m: 3.96}
    target:
      sequence: partial                    # none, partial, symmetric or asymmetric
      leader: top                          # optional: the segment that takes over
      switch_injected_m3: {value: 2.7e-5, tolerance: 0.5e-5}     # optional
      plateau_pressure_pa: {value: 2400.0, tolerance: 150.0}     # optional
      plateau_from_m3: {value: 4.0e-5, tolerance: 0.5e-5}        # optional: within 1 % from
      tip_distance_m: {injected_m3: 6.0e-5, value: 0.17, tolerance: 0.02}  # optional
      max_injected_m3: 6.5e-5              # the programme's range (default 65 mL)
    grid:                                  # optional
      points: 3                            # per varied parameter
      element_size_m: 0.002                # the unit cells' mesh
      thin_layer_cells: 1
    search:                                # optional
      seed: 0
      keep: 5                              # designs listed
      generations: 12
      population: 6                        # per varied parameter (scipy's popsize)

Every mistake raises :class:`DesignError` with one line ``<file>: <key path>: <problem>``.
"""

from dataclasses import dataclass
import math
from pathlib import Path

from softseq_ros.errors import not_a_file
from softseq_ros.quasistatic.sequence import SEQUENCE_TYPES
from softseq_ros.scene.design import (
    Design,
    DesignError,
    Material,
    design_path,
    load_design,
    with_changes,
)
from softseq_ros.scene.validation import SCENE_NAME, SEGMENT_NAME, Context, SceneError, read_yaml

VARIABLES = ('membrane_thickness_m', 'wall_thickness_m', 'membrane_length_m')
DEFAULT_MAX_INJECTED_M3 = 6.5e-5
# The most pairs a search may assemble: population x generations x material fits. A pair
# costs about 0.2 s (docs/fem.md), so this is about an hour; the shipped problems allow 20
# to 832 (and stop early: 128 for paper_partial). A population of 1e6 was taken and would
# have run for months.
MAX_SEARCH_PAIRS = 20_000


@dataclass(frozen=True)
class Tolerance:
    """A target value and how far from it still meets the target (same unit)."""

    value: float
    tolerance: float

    def error(self, got: float | None) -> float:
        """Distance in tolerances (inf when there is nothing to compare)."""
        return math.inf if got is None else (got - self.value) / self.tolerance


@dataclass(frozen=True)
class Target:
    """What the assembled pair must do."""

    sequence: str
    leader: str | None = None
    switch: Tolerance | None = None
    plateau: Tolerance | None = None
    plateau_from: Tolerance | None = None
    tip_distance: Tolerance | None = None
    tip_at_m3: float | None = None
    max_injected_m3: float = DEFAULT_MAX_INJECTED_M3


@dataclass(frozen=True)
class SegmentSpace:
    """One segment: its base design and the ranges of what may vary."""

    name: str
    design: Design
    ranges: dict[str, tuple[float, float]]

    @property
    def varied(self) -> list[str]:
        """The parameters with a range of more than one value."""
        return [k for k, (lo, hi) in self.ranges.items() if hi > lo]


@dataclass(frozen=True)
class Problem:
    """A loaded, checked ``softseq design`` file."""

    name: str
    segments: list[SegmentSpace]
    materials: list[Material]
    target: Target
    points: int = 3
    element_size_m: float = 0.002
    thin_layer_cells: int = 1
    seed: int = 0
    keep: int = 5
    generations: int = 12
    population: int = 6
    path: Path | None = None


def _tolerance(ctx: Context, raw: object, key: str, gt: float | None = None) -> Tolerance:
    values = ctx.mapping(raw, key, ('value', 'tolerance'))
    value = ctx.number(values['value'], f'{key}.value', gt=gt)
    tolerance = ctx.number(values['tolerance'], f'{key}.tolerance', gt=0.0)
    return Tolerance(value, tolerance)


def problem_from_dict(data: object, path: str | Path | None = None) -> Problem:
    """Check a parsed problem file; DesignError with one line on any mistake."""
    shown = str(path) if path is not None else '<design problem>'
    folder = Path(path).parent if path is not None else Path('.')
    ctx = Context(shown, folder)
    try:
        raw = ctx.mapping(data, '', ('name', 'segments', 'target'),
                          ('materials', 'grid', 'search', 'description'))
        name = ctx.text(raw['name'], 'name')
        if not SCENE_NAME.match(name):
            raise ctx.error('name', f'must start with a letter or digit and hold only letters, '
                                    f'digits, _, - and ., got {name!r}')
        items = ctx.sequence(raw['segments'], 'segments')
        if len(items) != 2:
            raise ctx.error('segments', f'must list two segments, base to tip, got {len(items)}')
        segments = []
        for index, item in enumerate(items):
            key = f'segments[{index}]'
            entry = ctx.mapping(item, key, ('name', 'design'), ('vary',))
            seg_name = ctx.text(entry['name'], f'{key}.name')
            if not SEGMENT_NAME.match(seg_name):
                raise ctx.error(f'{key}.name', f'must be a letter then letters, digits or _, '
                                               f'got {seg_name!r}')
            design_name = ctx.text(entry['design'], f'{key}.design')
            candidate = folder / design_name
            try:
                design = load_design(candidate if candidate.is_file()
                                     else design_path(design_name))
            except DesignError as err:
                raise ctx.error(f'{key}.design', str(err)) from None
            vary = ctx.mapping(entry.get('vary') or {}, f'{key}.vary', (), VARIABLES)
            ranges = {}
            for variable in VARIABLES:
                where = f'{key}.vary.{variable}'
                if variable not in vary:
                    continue
                bounds = ctx.sequence(vary[variable], where)
                if len(bounds) != 2:
                    raise ctx.error(where, f'must be [low, high], got {bounds!r}')
                lo = ctx.number(bounds[0], f'{where}[0]', gt=0.0)
                hi = ctx.number(bounds[1], f'{where}[1]', gt=0.0)
                if hi < lo:
                    raise ctx.error(where, f'high ({hi:g}) is below low ({lo:g})')
                ranges[variable] = (lo, hi)
                for value in (lo, hi):   # the design file's own checks at both ends
                    try:
                        with_changes(design, {f'geometry.{variable}': value})
                    except DesignError as err:
                        problem = str(err).split(': ', 2)[-1]
                        raise ctx.error(where, f'{value:g} is no valid design: {problem}') \
                            from None
            segments.append(SegmentSpace(seg_name, design, ranges))
        if segments[0].name == segments[1].name:
            raise ctx.error('segments[1].name', f'{segments[1].name!r} is taken by the first')
        materials = []
        if raw.get('materials') is not None:
            listed = ctx.sequence(raw['materials'], 'materials')
            if not listed:
                raise ctx.error('materials', 'must list at least one material fit')
            for index, item in enumerate(listed):
                ctx.material(item, f'materials[{index}]')
                materials.append(Material(law=item['law'],
                                          params={k: v for k, v in item.items() if k != 'law'}))
        else:
            first, second = (s.design.material for s in segments)
            if first != second:
                raise ctx.error('materials', 'the two designs have different materials; list '
                                             'the fits to choose from (both segments share one)')
            materials = [first]
        target = _target(ctx, raw['target'], [s.name for s in segments])
        grid = ctx.mapping(raw.get('grid') or {}, 'grid', (),
                           ('points', 'element_size_m', 'thin_layer_cells'))
        points = ctx.integer(grid.get('points', 3), 'grid.points', ge=2)
        if points > 6:
            raise ctx.error('grid.points', f'must be at most 6 (a coarse grid: the '
                                           f'interpolation does the rest), got {points}')
        element = ctx.number(grid.get('element_size_m', 0.002), 'grid.element_size_m', gt=0.0)
        thin = ctx.integer(grid.get('thin_layer_cells', 1), 'grid.thin_layer_cells', ge=1)
        for segment in segments:   # the mesh settings as a design file checks them
            try:
                with_changes(segment.design, {'mesh.element_size_m': element,
                                              'mesh.thin_layer_cells': thin})
            except DesignError as err:
                raise ctx.error('grid', str(err).split(': ', 2)[-1]) from None
        search = ctx.mapping(raw.get('search') or {}, 'search', (),
                             ('seed', 'keep', 'generations', 'population'))
        seed = ctx.integer(search.get('seed', 0), 'search.seed', ge=0)
        keep = ctx.integer(search.get('keep', 5), 'search.keep', ge=1)
        generations = ctx.integer(search.get('generations', 12), 'search.generations', ge=1)
        population = ctx.integer(search.get('population', 6), 'search.population', ge=2)
        if not any(s.varied for s in segments) and len(materials) == 1:
            raise ctx.error('segments', 'nothing to vary: give a [low, high] range under vary, '
                                        'or several materials')
        varied = sum(len(s.varied) for s in segments)
        if varied:
            # scipy's differential evolution: popsize x the varied parameters, rounded up to
            # a power of two by the Sobol start, for the start and each generation.
            size = 2 ** math.ceil(math.log2(population * varied))
            pairs = size * (generations + 1) * len(materials)
            if pairs > MAX_SEARCH_PAIRS:
                raise ctx.error('search', f'population {population} x {varied} varied '
                                f'parameters (a population of {size} with the Sobol start) '
                                f'x {generations + 1} generations (the start and '
                                f'{generations}) x {len(materials)} material fit(s) = '
                                f'{pairs} pairs to assemble, more than {MAX_SEARCH_PAIRS} '
                                '(about an hour at 0.2 s a pair)')
    except DesignError:
        raise
    except SceneError as err:
        raise DesignError(str(err)) from None
    return Problem(name=name, segments=segments, materials=materials, target=target,
                   points=points, element_size_m=element, thin_layer_cells=thin, seed=seed,
                   keep=keep, generations=generations, population=population,
                   path=Path(path) if path is not None else None)


def _target(ctx: Context, value: object, names: list[str]) -> Target:
    raw = ctx.mapping(value, 'target', ('sequence',),
                      ('leader', 'switch_injected_m3', 'plateau_pressure_pa', 'plateau_from_m3',
                       'tip_distance_m', 'max_injected_m3'))
    sequence = ctx.text(raw['sequence'], 'target.sequence')
    if sequence not in SEQUENCE_TYPES:
        raise ctx.error('target.sequence', f'unknown sequence type {sequence!r}; expected one '
                                           f'of {", ".join(SEQUENCE_TYPES)}')
    top = ctx.number(raw.get('max_injected_m3', DEFAULT_MAX_INJECTED_M3),
                     'target.max_injected_m3', gt=0.0)
    leader = None
    if raw.get('leader') is not None:
        leader = ctx.text(raw['leader'], 'target.leader')
        if leader not in names:
            raise ctx.error('target.leader', f'{leader!r} is none of the segments '
                                             f'({", ".join(names)})')
    switch = plateau = plateau_from = tip = None
    tip_at = None
    if raw.get('switch_injected_m3') is not None:
        switch = _tolerance(ctx, raw['switch_injected_m3'], 'target.switch_injected_m3', gt=0.0)
        if not switch.value < top:
            raise ctx.error('target.switch_injected_m3.value',
                            f'must be below target.max_injected_m3 ({top:g}), got '
                            f'{switch.value:g}')
        if sequence == 'none':
            raise ctx.error('target.switch_injected_m3', "a 'none' sequence has no switch")
    if raw.get('plateau_pressure_pa') is not None:
        plateau = _tolerance(ctx, raw['plateau_pressure_pa'], 'target.plateau_pressure_pa',
                             gt=0.0)
    if raw.get('plateau_from_m3') is not None:
        plateau_from = _tolerance(ctx, raw['plateau_from_m3'], 'target.plateau_from_m3', gt=0.0)
        if not plateau_from.value <= top:
            raise ctx.error('target.plateau_from_m3.value',
                            f'must be at most target.max_injected_m3 ({top:g}), got '
                            f'{plateau_from.value:g}')
    if raw.get('tip_distance_m') is not None:
        key = 'target.tip_distance_m'
        entry = ctx.mapping(raw['tip_distance_m'], key, ('injected_m3', 'value', 'tolerance'))
        tip_at = ctx.number(entry['injected_m3'], f'{key}.injected_m3', gt=0.0)
        if tip_at > top:
            raise ctx.error(f'{key}.injected_m3', f'must be at most target.max_injected_m3 '
                                                  f'({top:g}), got {tip_at:g}')
        tip = _tolerance(ctx, {k: entry[k] for k in ('value', 'tolerance')}, key, gt=0.0)
    return Target(sequence=sequence, leader=leader, switch=switch, plateau=plateau,
                  plateau_from=plateau_from, tip_distance=tip, tip_at_m3=tip_at,
                  max_injected_m3=top)


def load_problem(path: str | Path) -> Problem:
    """Load and check a problem file; DesignError with one line."""
    path = Path(path)
    if not path.is_file():
        raise DesignError(f'{path}: {not_a_file(path, "design problem file")}')
    try:
        data = read_yaml(path, str(path))
    except SceneError as err:
        raise DesignError(str(err).replace('scene file', 'design problem file')) from None
    return problem_from_dict(data, path)
