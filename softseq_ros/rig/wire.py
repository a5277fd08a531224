"""
The contract on the wire: core values to CDR bytes, and received ROS messages to core values.

The nodes publish exactly these bytes (rclpy's ``publish`` takes serialised messages) and the
batch runner writes exactly these bytes into its bags, so a batch bag and a bag recorded from
the nodes over DDS hold the same encoding of the same values. Nothing here imports rclpy:
templates of fixed-layout messages (pose arrays, marker arrays) are built from plain objects
with the messages' fields, and received messages are read by their fields only.
"""

from functools import lru_cache
import json
from types import SimpleNamespace
from typing import Any, Callable

from softseq_ros.bag.cdr import (
    ENCAPSULATION,
    FixedLayout,
    encoder_for,
    fluid_pressure_cdr,
    joint_state_packer,
    string_cdr,
)
from softseq_ros.errors import UserError
from softseq_ros.rig.contract import FRAME_ID
from softseq_ros.rig.render import SEGMENT_RGB
from softseq_ros.rig.values import (
    Backbone,
    Markers,
    Pressure,
    PumpCommand,
    PumpStatus,
    SceneIdentity,
    SegmentCurvatures,
    SegmentVolumes,
    SideImage,
    Snapshot,
    SnapshotStep,
    SnapThrough,
    TopicValue,
)

NS_PER_S = 1_000_000_000
SYRINGE_JOINT = 'syringe'
MARKER_WIDTH_M = 0.015  # the paper's 15 x 15 mm section
LINE_STRIP = 4
_SYRINGE = (SYRINGE_JOINT,)


class InputError(UserError):
    """A received message that cannot become a core value; ``key`` names the kind of fault."""

    def __init__(self, key: str, text: str) -> None:
        """``key`` groups repeats of the same fault (for throttled warnings)."""
        super().__init__(text)
        self.key = key


# ---------------------------------------------------------------- values -> CDR bytes

_COMMAND_PACK, _COMMAND_BLOCK = joint_state_packer('', _SYRINGE, (1, 1, 0))


def _pump_command(value: PumpCommand) -> bytes:
    sec, nanosec = divmod(value.stamp_ns, NS_PER_S)
    return ENCAPSULATION + _COMMAND_PACK(sec, nanosec, _COMMAND_BLOCK, 1, value.injected_m3, 1,
                                         value.flow_m3_per_s, 0)


# Per joint names: a segment state's (pack, block) for volumes (effort = pressure) and
# for curvatures (positions only); a rig sends one set of names for hours.
_volume_packers: dict[tuple[str, ...], tuple[Callable[..., bytes], bytes]] = {}
_curvature_packers: dict[tuple[str, ...], tuple[Callable[..., bytes], bytes]] = {}


def pump_status_json(value: PumpStatus) -> str:
    """The JSON text ``pump/status`` carries."""
    return json.dumps({'state': value.state, 'reason': value.reason,
                       'stamp_ns': value.stamp_ns})


def _pump_status(value: PumpStatus) -> bytes:
    return string_cdr(pump_status_json(value))


def _pressure(value: Pressure) -> bytes:
    sec, nanosec = divmod(value.stamp_ns, NS_PER_S)
    return fluid_pressure_cdr(sec, nanosec, '', value.absolute_pa, 0.0)


def _volumes(value: SegmentVolumes) -> bytes:
    names, volumes = value.names, value.volumes_m3
    n = len(names)
    packer = _volume_packers.get(names)
    if packer is None or n != len(volumes):
        packer = _volume_packers[names] = joint_state_packer('', names, (len(volumes), 0, n))
    pack, block = packer
    sec, nanosec = divmod(value.stamp_ns, NS_PER_S)
    return ENCAPSULATION + pack(sec, nanosec, block, len(volumes), *volumes, 0, n,
                                *((value.gauge_pa,) * n))


def _curvatures(value: SegmentCurvatures) -> bytes:
    names, curvatures = value.names, value.curvatures_per_m
    packer = _curvature_packers.get(names)
    if packer is None or len(names) != len(curvatures):
        packer = _curvature_packers[names] = joint_state_packer('', names,
                                                                (len(curvatures), 0, 0))
    pack, block = packer
    sec, nanosec = divmod(value.stamp_ns, NS_PER_S)
    return ENCAPSULATION + pack(sec, nanosec, block, len(curvatures), *curvatures, 0, 0)


def _snap_through(value: SnapThrough) -> bytes:
    return string_cdr(json.dumps({
        'injected_m3': value.injected_m3, 'from_volumes_m3': value.from_volumes_m3,
        'to_volumes_m3': value.to_volumes_m3, 'from_pressure_pa': value.from_pressure_pa,
        'to_pressure_pa': value.to_pressure_pa}))


def scene_identity_json(value: SceneIdentity) -> str:
    """The JSON text ``actuator/scene`` carries."""
    return json.dumps({'scene': value.scene, 'segments': list(value.segments),
                       'segments_sha256': value.segments_sha256, 'stamp_ns': value.stamp_ns})


def _scene_identity(value: SceneIdentity) -> bytes:
    return string_cdr(scene_identity_json(value))


def _snapshot_step(value: SnapshotStep) -> bytes:
    return string_cdr(json.dumps({
        'step': value.step, 'trigger_injected_m3': value.trigger_injected_m3,
        'direction': value.direction, 'injected_m3': value.injected_m3,
        'stamp_ns': value.stamp_ns}))


def _header(frame_id: str = FRAME_ID) -> SimpleNamespace:
    return SimpleNamespace(stamp=SimpleNamespace(sec=0, nanosec=0), frame_id=frame_id)


