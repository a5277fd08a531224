"""
The rig behind a pressure regulator: its core commands target pressures, the actuator holds
each segment there as an independent hysteron, and the recording reads back as a regulator's.

Checked against the thin-walled Gent sphere's closed form (each segment's pressure at its
recorded volume equals the commanded target; the flips at its peak and valley), and against
the programme's own breakpoints.
"""

import json
import math

import numpy as np
import pytest
from scipy.optimize import minimize_scalar
import yaml

import softseq_ros
from softseq_ros.analysis.report import write_report
from softseq_ros.bag.reader import read_bag
from softseq_ros.quasistatic.regulator import regulated_path
from softseq_ros.rig.actuator import ActuatorCore
from softseq_ros.rig.build import SettingError, pump_core
from softseq_ros.rig.model import RegulatedModel, actuator_model
from softseq_ros.rig.pump import RUNNING
from softseq_ros.scene.loader import load_scene, scene_from_dict
from softseq_ros.wire.payloads import DECODERS, InputError, encode
from softseq_ros.wire.values import Notice, PumpCommand, PumpSetpoint, regulator_command

ML = 1e-6
R = 0.006
# The Fig. 1 pair: (name, Jm, wall [m]), base to tip.
PAIR = (('bottom', 40.0, 0.6e-3), ('top', 30.0, 0.564e-3))
MU = 60e3
UP_S, HOLD_S, RATE = 40.0, 5.0, 200.0     # to 8 kPa at 200 Pa/s, held, and back


def gent(stretch: float, jm: float, wall: float) -> float:
    """The thin-walled Gent sphere: p = 2 mu H / R (1/l - 1/l^7) / (1 - (2 l^2 + l^-4 - 3)/Jm)."""
    return (2 * MU * wall / R * (1 / stretch - stretch**-7)
            / (1 - (2 * stretch**2 + stretch**-4 - 3) / jm))


def peak_and_valley(jm: float, wall: float) -> tuple[float, float]:
    top = minimize_scalar(lambda s: -gent(s, jm, wall), bounds=(1.0, 2.5), method='bounded',
                          options={'xatol': 1e-12})
    bottom = minimize_scalar(lambda s: gent(s, jm, wall), bounds=(top.x, 3.5),
                             method='bounded', options={'xatol': 1e-12})
    return gent(top.x, jm, wall), gent(bottom.x, jm, wall)


def regulated_scene(tmp_path, legs=None, rate=RATE):
    data = {
        'name': 'pair_behind_a_regulator',
        'segments': [{'name': name, 'length_m': 0.111,
                      'balloon': {'material': {'law': 'gent', 'shear_modulus_pa': MU,
                                               'jm': jm},
                                  'radius_m': R, 'thickness_m': wall,
                                  'max_stretch': 4.0 if jm == 40.0 else 3.6,
                                  'curvature_per_m_per_m3': 5.0e5}}
                     for name, jm, wall in PAIR],
        'supply': {'regulator': {}},
        'pump': {'pressure_rate_pa_per_s': rate, 'rate_hz': 20,
                 'legs': legs or [{'inflate_to_pa': 8000.0}, {'hold_s': HOLD_S},
                                  {'deflate_to_pa': 0.0}]},
        'camera': {'rate_hz': 2},
    }
    path = tmp_path / 'regulated.yaml'
    path.write_text(yaml.safe_dump(data))
    return scene_from_dict(data, path)


def programme_target(t: np.ndarray) -> np.ndarray:
    return np.interp(t, [0.0, UP_S, UP_S + HOLD_S, 2 * UP_S + HOLD_S],
                     [0.0, 8000.0, 8000.0, 0.0])


