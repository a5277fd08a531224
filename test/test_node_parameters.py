"""
Node parameters given on the command line or in a file take effect, or are refused in one line.

rcl reads a ``-p node:name:=value`` prefix as a node at the root, so under ``-r __ns:=`` it
reached nothing, and it refuses a prefix with a slash; softseq matches the prefix itself
(softseq_ros.nodes.parameters). The nodes run as console scripts, started as a user starts
them, and the test reads their parameters back over their parameter services.
"""

import json
import os
from pathlib import Path
import signal
import subprocess
import sys

import numpy as np
import pytest
from rcl_interfaces.srv import GetParameters, SetParameters
from rclpy.node import Node
from rclpy.parameter import Parameter, parameter_value_to_python
from test_nodes import status_states, write_scene
from test_nodes_processes import STARTUP_TIMEOUT_S

from softseq_ros.nodes.parameters import (
    NodeConfigError,
    ParameterRule,
    node_fqn,
    split_ros_arguments,
)
from softseq_ros.nodes.syringe_pump import SyringePumpNode
from softseq_ros.quasistatic.equilibrium import EquilibriumMap, Tracker
from softseq_ros.scene.loader import load_scene
from softseq_ros.testing import Collector, call_trigger, spinning, wait_for

PARAMS_EXAMPLE = Path(__file__).resolve().parent.parent / 'config' / 'params' / \
    'params_example.yaml'
RELIEF_PA = 5000.0


def _run(env, cwd, script: str, *ros_args: str) -> subprocess.CompletedProcess:
    return subprocess.run([os.path.join(sys.prefix, 'bin', script), '--ros-args', *ros_args],
                          env=env, cwd=cwd, capture_output=True, text=True, timeout=60)


class Processes:
    """Console scripts started with any ROS arguments; stopped by SIGINT when the block ends."""

    def __init__(self, env, log_dir: Path) -> None:
        self.env, self.log_dir, self.started = env, log_dir, []

    def __enter__(self) -> 'Processes':
        return self

    def __exit__(self, *_exc) -> None:
        for process in self.started:
            if process.poll() is None:
                process.send_signal(signal.SIGINT)
        for process in self.started:
            try:
                process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()

    def start(self, name: str, script: str, *ros_args: str, cwd=None) -> subprocess.Popen:
        log = open(self.log_dir / f'{name}.log', 'ab')
        process = subprocess.Popen(
            [os.path.join(sys.prefix, 'bin', script), '--ros-args', *ros_args],
            env=self.env, cwd=cwd, stdout=log, stderr=subprocess.STDOUT)
        log.close()
        self.started.append(process)
        return process

    def log(self, name: str) -> str:
        return (self.log_dir / f'{name}.log').read_text(errors='replace')


def parameters_of(node: Node, fqn: str, names: list[str]) -> dict:
    """A running node's parameters, read over its get_parameters service."""
    client = node.create_client(GetParameters, f'{fqn}/get_parameters')
    assert client.wait_for_service(timeout_sec=STARTUP_TIMEOUT_S), f'{fqn} did not come up'
    future = client.call_async(GetParameters.Request(names=names))
    wait_for(future.done, f'the parameters of {fqn}')
    values = future.result().values
    assert len(values) == len(names), f'{fqn} has not all of {names}'
    return {name: parameter_value_to_python(value) for name, value in zip(names, values)}


# ------------------------------------------------------------------------ matching rules

