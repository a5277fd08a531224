"""
The rig's cores without ROS: pump programme and safety, actuator commands, camera triggers.

The references are independent of the core code: closed forms for the pump programme, the
equilibrium solver run on the same command volumes, and the kinematics module for the poses.
"""

import json
import math
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest
from scenes import FAST_SCENE, inside_the_hysteresis_loop, write_scene

from softseq_ros.quasistatic.equilibrium import EquilibriumMap, Tracker
from softseq_ros.rig.build import SettingError, actuator_core, camera_core, pump_core
from softseq_ros.rig.model import QuasiStaticModel
from softseq_ros.rig.routing import Router
from softseq_ros.scene.loader import load_scene
from softseq_ros.scene.programme import Leg
from softseq_ros.segments.identity import segments_sha256
from softseq_ros.segments.kinematics import backbone_batch
from softseq_ros.wire import contract
from softseq_ros.wire.payloads import InputError, pump_command
from softseq_ros.wire.values import (
    TOPIC_VALUE_TYPES,
    WARNING,
    Backbone,
    Notice,
    PumpCommand,
    PumpStatus,
    SceneIdentity,
    SegmentCurvatures,
    SegmentVolumes,
    Snapshot,
    SnapshotStep,
)

AMBIENT = 101325.0


def command(volume: float, stamp: int = 0) -> PumpCommand:
    return PumpCommand(stamp, volume, 0.0)


def state_at(gauge_pa: float) -> SegmentVolumes:
    """An actuator state with the gauge pressure ``gauge_pa`` (what the pump listens to)."""
    return SegmentVolumes(0, ('bottom', 'top'), [1e-5, 1e-5], gauge_pa)


def topic_values(outputs, kind):
    return [value for value in outputs if type(value) is kind]


# ------------------------------------------------------------------------- contract

def test_contract_names_are_relative_and_every_consumed_topic_reaches_a_handler():
    for topic in contract.RIG_TOPICS:
        assert not topic.name.startswith('/'), topic.name
        # Every topic comes from a rig core, or from a controller outside the rig.
        assert topic.producer in contract.NODE_NAMES or topic.producer == contract.CONTROLLER
        assert topic.output is None or topic.output in contract.OUTPUT_NAMES \
            or contract.DERIVED_OUTPUTS.get(topic.output) in contract.OUTPUT_NAMES
    # Every topic has exactly one value type, and every consumed topic's value type is one
    # that the consuming core's handle takes (it would otherwise be silently dropped).
    assert sorted(kind.topic.name for kind in TOPIC_VALUE_TYPES) == \
        sorted(topic.name for topic in contract.RIG_TOPICS)
    assert {t.name for t in contract.consumed_by(contract.ACTUATOR)} == {'pump/command'}
    # The pump's relief reads the gauge pressure the actuator computed (no ambient of its own).
    # Its setpoints come from a controller.
    assert {t.name for t in contract.consumed_by(contract.PUMP)} == {'actuator/volumes',
                                                                   'pump/setpoint'}
    assert {t.name for t in contract.consumed_by(contract.CAMERA)} == {
        'actuator/volumes', 'actuator/curvatures'}
    # Every output a scene may list switches some topic on.
    assert {t.output for t in contract.RIG_TOPICS} - {None} == \
        set(contract.OUTPUT_NAMES) | set(contract.DERIVED_OUTPUTS)
    assert contract.resolve('pump/command', '/rig2') == '/rig2/pump/command'
    assert contract.resolve('pump/command') == '/pump/command'
    assert contract.relative_name('/rig2/pump/command', '/rig2') == 'pump/command'
    assert contract.find_namespaces(['/rig2/pump/command', '/pump/command', '/x/other']) == [
        '/', '/rig2']


def test_the_batch_runner_and_the_cores_run_without_rclpy():
    # A fresh interpreter in which rclpy cannot be imported.
    code = ('import sys; sys.modules["rclpy"] = None; '
            'import softseq_ros.batch, softseq_ros.rig.build, softseq_ros.wire.payloads; '
            'print("ok")')
    result = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 0 and result.stdout.strip() == 'ok', result.stderr


