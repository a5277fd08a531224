"""
The actuator resumes only after an abnormal end: real console-script processes, real DDS.

One experiment after another must start at rest: a clean stop (SIGINT, handled) marks the state
file closed and the next start is at rest without a word about resuming. A ``kill -9`` leaves
the file open: the next start resumes on the branch the history put it on and says so loudly,
with how to start at rest. fig1_asymmetric inside its hysteresis loop tells the two apart: the
same commanded volume sits on the deflation branch after the history, on the inflation branch
from rest.
"""

import json
import signal
import time

import numpy as np
import pytest
from rclpy.node import Node
from scenes import inside_the_hysteresis_loop
from sensor_msgs.msg import JointState
from test_nodes_processes import STARTUP_TIMEOUT_S, node_processes

from softseq_ros.nodes.core_node import qos_profile
from softseq_ros.quasistatic.equilibrium import EquilibriumMap
from softseq_ros.rig.build import actuator_core
from softseq_ros.scene.loader import load_scene
from softseq_ros.testing import Collector, spinning, wait_for
from softseq_ros.wire import contract
from softseq_ros.wire.values import WARNING, PumpCommand

pytestmark = pytest.mark.ros

SCENE = 'fig1_asymmetric'


class Driver(Node):
    """Commands the actuator as a pump would and keeps its answers."""

    def __init__(self, context) -> None:
        super().__init__('resume_rule_driver', context=context)
        self.collector = Collector(['actuator/volumes'], context)
        self.answers = self.collector.received['/actuator/volumes']
        self.commands = self.create_publisher(JointState, contract.PUMP_COMMAND.name,
                                              qos_profile(contract.PUMP_COMMAND.qos))

    def command(self, injected_m3: float) -> None:
        msg = JointState(name=['syringe'], position=[injected_m3], velocity=[0.0])
        msg.header.stamp = self.get_clock().now().to_msg()
        self.commands.publish(msg)

    def wait_for_actuator(self) -> None:
        wait_for(lambda: self.commands.get_subscription_count() == 1
                 and self.collector.matched('/actuator/volumes'),
                 'the actuator on pump/command and actuator/volumes', timeout=STARTUP_TIMEOUT_S)

    def answer_at(self, injected_m3: float, rest_m3: float, after: int, scale: float):
        """
        Command ``injected_m3`` until an answer (after the first ``after``) holds it; return it.

        Sent again and again: after a ``kill -9`` the dead actuator's subscription still counts
        until its lease runs out, so a match says nothing about the new one, and a command
        repeated changes nothing.
        """
        def found():
            return next((np.array(m.position) for m in self.answers[after:]
                         if abs(sum(m.position) - rest_m3 - injected_m3) < 1e-9 * scale), None)

        def sent_and_found():
            if found() is None:
                self.command(injected_m3)
                time.sleep(0.2)
            return found() is not None
        wait_for(sent_and_found, f'an answer at {injected_m3 * 1e6:.4f} mL',
                 timeout=STARTUP_TIMEOUT_S)
        return found()


def _stop_and_restart(context, ros_env, ros_home, tmp_path, stop_signal):
    """
    Run the actuator into the loop, stop it with ``stop_signal``, restart it, command the same
    volume. Returns (the state file after the stop, the answer after the restart, its log, the
    hysteresis states, the stopped process's exit code).
    """
    emap = EquilibriumMap(load_scene(SCENE).segments)
    middle, inflating, deflating = inside_the_hysteresis_loop(emap)
    top = 0.98 * emap.injected_range[1]
    rest, scale = emap.total_rest_volume, emap.v_scale
    state_file = ros_home / 'softseq' / 'actuator.json'
    params = {'scene': SCENE, 'resume_timeout_s': 0.2}
    driver = Driver(context)
    with node_processes(ros_env, tmp_path) as start, \
            spinning(context, driver, driver.collector):
        first = start('first', 'actuator', **params)
        driver.wait_for_actuator()
        # The jump rule walks every volume in between: up to the top, back into the loop.
        driver.command(top)
        held = driver.answer_at(middle, rest, 0, scale)
        np.testing.assert_allclose(held, deflating, rtol=1e-9, atol=1e-9 * scale)
        first.send_signal(stop_signal)
        code = first.wait(timeout=30)
        saved = json.loads(state_file.read_text(encoding='utf-8'))
        before = len(driver.answers)
        start('second', 'actuator', **params)
        driver.wait_for_actuator()
        answer = driver.answer_at(middle, rest, before, scale)
    log = (tmp_path / 'second.log').read_text(encoding='utf-8', errors='replace')
    return saved, answer, log, (inflating, deflating, scale), code


def test_after_a_clean_stop_the_actuator_starts_at_rest_without_a_word(
        context, ros_env, ros_home, tmp_path):
    saved, answer, log, (inflating, deflating, scale), code = _stop_and_restart(
        context, ros_env, ros_home, tmp_path, signal.SIGINT)
    assert code == 0
    assert saved['closed'] is True
    # From rest, the same volume is on the inflation branch: the history was not carried over.
    np.testing.assert_allclose(answer, inflating, rtol=1e-9, atol=1e-9 * scale)
    assert np.max(np.abs(answer - deflating)) > 1e-3 * scale
    assert 'resum' not in log
    assert 'no previous state' not in log


def test_after_a_kill_the_actuator_resumes_and_says_so_loudly(
        context, ros_env, ros_home, tmp_path):
    saved, answer, log, (inflating, deflating, scale), _ = _stop_and_restart(
        context, ros_env, ros_home, tmp_path, signal.SIGKILL)
    assert saved['closed'] is False
    np.testing.assert_allclose(answer, deflating, rtol=1e-9, atol=1e-9 * scale)
    state_file = ros_home / 'softseq' / 'actuator.json'
    warning = next(line for line in log.splitlines() if 'resumed' in line)
    assert '[WARN]' in warning
    assert str(state_file) in warning
    assert ' mL injected' in warning
    # How to start at rest, as a user types it in a shell (bare '' would be eaten by it).
    assert '-p "state_file:=\'\'"' in warning
    assert f'delete {state_file}' in warning


def test_the_core_resumes_only_from_a_file_its_last_run_did_not_close(tmp_path):
    scene = load_scene(SCENE)
    state_file = tmp_path / 'actuator.json'
    first = actuator_core(scene, state_file=str(state_file))
    first.handle(PumpCommand(0, 1.0e-5, 0.0), 0)
    assert json.loads(state_file.read_text(encoding='utf-8'))['closed'] is False
    assert first.close() == []
    saved = json.loads(state_file.read_text(encoding='utf-8'))
    assert saved['closed'] is True and saved['injected_m3'] == pytest.approx(1.0e-5)
    # Closed: at rest, and not a word.
    second = actuator_core(scene, state_file=str(state_file))
    assert second.resume_from_file() == (False, [])
    assert second.model.saved()['injected_m3'] == 0.0
    # A run stopped while it still waits for a previous state leaves the file as it found it.
    state_file.write_text(json.dumps({**saved, 'closed': False}), encoding='utf-8')
    waiting = actuator_core(scene, state_file=str(state_file))
    waiting.begin_wait()
    waiting.close()
    assert json.loads(state_file.read_text(encoding='utf-8'))['closed'] is False
    resumed, notices = actuator_core(scene, state_file=str(state_file)).resume_from_file()
    assert resumed and notices[0].level == WARNING
