"""
Launch-free integration tests of the rig's nodes: real rclpy nodes over real DDS in one process.

What a test of a node needs besides the node itself, and what is easy to get subtly wrong:

- :func:`ros_context`: an rclpy Context of its own, shut down afterwards, so tests never share
  a graph through the global context.
- :func:`spinning`: the nodes spun by a SingleThreadedExecutor in a thread while the test
  body waits on conditions, then stopped in the order that cannot abort the process (shut
  the executor down, join its thread, then destroy the nodes).
- :class:`Collector`: a node that subscribes to contract topics with the contract's
  reliability and durability but a deep queue, and keeps every message. A probe of depth 1
  on the latched ``actuator/volumes`` (as the rig's own consumers read it, newest only) keeps
  only the newest sample when the test thread is slower than the publisher: it loses
  samples without a sign.
- :func:`wait_for` and :meth:`Collector.wait_for_publishers`: wait on a condition (a
  publisher matched, a count reached), never on a sleep: the first message after discovery
  is lost when nobody has matched yet, and a loaded machine is slow in ways no sleep guesses.
- :func:`call_trigger`: a ``std_srvs/Trigger`` call (the pump's ``~/start`` and so on) from a
  node that is being spun.

Give each test process its own ``ROS_DOMAIN_ID`` and ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``
(before rclpy creates its first participant), so parallel runs never see each other. Tests that
kill a node with SIGKILL and start it again need Fast DDS without its shared-memory transport
(the restarted node can take over the dead one's port and hear nothing): our own tests run on
UDP over the loopback interface alone, from the profile ``test/fastdds_udp_localhost.xml``
(``FASTRTPS_DEFAULT_PROFILES_FILE``, with ``ROS_AUTOMATIC_DISCOVERY_RANGE=SYSTEM_DEFAULT``, as
``test/conftest.py`` sets them).

Example (the README's, which a test runs)::

    from softseq_ros.nodes.actuator import ActuatorNode
    from softseq_ros.nodes.syringe_pump import SyringePumpNode
    from softseq_ros.testing import Collector, call_trigger, ros_context, spinning, wait_for
    from rclpy.parameter import Parameter

    with ros_context() as context:
        pump = SyringePumpNode(context=context, parameter_overrides=[
            Parameter('scene', value='fig1_none'), Parameter('autostart', value=False)])
        actuator = ActuatorNode(context=context, parameter_overrides=[
            Parameter('scene', value='fig1_none'), Parameter('state_file', value='')])
        collector = Collector(['pump/command', 'pump/status', 'actuator/volumes'], context)
        with spinning(context, pump, actuator, collector):
            collector.wait_for_publishers()
            assert call_trigger(collector, 'syringe_pump/start').success
            wait_for(lambda: collector.states()[-1:] == ['finished'], 'the programme to end')
"""

from contextlib import contextmanager
import json
import threading
import time
from typing import Any, Callable, Iterable, Iterator

from rclpy.context import Context
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile
from std_srvs.srv import Trigger

from softseq_ros.nodes.core_node import message_class, qos_profile
from softseq_ros.wire import contract

__all__ = ['COLLECTOR_DEPTH', 'TIMEOUT_S', 'Collector', 'call_trigger', 'ros_context',
           'spinning', 'stamp_ns', 'wait_for']

# Long enough for a node to start on a loaded 2-core machine; a wait ends as soon as its
# condition holds, so a generous bound costs nothing when all is well.
TIMEOUT_S = 15.0
# A collector's queue per topic: deeper than any burst a test publishes between two turns of
# its executor (the contract's own depths are for the rig's consumers, which keep up).
COLLECTOR_DEPTH = 10_000


@contextmanager
def ros_context(args: list[str] | None = None) -> Iterator[Context]:
    """An initialised rclpy Context of its own, shut down when the block ends."""
    import rclpy

    context = Context()
    rclpy.init(args=args, context=context)
    try:
        yield context
    finally:
        rclpy.try_shutdown(context=context)


def wait_for(condition: Callable[[], Any], what: str, timeout: float = TIMEOUT_S,
             explain: Callable[[], str] | None = None) -> None:
    """
    Poll ``condition`` (every 10 ms) until it is true; fail naming ``what`` after ``timeout`` s.

    ``explain`` (optional) returns what was seen instead, for the failure message. The nodes
    must be spun meanwhile (:func:`spinning`): this only watches.
    """
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            seen = f'; {explain()}' if explain is not None else ''
            raise AssertionError(f'timed out after {timeout:g} s waiting for {what}{seen}')
        time.sleep(0.01)


