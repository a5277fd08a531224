"""
Shared pieces of the rig's nodes: topic table and QoS, parameter declaration, the main runner.

Every rig node derives from :class:`RigNode`, which implements the batch-mode contract of the
rig (``emit`` and ``now`` constructor keywords, one ``_publish`` method) and declares parameters
with descriptors whose values are validated in one set-parameters callback that answers with a
reason naming the parameter. Rates accept integers and doubles (``-p rate_hz:=100`` works).

In batch mode (``emit`` given) a node creates no publishers, subscriptions, services or timers:
the batch runner calls the public ``on_<topic>`` handlers and ``tick()`` itself.
"""

from collections import deque
from dataclasses import dataclass
import math
import sys
import time
from typing import Any, Callable, Sequence

from geometry_msgs.msg import PoseArray
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
    SetParametersResult,
)
import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.logging import LoggingSeverity
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import FluidPressure, Image, JointState
from std_msgs.msg import String
from visualization_msgs.msg import MarkerArray

from softseq_ros.physics.scene import OUTPUT_NAMES, Scene, SceneError, load_scene

FRAME_ID = 'softseq_base'
DEFAULT_AMBIENT_PRESSURE_PA = 101325.0
WARNING_INTERVAL_S = 2.0


def _qos(depth: int, *, reliable: bool = True, latched: bool = False) -> QoSProfile:
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=depth,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


# Deep: a command the actuator's queue drops is skipped physics-wise (the jump rule), but its
# answer is missing from the recording; a stalled process must not lose any.
COMMAND_QOS = _qos(1000)
STATUS_QOS = _qos(10, latched=True)
PRESSURE_QOS = _qos(100)
VOLUMES_QOS = _qos(1, latched=True)
CURVATURES_QOS = _qos(100)
EVENTS_QOS = _qos(100, latched=True)
BACKBONE_QOS = _qos(10)
SNAPSHOTS_QOS = _qos(20, latched=True)
MARKERS_QOS = _qos(10)
IMAGE_QOS = _qos(2, reliable=False)
# The QoS rclpy's TimeSource subscribes to /clock with: best effort, depth 1.
CLOCK_QOS = _qos(1, reliable=False)


@dataclass(frozen=True)
class TopicSpec:
    """A rig topic: its message class and QoS (the table of the rig contract)."""

    msg_type: type
    qos: QoSProfile


TOPICS: dict[str, TopicSpec] = {
    '/pump/command': TopicSpec(JointState, COMMAND_QOS),
    '/pump/status': TopicSpec(String, STATUS_QOS),
    '/actuator/pressure': TopicSpec(FluidPressure, PRESSURE_QOS),
    '/actuator/volumes': TopicSpec(JointState, VOLUMES_QOS),
    '/actuator/curvatures': TopicSpec(JointState, CURVATURES_QOS),
    '/actuator/events': TopicSpec(String, EVENTS_QOS),
    '/camera/backbone': TopicSpec(PoseArray, BACKBONE_QOS),
    '/camera/snapshots': TopicSpec(PoseArray, SNAPSHOTS_QOS),
    '/camera/markers': TopicSpec(MarkerArray, MARKERS_QOS),
    '/camera/image': TopicSpec(Image, IMAGE_QOS),
    '/clock': TopicSpec(Clock, CLOCK_QOS),
}

# Which node handler consumes which topic: the batch runner routes emitted messages by this.
ROUTES: dict[str, tuple[tuple[str, str], ...]] = {
    '/pump/command': (('actuator', 'on_pump_command'),),
    '/actuator/pressure': (('syringe_pump', 'on_pressure'),),
    '/actuator/volumes': (('camera', 'on_volumes'),),
    '/actuator/curvatures': (('camera', 'on_curvatures'),),
}

# Scene output names (softseq_ros.physics.scene.OUTPUT_NAMES) and the topics they switch on.
OUTPUT_TOPICS: dict[str, tuple[str, ...]] = {
    'pressure': ('/actuator/pressure',),
    'volumes': ('/actuator/volumes',),
    'curvature': ('/actuator/curvatures',),
    'events': ('/actuator/events',),
    'poses': ('/camera/backbone', '/camera/snapshots'),
    'markers': ('/camera/markers',),
    'image': ('/camera/image',),
}


