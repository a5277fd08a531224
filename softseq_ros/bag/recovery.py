"""
Recovery of a bag whose writer died (SIGKILL, power loss) or whose file was damaged.

The recorder closes a chunk and fsyncs at least every ``flush_period_s``, so everything written
more than about that long before the end is on disk; :func:`recover` reads what is intact and
writes a complete bag from it.

What is kept is checked: every chunk is decompressed and its records' CRC
(``uncompressed_crc``) compared, also in a file that looks complete, and a chunk that fails is
dropped whole and reported with its byte range and, where an index says so, its message count.
The file written is read back with mcap's reader (CRCs checked) before it takes the bag
file's name, and the whole bag with rosbags (an independent reader) before the recovery reports
success.

A recovery never makes a bag less readable than it was: a file is only replaced by one that
holds at least the messages mcap's own readers read in it (CRCs checked, up to where they
stop); one that would hold fewer (messages without a schema, or of an encoding a rosbag2 bag
cannot carry) is refused and left as it was, and a metadata.yaml that rosbags cannot read the
bag through is not left behind. A file with nothing in it to recover (empty, the magic bytes
alone, the magic followed by something that is not an MCAP header) is refused, and so is a bag
whose writer still holds its lock (:mod:`softseq_ros.bag.writer`): a file being written is
never moved or replaced.
"""

import bisect
from dataclasses import dataclass, field, replace
import io
import os
from pathlib import Path
import struct
from typing import Any, BinaryIO, Iterator
import zlib

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Message,
    MessageIndex,
    Schema,
    Statistics,
)
from mcap.stream_reader import breakup_chunk, get_chunk_data_stream

from softseq_ros.errors import file_kind
from softseq_ros.stopping import HeldSignals

from .layout import MCAP_MAGIC, METADATA_FILE, file_order
from .writer import (
    MESSAGE_ENCODING,
    SCHEMA_ENCODING,
    BagWriter,
    BagWriterError,
    bag_information,
    lock_state,
    write_metadata_yaml,
)


@dataclass(frozen=True)
class DroppedRange:
    """Bytes of the damaged file that :func:`recover` could not keep, and why."""

    start: int          # byte offset in the file, inclusive
    end: int            # exclusive
    what: str           # 'chunk', 'torn tail' or 'damaged records'
    reason: str
    messages: int | None = None   # messages lost there, when an index tells

    def describe(self) -> str:
        """One line: what, where, how many messages, why."""
        count = f', {self.messages} messages' if self.messages is not None else ''
        return f'{self.what} at bytes {self.start}-{self.end}{count}: {self.reason}'


@dataclass(frozen=True)
class RecoveryResult:
    """What :func:`recover` found and wrote."""

    mcap_path: Path
    message_count: int
    was_complete: bool
    damaged_copy: Path | None
    stop_reason: str
    dropped: tuple[DroppedRange, ...] = ()
    # Messages the damaged file's own statistics counted, when its summary is intact.
    expected_count: int | None = None

    @property
    def dropped_messages(self) -> int | None:
        """Messages known lost: from the statistics if intact, else from the indexes."""
        if self.expected_count is not None:
            return self.expected_count - self.message_count
        known = [d.messages for d in self.dropped if d.messages is not None]
        return sum(known) if len(known) == len(self.dropped) else None


DAMAGED_SUFFIX = '.truncated'
RECOVERING_SUFFIX = '.recovering'
_RECORD_HEAD = struct.Struct('<BQ')
# Footer record: opcode, length, summary start, summary offset start, summary CRC.
_FOOTER = struct.Struct('<BQQQI')
# Messages stand at the top level too, in a file written without chunks.
_READERS = {Opcode.HEADER: Header, Opcode.SCHEMA: Schema, Opcode.CHANNEL: Channel,
            Opcode.CHUNK: Chunk, Opcode.MESSAGE_INDEX: MessageIndex, Opcode.MESSAGE: Message,
            Opcode.DATA_END: DataEnd, Opcode.FOOTER: Footer}


class NothingToRecoverError(BagWriterError):
    """A file that holds no recording at all (empty, magic alone, not MCAP)."""


class BagInUseError(BagWriterError):
    """A bag whose writer still holds its lock: it is being written."""


class RecoveryRefusedError(BagWriterError):
    """A recovery that would keep fewer messages than a plain read of the file gives."""


