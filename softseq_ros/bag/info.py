"""
``softseq info BAG``: what ``ros2 bag info`` shows of a bag, and what the rig knows of it.

The rosbag2 part: files, size, storage, duration, start and end, message count, and per topic
its type and count, and where the counts come from. From metadata.yaml, as rosbag2's tools
read it, when the .mcap files hold as many (their MCAP statistics, or a scan where a file has
none); from a scan of the .mcap files (softseq_ros.bag.reader.scanned_summary) when there is
no metadata.yaml or a file has no summary (the recording did not finish), or when the files
hold another count than metadata.yaml says (one written at an earlier flush, a file cut short
or grown since): then metadata.yaml's count is shown beside the scan's. Ours: the MCAP chunk
compression, whether the bag is complete (metadata.yaml written and an MCAP summary section at
the end of every file, which only a recorder that closed its bag writes), the rig namespaces it
holds (where a ``pump/command`` or an ``actuator/scene`` topic is) and, per namespace, the scene
that made it: the actuator's latched ``actuator/scene`` (scene name, its segments base to tip,
the SHA-256 of their definitions: softseq_ros.segments.identity).

Needs no ROS: the .mcap files are read with the mcap library and std_msgs/String is one CDR
string. A path that holds no MCAP bag (a sqlite3 bag, a stray folder) or a file that is no
MCAP, and a metadata.yaml that cannot be read, are a :class:`BagInfoError` in one line.
"""

from dataclasses import dataclass, field
from datetime import datetime, timezone
import io
import os
from pathlib import Path
import struct

from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Footer, Message
from mcap.stream_reader import StreamReader
from mcap.summary import Summary

from softseq_ros.bag.arrays import BagArrayError, string_text
from softseq_ros.bag.layout import MCAP_MAGIC, METADATA_FILE, mcap_files, read_metadata
from softseq_ros.bag.reader import (
    BagReadError,
    BagSummary,
    TopicSummary,
    bag_summary,
    scanned_summary,
)
from softseq_ros.errors import UserError
from softseq_ros.wire import contract
from softseq_ros.wire.payloads import SCENE_IDENTITY_JSON, PayloadError
from softseq_ros.wire.values import SceneIdentity

# Where counts come from when they are not metadata.yaml's (``softseq info``'s Counts row).
SCANNED = 'a scan of the .mcap files'


class BagInfoError(UserError):
    """A path that holds no readable MCAP bag; the message names it and says why."""


@dataclass(frozen=True)
class SceneSaid:
    """One scene identity an actuator published in the bag, with the namespace it ran in."""

    namespace: str
    identity: SceneIdentity


@dataclass(frozen=True)
class BagInfo:
    """Everything ``softseq info`` prints of one bag."""

    path: Path
    files: tuple[Path, ...]
    size_bytes: int
    summary: BagSummary
    compression: tuple[str, ...]            # MCAP chunk compressions used ('none' unchunked)
    has_metadata: bool                      # metadata.yaml written (rosbag2 reads the bag)
    files_without_summary: tuple[Path, ...]  # .mcap files whose writer never closed them
    storage: str = 'mcap'
    ros_distro: str = ''
    counted_by: str = METADATA_FILE         # METADATA_FILE, or SCANNED: where the counts are from
    # What metadata.yaml says where it disagrees with the scan shown; None where it does not.
    metadata_disagrees: BagSummary | None = None
    namespaces: tuple[str, ...] = ()
    scenes: tuple[SceneSaid, ...] = field(default_factory=tuple)

    @property
    def complete(self) -> bool:
        """True when the recorder closed the bag: metadata.yaml and every MCAP summary."""
        return self.has_metadata and not self.files_without_summary


def _check_magic(file: Path) -> None:
    with open(file, 'rb') as stream:
        head = stream.read(len(MCAP_MAGIC))
    if head != MCAP_MAGIC:
        raise BagInfoError(f'{file}: not an MCAP file (it does not start with the MCAP magic)')


def _chunk_compressions(file: Path) -> tuple[set[str], Summary | None]:
    """The compressions of a file's chunks and its MCAP summary (None: the file is not closed)."""
    try:
        with open(file, 'rb') as stream:
            summary = make_reader(stream).get_summary()
    except (McapError, struct.error, ValueError, EOFError, OSError):
        summary = None
    if summary is not None:
        return {index.compression or 'none' for index in summary.chunk_indexes}, summary
    # Never closed: the chunks written so far say how they are compressed.
    found: set[str] = set()
    with open(file, 'rb') as stream:
        try:
            records = StreamReader(io.BufferedReader(stream), emit_chunks=True).records
            for record in records:
                if isinstance(record, Chunk):
                    found.add(record.compression or 'none')
                elif isinstance(record, Footer):
                    break
        except Exception:  # noqa: S110 - the damaged tail of an unfinished file ends the scan
            pass
    return found, None


