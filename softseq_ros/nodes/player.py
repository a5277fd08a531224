"""
Replay a bag on its topics, with its timing and QoS (``softseq play BAG``).

This serves where ``ros2 bag play`` is not installed. Each recorded topic gets a publisher of
its recorded type with the QoS the bag says it was offered (``offered_qos_profiles``;
rosbag2's default when a bag does not say), under the name it was recorded with. Messages go
out as the recorded CDR bytes (rclpy publishes serialized messages as they are), in log-time
order, spaced as recorded divided by ``rate``; with ``clock`` the bag's time is published on
``/clock`` (rosgraph_msgs/Clock) before each message, so nodes with ``use_sim_time`` follow
the recording.

As ``ros2 bag play`` does, a replay can start ``start_offset_s`` into the bag, publish a topic
under another name (``remap``: recorded name -> new name, the player's own mapping of the
recorded names, applied all at once, so ``A:=B`` with ``B:=A`` swaps two topics; it never
reaches rcl, and two topics of different types under one name are refused, the node's own
/rosout and /parameter_events counted), take the QoS of
some topics from an overrides file (``ros2 bag play --qos-profile-overrides-path``'s YAML:
recorded topic name -> history, depth, reliability, durability, deadline, lifespan,
liveliness, liveliness_lease_duration, avoid_ros_namespace_conventions; a regular file of
UTF-8, read without blocking, a depth of 32 bits, durations of int64 ns), and be paused,
resumed and sped up while it runs. rosbag2's own service types (rosbag2_interfaces) are not
installed here, so its services take the std_srvs forms: ``~/pause``, ``~/resume``,
``~/toggle_paused`` and ``~/is_paused`` (std_srvs/Trigger; ``is_paused`` answers in
``success``) and the rate is the node's ``rate`` parameter, set at run time as
``ros2 param set /softseq_player rate 2.0`` (rosbag2's ``~/set_rate`` and ``~/get_rate``).
A change of rate or a pause keeps the bag time reached: the replay goes on from there.

SIGINT and SIGTERM end a replay as they end ``softseq run``: held while rclpy loads and the
publishers are made (a signal inside an import would leave a half-loaded module and a
misleading error), then acting between two messages; the replay closes its node and context
and the command exits 130 or 143. A SIGINT that the parent shell set to be ignored (a
background job) still stops it, as it stops ``softseq run``.
"""

from dataclasses import dataclass
import importlib
import math
from pathlib import Path
import threading
import time
from typing import Any, Iterator, Mapping

from mcap.reader import make_reader
from rcl_interfaces.msg import (
    FloatingPointRange,
    ParameterDescriptor,
    ParameterType,
    SetParametersResult,
)
from rclpy.duration import Duration
from rclpy.exceptions import InvalidTopicNameException
from rclpy.expand_topic_name import expand_topic_name
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    LivelinessPolicy,
    QoSProfile,
    ReliabilityPolicy,
)
from rclpy.validate_topic_name import validate_topic_name
from rosgraph_msgs.msg import Clock
from std_srvs.srv import Trigger
import yaml

from softseq_ros.bag.arrays import BagArrays, open_bag
from softseq_ros.bag.reader import bag_summary
from softseq_ros.errors import NotRegularFileError, UserError, read_regular_file
from softseq_ros.stopping import HeldSignals
from softseq_ros.wire import contract
from softseq_ros.yaml_text import parse_yaml

CLOCK_TOPIC = contract.CLOCK.name
CLOCK_TYPE = contract.CLOCK.type_name
# Longest sleep between two looks at the stop signals held (a replay at a slow rate sleeps long).
SIGNAL_POLL_S = 0.05
# rclpy's TimeSource subscribes to /clock with this QoS.
CLOCK_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)
# Topics the player's node publishes on by itself, whatever the bag holds: rcl's log and
# rclpy's parameter events. A played topic of another type under one of these names fails in
# create_publisher.
NODE_TOPICS = {'/rosout': ("the player's log", 'rcl_interfaces/msg/Log'),
               '/parameter_events': ("the player's parameter events",
                                     'rcl_interfaces/msg/ParameterEvent')}
