"""
The rig's nodes as separate processes, started the way a user starts them (console scripts).

Each node runs from the venv's bin/ with ``--ros-args -p ...`` and the whole environment of this
test (the ROS wheels need it, and it carries this run's ROS_DOMAIN_ID). The test subscribes over
DDS and checks the outputs against the equilibrium solver run on the commands it received.
"""

from contextlib import contextmanager
import json
import os
from pathlib import Path
import select
import signal
import subprocess
import sys
import time

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
import pytest
from rclpy.node import Node
from rclpy.qos import QoSProfile
from test_nodes import (
    check_against_solver,
    check_poses,
    status_history,
    status_states,
    write_scene,
)
import yaml

from softseq_ros.analysis.recording import load_recording
from softseq_ros.analysis.report import write_report
from softseq_ros.nodes.recorder import Recorder
from softseq_ros.quasistatic.equilibrium import EquilibriumMap, Tracker
from softseq_ros.scene.loader import load_scene
from softseq_ros.scene.paths import config_dir
from softseq_ros.testing import Collector, call_trigger, spinning, wait_for

pytestmark = pytest.mark.ros

# Starting a node imports rclpy, numpy and scipy and assembles the equilibrium map: seconds,
# and more on a loaded machine.
STARTUP_TIMEOUT_S = 60.0


@contextmanager
def node_processes(env, log_dir: Path):
    """Start console-script nodes with start(name, script, **params); kill them all at the end."""
    started = []

    def start(name: str, script: str, **params) -> subprocess.Popen:
        args = [os.path.join(sys.prefix, 'bin', script), '--ros-args']
        for key, value in params.items():
            args += ['-p', f'{key}:={value}']
        log = open(log_dir / f'{name}.log', 'ab')
        process = subprocess.Popen(args, env=env, stdout=log, stderr=subprocess.STDOUT)
        log.close()
        started.append(process)
        return process

    try:
        yield start
    except BaseException:
        # What the nodes said is the first thing a failure needs; their logs go with the tmp dir.
        for log in sorted(log_dir.glob('*.log')):
            lines = log.read_text(encoding='utf-8', errors='replace').splitlines()
            print(f'--- {log.name} (last 40 lines) ---', *lines[-40:], sep='\n')
        raise
    finally:
        for process in started:
            if process.poll() is None:
                process.send_signal(signal.SIGINT)
        for process in started:
            try:
                process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()


# The 3 s programme, with room for a loaded machine (two test workers and four processes).
PROGRAMME_TIMEOUT_S = 60.0
# The pump holds when the actuator has not answered for this long. On a loaded machine a node
# process can stall for seconds; these tests are about the outputs, not about a dead actuator
# (test_pump_feedback holds the pump to its default timeout).
PATIENT_FEEDBACK_TIMEOUT_S = 30.0


def _log_tails(log_dir: Path, lines: int = 5) -> str:
    """The last lines of every node log in ``log_dir``, for a failure message."""
    tails = []
    for log in sorted(log_dir.glob('*.log')):
        text = log.read_text(encoding='utf-8', errors='replace').splitlines()[-lines:]
        tails.append(f'{log.name}: ' + ' | '.join(text))
    return '; '.join(tails)


RUN_TOPICS = ['pump/command', 'pump/status', 'actuator/pressure', 'actuator/volumes',
              'actuator/curvatures', 'camera/backbone']