def test_node_prefixed_rules_are_taken_from_rcl_and_the_rest_left_to_it():
    argv = ['rig', 'extra', '--ros-args', '-r', '__ns:=/rig_b', '-p', 'rate_hz:=100',
            '-p', 'syringe_pump:autostart:=false', '--param', '/rig_b/camera:rate_hz:=30',
            '-p', "legs:='[{inflate_to_m3: 5.0e-6}]'", '--params-file', 'f.yaml',
            '-p', 'rig_b/actuator:state_file:=a:=b', '--', '-p', 'x:y:=1']
    split = split_ros_arguments(argv)
    assert split.rules == [ParameterRule('syringe_pump', 'autostart', 'false'),
                           ParameterRule('/rig_b/camera', 'rate_hz', '30'),
                           ParameterRule('rig_b/actuator', 'state_file', 'a:=b')]
    # What rcl still reads: everything but the node-prefixed rules (after '--' nothing is ROS's).
    assert split.rcl_args == ['rig', 'extra', '--ros-args', '-r', '__ns:=/rig_b',
                              '-p', 'rate_hz:=100', '-p', "legs:='[{inflate_to_m3: 5.0e-6}]'",
                              '--params-file', 'f.yaml', '--', '-p', 'x:y:=1']
    assert [r.name for r in split.global_rules] == ['rate_hz', 'legs']
    pump = ('syringe_pump', '/rig_b/syringe_pump')
    assert split.rules_for(*pump) == split.rules[:1]
    assert split.rules_for('camera', '/rig_b/camera') == split.rules[1:2]
    assert split.rules_for('actuator', '/rig_b/actuator') == split.rules[2:]
    # A fully qualified prefix names one namespace only; a bare name any.
    assert not split.rules[1].matches('camera', '/rig_c/camera')
    assert split.rules[0].matches('syringe_pump', '/lab/a/syringe_pump')
    # A wildcard prefix stays rcl's (which refuses it with its own words).
    assert split_ros_arguments(['--ros-args', '-p', '**/camera:rate_hz:=1']).rules == []


def test_node_names_follow_rcls_remapping_order():
    remaps = split_ros_arguments(['--ros-args', '-r', 'camera:__ns:=/cams', '-r', '__ns:=/rig_b',
                                  '-r', 'syringe_pump:__node:=pump_b']).remaps
    assert node_fqn('camera', '', remaps) == ('camera', '/cams/camera')
    assert node_fqn('actuator', '', remaps) == ('actuator', '/rig_b/actuator')
    assert node_fqn('syringe_pump', '', remaps) == ('pump_b', '/rig_b/pump_b')
    assert node_fqn('actuator', 'lab', []) == ('actuator', '/lab/actuator')


def test_a_node_built_in_process_takes_its_prefixed_rules_in_a_namespace(context, tmp_path):
    scene = [Parameter('scene', value=write_scene(tmp_path))]
    for rule in ('syringe_pump:autostart:=false', 'rig_b/syringe_pump:autostart:=false',
                 '/rig_b/syringe_pump:autostart:=false'):
        pump = SyringePumpNode(context=context, parameter_overrides=scene, cli_args=[
            '--ros-args', '-r', '__ns:=/rig_b', '-p', rule, '-p', 'syringe_pump:cycles:=3'])
        try:
            assert pump.get_parameter('autostart').value is False, rule
            assert pump.get_parameter('cycles').value == 3
            assert pump.state == 'idle'
        finally:
            pump.destroy_node()
    with pytest.raises(NodeConfigError, match='/rig_b/syringe_pump, not /rig_c/syringe_pump'):
        SyringePumpNode(context=context, parameter_overrides=scene, cli_args=[
            '--ros-args', '-r', '__ns:=/rig_b', '-p', '/rig_c/syringe_pump:autostart:=false'])


# ------------------------------------------------------------------- every executable

