"""
Recovery of a bag whose writer died (SIGKILL, power loss): its index and metadata rebuilt.

The recorder closes a chunk and fsyncs at least every ``flush_period_s``, so everything written
more than about that long before the end is on disk; :func:`recover` reads what is intact and
writes a complete bag from it.
"""

from dataclasses import dataclass
import io
import os
from pathlib import Path
import struct
from typing import Any, Iterator

from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader

from .writer import BagWriter, BagWriterError, bag_information, write_metadata_yaml


@dataclass(frozen=True)
class RecoveryResult:
    """What :func:`recover` found and wrote."""

    mcap_path: Path
    message_count: int
    was_complete: bool
    damaged_copy: Path | None
    stop_reason: str


MCAP_MAGIC = b'\x89MCAP0\r\n'
DAMAGED_SUFFIX = '.truncated'
RECOVERING_SUFFIX = '.recovering'


def _bag_files(directory: Path) -> tuple[Path, Path | None]:
    """The bag's .mcap path (perhaps missing) and an earlier recovery's damaged original."""
    mcaps = sorted(directory.glob('*.mcap'))
    damaged = sorted(directory.glob('*.mcap' + DAMAGED_SUFFIX))
    if len(mcaps) > 1 or len(damaged) > 1:
        found = ', '.join(p.name for p in [*mcaps, *damaged])
        raise BagWriterError(f'{directory}: expected one .mcap file, found {found}')
    if mcaps:
        path = mcaps[0]
        original = path.with_name(path.name + DAMAGED_SUFFIX)
        if damaged and damaged[0] != original:
            raise BagWriterError(f'{directory}: {damaged[0].name} does not belong to '
                                 f'{path.name}')
        return path, original if original.exists() else None
    if damaged:
        return damaged[0].with_name(damaged[0].name[:-len(DAMAGED_SUFFIX)]), damaged[0]
    raise BagWriterError(f'{directory}: no .mcap file in it')


def _check_mcap(path: Path) -> None:
    with open(path, 'rb') as stream:
        start = stream.read(len(MCAP_MAGIC))
    if start != MCAP_MAGIC:
        raise BagWriterError(f'{path}: not an MCAP file (it does not start with the MCAP '
                             'magic bytes); nothing to recover')


def _sync_directory(directory: Path) -> None:
    descriptor = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(descriptor)
    finally:
        os.close(descriptor)


def _information_from_complete(path: Path) -> dict[str, Any] | None:
    with open(path, 'rb') as stream:
        try:
            summary = make_reader(stream).get_summary()
        except (McapError, OSError, ValueError, EOFError, KeyError, struct.error):
            return None
    if summary is None or summary.statistics is None:
        return None
    stats = summary.statistics
    rows = []
    for channel_id, channel in summary.channels.items():
        schema = summary.schemas.get(channel.schema_id)
        rows.append((channel.topic, schema.name if schema else '',
                     channel.metadata.get('offered_qos_profiles', ''),
                     channel.metadata.get('topic_type_hash', ''),
                     stats.channel_message_counts.get(channel_id, 0)))
    start = stats.message_start_time if stats.message_count else 0
    duration = stats.message_end_time - stats.message_start_time if stats.message_count else 0
    return bag_information(file_name=path.name, start_ns=start, duration_ns=duration,
                           topics=rows)


def _intact_records(path: Path, outcome: dict[str, str]) -> Iterator[Any]:
    """Yield records in file order up to the first truncated or corrupt one."""
    with open(path, 'rb') as stream:
        reader = StreamReader(io.BufferedReader(stream), validate_crcs=True)
        try:
            yield from reader.records
        except Exception as err:  # any failure at all marks where the damaged tail starts
            outcome['stop_reason'] = f'stopped at the damaged tail: {type(err).__name__}: {err}'
            return
    outcome['stop_reason'] = 'read to the end'


def recover(directory: str | os.PathLike, *, keep_damaged: bool = True) -> RecoveryResult:
    """
    Make a readable bag of a directory whose writer died (SIGKILL, power loss, full disk).

    A complete .mcap (footer present) only gets its metadata.yaml rewritten from the file's
    summary. A truncated one is read with the non-seeking stream reader up to the damaged
    tail; the schemas, channels and messages read are written into a temporary file beside
    it, fsynced, and only then does the damaged file become ``<name>.truncated`` and the new
    one take its name, so the only full copy is never overwritten or deleted before its
    replacement is on disk. A recovery that was cut short (killed, disk full) is simply run
    again: it reads the damaged original it kept, any number of times. ``keep_damaged``
    False removes the damaged original once the recovered bag is complete.
    """
    directory = Path(directory)
    if not directory.is_dir():
        raise BagWriterError(f'{directory}: not a bag directory')
    path, original = _bag_files(directory)
    if path.exists():
        _check_mcap(path)
        information = _information_from_complete(path)
        if information is not None:
            write_metadata_yaml(directory, information)
            if original is not None and not keep_damaged:
                original.unlink()
            return RecoveryResult(path, information['message_count'], True,
                                  original if keep_damaged else None, 'complete file')
    source = original if original is not None else path
    _check_mcap(source)
    temporary = path.with_name(path.name + RECOVERING_SUFFIX)
    temporary.unlink(missing_ok=True)   # left by a recovery that was killed
    outcome = {'stop_reason': ''}
    try:
        writer = _copy_intact(source, directory, temporary, path.name, outcome)
    except (OSError, BagWriterError) as err:
        temporary.unlink(missing_ok=True)
        reason = err.strerror if isinstance(err, OSError) and err.strerror else err
        raise BagWriterError(f'{directory}: cannot write the recovered bag ({reason}); '
                             f'{source.name} is untouched') from None
    damaged = path.with_name(path.name + DAMAGED_SUFFIX)
    if original is None:
        os.replace(path, damaged)
        _sync_directory(directory)
    os.replace(temporary, path)
    _sync_directory(directory)
    write_metadata_yaml(directory, writer.bag_information())
    if not keep_damaged:
        damaged.unlink()
    return RecoveryResult(path, writer.message_count, False,
                          damaged if keep_damaged else None, outcome['stop_reason'])


def _copy_intact(source: Path, directory: Path, temporary: Path, final_name: str,
                 outcome: dict[str, str]) -> BagWriter:
    """Write what is intact in ``source`` into ``temporary`` (closed and fsynced on return)."""
    schemas: dict[int, Schema] = {}
    topics_by_channel: dict[int, str] = {}
    writer = BagWriter.for_recovery(directory, temporary.name, final_name)
    try:
        for record in _intact_records(source, outcome):
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel) and record.schema_id in schemas:
                if record.topic not in writer.topics:
                    schema = schemas[record.schema_id]
                    writer.add_topic_with_definition(
                        record.topic, schema.name, schema.data.decode('utf-8'),
                        record.metadata.get('offered_qos_profiles', ''),
                        record.metadata.get('topic_type_hash', ''))
                topics_by_channel[record.id] = record.topic
            elif isinstance(record, Message) and record.channel_id in topics_by_channel:
                writer.write(topics_by_channel[record.channel_id], record.data,
                             record.log_time, record.publish_time)
    finally:
        writer.close()
    return writer
