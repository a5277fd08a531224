"""Segment design files, the `softseq fem` command's refusals, the table cache and layering."""

import ast
from pathlib import Path
import subprocess
import sys

import numpy as np
import pytest
import yaml

from softseq_ros.fem.segment import build_segment
from softseq_ros.scene.design import DesignError, design_from_dict, load_design, with_changes
from softseq_ros.scene.loader import SceneError, load_scene
from softseq_ros.scene.tables import read_table

REPO = Path(__file__).resolve().parents[1]
TOP = REPO / 'config' / 'designs' / 'paper_top.yaml'
BOTTOM = REPO / 'config' / 'designs' / 'paper_bottom.yaml'


def _raw(path: Path = TOP) -> dict:
    return yaml.safe_load(path.read_text())


def _error(data: dict) -> str:
    with pytest.raises(DesignError) as info:
        design_from_dict(data, 'x.yaml')
    message = str(info.value)
    assert '\n' not in message
    return message


def test_shipped_designs_are_table_i():
    top, bottom = load_design(TOP), load_design(BOTTOM)
    for design in (top, bottom):
        g = design.geometry
        assert (g.length_m, g.height_m, g.width_m) == (0.111, 0.015, 0.015)
        assert (g.beam_thickness_m, g.cavity_width_m) == (0.005, 0.011)
        assert (g.wall_length_m, g.membrane_length_m) == (0.004, 0.006)
        assert g.wall_reading == 'skin_bands'
        assert g.side_wall_thickness_m == pytest.approx(0.002)
        assert g.membranes == 11
        assert g.end_cap_length_m == pytest.approx(0.0025)
    assert (top.geometry.membrane_thickness_m, top.geometry.wall_thickness_m) == (0.0005, 0.002)
    assert (bottom.geometry.membrane_thickness_m,
            bottom.geometry.wall_thickness_m) == (0.001, 0.001)


@pytest.mark.parametrize('edit, expected', [
    (lambda d: d['geometry'].pop('height_m'),
     'x.yaml: geometry.height_m: required key is missing'),
    (lambda d: d['geometry'].update(height_mm=15), 'x.yaml: geometry.height_mm: wrong or missing '
                                                   'unit suffix; scene files use SI units, '
                                                   'write height_m'),
    (lambda d: d['geometry'].update(membrane_thickness_m=-1e-3),
     'x.yaml: geometry.membrane_thickness_m: must be > 0, got -0.001'),
    (lambda d: d['geometry'].update(cavity_width_m=0.02),
     'x.yaml: geometry.cavity_width_m: must be below width_m'),
    (lambda d: d['geometry'].update(wall_reading='ribs'),
     "x.yaml: geometry.wall_reading: unknown reading 'ribs'"),
    (lambda d: d['geometry'].update(wall_reading='side_walls', wall_thickness_m=0.001,
                                    skin_band_thickness_m=0.002),
     'x.yaml: geometry.cavity_width_m: with side walls 0.001 m thick the cavity is'),
    (lambda d: d['geometry'].update(wall_reading='side_walls'),
     'x.yaml: geometry.skin_band_thickness_m: required with wall_reading side_walls'),
    (lambda d: d['geometry'].update(wall_thickness_m=0.011),
     'x.yaml: geometry.wall_thickness_m: must leave a cavity'),
    (lambda d: d['material'].update(law='rubber'),
     "x.yaml: material.law: unknown material law 'rubber'"),
    (lambda d: d['material'].pop('lambda_m'),
     'x.yaml: material.lambda_m: required key is missing'),
    (lambda d: d['mesh'].update(model='quarter'), "x.yaml: mesh.model: unknown model 'quarter'"),
    (lambda d: d['mesh'].update(element_size_m=0.01),
     'x.yaml: mesh.element_size_m: must be at most a quarter of height_m'),
    (lambda d: d['volume'].update(first_step_m3=1.0),
     'x.yaml: volume.first_step_m3: must not exceed max_injected_m3'),
    (lambda d: d.update(extra=1), 'x.yaml: extra: unknown key'),
    (lambda d: d['geometry'].update(membrane_thickness_factors=[1.0] * 11),
     'x.yaml: geometry.membrane_thickness_factors: only for mesh.model whole_segment'),
    (lambda d: (d['mesh'].update(model='whole_segment'),
                d['geometry'].update(membrane_thickness_factors=[1.0] * 10)),
     'x.yaml: geometry.membrane_thickness_factors: must be a list of 11 numbers'),
    (lambda d: (d['mesh'].update(model='whole_segment'),
                d['geometry'].update(membrane_thickness_factors=[1.0] * 10 + [2.0])),
     'x.yaml: geometry.membrane_thickness_factors[10]: must be <= 1.5'),
    (lambda d: (d['mesh'].update(model='whole_segment'),
                d['geometry'].update(membrane_thickness_factors=[0.2] + [1.0] * 10)),
     'x.yaml: geometry.membrane_thickness_factors[0]: must be >= 0.5, got 0.2'),
])
def test_bad_designs_are_refused_with_one_line_naming_the_key(edit, expected):
    data = _raw()
    edit(data)
    assert _error(data).startswith(expected)


