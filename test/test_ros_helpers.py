"""
``softseq ros``, run as a user runs it (a process of its own), against real nodes.

The nodes run in this test process (softseq_ros.testing) or, for ``softseq ros rig``, as the
processes it starts; the command reaches them over DDS in this run's ROS domain (ros_env).
"""

import json
from pathlib import Path
import signal
import subprocess
import sys
import time

import pytest
from rcl_interfaces.msg import ParameterType
from rclpy.parameter import Parameter
from scenes import write_scene
import yaml

from softseq_ros.bag.reader import bag_summary, read_bag
from softseq_ros.nodes.actuator import ActuatorNode
from softseq_ros.nodes.managed_syringe_pump import ManagedSyringePumpNode
from softseq_ros.nodes.syringe_pump import SyringePumpNode
from softseq_ros.ros_tools.calls import parameter_value
from softseq_ros.ros_tools.echo import message_fields
from softseq_ros.ros_tools.launcher import rig_commands
from softseq_ros.testing import Collector, call_trigger, spinning, wait_for

# What the command may take to find a node on a loaded machine; it ends as soon as it does.
FIND_S = '30'
# A command's whole run: the interpreter, rclpy and the wait above.
COMMAND_TIMEOUT_S = 120.0
# A rig of three nodes and a recorder starting as processes on a loaded 2-core machine.
RIG_TIMEOUT_S = 120.0


def softseq_ros(env: dict[str, str], *args: str) -> subprocess.CompletedProcess:
    """``softseq ros ARGS`` in a process of its own, with this run's ROS environment."""
    return subprocess.run([sys.executable, '-m', 'softseq_ros.cli', 'ros', *args], env=env,
                          capture_output=True, text=True, timeout=COMMAND_TIMEOUT_S,
                          stdin=subprocess.DEVNULL)


def pump_node(context, scene: str, node_class=SyringePumpNode, namespace: str = '/',
              **parameters):
    """A pump on ``scene`` that waits for ~/start and needs no actuator unless told."""
    values = {'scene': scene, 'autostart': False, 'open_loop': True, **parameters}
    return node_class(context=context, namespace=namespace, parameter_overrides=[
        Parameter(name, value=value) for name, value in values.items()])


# ------------------------------------------------------------------ without a ROS graph

def test_a_value_is_yaml_as_ros2_param_set_reads_it_and_takes_the_declared_type():
    legs = '[{inflate_to_m3: 2.0e-5}, {deflate_to_m3: 0.0}]'
    as_string = parameter_value(legs, ParameterType.PARAMETER_STRING, False)
    assert (as_string.type, as_string.string_value) == (ParameterType.PARAMETER_STRING, legs)
    # An empty YAML list would otherwise be a bool array a string parameter refuses.
    assert parameter_value('[]', ParameterType.PARAMETER_STRING, False).string_value == '[]'
    assert parameter_value("'quoted'", ParameterType.PARAMETER_STRING, False).string_value \
        == 'quoted'
    # A double parameter takes an integer, and 1e9 (text to YAML 1.1), as the numbers meant.
    assert parameter_value('100', ParameterType.PARAMETER_DOUBLE, False).double_value == 100.0
    assert parameter_value('1e9', ParameterType.PARAMETER_DOUBLE, False).double_value == 1e9
    # Where the node takes several types, the YAML's own type goes, as ros2 param set sends it.
    dynamic = parameter_value('100', ParameterType.PARAMETER_DOUBLE, True)
    assert (dynamic.type, dynamic.integer_value) == (ParameterType.PARAMETER_INTEGER, 100)
    assert parameter_value('true', ParameterType.PARAMETER_BOOL, False).bool_value is True
    mapping = parameter_value('{a: 1}', ParameterType.PARAMETER_INTEGER, False)
    assert (mapping.type, mapping.string_value) == (ParameterType.PARAMETER_STRING, '{a: 1}')


def test_a_message_prints_as_plain_data_with_long_arrays_cut():
    from sensor_msgs.msg import JointState

    message = JointState(name=['base', 'bottom'], position=[1.0e-5, 2.0e-5],
                         effort=[float(i) for i in range(6)])
    fields = message_fields(message, truncate=4)
    assert fields['name'] == ['base', 'bott...']
    assert fields['position'] == [1.0e-5, 2.0e-5]
    assert fields['effort'] == [0.0, 1.0, 2.0, 3.0, '...']
    assert fields['header'] == {'stamp': {'sec': 0, 'nanosec': 0}, 'frame_id': ''}
    yaml.safe_dump(fields)   # plain data: no numpy or array type left in it