def _bag_files(directory: Path) -> list[tuple[Path, Path | None]]:
    """
    Each .mcap path of the bag (perhaps missing) with an earlier recovery's damaged original.

    A bag split by size or duration has several files (name_0.mcap, name_1.mcap, ...), each
    recovered on its own.
    """
    mcaps = {p.name: p for p in directory.glob('*.mcap')}
    damaged = {p.name[:-len(DAMAGED_SUFFIX)]: p for p in directory.glob('*.mcap' + DAMAGED_SUFFIX)}
    for path in [*mcaps.values(), *damaged.values()]:
        # Checked before anything opens it: a FIFO would block the recovery for ever.
        try:
            kind = file_kind(os.stat(path).st_mode)
        except OSError:
            continue   # a dangling link: as a missing file
        if kind != 'a regular file':
            raise BagWriterError(f'{path}: {kind}, not a regular file: not a bag file; nothing '
                                 'written or moved')
    if not mcaps and not damaged:
        raise BagWriterError(f'{directory}: no .mcap file in it')
    names = sorted(set(mcaps) | set(damaged), key=lambda n: file_order(directory / n))
    return [(directory / name, damaged.get(name)) for name in names]


def _refuse_if_in_use(directory: Path, *paths: Path | None) -> None:
    for path in paths:
        if path is not None and path.exists() and lock_state(path) == 'locked':
            raise BagInUseError(
                f'{directory}: in use: {path.name} is being written by another process (its '
                'writer holds the lock); recover it after the recording has ended or its '
                'writer was killed')


def _sync_directory(directory: Path) -> None:
    descriptor = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(descriptor)
    finally:
        os.close(descriptor)


# ---------------------------------------------------------------- reading what is intact


@dataclass
class _Summary:
    """An MCAP summary section whose CRC holds, as far as recovery needs it."""

    start: int
    chunk_offsets: list[int]
    chunk_indexes: dict[int, ChunkIndex]
    message_count: int | None
    schemas: dict[int, Schema]
    channels: dict[int, Channel]
    channel_message_counts: dict[int, int] = field(default_factory=dict)

    @property
    def describes_its_channels(self) -> bool:
        """
        True when every channel the statistics count messages on is in the summary.

        A writer may leave the channels and schemas out of its summary (``repeatChannels`` and
        ``repeatSchemas`` false in mcap's writers): metadata.yaml cannot be made from it, and
        readers that go by the summary (rosbags) find no topic in the file.
        """
        if self.message_count and not self.channels:
            return False
        for channel_id, count in self.channel_message_counts.items():
            channel = self.channels.get(channel_id)
            if count and (channel is None or channel.schema_id != 0
                          and channel.schema_id not in self.schemas):
                return False
        return True


@dataclass
class _Scan:
    """What one pass over a file found."""

    path: Path
    size: int
    summary: _Summary | None = None
    dropped: list[DroppedRange] = field(default_factory=list)
    messages: int = 0
    reached_data_end: bool = False
    stop_reason: str = ''
    # Offsets of a second MCAP magic and header in the data section (a writer started twice
    # on one file): the records after it are read on, but mcap's readers stop there.
    restarts: list[int] = field(default_factory=list)
    # Offsets of chunks whose length field disagreed with their index, read by the index.
    mended: list[int] = field(default_factory=list)

    @property
    def intact(self) -> bool:
        """
        Nothing dropped, the data section ends, and the summary counts and describes it.

        Only such a file is kept as it is (readers can read it as it stands); any other is
        rewritten from what was read.
        """
        return (self.reached_data_end and not self.dropped and not self.restarts
                and not self.mended and self.summary is not None
                and self.summary.message_count == self.messages
                and self.summary.describes_its_channels)


def _nothing(path: Path, why: str) -> NothingToRecoverError:
    return NothingToRecoverError(f'nothing to recover in {path}: {why}')


def _parse(opcode: int, body: bytes) -> Any:
    """One record from its body; None for a kind recovery does not need."""
    reader = _READERS.get(opcode)
    if reader is None:
        return None
    stream = ReadDataStream(io.BytesIO(body))
    record = reader.read(stream, len(body)) if reader is Message else reader.read(stream)
    if stream.count > len(body):
        raise ValueError('record longer than its length field')
    return record