# ------------------------------------------------------------------------- pump

def test_pump_programme_hold_stop_and_safety(tmp_path):
    flow = 2.0e-5
    pump, rate = pump_core(load_scene(write_scene(tmp_path)), autostart=False, open_loop=True)
    assert rate == 100.0
    statuses = [v.state for v in topic_values(pump.begin(0), PumpStatus)]
    last = []

    def tick_at(seconds):
        """The command in force after a tick (a pump at rest may only repeat it later)."""
        outputs = pump.tick(int(round(seconds * 1e9)))
        statuses.extend(v.state for v in topic_values(outputs, PumpStatus))
        last.extend(topic_values(outputs, PumpCommand))
        return last[-1].injected_m3, last[-1].flow_m3_per_s

    def request(reply):
        statuses.extend(v.state for v in topic_values(reply.outputs, PumpStatus))
        return reply.success

    assert tick_at(0.0) == (0.0, 0.0)                      # idle: nothing moves
    assert tick_at(0.5) == (0.0, 0.0)
    assert request(pump.start(500_000_000))                # run time starts at 0.5 s
    assert tick_at(1.0) == pytest.approx((0.5 * flow, flow), rel=1e-12)
    assert request(pump.hold(1_000_000_000))
    assert tick_at(3.0) == pytest.approx((0.5 * flow, 0.0), rel=1e-12)
    assert request(pump.start(3_000_000_000))              # 2 s held are not run time
    assert tick_at(3.25) == pytest.approx((0.75 * flow, flow), rel=1e-12)
    # 1.5 s of run time up (until 4.0 s), then down at the same rate.
    assert tick_at(4.5) == pytest.approx((3.0e-5 - 0.5 * flow, -flow), rel=1e-12)
    # Safety: a gauge pressure above the limit stops the pump where it is.
    limit = pump.max_pressure_pa
    assert pump.handle(state_at(0.99 * limit), 4_500_000_000) == []
    assert pump.state == 'running'
    stopped = pump.handle(state_at(1.01 * limit), 4_500_000_000)
    assert pump.state == 'stopped' and 'max_pressure_pa' in pump.reason
    warning, status = stopped
    assert warning.level == WARNING and status.state == 'stopped'
    statuses.append(status.state)
    frozen = tick_at(4.5)[0]
    assert tick_at(9.0) == (frozen, 0.0)
    assert not request(pump.start(9_000_000_000))          # only reset leaves 'stopped'
    assert request(pump.reset(9_000_000_000)) and tick_at(9.5) == (0.0, 0.0)
    # The volume limit: stop at max_injected_m3 exactly.
    pump.max_injected_m3 = 1.0e-5
    request(pump.start(9_500_000_000))
    tick_at(9.75)
    assert tick_at(10.25) == (1.0e-5, 0.0)
    assert pump.state == 'stopped' and 'max_injected_m3' in pump.reason
    assert statuses[:5] == ['idle', 'running', 'held', 'running', 'stopped']
    assert statuses[-1] == 'stopped'


def test_pump_starts_by_itself_and_finishes_at_the_end_of_the_programme(tmp_path):
    scene = load_scene(write_scene(tmp_path))
    pump, _ = pump_core(scene, legs=(Leg.inflate(1.0e-5), Leg.hold(1.0)),
                        flow_rate_m3_per_s=1.0e-5)
    first = pump.tick(10 * 10**9)                 # autostart at the first tick
    assert [v.state for v in topic_values(first, PumpStatus)] == ['running']
    for seconds in (10.5, 11.0, 11.9):
        outputs = pump.tick(int(seconds * 1e9))
    assert pump.state == 'running'
    assert topic_values(outputs, PumpCommand)[0].injected_m3 == pytest.approx(1.0e-5,
                                                                              rel=1e-12)
    finished = pump.tick(12 * 10**9)
    assert pump.state == 'finished'
    status, = topic_values(finished, PumpStatus)
    assert status.state == 'finished' and status.stamp_ns == 12 * 10**9


