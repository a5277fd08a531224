"""
Write MCAP bags in the layout of rosbag2 (ROS 2 Jazzy), and recover them after a crash.

A bag is a directory holding one ``<name>_0.mcap`` file and a ``metadata.yaml`` beside it,
as ``ros2 bag record -s mcap`` leaves it. What is matched (rosbag2 Jazzy,
rosbag2_storage_mcap/mcap_storage.cpp and rosbag2_storage/yaml.hpp, qos.cpp):

- MCAP header profile ``ros2``; chunked data with message indexes and a summary section
  holding schemas, channels, Statistics, chunk and metadata indexes.
- One schema per type, named ``pkg/msg/Type``, encoding ``ros2msg``, data = the full
  definition text (see :mod:`softseq_ros.bag.msgdefs`).
- One channel per topic, message encoding ``cdr``, metadata ``offered_qos_profiles`` (a
  YAML string, empty when unknown) and ``topic_type_hash`` (RIHS01, left out when the
  package ships no type description).
- On close, a Metadata record named ``rosbag2`` whose key ``serialized_metadata`` holds the
  bag information as YAML, then ``metadata.yaml`` with key ``rosbag2_bagfile_information``,
  version 9, in rosbag2's field order; in version 9 ``offered_qos_profiles`` is a YAML
  sequence in metadata.yaml and policies are written by name (``keep_last``, ``reliable``).
  ``compression_format``/``compression_mode`` stay empty as with rosbag2's MCAP plugin:
  MCAP compresses inside its chunks, which is not rosbag2 file or message compression.

Crash safety: the chunk in progress is closed and the file fsynced at least every
``flush_period_s`` (a background thread does it when no messages arrive), so after a
SIGKILL everything written more than about that long ago is on disk; :func:`recover`
rebuilds a complete bag from such a truncated file.
"""

from dataclasses import dataclass
from functools import lru_cache, partial
from importlib.metadata import PackageNotFoundError, version
import io
import os
from pathlib import Path
import struct
import threading
import time
from typing import Any, BinaryIO, Callable, Iterator, Mapping, Sequence

from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader
import yaml

from .cdr import encode
from .mcap_file import ChunkedMcapWriter
from .msgdefs import canonical_type_name, message_definition, type_description_hash

METADATA_FILE = 'metadata.yaml'
METADATA_VERSION = 9
STORAGE_IDENTIFIER = 'mcap'
PROFILE = 'ros2'
SCHEMA_ENCODING = 'ros2msg'
MESSAGE_ENCODING = 'cdr'
# mcap-cpp's default chunk size, which rosbag2 keeps.
DEFAULT_CHUNK_SIZE = 768 * 1024
DEFAULT_FLUSH_PERIOD_S = 0.5
# The chunk compression names MCAP records carry ('' = none).
_COMPRESSIONS = {None: '', 'none': '', 'zstd': 'zstd', 'lz4': 'lz4'}
# RMW_DURATION_INFINITE as rosbag2 writes it: {sec: INT64_MAX // 1e9, nsec: INT64_MAX % 1e9}.
INFINITE_DURATION = {'sec': 9223372036, 'nsec': 854775807}


class BagWriterError(ValueError):
    """A bag cannot be written as asked (bad directory, topic, type or state)."""


def _library_name() -> str:
    try:
        mcap_version = version('mcap')
    except PackageNotFoundError:
        mcap_version = 'unknown'
    return f'softseq_ros bag writer; mcap-python/{mcap_version}'


def message_type_name(msg: Any) -> str:
    """Return ``pkg/msg/Type`` of an rclpy message object."""
    cls = type(msg)
    package, namespace = cls.__module__.split('.')[:2]
    return f'{package}/{namespace}/{cls.__name__}'


@lru_cache(maxsize=None)
def _cdr_decoder(type_name: str) -> Any:
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    store = get_typestore(Stores.EMPTY)
    store.register(get_types_from_msg(message_definition(type_name), type_name))
    return store


