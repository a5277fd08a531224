"""
Fast CDR encoding of the rig's message types, byte for byte what DDS carries.

rclpy's ``serialize_message`` first converts the whole Python message into its C struct, which
costs about 300 us for a 41-pose PoseArray, and Fast DDS then pads some buffers with bytes that
belong to no field (which strict readers refuse, so they must be cut by decoding the message
again). A batch run serialises hundreds of thousands of messages, so the rig's own types are
encoded here directly (little-endian CDR, XCDR1 plain encapsulation); the tests check every
encoder against rclpy's serialisation. Other types fall back to the general path.
"""

from array import array
from operator import attrgetter
import re
import struct
import sys
from typing import Any, Callable

_ENCAPSULATION = b'\x00\x01\x00\x00'
_U32 = struct.Struct('<I')
_I32 = struct.Struct('<i')
_STAMP = struct.Struct('<iI')
_F64 = struct.Struct('<d')
_F64X2 = struct.Struct('<dd')
_F64X3 = struct.Struct('<ddd')
_F64X7 = struct.Struct('<7d')
_F32X4 = struct.Struct('<4f')
_POSE_FIELDS = attrgetter('position.x', 'position.y', 'position.z', 'orientation.x',
                          'orientation.y', 'orientation.z', 'orientation.w')
_POINT_FIELDS = attrgetter('x', 'y', 'z')
# rclpy keeps float64[] fields as array('d') in native order: on a little-endian machine its
# bytes are already CDR's.
_NATIVE_LITTLE = sys.byteorder == 'little'


class _Buffer:
    """
    A growing CDR buffer; offsets for alignment count from after the encapsulation.

    With ``marks`` (a :class:`_Marks`), it notes where each message header's stamp and each
    pose or point block lands (for :class:`FixedLayout`).
    """

    __slots__ = ('data', 'marks')

    def __init__(self, marks: '_Marks | None' = None) -> None:
        self.data = bytearray(_ENCAPSULATION)
        self.marks = marks

    def align(self, size: int) -> None:
        pad = -(len(self.data) - 4) % size
        if pad:
            self.data += b'\x00' * pad

    def u32(self, value: int) -> None:
        self.align(4)
        self.data += _U32.pack(value)

    def i32(self, value: int) -> None:
        self.align(4)
        self.data += _I32.pack(value)

    def u8(self, value: int) -> None:
        self.data.append(value & 0xFF)

    def string(self, text: str) -> None:
        encoded = text.encode()
        self.u32(len(encoded) + 1)
        self.data += encoded
        self.data.append(0)

    def strings(self, texts: Any) -> None:
        self.u32(len(texts))
        for text in texts:
            self.string(text)

    def doubles(self, values: Any) -> None:
        count = len(values)
        self.u32(count)
        if count:
            self.align(8)
            if _NATIVE_LITTLE and isinstance(values, array) and values.typecode == 'd':
                self.data += values.tobytes()
            else:
                self.data += struct.pack(f'<{count}d', *values)

    def octets(self, values: Any) -> None:
        self.u32(len(values))
        self.data += bytes(values)

    def header(self, header: Any, marked: bool = True) -> None:
        stamp = header.stamp
        self.align(4)
        if marked and self.marks is not None:
            self.marks.stamps.append(len(self.data))
        self.data += _STAMP.pack(stamp.sec, stamp.nanosec)
        self.string(header.frame_id)

    def point(self, point: Any) -> None:
        self.align(8)
        self.data += _F64X3.pack(point.x, point.y, point.z)

    def pose(self, pose: Any) -> None:
        self.align(8)
        self.data += _F64X7.pack(*_POSE_FIELDS(pose))

    def poses(self, poses: Any) -> None:
        self.u32(len(poses))
        if poses:
            # Every pose is 56 bytes of float64: aligned once, aligned for all.
            self.align(8)
            self._mark_block(len(poses) * 56)
            pack = _F64X7.pack
            self.data += b''.join([pack(*_POSE_FIELDS(p)) for p in poses])

    def points(self, points: Any) -> None:
        self.u32(len(points))
        if points:
            self.align(8)
            self._mark_block(len(points) * 24)
            pack = _F64X3.pack
            self.data += b''.join([pack(*_POINT_FIELDS(p)) for p in points])

    def _mark_block(self, size: int) -> None:
        if self.marks is not None:
            self.marks.blocks.append((len(self.data), size))

    def color(self, color: Any) -> None:
        self.align(4)
        self.data += _F32X4.pack(color.r, color.g, color.b, color.a)