def test_pump_holds_when_the_actuator_falls_silent_and_goes_on_only_when_asked(tmp_path):
    scene = load_scene(write_scene(tmp_path))
    wall = [0]
    # 0 -> 30 mL in 1.5 s, then a long hold.
    legs = (Leg.inflate(3.0e-5), Leg.hold(100.0))
    pump, _ = pump_core(scene, legs=legs, feedback_timeout_s=2.0,
                        feedback_clock=lambda: wall[0])

    def tick(seconds, answer=True):
        wall[0] = int(seconds * 1e9)
        outputs = pump.tick(wall[0])
        if answer:
            # The actuator's answer carries the stamp of the command it answers.
            pump.handle(SegmentVolumes(wall[0], ('bottom', 'top'), [1e-5, 1e-5], 5.0e3),
                        wall[0])
        return outputs

    tick(0.0)
    assert pump.state == 'running'
    for second in (0.5, 1.0, 1.5, 2.5, 3.0):      # answered: keeps running
        tick(second)
    assert pump.state == 'running'
    volumes = [topic_values(tick(3.0 + 0.5 * i, answer=False), PumpCommand)[0].injected_m3
               for i in range(1, 5)]
    assert pump.state == 'running'                 # 2 s of silence is the limit, not more
    held = tick(5.5, answer=False)
    status, = topic_values(held, PumpStatus)
    assert status.state == 'held' and 'no pressure from the actuator for 2 s' in status.reason
    assert [n.level for n in held if type(n) is Notice] == [WARNING]
    # Held: the volume stays where it was, with no flow, even when the actuator is back
    # (said again by the heartbeat, a second after the hold).
    assert topic_values(tick(6.0), PumpCommand) == []
    command, = topic_values(tick(6.5), PumpCommand)
    assert command.flow_m3_per_s == 0.0 and command.injected_m3 >= volumes[-1]
    assert pump.state == 'held'
    assert pump.start(int(6.5e9)).success and pump.state == 'running'
    tick(7.0)
    assert pump.state == 'running'
    # Open loop (no actuator at all): never holds for want of feedback.
    free, _ = pump_core(scene, legs=legs, open_loop=True, feedback_clock=lambda: wall[0])
    for second in range(0, 60, 5):
        wall[0] = second * 10**9
        free.tick(wall[0])
    assert free.state == 'running'


def test_a_pump_at_rest_repeats_its_command_once_a_second_and_says_every_change_at_once(
        tmp_path):
    pump, _ = pump_core(load_scene(write_scene(tmp_path)), autostart=False, open_loop=True)
    pump.begin(0)

    def commands(seconds):
        return topic_values(pump.tick(int(round(seconds * 1e9))), PumpCommand)

    # Idle: the first tick says where it is (twice: a new volume), then once a second
    # (HEARTBEAT_S), not at 100 Hz.
    assert [len(commands(0.01 * k)) for k in range(0, 2)] == [1, 1]
    assert [len(commands(0.01 * k)) for k in range(2, 101)] == [0] * 99
    assert len(commands(1.01)) == 1
    # Running: every tick.
    pump.start(int(1.01e9))
    assert [len(commands(1.01 + 0.01 * k)) for k in range(1, 50)] == [1] * 49
    # Held between two ticks: the next says the new volume, and once more, then the heartbeat.
    pump.hold(int(1.505e9))
    assert [len(commands(1.51 + 0.01 * k)) for k in range(0, 2)] == [1, 1]
    assert [len(commands(1.51 + 0.01 * k)) for k in range(2, 101)] == [0] * 99
    assert len(commands(2.52)) == 1


