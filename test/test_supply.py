"""
The compliant syringe line (trapped gas, a swelling line) as one more member of the
equilibrium: its law against closed forms, two linear segments behind it against the
compliances combined, and its limits (no gas: the ideal syringe; a very soft line: each
segment jumps at its own peak, as under pressure control).
"""

import math

import numpy as np
import pytest
from scenes import shipped_scene_with
from scipy.integrate import quad
from scipy.optimize import brentq

from softseq_ros.quasistatic.equilibrium import EquilibriumMap, Tracker, inflate_and_deflate
from softseq_ros.quasistatic.graph import SNAP, transition_graph
from softseq_ros.quasistatic.landing import stable
from softseq_ros.scene.loader import load_scene
from softseq_ros.segments.models import LinearSegment
from softseq_ros.segments.supply import CompliantSupply

AMBIENT = 101325.0
K1, K2 = 2.0e9, 5.0e9      # Pa/m^3


def linear_pair():
    return [LinearSegment('base', 0.1, 1.0e-6, K1, 4.0e-5),
            LinearSegment('tip', 0.1, 1.0e-6, K2, 4.0e-5)]


@pytest.mark.parametrize('options', [
    {'gas_volume_m3': 1e-6},
    {'gas_volume_m3': 1e-6, 'polytropic_exponent': 1.4},
    {'line_compliance_m3_per_pa': 1e-10},
    {'gas_volume_m3': 2e-6, 'line_compliance_m3_per_pa': 3e-11, 'polytropic_exponent': 1.2},
], ids=['isothermal_gas', 'adiabatic_gas', 'line_only', 'gas_and_line'])
def test_the_line_s_law_against_its_closed_forms(options):
    line = CompliantSupply(max_pressure_pa=2e5, **options)
    gas, n = options.get('gas_volume_m3', 0.0), options.get('polytropic_exponent', 1.0)
    compliance = options.get('line_compliance_m3_per_pa', 0.0)
    p = np.array([0.0, 1.0, 1e3, 5e4, 2e5])
    # Boyle (or the polytrope) and the line: s = V_g (1 - (p_a / (p_a + p))^(1/n)) + C p
    # (written so, 1 Pa loses a few digits to the subtraction).
    expected = gas * (1.0 - (AMBIENT / (AMBIENT + p)) ** (1.0 / n)) + compliance * p
    np.testing.assert_allclose(line.taken_up(p), expected, rtol=1e-10, atol=0.0)
    np.testing.assert_allclose(line.pressure(expected), p, rtol=1e-12, atol=1e-9)
    s = float(expected[3])
    assert float(line.energy(s)) == pytest.approx(
        quad(lambda x: float(line.pressure(x)), 0.0, s, epsabs=0.0, epsrel=1e-13)[0],
        rel=1e-11)
    slope = gas / (n * AMBIENT) * (AMBIENT / (AMBIENT + 5e4)) ** (1.0 / n + 1.0) + compliance
    assert float(line.stiffness(s)) == pytest.approx(1.0 / slope, rel=1e-12)
    assert line.rest_volume == 0.0 and line.max_volume == pytest.approx(expected[-1], rel=1e-14)
    assert float(line.curvature(s)) == 0.0


@pytest.mark.parametrize('options, words', [
    ({}, 'needs gas_volume_m3 or line_compliance_m3_per_pa above 0'),
    ({'gas_volume_m3': -1e-6}, 'must be >= 0'),
    ({'gas_volume_m3': float('nan')}, 'must be a finite number'),
    ({'gas_volume_m3': 1e-6, 'polytropic_exponent': 0.9}, 'polytropic_exponent must be >= 1'),
    ({'gas_volume_m3': 1e-6, 'ambient_pa': 0.0}, 'ambient_pa must be > 0'),
])
def test_a_line_that_cannot_be_is_refused(options, words):
    with pytest.raises(ValueError, match=words):
        CompliantSupply(max_pressure_pa=1e5, **options)


def test_two_linear_segments_behind_a_gas_bubble_have_the_compliances_combined():
    # The segments in parallel, the gas in series: the piston's V = p/k1 + p/k2 + s(p), so
    # dp/dV = 1 / (1/k1 + 1/k2 + s'(p)).
    line = CompliantSupply(1.0e-6, max_pressure_pa=1e6)
    emap = EquilibriumMap(linear_pair(), supply=line)
    injected = np.linspace(0.0, 2.0e-5, 41)
    path = Tracker(emap).sweep(injected)
    exact = [brentq(lambda q, v=v: q / K1 + q / K2 + float(line.taken_up(q)) - v, 0.0, 1e6,
                    xtol=1e-13, rtol=1e-15) if v > 0 else 0.0 for v in injected]
    np.testing.assert_allclose(path.pressure, exact, rtol=1e-12, atol=1e-9)
    # The segments hold p / k_i each; the line holds the rest of what the piston pushed.
    np.testing.assert_allclose(path.volumes - 1.0e-6,
                               np.column_stack([path.pressure / K1, path.pressure / K2]),
                               rtol=1e-12, atol=1e-20)
    h = 1.0e-9
    for v in (5.0e-6, 1.5e-5):
        up = Tracker(emap).sweep([v + h]).pressure[0]
        down = Tracker(emap).sweep([v - h]).pressure[0]
        p = float(Tracker(emap).sweep([v]).pressure[0])
        combined = 1.0 / (1.0 / K1 + 1.0 / K2 + float(line.taken_up_slope(p)))
        assert (up - down) / (2 * h) == pytest.approx(combined, rel=1e-6)


