"""
The fluid network on the rig and at its edges: what a dynamic actuator publishes (channel
flows, timed snap-throughs, warnings), the pump's relief on the dynamic pressure, turbulent
friction, and the limits of near-zero resistance and near-zero flow.
"""

import json
import math
from pathlib import Path
import re

import numpy as np
import pytest
import yaml

import softseq_ros
from softseq_ros import cli
from softseq_ros.analysis.report import write_report
from softseq_ros.bag.reader import bag_summary, read_bag
from softseq_ros.dynamic.flow import NetworkDomainError, NetworkFlow
from softseq_ros.dynamic.network import LAMINAR_REYNOLDS, tube_law
from softseq_ros.quasistatic.equilibrium import EquilibriumMap, Tracker
from softseq_ros.scene.loader import SceneError, load_scene, scene_from_dict
from softseq_ros.scene.network import BLASIUS, Fluid, NetworkSettings, Tube
from softseq_ros.scene.validation import YamlLoader

ML = 1e-6
WATER = Fluid()
FIG1 = Path(__file__).resolve().parents[1] / 'config' / 'fig1_asymmetric.yaml'


def fig1_with_network(tmp_path: Path, network: dict, flow: float = 2e-7,
                      top: float = 3.0e-5, hold: float = 30.0):
    """
    The Fig. 1 asymmetric pair with ``network``, inflated at ``flow`` to ``top``, then held.

    The hold lets the snap-through's exchange, still under way at 30 mL, run its course: an
    exchange goes out on the events topic when it has.
    """
    data = yaml.load(FIG1.read_text(), Loader=YamlLoader)
    data['pump'].update({'flow_rate_m3_per_s': flow,
                         'legs': [{'inflate_to_m3': top}] + ([{'hold_s': hold}] if hold else [])})
    data['camera'] = {'rate_hz': 1}
    data['network'] = network
    # Written out too, for the commands that take a scene file.
    path = tmp_path / 'fig1_network.yaml'
    path.write_text(yaml.safe_dump(data))
    return scene_from_dict(data, path)


def test_the_rig_records_channel_flows_and_snap_throughs_with_their_timing(tmp_path):
    channel = {'length_m': 0.01, 'radius_m': 0.5e-3}
    scene = fig1_with_network(tmp_path, {'channels': [channel], 'rate_hz': 200})
    result = softseq_ros.run(scene, tmp_path / 'bag', start_time_ns=0)
    bag = tmp_path / 'bag'
    flows = list(read_bag(bag, ['/actuator/channel_flows']))
    volumes = list(read_bag(bag, ['/actuator/volumes']))
    # Each volumes message comes with its channel flows: one per pump command (150 s at
    # 50 Hz), and more at the network's 200 Hz while the snap-through moves the fluid.
    assert len(flows) == len(volumes) == result.message_counts['/actuator/channel_flows']
    commands = result.message_counts['/pump/command']
    assert len(flows) > commands > 0.9 * 50 * 3.0e-5 / 2e-7
    law = tube_law(Tube(**channel), WATER)
    bottom, top = scene.segments
    for message, state in zip(flows[::25], volumes[::25]):
        assert list(message.msg.name) == ['bottom_to_top']
        assert message.log_time_ns == state.log_time_ns
        v_bottom, v_top = state.msg.position
        # Drop: the two segments' pressures at their volumes; flow: Hagen-Poiseuille's.
        drop = float(bottom.pressure(v_bottom) - top.pressure(v_top))
        assert message.msg.effort[0] == pytest.approx(drop, abs=1e-9 * abs(drop) + 1e-9)
        resistance = 8 * 1e-3 * 0.01 / (math.pi * 0.5e-3 ** 4)
        assert law.resistance == pytest.approx(resistance, rel=1e-14)
        assert message.msg.velocity[0] == pytest.approx(drop / resistance, rel=1e-12,
                                                        abs=1e-30)
    events = [(m.log_time_ns, json.loads(m.msg.data))
              for m in read_bag(bag, ['/actuator/events'])]
    # Every exchange is an event: the bottom giving the top some fluid past its peak (no
    # snap-through), then the snap-through.
    assert [e['snap_through'] for _, e in events] == [False, True]
    published, event = events[1]
    moved = event['to_volumes_m3'][0] - event['from_volumes_m3'][0]
    # The snap started before it was published, lasted a positive time, and moved at least
    # what the bottom's volume gained beyond the pump's own push in that time.
    assert 0 < event['start_ns'] < published
    assert 0.0 < event['duration_s'] < (published - event['start_ns']) / 1e9
    assert event['fluid_moved_m3'] > 0.5 * moved > 2 * ML
    assert event['peak_exchange_m3_per_s'] > 5 * 2e-7
    # While it ran, the state went out at the network's 200 Hz, between the pump's commands.
    during = [m.log_time_ns for m in flows
              if event['start_ns'] <= m.log_time_ns <= published]
    assert np.max(np.diff(during)) <= 1e9 / 200 * 1.001
    command_times = {m.log_time_ns for m in read_bag(bag, ['/pump/command'])}
    assert len(set(during) - command_times) > 0.5 * len(during)


