"""Scene files: shipped scenes load and show what they claim; mistakes get one-line errors."""

import copy
from pathlib import Path
import re

import numpy as np
import pytest
import yaml

from softseq_ros.quasistatic.equilibrium import EquilibriumMap, classify
from softseq_ros.scene.loader import Scene, SceneError, load_scene, scene_from_dict
from softseq_ros.scene.paths import config_dir, scene_path, shipped_scenes
from softseq_ros.segments.models import BalloonSegment, LinearSegment, TabulatedSegment

ML = 1e-6
SHIPPED = ('paper', 'fig1_none', 'fig1_partial', 'fig1_symmetric', 'fig1_asymmetric',
           'three_segments')
REPO_CONFIG = Path(__file__).resolve().parents[1] / 'config'


def valid_scene() -> dict:
    return {
        'name': 'unit',
        'segments': [
            {'name': 'bottom', 'length_m': 0.1,
             'linear': {'rest_volume_m3': 1e-5, 'stiffness_pa_per_m3': 1e9,
                        'max_volume_m3': 6e-5, 'curvature_per_m_per_m3': 5e5}},
            {'name': 'top', 'length_m': 0.1,
             'balloon': {'material': {'law': 'gent', 'shear_modulus_pa': 34e3, 'jm': 16.0},
                         'radius_m': 0.01, 'thickness_m': 1.5e-3, 'max_stretch': 2.6}},
        ],
        'pump': {'flow_rate_m3_per_s': 5e-8, 'rate_hz': 50, 'cycles': 1,
                 'legs': [{'inflate_to_m3': 6.5e-5}, {'hold_s': 10}, {'deflate_to_m3': 0.0}]},
        'camera': {'rate_hz': 10, 'noise_std_m': 0.0, 'seed': 0,
                   'trigger_injected_m3': [5e-6, 2.5e-5]},
        'outputs': ['pressure', 'volumes', 'events'],
    }


_TOKEN = re.compile(r'([^.\[\]]+)|\[(\d+)\]')


def _walk(data: dict, key_path: str) -> tuple[object, object]:
    keys = [name if name else int(index) for name, index in _TOKEN.findall(key_path)]
    parent = data
    for key in keys[:-1]:
        parent = parent[key]
    return parent, keys[-1]


def put(key_path: str, value: object):
    def edit(data: dict) -> None:
        parent, key = _walk(data, key_path)
        parent[key] = value
    return edit


def drop(key_path: str):
    def edit(data: dict) -> None:
        parent, key = _walk(data, key_path)
        del parent[key]
    return edit


def rename(key_path: str, new_key: str):
    def edit(data: dict) -> None:
        parent, key = _walk(data, key_path)
        parent[new_key] = parent.pop(key)
    return edit