def _read_summary(stream: BinaryIO, size: int) -> _Summary | None:
    """The summary of a file that ends with a footer whose summary CRC holds; else None."""
    footer_at = size - len(MCAP_MAGIC) - _FOOTER.size
    if footer_at <= len(MCAP_MAGIC):
        return None
    stream.seek(footer_at)
    tail = stream.read(_FOOTER.size + len(MCAP_MAGIC))
    if tail[_FOOTER.size:] != MCAP_MAGIC:
        return None
    opcode, length, start, offsets_start, crc = _FOOTER.unpack(tail[:_FOOTER.size])
    if opcode != Opcode.FOOTER or length != 20 or not len(MCAP_MAGIC) < start <= footer_at:
        return None
    stream.seek(start)
    summary = stream.read(footer_at - start)
    if crc != 0 and zlib.crc32(tail[:_FOOTER.size - 4], zlib.crc32(summary)) != crc:
        return None
    chunk_indexes: dict[int, ChunkIndex] = {}
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    statistics = None
    try:
        data = ReadDataStream(io.BytesIO(summary))
        while data.count < len(summary):
            opcode, length = _RECORD_HEAD.unpack(data.read(_RECORD_HEAD.size))
            body = ReadDataStream(io.BytesIO(data.read(length)))
            if opcode == Opcode.CHUNK_INDEX:
                index = ChunkIndex.read(body)
                chunk_indexes[index.chunk_start_offset] = index
            elif opcode == Opcode.STATISTICS:
                statistics = Statistics.read(body)
            elif opcode == Opcode.SCHEMA:
                schema = Schema.read(body)
                schemas[schema.id] = schema
            elif opcode == Opcode.CHANNEL:
                channel = Channel.read(body)
                channels[channel.id] = channel
    except Exception:  # noqa: BLE001 - a summary that does not parse is no summary
        return None
    return _Summary(start=start, chunk_offsets=sorted(chunk_indexes),
                    chunk_indexes=chunk_indexes,
                    message_count=statistics.message_count if statistics else None,
                    schemas=schemas, channels=channels,
                    channel_message_counts=dict(statistics.channel_message_counts)
                    if statistics else {})


def _indexed_messages(stream: BinaryIO, index: ChunkIndex | None) -> int | None:
    """How many messages a chunk held, from its message indexes (the summary points at them)."""
    if index is None or not index.message_index_offsets:
        return None
    position = stream.tell()
    try:
        count = 0
        for offset in index.message_index_offsets.values():
            stream.seek(offset)
            opcode, length = _RECORD_HEAD.unpack(stream.read(_RECORD_HEAD.size))
            if opcode != Opcode.MESSAGE_INDEX:
                return None
            count += len(_parse(opcode, stream.read(length)).records)
        return count
    except Exception:  # noqa: BLE001 - an index that does not parse counts nothing
        return None
    finally:
        stream.seek(position)


