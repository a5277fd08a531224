"""softseq play: a bag replayed over DDS reaches a subscriber as recorded (launch-free)."""

from pathlib import Path
import threading

from mcap.reader import make_reader
import pytest
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
import yaml

from softseq_ros.batch import run_scene
from softseq_ros.nodes.player import CLOCK_QOS, BagPlayer, PlayError, message_class, qos_from_bag
from softseq_ros.rig import contract
from softseq_ros.testing import spinning, wait_for

pytestmark = pytest.mark.ros
CONFIG = Path(__file__).resolve().parents[1] / 'config'


@pytest.fixture(scope='module')
def small_bag(tmp_path_factory) -> Path:
    scene = yaml.safe_load((CONFIG / 'fig1_asymmetric.yaml').read_text())
    scene['name'] = 'replay'
    scene['pump'].update(flow_rate_m3_per_s=2.0e-5, rate_hz=20,
                         legs=[{'inflate_to_m3': 5.0e-5}, {'deflate_to_m3': 0.0}])
    scene['camera'] = {'rate_hz': 2, 'trigger_injected_m3': [2.5e-5]}
    folder = tmp_path_factory.mktemp('replay')
    (folder / 'replay.yaml').write_text(yaml.safe_dump(scene))
    run_scene(folder / 'replay.yaml', folder / 'bag', show_progress=False)
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
    with pytest.raises(PlayError, match='rate must be > 0'):
        BagPlayer(str(small_bag), rate=0.0, context=context)
    with pytest.raises(PlayError, match='no topic /nope'):
        BagPlayer(str(small_bag), topics=['/nope'], context=context)