def test_the_rig_command_lines_mirror_the_launch_file(tmp_path):
    commands = rig_commands('/rig2', tmp_path / 'p.yaml', 'paper', tmp_path / 'bag')
    assert list(commands) == ['recorder', 'rig']   # the recorder listens first
    rig, recorder = commands['rig'], commands['recorder']
    assert rig[rig.index('--ros-args'):] == [
        '--ros-args', '-r', '__ns:=/rig2', '-p', 'autostart:=false',
        '--params-file', str(tmp_path / 'p.yaml'), '-p', 'scene:="paper"']
    assert recorder[recorder.index('--ros-args'):] == [
        '--ros-args', '-r', '__ns:=/rig2', '--params-file', str(tmp_path / 'p.yaml'),
        '-p', f'output:="{tmp_path / "bag"}"']


def test_the_rig_refuses_a_bag_folder_in_use_before_starting_anything(ros_env, tmp_path):
    bag = tmp_path / 'bag'
    bag.mkdir()
    (bag / 'metadata.yaml').write_text('old\n')
    result = softseq_ros(ros_env, 'rig', '--namespace', '/rig2', '--record', str(bag))
    assert result.returncode == 2
    assert result.stderr == (f'softseq ros rig: error: --record {bag}: already exists and is '
                             'not an empty folder; a recording never overwrites one\n')
    assert sorted(p.name for p in bag.iterdir()) == ['metadata.yaml']


# ------------------------------------------------------------------------ against nodes

@pytest.mark.ros
def test_call_starts_the_pump_and_a_refusal_exits_1(context, ros_env, tmp_path):
    pump = pump_node(context, write_scene(tmp_path))
    collector = Collector(['pump/status'], context)
    with spinning(context, pump, collector):
        collector.wait_for_publishers()
        started = softseq_ros(ros_env, 'call', '/syringe_pump/start', '--timeout', FIND_S)
        assert started.returncode == 0, started.stderr
        assert started.stdout == 'success: true\nmessage: running\n'
        wait_for(lambda: 'running' in collector.states(), 'the pump to say it runs')
        # ~/load refuses while the programme runs: an answer, not a usage error.
        refused = softseq_ros(ros_env, 'call', 'syringe_pump/load', '--timeout', FIND_S)
        assert refused.returncode == 1, refused.stderr
        assert refused.stdout.startswith('success: false\nmessage: ')


@pytest.mark.ros
def test_param_set_shows_a_refusal_and_takes_yaml_legs_whole(context, ros_env, tmp_path):
    pump = pump_node(context, write_scene(tmp_path))
    with spinning(context, pump):
        before = pump.get_parameter('rate_hz').value
        refused = softseq_ros(ros_env, 'param', 'set', '/syringe_pump', 'rate_hz', '1e9',
                              '--timeout', FIND_S)
        assert refused.returncode == 1
        [line] = refused.stderr.splitlines()
        assert line.startswith('softseq ros param set: /syringe_pump refused rate_hz = ')
        assert 'must be <= 10000' in line
        assert pump.get_parameter('rate_hz').value == before

        legs = '[{inflate_to_m3: 2.0e-5}, {hold_s: 2}, {deflate_to_m3: 0.0}]'
        taken = softseq_ros(ros_env, 'param', 'set', 'syringe_pump', 'legs', legs,
                            '--timeout', FIND_S)
        assert taken.returncode == 0, taken.stderr
        assert pump.get_parameter('legs').value == legs
        got = softseq_ros(ros_env, 'param', 'get', '/syringe_pump', 'legs', '--timeout', FIND_S)
        assert (got.returncode, got.stdout) == (0, legs + '\n')
        # The pump reads the text as its programme: ~/load takes the three legs, 1 s at
        # 20 mL/s up, 2 s held and 1 s down (the scene's own programme takes 3 s).
        loaded = softseq_ros(ros_env, 'call', '/syringe_pump/load', '--timeout', FIND_S)
        assert loaded.returncode == 0, loaded.stdout + loaded.stderr
        assert loaded.stdout == 'success: true\nmessage: idle with the new programme (4 s)\n'

        described = softseq_ros(ros_env, 'param', 'describe', '/syringe_pump', 'autostart',
                                '--timeout', FIND_S)
        assert described.returncode == 0, described.stderr
        assert '  type: bool\n' in described.stdout
        assert '  read-only: true' in described.stdout
        unknown = softseq_ros(ros_env, 'param', 'get', '/syringe_pump', 'rate_hx',
                              '--timeout', FIND_S)
        assert unknown.returncode == 2
        assert unknown.stderr == ('softseq ros param: error: /syringe_pump has no parameter '
                                  'rate_hx (did you mean rate_hz?)\n')


