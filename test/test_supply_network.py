"""
The compliant supply line in time: the network carries the line's fluid as a state.

The piston pushes Q into the line, which holds s at gauge pressure p_s(s); the supply tube
(resistance R) carries q_s = (p_s - p) / R into the fed segment. A line of compliance C_s
(exactly linear) in front of a linear segment of compliance C is a series RC circuit:

- after a sudden injection dV into the line both pressures relax onto dV / (C_s + C) with
  tau = R C_s C / (C_s + C) (C_s dp_s/dt = -q_s, C dp/dt = q_s, so d(p_s - p)/dt =
  -(p_s - p) / tau);
- pumped at Q from rest, d = p_s - p obeys d' = Q / C_s - d / tau, so
  d(t) = R Q C / (C_s + C) (1 - exp(-t / tau)), and the quasi-static pressure (line and
  segment at one pressure, V = (C_s + C) p_qs) is p_qs = p + C_s d / (C_s + C): the segment lags
  it by R Q C_s C / (C_s + C)^2 = Q tau / (C_s + C), the line leads it by R Q C^2 / (C_s + C)^2.
"""

import math
from pathlib import Path

import numpy as np
import pytest
from scenes import FAST_ASYMMETRIC_PUMP, shipped_scene_with
import yaml

import softseq_ros
from softseq_ros import cli
from softseq_ros.dynamic.flow import NetworkDomainError, NetworkFlow
from softseq_ros.dynamic.network import tube_law
from softseq_ros.dynamic.path import FlowSchedule, run_schedule
from softseq_ros.quasistatic.equilibrium import EquilibriumMap, Tracker
from softseq_ros.rig.model import DynamicModel, actuator_model
from softseq_ros.scene.loader import SceneError, load_scene
from softseq_ros.scene.network import Fluid, NetworkSettings, Tube
from softseq_ros.segments.models import LinearSegment
from softseq_ros.segments.supply import STANDARD_AMBIENT_PA, CompliantSupply

ML = 1e-6
C_LINE = 1.0e-10        # the line's compliance [m^3/Pa]: 1 mL raises 10 kPa
C_SEGMENT = 2.0e-10     # the linear segment's
REST = 1.0 * ML
SUPPLY_TUBE = Tube(length_m=0.1, radius_m=1.0e-3)     # R = 2.5e8 Pa s/m^3, no inertance
CHANNEL = Tube(length_m=0.01, radius_m=0.5e-3)
# The network the Fig. 1 pair runs behind a line: a 0.5 m supply tube of 0.8 mm radius.
FIG1_NETWORK = {'supply': {'length_m': 0.5, 'radius_m': 0.8e-3},
                'channels': [{'length_m': 0.01, 'radius_m': 0.5e-3}]}


def linear_segment() -> LinearSegment:
    return LinearSegment('bag', 0.1, REST, 1.0 / C_SEGMENT, 50.0 * ML)


def compliance_line(compliance: float = C_LINE) -> CompliantSupply:
    return CompliantSupply(line_compliance_m3_per_pa=compliance, max_pressure_pa=1.0e5)


def behind_a_line(line: CompliantSupply, segments=None, tube: Tube = SUPPLY_TUBE,
                  rtol: float = 1e-11) -> NetworkFlow:
    segments = [linear_segment()] if segments is None else segments
    channels = tuple(CHANNEL for _ in segments[1:])
    return NetworkFlow(segments, NetworkSettings(Fluid(), tube, channels), rtol=rtol, line=line)


def series_time_constant(line_compliance: float) -> float:
    resistance = tube_law(SUPPLY_TUBE, Fluid()).resistance
    return resistance * line_compliance * C_SEGMENT / (line_compliance + C_SEGMENT)


# ---------------------------------------------------------------------- the line's law

