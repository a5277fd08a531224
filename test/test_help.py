"""
Every executable answers ``--help`` with its parameters, topics and services, starting nothing.

The executables run as a user runs them (console scripts, a fresh working directory); the
parameters the help must name are those the real nodes declare, built here over real rclpy.
"""

import os
import re
import subprocess
import sys

import pytest
from rclpy.parameter import Parameter

from softseq_ros.nodes.actuator import ActuatorNode
from softseq_ros.nodes.camera import CameraNode
from softseq_ros.nodes.pressure_hold import PressureHoldNode
from softseq_ros.nodes.recorder import Recorder
from softseq_ros.nodes.runner import node_role
from softseq_ros.nodes.sim_clock import SimClockNode
from softseq_ros.nodes.syringe_pump import SyringePumpNode
from softseq_ros.wire import contract

pytestmark = pytest.mark.ros

# A node that starts instead of answering never ends by itself: this bounds the wait for it.
HELP_TIMEOUT_S = 120.0

EXECUTABLES = {
    'syringe_pump': [SyringePumpNode],
    'actuator': [ActuatorNode],
    'camera': [CameraNode],
    'pressure_hold': [PressureHoldNode],
    'recorder': [Recorder],
    'sim_clock': [SimClockNode],
    'rig': [SyringePumpNode, ActuatorNode, CameraNode],
}


def _declared_names(context, node_class, tmp_path) -> set[str]:
    """The parameters a real node of ``node_class`` has once built."""
    overrides = {ActuatorNode: [Parameter('state_file', value='')],
                 Recorder: [Parameter('output', value=str(tmp_path / 'bag'))]}
    node = node_class(context=context, parameter_overrides=overrides.get(node_class, []))
    try:
        names = set(node.get_parameters_by_prefix(''))
    finally:
        if isinstance(node, Recorder):
            node.close_bag()
        node.destroy_node()
    return names


def _help(script: str, args: list[str], cwd, env) -> subprocess.CompletedProcess:
    return subprocess.run([os.path.join(sys.prefix, 'bin', script), *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=HELP_TIMEOUT_S)


def _sections(text: str) -> dict[str, str]:
    """The help's text per 'Parameters of NODE' section, up to the next such section."""
    parts = text.split('Parameters of ')[1:]
    return {part.split(' ', 1)[0]: part for part in parts}


@pytest.mark.parametrize('script', sorted(EXECUTABLES))
def test_help_lists_what_the_node_declares_and_starts_nothing(script, context, ros_env,
                                                              tmp_path):
    cwd, home = tmp_path / 'cwd', tmp_path / 'home'
    cwd.mkdir()
    home.mkdir()
    # A ROS home of its own: rclpy would log there, the actuator write its state file there.
    result = _help(script, ['--help'], cwd, {**ros_env, 'ROS_HOME': str(home)})
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith(f'usage: {script} ')
    assert result.stderr == ''
    # Nothing was started: no bag folder, no state file, no log, nothing in the working folder.
    assert list(cwd.iterdir()) == []
    assert list(home.iterdir()) == []
    sections = _sections(result.stdout)
    for node_class in EXECUTABLES[script]:
        section = sections[node_class.NODE_NAME]
        for name in _declared_names(context, node_class, tmp_path):
            assert f'\n  {name}: ' in section, f'{script} --help: parameter {name} missing'
    if script != 'recorder':
        for node_class in EXECUTABLES[script]:
            role = node_role(node_class)
            produced = [t for t in contract.RIG_TOPICS + (contract.CLOCK,)
                        if t.producer in (role, node_class.NODE_NAME)]
            assert produced
            for topic in produced:
                assert f'publishes {topic.name} [{topic.type_name}]' in result.stdout


def test_help_shows_ranges_read_only_and_services(ros_env, tmp_path):
    result = _help('syringe_pump', ['-h', '--ros-args', '-p', 'autostart:=true'], tmp_path,
                   ros_env)
    assert result.returncode == 0, result.stderr
    text = ' '.join(result.stdout.split())
    assert 'rate_hz: double, range > 0 and <= 10000; integer or double, default 50' in text
    assert 'autostart: bool, default true, read-only' in text
    for service in SyringePumpNode.SERVICES:
        assert f'~/{service}: ' in text
    # The quoting a YAML-valued parameter needs on the command line, where a user looks.
    assert '-p "legs:=\'[{inflate_to_m3: 2.0e-5}, {deflate_to_m3: 0.0}]\'"' in text
    assert 'subscribes actuator/volumes [sensor_msgs/msg/JointState]' in text
    assert list(tmp_path.iterdir()) == []


def test_help_names_only_scene_outputs_as_scene_outputs(ros_env, tmp_path):
    # 'flows' is no key of a scene's outputs: the channel flows come with the volumes where
    # the scene has a network, and the help said 'scene output flows'.
    from softseq_ros.scene.outputs import OUTPUT_NAMES

    result = _help('actuator', ['--help'], tmp_path, ros_env)
    assert result.returncode == 0, result.stderr
    text = ' '.join(result.stdout.split())
    named = re.findall(r', scene output (\w+)\)', text)
    assert named and set(named) <= set(OUTPUT_NAMES)
    assert ('publishes actuator/channel_flows [sensor_msgs/msg/JointState] (depth 1000, '
            'reliable, with scene output volumes when the scene has a network)') in text


def test_help_after_ros_args_is_no_help_flag(ros_env, tmp_path):
    # After --ros-args the arguments are rcl's: -h there is refused by rcl, not read as help.
    result = _help('sim_clock', ['--ros-args', '--help'], tmp_path, ros_env)
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        "sim_clock: error: unknown ROS argument(s) after --ros-args: ['--help']; -h/--help "
        'goes before --ros-args']
    assert 'usage: sim_clock' not in result.stdout