def test_an_exchange_under_way_when_a_batch_run_ends_goes_out_cut_short(tmp_path):
    # No hold: the programme ends at 30 mL while the snap-through's exchange still moves fluid.
    # A batch run's time stops with its pump; before, that exchange never reached the bag.
    channel = {'length_m': 0.01, 'radius_m': 0.5e-3}
    scene = fig1_with_network(tmp_path, {'channels': [channel], 'rate_hz': 200}, hold=0.0)
    softseq_ros.run(scene, tmp_path / 'bag', start_time_ns=0)
    events = [(m.log_time_ns, json.loads(m.msg.data))
              for m in read_bag(tmp_path / 'bag', ['/actuator/events'])]
    held = fig1_with_network(tmp_path, {'channels': [channel], 'rate_hz': 200})
    softseq_ros.run(held, tmp_path / 'held', start_time_ns=0)
    whole = [json.loads(m.msg.data) for m in read_bag(tmp_path / 'held', ['/actuator/events'])]
    assert [e['snap_through'] for _, e in events] == [e['snap_through'] for e in whole] \
        == [False, True]
    # The one that ran its course carries no cut_short key (its bytes as before).
    assert 'cut_short' not in events[0][1] and 'cut_short' not in whole[1]
    published, cut = events[1]
    assert cut['cut_short'] is True
    # It started where the held run's did; it went out at the run's last instant, with the
    # state there and the fluid the recorded volumes moved from its start to there.
    assert cut['start_ns'] == whole[1]['start_ns']
    volumes = list(read_bag(tmp_path / 'bag', ['/actuator/volumes']))
    assert published == volumes[-1].log_time_ns
    assert cut['to_volumes_m3'] == pytest.approx(list(volumes[-1].msg.position), rel=1e-9)
    during = [m for m in volumes if m.log_time_ns >= cut['start_ns']]
    v = np.array([m.msg.position for m in during])
    pumped = np.array([m.msg.position for m in read_bag(tmp_path / 'bag', ['/pump/command'])
                       if m.log_time_ns >= cut['start_ns']])[:, 0]
    moved = 0.5 * (np.abs(np.diff(v, axis=0)).sum() - abs(pumped[-1] - pumped[0]))
    assert cut['fluid_moved_m3'] == pytest.approx(moved, rel=0.02)
    assert cut['fluid_moved_m3'] < whole[1]['fluid_moved_m3']
    # The report says so beside its numbers, and metrics.json marks it.
    metrics, text = write_report(tmp_path / 'bag', tmp_path / 'report', figures=False)
    assert 'still under way when the run ended' in text
    assert [s['cut_short'] for s in metrics['transients']['snaps']] == [True]


def test_a_quasi_static_scene_has_no_channel_flows_topic(tmp_path):
    data = yaml.load(FIG1.read_text(), Loader=YamlLoader)
    data['pump'].update({'legs': [{'inflate_to_m3': 2.0e-6}]})
    data['camera'] = {'rate_hz': 1}
    softseq_ros.run(scene_from_dict(data, tmp_path / 'fig1.yaml'), tmp_path / 'bag',
             start_time_ns=0)
    assert '/actuator/channel_flows' not in bag_summary(tmp_path / 'bag').topics


