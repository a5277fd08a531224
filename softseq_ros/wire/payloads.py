"""
The contract on the wire: core values to CDR bytes, and received ROS messages to core values.

The nodes publish exactly these bytes (rclpy's ``publish`` takes serialised messages) and the
batch runner writes exactly these bytes into its bags, so a batch bag and a bag recorded from
the nodes over DDS hold the same encoding of the same values. Nothing here imports rclpy:
templates of fixed-layout messages (pose arrays, marker arrays) are built from plain objects
with the messages' fields, and received messages are read by their fields only.

The JSON objects the std_msgs/String topics carry are defined here once, per value type, with
both their encoder and their decoder (:class:`JsonPayload`): the analysis reads recorded
payloads with the same codec the nodes and the batch runner write them with.
"""

import dataclasses
from functools import lru_cache
import json
from types import SimpleNamespace
from typing import Any, Callable

import numpy as np

from softseq_ros.errors import UserError
from softseq_ros.wire.cdr import (
    ENCAPSULATION,
    FixedLayout,
    encoder_for,
    fluid_pressure_block,
    fluid_pressure_cdr,
    joint_state_blocks,
    joint_state_packer,
    string_cdr,
)
from softseq_ros.wire.contract import FRAME_ID, NS_PER_S, SEGMENT_RGB
from softseq_ros.wire.values import (
    Backbone,
    ChannelFlows,
    Markers,
    Pressure,
    PumpCommand,
    PumpSetpoint,
    PumpStatus,
    SceneIdentity,
    SegmentCurvatures,
    SegmentVolumes,
    SideImage,
    Snapshot,
    SnapshotStep,
    SnapThrough,
    TopicValue,
    regulator_command,
)

SYRINGE_JOINT = 'syringe'
# A pressure regulator's command: its target gauge pressure, as the joint's effort.
REGULATOR_JOINT = 'regulator'
MARKER_WIDTH_M = 0.015  # the paper's 15 x 15 mm section
LINE_STRIP = 4
_SYRINGE = (SYRINGE_JOINT,)


class InputError(UserError):
    """A received message that cannot become a core value; ``key`` names the kind of fault."""

    def __init__(self, key: str, text: str) -> None:
        """``key`` groups repeats of the same fault (for throttled warnings)."""
        super().__init__(text)
        self.key = key


# ---------------------------------------------------------------- JSON in std_msgs/String
#
# Every std_msgs/String topic of the contract carries one JSON object per message. Its codec
# below is the only place that knows the object's keys: the nodes and the batch runner encode
# with it and the analysis decodes with it, so the two cannot disagree.

STAMP_KEY = 'stamp_ns'


class PayloadError(InputError):
    """A String payload that is not the JSON its topic carries; names the topic and the key."""

    def __init__(self, topic: str, what: str, key: str | None, problem: str,
                 text: str) -> None:
        """``key``: the offending key (None: the text as a whole); ``problem``: what is wrong."""
        super().__init__(f'{topic}: {key or "json"}',
                         f'{topic}: not a {what} ({problem}): {text[:60]!r}')
        self.topic, self.what, self.field, self.problem = topic, what, key, problem


def _is_number(item: Any) -> bool:
    return type(item) is int or type(item) is float  # json.loads gives no bool subclass here


# A key's kind: what it must hold in the JSON, how to test it, and how the value holds it.
_KINDS: dict[str, tuple[str, Callable[[Any], bool], Callable[[Any], Any]]] = {
    'int': ('an integer', lambda item: type(item) is int, int),
    'float': ('a number', _is_number, float),
    'str': ('a string', lambda item: type(item) is str, str),
    'floats': ('a list of numbers',
               lambda item: type(item) is list and all(_is_number(x) for x in item),
               lambda item: [float(x) for x in item]),
    'strs': ('a list of strings',
             lambda item: type(item) is list and all(type(x) is str for x in item), tuple),
    'bool': ('true or false', lambda item: type(item) is bool, bool),
}