def _intact_records(path: Path, scan: _Scan, parse: bool = True) -> Iterator[Any]:
    """
    Yield the schemas, channels and messages of every intact chunk, in file order.

    Top-level records are walked by their length fields. A chunk whose records fail their
    CRC (or do not decompress or parse) is dropped whole; the message indexes after it say
    how many messages went with it. Where the walk itself loses its footing (a record that
    does not parse, a length beyond the end), an intact summary's chunk index says where the
    next chunk starts; without one, the rest of the file is the damaged tail. ``parse`` False
    only checks and counts (the CRC still checked), yielding nothing: five times as fast.
    """
    with open(path, 'rb') as stream:
        scan.size = size = os.fstat(stream.fileno()).st_size
        if size == 0:
            raise _nothing(path, 'the file is empty')
        if stream.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
            raise _nothing(path, 'not an MCAP file (it does not start with the MCAP magic '
                           'bytes)')
        if size == len(MCAP_MAGIC):
            raise _nothing(path, 'the file holds only the MCAP magic bytes')
        scan.summary = _read_summary(stream, size)
        data_end = scan.summary.start if scan.summary is not None else size
        offset = len(MCAP_MAGIC)
        stream.seek(offset)
        last_dropped: int | None = None   # index into scan.dropped of a chunk just dropped
        first = True
        while offset < data_end:
            head = stream.read(_RECORD_HEAD.size)
            if not first and head == MCAP_MAGIC + bytes([Opcode.HEADER]):
                scan.restarts.append(offset)
                offset += len(MCAP_MAGIC)
                stream.seek(offset)
                continue
            problem = None
            record = None
            end = offset
            if len(head) < _RECORD_HEAD.size:
                problem = 'a record cut short'
            else:
                opcode, length = _RECORD_HEAD.unpack(head)
                index = scan.summary.chunk_indexes.get(offset) if scan.summary else None
                if index is not None and opcode == Opcode.CHUNK \
                        and index.chunk_length != _RECORD_HEAD.size + length:
                    # The chunk's length field is damaged, its index (in a summary whose CRC
                    # holds) is not: mcap's indexed reader reads the chunk so, and so does this.
                    scan.mended.append(offset)
                    length = index.chunk_length - _RECORD_HEAD.size
                end = offset + _RECORD_HEAD.size + length
                if end > size:
                    problem = (f'a record (opcode 0x{opcode:02x}) of {length} bytes runs past '
                               'the end of the file')
                else:
                    try:
                        record = _parse(opcode, stream.read(length))
                    except Exception as err:  # noqa: BLE001 - any failure: the walk lost footing
                        problem = (f'a record (opcode 0x{opcode:02x}) that does not parse '
                                   f'({type(err).__name__})')
                    if problem is None and _swallows_a_chunk(scan.summary, offset, end):
                        problem = (f'a record (opcode 0x{opcode:02x}) whose length runs over '
                                   'the start of an indexed chunk')
            if first:
                if problem is not None or not isinstance(record, Header):
                    raise _nothing(path, 'no MCAP header after the magic bytes (what follows '
                                   'them is not an MCAP recording)')
                first = False
            if problem is not None:
                following = _chunks_after(scan.summary, offset)
                resume = following[0] if following else data_end
                scan.dropped.append(DroppedRange(
                    offset, resume, 'damaged records' if following else 'torn tail', problem,
                    _messages_between(stream, scan.summary, offset, resume)))
                if not following:
                    scan.stop_reason = f'stopped at the damaged tail: {problem}'
                    return
                last_dropped = None
                offset = resume
                stream.seek(offset)
                continue
            if isinstance(record, Chunk):
                try:
                    chunk_records = breakup_chunk(record, validate_crc=True) if parse else []
                    if not parse:
                        scan.messages += _count_messages(record)
                except Exception as err:  # noqa: BLE001 - CRC, decompression or parse: dropped
                    index = scan.summary.chunk_indexes.get(offset) if scan.summary else None
                    scan.dropped.append(DroppedRange(
                        offset, end, 'chunk', _chunk_failure(err),
                        _indexed_messages(stream, index)))
                    last_dropped = len(scan.dropped) - 1
                else:
                    last_dropped = None
                    for chunk_record in chunk_records:
                        if isinstance(chunk_record, Message):
                            scan.messages += 1
                        yield chunk_record
            elif isinstance(record, MessageIndex):
                if last_dropped is not None:
                    dropped = scan.dropped[last_dropped]
                    if scan.summary is None or dropped.messages is None:
                        scan.dropped[last_dropped] = DroppedRange(
                            dropped.start, dropped.end, dropped.what, dropped.reason,
                            (dropped.messages or 0) + len(record.records))
            else:
                last_dropped = None
                if isinstance(record, (Schema, Channel)):
                    yield record
                elif isinstance(record, Message):
                    scan.messages += 1
                    yield record
                elif isinstance(record, (DataEnd, Footer)):
                    scan.reached_data_end = True
                    scan.stop_reason = 'read to the end'
                    return
            offset = end
    scan.stop_reason = ('the file ends without its summary (the writer did not close it)'
                        if scan.summary is None else 'read to the summary')


def _stop_reason(scan: _Scan) -> str:
    reason = scan.stop_reason
    if scan.reached_data_end and scan.summary is None:
        reason = 'read to the end; the summary section is missing or fails its CRC (rebuilt)'
    elif scan.reached_data_end and scan.summary.message_count is None:
        reason = 'read to the end; the summary section has no statistics (rebuilt)'
    elif scan.reached_data_end and not scan.summary.describes_its_channels:
        reason = 'read to the end; the summary section does not describe every channel (rebuilt)'
    if scan.mended:
        reason += (f'; the length field of the chunk at {_bytes_at(scan.mended)} disagrees with '
                   'its index (read by the index)')
    if scan.restarts:
        reason += (f'; a second MCAP magic and header at {_bytes_at(scan.restarts)} (a writer '
                   'started twice on the file) skipped')
    return reason


def _bytes_at(offsets: list[int]) -> str:
    return ('byte ' if len(offsets) == 1 else 'bytes ') + ', '.join(map(str, offsets))