def test_a_batch_run_behind_a_regulator_holds_each_segment_at_the_target(tmp_path):
    scene = regulated_scene(tmp_path)
    result = softseq_ros.run(scene, tmp_path / 'bag', start_time_ns=0)
    assert result.pump_state == 'finished'
    bag = tmp_path / 'bag'
    commands = list(read_bag(bag, ['/pump/command']))
    # Every command is the regulator's target at its instant, and nothing else.
    assert {tuple(m.msg.name) for m in commands} == {('regulator',)}
    assert all(len(m.msg.position) == len(m.msg.velocity) == 0 for m in commands)
    stamps = np.array([m.msg.header.stamp.sec + 1e-9 * m.msg.header.stamp.nanosec
                       for m in commands])
    targets = np.array([m.msg.effort[0] for m in commands])
    np.testing.assert_allclose(targets, programme_target(stamps), rtol=1e-12, atol=1e-9)
    assert targets.max() == pytest.approx(8000.0, rel=1e-12)
    # Every answer: each segment at the target on its curve (the closed form at the stretch
    # of its recorded volume), on a rising piece (the curve climbs there).
    by_stamp = dict(zip((m.log_time_ns for m in commands), targets))
    volumes = [m for m in read_bag(bag, ['/actuator/volumes']) if m.log_time_ns in by_stamp]
    assert len(volumes) >= len(commands) - 1
    v0 = 4 / 3 * math.pi * R**3
    for message in volumes[::7]:
        target = by_stamp[message.log_time_ns]
        for (_, jm, wall), volume, gauge in zip(PAIR, message.msg.position,
                                                   message.msg.effort):
            stretch = (volume / v0) ** (1 / 3)
            assert gent(stretch, jm, wall) == pytest.approx(target, rel=1e-9, abs=1e-6)
            assert gauge == pytest.approx(target, rel=1e-12, abs=1e-9)
            assert gent(stretch * (1 + 1e-6), jm, wall) > gent(stretch, jm, wall) \
                or target == 0.0
    # Four flips: each segment at its own peak going up, at its own valley coming down, the
    # thinner top first; the fluid comes from the regulator, not from the other segment.
    events = [json.loads(m.msg.data) for m in read_bag(bag, ['/actuator/events'])]
    (top_peak, top_valley), (bottom_peak, bottom_valley) = (peak_and_valley(jm, wall)
                                                            for _, jm, wall in PAIR[::-1])
    assert [e['from_pressure_pa'] for e in events] == pytest.approx(
        [top_peak, bottom_peak, top_valley, bottom_valley], rel=1e-9)
    for event, moving in zip(events, (1, 0, 1, 0)):
        still = 1 - moving
        assert event['to_volumes_m3'][still] == event['from_volumes_m3'][still]
        change = event['to_volumes_m3'][moving] - event['from_volumes_m3'][moving]
        assert abs(change) > 5 * ML
    # The report reads the regulator's bag: the injected volume is what the segments took.
    metrics, text = write_report(bag, tmp_path / 'report', scene_name=str(scene.path),
                                 figures=False)
    assert metrics['snap_count'] == 4
    assert text.count('taken from the regulator') == 2
    assert text.count('given back to the regulator') == 2
    assert any('pressure regulator' in note for note in metrics['notes'])
    last = volumes[-1].msg.position
    rest = sum(scene.segments[i].rest_volume for i in range(2))
    assert metrics['injected_range_m3'][0] == pytest.approx(0.0, abs=1e-15)
    assert sum(last) - rest == pytest.approx(0.0, abs=1e-12)


def test_a_regulator_in_setpoint_mode_holds_a_target_beyond_the_relief_at_the_relief(tmp_path):
    scene = regulated_scene(tmp_path)
    core, rate_hz = pump_core(scene, feedback_clock=None, open_loop=True)
    relief = scene.regulator.max_pressure_pa
    assert rate_hz == 20.0 and math.isinf(core.max_injected_m3)
    core.begin(0)
    assert core.set_mode(0, True).success
    # A volume or a flow cannot drive a regulator, nor a pressure that is no number or below
    # vacuum: refused, counted, warned (once per kind of setpoint).
    warned = []
    for refused in (PumpSetpoint(0, injected_m3=1e-6), PumpSetpoint(0, flow_m3_per_s=1e-7),
                    PumpSetpoint(0, gauge_pa=math.nan), PumpSetpoint(0, gauge_pa=-2e5)):
        warned += core.take_setpoint(refused, 0)
    assert [n.level for n in warned] == ['warning'] * 3
    assert all(isinstance(n, Notice) for n in warned)
    assert 'regulator' in warned[0].text and 'not a finite number' in warned[2].text
    assert core.setpoints_refused == 4 and core.setpoint is None
    assert 'below vacuum' in core.last_refused_setpoint
    # Beyond the relief: held at the relief, approached at the programme's rate.
    core.take_setpoint(PumpSetpoint(0, gauge_pa=3 * relief), 0)
    assert core.setpoints_refused == 5 and core.setpoints_held_at_relief == 1
    step = 50_000_000
    sent = []
    for k in range(1, 4000):
        sent += [v for v in core.tick(k * step) if isinstance(v, PumpCommand)]
    assert core.state == RUNNING
    assert sent[-1].regulated and sent[-1].gauge_pa == pytest.approx(relief, rel=1e-12)
    rises = np.diff([c.gauge_pa for c in sent])
    assert rises.max() == pytest.approx(RATE * step * 1e-9, rel=1e-9)
    # Back to the programme only from 0 Pa, where it starts: no command jumps.
    assert not core.set_mode(4000 * step, False).success
    core.take_setpoint(PumpSetpoint(0, gauge_pa=0.0), 4000 * step)
    for k in range(4001, 8000):
        core.tick(k * step)
    assert core.target_pa == 0.0
    assert core.set_mode(8000 * step, False).success


