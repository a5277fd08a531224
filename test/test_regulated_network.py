"""A pressure regulator as a scene's supply: its programme, the network it drives, refusals."""

import csv
import math
from pathlib import Path
import subprocess
import sys

import numpy as np
import pytest
import yaml

import softseq_ros
from softseq_ros.dynamic.network import tube_law
from softseq_ros.dynamic.regulated import regulated_network_path
from softseq_ros.quasistatic.regulator import regulated_path
from softseq_ros.scene.loader import scene_from_dict
from softseq_ros.scene.network import Fluid, NetworkSettings, Tube
from softseq_ros.scene.paths import scene_path
from softseq_ros.scene.regulator import PressureProgramme, Regulator
from softseq_ros.scene.validation import SceneError
from softseq_ros.segments.models import LinearSegment

STIFFNESS = 1.0e9            # Pa/m^3: C = 1 mL per kPa
COMPLIANCE = 1.0 / STIFFNESS
STEP_PA = 5000.0


def _one_linear_segment() -> tuple[LinearSegment, NetworkSettings, float]:
    """A linear segment behind a 0.5 m tube of 0.4 mm radius, and the tube's R."""
    segment = LinearSegment('only', 0.05, 1.0e-6, STIFFNESS, 1.0e-4)
    network = NetworkSettings(Fluid(), Tube(0.5, 0.4e-3), (), rtol=1e-10)
    return segment, network, tube_law(network.supply, network.fluid).resistance


def _step(duration_s: float) -> PressureProgramme:
    # A step as the programme's legs can give it: a ramp far shorter than any time constant.
    return PressureProgramme((0.0, 1.0e-12, duration_s), (0.0, STEP_PA, STEP_PA))


def test_a_pressure_step_through_a_tube_fills_a_linear_segment_with_tau_r_c():
    segment, network, resistance = _one_linear_segment()
    tau = resistance * COMPLIANCE
    times = np.linspace(0.0, 8.0 * tau, 161)
    path = regulated_network_path([segment], network, Regulator(_step(10.0 * tau)), times)
    exact = STEP_PA * -np.expm1(-times / tau)
    assert np.max(np.abs(path.segment_pressure[:, 0] - exact)) < 1e-6 * STEP_PA
    # What it let in is the segment's fluid, and the tube's flow the drop over R.
    assert np.allclose(path.injected, exact * COMPLIANCE, rtol=0, atol=1e-9 * STEP_PA * COMPLIANCE)
    assert np.allclose(path.supply_flow[1:], (STEP_PA - exact[1:]) / resistance, rtol=1e-6)


def test_a_lagging_regulator_and_the_tube_are_two_first_order_stages_in_series():
    segment, network, resistance = _one_linear_segment()
    tau = resistance * COMPLIANCE
    lag = 0.3 * tau
    times = np.linspace(0.0, 8.0 * tau, 161)
    path = regulated_network_path([segment], network,
                                  Regulator(_step(10.0 * tau), time_constant_s=lag), times)
    exact = STEP_PA * (1.0 - (lag * np.exp(-times / lag) - tau * np.exp(-times / tau))
                       / (lag - tau))
    assert np.max(np.abs(path.segment_pressure[:, 0] - exact)) < 1e-6 * STEP_PA
    assert np.allclose(path.pressure, STEP_PA * -np.expm1(-times / lag), rtol=0,
                       atol=1e-6 * STEP_PA)


def test_a_regulator_at_its_most_flow_fills_at_that_flow_then_relaxes_with_tau():
    segment, network, resistance = _one_linear_segment()
    tau = resistance * COMPLIANCE
    most = 0.2 * STEP_PA / resistance
    times = np.linspace(0.0, 10.0 * tau, 201)
    path = regulated_network_path([segment], network,
                                  Regulator(_step(12.0 * tau), max_flow_m3_per_s=most), times)
    # At the limit until the drop over the tube drives no more than it, C (P - R q) / q.
    limited_until = COMPLIANCE * (STEP_PA - resistance * most) / most
    exact = np.where(times < limited_until, most * times / COMPLIANCE,
                     STEP_PA - resistance * most * np.exp(-(times - limited_until) / tau))
    assert np.max(np.abs(path.segment_pressure[:, 0] - exact)) < 1e-6 * STEP_PA
    assert np.max(path.supply_flow) <= most * (1.0 + 1e-12)