BAD_SCENES = [
    (put('segments[1].length_m', -0.1), 'segments[1].length_m', 'must be > 0, got -0.1'),
    (put('segments[0].length_m', 0), 'segments[0].length_m', 'must be > 0, got 0'),
    (put('segments[0].length_m', '0.1'), 'segments[0].length_m', 'must be a number, got str'),
    (put('segments[0].length_m', float('inf')), 'segments[0].length_m', 'must be finite'),
    (put('pump.rate_hz', True), 'pump.rate_hz', 'must be a number, got bool'),
    (drop('name'), 'name', 'required key is missing'),
    (drop('segments[0].length_m'), 'segments[0].length_m', 'required key is missing'),
    (put('colour', 'red'), 'colour', 'unknown key; expected one of name, segments, pump'),
    (put('camera.colour', 'red'), 'camera.colour', 'unknown key'),
    (rename('segments[0].length_m', 'length_mm'), 'segments[0].length_mm',
     'wrong or missing unit suffix; scene files use SI units, write length_m'),
    (rename('segments[0].length_m', 'length'), 'segments[0].length', 'write length_m'),
    (rename('pump.flow_rate_m3_per_s', 'flow_rate_ml_per_s'), 'pump.flow_rate_ml_per_s',
     'write flow_rate_m3_per_s'),
    (put('pump.legs[1]', {'hold_min': 1}), 'pump.legs[1].hold_min', 'write hold_s'),
    (rename('segments[0].linear.rest_volume_m3', 'rest_volume_ml'),
     'segments[0].linear.rest_volume_ml', 'write rest_volume_m3'),
    (rename('segments[1].balloon.material.shear_modulus_pa', 'shear_modulus_kpa'),
     'segments[1].balloon.material.shear_modulus_kpa', 'write shear_modulus_pa'),
    (put('segments', []), 'segments', 'needs at least 2 segments'),
    (lambda d: d['segments'].pop(), 'segments', 'needs at least 2 segments (base to tip), got 1'),
    (put('segments', {'a': 1}), 'segments', 'must be a list, got dict'),
    (put('segments[1].name', 'bottom'), 'segments[1].name',
     "'bottom' is already used by segments[0]"),
    (put('segments[0].name', 'top segment'), 'segments[0].name', 'must start with a letter'),
    (put('segments[0].name', 7), 'segments[0].name', 'must be text, got int'),
    (drop('segments[0].linear'), 'segments[0]', 'needs exactly one model key out of table, '
                                                'design, linear, balloon; found none'),
    (put('segments[0].table', 'x.csv'), 'segments[0]', 'found table, linear'),
    (put('segments[0].linear.max_volume_m3', 1e-5), 'segments[0].linear.max_volume_m3',
     'must be > 1e-05, got 1e-05'),
    (put('segments[0].linear.stiffness_pa_per_m3', -1.0),
     'segments[0].linear.stiffness_pa_per_m3', 'must be > 0'),
    (put('segments[1].balloon.material.law', 'rubber'), 'segments[1].balloon.material.law',
     "unknown material law 'rubber'"),
    (drop('segments[1].balloon.material.jm'), 'segments[1].balloon.material.jm',
     'required key is missing'),
    (drop('segments[1].balloon.material.law'), 'segments[1].balloon.material.law',
     'required key is missing'),
    (put('segments[1].balloon.max_stretch', 3.5), 'segments[1].balloon.max_stretch',
     'must be below the stretch at which the material locks (3.08'),
    (put('segments[1].balloon.max_stretch', 1.0), 'segments[1].balloon.max_stretch',
     'must be > 1'),
    (put('segments[1].balloon.material', {'law': 'ogden', 'mu_pa': [1e3, 2e3], 'alpha': [2.0]}),
     'segments[1].balloon.material.alpha', 'needs as many values as mu_pa (2), got 1'),
    (put('segments[1].balloon.material', {'law': 'ogden', 'mu_pa': [1e3, 'x'], 'alpha': [2, 3]}),
     'segments[1].balloon.material.mu_pa[1]', 'must be a number'),
    (put('segments[0]', {'name': 'a', 'length_m': 0.1, 'table': 'nowhere.csv'}),
     'segments[0].table', 'file not found'),
    (put('pump.rate_hz', 0), 'pump.rate_hz', 'must be > 0, got 0'),
    (put('pump.flow_rate_m3_per_s', -5e-8), 'pump.flow_rate_m3_per_s', 'must be >= 1e-15'),
    # Upper bounds, the same the nodes declare: each of these crashed or hung a run once.
    (put('pump.flow_rate_m3_per_s', 1e-300), 'pump.flow_rate_m3_per_s',
     'must be >= 1e-15, got 1e-300'),
    (put('pump.rate_hz', 1e7), 'pump.rate_hz', 'must be <= 10000, got 1e+07'),
    (put('pump.rate_hz', 1e12), 'pump.rate_hz', 'must be <= 10000'),
    (put('pump.cycles', 10**9), 'pump.cycles', 'must be <= 1e+06, got 1e+09'),
    (put('pump.legs[1]', {'hold_s': 1e300}), 'pump.legs[1].hold_s', 'must be <= 1e+07'),
    (put('camera.rate_hz', 1e9), 'camera.rate_hz', 'must be <= 1000, got 1e+09'),
    (put('camera.points_per_segment', 10**8), 'camera.points_per_segment', 'must be <= 10000'),
    (put('camera.image_width_px', 10**5), 'camera.image_width_px', 'must be <= 8192'),
    (put('camera.image_height_px', 8), 'camera.image_height_px', 'must be >= 16, got 8'),
    (put('solver', {'resolution': 10**9}), 'solver.resolution', 'must be <= 100000'),
    (put('pump.cycles', 0), 'pump.cycles', 'must be >= 1, got 0'),
    (put('pump.cycles', 1.5), 'pump.cycles', 'must be an integer, got float'),
    (put('pump.legs', []), 'pump.legs', 'needs at least one leg'),
    (drop('pump.legs'), 'pump.legs', 'required key is missing'),
    (put('pump.legs[0]', {'inflate_to_m3': 1e-5, 'hold_s': 1}), 'pump.legs[0]',
     'needs exactly one of inflate_to_m3, deflate_to_m3, hold_s'),
    (put('pump.legs[0]', {'deflate_to_m3': 1e-5}), 'pump.legs[0].deflate_to_m3',
     'must be below the injected volume the leg starts from (0 m^3)'),
    (put('pump.legs[1]', {'inflate_to_m3': 6.5e-5}), 'pump.legs[1].inflate_to_m3',
     'must be above the injected volume'),
    (lambda d: d['pump'].update(cycles=2, legs=[{'inflate_to_m3': 1e-5}, {'hold_s': 1}]),
     'pump.legs[0].inflate_to_m3', 'in cycle 2'),
    (put('pump.legs[0]', {'inflate_to_m3': 2e-4}), 'pump.legs[0].inflate_to_m3',
     'exceeds what the segments hold'),
    (put('pump.legs[1]', {'hold_s': 0}), 'pump.legs[1].hold_s', 'must be > 0'),
    (put('pump.legs[0]', {'inflate_to_m3': 1e-5, 'flow_rate_m3_per_s': -1e-7}),
     'pump.legs[0].flow_rate_m3_per_s', 'must be >= 1e-15, got -1e-07'),
    (put('pump.legs[0]', {'inflate_to_m3': 1e-5, 'flow_rate_m3_per_s': 0}),
     'pump.legs[0].flow_rate_m3_per_s', 'must be >= 1e-15, got 0'),
    (put('pump.legs[0]', {'inflate_to_m3': 1e-5, 'flow_rate_m3_per_s': float('nan')}),
     'pump.legs[0].flow_rate_m3_per_s', 'must be finite'),
    (put('pump.legs[0]', {'inflate_to_m3': 1e-5, 'flow_rate_m3_per_s': '1e-7'}),
     'pump.legs[0].flow_rate_m3_per_s', 'must be a number, got str'),
    (put('pump.legs[1]', {'hold_s': 1, 'flow_rate_m3_per_s': 1e-7}),
     'pump.legs[1].flow_rate_m3_per_s', 'a hold leg moves nothing'),
    (put('pump.legs[0]', {'flow_rate_m3_per_s': 1e-7}), 'pump.legs[0]',
     'needs exactly one of inflate_to_m3, deflate_to_m3, hold_s'),
    (put('pump.legs[0]', {'inflate_to_m3': 1e-5, 'flow_rate_ml_per_s': 0.1}),
     'pump.legs[0].flow_rate_ml_per_s', 'write flow_rate_m3_per_s'),
    (put('pump.start_injected_m3', -1e-6), 'pump.start_injected_m3', 'must be >= 0'),
    (put('camera.rate_hz', -10), 'camera.rate_hz', 'must be > 0, got -10'),
    (put('camera.noise_std_m', -1e-3), 'camera.noise_std_m', 'must be >= 0'),
    (put('camera.seed', 1.5), 'camera.seed', 'must be an integer'),
    (put('camera.trigger_injected_m3', [2e-5, 1e-5]), 'camera.trigger_injected_m3[1]',
     'triggers must increase'),
    (put('camera.trigger_injected_m3', [7e-5]), 'camera.trigger_injected_m3[0]',
     'is never reached: the pump goes up to 6.5e-05 m^3'),
    (put('camera.points_per_segment', 0), 'camera.points_per_segment', 'must be >= 1'),
    (put('camera', {1: 2}), 'camera', 'keys must be text'),
    (put('outputs', ['pressure', 'pose']), 'outputs[1]', "unknown output 'pose'"),
    (put('outputs', ['pressure', 'pressure']), 'outputs[1]', 'listed twice'),
    (put('outputs', 'pressure'), 'outputs', 'must be a list, got str'),
    (put('solver', {'resolution': 3}), 'solver.resolution', 'must be >= 16'),
    (put('solver', {'resolution': 'fine'}), 'solver.resolution', 'must be an integer'),
    (put('description', 5), 'description', 'must be text'),
    (put('name', 'my scene'), 'name', 'must start with a letter or digit'),
]


