"""
The reference of scene files and design files: every key their validation accepts, what it means.

One entry per key the validation (softseq_ros.scene.loader, .network, .design and the material
laws of softseq_ros.segments.materials) accepts, by its section's key path (list items as
``[]``): its type, unit and default in words, and the range of softseq_ros.scene.limits where
one holds. docs/scene_reference.md is written from here (``python tools/scene_reference.py``);
test/test_scene_reference.py loads scenes that reach every section of the validation and fails
when a key it accepts has no entry here, when an entry names a key it does not accept, or when
the written reference is not what this module writes.
"""

from dataclasses import dataclass

from softseq_ros.scene.limits import LIMITS


@dataclass(frozen=True)
class Key:
    """One key: ``what`` it is (type, unit, default, meaning); ``limit``: its LIMITS entry."""

    name: str
    what: str
    required: bool = False
    limit: str | None = None


@dataclass(frozen=True)
class Section:
    """The keys of one mapping of the file, at ``path`` (list items as ``[]``)."""

    path: str
    title: str
    keys: tuple[Key, ...]


def _tube(path: str, title: str) -> Section:
    return Section(path, title, (
        Key('length_m', 'number [m]', True, 'network.tube.length_m'),
        Key('radius_m', 'number [m]: inner radius', True, 'network.tube.radius_m'),
        Key('inertance', "true or false (false): the fluid's inertia counts, the tube's flow "
            'becomes a state'),
        Key('minor_loss', 'number (0): loss coefficient K of ends and bends, a drop K rho q|q| '
            '/ (2 A^2)', limit='network.tube.minor_loss'),
        Key('friction', "laminar (default) or blasius: Blasius's smooth-pipe law above about "
            'Re 1190'),
    ))


MATERIAL = Section('segments[].balloon.material', 'A membrane law (`law` picks which '
                   'parameters it takes)', (
    Key('law', 'neo_hookean, mooney_rivlin, gent, ogden, arruda_boyce or yeoh', True),
    Key('shear_modulus_pa', 'number [Pa] > 0: initial shear modulus mu (neo_hookean, gent, '
        'arruda_boyce)'),
    Key('jm', 'number > 0: locking invariant J_m (gent)'),
    Key('lambda_m', 'number > 0: locking stretch (arruda_boyce)'),
    Key('c1_pa', 'number [Pa] > 0: C1 (mooney_rivlin, yeoh)'),
    Key('c2_pa', 'number [Pa]: C2 (mooney_rivlin, yeoh)'),
    Key('c3_pa', 'number [Pa] (0): C3 (yeoh)'),
    Key('mu_pa', "list of numbers [Pa]: the terms' moduli (ogden)"),
    Key('alpha', "list of numbers, as many as mu_pa: the terms' exponents (ogden)"),
))

