"""The whole actuator on one cavity (`softseq fem ... --model actuator`), coarse short meshes."""

import csv
from pathlib import Path

import numpy as np
import pytest

from softseq_ros.scene.design import load_design, with_changes

REPO = Path(__file__).resolve().parents[1]
DESIGNS = REPO / 'config' / 'designs'
# Two pitches per segment (caps of half a wall: two segments meet in one wall band), coarse.
SHORT = {'geometry.length_m': 0.02, 'mesh.element_size_m': 0.003, 'mesh.thin_layer_cells': 1,
         'volume.max_injected_m3': 1.5e-6, 'volume.first_step_m3': 5e-7,
         'volume.max_step_m3': 5e-7}


def _rows(path: Path) -> list[dict]:
    lines = [line for line in path.read_text().splitlines() if not line.startswith('#')]
    return [{k: float(v) for k, v in row.items()} for row in csv.DictReader(lines)]


@pytest.fixture(scope='module')
def two_equal_halves(tmp_path_factory):
    """The top design twice on one cavity (via the command) and as one segment twice as long."""
    from softseq_ros.cli import main
    from softseq_ros.fem.table import run_design

    folder = tmp_path_factory.mktemp('actuator')
    sets = [arg for key, value in SHORT.items() for arg in ('--set', f'{key}={value}')]
    out = folder / 'actuator.csv'
    code = main(['fem', 'paper_top', 'paper_top', '--model', 'actuator', *sets, '--out',
                 str(out), '--cache-dir', str(folder / 'cache'), '--quiet'])
    assert code == 0
    whole = run_design(with_changes(load_design(DESIGNS / 'paper_top.yaml'),
                                    {**SHORT, 'geometry.length_m': 0.04,
                                     'mesh.model': 'whole_segment'}))
    return _rows(out), whole, out


def test_two_equal_segments_on_one_cavity_are_one_segment_twice_as_long(two_equal_halves):
    rows, whole, _ = two_equal_halves
    # Same mesh, same cavity, same constraint: the same PV curve to round-off.
    assert len(rows) == whole.volumes.size
    injected = np.array([r['injected_m3'] for r in rows])
    pressure = np.array([r['pressure_pa'] for r in rows])
    assert injected[-1] == pytest.approx(1.5e-6, rel=1e-9)
    np.testing.assert_allclose(injected, whole.injected, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(pressure[1:], whole.pressures[1:], rtol=1e-7)
    # The parts add up to the whole cavity at every row.
    by_part = np.array([[r['volume_s0_m3'], r['volume_s1_m3']] for r in rows])
    np.testing.assert_allclose(by_part.sum(axis=1), whole.volumes, rtol=1e-12)
    # The base half is clamped, the tip half free: it takes more of the fluid and bends more.
    assert rows[-1]['volume_s1_m3'] > rows[-1]['volume_s0_m3']
    assert rows[-1]['curvature_s1_per_m'] > max(rows[-1]['curvature_s0_per_m'], 0.1)
    # The backbone: the tip beyond the junction along x, bent toward the beam (-z).
    assert rows[-1]['end_s1_x_m'] > rows[-1]['end_s0_x_m'] > 0.019
    assert rows[0]['end_s1_z_m'] > rows[-1]['end_s1_z_m']


def test_each_part_of_the_cavity_at_rest_is_its_geometry():
    from softseq_ros.fem.actuator import run_actuator

    designs = [with_changes(load_design(DESIGNS / f'paper_{name}.yaml'),
                            {**SHORT, 'volume.max_injected_m3': 5e-7}) for name in
               ('bottom', 'top')]
    result = run_actuator(designs)
    for index, design in enumerate(designs):
        g = design.geometry
        cavity = g.height_m - g.beam_thickness_m
        # Membranes over the cavity, and the wall bands between them and in the junction.
        under_membranes = g.membranes * g.membrane_length_m * (cavity - g.membrane_thickness_m)
        bands = (g.membranes - 1) * g.wall_length_m + g.end_cap_length_m
        expected = g.cavity_width_m * (under_membranes
                                       + bands * (cavity - g.skin_band_thickness_m))
        assert result.volumes[0, index] == pytest.approx(expected, rel=1e-12)
    # The fluid injected goes into the two parts and nowhere else.
    np.testing.assert_allclose(result.injected_by_segment().sum(axis=1), result.injected,
                               rtol=1e-9, atol=1e-16)
    assert result.stop_reason == 'reached the requested volume'


@pytest.mark.parametrize('args, expected', [
    (['paper_top', '--model', 'actuator'], '--model actuator: give the segment designs base to '
                                           'tip, at least two (got 1)'),
    (['paper_bottom', 'paper_top'], 'one design, or several (base to tip) with --model actuator'),
    (['paper_bottom', 'paper_top_yeoh', '--model', 'actuator'],
     'material: differs from that of'),
    (['paper_bottom', 'paper_top', '--model', 'actuator', '--sweep', 'mesh.element_size_m=1'],
     '--sweep: not with --model actuator'),
])
def test_the_actuator_is_refused_in_one_line_before_any_work(args, expected, tmp_path, capsys,
                                                              monkeypatch):
    from softseq_ros.cli import main

    monkeypatch.chdir(tmp_path)
    assert main(['fem', *args, '--cache-dir', str(tmp_path / 'cache')]) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith('softseq fem: error: ')
    assert expected in lines[0]
    assert not captured.out and not list(tmp_path.iterdir())


def test_segments_of_another_cross_section_are_refused(tmp_path):
    from softseq_ros.fem.actuator import check_actuator
    from softseq_ros.scene.design import DesignError

    bottom = load_design(DESIGNS / 'paper_bottom.yaml')
    taller = with_changes(load_design(DESIGNS / 'paper_top.yaml'), {'geometry.height_m': 0.016})
    with pytest.raises(DesignError, match=r'geometry.height_m: 0.016 differs from 0.015'):
        check_actuator([bottom, taller])