class LocalRoutes:
    """
    Hands messages between the rig's nodes in one process, by ROUTES, in the order they were sent.

    The batch runner and the ``rig`` executable use it. ``node_names`` are the nodes living in
    the process; a topic is carried here when one of them consumes it (their DDS subscription
    to it is then not made: it would deliver the same message a second time). ``send`` queues
    a message for its consumers' handlers, ``drain`` runs the queue; a handler that publishes
    queues more, which the same ``drain`` runs, so a pump command reaches the camera's frame
    within the pump's own tick, as rclcpp's intra-process communication would have it.
    """

    def __init__(self, node_names: Sequence[str]) -> None:
        """Routes among the nodes ``node_names`` (register each with :meth:`add`)."""
        self.node_names = frozenset(node_names)
        self._nodes: dict[str, Any] = {}
        self._handlers: dict[str, list[Callable[[Any], None]]] = {}
        self._queue: deque[tuple[Callable[[Any], None], Any]] = deque()
        self._draining = False

    def add(self, node: Any) -> None:
        """Register a built node (by its NODE_NAME)."""
        self._nodes[node.NODE_NAME] = node
        self._handlers.clear()

    def carries(self, topic: str) -> bool:
        """True when a node of this process consumes ``topic``."""
        return any(node in self.node_names for node, _ in ROUTES.get(topic, ()))

    def send(self, topic: str, msg: Any) -> None:
        """Queue ``msg`` (a message, or its CDR bytes) for the handlers that consume ``topic``."""
        handlers = self._handlers.get(topic)
        if handlers is None:
            # A node may publish while the others are still being built: like a subscriber
            # that does not exist yet, a node not registered yet does not get the message.
            handlers = [getattr(self._nodes[node], handler)
                        for node, handler in ROUTES.get(topic, ()) if node in self._nodes]
            self._handlers[topic] = handlers
        if handlers:
            if type(msg) is bytes:
                msg = deserialize_message(msg, TOPICS[topic].msg_type)
            queue = self._queue
            for handler in handlers:
                queue.append((handler, msg))

    def drain(self) -> None:
        """Run the queued handlers (and what they queue); nested calls leave it to the outer."""
        if self._draining:
            return
        self._draining = True
        try:
            queue = self._queue
            while queue:
                handler, msg = queue.popleft()
                handler(msg)
        finally:
            self._draining = False


def outputs_reason(value: list[str]) -> str | None:
    """Why an ``outputs`` parameter is refused (an unknown output name), or None."""
    unknown = [name for name in value if name not in OUTPUT_NAMES]
    if unknown:
        return (f'unknown output(s) {", ".join(unknown)}; expected some of '
                f'{", ".join(OUTPUT_NAMES)}')
    return None


class NodeConfigError(ValueError):
    """A node configuration that cannot run; the message names the parameter."""


def stamp_header(header: Any, nanoseconds: int) -> None:
    """Write a time in nanoseconds into ``header.stamp`` (no allocation)."""
    header.stamp.sec, header.stamp.nanosec = divmod(int(nanoseconds), 1_000_000_000)


def stamp_ns(header: Any) -> int:
    """A header's stamp in nanoseconds."""
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


@dataclass(frozen=True)
class _Rule:
    """How a declared parameter's values are checked."""

    kind: str  # 'float', 'int', 'str', 'bool', 'str_array', 'float_array'
    minimum: float | None = None
    maximum: float | None = None
    open_minimum: bool = False
    check: Callable[[Any], str | None] | None = None

    def reason(self, parameter: Parameter) -> str | None:
        """Why ``parameter`` is refused, or None when it is fine."""
        value = parameter.value
        kind = parameter.type_
        if kind == Parameter.Type.NOT_SET:
            return None  # declared without a value (an empty list): nothing to check
        if self.kind == 'float':
            if kind not in (Parameter.Type.DOUBLE, Parameter.Type.INTEGER):
                return f'must be a number (integer or double), got {kind.name.lower()} {value!r}'
            value = float(value)
            if not math.isfinite(value):
                return f'must be finite, got {value}'
        elif self.kind == 'int':
            if kind != Parameter.Type.INTEGER:
                return f'must be an integer, got {kind.name.lower()} {value!r}'
        elif self.kind == 'str' and kind != Parameter.Type.STRING:
            return f'must be a string, got {kind.name.lower()} {value!r}'
        elif self.kind == 'bool' and kind != Parameter.Type.BOOL:
            return f'must be true or false, got {kind.name.lower()} {value!r}'
        elif self.kind == 'str_array' and kind != Parameter.Type.STRING_ARRAY:
            return f'must be a list of strings, got {kind.name.lower()} {value!r}'
        elif self.kind == 'float_array':
            if kind not in (Parameter.Type.DOUBLE_ARRAY, Parameter.Type.INTEGER_ARRAY):
                return f'must be a list of numbers, got {kind.name.lower()} {value!r}'
            if not all(math.isfinite(float(x)) for x in value):
                return 'must hold finite numbers only'
        if self.kind in ('float', 'int'):
            if self.minimum is not None:
                if self.open_minimum and not value > self.minimum:
                    return f'must be > {self.minimum:g}, got {value:g}'
                if not self.open_minimum and not value >= self.minimum:
                    return f'must be >= {self.minimum:g}, got {value:g}'
            if self.maximum is not None and not value <= self.maximum:
                return f'must be <= {self.maximum:g}, got {value:g}'
        if self.check is not None:
            return self.check(value)
        return None


