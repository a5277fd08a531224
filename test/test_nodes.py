"""
The rig's nodes in one process: real rclpy over real DDS, namespaces, remapping, parameters.

The references are independent of the node code: the equilibrium solver run on the very
command volumes the test received, closed forms for the pump programme and the pose convention,
and the kinematics module for the backbone geometry.
"""

import json
import math
import time

import numpy as np
import pytest
from rclpy.exceptions import InvalidParameterValueException
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from scenes import inside_the_hysteresis_loop, write_scene
from sensor_msgs.msg import JointState

from softseq_ros.nodes.actuator import ActuatorNode
from softseq_ros.nodes.camera import CameraNode
from softseq_ros.nodes.core_node import message_class, qos_profile
from softseq_ros.nodes.runner import spin_past_lost_messages
from softseq_ros.nodes.sim_clock import SimClockNode
from softseq_ros.nodes.syringe_pump import SyringePumpNode
from softseq_ros.quasistatic.equilibrium import EquilibriumMap, Tracker
from softseq_ros.rig.render import SideViewRenderer
from softseq_ros.scene.loader import load_scene
from softseq_ros.segments.kinematics import backbone_batch
from softseq_ros.testing import TIMEOUT_S, Collector, call_trigger, spinning, stamp_ns, wait_for
from softseq_ros.wire import contract
from softseq_ros.wire.contract import SEGMENT_RGB

AMBIENT = 101325.0

pytestmark = pytest.mark.ros


def status_states(messages) -> list[str]:
    """The states of received pump/status messages (JSON)."""
    return [json.loads(m.data)['state'] for m in messages]


def status_history(messages) -> str:
    """The received pump/status messages as 'state (reason)', for a failure message."""
    statuses = [json.loads(m.data) for m in messages]
    return 'pump states: ' + ', '.join(f"{s['state']} ({s.get('reason', '')})" for s in statuses)


def rclpy_spin_once(node: Node) -> None:
    """Handle what is ready for ``node`` (a node no executor spins), waiting at most 0.1 s."""
    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    try:
        executor.spin_once(timeout_sec=0.1)
    finally:
        executor.remove_node(node)
        executor.shutdown()


@pytest.mark.ros
def test_a_message_rclpy_cannot_take_is_lost_with_a_warning_not_the_process(context, capfd):
    # rclpy's take has failed under a 10 kHz load to convert a message it received, and the
    # executor raised that from spin: the actuator process ended. Only that message is lost
    # now; any other error still ends the run.
    node = Node('lossy', context=context)
    calls = []

    def tick():
        calls.append(len(calls))
        if len(calls) == 1:
            raise RuntimeError("Unable to convert call argument '0' to Python object")
        if len(calls) == 3:
            raise RuntimeError('something else')

    node.create_timer(0.01, tick)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        with pytest.raises(RuntimeError, match='something else'):
            spin_past_lost_messages(executor, node)
    finally:
        executor.shutdown()
        node.destroy_node()
    assert len(calls) == 3
    assert 'a message could not be taken and is lost' in capfd.readouterr().err


MOVING_COMMANDS = 20   # the fewest commands with flow a comparison with the solver needs


def check_against_solver(emap: EquilibriumMap, commands, pressures, volumes, curvatures):
    """
    Received actuator outputs equal the solver swept over the received commands.

    Outputs carry the stamp of the command they answer, so they are paired by stamp: a message
    the test's own queue dropped under load costs a comparison, never a misalignment. The
    solver's jump rule makes the sweep over the received commands valid even if the test
    missed some that the actuator got.
    """
    injected = np.array([c.position[0] for c in commands])
    path = Tracker(emap).sweep(injected)
    row_of = {stamp_ns(c.header): row for row, c in enumerate(commands)}

    def paired(messages):
        rows, found = [], []
        for message in messages:
            row = row_of.get(stamp_ns(message.header))
            if row is not None:
                rows.append(row)
                found.append(message)
        return np.array(rows, dtype=int), found

    moving = int(np.sum(injected > 0.0))
    for topic, messages in ((contract.VOLUMES, volumes), (contract.PRESSURE, pressures),
                            (contract.CURVATURES, curvatures)):
        rows, _ = paired(messages)
        # A latched topic of depth 1 keeps only the latest state: a starved reader may miss
        # states in between, and what it gets must still be right.
        share = 0.9 if topic.qos.depth > 1 else 0.2
        # The pump ticks on the wall clock: on a loaded machine it skips ticks (a 1.2 s
        # programme at 100 Hz gave 42 commands, not 120), so some commands, not a count.
        assert moving >= MOVING_COMMANDS and np.sum(injected[rows] > 0.0) >= share * moving, \
            f'only {len(rows)} {topic.name} outputs answer the {len(injected)} commands received'
    rows, found = paired(volumes)
    np.testing.assert_allclose([m.position for m in found], path.volumes[rows], rtol=1e-9,
                               atol=1e-9 * emap.v_scale)
    np.testing.assert_allclose([m.effort for m in found],
                               np.repeat(path.pressure[rows, None], 2, axis=1),
                               rtol=1e-9, atol=1e-9 * emap.p_scale)
    rows, found = paired(pressures)
    np.testing.assert_allclose([m.fluid_pressure - AMBIENT for m in found], path.pressure[rows],
                               rtol=1e-9, atol=1e-9 * emap.p_scale)
    rows, found = paired(curvatures)
    np.testing.assert_allclose([m.position for m in found], path.curvatures[rows], rtol=1e-9,
                               atol=1e-12)
    return path


