"""
The rig's topic contract: every topic the rig's cores produce or consume, in one table.

For each topic: its name relative to the node's namespace (``pump/command``: started with
``-r __ns:=/rig2`` a whole rig moves to ``/rig2/pump/command``), its ROS message type, its QoS,
which core produces it, which cores consume it, and which scene ``outputs`` entry switches it
on (None: always on). Nodes create their publishers and subscriptions from it, the one-process
rig and the batch runner route values between cores by it, the recorder records its topics by
default and the analysis finds its topics by it. Nothing here imports rclpy: QoS is plain data
that the nodes turn into rclpy profiles and the bag writer into rosbag2's QoS YAML.
"""

from dataclasses import dataclass

# A light module (no numpy, no scipy): the contract is read by quick commands too.
from softseq_ros.scene.outputs import DEFAULT_OUTPUTS as SCENE_DEFAULT_OUTPUTS
from softseq_ros.scene.outputs import OUTPUT_NAMES as SCENE_OUTPUT_NAMES

# Core roles and the names of the ROS nodes that host them.
PUMP = 'pump'
ACTUATOR = 'actuator'
CAMERA = 'camera'
NODE_NAMES: dict[str, str] = {PUMP: 'syringe_pump', ACTUATOR: 'actuator', CAMERA: 'camera'}
# A controller closing the loop on the rig (the user's, or the example pressure_hold): it reads
# the actuator's volumes and gives the pump setpoints. Not one of the rig's own nodes.
CONTROLLER = 'controller'

FRAME_ID = 'softseq_base'
DEFAULT_AMBIENT_PRESSURE_PA = 101325.0
# Stamps on every topic and in every bag are integer nanoseconds.
NS_PER_S = 1_000_000_000
# Segment i is drawn in SEGMENT_RGB[i % 6] by the markers and the side-view image alike, so a
# viewer matches the two by colour.
SEGMENT_RGB = ((31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40),
               (148, 103, 189), (140, 86, 75))

# The outputs a scene may list are the scene's business (scene.outputs); which topics
# each switches on is the contract's (Topic.output).
OUTPUT_NAMES = SCENE_OUTPUT_NAMES
DEFAULT_OUTPUTS = SCENE_DEFAULT_OUTPUTS


@dataclass(frozen=True)
class Qos:
    """A topic's QoS: keep-last ``depth``, reliable or best effort, latched or volatile."""

    depth: int
    reliable: bool = True
    latched: bool = False  # transient_local: a late joiner gets the last ``depth`` messages


@dataclass(frozen=True)
class Topic:
    """One topic of the contract."""

    name: str                      # relative to the node's namespace
    type_name: str                 # pkg/msg/Type
    qos: Qos                       # the publisher's (a recorder asks for it, a bag says it)
    producer: str                  # core role
    consumers: tuple[str, ...]     # core roles whose ``handle`` takes it
    output: str | None             # scene output name that switches it on, None: always on
    content: str                   # what the message holds (units, frame)
    # What the consumer cores read with, when not ``qos``: a latched state topic keeps many
    # messages for a reader that must not miss one, and its consumers want the current state.
    consumer_qos: Qos | None = None

    @property
    def reader_qos(self) -> Qos:
        """The QoS the consumer cores (and a restarting actuator) subscribe with."""
        return self.qos if self.consumer_qos is None else self.consumer_qos


# How many messages the publisher of a message-per-command topic keeps for each reader: a
# reader that stalls (a recorder on a loaded machine) misses none for this many commands,
# 5 s at 200 Hz. A keep-last publisher replaces a message its reliable reader has not yet
# acknowledged once its history is full, so a depth of 1 lost answers to any reader slower
# than the actuator for a moment (a recorder at 200 Hz missed 143 that a probe received).
ANSWER_DEPTH = 1000
# Camera frames: 1 s at 100 Hz, 10 s at the scene's default 10 Hz.
FRAME_DEPTH = 100


