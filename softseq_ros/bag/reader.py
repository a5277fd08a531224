"""
Read rosbag2 bags (MCAP storage) without ROS: messages and a summary.

Messages are decoded with rosbags (Ternaris), an independent rosbag2 implementation that
builds its decoders from the definitions stored in the bag, so no message package has to
be installed and the decoded objects carry the ROS field names (``msg.header.stamp.sec``).
rosbags takes topics and counts from ``metadata.yaml``: a bag whose writer died has none;
run :func:`softseq_ros.bag.recovery.recover` on it first (:func:`bag_summary` still gives a
provisional summary from the .mcap alone).
"""

from dataclasses import dataclass, field
import io
import os
from pathlib import Path
from typing import Any, Iterable, Iterator, NamedTuple

from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.rosbag2 import ReaderError

from softseq_ros.bag.layout import METADATA_FILE, mcap_files, read_metadata
from softseq_ros.errors import UserError


class BagReadError(UserError):
    """A bag directory is missing, incomplete or malformed."""


class BagMessage(NamedTuple):
    """One message read back from a bag."""

    topic: str
    type_name: str
    log_time_ns: int
    msg: Any


@dataclass(frozen=True)
class TopicSummary:
    """Type and message count of one topic."""

    type_name: str
    message_count: int


@dataclass(frozen=True)
class BagSummary:
    """What a bag holds; ``complete`` is False when read from a bag without metadata.yaml."""

    topics: dict[str, TopicSummary] = field(default_factory=dict)
    message_count: int = 0
    start_ns: int = 0
    duration_ns: int = 0
    complete: bool = True

    @property
    def end_ns(self) -> int:
        """Log time of the last message [ns]."""
        return self.start_ns + self.duration_ns

    @property
    def duration_s(self) -> float:
        """Time from the first to the last message [s]."""
        return self.duration_ns * 1e-9


def _bag_directory(directory: str | os.PathLike) -> Path:
    path = Path(directory)
    if not path.is_dir():
        raise BagReadError(f'{path}: not a bag directory')
    return path


def read_bag(directory: str | os.PathLike,
             topics: Iterable[str] | None = None) -> Iterator[BagMessage]:
    """
    Iterate over the messages of a bag in log-time order, decoded.

    Yields (topic, type_name, log_time_ns, msg); ``topics`` restricts to those topics.
    """
    path = _bag_directory(directory)
    if not (path / METADATA_FILE).is_file():
        raise BagReadError(
            f'{path}: no {METADATA_FILE}; the recording did not finish - recover it first '
            '(softseq recover BAG)')
    wanted = None if topics is None else set(topics)
    try:
        with AnyReader([path]) as reader:
            connections = [c for c in reader.connections
                           if wanted is None or c.topic in wanted]
            if wanted is not None:
                missing = wanted - {c.topic for c in reader.connections}
                if missing:
                    raise BagReadError(
                        f'{path}: no topic {", ".join(sorted(missing))} in this bag')
            for connection, log_time_ns, raw in reader.messages(connections=connections):
                yield BagMessage(connection.topic, connection.msgtype, log_time_ns,
                                 reader.deserialize(raw, connection.msgtype))
    except (AnyReaderError, ReaderError) as err:
        raise BagReadError(f'{path}: {err}') from None


# A bag's times are int64 nanoseconds since 1970 (rosbag2's rcutils_time_point_value_t).
LAST_TIME_NS = 2**63 - 1


def _summary_from_metadata(path: Path) -> BagSummary:
    metadata_path = path / METADATA_FILE
    info = read_metadata(path, BagReadError)
    try:
        topics = {
            entry['topic_metadata']['name']: TopicSummary(
                entry['topic_metadata']['type'], int(entry['message_count']))
            for entry in info['topics_with_message_count']}
        summary = BagSummary(topics=topics, message_count=int(info['message_count']),
                             start_ns=int(info['starting_time']['nanoseconds_since_epoch']),
                             duration_ns=int(info['duration']['nanoseconds']))
    except (KeyError, TypeError, ValueError, OverflowError) as err:
        raise BagReadError(
            f'{metadata_path}: missing or malformed rosbag2 field {err}') from None
    for key, value, bound in (
            ('starting_time.nanoseconds_since_epoch', summary.start_ns, LAST_TIME_NS),
            ('duration.nanoseconds', summary.duration_ns, LAST_TIME_NS - summary.start_ns)):
        if not 0 <= value <= bound:
            shown = value if abs(value) < 10**20 else \
                f'an integer of {len(str(abs(value)))} digits'
            raise BagReadError(
                f'{metadata_path}: {key}: {shown} is outside what a bag can carry: from 0 to '
                f'{bound} ns (int64 ns since 1970, until 2262)')
    return summary


def _summary_from_mcap(path: Path) -> BagSummary:
    _, candidates = mcap_files(path, BagReadError)
    if len(candidates) != 1:
        raise BagReadError(f'{path}: no {METADATA_FILE} and not exactly one .mcap file')
    return scanned_summary(candidates)


def scanned_summary(files: Iterable[Path]) -> BagSummary:
    """
    What the intact part of ``files`` holds, counted message by message (complete=False).

    For a bag whose writer did not finish: neither metadata.yaml nor an MCAP summary counts
    what is there.
    """
    counts: dict[str, int] = {}
    types: dict[str, str] = {}
    times: list[int] = []
    for file in files:
        schemas: dict[int, str] = {}
        channels: dict[int, str] = {}
        with open(file, 'rb') as stream:
            try:
                for record in StreamReader(io.BufferedReader(stream),
                                           validate_crcs=True).records:
                    if isinstance(record, Schema):
                        schemas[record.id] = record.name
                    elif isinstance(record, Channel):
                        channels[record.id] = record.topic
                        types.setdefault(record.topic, schemas.get(record.schema_id, ''))
                        counts.setdefault(record.topic, 0)
                    elif isinstance(record, Message) and record.channel_id in channels:
                        counts[channels[record.channel_id]] += 1
                        times.append(record.log_time)
            except Exception:  # noqa: S110 - the damaged tail of an unfinished file ends it
                pass
    start = min(times) if times else 0
    return BagSummary(
        topics={topic: TopicSummary(types[topic], count) for topic, count in counts.items()},
        message_count=len(times), start_ns=start,
        duration_ns=(max(times) - start) if times else 0, complete=False)


def bag_summary(directory: str | os.PathLike) -> BagSummary:
    """
    Summarize a bag: topics with types and counts, start time and duration.

    Uses metadata.yaml (as every rosbag2 tool does, so also on a recovered bag); without
    it, scans the intact part of the .mcap and returns a summary with complete=False.
    """
    path = _bag_directory(directory)
    if (path / METADATA_FILE).is_file():
        return _summary_from_metadata(path)
    return _summary_from_mcap(path)