@pytest.mark.ros
def test_lifecycle_configures_and_activates_the_managed_pump(context, ros_env, tmp_path):
    pump = pump_node(context, write_scene(tmp_path), ManagedSyringePumpNode, namespace='/m')
    with spinning(context, pump):
        state = softseq_ros(ros_env, 'lifecycle', 'get', '/m/syringe_pump', '--timeout', FIND_S)
        assert (state.returncode, state.stdout) == (0, 'unconfigured [1]\n'), state.stderr
        too_early = softseq_ros(ros_env, 'lifecycle', 'set', '/m/syringe_pump', 'activate',
                                '--timeout', FIND_S)
        assert too_early.returncode == 1
        assert too_early.stderr == ('softseq ros lifecycle set: /m/syringe_pump is '
                                    'unconfigured: no transition activate from there (it has: '
                                    'configure, shutdown)\n')
        for transition, reached in (('configure', 'inactive'), ('activate', 'active')):
            # A relative name, in the namespace given.
            result = softseq_ros(ros_env, 'lifecycle', 'set', 'syringe_pump', transition,
                                 '--namespace', '/m', '--timeout', FIND_S)
            assert result.returncode == 0, result.stderr
            assert result.stdout == f'/m/syringe_pump: {transition} done, now {reached}\n'
        # Active: its services act.
        started = softseq_ros(ros_env, 'call', '/m/syringe_pump/start', '--timeout', FIND_S)
        assert (started.returncode, started.stdout) == (0, 'success: true\nmessage: running\n')


@pytest.mark.ros
def test_echo_prints_count_messages_as_yaml(context, ros_env, tmp_path):
    scene = write_scene(tmp_path)
    pump = pump_node(context, scene, open_loop=False, feedback_timeout_s=600.0)
    actuator = ActuatorNode(context=context, parameter_overrides=[
        Parameter('scene', value=scene), Parameter('state_file', value='')])
    collector = Collector(['pump/command', 'actuator/volumes'], context)
    with spinning(context, pump, actuator, collector):
        collector.wait_for_publishers()
        assert call_trigger(collector, '/syringe_pump/start').success
        result = softseq_ros(ros_env, 'echo', '/actuator/volumes', '--count', '3',
                             '--timeout', FIND_S)
    assert result.returncode == 0, result.stderr
    documents = result.stdout.split('---\n')
    assert documents[-1] == '' and len(documents) == 4
    for document in documents[:3]:
        message = yaml.safe_load(document)
        assert message['name'] == ['bottom', 'top']
        assert len(message['position']) == len(message['effort']) == 2


@pytest.mark.ros
def test_echo_without_count_ends_at_ctrl_c_after_a_whole_message(context, ros_env, tmp_path):
    pump = pump_node(context, write_scene(tmp_path))   # idle, it commands its volume at 100 Hz
    printed = tmp_path / 'echo.out'
    with spinning(context, pump), open(printed, 'wb') as output:
        echo = subprocess.Popen(
            [sys.executable, '-m', 'softseq_ros.cli', 'ros', 'echo', 'pump/command',
             '--timeout', FIND_S], env=ros_env, stdout=output, stderr=subprocess.PIPE,
            stdin=subprocess.DEVNULL)
        try:
            wait_for(lambda: printed.read_text().count('---\n') >= 2, 'two messages printed',
                     timeout=COMMAND_TIMEOUT_S)
            echo.send_signal(signal.SIGINT)
            _, errors = echo.communicate(timeout=COMMAND_TIMEOUT_S)
        finally:
            if echo.poll() is None:
                echo.kill()
                echo.wait()
    assert (echo.returncode, errors) == (0, b'')
    text = printed.read_text()
    assert text.endswith('---\n')
    for document in text.split('---\n')[:-1]:
        assert yaml.safe_load(document)['name'] == ['syringe']


@pytest.mark.ros
def test_nothing_there_ends_within_the_timeout_in_one_line(context, ros_env, tmp_path):
    pump = pump_node(context, write_scene(tmp_path))
    with spinning(context, pump):
        began = time.monotonic()
        missing = softseq_ros(ros_env, 'call', 'syringe_pump/start', '--namespace', '/rig9',
                              '--timeout', '5')
        took = time.monotonic() - began
        assert missing.returncode == 2
        # The pump at the root is named: the namespace was what was wrong.
        assert missing.stderr == ('softseq ros call: error: no service '
                                  '/rig9/syringe_pump/start within 5 s; is the node running, '
                                  'in that namespace? (found /syringe_pump/start)\n')
        assert missing.stdout == ''
        # It waited the time given, and not much more (the interpreter and rclpy start first).
        assert 5.0 <= took < 5.0 + 60.0
        # rcl's own namespace argument resolves relative names as --namespace does.
        remapped = softseq_ros(ros_env, 'param', 'get', 'syringe_pump', 'rate_hz',
                               '--timeout', '2', '--ros-args', '-r', '__ns:=/rig9')
        assert remapped.returncode == 2
        assert remapped.stderr.startswith('softseq ros param: error: no node '
                                          '/rig9/syringe_pump (its parameter services) within '
                                          '2 s; is the node running, in that namespace?')
    nobody = softseq_ros(ros_env, 'echo', '/rig9/pump/status', '--count', '1', '--timeout', '2')
    assert nobody.returncode == 2
    assert nobody.stderr == ('softseq ros echo: error: no publisher on /rig9/pump/status within '
                             '2 s; is the node running, in that namespace?\n')


