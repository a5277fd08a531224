"""
``softseq solve`` on a scene with a network: the path in time and its snap-throughs.

A scene without a network keeps the quasi-static output, byte for byte; with one, the CSV has
the quasi-static columns (the pressure is the syringe's, gauge) with the time first and the
channel flows added, and the snap-throughs go to OUT_snaps.csv beside it.
"""

import csv
from pathlib import Path

import numpy as np
import pytest
import yaml

import softseq_ros
from softseq_ros import cli
from softseq_ros.quasistatic.equilibrium import Tracker
from softseq_ros.quasistatic.solve import equilibrium_map, scene_map, write_path
from softseq_ros.scene.loader import load_scene
from softseq_ros.scene.validation import YamlLoader

CONFIG = Path(__file__).resolve().parents[1] / 'config'
ML = 1e-6


def read_csv(path: Path) -> tuple[list[str], list[list[str]]]:
    with path.open() as handle:
        rows = list(csv.reader(handle))
    return rows[0], rows[1:]


def asymmetric_with_network(tmp_path: Path, **pump: object) -> Path:
    """The Fig. 1 asymmetric pair joined by a 10 mm channel of 0.5 mm radius."""
    data = yaml.load((CONFIG / 'fig1_asymmetric.yaml').read_text(), Loader=YamlLoader)
    data['pump'].update(pump)
    data['camera'] = {'rate_hz': 1}
    data['network'] = {'channels': [{'length_m': 0.01, 'radius_m': 0.5e-3}]}
    path = tmp_path / 'fig1_network.yaml'
    path.write_text(yaml.safe_dump(data))
    return path


def scene_names(scene_file: Path) -> tuple[str, ...]:
    return load_scene(scene_file).segment_names


def test_without_a_network_solve_writes_the_quasistatic_bytes(tmp_path, capsys):
    # The Fig. 1 asymmetric scene as shipped (no network), its pump sampled at 2 Hz.
    data = yaml.load((CONFIG / 'fig1_asymmetric.yaml').read_text(), Loader=YamlLoader)
    data['pump']['rate_hz'] = 2
    scene_file = tmp_path / 'fig1_2hz.yaml'
    scene_file.write_text(yaml.safe_dump(data))
    out = tmp_path / 'path.csv'
    assert cli.main(['solve', str(scene_file), '--out', str(out)]) == 0
    scene = load_scene(scene_file)
    assert scene.network is None
    _, history = scene.pump.profile.sample(scene.pump.rate_hz)
    expected = tmp_path / 'expected.csv'
    write_path(expected, Tracker(scene_map(scene))
               .sweep(history), scene.segment_names)
    assert out.read_bytes() == expected.read_bytes()
    assert not (tmp_path / 'path_snaps.csv').exists()
    assert 'snap-throughs: 26.3' in capsys.readouterr().out


def test_pumped_slowly_the_written_snaps_are_where_the_quasistatic_ones_are(tmp_path, capsys):
    scene_file = asymmetric_with_network(tmp_path, flow_rate_m3_per_s=1e-9)
    history = np.linspace(0.0, 30 * ML, 301)
    history_file = tmp_path / 'history.csv'
    history_file.write_text('injected_m3\n' + ''.join(f'{float(u)!r}\n' for u in history))
    out = tmp_path / 'path.csv'
    assert cli.main(['solve', str(scene_file), '--path', str(history_file),
                     '--out', str(out)]) == 0
    printed = capsys.readouterr().out
    assert 'exchanges: 2, snap-throughs: 1 ->' in printed
    assert 'peak Reynolds number per channel' in printed
    scene = load_scene(scene_file)
    expected = Tracker(equilibrium_map(scene.segments)).sweep(history).events
    assert len(expected) == 1
    header, rows = read_csv(tmp_path / 'path_snaps.csv')
    # Every exchange is a row: past the bottom's peak at 2.6 mL it gives the top some fluid on
    # the stable branch (no snap-through), then the pair snaps.
    assert len(rows) == 2
    # Numbers, then the names of the segments that gave the fluid and took it, whether it
    # was a snap-through, and whether the path's end cut it short.
    assert header[-4:] == ['giving', 'taking', 'snap_through', 'cut_short']
    assert rows[0][-4:] == ['bottom', 'top', '0', '0']
    assert rows[1][-4:] == ['top', 'bottom', '1', '0']
    snap = dict(zip(header[:-4], map(float, rows[1][:-4])))
    gained = [snap[f'exchanged_{name}_m3'] for name in scene_names(scene_file)]
    assert gained[0] == pytest.approx(-gained[1], rel=1e-9) and gained[0] > 0.0
    assert gained[0] == pytest.approx(snap['fluid_moved_m3'], rel=1e-6)
    # Pumped at 1e-9 m^3/s the exchange starts near the fold (where the top starts to give,
    # a little before it) and lands where the quasi-static snap does.
    assert snap['injected_m3'] == pytest.approx(expected[0].injected, abs=0.2 * ML)
    for k, name in enumerate(scene.segment_names):
        assert snap[f'to_volume_{name}_m3'] == pytest.approx(expected[0].to_volumes[k],
                                                             abs=0.3 * ML)
    moved = abs(expected[0].to_volumes[0] - expected[0].from_volumes[0])
    assert snap['fluid_moved_m3'] == pytest.approx(moved, rel=0.05)
    assert 0.0 < snap['duration_s'] < snap['end_s'] - snap['start_s']
    assert snap['peak_exchange_m3_per_s'] > 100 * 1e-9
    # The path marks the row where it started; the rows are the history's, one each.
    header, rows = read_csv(out)
    injected = np.array([float(r[header.index('injected_m3')]) for r in rows])
    np.testing.assert_allclose(injected, history, rtol=0, atol=1e-12 * scene.capacity)
    marked = [float(r[header.index('injected_m3')]) for r in rows if r[-1] == 'snap']
    assert len(marked) == 1 and 0.0 <= marked[0] - snap['injected_m3'] <= 0.1 * ML
    # A volume history is pushed at the pump's flow rate, row to row.
    times = np.array([float(r[0]) for r in rows])
    np.testing.assert_allclose(times, history / 1e-9, rtol=1e-12)
    # Beside them, each segment's passages through the folds of its curve, located in time:
    # the bottom passes its peak just before the pair snaps, and is carried over its valley.
    header, rows = read_csv(tmp_path / 'path_folds.csv')
    assert header == ['time_s', 'injected_m3', 'segment', 'kind', 'direction',
                      'fold_volume_m3', 'fold_pressure_pa']
    passed = [(r[2], r[3], r[4]) for r in rows]
    assert passed.index(('bottom', 'peak', 'filling')) < \
        passed.index(('bottom', 'valley', 'filling'))
    peak = rows[passed.index(('bottom', 'peak', 'filling'))]
    assert float(peak[1]) < snap['injected_m3'] < expected[0].injected
    assert float(peak[0]) == pytest.approx(float(peak[1]) / 1e-9, rel=1e-12)
    assert f'fold crossings: {len(rows)} ->' in printed
    assert printed.count('passes the ') == len(rows)


