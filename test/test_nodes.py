"""
The rig's nodes in one process: real rclpy over real DDS, and the batch-mode hooks.

The references are independent of the node code: the equilibrium solver run on the very
command volumes the test received, closed forms for the pump programme and the pose convention,
and the kinematics module for the backbone geometry.
"""

from contextlib import contextmanager
import json
import math
import threading
import time

from geometry_msgs.msg import PoseArray
import numpy as np
import pytest
from rclpy.exceptions import InvalidParameterValueException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import FluidPressure, JointState
from std_srvs.srv import Trigger
import yaml

from softseq_ros.nodes.actuator import ActuatorNode
from softseq_ros.nodes.camera import CameraNode
from softseq_ros.nodes.common import TOPICS, stamp_ns
from softseq_ros.nodes.sim_clock import SimClockNode
from softseq_ros.nodes.syringe_pump import SyringePumpNode
from softseq_ros.physics.equilibrium import EquilibriumMap, Tracker
from softseq_ros.physics.kinematics import backbone_batch
from softseq_ros.physics.render import SEGMENT_RGB, SideViewRenderer
from softseq_ros.physics.scene import load_scene

TIMEOUT_S = 15.0
AMBIENT = 101325.0

# Linear bottom and a neo-Hookean balloon top (the symmetric case of Fig. 1): the top passes its
# pressure peak at about 20 mL injected and then takes the bottom's fluid, so the path is
# strongly nonlinear. The pump runs 0 -> 30 mL -> 0 at 20 mL/s (3 s).
FAST_SCENE = {
    'name': 'fast_symmetric',
    'segments': [
        {'name': 'bottom', 'length_m': 0.111,
         'linear': {'rest_volume_m3': 1.0e-5, 'stiffness_pa_per_m3': 5.0e+8,
                    'max_volume_m3': 4.0e-5, 'curvature_per_m_per_m3': 8.0e+5}},
        {'name': 'top', 'length_m': 0.111,
         'balloon': {'material': {'law': 'neo_hookean', 'shear_modulus_pa': 34.0e+3},
                     'radius_m': 0.010, 'thickness_m': 2.0e-3, 'max_stretch': 2.6,
                     'curvature_per_m_per_m3': 4.0e+5}},
    ],
    'pump': {'flow_rate_m3_per_s': 2.0e-5, 'rate_hz': 100,
             'legs': [{'inflate_to_m3': 3.0e-5}, {'deflate_to_m3': 0.0}]},
    'camera': {'rate_hz': 20, 'trigger_injected_m3': [1.0e-5, 2.5e-5]},
    'outputs': ['pressure', 'volumes', 'curvature', 'poses', 'markers', 'image', 'events'],
}

pytestmark = pytest.mark.ros


def write_scene(folder, **changes) -> str:
    """Write FAST_SCENE (with top-level or pump changes) as YAML; return its path."""
    scene = json.loads(json.dumps(FAST_SCENE))
    for key, value in changes.items():
        if key in ('legs', 'flow_rate_m3_per_s', 'rate_hz'):
            scene['pump'][key] = value
        else:
            scene[key] = value
    path = folder / f'{scene["name"]}.yaml'
    path.write_text(yaml.safe_dump(scene), encoding='utf-8')
    return str(path)