def _joint_state(msg: Any, out: _Buffer) -> None:
    out.header(msg.header)
    out.strings(msg.name)
    out.doubles(msg.position)
    out.doubles(msg.velocity)
    out.doubles(msg.effort)


def _fluid_pressure(msg: Any, out: _Buffer) -> None:
    out.header(msg.header)
    out.align(8)
    out.data += _F64X2.pack(msg.fluid_pressure, msg.variance)


# The rig sends messages of the same frame ids, joint names and array lengths hundreds of
# thousands of times: for each such shape, everything after the encapsulation is one
# struct.Struct (with the names' bytes as one field and zero padding as pad bytes), so a
# message costs one pack call.
_LAYOUT_CACHE_SIZE = 256
_joint_state_layouts: dict[tuple[Any, ...], tuple[struct.Struct, bytes]] = {}
_fluid_pressure_layouts: dict[str, tuple[struct.Struct, bytes]] = {}


def _remember(cache: dict, key: Any, value: Any) -> Any:
    if len(cache) >= _LAYOUT_CACHE_SIZE:
        cache.clear()
    cache[key] = value
    return value


def _texts_block(frame_id: str, names: Any) -> bytes:
    """Frame id and (when ``names`` is not None) a string sequence, as after a stamp."""
    out = _Buffer()
    out.data += bytes(8)
    out.string(frame_id)
    if names is not None:
        out.strings(names)
    return bytes(out.data[4 + 8:])


def _joint_state_layout(key: tuple[Any, ...]) -> tuple[struct.Struct, bytes]:
    frame_id, counts, names = key[0], key[1:4], key[4:]
    block = _texts_block(frame_id, names)
    offset = 8 + len(block)
    fmt = f'<iI{len(block)}s'
    for count in counts:
        pad = -offset & 3
        fmt += 'x' * pad + 'I'
        offset += pad + 4
        if count:
            pad = -offset & 7
            fmt += 'x' * pad + f'{count}d'
            offset += pad + 8 * count
    return _remember(_joint_state_layouts, key, (struct.Struct(fmt), block))


def joint_state_cdr(sec: int, nanosec: int, frame_id: str, names: Any, position: Any,
                    velocity: Any, effort: Any) -> bytes:
    """CDR bytes of a sensor_msgs/JointState from its fields (sequences of floats)."""
    key = (frame_id, len(position), len(velocity), len(effort), *names)
    layout, block = _joint_state_layouts.get(key) or _joint_state_layout(key)
    return _ENCAPSULATION + layout.pack(sec, nanosec, block, key[1], *position, key[2],
                                        *velocity, key[3], *effort)


def joint_state_packer(frame_id: str, names: Any,
                       counts: tuple[int, int, int]) -> tuple[Callable[..., bytes], bytes]:
    """
    ``(pack, block)`` for JointStates of one frame, joint names and array lengths.

    ``_ENCAPSULATION``-less bytes are ``pack(sec, nanosec, block, n_position, *position,
    n_velocity, *velocity, n_effort, *effort)``: a sender whose shape never changes looks its
    layout up once instead of at every message.
    """
    key = (frame_id, *counts, *names)
    layout, block = _joint_state_layouts.get(key) or _joint_state_layout(key)
    return layout.pack, block


ENCAPSULATION = _ENCAPSULATION


def _format_offsets(fmt: str) -> list[int]:
    """Where each item of a little-endian struct format (no alignment) starts."""
    offsets, at = [], 0
    for count, code in re.findall(r'(\d*)([a-zA-Z])', fmt):
        size = struct.calcsize('<' + code)
        if code == 'x':
            at += int(count or 1)
            continue
        offsets.append(at)
        at += size * int(count or 1) if code != 's' else int(count or 1)
    return offsets


