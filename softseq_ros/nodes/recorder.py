"""
Recorder node: writes the rig's topics into an MCAP bag in the rosbag2 layout.

It subscribes with ``raw=True`` (the CDR bytes are stored as received, never decoded) once
a topic has a publisher, takes the type from the graph unless given, asks for reliable
delivery (and transient_local when every publisher offers it, so latched state is not
missed), and writes each message with log time = receive time (node clock) and publish
time = the publisher's source timestamp. The bag writing itself lives in
:mod:`softseq_ros.bag.writer` and needs no rclpy.
"""

from datetime import datetime, timezone
from functools import partial
import importlib
from pathlib import Path
import re
import signal
import sys
from typing import Any, Sequence

from rcl_interfaces.msg import (
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
    SetParametersResult,
)
import rclpy
from rclpy.clock import Clock, ClockType
from rclpy.exceptions import InvalidTopicNameException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.validate_topic_name import validate_topic_name

from softseq_ros.bag.forms import offered_qos_yaml, qos_profile_dict
from softseq_ros.bag.msgdefs import MessageDefinitionError, canonical_type_name
from softseq_ros.bag.writer import BagWriter, BagWriterError
from softseq_ros.nodes.diagnostics import (
    ERROR_LEVEL,
    OK_LEVEL,
    WARN_LEVEL,
    DiagnosticsPublisher,
    Health,
)
from softseq_ros.nodes.parameters import NodeConfigError, ParameterNode
from softseq_ros.nodes.runner import build_nodes, exit_with_help, init_ros
from softseq_ros.wire import contract

# The topics recorded when the `topics` parameter is not given: every topic of the rig's
# contract, relative to the recorder's namespace. A topic nobody publishes (an output the
# scene does not list, such as the image by default) is not in the bag.
RIG_TOPICS: tuple[str, ...] = tuple(topic.name for topic in contract.RIG_TOPICS)
DISCOVERY_PERIOD_S = 0.5
# The longest split a bag's int64 nanoseconds carry with room to spare (31 years).
MAX_BAG_DURATION_S = 1.0e9
QUEUE_DEPTH = 1000


def default_output_directory(now: datetime | None = None) -> Path:
    """Return ``bags/rig_<UTC timestamp>`` (rosbag2's timestamp format) for a new bag."""
    now = now or datetime.now(timezone.utc)
    return Path('bags') / now.astimezone(timezone.utc).strftime('rig_%Y_%m_%d-%H_%M_%S')


