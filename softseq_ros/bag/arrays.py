"""
Read chosen topics of an MCAP bag straight into numpy arrays, one chunk at a time.

A rig bag holds hundreds of thousands of small messages of a few fixed layouts (a JointState
with the same joint names, a FluidPressure with the same frame id). Decoding each into a Python
object, as general readers must (rosbags, mcap-ros2-support), costs microseconds per message and
memory per object. Here the summary section's chunk indexes and each chunk's message indexes say
where a wanted channel's messages lie in the decompressed chunk; the messages of one byte length
are gathered into a (messages x bytes) matrix, the first one is parsed as CDR to find where the
stamp and the float64 arrays sit, the matrix is checked to agree with it everywhere else (joint
names, frame id, array lengths), and the columns are read as views. Messages of other types or of
varying layout (strings, snapshots) are few and are decoded one by one.

Only one decompressed chunk is held at a time and the output arrays are sized from the summary's
message counts, so memory grows with the columns asked for, not with the bag.
"""

from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
import os
from pathlib import Path
import struct
from typing import Any, BinaryIO, Iterable
import zlib

from mcap.exceptions import McapError
from mcap.reader import make_reader
import numpy as np
from numpy.typing import NDArray

from softseq_ros.bag.layout import MCAP_MAGIC, listed_files, mcap_files
from softseq_ros.errors import UserError

_OP_MESSAGE = 0x05
_OP_CHUNK = 0x06
_OP_MESSAGE_INDEX = 0x07
# Message record: opcode (1), record length (8), channel (2), sequence (4), log time (8),
# publish time (8), then the message data.
_MESSAGE_DATA_START = 1 + 8 + 2 + 4 + 8 + 8
_MESSAGE_FIELDS_AFTER_LENGTH = 2 + 4 + 8 + 8
_CDR_LITTLE_ENDIAN = (0x00, 0x01)
_U32 = struct.Struct('<I')
_U64 = struct.Struct('<Q')
_CHUNK_HEAD = struct.Struct('<BQQQQI')  # opcode, length, start, end, uncompressed size, crc

Bytes = NDArray[np.uint8]
Ints = NDArray[np.int64]


class BagArrayError(UserError):
    """A bag that cannot be read as asked; the message names the file and what is wrong."""


@dataclass(frozen=True)
class ChannelInfo:
    """One channel (topic) of a bag."""

    channel_id: int
    topic: str
    type_name: str            # pkg/msg/Type
    offered_qos_profiles: str  # rosbag2's YAML string (may be empty)
    message_count: int


def canonical_type(name: str) -> str:
    """``pkg/msg/Type`` also for the ROS 1 style ``pkg/Type``."""
    parts = name.split('/')
    return f'{parts[0]}/msg/{parts[1]}' if len(parts) == 2 else name


# ------------------------------------------------------------------------------------ decoders


class _Decoder:
    """Receives a channel's messages, chunk by chunk, in file order."""

    def __init__(self, topic: str) -> None:
        self.topic = topic
        self.count = 0

    def reserve(self, count: int) -> None:
        """The channel's message count from the summary (0 when unknown)."""

    def add(self, chunk: NDArray[np.uint8], starts: NDArray[np.int64],
            sizes: NDArray[np.int64], log_times: NDArray[np.int64], where: str) -> None:
        """Messages of one chunk: data ``chunk[start:start + size]``, in file order."""
        self.count += starts.size
        self._take(chunk, starts, sizes, log_times, where)

    def _take(self, chunk: Bytes, starts: Ints, sizes: Ints, log_times: Ints,
              where: str) -> None:
        raise NotImplementedError


def _gather_bytes(chunk: NDArray[np.uint8], starts: NDArray[np.int64],
                  offsets: NDArray[np.int64]) -> NDArray[np.uint8]:
    """The bytes at ``offsets`` from each start as a (len(starts), len(offsets)) matrix."""
    return np.take(chunk, starts.astype(np.int32)[:, None] + offsets.astype(np.int32))