def test_per_node_parameters_reach_every_executable_in_a_namespace(context, ros_env, tmp_path):
    scene = f'scene:={write_scene(tmp_path)}'
    probe = Node('probe', context=context)
    with spinning(context, probe), Processes(ros_env, tmp_path) as processes:
        # The rig: three nodes in one process, each reached by one of the three forms.
        processes.start('rig', 'rig', '-r', '__ns:=/rig_b', '-p', scene,
                        '-p', 'syringe_pump:autostart:=false',
                        '-p', 'rig_b/camera:rate_hz:=30',
                        '-p', '/rig_b/actuator:resume_timeout_s:=0.0')
        processes.start('pump', 'syringe_pump', '-r', '__ns:=/rig_d', '-p', scene,
                        '-p', '/rig_d/syringe_pump:autostart:=false',
                        '-p', 'syringe_pump:max_pressure_pa:=5000')
        processes.start('actuator', 'actuator', '-r', '__ns:=/rig_d', '-p', scene,
                        '-p', 'actuator:resume_timeout_s:=0.0')
        processes.start('camera', 'camera', '-r', '__ns:=/rig_d', '-p', scene,
                        '-p', 'rig_d/camera:noise_std_m:=0.001')
        processes.start('clock', 'sim_clock', '-r', '__ns:=/rig_c',
                        '-p', 'sim_clock:speedup:=7', '-p', '/rig_c/sim_clock:rate_hz:=50')
        processes.start('recorder', 'recorder', '-r', '__ns:=/rig_c',
                        '-p', f'recorder:output:={tmp_path / "bag_c"}',
                        '-p', '/rig_c/recorder:compression:=zstd')
        got = {
            '/rig_b/syringe_pump': parameters_of(probe, '/rig_b/syringe_pump', ['autostart']),
            '/rig_b/camera': parameters_of(probe, '/rig_b/camera', ['rate_hz']),
            '/rig_b/actuator': parameters_of(probe, '/rig_b/actuator',
                                             ['resume_timeout_s']),
            '/rig_d/syringe_pump': parameters_of(probe, '/rig_d/syringe_pump',
                                                 ['autostart', 'max_pressure_pa']),
            '/rig_d/actuator': parameters_of(probe, '/rig_d/actuator', ['resume_timeout_s']),
            '/rig_d/camera': parameters_of(probe, '/rig_d/camera', ['noise_std_m']),
            '/rig_c/sim_clock': parameters_of(probe, '/rig_c/sim_clock',
                                              ['speedup', 'rate_hz']),
            '/rig_c/recorder': parameters_of(probe, '/rig_c/recorder',
                                             ['output', 'compression']),
        }
        assert all(p.poll() is None for p in processes.started), \
            {p.args[0]: p.returncode for p in processes.started}
    assert got == {
        '/rig_b/syringe_pump': {'autostart': False},
        '/rig_b/camera': {'rate_hz': 30},
        '/rig_b/actuator': {'resume_timeout_s': 0.0},
        '/rig_d/syringe_pump': {'autostart': False, 'max_pressure_pa': 5000},
        '/rig_d/actuator': {'resume_timeout_s': 0.0},
        '/rig_d/camera': {'noise_std_m': 0.001},
        '/rig_c/sim_clock': {'speedup': 7, 'rate_hz': 50},
        '/rig_c/recorder': {'output': str(tmp_path / 'bag_c'), 'compression': 'zstd'},
    }


# ------------------------------------------------------------------------ the relief

def test_the_pump_relief_given_per_node_acts_at_5_kpa_in_a_namespaced_rig(
        context, ros_env, tmp_path):
    # The fast scene passes 5 kPa gauge at about 11 mL of its 30 mL programme (peak 8.4 kPa):
    # with the default relief (100 kPa) the programme would finish.
    scene_path = write_scene(tmp_path)
    collector = Collector(['pump/command', 'pump/status'], context, namespace='/rig_b')
    got = collector.received
    with spinning(context, collector), Processes(ros_env, tmp_path) as processes:
        processes.start('rig', 'rig', '-r', '__ns:=/rig_b', '-p', f'scene:={scene_path}',
                        '-p', 'syringe_pump:autostart:=false',
                        '-p', f'syringe_pump:max_pressure_pa:={RELIEF_PA:g}',
                        '-p', 'resume_timeout_s:=0.0')
        wait_for(lambda: all(collector.matched(t) for t in got), 'the rig up and matched',
                 timeout=STARTUP_TIMEOUT_S)
        assert call_trigger(collector, '/rig_b/syringe_pump/start').success
        wait_for(lambda: {'stopped', 'finished'} & set(status_states(got['/rig_b/pump/status'])),
                 'the pump to stop or finish', timeout=STARTUP_TIMEOUT_S)
        last = json.loads(got['/rig_b/pump/status'][-1].data)
    assert last['state'] == 'stopped', (last, processes.log('rig'))
    assert f'max_pressure_pa {RELIEF_PA:g} Pa' in last['reason'], last
    # The pump went on only while the gauge pressure of what it commanded stayed under the
    # relief, and it stopped on the answer to the first command whose pressure passed it: at
    # most at the volume of that instant, less than one tick of flow further.
    scene = load_scene(scene_path)
    emap = EquilibriumMap(scene.segments)
    commands = got['/rig_b/pump/command']
    injected = np.array([m.position[0] for m in commands])
    pressure = Tracker(emap).sweep(injected).pressure
    over = np.flatnonzero(pressure > RELIEF_PA)
    assert over.size, 'no command passed the relief'
    one_tick = scene.pump.profile.flow_rate / scene.pump.rate_hz
    assert injected.max() < injected[over[0]] + one_tick
    assert pressure[:over[0]].max() <= RELIEF_PA