def _duration(duration: Any) -> dict[str, int]:
    nanoseconds = int(duration.nanoseconds)
    return {'sec': nanoseconds // 1_000_000_000, 'nsec': nanoseconds % 1_000_000_000}


def offered_profile(qos: QoSProfile) -> dict[str, Any]:
    """Convert a publisher's offered QoS to rosbag2's version-9 profile dictionary."""
    return qos_profile_dict(
        history=qos.history.name.lower(), depth=qos.depth,
        reliability=qos.reliability.name.lower(), durability=qos.durability.name.lower(),
        deadline=_duration(qos.deadline), lifespan=_duration(qos.lifespan),
        liveliness=qos.liveliness.name.lower(),
        liveliness_lease_duration=_duration(qos.liveliness_lease_duration),
        avoid_ros_namespace_conventions=qos.avoid_ros_namespace_conventions)


def request_for_offers(offers: Sequence[QoSProfile]) -> QoSProfile:
    """
    Choose the subscription QoS that receives from all publishers without losses.

    Reliable when every publisher is reliable (a reliable subscription would not match a
    best-effort one), transient_local when every publisher keeps its last messages for late
    joiners, as rosbag2's recorder does.
    """
    reliable = all(o.reliability == ReliabilityPolicy.RELIABLE for o in offers)
    transient = bool(offers) and all(
        o.durability == DurabilityPolicy.TRANSIENT_LOCAL for o in offers)
    return QoSProfile(
        depth=QUEUE_DEPTH,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if transient else DurabilityPolicy.VOLATILE)


def message_class(type_name: str) -> type:
    """Import the Python class of a ``pkg/msg/Type`` message type."""
    package, namespace, name = canonical_type_name(type_name).split('/')
    try:
        return getattr(importlib.import_module(f'{package}.{namespace}'), name)
    except (ImportError, AttributeError):
        raise MessageDefinitionError(
            f'message type {type_name}: its Python package is not installed') from None


class Recorder(ParameterNode):
    """Subscribe to a list of topics and write everything received into one bag."""

    NODE_NAME = 'recorder'
    DIAGNOSTIC_TASK = 'recorder'
    # What --help says of its topics: they are a parameter's, not the contract's.
    HELP_TOPICS = (
        'subscribes to the topics of its topics parameter, by default every topic of the '
        f'rig\'s contract: {", ".join(RIG_TOPICS)}; each once it has a publisher; with '
        'all_topics or regex also every topic of the graph they take, as it appears',)

    def __init__(self, **node_kwargs: Any) -> None:
        """Declare parameters, open the bag and start looking for the topics."""
        super().__init__(self.NODE_NAME, **node_kwargs)
        topics = self.declare_checked(
            'topics', list(RIG_TOPICS), ParameterDescriptor(
                type=ParameterType.PARAMETER_STRING_ARRAY, read_only=True,
                description='Topics to record (relative names are resolved in the node '
                            'namespace; default: every topic of the rig); all_topics and '
                            'regex add to them, so give "topics:=[]" to record only theirs.'),
        ) or []   # rcl reads topics:=[] as a value not set
        # Declared without a value when not given, so its type cannot be static: rclpy's
        # get_parameters service answers nothing at all (not even the other names asked for)
        # when one of them is a statically typed parameter without a value. Its type is
        # checked here instead.
        self.add_on_set_parameters_callback(_check_types_parameter)
        self.declare_checked(
            'types', None, ParameterDescriptor(
                type=ParameterType.PARAMETER_STRING_ARRAY, read_only=True, dynamic_typing=True,
                additional_constraints='a list of strings, or not set',
                description='Message types (pkg/msg/Type), one per entry of topics; an empty '
                            'entry or a missing list means: take the type from the graph.'))
        output = self._read_only('output', '', ParameterType.PARAMETER_STRING,
                                 'Bag directory to create; empty: bags/rig_<UTC timestamp>.')
        compression = self._read_only('compression', 'zstd', ParameterType.PARAMETER_STRING,
                                      'MCAP chunk compression: zstd, lz4 or none.')
        all_topics = self._read_only(
            'all_topics', False, ParameterType.PARAMETER_BOOL,
            'Record every topic of the graph as it appears (ros2 bag record -a), hidden ones '
            '(a name part starting with _) excepted, besides those of topics.')
        pattern = self._read_only(
            'regex', '', ParameterType.PARAMETER_STRING,
            'Also record every topic whose absolute name this regular expression matches '
            '(Python re.search), as it appears (ros2 bag record -e); empty: none.')
        exclude = self._read_only(
            'exclude_regex', '', ParameterType.PARAMETER_STRING,
            'Leave out the topics that all_topics or regex would add and this regular '
            'expression matches (ros2 bag record -x); empty: none.')
        max_size = self._read_only(
            'max_bag_size', 0, ParameterType.PARAMETER_INTEGER,
            'Split the bag into a new .mcap file once the current one has this many bytes on '
            'disk (at a chunk boundary); 0: never.', additional_constraints='>= 0',
            integer_range=[IntegerRange(from_value=0, to_value=2 ** 62, step=0)])
        max_duration = self._read_only(
            'max_bag_duration', 0.0, ParameterType.PARAMETER_DOUBLE,
            "Split the bag into a new .mcap file once a message comes this many seconds (log "
            "time) after the current file's first; 0: never.", dynamic_typing=True,
            additional_constraints='>= 0; integer or double')
        self._patterns = [_compiled('regex', pattern)] if pattern else []
        self._exclude = _compiled('exclude_regex', exclude) if exclude else None
        self._all_topics = bool(all_topics)
        if isinstance(max_duration, bool) or not isinstance(max_duration, (int, float)) \
                or not 0.0 <= max_duration <= MAX_BAG_DURATION_S:
            raise BagWriterError(f'parameter max_bag_duration: must be a number of seconds '
                                 f'>= 0 and <= {MAX_BAG_DURATION_S:g}, got {max_duration!r}')
        types = list(self.get_parameter('types').value or [])
        if types and len(types) != len(topics):
            raise BagWriterError(
                f'parameter types: {len(types)} entries for {len(topics)} topics; give one type '
                'per topic (an empty string to discover it)')
        self._wanted: dict[str, str] = {}
        for index, topic in enumerate(topics):
            given = types[index] if types else ''
            try:
                validate_topic_name(topic)
            except InvalidTopicNameException as err:
                reason = str(err).splitlines()[0]
                raise BagWriterError(f'parameter topics: {topic!r} is not a valid topic name '
                                     f'({reason})') from None
            resolved = self.resolve_topic_name(topic)
            self._wanted[resolved] = canonical_type_name(given) if given else ''
        self._output = Path(output) if output else default_output_directory()
        try:
            self._bag = BagWriter(self._output,
                                  compression=None if compression == 'none' else compression,
                                  max_file_size_bytes=int(max_size),
                                  max_file_duration_s=float(max_duration))
        except BagWriterError as err:
            if not str(err).startswith(str(self._output)):
                raise
            # The folder cannot be made: say which parameter gave it.
            raise BagWriterError(f'parameter output: {err}') from None
        try:
            self._subscriptions_by_topic: dict[str, Any] = {}
            self._reported: set[str] = set()
            self.bytes_written = 0                 # CDR payload bytes handed to the bag
            self.failed_topics: dict[str, str] = {}   # topic -> why it is not recorded
            self.write_failures = 0
            self.diagnostics = DiagnosticsPublisher(self, self.DIAGNOSTIC_TASK, self.health)
            self.get_logger().info(
                f'recording {len(self._wanted)} topics into {self._output}')
            # Wall-clock discovery: with use_sim_time the node clock stands still until /clock
            # arrives, and the topics must be found before that.
            self.create_timer(DISCOVERY_PERIOD_S, self._discover,
                              clock=Clock(clock_type=ClockType.STEADY_TIME))
            self._discover()
        except BaseException:
            # A signal while the node starts shuts the context down under whatever rclpy call
            # runs then, and the node is never handed back to be closed: the bag it opened is
            # closed here, whole, with its metadata, before the start-up fails.
            self._bag.close()
            raise

    def _read_only(self, name: str, default: Any, kind: int, description: str,
                   **descriptor: Any) -> Any:
        """Declare a read-only parameter (set at start only); return its value."""
        return self.declare_checked(name, default, ParameterDescriptor(
            type=kind, read_only=True, description=description, **descriptor))

    @property
    def bag(self) -> BagWriter:
        """The bag being written."""
        return self._bag

    @property
    def recorded_topics(self) -> list[str]:
        """Topics subscribed to so far."""
        return list(self._subscriptions_by_topic)

    def _discover(self) -> None:
        # The timer keeps running even when every topic is found: with rclpy 7.1.6 a node
        # whose timer was cancelled sometimes ignores SIGTERM inside spin().
        discovering = self._all_topics or self._patterns
        if self._bag.closed or (not discovering
                                and len(self._subscriptions_by_topic) == len(self._wanted)):
            return
        graph = dict(self.get_topic_names_and_types())
        if discovering:
            for topic in graph:
                if topic not in self._wanted and self._matches(topic):
                    self._wanted[topic] = ''
        for topic, given_type in self._wanted.items():
            if topic in self._subscriptions_by_topic:
                continue
            publishers = self.get_publishers_info_by_topic(topic)
            if not publishers:
                continue
            type_name = given_type or self._type_from_graph(topic, graph.get(topic, []))
            if not type_name:
                continue
            try:
                self._subscribe(topic, type_name, [p.qos_profile for p in publishers
                                                   if p.topic_type == type_name])
            except (MessageDefinitionError, BagWriterError) as err:
                self.failed_topics[topic] = str(err)
                if topic not in self._reported:
                    self._reported.add(topic)
                    self.get_logger().error(f'not recording {topic}: {err}')

    def _matches(self, topic: str) -> bool:
        """True when all_topics or regex adds ``topic`` (hidden ones never, exclusions not)."""
        if any(part.startswith('_') for part in topic.split('/')):
            return False
        if self._exclude is not None and self._exclude.search(topic):
            return False
        return self._all_topics or any(p.search(topic) for p in self._patterns)

    def _type_from_graph(self, topic: str, types: list[str]) -> str:
        if len(types) > 1 and topic not in self._reported:
            self._reported.add(topic)
            self.get_logger().warning(
                f'{topic} has several types {types}; recording {types[0]} '
                '(set parameter types to choose)')
        return types[0] if types else ''

    def _subscribe(self, topic: str, type_name: str, offers: list[QoSProfile]) -> None:
        msg_type = message_class(type_name)
        self._bag.add_topic(topic, type_name,
                            offered_qos_yaml([offered_profile(o) for o in offers]))
        qos = request_for_offers(offers)
        self._subscriptions_by_topic[topic] = self.create_subscription(
            msg_type, topic, partial(self._on_message, topic), qos, raw=True)
        self.get_logger().info(
            f'recording {topic} [{type_name}] {qos.reliability.name.lower()}/'
            f'{qos.durability.name.lower()}')

    def _on_message(self, topic: str, cdr_bytes: bytes, info: dict[str, int]) -> None:
        if self._bag.closed:
            return
        received_ns = self.get_clock().now().nanoseconds
        try:
            self._bag.write(topic, cdr_bytes, received_ns,
                            int(info.get('source_timestamp') or received_ns))
        except BagWriterError:
            self.write_failures += 1
            raise
        self.bytes_written += len(cdr_bytes)

    def health(self) -> Health:
        """
        The recording's health for /diagnostics: messages and bytes written, failures.

        ``messages <topic>`` counts each recorded topic's messages, so a user (or a test) can
        see that a node restarted on a topic is being recorded again.

        ERROR once the bag cannot be written on (a full disk: the message says what to run),
        WARN while a topic cannot be recorded (its type not installed, say), else OK.
        """
        bag = self._bag
        values: dict[str, object] = {
            'output': str(self._output), 'messages_written': bag.message_count,
            'bytes_written': self.bytes_written, 'write_failures': self.write_failures,
            'topics_recorded': len(self._subscriptions_by_topic),
            'topics_failed': len(self.failed_topics),
            **{f'messages {topic}': count
               for topic, count in sorted(bag.topic_message_counts.items())}}
        if bag.failure is not None:
            return Health(ERROR_LEVEL, bag.failure, values)
        if self.failed_topics:
            topic, why = next(iter(self.failed_topics.items()))
            more = f' (and {len(self.failed_topics) - 1} more)' if len(self.failed_topics) > 1 \
                else ''
            return Health(WARN_LEVEL, f'not recording {topic}: {why}{more}', values)
        if bag.closed:
            return Health(OK_LEVEL, f'closed {self._output}', values)
        return Health(OK_LEVEL, f'recording {len(self._subscriptions_by_topic)} topics into '
                                f'{self._output}', values)

    def close_bag(self, log: bool = True) -> str | None:
        """
        Finish the bag (summary, metadata.yaml); safe to call more than once.

        Returns the line that says so (logged here unless ``log`` is False), None when the
        bag was closed before. Raises BagWriterError when the bag could not be written
        completely (a full disk): what was flushed before is on disk, for ``softseq recover``.
        """
        if self._bag.closed:
            return None
        self._bag.close()
        line = f'closed {self._output} with {self._bag.message_count} messages'
        if log:
            self.get_logger().info(line)
        return line


def _compiled(name: str, pattern: str) -> 're.Pattern[str]':
    try:
        return re.compile(pattern)
    except re.error as err:
        raise BagWriterError(f'parameter {name}: {pattern!r} is not a regular expression '
                             f'({err})') from None


def _check_types_parameter(parameters: list[Parameter]) -> SetParametersResult:
    for parameter in parameters:
        if parameter.name == 'types' and parameter.type_ not in (
                Parameter.Type.STRING_ARRAY, Parameter.Type.NOT_SET):
            return SetParametersResult(
                successful=False, reason=f'types: must be a list of strings, got '
                f'{parameter.type_.name.lower()} {parameter.value!r}')
    return SetParametersResult(successful=True)


# The signals that stopped the recorder (rclpy's shutdown of the context did the stopping).
_STOPPED_BY: list[int] = []


def _stop_by_shutdown(signum: int, _frame: object) -> None:
    """SIGINT is left to rclpy's shutdown of the context; which signal it was is kept."""
    _STOPPED_BY.append(signum)


def main(args: list[str] | None = None) -> None:
    """Run the recorder until SIGINT/SIGTERM, then close the bag completely."""
    exit_with_help([Recorder], args, 'recorder')
    # On SIGINT rclpy shuts the executor down and then calls Python's handler, whose
    # KeyboardInterrupt could land inside a chunk being written; the shutdown alone stops the
    # recording between two callbacks, with every chunk whole.
    signal.signal(signal.SIGINT, _stop_by_shutdown)
    arguments = init_ros(args, 'recorder')
    built: list[Recorder] = []
    node = None
    exit_code = 0
    try:
        executor = SingleThreadedExecutor()
        build_nodes([Recorder], arguments, built)
        node = built[0]
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except NodeConfigError as err:
        # A -p rule that would change nothing: refused in one line, as the rig's nodes do.
        print(f'recorder: error: {err}', file=sys.stderr)
        exit_code = 2
    except (BagWriterError, MessageDefinitionError) as err:
        # One line, naming the path or the topic; a failed bag is not closed a second time.
        print(f'recorder: {err}', file=sys.stderr)
        exit_code = 1
    except Exception:
        # A signal during start-up shuts the context down under the feet of whatever rclpy
        # call runs then; that is a normal stop, anything else is a bug to show.
        if rclpy.ok():
            raise
        if not built and _STOPPED_BY:
            # Stopped before it recorded: it ends as any executable a signal ends while it
            # loads, quietly with 128 + the signal, and leaves no bag to look for (a bag it
            # had opened is closed whole: Recorder.__init__).
            exit_code = 128 + _STOPPED_BY[0]
    finally:
        node = built[0] if built else None
        if node is not None:
            closed = None
            try:
                closed = node.close_bag(log=False)
            except BagWriterError as err:
                if not exit_code:
                    print(f'recorder: {err}', file=sys.stderr)
                    exit_code = 1
            # The node's logger name: its namespace and name, as every other line it logged.
            name = node.get_logger().name
            node.destroy_node()
            if closed is not None:
                # Logged once the node is gone: after a Ctrl-C the context is shut down, and
                # the node's logger would fail to publish the line on /rosout.
                rclpy.logging.get_logger(name).info(closed)
        rclpy.try_shutdown()
    if exit_code:
        sys.exit(exit_code)


if __name__ == '__main__':
    main()