def check_poses(poses, curvature_rows, lengths, points_per_segment):
    """Every backbone message is the kinematics of one received curvature vector."""
    points, _ = backbone_batch(np.asarray(curvature_rows), lengths, points_per_segment)
    for msg in poses:
        assert msg.header.frame_id == 'softseq_base'
        xyz = np.array([[p.position.x, p.position.y, p.position.z] for p in msg.poses])
        assert np.all(xyz[:, 1] == 0.0)
        distance = np.max(np.abs(points - xyz[None, :, [0, 2]]), axis=(1, 2))
        assert distance.min() < 1e-12
        # Convention, checked in closed form: the pose's +x axis is the tangent; on a
        # constant-curvature arc the chord between two samples points along the mean of
        # their tangent angles.
        q = np.array([[p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w]
                      for p in msg.poses])
        assert np.allclose(q[:, [0, 2]], 0.0)
        np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-12)
        tangent_x = q[:, 3] ** 2 - q[:, 1] ** 2       # R(q) applied to (1, 0, 0)
        tangent_z = -2.0 * q[:, 3] * q[:, 1]
        theta = np.unwrap(np.arctan2(tangent_z, tangent_x))
        chord = np.diff(xyz[:, [0, 2]], axis=0)
        chord_angle = np.arctan2(chord[:, 1], chord[:, 0])
        np.testing.assert_allclose(np.angle(np.exp(1j * (chord_angle
                                                         - 0.5 * (theta[1:] + theta[:-1])))),
                                   0.0, atol=1e-9)


# ------------------------------------------------------------------------- one process, DDS