def joint_state_blocks(frame_id: str, names: Any,
                       counts: tuple[int, int, int]) -> list[int | None]:
    """
    Where a JointState's position, velocity and effort float64 blocks start in its bytes.

    Offsets count from the message's first byte (the encapsulation); None for an empty array.
    The stamp is at 4 (sec, int32) and 8 (nanosec, uint32).
    """
    key = (frame_id, *counts, *names)
    layout, _ = _joint_state_layouts.get(key) or _joint_state_layout(key)
    # Items: sec, nanosec, texts, then per array its count and (when not empty) its floats.
    items = iter(_format_offsets(layout.format)[3:])
    found = []
    for count in counts:
        next(items)
        found.append(4 + next(items) if count else None)
    return found


def fluid_pressure_block(frame_id: str) -> int:
    """Where a FluidPressure's fluid_pressure (then variance) starts in its bytes."""
    layout, _ = _fluid_pressure_layouts.get(frame_id) or _fluid_pressure_layout(frame_id)
    return 4 + _format_offsets(layout.format)[3]


def _joint_state_bytes(msg: Any) -> bytes:
    header = msg.header
    stamp = header.stamp
    return joint_state_cdr(stamp.sec, stamp.nanosec, header.frame_id, msg.name, msg.position,
                           msg.velocity, msg.effort)


def _fluid_pressure_layout(frame_id: str) -> tuple[struct.Struct, bytes]:
    block = _texts_block(frame_id, None)
    pad = -(8 + len(block)) & 7
    return _remember(_fluid_pressure_layouts, frame_id,
                     (struct.Struct(f'<iI{len(block)}s{pad}xdd'), block))


def fluid_pressure_cdr(sec: int, nanosec: int, frame_id: str, fluid_pressure: float,
                       variance: float) -> bytes:
    """CDR bytes of a sensor_msgs/FluidPressure from its fields."""
    layout, block = (_fluid_pressure_layouts.get(frame_id)
                     or _fluid_pressure_layout(frame_id))
    return _ENCAPSULATION + layout.pack(sec, nanosec, block, fluid_pressure, variance)


def _fluid_pressure_bytes(msg: Any) -> bytes:
    header = msg.header
    stamp = header.stamp
    return fluid_pressure_cdr(stamp.sec, stamp.nanosec, header.frame_id, msg.fluid_pressure,
                              msg.variance)


def string_cdr(text: str) -> bytes:
    """CDR bytes of a std_msgs/String holding ``text``."""
    encoded = text.encode()
    return _ENCAPSULATION + _U32.pack(len(encoded) + 1) + encoded + b'\x00'


def _pose_array(msg: Any, out: _Buffer) -> None:
    out.header(msg.header)
    out.poses(msg.poses)


def _string(msg: Any, out: _Buffer) -> None:
    out.string(msg.data)


def _image(msg: Any, out: _Buffer) -> None:
    out.header(msg.header)
    out.u32(msg.height)
    out.u32(msg.width)
    out.string(msg.encoding)
    out.u8(msg.is_bigendian)
    out.u32(msg.step)
    out.octets(msg.data)


def _marker(marker: Any, out: _Buffer) -> None:
    out.header(marker.header)
    out.string(marker.ns)
    out.i32(marker.id)
    out.i32(marker.type)
    out.i32(marker.action)
    out.pose(marker.pose)
    out.point(marker.scale)
    out.color(marker.color)
    out.align(4)
    out.data += _STAMP.pack(marker.lifetime.sec, marker.lifetime.nanosec)
    out.u8(marker.frame_locked)
    out.points(marker.points)
    out.u32(len(marker.colors))
    for color in marker.colors:
        out.color(color)
    out.string(marker.texture_resource)
    texture = marker.texture
    out.header(texture.header, marked=False)
    out.string(texture.format)
    out.octets(texture.data)
    out.u32(len(marker.uv_coordinates))
    for uv in marker.uv_coordinates:
        out.align(4)
        out.data += struct.pack('<ff', uv.u, uv.v)
    out.string(marker.text)
    out.string(marker.mesh_resource)
    out.string(marker.mesh_file.filename)
    out.octets(marker.mesh_file.data)
    out.u8(marker.mesh_use_embedded_materials)


