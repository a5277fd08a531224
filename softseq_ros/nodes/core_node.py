"""
The ROS side of a rig core: publishers and subscriptions from the contract, values on the wire.

A :class:`CoreNode` hosts one core (softseq_ros.rig). It creates a publisher for every topic
its core produces and the scene's outputs switch on, and a subscription for every topic its
core consumes, all with the contract's relative names and QoS, so ``-r __ns:=/rig2`` moves the
whole rig and ``-r pump/command:=/elsewhere`` remaps one topic. What the core returns goes out
as the CDR bytes of softseq_ros.wire.payloads (the bytes a batch bag holds); what arrives is turned
into a core value by the same module, and a message that cannot be one is a logged warning.

Several nodes in one process (the ``rig`` executable) share a :class:`LocalCores`: a value one
of their cores produces goes straight to the consuming cores there (softseq_ros.rig.routing),
and is still published over DDS for the world outside; a topic produced in the process is not
subscribed to over DDS (it would arrive twice).
"""

import importlib
import time
from typing import Any, Callable

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from softseq_ros.nodes.diagnostics import (
    LEVEL_OF_NOTICE,
    OK_LEVEL,
    DiagnosticsPublisher,
    Health,
)
from softseq_ros.nodes.parameters import ParameterNode
from softseq_ros.rig.routing import Router
from softseq_ros.rig.throttle import Throttle
from softseq_ros.wire import contract
from softseq_ros.wire.payloads import DECODERS, ENCODERS, InputError
from softseq_ros.wire.values import ERROR, INFO, TOPIC_VALUE_TYPES, WARNING, Notice, Output