def _messages_between(stream: BinaryIO, summary: _Summary | None, start: int,
                      end: int) -> int | None:
    """Messages of the indexed chunks that start in [start, end); None when not known."""
    if summary is None:
        return None
    counts = [_indexed_messages(stream, summary.chunk_indexes[offset])
              for offset in summary.chunk_offsets if start <= offset < end]
    return None if None in counts else sum(counts)


def _chunks_after(summary: _Summary | None, offset: int) -> list[int]:
    if summary is None:
        return []
    return summary.chunk_offsets[bisect.bisect_right(summary.chunk_offsets, offset):]


def _swallows_a_chunk(summary: _Summary | None, offset: int, end: int) -> bool:
    """True when an intact index puts a chunk's start inside this record (a damaged length)."""
    following = _chunks_after(summary, offset)
    return bool(following) and following[0] < end


def _count_messages(chunk: Chunk) -> int:
    """The message records in a chunk whose CRC holds, walked by their headers."""
    stream, size = get_chunk_data_stream(chunk, validate_crc=True)
    data = stream.read(size)
    offset = count = 0
    unpack = _RECORD_HEAD.unpack_from
    while offset < size:
        opcode, length = unpack(data, offset)
        count += opcode == Opcode.MESSAGE
        offset += _RECORD_HEAD.size + length
    if offset != size:
        raise ValueError('the records overrun the chunk')
    return count


def _chunk_failure(err: Exception) -> str:
    if 'crc' in str(err).lower():
        return f"its records fail the chunk's CRC ({err})"
    return f'its records do not decompress or parse ({type(err).__name__}: {err})'


def _check(path: Path) -> _Scan:
    """One pass over ``path`` that reads (and CRC-checks) everything and writes nothing."""
    scan = _Scan(path, 0)
    for _ in _intact_records(path, scan, parse=False):
        pass
    return scan


# ---------------------------------------------------------------- checking what was written


def _verify_file(directory: Path, path: Path, expected: int, *, mcap_read: bool = True) -> None:
    """
    Read one file back with mcap (CRCs checked); raise unless it holds ``expected`` messages.

    ``mcap_read`` False skips mcap's full read for a file that was not written but has just
    been read through with every CRC checked (a complete file whose metadata is rewritten).
    """
    from mcap.reader import make_reader
    from mcap.stream_reader import StreamReader

    try:
        if mcap_read:
            with open(path, 'rb') as stream:
                count = sum(isinstance(r, Message) for r in
                            StreamReader(stream, validate_crcs=True).records)
            if count != expected:
                raise ValueError(f"mcap's reader finds {count} messages, not {expected}")
        with open(path, 'rb') as stream:
            statistics = make_reader(stream).get_summary().statistics
        if statistics is None or statistics.message_count != expected:
            raise ValueError(f'its statistics do not count {expected} messages')
    except Exception as err:  # noqa: BLE001 - any reader's failure is a bag not recovered
        raise BagWriterError(f'{directory}: the recovered bag does not read back cleanly '
                             f'({path.name}: {type(err).__name__}: {err})') from None


def _plain_read_count(path: Path, summary: _Summary | None) -> int:
    """
    Messages mcap's own readers read in ``path``, CRCs checked, up to where they stop.

    The stream reader, and where an intact summary indexes the chunks the indexed reader too
    (it reads the chunks it can reach by their index): the more of the two. A chunk that fails
    its CRC stops them, as it is dropped by the recovery.
    """
    from mcap.reader import make_reader
    from mcap.stream_reader import StreamReader

    streamed = 0
    with open(path, 'rb') as stream:
        try:
            for record in StreamReader(stream, validate_crcs=True).records:
                streamed += isinstance(record, Message)
        except Exception:  # noqa: BLE001, S110 - where the reader stops is what it reads
            pass
    # The stream reader can also end without a fault short of the end: a length field that
    # runs over the next chunks makes it skip them.
    if summary is None or not summary.chunk_offsets:
        return streamed
    indexed = 0
    with open(path, 'rb') as stream:
        try:
            for _ in make_reader(stream, validate_crcs=True).iter_messages():
                indexed += 1
        except Exception:  # noqa: BLE001, S110 - likewise
            pass
    return max(streamed, indexed)


def _verify(directory: Path, expected: int) -> None:
    """Read the whole bag back with rosbags (an independent reader, through metadata.yaml)."""
    try:
        from rosbags.rosbag2 import Reader

        with Reader(directory) as reader:
            count = sum(1 for _ in reader.messages())
            if count != expected or reader.message_count != expected:
                raise ValueError(f'rosbags reads {count} messages (metadata.yaml: '
                                 f'{reader.message_count}), not {expected}')
    except Exception as err:  # noqa: BLE001 - any reader's failure is a bag not recovered
        raise BagWriterError(f'{directory}: the recovered bag does not read back cleanly '
                             f'({type(err).__name__}: {err})') from None


