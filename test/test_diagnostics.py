"""
/diagnostics: every node's health as diagnostic_msgs/DiagnosticArray, namespaced rigs apart,
recordable into a bag that the independent readers decode.
"""

import json
import math
from pathlib import Path

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from mcap_ros2.reader import read_ros2_messages
import pytest
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile
from rosbags.highlevel import AnyReader
from sensor_msgs.msg import JointState
from std_msgs.msg import String

import softseq_ros
from softseq_ros.bag.info import bag_info, format_info
from softseq_ros.nodes.actuator import ActuatorNode
from softseq_ros.nodes.camera import CameraNode
from softseq_ros.nodes.recorder import Recorder
from softseq_ros.nodes.syringe_pump import SyringePumpNode
from softseq_ros.testing import Collector, call_trigger, spinning, wait_for
from softseq_ros.wire import contract

pytestmark = pytest.mark.ros
NS = '/rig_d'


def latest(collector: Collector) -> dict[str, DiagnosticStatus]:
    """The newest status of each hardware_id received on /diagnostics."""
    found = {}
    for array in collector.messages('/diagnostics'):
        for status in array.status:
            found[status.hardware_id] = status
    return found


def values(status: DiagnosticStatus) -> dict[str, str]:
    return {pair.key: pair.value for pair in status.values}


def test_every_node_reports_its_health_under_its_fully_qualified_name(context, tmp_path: Path):
    scene = [Parameter('scene', value='fig1_none')]
    # 1 kPa per mL on the bottom segment: a 300 Pa relief setting trips within a few commands.
    pump = SyringePumpNode(context=context, namespace=NS, parameter_overrides=scene + [
        Parameter('autostart', value=False), Parameter('flow_rate_m3_per_s', value=2e-6),
        Parameter('max_pressure_pa', value=300.0)])
    actuator = ActuatorNode(context=context, namespace=NS, parameter_overrides=scene + [
        Parameter('state_file', value=''), Parameter('resume_timeout_s', value=0.0)])
    camera = CameraNode(context=context, namespace=NS, parameter_overrides=scene)
    recorder = Recorder(context=context, namespace=NS, parameter_overrides=[
        Parameter('output', value=str(tmp_path / 'bag')),
        Parameter('topics', value=['pump/command', 'pump/status', 'actuator/volumes',
                                   'actuator/scene', '/diagnostics', 'unknown_type']),
        Parameter('types', value=['', '', '', '', '', 'no_such_msgs/msg/Nothing'])])
    collector = Collector(['pump/status'], context, namespace=NS)
    collector.add('/diagnostics', DiagnosticArray, QoSProfile(depth=10))
    intruder = Node('intruder', context=context, namespace=NS)
    garbage = intruder.create_publisher(JointState, 'pump/command', QoSProfile(depth=10))
    unknown = intruder.create_publisher(String, 'unknown_type', QoSProfile(depth=10))
    names = {f'{NS}/{name}': task for name, task in (
        ('syringe_pump', 'syringe pump'), ('actuator', 'actuator'), ('camera', 'camera'),
        ('recorder', 'recorder'))}
    try:
        with spinning(context, pump, actuator, camera, recorder, collector, intruder):
            wait_for(lambda: set(latest(collector)) == set(names), 'a status of every node',
                     explain=lambda: f'got {sorted(latest(collector))}')
            for fqn, status in latest(collector).items():
                assert status.name == f'{fqn}: {names[fqn]}'
            pump_status = latest(collector)[f'{NS}/syringe_pump']
            assert pump_status.level == DiagnosticStatus.OK
            assert values(pump_status)['state'] == 'idle'
            assert float(values(pump_status)['max_pressure_pa (gauge)']) == 300.0
            # A topic whose type is not installed: the recorder says so, and records the rest.
            wait_for(lambda: recorder.failed_topics, 'the recorder to try the unknown type')
            unknown.publish(String(data='x'))

            assert call_trigger(collector, f'{NS}/syringe_pump/start').success
            wait_for(lambda: 'stopped' in collector.states(), 'the relief valve')

            def pump_says():
                status = latest(collector)[f'{NS}/syringe_pump']
                return status if values(status)['state'] == 'stopped' else None
            wait_for(pump_says, 'the stop on /diagnostics')
            status = pump_says()
            assert status.level == DiagnosticStatus.ERROR
            assert 'exceeds max_pressure_pa' in status.message
            assert float(values(status)['relief_margin_pa']) < 0.0

            # Garbage on the actuator's command topic: refused, and said on /diagnostics.
            garbage.publish(JointState(name=['syringe'], position=[math.nan], velocity=[0.0]))

            def actuator_says():
                status = latest(collector)[f'{NS}/actuator']
                return status if int(values(status)['refused_commands']) >= 1 else None
            wait_for(actuator_says, 'the refusal on /diagnostics')
            assert actuator_says().level == DiagnosticStatus.WARN

            def recorder_says():
                status = latest(collector)[f'{NS}/recorder']
                return status if int(values(status)['messages_written']) > 3 else None
            wait_for(recorder_says, 'the recorder to write')
            status = recorder_says()
            assert status.level == DiagnosticStatus.WARN
            assert status.message.startswith(f'not recording {NS}/unknown_type:')
            assert int(values(status)['bytes_written']) > 0
            assert values(status)['write_failures'] == '0'
            # Each recorded topic's count, adding up to the whole.
            per_topic = {key.removeprefix('messages '): int(value)
                         for key, value in values(status).items()
                         if key.startswith('messages ')}
            assert per_topic[f'{NS}/actuator/scene'] >= 1
            assert sum(per_topic.values()) == int(values(status)['messages_written'])
            camera_status = latest(collector)[f'{NS}/camera']
            assert float(values(camera_status)['rate_hz']) == 10.0
            recorder.close_bag(log=False)
    finally:
        recorder.close_bag(log=False)

    # The recorded /diagnostics: a full definition in the bag, read by both independent
    # readers and by softseq info; the rig's topics beside it are as always.
    bag = tmp_path / 'bag'
    assert '/diagnostics' in format_info(bag_info(bag))
    with AnyReader([bag]) as reader:
        connection, = [c for c in reader.connections if c.topic == '/diagnostics']
        assert connection.msgtype == 'diagnostic_msgs/msg/DiagnosticArray'
        decoded = [reader.deserialize(raw, connection.msgtype)
                   for _, _, raw in reader.messages(connections=[connection])]
    assert decoded and {s.hardware_id for m in decoded for s in m.status} <= set(names)
    mcap_file, = bag.glob('*.mcap')
    by_mcap = [m.ros_msg for m in read_ros2_messages(str(mcap_file), topics=['/diagnostics'])]
    assert [len(m.status) for m in by_mcap] == [len(m.status) for m in decoded]
    statuses = [json.loads(m.ros_msg.data)['state'] for m in
                read_ros2_messages(str(mcap_file), topics=[f'{NS}/pump/status'])]
    assert statuses[-1] == 'stopped'


def test_the_batch_runner_records_no_diagnostics(tmp_path: Path):
    # A batch bag is the run's recording; /diagnostics is a live rig's health.
    softseq_ros.run('fig1_none', tmp_path / 'bag', start_time_ns=0,
                    overrides={'pump': {'flow_rate_m3_per_s': 2.0e-5}})
    topics = bag_info(tmp_path / 'bag').summary.topics
    assert '/pump/command' in topics and contract.DIAGNOSTICS.name not in topics