def test_core_settings_are_checked_with_their_names(tmp_path):
    scene = load_scene(write_scene(tmp_path))
    with pytest.raises(SettingError, match='pump: unknown setting'):
        pump_core(scene, rate=5)
    with pytest.raises(SettingError, match='cycles'):
        pump_core(scene, cycles=0)
    with pytest.raises(SettingError, match='frame_trigger must be timer or state'):
        camera_core(scene, frame_trigger='sometimes')


# ------------------------------------------------------------------------- actuator

def test_actuator_refuses_garbage_and_keeps_its_state(tmp_path):
    actuator = actuator_core(load_scene(write_scene(tmp_path)))
    actuator.handle(command(1.0e-5), 0)
    before = (actuator.model.tracker.branch, actuator.model.tracker.total)
    warnings = []
    for value in (command(math.nan), command(math.inf), command(-1.0e-6), command(1.0)):
        warnings += [n.text for n in actuator.handle(value, 0) if type(n) is Notice]
        assert (actuator.model.tracker.branch, actuator.model.tracker.total) == before
    assert actuator.rejected_commands == 4
    assert any('1' in w and 'beyond' in w for w in warnings), warnings
    assert any('not finite' in w for w in warnings) and any('negative' in w for w in warnings)
    # The same refusal within the throttle interval is counted, not repeated.
    repeated = [n for _ in range(5) for n in actuator.handle(command(math.nan), 0)]
    assert repeated == []
    assert actuator.rejected_commands == 9
    # Messages that are no pump command at all are refused when they are read.

    class Msg:
        def __init__(self, names, position):
            self.name, self.position, self.velocity = names, position, []
            self.header = type('H', (), {'stamp': type('S', (), {'sec': 0, 'nanosec': 0})})

    for names, position, key in ((['syringe', 'other'], [1e-5, 1e-5], 'shape'),
                                 (['x'], [1e-5], 'name'), (['syringe'], [], 'shape')):
        with pytest.raises(InputError) as refused:
            pump_command(Msg(names, position))
        assert refused.value.key == key
    outputs = actuator.handle(command(2.5e-5), 0)
    volumes, = topic_values(outputs, SegmentVolumes)
    reference = Tracker(actuator.model.emap).sweep([1.0e-5, 2.5e-5])
    np.testing.assert_allclose(volumes.volumes_m3, reference.volumes[-1], rtol=1e-9)


def test_actuator_repeats_its_outputs_without_solving_and_stamps_them(tmp_path):
    actuator = actuator_core(load_scene(write_scene(tmp_path)),
                             outputs=frozenset({'volumes', 'curvature'}))
    sent = []
    for second, volume in enumerate([2.0e-5, 2.0e-5, 2.0e-5, 2.1e-5]):
        sent += actuator.handle(command(volume, second * 10**9), 0)
    assert actuator.model.solves == 2
    volumes = topic_values(sent, SegmentVolumes)
    assert [v.stamp_ns for v in volumes] == [0, 10**9, 2 * 10**9, 3 * 10**9]
    assert volumes[0].volumes_m3 == volumes[1].volumes_m3 == volumes[2].volumes_m3
    assert volumes[2].volumes_m3 != volumes[3].volumes_m3
    # Only the listed outputs are given.
    assert {type(v) for v in sent} == {SegmentVolumes, SegmentCurvatures}


def test_actuator_names_its_scene_once_at_start_whatever_its_outputs(tmp_path):
    scene = load_scene(write_scene(tmp_path))
    actuator = actuator_core(scene, outputs=frozenset({'volumes'}))
    identity, = actuator.begin(7)
    assert identity == SceneIdentity(7, 'fast_symmetric', ('bottom', 'top'),
                                     segments_sha256(scene.segments))
    # Commands never repeat it: it is said once, on a latched topic.
    assert not topic_values(actuator.handle(command(1.0e-5), 8), SceneIdentity)