def test_the_pump_relief_acts_on_the_dynamic_pressure_at_the_syringe(tmp_path):
    # The pair stays below 9 kPa quasi-statically up to 30 mL; a narrow supply line adds
    # R Q = 8 mu l Q / (pi r^4) = 4.1 kPa at 0.2 mL/s: the syringe sees more than the relief.
    channel = {'length_m': 0.01, 'radius_m': 0.5e-3}
    supply = {'length_m': 0.5, 'radius_m': 0.5e-3}
    relief = {'pump': {'max_pressure_pa': 9.0e3}}
    narrow = fig1_with_network(tmp_path, {'channels': [channel], 'supply': supply})
    result = softseq_ros.run(narrow, tmp_path / 'narrow', start_time_ns=0, overrides=relief)
    assert result.pump_state == 'stopped'
    statuses = [json.loads(m.msg.data) for m in read_bag(tmp_path / 'narrow',
                                                           ['/pump/status'])]
    assert 'max_pressure_pa' in statuses[-1]['reason']
    commands = [m.msg.position[0] for m in read_bag(tmp_path / 'narrow', ['/pump/command'])]
    assert max(commands) < 2.9e-5
    # Without the supply line the same programme runs to its end under the same relief.
    ideal = fig1_with_network(tmp_path, {'channels': [channel]})
    result = softseq_ros.run(ideal, tmp_path / 'ideal', start_time_ns=0, overrides=relief)
    assert result.pump_state == 'finished'


def test_blasius_friction_is_laminar_below_its_crossing_and_turbulent_above():
    laminar = tube_law(Tube(0.01, 0.5e-3), WATER)
    turbulent = tube_law(Tube(0.01, 0.5e-3, friction=BLASIUS), WATER)
    # The crossing of 64 / Re and 0.316 Re^(-1/4): Re = (64 / 0.316)^(4/3).
    crossing = (64.0 / 0.316) ** (4.0 / 3.0)
    q_cross = crossing / laminar.reynolds_per_flow
    for share in (1e-6, 0.5, 0.99):
        q = share * q_cross
        assert turbulent.drop(q) == laminar.drop(q) == pytest.approx(laminar.resistance * q)
    # Above it, the Darcy-Weisbach drop with Blasius's friction factor, written out here.
    area, diameter = math.pi * 0.5e-3 ** 2, 1.0e-3
    for reynolds in (3000.0, 1.0e4, 5.0e4):
        q = reynolds / laminar.reynolds_per_flow
        velocity = q / area
        expected = 0.316 * reynolds ** -0.25 * (0.01 / diameter) * 998.0 * velocity ** 2 / 2
        assert turbulent.drop(q) == pytest.approx(expected, rel=1e-12)
        assert turbulent.drop(-q) == -turbulent.drop(q)
        assert turbulent.drop(q) > laminar.drop(q)
    # The flow a drop drives inverts the drop, with minor losses too; the slope is its
    # derivative (a centred difference).
    lossy = tube_law(Tube(0.01, 0.5e-3, minor_loss=1.5, friction=BLASIUS), WATER)
    for law in (laminar, turbulent, lossy):
        for drop in (1e-3, 10.0, 1e3, 3e4, -2e4):
            q = law.flow(drop)
            assert law.drop(q) == pytest.approx(drop, rel=1e-12)
            h = 1e-6 * abs(drop)
            slope = (law.flow(drop + h) - law.flow(drop - h)) / (2 * h)
            assert law.flow_slope(drop) == pytest.approx(slope, rel=1e-5)


def test_the_friction_law_is_checked_in_the_scene(tmp_path):
    with pytest.raises(SceneError, match=r'network\.channels\[0\]\.friction: must be one of '
                                         r'laminar, blasius'):
        fig1_with_network(tmp_path, {'channels': [{'length_m': 0.01, 'radius_m': 5e-4,
                                                    'friction': 'moody'}]})