def test_the_other_wall_reading_is_expressible():
    data = _raw()
    # Side walls d = 2 mm thick (the top segment's d) are consistent with g = 11 mm.
    data['geometry'].update(wall_reading='side_walls', skin_band_thickness_m=0.002)
    design = design_from_dict(data, 'x.yaml')
    assert design.geometry.side_wall_thickness_m == pytest.approx(0.002)
    assert design.geometry.skin_band_thickness_m == 0.002
    # For the bottom segment (d = 1 mm) that reading needs a 13 mm cavity: g must say so.
    data = _raw(BOTTOM)
    data['geometry'].update(wall_reading='side_walls', skin_band_thickness_m=0.001)
    assert '= 0.013 m wide, got 0.011' in _error(data)
    data['geometry']['cavity_width_m'] = 0.013
    assert design_from_dict(data, 'x.yaml').geometry.side_wall_thickness_m == pytest.approx(0.001)


def test_design_hash_follows_what_decides_the_result():
    top = load_design(TOP)
    same = with_changes(top, {})
    assert same.digest() == top.digest()
    renamed = design_from_dict({**_raw(), 'description': 'other words'}, 'y.yaml')
    assert renamed.digest() == top.digest()
    for change in ({'geometry.membrane_thickness_m': 0.0006}, {'material.lambda_m': 4.5},
                   {'mesh.element_size_m': 0.001}, {'volume.max_injected_m3': 6e-5}):
        assert with_changes(top, change).digest() != top.digest()


def test_membrane_thickness_factors_thin_one_membrane_and_change_only_that_designs_hash():
    coarse = {'mesh.element_size_m': 0.002, 'mesh.thin_layer_cells': 1,
              'mesh.model': 'whole_segment'}
    even = with_changes(load_design(TOP), coarse)
    factors = [1.0] * 5 + [0.9] + [1.0] * 5
    odd = with_changes(even, {'geometry.membrane_thickness_factors': factors})
    assert odd.geometry.membrane_thickness_factors == tuple(factors)
    assert odd.digest() != even.digest()
    # A design without factors keeps the hash it had before they existed.
    assert 'membrane_thickness_factors' not in load_design(TOP).identity()['geometry']
    g = even.geometry
    base, thinned = build_segment(even), build_segment(odd)
    # The sixth membrane's skin is 10 % thinner: the cavity grows by that sliver of fluid.
    sliver = 0.1 * g.membrane_thickness_m * g.membrane_length_m * g.cavity_width_m / 2
    assert (thinned.model.rest_volume - base.model.rest_volume
            == pytest.approx(sliver, rel=1e-9))
    # The outer surface stays flat.
    assert thinned.model.reference[:, 2].max() == pytest.approx(g.height_m, abs=1e-15)


def test_both_models_mesh_the_table_i_cavity():
    coarse = {'mesh.element_size_m': 0.002, 'mesh.thin_layer_cells': 1}
    top = with_changes(load_design(TOP), coarse)
    cell = build_segment(top)
    whole = build_segment(with_changes(top, {'mesh.model': 'whole_segment'}))
    g = top.geometry
    cavity = g.cavity_width_m * (g.membranes * g.membrane_length_m
                                 * (g.height_m - g.beam_thickness_m - g.membrane_thickness_m)
                                 + (g.membranes - 1) * g.wall_length_m
                                 * (g.height_m - g.beam_thickness_m - g.skin_band_thickness_m))
    assert whole.segment_volume(whole.model.rest_volume) == pytest.approx(cavity, rel=1e-12)
    # The unit cell counts 11 whole walls, the segment 10 between its end caps.
    per_wall = g.cavity_width_m * g.wall_length_m * (g.height_m - g.beam_thickness_m
                                                     - g.skin_band_thickness_m)
    assert cell.segment_volume(cell.model.rest_volume) == pytest.approx(cavity + per_wall,
                                                                       rel=1e-12)
    assert whole.dofs > 5 * cell.dofs