def _run_programme(context, ros_env, tmp_path, start_nodes, pump_subscribers):
    """
    Start the nodes (``start_nodes(start, scene_path)``), run the pump's programme, collect.

    ``pump_subscribers`` is how many DDS subscriptions /pump/command must have before the
    start (the collector's and any actuator's). Returns the scene, the messages received and
    the started processes, each checked to be still running at the end.
    """
    scene_path = write_scene(tmp_path)
    collector = Collector(RUN_TOPICS, context)
    got = collector.received
    with node_processes(ros_env, tmp_path) as start, spinning(context, collector):
        processes = start_nodes(start, scene_path)
        wait_for(lambda: all(collector.matched(t) for t in got),
                 'all nodes up and matched', timeout=STARTUP_TIMEOUT_S)
        wait_for(lambda: collector.count_subscribers('/pump/command') == pump_subscribers,
                 f'{pump_subscribers} subscriptions to /pump/command')
        assert call_trigger(collector, '/syringe_pump/start').success
        wait_for(lambda: 'finished' in status_states(got['/pump/status']),
                 'the programme to finish', timeout=PROGRAMME_TIMEOUT_S,
                 explain=lambda: status_history(got['/pump/status'])
                 + '; ' + _log_tails(tmp_path))
        n_commands = len(got['/pump/command'])
        wait_for(lambda: len(got['/actuator/curvatures']) >= n_commands - 5,
                 'the actuator outputs of every command')
        assert all(process.poll() is None for process in processes)
    scene = load_scene(scene_path)
    path = check_against_solver(EquilibriumMap(scene.segments), list(got['/pump/command']),
                                got['/actuator/pressure'], got['/actuator/volumes'],
                                got['/actuator/curvatures'])
    # A frame shows the state of some command. Frames and curvatures come from different
    # processes, so a frame can reach the test before (or without) the curvature message it
    # shows: the states to match are the solver's at every command received.
    check_poses(list(got['/camera/backbone']), path.curvatures.tolist(),
                np.array(scene.lengths), scene.camera.points_per_segment)
    return scene, got, processes


def test_console_script_nodes_match_the_solver(context, ros_env, tmp_path):
    def start_nodes(start, scene_path):
        return [start('actuator', 'actuator', scene=scene_path, resume_timeout_s=0.2),
                start('pump', 'syringe_pump', scene=scene_path, rate_hz=100, autostart='false',
                      feedback_timeout_s=PATIENT_FEEDBACK_TIMEOUT_S),
                start('camera', 'camera', scene=scene_path, rate_hz=20)]

    _, got, _ = _run_programme(context, ros_env, tmp_path, start_nodes, pump_subscribers=2)
    assert len(got['/camera/backbone']) >= 10


def _hysteresis_scene(tmp_path):
    """fig1_asymmetric with a fast programme that ends held inside the hysteresis loop."""
    shipped = config_dir() / 'fig1_asymmetric.yaml'
    scene = load_scene(shipped)
    try:
        emap = EquilibriumMap(scene.segments)
    except (RuntimeError, ValueError) as err:
        pytest.skip(f'{shipped.name}: the equilibrium map cannot be assembled ({err})')
    lo, hi = emap.injected_range
    grid = np.linspace(lo, 0.98 * hi, 2001)
    inflation = Tracker(emap).sweep(grid)
    deflation = Tracker(emap, injected=grid[-1], volumes=inflation.volumes[-1]).sweep(
        grid[::-1])
    gap = np.max(np.abs(inflation.volumes - deflation.volumes[::-1]), axis=1)
    middle = float(grid[int(np.argmax(gap))])
    assert gap.max() > 1e-3 * emap.v_scale, 'fig1_asymmetric shows no hysteresis'
    top = float(grid[-1])
    data = yaml.safe_load(shipped.read_text(encoding='utf-8'))
    # Up and back down to the middle of the loop in about 3 s, then a long hold.
    flow = (2.0 * top - middle) / 3.0
    data['pump'] = {'flow_rate_m3_per_s': flow, 'rate_hz': 100,
                    'legs': [{'inflate_to_m3': top}, {'deflate_to_m3': middle},
                             {'hold_s': 600.0}]}
    path = tmp_path / 'hysteresis.yaml'
    path.write_text(yaml.safe_dump(data), encoding='utf-8')
    return str(path), emap, middle