@pytest.mark.parametrize('edit, key_path, problem', BAD_SCENES,
                         ids=[f'{i}-{case[1]}' for i, case in enumerate(BAD_SCENES)])
def test_bad_scene_gives_one_line_with_the_key_path(edit, key_path, problem, tmp_path):
    data = valid_scene()
    edit(data)
    path = tmp_path / 'x.yaml'
    with pytest.raises(SceneError) as caught:
        scene_from_dict(data, path)
    message = str(caught.value)
    assert '\n' not in message
    assert message.startswith(f'{path}: {key_path}: '), message
    assert problem in message, message


def test_the_example_message_of_the_docs():
    data = valid_scene()
    data['segments'][1]['length_m'] = -0.1
    with pytest.raises(SceneError) as caught:
        scene_from_dict(data, 'config/x.yaml')
    assert str(caught.value) == 'config/x.yaml: segments[1].length_m: must be > 0, got -0.1'


def test_top_level_must_be_a_mapping():
    with pytest.raises(SceneError, match=r'^a\.yaml: \(top level\): must be a mapping, got list'):
        scene_from_dict([1, 2], 'a.yaml')


def test_valid_scene_builds_the_segment_models():
    scene = scene_from_dict(valid_scene(), None)
    assert isinstance(scene, Scene)
    bottom, top = scene.segments
    assert isinstance(bottom, LinearSegment) and isinstance(top, BalloonSegment)
    assert scene.segment_names == ('bottom', 'top')
    assert scene.lengths == (0.1, 0.1)
    # p = k (v - v0): 1e9 Pa/m^3 times 2 mL is 2 kPa; curvature 5e5 * 2e-6 = 1 1/m.
    assert bottom.pressure(1.2e-5) == pytest.approx(2000.0)
    assert bottom.curvature(1.2e-5) == pytest.approx(1.0)
    # Balloon rest volume 4/3 pi R^3 and the Gent law at the thin-membrane formula.
    assert top.rest_volume == pytest.approx(4.0 / 3.0 * np.pi * 0.01**3)
    lam = 1.5
    i1 = 2 * lam**2 + lam**-4
    dw = 34e3 * (4 * lam - 4 * lam**-5) / 2 / (1 - (i1 - 3) / 16.0)
    assert top.pressure(top.rest_volume * lam**3) == pytest.approx(1.5e-3 / (0.01 * lam**2) * dw)
    assert scene.pump.rate_hz == 50.0
    assert scene.pump.profile.duration() == pytest.approx(2610.0)
    assert scene.camera.trigger_injected_m3 == (5e-6, 2.5e-5)
    assert scene.camera.points_per_segment == 20
    assert scene.outputs == frozenset({'pressure', 'volumes', 'events'})
    assert scene.solver.resolution is None
    assert scene.capacity == pytest.approx(5e-5 + top.max_volume - top.rest_volume)