def test_actuator_buffers_commands_while_it_waits_for_a_previous_state(tmp_path):
    scene = load_scene('fig1_asymmetric')
    emap = EquilibriumMap(scene.segments)
    middle, inflating, held = inside_the_hysteresis_loop(emap, 401)
    grid = np.linspace(0.0, 0.98 * emap.injected_range[1], 401)
    row = int(np.argmin(np.abs(grid - middle)))
    state_file = tmp_path / 'state.json'
    first = actuator_core(scene, QuasiStaticModel(emap, scene.segment_names),
                          state_file=str(state_file))
    for volume in list(grid) + list(grid[::-1][:len(grid) - row]):
        first.handle(command(float(volume)), 0)
    # The newest state, written at once or at the driver's next flush (0.1 s in the node).
    first.flush_state()
    assert json.loads(state_file.read_text())['volumes_m3'] == pytest.approx(list(held),
                                                                              rel=1e-9)
    second = actuator_core(scene, QuasiStaticModel(emap, scene.segment_names),
                           state_file=str(state_file))
    second.begin_wait()
    assert second.handle(command(float(grid[row])), 0) == []
    resumed, notices = second.resume_from_file()
    assert resumed and 'resumed from state_file' in notices[0].text
    answered = topic_values(second.end_wait(0), SegmentVolumes)
    assert len(answered) == 1
    np.testing.assert_allclose(answered[0].volumes_m3, held, rtol=1e-9,
                               atol=1e-9 * emap.v_scale)
    # A fresh start would sit on the other branch: the history matters.
    assert np.max(np.abs(np.array(answered[0].volumes_m3) - inflating)) > 1e-3 * emap.v_scale
    wrong, notices = second.resume_from(['a', 'b'], [1e-6, 1e-6], 'a test')
    assert not wrong and 'does not fit this scene' in notices[0].text
    # The same segment names with other curves (a scene changed between runs): at rest.
    other = load_scene('fig1_symmetric')
    assert other.segment_names == scene.segment_names
    third = actuator_core(other, state_file=str(state_file))
    resumed, notices = third.resume_from_file()
    assert not resumed and 'written for other segments' in notices[0].text
    assert third.model.tracker.state.injected == 0.0


# ------------------------------------------------------------------------- camera

def _feed_camera(camera, path, order_flips=True):
    out = []
    for row in range(path.injected.size):
        stamp = (row + 1) * 10**8
        volumes = SegmentVolumes(stamp, ('bottom', 'top'), list(path.volumes[row]),
                                 float(path.pressure[row]))
        curvatures = SegmentCurvatures(stamp, ('bottom', 'top'), list(path.curvatures[row]))
        # Volumes and curvatures of one command, in either order.
        pair = (volumes, curvatures) if row % 2 or not order_flips else (curvatures, volumes)
        for value in pair:
            out += camera.handle(value, stamp)
        out += camera.tick(stamp)
    return out


