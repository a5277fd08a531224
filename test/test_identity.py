"""
The segments' digest: the same for the same physics on any machine, different for other physics.

The reference is the definition written out by hand (the JSON a reader can check against the
scene file) and hashed with hashlib here; the other tests change one thing at a time.
"""

import hashlib
import json
import os
from pathlib import Path
import subprocess
import sys

import numpy as np
import pytest
import yaml

from softseq_ros.scene.loader import load_scene
from softseq_ros.segments import identity
from softseq_ros.segments.identity import segments_sha256, short
from softseq_ros.segments.materials import Gent, Ogden, Yeoh, material_definition
from softseq_ros.segments.models import BalloonSegment, LinearSegment, TabulatedSegment

CONFIG = Path(__file__).resolve().parents[1] / 'config'

TABLE = ('volume_m3,pressure_pa,curvature_per_m\n'
         '1.0e-5,0.0,0.0\n'
         '2.0e-5,4000.0,3.5\n'
         '3.0e-5,5000.0,7.25\n'
         '4.5e-5,5200.0,9.0\n')
LINEAR = {'rest_volume_m3': 1.0e-5, 'stiffness_pa_per_m3': 5.0e+8, 'max_volume_m3': 4.0e-5,
          'curvature_per_m_per_m3': 8.0e+5}


def scene_with(folder: Path, table_text: str | bytes, table_name: str = 'seg.csv',
               **segment_changes) -> dict:
    """A two-segment scene: a table at the base, a linear segment at the tip."""
    path = folder / table_name
    if isinstance(table_text, bytes):
        path.write_bytes(table_text)
    else:
        path.write_text(table_text, encoding='utf-8')
    base = {'name': 'bottom', 'length_m': 0.111, 'table': table_name, **segment_changes}
    return {'name': 'digest', 'segments': [base, {'name': 'top', 'length_m': 0.111,
                                                    'linear': dict(LINEAR)}],
            'pump': {'legs': [{'inflate_to_m3': 1.0e-5}]}}


def digest_of(folder: Path, data: dict) -> str:
    scene_file = folder / 'scene.yaml'
    scene_file.write_text(yaml.safe_dump(data), encoding='utf-8')
    return segments_sha256(load_scene(scene_file).segments)


def test_the_digest_is_sha256_of_the_definitions_as_sorted_json(tmp_path):
    data = scene_with(tmp_path, TABLE)
    expected = [
        {'name': 'bottom', 'length_m': 0.111, 'model': 'table',
         'volume_m3': [1.0e-5, 2.0e-5, 3.0e-5, 4.5e-5],
         'pressure_pa': [0.0, 4000.0, 5000.0, 5200.0],
         'curvature_per_m': [0.0, 3.5, 7.25, 9.0]},
        {'name': 'top', 'length_m': 0.111, 'model': 'linear', **LINEAR},
    ]
    text = json.dumps(expected, sort_keys=True, separators=(',', ':'))
    assert digest_of(tmp_path, data) == hashlib.sha256(text.encode()).hexdigest()
    assert len(short(digest_of(tmp_path, data))) == identity.SHORT_LENGTH


def test_the_shipped_balloon_scene_is_hashed_by_the_numbers_in_its_file():
    # Closed-form models are hashed by their parameters, never by sampled curves: the Gent
    # law's logarithm may round differently elsewhere, its parameters do not. The reference
    # is the scene file's own numbers, written out as the definition and hashed here.
    raw = yaml.safe_load((CONFIG / 'fig1_asymmetric.yaml').read_text(encoding='utf-8'))
    expected = []
    for item in raw['segments']:
        balloon = item['balloon']
        expected.append({'name': item['name'], 'length_m': float(item['length_m']),
                         'model': 'balloon',
                         'material': {key: value if key == 'law' else float(value)
                                      for key, value in balloon['material'].items()},
                         **{key: float(balloon[key]) for key in (
                             'radius_m', 'thickness_m', 'max_stretch',
                             'curvature_per_m_per_m3')}})
    text = json.dumps(expected, sort_keys=True, separators=(',', ':'))
    segments = load_scene('fig1_asymmetric').segments
    assert segments_sha256(segments) == hashlib.sha256(text.encode()).hexdigest()


def test_the_digest_is_the_same_in_another_process_with_another_hash_seed():
    code = ('from softseq_ros.segments.identity import segments_sha256; '
            'from softseq_ros.scene.loader import load_scene; '
            'print(segments_sha256(load_scene("paper").segments))')
    digests = set()
    for seed in ('0', '12345'):
        result = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                                timeout=120, env={**os.environ, 'PYTHONHASHSEED': seed})
        assert result.returncode == 0, result.stderr
        digests.add(result.stdout.strip())
    assert digests == {segments_sha256(load_scene('paper').segments)}


