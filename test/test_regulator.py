"""
Segments behind an ideal pressure regulator: independent hysterons, against the closed form of
a Gent balloon, and a pair that no longer shares its fluid.
"""

import json
import math
import re

import numpy as np
import pytest
from scipy.optimize import brentq, minimize_scalar

from softseq_ros.quasistatic.regulator import PressureDomainError, regulated_path
from softseq_ros.segments.materials import Gent
from softseq_ros.segments.models import BalloonSegment

R, H, MU, JM, STRETCH = 0.006, 0.6e-3, 60e3, 30.0, 4.0
V0 = 4.0 / 3.0 * math.pi * R**3


def gent_pressure(stretch: float) -> float:
    """The thin-walled Gent sphere (docs/DESIGN): p = 2 mu H / R (1/l - 1/l^7) / (1 - I/Jm)."""
    return (2 * MU * H / R * (1 / stretch - stretch**-7)
            / (1 - (2 * stretch**2 + stretch**-4 - 3) / JM))


def test_a_gent_balloon_jumps_at_its_peak_and_back_at_its_valley():
    balloon = BalloonSegment('g', 0.1, Gent(MU, JM), R, H, STRETCH)
    # The closed form's peak and valley, and the stretches where the curve holds them again.
    top = minimize_scalar(lambda s: -gent_pressure(s), bounds=(1.0, 2.5), method='bounded',
                          options={'xatol': 1e-12})
    bottom = minimize_scalar(gent_pressure, bounds=(top.x, 3.5), method='bounded',
                             options={'xatol': 1e-12})
    peak, valley = gent_pressure(top.x), gent_pressure(bottom.x)
    up_to = brentq(lambda s: gent_pressure(s) - peak, bottom.x, STRETCH, xtol=1e-15)
    down_to = brentq(lambda s: gent_pressure(s) - valley, 1.0, top.x, xtol=1e-15)
    pressures = np.concatenate([np.linspace(0.0, 1.2 * peak, 61),
                                np.linspace(1.2 * peak, 0.0, 61)])
    path = regulated_path([balloon], pressures)
    assert len(path.flips) == 2
    up, down = path.flips
    assert up.pressure == pytest.approx(peak, rel=1e-9)
    assert up.from_volume == pytest.approx(V0 * top.x**3, rel=1e-6)
    assert up.to_volume == pytest.approx(V0 * up_to**3, rel=1e-9)
    assert down.pressure == pytest.approx(valley, rel=1e-9)
    assert down.to_volume == pytest.approx(V0 * down_to**3, rel=1e-9)
    # Between the flips the balloon is on its upper rising piece, at every pressure above
    # the valley, on the way up as on the way down: the hysteresis loop of one hysteron.
    assert up.row < down.row
    np.testing.assert_allclose(balloon.pressure(path.volumes[:, 0]), pressures, rtol=1e-9,
                               atol=1e-6)


def test_two_balloons_behind_a_regulator_flip_each_at_its_own_peak():
    # Different walls: different peaks. Under pressure control each flips when the pressure
    # passes its own peak, alone, and the other keeps its volume: the coupling is gone.
    thin = BalloonSegment('thin', 0.1, Gent(MU, JM), R, 0.5e-3, STRETCH)
    thick = BalloonSegment('thick', 0.1, Gent(MU, JM), R, 0.7e-3, STRETCH)
    peaks = [next(pc.p_at_hi for pc in s.monotone_pieces() if pc.direction > 0)
             for s in (thin, thick)]
    pressures = np.linspace(0.0, 1.1 * max(peaks), 200)
    path = regulated_path([thin, thick], pressures)
    assert [f.segment for f in path.flips] == [0, 1]
    for flip, peak in zip(path.flips, peaks):
        assert flip.pressure == pytest.approx(peak, rel=1e-12)
    # Each segment's volume is its own curve's at the common pressure, whatever the other's.
    alone = regulated_path([thin], pressures)
    np.testing.assert_array_equal(path.volumes[:, 0], alone.volumes[:, 0])
    # What the regulator let in: nothing at 0 Pa, and more at every higher pressure (each
    # balloon on a rising piece, or jumping to a larger volume).
    assert path.injected[0] == pytest.approx(0.0, abs=1e-20)
    assert np.all(np.diff(path.injected) > 0.0)
    # Counted from rest, also for a history that starts above 0 Pa.
    later = regulated_path([thin], [1000.0, 2000.0])
    expected = float(thin.invert(thin.monotone_pieces()[0], np.array([1000.0]))[0])
    assert later.injected[0] == pytest.approx(expected - thin.rest_volume, rel=1e-12)


def test_a_pressure_beyond_the_curves_is_refused_naming_the_segment():
    balloon = BalloonSegment('g', 0.1, Gent(MU, JM), R, H, STRETCH)
    with pytest.raises(PressureDomainError, match="row 1: .* segment 'g'"):
        regulated_path([balloon], [0.0, 1e7])


def gent_wall_pressure(stretch: float, wall_m: float) -> float:
    """The closed form of ``gent_pressure`` for another wall thickness."""
    return gent_pressure(stretch) * wall_m / H