def test_rig_in_one_process_matches_the_solver(context, tmp_path):
    scene_path = write_scene(tmp_path)
    scene = load_scene(scene_path)
    emap = EquilibriumMap(scene.segments)
    common = [Parameter('scene', value=scene_path)]
    pump = SyringePumpNode(context=context, parameter_overrides=common + [
        Parameter('autostart', value=False), Parameter('rate_hz', value=100)])
    actuator = ActuatorNode(context=context, parameter_overrides=common + [
        Parameter('resume_timeout_s', value=0.0)])
    camera = CameraNode(context=context, parameter_overrides=common)
    topics = ['pump/command', 'pump/status', 'actuator/pressure', 'actuator/volumes',
              'actuator/curvatures', 'actuator/events', 'camera/backbone',
              'camera/snapshots', 'camera/snapshot_steps', 'camera/markers']
    collector = Collector(topics, context)
    got = collector.received
    with spinning(context, pump, actuator, camera, collector):
        wait_for(lambda: all(collector.matched(t) for t in got), 'all topics matched')
        wait_for(lambda: pump.publisher(contract.PUMP_COMMAND).get_subscription_count() == 2,
                 'the actuator and the test on pump/command')
        wait_for(lambda: not actuator.resuming, 'the actuator to finish its resume wait')
        response = call_trigger(collector, '/syringe_pump/start')
        assert response.success, response.message
        wait_for(lambda: 'finished' in status_states(got['/pump/status']),
                 'the programme to finish', explain=lambda: status_history(got['/pump/status']))
        n_commands = len(got['/pump/command'])
        wait_for(lambda: len(got['/actuator/curvatures']) >= n_commands - 5,
                 'the actuator outputs of every command')
        statuses = [json.loads(m.data) for m in got['/pump/status']]
        assert [s['state'] for s in statuses][-2:] == ['running', 'finished']
        # Each status carries the time it was entered, on the node clock.
        assert statuses[-1]['stamp_ns'] >= statuses[-2]['stamp_ns'] > 0
        # A late joiner gets the current state only, not the history.
        late = Collector(['pump/status'], context, name='late')
        executor_thread_free = late.received['/pump/status']
        deadline = time.monotonic() + TIMEOUT_S
        while not executor_thread_free and time.monotonic() < deadline:
            rclpy_spin_once(late)
        time.sleep(0.2)
        rclpy_spin_once(late)
        assert status_states(executor_thread_free) == ['finished']
        late.destroy_node()
        assert camera.core.images_rendered == 0, 'an image was rendered with nobody subscribed'

        commands = list(got['/pump/command'])
        path = check_against_solver(emap, commands, got['/actuator/pressure'],
                                    got['/actuator/volumes'], got['/actuator/curvatures'])
        assert len(got['/actuator/events']) == len(path.events)
        # The run went past the top's pressure peak (about 20 mL) and back to rest.
        injected = np.array([c.position[0] for c in commands])
        assert 2.5e-5 < injected.max() <= 3.0e-5 and injected[-1] == 0.0

        curvature_rows = [list(m.position) for m in got['/actuator/curvatures']]
        poses = list(got['/camera/backbone'])
        assert len(poses) >= 10
        check_poses(poses, curvature_rows, np.array(scene.lengths),
                    scene.camera.points_per_segment)
        # Two triggers, each crossed up and down; each snapshot says which.
        assert len(got['/camera/snapshots']) == 4
        steps = [json.loads(m.data) for m in got['/camera/snapshot_steps']]
        assert [(s['step'], s['direction']) for s in steps] == [
            (1, 'inflation'), (2, 'inflation'), (2, 'deflation'), (1, 'deflation')]
        assert [s['stamp_ns'] for s in steps] == [
            stamp_ns(m.header) for m in got['/camera/snapshots']]
        markers = got['/camera/markers'][-1].markers
        assert [m.type for m in markers] == [4, 4]          # LINE_STRIP per segment
        assert len(markers[0].points) == scene.camera.points_per_segment + 1

        # The image is rendered only while someone subscribes: a viewer node of its own,
        # spun here, so that destroying it never races the executor thread of the others.
        images = []
        viewer = Node('viewer', context=context)
        viewer.create_subscription(message_class(contract.IMAGE.type_name), '/camera/image',
                                   images.append, qos_profile(contract.IMAGE.qos))
        deadline = time.monotonic() + TIMEOUT_S
        while len(images) < 2:
            assert time.monotonic() < deadline, 'timed out waiting for camera images'
            rclpy_spin_once(viewer)
        image = images[-1]
        assert (image.encoding, image.width, image.height, image.step) == (
            'rgb8', 640, 480, 3 * 640)
        pixels = np.frombuffer(bytes(image.data), np.uint8).reshape(480, 640, 3)
        for colour in SEGMENT_RGB[:2]:
            assert np.all(pixels == colour, axis=2).sum() > 100
        viewer.destroy_node()
        image_publisher = camera.publisher(contract.IMAGE)
        wait_for(lambda: image_publisher.get_subscription_count() == 0, 'the image unsubscribe')
        # A frame in progress may still have seen the subscriber: count from the next one.
        frames = len(got['/camera/backbone'])
        wait_for(lambda: len(got['/camera/backbone']) > frames, 'one more frame')
        rendered = camera.core.images_rendered
        frames = len(got['/camera/backbone'])
        wait_for(lambda: len(got['/camera/backbone']) >= frames + 3, 'three more frames')
        assert camera.core.images_rendered == rendered


# ------------------------------------------------------------------------- parameters