def _fig1_segments():
    return softseq_ros.load_scene('fig1_asymmetric').segments


def _fig1_network(rtol: float = 1e-8) -> NetworkSettings:
    return NetworkSettings(Fluid(), Tube(0.5, 0.8e-3), (Tube(0.01, 0.5e-3),), rtol=rtol)


def test_ramped_slower_each_balloon_leaves_its_peak_where_the_quasi_static_flip_is():
    segments = _fig1_segments()
    peak = segments[1].monotone_pieces()[0].p_max
    flips = regulated_path(segments, np.linspace(0.0, 7600.0, 7601)).flips
    # Quasi-statically the top balloon, whose peak is lower, flips at its peak exactly.
    assert [(f.segment, f.pressure) for f in flips] == [(1, peak)]
    gaps = []
    for rate in (4.0, 0.4, 0.04):
        # Up to 7.6 kPa, between the two peaks, and held there.
        top = 7600.0
        programme = PressureProgramme((0.0, top / rate, top / rate + 2000.0), (0.0, top, top))
        path = regulated_network_path(segments, _fig1_network(), Regulator(programme),
                                      np.linspace(0.0, programme.duration(), 20))
        first = next(c for c in path.folds if c.segment == 'top' and c.kind == 'peak')
        # The target when the top balloon passes its peak, less the peak: the lag of the tube
        # and the channel. Through a fold it scales with the rate to the power 2/3 (near the
        # peak p = p* - a d^2 / 2, so R dd/dt = r t + a d^2 / 2: time scales as
        # (R^2 / (a r))^(1/3), the lag r t as r^(2/3)).
        gaps.append(float(programme.target_at(first.time_s)) - peak)
    assert all(gap > 0.0 for gap in gaps)
    for faster, slower in zip(gaps, gaps[1:]):
        assert faster / slower == pytest.approx(10.0 ** (2.0 / 3.0), rel=0.15)
    assert gaps[-1] < 1e-3 * peak


# ---------------------------------------------------------------------------- the scene


def _regulator_scene(tmp_path: Path, regulator: dict | None = None, pump: dict | None = None,
                     network: bool = True, **more: object) -> dict:
    data = yaml.safe_load(scene_path('fig1_asymmetric_regulator').read_text())
    if regulator is not None:
        data['supply'] = {'regulator': regulator}
    if pump is not None:
        data['pump'] = pump
    if not network:
        del data['network']
    data.update(more)
    return data


def _load(data: dict, tmp_path: Path):
    path = tmp_path / 'scene.yaml'
    path.write_text(yaml.safe_dump(data))
    return scene_from_dict(data, path)


def test_the_shipped_regulator_scene_holds_its_programme_and_has_no_syringe(tmp_path):
    scene = softseq_ros.load_scene('fig1_asymmetric_regulator')
    assert scene.pump is None and scene.supply is None
    programme = scene.regulator.programme
    assert programme.times == (0.0, 320.0, 500.0, 820.0)
    assert programme.pressures == (0.0, 8000.0, 8000.0, 0.0)
    assert scene.regulator.time_constant_s == 0.5
    assert scene.regulator.max_flow_m3_per_s == 2.0e-6
    assert float(programme.target_at(160.0)) == 4000.0