def test_the_columns_are_si_and_the_volumes_keep_the_mass(tmp_path, capsys):
    # A hold long enough for the snap's exchange to run its course (to 162 s).
    scene_file = asymmetric_with_network(tmp_path, flow_rate_m3_per_s=2e-7, rate_hz=10,
                                         legs=[{'inflate_to_m3': 3.0e-5}, {'hold_s': 20.0}])
    out = tmp_path / 'path.csv'
    assert cli.main(['solve', str(scene_file), '--out', str(out)]) == 0
    capsys.readouterr()
    scene = load_scene(scene_file)
    names = scene.segment_names
    header, rows = read_csv(out)
    assert header == (['time_s', 'injected_m3', 'pressure_pa']
                      + [f'pressure_{n}_pa' for n in names]
                      + [f'volume_{n}_m3' for n in names]
                      + [f'curvature_{n}_per_m' for n in names]
                      + ['flow_bottom_to_top_m3_per_s', 'event'])
    values = np.array([[float(x) for x in r[:-1]] for r in rows])
    column = {name: values[:, k] for k, name in enumerate(header[:-1])}
    # The pump's programme at its 10 Hz: 150 s of ramp and 20 s of hold, both ends included.
    assert values.shape[0] == 1701
    np.testing.assert_allclose(column['time_s'], np.arange(1701) / 10.0, atol=1e-9)
    np.testing.assert_allclose(column['injected_m3'], scene.pump.profile.injected_at(
        column['time_s']), rtol=0, atol=1e-12 * scene.capacity)
    # SI: cubic metres (tens of mL are 1e-5 m^3), pascals (a few kPa gauge), m^3/s.
    volumes = np.column_stack([column[f'volume_{n}_m3'] for n in names])
    assert 5e-7 < volumes.min() and volumes.max() < 1e-4
    # Each segment's own gauge pressure is its curve's at its volume.
    for n, segment, v in zip(names, scene.segments, volumes.T):
        np.testing.assert_allclose(column[f'pressure_{n}_pa'], segment.pressure(v), rtol=1e-12)
    assert 1e3 < column['pressure_pa'].max() < 2e4
    flow = column['flow_bottom_to_top_m3_per_s']
    assert np.abs(flow).max() < 1e-4 and np.abs(flow).max() > 2e-7
    rest = sum(s.rest_volume for s in scene.segments)
    np.testing.assert_allclose(volumes.sum(axis=1) - rest, column['injected_m3'], rtol=0,
                               atol=1e-12 * scene.capacity)
    # The fast pump still meets one snap-through on the way, written beside the path.
    snap_header, snaps = read_csv(tmp_path / 'path_snaps.csv')
    assert snap_header[:6] == ['start_s', 'end_s', 'injected_m3', 'duration_s',
                               'fluid_moved_m3', 'peak_exchange_m3_per_s']
    assert [row[-2] for row in snaps] == ['0', '1'] and 26.0 * ML < float(snaps[1][2]) < 28.0 * ML


def test_a_negative_history_row_is_refused_in_one_line(tmp_path, capsys):
    scene_file = asymmetric_with_network(tmp_path)
    history_file = tmp_path / 'history.csv'
    history_file.write_text('injected_m3\n0\n-1e-6\n')
    assert cli.main(['solve', str(scene_file), '--path', str(history_file),
                     '--out', str(tmp_path / 'out.csv')]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'history.csv: injected_m3:' in err[0] and '>= 0' in err[0]


@pytest.mark.parametrize('name', ['paper', 'fig1_asymmetric'])
def test_the_shipped_dynamic_variants_are_their_scenes_with_a_network(name):
    from softseq_ros.segments.identity import segments_sha256

    still, moving = load_scene(name), load_scene(f'{name}_dynamic')
    # The same segments, programme and camera: only the network differs.
    assert segments_sha256(moving.segments) == segments_sha256(still.segments)
    assert moving.pump == still.pump and moving.camera == still.camera
    assert still.network is None and moving.network is not None
    assert moving.network.supply is not None and len(moving.network.channels) == 1
    # Pumped as slowly as the paper's rig, the sequence in time is the quasi-static one.
    assert softseq_ros.classify(moving) == softseq_ros.classify(still)