_RELIABILITY = {'reliable': ReliabilityPolicy.RELIABLE, 1: ReliabilityPolicy.RELIABLE,
                'best_effort': ReliabilityPolicy.BEST_EFFORT, 2: ReliabilityPolicy.BEST_EFFORT}
_DURABILITY = {'transient_local': DurabilityPolicy.TRANSIENT_LOCAL,
               1: DurabilityPolicy.TRANSIENT_LOCAL, 'volatile': DurabilityPolicy.VOLATILE,
               2: DurabilityPolicy.VOLATILE}


# The largest rate a replay takes (a rate is a speed factor; 1e6 plays a day in 0.1 s).
MAX_RATE = 1.0e6
_HISTORY = {'keep_last': HistoryPolicy.KEEP_LAST, 'keep_all': HistoryPolicy.KEEP_ALL,
            'system_default': HistoryPolicy.SYSTEM_DEFAULT}
_RELIABILITY_NAMES = {'reliable': ReliabilityPolicy.RELIABLE,
                      'best_effort': ReliabilityPolicy.BEST_EFFORT,
                      'system_default': ReliabilityPolicy.SYSTEM_DEFAULT}
_DURABILITY_NAMES = {'transient_local': DurabilityPolicy.TRANSIENT_LOCAL,
                     'volatile': DurabilityPolicy.VOLATILE,
                     'system_default': DurabilityPolicy.SYSTEM_DEFAULT}
_LIVELINESS = {'automatic': LivelinessPolicy.AUTOMATIC,
               'manual_by_topic': LivelinessPolicy.MANUAL_BY_TOPIC,
               'system_default': LivelinessPolicy.SYSTEM_DEFAULT}
_DURATION_KEYS = ('deadline', 'lifespan', 'liveliness_lease_duration')


class PlayError(UserError):
    """A bag or an option that the player cannot use."""


def rate_reason(rate: object) -> str | None:
    """Why ``rate`` cannot be a replay's speed factor, or None."""
    if isinstance(rate, bool) or not isinstance(rate, (int, float)):
        return f'rate: must be a number, got {rate!r}'
    if not (0.0 < rate <= MAX_RATE):
        return f'rate: must be > 0 and <= {MAX_RATE:g}, got {rate}'
    return None


def _shown(value: object) -> str:
    """``value`` for a message: an integer of hundreds of digits by its size only."""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= 10**20:
        return f'an integer of {len(str(abs(value)))} digits'
    return repr(value)


def parse_remaps(rules: list[str] | None) -> dict[str, str]:
    """``FROM:=TO`` rules as a dict; PlayError naming the rule that is malformed."""
    remaps: dict[str, str] = {}
    for rule in rules or []:
        source, separator, target = rule.partition(':=')
        if not separator or not source or not target:
            raise PlayError(f'--remap {rule}: expected FROM:=TO, e.g. /pump/command:=/replayed')
        if source in remaps:
            raise PlayError(f'--remap {rule}: {source} is remapped twice')
        remaps[source] = target
    return remaps


def _resolved(name: str) -> str:
    """The fully qualified name the player's publisher of ``name`` gets."""
    return expand_topic_name(name, BagPlayer.NODE_NAME, '/')


def _check_one_type_per_name(bag: BagArrays, topics: list[str], remap: Mapping[str, str],
                             clock: bool) -> None:
    """
    Refuse two played topics of different types published under one name (PlayError).

    The names are those after ``remap`` (the player's own mapping, applied to the recorded
    names at once, so ``A:=B`` with ``B:=A`` swaps them); with ``clock`` the player also
    publishes rosgraph_msgs/msg/Clock on /clock, and its node always publishes on
    :data:`NODE_TOPICS`. The error names the options that put the topics there, or the bag.
    """
    placed: dict[str, tuple[str, str]] = dict(NODE_TOPICS)
    if clock:
        placed[CLOCK_TOPIC] = ('the bag time of --clock', CLOCK_TYPE)
    for topic in topics:
        name, type_name = _resolved(remap.get(topic, topic)), bag.channels[topic].type_name
        other, other_type = placed.setdefault(name, (topic, type_name))
        if other_type != type_name:
            said = [f'--remap {source}:={target}' for source, target in remap.items()
                    if _resolved(target) == name]
            if clock and name == CLOCK_TOPIC:
                said.append('--clock')
            raise PlayError(f'{" ".join(said) or bag.path}: {name} would carry {other} '
                            f'({other_type}) and {topic} ({type_name}); a topic has one type')