def test_a_profile_leg_and_rates_per_leg_make_the_target(tmp_path):
    (tmp_path / 'p.csv').write_text('time_s,gauge_pa\n0,2000\n10,5000\n30,1000\n')
    pump = {'pressure_rate_pa_per_s': 100.0, 'cycles': 2,
            'legs': [{'inflate_to_pa': 2000.0, 'rate_pa_per_s': 400.0}, {'profile': 'p.csv'},
                     {'hold_s': 5.0}, {'deflate_to_pa': 0.0}]}
    scene = _load(_regulator_scene(tmp_path, pump=pump), tmp_path)
    programme = scene.regulator.programme
    assert programme.times == (0.0, 5.0, 15.0, 35.0, 40.0, 50.0, 55.0, 65.0, 85.0, 90.0, 100.0)
    assert programme.pressures == (0.0, 2000.0, 5000.0, 1000.0, 1000.0, 0.0, 2000.0, 5000.0,
                                   1000.0, 1000.0, 0.0)


@pytest.mark.parametrize('regulator, pump_change, where, says', [
    ({'time_constant_s': -1.0}, None, 'supply.regulator.time_constant_s', 'must be >= 0'),
    ({'time_constant_s': math.nan}, None, 'supply.regulator.time_constant_s', 'finite'),
    ({'max_flow_m3_per_s': 0.0}, None, 'supply.regulator.max_flow_m3_per_s', 'must be >='),
    ({'max_pressure_pa': 7000.0}, None, 'pump.legs[0].inflate_to_pa',
     "above the regulator's relief"),
    ({}, {'legs': [{'inflate_to_pa': 12000.0}]}, 'pump.legs[0].inflate_to_pa',
     'segment bottom holds on a stable piece'),
    ({}, {'legs': [{'inflate_to_m3': 1e-5}]}, 'pump.legs[0].inflate_to_m3', 'gauge pressures'),
    ({}, {'flow_rate_m3_per_s': 1e-7, 'legs': [{'inflate_to_pa': 1000.0}]},
     'pump.flow_rate_m3_per_s', 'pressure_rate_pa_per_s'),
    ({}, {'legs': [{'inflate_to_pa': 1000.0}, {'inflate_to_pa': 500.0}]},
     'pump.legs[1].inflate_to_pa', 'must be above the target the leg starts from'),
    ({}, {'legs': [{'hold_s': 1.0, 'rate_pa_per_s': 5.0}]}, 'pump.legs[0].rate_pa_per_s',
     'only an inflate_to_pa or deflate_to_pa leg'),
    ({}, {'legs': [{'profile': 'bad.csv'}]}, 'pump.legs[0].profile', 'does not come after'),
    ({}, {'legs': [{'profile': 'late.csv'}]}, 'pump.legs[0].profile', 'not at the target'),
    ({}, {'cycles': 1000000, 'legs': [{'inflate_to_pa': 1000.0}, {'deflate_to_pa': 0.0}] * 5
          + [{'hold_s': 1.0}]}, 'pump.cycles', '1000000 cycles of 11 breakpoints each'),
])
def test_a_bad_regulator_or_programme_is_refused_in_one_line(tmp_path, regulator, pump_change,
                                                              where, says):
    (tmp_path / 'bad.csv').write_text('time_s,gauge_pa\n0,0\n5,100\n5,200\n')
    (tmp_path / 'late.csv').write_text('time_s,gauge_pa\n0,100\n5,200\n')
    data = _regulator_scene(tmp_path, regulator=regulator, pump=pump_change)
    with pytest.raises(SceneError) as caught:
        _load(data, tmp_path)
    message = str(caught.value)
    assert '\n' not in message
    assert f'scene.yaml: {where}: ' in message
    assert says in message


def test_a_regulator_with_a_syringe_line_or_without_a_supply_tube_is_refused(tmp_path):
    data = _regulator_scene(tmp_path)
    data['supply']['trapped_gas_m3'] = 1e-6
    with pytest.raises(SceneError, match=r'supply\.trapped_gas_m3: a pressure regulator '
                                         r'replaces the syringe'):
        _load(data, tmp_path)
    data = _regulator_scene(tmp_path)
    del data['network']['supply']
    with pytest.raises(SceneError, match=r'network\.supply: a pressure regulator drives the fed '
                                         r'segment through the supply tube'):
        _load(data, tmp_path)