@contextmanager
def spinning(context: Context, *nodes: Node) -> Iterator[SingleThreadedExecutor]:
    """
    Spin ``nodes`` on a SingleThreadedExecutor in a thread; afterwards stop it and destroy them.

    The order of the ending matters: a node destroyed (or a context shut down) while the
    executor thread still waits on it can abort the process, so the executor is shut down
    and its thread joined before the nodes are destroyed.
    """
    executor = SingleThreadedExecutor(context=context)
    for node in nodes:
        executor.add_node(node)
    stopping = threading.Event()
    failures: list[BaseException] = []

    def spin() -> None:
        try:
            executor.spin()
        except ExternalShutdownException:
            pass
        except Exception as err:  # noqa: BLE001 - handed to the test thread below
            # The shutdown destroys the executor's guard condition, and a callback just
            # finishing may still trigger it (rclpy's InvalidHandle): that is the end of the
            # spin. Anything before the shutdown is a failure of the test.
            if not stopping.is_set():
                failures.append(err)

    thread = threading.Thread(target=spin, name='softseq-testing-spin', daemon=True)
    thread.start()
    try:
        yield executor
    finally:
        stopping.set()
        executor.shutdown(timeout_sec=10.0)
        thread.join(timeout=10.0)
        for node in nodes:
            node.destroy_node()
    if failures:
        raise failures[0]


def stamp_ns(header: Any) -> int:
    """A std_msgs/Header's stamp in nanoseconds."""
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


class Collector(Node):
    """
    A node that subscribes to rig topics and keeps every message it receives.

    ``topics`` are contract names (``'pump/command'``, ``'actuator/volumes'``, ...), resolved
    in ``namespace``; each subscription has the contract's reliability and durability (so it
    matches the rig's publishers and gets latched state) and a queue of ``depth`` messages.
    :attr:`received` maps each absolute topic name to the list of messages, in arrival order;
    :meth:`add` subscribes to a topic outside the contract.
    """

    def __init__(self, topics: Iterable[str], context: Context, namespace: str = '/',
                 name: str = 'collector', depth: int = COLLECTOR_DEPTH) -> None:
        """Subscribe to ``topics`` (contract names) in ``namespace``."""
        super().__init__(name, context=context)
        self.namespace = namespace
        self.depth = depth
        self.received: dict[str, list[Any]] = {}
        self.subscriptions_by_topic: dict[str, Any] = {}
        for topic in topics:
            spec = contract.TOPICS_BY_NAME[topic]
            qos = qos_profile(spec.qos)
            self.add(contract.resolve(topic, namespace), message_class(spec.type_name), qos)

    def add(self, topic: str, message_type: type, qos: QoSProfile) -> list[Any]:
        """
        Subscribe to ``topic`` (an absolute name) with ``qos`` made ``depth`` deep.

        Returns the list the messages arrive in (also ``received[topic]``).
        """
        qos = QoSProfile(history=qos.history, depth=max(qos.depth, self.depth),
                         reliability=qos.reliability, durability=qos.durability)
        messages: list[Any] = []
        self.received[topic] = messages
        self.subscriptions_by_topic[topic] = self.create_subscription(
            message_type, topic, messages.append, qos)
        return messages

    def absolute(self, topic: str) -> str:
        """The absolute name of ``topic``: a contract name resolved in the namespace, or as is."""
        if topic in self.received:
            return topic
        return contract.resolve(topic, self.namespace)

    def messages(self, topic: str) -> list[Any]:
        """The messages received on ``topic`` (contract or absolute name), in arrival order."""
        return self.received[self.absolute(topic)]

    def matched(self, topic: str) -> bool:
        """True when ``topic`` (contract or absolute name) has at least one publisher."""
        return self.subscriptions_by_topic[self.absolute(topic)].get_publisher_count() > 0

    def wait_for_publishers(self, topics: Iterable[str] | None = None,
                            timeout: float = TIMEOUT_S) -> None:
        """Wait until every topic (default: all subscribed) has a publisher."""
        names = [self.absolute(t) for t in (topics if topics is not None else self.received)]
        wait_for(lambda: all(self.matched(t) for t in names),
                 'publishers on ' + ', '.join(names), timeout,
                 explain=lambda: 'none on ' + ', '.join(t for t in names if not self.matched(t)))

    def wait_for_count(self, topic: str, count: int, timeout: float = TIMEOUT_S) -> list[Any]:
        """Wait until ``count`` messages arrived on ``topic``; returns its message list."""
        messages = self.messages(topic)
        wait_for(lambda: len(messages) >= count, f'{count} messages on {self.absolute(topic)}',
                 timeout, explain=lambda: f'{len(messages)} arrived')
        return messages

    def states(self, topic: str = contract.PUMP_STATUS.name) -> list[str]:
        """The pump states received on ``pump/status`` (JSON), in order."""
        return [json.loads(m.data)['state'] for m in self.messages(topic)]


def call_trigger(node: Node, service: str, timeout: float = TIMEOUT_S) -> Trigger.Response:
    """
    Call the ``std_srvs/Trigger`` service ``service`` from ``node``, which must be spinning.

    A relative name resolves in the node's namespace (``'syringe_pump/start'`` from a node at
    the root is ``/syringe_pump/start``). The client stays until the node is destroyed:
    destroying it here, while the executor thread may be adding it to a wait set, can kill
    that thread (rclpy's InvalidHandle).
    """
    client = node.create_client(Trigger, service)
    if not client.wait_for_service(timeout_sec=timeout):
        raise AssertionError(f'timed out after {timeout:g} s waiting for the service {service}')
    future = client.call_async(Trigger.Request())
    wait_for(future.done, f'the answer of {service}', timeout)
    return future.result()
