"""
Recovery of a bag whose writer died (SIGKILL, power loss) or whose file was damaged.

The recorder closes a chunk and fsyncs at least every ``flush_period_s``, so everything written
more than about that long before the end is on disk; :func:`recover` reads what is intact and
writes a complete bag from it.

What is kept is checked: every chunk is decompressed and its records' CRC
(``uncompressed_crc``) compared, also in a file that looks complete, and a chunk that fails is
dropped whole and reported with its byte range and, where an index says so, its message count.
The bag written is read back before the recovery reports success: with mcap's reader, CRCs
checked, and with rosbags (an independent reader). A file with nothing in it to recover (empty,
the magic bytes alone, the magic followed by something that is not an MCAP header) is refused,
and so is a bag whose writer still holds its lock (:mod:`softseq_ros.bag.writer`): a file
being written is never moved or replaced.
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

from .layout import MCAP_MAGIC, file_order
from .writer import (
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

    @property
    def intact(self) -> bool:
        """Nothing dropped, the data section ends, and the summary counts what was read."""
        return (self.reached_data_end and not self.dropped and self.summary is not None
                and self.summary.message_count == self.messages)


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
                    schemas=schemas, channels=channels)


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
            problem = None
            record = None
            end = offset
            if len(head) < _RECORD_HEAD.size:
                problem = 'a record cut short'
            else:
                opcode, length = _RECORD_HEAD.unpack(head)
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
    if scan.reached_data_end and scan.summary is None:
        return 'read to the end; the summary section is missing or fails its CRC (rebuilt)'
    return scan.stop_reason


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
    statistics counting what was read) only gets its metadata.yaml rewritten. Otherwise the
    schemas, channels and messages of the intact chunks are written into a temporary file
    beside it, fsynced, and only then does the damaged file become ``<name>.truncated`` and
    the new one take its name, so the only full copy is never overwritten or deleted before
    its replacement is on disk. A recovery that was cut short (killed, disk full) is simply
    run again: it reads the damaged original it kept, any number of times. ``keep_damaged``
    False removes the damaged original once the recovered bag is complete and read back.
    A bag split into several files has each file recovered so (the files a writer closed
    are complete; the last one it wrote is the one cut short), and one metadata.yaml lists
    them all; a last file that holds nothing yet (the writer died right after opening it)
    is set aside as ``<name>.truncated`` and left out.

    Refused (nothing written, nothing moved): a bag whose writer still holds its lock
    (:class:`BagInUseError`), and a file with nothing to recover (:class:`NothingToRecoverError`).
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
    write_metadata_yaml(directory, _information_from_summary([r.mcap_path for r in results]))
    total = sum(r.message_count for r in results)
    _verify(directory, total)
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
            _verify_file(directory, path, scan.messages, mcap_read=False)
            return RecoveryResult(path, scan.messages, True, original, 'complete file')
    source = original if original is not None else path
    temporary = path.with_name(path.name + RECOVERING_SUFFIX)
    temporary.unlink(missing_ok=True)   # left by a recovery that was killed
    scan = _Scan(source, 0)
    try:
        writer = _copy_intact(source, directory, temporary, path.name, scan)
    except (OSError, BagWriterError) as err:
        temporary.unlink(missing_ok=True)
        if isinstance(err, NothingToRecoverError):
            raise
        reason = err.strerror if isinstance(err, OSError) and err.strerror else err
        raise BagWriterError(f'{directory}: cannot write the recovered bag ({reason}); '
                             f'{source.name} is untouched') from None
    # Checked again at the last moment: a file being written is never moved aside.
    _refuse_if_in_use(directory, path)
    damaged = path.with_name(path.name + DAMAGED_SUFFIX)
    if original is None:
        os.replace(path, damaged)
        _sync_directory(directory)
    os.replace(temporary, path)
    _sync_directory(directory)
    _verify_file(directory, path, writer.message_count)
    summary = scan.summary
    dropped = list(scan.dropped)
    orphans = scan.messages - writer.message_count
    if orphans:
        # Messages intact in themselves whose channel record was in a part dropped, and that
        # no intact summary describes: without their type they cannot be written.
        dropped.append(DroppedRange(0, scan.size, 'messages', 'their channel record was in a '
                                    'dropped part of the file', orphans))
    return RecoveryResult(path, writer.message_count, False, damaged, _stop_reason(scan),
                          tuple(dropped),
                          summary.message_count if summary is not None else None)


def _copy_intact(source: Path, directory: Path, temporary: Path, final_name: str,
                 scan: _Scan) -> BagWriter:
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
    return copier.writer


class _Copier:
    """Schemas, channels and messages into the recovered bag, each message's topic first."""

    def __init__(self, writer: BagWriter, scan: _Scan) -> None:
        self.writer = writer
        self.scan = scan
        self.schemas: dict[int, Schema] = {}
        self.topics_by_channel: dict[int, str] = {}

    def copy(self, record: Any) -> None:
        if isinstance(record, Schema):
            self.schemas[record.id] = record
        elif isinstance(record, Channel):
            self._channel(record)
        elif isinstance(record, Message):
            topic = self.topics_by_channel.get(record.channel_id)
            if topic is None and self.scan.summary is not None:
                # Its channel record went with a dropped chunk; the intact summary has it.
                channel = self.scan.summary.channels.get(record.channel_id)
                if channel is not None:
                    self._channel(channel)
                    topic = self.topics_by_channel.get(record.channel_id)
            if topic is not None:
                self.writer.write(topic, record.data, record.log_time, record.publish_time)

    def _channel(self, record: Channel) -> None:
        schema = self.schemas.get(record.schema_id)
        if schema is None and self.scan.summary is not None:
            schema = self.scan.summary.schemas.get(record.schema_id)
        if schema is None:
            return
        if record.topic not in self.writer.topics:
            self.writer.add_topic_with_definition(
                record.topic, schema.name, schema.data.decode('utf-8'),
                record.metadata.get('offered_qos_profiles', ''),
                record.metadata.get('topic_type_hash', ''))
        self.topics_by_channel[record.id] = record.topic