def test_optional_sections_take_defaults():
    data = valid_scene()
    del data['camera'], data['outputs']
    del data['pump']['flow_rate_m3_per_s'], data['pump']['rate_hz'], data['pump']['cycles']
    scene = scene_from_dict(data, None)
    assert scene.pump.profile.flow_rate == 5e-8
    assert scene.pump.rate_hz == 50.0
    assert scene.camera.rate_hz == 10.0
    assert scene.camera.trigger_injected_m3 == ()
    assert 'image' not in scene.outputs and 'poses' in scene.outputs


def write_table(path: Path) -> None:
    path.write_text('# a test segment\nvolume_m3,pressure_pa,curvature_per_m\n'
                    '1e-5,0,0\n2e-5,5000,3\n4e-5,8000,9\n')


def test_table_path_is_relative_to_the_scene_file(tmp_path, monkeypatch):
    (tmp_path / 'segments').mkdir()
    write_table(tmp_path / 'segments' / 'a.csv')
    data = valid_scene()
    data['segments'][0] = {'name': 'bottom', 'length_m': 0.1, 'table': 'segments/a.csv'}
    data['pump']['legs'] = [{'inflate_to_m3': 3e-5}]
    scene_file = tmp_path / 'scene.yaml'
    scene_file.write_text(yaml.safe_dump(data))
    monkeypatch.chdir('/')
    scene = load_scene(scene_file)
    assert isinstance(scene.segments[0], TabulatedSegment)
    assert scene.segments[0].pressure(2e-5) == pytest.approx(5000.0)
    assert scene.segments[0].length == 0.1