def _softseq(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, '-m', 'softseq_ros.cli', 'fem', *args],
                          capture_output=True, text=True, env=env, timeout=120)


@pytest.mark.parametrize('args, expected', [
    (['no_such_design'], 'no_such_design: no such design file and no shipped design'),
    (['paper_top', '--set', 'mesh.element_size_m'], "--set 'mesh.element_size_m': expected "
                                                    'KEY=VALUE'),
    (['paper_top', '--set', 'geometry.spam_m=1'], 'geometry.spam_m: no such key'),
    (['paper_top', '--set', 'geometry.membrane_thickness_m=0'],
     'geometry.membrane_thickness_m: must be > 0, got 0'),
    (['paper_top', '--workers', '2'], '--workers: only with --sweep'),
    (['paper_top', '--sweep', 'mesh.element_size_m=0.001,0.002'], '--sweep: needs --out-dir'),
    (['paper_top', '--sweep', 'mesh.element_size_m=0.001', '--out-dir', 'x', '--workers', '0'],
     '--workers: must be >= 1, got 0'),
    (['paper_top', '--sweep', 'mesh.element_size_m=0.001', '--out-dir', 'x',
      '--scheduler', 'tcp://127.0.0.1:1', '--workers', '2'], '--workers: not with --scheduler'),
])
def test_fem_command_refuses_bad_requests_before_starting(args, expected, tmp_path, capsys,
                                                         monkeypatch):
    from softseq_ros.cli import main

    monkeypatch.chdir(tmp_path)
    assert main(['fem', *args]) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith('softseq fem: error: ')
    assert expected in lines[0]
    assert not captured.out and not list(tmp_path.iterdir())  # refused before any work


def test_fem_command_computes_once_then_serves_the_cache(tmp_path):
    env = {**__import__('os').environ, 'SOFTSEQ_FEM_CACHE': str(tmp_path / 'cache'),
           'OMP_NUM_THREADS': '1'}
    quick = ['--set', 'mesh.element_size_m=0.003', '--set', 'mesh.thin_layer_cells=1',
             '--set', 'volume.max_injected_m3=3e-6']
    out = tmp_path / 'top.csv'
    first = _softseq('paper_top', *quick, '--out', str(out), env=env)
    assert first.returncode == 0, first.stderr
    assert 'computed in' in first.stdout
    assert 'mL injected' in first.stderr  # progress while it runs
    text = out.read_text()
    assert '# Material: arruda_boyce' in text and 'design hash' in text
    cached = list((tmp_path / 'cache').glob('paper_top-*.csv'))
    assert len(cached) == 1 and cached[0].read_text() == text
    again = _softseq('paper_top', *quick, '--out', str(tmp_path / 'again.csv'), '--quiet',
                     env=env)
    assert again.returncode == 0 and 'from the cache' in again.stdout
    assert (tmp_path / 'again.csv').read_text() == text


def _imports(path: Path) -> set[str]:
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            found.add(node.module)
    return found


def test_physics_and_the_rig_never_import_the_fem():
    light = [*(path for layer in ('segments', 'scene', 'quasistatic', 'rig')
               for path in sorted((REPO / 'softseq_ros' / layer).rglob('*.py'))),
             *sorted((REPO / 'softseq_ros' / 'nodes').rglob('*.py')),
             REPO / 'softseq_ros' / 'batch.py']
    heavy = ('softseq_ros.fem', 'felupe', 'tensortrax', 'pymetis', 'dask', 'distributed')
    for path in light:
        bad = {name for name in _imports(path) if name.startswith(heavy)}
        assert not bad, f'{path.relative_to(REPO)} imports {bad}'


def test_the_fem_package_is_installed_with_the_rest():
    from setuptools import find_packages

    # A folder without __init__.py works in a source checkout but is left out of an install.
    assert 'softseq_ros.fem' in find_packages(str(REPO), exclude=['test', 'test.*', 'bench',
                                                                  'bench.*'])
    assert (REPO / 'config' / 'designs' / 'paper_top.yaml').is_file()