def serialize(msg: Any) -> bytes:
    """
    Serialize an rclpy message object to CDR bytes as they travel over DDS (needs rclpy).

    rclpy's serialize_message (Fast DDS) returns a buffer of the estimated size, which can
    end in bytes that belong to no field; strict readers (rosbags) refuse such messages, and
    a subscriber never receives them. The buffer is cut where the last field ends. The rig's
    own types skip all that through :mod:`softseq_ros.bag.cdr`.
    """
    type_name = message_type_name(msg)
    encoded = encode(msg, type_name)
    if encoded is not None:
        return encoded
    from rclpy.serialization import serialize_message
    raw = serialize_message(msg)
    store = _cdr_decoder(type_name)
    msgdef = store.get_msgdef(type_name)
    decode = msgdef.deserialize_cdr_le if raw[1] else msgdef.deserialize_cdr_be
    _, end = decode(raw[4:], 0, msgdef.cls, store)
    return bytes(raw[:4 + end])


class _IndentedDumper(yaml.SafeDumper):
    """Indent sequences inside mappings, as yaml-cpp (and so rosbag2) does."""

    def increase_indent(self, flow: bool = False, indentless: bool = False) -> None:
        """Never emit indentless sequences."""
        super().increase_indent(flow, False)


def _dump_yaml(data: Any) -> str:
    return yaml.dump(data, Dumper=_IndentedDumper, sort_keys=False, default_flow_style=False,
                     allow_unicode=True)


def qos_profile_dict(
    *, history: str = 'keep_last', depth: int = 10, reliability: str = 'reliable',
    durability: str = 'volatile', deadline: Mapping[str, int] = INFINITE_DURATION,
    lifespan: Mapping[str, int] = INFINITE_DURATION, liveliness: str = 'automatic',
    liveliness_lease_duration: Mapping[str, int] = INFINITE_DURATION,
    avoid_ros_namespace_conventions: bool = False,
) -> dict[str, Any]:
    """
    Build one offered QoS profile in rosbag2's version-9 form (policies by name).

    Names are those of rmw's qos_string_conversions: history keep_last/keep_all,
    reliability reliable/best_effort, durability volatile/transient_local, liveliness
    automatic/manual_by_topic (or system_default/unknown). Durations are {sec, nsec}.
    """
    return {
        'history': history, 'depth': int(depth), 'reliability': reliability,
        'durability': durability,
        'deadline': {'sec': int(deadline['sec']), 'nsec': int(deadline['nsec'])},
        'lifespan': {'sec': int(lifespan['sec']), 'nsec': int(lifespan['nsec'])},
        'liveliness': liveliness,
        'liveliness_lease_duration': {'sec': int(liveliness_lease_duration['sec']),
                                      'nsec': int(liveliness_lease_duration['nsec'])},
        'avoid_ros_namespace_conventions': bool(avoid_ros_namespace_conventions),
    }


def offered_qos_yaml(profiles: Sequence[Mapping[str, Any]]) -> str:
    """Serialize offered QoS profiles to the YAML string rosbag2 puts in channel metadata."""
    if not profiles:
        return ''
    return _dump_yaml([dict(profile) for profile in profiles]).rstrip('\n')


def _parse_qos_yaml(topic: str, qos_profiles_yaml: str) -> list[Any]:
    if not qos_profiles_yaml.strip():
        return []
    try:
        profiles = yaml.safe_load(qos_profiles_yaml)
    except yaml.YAMLError as err:
        raise BagWriterError(
            f'topic {topic}: offered_qos_profiles is not valid YAML: {err}') from None
    if not isinstance(profiles, list):
        raise BagWriterError(
            f'topic {topic}: offered_qos_profiles must be a YAML sequence of profiles')
    return profiles


@dataclass
class _Topic:
    name: str
    type_name: str
    channel_id: int
    qos_profiles_yaml: str
    type_hash: str