def wait_for(condition, what: str, timeout: float = TIMEOUT_S) -> None:
    """Poll ``condition`` until true; fail naming ``what`` after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f'timed out waiting for {what}')
        time.sleep(0.01)


@contextmanager
def spinning(context, *nodes):
    """Spin ``nodes`` on a SingleThreadedExecutor in a thread; shut down, join, destroy."""
    executor = SingleThreadedExecutor(context=context)
    for node in nodes:
        executor.add_node(node)

    def spin() -> None:
        try:
            executor.spin()
        except ExternalShutdownException:
            pass

    thread = threading.Thread(target=spin, daemon=True)
    thread.start()
    try:
        yield executor
    finally:
        # Order matters: a node destroyed (or a context shut down) while the executor thread
        # still waits on it can abort the process. Stop the executor, join, then destroy.
        executor.shutdown(timeout_sec=10.0)
        thread.join(timeout=10.0)
        for node in nodes:
            node.destroy_node()


class Collector(Node):
    """Subscribes to rig topics with their contract QoS (deeper queues) and keeps everything."""

    def __init__(self, topics, context) -> None:
        super().__init__('collector', context=context)
        self.received = {topic: [] for topic in topics}
        self.subscriptions_by_topic = {}
        for topic in topics:
            spec = TOPICS[topic]
            qos = QoSProfile(depth=1000, reliability=spec.qos.reliability,
                             durability=spec.qos.durability)
            self.subscriptions_by_topic[topic] = self.create_subscription(
                spec.msg_type, topic, self.received[topic].append, qos)

    def matched(self, topic: str) -> bool:
        return self.subscriptions_by_topic[topic].get_publisher_count() > 0

    def unsubscribe(self, topic: str) -> None:
        self.destroy_subscription(self.subscriptions_by_topic.pop(topic))


def call_trigger(node: Node, service: str) -> Trigger.Response:
    """Call a std_srvs/Trigger service from a node that an executor is spinning."""
    client = node.create_client(Trigger, service)
    try:
        assert client.wait_for_service(timeout_sec=TIMEOUT_S), f'{service} not available'
        future = client.call_async(Trigger.Request())
        wait_for(future.done, f'the answer of {service}')
        return future.result()
    finally:
        node.destroy_client(client)


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
    for name, messages in (('volumes', volumes), ('pressure', pressures),
                           ('curvatures', curvatures)):
        rows, _ = paired(messages)
        assert np.sum(injected[rows] > 0.0) >= 0.9 * moving > 50, \
            f'only {len(rows)} {name} outputs answer the {len(injected)} commands received'
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
    topics = ['/pump/command', '/pump/status', '/actuator/pressure', '/actuator/volumes',
              '/actuator/curvatures', '/actuator/events', '/camera/backbone',
              '/camera/snapshots', '/camera/markers']
    collector = Collector(topics, context)
    got = collector.received
    with spinning(context, pump, actuator, camera, collector):
        wait_for(lambda: all(collector.matched(t) for t in topics), 'all topics matched')
        wait_for(lambda: pump._rig_publishers['/pump/command'].get_subscription_count() == 2,
                 'the actuator and the test on /pump/command')
        wait_for(lambda: not actuator._resuming, 'the actuator to finish its resume wait')
        response = call_trigger(collector, '/syringe_pump/start')
        assert response.success, response.message
        wait_for(lambda: any(m.data == 'finished' for m in got['/pump/status']),
                 'the programme to finish')
        n_commands = len(got['/pump/command'])
        wait_for(lambda: len(got['/actuator/curvatures']) >= n_commands - 5,
                 'the actuator outputs of every command')
        assert [m.data for m in got['/pump/status']][-3:] == ['idle', 'running', 'finished']
        assert camera.images_rendered == 0, 'an image was rendered with nobody subscribed'

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
        # Two triggers, each crossed up and down.
        assert len(got['/camera/snapshots']) == 4
        markers = got['/camera/markers'][-1].markers
        assert [m.type for m in markers] == [4, 4]          # LINE_STRIP per segment
        assert len(markers[0].points) == scene.camera.points_per_segment + 1

        # The image is rendered only while someone subscribes.
        images = []
        subscription = collector.create_subscription(
            TOPICS['/camera/image'].msg_type, '/camera/image', images.append,
            TOPICS['/camera/image'].qos)
        wait_for(lambda: len(images) >= 2, 'camera images')
        image = images[-1]
        assert (image.encoding, image.width, image.height, image.step) == (
            'rgb8', 640, 480, 3 * 640)
        pixels = np.frombuffer(bytes(image.data), np.uint8).reshape(480, 640, 3)
        for colour in SEGMENT_RGB[:2]:
            assert np.all(pixels == colour, axis=2).sum() > 100
        collector.destroy_subscription(subscription)
        image_publisher = camera._rig_publishers['/camera/image']
        wait_for(lambda: image_publisher.get_subscription_count() == 0, 'the image unsubscribe')
        # A frame in progress may still have seen the subscriber: count from the next one.
        frames = len(got['/camera/backbone'])
        wait_for(lambda: len(got['/camera/backbone']) > frames, 'one more frame')
        rendered = camera.images_rendered
        frames = len(got['/camera/backbone'])
        wait_for(lambda: len(got['/camera/backbone']) >= frames + 3, 'three more frames')
        assert camera.images_rendered == rendered


# ------------------------------------------------------------------------- batch-mode hooks

class Clock:
    """A settable time source for the batch hooks (nanoseconds)."""

    def __init__(self) -> None:
        self.ns = 0

    def __call__(self) -> int:
        return self.ns

    def set_s(self, seconds: float) -> None:
        self.ns = int(round(seconds * 1e9))


def command(volume, names=('syringe',)) -> JointState:
    return JointState(name=list(names), position=[volume] * max(1, len(names)))


def test_actuator_refuses_garbage_and_keeps_its_state(context, tmp_path):
    sent = []
    actuator = ActuatorNode(context=context, emit=lambda t, m: sent.append((t, m)),
                            now=Clock(),
                            parameter_overrides=[Parameter('scene', value=write_scene(tmp_path))])
    warnings = []
    actuator.log_warning = warnings.append
    try:
        garbage = [command(math.nan), command(math.inf), command(-1.0e-6),
                   command(1.0e-5, names=('syringe', 'other')), command(1.0e-5, names=('x',)),
                   JointState(name=['syringe'], position=[]), command(1.0)]
        actuator.on_pump_command(command(1.0e-5))
        before = (actuator.tracker.branch, actuator.tracker.total)
        for msg in garbage:
            actuator.on_pump_command(msg)
            assert (actuator.tracker.branch, actuator.tracker.total) == before
        assert actuator.rejected_commands == len(garbage)
        assert any('1' in w and 'beyond' in w for w in warnings), warnings
        assert any('not finite' in w for w in warnings)
        # The same refusal within the throttle interval is counted, not repeated.
        for _ in range(5):
            actuator.on_pump_command(command(math.nan))
        assert sum('not finite' in w for w in warnings) == 1

        actuator.on_pump_command(command(2.5e-5))
        volumes = [m for t, m in sent if t == '/actuator/volumes']
        assert len(volumes) == 2
        reference = Tracker(actuator.emap).sweep([1.0e-5, 2.5e-5])
        np.testing.assert_allclose(volumes[-1].position, reference.volumes[-1], rtol=1e-9)
    finally:
        actuator.destroy_node()


def test_actuator_repeats_cached_outputs_without_solving(context, tmp_path):
    clock = Clock()
    sent = []
    actuator = ActuatorNode(context=context, emit=lambda t, m: sent.append(
        (t, m.header.stamp.sec, list(m.position))) if t != '/actuator/pressure' else None,
        now=clock, parameter_overrides=[
            Parameter('scene', value=write_scene(tmp_path)),
            Parameter('outputs', value=['volumes', 'curvature'])])
    try:
        for second, volume in enumerate([2.0e-5, 2.0e-5, 2.0e-5, 2.1e-5]):
            clock.set_s(second)
            actuator.on_pump_command(command(volume))
        assert actuator.solves == 2
        volumes = [s for s in sent if s[0] == '/actuator/volumes']
        assert [s[1] for s in volumes] == [0, 1, 2, 3]          # a fresh stamp every time
        assert volumes[0][2] == volumes[1][2] == volumes[2][2] != volumes[3][2]
        # Only the listed outputs are published.
        assert {s[0] for s in sent} == {'/actuator/volumes', '/actuator/curvatures'}
    finally:
        actuator.destroy_node()


def test_pump_programme_hold_stop_and_safety(context, tmp_path):
    clock = Clock()
    sent = []
    flow = 2.0e-5
    pump = SyringePumpNode(context=context, emit=lambda t, m: sent.append(
        (t, m.data if t == '/pump/status' else (m.position[0], m.velocity[0]))), now=clock,
        parameter_overrides=[Parameter('scene', value=write_scene(tmp_path)),
                             Parameter('autostart', value=False)])

    def tick_at(seconds):
        clock.set_s(seconds)
        pump.tick()
        return sent[-1][1]

    try:
        assert tick_at(0.0) == (0.0, 0.0)                      # idle: nothing moves
        assert tick_at(0.5) == (0.0, 0.0)
        assert pump.start()[0]                                  # run time starts at 0.5 s
        assert tick_at(1.0) == pytest.approx((0.5 * flow, flow), rel=1e-12)
        assert pump.hold()[0]
        assert tick_at(3.0) == pytest.approx((0.5 * flow, 0.0), rel=1e-12)
        assert pump.start()[0]                                  # 2 s held are not run time
        assert tick_at(3.25) == pytest.approx((0.75 * flow, flow), rel=1e-12)
        # 1.5 s of run time up (until 4.0 s), then down at the same rate.
        assert tick_at(4.5) == pytest.approx((3.0e-5 - 0.5 * flow, -flow), rel=1e-12)
        # Safety: a gauge pressure above the limit stops the pump where it is.
        pump.on_pressure(FluidPressure(fluid_pressure=AMBIENT + 99.0e3))
        assert pump.state == 'running'
        pump.on_pressure(FluidPressure(fluid_pressure=AMBIENT + 101.0e3))
        assert pump.state == 'stopped' and 'max_pressure_pa' in pump.reason
        frozen = tick_at(4.5)[0]
        assert tick_at(9.0) == (frozen, 0.0)
        assert not pump.start()[0]                              # only reset leaves 'stopped'
        assert pump.reset()[0] and tick_at(9.5) == (0.0, 0.0)
        # The volume limit: stop at max_injected_m3 exactly.
        assert pump.set_parameters([Parameter('max_injected_m3', value=1.0e-5)])[0].successful
        pump.start()
        tick_at(9.75)
        assert tick_at(10.25) == (1.0e-5, 0.0)
        assert pump.state == 'stopped' and 'max_injected_m3' in pump.reason
        statuses = [m for t, m in sent if t == '/pump/status']
        assert statuses[:4] == ['idle', 'running', 'held', 'running']
        assert statuses[-1].startswith('stopped: injected volume reached max_injected_m3')
    finally:
        pump.destroy_node()


def test_pump_finishes_at_the_end_of_the_programme(context, tmp_path):
    clock = Clock()
    sent = []
    pump = SyringePumpNode(context=context, emit=lambda t, m: sent.append(t), now=clock,
                           parameter_overrides=[
                               Parameter('scene', value=write_scene(tmp_path)),
                               Parameter('legs', value='[{inflate_to_m3: 1e-5}, {hold_s: 1}]'),
                               Parameter('flow_rate_m3_per_s', value=1.0e-5)])
    try:
        clock.set_s(10.0)
        pump.tick()                                 # autostart at the first tick
        for seconds in (10.5, 11.0, 11.9):
            clock.set_s(seconds)
            pump.tick()
        assert pump.state == 'running'
        assert pump._command.position[0] == pytest.approx(1.0e-5, rel=1e-12)
        clock.set_s(12.0)
        pump.tick()
        assert pump.state == 'finished'
    finally:
        pump.destroy_node()


def test_camera_snapshots_and_seeded_noise(context, tmp_path):
    scene_path = write_scene(tmp_path)
    scene = load_scene(scene_path)
    emap = EquilibriumMap(scene.segments)
    # 60 rows: the triggers (10 and 25 mL) fall between rows, never on one.
    path = Tracker(emap).sweep(np.linspace(0.0, 3.0e-5, 60))

    def run(seed):
        clock = Clock()
        sent = []
        camera = CameraNode(context=context, emit=lambda t, m: sent.append(
            (t, np.array([[p.position.x, p.position.z]
                          for p in deserialize_message(m, PoseArray).poses]))
            if t != '/camera/markers' else None), now=clock,
            parameter_overrides=[Parameter('scene', value=scene_path),
                                 Parameter('noise_std_m', value=1.0e-3),
                                 Parameter('seed', value=seed),
                                 Parameter('outputs', value=['poses'])])
        try:
            for row in range(path.injected.size):
                clock.ns += 10 ** 8
                stamp = clock.ns
                volumes = JointState(name=['bottom', 'top'], position=list(path.volumes[row]))
                curvatures = JointState(name=['bottom', 'top'],
                                        position=list(path.curvatures[row]))
                for msg in (volumes, curvatures):
                    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 10 ** 9)
                # Volumes and curvatures of one command, in either order.
                if row % 2:
                    camera.on_volumes(volumes)
                    camera.on_curvatures(curvatures)
                else:
                    camera.on_curvatures(curvatures)
                    camera.on_volumes(volumes)
                camera.tick()
        finally:
            camera.destroy_node()
        return sent

    first, again, other = run(7), run(7), run(8)
    snapshots = [p for t, p in first if t == '/camera/snapshots']
    assert len(snapshots) == 2                     # 10 mL and 25 mL crossed once each
    assert all(np.array_equal(a[1], b[1]) for a, b in zip(first, again))
    frames = [p for t, p in first if t == '/camera/backbone']
    clean, _ = backbone_batch(path.curvatures, np.array(scene.lengths),
                              scene.camera.points_per_segment)
    errors = np.concatenate([(f - c).ravel() for f, c in zip(frames, clean)])
    assert errors.std() == pytest.approx(1.0e-3, rel=0.1)
    other_frames = [p for t, p in other if t == '/camera/backbone']
    assert not np.array_equal(frames[0], other_frames[0])
    # Snapshot at 10 mL: the state at the first command past the trigger (row 20, 10.2 mL).
    misfit = np.mean((clean - snapshots[0][None]) ** 2, axis=(1, 2))
    assert int(np.argmin(misfit)) == 20


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
        result, = pump.set_parameters([Parameter('flow_rate_m3_per_s', value=1.0e-6)])
        assert not result.successful and 'read-only' in result.reason
        result, = camera.set_parameters([Parameter('noise_std_m', value=-1.0e-3)])
        assert not result.successful and result.reason.startswith('noise_std_m: must be >= 0')
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
    with pytest.raises(InvalidParameterValueException, match=r'legs\[0\]: unknown key'):
        SyringePumpNode(context=context, parameter_overrides=[
            scene, Parameter('legs', value='[{inflate_to_ml: 5}]')])
    with pytest.raises(InvalidParameterValueException, match='seed out of range'):
        CameraNode(context=context, parameter_overrides=[scene, Parameter('seed', value=-1)])


# ------------------------------------------------------------------------- sim clock

def test_sim_clock_runs_speedup_times_wall_time_and_nodes_follow_it(context):
    wall = [5_000_000_000]
    sent = []
    clock = SimClockNode(context=context, wall_ns=lambda: wall[0],
                         emit=lambda t, m: sent.append(m.clock.sec * 10 ** 9 + m.clock.nanosec),
                         parameter_overrides=[Parameter('speedup', value=100),
                                              Parameter('start_s', value=2.0)])
    try:
        wall[0] += 260_000_000           # 0.26 s of wall time: 26 s of sim time
        clock.tick()
        assert sent[-1] == 28_000_000_000
        assert clock.set_parameters([Parameter('speedup', value=10.0)])[0].successful
        wall[0] += 1_000_000_000
        clock.tick()
        assert sent[-1] == 38_000_000_000   # continuous across the change
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
    # Somebody still holds the last /actuator/volumes (transient_local): an actuator that
    # starts now continues on that branch. fig1_asymmetric, inside its hysteresis loop.
    scene = load_scene('fig1_asymmetric')
    emap = EquilibriumMap(scene.segments)
    grid = np.linspace(0.0, 0.98 * emap.injected_range[1], 1001)
    inflating = Tracker(emap).sweep(grid)
    deflating = Tracker(emap, injected=grid[-1], volumes=inflating.volumes[-1]).sweep(
        grid[::-1])
    gap = np.max(np.abs(deflating.volumes[::-1] - inflating.volumes), axis=1)
    row = int(np.argmax(gap))
    assert gap[row] > 1e-3 * emap.v_scale
    held_volumes = deflating.volumes[::-1][row]
    keeper = Node('keeper', context=context)
    spec = TOPICS['/actuator/volumes']
    latched = keeper.create_publisher(spec.msg_type, '/actuator/volumes', spec.qos)
    latched.publish(JointState(name=['bottom', 'top'], position=list(held_volumes)))
    actuator = ActuatorNode(context=context, parameter_overrides=[
        Parameter('scene', value='fig1_asymmetric'), Parameter('resume_timeout_s', value=10.0)])
    with spinning(context, keeper, actuator):
        wait_for(lambda: not actuator._resuming, 'the resume')
        resumed = actuator.tracker.state
    assert resumed.injected == pytest.approx(grid[row], rel=1e-9)
    np.testing.assert_allclose(resumed.volumes, held_volumes, rtol=1e-9,
                               atol=1e-9 * emap.v_scale)
    # Not where a fresh start would have put it.
    assert np.max(np.abs(resumed.volumes - inflating.volumes[row])) > 1e-3 * emap.v_scale


def test_state_triggered_camera_draws_each_state_at_most_at_its_rate(context, tmp_path):
    scene_path = write_scene(tmp_path)
    clock = Clock()
    sent = []
    camera = CameraNode(context=context, emit=lambda t, m: sent.append((t, clock.ns, m)),
                        now=clock,
                        parameter_overrides=[Parameter('scene', value=scene_path),
                                             Parameter('rate_hz', value=10.0),
                                             Parameter('frame_trigger', value='state'),
                                             Parameter('outputs', value=['poses'])])
    try:
        states = []
        # 20 ms apart: a frame at most every half period (50 ms) of the 10 Hz camera.
        for i in range(12):
            clock.ns = 10**9 + 20_000_000 * i
            curvatures = [1.0 + i, -2.0 * i]
            msg = JointState(name=['bottom', 'top'], position=curvatures)
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(clock.ns, 10**9)
            camera.on_curvatures(msg)
            states.append(curvatures)
        camera.tick()  # the frame timer takes no frames in this mode
    finally:
        camera.destroy_node()
    frames = [(now, deserialize_message(m, PoseArray)) for t, now, m in sent
              if t == '/camera/backbone']
    # States 0, 3, 6, 9 (60 ms apart) are drawn at once, stamped when taken.
    assert [now for now, _ in frames] == [10**9 + 20_000_000 * i for i in (0, 3, 6, 9)]
    assert all(stamp_ns(msg.header) == now for now, msg in frames)
    check_poses([msg for _, msg in frames], [states[i] for i in (0, 3, 6, 9)],
                np.array(load_scene(scene_path).lengths),
                load_scene(scene_path).camera.points_per_segment)


def test_camera_refuses_an_unknown_frame_trigger(context, tmp_path):
    with pytest.raises(InvalidParameterValueException, match='must be timer or state'):
        CameraNode(context=context, emit=lambda t, m: None, now=Clock(),
                   parameter_overrides=[Parameter('scene', value=write_scene(tmp_path)),
                                        Parameter('frame_trigger', value='sometimes')])