def test_a_scene_naming_a_design_gets_its_table_from_the_cache(tmp_path, monkeypatch):
    cache = tmp_path / 'cache'
    monkeypatch.setenv('SOFTSEQ_FEM_CACHE', str(cache))
    design = yaml.safe_load(TOP.read_text())
    design['name'] = 'quick_top'
    design['mesh'].update(element_size_m=0.003, thin_layer_cells=1)
    design['volume']['max_injected_m3'] = 3e-6
    (tmp_path / 'designs').mkdir()
    (tmp_path / 'designs' / 'quick_top.yaml').write_text(yaml.safe_dump(design))
    bottom = REPO / 'config' / 'segments' / 'paper_bottom.csv'
    scene = {'name': 'designed', 'segments': [
        {'name': 'bottom', 'length_m': 0.111, 'table': str(bottom)},
        {'name': 'top', 'length_m': 0.111, 'design': 'designs/quick_top.yaml'}],
        'pump': {'legs': [{'inflate_to_m3': 2e-6}, {'deflate_to_m3': 0.0}]}}
    scene_file = tmp_path / 'designed.yaml'
    scene_file.write_text(yaml.safe_dump(scene))
    # Not computed yet: the scene says how to make the table, and starts no FEM itself.
    with pytest.raises(SceneError) as missing:
        load_scene(scene_file)
    assert str(missing.value).startswith(f'{scene_file}: segments[1].design: ')
    assert 'no FEM table of this design' in str(missing.value)
    assert 'softseq fem' in str(missing.value) and not cache.exists()
    made = _softseq(str(tmp_path / 'designs' / 'quick_top.yaml'), '--quiet',
                    env={**__import__('os').environ, 'OMP_NUM_THREADS': '1'})
    assert made.returncode == 0, made.stderr
    cached, = cache.glob('quick_top-*.csv')
    top = load_scene(scene_file).segments[1]
    lines = [line for line in cached.read_text().splitlines() if not line.startswith('#')]
    header, *rows = [line.split(',') for line in lines]
    columns = {name: np.array([float(row[i]) for row in rows]) for i, name in enumerate(header)}
    np.testing.assert_array_equal(top.volumes, columns['volume_m3'])
    np.testing.assert_array_equal(top.pressures, columns['pressure_pa'])
    # The segment's length is the design's.
    scene['segments'][1]['length_m'] = 0.2
    scene_file.write_text(yaml.safe_dump(scene))
    with pytest.raises(SceneError, match=r'segments\[1\]\.length_m: 0\.2 m differs from the '
                                         r"design's geometry\.length_m \(0\.111 m\)"):
        load_scene(scene_file)


def test_a_table_with_a_snap_through_says_where_and_reads_as_a_segment(tmp_path):
    from softseq_ros.fem.table import FemResult, write_table

    design = with_changes(load_design(TOP), {'mesh.model': 'whole_segment'})
    # A ramp that snaps between rows 3 and 4: the pressure drops over one tiny volume step.
    injected = np.array([0.0, 5.0, 10.0, 15.0, 15.002, 20.0]) * 1e-6
    pressures = np.array([0.0, 1500.0, 2300.0, 2400.0, 1900.0, 2100.0])
    result = FemResult(design, 2e-5 + injected, pressures, np.linspace(0.0, 30.0, 6),
                       np.zeros(6), 'reached the requested volume', False, 7354, 1545, 2656,
                       200, 60.0, snaps=[(4, 5, 0.0031)])
    path = write_table(result, tmp_path / 'snapped.csv')
    comments = [line for line in path.read_text().splitlines() if line.startswith('#')]
    (line,) = [c for c in comments if '15.002 mL injected' in c]
    assert '2400.0 -> 1900.0 Pa' in line and 'membrane 6 of 11 (from the base)' in line
    assert 'bulges 3.10 mm more' in line
    segment = read_table(path, length=design.geometry.length_m)
    # A scene reads the snap as a fall over that tiny volume step, without overshoot.
    assert segment.pressure(2e-5 + 15.001e-6) == pytest.approx(2150.0, rel=0.05)
    assert float(segment.stiffness(2e-5 + 15.001e-6)) < -1e10