def qos_profile(qos: contract.Qos) -> QoSProfile:
    """The rclpy QoS profile of a contract QoS."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=qos.depth,
        reliability=ReliabilityPolicy.RELIABLE if qos.reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=(DurabilityPolicy.TRANSIENT_LOCAL if qos.latched
                    else DurabilityPolicy.VOLATILE))


def message_class(type_name: str) -> type:
    """The Python class of a ``pkg/msg/Type`` message type."""
    package, namespace, name = type_name.split('/')
    return getattr(importlib.import_module(f'{package}.{namespace}'), name)


class LocalCores:
    """The cores of one process and the nodes hosting them, routed by the contract."""

    def __init__(self) -> None:
        """An empty process; nodes join with :meth:`add`."""
        self.nodes: dict[str, 'CoreNode'] = {}
        self.router: Router | None = None

    def add(self, node: 'CoreNode') -> None:
        """Register a built node; routing covers every core registered so far."""
        self.nodes[node.core.role] = node
        first = next(iter(self.nodes.values()))
        self.router = Router({role: n.core for role, n in self.nodes.items()},
                             lambda: first.now_ns())

    def produces(self, role: str) -> bool:
        """True when the core ``role`` lives in this process."""
        return role in self.nodes

    def send(self, outputs: list[Output]) -> None:
        """Route ``outputs`` among the local cores; each node publishes what its core made."""
        nodes = self.nodes
        for value in self.router.run(outputs):
            role = value.source if type(value) is Notice else value.topic.producer
            nodes[role].emit(value)


class CoreNode(ParameterNode):
    """
    Base of the pump, actuator and camera nodes: one core, its topics, its log.

    Subclasses build ``self.core`` and then call :meth:`connect`. ``local`` is the process's
    :class:`LocalCores` when several rig nodes share one process.
    """

    def __init__(self, node_name: str, *, local: LocalCores | None = None,
                 **node_kwargs: Any) -> None:
        """Create the node; keywords go to rclpy's Node."""
        super().__init__(node_name, **node_kwargs)
        self.local = local
        self.core: Any = None
        self._publishers_by_type: dict[type, Any] = {}
        self._publishers_by_name: dict[str, Any] = {}
        self._subscriptions_by_name: dict[str, Any] = {}
        self._throttle = Throttle()
        # For /diagnostics: what the node published, refused and warned about.
        self.published: dict[str, int] = {}
        self.last_published: dict[type, Output] = {}
        self.refusals = 0
        self.warnings = 0
        self.last_warning = ''
        self._last_warning_at = -float('inf')
        self._last_warning_level = OK_LEVEL
        self.diagnostics: DiagnosticsPublisher | None = None

    def now_ns(self) -> int:
        """The node clock in nanoseconds (ROS time, or sim time with use_sim_time)."""
        return self.get_clock().now().nanoseconds

    def connect(self, outputs: frozenset[str]) -> None:
        """Publishers and subscriptions of the core's topics (``outputs`` switch them on)."""
        role = self.core.role
        for kind in TOPIC_VALUE_TYPES:
            topic = kind.topic
            if topic.producer != role or not contract.enabled(topic, outputs):
                continue
            publisher = self._publishers_by_name.get(topic.name)
            if publisher is None:
                publisher = self.create_publisher(message_class(topic.type_name), topic.name,
                                                  qos_profile(topic.qos))
                self._publishers_by_name[topic.name] = publisher
            self._publishers_by_type[kind] = publisher
        for topic in contract.consumed_by(role):
            if self.local is not None and self.local.produces(topic.producer):
                continue
            self._subscriptions_by_name[topic.name] = self.create_subscription(
                message_class(topic.type_name), topic.name,
                self.receiver(topic, DECODERS[topic.name]), qos_profile(topic.reader_qos))
        if self.local is not None:
            self.local.add(self)
        self.diagnostics = DiagnosticsPublisher(self, self.DIAGNOSTIC_TASK, self.health)

    # What the node's DiagnosticStatus is named after (``<fqn>: <task>``).
    DIAGNOSTIC_TASK = 'rig core'
    # A warning keeps the status at WARN this long [s, wall clock], then it is history.
    WARNING_HOLD_S = 10.0

    def health(self) -> Health:
        """The node's health for /diagnostics: recent warnings, refusals, messages sent."""
        recent = time.monotonic() - self._last_warning_at < self.WARNING_HOLD_S
        values: dict[str, object] = {'warnings': self.warnings, 'refused_messages':
                                     self.refusals, 'last_warning': self.last_warning}
        values.update((f'published {topic}', count) for topic, count in self.published.items())
        if recent:
            return Health(self._last_warning_level, self.last_warning, values)
        return Health(OK_LEVEL, 'ok', values)

    def disconnect(self) -> None:
        """Destroy what :meth:`connect` made (a managed node's cleanup)."""
        for publisher in self._publishers_by_name.values():
            self.destroy_publisher(publisher)
        for subscription in self._subscriptions_by_name.values():
            self.destroy_subscription(subscription)
        self._publishers_by_name.clear()
        self._publishers_by_type.clear()
        self._subscriptions_by_name.clear()
        if self.diagnostics is not None:
            self.diagnostics.destroy()
            self.diagnostics = None

    def publisher(self, topic: contract.Topic) -> Any:
        """The publisher of a contract topic (None when this node does not publish it)."""
        return self._publishers_by_name.get(topic.name)

    def subscription(self, topic: contract.Topic) -> Any:
        """The DDS subscription to a contract topic (None when there is none)."""
        return self._subscriptions_by_name.get(topic.name)

    # ---------------------------------------------------------------- values in and out

    def receiver(self, topic: contract.Topic, decode: Callable[[Any], Any]) -> Callable:
        """The subscription callback of a consumed topic (a node may take some its own way)."""
        return lambda msg: self._receive(topic, decode, msg)

    def _receive(self, topic: contract.Topic, decode: Callable[[Any], Any], msg: Any) -> None:
        try:
            value = decode(msg)
        except InputError as err:
            self.send(self.refused(err))
            return
        self.send(self.core.handle(value, self.now_ns()))

    def refused(self, err: InputError) -> list[Output]:
        """What a message that cannot become a core value gives: a throttled warning."""
        self.refusals += 1
        text = self._throttle.admit(err.key, str(err))
        return [] if text is None else [Notice(self.core.role, WARNING, text)]

    def send(self, outputs: list[Output]) -> None:
        """Publish what the core returned (through the process's routing when shared)."""
        if not outputs:
            return
        if self.local is not None:
            self.local.send(outputs)
            return
        for value in outputs:
            self.emit(value)

    def emit(self, value: Output) -> None:
        """One value: published as its topic's CDR bytes, or a notice logged."""
        if type(value) is Notice:
            self.log(value.level, value.text)
            return
        kind = type(value)
        publisher = self._publishers_by_type.get(kind)
        if publisher is not None:
            publisher.publish(ENCODERS[kind](value))
            name = kind.topic.name
            self.published[name] = self.published.get(name, 0) + 1
            self.last_published[kind] = value

    def log(self, level: str, text: str) -> None:
        """Log through the node's rclpy logger (console and /rosout)."""
        if level in LEVEL_OF_NOTICE:
            self.warnings += 1
            self.last_warning = text
            self._last_warning_at = time.monotonic()
            self._last_warning_level = LEVEL_OF_NOTICE[level]
        log_to(self.get_logger(), level, text)


def log_to(logger: Any, level: str, text: str) -> None:
    """Log ``text`` at a notice's ``level`` through an rclpy logger."""
    if level == INFO:
        logger.info(text)
    elif level == WARNING:
        logger.warning(text)
    elif level == ERROR:
        logger.error(text)
    else:
        logger.debug(text)