# A QoS duration is an int64 of nanoseconds in rcl (rcl_duration_t).
MAX_QOS_DURATION_NS = 2**63 - 1
# A history depth is a 32-bit integer in DDS (Fast DDS's HistoryQosPolicy.depth).
MAX_QOS_DEPTH = 2**31 - 1


def _qos_duration(path: str, topic: str, key: str, value: object) -> Duration:
    if not isinstance(value, Mapping) or set(value) - {'sec', 'nsec'} or not all(
            isinstance(value.get(k, 0), int) and not isinstance(value.get(k, 0), bool)
            and value.get(k, 0) >= 0 for k in ('sec', 'nsec')):
        raise PlayError(f'{path}: {topic}.{key}: expected {{sec: S, nsec: N}} with '
                        f'non-negative integers, got {value!r}')
    total = value.get('sec', 0) * 10**9 + value.get('nsec', 0)
    if total > MAX_QOS_DURATION_NS:
        raise PlayError(f'{path}: {topic}.{key}: {_shown(value.get("sec", 0))} s and '
                        f'{_shown(value.get("nsec", 0))} ns is beyond the longest QoS duration, '
                        f'{MAX_QOS_DURATION_NS} ns (int64, about 292 years)')
    return Duration(seconds=value.get('sec', 0), nanoseconds=value.get('nsec', 0))


def _qos_text(path: str) -> str:
    """The text of a QoS overrides file: a regular file of UTF-8, read without blocking."""
    try:
        data = read_regular_file(path)
    except NotRegularFileError as err:
        raise PlayError(f'{path}: cannot read the QoS overrides ({err.kind}, not a regular '
                        'file)') from None
    except OSError as err:
        raise PlayError(f'{path}: cannot read the QoS overrides ({err.strerror or err})') \
            from None
    try:
        return data.decode('utf-8-sig')
    except UnicodeDecodeError as err:
        raise PlayError(f'{path}: the QoS overrides are not UTF-8 text (byte {err.start}); '
                        'save the file as UTF-8') from None


def qos_overrides(path: str | Path, topics: list[str] | set[str]) -> dict[str, QoSProfile]:
    """
    The QoS profiles of a ``--qos-profile-overrides-path`` file, by recorded topic name.

    The file is rosbag2's: a mapping of topic names to profiles whose policies are named as
    rmw names them (``reliability: best_effort``, ``durability: transient_local``, ...);
    what a profile leaves out keeps rclpy's default. PlayError names the file, the topic and
    the key of anything that cannot be used, and a topic the bag does not hold.
    """
    path = str(path)
    text = _qos_text(path)
    data = parse_yaml(text, path, PlayError)
    if not isinstance(data, Mapping):
        raise PlayError(f'{path}: expected a mapping of topic names to QoS profiles')
    profiles = {}
    for topic, fields in data.items():
        if topic not in topics:
            raise PlayError(f'{path}: topic {topic}: not in the bag (its topics: '
                            f'{", ".join(sorted(topics))})')
        if not isinstance(fields, Mapping):
            raise PlayError(f'{path}: {topic}: expected a mapping of QoS policies')
        options: dict[str, Any] = {'depth': 10}
        for key, value in fields.items():
            names = {'history': _HISTORY, 'reliability': _RELIABILITY_NAMES,
                     'durability': _DURABILITY_NAMES, 'liveliness': _LIVELINESS}.get(key)
            if names is not None:
                if value not in names:
                    raise PlayError(f'{path}: {topic}.{key}: {value!r} is none of '
                                    f'{", ".join(names)}')
                options[key] = names[value]
            elif key == 'depth':
                if isinstance(value, bool) or not isinstance(value, int) \
                        or not 0 <= value <= MAX_QOS_DEPTH:
                    raise PlayError(f'{path}: {topic}.depth: expected an integer >= 0 and '
                                    f'<= {MAX_QOS_DEPTH} (a DDS history depth is 32 bits), '
                                    f'got {_shown(value)}')
                options['depth'] = value
            elif key in _DURATION_KEYS:
                options[key] = _qos_duration(path, topic, key, value)
            elif key == 'avoid_ros_namespace_conventions':
                if not isinstance(value, bool):
                    raise PlayError(f'{path}: {topic}.{key}: expected true or false, '
                                    f'got {value!r}')
                options[key] = value
            else:
                raise PlayError(f'{path}: {topic}.{key}: unknown QoS policy (expected '
                                f'history, depth, reliability, durability, deadline, '
                                'lifespan, liveliness, liveliness_lease_duration or '
                                'avoid_ros_namespace_conventions)')
        profiles[topic] = QoSProfile(**options)
    return profiles


