"""
The scene reference (docs/scene_reference.md) against the validation itself.

Scenes and designs that reach every ``mapping`` of the validation are loaded with that method
recording the keys it accepts, per section; each must have its entry in
softseq_ros/scene/reference.py and no entry may name a key the validation refuses. A new
section of the validation fails here until a scene below reaches it.
"""

import ast
from pathlib import Path
import re

import pytest
from scenes import shipped_scene_with

import softseq_ros
from softseq_ros.scene import reference, validation
from softseq_ros.scene.design import load_design
from softseq_ros.scene.paths import config_dir, shipped_scenes
from softseq_ros.segments.materials import LAW_NAMES, material_parameter_names

REPO = Path(__file__).resolve().parent.parent
SCENE_MODULES = ('loader.py', 'network.py', 'regulator.py', 'validation.py')
DESIGN_MODULES = ('design.py', 'validation.py')


def _mapping_sites(modules) -> set[tuple[str, int]]:
    """Every call of a ``.mapping(`` in these modules of softseq_ros/scene: (file, line)."""
    sites = set()
    for module in modules:
        tree = ast.parse((REPO / 'softseq_ros' / 'scene' / module).read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) \
                    and node.func.attr == 'mapping':
                sites.add((module, node.lineno))
    return sites


@pytest.fixture
def accepted(monkeypatch):
    """The keys the validation accepts per section (``[]`` for list items), and where."""
    seen: dict[str, set[str]] = {}
    sites: set[tuple[str, int]] = set()
    original = validation.Context.mapping

    def recording(self, value, key_path, required, optional=()):
        caller = __import__('sys')._getframe(1)
        sites.add((Path(caller.f_code.co_filename).name, caller.f_lineno))
        seen.setdefault(re.sub(r'\[\d+\]', '[]', key_path), set()).update(required + optional)
        return original(self, value, key_path, required, optional)

    monkeypatch.setattr(validation.Context, 'mapping', recording)
    return seen, sites


def _documented(sections) -> dict[str, set[str]]:
    return {section.path: {key.name for key in section.keys} for section in sections}


def test_every_key_a_scene_may_hold_is_in_the_reference_and_nothing_else(accepted, tmp_path):
    seen, sites = accepted
    for name in shipped_scenes():
        softseq_ros.load_scene(name)
    # What no shipped scene holds: a smoothed table, a supply line, a linear segment.
    softseq_ros.load_scene(shipped_scene_with(
        tmp_path, 'paper.yaml', 'smoothed.yaml',
        segments=[{'name': 'bottom', 'length_m': 0.111, 'table': str(
                   config_dir() / 'segments' / 'paper_bottom.csv'), 'smoothing': {}},
                  {'name': 'top', 'length_m': 0.111, 'table': str(
                   config_dir() / 'segments' / 'paper_top.csv')}],
        supply={'trapped_gas_m3': 1.0e-6}))
    # Every mapping the validation of a scene has was reached.
    reached = {site for site in sites if site[0] in SCENE_MODULES}
    missing = {site for site in _mapping_sites(SCENE_MODULES) if site not in reached}
    assert not missing, f'no scene here reaches the validation at {sorted(missing)}'
    documented = _documented(reference.SCENE_SECTIONS)
    # A material's keys depend on its law: every law's parameters, from the laws' own table.
    seen['segments[].balloon.material'] = {'law'}.union(
        *(material_parameter_names(law) for law in LAW_NAMES))
    assert set(documented) == set(seen), 'sections documented and validated differ'
    for path, keys in seen.items():
        assert documented[path] == keys, (
            f'{path or "(top level)"}: undocumented {sorted(keys - documented[path])}, '
            f'documented but refused {sorted(documented[path] - keys)}')


