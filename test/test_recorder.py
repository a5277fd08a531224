"""The recorder node: QoS choices, and a real recording stopped with SIGTERM or SIGINT."""

from datetime import datetime, timezone
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

import pytest
import rclpy
from rclpy.duration import Duration
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64, String

from softseq_ros.bag.reader import bag_summary, read_bag
from softseq_ros.nodes.recorder import (
    RIG_TOPICS,
    default_output_directory,
    offered_profile,
    request_for_offers,
)

REPO = Path(__file__).resolve().parents[1]
TIMEOUT_S = 60.0


def test_default_output_is_a_utc_stamped_directory_under_bags():
    when = datetime(2025, 3, 4, 5, 6, 7, tzinfo=timezone.utc)
    assert default_output_directory(when) == Path('bags/rig_2025_03_04-05_06_07')
    # Relative: a recorder started in a rig's namespace records that rig.
    assert RIG_TOPICS and not any(topic.startswith('/') for topic in RIG_TOPICS)
    # By default every bag names the scene that made it.
    assert 'actuator/scene' in RIG_TOPICS


def test_request_is_reliable_and_latched_only_when_every_publisher_offers_it():
    reliable_latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                  durability=DurabilityPolicy.TRANSIENT_LOCAL)
    reliable = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.VOLATILE)
    best_effort = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT,
                             durability=DurabilityPolicy.VOLATILE)
    both = request_for_offers([reliable_latched])
    assert (both.reliability, both.durability) == (ReliabilityPolicy.RELIABLE,
                                                   DurabilityPolicy.TRANSIENT_LOCAL)
    mixed = request_for_offers([reliable_latched, reliable])
    assert (mixed.reliability, mixed.durability) == (ReliabilityPolicy.RELIABLE,
                                                     DurabilityPolicy.VOLATILE)
    # A reliable subscription would not match a best-effort publisher at all.
    assert request_for_offers([reliable, best_effort]).reliability == \
        ReliabilityPolicy.BEST_EFFORT


def test_offered_profile_uses_rosbag2_version_9_names():
    profile = offered_profile(QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=7, reliability=ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL, deadline=Duration(seconds=1.5)))
    assert profile['history'] == 'keep_last' and profile['depth'] == 7
    assert profile['reliability'] == 'best_effort'
    assert profile['durability'] == 'transient_local'
    assert profile['liveliness'] == 'system_default'
    assert profile['deadline'] == {'sec': 1, 'nsec': 500_000_000}


def _domain_id() -> str:
    # Each run gets its own DDS domain unless the caller chose one.
    return os.environ.get('ROS_DOMAIN_ID') or str(100 + os.getpid() % 100)


def _wait_for(condition, what: str) -> None:
    deadline = time.monotonic() + TIMEOUT_S
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f'timed out waiting for {what}')
        time.sleep(0.02)


@pytest.mark.ros
@pytest.mark.parametrize('stop', ['SIGTERM', 'SIGINT'])
def test_a_stop_signal_leaves_a_complete_bag(tmp_path, monkeypatch, stop):
    monkeypatch.setenv('ROS_DOMAIN_ID', _domain_id())
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join(filter(None, [str(REPO), env.get('PYTHONPATH')]))
    output = tmp_path / 'rig_bag'
    volumes = [1e-6 * i for i in range(40)]

    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node('recorder_test_publisher', context=context)
    recorder = None
    try:
        volume_pub = node.create_publisher(Float64, '/test/volume', 10)
        # Published before the recorder exists: only a transient_local request receives it.
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        phase_pub = node.create_publisher(String, '/test/phase', latched)
        phase_pub.publish(String(data='filling'))
        recorder = subprocess.Popen(
            [sys.executable, '-m', 'softseq_ros.nodes.recorder', '--ros-args',
             '-p', 'topics:=[/test/volume, /test/phase]',
             '-p', 'types:=["", std_msgs/msg/String]', '-p', f'output:={output}',
             '-r', '__ns:=/rig_a'],
            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        _wait_for(lambda: volume_pub.get_subscription_count() >= 1
                  and phase_pub.get_subscription_count() >= 1, 'the recorder to subscribe')
        for volume in volumes:
            volume_pub.publish(Float64(data=volume))
        # The recorder flushes periodically: wait until all messages are on disk.
        _wait_for(lambda: bag_summary(output).message_count == len(volumes) + 1,
                  'all messages in the bag')
        recorder.send_signal(getattr(signal, stop))
        log, _ = recorder.communicate(timeout=TIMEOUT_S)
        assert recorder.returncode == 0, log
        # A clean stop says so, and says nothing else (no failed publish on /rosout).
        assert f'closed {output} with {len(volumes) + 1} messages' in log, log
        assert 'Failed' not in log and 'rosout' not in log, log
        # The last line names the node as every line before it does, namespace and all.
        closed, = [line for line in log.splitlines() if 'closed ' in line]
        assert '[rig_a.recorder]: ' in closed, closed
    finally:
        if recorder is not None and recorder.poll() is None:
            recorder.kill()
            recorder.wait()
        node.destroy_node()
        rclpy.try_shutdown(context=context)

    assert (output / 'metadata.yaml').is_file()
    summary = bag_summary(output)
    assert summary.complete
    assert {t: (s.type_name, s.message_count) for t, s in summary.topics.items()} == {
        '/test/volume': ('std_msgs/msg/Float64', len(volumes)),
        '/test/phase': ('std_msgs/msg/String', 1)}
    messages = list(read_bag(output))
    assert [m.msg.data for m in messages if m.topic == '/test/volume'] == volumes
    assert [m.msg.data for m in messages if m.topic == '/test/phase'] == ['filling']
    log_times = [m.log_time_ns for m in messages]
    assert log_times == sorted(log_times)
