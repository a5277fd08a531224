"""
softseq scatter on a scene whose segments are FEM designs: a design's modulus and geometry.

The pair is the paper's on the coarsest mesh the designs allow (3.75 mm unit cells to 30 mL,
the tables of the design search's tiny problem, shipped in bench/fem_design/tiny_cache); the
top's own table at 0.5 mm is one FEM run of about two seconds, the rest is the shipped cache.

- A design's every modulus times k leaves the FEM's state at each volume as it is and
  multiplies its pressure by k (the bulk modulus is a fixed multiple of the shear modulus):
  checked against a direct FEM run of the stiffer material.
- A drawn membrane thickness is read from unit cells on a grid over the distribution's range,
  interpolated: checked against a direct FEM run between the grid points.
"""

import json
import os
from pathlib import Path
import shutil
import subprocess
import sys

import numpy as np
import pytest
import yaml

from softseq_ros.analysis import scatter
from softseq_ros.cli import main
from softseq_ros.fem.design_grid import ensure_tables
from softseq_ros.scene.design import load_design, with_changes
from softseq_ros.scene.loader import scene_from_dict
from softseq_ros.scene.tables import read_table

REPO = Path(__file__).resolve().parents[1]
SHIPPED = REPO / 'bench' / 'fem_design' / 'tiny_cache'
COARSE = {'model': 'unit_cell', 'element_size_m': 0.00375, 'thin_layer_cells': 1,
          'bulk_ratio': 5000.0}
MU = 16300.0   # the designs' Arruda-Boyce shear modulus [Pa]


@pytest.fixture(scope='module')
def pair(tmp_path_factory):
    """(scene file, FEM cache): the coarse pair, its tables cached (the top's computed)."""
    folder = tmp_path_factory.mktemp('design_scatter')
    cache = folder / 'cache'
    shutil.copytree(SHIPPED, cache)
    segments = []
    for name in ('bottom', 'top'):
        data = yaml.safe_load((REPO / 'config' / 'designs' / f'paper_{name}.yaml').read_text())
        data['mesh'] = dict(COARSE)
        data['volume']['max_injected_m3'] = 3.0e-5
        path = folder / f'paper_{name}.yaml'
        path.write_text(yaml.safe_dump(data))
        _, runs = ensure_tables([load_design(path)], cache, 1, None, None, name)
        assert runs == (1 if name == 'top' else 0)   # the bottom is the shipped table
        segments.append({'name': name, 'length_m': 0.111, 'design': str(path)})
    scene = folder / 'fem_pair.yaml'
    scene.write_text(yaml.safe_dump({'name': 'fem_pair', 'segments': segments,
                                     'pump': {'legs': [{'inflate_to_m3': 3.0e-5}]}}))
    return scene, cache


@pytest.fixture
def scene(pair, monkeypatch):
    path, cache = pair
    monkeypatch.setenv('SOFTSEQ_FEM_CACHE', str(cache))
    return scene_from_dict(yaml.safe_load(path.read_text()))


def _direct(cache: Path, design) -> object:   # noqa: ANN001
    paths, _ = ensure_tables([design], cache, 1, None, None, 'direct')
    return read_table(paths[design.digest()], name='top', length=0.111)


def test_a_designs_modulus_scales_its_fem_table_as_a_direct_fem_run_does(pair, scene):
    _, cache = pair
    parameters = scatter.parameters_of(scene, {'top.material.shear_modulus_pa': 'normal:5%',
                                               'top.modulus_scale': 'uniform:10%'})
    assert [p.nominal for p in parameters] == [MU, 1.0]
    model = scatter.ScatterModel.of(scene, parameters)
    top = scene.segments[1]
    stiffer = _direct(cache, with_changes(load_design(Path(pair[0]).parent / 'paper_top.yaml'),
                                          {'material.shear_modulus_pa': 1.1 * MU}))
    np.testing.assert_allclose(stiffer.volumes, top.volumes, rtol=1e-12)
    np.testing.assert_allclose(stiffer.curvatures, top.curvatures, rtol=1e-6, atol=1e-9)
    for values in ([1.1 * MU, 1.0], [MU, 1.1], [1.1 ** 0.5 * MU, 1.1 ** 0.5]):
        drawn = model.segments_at(values)[1]
        np.testing.assert_allclose(drawn.pressures, stiffer.pressures, rtol=1e-6, atol=1e-6)
        np.testing.assert_array_equal(drawn.curvatures, top.curvatures)
    assert model.segments_at([MU, 1.0])[0] is scene.segments[0]   # the bottom as it was