def test_every_key_a_design_may_hold_is_in_the_reference_and_nothing_else(accepted):
    seen, sites = accepted
    for design in sorted((config_dir() / 'designs').glob('*.yaml')):
        load_design(design)
    missing = _mapping_sites(DESIGN_MODULES) - sites
    assert not missing, f'no design here reaches the validation at {sorted(missing)}'
    seen['material'] = {'law'}.union(*(material_parameter_names(law) for law in LAW_NAMES))
    documented = _documented(reference.DESIGN_SECTIONS)
    assert set(documented) == set(seen)
    for path, keys in seen.items():
        assert documented[path] == keys, (
            f'{path or "(top level)"}: undocumented {sorted(keys - documented[path])}, '
            f'documented but refused {sorted(documented[path] - keys)}')


def test_the_written_reference_is_the_one_the_module_writes():
    written = (REPO / 'docs' / 'scene_reference.md').read_text(encoding='utf-8')
    assert written == reference.reference_text(), (
        'docs/scene_reference.md is stale: run python tools/scene_reference.py')
    # Every range it gives is a limit the validation holds the key to.
    for section in reference.SCENE_SECTIONS + reference.DESIGN_SECTIONS:
        for key in section.keys:
            assert key.limit is None or key.limit.rsplit('.', 1)[1] == key.name


@pytest.mark.parametrize('mu, alpha, key', [
    ([60.0e3], [-1.0], 'alpha[0]'), ([-60.0e3], [2.0], 'mu_pa[0]'), ([60.0e3], [0.0], 'alpha[0]'),
    ([0.0], [2.0], 'mu_pa[0]')])
def test_an_ogden_term_that_does_not_stiffen_is_refused_at_its_value(tmp_path, mu, alpha, key):
    from scenes import shipped_scene_with

    from softseq_ros.scene.validation import SceneError

    ogden = {'name': 'top', 'length_m': 0.111, 'balloon': {
        'material': {'law': 'ogden', 'mu_pa': mu, 'alpha': alpha}, 'radius_m': 0.006,
        'thickness_m': 0.6e-3, 'max_stretch': 3.0}}
    bottom = {'name': 'bottom', 'length_m': 0.111, 'balloon': {
        'material': {'law': 'gent', 'shear_modulus_pa': 60.0e3, 'jm': 40.0},
        'radius_m': 0.006, 'thickness_m': 0.6e-3, 'max_stretch': 3.0}}
    path = shipped_scene_with(tmp_path, 'fig1_asymmetric.yaml', 'ogden.yaml',
                              segments=[bottom, ogden])
    where = re.escape(f'segments[1].balloon.material.{key}: mu_pa[0] x alpha[0]')
    with pytest.raises(SceneError, match=where):
        softseq_ros.load_scene(path)
    # Treloar's rubber has a term with both negative: it stiffens, and is taken.
    ogden['balloon']['material'] = {'law': 'ogden', 'mu_pa': [6.3e5, 1.2e3, -1.0e4],
                                    'alpha': [1.3, 5.0, -2.0]}
    path = shipped_scene_with(tmp_path, 'fig1_asymmetric.yaml', 'treloar.yaml',
                              segments=[bottom, ogden],
                              pump={'legs': [{'inflate_to_m3': 1.0e-5}, {'deflate_to_m3': 0.0}]},
                              camera={'rate_hz': 1})
    assert softseq_ros.load_scene(path).segments[1].name == 'top'


def test_segments_without_a_stable_state_are_refused_naming_those_that_fall_from_rest():
    from softseq_ros.errors import UserError
    from softseq_ros.quasistatic.equilibrium import EquilibriumMap
    from softseq_ros.segments.materials import Gent, Ogden
    from softseq_ros.segments.models import BalloonSegment

    falling = BalloonSegment('soft', 0.1, Ogden((-60.0e3,), (2.0,)), 0.006, 0.6e-3, 3.0)
    with pytest.raises(UserError, match='no stable equilibrium at all: the pressure of soft '
                                        'falls from rest'):
        EquilibriumMap([falling, BalloonSegment('gent', 0.1, Gent(60e3, 40.0), 0.006, 0.6e-3,
                                                3.0)])