class JsonPayload:
    """
    The JSON object a std_msgs/String topic carries for one value type: its keys, both ways.

    ``keys`` are (key, kind) pairs in the order they are written; each key is the name of the
    value's field. ``stamp_ns`` is a key when the payload carries its stamp; a payload that does
    not (``actuator/events``) takes the message's time from the caller. ``check`` returns the
    key and what is wrong with a decoded value beyond keys and kinds (None: nothing).

    The text is ``json.dumps`` of the keys in order, with json's default separators: the bytes
    the bags already hold, so a key, its order or its kind never changes here unnoticed. Decoding
    refuses non-JSON, a JSON value that is no object, a missing key and a key of the wrong kind
    with a :class:`PayloadError`; keys it does not know are left alone.
    """

    def __init__(self, value_type: type, what: str, keys: tuple[tuple[str, str], ...],
                 check: Callable[[Any], tuple[str, str] | None] | None = None,
                 optional: tuple[tuple[str, str], ...] = ()) -> None:
        """
        A codec for ``value_type`` (a values class with a String ``topic``).

        ``optional`` keys come after ``keys``, each written only when the value's field is not
        None and read back as None when absent: a payload that gains them keeps the bytes of
        every value that has none.
        """
        fields = {field.name for field in dataclasses.fields(value_type)}
        names = tuple(key for key, _ in keys)
        every = names + tuple(key for key, _ in optional)
        unknown = set(every) - fields - {STAMP_KEY}
        missing = fields - set(every) - {STAMP_KEY}
        if unknown or missing or STAMP_KEY not in fields or len(set(every)) != len(every) \
                or any(kind not in _KINDS for _, kind in keys + optional):
            raise TypeError(f'{value_type.__name__}: JSON keys {every} do not match its fields '
                            f'(not fields: {sorted(unknown)}, fields left out: {sorted(missing)})')
        self.value_type, self.what, self.keys, self.check = value_type, what, keys, check
        self.optional = optional
        self.names = names
        self.topic = value_type.topic

    @property
    def carries_stamp(self) -> bool:
        """True when the payload carries ``stamp_ns`` (else the message's time is the stamp)."""
        return STAMP_KEY in self.names

    def required(self, stamp_given: bool = False) -> tuple[str, ...]:
        """The keys a payload must hold (``stamp_given``: the caller knows the message time)."""
        return tuple(name for name in self.names if not (stamp_given and name == STAMP_KEY))

    def fields(self, value: Any) -> dict[str, Any]:
        """The JSON object of ``value``, keys in the written order."""
        out = {}
        for key, kind in self.keys:
            item = getattr(value, key)
            out[key] = list(item) if kind in ('floats', 'strs') else item
        for key, kind in self.optional:
            item = getattr(value, key)
            if item is not None:
                out[key] = list(item) if kind in ('floats', 'strs') else item
        return out

    def text(self, value: Any) -> str:
        """The JSON text the topic carries for ``value``."""
        return json.dumps(self.fields(value))

    def encode(self, value: Any) -> bytes:
        """The CDR bytes of the std_msgs/String holding ``value``."""
        return string_cdr(self.text(value))

    def decode(self, text: str, stamp_ns: int | None = None) -> Any:
        """
        The value a payload holds; :class:`PayloadError` (one line) when it holds none.

        ``stamp_ns``: the message's time, the value's stamp when the payload carries none
        (required for a codec whose payload never does; without it a missing ``stamp_ns`` key
        is refused).
        """
        if not self.carries_stamp and stamp_ns is None:
            raise TypeError(f'{self.topic.name} carries no stamp: decode needs stamp_ns')
        try:
            data = json.loads(text)
        except json.JSONDecodeError as err:
            raise self._error(None, f'not JSON: {err.msg}', text) from None
        except (ValueError, RecursionError) as err:
            raise self._error(None, f'not JSON: {err}', text) from None
        if type(data) is not dict:
            raise self._error(None, f'not a JSON object: {_short(data)}', text)
        values = {}
        for key, kind in self.keys + self.optional:
            if key not in data:
                if key == STAMP_KEY and stamp_ns is not None:
                    values[key] = stamp_ns
                    continue
                if (key, kind) in self.optional:
                    continue
                raise self._error(key, f'no key {key}; expected {", ".join(self.names)}',
                                  text)
            item = data[key]
            noun, accepts, convert = _KINDS[kind]
            if not accepts(item):
                raise self._error(key, f'{key} must be {noun}, got {_short(item)}', text)
            try:
                values[key] = convert(item)
            except OverflowError:
                raise self._error(key, f'{key} is out of range', text) from None
        if not self.carries_stamp:
            values[STAMP_KEY] = stamp_ns
        value = self.value_type(**values)
        fault = self.check(value) if self.check else None
        if fault is not None:
            raise self._error(*fault, text)
        return value

    def _error(self, key: str | None, problem: str, text: str) -> PayloadError:
        return PayloadError(self.topic.name, self.what, key, problem, text)