def test_a_channel_that_leaves_the_laminar_range_is_warned_about_once(tmp_path, capsys):
    # A wide short channel: the snap-through's exchange reaches Reynolds numbers in the
    # thousands. Warned once, with the channel's name and what to do.
    channel = {'length_m': 0.01, 'radius_m': 1.0e-3}
    scene = fig1_with_network(tmp_path, {'channels': [channel], 'rate_hz': 50})
    result = softseq_ros.run(scene, tmp_path / 'bag', start_time_ns=0)
    turbulent = [line for line in result.warnings if 'no longer laminar' in line]
    assert len(turbulent) == 1
    assert 'channel bottom_to_top' in turbulent[0] and 'friction: blasius' in turbulent[0]
    peak = float(turbulent[0].split('Reynolds number ')[1].split()[0])
    assert peak > LAMINAR_REYNOLDS
    # `softseq solve` on the scene says the same, in the same words (its peak is its own).
    assert cli.main(['solve', str(tmp_path / 'fig1_network.yaml'),
                     '--out', str(tmp_path / 'path.csv')]) == 0
    solved = [line for line in capsys.readouterr().err.splitlines() if 'no longer laminar' in line]

    def worded(line: str) -> str:
        return re.sub(r'number \d+', 'number N', line)

    said = turbulent[0][turbulent[0].index('channel '):]   # after the node's name
    assert [worded(line) for line in solved] == [f'softseq solve: warning: {worded(said)}']
    # With Blasius's law the channel says it follows it, and the turbulent drop slows the
    # exchange: the snap takes longer.
    channel['friction'] = BLASIUS
    scene = fig1_with_network(tmp_path, {'channels': [channel], 'rate_hz': 50})
    blasius = softseq_ros.run(scene, tmp_path / 'blasius', start_time_ns=0)
    assert any('follows Blasius' in line for line in blasius.warnings)
    durations = [event['duration_s'] for bag in ('bag', 'blasius')
                 for event in map(json.loads, (m.msg.data for m in read_bag(
                     tmp_path / bag, ['/actuator/events'])))
                 if event['snap_through']]
    assert len(durations) == 2 and durations[1] > durations[0]


def test_near_zero_resistance_stays_well_posed_and_lands_on_the_quasi_static_path():
    # A channel as short as it is wide, its resistance taken towards zero with the fluid's
    # viscosity (1000x): the time constant falls to microseconds against a pump that takes
    # minutes. The stiff integrator steps over it at no extra cost, and the path closes on the
    # quasi-static one (first order in R, down to the tolerance's floor), snaps included.
    segments = load_scene('fig1_asymmetric').segments
    emap = EquilibriumMap(segments)
    grid = np.linspace(0.0, 0.95 * emap.injected_range[1], 400)
    quasistatic = Tracker(emap).sweep(grid)
    far = np.ones(len(grid), bool)
    for snap in quasistatic.events:
        far &= np.abs(grid - snap.injected) > 1.0 * ML
    distances = []
    for viscosity in (1.0e-3, 1.0e-6):
        flow = NetworkFlow(segments, NetworkSettings(Fluid(viscosity_pa_s=viscosity), None,
                                                     (Tube(1.0e-3, 1.0e-3),)))
        flow.set_flow(1e-7)
        path = []
        for injected in grid:
            flow.advance(injected / 1e-7)
            path.append(flow.volumes())
        assert np.all(np.isfinite(path))
        distances.append(np.max(np.abs(np.array(path)[far] - quasistatic.volumes[far])))
        # A few steps per output, not millions for the microsecond time constant.
        assert flow.steps < 3 * len(grid)
        # Each snap-through's exchange starts near the quasi-static fold (the first a little
        # before it, where the top starts to give on the stable branch) and peaks just after
        # it (the passage through the saddle-node, late by a delay the pump's rate sets).
        snaps = [s for s in flow.take_snaps() if s.snap_through]
        assert len(snaps) == len(quasistatic.events)
        for snap, event in zip(snaps, quasistatic.events):
            assert snap.injected == pytest.approx(event.injected, abs=0.3 * ML)
            assert 0.0 < 1e-7 * snap.peak_s - event.injected < 0.1 * ML
    assert distances[1] < distances[0] / 20
    assert distances[1] < 1e-6 * emap.v_scale


def test_near_zero_flow_holds_still_for_as_long_as_asked():
    segments = load_scene('fig1_asymmetric').segments
    flow = NetworkFlow(segments, NetworkSettings(WATER, None, (Tube(0.01, 0.5e-3),)))
    flow.set_flow(1e-18)          # 1 fL/s: a month of it moves 2.6 nL
    month = 30 * 86400.0
    flow.advance(month)
    volumes = flow.volumes()
    assert float(np.sum(volumes)) == pytest.approx(flow.rest_total + 1e-18 * month,
                                                   abs=1e-12 * flow.v_scale)
    assert np.all(np.isfinite(volumes)) and flow.steps < 1000
    assert flow.take_snaps() == []


