"""
A chunked MCAP writer whose per-message cost is a few list appends.

mcap's own ``Writer`` builds a ``Message`` dataclass per message and writes its fields one by one
through a ``BytesIO`` (about 15 us per message), which was a fifth of a batch run. Here a message
only joins the open chunk's lists; when the chunk closes, the message records' headers, the chunk's
bytes and the message indexes are built for all its messages at once with numpy. Every other record
(header, schemas, channels, chunks' framing, summary, footer) is written by mcap's own record
classes, so the layout stays the library's: schemas and channels inside the chunks, then a summary
with schemas, channels, statistics, chunk, attachment and metadata indexes, and summary offsets.

Messages go to one of two chunks open at a time, by the size of their channel's first message:
bulk channels (camera frames, marker arrays: a kilobyte or more) fill chunks of their own, so a
reader of the small state topics (pump, pressure, volumes, curvatures) decompresses only the
chunks that hold them, a quarter of a rig bag's bytes. MCAP allows chunks whose time ranges
overlap, and indexed readers (mcap's, rosbags', Foxglove's, rosbag2's) merge them by log time;
each channel's messages stay in one chunk sequence, in order, and schema and channel records
travel in whichever chunk is written first after they are registered, so they precede every
message of theirs in the file.

Compression runs on a worker thread (zstd and lz4 release the GIL), so on a machine with two cores
the next chunk is filled while the last one is compressed; records still reach the file in order.
"""

from concurrent.futures import Future, ThreadPoolExecutor
import struct
from typing import Any, BinaryIO
import zlib

from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)
import numpy as np

from softseq_ros.bag.layout import MCAP_MAGIC

# Message record: opcode, record length, channel id, sequence, log time, publish time.
_MESSAGE_FIXED = 2 + 4 + 8 + 8
_MESSAGE_INDEX_HEADER = struct.Struct('<BQHI')
_FOOTER_CRC_PREFIX = struct.Struct('<BQQQ')


def _compressor(compression: str) -> Any:
    if compression == 'zstd':
        import zstandard
        return zstandard.ZstdCompressor().compress
    if compression == 'lz4':
        import lz4.frame
        return lz4.frame.compress
    return None


# A message record's header: opcode, record length, channel id, sequence, log and publish time.
_MESSAGE_RECORD = np.dtype([('opcode', 'u1'), ('length', '<u8'), ('channel', '<u2'),
                            ('sequence', '<u4'), ('log_time', '<u8'),
                            ('publish_time', '<u8')])
_MESSAGE_HEADER_SIZE = _MESSAGE_RECORD.itemsize  # 31 bytes
# A channel whose first message has at least this many bytes fills the bulk chunks.
BULK_MESSAGE_BYTES = 1024


class _OpenChunk:
    """
    The chunk being filled: its schema and channel records, then its messages.

    Messages added one by one wait in the lists until the chunk closes or a block of records
    built elsewhere (:meth:`ChunkedMcapWriter.add_rows`) follows them; then they become a
    *piece*: the records' bytes with each record's channel, log time and size, in order.
    """

    __slots__ = ('prefix', 'channels', 'sequences', 'log_times', 'publish_times', 'data',
                 'size', 'pieces', 'piece_count', 'first_time')

    def __init__(self) -> None:
        self.prefix = bytearray()
        self.channels: list[int] = []
        self.sequences: list[int] = []
        self.log_times: list[int] = []
        self.publish_times: list[int] = []
        self.data: list[bytes] = []
        self.size = 0
        # (records' bytes, channels, log times, record sizes) of the messages before the lists.
        self.pieces: list[tuple[Any, np.ndarray, np.ndarray, np.ndarray]] = []
        self.piece_count = 0
        self.first_time: int | None = None   # log time of the chunk's first message

    @property
    def count(self) -> int:
        return len(self.data) + self.piece_count

    def first_log_time(self) -> int:
        return self.first_time if self.first_time is not None else self.log_times[0]

    def time_range(self) -> tuple[int, int]:
        times = [min(self.log_times), max(self.log_times)] if self.log_times else []
        for _, _, log_times, _ in self.pieces:
            times += [int(log_times.min()), int(log_times.max())]
        return min(times), max(times)

    def seal(self) -> None:
        """The messages of the lists as a piece (their record headers built at once)."""
        if not self.data:
            return
        records, data = _assemble(self)
        if self.first_time is None:
            self.first_time = self.log_times[0]
        self.pieces.append((data, records['channel'].copy(), records['log_time'].copy(),
                            records['length'] + np.uint64(9)))
        self.piece_count += len(self.data)
        self.channels, self.sequences, self.log_times = [], [], []
        self.publish_times, self.data = [], []