def _counted_by_statistics(summaries: list[Summary]) -> BagSummary | None:
    """
    What closed files hold by their MCAP statistics.

    None where one has no statistics or counts messages on a channel its summary does not
    describe: then only a scan tells.
    """
    counts: dict[str, int] = {}
    types: dict[str, str] = {}
    spans = []
    for summary in summaries:
        statistics = summary.statistics
        if statistics is None:
            return None
        for channel_id, count in statistics.channel_message_counts.items():
            channel = summary.channels.get(channel_id)
            if channel is None:
                return None
            schema = summary.schemas.get(channel.schema_id)
            types.setdefault(channel.topic, schema.name if schema is not None else '')
            counts[channel.topic] = counts.get(channel.topic, 0) + count
        if sum(statistics.channel_message_counts.values()) != statistics.message_count:
            return None
        if statistics.message_count:
            spans.append((statistics.message_start_time, statistics.message_end_time))
    start = min((a for a, _ in spans), default=0)
    end = max((b for _, b in spans), default=0)
    return BagSummary(topics={t: TopicSummary(types[t], n) for t, n in counts.items()},
                      message_count=sum(counts.values()), start_ns=start,
                      duration_ns=end - start)


def _same_counts(one: BagSummary, other: BagSummary) -> bool:
    return one.message_count == other.message_count and \
        {t: s.message_count for t, s in one.topics.items() if s.message_count} == \
        {t: s.message_count for t, s in other.topics.items() if s.message_count}


def _scenes(files: tuple[Path, ...], namespaces: tuple[str, ...]) -> tuple[SceneSaid, ...]:
    """The distinct scene identities said on each namespace's actuator/scene, in order."""
    wanted = {contract.resolve(contract.SCENE.name, ns): ns for ns in namespaces}
    said: list[SceneSaid] = []
    for file in files:
        channels: dict[int, str] = {}
        with open(file, 'rb') as stream:
            try:
                for record in StreamReader(io.BufferedReader(stream)).records:
                    if isinstance(record, Channel) and record.topic in wanted:
                        channels[record.id] = record.topic
                    elif isinstance(record, Message) and record.channel_id in channels:
                        topic = channels[record.channel_id]
                        try:
                            text = string_text(record.data, f'{file}: {topic}')
                            value = SCENE_IDENTITY_JSON.decode(text, stamp_ns=record.log_time)
                        except (PayloadError, BagArrayError):
                            continue  # a garbled identity names no scene
                        namespace = wanted[topic]
                        if not any(s.namespace == namespace
                                   and s.identity.names() == value.names() for s in said):
                            said.append(SceneSaid(namespace, value))
            except Exception:  # noqa: S110 - the damaged tail of an unfinished file ends it
                pass
    return tuple(said)


def _ros_distro(folder: Path) -> tuple[str, str]:
    try:
        info = read_metadata(folder, BagInfoError)
    except BagInfoError:
        return 'mcap', ''
    return str(info.get('storage_identifier') or 'mcap'), str(info.get('ros_distro') or '')


def bag_info(path: str | os.PathLike) -> BagInfo:
    """Read what ``softseq info`` shows of the bag at ``path`` (a folder or its .mcap file)."""
    folder, files = mcap_files(Path(path), BagInfoError)
    for file in files:
        _check_magic(file)
    has_metadata = (folder / METADATA_FILE).is_file()
    compressions: set[str] = set()
    unclosed = []
    closed_summaries = []
    for file in files:
        found, file_summary = _chunk_compressions(file)
        compressions |= found
        if file_summary is None:
            unclosed.append(file)
        else:
            closed_summaries.append(file_summary)
    said = None
    if has_metadata:
        try:
            said = bag_summary(folder)
        except BagReadError as err:
            raise BagInfoError(str(err)) from None
    # metadata.yaml counts what its writer had written when it wrote it: the files may hold
    # more or fewer messages since. Only files that all were closed have statistics to hold
    # it against without reading every message.
    held = None if unclosed else _counted_by_statistics(closed_summaries)
    if said is not None and held is not None and _same_counts(said, held):
        summary, counted_by, disagrees = said, METADATA_FILE, None
    else:
        summary = scanned_summary(files)
        agrees = said is not None and _same_counts(said, summary)
        if agrees and not unclosed:
            summary, counted_by, disagrees = said, METADATA_FILE, None
        else:
            counted_by, disagrees = SCANNED, None if agrees else said
    topics = tuple(summary.topics)
    namespaces = tuple(sorted(set(contract.find_namespaces(topics))
                              | set(contract.find_namespaces(topics, contract.SCENE.name))))
    storage, distro = _ros_distro(folder) if has_metadata else ('mcap', '')
    return BagInfo(
        path=folder, files=files, size_bytes=sum(f.stat().st_size for f in files),
        summary=summary, compression=tuple(sorted(compressions)) or ('none',),
        has_metadata=has_metadata, files_without_summary=tuple(unclosed), storage=storage,
        ros_distro=distro, namespaces=namespaces, scenes=_scenes(files, namespaces),
        counted_by=counted_by, metadata_disagrees=disagrees)