def test_bad_table_names_scene_key_and_table(tmp_path):
    (tmp_path / 'bad.csv').write_text('volume_m3,pressure_pa\n0,0\n1e-5,10\n')
    data = valid_scene()
    data['segments'][0] = {'name': 'bottom', 'length_m': 0.1, 'table': 'bad.csv'}
    with pytest.raises(SceneError) as caught:
        scene_from_dict(data, tmp_path / 's.yaml')
    message = str(caught.value)
    assert message.startswith(f'{tmp_path / "s.yaml"}: segments[0].table: {tmp_path / "bad.csv"}')
    assert 'curvature_per_m' in message and '\n' not in message


def test_yaml_numbers_without_a_dot_are_numbers(tmp_path):
    text = yaml.safe_dump(valid_scene()).replace('5.0e-08', '5e-8')
    assert 'flow_rate_m3_per_s: 5e-8' in text
    path = tmp_path / 's.yaml'
    path.write_text(text)
    assert load_scene(path).pump.profile.flow_rate == 5e-8


def test_duplicate_yaml_key_is_refused_with_its_line(tmp_path):
    path = tmp_path / 's.yaml'
    path.write_text('name: a\nname: b\n')
    with pytest.raises(SceneError, match=r": line 2, column 1: duplicate key 'name'$"):
        load_scene(path)


def test_yaml_syntax_error_is_one_line(tmp_path):
    path = tmp_path / 's.yaml'
    path.write_text('name: a\nsegments: [\n')
    with pytest.raises(SceneError) as caught:
        load_scene(path)
    assert str(caught.value).startswith(f'{path}: line ')
    assert '\n' not in str(caught.value)


def test_missing_scene_file():
    with pytest.raises(SceneError, match='nowhere/x.yaml: scene file not found'):
        load_scene('nowhere/x.yaml')
    with pytest.raises(SceneError, match=r'^nonesuch: no such scene file.*shipped: .*paper'):
        load_scene('nonesuch')


def test_config_dir_is_the_checkout_folder_and_bare_names_resolve():
    assert config_dir() == REPO_CONFIG
    assert scene_path('paper') == REPO_CONFIG / 'paper.yaml'
    assert set(SHIPPED) <= set(shipped_scenes())


def test_installed_layout_is_found(tmp_path, monkeypatch):
    import softseq_ros.scene.paths as paths_module
    share = tmp_path / 'share' / 'softseq_ros' / 'config'
    share.mkdir(parents=True)
    (share / 'paper.yaml').write_text('name: paper\n')
    monkeypatch.setattr(paths_module, '__file__', str(tmp_path / 'lib' / 'a' / 'b' / 'scene.py'))
    monkeypatch.setenv('AMENT_PREFIX_PATH', str(tmp_path))
    assert config_dir() == share