class RigNode(Node):
    """
    Base of the rig's nodes: batch-mode plumbing, parameter rules and throttled warnings.

    ``emit(topic, msg)``, when given, receives every outgoing message instead of a ROS
    publisher; ``now()`` returns the current time in nanoseconds (default: the node clock).
    ``local_routes`` (the ``rig`` executable) hands what the node publishes also straight to
    the other nodes of the process (see :class:`LocalRoutes`).
    Other keywords go to rclpy's Node (``context``, ``parameter_overrides``, ...).
    """

    def __init__(self, node_name: str, *, emit: Callable[[str, Any], None] | None = None,
                 now: Callable[[], int] | None = None, local_routes: LocalRoutes | None = None,
                 **node_kwargs: Any) -> None:
        """Create the node and install the parameter validation callbacks."""
        super().__init__(node_name, **node_kwargs)
        self._emit = emit
        self._local_routes = local_routes
        self._now_fn = now
        self._rig_publishers: dict[str, Any] = {}
        self._rules: dict[str, _Rule] = {}
        self._last_warning: dict[str, float] = {}
        self._suppressed: dict[str, int] = {}
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._post_set)
        # Declarations run the callbacks too; changes apply only once the node is built.
        self.configured = False

    @property
    def batch_mode(self) -> bool:
        """True when messages go to ``emit`` instead of ROS publishers."""
        return self._emit is not None

    # ---------------------------------------------------------------- time and publishing

    def now_ns(self) -> int:
        """Current time in nanoseconds (``now`` keyword, else the node clock)."""
        if self._now_fn is not None:
            return int(self._now_fn())
        return self.get_clock().now().nanoseconds

    def _make_publisher(self, topic: str) -> None:
        if self._emit is None:
            spec = TOPICS[topic]
            self._rig_publishers[topic] = self.create_publisher(spec.msg_type, topic, spec.qos)
        else:
            self._rig_publishers[topic] = None

    def _publish(self, topic: str, msg: Any) -> None:
        """Send one message: to ``emit`` in batch mode, else to the topic's publisher."""
        if self._emit is not None:
            self._emit(topic, msg)
        else:
            self._rig_publishers[topic].publish(msg)
            local = self._local_routes
            if local is not None:
                local.send(topic, msg)
                local.drain()

    def _publishes(self, topic: str) -> bool:
        return topic in self._rig_publishers

    def _subscribe(self, topic: str, callback: Callable[[Any], None]) -> None:
        local = self._local_routes
        if self._emit is None and not (local is not None and local.carries(topic)):
            spec = TOPICS[topic]
            self.create_subscription(spec.msg_type, topic, callback, spec.qos)

    def _log(self, severity: LoggingSeverity, text: str) -> None:
        logger = self.get_logger()
        if logger.is_enabled_for(severity):
            # rclpy's logger locates its caller with inspect (source files read at every call,
            # and a scan of every loaded module at the first); the line is handed to rcutils
            # as rclpy would, with the caller taken from the frame directly.
            caller = sys._getframe(2)
            _rclpy.rclpy_logging_rcutils_log(severity, logger.name, text,
                                             caller.f_code.co_name, caller.f_code.co_filename,
                                             caller.f_lineno)

    def log_info(self, text: str) -> None:
        """Log ``text`` at INFO (to the console and /rosout, as the node's logger does)."""
        self._log(LoggingSeverity.INFO, text)

    def log_warning(self, text: str) -> None:
        """Log ``text`` at WARN."""
        self._log(LoggingSeverity.WARN, text)

    def log_error(self, text: str) -> None:
        """Log ``text`` at ERROR."""
        self._log(LoggingSeverity.ERROR, text)

    def warn_throttled(self, key: str, text: str) -> None:
        """Log a warning at most every WARNING_INTERVAL_S per ``key``, counting the rest."""
        wall = time.monotonic()
        last = self._last_warning.get(key)
        if last is not None and wall - last < WARNING_INTERVAL_S:
            self._suppressed[key] = self._suppressed.get(key, 0) + 1
            return
        suppressed = self._suppressed.pop(key, 0)
        if suppressed:
            text += f' ({suppressed} similar warnings suppressed)'
        self._last_warning[key] = wall
        self.log_warning(text)

    # ---------------------------------------------------------------- parameters

    def _declare(self, name: str, default: Any, descriptor: ParameterDescriptor,
                 rule: _Rule) -> Any:
        self._rules[name] = rule
        descriptor.name = name
        return self.declare_parameter(name, default, descriptor).value

    def declare_number(self, name: str, default: float, description: str, *,
                       minimum: float | None = None, maximum: float | None = None,
                       open_minimum: bool = False, read_only: bool = False) -> float:
        """Declare a double that also accepts integers (``-p rate_hz:=100``); return it."""
        descriptor = ParameterDescriptor(
            type=ParameterType.PARAMETER_DOUBLE, description=description,
            read_only=read_only, dynamic_typing=True,
            additional_constraints=_bounds_text(minimum, maximum, open_minimum)
            + '; integer or double')
        if minimum is not None and maximum is not None:
            descriptor.floating_point_range = [FloatingPointRange(
                from_value=float(minimum), to_value=float(maximum), step=0.0)]
        value = self._declare(name, float(default), descriptor,
                              _Rule('float', minimum, maximum, open_minimum))
        return float(value)

    def declare_integer(self, name: str, default: int, description: str, *,
                        minimum: int | None = None, maximum: int | None = None,
                        read_only: bool = False) -> int:
        """Declare an integer parameter with an IntegerRange; return it."""
        descriptor = ParameterDescriptor(
            type=ParameterType.PARAMETER_INTEGER, description=description,
            read_only=read_only, additional_constraints=_bounds_text(minimum, maximum, False))
        if minimum is not None:
            descriptor.integer_range = [IntegerRange(
                from_value=int(minimum), to_value=int(maximum if maximum is not None
                                                      else 2 ** 31 - 1), step=0)]
        return int(self._declare(name, int(default), descriptor, _Rule('int', minimum, maximum)))

    def declare_text(self, name: str, default: str, description: str, *,
                     read_only: bool = False,
                     check: Callable[[Any], str | None] | None = None) -> str:
        """Declare a string parameter; ``check(value)`` returns a reason to refuse it."""
        descriptor = ParameterDescriptor(type=ParameterType.PARAMETER_STRING,
                                         description=description, read_only=read_only)
        return str(self._declare(name, default, descriptor, _Rule('str', check=check)))

    def declare_flag(self, name: str, default: bool, description: str, *,
                     read_only: bool = False) -> bool:
        """Declare a boolean parameter; return it."""
        descriptor = ParameterDescriptor(type=ParameterType.PARAMETER_BOOL,
                                         description=description, read_only=read_only)
        return bool(self._declare(name, bool(default), descriptor, _Rule('bool')))

    def declare_texts(self, name: str, default: Sequence[str], description: str, *,
                      read_only: bool = False,
                      check: Callable[[Any], str | None] | None = None) -> list[str]:
        """Declare a string-array parameter; return it."""
        descriptor = ParameterDescriptor(type=ParameterType.PARAMETER_STRING_ARRAY,
                                         description=description, read_only=read_only)
        return list(self._declare(name, list(default), descriptor,
                                  _Rule('str_array', check=check)))

    def declare_numbers(self, name: str, default: Sequence[float], description: str, *,
                        read_only: bool = False,
                        check: Callable[[Any], str | None] | None = None) -> list[float]:
        """Declare a double-array parameter; return it as floats ([] when unset)."""
        descriptor = ParameterDescriptor(type=ParameterType.PARAMETER_DOUBLE_ARRAY,
                                         description=description, read_only=read_only)
        # An empty list has no element type; rclpy declares it from the type alone (unset).
        value = self._declare(name, [float(x) for x in default] or Parameter.Type.DOUBLE_ARRAY,
                              descriptor, _Rule('float_array', check=check))
        return [float(x) for x in (value or [])]

    def declare_scene(self) -> Scene:
        """Declare the read-only ``scene`` parameter and load the scene it names."""
        name = self.declare_text(
            'scene', 'paper', 'Scene file path or shipped scene name; it gives the defaults '
            'of the other parameters.', read_only=True)
        return load_scene(name)

    def _validate_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        for parameter in parameters:
            rule = self._rules.get(parameter.name)
            if rule is None:
                continue
            reason = rule.reason(parameter)
            if reason is not None:
                return SetParametersResult(successful=False,
                                           reason=f'{parameter.name}: {reason}')
        return SetParametersResult(successful=True)

    def _post_set(self, parameters: list[Parameter]) -> None:
        if self.configured:
            self._parameters_changed(parameters)

    def _parameters_changed(self, parameters: list[Parameter]) -> None:
        """Apply accepted changes; nodes override this for their dynamic parameters."""

    def _make_timer(self, rate_hz: float, callback: Callable[[], None]) -> Any:
        if self._emit is not None:
            return None
        return self.create_timer(1.0 / rate_hz, callback)