def test_parameters_are_validated_with_a_reason(context, tmp_path):
    scene = Parameter('scene', value=write_scene(tmp_path))
    pump = SyringePumpNode(context=context, parameter_overrides=[scene])
    camera = CameraNode(context=context, parameter_overrides=[scene])
    clock = SimClockNode(context=context)
    try:
        result, = pump.set_parameters([Parameter('rate_hz', value=-5.0)])
        # rclpy's range check (descriptor) or ours: either way the reason names the parameter.
        assert not result.successful and 'rate_hz' in result.reason and '-5' in result.reason
        result, = pump.set_parameters([Parameter('rate_hz', value=0)])
        assert not result.successful and result.reason == 'rate_hz: must be > 0, got 0'
        result, = pump.set_parameters([Parameter('rate_hz', value='fast')])
        assert not result.successful and 'rate_hz: must be a number' in result.reason
        result, = pump.set_parameters([Parameter('rate_hz', value=25)])     # an integer
        assert result.successful and pump.rate_hz == 25.0
        assert pump._timer.timer_period_ns == 40_000_000
        result, = pump.set_parameters([Parameter('open_loop', value=True)])
        assert not result.successful and 'read-only' in result.reason
        result, = camera.set_parameters([Parameter('noise_std_m', value=-1.0e-3)])
        assert not result.successful and 'noise_std_m' in result.reason \
            and '-0.001' in result.reason
        result, = camera.set_parameters([Parameter('rate_hz', value=5)])
        assert result.successful and camera._timer.timer_period_ns == 200_000_000
        result, = clock.set_parameters([Parameter('speedup', value=0)])
        assert not result.successful and 'speedup: must be > 0' in result.reason
    finally:
        for node in (pump, camera, clock):
            node.destroy_node()
    # Values given at start are checked by the same rules.
    with pytest.raises(InvalidParameterValueException, match='unknown output'):
        CameraNode(context=context, parameter_overrides=[
            scene, Parameter('outputs', value=['poses', 'photons'])])
    with pytest.raises(InvalidParameterValueException,
                       match=r'legs\[0\]\.inflate_to_ml: wrong or missing unit suffix'):
        SyringePumpNode(context=context, parameter_overrides=[
            scene, Parameter('legs', value='[{inflate_to_ml: 5}]')])
    # A range rclpy checks itself (from the descriptor), said in our words.
    with pytest.raises(InvalidParameterValueException,
                       match=r'^/camera: parameter seed: must be >= 0, got -1$'):
        CameraNode(context=context, parameter_overrides=[scene, Parameter('seed', value=-1)])


# ------------------------------------------------------------------------- sim clock

def test_sim_clock_runs_speedup_times_wall_time_and_nodes_follow_it(context):
    wall = [5_000_000_000]
    clock = SimClockNode(context=context, wall_ns=lambda: wall[0],
                         parameter_overrides=[Parameter('speedup', value=100),
                                              Parameter('start_s', value=2.0)])
    try:
        wall[0] += 260_000_000           # 0.26 s of wall time: 26 s of sim time
        clock.tick()
        assert clock.sim_ns == 28_000_000_000
        assert clock.set_parameters([Parameter('speedup', value=10.0)])[0].successful
        wall[0] += 1_000_000_000
        clock.tick()
        assert clock.sim_ns == 38_000_000_000   # continuous across the change
    finally:
        clock.destroy_node()

    live = SimClockNode(context=context)
    follower = Node('follower', context=context,
                    parameter_overrides=[Parameter('use_sim_time', value=True)])
    with spinning(context, live, follower):
        wait_for(lambda: follower.get_clock().now().nanoseconds > 0, 'sim time to arrive')
        seen = follower.get_clock().now().nanoseconds
        wait_for(lambda: follower.get_clock().now().nanoseconds > seen, 'sim time to advance')


# ------------------------------------------------------------------------- rendering

def test_side_view_draws_each_segment_where_the_backbone_is():
    renderer = SideViewRenderer(200, 100, half_extent_m=0.25)
    lengths = np.array([0.1, 0.1])
    # A straight first segment, then a half turn of the second toward +z.
    curvatures = np.array([[0.0, math.pi / 0.1]])
    points, _ = backbone_batch(curvatures, lengths, 20)
    image = renderer.render(points[0], [20, 40])
    columns, rows = renderer.to_pixels(points[0]).T
    # Closed form: the half turn of length 0.1 m has diameter 0.2 / pi; it ends above x = 0.1.
    tip_x, tip_z = 0.1, 0.2 / math.pi
    np.testing.assert_allclose(points[0, -1], [tip_x, tip_z], atol=1e-12)
    col, row = int(round(columns[10])), int(round(rows[10]))
    assert tuple(image[row, col]) == SEGMENT_RGB[0]
    col, row = int(round(columns[-1])), int(round(rows[-1]))
    assert tuple(image[row, col]) == SEGMENT_RGB[1]
    # Nothing is drawn below the base line on the right, where the backbone never goes.
    below = renderer.to_pixels([[0.05, -0.05]])[0]
    assert tuple(image[int(below[1]), int(below[0])]) == (236, 240, 244)