class ChunkedMcapWriter:
    """Write an MCAP file with chunks, message indexes and a summary to a binary stream."""

    def __init__(self, stream: BinaryIO, *, chunk_size: int, compression: str = 'zstd') -> None:
        """``compression`` is 'zstd', 'lz4' or '' (none); chunks close past ``chunk_size``."""
        self._stream = stream
        self._chunk_size = chunk_size
        self._compression = compression
        self._compress = _compressor(compression)
        self._worker = ThreadPoolExecutor(1, thread_name_prefix='mcap-chunk') \
            if self._compress is not None else None
        self._pending: Future | None = None
        self._pending_chunk: tuple[_OpenChunk, bytes] | None = None
        # Open chunks: [0] small messages, [1] bulk ones; each channel keeps to one of them.
        self._lanes = [_OpenChunk(), _OpenChunk()]
        self._lane_of: dict[int, int] = {}
        self._prefix = bytearray()  # schema and channel records not yet in a written chunk
        self._schemas: list[Schema] = []
        self._channels: list[Channel] = []
        # The summary's chunk index, kept as the bytes it is written as: a recording closes a
        # chunk at every flush, several per second, and a record object per chunk would grow
        # the recorder by 15 MB an hour (bench/soak_results.md).
        self._chunk_index_records = bytearray()
        self._metadata_indexes: list[MetadataIndex] = []
        self._channel_counts: dict[int, int] = {}
        self._message_count = 0
        self._start = 0
        self._end = 0
        self._chunk_count = 0
        self._offset = 0

    @property
    def message_count(self) -> int:
        """Messages added so far."""
        return self._message_count + sum(lane.count for lane in self._lanes)

    @property
    def bytes_written(self) -> int:
        """Bytes handed to the stream so far (a chunk in progress not yet among them)."""
        return self._offset

    @property
    def time_range(self) -> tuple[int, int] | None:
        """Earliest and latest log time of the messages so far; None before the first."""
        ranges = [(self._start, self._end)] if self._message_count else []
        for lane in self._lanes:
            if lane.count:
                ranges.append(lane.time_range())
        if not ranges:
            return None
        return min(r[0] for r in ranges), max(r[1] for r in ranges)

    # ---------------------------------------------------------------- records

    def _write(self, data: bytes) -> None:
        self._stream.write(data)
        self._offset += len(data)

    def _write_record(self, record: Any) -> None:
        """Write one record outside any chunk."""
        self._write(_record_bytes(record))

    def start(self, profile: str, library: str) -> None:
        """Write the magic and the header."""
        self._write(MCAP_MAGIC)
        self._write_record(Header(profile=profile, library=library))

    def _append_to_chunk(self, record: Any) -> None:
        self._prefix += _record_bytes(record)

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        """Add a schema (written into the chunk in progress, as mcap does); return its id."""
        schema = Schema(id=len(self._schemas) + 1, name=name, encoding=encoding, data=data)
        self._schemas.append(schema)
        self._append_to_chunk(schema)
        return schema.id

    def register_channel(self, topic: str, message_encoding: str, schema_id: int,
                         metadata: dict[str, str]) -> int:
        """Add a channel (written into the chunk in progress); return its id."""
        channel = Channel(id=len(self._channels) + 1, topic=topic,
                          message_encoding=message_encoding, schema_id=schema_id,
                          metadata=dict(metadata))
        self._channels.append(channel)
        self._channel_counts[channel.id] = 0
        self._append_to_chunk(channel)
        return channel.id

    def add_message(self, channel_id: int, data: bytes, log_time: int,
                    publish_time: int) -> None:
        """Add one message to its channel's open chunk; the sequence number counts the channel."""
        lane = self._lane_of.get(channel_id)
        if lane is None:
            lane = self._lane_of[channel_id] = int(len(data) >= BULK_MESSAGE_BYTES)
        chunk = self._lanes[lane]
        counts = self._channel_counts
        chunk.channels.append(channel_id)
        chunk.sequences.append(counts[channel_id])
        counts[channel_id] += 1
        chunk.log_times.append(log_time)
        chunk.publish_times.append(publish_time)
        chunk.data.append(data)
        chunk.size += _MESSAGE_HEADER_SIZE + len(data)
        if chunk.size > self._chunk_size:
            self._close_chunk(lane)

    def lane_of(self, channel_id: int, size: int) -> int:
        """The open chunk (0 small, 1 bulk) a channel's messages go to; ``size``: a message's."""
        lane = self._lane_of.get(channel_id)
        if lane is None:
            lane = self._lane_of[channel_id] = int(size >= BULK_MESSAGE_BYTES)
        return lane

    def add_rows(self, parts: 'list[RowBlock]') -> None:
        """
        Add blocks of messages as :meth:`add_message` would add them one at a time.

        Each :class:`RowBlock` holds rows of records built elsewhere (a structured array of
        :func:`row_dtype`: one record per slot, headers left for this method to fill) and
        each row's log time (also its publish time) and order key. Messages are added in the
        order of (key, block, slot): chunks close after the same messages, in the same order,
        with the same bytes as one message after another would give.
        """
        streams: dict[int, list[tuple[np.ndarray, np.ndarray, int, 'RowBlock', list[int]]]] = {}
        for number, block in enumerate(parts):
            rows, count = block.rows, block.rows.size
            if not count:
                continue
            by_lane: dict[int, list[int]] = {}
            for slot, (channel_id, size) in enumerate(zip(block.channels, block.sizes)):
                header = rows[f'h{slot}']
                header['opcode'] = Opcode.MESSAGE
                header['length'] = size + _MESSAGE_FIXED
                header['channel'] = channel_id
                first = self._channel_counts[channel_id]
                header['sequence'] = np.arange(first, first + count, dtype=np.uint32)
                self._channel_counts[channel_id] = first + count
                header['log_time'] = block.log_times
                header['publish_time'] = block.log_times
                by_lane.setdefault(self.lane_of(channel_id, size), []).append(slot)
            for lane, slots in by_lane.items():
                streams.setdefault(lane, []).append((block.keys, block.log_times, number,
                                                     block, slots))
        cuts = []
        lanes = {}
        for lane, blocks in streams.items():
            lanes[lane] = stream = _LaneStream(blocks)
            for index in stream.cuts(self._lanes[lane].size, self._chunk_size):
                cuts.append((int(stream.keys[index]), lane, index))
        cuts.sort()
        done = dict.fromkeys(lanes, 0)
        for _, lane, index in cuts:
            self._append_piece(lane, lanes[lane], done[lane], index + 1)
            done[lane] = index + 1
            self._close_chunk(lane)
        for lane, stream in lanes.items():
            if done[lane] < stream.count:
                self._append_piece(lane, stream, done[lane], stream.count)

    def _append_piece(self, lane: int, stream: '_LaneStream', begin: int, end: int) -> None:
        chunk = self._lanes[lane]
        chunk.seal()
        if chunk.first_time is None:
            chunk.first_time = int(stream.log_times[begin])
        chunk.pieces.append((stream.data[int(stream.offsets[begin]):int(stream.offsets[end])],
                             stream.channels[begin:end], stream.log_times[begin:end],
                             stream.sizes[begin:end]))
        chunk.piece_count += end - begin
        chunk.size += int(stream.offsets[end] - stream.offsets[begin])

    def channel_message_count(self, channel_id: int) -> int:
        """Messages added to one channel so far."""
        return self._channel_counts[channel_id]

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """Write a metadata record (after the chunks in progress) and index it."""
        self._close_chunks()
        self._drain()
        record = _record_bytes(Metadata(name=name, metadata=data))
        self._metadata_indexes.append(MetadataIndex(offset=self._offset, length=len(record),
                                                    name=name))
        self._write(record)

    # ---------------------------------------------------------------- chunks

    def _close_chunks(self) -> None:
        """Close both open chunks, the one with the older first message first."""
        for lane in sorted((i for i, chunk in enumerate(self._lanes) if chunk.count),
                           key=lambda i: self._lanes[i].first_log_time()):
            self._close_chunk(lane)

    def _close_chunk(self, lane: int) -> None:
        chunk = self._lanes[lane]
        if not chunk.count:
            return  # schemas and channels alone stay for the next chunk, as in mcap
        self._lanes[lane] = _OpenChunk()
        chunk.prefix, self._prefix = self._prefix, bytearray()
        chunk.seal()
        pieces = chunk.pieces
        data = bytes(chunk.prefix) + b''.join([piece[0] for piece in pieces])
        if len(pieces) == 1:
            _, channels, log_times, sizes = pieces[0]
        else:
            channels = np.concatenate([piece[1] for piece in pieces])
            log_times = np.concatenate([piece[2] for piece in pieces])
            sizes = np.concatenate([piece[3] for piece in pieces])
        start, end = int(log_times.min()), int(log_times.max())
        self._message_count += chunk.count
        self._start = min(self._start, start) if self._chunk_count else start
        self._end = max(self._end, end)
        self._chunk_count += 1
        indexes = _message_indexes(channels, log_times,
                                   _record_offsets(len(chunk.prefix), sizes))
        if self._worker is None:
            self._write_chunk(start, end, indexes, data, data)
            return
        # One compression in flight: the file gets the chunks in order.
        compressed = self._worker.submit(self._compress, data)
        self._drain()
        self._pending = compressed
        self._pending_chunk = (start, end, indexes, data)

    def _drain(self) -> None:
        if self._pending is not None:
            compressed = self._pending.result()
            start, end, indexes, data = self._pending_chunk
            self._pending = self._pending_chunk = None
            self._write_chunk(start, end, indexes, data, compressed)

    def _write_chunk(self, start: int, end: int, indexes: list[tuple[int, bytes]], data: bytes,
                     compressed: bytes) -> None:
        record = Chunk(compression=self._compression, data=compressed,
                       message_start_time=start, message_end_time=end,
                       uncompressed_crc=zlib.crc32(data), uncompressed_size=len(data))
        chunk_offset = self._offset
        chunk_record = _record_bytes(record)
        self._write(chunk_record)
        index_offsets = {}
        index_start = self._offset
        for channel_id, index_record in indexes:
            index_offsets[channel_id] = self._offset
            self._write(index_record)
        self._chunk_index_records += _record_bytes(ChunkIndex(
            message_start_time=start, message_end_time=end,
            chunk_start_offset=chunk_offset, chunk_length=len(chunk_record),
            message_index_offsets=index_offsets,
            message_index_length=self._offset - index_start,
            compression=self._compression, compressed_size=len(compressed),
            uncompressed_size=len(data)))

    def flush(self) -> None:
        """Close the chunks in progress and write everything to the stream."""
        self._close_chunks()
        self._drain()
        self._stream.flush()

    # ---------------------------------------------------------------- summary

    def finish(self) -> None:
        """Write the data end, the summary, the footer and the closing magic."""
        self._close_chunks()
        self._drain()
        if self._worker is not None:
            self._worker.shutdown()
        self._write_record(DataEnd(data_section_crc=0))
        summary_start = self._offset
        builder = RecordBuilder()
        offsets = []

        def group(opcode: Opcode, records: list[Any] | bytes) -> None:
            start = builder.count
            if isinstance(records, (bytes, bytearray)):
                builder.write(records)
            else:
                for record in records:
                    record.write(builder)
            offsets.append(SummaryOffset(group_opcode=opcode, group_start=summary_start + start,
                                         group_length=builder.count - start))

        group(Opcode.SCHEMA, self._schemas)
        group(Opcode.CHANNEL, self._channels)
        group(Opcode.STATISTICS, [Statistics(
            attachment_count=0, channel_count=len(self._channels),
            channel_message_counts=dict(self._channel_counts), chunk_count=self._chunk_count,
            message_count=self._message_count, message_end_time=self._end,
            message_start_time=self._start, metadata_count=len(self._metadata_indexes),
            schema_count=len(self._schemas))])
        group(Opcode.CHUNK_INDEX, bytes(self._chunk_index_records))
        group(Opcode.ATTACHMENT_INDEX, [])
        group(Opcode.METADATA_INDEX, self._metadata_indexes)
        summary_offset_start = summary_start + builder.count
        for offset in offsets:
            offset.write(builder)
        summary = builder.end()
        crc = zlib.crc32(summary)
        crc = zlib.crc32(_FOOTER_CRC_PREFIX.pack(Opcode.FOOTER, 8 + 8 + 4, summary_start,
                                                 summary_offset_start), crc)
        self._write(summary)
        self._write_record(Footer(summary_start=summary_start,
                                  summary_offset_start=summary_offset_start, summary_crc=crc))
        self._write(MCAP_MAGIC)