def test_the_line_s_pressure_inverts_its_law_beyond_the_member_s_range():
    # What the network follows: the exact inverse of s(p), also below ambient (a fast
    # withdrawal: the gas expands, its gauge pressure tends to -p_a) and above the member's
    # highest pressure (a pump outrunning the tube). Round trip to 1e-12 relative, and inside
    # the member's range the member's own pressure to the same.
    lines = [CompliantSupply(1.0e-6, max_pressure_pa=2.0e4),
             CompliantSupply(line_compliance_m3_per_pa=1.0e-10, max_pressure_pa=2.0e4),
             CompliantSupply(1.0e-6, line_compliance_m3_per_pa=1.0e-11, max_pressure_pa=2.0e4),
             CompliantSupply(1.0e-5, polytropic_exponent=1.4, line_compliance_m3_per_pa=1.0e-9,
                             max_pressure_pa=2.0e4)]
    for line in lines:
        for held in np.concatenate([-np.geomspace(1e-12, 1e-4, 9),
                                    np.linspace(0.0, 3.0 * line.max_volume, 13)]):
            pressure = line.line_pressure(float(held))
            if pressure <= -line.ambient:
                # Gas never reaches absolute zero; a compliance alone does, where the network
                # refuses the state (test_a_line_drawn_beyond_vacuum_is_refused_...).
                assert line.gas_volume == 0.0 and pressure == held / line.compliance
                continue
            back = float(line.taken_up(pressure))
            assert back == pytest.approx(held, rel=1e-12, abs=1e-24)
            if 0.0 <= held <= line.max_volume:
                assert pressure == pytest.approx(float(line.pressure(float(held))), rel=1e-12,
                                                 abs=1e-9)
    # Gas alone cannot take up its own volume: no pressure does it.
    assert math.isnan(lines[0].line_pressure(1.0e-6))


# ---------------------------------------------------------------------- closed forms

def test_a_step_into_the_line_relaxes_with_the_series_time_constant():
    # (1) A compliance-only line (exactly linear) and a linear segment behind a tube of
    # resistance R: dV put into the line at once relaxes onto dV / (C_s + C) with
    # tau = R C_s C / (C_s + C), to 1e-6 of the decaying gap at 25 times up to 5 tau (the
    # integrator's rtol is 1e-11; a tau off by 1e-6 would show at 5 tau as 5e-6).
    tau = series_time_constant(C_LINE)
    flow = behind_a_line(compliance_line())
    step = 3.0 * ML
    flow.inject_now(step)
    # Right after the step the line gives the segment fluid with the pump at rest: the line is
    # a member of the exchange, so a transient runs.
    assert flow.exchanging
    start, settled = step / C_LINE, step / (C_LINE + C_SEGMENT)
    assert flow.syringe_pressure() == pytest.approx(start, rel=1e-15)
    for t in np.linspace(0.1, 5.0, 25) * tau:
        flow.advance(t)
        held, line_pressure, supply_flow = flow.line_state()
        segment_pressure = float(flow.pressures(flow.volumes())[0])
        decay = math.exp(-t / tau)
        assert line_pressure - settled == pytest.approx((start - settled) * decay, rel=1e-6)
        assert segment_pressure - settled == pytest.approx(-settled * decay, rel=1e-6)
        assert supply_flow == pytest.approx(start * decay / tube_law(SUPPLY_TUBE,
                                                                     Fluid()).resistance,
                                            rel=1e-6)
        assert flow.syringe_pressure() == line_pressure
        # The piston's volume is the segment's fluid plus the line's, to round-off.
        assert abs(held + flow.volumes()[0] - REST - step) <= 1e-12 * step


def test_a_small_step_into_a_gas_bubble_relaxes_as_its_linearisation():
    # (1, gas) Isothermal air of volume V_g at p_a has the compliance V_g / p_a at 0 Pa gauge;
    # its law p = p_a s / (V_g - s) bends at first order in p / p_a. So a step of pressure dp
    # relaxes as the linear closed form with that compliance, off by a share proportional to
    # dp / p_a: ten times less for a ten times smaller step (first order, to 1 %), and below
    # 1e-3 of the gap for a 10 Pa step.
    gas = 1.0e-5
    line = CompliantSupply(gas, max_pressure_pa=1.0e5)
    compliance = gas / STANDARD_AMBIENT_PA
    tau = series_time_constant(compliance)
    deviations = []
    for pressure_step in (1.0e3, 1.0e2, 1.0e1):
        flow = behind_a_line(line)
        step = pressure_step * compliance
        flow.inject_now(step)
        settled = step / (compliance + C_SEGMENT)
        worst = 0.0
        for t in np.linspace(0.1, 5.0, 25) * tau:
            flow.advance(t)
            gap = (pressure_step - settled) * math.exp(-t / tau)
            worst = max(worst, abs(flow.line_state()[1] - settled - gap) / gap)
        deviations.append(worst / (pressure_step / STANDARD_AMBIENT_PA))
    # The deviation per unit of dp / p_a: the same coefficient at every amplitude.
    assert deviations == pytest.approx([deviations[-1]] * 3, rel=1e-2)
    assert deviations[-1] * 1.0e1 / STANDARD_AMBIENT_PA < 1e-3