def test_actuator_resumes_from_the_latched_volumes_of_a_live_publisher(context):
    # Somebody still holds the last actuator/volumes (transient_local): an actuator that
    # starts now continues on that branch. fig1_asymmetric, inside its hysteresis loop.
    scene = load_scene('fig1_asymmetric')
    emap = EquilibriumMap(scene.segments)
    middle, inflating, held_volumes = inside_the_hysteresis_loop(emap)
    assert np.max(np.abs(held_volumes - inflating)) > 1e-3 * emap.v_scale
    keeper = Node('keeper', context=context)
    latched = keeper.create_publisher(JointState, 'actuator/volumes',
                                      qos_profile(contract.VOLUMES.qos))
    latched.publish(JointState(name=['bottom', 'top'], position=list(held_volumes)))
    actuator = ActuatorNode(context=context, parameter_overrides=[
        Parameter('scene', value='fig1_asymmetric'), Parameter('resume_timeout_s', value=10.0)])
    with spinning(context, keeper, actuator):
        wait_for(lambda: not actuator.resuming, 'the resume')
        resumed = actuator.core.model.tracker.state
    assert resumed.injected == pytest.approx(middle, rel=1e-9)
    np.testing.assert_allclose(resumed.volumes, held_volumes, rtol=1e-9,
                               atol=1e-9 * emap.v_scale)
    # Not where a fresh start would have put it.
    assert np.max(np.abs(resumed.volumes - inflating)) > 1e-3 * emap.v_scale


def test_actuator_state_file_is_in_the_ros_home_per_namespace_unless_off(context, ros_home):
    scene = Parameter('scene', value='paper')
    plain = ActuatorNode(context=context, parameter_overrides=[scene])
    moved = ActuatorNode(context=context, cli_args=['--ros-args', '-r', '__ns:=/lab/rig2'],
                         parameter_overrides=[scene])
    off = ActuatorNode(context=context, parameter_overrides=[
        scene, Parameter('state_file', value='')])
    try:
        assert plain.core.state_file == ros_home / 'softseq' / 'actuator.json'
        assert moved.core.state_file == ros_home / 'softseq' / 'lab' / 'rig2' / 'actuator.json'
        assert off.core.state_file is None
    finally:
        for node in (plain, moved, off):
            node.destroy_node()


def test_camera_refuses_an_unknown_frame_trigger(context, tmp_path):
    with pytest.raises(InvalidParameterValueException, match='must be timer or state'):
        CameraNode(context=context, parameter_overrides=[
            Parameter('scene', value=write_scene(tmp_path)),
            Parameter('frame_trigger', value='sometimes')])


# ------------------------------------------------------------------------- namespaces

def _rig_nodes(context, scene_path, namespace, **pump_params):
    """Pump, actuator and camera as separate nodes, started with -r __ns:=namespace."""
    args = ['--ros-args', '-r', f'__ns:={namespace}']
    scene = [Parameter('scene', value=scene_path)]
    pump = SyringePumpNode(context=context, cli_args=args, parameter_overrides=scene + [
        Parameter('autostart', value=False)] + [Parameter(k, value=v)
                                               for k, v in pump_params.items()])
    actuator = ActuatorNode(context=context, cli_args=args, parameter_overrides=scene + [
        Parameter('resume_timeout_s', value=0.0)])
    camera = CameraNode(context=context, cli_args=args, parameter_overrides=scene)
    return pump, actuator, camera