# ----------------------------------------------------------------------- params files

def test_the_shipped_params_file_with_fully_qualified_names_takes_effect(
        context, ros_env, tmp_path):
    # The example is for /rig_b; the command line adds the scene and overrides one value.
    probe = Node('probe', context=context)
    with spinning(context, probe), Processes(ros_env, tmp_path) as processes:
        processes.start('rig', 'rig', '-r', '__ns:=/rig_b',
                        '-p', f'scene:={write_scene(tmp_path)}',
                        '--params-file', str(PARAMS_EXAMPLE), '-p', 'camera:rate_hz:=25')
        processes.start('recorder', 'recorder', '-r', '__ns:=/rig_b',
                        '--params-file', str(PARAMS_EXAMPLE), cwd=tmp_path)
        pump = parameters_of(probe, '/rig_b/syringe_pump',
                             ['autostart', 'rate_hz', 'max_pressure_pa',
                              'feedback_timeout_s'])
        actuator = parameters_of(probe, '/rig_b/actuator', ['resume_timeout_s'])
        camera = parameters_of(probe, '/rig_b/camera', ['rate_hz', 'frame_trigger'])
        recorder = parameters_of(probe, '/rig_b/recorder', ['output', 'compression'])
        status = Collector(['pump/status'], context, namespace='/rig_b', name='status')
        with spinning(context, status):
            wait_for(lambda: status.received['/rig_b/pump/status'], 'the pump status',
                     timeout=STARTUP_TIMEOUT_S)
            states = status_states(status.received['/rig_b/pump/status'])
    assert pump == {'autostart': False, 'rate_hz': 100, 'max_pressure_pa': 50000.0,
                    'feedback_timeout_s': 2.0}
    assert states == ['idle']  # autostart false: it waits for ~/start
    assert actuator == {'resume_timeout_s': 0.0}
    # The command line wins over the file.
    assert camera == {'rate_hz': 25, 'frame_trigger': 'state'}
    assert recorder == {'output': 'bags/rig_b', 'compression': 'zstd'}
    assert (tmp_path / 'bags' / 'rig_b').is_dir()


# ------------------------------------------------------------------ refused, one line

def _one_error_line(result: subprocess.CompletedProcess, script: str) -> str:
    assert result.returncode == 2, result.stderr
    assert 'Traceback' not in result.stderr, result.stderr
    errors = [line for line in result.stderr.splitlines() if line.startswith(f'{script}: ')]
    assert len(errors) == 1, result.stderr
    return errors[0]


def test_a_prefix_that_reaches_no_node_is_refused_naming_the_nodes_there_are(
        ros_env, tmp_path):
    for prefix in ('syringe_pmp', '/rig_a/syringe_pump', 'rig_a/syringe_pump'):
        result = _run(ros_env, tmp_path, 'rig', '-r', '__ns:=/rig_b',
                      '-p', f'{prefix}:max_pressure_pa:=5000')
        line = _one_error_line(result, 'rig')
        assert f'-p {prefix}:max_pressure_pa:=5000' in line, line
        assert '/rig_b/syringe_pump, /rig_b/actuator, /rig_b/camera' in line, line