def test_a_designs_membrane_thickness_is_read_from_its_unit_cells(pair, scene):
    _, cache = pair
    parameters = scatter.parameters_of(
        scene, {'top.geometry.membrane_thickness_m': 'uniform:0.0004,0.0006'})
    said = []
    model, grids = scatter.with_fem_grid(scatter.ScatterModel.of(scene, parameters), 3, cache,
                                         1, None, said.append)
    # 0.4 and 0.6 mm are the shipped tables, 0.5 mm the scene's own: nothing computed.
    assert grids == [{'segment': 'top', 'design': 'paper_top', 'scene_model': 'unit_cell',
                      'element_size_m': 0.00375,
                      'axes': {'membrane_thickness_m': [0.0004, 0.0005, 0.0006]},
                      'tables': 3, 'computed': 0}]
    assert any('3 unit-cell FEM tables of design paper_top' in line for line in said)
    top = scene.segments[1]
    at_scene = model.segments_at([0.0005])[1]
    # At a grid point: the scene's table, resampled at the grid's cell volumes.
    volumes = top.volumes[1:]
    assert np.max(np.abs(at_scene.pressure(volumes) / top.pressures[1:] - 1)) < 0.01
    # Half-way between grid points, where linear interpolation is worst, against direct FEM.
    design = with_changes(load_design(Path(pair[0]).parent / 'paper_top.yaml'),
                          {'geometry.membrane_thickness_m': 0.00045})
    direct = _direct(cache, design)
    drawn = model.segments_at([0.00045])[1]
    assert drawn.rest_volume == pytest.approx(direct.rest_volume, rel=1e-12)
    error = drawn.pressure(direct.volumes[1:]) / direct.pressures[1:] - 1
    assert np.max(np.abs(error)) < 0.02
    # Thinner membranes: lower pressure at every volume (the grid's order, kept in between).
    thin, thick = (model.segments_at([t])[1] for t in (0.0004, 0.0006))
    assert np.all(thin.pressure(volumes[1:]) < drawn.pressure(volumes[1:]))
    assert np.all(drawn.pressure(volumes[1:]) < thick.pressure(volumes[1:]))


def test_a_design_scatter_on_the_command_line_computes_its_grid_once(pair, tmp_path):
    path, cache = pair
    env = {**os.environ, 'SOFTSEQ_FEM_CACHE': str(cache)}
    words = [sys.executable, '-m', 'softseq_ros.cli', 'scatter', str(path),
             '--vary', 'top.geometry.membrane_thickness_m=normal:5%',
             '--vary', 'top.modulus_scale=normal:5%', '--samples', '30', '--sobol', '0',
             '--workers', '1', '--seed', '3']
    runs = []
    for out in (tmp_path / 'first', tmp_path / 'again'):
        done = subprocess.run([*words, '--out', str(out)], capture_output=True, text=True,
                              timeout=300, stdin=subprocess.DEVNULL, env=env)
        assert done.returncode == 0, done.stderr
        runs.append(json.loads((out / 'scatter.json').read_text()))
        assert 'unit-cell FEM tables of design paper_top' in done.stderr
        assert 'note: segment top: its geometry from 3 unit-cell FEM tables' in done.stdout
    first, again = runs
    # The normal's ends (+-4.75 deviations) are new cells; the middle one is the scene's.
    assert first['fem_grids'][0]['computed'] == 2 and again['fem_grids'][0]['computed'] == 0
    axis = first['fem_grids'][0]['axes']['membrane_thickness_m']
    assert axis[1] == 0.0005
    assert axis[0] == pytest.approx(0.0005 * (1 - 0.05 * 4.753), rel=1e-3)
    assert first['samples'] == again['samples']
    # The pressure the pair levels off at is the top's: times the modulus scale exactly, and
    # rising with the thickness, less than in proportion (the skin and walls carry part).
    rows = [s for s in first['samples'] if s['plateau_pressure_pa'] is not None]
    assert len(rows) >= 25
    x = np.log([[s['values'][0] / 0.0005, s['values'][1]] for s in rows])
    y = np.log([s['plateau_pressure_pa'] for s in rows])
    (_, thickness, modulus), *_ = np.linalg.lstsq(np.column_stack([np.ones(len(y)), x]), y,
                                                 rcond=None)
    assert modulus == pytest.approx(1.0, abs=0.05)
    assert 0.2 < thickness < 0.8


BAD = {
    'a_geometry_key_not_drawn': ('top.geometry.height_m=normal:5%',
                                 'segment top is the FEM table of design paper_top: it has '
                                 'pressure_scale, noise_std_pa, modulus_scale, '
                                 'geometry.membrane_thickness_m, geometry.wall_thickness_m, '
                                 'material.shear_modulus_pa, not'),
    'a_law_shape_parameter': ('top.material.lambda_m=normal:5%',
                              'lambda_m alone changes the shape of the arruda_boyce law'),
    'no_cavity_left': ('top.geometry.membrane_thickness_m=uniform:0.0004,0.02',
                       'top.geometry.membrane_thickness_m=uniform:0.0004,0.02: its highest '
                       'draw, 0.02, is refused: '),
    'a_negative_modulus': ('top.modulus_scale=uniform:-1,2',
                           'its lowest draw, -1, is refused: top.modulus_scale: a modulus '
                           'must be > 0'),
}


@pytest.mark.parametrize('case', sorted(BAD))
def test_a_designs_bad_parameters_are_refused_in_one_line(case, pair, monkeypatch, capsys,
                                                          tmp_path):
    path, cache = pair
    monkeypatch.setenv('SOFTSEQ_FEM_CACHE', str(cache))
    word, expected = BAD[case]
    out = tmp_path / 'out'
    code = main(['scatter', str(path), '--vary', word, '--out', str(out), '--quiet'])
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith('softseq scatter: error: '), err
    assert expected in lines[0], lines[0]
    assert not out.exists()