def test_a_syringe_setting_for_a_regulator_is_refused_by_name(tmp_path):
    scene = regulated_scene(tmp_path)
    with pytest.raises(SettingError, match='flow_rate_m3_per_s'):
        pump_core(scene, flow_rate_m3_per_s=1e-7)
    with pytest.raises(SettingError, match='max_pressure_pa'):
        pump_core(scene, max_pressure_pa=1000.0)


def test_each_actuator_refuses_the_other_supplys_command_and_keeps_its_state(tmp_path):
    regulated = ActuatorCore(actuator_model(regulated_scene(tmp_path)), ('bottom', 'top'))
    assert isinstance(regulated.model, RegulatedModel)
    before = list(regulated.model.state().volumes)
    said = regulated.handle(PumpCommand(1, 2e-6, 1e-7), 1)
    assert [n.level for n in said] == ['warning'] and 'regulator' in said[0].text
    assert regulated.model.state().volumes == before and regulated.rejected_commands == 1
    syringe = ActuatorCore(actuator_model(load_scene('fig1_asymmetric')), ('bottom', 'top'))
    said = syringe.handle(regulator_command(1, 5000.0), 1)
    assert [n.level for n in said] == ['warning'] and 'syringe' in said[0].text
    # A target beyond what a segment holds on a rising piece: refused, the state kept.
    said = regulated.handle(regulator_command(2, 1e6), 2)
    assert [n.level for n in said] == ['warning'] and regulated.rejected_commands == 2
    assert regulated.model.state().volumes == before


def test_the_regulator_command_is_a_joint_state_with_one_effort():
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import JointState

    from softseq_ros.bag.forms import serialize

    data = encode(regulator_command(1_500_000_000, 5000.0))
    msg = deserialize_message(data, JointState)
    assert list(msg.name) == ['regulator'] and list(msg.effort) == [5000.0]
    assert not len(msg.position) and not len(msg.velocity)
    assert serialize(msg) == data
    decoded = DECODERS['pump/command'](msg)
    assert decoded.regulated and decoded.gauge_pa == 5000.0
    assert decoded.stamp_ns == 1_500_000_000
    msg.position = [1.0]
    with pytest.raises(InputError, match='one effort'):
        DECODERS['pump/command'](msg)


STIFFNESS = 1.0e10           # Pa/m^3: C = 0.1 mL per kPa
RAMP_PA_PER_S = 50.0


def linear_behind_a_tube(tmp_path, regulator=None, legs=None, rtol=1e-9):
    """
    Two linear segments behind a 0.5 m tube of 0.4 mm radius, ramped by a regulator.

    Their channel (5 mm of 5 mm radius) resists 4e-7 of the tube: the two are one compliance
    2 C as far as the tube can tell.
    """
    linear = {'rest_volume_m3': 1.0e-6, 'stiffness_pa_per_m3': STIFFNESS,
              'max_volume_m3': 1.0e-4}
    data = {
        'name': 'linear_behind_a_regulator',
        'segments': [{'name': name, 'length_m': 0.05, 'linear': dict(linear)}
                     for name in ('base', 'tip')],
        'network': {'supply': {'length_m': 0.5, 'radius_m': 0.4e-3},
                    'channels': [{'length_m': 5.0e-3, 'radius_m': 5.0e-3}],
                    'rtol': rtol, 'rate_hz': 20.0},
        'supply': {'regulator': regulator or {}},
        'pump': {'pressure_rate_pa_per_s': RAMP_PA_PER_S, 'rate_hz': 20,
                 'legs': legs or [{'inflate_to_pa': 5000.0}, {'hold_s': 60.0}]},
        'camera': {'rate_hz': 1},
        'outputs': ['pressure', 'volumes', 'events'],
    }
    path = tmp_path / 'linear.yaml'
    path.write_text(yaml.safe_dump(data))
    return scene_from_dict(data, path)