def test_the_graph_of_two_balloons_behind_a_regulator_is_the_two_hysterons():
    from softseq_ros.quasistatic.regulator import hysteron_graph

    walls = (0.5e-3, 0.7e-3)
    balloons = [BalloonSegment(f'w{i}', 0.1, Gent(MU, JM), R, wall, STRETCH)
                for i, wall in enumerate(walls)]
    peaks, valleys = [], []
    for wall in walls:
        top = minimize_scalar(lambda s, w=wall: -gent_wall_pressure(s, w), bounds=(1.0, 2.5),
                              method='bounded', options={'xatol': 1e-12})
        bottom = minimize_scalar(lambda s, w=wall: gent_wall_pressure(s, w),
                                 bounds=(top.x, 3.5), method='bounded',
                                 options={'xatol': 1e-12})
        peaks.append(gent_wall_pressure(top.x, wall))
        valleys.append(gent_wall_pressure(bottom.x, wall))
    # The thin balloon's loop lies below the thick one's: both flip up one after the other.
    assert peaks[0] < valleys[1]
    graph = hysteron_graph(balloons)
    states = {s.pieces: s for s in graph.states}
    # Of the four combinations, (thin down, thick up) needs the thick one's peak while the
    # thin one holds below its own valley: no pressure does both, no history reaches it.
    assert set(states) == {(0, 0), (1, 0), (1, 1)}
    ups = {(f.source, f.target): f for f in graph.flips if f.up and f.target is not None}
    downs = {(f.source, f.target): f for f in graph.flips if not f.up}
    rest, one, both = (states[k].index for k in ((0, 0), (1, 0), (1, 1)))
    assert ups[(rest, one)].pressure == pytest.approx(peaks[0], rel=1e-9)
    assert ups[(one, both)].pressure == pytest.approx(peaks[1], rel=1e-9)
    assert downs[(both, one)].pressure == pytest.approx(valleys[1], rel=1e-9)
    assert downs[(one, rest)].pressure == pytest.approx(valleys[0], rel=1e-9)
    # Each state holds from its highest valley to its lowest peak.
    assert states[(1, 0)].p_low == pytest.approx(valleys[0], rel=1e-9)
    assert states[(1, 0)].p_high == pytest.approx(peaks[1], rel=1e-9)
    # And a pressure history through the flips visits the states in that order.
    history = [0.0, 1.01 * peaks[0], 1.01 * peaks[1], 0.99 * valleys[1], 0.99 * valleys[0]]
    path = regulated_path(balloons, history)
    assert [(f.segment, f.to_volume > f.from_volume) for f in path.flips] == [
        (0, True), (1, True), (1, False), (0, False)]


def test_solve_and_graph_follow_a_regulator_from_the_command_line(tmp_path, capsys):
    import csv

    from softseq_ros.cli import main
    from softseq_ros.quasistatic.regulator import hysteron_graph
    from softseq_ros.scene.loader import load_scene

    scene = load_scene('fig1_asymmetric')
    graph = hysteron_graph(scene.segments)
    peak = min(f.pressure for f in graph.flips if f.up)
    history = tmp_path / 'pressures.csv'
    history.write_text('gauge_pa\n0\n' + f'{0.5 * peak!r}\n{1.001 * peak!r}\n0\n')
    out = tmp_path / 'path.csv'
    assert main(['solve', 'fig1_asymmetric', '--pressure-path', str(history),
                 '--out', str(out)]) == 0
    rows = list(csv.DictReader(out.open()))
    assert [float(r['gauge_pa']) for r in rows] == [0.0, 0.5 * peak, 1.001 * peak, 0.0]
    assert rows[2]['event'] == 'flip top' and rows[3]['event'] == 'flip top'
    assert float(rows[0]['injected_m3']) == pytest.approx(0.0, abs=1e-18)
    assert 'top flips up past its peak' in capsys.readouterr().out
    folder = tmp_path / 'graph'
    assert main(['graph', 'fig1_asymmetric', '--regulator', '--out', str(folder)]) == 0
    written = json.loads((folder / 'graph.json').read_text())
    assert len(written['states']) == len(graph.states) == 4
    assert (folder / 'graph.png').stat().st_size > 0
    # What cannot be done is refused in one line, exit 2, before anything is written.
    capsys.readouterr()
    for args, said in (
            (['solve', 'fig1_asymmetric', '--pressure-path', str(history), '--path',
              str(history), '--out', str(tmp_path / 'x.csv')], 'not both'),
            (['graph', 'fig1_asymmetric', '--regulator', '--reversals', '1'], '--reversals'),
            (['solve', 'rate_inversion', '--pressure-path', str(history), '--out',
              str(tmp_path / 'x.csv')], 'network: a regulator holds the pressure')):
        assert main(args) == 2
        error = capsys.readouterr().err
        assert said in error and len(error.strip().splitlines()) == 1
    beyond = tmp_path / 'beyond.csv'
    beyond.write_text('gauge_pa\n0\n1e9\n')
    assert main(['solve', 'fig1_asymmetric', '--pressure-path', str(beyond), '--out',
                 str(tmp_path / 'y.csv')]) == 2
    assert re.search(r'beyond.csv: gauge_pa: row 1: .*segment', capsys.readouterr().err)
    assert not (tmp_path / 'x.csv').exists() and not (tmp_path / 'y.csv').exists()