def test_pumped_at_a_steady_flow_the_segment_lags_the_quasi_static_pressure_by_q_tau_over_c():
    # (2) Q into line, tube and segment from rest. d = p_s - p = R Q C / (C_s + C)
    # (1 - exp(-t / tau)); the quasi-static pressure of the injected volume is
    # p_qs = Q t / (C_s + C), and the segment lags it by C_s d / (C_s + C), at the steady
    # state R Q C_s C / (C_s + C)^2 = Q tau / (C_s + C). To 1e-6 relative at every time (the
    # lag is a difference of two pressures 20 times larger at the end: rtol 1e-11 keeps it).
    tau = series_time_constant(C_LINE)
    resistance = tube_law(SUPPLY_TUBE, Fluid()).resistance
    pump = 1.0e-6
    total = C_LINE + C_SEGMENT
    flow = behind_a_line(compliance_line())
    flow.set_flow(pump)
    for t in np.concatenate([np.linspace(0.1, 5.0, 25), [20.0]]) * tau:
        flow.advance(t)
        _, line_pressure, supply_flow = flow.line_state()
        segment_pressure = float(flow.pressures(flow.volumes())[0])
        rise = 1.0 - math.exp(-t / tau)
        lead = resistance * pump * C_SEGMENT / total * rise
        quasi_static = pump * t / total
        assert line_pressure - segment_pressure == pytest.approx(lead, rel=1e-6)
        assert quasi_static - segment_pressure == pytest.approx(C_LINE * lead / total, rel=1e-6)
        assert supply_flow == pytest.approx(lead / resistance, rel=1e-6)
    # At the steady state (20 tau: exp(-20) = 2e-9 of the transient left): the segment's lag
    # Q tau / (C_s + C), the line's lead R Q C^2 / (C_s + C)^2, and the tube carries the
    # segment's share of the pump's flow, Q C / (C_s + C).
    assert quasi_static - segment_pressure == pytest.approx(pump * tau / total, rel=1e-6)
    assert line_pressure - quasi_static == pytest.approx(
        resistance * pump * C_SEGMENT ** 2 / total ** 2, rel=1e-6)
    assert supply_flow == pytest.approx(pump * C_SEGMENT / total, rel=1e-6)
    # The line and the segment fill together: no fluid moves between them beyond the pump's.
    assert not flow.exchanging


def test_with_the_tube_s_inertance_the_line_and_the_segment_ring_as_a_series_rlc_circuit():
    # The supply tube's flow becomes a state: L_s dq_s/dt = p_s - p - R q_s. With
    # C = C_s C_seg / (C_s + C_seg), d = p_s - p obeys d' = -q_s / C, so after a step d0 into
    # the line d = d0 exp(-a t) (cos w t + a / w sin w t) and q_s = d0 / (L w) exp(-a t)
    # sin w t, a = R / (2 L), w = sqrt(1 / (L C) - a^2): held to 1e-6 of d0 (and of the
    # flow's scale) over three periods; it overshoots (damping ratio 0.18).
    tube = Tube(length_m=0.1, radius_m=1.0e-3, inertance=True)
    law = tube_law(tube, Fluid())
    series = C_LINE * C_SEGMENT / (C_LINE + C_SEGMENT)
    decay = law.resistance / (2.0 * law.inertance)
    omega = math.sqrt(1.0 / (law.inertance * series) - decay ** 2)
    assert 0.1 < decay * math.sqrt(law.inertance * series) < 0.3
    flow = behind_a_line(compliance_line(), tube=tube)
    step = 2.0 * ML
    flow.inject_now(step)
    start = step / C_LINE
    gaps = []
    for t in np.linspace(0.02, 3.0, 150) * 2.0 * math.pi / omega:
        flow.advance(t)
        _, line_pressure, supply_flow = flow.line_state()
        gap = line_pressure - float(flow.pressures(flow.volumes())[0])
        envelope = math.exp(-decay * t)
        expected = start * envelope * (math.cos(omega * t) + decay / omega * math.sin(omega * t))
        assert gap == pytest.approx(expected, abs=1e-6 * start)
        scale = start / (law.inertance * omega)
        assert supply_flow == pytest.approx(scale * envelope * math.sin(omega * t),
                                            abs=1e-6 * scale)
        gaps.append(gap)
    assert min(gaps) < -0.5 * start