def _information_from_summary(paths: list[Path]) -> dict[str, Any]:
    """metadata.yaml's content from the summaries of the bag's files, in order."""
    from mcap.reader import make_reader

    rows: dict[str, list] = {}
    files = []
    for path in paths:
        with open(path, 'rb') as stream:
            summary = make_reader(stream).get_summary()
        stats = summary.statistics
        for channel_id, channel in summary.channels.items():
            schema = summary.schemas.get(channel.schema_id)
            count = stats.channel_message_counts.get(channel_id, 0)
            row = rows.get(channel.topic)
            if row is None:
                rows[channel.topic] = [channel.topic, schema.name if schema else '',
                                       channel.metadata.get('offered_qos_profiles', ''),
                                       channel.metadata.get('topic_type_hash', ''), count]
            else:
                row[4] += count
        start = stats.message_start_time if stats.message_count else 0
        duration = stats.message_end_time - start if stats.message_count else 0
        files.append((path.name, start, duration, stats.message_count))
    spans = [(start, start + duration) for _, start, duration, count in files if count]
    first = min((a for a, _ in spans), default=0)
    last = max((b for _, b in spans), default=0)
    return bag_information(file_name=paths[-1].name, start_ns=first, duration_ns=last - first,
                           topics=[tuple(row) for row in rows.values()], files=files)


# ---------------------------------------------------------------- recovery


def recover(directory: str | os.PathLike, *, keep_damaged: bool = True) -> RecoveryResult:
    """
    Make a readable bag of a directory whose writer died (SIGKILL, power loss, full disk).

    Every chunk's CRC is checked. A complete .mcap (summary intact, every chunk valid, the
    statistics counting what was read, every channel counted described) only gets its
    metadata.yaml rewritten. Otherwise the schemas, channels and messages of the intact
    chunks are written into a temporary file beside it, fsynced and read back, and only then
    does the damaged file become ``<name>.truncated`` and the new one take its name, so the
    only full copy is never overwritten or deleted before its replacement is on disk. A
    recovery that was cut short (killed, disk full) is simply run again: it reads the damaged
    original it kept, any number of times; one stopped by SIGINT or SIGTERM leaves no copy
    behind and never a bag without its file (the renames hold the stop until both are done).
    ``keep_damaged`` False removes the damaged original once the recovered bag is complete
    and read back.
    A bag split into several files has each file recovered so (the files a writer closed
    are complete; the last one it wrote is the one cut short), and one metadata.yaml lists
    them all; a last file that holds nothing yet (the writer died right after opening it)
    is set aside as ``<name>.truncated`` and left out.

    Refused (nothing written, nothing moved): a bag whose writer still holds its lock
    (:class:`BagInUseError`), a file with nothing to recover (:class:`NothingToRecoverError`),
    and a file whose recovery would hold fewer messages than mcap's readers read in it, or
    whose messages a rosbag2 bag cannot carry (:class:`RecoveryRefusedError`; the files of a
    split bag are recovered one after the other, so those before such a file are already
    recovered).
    """
    directory = Path(directory)
    if not directory.is_dir():
        raise BagWriterError(f'{directory}: not a bag directory')
    files = _bag_files(directory)
    for path, original in files:
        _refuse_if_in_use(directory, path, original)
    results = []
    for number, (path, original) in enumerate(files):
        try:
            results.append(_recover_file(directory, path, original))
        except NothingToRecoverError:
            if len(files) == 1 or number != len(files) - 1:
                raise
            if path.exists() and original is None:
                os.replace(path, path.with_name(path.name + DAMAGED_SUFFIX))
                _sync_directory(directory)
            else:
                path.unlink(missing_ok=True)
    metadata = directory / METADATA_FILE
    previous_metadata = metadata.read_bytes() if metadata.is_file() else None
    information = _information_from_summary([r.mcap_path for r in results])
    with HeldSignals():   # never a metadata.yaml.tmp left beside the bag
        write_metadata_yaml(directory, information)
    total = sum(r.message_count for r in results)
    try:
        _verify(directory, total)
    except BagWriterError as err:
        if any(not r.was_complete for r in results):
            raise
        # Only metadata.yaml was written, and rosbags cannot read the bag through it: the bag
        # is left as it was.
        with HeldSignals():
            _put_back(metadata, previous_metadata)
        raise BagWriterError(f'{err}; nothing written or moved') from None
    if not keep_damaged:
        for result in results:
            if result.damaged_copy is not None:
                result.damaged_copy.unlink()
        results = [replace(r, damaged_copy=None) for r in results]
    if len(results) == 1:
        return results[0]
    rebuilt = [r for r in results if not r.was_complete]
    expected = [r.expected_count if not r.was_complete else r.message_count for r in results]
    return RecoveryResult(
        (rebuilt or results)[-1].mcap_path, total, not rebuilt,
        next((r.damaged_copy for r in rebuilt if r.damaged_copy is not None), None),
        '; '.join(f'{r.mcap_path.name}: {r.stop_reason}' for r in (rebuilt or results[-1:])),
        tuple(d for r in rebuilt for d in r.dropped),
        None if None in expected else sum(expected))


