"""
Replay a bag on its topics, with its timing and QoS (``softseq play BAG``).

This serves where ``ros2 bag play`` is not installed. Each recorded topic gets a publisher of
its recorded type with the QoS the bag says it was offered (``offered_qos_profiles``;
rosbag2's default when a bag does not say), under the name it was recorded with. Messages go
out as the recorded CDR bytes (rclpy publishes serialized messages as they are), in log-time
order, spaced as recorded divided by ``rate``; with ``clock`` the bag's time is published on
``/clock`` (rosgraph_msgs/Clock) before each message, so nodes with ``use_sim_time`` follow
the recording.

SIGINT and SIGTERM end a replay as they end ``softseq run``: held while rclpy loads and the
publishers are made (a signal inside an import would leave a half-loaded module and a
misleading error), then acting between two messages; the replay closes its node and context
and the command exits 130 or 143. A SIGINT that the parent shell set to be ignored (a
background job) still stops it, as it stops ``softseq run``.
"""

from dataclasses import dataclass
import importlib
import threading
import time
from typing import Any, Iterator

from mcap.reader import make_reader
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
import yaml

from softseq_ros.bag.arrays import BagArrays, open_bag
from softseq_ros.errors import UserError
from softseq_ros.rig import contract
from softseq_ros.stopping import HeldSignals

CLOCK_TOPIC = contract.CLOCK.name
# Longest sleep between two looks at the stop signals held (a replay at a slow rate sleeps long).
SIGNAL_POLL_S = 0.05
# rclpy's TimeSource subscribes to /clock with this QoS.
CLOCK_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)
_RELIABILITY = {'reliable': ReliabilityPolicy.RELIABLE, 1: ReliabilityPolicy.RELIABLE,
                'best_effort': ReliabilityPolicy.BEST_EFFORT, 2: ReliabilityPolicy.BEST_EFFORT}
_DURABILITY = {'transient_local': DurabilityPolicy.TRANSIENT_LOCAL,
               1: DurabilityPolicy.TRANSIENT_LOCAL, 'volatile': DurabilityPolicy.VOLATILE,
               2: DurabilityPolicy.VOLATILE}


class PlayError(UserError):
    """A bag or an option that the player cannot use."""


def message_class(type_name: str) -> Any:
    """The rclpy message class of ``pkg/msg/Type``."""
    parts = type_name.split('/')
    package, name = parts[0], parts[-1]
    try:
        return getattr(importlib.import_module(f'{package}.msg'), name)
    except (ImportError, AttributeError):
        raise PlayError(f'message type {type_name} is not installed here') from None


def qos_from_bag(offered: str, topic: str) -> QoSProfile:
    """The QoS a bag says its publisher offered; rosbag2's default (reliable, volatile) else."""
    profiles = []
    if offered.strip():
        try:
            profiles = yaml.safe_load(offered) or []
        except yaml.YAMLError as err:
            raise PlayError(f'topic {topic}: offered_qos_profiles is not YAML ({err})') from None
    if not profiles:
        return QoSProfile(depth=10)
    first = profiles[0]
    depth = int(first.get('depth', 10) or 10)
    history = HistoryPolicy.KEEP_ALL if first.get('history') in ('keep_all', 2) \
        else HistoryPolicy.KEEP_LAST
    return QoSProfile(history=history, depth=depth,
                      reliability=_RELIABILITY.get(first.get('reliability'),
                                                   ReliabilityPolicy.RELIABLE),
                      durability=_DURABILITY.get(first.get('durability'),
                                                 DurabilityPolicy.VOLATILE))


@dataclass
class PlayResult:
    """What a replay sent."""

    messages: int = 0
    loops: int = 0