@pytest.mark.parametrize('name', SHIPPED)
def test_shipped_scene_loads(name):
    scene = load_scene(name)
    assert scene.name == name
    assert scene.path == REPO_CONFIG / f'{name}.yaml'
    assert len(scene.segments) >= 2
    assert scene.description
    assert scene.pump.profile.max_injected() <= scene.capacity


def test_paper_scene_matches_the_paper():
    scene = load_scene('paper')
    assert scene.segment_names == ('bottom', 'top')
    assert sum(scene.lengths) == pytest.approx(0.222)
    profile = scene.pump.profile
    assert profile.flow_rate == pytest.approx(0.05 * ML)
    assert profile.max_injected() == pytest.approx(65 * ML)
    assert profile.injected_at(profile.duration()) == 0.0
    assert scene.pump.rate_hz == 50.0 and scene.camera.rate_hz == 10.0
    np.testing.assert_allclose(scene.camera.trigger_injected_m3,
                               np.array([5, 15, 25, 45, 60]) * ML)


def dense_equilibria(scene: Scene, injected: float, n: int = 4001) -> list[tuple[float, bool]]:
    """All (v_bottom, stable) with p_bottom(v) = p_top(V - v), by a sign scan (two segments)."""
    a, b = scene.segments
    total = injected + a.rest_volume + b.rest_volume
    lo, hi = max(a.rest_volume, total - b.max_volume), min(a.max_volume, total - b.rest_volume)
    v = np.linspace(lo, hi, n)
    f = a.pressure(v) - b.pressure(total - v)
    cross = np.nonzero(np.sign(f[1:]) != np.sign(f[:-1]))[0]
    roots = v[cross] - f[cross] * (v[cross + 1] - v[cross]) / (f[cross + 1] - f[cross])
    return [(r, bool(a.stiffness(r) + b.stiffness(total - r) > 0)) for r in roots]


def turning_pressures(segment) -> np.ndarray:
    lam = np.linspace(1.0, np.cbrt(segment.max_volume / segment.rest_volume), 20001)
    p = segment.pressure(segment.rest_volume * lam**3)
    turns = np.nonzero(np.sign(np.diff(p[1:])) != np.sign(np.diff(p[:-1])))[0] + 1
    return p[turns]


def test_fig1_none_has_linear_curves():
    scene = load_scene('fig1_none')
    assert all(isinstance(s, LinearSegment) for s in scene.segments)


def test_fig1_partial_has_a_monotonic_curve_with_a_plateau():
    _, top = load_scene('fig1_partial').segments
    v = np.linspace(top.rest_volume, top.max_volume, 4001)
    k = top.stiffness(v)
    assert np.all(k > 0)                      # no peak: a single equilibrium everywhere
    assert k.min() < 0.02 * k[0]              # but nearly flat somewhere: the plateau


def test_fig1_symmetric_has_a_peak_and_stays_stable():
    scene = load_scene('fig1_symmetric')
    bottom, top = scene.segments
    assert turning_pressures(top).size == 1   # one peak, no valley
    v = np.linspace(top.rest_volume, top.max_volume, 4001)
    assert bottom.stiffness(bottom.rest_volume) > -top.stiffness(v).min()
    for injected in np.linspace(1 * ML, 70 * ML, 30):
        equilibria = dense_equilibria(scene, injected)
        assert len(equilibria) == 1 and equilibria[0][1]