def _put_back(path: Path, content: bytes | None) -> None:
    """``path`` as it was before: ``content``, or no file at all (None)."""
    if content is None:
        path.unlink(missing_ok=True)
    else:
        temporary = path.with_name(path.name + '.tmp')
        with open(temporary, 'wb') as stream:
            stream.write(content)
            stream.flush()
            os.fsync(stream.fileno())
        os.replace(temporary, path)
    _sync_directory(path.parent)


def _recover_file(directory: Path, path: Path, original: Path | None) -> RecoveryResult:
    """One .mcap file of the bag made whole (metadata.yaml is the caller's)."""
    if path.exists():
        try:
            scan = _check(path)
        except NothingToRecoverError:
            if original is None:
                raise
            scan = None   # a cut-short recovery's output: the damaged original is read instead
        if scan is not None and scan.intact:
            _refuse_channels_a_bag_cannot_carry(path, scan.summary)
            _verify_file(directory, path, scan.messages, mcap_read=False)
            return RecoveryResult(path, scan.messages, True, original, 'complete file')
    source = original if original is not None else path
    temporary = path.with_name(path.name + RECOVERING_SUFFIX)
    temporary.unlink(missing_ok=True)   # left by a recovery that was killed
    scan = _Scan(source, 0)
    # Until the copy takes the bag file's name, a refusal, a failure or a stop (SIGINT,
    # SIGTERM) leaves nothing of it behind.
    try:
        try:
            copier = _copy_intact(source, directory, temporary, path.name, scan)
        except (OSError, BagWriterError) as err:
            if isinstance(err, NothingToRecoverError):
                raise
            reason = err.strerror if isinstance(err, OSError) and err.strerror else err
            raise BagWriterError(f'{directory}: cannot write the recovered bag ({reason}); '
                                 f'{source.name} is untouched') from None
        kept = copier.writer.message_count
        _verify_file(directory, temporary, kept)
        _refuse_fewer_than_a_plain_read(source, scan, copier)
        # Checked again at the last moment: a file being written is never moved aside.
        _refuse_if_in_use(directory, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
    damaged = path.with_name(path.name + DAMAGED_SUFFIX)
    # A stop between the two renames would leave the bag without its file: it acts after both.
    with HeldSignals():
        if original is None:
            os.replace(path, damaged)
            _sync_directory(directory)
        os.replace(temporary, path)
        _sync_directory(directory)
    summary = scan.summary
    dropped = list(scan.dropped)
    dropped.extend(DroppedRange(0, scan.size, 'messages', why, count)
                   for why, count in copier.skipped.items())
    return RecoveryResult(path, kept, False, damaged, _stop_reason(scan), tuple(dropped),
                          summary.message_count if summary is not None else None)


def _refuse_channels_a_bag_cannot_carry(path: Path, summary: _Summary) -> None:
    """RecoveryRefusedError naming the channels of a complete file metadata.yaml cannot list."""
    unwritable = {}
    for channel_id, count in summary.channel_message_counts.items():
        channel = summary.channels.get(channel_id)
        if count and channel is not None:
            why = _unwritable(channel, summary.schemas.get(channel.schema_id))
            if why is not None:
                unwritable[why] = unwritable.get(why, 0) + count
    if unwritable:
        why = '; '.join(f'{count} messages: {why}' for why, count in unwritable.items())
        raise RecoveryRefusedError(f'{path}: a rosbag2 bag cannot carry some of its messages '
                                   f'({why}); nothing written or moved')


def _unwritable(channel: Channel, schema: Schema | None) -> str | None:
    """Why a rosbag2 bag cannot carry the messages of ``channel``; None when it can."""
    if channel.schema_id == 0:
        return f'{channel.topic} has no schema'
    if schema is None:
        return f'the schema of {channel.topic} was in a dropped part of the file'
    if channel.message_encoding != MESSAGE_ENCODING or schema.encoding != SCHEMA_ENCODING:
        return (f'{channel.topic} holds {channel.message_encoding or "unnamed"} messages of a '
                f'{schema.encoding or "unnamed"} schema, not {MESSAGE_ENCODING} of '
                f'{SCHEMA_ENCODING}')
    try:
        schema.data.decode('utf-8')
    except UnicodeDecodeError:
        return f'the {SCHEMA_ENCODING} schema of {channel.topic} is not UTF-8 text'
    return None


def _refuse_fewer_than_a_plain_read(source: Path, scan: _Scan, copier: '_Copier') -> None:
    """RecoveryRefusedError when mcap's readers read more messages in ``source`` than were kept."""
    # Read even when every message the walk found is kept: the walk is what is checked here.
    kept, plain = copier.writer.message_count, _plain_read_count(source, scan.summary)
    if kept < plain:
        why = '; '.join(f'{count} messages: {why}' for why, count in copier.skipped.items())
        raise RecoveryRefusedError(
            f'{source}: a recovery would keep {kept} of the {plain} messages that mcap reads in '
            f'it ({why or "it reads further into the file"}); nothing written or moved')


def _copy_intact(source: Path, directory: Path, temporary: Path, final_name: str,
                 scan: _Scan) -> '_Copier':
    """Write what is intact in ``source`` into ``temporary`` (closed and fsynced on return)."""
    records = _intact_records(source, scan)
    # The first record read decides whether there is anything at all, before a file is made.
    first = next(records, None)
    copier = _Copier(BagWriter.for_recovery(directory, temporary.name, final_name), scan)
    try:
        for record in ([first] if first is not None else []):
            copier.copy(record)
        for record in records:
            copier.copy(record)
    finally:
        copier.writer.close()
    return copier


class _Copier:
    """
    Schemas, channels and messages into the recovered bag, each message's topic first.

    A message the bag cannot hold is counted in ``skipped`` under the reason: its channel
    record lost with a dropped part, a channel without a schema, or one whose messages are not
    CDR of a ros2msg definition (a rosbag2 bag would label them as such and mislead readers).
    """

    def __init__(self, writer: BagWriter, scan: _Scan) -> None:
        self.writer = writer
        self.scan = scan
        self.schemas: dict[int, Schema] = {}
        self.topics_by_channel: dict[int, str] = {}
        self.unwritable: dict[int, str] = {}    # channel id: why its messages are not kept
        self.skipped: dict[str, int] = {}       # why: messages not kept

    def copy(self, record: Any) -> None:
        if isinstance(record, Schema):
            self.schemas[record.id] = record
        elif isinstance(record, Channel):
            self._channel(record)
        elif isinstance(record, Message):
            topic = self.topics_by_channel.get(record.channel_id)
            if topic is None and self.scan.summary is not None \
                    and record.channel_id not in self.unwritable:
                # Its channel record went with a dropped chunk; the intact summary has it.
                channel = self.scan.summary.channels.get(record.channel_id)
                if channel is not None:
                    self._channel(channel)
                    topic = self.topics_by_channel.get(record.channel_id)
            if topic is None:
                why = self.unwritable.get(
                    record.channel_id, 'their channel record was in a dropped part of the file')
                self.skipped[why] = self.skipped.get(why, 0) + 1
            else:
                self.writer.write(topic, record.data, record.log_time, record.publish_time)

    def _channel(self, record: Channel) -> None:
        schema = self.schemas.get(record.schema_id)
        if schema is None and self.scan.summary is not None:
            schema = self.scan.summary.schemas.get(record.schema_id)
        why = _unwritable(record, schema)
        if why is not None:
            self.unwritable[record.id] = why
            return
        if record.topic not in self.writer.topics:
            self.writer.add_topic_with_definition(
                record.topic, schema.name, schema.data.decode('utf-8'),
                record.metadata.get('offered_qos_profiles', ''),
                record.metadata.get('topic_type_hash', ''))
        self.topics_by_channel[record.id] = record.topic
