"""
A history in time (``softseq solve --path`` with a ``time_s`` column): a dynamic scene follows
it as it is, holds included; a quasi-static one follows its volumes in order.
"""

import csv
from pathlib import Path

import numpy as np
import pytest
from scenes import shipped_scene_with

import softseq_ros
from softseq_ros import cli
from softseq_ros.dynamic.path import timed_history_schedule


def network_scene(folder: Path) -> Path:
    """The Fig. 1 asymmetric pair joined by a 10 mm channel of 0.2 mm radius (slow to settle)."""
    return shipped_scene_with(folder, 'fig1_asymmetric.yaml', 'fig1_network.yaml',
                              camera={'rate_hz': 1},
                              network={'channels': [{'length_m': 0.01, 'radius_m': 0.2e-3}]})


def write_history(path: Path, rows: list[tuple[float, float]]) -> Path:
    path.write_text('time_s,injected_m3\n' + ''.join(f'{t!r},{v!r}\n' for t, v in rows))
    return path


def read_columns(path: Path) -> dict[str, np.ndarray]:
    with path.open() as handle:
        rows = list(csv.reader(handle))
    values = np.array([[float(x) for x in row[:-1]] for row in rows[1:]])
    return {name: values[:, k] for k, name in enumerate(rows[0][:-1])}


def test_a_dynamic_scene_follows_a_history_in_time_holds_included(tmp_path, capsys):
    # A fast fill to 20 mL in 2 s, then a 60 s hold: the pump stands still while the fluid
    # goes on moving through the channel until both segments are at one pressure.
    scene = network_scene(tmp_path)
    times = [0.0, 2.0, 3.0, 12.0, 62.0]
    volumes = [0.0, 2.0e-5, 2.0e-5, 2.0e-5, 2.0e-5]
    history = write_history(tmp_path / 'history.csv', list(zip(times, volumes)))
    out = tmp_path / 'path.csv'
    assert cli.main(['solve', str(scene), '--path', str(history), '--out', str(out)]) == 0
    assert f'at the times of {history}' in capsys.readouterr().out
    column = read_columns(out)
    np.testing.assert_allclose(column['time_s'], times, rtol=0, atol=1e-12)
    np.testing.assert_allclose(column['injected_m3'], volumes, rtol=0, atol=1e-15)
    flow = np.abs(column['flow_bottom_to_top_m3_per_s'])
    gap = np.abs(column['pressure_bottom_pa'] - column['pressure_top_pa'])
    # Right after the fill the channel still carries fluid and the pressures differ; by the
    # end of the hold it has settled.
    assert flow[2] > 100 * flow[-1] and gap[2] > 100 * gap[-1]
    assert gap[-1] < 1.0


def test_a_history_in_time_pushes_linearly_between_its_rows():
    schedule = timed_history_schedule([5.0, 10.0, 20.0], [1.0e-5, 1.0e-5, 3.0e-5])
    # From rest at 0 s to the first row, a hold, then 2 mL/s.
    np.testing.assert_allclose(schedule.times, [0.0, 5.0, 10.0, 20.0])
    np.testing.assert_allclose(schedule.flows, [2.0e-6, 0.0, 2.0e-6])
    np.testing.assert_allclose(schedule.injected_at([2.5, 7.5, 15.0]),
                               [5.0e-6, 1.0e-5, 2.0e-5], rtol=1e-14)


@pytest.mark.parametrize('rows, words', [
    ([(0.0, 0.0), (2.0, 1e-5), (2.0, 2e-5)], 'time_s in data row 3: 2 s does not come after'),
    ([(0.0, 0.0), (3.0, 1e-5), (1.0, 2e-5)], 'time_s in data row 3: 1 s does not come after'),
    ([(-1.0, 0.0), (2.0, 1e-5)], 'time_s in data row 1: -1 s is before the start at 0 s'),
    ([(0.0, 1e-5), (2.0, 2e-5)], 'time_s in data row 1: the network starts at rest at 0 s'),
], ids=['repeated_time', 'time_going_back', 'negative_time', 'not_at_rest_at_0_s'])
def test_a_bad_history_in_time_is_refused_in_one_line(tmp_path, capsys, rows, words):
    history = write_history(tmp_path / 'history.csv', rows)
    code = cli.main(['solve', str(network_scene(tmp_path)), '--path', str(history), '--out',
                     str(tmp_path / 'out.csv')])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert f'{history}: {words}' in err[0]
    assert not (tmp_path / 'out.csv').exists()


def test_a_quasistatic_path_does_not_depend_on_the_times(tmp_path, capsys):
    rows = [(0.0, 0.0), (10.0, 3.0e-5), (11.0, 4.5e-5), (500.0, 1.0e-5)]
    timed = softseq_ros.solve('fig1_asymmetric', [v for _, v in rows], times=[t for t, _ in rows])
    plain = softseq_ros.solve('fig1_asymmetric', [v for _, v in rows])
    np.testing.assert_array_equal(timed.volumes, plain.volumes)
    history = write_history(tmp_path / 'history.csv', rows)
    assert cli.main(['solve', 'fig1_asymmetric', '--path', str(history), '--out',
                     str(tmp_path / 'out.csv')]) == 0
    assert 'their times do not change it' in capsys.readouterr().out