def test_the_rig_in_time_fills_a_linear_segment_behind_a_tube_as_the_closed_form(tmp_path):
    # A ramp a t through the tube's R into a compliance 2 C: 2 R C dp/dt + p = a t, so
    # p(t) = a (t - tau (1 - exp(-t / tau))), tau = 2 R C; then held at 5 kPa, p relaxes to it.
    from softseq_ros.dynamic.network import tube_law
    scene = linear_behind_a_tube(tmp_path)
    tau = 2.0 * tube_law(scene.network.supply, scene.network.fluid).resistance / STIFFNESS
    assert 0.5 < tau < 20.0
    softseq_ros.run(scene, tmp_path / 'bag', start_time_ns=0)
    states = list(read_bag(tmp_path / 'bag', ['/actuator/volumes']))
    ramp_s = 5000.0 / RAMP_PA_PER_S
    checked = 0
    for message in states:
        t = message.log_time_ns / 1e9
        if t <= ramp_s:
            exact = RAMP_PA_PER_S * (t - tau * -np.expm1(-t / tau))
        else:
            at_end = RAMP_PA_PER_S * (ramp_s - tau * -np.expm1(-ramp_s / tau))
            exact = 5000.0 - (5000.0 - at_end) * np.exp(-(t - ramp_s) / tau)
        for volume in message.msg.position:
            assert (volume - 1.0e-6) * STIFFNESS == pytest.approx(exact, abs=1e-6 * 5000.0), t
        checked += 1
    assert checked > 2000
    # The published pressure is the regulator's outlet's: the target itself (no lag).
    pressures = [m.msg.effort[0] for m in states]
    assert max(pressures) == pytest.approx(5000.0, rel=1e-12)


def test_the_rig_in_time_follows_the_regulated_network_path(tmp_path):
    # The Fig. 1 pair in time behind a lagging regulator (shipped), its ramp shortened: the
    # rig's states, integrated command by command, are the path's (one integration per leg).
    from softseq_ros.dynamic.regulated import regulated_network_path
    scene = load_scene('fig1_asymmetric_regulator')
    softseq_ros.run(scene, tmp_path / 'bag', start_time_ns=0)
    states = list(read_bag(tmp_path / 'bag', ['/actuator/volumes']))
    times = np.array([m.log_time_ns / 1e9 for m in states])
    recorded = np.array([list(m.msg.position) for m in states])
    path = regulated_network_path(scene.segments, scene.network, scene.regulator, times,
                                  rtol=1e-10)
    scale = float(np.ptp(path.volumes))
    assert np.max(np.abs(recorded - path.volumes)) < 1e-5 * scale
    outlet = np.array([m.msg.effort[0] for m in states])
    assert np.max(np.abs(outlet - path.pressure)) < 1e-5 * scene.regulator.programme.highest()
    # Each flip is a snap-through event. The top's first: from its peak, passed filling where
    # the path passes it, to where the hysteron lands (its upper rising piece at the peak's
    # pressure), the water from the regulator.
    published = {json.loads(m.msg.data)['start_ns']: (m.log_time_ns, json.loads(m.msg.data))
                 for m in read_bag(tmp_path / 'bag', ['/actuator/events'])}
    events = [event for _, event in published.values()]
    first = min(events, key=lambda e: e['start_ns'])
    peak = next(c for c in path.folds if c.segment == 'top' and c.kind == 'peak')
    assert first['taking_segments'] == ['top'] and first['giving_segments'] == []
    assert first['start_ns'] / 1e9 == pytest.approx(peak.time_s, abs=1e-3)
    hysteron = regulated_path(scene.segments, [0.0, 7600.0]).flips[0]
    assert hysteron.segment == 1
    assert first['from_volumes_m3'][1] == pytest.approx(hysteron.from_volume, rel=1e-6)
    assert first['to_volumes_m3'][1] == pytest.approx(hysteron.to_volume, rel=1e-9)
    assert first['fluid_moved_m3'] == pytest.approx(hysteron.to_volume - hysteron.from_volume,
                                                    rel=1e-6)
    # It goes out when it has landed: its 10-90 % lies between its start and then.
    landed_ns = published[first['start_ns']][0]
    assert 0.0 < first['duration_s'] < (landed_ns - first['start_ns']) / 1e9
    # Both segments flip up and back down: the report counts the flips in time.
    up = {e['taking_segments'][0] for e in events if e['taking_segments']}
    down = {e['giving_segments'][0] for e in events if e['giving_segments']}
    assert up == down == {'bottom', 'top'}
    metrics, text = write_report(tmp_path / 'bag', tmp_path / 'report', figures=False)
    assert metrics['snap_count'] == len(events)
    assert 'taken from the regulator' in text and 'given back to the regulator' in text