def test_the_channels_peak_flows_count_the_supply_tube_s_flow_into_the_fed_segment():
    # A channel's flow within a step is found by mass from the segments' rates and what enters
    # the fed segment: behind a line that is the supply tube's flow, not the pump's. Pumped
    # at 1 mL/s to 10 mL, the channel's flow rises onto its steady value, the top's share of
    # the tube's flow, Q (1 - C_s / (C_s + C_1 + C_2)) C_2 / (C_1 + C_2) = 0.5 mL/s, so its peak
    # Reynolds number is that flow's: to 1e-9 (measured 5e-12). The pump's flow in the tube's
    # place would make it a third more (the line takes up a quarter of the pump's flow).
    pair = [LinearSegment('bottom', 0.1, REST, 1.0e10, 50.0 * ML),
            LinearSegment('top', 0.1, REST, 5.0e9, 50.0 * ML)]
    network = NetworkSettings(Fluid(), SUPPLY_TUBE, (Tube(0.1, 1.0e-3),), rtol=1e-10)
    times = np.linspace(0.0, 10.0, 201)
    flow = NetworkFlow(pair, network, line=compliance_line())
    flow.set_flow(1.0e-6)
    _, _, flows, _ = flow.read_states(times, flow.advance_through(times))
    steady = 1.0e-6 * (1.0 - C_LINE / (C_LINE + 3.0e-10)) * 2.0 / 3.0
    assert np.max(np.abs(flows[:, 0])) == pytest.approx(steady, rel=1e-9)
    reynolds = tube_law(Tube(0.1, 1.0e-3), Fluid()).reynolds(steady)
    assert flow.peak_reynolds[0] == pytest.approx(reynolds, rel=1e-9)


def test_as_the_line_stiffens_the_path_converges_to_the_network_without_one_at_first_order():
    # (3) Two linear segments fed through the supply tube, pumped at 1 mL/s to 10 mL, behind a
    # line of compliance C_s, or of isothermal gas V_g (compliance V_g / p_a at 0 Pa), from
    # 1e-11 to 1e-14 m^3/Pa; without a line the pump's flow enters the base at once. The
    # volumes differ by what the line holds and by its delay, both proportional to C_s: ten
    # times closer per decade (measured 9.71, 9.97, 10.00 and 9.83, 9.98, 10.00), and the
    # syringe's pressure converges onto the base's plus the tube's steady drop R Q after the
    # line's own transient (R C_s at most 2.5 ms; compared from 0.5 s on).
    pair = [LinearSegment('bottom', 0.1, REST, 1.0e10, 50.0 * ML),
            LinearSegment('top', 0.1, REST, 5.0e9, 50.0 * ML)]
    network = NetworkSettings(Fluid(), SUPPLY_TUBE, (Tube(0.1, 1.0e-3),), rtol=1e-10)
    pump = 1.0e-6
    times = np.linspace(0.0, 10.0 * ML / pump, 201)
    late = times > 0.5

    def path(line: CompliantSupply | None) -> tuple[np.ndarray, np.ndarray]:
        flow = NetworkFlow(pair, network, line=line)
        flow.set_flow(pump)
        _, volumes, _, syringe = flow.read_states(times, flow.advance_through(times))
        return volumes, syringe

    ideal_volumes, ideal_syringe = path(None)
    sizes = (1e-11, 1e-12, 1e-13, 1e-14)
    for make in (compliance_line,
                 lambda c: CompliantSupply(c * STANDARD_AMBIENT_PA, max_pressure_pa=1.0e5)):
        volume_gaps, pressure_gaps = [], []
        for size in sizes:
            volumes, syringe = path(make(size))
            volume_gaps.append(np.max(np.abs(volumes - ideal_volumes)))
            pressure_gaps.append(np.max(np.abs(syringe - ideal_syringe)[late]))
        for gaps in (volume_gaps, pressure_gaps):
            ratios = np.array(gaps[:-1]) / np.array(gaps[1:])
            assert np.all(np.abs(ratios[1:] / 10.0 - 1.0) < 0.01), gaps
            assert np.all(ratios > 9.5), gaps
        # At 1e-14 m^3/Pa, within 1e-3 of a millilitre and 2 Pa.
        assert volume_gaps[-1] < 1e-3 * ML and pressure_gaps[-1] < 2.0


