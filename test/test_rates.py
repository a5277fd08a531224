"""
Rate maps (``softseq rates``): the sequence of a scene with a network over pump flow and
channel radius, classified by the same rules as a recording, against the quasi-static one.
"""

import csv
from pathlib import Path

from figure_checks import capture_figures, laid_out, titles
import pytest
import yaml

from softseq_ros import cli
from softseq_ros.analysis.rates import RatePoint, quasistatic_reference, rate_point
from softseq_ros.scene.loader import load_scene, scene_from_dict
from softseq_ros.scene.validation import YamlLoader

CONFIG = Path(__file__).resolve().parents[1] / 'config'
ML = 1e-6


def shipped(tmp_path: Path, inflate_to_m3: float | None = None):
    """The shipped rate_inversion scene, its inflation stopped at ``inflate_to_m3`` if given."""
    data = yaml.load((CONFIG / 'rate_inversion.yaml').read_text(), Loader=YamlLoader)
    if inflate_to_m3 is not None:
        data['pump']['legs'][0] = {'inflate_to_m3': inflate_to_m3}
        data['camera']['trigger_injected_m3'] = []
    return scene_from_dict(data, tmp_path / 'rate_inversion.yaml')


def read_table(path: Path) -> tuple[list[str], list[dict]]:
    lines = path.read_text().splitlines()
    comments = [line for line in lines if line.startswith('#')]
    rows = list(csv.DictReader(line for line in lines if not line.startswith('#')))
    return comments, rows


@pytest.mark.parametrize('inflate_to_m3, expected_type', [(4.0e-5, 'symmetric'),
                                                          (None, 'asymmetric')])
def test_a_slow_pump_reproduces_the_quasistatic_classification(tmp_path, inflate_to_m3,
                                                                expected_type):
    # To 40 mL the tip takes over at its peak and the base gives its fluid back (symmetric);
    # to 60 mL the base snaps through at 45 mL and back at 40 mL (asymmetric).
    scene = shipped(tmp_path, inflate_to_m3)
    reference = quasistatic_reference(scene, samples_per_leg=200)
    assert reference['sequence_type'] == expected_type
    assert reference['leading_segment'] == 'tip'
    slow = rate_point(RatePoint(scene, 1e-10, 0.5e-3, samples_per_leg=200))
    assert slow['sequence_type'] == reference['sequence_type']
    assert slow['leading_segment'] == reference['leading_segment']
    assert slow['lead_injected_m3'] == pytest.approx(reference['lead_injected_m3'], abs=0.7 * ML)
    # The same snap-throughs, their exchanges peaking where the quasi-static solver finds
    # them, each moving the quasi-static jump's fluid or more: an exchange starts where a
    # segment first gives fluid, on deflation 3.4 mL before the fold (one segment gives the
    # other fluid along the stable branch, then the pair snaps), and counts that too.
    assert len(slow['snaps']) == len(reference['snaps'])
    for snap, expected in zip(slow['snaps'], reference['snaps']):
        assert snap['peak_injected_m3'] == pytest.approx(expected['injected_m3'], abs=0.3 * ML)
        assert snap['fluid_moved_m3'] > 0.95 * expected['fluid_moved_m3']
        assert snap['fluid_moved_m3'] < 1.5 * expected['fluid_moved_m3']
        assert snap['duration_s'] > 0.0


def test_the_shipped_scene_inverts_the_order_at_a_fast_pump(tmp_path, capsys, monkeypatch):
    from softseq_ros.analysis import figures

    drawn = capture_figures(monkeypatch, figures)
    out = tmp_path / 'map'
    assert cli.main(['rates', 'rate_inversion', '--flows', '3e-9,1e-7', '--radii',
                     '0.2e-3', '--samples', '100', '--workers', '2', '--out', str(out)]) == 0
    printed = capsys.readouterr().out
    comments, rows = read_table(out / 'rates.csv')
    # The figure in the paper style: no title, 300 dpi, cropped to what is drawn.
    [fig] = drawn
    assert not titles(fig)
    laid_out(out / 'rates.png')
    # One row per grid point; SI throughout.
    assert [(float(r['flow_rate_m3_per_s']), float(r['channel_radius_m'])) for r in rows] == [
        (3e-9, 0.2e-3), (1e-7, 0.2e-3)]
    assert 'quasi-static along the same programme: asymmetric, tip leads' in comments[1]
    lead = {(float(r['flow_rate_m3_per_s']), float(r['channel_radius_m'])):
            r['leading_segment'] for r in rows}
    # Slowly the tip (lower peak) takes over first, as quasi-statically; at 0.1 mL/s through
    # the 0.2 mm channel the base passes its own peak first.
    assert lead == {(3e-9, 0.2e-3): 'tip', (1e-7, 0.2e-3): 'base'}
    for row in rows:
        assert float(row['peak_reynolds']) > 0.0 and not row['refused']
    assert '| 0.1 mL/s | 0.2 mm |' in printed and 'base (' in printed


def test_a_point_the_pump_overfills_is_a_row_that_says_so(tmp_path):
    scene = shipped(tmp_path)
    row = rate_point(RatePoint(scene, 3e-7, 0.15e-3, samples_per_leg=60))
    assert row['sequence_type'] == 'refused'
    assert 'segment base passes the end of its curve' in row['refused']


@pytest.mark.parametrize('options, message', [
    (['--flows', '1e-7,abc', '--radii', '2e-4'],
     "--flows: '1e-7,abc' is not a comma-separated list of numbers"),
    (['--flows', '1e-7', '--radii=-2e-4'], '--radii: every value must be finite and > 0'),
    (['--flows', '0', '--radii', '2e-4'], '--flows: every value must be finite and > 0'),
    (['--flows', '1e-7', '--radii', '0.05'], '--radii: 0.05 m exceeds the shortest channel'),
    (['--flows', '1e-7', '--radii', '2e-4', '--workers', '0'], '--workers: must be >= 1'),
    (['--flows', '1e-7', '--radii', '2e-4', '--samples', '10'], '--samples: must be >= 50'),
    (['--flows', '1e-7', '--radii', '2e-4', '--workers', '2', '--scheduler', 'tcp://x:1'],
     '--workers: not with --scheduler'),
])
def test_bad_options_are_refused_in_one_line_before_anything_runs(tmp_path, capsys, options,
                                                                   message):
    out = tmp_path / 'map'
    assert cli.main(['rates', 'rate_inversion', *options, '--out', str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f'softseq rates: error: {message}'), err
    assert not out.exists()


def test_a_scene_without_a_network_is_refused_in_one_line(tmp_path, capsys):
    assert load_scene('fig1_asymmetric').network is None
    assert cli.main(['rates', 'fig1_asymmetric', '--flows', '1e-7', '--radii', '2e-4',
                     '--out', str(tmp_path / 'map')]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'the scene has no network block' in err[0]


def test_a_dask_cluster_maps_the_same_rows_as_local_processes(tmp_path):
    from distributed import LocalCluster

    from softseq_ros.analysis.rates import run_rates

    scene = shipped(tmp_path, 2.0e-5)
    grid = {'flows': [3e-9, 1e-7], 'radii': [0.2e-3], 'samples_per_leg': 60, 'progress': None}
    local = run_rates(scene, workers=1, **grid)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster:
        remote = run_rates(scene, scheduler=cluster.scheduler_address, **grid)
    # The same numbers whichever worker ran them (the run time aside).
    for ours, theirs in zip(local, remote):
        ours.pop('wall_s'), theirs.pop('wall_s')
        assert ours == theirs
    assert [row['leading_segment'] for row in local] == ['tip', 'base']