def test_camera_snapshots_say_their_step_and_noise_is_seeded(tmp_path):
    scene_path = write_scene(tmp_path)
    scene = load_scene(scene_path)
    emap = EquilibriumMap(scene.segments)
    # 60 rows up and 60 down: the triggers (10 and 25 mL) fall between rows, never on one.
    up = np.linspace(0.0, 3.0e-5, 60)
    path = Tracker(emap).sweep(np.concatenate([up, up[::-1]]))

    def run(seed):
        camera = camera_core(scene, noise_std_m=1.0e-3, seed=seed,
                             outputs=frozenset({'poses'}))
        return _feed_camera(camera, path)

    first, again, other = run(7), run(7), run(8)
    snapshots = topic_values(first, Snapshot)
    steps = topic_values(first, SnapshotStep)
    assert [(s.step, s.direction) for s in steps] == [
        (1, 'inflation'), (2, 'inflation'), (2, 'deflation'), (1, 'deflation')]
    assert [s.trigger_injected_m3 for s in steps] == [1.0e-5, 2.5e-5, 2.5e-5, 1.0e-5]
    assert [s.stamp_ns for s in steps] == [s.stamp_ns for s in snapshots]
    # Each step's state is the first command past its trigger.
    for step in steps:
        row = step.stamp_ns // 10**8 - 1
        assert step.injected_m3 == pytest.approx(path.injected[row], abs=1e-9 * emap.v_scale)
        previous = path.injected[row - 1]
        assert (previous - step.trigger_injected_m3) * (path.injected[row]
                                                        - step.trigger_injected_m3) <= 0
    frames = [v.poses for v in topic_values(first, Backbone)]
    assert all(np.array_equal(a.poses, b.poses) for a, b in zip(
        topic_values(first, Backbone), topic_values(again, Backbone)))
    assert not np.array_equal(frames[0], topic_values(other, Backbone)[0].poses)
    clean, _ = backbone_batch(path.curvatures, np.array(scene.lengths),
                              scene.camera.points_per_segment)
    errors = np.concatenate([(f[:, [0, 2]] - c).ravel() for f, c in zip(frames, clean)])
    assert errors.std() == pytest.approx(1.0e-3, rel=0.1)
    # Snapshot at 10 mL: the state at the first command past the trigger (row 20, 10.2 mL).
    misfit = np.mean((clean - snapshots[0].poses[None, :, [0, 2]]) ** 2, axis=(1, 2))
    assert int(np.argmin(misfit)) == 20