def test_what_does_not_change_the_physics_does_not_change_the_digest(tmp_path):
    reference = digest_of(tmp_path, scene_with(tmp_path, TABLE))
    crlf_bom = ('\ufeff# measured on the rig, 2026-03-01\r\n' + TABLE.replace('\n', '\r\n'))
    same = [
        scene_with(tmp_path, crlf_bom.encode('utf-8'), 'crlf.csv'),
        # Other file name, comment lines, column order, an extra column, other spellings of
        # the same numbers, a negative zero.
        scene_with(tmp_path, '# provenance: FEM run 7\n'
                             'curvature_per_m,injected_m3,volume_m3,pressure_pa\n'
                             '-0.0,0,0.00001,0\n'
                             '3.50,1e-5,2e-05,4.0e3\n'
                             '7.25,2e-5,3.0E-5,5000\n'
                             '9,3.5e-5,4.50e-5,5200.000\n', 'other_name.csv'),
    ]
    for data in same:
        assert digest_of(tmp_path, data) == reference
    # The scene's name, description and pump do not define the segments.
    renamed = scene_with(tmp_path, TABLE)
    renamed.update(name='another', description='same segments', pump={
        'legs': [{'inflate_to_m3': 2.0e-5}, {'deflate_to_m3': 0.0}]})
    assert digest_of(tmp_path, renamed) == reference


def test_a_changed_row_length_name_or_order_changes_the_digest(tmp_path):
    reference = digest_of(tmp_path, scene_with(tmp_path, TABLE))
    # One pressure one ulp up.
    bumped = TABLE.replace('4000.0', repr(float(np.nextafter(4000.0, 5000.0))))
    changed = [
        scene_with(tmp_path, bumped, 'bumped.csv'),
        scene_with(tmp_path, TABLE.replace('7.25', '7.5'), 'curvature.csv'),
        scene_with(tmp_path, TABLE + '5.0e-5,5300.0,9.5\n', 'longer.csv'),
        scene_with(tmp_path, TABLE, length_m=0.112),
        scene_with(tmp_path, TABLE, name='base'),
    ]
    digests = {digest_of(tmp_path, data) for data in changed}
    assert reference not in digests and len(digests) == len(changed)
    # Base and tip swapped: the same two segments in another order are another actuator.
    swapped = scene_with(tmp_path, TABLE)
    swapped['segments'].reverse()
    assert digest_of(tmp_path, swapped) != reference


def test_model_parameters_define_closed_form_segments():
    gent = BalloonSegment('b', 0.1, Gent(60e3, 40.0), 0.006, 6e-4, 3.0, curvature_gain=5e5)
    assert gent.definition() == {
        'name': 'b', 'length_m': 0.1, 'model': 'balloon',
        'material': {'law': 'gent', 'shear_modulus_pa': 60000.0, 'jm': 40.0},
        'radius_m': 0.006, 'thickness_m': 0.0006, 'max_stretch': 3.0,
        'curvature_per_m_per_m3': 500000.0}
    thinner = BalloonSegment('b', 0.1, Gent(60e3, 40.0), 0.006, 5.9e-4, 3.0,
                             curvature_gain=5e5)
    stiffer = BalloonSegment('b', 0.1, Gent(61e3, 40.0), 0.006, 6e-4, 3.0, curvature_gain=5e5)
    digests = {segments_sha256([s]) for s in (gent, thinner, stiffer)}
    assert len(digests) == 3
    # Yeoh without C3 is Yeoh with C3 = 0; Ogden's terms are lists.
    assert material_definition(Yeoh(17e3, -200.0)) == material_definition(Yeoh(17e3, -200.0, 0.0))
    assert material_definition(Ogden((22.7e3,), (3.0,))) == {
        'law': 'ogden', 'mu_pa': [22700.0], 'alpha': [3.0]}
    linear = LinearSegment('l', 0.1, 1e-5, 5e8, 4e-5)
    assert linear.definition()['curvature_per_m_per_m3'] == 0.0
    json.dumps([gent.definition(), linear.definition()], allow_nan=False)


def test_a_smoothed_table_is_defined_by_its_rows_and_options_not_by_the_fit(tmp_path,
                                                                           monkeypatch):
    rng = np.random.default_rng(3)
    volumes = np.linspace(1e-5, 5e-5, 40)
    pressures = 6000.0 * np.tanh((volumes - 1e-5) / 1e-5) + rng.normal(0.0, 30.0, 40)
    pressures[0] = 0.0
    rows = ''.join(f'{v!r},{p!r},{1e5 * (v - 1e-5)!r}\n'
                   for v, p in zip(volumes.tolist(), pressures.tolist()))
    text = 'volume_m3,pressure_pa,curvature_per_m\n' + rows
    plain = digest_of(tmp_path, scene_with(tmp_path, text))
    smoothed = digest_of(tmp_path, scene_with(tmp_path, text, smoothing={}))
    explicit = digest_of(tmp_path, scene_with(tmp_path, text, smoothing={'noise_std_pa': 30}))
    other = digest_of(tmp_path, scene_with(tmp_path, text, smoothing={'prominence_pa': 500.0}))
    assert len({plain, smoothed, explicit, other}) == 4
    scene_file = tmp_path / 'scene.yaml'
    segment = load_scene(scene_file).segments[0]
    # The definition holds the rows as read, though the physics runs on the fitted pressures.
    assert segment.definition()['pressure_pa'] == [float(p) for p in pressures]
    assert segment.definition()['smoothing'] == [{'noise_std_pa': None,
                                                  'prominence_pa': 500.0}]
    assert not np.array_equal(segment.pressures, pressures)
    # A fit that rounds one bit differently (another machine's LAPACK) leaves the digest.
    import softseq_ros.scene.loader as scene_module

    original = scene_module.smooth_table
    monkeypatch.setattr(scene_module, 'smooth_table',
                        lambda *a, **k: np.nextafter(original(*a, **k), np.inf))
    again = load_scene(scene_file).segments[0]
    assert not np.array_equal(again.pressures, segment.pressures)
    assert segments_sha256([again]) == segments_sha256([segment])