def _words_at_every_byte(chunk: NDArray[np.uint8]) -> NDArray[np.uint64]:
    """
    The chunk as overlapping little-endian 8-byte words, one starting at each byte (a view).

    Messages start at any byte of a chunk; gathering eight bytes per index instead of one is
    an eighth of the index arrays, which is most of the cost of gathering.
    """
    return np.ndarray((max(chunk.size - 7, 0),), dtype='<u8', buffer=chunk, strides=(1,))


def _gather_words(chunk: NDArray[np.uint8], starts: NDArray[np.int64],
                  count: int) -> NDArray[np.uint64]:
    """``count`` consecutive 8-byte words from each start, as a (len(starts), count) matrix."""
    index = starts.astype(np.int32)[:, None] + np.arange(0, 8 * count, 8, dtype=np.int32)
    return _words_at_every_byte(chunk)[index]


class _Cursor:
    """A minimal CDR (XCDR1, little endian) walker over one message, for finding a layout."""

    def __init__(self, data: bytes, where: str) -> None:
        self.data = data
        self.where = where
        if len(data) < 4 or tuple(data[:2]) != _CDR_LITTLE_ENDIAN:
            raise BagArrayError(f'{where}: not little-endian CDR (encapsulation '
                                f'{bytes(data[:4]).hex() or "missing"})')
        self.pos = 4

    def align(self, size: int) -> None:
        self.pos += -(self.pos - 4) % size

    def need(self, size: int) -> None:
        """Fail clearly when the message ends before ``size`` more bytes."""
        if self.pos + size > len(self.data):
            raise BagArrayError(f'{self.where}: message ends inside a field (CDR of '
                                f'{len(self.data)} bytes, needed {self.pos + size})')

    def u32(self) -> int:
        self.align(4)
        self.need(4)
        value = _U32.unpack_from(self.data, self.pos)[0]
        self.pos += 4
        return value

    def string(self) -> str:
        length = self.u32()
        self.need(length)
        raw = bytes(self.data[self.pos:self.pos + length])
        self.pos += length
        return raw.rstrip(b'\x00').decode('utf-8', errors='replace')

    def doubles_at(self) -> tuple[int, int]:
        """Offset and count of a float64 sequence; moves past it."""
        count = self.u32()
        if count:
            self.align(8)
        start = self.pos
        self.need(8 * count)
        self.pos += 8 * count
        return start, count

    def float64(self) -> float:
        self.align(8)
        self.need(8)
        value = struct.unpack_from('<d', self.data, self.pos)[0]
        self.pos += 8
        return value


def _header(cursor: _Cursor) -> tuple[int, str]:
    """Stamp [ns] and frame id of a std_msgs/Header."""
    cursor.align(4)
    cursor.need(8)
    sec, nanosec = struct.unpack_from('<iI', cursor.data, cursor.pos)
    cursor.pos += 8
    return sec * 1_000_000_000 + nanosec, cursor.string()


class _Columns:
    """Growable per-channel output arrays, sized from the summary when it is known."""

    def __init__(self) -> None:
        self.arrays: dict[str, np.ndarray] = {}
        self.used = 0
        self.capacity = 0

    def ensure(self, names_shapes: dict[str, tuple[tuple[int, ...], Any]], extra: int,
               reserve: int) -> None:
        if not self.arrays:
            self.capacity = max(reserve, extra)
            self.arrays = {name: np.empty((self.capacity, *shape), dtype=dtype)
                           for name, (shape, dtype) in names_shapes.items()}
        elif self.used + extra > self.capacity:
            self.capacity = max(2 * self.capacity, self.used + extra)
            for name, array in self.arrays.items():
                grown = np.empty((self.capacity, *array.shape[1:]), dtype=array.dtype)
                grown[:self.used] = array[:self.used]
                self.arrays[name] = grown

    def result(self) -> dict[str, np.ndarray]:
        return {name: array[:self.used] for name, array in self.arrays.items()}