# ---------------------------------------------------------------------- snap-throughs

@pytest.fixture(scope='module')
def fig1_behind_air(tmp_path_factory):
    """The Fig. 1 pair behind 10 mL of isothermal air and a supply tube, and its map."""
    folder = tmp_path_factory.mktemp('fig1_air')
    path = shipped_scene_with(folder, 'fig1_asymmetric.yaml', 'fig1_air.yaml',
                              network=FIG1_NETWORK, supply={'trapped_gas_m3': 1.0e-5})
    scene = load_scene(path)
    return scene, EquilibriumMap(scene.segments, supply=scene.supply)


def test_pumped_slowly_the_rig_s_snaps_start_where_the_quasi_static_ones_with_the_line_do(
        fig1_behind_air):
    # (4) The rig's dynamic model, commanded every 0.1 mL along a ramp at 1e-8 and 1e-9 m^3/s,
    # against the quasi-static map with the same line (EquilibriumMap(..., supply=...)). The
    # line moves the quasi-static snaps 0.70 and 0.67 mL later than the ideal syringe's; each
    # dynamic snap's exchange peaks past the fold by the passage's delay, which shrinks with
    # the flow (measured 0.43 and 0.32 mL at 1e-8, 0.069 and 0.065 mL at 1e-9). At 1e-9
    # within 0.1 mL, well inside the line's own shift, and at least four times closer than at
    # 1e-8.
    scene, emap = fig1_behind_air
    top = 0.95 * emap.injected_range[1]
    expected = Tracker(emap).sweep(np.linspace(0.0, top, 2000)).events
    ideal = Tracker(EquilibriumMap(scene.segments)).sweep(np.linspace(0.0, top, 2000)).events
    assert len(expected) == len(ideal) == 2
    shifts = [e.injected - i.injected for e, i in zip(expected, ideal)]
    assert min(shifts) > 0.6 * ML
    distances = []
    for pump in (1.0e-8, 1.0e-9):
        model = actuator_model(scene)
        assert isinstance(model, DynamicModel) and model.members[-1] is scene.supply
        exchanges = []
        for injected in np.arange(0.0, top, 0.1 * ML):
            exchanges += model.command(float(injected), round(injected / pump * 1e9))
        # Every exchange is reported; the snap-throughs among them are the quasi-static snaps'
        # (the other: the bottom, past its peak, gives the top some fluid on the stable branch).
        snaps = [snap for snap in exchanges if snap.snap_through]
        assert len(snaps) == 2 and len(exchanges) == 3
        # Where each exchange peaks (it starts where a segment first gives, which can be
        # before the fold).
        distances.append([snap.peak_ns * 1e-9 * pump - event.injected
                          for snap, event in zip(snaps, expected)])
        for snap, event in zip(snaps, expected):
            # The segment the quasi-static snap fills takes the fluid, the other gives it.
            gained = np.subtract(event.to_volumes, event.from_volumes)
            assert snap.taking == (scene.segment_names[int(np.argmax(gained))],)
            assert snap.giving == (scene.segment_names[int(np.argmin(gained))],)
    distances = np.array(distances)
    assert np.all(distances > 0.0), distances
    assert np.all(distances[1] < 0.1 * ML) and np.all(distances[1] < distances[0] / 4.0)
    assert np.all(distances[1] < 0.15 * np.array(shifts))