def _tail(path: Path, lines: int = 30) -> str:
    if not path.exists():
        return f'{path.name}: nothing'
    return f'{path.name}: ' + '\n'.join(path.read_text(errors='replace').splitlines()[-lines:])


@pytest.mark.ros
def test_one_command_runs_a_rig_in_a_namespace_into_a_bag_and_stops_on_sigint(
        context, ros_env, tmp_path):
    # No image: the recorder would subscribe to it, and rendering it costs a core.
    scene = write_scene(tmp_path, outputs=['pressure', 'volumes', 'curvature', 'poses'])
    params = tmp_path / 'rig.yaml'
    params.write_text(yaml.safe_dump({
        # Patient with an actuator slow to answer on a loaded machine: this is about the rig.
        '/rig2/syringe_pump': {'ros__parameters': {'max_pressure_pa': 50000.0,
                                                   'feedback_timeout_s': 600.0}},
        '/rig2/actuator': {'ros__parameters': {'resume_timeout_s': 0.0, 'state_file': ''}},
        '/rig2/recorder': {'ros__parameters': {'compression': 'lz4'}},
    }))
    bag = tmp_path / 'bags' / 'rig2'
    log = tmp_path / 'rig.log'
    collector = Collector(['pump/status'], context, namespace='/rig2')
    with open(log, 'wb') as output, spinning(context, collector):
        rig = subprocess.Popen(
            [sys.executable, '-m', 'softseq_ros.cli', 'ros', 'rig', '--namespace', '/rig2',
             '--params-file', str(params), '--scene', scene, '--record', str(bag), '--start',
             '--timeout', str(RIG_TIMEOUT_S)],
            env=ros_env, stdout=output, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
        try:
            # --start: the programme runs once the recorder records the pump's commands.
            wait_for(lambda: 'finished' in collector.states(), 'the programme to finish',
                     timeout=2 * RIG_TIMEOUT_S, explain=lambda: _tail(log))
            # The parameters file reached the rig's nodes in their namespace.
            relief = softseq_ros(ros_env, 'param', 'get', '/rig2/syringe_pump',
                                 'max_pressure_pa', '--timeout', FIND_S)
            assert (relief.returncode, relief.stdout) == (0, '50000.0\n'), relief.stderr
            rig.send_signal(signal.SIGINT)
            assert rig.wait(timeout=RIG_TIMEOUT_S) == 0, _tail(log)
        finally:
            if rig.poll() is None:
                rig.kill()
                rig.wait()
    summary = bag_summary(bag)
    assert summary.complete, _tail(log)
    assert summary.topics and all(topic.startswith('/rig2/') for topic in summary.topics)
    assert summary.topics['/rig2/pump/command'].message_count > 0
    assert summary.topics['/rig2/actuator/volumes'].message_count > 0
    states = [json.loads(m.msg.data)['state'] for m in read_bag(bag, ['/rig2/pump/status'])]
    # Recorded from before the start: the idle pump, then its whole programme.
    assert states[0] == 'idle' and 'running' in states and states[-1] == 'finished', states
    assert 'closed' in log.read_text(), _tail(log)


def test_a_wait_without_end_and_a_scene_no_node_loads_are_refused_before_anything_starts(
        tmp_path):
    from pathlib import Path
    import subprocess
    import sys

    softseq = str(Path(sys.prefix) / 'bin' / 'softseq')
    for argv, said in (
            (['ros', 'call', '/syringe_pump/start', '--timeout', '1e300'], 'at most 3600'),
            (['ros', 'rig', '--scene', str(tmp_path / 'missing.yaml')], 'scene file not found'),
            (['ros', 'rig', '--scene', ' '], '--scene: empty')):
        result = subprocess.run([softseq, *argv], capture_output=True, text=True, timeout=60,
                                cwd=tmp_path)
        lines = result.stderr.strip().splitlines()
        assert result.returncode == 2 and len(lines) == 1 and said in lines[0], result.stderr
    assert not list(tmp_path.glob('bags*'))     # no rig started, nothing recorded