class PlaybackClock:
    """
    Bag time against wall time, at a rate that can change and with pauses.

    A change of rate and a pause keep the bag time reached; thread safe (services and the
    rate parameter change it from the executor thread while the replay waits on it).
    """

    def __init__(self, rate: float) -> None:
        """A clock at ``rate``, not started."""
        self._changed = threading.Condition()
        self.rate = float(rate)
        self.paused = False
        self._wall = time.monotonic()
        self._bag_ns = 0

    def start(self, bag_ns: int) -> None:
        """Bag time ``bag_ns`` is now."""
        with self._changed:
            self._wall, self._bag_ns = time.monotonic(), int(bag_ns)
            self._changed.notify_all()

    def _now_locked(self) -> float:
        if self.paused:
            return float(self._bag_ns)
        return self._bag_ns + (time.monotonic() - self._wall) * 1e9 * self.rate

    def now_ns(self) -> float:
        """The bag time reached [ns]."""
        with self._changed:
            return self._now_locked()

    def set_rate(self, rate: float) -> None:
        """Go on at ``rate`` from the bag time reached."""
        with self._changed:
            self._bag_ns, self._wall = self._now_locked(), time.monotonic()
            self.rate = float(rate)
            self._changed.notify_all()

    def set_paused(self, paused: bool) -> bool:
        """Pause or resume; True when that changed anything."""
        with self._changed:
            if paused == self.paused:
                return False
            self._bag_ns, self._wall = self._now_locked(), time.monotonic()
            self.paused = paused
            self._changed.notify_all()
            return True

    def wait_until(self, bag_ns: int, poll_s: float) -> bool:
        """Wait at most ``poll_s`` for bag time ``bag_ns``; True once it is reached."""
        with self._changed:
            if self.paused:
                self._changed.wait(poll_s)
                return False
            left = (bag_ns - self._now_locked()) * 1e-9 / self.rate
            if left <= 0.0:
                return True
            self._changed.wait(min(left, poll_s))
            return not self.paused and self._now_locked() >= bag_ns


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

    NODE_NAME = 'softseq_player'
    # Its std_srvs/Trigger services (~/name), as ros2 bag play's of the same names.
    SERVICES: dict[str, str] = {
        'pause': 'pause the replay (the bag time stands still)',
        'resume': 'go on from where it was paused',
        'toggle_paused': 'pause when playing, resume when paused',
        'is_paused': 'success is true while paused'}

    def __init__(self, bag: str, *, rate: float = 1.0, loop: bool = False,
                 clock: bool = False, topics: list[str] | None = None,
                 start_offset_s: float = 0.0, remap: Mapping[str, str] | None = None,
                 qos_overrides_path: str | Path | None = None,
                 **node_options: Any) -> None:
        """Open the bag and create one publisher per topic (refuses bad options first)."""
        reason = rate_reason(rate)
        if reason is not None:
            raise PlayError(reason)
        if not (isinstance(start_offset_s, (int, float)) and math.isfinite(start_offset_s)
                and start_offset_s >= 0.0):
            raise PlayError(f'start offset must be a finite number of seconds >= 0, '
                            f'got {start_offset_s}')
        self.bag: BagArrays = open_bag(bag)
        unknown = sorted(set(topics or []) - set(self.bag.channels))
        if unknown:
            raise PlayError(f'{bag}: no topic {", ".join(unknown)} in this bag')
        self.topics = list(topics) if topics else sorted(self.bag.channels)
        remap = dict(remap or {})
        for source, target in remap.items():
            if source not in self.topics:
                raise PlayError(f'--remap {source}:={target}: no topic {source} among those '
                                f'played ({", ".join(self.topics)})')
            try:
                validate_topic_name(target)
            except InvalidTopicNameException as err:
                raise PlayError(f'--remap {source}:={target}: {target!r} is not a valid topic '
                                f'name ({str(err).splitlines()[0]})') from None
        _check_one_type_per_name(self.bag, self.topics, remap, clock)
        overrides = qos_overrides(qos_overrides_path, self.topics) \
            if qos_overrides_path is not None else {}
        summary = bag_summary(bag)
        # Compared as a float first: 1e300 s is no integer of nanoseconds.
        if start_offset_s > 0.0 and start_offset_s * 1e9 > summary.duration_ns + 0.5:
            raise PlayError(f"{bag}: start offset {start_offset_s:g} s is past the bag's end "
                            f'({summary.duration_ns * 1e-9:.9g} s after its start)')
        self.start_ns = summary.start_ns + int(round(start_offset_s * 1e9))
        super().__init__(self.NODE_NAME, **node_options)
        self.loop = bool(loop)
        self.remap = remap
        self.clock_source = PlaybackClock(rate)
        self.publishers_by_topic = {}
        for topic in self.topics:
            info = self.bag.channels[topic]
            self.publishers_by_topic[topic] = self.create_publisher(
                message_class(info.type_name), remap.get(topic, topic),
                overrides.get(topic) or qos_from_bag(info.offered_qos_profiles, topic))
        self.clock_publisher = self.create_publisher(Clock, CLOCK_TOPIC, CLOCK_QOS) \
            if clock else None
        self._stop = threading.Event()
        # Stop signals held by the caller (HeldSignals.pending): non-empty ends the replay.
        self.signals: list[int] = []
        self.add_on_set_parameters_callback(self._check_rate)
        self.declare_parameter('rate', float(rate), ParameterDescriptor(
            type=ParameterType.PARAMETER_DOUBLE, dynamic_typing=True,
            description='Speed factor of the replay (integer or double); '
            'set at run time to change it from the bag time reached.',
            floating_point_range=[FloatingPointRange(from_value=0.0, to_value=MAX_RATE)]))
        self.add_post_set_parameters_callback(self._rate_changed)
        for name in self.SERVICES:
            self.create_service(Trigger, f'~/{name}', getattr(self, f'_serve_{name}'))

    @property
    def rate(self) -> float:
        """The replay's speed factor now."""
        return self.clock_source.rate

    @property
    def paused(self) -> bool:
        """True while the replay is paused."""
        return self.clock_source.paused

    def _check_rate(self, parameters: list[Parameter]) -> SetParametersResult:
        for parameter in parameters:
            if parameter.name == 'rate':
                reason = rate_reason(parameter.value)
                if reason is not None:
                    return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    def _rate_changed(self, parameters: list[Parameter]) -> None:
        for parameter in parameters:
            if parameter.name == 'rate':
                self.clock_source.set_rate(float(parameter.value))

    def _answer(self, response: Trigger.Response, success: bool,
                message: str) -> Trigger.Response:
        response.success, response.message = success, message
        return response

    def _serve_pause(self, _request: Trigger.Request,
                     response: Trigger.Response) -> Trigger.Response:
        changed = self.clock_source.set_paused(True)
        return self._answer(response, True, 'paused' if changed else 'already paused')

    def _serve_resume(self, _request: Trigger.Request,
                      response: Trigger.Response) -> Trigger.Response:
        changed = self.clock_source.set_paused(False)
        return self._answer(response, True, 'playing' if changed else 'already playing')

    def _serve_toggle_paused(self, _request: Trigger.Request,
                             response: Trigger.Response) -> Trigger.Response:
        paused = not self.clock_source.paused
        self.clock_source.set_paused(paused)
        return self._answer(response, True, 'paused' if paused else 'playing')

    def _serve_is_paused(self, _request: Trigger.Request,
                         response: Trigger.Response) -> Trigger.Response:
        paused = self.clock_source.paused
        return self._answer(response, paused, 'paused' if paused else 'playing')

    def stop(self) -> None:
        """Ask a running :meth:`play` to end after the current message."""
        self._stop.set()

    def _stopped(self) -> bool:
        return bool(self.signals) or self._stop.is_set()

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
                        topics=list(wanted), starting_at=self.start_ns, log_time_order=True):
                    yield channel.topic, message.log_time, message.data

    def _wait_for(self, log_time: int) -> bool:
        """Wait until bag time ``log_time`` (paused time not counting); False when stopped."""
        while not self._stopped():
            if self.clock_source.wait_until(log_time, SIGNAL_POLL_S):
                return True
        return False

    def play(self) -> PlayResult:
        """Replay until the bag ends (or forever with ``loop``, until :meth:`stop`)."""
        result = PlayResult()
        while not self._stopped():
            # Each pass starts at the start offset, as ros2 bag play's loop does.
            self.clock_source.start(self.start_ns)
            for topic, log_time, data in self._messages():
                if self._stopped() or not self._wait_for(log_time):
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