def _short(item: Any) -> str:
    text = json.dumps(item)
    return text if len(text) <= 40 else text[:37] + '...'


_HEX = frozenset('0123456789abcdefABCDEF')
SHA256_HEX_DIGITS = 64
INFLATION, DEFLATION = 'inflation', 'deflation'


def _scene_fault(value: SceneIdentity) -> tuple[str, str] | None:
    digest = value.segments_sha256
    if len(digest) != SHA256_HEX_DIGITS or not set(digest) <= _HEX:
        return 'segments_sha256', (f'segments_sha256 must be {SHA256_HEX_DIGITS} hexadecimal '
                                   'digits')
    return None


def _step_fault(value: SnapshotStep) -> tuple[str, str] | None:
    if value.direction not in (INFLATION, DEFLATION):
        return 'direction', (f'direction must be {INFLATION} or {DEFLATION}, '
                             f'got {value.direction!r}')
    return None


PUMP_STATUS_JSON = JsonPayload(
    PumpStatus, 'pump status', (('state', 'str'), ('reason', 'str'), (STAMP_KEY, 'int')))
# A snap-through event carries no stamp (bags hold it so): read back, the message's time is
# its stamp.
SNAP_THROUGH_JSON = JsonPayload(
    SnapThrough, 'snap-through event',
    (('injected_m3', 'float'), ('from_volumes_m3', 'floats'), ('to_volumes_m3', 'floats'),
     ('from_pressure_pa', 'float'), ('to_pressure_pa', 'float')),
    # A snap-through in time: a quasi-static one has none of these (and its bytes stay).
    optional=(('start_ns', 'int'), ('duration_s', 'float'), ('fluid_moved_m3', 'float'),
              ('peak_exchange_m3_per_s', 'float'), ('giving_segments', 'strs'),
              ('taking_segments', 'strs'), ('snap_through', 'bool'), ('peak_ns', 'int'),
              ('cut_short', 'bool')))
SCENE_IDENTITY_JSON = JsonPayload(
    SceneIdentity, 'scene identity',
    (('scene', 'str'), ('segments', 'strs'), ('segments_sha256', 'str'), (STAMP_KEY, 'int')),
    _scene_fault)
SNAPSHOT_STEP_JSON = JsonPayload(
    SnapshotStep, 'snapshot step',
    (('step', 'int'), ('trigger_injected_m3', 'float'), ('direction', 'str'),
     ('injected_m3', 'float'), (STAMP_KEY, 'int')),
    _step_fault)

# The codec of every value a std_msgs/String topic carries, by value type and by topic name.
JSON_PAYLOADS: dict[type, JsonPayload] = {
    codec.value_type: codec
    for codec in (PUMP_STATUS_JSON, SNAP_THROUGH_JSON, SCENE_IDENTITY_JSON, SNAPSHOT_STEP_JSON)}