def test_a_withdrawal_faster_than_the_channel_collapses_the_base_and_still_ends_at_rest(
        tmp_path):
    # Up to 20 mL and back to nothing at 0.2 mL/s: at the end the syringe draws from the base
    # faster than the top's fluid comes through the channel. The base collapses below its
    # rest volume under suction (a gauge pressure below zero), pulls the top's fluid through,
    # and the run ends at rest, nothing refused.
    data = yaml.load(FIG1.read_text(), Loader=YamlLoader)
    data['pump'].update({'flow_rate_m3_per_s': 2e-7,
                         'legs': [{'inflate_to_m3': 2.0e-5}, {'deflate_to_m3': 0.0},
                                  {'hold_s': 5.0}]})
    data['camera'] = {'rate_hz': 1}
    data['network'] = {'channels': [{'length_m': 0.02, 'radius_m': 0.25e-3}]}
    scene = scene_from_dict(data, tmp_path / 'withdrawal.yaml')
    result = softseq_ros.run(scene, tmp_path / 'bag', start_time_ns=0)
    assert result.pump_state == 'finished'
    assert not [line for line in result.warnings if 'refused' in line or 'held' in line]
    states = [m.msg for m in read_bag(tmp_path / 'bag', ['/actuator/volumes'])]
    rest = [segment.rest_volume for segment in scene.segments]
    assert min(s.position[0] - rest[0] for s in states) < 0.0
    assert min(s.effort[0] for s in states) < 0.0
    np.testing.assert_allclose(states[-1].position, rest, atol=1e-9 * ML)


def test_a_segment_passing_the_end_of_its_curve_is_refused_at_the_located_instant():
    # The rate-inversion pair through a 0.15 mm channel at 0.3 mL/s: the base cannot pass its
    # fluid on fast enough and reaches the end of its curve at about 197 s, between two of the
    # 1 s outputs and inside an integrator step. Refused at the instant located on the step's
    # cubic, against where an independent reference's base crosses its largest volume.
    from scipy.optimize import brentq
    from test_dynamic import reference_pair

    segments = load_scene('rate_inversion').segments
    tube, flow_rate = Tube(0.02, 0.15e-3), 3e-7
    flow = NetworkFlow(segments, NetworkSettings(WATER, None, (tube,)))
    flow.set_flow(flow_rate)
    outputs = np.arange(1.0, 300.0)
    with pytest.raises(NetworkDomainError, match=r'^segment base passes the end of its curve at '
                                                 r'196\.714 s \(5\.79058e-05 m\^3, injected '
                                                 r'5\.90141e-05 m\^3\)$') as refused:
        flow.advance_through(outputs)
    reference = reference_pair(segments, tube, flow_rate, 200.0, 1e-12)
    expected = brentq(lambda t: reference(t)[0] - segments[0].max_volume, 150.0, 200.0,
                      xtol=1e-12)
    assert abs(flow.t - expected) < 1e-7 * expected
    # The outputs before it, and the network left at it with the base at the end of its curve.
    assert refused.value.located and refused.value.rows.shape == (196, 1)
    assert flow.volumes()[0] == pytest.approx(segments[0].max_volume, abs=1e-9 * flow.v_scale)
    located = flow.t
    with pytest.raises(NetworkDomainError, match='passes the end of its curve'):
        flow.advance(located + 1.0)
    assert flow.t == pytest.approx(located, rel=1e-12)


def test_the_rig_notes_a_segment_passing_a_fold_of_its_curve(tmp_path):
    from softseq_ros.rig.build import actuator_core
    from softseq_ros.wire.values import INFO, Notice, PumpCommand

    # Up to 4 mL at 0.2 mL/s: the top passes the peak of its curve at about 2.8 mL.
    scene = fig1_with_network(tmp_path, {'channels': [{'length_m': 0.01,
                                                         'radius_m': 0.5e-3}]})
    core = actuator_core(scene)
    said = []
    for k in range(1, 1001):
        now = k * 20_000_000
        said += core.handle(PumpCommand(now, 2e-7 * k * 0.02, 2e-7), now)
    notes = [n.text for n in said if isinstance(n, Notice) and n.level == INFO]
    assert len(notes) == 1 and notes[0].startswith('segment top passes the peak of its curve (')
    injected = float(notes[0].split(', ')[-1].split(' mL injected')[0])
    assert 2.7 < injected < 2.9