class FixedLayoutDecoder(_Decoder):
    """
    A header-stamped message whose layout only the values change: stamps and float64 columns.

    Subclasses find the layout in one message (``_layout``): the float64 fields to read as
    (name, offset, count) and the text they must share with every other message.
    """

    def __init__(self, topic: str, limit: int | None = None, log_times: bool = True,
                 mean: Iterable[str] = (), required: Iterable[str] = ()) -> None:
        """
        Keep at most ``limit`` messages.

        ``log_times`` False drops the log time column, and a field named in ``mean`` is kept
        as its mean over the array (n, 1): less memory on long bags where only that is needed.
        A message whose field named in ``required`` is empty is left out and counted in
        :attr:`skipped` (a foreign publisher's JointState without positions, say).
        """
        super().__init__(topic)
        self.limit = limit
        self.log_times = log_times
        self.mean = frozenset(mean)
        self.required = frozenset(required)
        self.skipped: dict[str, int] = {}   # why -> messages left out
        self.signs: frozenset[str] = frozenset()
        self._columns = _Columns()
        self._reserve = 0
        self.text: Any = None      # what the first message's text fields said (names, frame)

    def reserve(self, count: int) -> None:
        """Size the columns for ``count`` messages (at most ``limit``)."""
        self._reserve = count if self.limit is None else min(count, self.limit)

    def _layout(self, cursor: _Cursor) -> tuple[Any, list[tuple[str, int, int]]]:
        raise NotImplementedError

    def _take(self, chunk: Bytes, starts: Ints, sizes: Ints, log_times: Ints,
              where: str) -> None:
        if self.limit is not None:
            room = self.limit - self._columns.used
            if room <= 0:
                return
            starts, sizes, log_times = starts[:room], sizes[:room], log_times[:room]
        for size in np.unique(sizes).tolist():
            rows = np.flatnonzero(sizes == size) if sizes.size else sizes
            self._add_group(chunk, starts[rows], int(size), log_times[rows], where)

    def _add_group(self, chunk: Bytes, starts: Ints, size: int, log_times: Ints,
                   where: str) -> None:
        first = chunk[int(starts[0]):int(starts[0]) + size].tobytes()
        cursor = _Cursor(first, where)
        text, fields = self._layout(cursor)
        empty = sorted(name for name, _, count in fields if name in self.required and not count)
        if empty:
            self._skip_empty(chunk, starts, size, log_times, where, empty, fields)
            return
        if self.text is None:
            self.text = text
        elif text != self.text:
            raise BagArrayError(f'{where}: {self.topic} changes its names or frame id from '
                                f'{self.text!r} to {text!r} within the recording')
        # XCDR1 aligns a float64 to 8 bytes counted from the end of the 4-byte encapsulation
        # header, so 8-byte words from byte 4 on hold the stamp (word 0) and each float64 whole.
        count_words = (size - 4) // 8
        data_words = np.zeros(count_words, dtype=bool)
        data_words[0] = True
        for _, offset, count in fields:
            data_words[(offset - 4) // 8:(offset - 4) // 8 + count] = True
        words = _gather_words(chunk, starts + 4, count_words)
        edges = _gather_bytes(chunk, starts, np.r_[0:4, 4 + 8 * count_words:size])
        # Every byte outside the stamp and the float64 fields must equal the first message's:
        # then each message has the first one's layout, names and lengths.
        text_words = ~data_words
        if not (np.array_equal(words[:, text_words],
                               np.broadcast_to(words[0, text_words],
                                               (words.shape[0], int(text_words.sum()))))
                and np.array_equal(edges, np.broadcast_to(edges[0], edges.shape))):
            # Same size, different layout (rare): decode those messages one by one.
            for row in range(words.shape[0]):
                self._add_group(chunk, starts[row:row + 1], size, log_times[row:row + 1],
                                where)
            return
        n = words.shape[0]
        shapes = {'stamp_ns': ((), np.int64)}
        if self.log_times:
            shapes['log_time_ns'] = ((), np.int64)
        reduced = self.mean | self.signs
        for name, _, count in fields:
            shapes[name] = ((min(count, 1) if name in reduced else count,),
                            np.int8 if name in self.signs else np.float64)
        columns = self._columns
        columns.ensure(shapes, n, self._reserve)
        for name, _, count in fields:
            width = min(count, 1) if name in reduced else count
            if columns.arrays[name].shape[1] != width:
                raise BagArrayError(f'{where}: {self.topic}.{name} changes length '
                                    f'(now {count} values)')
        at = slice(columns.used, columns.used + n)
        stamp = words[:, 0]
        seconds = (stamp & 0xFFFFFFFF).astype(np.uint32).view(np.int32).astype(np.int64)
        columns.arrays['stamp_ns'][at] = seconds * 1_000_000_000 + (stamp >> 32).astype(np.int64)
        if self.log_times:
            columns.arrays['log_time_ns'][at] = log_times
        for name, offset, count in fields:
            if not count:
                continue
            first_word = (offset - 4) // 8
            values = words[:, first_word:first_word + count].view('<f8')
            if name in self.signs:
                columns.arrays[name][at] = np.sign(values[:, :1])
            elif name in self.mean:
                columns.arrays[name][at] = values.mean(axis=1, keepdims=True)
            else:
                columns.arrays[name][at] = values
        columns.used += n

    def _skip_empty(self, chunk: Bytes, starts: Ints, size: int, log_times: Ints, where: str,
                    empty: list[str], fields: list[tuple[str, int, int]]) -> None:
        # Messages of one size may still differ in layout: only those whose own required
        # field is empty are left out.
        if starts.size > 1:
            for row in range(starts.size):
                self._add_group(chunk, starts[row:row + 1], size, log_times[row:row + 1],
                                where)
            return
        why = f'no {" or ".join(empty)}'
        self.skipped[why] = self.skipped.get(why, 0) + 1

    def result(self) -> dict[str, np.ndarray]:
        """Columns: log_time_ns, stamp_ns and the float64 fields, in file order."""
        return self._columns.result()

    def release(self) -> dict[str, np.ndarray]:
        """:meth:`result`, the decoder letting go of the columns (a caller may free them)."""
        columns = self._columns.result()
        self._columns = _Columns()
        return columns


class JointStateDecoder(FixedLayoutDecoder):
    """sensor_msgs/JointState: ``position``, ``velocity``, ``effort`` as (n, joints) arrays."""

    def __init__(self, topic: str, fields: Iterable[str] = ('position', 'velocity', 'effort'),
                 limit: int | None = None, log_times: bool = True,
                 mean: Iterable[str] = (), signs: Iterable[str] = (),
                 required: Iterable[str] = ()) -> None:
        """
        Read ``fields`` of every message (see :class:`FixedLayoutDecoder` for the rest).

        A field in ``signs`` keeps only the sign of its first value, as int8 (the direction
        of a flow, for one eighth of the memory).
        """
        super().__init__(topic, limit, log_times, mean, required)
        self.fields = tuple(fields)
        self.signs = frozenset(signs)

    def _layout(self, cursor: _Cursor) -> tuple[Any, list[tuple[str, int, int]]]:
        _, frame_id = _header(cursor)
        names = tuple(cursor.string() for _ in range(cursor.u32()))
        found = {}
        for name in ('position', 'velocity', 'effort'):
            found[name] = cursor.doubles_at()
        return (frame_id, names), [(name, *found[name]) for name in self.fields]

    @property
    def names(self) -> tuple[str, ...]:
        """The joint names (empty before the first message)."""
        return self.text[1] if self.text else ()


class FluidPressureDecoder(FixedLayoutDecoder):
    """sensor_msgs/FluidPressure: ``fluid_pressure`` and ``variance`` as (n, 1) arrays."""

    def _layout(self, cursor: _Cursor) -> tuple[Any, list[tuple[str, int, int]]]:
        _, frame_id = _header(cursor)
        cursor.align(8)
        offset = cursor.pos
        return frame_id, [('fluid_pressure', offset, 1), ('variance', offset + 8, 1)]


def string_text(data: bytes, where: str) -> str:
    """
    The text of one std_msgs/String in CDR, checked as every decoder here checks its fields.

    Raises BagArrayError naming ``where`` when the bytes are no such message.
    """
    return _Cursor(data, where).string()


class StringDecoder(_Decoder):
    """
    std_msgs/String, one by one: a list of (log_time_ns, text).

    A message larger than ``max_bytes`` (the rig's JSON payloads are a few hundred bytes) is
    left out and counted in :attr:`skipped`, not decoded: a foreign publisher's megabytes
    would otherwise be held and parsed as they are.
    """

    def __init__(self, topic: str, max_bytes: int | None = None) -> None:
        super().__init__(topic)
        self.max_bytes = max_bytes
        self.messages: list[tuple[int, str]] = []
        self.skipped: dict[str, int] = {}   # why -> messages left out

    def _take(self, chunk: Bytes, starts: Ints, sizes: Ints, log_times: Ints,
              where: str) -> None:
        for start, size, log_time in zip(starts.tolist(), sizes.tolist(), log_times.tolist()):
            if self.max_bytes is not None and size > self.max_bytes:
                why = f'larger than {self.max_bytes} bytes'
                self.skipped[why] = self.skipped.get(why, 0) + 1
                continue
            cursor = _Cursor(chunk[start:start + size].tobytes(), where)
            self.messages.append((log_time, cursor.string()))


class PoseArrayDecoder(_Decoder):
    """geometry_msgs/PoseArray, one by one: (log_time_ns, stamp_ns, positions (n, 3))."""

    def __init__(self, topic: str) -> None:
        super().__init__(topic)
        self.messages: list[tuple[int, int, NDArray[np.float64]]] = []

    def _take(self, chunk: Bytes, starts: Ints, sizes: Ints, log_times: Ints,
              where: str) -> None:
        for start, size, log_time in zip(starts.tolist(), sizes.tolist(), log_times.tolist()):
            data = chunk[start:start + size].tobytes()
            cursor = _Cursor(data, where)
            stamp, _ = _header(cursor)
            count = cursor.u32()
            if count:
                cursor.align(8)
            cursor.need(56 * count)
            poses = np.frombuffer(data, '<f8', 7 * count, cursor.pos).reshape(count, 7)
            self.messages.append((log_time, stamp, poses[:, :3].copy()))


class CountDecoder(_Decoder):
    """Counts a channel's messages without decoding them."""

    def _take(self, chunk: Bytes, starts: Ints, sizes: Ints, log_times: Ints,
              where: str) -> None:
        return  # add() has counted them


# ------------------------------------------------------------------------------------ the bag


@dataclass
class BagArrays:
    """A bag directory opened for array reads: its channels and files."""

    path: Path
    files: list[Path]
    channels: dict[str, ChannelInfo] = field(default_factory=dict)
    # Each file's summary section as mcap parsed it on opening, kept for reading.
    summaries: dict[Path, Any] = field(default_factory=dict, repr=False)

    @property
    def topics(self) -> list[str]:
        """Every topic name in the bag."""
        return sorted(self.channels)

    def read(self, decoders: Iterable[_Decoder], validate_crcs: bool = False) -> None:
        """
        Stream every chunk once, handing each decoder its topic's messages.

        ``validate_crcs`` also checks each chunk's CRC (about a tenth more time); a damaged
        chunk usually fails to decompress anyway.
        """
        wanted = {decoder.topic: decoder for decoder in decoders}
        for topic, decoder in wanted.items():
            if topic not in self.channels:
                raise BagArrayError(f'{self.path}: no topic {topic} in this bag')
            decoder.reserve(self.channels[topic].message_count)
        for file in self.files:
            with open(file, 'rb') as stream:
                _read_file(stream, file, self.summaries.get(file), wanted, validate_crcs)
        for decoder in wanted.values():
            expected = self.channels[decoder.topic].message_count
            if expected and decoder.count != expected:
                raise BagArrayError(f'{self.path}: {decoder.topic}: the summary counts '
                                    f'{expected} messages, the chunks hold {decoder.count}')


def open_bag(directory: str | os.PathLike) -> BagArrays:
    """Open a bag directory (or one .mcap file): channels and counts from the summary."""
    path = Path(directory)
    if path.is_file():
        files, root = [path], path
    elif path.is_dir():
        files = listed_files(path, BagArrayError) or list(mcap_files(path, BagArrayError)[1])
        root = path
    else:
        raise BagArrayError(f'{path}: no such bag directory or file')
    bag = BagArrays(root, files)
    for file in files:
        with open(file, 'rb') as stream:
            bag.summaries[file] = _summary(stream, file)
        for info in _channels_of(file, bag.summaries[file]):
            known = bag.channels.get(info.topic)
            if known is not None and known.type_name != info.type_name:
                raise BagArrayError(f'{file}: topic {info.topic} is {info.type_name} here and '
                                    f'{known.type_name} in an earlier file')
            count = info.message_count + (known.message_count if known else 0)
            bag.channels[info.topic] = ChannelInfo(info.channel_id, info.topic, info.type_name,
                                                   info.offered_qos_profiles, count)
    return bag


def _summary(stream: BinaryIO, file: Path) -> Any:
    head = stream.read(len(MCAP_MAGIC))
    if head != MCAP_MAGIC:
        raise BagArrayError(f'{file}: not an MCAP file (it starts with {head[:8]!r})')
    stream.seek(0)
    try:
        summary = make_reader(stream).get_summary()
    except (McapError, struct.error, EOFError, ValueError) as err:
        raise BagArrayError(f'{file}: no readable summary section ({err}); if the recording '
                            'was cut short, run: softseq recover BAG') from None
    if summary is None:
        raise BagArrayError(f'{file}: no summary section (the recording did not finish); '
                            'run: softseq recover BAG')
    return summary


def _channels_of(file: Path, summary: Any) -> list[ChannelInfo]:
    counts = summary.statistics.channel_message_counts if summary.statistics else {}
    result = []
    for channel in summary.channels.values():
        schema = summary.schemas.get(channel.schema_id)
        if channel.message_encoding != 'cdr':
            raise BagArrayError(f'{file}: topic {channel.topic} is encoded as '
                                f'{channel.message_encoding!r}, not cdr: not a ROS 2 bag')
        result.append(ChannelInfo(channel.id, channel.topic,
                                  canonical_type(schema.name) if schema else '',
                                  channel.metadata.get('offered_qos_profiles', ''),
                                  int(counts.get(channel.id, 0))))
    return result


def _read_file(stream: BinaryIO, file: Path, summary: Any, wanted: dict[str, _Decoder],
               validate_crcs: bool) -> None:
    if summary is None:
        summary = _summary(stream, file)
    by_channel = {channel.id: wanted[channel.topic] for channel in summary.channels.values()
                  if channel.topic in wanted}
    if not by_channel:
        return
    if not summary.chunk_indexes:
        _read_unchunked(stream, file, summary, by_channel)
        return
    # The next chunk decompresses on a worker thread (zstd and lz4 release the GIL) while this
    # one is decoded: on two cores the reader then waits for neither.
    batch = _Batch(by_channel)
    with ThreadPoolExecutor(1, thread_name_prefix='mcap-read') as worker:
        pending = None
        for index in sorted(summary.chunk_indexes, key=lambda c: (c.message_start_time,
                                                                    c.chunk_start_offset)):
            present = [cid for cid in by_channel if cid in index.message_index_offsets]
            if index.message_index_offsets and not present:
                continue
            where = f'{file} (chunk at byte {index.chunk_start_offset})'
            stream.seek(index.chunk_start_offset)
            record = stream.read(index.chunk_length)
            indexes = stream.read(index.message_index_length)
            job = (worker.submit(_chunk_bytes, record, index.compression, where, validate_crcs),
                   index, indexes, present, where)
            if pending is not None:
                batch.add(*_chunk_messages(*pending, by_channel))
            pending = job
        if pending is not None:
            batch.add(*_chunk_messages(*pending, by_channel))
        batch.flush()


class _Batch:
    """
    Consecutive chunks decoded as one: a few large numpy operations instead of many small ones.

    A chunk holds a few hundred messages of each channel, so decoding chunk by chunk is mostly
    the fixed cost of each numpy call; a batch of about BATCH_BYTES of decompressed chunks
    keeps that cost small and the memory bounded.
    """

    BATCH_BYTES = 8 << 20

    def __init__(self, by_channel: dict[int, '_Decoder']) -> None:
        self.by_channel = by_channel
        self.chunks: list[NDArray[np.uint8]] = []
        self.messages: list[dict[int, tuple[np.ndarray, np.ndarray]]] = []
        self.wheres: list[str] = []
        self.size = 0

    def add(self, chunk: NDArray[np.uint8], messages: dict[int, tuple[np.ndarray, np.ndarray]],
            where: str) -> None:
        self.chunks.append(chunk)
        self.messages.append(messages)
        self.wheres.append(where)
        self.size += chunk.size
        if self.size >= self.BATCH_BYTES:
            self.flush()

    def flush(self) -> None:
        if not self.chunks:
            return
        if len(self.chunks) == 1:
            data, bases = self.chunks[0], [0]
            where = self.wheres[0]
        else:
            data = np.concatenate(self.chunks)
            bases = np.cumsum([0] + [c.size for c in self.chunks[:-1]]).tolist()
            where = f'{self.wheres[0]} or one of the {len(self.chunks) - 1} chunks after it'
        for channel_id, decoder in self.by_channel.items():
            parts = [(messages[channel_id], base, base + chunk.size) for messages, base, chunk
                     in zip(self.messages, bases, self.chunks) if channel_id in messages]
            if not parts:
                continue
            offsets = np.concatenate([o + base for (o, _), base, _ in parts])
            log_times = np.concatenate([t for (_, t), _, _ in parts])
            ends = np.concatenate([np.full(o.size, end) for (o, _), _, end in parts])
            _deliver(data, offsets, log_times, decoder, where, ends)
        self.chunks, self.messages, self.wheres, self.size = [], [], [], 0


def _chunk_messages(chunk_future: Future, index: Any, indexes: bytes, present: list[int],
                    where: str, by_channel: dict[int, '_Decoder']
                    ) -> tuple[NDArray[np.uint8], dict[int, tuple[np.ndarray, np.ndarray]], str]:
    """A chunk's bytes and, for each wanted channel in it, its messages' offsets and log times."""
    chunk = chunk_future.result()
    if index.message_index_offsets:
        base = index.chunk_start_offset + index.chunk_length
        messages = {channel_id: _message_index(
            indexes, index.message_index_offsets[channel_id] - base, where)
            for channel_id in present}
    else:
        messages = {channel_id: found for channel_id, found in _scan_chunk(chunk, where).items()
                    if channel_id in by_channel}
    for offsets, _ in messages.values():
        if offsets.size and (offsets.min() < 0 or offsets.max() >= chunk.size):
            raise BagArrayError(f'{where}: a message index points at no message record')
    return chunk, messages, where


def _chunk_bytes(record: bytes, compression: str, where: str,
                 validate_crcs: bool = False) -> NDArray[np.uint8]:
    if len(record) < _CHUNK_HEAD.size or record[0] != _OP_CHUNK:
        raise BagArrayError(f'{where}: the chunk index points at no chunk record')
    _, _, _, _, size, crc = _CHUNK_HEAD.unpack_from(record, 0)
    pos = _CHUNK_HEAD.size
    name_length = _U32.unpack_from(record, pos)[0]
    pos += 4 + name_length
    data_length = _U64.unpack_from(record, pos)[0]
    pos += 8
    payload = record[pos:pos + data_length]
    try:
        if compression == 'zstd':
            import zstandard
            data = zstandard.ZstdDecompressor().decompress(payload, max_output_size=size)
        elif compression == 'lz4':
            import lz4.frame
            data = lz4.frame.decompress(payload)
        elif compression == '':
            data = bytes(payload)
        else:
            raise BagArrayError(f'{where}: unknown chunk compression {compression!r}')
    except BagArrayError:
        raise
    except Exception as err:  # noqa: BLE001 - any decompressor failure means a damaged chunk
        raise BagArrayError(f'{where}: the chunk does not decompress ({err})') from None
    if len(data) != size or (validate_crcs and crc and zlib.crc32(data) != crc):
        raise BagArrayError(f'{where}: the chunk is damaged (size or CRC does not match)')
    return np.frombuffer(data, dtype=np.uint8)


def _message_index(indexes: bytes, pos: int, where: str) -> tuple[np.ndarray, np.ndarray]:
    if pos < 0 or pos + 15 > len(indexes) or indexes[pos] != _OP_MESSAGE_INDEX:
        raise BagArrayError(f'{where}: a message index offset points at no message index')
    length = _U32.unpack_from(indexes, pos + 11)[0]
    entries = np.frombuffer(indexes, '<u8', length // 8, pos + 15).reshape(-1, 2)
    return entries[:, 1].astype(np.int64), entries[:, 0].astype(np.int64)


def _scan_chunk(chunk: NDArray[np.uint8], where: str) -> dict[int, tuple[list, list]]:
    """Offsets and log times of every message record in a chunk without message indexes."""
    data = chunk.tobytes()
    found: dict[int, tuple[list, list]] = {}
    pos = 0
    while pos + 9 <= len(data):
        opcode = data[pos]
        length = _U64.unpack_from(data, pos + 1)[0]
        if opcode == _OP_MESSAGE:
            channel_id = int.from_bytes(data[pos + 9:pos + 11], 'little')
            log_time = _U64.unpack_from(data, pos + 15)[0]
            offsets, times = found.setdefault(channel_id, ([], []))
            offsets.append(pos)
            times.append(log_time)
        pos += 9 + length
    if pos != len(data):
        raise BagArrayError(f'{where}: the chunk ends inside a record')
    return {cid: (np.array(o, dtype=np.int64), np.array(t, dtype=np.int64))
            for cid, (o, t) in found.items()}


def _deliver(chunk: NDArray[np.uint8], offsets: np.ndarray, log_times: np.ndarray,
             decoder: _Decoder, where: str, ends: np.ndarray | int | None = None) -> None:
    """Hand a decoder its messages at ``offsets``; ``ends``: where each one's chunk ends."""
    if not offsets.size:
        return
    ends = chunk.size if ends is None else ends
    order = np.argsort(offsets, kind='stable')
    offsets, log_times = offsets[order], log_times[order]
    if not np.isscalar(ends):
        ends = ends[order]
    if np.any(offsets + _MESSAGE_DATA_START > ends) or np.any(chunk[offsets] != _OP_MESSAGE):
        raise BagArrayError(f'{where}: a message index points at no message record')
    lengths = _words_at_every_byte(chunk)[offsets + 1].astype(np.int64)
    sizes = lengths - _MESSAGE_FIELDS_AFTER_LENGTH
    starts = offsets + _MESSAGE_DATA_START
    if np.any(sizes < 0) or np.any(starts + sizes > ends):
        raise BagArrayError(f'{where}: a message record runs past its chunk')
    decoder.add(chunk, starts, sizes, log_times, f'{where}: {decoder.topic}')


def _read_unchunked(stream: BinaryIO, file: Path, summary: Any,
                    by_channel: dict[int, _Decoder]) -> None:
    """A bag without chunks (rare): mcap's reader, message by message."""
    stream.seek(0)
    topics = {cid: summary.channels[cid].topic for cid in by_channel}
    try:
        for _, channel, message in make_reader(stream).iter_messages(
                topics=list(topics.values())):
            data = np.frombuffer(message.data, dtype=np.uint8)
            by_channel[channel.id].add(data, np.array([0]), np.array([data.size]),
                                       np.array([message.log_time]), f'{file}: {channel.topic}')
    except McapError as err:
        raise BagArrayError(f'{file}: {err}') from None