def test_a_bad_value_for_one_node_of_a_namespaced_rig_is_refused_naming_it(ros_env, tmp_path):
    scene = f'scene:={write_scene(tmp_path)}'
    # Ours, naming the node of the three and the parameter (rclpy's said "Invalid parameter
    # value (0) for parameter. Reason: rate_hz: must be > 0, got 0: rate_hz").
    line = _one_error_line(_run(ros_env, tmp_path, 'rig', '-r', '__ns:=/rig_b', '-p', scene,
                                '-p', 'camera:rate_hz:=0'), 'rig')
    assert line == 'rig: error: /rig_b/camera: parameter rate_hz: must be > 0, got 0', line
    # The fully qualified form, refused for its value and not for its form (no quoting hint);
    # a range rclpy checks itself (from the descriptor) is said in our words too.
    line = _one_error_line(_run(ros_env, tmp_path, 'syringe_pump', '-r', '__ns:=/rig_b',
                                '-p', scene, '-p', 'rig_b/syringe_pump:cycles:=0'),
                           'syringe_pump')
    assert line == 'syringe_pump: error: /rig_b/syringe_pump: parameter cycles: must be >= 1, ' \
        'got 0', line
    # A value rcl cannot read is named as typed, with the hint where it helps.
    line = _one_error_line(_run(ros_env, tmp_path, 'rig', '-r', '__ns:=/rig_b', '-p', scene,
                                '-p', 'syringe_pump:legs:=[{inflate_to_m3: 5.0e-6}]'), 'rig')
    assert '-p syringe_pump:legs:=[{inflate_to_m3: 5.0e-6}]' in line, line
    assert 'quote a value' in line, line


def test_a_parameter_no_node_has_is_refused(ros_env, tmp_path):
    scene = f'scene:={write_scene(tmp_path)}'
    for rule, where in (('syringe_pump:max_presure_pa:=5000', '/rig_b/syringe_pump'),
                        ('max_presure_pa:=5000',
                         '/rig_b/syringe_pump, /rig_b/actuator, /rig_b/camera')):
        line = _one_error_line(_run(ros_env, tmp_path, 'rig', '-r', '__ns:=/rig_b',
                                    '-p', scene, '-p', rule), 'rig')
        assert f'-p {rule}: no parameter max_presure_pa on {where}' in line, line


def test_a_value_refused_at_run_time_is_our_one_line(context):
    # As `ros2 param set` asks: over the node's set_parameters service.
    pump = SyringePumpNode(context=context, parameter_overrides=[
        Parameter('scene', value='fig1_none'), Parameter('autostart', value=False)])
    asker = Node('asker', context=context)
    client = asker.create_client(SetParameters, '/syringe_pump/set_parameters')
    with spinning(context, pump, asker):
        assert client.wait_for_service(timeout_sec=STARTUP_TIMEOUT_S)

        def refused(name, value) -> str:
            future = client.call_async(SetParameters.Request(
                parameters=[Parameter(name, value=value).to_parameter_msg()]))
            wait_for(future.done, f'the answer to setting {name}')
            (result,) = future.result().results
            assert not result.successful
            return result.reason
        # rclpy types use_sim_time itself and said "Wrong parameter type, expected
        # 'Type.BOOL' got 'Type.STRING'".
        assert refused('use_sim_time', 'true') == \
            "use_sim_time: must be true or false, got string 'true'"
        assert refused('rate_hz', 0) == 'rate_hz: must be > 0, got 0'
        assert refused('rate_hz', 1.0e9) == 'rate_hz: must be <= 10000, got 1e+09'
        assert refused('scene', 'paper') == \
            'scene: read-only, it is set when the node starts (--ros-args -p scene:=...)'
        # The Python API says the same.
        (result,) = pump.set_parameters([Parameter('use_sim_time', value='yes')])
        assert result.reason == "use_sim_time: must be true or false, got string 'yes'"
        assert pump.get_parameter('use_sim_time').value is False


def test_use_sim_time_that_is_no_boolean_is_our_one_line(ros_env, tmp_path):
    # rcl reads yes/no/on/off as booleans (YAML 1.1); a word or a quoted 'true' is a string.
    for script, rule in (('camera', 'use_sim_time:=maybe'),
                         ('rig', "syringe_pump:use_sim_time:='true'")):
        line = _one_error_line(_run(ros_env, tmp_path, script, '-r', '__ns:=/rig_b',
                                    '-p', rule), script)
        assert 'use_sim_time: must be true or false, got string' in line, line
        assert 'Trying to set' not in line, line