@pytest.mark.parametrize('ulps', [-4, 4])
def test_camera_snapshots_a_state_that_lands_on_its_trigger_whatever_its_round_off(tmp_path,
                                                                                    ulps):
    """
    A pump stepping exactly onto a trigger: the snapshot is at that step on the way up, and at
    the step after it on the way down, whether the segments' volumes sum to a few ulps above
    or below the trigger.
    """
    scene = load_scene(write_scene(tmp_path))
    emap = EquilibriumMap(scene.segments)
    up = np.linspace(0.0, 3.0e-5, 31)
    up[10], up[25] = 1.0e-5, 2.5e-5          # the scene's triggers, exactly
    commanded = np.concatenate([up, up[::-1]])
    path = Tracker(emap).sweep(commanded)
    volumes = path.volumes.copy()
    rest = sum(s.rest_volume for s in scene.segments)
    for row in np.flatnonzero(np.isin(commanded, [1.0e-5, 2.5e-5])):
        # The sum of the volumes this many ulps off the trigger, the first segment taking it.
        target = commanded[row] + rest
        while (volumes[row].sum() - target) * np.sign(ulps) < 4 * abs(ulps) * np.spacing(target):
            volumes[row, 0] = np.nextafter(volumes[row, 0], np.sign(ulps) * np.inf)
        while (volumes[row].sum() - target) * np.sign(ulps) > 4 * abs(ulps) * np.spacing(target):
            volumes[row, 0] = np.nextafter(volumes[row, 0], -np.sign(ulps) * np.inf)
        assert 0.0 < (volumes[row].sum() - target) * np.sign(ulps) < 1e-12 * target
    nudged = SimpleNamespace(injected=path.injected, volumes=volumes, pressure=path.pressure,
                             curvatures=path.curvatures)
    steps = topic_values(_feed_camera(camera_core(scene, outputs=frozenset({'poses'})), nudged),
                         SnapshotStep)
    # On the way up, the row the pump puts on the trigger; on the way down, the next one.
    expected = [int(np.flatnonzero(commanded == 1.0e-5)[0]),
                int(np.flatnonzero(commanded == 2.5e-5)[0]),
                int(np.flatnonzero(commanded == 2.5e-5)[1]) + 1,
                int(np.flatnonzero(commanded == 1.0e-5)[1]) + 1]
    assert [(s.step, s.direction) for s in steps] == [
        (1, 'inflation'), (2, 'inflation'), (2, 'deflation'), (1, 'deflation')]
    assert [s.stamp_ns // 10**8 - 1 for s in steps] == expected


def test_state_triggered_camera_draws_each_state_at_most_at_its_rate(tmp_path):
    scene = load_scene(write_scene(tmp_path))
    camera = camera_core(scene, rate_hz=10.0, frame_trigger='state',
                         outputs=frozenset({'poses'}))
    frames, states = [], []
    # 20 ms apart: a frame at most every half period (50 ms) of the 10 Hz camera.
    for i in range(12):
        now = 10**9 + 20_000_000 * i
        curvatures = [1.0 + i, -2.0 * i]
        frames += topic_values(camera.handle(SegmentCurvatures(now, ('bottom', 'top'),
                                                               curvatures), now), Backbone)
        states.append(curvatures)
    assert camera.tick(2 * 10**9) == []        # the frame timer takes no frames in this mode
    # States 0, 3, 6, 9 (60 ms apart) are drawn at once, stamped when taken.
    assert [f.stamp_ns for f in frames] == [10**9 + 20_000_000 * i for i in (0, 3, 6, 9)]
    points, _ = backbone_batch(np.array([states[i] for i in (0, 3, 6, 9)]),
                               np.array(scene.lengths), scene.camera.points_per_segment)
    for frame, expected in zip(frames, points):
        np.testing.assert_allclose(frame.poses[:, [0, 2]], expected, atol=1e-15)


def test_camera_warns_about_unusable_states_and_keeps_the_last_good_one(tmp_path):
    scene = load_scene(write_scene(tmp_path))
    camera = camera_core(scene, outputs=frozenset({'poses'}))
    camera.handle(SegmentCurvatures(1, ('bottom', 'top'), [1.0, 2.0]), 1)
    bad = camera.handle(SegmentCurvatures(2, ('bottom',), [math.nan]), 2)
    assert [n.level for n in bad] == [WARNING] and "joints ['bottom'] are not the " \
        "segments ['bottom', 'top']" in bad[0].text
    # Another actuator's joints, or a NaN, are no state of these segments either (each
    # counted; the warning is said once per kind every 2 s).
    camera.handle(SegmentCurvatures(2, ('left', 'right'), [3.0, 4.0]), 2)
    camera.handle(SegmentCurvatures(2, ('bottom', 'top'), [math.nan, 4.0]), 2)
    camera.handle(SegmentVolumes(2, ('a', 'b'), [1.0e-5, 1.0e-5], 0.0), 2)
    assert camera.refused_states == 4
    frame, = topic_values(camera.tick(3), Backbone)
    points, _ = backbone_batch(np.array([[1.0, 2.0]]), np.array(scene.lengths),
                               scene.camera.points_per_segment)
    np.testing.assert_allclose(frame.poses[:, [0, 2]], points[0], atol=1e-15)


# ------------------------------------------------------------------------- routing

def test_router_hands_values_to_consumers_first_in_first_out(tmp_path):
    scene = load_scene(write_scene(tmp_path))
    pump, _ = pump_core(scene, max_pressure_pa=1.0)
    actuator = actuator_core(scene)
    camera = camera_core(scene, frame_trigger='state', rate_hz=1000.0)
    now = [10**9]
    router = Router({'pump': pump, 'actuator': actuator, 'camera': camera}, lambda: now[0])
    router.run(pump.tick(now[0]))
    now[0] = 2 * 10**9
    produced = router.run(pump.tick(now[0]))
    kinds = [type(v).__name__ for v in produced if type(v) is not Notice]
    # The command, the actuator's answer to it, then what its consumers made of that: the
    # pump stops on the pressure (limit 1 Pa), the camera takes a frame of the state.
    assert kinds[:4] == ['PumpCommand', 'Pressure', 'SegmentVolumes', 'SegmentCurvatures']
    assert 'PumpStatus' in kinds[4:] and 'Backbone' in kinds[4:]
    assert kinds.index('PumpStatus') < kinds.index('Backbone')
    assert pump.state == 'stopped'
    assert FAST_SCENE['name'] == scene.name
