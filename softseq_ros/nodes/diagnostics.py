"""
Each node's health on ``/diagnostics`` (diagnostic_msgs/DiagnosticArray) for rqt and Foxglove.

Once a second (wall clock, so it also reports while a sim clock stands still) a node publishes
one DiagnosticArray holding one DiagnosticStatus: level OK, WARN or ERROR, a one-line message
and key-value pairs, as ``diagnostic_updater`` does in C++. ``/diagnostics`` is absolute by ROS
convention (the diagnostic aggregator listens there, whatever the namespace), so the status is
named ``<fully qualified node name>: <task>`` and its ``hardware_id`` is the node's fully
qualified name: two rigs in two namespaces stay apart. Values are SI, as on every topic.

The batch runner publishes nothing: ``/diagnostics`` is the health of a live rig, not part of
the recording of a run (``softseq run`` bags stay as they are).
"""

from dataclasses import dataclass, field
from typing import Callable

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import QoSProfile

from softseq_ros.wire import contract
from softseq_ros.wire.values import ERROR, WARNING

PERIOD_S = 1.0
OK_LEVEL = DiagnosticStatus.OK
WARN_LEVEL = DiagnosticStatus.WARN
ERROR_LEVEL = DiagnosticStatus.ERROR
# A notice's level (softseq_ros.wire.values) as a diagnostic level.
LEVEL_OF_NOTICE = {WARNING: WARN_LEVEL, ERROR: ERROR_LEVEL}


@dataclass
class Health:
    """What a node says of itself: a level, one line, and named values (text)."""

    level: bytes = OK_LEVEL
    message: str = 'ok'
    values: dict[str, object] = field(default_factory=dict)


def worst(*levels: bytes) -> bytes:
    """The most severe of diagnostic ``levels`` (OK < WARN < ERROR)."""
    return max(levels, key=lambda level: level[0])


def _text(value: object) -> str:
    if isinstance(value, float):
        return f'{value:.9g}'
    if isinstance(value, bool):
        return str(value).lower()
    return str(value)


class DiagnosticsPublisher:
    """Publishes ``health()`` of ``node`` on /diagnostics every ``period_s`` of wall time."""

    def __init__(self, node: Node, task: str, health: Callable[[], Health],
                 period_s: float = PERIOD_S) -> None:
        """Create the publisher and its steady-clock timer on ``node``."""
        self._node = node
        self._task = task
        self._health = health
        # Reliable and volatile (rclpy's defaults), as diagnostic_updater publishes.
        self.publisher = node.create_publisher(DiagnosticArray, contract.DIAGNOSTICS.name,
                                               QoSProfile(depth=contract.DIAGNOSTICS.qos.depth))
        self.timer = node.create_timer(period_s, self.publish,
                                       clock=Clock(clock_type=ClockType.STEADY_TIME))

    def destroy(self) -> None:
        """Stop publishing: the timer and the publisher are destroyed."""
        self._node.destroy_timer(self.timer)
        self._node.destroy_publisher(self.publisher)

    def status(self) -> DiagnosticStatus:
        """The node's status now."""
        health = self._health()
        fqn = self._node.get_fully_qualified_name()
        return DiagnosticStatus(
            level=health.level, name=f'{fqn}: {self._task}', message=health.message,
            hardware_id=fqn,
            values=[KeyValue(key=key, value=_text(value))
                    for key, value in health.values.items()])

    def publish(self) -> None:
        """Publish one DiagnosticArray with the node's status, stamped with the node clock."""
        array = DiagnosticArray(status=[self.status()])
        array.header.stamp = self._node.get_clock().now().to_msg()
        self.publisher.publish(array)