class BagWriter:
    """
    Write raw CDR messages into a new rosbag2 MCAP bag directory.

    Use as a context manager; :meth:`close` (also on an exception) writes the summary, the
    ``rosbag2`` metadata record and ``metadata.yaml``. Thread safe: the recorder's callbacks
    and the periodic flush may run on different threads. No rclpy needed.
    """

    def __init__(self, directory: str | os.PathLike, *, chunk_size: int = DEFAULT_CHUNK_SIZE,
                 compression: str | None = 'zstd',
                 flush_period_s: float | None = DEFAULT_FLUSH_PERIOD_S) -> None:
        """
        Create ``directory`` and open ``<directory name>_0.mcap`` in it for writing.

        The directory must not exist or be empty. ``compression`` is applied per chunk
        ('zstd', 'lz4' or None). ``flush_period_s`` bounds how long a written message may stay
        in memory before it is on disk; None disables the periodic flush.
        """
        self._init(Path(directory), None, chunk_size=chunk_size, compression=compression,
                   flush_period_s=flush_period_s)

    def _init(self, directory: Path, file_name: str | None, *, chunk_size: int,
              compression: str | None, flush_period_s: float | None) -> None:
        if compression not in _COMPRESSIONS:
            raise BagWriterError(
                f'compression {compression!r}: expected one of zstd, lz4 or None')
        if chunk_size <= 0:
            raise BagWriterError(f'chunk_size {chunk_size}: must be a positive byte count')
        if flush_period_s is not None and not flush_period_s > 0:
            raise BagWriterError(f'flush_period_s {flush_period_s}: must be positive or None')
        if file_name is None:
            if directory.exists() and (not directory.is_dir() or any(directory.iterdir())):
                raise BagWriterError(
                    f'{directory}: bag directory already exists and is not empty')
            file_name = f'{directory.name}_0.mcap'
        directory.mkdir(parents=True, exist_ok=True)
        self._directory = directory
        self._mcap_path = directory / file_name
        self._lock = threading.RLock()
        self._topics: dict[str, _Topic] = {}
        self._schema_ids: dict[str, int] = {}
        self._closed = False
        self._unflushed = False
        self._last_flush = time.monotonic()
        self._flush_period_s = flush_period_s
        self._file: BinaryIO = open(self._mcap_path, 'xb')
        self._writer = ChunkedMcapWriter(self._file, chunk_size=chunk_size,
                                         compression=_COMPRESSIONS[compression])
        self._writer.start(profile=PROFILE, library=_library_name())
        self._stop = threading.Event()
        self._flusher: threading.Thread | None = None
        if flush_period_s is not None:
            self._flusher = threading.Thread(target=self._flush_periodically,
                                             name='bag-flusher', daemon=True)
            self._flusher.start()

    @classmethod
    def _for_recovery(cls, directory: Path, file_name: str) -> 'BagWriter':
        writer = cls.__new__(cls)
        writer._init(directory, file_name, chunk_size=DEFAULT_CHUNK_SIZE, compression='zstd',
                     flush_period_s=None)
        return writer

    @property
    def directory(self) -> Path:
        """The bag directory."""
        return self._directory

    @property
    def mcap_path(self) -> Path:
        """The .mcap file inside the bag directory."""
        return self._mcap_path

    @property
    def message_count(self) -> int:
        """Messages written so far."""
        return self._writer.message_count

    @property
    def topics(self) -> dict[str, str]:
        """Registered topics and their types."""
        return {name: topic.type_name for name, topic in self._topics.items()}

    @property
    def closed(self) -> bool:
        """True once :meth:`close` has run."""
        return self._closed

    def __enter__(self) -> 'BagWriter':
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def add_topic(self, name: str, type_name: str, qos_profiles_yaml: str = '') -> None:
        """
        Register a topic of type ``pkg/msg/Type`` before writing to it.

        The schema text and type hash come from the installed message package.
        ``qos_profiles_yaml`` is the publishers' offered QoS as rosbag2 serializes it (see
        :func:`offered_qos_yaml`); empty when unknown. Registering a topic again with the same
        type does nothing; with another type it is an error.
        """
        type_name = canonical_type_name(type_name)
        with self._lock:
            if self._check_existing(name, type_name):
                return
            self._add_channel(name, type_name, message_definition(type_name),
                              qos_profiles_yaml, type_description_hash(type_name) or '')

    def _check_existing(self, name: str, type_name: str) -> bool:
        self._check_open()
        if not name.startswith('/'):
            raise BagWriterError(f'topic {name!r}: expected an absolute name such as /{name}')
        existing = self._topics.get(name)
        if existing is None:
            return False
        if existing.type_name != type_name:
            raise BagWriterError(
                f'topic {name}: already registered with type {existing.type_name}, '
                f'not {type_name}')
        return True

    def _add_channel(self, name: str, type_name: str, schema_text: str,
                     qos_profiles_yaml: str, type_hash: str) -> None:
        _parse_qos_yaml(name, qos_profiles_yaml)
        schema_id = self._schema_ids.get(type_name)
        if schema_id is None:
            schema_id = self._writer.register_schema(
                name=type_name, encoding=SCHEMA_ENCODING, data=schema_text.encode('utf-8'))
            self._schema_ids[type_name] = schema_id
        metadata = {'offered_qos_profiles': qos_profiles_yaml}
        if type_hash:
            metadata['topic_type_hash'] = type_hash
        channel_id = self._writer.register_channel(
            topic=name, message_encoding=MESSAGE_ENCODING, schema_id=schema_id,
            metadata=metadata)
        self._topics[name] = _Topic(name, type_name, channel_id, qos_profiles_yaml, type_hash)

    def write(self, topic: str, cdr_bytes: bytes, log_time_ns: int,
              publish_time_ns: int | None = None) -> None:
        """
        Append one serialized message to a registered topic.

        ``log_time_ns`` is the receive time, ``publish_time_ns`` the send time (defaults to
        the receive time), both in nanoseconds since the epoch of the clock in use.
        """
        with self._lock:
            if self._closed:
                self._check_open()
            entry = self._topics.get(topic)
            if entry is None:
                raise BagWriterError(f'topic {topic}: not registered; call add_topic first')
            if log_time_ns < 0:
                raise BagWriterError(f'topic {topic}: negative log time {log_time_ns} ns')
            self._writer.add_message(
                entry.channel_id, cdr_bytes, log_time_ns,
                log_time_ns if publish_time_ns is None else publish_time_ns)
            if self._flush_period_s is not None:
                self._unflushed = True
                if time.monotonic() - self._last_flush >= self._flush_period_s:
                    self._flush_locked()

    def appender(self, topic: str) -> Callable[[bytes, int, int], None]:
        """
        A function ``(cdr_bytes, log_time_ns, publish_time_ns)`` that writes to ``topic``.

        For a bag written from one thread without the periodic flush (``flush_period_s``
        None), such as a batch run's: it skips the lock and the checks of :meth:`write`,
        which are a third of a message's cost there.
        """
        with self._lock:
            self._check_open()
            if self._flush_period_s is not None:
                raise BagWriterError('appender: only for a writer without the periodic flush '
                                     '(flush_period_s=None)')
            entry = self._topics.get(topic)
            if entry is None:
                raise BagWriterError(f'topic {topic}: not registered; call add_topic first')
            return partial(self._writer.add_message, entry.channel_id)

    def flush(self) -> None:
        """Close the chunk in progress and force everything written so far onto the disk."""
        with self._lock:
            self._check_open()
            self._flush_locked()

    def _flush_locked(self) -> None:
        self._writer.flush()
        os.fsync(self._file.fileno())
        self._unflushed = False
        self._last_flush = time.monotonic()

    def _flush_periodically(self) -> None:
        assert self._flush_period_s is not None
        while not self._stop.wait(self._flush_period_s / 2):
            with self._lock:
                if (not self._closed and self._unflushed
                        and time.monotonic() - self._last_flush >= self._flush_period_s / 2):
                    self._flush_locked()

    def _check_open(self) -> None:
        if self._closed:
            raise BagWriterError(f'{self._mcap_path}: bag is already closed')

    def bag_information(self) -> dict[str, Any]:
        """Return the ``rosbag2_bagfile_information`` content for the messages so far."""
        time_range = self._writer.time_range
        start, duration = (time_range[0], time_range[1] - time_range[0]) if time_range \
            else (0, 0)
        return bag_information(
            file_name=self._mcap_path.name, start_ns=start, duration_ns=duration,
            topics=[(t.name, t.type_name, t.qos_profiles_yaml, t.type_hash,
                     self._writer.channel_message_count(t.channel_id))
                    for t in self._topics.values()])

    def close(self) -> None:
        """Finish the MCAP file (summary and ``rosbag2`` record) and write metadata.yaml."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._stop.set()
            information = self.bag_information()
            serialized = _dump_yaml(information)
            self._writer.add_metadata('rosbag2', {'serialized_metadata': serialized})
            self._writer.finish()
            self._file.flush()
            os.fsync(self._file.fileno())
            self._file.close()
            write_metadata_yaml(self._directory, information)
        if self._flusher is not None and self._flusher is not threading.current_thread():
            self._flusher.join()


def bag_information(*, file_name: str, start_ns: int, duration_ns: int,
                    topics: Sequence[tuple[str, str, str, str, int]]) -> dict[str, Any]:
    """
    Build rosbag2's ``rosbag2_bagfile_information`` (version 9) for a one-file bag.

    ``topics`` holds (name, type, offered QoS YAML string, type hash, message count) rows.
    Field order follows rosbag2_storage/yaml.hpp.
    """
    message_count = sum(row[4] for row in topics)
    return {
        'version': METADATA_VERSION,
        'storage_identifier': STORAGE_IDENTIFIER,
        'duration': {'nanoseconds': int(duration_ns)},
        'starting_time': {'nanoseconds_since_epoch': int(start_ns)},
        'message_count': message_count,
        'topics_with_message_count': [
            {'topic_metadata': {
                'name': name, 'type': type_name, 'serialization_format': MESSAGE_ENCODING,
                'offered_qos_profiles': _parse_qos_yaml(name, qos_yaml),
                'type_description_hash': type_hash},
             'message_count': count}
            for name, type_name, qos_yaml, type_hash, count in topics],
        'compression_format': '',
        'compression_mode': '',
        'relative_file_paths': [file_name],
        'files': [{'path': file_name,
                   'starting_time': {'nanoseconds_since_epoch': int(start_ns)},
                   'duration': {'nanoseconds': int(duration_ns)},
                   'message_count': message_count}],
        'custom_data': None,
        'ros_distro': os.environ.get('ROS_DISTRO') or 'jazzy',
    }


def write_metadata_yaml(directory: str | os.PathLike, information: Mapping[str, Any]) -> Path:
    """Write ``metadata.yaml`` atomically (temporary file, fsync, rename) and return its path."""
    directory = Path(directory)
    path = directory / METADATA_FILE
    temporary = directory / (METADATA_FILE + '.tmp')
    with open(temporary, 'w', encoding='utf-8') as stream:
        stream.write(_dump_yaml({'rosbag2_bagfile_information': dict(information)}))
        stream.flush()
        os.fsync(stream.fileno())
    temporary.replace(path)
    directory_fd = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(directory_fd)
    finally:
        os.close(directory_fd)
    return path


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
    writer = BagWriter._for_recovery(directory, path.name)
    try:
        for record in _intact_records(damaged, outcome):
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel) and record.schema_id in schemas:
                if record.topic not in writer._topics:
                    schema = schemas[record.schema_id]
                    writer._add_channel(
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