def _xyz() -> SimpleNamespace:
    return SimpleNamespace(x=0.0, y=0.0, z=0.0)


def _pose() -> SimpleNamespace:
    return SimpleNamespace(position=_xyz(),
                           orientation=SimpleNamespace(x=0.0, y=0.0, z=0.0, w=1.0))


@lru_cache(maxsize=16)
def pose_array_layout(n_points: int) -> FixedLayout:
    """The fixed CDR layout of a PoseArray of ``n_points`` poses in ``softseq_base``."""
    template = SimpleNamespace(header=_header(), poses=[_pose() for _ in range(n_points)])
    return FixedLayout(template, 'geometry_msgs/msg/PoseArray')


@lru_cache(maxsize=16)
def marker_array_layout(points_per_line: tuple[int, ...]) -> FixedLayout:
    """The fixed CDR layout of one LINE_STRIP marker per segment (``points_per_line`` each)."""
    markers = []
    for index, count in enumerate(points_per_line):
        red, green, blue = SEGMENT_RGB[index % len(SEGMENT_RGB)]
        scale = _xyz()
        scale.x = MARKER_WIDTH_M
        markers.append(SimpleNamespace(
            header=_header(), ns='backbone', id=index, type=LINE_STRIP, action=0,
            pose=_pose(), scale=scale,
            color=SimpleNamespace(r=red / 255.0, g=green / 255.0, b=blue / 255.0, a=1.0),
            lifetime=SimpleNamespace(sec=0, nanosec=0), frame_locked=False,
            points=[_xyz() for _ in range(count)], colors=[], texture_resource='',
            texture=SimpleNamespace(header=_header(''), format='', data=b''),
            uv_coordinates=[], text='', mesh_resource='',
            mesh_file=SimpleNamespace(filename='', data=b''), mesh_use_embedded_materials=False))
    return FixedLayout(SimpleNamespace(markers=markers), 'visualization_msgs/msg/MarkerArray')


def _pose_array(value: Backbone | Snapshot) -> bytes:
    return pose_array_layout(len(value.poses)).encode(value.stamp_ns, [value.poses])


def _markers(value: Markers) -> bytes:
    layout = marker_array_layout(tuple(len(line) for line in value.lines))
    return layout.encode(value.stamp_ns, value.lines)


_image_encoder = encoder_for('sensor_msgs/msg/Image')


def _side_image(value: SideImage) -> bytes:
    sec, nanosec = divmod(value.stamp_ns, NS_PER_S)
    return _image_encoder(SimpleNamespace(
        header=SimpleNamespace(stamp=SimpleNamespace(sec=sec, nanosec=nanosec),
                               frame_id=FRAME_ID),
        height=value.height, width=value.width, encoding='rgb8', is_bigendian=0,
        step=3 * value.width, data=value.rgb))


ENCODERS: dict[type, Callable[[Any], bytes]] = {
    PumpCommand: _pump_command,
    PumpStatus: _pump_status,
    Pressure: _pressure,
    SegmentVolumes: _volumes,
    SegmentCurvatures: _curvatures,
    SnapThrough: _snap_through,
    SceneIdentity: _scene_identity,
    Backbone: _pose_array,
    Snapshot: _pose_array,
    SnapshotStep: _snapshot_step,
    Markers: _markers,
    SideImage: _side_image,
}


def encode(value: TopicValue) -> bytes:
    """The CDR bytes of a core value, as its topic carries them."""
    return ENCODERS[type(value)](value)


# ---------------------------------------------------------------- ROS messages -> values

def _stamp_ns(header: Any) -> int:
    stamp = header.stamp
    return stamp.sec * NS_PER_S + stamp.nanosec


def _floats(values: Any) -> list[float]:
    return values.tolist() if hasattr(values, 'tolist') else [float(v) for v in values]


def pump_command(msg: Any) -> PumpCommand:
    """A received sensor_msgs/JointState as a pump command; InputError when it is not one."""
    names, position = list(msg.name), msg.position
    if len(names) != 1 or len(position) != 1:
        raise InputError('shape', f'command refused: expected one joint ({SYRINGE_JOINT}) with '
                                  f'one position, got names {names} and {len(position)} '
                                  'positions')
    if names[0] != SYRINGE_JOINT:
        raise InputError('name', f'command refused: joint name must be {SYRINGE_JOINT}, '
                                 f'got {names[0]!r}')
    velocity = msg.velocity
    flow = float(velocity[0]) if len(velocity) == 1 else 0.0
    return PumpCommand(_stamp_ns(msg.header), float(position[0]), flow)


def pressure(msg: Any) -> Pressure:
    """A received sensor_msgs/FluidPressure."""
    return Pressure(_stamp_ns(msg.header), float(msg.fluid_pressure))


def segment_volumes(msg: Any) -> SegmentVolumes:
    """A received sensor_msgs/JointState of segment volumes (effort = gauge pressure)."""
    effort = msg.effort
    gauge = float(effort[0]) if len(effort) else float('nan')
    return SegmentVolumes(_stamp_ns(msg.header), tuple(msg.name), _floats(msg.position), gauge)


def segment_curvatures(msg: Any) -> SegmentCurvatures:
    """A received sensor_msgs/JointState of segment curvatures."""
    return SegmentCurvatures(_stamp_ns(msg.header), tuple(msg.name), _floats(msg.position))


DECODERS: dict[str, Callable[[Any], TopicValue]] = {
    PumpCommand.topic.name: pump_command,
    Pressure.topic.name: pressure,
    SegmentVolumes.topic.name: segment_volumes,
    SegmentCurvatures.topic.name: segment_curvatures,
}