def rcl_arguments(args: list[str] | None) -> list[str]:
    """
    What rcl is given of a command line: its program name and its ``--ros-args`` sections.

    rcl takes any FROM:=TO word outside ``--ros-args`` for a remap rule of its own (warning
    that the syntax is deprecated) and applies it to the names the player chose, which undid
    a swap: the words of ``--remap`` are the player's alone, and so is the rest of its
    command line.
    """
    if not args:
        return ['softseq']
    kept = [args[0]]
    in_ros_args = False
    for word in args[1:]:
        if word == '--ros-args':
            in_ros_args = True
        if in_ros_args:
            kept.append(word)
        if word == '--':
            in_ros_args = False
    return kept


def play(bag: str, rate: float = 1.0, loop: bool = False, clock: bool = False,
         topics: list[str] | None = None, wait_s: float = 0.0,
         args: list[str] | None = None, held: HeldSignals | None = None, *,
         start_offset_s: float = 0.0, remap: Mapping[str, str] | None = None,
         qos_overrides_path: str | Path | None = None) -> PlayResult:
    """
    Run a replay in its own rclpy context until it ends or SIGINT/SIGTERM.

    A stop signal ends the replay between two messages; once the node and the context are
    closed, KeyboardInterrupt (SIGINT) or TerminatedError (SIGTERM) is raised. ``held`` is a
    caller's :class:`HeldSignals` already in force (one that also covered the import of this
    module); without one, the signals are held from here on. ``args`` is a command line (a
    caller's ``sys.argv``): rcl is given its program name and its ``--ros-args`` sections
    only (:func:`rcl_arguments`).
    """
    if held is None:
        with HeldSignals() as own:
            return play(bag, rate, loop, clock, topics, wait_s, args, own,
                        start_offset_s=start_offset_s, remap=remap,
                        qos_overrides_path=qos_overrides_path)
    if not (isinstance(wait_s, (int, float)) and math.isfinite(wait_s) and wait_s >= 0.0):
        raise PlayError(f'--wait-for-subscribers: must be a finite number of seconds >= 0, '
                        f'got {wait_s}')
    held.check()
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

    held.check()
    context = rclpy.Context()
    rclpy.init(args=rcl_arguments(args), context=context)
    player = None
    try:
        player = BagPlayer(bag, rate=rate, loop=loop, clock=clock, topics=topics,
                           start_offset_s=start_offset_s, remap=remap,
                           qos_overrides_path=qos_overrides_path, context=context)
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