JSON_PAYLOADS_BY_TOPIC: dict[str, JsonPayload] = {
    codec.topic.name: codec for codec in JSON_PAYLOADS.values()}


# ---------------------------------------------------------------- values -> CDR bytes

_COMMAND_PACK, _COMMAND_BLOCK = joint_state_packer('', _SYRINGE, (1, 1, 0))


_REGULATOR_PACK, _REGULATOR_BLOCK = joint_state_packer('', (REGULATOR_JOINT,), (0, 0, 1))


def _pump_command(value: PumpCommand) -> bytes:
    sec, nanosec = divmod(value.stamp_ns, NS_PER_S)
    if value.gauge_pa is not None:
        return ENCAPSULATION + _REGULATOR_PACK(sec, nanosec, _REGULATOR_BLOCK, 0, 0, 1,
                                               value.gauge_pa)
    return ENCAPSULATION + _COMMAND_PACK(sec, nanosec, _COMMAND_BLOCK, 1, value.injected_m3, 1,
                                         value.flow_m3_per_s, 0)


# A setpoint gives one field: position, velocity or effort, each one value.
_SETPOINT_SHAPES = {'volume': (1, 0, 0), 'flow': (0, 1, 0), 'pressure': (0, 0, 1)}
_SETPOINT_PACKS = {kind: joint_state_packer('', _SYRINGE, shape)
                   for kind, shape in _SETPOINT_SHAPES.items()}


def _pump_setpoint(value: PumpSetpoint) -> bytes:
    sec, nanosec = divmod(value.stamp_ns, NS_PER_S)
    kind = value.kind
    pack, block = _SETPOINT_PACKS[kind]
    fields: list[float] = []
    for count in _SETPOINT_SHAPES[kind]:
        fields += [count, value.value] if count else [0]
    return ENCAPSULATION + pack(sec, nanosec, block, *fields)


# Per joint names: a segment state's (pack, block) for volumes (effort = pressure) and
# for curvatures (positions only); a rig sends one set of names for hours.
_volume_packers: dict[tuple[str, ...], tuple[Callable[..., bytes], bytes]] = {}
_curvature_packers: dict[tuple[str, ...], tuple[Callable[..., bytes], bytes]] = {}
_channel_packers: dict[tuple[str, ...], tuple[Callable[..., bytes], bytes]] = {}


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



def _channel_flows(value: ChannelFlows) -> bytes:
    names, flows, drops = value.names, value.flows_m3_per_s, value.drops_pa
    packer = _channel_packers.get(names)
    if packer is None or not len(names) == len(flows) == len(drops):
        packer = _channel_packers[names] = joint_state_packer('', names,
                                                              (0, len(flows), len(drops)))
    pack, block = packer
    sec, nanosec = divmod(value.stamp_ns, NS_PER_S)
    return ENCAPSULATION + pack(sec, nanosec, block, 0, len(flows), *flows, len(drops), *drops)


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
    PumpSetpoint: _pump_setpoint,
    PumpStatus: PUMP_STATUS_JSON.encode,
    Pressure: _pressure,
    SegmentVolumes: _volumes,
    SegmentCurvatures: _curvatures,
    ChannelFlows: _channel_flows,
    SnapThrough: SNAP_THROUGH_JSON.encode,
    SceneIdentity: SCENE_IDENTITY_JSON.encode,
    Backbone: _pose_array,
    Snapshot: _pose_array,
    SnapshotStep: SNAPSHOT_STEP_JSON.encode,
    Markers: _markers,
    SideImage: _side_image,
}


def encode(value: TopicValue) -> bytes:
    """The CDR bytes of a core value, as its topic carries them."""
    return ENCODERS[type(value)](value)