def test_as_the_gas_vanishes_the_path_tends_to_the_ideal_syringe_s_at_first_order():
    segments = linear_pair()
    injected = np.linspace(0.0, 2.0e-5, 21)
    ideal = Tracker(EquilibriumMap(segments)).sweep(injected).pressure
    gaps = []
    for gas in (1e-8, 1e-9, 1e-10, 1e-14):
        emap = EquilibriumMap(segments, supply=CompliantSupply(gas, max_pressure_pa=1e6))
        gaps.append(float(np.max(np.abs(Tracker(emap).sweep(injected).pressure - ideal))))
    # First order in the gas volume: ten times less gas, ten times closer; at 1e-14 m^3
    # (a 30 um bubble) within 1e-9 of the pressure range.
    assert gaps[0] / gaps[1] == pytest.approx(10.0, rel=0.01)
    assert gaps[1] / gaps[2] == pytest.approx(10.0, rel=0.01)
    assert gaps[3] < 1e-9 * float(ideal.max())


def first_turns(segments, direction):
    """Each segment's first peak (direction 1) or valley (-1) pressure [Pa], sorted."""
    return sorted(next(pc.p_at_hi for pc in s.monotone_pieces() if pc.direction == direction)
                  for s in segments)


def test_a_softer_line_moves_the_snaps_onto_each_segment_s_own_peak_and_valley():
    # Under volume control a segment past its peak is held by the others until the
    # stiffnesses cancel; behind a line of stiffness k_s = 1/C it goes where
    # k_f k_r + k_s (k_f + k_r) = 0, so its falling stiffness k_f is about -k_s: it leaves
    # a distance proportional to k_s past the peak, which is k_s^2 in pressure. A very soft
    # line puts every snap at a peak (inflating) or a valley (deflating), as under pressure
    # control, where each segment is an independent hysteron.
    segments = load_scene('fig1_asymmetric').segments
    peaks, valleys = first_turns(segments, 1), first_turns(segments, -1)
    distances, last = [], None
    for compliance in (None, 1e-9, 1e-8, 1e-7, 1e-6, 1e-5):
        line = (None if compliance is None
                else CompliantSupply(line_compliance_m3_per_pa=compliance, max_pressure_pa=3e4))
        last = inflate_and_deflate(EquilibriumMap(segments, supply=line), 4001)
        up = [e.from_pressure for e in last[0].events]
        distances.append(max(min(abs(p - q) for q in peaks) for p in up))
    assert all(a > b for a, b in zip(distances, distances[1:]))
    # Second order in the line's stiffness: ten times softer, a hundred times closer.
    assert distances[-2] / distances[-1] == pytest.approx(100.0, rel=0.05)
    np.testing.assert_allclose(sorted(e.from_pressure for e in last[0].events), peaks,
                               rtol=1e-8)
    np.testing.assert_allclose(sorted(e.from_pressure for e in last[1].events), valleys,
                               rtol=1e-6)


def test_as_the_gas_grows_the_snaps_tend_to_the_pressure_controlled_flips_at_second_order():
    # Isothermal gas at gauge p holds s = V_g p / (p_a + p), so its stiffness is
    # k_s = dp/ds = (p_a + p)^2 / (V_g p_a): inversely proportional to the gas's volume. The
    # fold behind a line of stiffness k_s lies a pressure proportional to k_s^2 from the peak
    # (the test above), so ten times the gas puts each snap a hundred times closer to where
    # the segment flips under pressure control: its peak inflating, its valley deflating.
    segments = load_scene('fig1_asymmetric').segments
    peaks, valleys = first_turns(segments, 1), first_turns(segments, -1)
    up_gaps, down_gaps = [], []
    for gas in (1e-3, 1e-2, 1e-1, 1.0):
        up, down = inflate_and_deflate(
            EquilibriumMap(segments, supply=CompliantSupply(gas, max_pressure_pa=3e4)), 4001)
        up_gaps.append(max(min(abs(e.from_pressure - q) for q in peaks) for e in up.events))
        down_gaps.append(max(min(abs(e.from_pressure - q) for q in valleys)
                             for e in down.events))
    for gaps in (up_gaps, down_gaps):
        assert all(a > b for a, b in zip(gaps, gaps[1:]))
        assert gaps[-2] / gaps[-1] == pytest.approx(100.0, rel=0.05)
    # A cubic metre of air: every snap within 1e-8 of a peak's pressure, 1e-6 of a valley's.
    assert up_gaps[-1] < 1e-8 * max(peaks) and down_gaps[-1] < 1e-6 * max(valleys)