def test_a_segment_drawing_on_a_soft_line_is_a_snap_through_with_the_line_giving():
    # Behind a soft line (1e-8 m^3/Pa: 70 mL at the segments' pressures) the Fig. 1 pair's
    # first quasi-static snap is the top segment jumping onto its next rising piece on fluid
    # the line gives: the line is a member of the equilibrium, and of the exchange in time.
    # Pumped at 1e-10 m^3/s the dynamic snap starts within 0.05 mL of the quasi-static one
    # (measured 0.020), and what the line gave and each segment gained are the quasi-static
    # jump's to 2 % (measured 0.8 % for the line, 0.1 % and 0.8 % for the segments; the
    # line's quasi-static share is the injected volume less the segments' fluid). Counting
    # the tube's flow as the only inflow, the top's gain would not be exchange at all.
    segments = load_scene('fig1_asymmetric').segments
    highest = max(max(abs(piece.p_at_lo), abs(piece.p_at_hi)) for segment in segments
                  for piece in segment.monotone_pieces())
    line = CompliantSupply(line_compliance_m3_per_pa=1.0e-8, max_pressure_pa=2.0 * highest)
    emap = EquilibriumMap(segments, supply=line)
    top = 0.95 * emap.injected_range[1]
    first = Tracker(emap).sweep(np.linspace(0.0, top, 2000)).events[0]
    pump = 1.0e-10
    flow = behind_a_line(line, segments,
                         tube=Tube(**FIG1_NETWORK['supply']), rtol=1e-8)
    flow.set_flow(pump)
    # The exchange runs its course by 0.6 mL past the fold (reported once it has).
    flow.advance(first.injected / pump + 1.0 * ML / pump)
    (snap,) = flow.take_snaps()
    assert snap.snap_through
    # It starts a little before the fold, where the top starts to give fluid on the stable
    # branch, and peaks just past it.
    assert abs(snap.injected - first.injected) < 0.2 * ML
    assert 0.0 < pump * snap.peak_s - first.injected < 0.1 * ML
    gained = np.subtract(first.to_volumes, first.from_volumes)
    line_gained = -float(np.sum(gained))
    assert line_gained < -5.0 * ML
    # What each member gained over the whole exchange: the quasi-static jump's, and the
    # line's more, as it gives the top fluid before the fold and evens out after it.
    assert snap.exchanged_line_m3 == pytest.approx(line_gained, rel=0.15)
    assert snap.exchanged_line_m3 < line_gained
    np.testing.assert_allclose(snap.exchanged_m3, gained, rtol=0.15)
    assert snap.taking() == [1] and gained[1] > 5.0 * ML
    # By mass: what the segments gained the line gave.
    assert abs(sum(snap.exchanged_m3) + snap.exchanged_line_m3) < 1e-12 * emap.v_scale
    assert snap.fluid_moved_m3 > 5.0 * ML


# ---------------------------------------------------------------------- the scene, solve, rig