# ---------------------------------------------------------------- many values -> CDR rows

class RowLayout:
    """
    The CDR of one topic's messages of a fixed layout, for many messages at once.

    A template message (encoded by :data:`ENCODERS`, so the same bytes) and where its stamps
    and float64 blocks lie: :attr:`dtype` is a structured type of the message's bytes
    (``raw``: all of them; ``s<i>``, ``n<i>``: header i's sec and nanosec; ``f<i>``: float64
    block i), so that :meth:`fill` writes thousands of messages with a few numpy assignments.
    """

    def __init__(self, template: bytes, stamps: tuple[int, ...],
                 blocks: tuple[tuple[int, int], ...]) -> None:
        """``stamps``: offsets of each header's stamp; ``blocks``: (offset, bytes) of each."""
        names, formats, offsets = ['raw'], [('u1', (len(template),))], [0]
        for i, offset in enumerate(stamps):
            names += [f's{i}', f'n{i}']
            formats += ['<i4', '<u4']
            offsets += [offset, offset + 4]
        for i, (offset, size) in enumerate(blocks):
            names.append(f'f{i}')
            formats.append(('<f8', (size // 8,)))
            offsets.append(offset)
        self.dtype = np.dtype({'names': names, 'formats': formats, 'offsets': offsets,
                               'itemsize': len(template)})
        self.size = len(template)
        self.template = np.frombuffer(template, dtype=np.uint8)
        self.stamps = len(stamps)
        self.blocks = len(blocks)

    def fill(self, view: np.ndarray, stamps_ns: np.ndarray, blocks: list[np.ndarray]) -> None:
        """
        Write messages into ``view`` (an array of :attr:`dtype`): one per stamp, with ``blocks``.

        Each block is (messages, floats of the block), float64, in the template's order.
        """
        view['raw'] = self.template
        sec, nanosec = np.divmod(np.asarray(stamps_ns, dtype=np.int64), NS_PER_S)
        for i in range(self.stamps):
            view[f's{i}'] = sec
            view[f'n{i}'] = nanosec
        for i, block in enumerate(blocks):
            view[f'f{i}'] = block.reshape(view.shape[0], -1)


def row_layout(value: TopicValue) -> RowLayout | None:
    """
    The :class:`RowLayout` of every message like ``value`` (same names, sizes and lengths).

    The float64 blocks of each type, in order: a pump command's injected volume and flow (a
    regulator's: its target gauge pressure); a
    pressure's absolute pressure (its variance stays 0); segment volumes' volumes and
    gauge pressure per joint; curvatures; a backbone's or snapshot's poses (n, 7); markers'
    points per line. None for a type without a fixed layout (JSON, images).
    """
    template = ENCODERS[type(value)](value)
    stamp = (4,)
    if type(value) is PumpCommand and value.gauge_pa is None:
        offsets = joint_state_blocks('', _SYRINGE, (1, 1, 0))
        return RowLayout(template, stamp, ((offsets[0], 8), (offsets[1], 8)))
    if type(value) is PumpCommand:
        offsets = joint_state_blocks('', (REGULATOR_JOINT,), (0, 0, 1))
        return RowLayout(template, stamp, ((offsets[2], 8),))
    if type(value) is Pressure:
        return RowLayout(template, stamp, ((fluid_pressure_block(''), 8),))
    if type(value) is SegmentVolumes:
        n = len(value.names)
        offsets = joint_state_blocks('', value.names, (len(value.volumes_m3), 0, n))
        return RowLayout(template, stamp, ((offsets[0], 8 * len(value.volumes_m3)),
                                           (offsets[2], 8 * n)))
    if type(value) is SegmentCurvatures:
        count = len(value.curvatures_per_m)
        offsets = joint_state_blocks('', value.names, (count, 0, 0))
        return RowLayout(template, stamp, ((offsets[0], 8 * count),))
    if type(value) in (Backbone, Snapshot):
        layout = pose_array_layout(len(value.poses))
    elif type(value) is Markers:
        layout = marker_array_layout(tuple(len(line) for line in value.lines))
    else:
        return None
    return RowLayout(layout.template, layout.stamp_offsets, layout.blocks)


# ---------------------------------------------------------------- ROS messages -> values

def _stamp_ns(header: Any) -> int:
    stamp = header.stamp
    return stamp.sec * NS_PER_S + stamp.nanosec


def _floats(values: Any) -> list[float]:
    return values.tolist() if hasattr(values, 'tolist') else [float(v) for v in values]


def pump_command(msg: Any) -> PumpCommand:
    """
    A received sensor_msgs/JointState as a pump command; InputError when it is not one.

    Joint ``syringe`` with one position (and a velocity, the flow), or joint ``regulator``
    with one effort (its target gauge pressure) and nothing else.
    """
    names, position = list(msg.name), msg.position
    if names == [REGULATOR_JOINT]:
        effort = msg.effort
        if len(effort) != 1 or len(position) or len(msg.velocity):
            raise InputError('shape', f'command refused: a {REGULATOR_JOINT} command gives one '
                                      f'effort (target gauge pressure) and nothing else, got '
                                      f'{len(position)} positions, {len(msg.velocity)} '
                                      f'velocities and {len(effort)} efforts')
        return regulator_command(_stamp_ns(msg.header), float(effort[0]))
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


SETPOINT_FIELDS = (('position', 'target injected volume [m^3]'),
                   ('velocity', 'flow [m^3/s]'), ('effort', 'target gauge pressure [Pa]'))


def pump_setpoint(msg: Any) -> PumpSetpoint:
    """
    A received sensor_msgs/JointState as a setpoint; InputError when it is not one.

    Joint ``syringe`` (or ``regulator``, the same), exactly one of position (target volume),
    velocity (flow) and effort (target gauge pressure) holding one value. Whether the value is
    in range is the pump's to say.
    """
    names = list(msg.name)
    if names not in ([SYRINGE_JOINT], [REGULATOR_JOINT]):
        raise InputError('setpoint name', f'setpoint refused: expected one joint named '
                                          f'{SYRINGE_JOINT} (or {REGULATOR_JOINT}), got names '
                                          f'{names}')
    given = [(field, getattr(msg, field)) for field, _ in SETPOINT_FIELDS]
    filled = [(field, values) for field, values in given if len(values)]
    if len(filled) != 1 or len(filled[0][1]) != 1:
        sizes = ', '.join(f'{field} {len(values)}' for field, values in given)
        raise InputError('setpoint shape', 'setpoint refused: give exactly one of position '
                                           '(target injected volume [m^3]), velocity (flow '
                                           '[m^3/s]) or effort (target gauge pressure [Pa]), '
                                           f'one value; got {sizes}')
    field, values = filled[0]
    number = float(values[0])
    stamp = _stamp_ns(msg.header)
    if field == 'position':
        return PumpSetpoint(stamp, injected_m3=number)
    if field == 'velocity':
        return PumpSetpoint(stamp, flow_m3_per_s=number)
    return PumpSetpoint(stamp, gauge_pa=number)


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


def channel_flows(msg: Any) -> ChannelFlows:
    """A received sensor_msgs/JointState of channel flows (velocity) and drops (effort)."""
    return ChannelFlows(_stamp_ns(msg.header), tuple(msg.name), _floats(msg.velocity),
                        _floats(msg.effort))


DECODERS: dict[str, Callable[[Any], TopicValue]] = {
    PumpCommand.topic.name: pump_command,
    PumpSetpoint.topic.name: pump_setpoint,
    Pressure.topic.name: pressure,
    SegmentVolumes.topic.name: segment_volumes,
    SegmentCurvatures.topic.name: segment_curvatures,
    ChannelFlows.topic.name: channel_flows,
}
