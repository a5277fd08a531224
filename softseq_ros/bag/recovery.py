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


def _find_mcap(directory: Path) -> Path:
    candidates = sorted(directory.glob('*.mcap'))
    if len(candidates) != 1:
        found = ', '.join(p.name for p in candidates) or 'none'
        raise BagWriterError(f'{directory}: expected exactly one .mcap file, found {found}')
    return candidates[0]


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
    Make a readable bag of a directory whose writer died (SIGKILL, power loss).

    A complete .mcap (footer present) only gets its metadata.yaml rewritten from the file's
    summary. A truncated one is read with the non-seeking stream reader up to the damaged
    tail; the schemas, channels and messages read are written into a new complete .mcap of
    the same name (the damaged file is kept as ``<name>.truncated`` unless
    ``keep_damaged`` is False) and metadata.yaml is written for it.
    """
    directory = Path(directory)
    if not directory.is_dir():
        raise BagWriterError(f'{directory}: not a bag directory')
    path = _find_mcap(directory)
    information = _information_from_complete(path)
    if information is not None:
        write_metadata_yaml(directory, information)
        return RecoveryResult(path, information['message_count'], True, None, 'complete file')

    damaged = path.with_name(path.name + '.truncated')
    path.replace(damaged)
    schemas: dict[int, Schema] = {}
    topics_by_channel: dict[int, str] = {}
    outcome = {'stop_reason': ''}
    writer = BagWriter.for_recovery(directory, path.name)
    try:
        for record in _intact_records(damaged, outcome):
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
    if not keep_damaged:
        damaged.unlink()
    return RecoveryResult(path, writer.message_count, False,
                          damaged if keep_damaged else None, outcome['stop_reason'])