def test_solve_writes_the_line_s_state_and_the_volumes_keep_the_mass(fig1_behind_air, tmp_path,
                                                                      capsys):
    scene, _ = fig1_behind_air
    history = np.linspace(0.0, 30.0 * ML, 301)
    history_file = tmp_path / 'history.csv'
    history_file.write_text('injected_m3\n' + ''.join(f'{float(u)!r}\n' for u in history))
    out = tmp_path / 'path.csv'
    assert cli.main(['solve', str(scene.path), '--path', str(history_file),
                     '--out', str(out)]) == 0
    assert 'samples of the network in time' in capsys.readouterr().out
    rows = np.genfromtxt(out, delimiter=',', names=True, dtype=None, encoding='utf-8')
    names = rows.dtype.names
    assert names[-4:] == ('supply_pressure_pa', 'supply_volume_m3', 'supply_flow_m3_per_s',
                          'event')
    # The piston pushes on the line: the syringe's pressure is the line's, the line holds
    # what its law says at that pressure, and the segments and the line hold what was
    # injected, to round-off.
    np.testing.assert_array_equal(rows['pressure_pa'], rows['supply_pressure_pa'])
    held = rows['supply_volume_m3']
    np.testing.assert_allclose(scene.supply.taken_up(rows['supply_pressure_pa']), held,
                               rtol=1e-12, atol=1e-24)
    rest = sum(segment.rest_volume for segment in scene.segments)
    fluid = sum(rows[f'volume_{name}_m3'] for name in scene.segment_names) - rest
    np.testing.assert_allclose(fluid + held, rows['injected_m3'], rtol=0,
                               atol=1e-12 * scene.capacity)
    assert held.max() > 1e-7
    # The tube carries what the pushed line passes on: a flow the pressures drive.
    law = tube_law(scene.network.supply, scene.network.fluid)
    fed = rows['pressure_bottom_pa']
    np.testing.assert_allclose(rows['supply_flow_m3_per_s'],
                               (rows['supply_pressure_pa'] - fed) / law.resistance,
                               rtol=1e-9, atol=1e-18)
    # The snaps' file says what the line gave or took beside each segment: by mass, nothing
    # is made or lost.
    snaps = np.atleast_1d(np.genfromtxt(tmp_path / 'path_snaps.csv', delimiter=',',
                                        names=True, dtype=None, encoding='utf-8'))
    assert snaps.dtype.names[-5:] == ('supply_exchanged_m3', 'giving', 'taking', 'snap_through',
                                    'cut_short')
    balance = sum(snaps[f'exchanged_{name}_m3'] for name in scene.segment_names)
    assert np.all(np.abs(balance + snaps['supply_exchanged_m3']) < 1e-12 * scene.capacity)


def test_a_resumed_dynamic_model_finds_the_line_s_fluid_by_mass(fig1_behind_air):
    # The rig saves the injected volume and the segments' volumes; the line's fluid is what
    # the segments do not hold of the injected volume, so a resumed model's line is at the
    # pressure it had (its law of that fluid alone), to round-off.
    scene, _ = fig1_behind_air
    model = actuator_model(scene)
    for k in range(1, 51):
        model.command(k * 0.2 * ML, k * 100_000_000)
    before = model.state()
    held = model.flow_network.line_state()[0]
    assert held > 1e-8
    resumed = actuator_model(scene)
    resumed.resume(**model.saved())
    after = resumed.state()
    assert after.volumes == before.volumes
    assert after.pressure == pytest.approx(before.pressure, rel=1e-9)
    assert resumed.flow_network.line_state()[0] == pytest.approx(held, rel=1e-9)


def test_the_rig_runs_a_network_behind_a_line_and_its_report_places_the_states(tmp_path):
    from softseq_ros.analysis.recording import load_recording
    from softseq_ros.analysis.report import SceneMismatchError

    path = shipped_scene_with(
        tmp_path, 'fig1_asymmetric.yaml', 'fig1_air_rig.yaml',
        pump={**FAST_ASYMMETRIC_PUMP, 'rate_hz': 50},
        camera={'rate_hz': 10, 'trigger_injected_m3': [5.0e-6]},
        network={'supply': {'length_m': 0.2, 'radius_m': 2.0e-3},
                 'channels': [{'length_m': 0.01, 'radius_m': 0.5e-3}]},
        supply={'trapped_gas_m3': 1.0e-5})
    scene = load_scene(path)
    result = softseq_ros.run(path, tmp_path / 'bag')
    assert result.pump_state == 'finished'
    recording = load_recording(result.bag)
    # At each command the state holds the commanded volume: the segments' fluid plus what the
    # line holds at the pressure it reports (the line's, the piston's).
    commands = dict(zip(np.round(recording.pump_time_s, 9), recording.pump_injected))
    at_command = [k for k, t in enumerate(np.round(recording.state_time_s, 9))
                  if t in commands]
    assert len(at_command) > 100
    rest = sum(segment.rest_volume for segment in scene.segments)
    held = scene.supply.taken_up(recording.pressure[at_command])
    commanded = [commands[t] for t in np.round(recording.state_time_s[at_command], 9)]
    np.testing.assert_allclose(recording.volumes[at_command].sum(axis=1) - rest + held,
                               commanded, rtol=0, atol=1e-12 * scene.capacity)
    assert held.max() > 1e-7
    metrics, _ = softseq_ros.report(result.bag, scene=path)
    assert metrics['snap_count'] > 0
    # The bag names the segments and the line together: the pair without the line is refused.
    with pytest.raises(SceneMismatchError, match='segments \\(or supply lines\\) differ'):
        softseq_ros.report(result.bag, scene='fig1_asymmetric')