@pytest.mark.parametrize('gas', [1e-6, 1e-5])
def test_every_snap_with_a_compliant_line_releases_energy_and_lands_stable(gas):
    segments = load_scene('fig1_asymmetric').segments
    emap = EquilibriumMap(segments, supply=CompliantSupply(gas, max_pressure_pa=3e4))
    graph = transition_graph(emap)
    snaps = [t for t in graph.transitions if t.kind == SNAP]
    assert snaps
    scale = max(abs(t.pressure_before) for t in snaps) * emap.numerics.v_scale
    for t in snaps:
        assert t.energy_released >= -1e-12 * scale
        total = t.injected + emap.total_rest_volume
        landed = emap.member_reader.rows(t.target, np.array([total]))[0]
        members = len(emap.members)
        volumes = landed[:members]
        pressures = [float(m.pressure(v)) for m, v in zip(emap.members, volumes)]
        assert max(pressures) - min(pressures) <= 1e-6 * max(pressures)
        assert math.isclose(volumes.sum(), total, rel_tol=1e-12)
        k = np.array([float(m.stiffness(v)) for m, v in zip(emap.members, volumes)])
        assert stable(k[None, :] / emap.numerics.k_scale, 0.0)[0]


def supply_scene(folder, **supply):
    return shipped_scene_with(folder, 'fig1_asymmetric.yaml', 'air.yaml', supply=supply)


def test_a_scene_s_supply_line_is_followed_by_solve_classify_and_graph(tmp_path, capsys):
    import softseq_ros
    from softseq_ros import cli

    path = supply_scene(tmp_path, trapped_gas_m3=1.0e-5, polytropic_exponent=1.4)
    scene = load_scene(path)
    assert scene.supply.gas_volume == 1.0e-5 and scene.supply.exponent == 1.4
    # Beyond every pressure on the segments' curves.
    assert scene.supply.max_pressure > max(pc.p_max for s in scene.segments
                                           for pc in s.monotone_pieces())
    injected = np.linspace(0.0, 5.0e-5, 201)
    solved = softseq_ros.solve(path, injected)
    direct = Tracker(EquilibriumMap(scene.segments, supply=scene.supply)).sweep(injected)
    np.testing.assert_array_equal(solved.pressure, direct.pressure)
    ideal = softseq_ros.solve('fig1_asymmetric', injected)
    # The line takes up some of what the piston pushed: the segments hold less.
    assert np.all(solved.volumes.sum(axis=1) <= ideal.volumes.sum(axis=1) + 1e-18)
    assert softseq_ros.classify(path) == 'asymmetric'
    graph = softseq_ros.graph(path)
    assert graph.snaps() and all(t.energy_released > 0.0 for t in graph.snaps())
    assert cli.main(['graph', str(path), '--out', str(tmp_path / 'graph')]) == 0
    assert (tmp_path / 'graph' / 'graph.png').stat().st_size > 0
    capsys.readouterr()


def test_the_rig_records_a_supply_line_and_its_report_places_the_states(tmp_path):
    import softseq_ros
    from softseq_ros.analysis.recording import load_recording
    from softseq_ros.analysis.report import SceneMismatchError

    path = supply_scene(tmp_path, trapped_gas_m3=1.0e-5)
    scene = load_scene(path)
    result = softseq_ros.run(path, tmp_path / 'bag')
    recording = load_recording(result.bag)
    # The piston's volume is the segments' fluid plus what the line holds at the pressure.
    rest = sum(s.rest_volume for s in scene.segments)
    held = scene.supply.taken_up(recording.pressure)
    np.testing.assert_allclose(recording.volumes.sum(axis=1) - rest + held,
                               recording.state_injected, rtol=0, atol=1e-12 * scene.capacity)
    assert held.max() > 1e-7
    metrics, _ = softseq_ros.report(result.bag, scene=path)
    visited = [stay['branch'] for stay in metrics['branches_visited']]
    assert len(visited) > 3 and metrics['snap_count'] == len(softseq_ros.graph(path).snaps())
    # The shipped pair without the line is other physics: refused.
    with pytest.raises(SceneMismatchError, match='segments \\(or supply lines\\) differ'):
        softseq_ros.report(result.bag, scene='fig1_asymmetric')