class RowBlock:
    """
    Rows of message records for :meth:`ChunkedMcapWriter.add_rows`: one record per slot a row.

    ``rows``: a structured array of :func:`row_dtype` (``sizes``: each slot's payload bytes),
    whose payloads the caller has filled; ``channels``: each slot's channel id;
    ``log_times``: each row's (uint64); ``keys``: each row's order among the blocks added
    together (int64, non-decreasing), less than 2**40.
    """

    __slots__ = ('rows', 'channels', 'sizes', 'log_times', 'keys')

    def __init__(self, rows: np.ndarray, channels: tuple[int, ...], sizes: tuple[int, ...],
                 log_times: np.ndarray, keys: np.ndarray) -> None:
        self.rows, self.channels, self.sizes = rows, tuple(channels), tuple(sizes)
        self.log_times = np.asarray(log_times, dtype=np.uint64)
        self.keys = np.asarray(keys, dtype=np.int64)


def row_dtype(payloads: 'list[np.dtype | int]') -> np.dtype:
    """A row of message records: per slot a header ``h<i>`` and its payload ``p<i>``."""
    fields = []
    for slot, payload in enumerate(payloads):
        fields.append((f'h{slot}', _MESSAGE_RECORD))
        fields.append((f'p{slot}', ('u1', payload) if isinstance(payload, int) else payload))
    return np.dtype(fields)