def test_fig1_asymmetric_has_peaks_valleys_and_folds():
    scene = load_scene('fig1_asymmetric')
    bottom, top = scene.segments
    peak_b, valley_b = turning_pressures(bottom)
    peak_t, valley_t = turning_pressures(top)
    # The one with the highest peak has the lowest valley.
    assert peak_b > peak_t and valley_b < valley_t
    counts = [len(dense_equilibria(scene, u)) for u in np.linspace(1 * ML, 60 * ML, 60)]
    # Folds: somewhere three equilibria coexist (two stable, one unstable).
    three = [u for u, c in zip(np.linspace(1 * ML, 60 * ML, 60), counts) if c == 3]
    assert three
    states = dense_equilibria(scene, three[0])
    assert [stable for _, stable in states] == [True, False, True]


@pytest.mark.parametrize('name, kind', [
    ('paper', 'partial'),
    ('fig1_none', 'none'),
    ('fig1_partial', 'partial'),
    ('fig1_symmetric', 'symmetric'),
    ('fig1_asymmetric', 'asymmetric'),
])
def test_fig1_scenes_classify_as_intended(name, kind):
    scene = load_scene(name)
    emap = EquilibriumMap(scene.segments)
    assert classify(emap) == kind
    # The pump never asks for more than the solver covers.
    assert scene.pump.profile.max_injected() <= emap.injected_range[1]


def test_scene_is_frozen():
    scene = scene_from_dict(copy.deepcopy(valid_scene()), None)
    with pytest.raises(AttributeError):
        scene.name = 'other'


def noisy_scene(tmp_path, smoothing=None):
    """A linear partner and a measured-looking table: a smooth plateau curve plus row noise."""
    rng = np.random.default_rng(7)
    v = np.linspace(1e-6, 41e-6, 200)
    clean = 8000.0 * (1.0 - np.exp(-(v - v[0]) / 5e-6))
    noisy = clean + rng.normal(0.0, 0.01 * 8000.0, v.size)
    noisy[0] = 0.0
    rows = '\n'.join(f'{a:.17g},{b:.17g},0.0' for a, b in zip(v, noisy))
    (tmp_path / 'rig.csv').write_text('volume_m3,pressure_pa,curvature_per_m\n' + rows + '\n')
    segment = {'name': 'measured', 'length_m': 0.1, 'table': 'rig.csv'}
    if smoothing is not None:
        segment['smoothing'] = smoothing
    data = {'name': 'noisy', 'segments': [
        {'name': 'spring', 'length_m': 0.1,
         'linear': {'rest_volume_m3': 1e-6, 'stiffness_pa_per_m3': 1e9, 'max_volume_m3': 60e-6}},
        segment],
        'pump': {'legs': [{'inflate_to_m3': 1e-5}]}}
    path = tmp_path / 'noisy.yaml'
    path.write_text(yaml.safe_dump(data))
    return path, clean, v


def test_opt_in_smoothing_removes_the_spurious_snaps_of_noisy_rig_data(tmp_path):
    from softseq_ros.quasistatic.equilibrium import Tracker

    raw_path, clean, v = noisy_scene(tmp_path)
    raw = load_scene(raw_path)
    smoothed = load_scene(noisy_scene(tmp_path, smoothing={})[0])
    # 1 % noise on a 200-row table turns one rising curve into dozens of tiny peaks.
    assert len(raw.segments[1].monotone_pieces()) > 10
    assert len(smoothed.segments[1].monotone_pieces()) == 1
    history = np.concatenate([np.linspace(0, 30e-6, 3000), np.linspace(30e-6, 0, 3000)])
    assert Tracker(EquilibriumMap(raw.segments)).sweep(history).events
    assert not Tracker(EquilibriumMap(smoothed.segments)).sweep(history).events
    # The smoothed curve stays near the noise-free one (noise was 80 Pa).
    error = np.abs(smoothed.segments[1].pressure(v) - clean)
    assert error[5:].max() < 80.0


def test_smoothing_is_for_tables_only(tmp_path):
    data = yaml.safe_load(noisy_scene(tmp_path)[0].read_text())
    data['segments'][0]['smoothing'] = {}
    path = tmp_path / 'bad.yaml'
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(SceneError) as info:
        load_scene(path)
    assert 'segments[0].smoothing: only a table can be smoothed' in str(info.value)