def test_killed_actuator_resumes_on_its_branch(context, ros_env, ros_home, tmp_path):
    scene_path, emap, middle = _hysteresis_scene(tmp_path)
    # No state_file given: the default one, in the ROS home, is what brings it back.
    actuator_params = {'scene': scene_path, 'resume_timeout_s': 0.5}
    topics = ['pump/command', 'pump/status', 'actuator/volumes', 'actuator/events']
    collector = Collector(topics, context)
    got = collector.received
    rest = emap.total_rest_volume

    def at_middle(msg) -> bool:
        return abs(sum(msg.position) - rest - middle) < 1e-9 * emap.v_scale

    with node_processes(ros_env, tmp_path) as start, spinning(context, collector):
        actuator = start('actuator', 'actuator', **actuator_params)
        start('pump', 'syringe_pump', scene=scene_path, rate_hz=100, autostart='false')
        wait_for(lambda: all(collector.matched(t) for t in got), 'all nodes up and matched',
                 timeout=STARTUP_TIMEOUT_S)
        wait_for(lambda: collector.count_subscribers('/pump/command') == 2,
                 'the actuator on /pump/command')
        assert call_trigger(collector, '/syringe_pump/start').success
        wait_for(lambda: any(at_middle(m) for m in got['/actuator/volumes']),
                 'the actuator to reach the hold inside the loop')
        actuator.send_signal(signal.SIGKILL)
        actuator.wait(timeout=10)
        assert (ros_home / 'softseq' / 'actuator.json').is_file()
        # A pump with no pressure feedback holds (a real pump must not push on blind) and
        # keeps commanding where it is.
        wait_for(lambda: any(json.loads(m.data)['state'] == 'held'
                             and 'no pressure' in json.loads(m.data)['reason']
                             for m in got['/pump/status']), 'the pump to hold', timeout=30)
        before = len(got['/actuator/volumes'])
        history = np.array([m.position[0] for m in got['/pump/command']])
        events = [json.loads(m.data) for m in got['/actuator/events']]
        start('actuator_restarted', 'actuator', **actuator_params)
        wait_for(lambda: len(got['/actuator/volumes']) > before, 'the restarted actuator',
                 timeout=STARTUP_TIMEOUT_S)
        first = np.array(got['/actuator/volumes'][before].position)

    # The snap-throughs before the kill were reported as the solver has them.
    expected = Tracker(emap).sweep(history).events
    assert len(expected) >= 2 and len(events) == len(expected)
    for event, snap in zip(events, expected):
        assert event['injected_m3'] == pytest.approx(snap.injected, rel=1e-9)
        np.testing.assert_allclose(event['to_volumes_m3'], snap.to_volumes, rtol=1e-9)
        assert event['from_pressure_pa'] == pytest.approx(snap.from_pressure, rel=1e-9)
    commands = np.array([m.position[0] for m in got['/pump/command']])
    continuation = Tracker(emap).sweep(commands).volumes[-1]
    fresh = Tracker(emap).step(middle).volumes
    assert commands[-1] == pytest.approx(middle, rel=1e-12)
    np.testing.assert_allclose(first, continuation, rtol=1e-9, atol=1e-9 * emap.v_scale)
    # The history matters here: a fresh start would sit on the other branch.
    assert np.max(np.abs(fresh - continuation)) > 1e-3 * emap.v_scale


def test_a_bad_parameter_on_the_command_line_is_one_line(ros_env, tmp_path):
    script = os.path.join(sys.prefix, 'bin', 'camera')
    for params, expected in ((['scene:=no_such_scene'], 'no_such_scene'),
                             (['scene:=fig1_none', 'noise_std_m:=-1.0'], 'noise_std_m')):
        args = [script, '--ros-args'] + [a for p in params for a in ('-p', p)]
        result = subprocess.run(args, env=ros_env, capture_output=True, text=True, timeout=30)
        assert result.returncode == 2, result.stderr
        assert 'Traceback' not in result.stderr
        errors = [line for line in result.stderr.splitlines() if line.startswith('camera: ')]
        assert len(errors) == 1 and expected in errors[0], result.stderr


def test_yaml_text_that_rcl_cannot_parse_is_one_line_with_the_fix(ros_env):
    # rcl reads -p values as YAML; the pump's legs are YAML text and need their own quotes.
    script = os.path.join(sys.prefix, 'bin', 'syringe_pump')
    result = subprocess.run([script, '--ros-args', '-p', 'legs:=[{inflate_to_m3: 5.0e-6}]'],
                            env=ros_env, capture_output=True, text=True, timeout=30)
    assert result.returncode == 2, result.stderr
    assert 'Traceback' not in result.stderr
    errors = [line for line in result.stderr.splitlines() if line.startswith('syringe_pump: ')]
    assert len(errors) == 1 and 'quote a value' in errors[0], result.stderr
    quoted = subprocess.run([script, '--ros-args', '-p', "legs:='[{inflate_to_m3: 5.0e-6}]'",
                             '-p', 'cycles:=0'], env=ros_env, capture_output=True, text=True,
                            timeout=30)
    # Quoted, the legs parse; the next mistake (cycles) is the one reported.
    assert quoted.returncode == 2 and 'cycles' in quoted.stderr, quoted.stderr