def test_a_fem_table_rewritten_with_other_provenance_keeps_its_digest(tmp_path):
    pytest.importorskip('felupe')
    from softseq_ros.fem.table import FemResult, write_table
    from softseq_ros.scene.design import load_design

    committed = load_scene('paper_fem')
    table = committed.segments[1]
    design = load_design(CONFIG / 'designs' / 'paper_top.yaml')

    def result(pressures, iterations):
        return FemResult(design, table.volumes, pressures, table.curvatures,
                         np.zeros_like(table.volumes), 'reached the requested volume', False,
                         4297, 1091, 1600, iterations, 12.5)

    folder = tmp_path / 'segments'
    write_table(result(table.pressures, 999), folder / 'paper_fem_top.csv')
    (folder / 'paper_fem_bottom.csv').write_bytes(
        (CONFIG / 'segments' / 'paper_fem_bottom.csv').read_bytes())
    data = yaml.safe_load((CONFIG / 'paper_fem.yaml').read_text())
    scene_file = tmp_path / 'paper_fem.yaml'
    scene_file.write_text(yaml.safe_dump(data))
    # Other Newton count and wall time in the comments, no cut curvature: the same table.
    assert segments_sha256(load_scene(scene_file).segments) == \
        segments_sha256(committed.segments)
    bumped = table.pressures.copy()
    bumped[5] *= 1.0 + 1e-9
    write_table(result(bumped, 999), folder / 'paper_fem_top.csv')
    assert segments_sha256(load_scene(scene_file).segments) != \
        segments_sha256(committed.segments)


def test_a_segment_named_by_its_design_is_defined_by_the_design_not_the_fem_rows(
        tmp_path, monkeypatch):
    pytest.importorskip('felupe')  # the table's cache key names the FEM library's version
    from softseq_ros.scene.design import cache_path, load_design

    monkeypatch.setenv('SOFTSEQ_FEM_CACHE', str(tmp_path / 'cache'))
    committed = load_scene('paper_fem').segments[1]
    (tmp_path / 'designs').mkdir()
    scene = yaml.safe_load((CONFIG / 'paper_fem.yaml').read_text())
    scene['segments'][0]['table'] = str(CONFIG / scene['segments'][0]['table'])
    scene['segments'][1] = {'name': 'top', 'length_m': 0.111, 'design': 'designs/top.yaml'}
    scene_file = tmp_path / 'designed.yaml'
    scene_file.write_text(yaml.safe_dump(scene))

    def digest(geometry: dict, pressure_factor: float = 1.0) -> str:
        design = yaml.safe_load((CONFIG / 'designs' / 'paper_top.yaml').read_text())
        design['geometry'].update(geometry)
        path = tmp_path / 'designs' / 'top.yaml'
        path.write_text(yaml.safe_dump(design))
        # The table `softseq fem` would have cached, its rows as some machine rounds them.
        table = cache_path(load_design(path))
        table.parent.mkdir(parents=True, exist_ok=True)
        pressures = (committed.pressures * pressure_factor).tolist()
        table.write_text('volume_m3,pressure_pa,curvature_per_m\n' + ''.join(
            f'{v!r},{p!r},{k!r}\n' for v, p, k in zip(
                committed.volumes.tolist(), pressures, committed.curvatures.tolist())))
        loaded = load_scene(scene_file)
        assert loaded.segments[1].definition()['model'] == 'design'
        assert loaded.segments[1].pressures.tolist() == pressures
        return segments_sha256(loaded.segments)

    reference = digest({})
    # Another machine's FEM rounds the rows otherwise: the same design, the same digest.
    assert digest({}, pressure_factor=1.0 + 1e-15) == reference
    # Another design (a thicker top membrane) is other physics.
    assert digest({'membrane_thickness_m': 0.0006}) != reference
    # The committed copy of a FEM table is a table: its rows define it.
    assert reference != segments_sha256(load_scene('paper_fem').segments)


def test_a_table_built_in_memory_is_defined_by_its_arrays():
    volumes, pressures, curvatures = [1e-5, 2e-5, 3e-5], [0.0, 10.0, 12.0], [0.0, 1.0, 2.0]
    one = TabulatedSegment('s', 0.1, volumes, pressures, curvatures, source='a.csv')
    two = TabulatedSegment('s', 0.1, np.array(volumes), np.array(pressures),
                           np.array(curvatures), source='elsewhere/b.csv')
    assert segments_sha256([one]) == segments_sha256([two])