def test_a_syringes_jobs_refuse_a_regulator_scene_before_anything_runs(tmp_path):
    # The rig runs behind a regulator (test_regulated_rig.py); the sequence types, a volume
    # history and a syringe's flow rates do not apply to one.
    with pytest.raises(SceneError, match=r'supply\.regulator: the sequence types'):
        softseq_ros.classify('fig1_asymmetric_regulator')
    with pytest.raises(SceneError, match=r'a volume history is a syringe'):
        softseq_ros.solve('fig1_asymmetric_regulator', [1e-6])
    out = tmp_path / 'rates'
    done = subprocess.run([sys.executable, '-m', 'softseq_ros.cli', 'rates',
                           'fig1_asymmetric_regulator', '--flows', '1e-7', '--radii', '2e-4',
                           '--out', str(out)],
                          capture_output=True, text=True, stdin=subprocess.DEVNULL)
    assert done.returncode == 2
    assert done.stderr.count('\n') == 1 and 'supply.regulator: softseq rates' in done.stderr
    assert not out.exists()


def test_a_quasi_static_regulator_scene_solves_its_programme_as_hysterons(tmp_path):
    data = _regulator_scene(tmp_path, network=False)
    scene = _load(data, tmp_path)
    path = softseq_ros.solve(scene)
    times = scene.regulator.programme.sample_times(scene.regulator.rate_hz)
    assert np.array_equal(path.time_s, times)
    alone = regulated_path(scene.segments, scene.regulator.programme.target_at(times))
    assert np.array_equal(path.volumes, alone.volumes)
    # Up to 8 kPa and back: the top flips at its peak, the bottom at its own; back down each at
    # its valley, the top first (its valley is higher).
    assert [f.segment for f in path.flips] == [1, 0, 1, 0]
    out = tmp_path / 'path.csv'
    done = subprocess.run([sys.executable, '-m', 'softseq_ros.cli', 'solve',
                           str(tmp_path / 'scene.yaml'), '--out', str(out)],
                          capture_output=True, text=True, stdin=subprocess.DEVNULL)
    assert done.returncode == 0, done.stderr
    rows = list(csv.DictReader(out.open()))
    assert len(rows) == times.size
    assert [float(r['time_s']) for r in rows] == times.tolist()
    assert [r['event'] for r in rows if r['event']] == ['flip top', 'flip bottom', 'flip top',
                                                      'flip bottom']


def test_the_shipped_regulator_scene_runs_in_time_and_writes_its_folds(tmp_path):
    out = tmp_path / 'path.csv'
    done = subprocess.run([sys.executable, '-m', 'softseq_ros.cli', 'solve',
                           'fig1_asymmetric_regulator', '--out', str(out)],
                          capture_output=True, text=True, stdin=subprocess.DEVNULL)
    assert done.returncode == 0, done.stderr
    rows = list(csv.DictReader(out.open()))
    header = list(rows[0])
    assert header[-3:] == ['target_pa', 'supply_flow_m3_per_s', 'event']
    injected = np.array([float(r['injected_m3']) for r in rows])
    volumes = np.array([[float(r['volume_bottom_m3']), float(r['volume_top_m3'])] for r in rows])
    rest = softseq_ros.load_scene('fig1_asymmetric_regulator').segments[0].rest_volume
    assert np.allclose(volumes.sum(axis=1) - 2 * rest, injected, rtol=0, atol=1e-15)
    flows = np.array([float(r['supply_flow_m3_per_s']) for r in rows])
    assert np.max(np.abs(flows)) <= 2.0e-6 * (1 + 1e-12)
    folds = list(csv.DictReader(out.with_name('path_folds.csv').open()))
    passed = {(f['segment'], f['kind'], f['direction']) for f in folds}
    # Both balloons pass their peaks filling and their valleys emptying on the way back.
    assert {('top', 'peak', 'filling'), ('bottom', 'peak', 'filling'),
            ('bottom', 'valley', 'emptying'), ('top', 'valley', 'emptying')} <= passed