PUMP_COMMAND = Topic(
    'pump/command', 'sensor_msgs/msg/JointState',
    # Deep: a command the actuator's queue drops is skipped physics-wise (the jump rule), but
    # its answer is missing from the recording; a stalled process must not lose any.
    Qos(ANSWER_DEPTH), PUMP, (ACTUATOR,), None,
    'joint syringe: position = injected volume [m^3], velocity = signed flow [m^3/s]; behind a '
    'pressure regulator, joint regulator: effort = target gauge pressure [Pa] (nothing else); '
    'at the pump rate while running, else on a change and once a second')
# What a controller asks of the pump, taken in its setpoint mode (the pump's ~/setpoint_mode):
# the same joint as pump/command, so a controller commands the pump as the pump commands the
# actuator. Reliable and deep enough that a burst of setpoints is not lost before the pump reads.
PUMP_SETPOINT = Topic(
    'pump/setpoint', 'sensor_msgs/msg/JointState', Qos(10), CONTROLLER, (PUMP,), None,
    'joint syringe (or regulator) with exactly one field given: position = target injected '
    'volume [m^3] '
    "(reached at the pump's flow rate), velocity = flow [m^3/s] (signed, + inflates), effort = "
    'target gauge pressure [Pa] (a pressure supply only); taken in setpoint mode')
PUMP_STATUS = Topic(
    'pump/status', 'std_msgs/msg/String', Qos(1, latched=True), PUMP, (), None,
    'JSON {"state", "reason", "stamp_ns"}: idle, running, held, finished or stopped')
PRESSURE = Topic(
    'actuator/pressure', 'sensor_msgs/msg/FluidPressure', Qos(ANSWER_DEPTH), ACTUATOR, (),
    'pressure', 'absolute pressure [Pa] = gauge + ambient')
# The pump reads its relief pressure here, gauge as the actuator computed it: no ambient
# pressure of its own that could disagree with the actuator's. Latched, so that a camera
# started later or a restarted actuator gets the current state; the consumers read the
# newest only (a late joiner is sent the publisher's whole history).
VOLUMES = Topic(
    'actuator/volumes', 'sensor_msgs/msg/JointState', Qos(ANSWER_DEPTH, latched=True),
    ACTUATOR, (CAMERA, PUMP, CONTROLLER), 'volumes',
    'one joint per segment, base to tip: position = volume [m^3], effort = gauge pressure [Pa]',
    consumer_qos=Qos(1, latched=True))
CURVATURES = Topic(
    'actuator/curvatures', 'sensor_msgs/msg/JointState', Qos(ANSWER_DEPTH), ACTUATOR,
    (CAMERA,), 'curvature', 'one joint per segment: position = curvature [1/m]')
# The channel flows are the other half of the volumes' state: on with them, for an actuator
# whose model has channels (a scene with a network). So 'flows' is a core's output that no
# scene lists: the actuator derives it (DERIVED_OUTPUTS: what it goes with).
DERIVED_OUTPUTS: dict[str, str] = {'flows': 'volumes'}
CHANNEL_FLOWS = Topic(
    'actuator/channel_flows', 'sensor_msgs/msg/JointState', Qos(ANSWER_DEPTH), ACTUATOR, (),
    'flows', 'one joint per channel, base to tip, named <segment>_to_<segment>: velocity = flow '
    '[m^3/s], positive towards the tip; effort = pressure drop along it [Pa]')
EVENTS = Topic(
    'actuator/events', 'std_msgs/msg/String', Qos(100, latched=True), ACTUATOR, (), 'events',
    'JSON per snap-through: injected_m3, from/to_volumes_m3, from/to_pressure_pa (gauge); in '
    'time (a scene with a network) one per exchange of fluid between the segments, with also '
    'start_ns, duration_s (10 % to 90 % of the fluid moved), fluid_moved_m3, '
    'peak_exchange_m3_per_s, giving_segments and taking_segments (names), snap_through and '
    'peak_ns; cut_short (true) on one the run ended while it was under way')