def test_rig_runs_the_three_nodes_in_one_process_with_state_triggered_frames(
        context, ros_env, tmp_path):
    def start_nodes(start, scene_path):
        # A global -p reaches every node that declares it; node:name:= only that node.
        return [start('rig', 'rig', scene=scene_path, rate_hz=50, autostart='false',
                      resume_timeout_s=0.0, feedback_timeout_s=PATIENT_FEEDBACK_TIMEOUT_S,
                      **{'camera:frame_trigger': 'state'})]

    # Inside the rig, commands go straight to the actuator: it has no DDS subscription, and
    # only the collector subscribes to /pump/command.
    _, got, (rig,) = _run_programme(context, ros_env, tmp_path, start_nodes,
                                    pump_subscribers=1)
    # The camera follows the state: about one frame per actuator state (the pump runs at the
    # camera's rate), far more than the scene's own 10 Hz camera would take.
    assert len(got['/camera/backbone']) >= 0.8 * len(got['/actuator/curvatures'])
    assert rig.returncode == 0, (tmp_path / 'rig.log').read_text()


def _recorded_by(node: Node, topics: list[str]) -> bool:
    """Whether the recorder node subscribes to every one of ``topics`` (absolute names)."""
    return all(any(info.node_name == Recorder.NODE_NAME
                   for info in node.get_subscriptions_info_by_topic(topic)) for topic in topics)


def test_a_recording_through_an_actuator_restart_is_reported_as_two_runs(context, ros_env,
                                                                         tmp_path):
    # A pump at 0.1 mL/s to 30 mL (300 s: far longer than the test), as patient as a loaded
    # machine needs while its actuator is down; the recorder running throughout.
    scene_path = write_scene(tmp_path, flow_rate_m3_per_s=1.0e-7, rate_hz=20,
                             legs=[{'inflate_to_m3': 3.0e-5}])
    bag = tmp_path / 'bag'
    collector = Collector(['actuator/scene', 'actuator/volumes'], context)
    scenes, answers = (collector.received[t] for t in ('/actuator/scene', '/actuator/volumes'))
    health = collector.add('/diagnostics', DiagnosticArray, QoSProfile(depth=10))

    def recorded(topic: str) -> int:
        """Messages on ``topic`` the recorder says it wrote (its newest /diagnostics)."""
        said = [pair.value for array in health for status in array.status
                if status.name.startswith('/recorder:') for pair in status.values
                if pair.key == f'messages {topic}']
        return int(said[-1]) if said else 0

    actuator = {'scene': scene_path, 'resume_timeout_s': 0.2}
    with node_processes(ros_env, tmp_path) as start, spinning(context, collector):
        recorder = start('recorder', 'recorder', output=str(bag))
        start('pump', 'syringe_pump', scene=scene_path, autostart='false',
              feedback_timeout_s=2 * STARTUP_TIMEOUT_S)
        first = start('actuator', 'actuator', **actuator)
        collector.wait_for_publishers(timeout=STARTUP_TIMEOUT_S)
        wait_for(lambda: _recorded_by(collector, ['/pump/command', '/pump/status',
                                                  '/actuator/volumes', '/actuator/scene']),
                 'the recorder on the pump and actuator topics', timeout=STARTUP_TIMEOUT_S)
        assert call_trigger(collector, '/syringe_pump/start').success
        rest = sum(segment.rest_volume for segment in load_scene(scene_path).segments)
        wait_for(lambda: answers and sum(answers[-1].position) - rest > 0.2e-6,
                 "the first actuator's answers to the running pump")
        # Stopped and started again mid-programme, as a user restarts a node by hand.
        first.send_signal(signal.SIGINT)
        assert first.wait(timeout=30) == 0
        answered = len(answers)
        start('actuator_again', 'actuator', **actuator)
        wait_for(lambda: len(scenes) >= 2 and len(answers) >= answered + 10,
                 "the restarted actuator's answers", timeout=STARTUP_TIMEOUT_S,
                 explain=lambda: _log_tails(tmp_path))
        # The recorder finds the restarted node on its own, later on a loaded machine (once
        # more than a second after this collector): stopped before, it had recorded none of it.
        wait_for(lambda: recorded('/actuator/scene') >= 2,
                 "the restarted actuator's scene in the bag", timeout=STARTUP_TIMEOUT_S,
                 explain=lambda: _log_tails(tmp_path))
        recorded_then = recorded('/actuator/volumes')
        wait_for(lambda: recorded('/actuator/volumes') >= recorded_then + 5,
                 "the restarted actuator's answers in the bag", timeout=STARTUP_TIMEOUT_S,
                 explain=lambda: _log_tails(tmp_path))
        recorder.send_signal(signal.SIGINT)
        assert recorder.wait(timeout=30) == 0
    recording = load_recording(bag)
    [restart] = recording.run_starts
    assert restart.cause == 'the actuator started again (it named its scene anew)'
    first_run, second_run = recording.runs()
    # The pump went on while the actuator was down: run 2 starts where run 1's commands left.
    assert second_run.state_injected.min() > first_run.state_injected.max() > 0.0
    metrics, text = write_report(bag, tmp_path / 'report', figures=False)
    assert [run['run'] for run in metrics['runs']] == [1, 2]
    assert metrics['runs'][1]['from_s'] == restart.time_s
    assert any(w.startswith('the bag holds 2 ') for w in metrics['warnings'])
    assert f'run 2 (from {restart.time_s:.3f} s' in text