SCENE_SECTIONS: tuple[Section, ...] = (
    Section('', 'The scene', (
        Key('name', 'text: letters, digits, _, - and .', True),
        Key('description', 'text (empty): one paragraph, shown by softseq scenes'),
        Key('segments', 'list of segments, base to tip, at least 2', True),
        Key('pump', 'the pump programme', True),
        Key('camera', 'the camera (defaults below)'),
        Key('outputs', 'list of pressure, volumes, curvature, poses, markers, events, image '
            '(all but image): the topics the rig publishes'),
        Key('solver', 'the equilibrium solver'),
        Key('network', 'the fluid network: time in the physics (docs/dynamic.md); none: '
            'quasi-static'),
        Key('supply', 'the syringe line: trapped gas and compliance, or a pressure regulator in '
            "the syringe's place (docs/supply.md); none: an ideal syringe"),
    )),
    Section('segments[]', 'A segment (exactly one of table, design, linear, balloon)', (
        Key('name', 'text: a letter, then letters, digits and _; unique', True),
        Key('length_m', 'number [m]: its length along the backbone', True, 'segments.length_m'),
        Key('table', 'path of a CSV of volume_m3 and pressure_pa (curvature_per_m optional), '
            'relative to the scene file'),
        Key('design', 'path or shipped name of a design file (below): its FEM table from '
            "softseq fem's cache"),
        Key('linear', 'a linear segment (below)'),
        Key('balloon', 'a spherical membrane of a material law (below)'),
        Key('smoothing', 'tables only, opt-in: smooth a measured table (below)'),
    )),
    Section('segments[].smoothing', 'Smoothing of a measured table', (
        Key('noise_std_pa', "number [Pa] >= 0 (absent or null: estimated from the rows): the "
            "readings' noise"),
        Key('prominence_pa', 'number [Pa] (absent or null: 6 noise deviations): the smallest '
            'peak or valley kept'),
    )),
    Section('segments[].linear', 'A linear segment', (
        Key('rest_volume_m3', 'number [m^3] >= 0', True),
        Key('stiffness_pa_per_m3', 'number [Pa/m^3] > 0', True),
        Key('max_volume_m3', 'number [m^3] > rest_volume_m3', True),
        Key('curvature_per_m_per_m3', 'number [1/m per m^3] (0): curvature per volume above '
            'rest'),
    )),
    Section('segments[].balloon', 'A thin-walled spherical membrane', (
        Key('material', 'a membrane law (below)', True),
        Key('radius_m', 'number [m] > 0: radius at rest', True),
        Key('thickness_m', 'number [m] > 0: wall at rest', True),
        Key('max_stretch', "number > 1, below the law's locking stretch: where its curve ends",
            True),
        Key('curvature_per_m_per_m3', 'number [1/m per m^3] (0): curvature per volume above '
            'rest'),
    )),
    MATERIAL,
    Section('pump', 'The pump programme (behind a regulator: its programme of gauge pressures, '
            'from rest, with legs, pressure_rate_pa_per_s, cycles and rate_hz only)', (
        Key('legs', 'list of legs (below), run in order', True),
        Key('pressure_rate_pa_per_s', 'number [Pa/s] (100): behind a regulator, the rate of a '
            'leg without its own', limit='pump.pressure_rate_pa_per_s'),
        Key('flow_rate_m3_per_s', 'number [m^3/s] (5e-8): the rate of a leg without its own',
            limit='pump.flow_rate_m3_per_s'),
        Key('rate_hz', 'number [Hz] (50): commands per second while running',
            limit='pump.rate_hz'),
        Key('cycles', 'integer (1): repetitions of the legs', limit='pump.cycles'),
        Key('start_injected_m3', 'number [m^3] (0): where the programme starts, reached from '
            'rest'),
        Key('start_history_m3', 'list of numbers [m^3]: injected volumes from rest, in order; '
            'the programme starts at the last (not with start_injected_m3)'),
        Key('start_branch', 'integer >= 0: a branch of softseq graph; the programme starts '
            "where the graph's history onto it ends (not with the two above)"),
    )),
    Section('pump.legs[]', 'A leg (exactly one of inflate_to_m3, deflate_to_m3, hold_s, '
            'profile; behind a regulator inflate_to_pa, deflate_to_pa, hold_s, profile)', (
        Key('inflate_to_m3', 'number [m^3], above where the leg starts'),
        Key('deflate_to_m3', 'number [m^3] >= 0, below where the leg starts'),
        Key('hold_s', 'number [s] > 0', limit='pump.legs.hold_s'),
        Key('profile', 'path of a CSV of time_s and injected_m3, followed linearly, relative to '
            'the scene file'),
        Key('flow_rate_m3_per_s', "number [m^3/s] (the pump's): this leg's own rate",
            limit='pump.flow_rate_m3_per_s'),
        Key('inflate_to_pa', 'number [Pa, gauge], above where the leg starts, within the '
            "regulator's relief and what every segment holds on a rising piece (regulator)"),
        Key('deflate_to_pa', 'number [Pa, gauge] >= 0, below where the leg starts (regulator)'),
        Key('rate_pa_per_s', "number [Pa/s] (pressure_rate_pa_per_s): this leg's own rate "
            '(regulator)', limit='pump.legs.rate_pa_per_s'),
    )),
    Section('camera', 'The camera', (
        Key('rate_hz', 'number [Hz] (10): frames per second', limit='camera.rate_hz'),
        Key('noise_std_m', 'number [m] (0): Gaussian noise on every point',
            limit='camera.noise_std_m'),
        Key('seed', "integer (0): the noise generator's seed", limit='camera.seed'),
        Key('trigger_injected_m3', 'list of numbers [m^3] ([]), increasing, reached by the '
            'pump: a snapshot at each'),
        Key('points_per_segment', 'integer (20): backbone points per segment',
            limit='camera.points_per_segment'),
        Key('image_width_px', 'integer (640)', limit='camera.image_width_px'),
        Key('image_height_px', 'integer (480)', limit='camera.image_height_px'),
    )),
    Section('solver', 'The equilibrium solver', (
        Key('resolution', "integer or null (null: the solver's default): samples per segment "
            'curve', limit='solver.resolution'),
    )),
    Section('network', 'The fluid network (docs/dynamic.md)', (
        Key('channels', 'list of tubes (below), one per neighbouring pair, base to tip', True),
        Key('fluid', 'the fluid (water at 20 C)'),
        Key('supply', 'a tube (below) from the syringe to the fed segment; none: ideal (needed '
            'behind a supply block)'),
        Key('feeds', 'a segment name (the base): the segment the syringe feeds'),
        Key('rate_hz', "number [Hz] > 0 (200): the actuator's output rate in time"),
        Key('rtol', "number (1e-6): the integrator's relative tolerance"),
    )),
    Section('network.fluid', 'The working fluid', (
        Key('viscosity_pa_s', 'number [Pa s] (1.0e-3)', limit='network.fluid.viscosity_pa_s'),
        Key('density_kg_per_m3', 'number [kg/m^3] (998)',
            limit='network.fluid.density_kg_per_m3'),
    )),
    _tube('network.supply', 'The supply tube'),
    _tube('network.channels[]', 'A channel between neighbouring segments'),
    Section('supply', 'The syringe line (docs/supply.md): at least one of the first two, or '
            'a regulator alone', (
        Key('trapped_gas_m3', 'number [m^3] (0): air in the line at the ambient pressure',
            limit='supply.trapped_gas_m3'),
        Key('line_compliance_m3_per_pa', "number [m^3/Pa] (0): the tubing's swelling",
            limit='supply.line_compliance_m3_per_pa'),
        Key('ambient_pa', 'number [Pa, absolute] (101325)', limit='supply.ambient_pa'),
        Key('polytropic_exponent', 'number (1: isothermal; 1.4: adiabatic air)',
            limit='supply.polytropic_exponent'),
        Key('regulator', "a pressure regulator in the syringe's place (below); the pump block "
            'is then its programme of gauge pressures'),
    )),
    Section('supply.regulator', 'A pressure regulator (docs/supply.md); with a network it '
            'needs network.supply', (
        Key('time_constant_s', 'number [s] (0: at once): its outlet follows the target as a '
            'first-order lag', limit='supply.regulator.time_constant_s'),
        Key('max_flow_m3_per_s', 'number [m^3/s] (no limit): the most it delivers or vents',
            limit='supply.regulator.max_flow_m3_per_s'),
        Key('max_pressure_pa', "number [Pa, gauge] (1.5 x the highest pressure on the "
            "segments' curves): its relief, above every target",
            limit='supply.regulator.max_pressure_pa'),
    )),
)