# ---------------------------------------------------------------------- refusals

def test_a_line_without_a_supply_tube_is_refused_naming_network_supply(tmp_path):
    # (5) Joined to the fed segment at once, the line would sit at its pressure: a constraint,
    # not an equation in time. The scene says which key to give, in one line.
    network = {'channels': FIG1_NETWORK['channels']}
    path = shipped_scene_with(tmp_path, 'fig1_asymmetric.yaml', 'no_tube.yaml',
                              network=network, supply={'trapped_gas_m3': 1.0e-6})
    with pytest.raises(SceneError) as caught:
        load_scene(path)
    message = str(caught.value)
    assert '\n' not in message
    assert message.startswith(f'{path}: network.supply: a compliant supply needs a supply '
                              'tube between the line and the fed segment')
    assert cli.main(['solve', str(path), '--out', str(tmp_path / 'out.csv')]) == 2
    # The network refuses it too, to a caller who builds one in Python.
    with pytest.raises(ValueError, match='needs a supply tube'):
        NetworkFlow([linear_segment()], NetworkSettings(Fluid(), None, ()),
                    line=compliance_line())
    # With the tube the same scene loads, and without the line the network is as it was.
    data = yaml.safe_load(Path(path).read_text(encoding='utf-8'))
    data['network'] = FIG1_NETWORK
    Path(path).write_text(yaml.safe_dump(data), encoding='utf-8')
    assert load_scene(path).supply is not None


def test_a_line_drawn_beyond_vacuum_is_refused_at_the_located_instant():
    # (5) A line of compliance alone (1e-11 m^3/Pa) in front of a segment at 25 kPa, withdrawn
    # at 1 L/s: the tube lets at most (p + p_a) / R back, so the line empties past what
    # vacuum allows (-p_a C) within milliseconds, long before the segment does. Refused where
    # its fluid crosses that level (located on the step's polynomial), the network left there.
    line = compliance_line(1.0e-11)
    flow = behind_a_line(line, rtol=1e-8)
    flow.inject_now(5.0 * ML)
    flow.advance(1.0)
    flow.set_flow(-1.0e-3)
    with pytest.raises(NetworkDomainError, match='the supply line draws a suction beyond '
                                                 'vacuum') as caught:
        flow.advance(2.0)
    assert caught.value.located
    held, pressure, _ = flow.line_state()
    assert held == pytest.approx(-line.compliance * line.ambient, rel=1e-9)
    assert pressure == pytest.approx(-line.ambient, rel=1e-9)
    assert 1.0 < flow.t < 1.01
    assert flow.volumes()[0] > REST + 3.0 * ML
    # Along a schedule (softseq solve) the path ends at the last sample before it, saying why,
    # as it does where a segment's own suction passes vacuum.
    schedule = FlowSchedule(np.array([0.0, 5.0, 6.0, 6.005]), np.array([1.0e-6, 0.0, -1.0e-3]))
    path = run_schedule([linear_segment()], NetworkSettings(Fluid(), SUPPLY_TUBE, ()),
                        schedule, np.concatenate([np.linspace(0.0, 6.0, 61),
                                                  np.linspace(6.0001, 6.005, 50)]), line=line)
    assert 'the supply line draws a suction beyond vacuum' in path.drained
    assert 6.0 < path.time_s[-1] < 6.005
    assert path.line_pressure[-1] > -line.ambient