# Which scene's segments the actuator runs, as ROS keeps a robot's description: latched, so
# a recorder that starts later still gets it, and every bag can name the physics behind it.
SCENE = Topic(
    'actuator/scene', 'std_msgs/msg/String', Qos(1, latched=True), ACTUATOR, (), None,
    'JSON {"scene", "segments", "segments_sha256", "stamp_ns"}: the scene name, its segments '
    'base to tip and the SHA-256 of their definitions (softseq_ros.segments.identity)')
BACKBONE = Topic(
    'camera/backbone', 'geometry_msgs/msg/PoseArray', Qos(FRAME_DEPTH), CAMERA, (), 'poses',
    'backbone points in softseq_base at the camera rate')
SNAPSHOTS = Topic(
    'camera/snapshots', 'geometry_msgs/msg/PoseArray', Qos(20, latched=True), CAMERA, (),
    'poses', "one backbone per trigger crossing (the paper's steps)")
SNAPSHOT_STEPS = Topic(
    'camera/snapshot_steps', 'std_msgs/msg/String', Qos(20, latched=True), CAMERA, (), 'poses',
    'JSON per snapshot, in the same order: step, trigger_injected_m3, direction, stamp_ns')
MARKERS = Topic(
    'camera/markers', 'visualization_msgs/msg/MarkerArray', Qos(FRAME_DEPTH), CAMERA, (),
    'markers',
    'one LINE_STRIP per segment')
IMAGE = Topic(
    'camera/image', 'sensor_msgs/msg/Image', Qos(2, reliable=False), CAMERA, (), 'image',
    'rgb8 side view, rendered only while someone subscribes')

RIG_TOPICS: tuple[Topic, ...] = (PUMP_COMMAND, PUMP_SETPOINT, PUMP_STATUS, PRESSURE, VOLUMES,
                                 CURVATURES, CHANNEL_FLOWS, EVENTS, SCENE, BACKBONE, SNAPSHOTS,
                                 SNAPSHOT_STEPS, MARKERS, IMAGE)
TOPICS_BY_NAME: dict[str, Topic] = {topic.name: topic for topic in RIG_TOPICS}

# The simulated clock is ROS's own (absolute by convention); QoS as rclpy's TimeSource takes it.
CLOCK = Topic('/clock', 'rosgraph_msgs/msg/Clock', Qos(1, reliable=False), 'sim_clock', (),
              None, 'simulated time')
# Absolute by ROS convention (the diagnostic aggregator listens there); every node publishes
# its own status, named and with the hardware_id of its fully qualified name.
DIAGNOSTICS = Topic(
    '/diagnostics', 'diagnostic_msgs/msg/DiagnosticArray', Qos(10), 'every node', (), None,
    "once a second, one DiagnosticStatus per node: level, message and values (SI); name "
    "'<node>: <task>' and hardware_id the node's fully qualified name")


def consumed_by(role: str) -> tuple[Topic, ...]:
    """The topics a core consumes."""
    return tuple(topic for topic in RIG_TOPICS if role in topic.consumers)


def enabled(topic: Topic, outputs: frozenset[str] | set[str]) -> bool:
    """True when ``outputs`` (scene output names) switch ``topic`` on."""
    return topic.output is None or topic.output in outputs


def resolve(name: str, namespace: str = '/') -> str:
    """The absolute name of a relative topic ``name`` in ``namespace`` (as ROS resolves it)."""
    if name.startswith('/'):
        return name
    return namespace.rstrip('/') + '/' + name


def relative_name(absolute: str, namespace: str = '/') -> str | None:
    """The contract name of an absolute topic under ``namespace``, or None when not under it."""
    prefix = namespace.rstrip('/') + '/'
    if not absolute.startswith(prefix):
        return None
    return absolute[len(prefix):]


def find_namespaces(absolute_topics: list[str] | set[str] | tuple[str, ...],
                    name: str = PUMP_COMMAND.name) -> list[str]:
    """The namespaces under which ``name`` appears among ``absolute_topics`` (sorted)."""
    suffix = '/' + name
    return sorted({topic[:-len(suffix)] or '/' for topic in absolute_topics
                   if topic.endswith(suffix)})