def _size_text(size: int) -> str:
    for unit in ('B', 'KiB', 'MiB', 'GiB'):
        if size < 1024 or unit == 'GiB':
            return f'{size:.1f} {unit}' if unit != 'B' else f'{size} B'
        size /= 1024
    return f'{size} B'


def _time_text(ns: int) -> str:
    moment = datetime.fromtimestamp(ns / 1e9, tz=timezone.utc)
    return f'{moment.strftime("%Y-%m-%d %H:%M:%S.%f")[:-3]} UTC ({ns // 10**9}.{ns % 10**9:09d})'


def _counts_text(info: BagInfo) -> str:
    """Where the counts shown come from, and what metadata.yaml says where it disagrees."""
    if info.counted_by == METADATA_FILE:
        return f'from {METADATA_FILE} (the .mcap files hold as many)'
    said = info.metadata_disagrees
    if said is None:
        why = f'{METADATA_FILE} says as many' if info.has_metadata else f'no {METADATA_FILE}'
        return f'from {SCANNED} ({why})'
    split = '' if said.message_count != info.summary.message_count else \
        ', split otherwise among the topics'
    return (f'from {SCANNED}; {METADATA_FILE} disagrees: it says {said.message_count} '
            f'messages{split}')


def format_info(info: BagInfo) -> str:
    """The text ``softseq info`` prints, laid out as ``ros2 bag info`` lays out its own."""
    summary = info.summary
    rows = [
        ('Files', ', '.join(f.name for f in info.files)),
        ('Bag size', _size_text(info.size_bytes)),
        ('Storage id', info.storage + (f' (ROS {info.ros_distro})' if info.ros_distro else '')),
        ('Compression', ', '.join(info.compression) + ' (MCAP chunks)'),
        ('Duration', f'{summary.duration_ns / 1e9:.9f} s'),
        ('Start', _time_text(summary.start_ns) if summary.message_count else '-'),
        ('End', _time_text(summary.end_ns) if summary.message_count else '-'),
        ('Messages', str(summary.message_count)),
        ('Counts', _counts_text(info)),
    ]
    if info.complete:
        rows.append(('Complete', 'yes (metadata.yaml and the MCAP summary written)'))
    else:
        missing = ([] if info.has_metadata else [f'no {METADATA_FILE}']) + [
            f'{f.name} has no MCAP summary' for f in info.files_without_summary]
        rows.append(('Complete', f'no: {"; ".join(missing)} (the recording did not finish; '
                                 'softseq recover BAG repairs it)'))
    rows.append(('Namespaces', ', '.join(info.namespaces) or '- (no rig topics)'))
    if info.scenes:
        for index, said in enumerate(info.scenes):
            scene = said.identity
            rows.append(('Scene' if index == 0 else '',
                         f'{scene.scene or "(unnamed)"} in {said.namespace}: segments '
                         f'{", ".join(scene.segments)} (base to tip), segments SHA-256 '
                         f'{scene.segments_sha256}'))
    else:
        rows.append(('Scene', f'- (no {contract.SCENE.name} message in the bag)'))
    width = max(len(name) for name, _ in rows) + 2
    lines = [f'{name + ":" if name else "":<{width}}{value}' for name, value in rows]
    lines.append('Topic information:')
    for topic in sorted(summary.topics):
        entry = summary.topics[topic]
        lines.append(f'  Topic: {topic} | Type: {entry.type_name} | '
                     f'Count: {entry.message_count} | Serialization Format: cdr')
    return '\n'.join(lines)
