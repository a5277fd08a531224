"""softseq play: a bag replayed over DDS reaches a subscriber as recorded (launch-free)."""

from pathlib import Path
import subprocess
import sys
import threading
import time

from mcap.reader import make_reader
import pytest
from rcl_interfaces.srv import SetParameters
from rclpy.node import Node
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock
from scenes import fast_asymmetric

import softseq_ros
from softseq_ros.bag.reader import bag_summary
from softseq_ros.nodes import player as player_module
from softseq_ros.nodes.player import (
    CLOCK_QOS,
    BagPlayer,
    PlaybackClock,
    PlayError,
    message_class,
    parse_remaps,
    qos_from_bag,
)
from softseq_ros.testing import call_trigger, spinning, wait_for
from softseq_ros.wire import contract

pytestmark = pytest.mark.ros
CONFIG = Path(__file__).resolve().parents[1] / 'config'


@pytest.fixture(scope='module')
def small_bag(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp('replay')
    scene = fast_asymmetric(folder, 'replay', pump_rate_hz=20, camera_rate_hz=2,
                            triggers=(2.5e-5,))
    softseq_ros.run(scene, folder / 'bag')
    return folder / 'bag'


def _recorded(bag: Path, topics: list[str]) -> dict[str, list[bytes]]:
    out: dict[str, list[bytes]] = {topic: [] for topic in topics}
    with open(next(bag.glob('*.mcap')), 'rb') as stream:
        for _, channel, message in make_reader(stream).iter_messages(topics=topics,
                                                                     log_time_order=True):
            out[channel.topic].append(bytes(message.data))
    return out


def test_a_subscriber_receives_what_the_bag_holds(context, small_bag):
    topics = [contract.resolve(spec.name, '/') for spec in
              (contract.PUMP_COMMAND, contract.VOLUMES, contract.EVENTS)]
    # Rate 2: the latched volumes keep one sample (depth 1, as recorded), so a publisher far
    # faster than the listener's executor would overwrite samples before they are delivered.
    player = BagPlayer(str(small_bag), rate=2.0, clock=True, topics=topics, context=context)
    listener = Node('replay_listener', context=context)
    received: dict[str, list[bytes]] = {topic: [] for topic in topics}
    clock: list[int] = []
    lock = threading.Lock()
    for topic in topics:
        info = player.bag.channels[topic]
        qos = qos_from_bag(info.offered_qos_profiles, topic)
        qos.depth = 10000  # the listener keeps everything it gets

        def keep(data, topic=topic):
            with lock:
                received[topic].append(bytes(data))
        listener.create_subscription(message_class(info.type_name), topic, keep, qos, raw=True)
    listener.create_subscription(
        Clock, '/clock', lambda msg: clock.append(msg.clock.sec * 10**9 + msg.clock.nanosec),
        CLOCK_QOS)
    expected = _recorded(small_bag, topics)
    # QoS as recorded: the volumes are latched (transient local), the commands deep.
    assert player.publishers_by_topic[topics[1]].qos_profile.durability.name == \
        'TRANSIENT_LOCAL'
    assert player.publishers_by_topic[topics[0]].qos_profile.depth == 1000
    try:
        with spinning(context, player, listener):
            assert player.wait_for_subscribers(10.0)
            wait_for(lambda: all(p.get_subscription_count() for p in
                                 player.publishers_by_topic.values()), 'matching')
            result = player.play()
            total = sum(len(v) for v in expected.values())
            assert result.messages == total > 100
            wait_for(lambda: sum(len(v) for v in received.values()) >= total, 'the replay')
    finally:
        player.destroy_node()
        listener.destroy_node()
    for topic in topics:
        assert received[topic] == expected[topic], topic
    assert len(expected[topics[2]]) == 4  # the four snap-through events, in order
    assert clock and clock == sorted(clock)


def test_bad_options_are_refused_before_anything_is_published(context, small_bag):
    with pytest.raises(PlayError, match='rate: must be > 0'):
        BagPlayer(str(small_bag), rate=0.0, context=context)
    with pytest.raises(PlayError, match='no topic /nope'):
        BagPlayer(str(small_bag), topics=['/nope'], context=context)


# ------------------------------------------------------------------ ros2 bag play's options

def _listen(node: Node, topic: str, msg_type, qos) -> list:
    got: list = []
    lock = threading.Lock()

    def keep(data) -> None:
        with lock:
            got.append(bytes(data))
    node.create_subscription(msg_type, topic, keep, qos, raw=True)
    return got


def test_start_offset_remap_and_qos_overrides(context, small_bag, tmp_path):
    command = contract.resolve(contract.PUMP_COMMAND.name, '/')
    volumes = contract.resolve(contract.VOLUMES.name, '/')
    summary = bag_summary(small_bag)
    offset_s = 1.5
    with open(next(small_bag.glob('*.mcap')), 'rb') as stream:
        expected = [bytes(m.data) for _, _, m in make_reader(stream).iter_messages(
            topics=[command], log_time_order=True)
            if m.log_time >= summary.start_ns + int(offset_s * 1e9)]
    overrides = tmp_path / 'qos.yaml'
    overrides.write_text(f'{volumes}:\n  reliability: best_effort\n  durability: volatile\n'
                         '  history: keep_last\n  depth: 3\n'
                         '  deadline: {sec: 2, nsec: 0}\n')
    player = BagPlayer(str(small_bag), rate=20.0, topics=[command, volumes],
                       start_offset_s=offset_s, remap={command: '/replayed/command'},
                       qos_overrides_path=overrides, context=context)
    # Remapped: published under the new name only. Overridden: the file's QoS, not the bag's.
    assert player.publishers_by_topic[command].topic_name == '/replayed/command'
    qos = player.publishers_by_topic[volumes].qos_profile
    assert (qos.reliability.name, qos.durability.name, qos.depth) == (
        'BEST_EFFORT', 'VOLATILE', 3)
    assert qos.deadline.nanoseconds == 2_000_000_000
    assert player.publishers_by_topic[command].qos_profile.depth == 1000   # as recorded
    listener = Node('offset_listener', context=context)
    got = _listen(listener, '/replayed/command', message_class(contract.PUMP_COMMAND.type_name),
                  qos_from_bag(player.bag.channels[command].offered_qos_profiles, command))
    original = _listen(listener, command, message_class(contract.PUMP_COMMAND.type_name),
                       qos_from_bag(player.bag.channels[command].offered_qos_profiles, command))
    with spinning(context, player, listener):
        wait_for(lambda: player.publishers_by_topic[command].get_subscription_count() == 1,
                 'the listener on the remapped topic')
        player.play()
        wait_for(lambda: len(got) >= len(expected), 'the replay from the offset')
    # Exactly the messages from the offset on, none before it, none on the recorded name.
    assert got == expected and 0 < len(expected) < summary.topics[command].message_count
    assert original == []


def test_bad_play_options_are_refused_naming_what_is_wrong(context, small_bag, tmp_path):
    command = contract.resolve(contract.PUMP_COMMAND.name, '/')
    with pytest.raises(PlayError, match='start offset must be a finite number'):
        BagPlayer(str(small_bag), start_offset_s=-1.0, context=context)
    with pytest.raises(PlayError, match=r"start offset 1e\+06 s is past the bag's end"):
        BagPlayer(str(small_bag), start_offset_s=1e6, context=context)
    with pytest.raises(PlayError, match='--remap /nope:=/x: no topic /nope'):
        BagPlayer(str(small_bag), remap={'/nope': '/x'}, context=context)
    with pytest.raises(PlayError, match=r"'/a b' is not a valid topic name"):
        BagPlayer(str(small_bag), remap={command: '/a b'}, context=context)
    with pytest.raises(PlayError, match='expected FROM:=TO'):
        parse_remaps(['/pump/command=/x'])
    assert parse_remaps([f'{command}:=/x']) == {command: '/x'}
    bad = tmp_path / 'bad.yaml'
    for text, reason in ((f'{command}:\n  reliability: sometimes\n',
                          rf"{bad}: {command}.reliability: 'sometimes' is none of"),
                         (f'{command}:\n  depht: 3\n', rf'{command}.depht: unknown QoS policy'),
                         ('/elsewhere:\n  depth: 3\n', r'topic /elsewhere: not in the bag'),
                         (f'{command}:\n  depth: -1\n', r'depth: expected an integer >= 0'),
                         ('[1, 2]\n', 'expected a mapping of topic names')):
        bad.write_text(text)
        with pytest.raises(PlayError, match=reason):
            BagPlayer(str(small_bag), qos_overrides_path=bad, context=context)


def test_the_playback_clock_keeps_the_bag_time_reached_across_rate_changes_and_pauses(
        monkeypatch):
    wall = [100.0]
    monkeypatch.setattr(player_module.time, 'monotonic', lambda: wall[0])
    clock = PlaybackClock(2.0)
    clock.start(1_000)
    wall[0] += 1.0
    assert clock.now_ns() == 1_000 + 2e9
    clock.set_rate(0.5)                  # from the bag time reached, at the new rate
    wall[0] += 2.0
    assert clock.now_ns() == 1_000 + 3e9
    assert clock.set_paused(True) and not clock.set_paused(True)
    wall[0] += 50.0                      # paused: the bag time stands still
    assert clock.now_ns() == 1_000 + 3e9
    assert not clock.wait_until(1_000 + 3e9 + 1, 0.0)
    assert clock.set_paused(False)
    wall[0] += 2.0
    assert clock.now_ns() == 1_000 + 4e9
    assert clock.wait_until(1_000 + 4e9, 0.0)


def test_pause_resume_toggle_and_rate_over_ros(context, small_bag):
    command = contract.resolve(contract.PUMP_COMMAND.name, '/')
    total = bag_summary(small_bag).topics[command].message_count
    player = BagPlayer(str(small_bag), rate=1.0, topics=[command], context=context)
    listener = Node('pause_listener', context=context)
    got = _listen(listener, command, message_class(contract.PUMP_COMMAND.type_name),
                  qos_from_bag(player.bag.channels[command].offered_qos_profiles, command))
    set_rate = listener.create_client(SetParameters, '/softseq_player/set_parameters')
    with spinning(context, player, listener):
        wait_for(lambda: player.publishers_by_topic[command].get_subscription_count() == 1,
                 'the listener')
        replay = threading.Thread(target=player.play, daemon=True)
        replay.start()
        wait_for(lambda: len(got) >= 5, 'the first messages')
        answer = call_trigger(listener, '/softseq_player/pause')
        assert (answer.success, answer.message) == (True, 'paused')
        assert call_trigger(listener, '/softseq_player/is_paused').success
        assert call_trigger(listener, '/softseq_player/pause').message == 'already paused'
        paused_at = player.clock_source.now_ns()
        count = len(got)
        # Paused: the bag time stands still and nothing more goes out (one message may have
        # been on its way as the pause came). Something not happening takes a while to see.
        time.sleep(0.3)
        assert player.clock_source.now_ns() == paused_at and len(got) <= count + 1
        assert call_trigger(listener, '/softseq_player/toggle_paused').message == 'playing'
        assert not call_trigger(listener, '/softseq_player/is_paused').success
        # The rate, set at run time as a parameter: refused with a reason, or taken.
        for value, ok in ((Parameter('rate', value=0.0), False),
                          (Parameter('rate', value='fast'), False),
                          (Parameter('rate', value=50), True)):
            future = set_rate.call_async(SetParameters.Request(
                parameters=[value.to_parameter_msg()]))
            wait_for(future.done, 'the answer of set_parameters')
            result, = future.result().results
            assert result.successful == ok, result.reason
            if not ok:
                assert 'rate: must be' in result.reason
        assert player.rate == 50.0
        replay.join(timeout=30.0)
        assert not replay.is_alive()
        wait_for(lambda: len(got) == total, 'every message')
    expected = _recorded(small_bag, [command])[command]
    assert got == expected


def test_the_command_refuses_bad_play_options_in_one_line(small_bag, tmp_path, ros_env):
    # One start of the command (a second each on a loaded machine); the options' other
    # refusals are the player's, tested above in this process.
    for options, reason in ((['--qos-profile-overrides-path', str(tmp_path / 'none.yaml')],
                             'cannot read the QoS overrides'),):
        result = subprocess.run([sys.executable, '-m', 'softseq_ros.cli', 'play',
                                 str(small_bag), *options], capture_output=True, text=True,
                                env=ros_env, timeout=120, stdin=subprocess.DEVNULL)
        assert result.returncode == 2, result.stderr
        line, = result.stderr.strip().splitlines()
        assert line.startswith('softseq play: ') and reason in line, line