def test_on_the_rig_feeding_the_tip_reverses_the_channel_flow_and_keeps_the_mass(tmp_path):
    from softseq_ros.rig.build import actuator_core
    from softseq_ros.wire.values import ChannelFlows, PumpCommand, SegmentVolumes

    channel = {'length_m': 0.01, 'radius_m': 0.5e-3}
    bottom, top = load_scene('fig1_asymmetric').segments
    rest = bottom.rest_volume + top.rest_volume
    flows = {}
    for feeds in ('bottom', 'top'):
        scene = fig1_with_network(tmp_path, {'channels': [channel], 'feeds': feeds})
        core = actuator_core(scene)
        said = []
        for k in range(1, 201):   # 2 mL at 0.2 mL/s, commands at 20 Hz
            now = k * 50_000_000
            said += core.handle(PumpCommand(now, 1e-8 * k, 2e-7), now)
            said += core.tick(now + 25_000_000)
        states = [v for v in said if isinstance(v, SegmentVolumes)]
        flows[feeds] = np.array([v.flows_m3_per_s[0] for v in said
                                 if isinstance(v, ChannelFlows)])
        # Mass at every output, commands and ticks alike: what the pump had pushed by then
        # (until the second command the actuator knows no rate and holds the first volume;
        # from there, the commands' ramp).
        for state in states:
            injected = 2e-7 * state.stamp_ns / 1e9 if state.stamp_ns >= 100_000_000 else 1e-8
            assert abs(sum(state.volumes_m3) - rest - injected) <= 1e-12 * scene.capacity
        # The syringe's pressure is the fed segment's (no supply line).
        fed = bottom if feeds == 'bottom' else top
        last = states[-1]
        assert last.gauge_pa == pytest.approx(
            float(fed.pressure(last.volumes_m3[0 if feeds == 'bottom' else 1])), rel=1e-12)
    # Fed at the base the channel carries fluid on to the tip; fed at the tip, back to the base.
    assert np.all(flows['bottom'][1:] > 0.0) and np.all(flows['top'][1:] < 0.0)


def test_suction_beyond_vacuum_is_refused_and_the_rig_holds_its_last_state(tmp_path):
    from softseq_ros.rig.build import actuator_core
    from softseq_ros.wire.values import WARNING, Notice, PumpCommand

    # The top holds most of 20 mL, the channel is narrow, and the syringe draws 20 mL/s: the
    # base would have to pull harder than vacuum to keep up.
    channel = {'length_m': 0.02, 'radius_m': 0.15e-3}
    scene = fig1_with_network(tmp_path, {'channels': [channel], 'rate_hz': 100})
    flow = NetworkFlow(scene.segments, scene.network)
    flow.set_volumes([2.0 * ML, 18.0e-6 + 2 * 0.905 * ML - 2.0 * ML], injected=18.0e-6)
    flow.set_flow(-2e-5)
    with pytest.raises(NetworkDomainError, match=r'^segment bottom collapses under suction '
                       r'beyond vacuum at .* s \(.* m\^3, rest .* m\^3, injected .* m\^3\): '
                       r'the syringe draws faster than the channels let the fluid follow$'):
        flow.advance(1.0)
    # On the rig: the commands and the ticks that would need it are refused with a warning;
    # the state stays at the last instant reached.
    core = actuator_core(scene)
    core.model.resume(18.0e-6, [2.0 * ML, 18.0e-6 + 2 * 0.905 * ML - 2.0 * ML])
    said = []
    for k in range(1, 60):
        now = k * 10_000_000
        said += core.handle(PumpCommand(now, max(18.0e-6 - 2e-5 * k * 0.01, 0.0), -2e-5), now)
        said += core.tick(now + 5_000_000)
    refusals = [n.text for n in said if isinstance(n, Notice) and n.level == WARNING
                and 'no longer laminar' not in n.text]
    assert refusals and all('beyond vacuum' in text for text in refusals)
    assert core.rejected_commands > 0
    volumes = core.model.state().volumes
    assert np.all(np.isfinite(volumes)) and volumes[0] < 0.905 * ML