class BagPlayer(Node):
    """Publishes a bag's messages on their topics; :meth:`play` runs the replay."""

    def __init__(self, bag: str, *, rate: float = 1.0, loop: bool = False,
                 clock: bool = False, topics: list[str] | None = None,
                 **node_options: Any) -> None:
        """Open the bag and create one publisher per topic (refuses bad options first)."""
        if not rate > 0.0:
            raise PlayError(f'rate must be > 0, got {rate}')
        self.bag: BagArrays = open_bag(bag)
        unknown = sorted(set(topics or []) - set(self.bag.channels))
        if unknown:
            raise PlayError(f'{bag}: no topic {", ".join(unknown)} in this bag')
        super().__init__('softseq_player', **node_options)
        self.rate = float(rate)
        self.loop = bool(loop)
        self.topics = list(topics) if topics else sorted(self.bag.channels)
        self.publishers_by_topic = {}
        for topic in self.topics:
            info = self.bag.channels[topic]
            self.publishers_by_topic[topic] = self.create_publisher(
                message_class(info.type_name), topic,
                qos_from_bag(info.offered_qos_profiles, topic))
        self.clock_publisher = self.create_publisher(Clock, CLOCK_TOPIC, CLOCK_QOS) \
            if clock else None
        self._stop = threading.Event()
        # Stop signals held by the caller (HeldSignals.pending): non-empty ends the replay.
        self.signals: list[int] = []

    def stop(self) -> None:
        """Ask a running :meth:`play` to end after the current message."""
        self._stop.set()

    def _stopped(self) -> bool:
        return bool(self.signals) or self._stop.is_set()

    def _sleep(self, seconds: float) -> None:
        """Sleep, looking at the held stop signals at least every SIGNAL_POLL_S."""
        deadline = time.monotonic() + seconds
        while not self._stopped():
            left = deadline - time.monotonic()
            if left <= 0.0:
                return
            self._stop.wait(min(left, SIGNAL_POLL_S))

    def wait_for_subscribers(self, timeout_s: float) -> bool:
        """Wait until every played topic has a subscriber (or the timeout); True if so."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and not self._stopped():
            if all(p.get_subscription_count() > 0 for p in self.publishers_by_topic.values()):
                return True
            time.sleep(0.01)
        return False

    def _messages(self) -> Iterator[tuple[str, int, bytes]]:
        wanted = set(self.topics)
        for file in self.bag.files:
            with open(file, 'rb') as stream:
                for _, channel, message in make_reader(stream).iter_messages(
                        topics=list(wanted), log_time_order=True):
                    yield channel.topic, message.log_time, message.data

    def play(self) -> PlayResult:
        """Replay until the bag ends (or forever with ``loop``, until :meth:`stop`)."""
        result = PlayResult()
        while not self._stopped():
            start_wall = time.monotonic()
            first_log = None
            for topic, log_time, data in self._messages():
                if self._stopped():
                    break
                if first_log is None:
                    first_log = log_time
                due = start_wall + (log_time - first_log) * 1e-9 / self.rate
                delay = due - time.monotonic()
                if delay > 0.0:
                    self._sleep(delay)
                    if self._stopped():
                        break
                if self.clock_publisher is not None:
                    stamp = Clock()
                    stamp.clock.sec, stamp.clock.nanosec = divmod(int(log_time), 1_000_000_000)
                    self.clock_publisher.publish(stamp)
                self.publishers_by_topic[topic].publish(data)
                result.messages += 1
            result.loops += 1
            if not self.loop:
                break
        return result


def play(bag: str, rate: float = 1.0, loop: bool = False, clock: bool = False,
         topics: list[str] | None = None, wait_s: float = 0.0,
         args: list[str] | None = None, held: HeldSignals | None = None) -> PlayResult:
    """
    Run a replay in its own rclpy context until it ends or SIGINT/SIGTERM.

    A stop signal ends the replay between two messages; once the node and the context are
    closed, KeyboardInterrupt (SIGINT) or TerminatedError (SIGTERM) is raised. ``held`` is a
    caller's :class:`HeldSignals` already in force (one that also covered the import of this
    module); without one, the signals are held from here on.
    """
    if held is None:
        with HeldSignals() as own:
            return play(bag, rate, loop, clock, topics, wait_s, args, own)
    held.check()
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

    held.check()
    context = rclpy.Context()
    rclpy.init(args=args, context=context)
    player = None
    try:
        player = BagPlayer(bag, rate=rate, loop=loop, clock=clock, topics=topics,
                           context=context)
        player.signals = held.pending
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(player)
        spinner = threading.Thread(target=_spin,
                                   args=(executor, ExternalShutdownException, context),
                                   daemon=True)
        spinner.start()
        try:
            if wait_s > 0.0:
                player.wait_for_subscribers(wait_s)
            result = player.play()
        finally:
            rclpy.try_shutdown(context=context)
            spinner.join(timeout=2.0)
    finally:
        if player is not None:
            player.destroy_node()
        rclpy.try_shutdown(context=context)
    held.check()
    return result


def _spin(executor: Any, shutdown: type[BaseException], context: Any) -> None:
    try:
        executor.spin()
    except shutdown:
        pass  # the context was shut down: the replay is over
    except Exception:
        # A shutdown under a running callback fails that callback (context invalid): after a
        # shutdown that is the end of the replay, not a bug.
        if context.ok():
            raise
