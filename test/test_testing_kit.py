"""
softseq_ros.testing, the public kit for launch-free node tests: the README's example runs, and
each helper does what a test relies on (no sample lost, failures surfaced and named).
"""

from pathlib import Path
import re

import pytest
from rclpy.node import Node
from rclpy.qos import QoSProfile
from sensor_msgs.msg import JointState

from softseq_ros.nodes.core_node import qos_profile
from softseq_ros.testing import Collector, call_trigger, spinning, wait_for
from softseq_ros.wire import contract

pytestmark = pytest.mark.ros
README = Path(__file__).resolve().parents[1] / 'README.md'


def readme_example() -> str:
    """The Python block of the README's section on testing nodes without launch."""
    text = README.read_text(encoding='utf-8')
    section = text[text.index('## Testing nodes without launch'):]
    section = section[:section.index('\n## ', 3)]
    blocks = re.findall(r'```python\n(.*?)```', section, re.S)
    assert len(blocks) == 1, 'the section should hold one Python example'
    return blocks[0]


def test_the_readme_example_runs_and_sees_the_rig_answer_every_command(capsys):
    code = readme_example()
    assert len(code.splitlines()) <= 25
    exec(compile(code, str(README), 'exec'), {})
    line = capsys.readouterr().out.strip().splitlines()[-1]
    match = re.fullmatch(r'(\d+) commands, up to ([\d.]+) mL injected, ([\d.]+) mL in the '
                         r'segments', line)
    assert match, line
    # 2 mL in and out at 2 mL/s at 50 Hz: about 100 commands on an idle machine, fewer when
    # a loaded one skips ticks (its peak command then falls short of 2 mL).
    assert int(match[1]) >= 10
    assert 0.0 < float(match[2]) <= 2.0
    # The segments hold their 20 mL at rest plus the most the pump injected: the answer to
    # the peak command arrived too.
    assert float(match[3]) == pytest.approx(20.0 + float(match[2]), abs=2e-6)


def test_a_collector_keeps_a_burst_that_a_probe_of_the_contract_depth_loses(context):
    volumes = contract.VOLUMES
    # The probe that lost samples: the latched volumes read keep-last 1, as the rig's own
    # consumers read them (they want the newest state only).
    probe_qos = qos_profile(contract.Qos(1, reliable=True, latched=True))
    publisher_node = Node('burst', context=context)
    publisher = publisher_node.create_publisher(JointState, '/actuator/volumes',
                                                qos_profile(volumes.qos))
    collector = Collector(['actuator/volumes'], context)
    probe_messages: list = []
    probe = Node('probe', context=context)
    probe.create_subscription(JointState, '/actuator/volumes', probe_messages.append,
                              probe_qos)
    # Published while nothing is spun: everything waits in the readers' queues, as when a
    # test thread falls behind the rig.
    wait_for(lambda: publisher.get_subscription_count() == 2, 'the collector and the probe')
    burst = 200
    for number in range(burst):
        publisher.publish(JointState(name=['a'], position=[float(number)]))
    with spinning(context, publisher_node, collector, probe):
        got = collector.wait_for_count('actuator/volumes', burst)
        wait_for(lambda: probe_messages, 'the probe to get something')
        assert [m.position[0] for m in got] == [float(n) for n in range(burst)]
        assert len(probe_messages) < burst / 2


def test_a_collector_takes_topics_outside_the_contract_and_names_what_it_waits_for(context):
    collector = Collector([], context, namespace='/rig9')
    collector.add('/elsewhere', JointState, QoSProfile(depth=1))
    assert collector.messages('/elsewhere') == []
    with pytest.raises(AssertionError, match=r'publishers on /elsewhere; none on /elsewhere'):
        collector.wait_for_publishers(timeout=0.05)
    with pytest.raises(AssertionError, match=r'1 messages on /elsewhere; 0 arrived'):
        collector.wait_for_count('/elsewhere', 1, timeout=0.05)
    assert collector.absolute('pump/status') == '/rig9/pump/status'
    collector.destroy_node()


def test_a_failing_callback_fails_the_test_and_a_missing_service_is_named(context):
    node = Node('failing', context=context)

    calls: list[int] = []

    def fail() -> None:
        calls.append(1)
        raise RuntimeError('a callback broke')

    node.create_timer(0.01, fail)
    with pytest.raises(RuntimeError, match='a callback broke'):
        with spinning(context, node):
            wait_for(lambda: calls, 'the timer to fire')
    caller = Node('caller', context=context)
    with spinning(context, caller):
        with pytest.raises(AssertionError, match='waiting for the service /nobody/start'):
            call_trigger(caller, '/nobody/start', timeout=0.1)