def test_two_namespaced_rigs_run_side_by_side_without_crosstalk(context, tmp_path):
    # The same scene, two programmes: rig1 pumps to 30 mL, rig2 only to 12 mL and back.
    scene_path = write_scene(tmp_path)
    scene = load_scene(scene_path)
    emap = EquilibriumMap(scene.segments)
    rig1 = _rig_nodes(context, scene_path, '/rig1')
    rig2 = _rig_nodes(context, scene_path, '/rig2',
                      legs='[{inflate_to_m3: 1.2e-5}, {deflate_to_m3: 0.0}]')
    topics = ['pump/command', 'pump/status', 'actuator/pressure', 'actuator/volumes',
              'actuator/curvatures', 'camera/backbone']
    collectors = [Collector(topics, context, namespace, f'collector{i}')
                  for i, namespace in ((1, '/rig1'), (2, '/rig2'))]
    warnings = []
    for actuator in (rig1[1], rig2[1]):
        actuator.log = lambda level, text, warnings=warnings: warnings.append(text)
    with spinning(context, *rig1, *rig2, *collectors):
        for collector in collectors:
            wait_for(lambda c=collector: all(c.matched(t) for t in c.received),
                     'both rigs matched')
        for pump, actuator, _ in (rig1, rig2):
            # Each pump has its own actuator (and the collector) on its command topic.
            publisher = pump.publisher(contract.PUMP_COMMAND)
            wait_for(lambda p=publisher: p.get_subscription_count() == 2,
                     'one actuator per pump')
            wait_for(lambda a=actuator: not a.resuming, 'the actuators to start')
        for collector, namespace in zip(collectors, ('/rig1', '/rig2')):
            assert call_trigger(collector, f'{namespace}/syringe_pump/start').success
        for collector, namespace in zip(collectors, ('/rig1', '/rig2')):
            statuses = collector.received[f'{namespace}/pump/status']
            wait_for(lambda s=statuses: 'finished' in status_states(s),
                     f'the programme of {namespace} to finish',
                     explain=lambda s=statuses: status_history(s))
        time.sleep(0.3)
    peaks = []
    for collector, namespace in zip(collectors, ('/rig1', '/rig2')):
        got = collector.received
        commands = list(got[f'{namespace}/pump/command'])
        check_against_solver(emap, commands, got[f'{namespace}/actuator/pressure'],
                             got[f'{namespace}/actuator/volumes'],
                             got[f'{namespace}/actuator/curvatures'])
        # Every answer in a namespace answers a command of that namespace's pump.
        stamps = {stamp_ns(c.header) for c in commands}
        # The actuator may say its rest state once, before any command came: it answers none.
        strays = [m for m in got[f'{namespace}/actuator/volumes']
                  if stamp_ns(m.header) not in stamps]
        assert len(strays) <= 1 and all(not any(m.effort) for m in strays)
        peaks.append(max(c.position[0] for c in commands))
    # Each rig followed its own programme: never past its own top, and near it. The pump
    # samples its programme on wall-clock ticks (100 Hz); on a loaded machine a tick may come
    # late and miss the top, so "near" allows a quarter second of the 20 mL/s flow (5 mL),
    # still far from the other rig's top.
    stall = 0.25 * 2.0e-5
    assert 3.0e-5 - stall < peaks[0] <= 3.0e-5 and 1.2e-5 - stall < peaks[1] <= 1.2e-5
    assert not any('publishers' in w for w in warnings), warnings


def test_actuator_warns_once_when_two_pumps_command_it(context, tmp_path):
    scene_path = write_scene(tmp_path)
    pump, actuator, camera = _rig_nodes(context, scene_path, '/shared')
    intruder = SyringePumpNode(context=context, cli_args=[
        '--ros-args', '-r', '__ns:=/shared', '-r', '__node:=other_pump'],
        parameter_overrides=[Parameter('scene', value=scene_path),
                             Parameter('autostart', value=False)])
    warnings = []
    actuator.log = lambda level, text: warnings.append(text)
    with spinning(context, pump, actuator, camera, intruder):
        wait_for(lambda: any('publishers' in w for w in warnings),
                 'the two-publisher warning', timeout=10.0)
        time.sleep(2.5)   # more checks of the same graph: no repeat
    warned = [w for w in warnings if 'publishers' in w]
    assert len(warned) == 1
    assert '/shared/pump/command' in warned[0]
    assert '/shared/syringe_pump' in warned[0] and '/shared/other_pump' in warned[0]


def test_one_topic_can_be_remapped(context, tmp_path):
    # The actuator listens to another pump topic; only the remapped pump reaches it.
    scene_path = write_scene(tmp_path)
    scene = [Parameter('scene', value=scene_path)]
    remap = ['--ros-args', '-r', 'pump/command:=/bench/syringe']
    pump = SyringePumpNode(context=context, cli_args=remap, parameter_overrides=scene + [
        Parameter('legs', value='[{inflate_to_m3: 5.0e-6}, {hold_s: 100}]')])
    actuator = ActuatorNode(context=context, cli_args=remap, parameter_overrides=scene + [
        Parameter('resume_timeout_s', value=0.0)])
    collector = Collector(['actuator/volumes'], context)
    got = collector.received['/actuator/volumes']
    with spinning(context, pump, actuator, collector):
        assert actuator.subscription(contract.PUMP_COMMAND).topic_name == '/bench/syringe'
        assert pump.publisher(contract.PUMP_COMMAND).topic_name == '/bench/syringe'
        wait_for(lambda: len(got) > 1 and sum(got[-1].position) > sum(got[0].position) + 1e-7,
                 'the actuator to follow the remapped pump')