DESIGN_SECTIONS: tuple[Section, ...] = (
    Section('', 'The design', (
        Key('name', 'text: letters, digits, _, - and .', True),
        Key('description', 'text (empty)'),
        Key('geometry', 'the unit cell (below)', True),
        Key('material', "a membrane law, as a balloon's (above)", True),
        Key('volume', 'the FEM inflation (below)', True),
        Key('mesh', 'the mesh (below)'),
    )),
    Section('geometry', "The segment's unit cell (docs/fem.md)", tuple(
        Key(name, 'number [m] > 0', True) for name in (
            'length_m', 'height_m', 'width_m', 'beam_thickness_m', 'cavity_width_m',
            'wall_length_m', 'membrane_length_m', 'membrane_thickness_m', 'wall_thickness_m'))
        + (Key('wall_reading', 'skin_bands (default) or side_walls: how the walls are read'),
           Key('skin_band_thickness_m', 'number [m] > 0: with wall_reading side_walls only'),
           Key('membrane_thickness_factors', 'list of numbers > 0: per-membrane factors on '
               'membrane_thickness_m'))),
    Section('mesh', 'The mesh', (
        Key('model', 'unit_cell (default: one cell, by symmetry) or whole_segment'),
        Key('element_size_m', 'number [m] > 0 (7.5e-4), at most a quarter of height_m'),
        Key('thin_layer_cells', 'integer (2): cells across a membrane'),
        Key('bulk_ratio', 'number >= 100 (5000): bulk to shear modulus, near incompressible'),
    )),
    Section('volume', 'The FEM inflation', (
        Key('max_injected_m3', 'number [m^3] > 0: up to where', True),
        Key('first_step_m3', 'number [m^3] > 0 (5e-7): the first volume step'),
        Key('max_step_m3', 'number [m^3] > 0 (2e-6): the largest volume step'),
    )),
    Section('material', 'A membrane law', MATERIAL.keys),
)


def _range(limit: str | None) -> str:
    if limit is None:
        return ''
    bound = LIMITS[limit]
    low = f'> {bound.minimum:g}' if bound.open_minimum else f'>= {bound.minimum:g}'
    return f'{low}, <= {bound.maximum:g}'


def _table(sections: tuple[Section, ...]) -> list[str]:
    lines = []
    for section in sections:
        lines += ['', f'### {section.title}: `{section.path or "(top level)"}`', '',
                  '| key | required | what | range |', '| --- | --- | --- | --- |']
        for key in section.keys:
            lines.append(f'| `{key.name}` | {"yes" if key.required else ""} | {key.what} | '
                         f'{_range(key.limit)} |')
    return lines


def reference_text() -> str:
    """docs/scene_reference.md as this module writes it."""
    lines = ['# Scene and design files: every key', '',
             'Written by `python tools/scene_reference.py` from',
             '`softseq_ros/scene/reference.py`; `test/test_scene_reference.py` checks it against',
             'what the validation accepts, so a key cannot be added without being documented',
             'here. Every quantity is SI and says its unit in its name; a default is in',
             "parentheses; a range is the scene's limit, the one the nodes' parameters of the",
             'same meaning share. A key path names list items as `[]`: `segments[].balloon` is',
             'the `balloon` of any segment. A mistake is refused in one line naming the file and',
             'the key path (docs/faults.md).', '',
             '## Scene files', '',
             '`softseq scenes` lists the shipped ones; README.md shows them in use.']
    lines += _table(SCENE_SECTIONS)
    lines += ['', '## Design files', '',
              "A segment designed for `softseq fem`, named by a scene segment's `design` "
              '(docs/fem.md).']
    lines += _table(DESIGN_SECTIONS)
    return '\n'.join(lines) + '\n'