def test_the_rig_in_time_notes_each_fold_where_the_path_locates_it(tmp_path):
    # The model driven as the regulator's core drives it (a command every 50 ms): the
    # segments pass the folds of their curves where the path's events locate them.
    from softseq_ros.dynamic.regulated import regulated_network_path
    from softseq_ros.rig.model import RegulatedFlowModel
    from softseq_ros.rig.regulator import PressureSchedule
    scene = load_scene('fig1_asymmetric_regulator')
    model = actuator_model(scene)
    assert isinstance(model, RegulatedFlowModel) and model.end_stop_m3 == math.inf
    schedule = PressureSchedule(scene.regulator.programme, 25.0)
    step_ns = 50_000_000
    notes = []
    for k in range(int(schedule.duration() * 20) + 1):
        model.command_pressure(schedule.command_at(k * step_ns / 1e9)[0], k * step_ns)
        model.advance(k * step_ns + step_ns // 2)
        notes += model.take_notes()
    found = model.run.take_fold_crossings()
    path = regulated_network_path(scene.segments, scene.network, scene.regulator,
                                  rtol=1e-10)
    assert notes and len(notes) == len(path.folds)
    assert all('passes the' in line for line in notes)
    assert found == []   # the notes took them
    assert [line.split(' passes the ')[0] for line in notes] == \
        [f'segment {c.segment}' for c in path.folds]
    times = [float(line.split(', at ')[1].split(' s,')[0]) for line in notes]
    assert times == pytest.approx([c.time_s for c in path.folds], abs=0.05)


@pytest.mark.ros
def test_the_pump_node_drives_a_regulator_and_takes_pressure_setpoints_over_dds(context,
                                                                                tmp_path):
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import JointState
    from std_srvs.srv import SetBool

    from softseq_ros.nodes.actuator import ActuatorNode
    from softseq_ros.nodes.syringe_pump import SyringePumpNode
    from softseq_ros.testing import Collector, spinning, wait_for

    # Fast enough for wall time: to 8 kPa in 2 s, held (both segments flipped on the way).
    scene = regulated_scene(tmp_path, legs=[{'inflate_to_pa': 8000.0}, {'hold_s': 600.0}],
                            rate=4000.0)
    path = Parameter('scene', value=str(scene.path))
    pump = SyringePumpNode(context=context, parameter_overrides=[path])
    actuator = ActuatorNode(context=context, parameter_overrides=[
        path, Parameter('resume_timeout_s', value=0.0), Parameter('state_file', value='')])
    collector = Collector(['pump/command', 'actuator/volumes', 'actuator/events'], context)
    commands = collector.messages('pump/command')
    volumes = collector.messages('actuator/volumes')
    with spinning(context, pump, actuator, collector):
        events = collector.wait_for_count('actuator/events', 2, timeout=60.0)
        wait_for(lambda: volumes and volumes[-1].effort[0] == 8000.0, 'the hold at 8 kPa')
        # A controller takes the regulator over, its target reached at the programme's rate.
        client = collector.create_client(SetBool, 'syringe_pump/setpoint_mode')
        assert client.wait_for_service(timeout_sec=10.0)
        future = client.call_async(SetBool.Request(data=True))
        wait_for(future.done, 'the setpoint mode')
        assert future.result().success
        publisher = collector.create_publisher(JointState, 'pump/setpoint', 10)
        setpoint = JointState(name=['regulator'], effort=[6000.0])
        wait_for(lambda: publisher.get_subscription_count() > 0, 'the pump to listen')
        publisher.publish(setpoint)
        wait_for(lambda: volumes and volumes[-1].effort[0] == 6000.0, 'the hold at 6 kPa')
        health = pump.health()
    assert all(list(m.name) == ['regulator'] and len(m.position) == 0 for m in commands)
    assert [json.loads(e.data)['from_pressure_pa'] for e in events[:2]] == pytest.approx(
        [peak_and_valley(jm, wall)[0] for _, jm, wall in PAIR[::-1]], rel=1e-9)
    assert health.values['mode'] == 'setpoint' and health.values['setpoints_taken'] == 1
    assert health.values['target_pa (gauge)'] == 6000.0