def set_timer_rate(timer: Any, rate_hz: float) -> None:
    """Change a timer's rate in place (no timer in batch mode)."""
    if timer is not None:
        timer.timer_period_ns = int(round(1e9 / rate_hz))


def _bounds_text(minimum: float | None, maximum: float | None, open_minimum: bool) -> str:
    parts = []
    if minimum is not None:
        parts.append(f'{">" if open_minimum else ">="} {minimum:g}')
    if maximum is not None:
        parts.append(f'<= {maximum:g}')
    return ' and '.join(parts) if parts else 'any value'


def run_node(node_class: Callable[..., Node], args: list[str] | None = None) -> None:
    """
    Run one node until SIGINT/SIGTERM: init, spin, then destroy the node and shut down.

    A configuration mistake (scene file, parameter value) ends the process with one line on
    stderr and exit status 2, not a traceback.
    """
    run_nodes([node_class], args, getattr(node_class, 'NODE_NAME', 'node'))


def run_nodes(node_classes: Sequence[Callable[..., Node]], args: list[str] | None,
              name: str) -> None:
    """
    ``run_node`` for several nodes in one process, on one single-threaded executor.

    With more than one node, messages between them go through :class:`LocalRoutes`; every
    topic is still published over DDS for the world outside.
    """
    try:
        rclpy.init(args=args)
    except _rclpy.RCLError as err:
        # rcl parses -p values as YAML: a string holding YAML (the pump's legs) needs its own
        # quotes, -p "legs:='[{inflate_to_m3: 5.0e-6}]'".
        reason = ' '.join(str(err).split(', at ')[0].split())
        print(f'{name}: error: {reason}; quote a value that is YAML text, e.g. '
              '-p "legs:=\'[{inflate_to_m3: 5.0e-6}]\'"', file=sys.stderr)
        sys.exit(2)
    nodes: list[Node] = []
    error = None
    try:
        local = (LocalRoutes([cls.NODE_NAME for cls in node_classes])
                 if len(node_classes) > 1 else None)
        for node_class in node_classes:
            node = node_class(local_routes=local) if local is not None else node_class()
            nodes.append(node)
            if local is not None:
                local.add(node)
        executor = SingleThreadedExecutor()
        for node in nodes:
            executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (SceneError, NodeConfigError, ParameterException) as err:
        error = ' '.join(str(err).split())
    except Exception:
        # SIGINT shuts the context down under a running callback, whose publish then fails
        # (RCLError: context invalid). After a shutdown that is the end of the run, not a bug.
        if rclpy.ok():
            raise
    finally:
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()
    if error is not None:
        print(f'{name}: error: {error}', file=sys.stderr)
        sys.exit(2)