class _LaneStream:
    """The messages of some row blocks that go to one open chunk, in the order they are added."""

    def __init__(self, blocks: list) -> None:
        parts_data, channels, log_times, sizes, keys, row_keys = [], [], [], [], [], []
        for row_order, times, number, block, slots in blocks:
            rows = block.rows
            if len(slots) * 2 != len(rows.dtype.names):
                from numpy.lib import recfunctions
                names = [name for slot in slots for name in (f'h{slot}', f'p{slot}')]
                rows = recfunctions.repack_fields(rows[names])
            count = rows.size
            record_sizes = [_MESSAGE_HEADER_SIZE + block.sizes[slot] for slot in slots]
            parts_data.append(rows)
            channels.append(np.tile(np.array([block.channels[s] for s in slots],
                                             dtype=np.uint16), count))
            log_times.append(np.repeat(times, len(slots)))
            sizes.append(np.tile(np.array(record_sizes, dtype=np.uint64), count))
            order = (row_order.astype(np.int64) << 10) + (number << 5)
            keys.append((order[:, None] + np.array(slots, dtype=np.int64)[None, :]).ravel())
            row_keys.append(order)
        if len(parts_data) == 1:
            self.data = memoryview(parts_data[0].tobytes())
            self.channels, self.log_times = channels[0], log_times[0]
            self.sizes, self.keys = sizes[0], keys[0]
        else:
            # Rows of several blocks in one chunk: merged by their keys, row by row.
            row_sizes = [rows.dtype.itemsize for rows in parts_data]
            per_row = [len(c) // max(rows.size, 1) for c, rows in zip(channels, parts_data)]
            entries = sorted((int(key), number, row)
                             for number, order in enumerate(row_keys)
                             for row, key in enumerate(order.tolist()))
            views = [memoryview(rows.tobytes()) for rows in parts_data]
            pieces, pick = [], []
            for _, number, row in entries:
                size = row_sizes[number]
                pieces.append(views[number][row * size:(row + 1) * size])
                first = sum(len(c) for c in channels[:number])
                pick.extend(range(first + row * per_row[number],
                                  first + (row + 1) * per_row[number]))
            self.data = memoryview(b''.join(pieces))
            index = np.array(pick, dtype=np.intp)
            self.channels = np.concatenate(channels)[index]
            self.log_times = np.concatenate(log_times)[index]
            self.sizes = np.concatenate(sizes)[index]
            self.keys = np.concatenate(keys)[index]
        self.count = self.sizes.size
        self.offsets = np.zeros(self.count + 1, dtype=np.uint64)
        np.cumsum(self.sizes, out=self.offsets[1:])

    def cuts(self, size: int, chunk_size: int) -> list[int]:
        """The messages after which a chunk that holds ``size`` bytes now closes."""
        found = []
        ends = self.offsets[1:].astype(np.int64) + size
        base = 0
        while True:
            index = int(np.searchsorted(ends, base + chunk_size, side='right'))
            if index >= self.count:
                return found
            found.append(index)
            base = int(ends[index])


def _record_bytes(record: Any) -> bytes:
    """One record (an mcap.records instance) as it stands in the file."""
    builder = RecordBuilder()
    record.write(builder)
    return builder.end()


def _assemble(chunk: _OpenChunk) -> tuple[np.ndarray, bytes]:
    """The message record headers of a chunk, and the chunk's uncompressed bytes."""
    count = len(chunk.data)
    lengths = np.fromiter(map(len, chunk.data), dtype=np.uint64, count=count)
    records = np.empty(count, dtype=_MESSAGE_RECORD)
    records['opcode'] = Opcode.MESSAGE
    records['length'] = lengths + _MESSAGE_FIXED
    records['channel'] = chunk.channels
    records['sequence'] = chunk.sequences
    records['log_time'] = chunk.log_times
    records['publish_time'] = chunk.publish_times
    headers = records.tobytes()
    parts: list[bytes | memoryview] = [b''] * (2 * count)
    view = memoryview(headers)
    size = _MESSAGE_HEADER_SIZE
    parts[0::2] = [view[i:i + size] for i in range(0, len(headers), size)]
    parts[1::2] = chunk.data
    return records, b''.join(parts)


def _record_offsets(prefix: int, sizes: np.ndarray) -> np.ndarray:
    """Where each message record starts in a chunk's uncompressed bytes (after ``prefix``)."""
    offsets = np.empty(sizes.size, dtype=np.uint64)
    offsets[0] = prefix
    np.cumsum(sizes[:-1], out=offsets[1:])
    offsets[1:] += np.uint64(prefix)
    return offsets


def _message_indexes(channels: np.ndarray, log_times: np.ndarray,
                     offsets: np.ndarray) -> list[tuple[int, bytes]]:
    """One MessageIndex record per channel of the chunk, channels in order of appearance."""
    unique, first = np.unique(channels, return_index=True)
    result = []
    for channel_id in unique[np.argsort(first)].tolist():
        rows = channels == channel_id
        entries = np.empty((int(rows.sum()), 2), dtype='<u8')
        entries[:, 0] = log_times[rows]
        entries[:, 1] = offsets[rows]
        payload = entries.tobytes()
        result.append((channel_id, _MESSAGE_INDEX_HEADER.pack(
            Opcode.MESSAGE_INDEX, 2 + 4 + len(payload), channel_id, len(payload)) + payload))
    return result
