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
    """The chunk being filled: its schema and channel records, then its messages' fields."""

    __slots__ = ('prefix', 'channels', 'sequences', 'log_times', 'publish_times', 'data',
                 'size')

    def __init__(self) -> None:
        self.prefix = bytearray()
        self.channels: list[int] = []
        self.sequences: list[int] = []
        self.log_times: list[int] = []
        self.publish_times: list[int] = []
        self.data: list[bytes] = []
        self.size = 0

    @property
    def count(self) -> int:
        return len(self.data)


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
                ranges.append((min(lane.log_times), max(lane.log_times)))
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
                           key=lambda i: self._lanes[i].log_times[0]):
            self._close_chunk(lane)

    def _close_chunk(self, lane: int) -> None:
        chunk = self._lanes[lane]
        if not chunk.count:
            return  # schemas and channels alone stay for the next chunk, as in mcap
        self._lanes[lane] = _OpenChunk()
        chunk.prefix, self._prefix = self._prefix, bytearray()
        records, data = _assemble(chunk)
        start, end = int(records['log_time'].min()), int(records['log_time'].max())
        self._message_count += chunk.count
        self._start = min(self._start, start) if self._chunk_count else start
        self._end = max(self._end, end)
        self._chunk_count += 1
        indexes = _message_indexes(records, offsets=_record_offsets(chunk, records))
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


def _record_bytes(record: Any) -> bytes:
    """One record (an mcap.records instance) as it stands in the file."""
    builder = RecordBuilder()
    record.write(builder)
    return builder.end()


def _assemble(chunk: _OpenChunk) -> tuple[np.ndarray, bytes]:
    """The message record headers of a chunk, and the chunk's uncompressed bytes."""
    lengths = np.fromiter(map(len, chunk.data), dtype=np.uint64, count=chunk.count)
    records = np.empty(chunk.count, dtype=_MESSAGE_RECORD)
    records['opcode'] = Opcode.MESSAGE
    records['length'] = lengths + _MESSAGE_FIXED
    records['channel'] = chunk.channels
    records['sequence'] = chunk.sequences
    records['log_time'] = chunk.log_times
    records['publish_time'] = chunk.publish_times
    headers = records.tobytes()
    parts: list[bytes | memoryview] = [b''] * (2 * chunk.count)
    view = memoryview(headers)
    size = _MESSAGE_HEADER_SIZE
    parts[0::2] = [view[i:i + size] for i in range(0, len(headers), size)]
    parts[1::2] = chunk.data
    return records, bytes(chunk.prefix) + b''.join(parts)


def _record_offsets(chunk: _OpenChunk, records: np.ndarray) -> np.ndarray:
    """Where each message record starts in the chunk's uncompressed bytes."""
    sizes = records['length'] + np.uint64(9)
    offsets = np.empty(chunk.count, dtype=np.uint64)
    offsets[0] = len(chunk.prefix)
    np.cumsum(sizes[:-1], out=offsets[1:])
    offsets[1:] += np.uint64(len(chunk.prefix))
    return offsets


def _message_indexes(records: np.ndarray, offsets: np.ndarray) -> list[tuple[int, bytes]]:
    """One MessageIndex record per channel of the chunk, channels in order of appearance."""
    channels = records['channel']
    unique, first = np.unique(channels, return_index=True)
    result = []
    for channel_id in unique[np.argsort(first)].tolist():
        rows = channels == channel_id
        entries = np.empty((int(rows.sum()), 2), dtype='<u8')
        entries[:, 0] = records['log_time'][rows]
        entries[:, 1] = offsets[rows]
        payload = entries.tobytes()
        result.append((channel_id, _MESSAGE_INDEX_HEADER.pack(
            Opcode.MESSAGE_INDEX, 2 + 4 + len(payload), channel_id, len(payload)) + payload))
    return result