@pytest.mark.parametrize('signum', [signal.SIGINT, signal.SIGTERM], ids=['SIGINT', 'SIGTERM'])
def test_a_signal_while_a_node_loads_ends_it_quietly(ros_env, tmp_path, signum):
    # A Ctrl-C in the second a node needs to load (rclpy, numpy, its scene) used to end in a
    # KeyboardInterrupt traceback through the imports.
    script = os.path.join(sys.prefix, 'bin', 'camera')
    process = subprocess.Popen([script, '--ros-args', '-p', 'scene:=fig1_none'], env=ros_env,
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT)

    def loading_rclpy() -> bool:
        # rcl's library mapped: the entry point has begun to load the node's module.
        try:
            with open(f'/proc/{process.pid}/maps', encoding='ascii', errors='replace') as maps:
                return 'librcl' in maps.read()
        except FileNotFoundError:
            return True
    wait_for(loading_rclpy, 'the camera to load rclpy', timeout=STARTUP_TIMEOUT_S)
    process.send_signal(signum)
    output, _ = process.communicate(timeout=60)
    assert b'Traceback' not in output and b'KeyboardInterrupt' not in output, output
    # At once, as a shell reports the signal (0 only if it was up already: a clean stop).
    assert process.returncode in (128 + signum, 0), output


@pytest.mark.parametrize('executable, words', [
    ('actuator', 'ready: scene rate_inversion (base, tip), a fluid network in time, publishing '
                 'curvature, events, flows, pressure, volumes'),
    ('camera', 'ready: scene rate_inversion, frames at 10 Hz, 5 snapshot volumes, publishing '
               'markers, poses'),
])
def test_the_actuator_and_the_camera_say_when_they_are_ready(ros_env, tmp_path, executable,
                                                            words):
    # They logged nothing at start: a user could not tell a node that loads its scene from one
    # that hangs, nor which model and outputs it took.
    process = subprocess.Popen(
        [executable, '--ros-args', '-p', 'scene:=rate_inversion', '-r', '__ns:=/rig_r'],
        env={**ros_env, 'ROS_HOME': str(tmp_path)}, stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT, text=True)
    try:
        lines: list[str] = []
        deadline = time.monotonic() + 60.0
        while not any('ready: ' in line for line in lines) and time.monotonic() < deadline:
            if select.select([process.stdout], [], [], 1.0)[0]:
                line = process.stdout.readline()
                if not line:
                    break
                lines.append(line)
        ready = [line for line in lines if 'ready: ' in line]
        assert ready and f'[rig_r.{executable}]: {words}' in ready[0], ''.join(lines)
    finally:
        process.send_signal(signal.SIGINT)
        process.communicate(timeout=30)