def _marker_array(msg: Any, out: _Buffer) -> None:
    out.u32(len(msg.markers))
    for marker in msg.markers:
        _marker(marker, out)


ENCODERS: dict[str, Callable[[Any, _Buffer], None]] = {
    'sensor_msgs/msg/JointState': _joint_state,
    'sensor_msgs/msg/FluidPressure': _fluid_pressure,
    'sensor_msgs/msg/Image': _image,
    'geometry_msgs/msg/PoseArray': _pose_array,
    'std_msgs/msg/String': _string,
    'visualization_msgs/msg/MarkerArray': _marker_array,
}


# The hot types of a batch run, encoded without the general buffer's per-field calls.
_FAST_ENCODERS: dict[str, Callable[[Any], bytes]] = {
    'sensor_msgs/msg/JointState': _joint_state_bytes,
    'sensor_msgs/msg/FluidPressure': _fluid_pressure_bytes,
}


def encoder_for(type_name: str) -> Callable[[Any], bytes] | None:
    """A function from a message of ``type_name`` to its CDR bytes; None if not handled here."""
    fast = _FAST_ENCODERS.get(type_name)
    if fast is not None:
        return fast
    encoder = ENCODERS.get(type_name)
    if encoder is None:
        return None

    def encode_general(msg: Any) -> bytes:
        out = _Buffer()
        encoder(msg, out)
        return bytes(out.data)
    return encode_general


def encode(msg: Any, type_name: str) -> bytes | None:
    """CDR bytes of ``msg`` (a message of ``type_name``), or None for a type not handled here."""
    encoder = encoder_for(type_name)
    return None if encoder is None else encoder(msg)


class _Marks:
    __slots__ = ('stamps', 'blocks')

    def __init__(self) -> None:
        self.stamps: list[int] = []
        self.blocks: list[tuple[int, int]] = []


class FixedLayout:
    """
    CDR of a message whose layout stays fixed: only its stamps and float64 blocks change.

    Built from one example message (a PoseArray, or a MarkerArray whose markers keep their
    point counts), it encodes that message once, noting where every message header's stamp
    and every pose or point block lands. :meth:`encode` then copies those bytes and writes a
    new stamp into every header and new values into the blocks: a 41-pose PoseArray costs a
    few microseconds from a numpy array, instead of the hundreds that filling 41 rclpy Pose
    objects and serialising them take.
    """

    def __init__(self, msg: Any, type_name: str) -> None:
        """Encode ``msg`` (of ``type_name``, one of the types with an encoder) as the template."""
        marks = _Marks()
        out = _Buffer(marks)
        ENCODERS[type_name](msg, out)
        self._template = bytes(out.data)
        self._stamps = tuple(marks.stamps)
        self.block_sizes = tuple(size for _, size in marks.blocks)
        self._blocks = tuple(marks.blocks)

    @property
    def template(self) -> bytes:
        """The example message's bytes."""
        return self._template

    @property
    def stamp_offsets(self) -> tuple[int, ...]:
        """Where each message header's stamp (sec, nanosec) starts."""
        return self._stamps

    @property
    def blocks(self) -> tuple[tuple[int, int], ...]:
        """(offset, bytes) of every float64 block, in message order."""
        return self._blocks

    def encode(self, stamp_ns: int, blocks: Any) -> bytes:
        """
        The message with every header stamped ``stamp_ns`` and its float64 blocks replaced.

        ``blocks`` holds one C-contiguous float64 array per pose or point list, in message
        order: (n, 7) for poses as (x, y, z, qx, qy, qz, qw), (n, 3) for points.
        """
        data = bytearray(self._template)
        stamp = _STAMP.pack(*divmod(int(stamp_ns), 1_000_000_000))
        for offset in self._stamps:
            data[offset:offset + 8] = stamp
        if len(blocks) != len(self._blocks):
            raise ValueError(f'expected {len(self._blocks)} blocks, got {len(blocks)}')
        for (offset, size), block in zip(self._blocks, blocks):
            raw = block.astype('<f8', copy=False).tobytes()
            if len(raw) != size:
                raise ValueError(f'block of {len(raw)} bytes where the layout holds {size}')
            data[offset:offset + size] = raw
        return bytes(data)