def test_a_held_pump_stays_held_while_the_fluid_evens_out_and_resumes_when_asked(tmp_path):
    from softseq_ros.rig.build import actuator_core, pump_core
    from softseq_ros.wire.values import PumpCommand, PumpStatus, SegmentVolumes

    # The pair through a narrow channel: pumped at 0.2 mL/s the top lags far behind its share.
    # The pump is held at 2 mL (its hold service) and started again 5 s later. While held it
    # commands the same volume with no flow; the actuator answers those commands (fresh
    # feedback: the pump neither times out nor trips) and, between them, says the fluid still
    # moving at the network's rate, with the injected volume held.
    scene = fig1_with_network(tmp_path, {'channels': [{'length_m': 0.02, 'radius_m': 0.2e-3}],
                                         'rate_hz': 200}, top=4.0e-6, hold=0.0)
    pump, _ = pump_core(scene, feedback_timeout_s=0.5, feedback_clock=lambda: now)
    actuator = actuator_core(scene)
    rest = sum(s.rest_volume for s in scene.segments)
    held_at, resumed_at = 10.0, 15.0
    said, statuses = [], []
    for k in range(0, 5101):             # 25.5 s at the actuator's 200 Hz, the pump at 50 Hz
        now = k * 5_000_000
        if now == held_at * 1e9:
            statuses += [v.state for v in pump.hold(now).outputs if type(v) is PumpStatus]
        if now == resumed_at * 1e9:
            statuses += [v.state for v in pump.start(now).outputs if type(v) is PumpStatus]
        out = actuator.tick(now)
        if k % 4 == 0:
            for value in pump.tick(now):
                if type(value) is PumpStatus:
                    statuses.append(value.state)
                    finished_ns = value.stamp_ns
                elif type(value) is PumpCommand:
                    out += actuator.handle(value, now)
        for value in out:
            if type(value) is SegmentVolumes:
                said.append((now, value, k % 4 != 0))
                pump.handle(value, now)
    assert statuses == ['running', 'held', 'running', 'finished']
    while_held = [(v, ticked) for t, v, ticked in said if held_at + 0.1 < t / 1e9 < resumed_at]
    # The actuator spoke at its own rate between the held commands: the fluid evened out.
    assert sum(ticked for _, ticked in while_held) > 0.9 * 150 * (resumed_at - held_at - 0.1)
    bottoms = [v.volumes_m3[0] for v, _ in while_held]
    assert bottoms[0] - bottoms[-1] > 0.1 * ML and np.all(np.diff(bottoms) <= 0.0)
    # The held volume, to 1e-12 of the segments' capacity, at every output of the hold.
    held = 2e-7 * held_at
    for state, _ in while_held:
        assert abs(sum(state.volumes_m3) - rest - held) <= 1e-12 * scene.capacity
    # Resumed, the programme ran to its end: 4 mL in 20 s of run time, the hold's 5 s not
    # counted.
    _, last, _ = said[-1]
    assert abs(sum(last.volumes_m3) - rest - 4.0e-6) <= 1e-12 * scene.capacity
    assert finished_ns == 25_000_000_000


def test_a_batch_run_whose_pump_is_held_for_good_ends_with_its_bag_complete(tmp_path):
    # A channel that passes almost nothing (minor loss 1e6): pumped at 1 mL/s, the base
    # passes the end of its curve while the tip is nearly empty, the actuator refuses the
    # commands beyond, the pump holds for want of answers, and in a batch run nobody can call
    # ~/start: the run used to tick on at 100x real time for ever.
    data = yaml.safe_load((FIG1.parent / 'rate_inversion.yaml').read_text())
    data['network']['channels'][0]['minor_loss'] = 1.0e6
    data['pump']['flow_rate_m3_per_s'] = 1.0e-6
    data['camera'] = {'rate_hz': 1}
    scene = scene_from_dict(data, tmp_path / 'overfill.yaml')
    programme_ns = scene.pump.profile.duration() * 1e9

    def bounded(stage, function):
        # A run that goes on past twice its programme would never end: fail instead.
        if stage != 'pump.tick':
            return function

        def tick(now):
            assert now <= 2.0 * programme_ns, 'the run went on past twice its programme'
            return function(now)
        return tick

    result = softseq_ros.run(scene, tmp_path / 'bag', start_time_ns=0, wrap=bounded)
    assert result.pump_state == 'held'
    assert any('nothing in a batch run starts it again' in w for w in result.warnings)
    # It ended where the pump held, not at the programme's end or later.
    assert result.sim_duration_s < 0.5 * scene.pump.profile.duration()
    summary = bag_summary(tmp_path / 'bag')
    assert summary.complete and summary.message_count == sum(result.message_counts.values())
    states = [json.loads(m.msg.data)['state'] for m in read_bag(tmp_path / 'bag',
                                                                ['/pump/status'])]
    assert states[-1] == 'held'
