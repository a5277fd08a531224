"""
Write MCAP bags in the layout of rosbag2 (ROS 2 Jazzy).

A bag is a directory holding one ``<name>_0.mcap`` file and a ``metadata.yaml`` beside it,
as ``ros2 bag record -s mcap`` leaves it; split by size or duration (``max_file_size_bytes``,
``max_file_duration_s``, as ``ros2 bag record --max-bag-size/--max-bag-duration``) it holds
``<name>_0.mcap``, ``<name>_1.mcap``, ..., each a complete MCAP file with every schema and
channel of the bag so far, all listed in ``metadata.yaml`` (``relative_file_paths`` and
``files``, each with its start, duration and message count). What is matched (rosbag2 Jazzy,
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
SIGKILL everything written more than about that long ago is on disk;
:func:`softseq_ros.bag.recovery.recover` rebuilds a complete bag from such a truncated file.
Message and QoS forms (CDR bytes, offered QoS, rosbag2's YAML) live in
:mod:`softseq_ros.bag.forms`.

A bag in use: the writer holds a POSIX record lock (``fcntl.lockf``) on its .mcap file from
creation to close. The kernel drops it when the writer's process ends, however it ends, so a
killed recording is recoverable at once, while :func:`softseq_ros.bag.recovery.recover` refuses
a file whose lock is held (:func:`lock_state`) instead of moving it away under a live writer.
"""

from dataclasses import dataclass
import errno
from functools import partial
from importlib.metadata import PackageNotFoundError, version
import os
from pathlib import Path
import threading
import time
from typing import Any, BinaryIO, Callable, Mapping, Sequence

from softseq_ros.bag.layout import METADATA_FILE
from softseq_ros.errors import UserError

from .forms import QosFormError, dump_yaml, parse_qos_yaml
from .mcap_file import ChunkedMcapWriter
from .msgdefs import canonical_type_name, message_definition, type_description_hash

try:
    import fcntl
except ImportError:  # Windows has no fcntl: bags there are written without a lock
    fcntl = None  # type: ignore[assignment]

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


class BagWriterError(UserError):
    """A bag cannot be written as asked (bad directory, topic, type or state)."""


def _library_name() -> str:
    try:
        mcap_version = version('mcap')
    except PackageNotFoundError:
        mcap_version = 'unknown'
    return f'softseq_ros bag writer; mcap-python/{mcap_version}'


@dataclass
class _Topic:
    name: str
    type_name: str
    channel_id: int
    qos_profiles_yaml: str
    type_hash: str
    earlier_count: int = 0      # messages in the bag's files closed before the current one


@dataclass(frozen=True)
class _ClosedFile:
    name: str
    start_ns: int
    duration_ns: int
    message_count: int


class BagWriter:
    """
    Write raw CDR messages into a new rosbag2 MCAP bag directory.

    Use as a context manager; :meth:`close` (also on an exception) writes the summary, the
    ``rosbag2`` metadata record and ``metadata.yaml``. Thread safe: the recorder's callbacks
    and the periodic flush may run on different threads. No rclpy needed.
    """

    def __init__(self, directory: str | os.PathLike, *, chunk_size: int = DEFAULT_CHUNK_SIZE,
                 compression: str | None = 'zstd',
                 flush_period_s: float | None = DEFAULT_FLUSH_PERIOD_S,
                 max_file_size_bytes: int = 0, max_file_duration_s: float = 0.0) -> None:
        """
        Create ``directory`` and open ``<directory name>_0.mcap`` in it for writing.

        The directory must not exist or be empty. ``compression`` is applied per chunk
        ('zstd', 'lz4' or None). ``flush_period_s`` bounds how long a written message may stay
        in memory before it is on disk; None disables the periodic flush. A message that
        finds the current file at ``max_file_size_bytes`` or more on disk, or
        ``max_file_duration_s`` or more of log time after the file's first message, goes
        into the next file (0: no limit). Files grow by whole chunks, so a file ends at the
        first chunk boundary past its size limit, as rosbag2's MCAP files do.
        """
        if not (isinstance(max_file_size_bytes, int) and max_file_size_bytes >= 0):
            raise BagWriterError(f'max_file_size_bytes {max_file_size_bytes!r}: must be a byte '
                                 'count >= 0 (0: no limit)')
        if not (0.0 <= max_file_duration_s < float('inf')):
            raise BagWriterError(f'max_file_duration_s {max_file_duration_s!r}: must be a '
                                 'finite number of seconds >= 0 (0: no limit)')
        self._max_file_size = max_file_size_bytes
        self._max_file_duration_ns = int(round(max_file_duration_s * 1e9))
        self._init(Path(directory), None, chunk_size=chunk_size, compression=compression,
                   flush_period_s=flush_period_s)

    def _init(self, directory: Path, file_name: str | None, *, chunk_size: int,
              compression: str | None, flush_period_s: float | None,
              final_name: str | None = None) -> None:
        if compression not in _COMPRESSIONS:
            raise BagWriterError(
                f'compression {compression!r}: expected one of zstd, lz4 or None')
        if chunk_size <= 0:
            raise BagWriterError(f'chunk_size {chunk_size}: must be a positive byte count')
        if flush_period_s is not None and not flush_period_s > 0:
            raise BagWriterError(f'flush_period_s {flush_period_s}: must be positive or None')
        if not hasattr(self, '_max_file_size'):
            self._max_file_size, self._max_file_duration_ns = 0, 0
        self._chunk_size = chunk_size
        self._compression = compression
        self._closed_files: list[_ClosedFile] = []
        self._file_start_ns: int | None = None
        self._schema_texts: dict[str, str] = {}
        try:
            if file_name is None:
                if directory.exists() and (not directory.is_dir() or any(directory.iterdir())):
                    raise BagWriterError(
                        f'{directory}: bag directory already exists and is not empty')
                file_name = f'{directory.name}_0.mcap'
            directory.mkdir(parents=True, exist_ok=True)
            self._file: BinaryIO = open(directory / file_name, 'xb')
        except OSError as err:
            raise BagWriterError(f'{directory}: cannot create the bag '
                                 f'({err.strerror or err})') from None
        _lock(self._file, directory / file_name)
        self._directory = directory
        self._mcap_path = directory / file_name
        # The name the file will have in the bag (a recovery writes a temporary file first);
        # the metadata names it, and metadata.yaml is left to whoever renames the file.
        self._final_name = final_name or file_name
        self._writes_metadata_yaml = final_name is None
        self._lock = threading.RLock()
        self._topics: dict[str, _Topic] = {}
        self._schema_ids: dict[str, int] = {}
        self._closed = False
        self._unflushed = False
        self._last_flush = time.monotonic()
        self._flush_period_s = flush_period_s
        self._failure: str | None = None
        self._writer = self._new_mcap()
        self._stop = threading.Event()
        self._flusher: threading.Thread | None = None
        if flush_period_s is not None:
            self._flusher = threading.Thread(target=self._flush_periodically,
                                             name='bag-flusher', daemon=True)
            self._flusher.start()

    def _new_mcap(self) -> ChunkedMcapWriter:
        writer = ChunkedMcapWriter(self._file, chunk_size=self._chunk_size,
                                   compression=_COMPRESSIONS[self._compression])
        writer.start(profile=PROFILE, library=_library_name())
        return writer

    @classmethod
    def for_recovery(cls, directory: Path, file_name: str, final_name: str) -> 'BagWriter':
        """
        A writer of a temporary file that becomes the bag file ``final_name`` once renamed.

        For softseq_ros.bag.recovery: in an existing bag directory, and its close writes no
        metadata.yaml (the recovery does, after the rename).
        """
        writer = cls.__new__(cls)
        writer._init(directory, file_name, chunk_size=DEFAULT_CHUNK_SIZE, compression='zstd',
                     flush_period_s=None, final_name=final_name)
        return writer

    @property
    def directory(self) -> Path:
        """The bag directory."""
        return self._directory

    @property
    def mcap_path(self) -> Path:
        """The .mcap file being written (the last of a split bag)."""
        return self._mcap_path

    @property
    def file_names(self) -> list[str]:
        """The bag's .mcap files so far, in order (one unless the bag was split)."""
        return [f.name for f in self._closed_files] + [self._final_name]

    @property
    def message_count(self) -> int:
        """Messages written so far."""
        return sum(f.message_count for f in self._closed_files) + self._writer.message_count

    @property
    def topic_message_counts(self) -> dict[str, int]:
        """Messages written so far per registered topic, over every file of a split bag."""
        return {name: topic.earlier_count + self._writer.channel_message_count(topic.channel_id)
                for name, topic in self._topics.items()}

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

    def add_topic_with_definition(self, name: str, type_name: str, definition: str,
                                  qos_profiles_yaml: str = '', type_hash: str = '') -> None:
        """Register a topic whose definition text comes with it (a bag being recovered)."""
        with self._lock:
            if self._check_existing(name, type_name):
                return
            self._add_channel(name, type_name, definition, qos_profiles_yaml, type_hash)

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
        _qos_profiles(name, qos_profiles_yaml)
        schema_id = self._schema_ids.get(type_name)
        if schema_id is None:
            schema_id = self._writer.register_schema(
                name=type_name, encoding=SCHEMA_ENCODING, data=schema_text.encode('utf-8'))
            self._schema_ids[type_name] = schema_id
        self._schema_texts[type_name] = schema_text
        topic = _Topic(name, type_name, 0, qos_profiles_yaml, type_hash)
        topic.channel_id = self._register_channel(topic, schema_id)
        self._topics[name] = topic

    def _register_channel(self, topic: _Topic, schema_id: int) -> int:
        metadata = {'offered_qos_profiles': topic.qos_profiles_yaml}
        if topic.type_hash:
            metadata['topic_type_hash'] = topic.type_hash
        return self._writer.register_channel(
            topic=topic.name, message_encoding=MESSAGE_ENCODING, schema_id=schema_id,
            metadata=metadata)

    def _split_due(self, log_time_ns: int) -> bool:
        start = self._file_start_ns
        if start is None:
            return False
        if self._max_file_duration_ns and log_time_ns - start >= self._max_file_duration_ns:
            return True
        return bool(self._max_file_size) and \
            self._writer.bytes_written >= self._max_file_size

    def _split_locked(self) -> None:
        """Finish the current file and go on in the next one, with every schema and channel."""
        time_range = self._writer.time_range
        start, end = time_range if time_range else (0, 0)
        closed = _ClosedFile(self._final_name, start, end - start, self._writer.message_count)
        counts = {name: self._writer.channel_message_count(topic.channel_id)
                  for name, topic in self._topics.items()}
        self._finish_file_locked()
        self._file.close()
        self._closed_files.append(closed)
        for name, topic in self._topics.items():
            topic.earlier_count += counts[name]
        index = len(self._closed_files)
        file_name = f'{self._directory.name}_{index}.mcap'
        self._file = open(self._directory / file_name, 'xb')
        _lock(self._file, self._directory / file_name)
        self._mcap_path = self._directory / file_name
        self._final_name = file_name
        self._file_start_ns = None
        self._writer = self._new_mcap()
        self._schema_ids = {}
        for topic in self._topics.values():
            schema_id = self._schema_ids.get(topic.type_name)
            if schema_id is None:
                schema_id = self._writer.register_schema(
                    name=topic.type_name, encoding=SCHEMA_ENCODING,
                    data=self._schema_texts[topic.type_name].encode('utf-8'))
                self._schema_ids[topic.type_name] = schema_id
            topic.channel_id = self._register_channel(topic, schema_id)
        self._sync_directory_locked()

    def _sync_directory_locked(self) -> None:
        descriptor = os.open(self._directory, os.O_RDONLY)
        try:
            os.fsync(descriptor)
        finally:
            os.close(descriptor)

    def _finish_file_locked(self) -> None:
        """The current file's summary and ``rosbag2`` record, on disk."""
        information = self.bag_information()
        self._writer.add_metadata('rosbag2', {'serialized_metadata': dump_yaml(information)})
        self._writer.finish()
        self._file.flush()
        os.fsync(self._file.fileno())

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
            if self._failure is not None:
                raise BagWriterError(self._failure)
            try:
                if (self._max_file_size or self._max_file_duration_ns) \
                        and self._split_due(log_time_ns):
                    self._split_locked()
                if self._file_start_ns is None or log_time_ns < self._file_start_ns:
                    self._file_start_ns = log_time_ns
                self._writer.add_message(
                    entry.channel_id, cdr_bytes, log_time_ns,
                    log_time_ns if publish_time_ns is None else publish_time_ns)
                if self._flush_period_s is not None:
                    self._unflushed = True
                    if time.monotonic() - self._last_flush >= self._flush_period_s:
                        self._flush_locked()
            except OSError as err:
                raise BagWriterError(self._fail(err)) from None

    @property
    def failure(self) -> str | None:
        """Why the bag could not be written on (a full disk, say), or None."""
        return self._failure

    def _fail(self, err: OSError) -> str:
        # What is on disk stays readable after a recovery; nothing more is written.
        if self._failure is None:
            self._failure = (f'{self._mcap_path}: cannot write ({err.strerror or err}); what '
                             'was flushed before is on disk: run softseq recover '
                             f'{self._directory} once there is room')
        return self._failure

    def appender(self, topic: str) -> Callable[[bytes, int, int], None]:
        """
        A function ``(cdr_bytes, log_time_ns, publish_time_ns)`` that writes to ``topic``.

        For a bag written from one thread without the periodic flush (``flush_period_s``
        None), such as a batch run's: it skips the lock and the checks of :meth:`write`,
        which are a third of a message's cost there.
        """
        with self._lock:
            self._check_open()
            if self._flush_period_s is not None or self._max_file_size \
                    or self._max_file_duration_ns:
                raise BagWriterError('appender: only for a writer without the periodic flush '
                                     '(flush_period_s=None) and without splitting')
            entry = self._topics.get(topic)
            if entry is None:
                raise BagWriterError(f'topic {topic}: not registered; call add_topic first')
            return partial(self._writer.add_message, entry.channel_id)

    def row_writer(self) -> tuple[dict[str, int], Callable[[list], None]]:
        """
        The channel id of every registered topic and a function that adds row blocks.

        For the same writers as :meth:`appender`: ``add_rows(blocks)`` takes
        :class:`~softseq_ros.bag.mcap_file.RowBlock` s of those channels' messages, records
        built by the caller, and writes them as one message after another would be written.
        """
        with self._lock:
            self._check_open()
            if self._flush_period_s is not None or self._max_file_size \
                    or self._max_file_duration_ns:
                raise BagWriterError('row_writer: only for a writer without the periodic flush '
                                     '(flush_period_s=None) and without splitting')
            return ({name: topic.channel_id for name, topic in self._topics.items()},
                    self._writer.add_rows)

    def flush(self) -> None:
        """Close the chunk in progress and force everything written so far onto the disk."""
        with self._lock:
            self._check_open()
            if self._failure is not None:
                raise BagWriterError(self._failure)
            try:
                self._flush_locked()
            except OSError as err:
                raise BagWriterError(self._fail(err)) from None

    def _flush_locked(self) -> None:
        self._writer.flush()
        os.fsync(self._file.fileno())
        self._unflushed = False
        self._last_flush = time.monotonic()

    def _flush_periodically(self) -> None:
        assert self._flush_period_s is not None
        while not self._stop.wait(self._flush_period_s / 2):
            with self._lock:
                if (not self._closed and self._failure is None and self._unflushed
                        and time.monotonic() - self._last_flush >= self._flush_period_s / 2):
                    try:
                        self._flush_locked()
                    except OSError as err:
                        self._fail(err)   # the next write or the close reports it

    def _check_open(self) -> None:
        if self._closed:
            raise BagWriterError(f'{self._mcap_path}: bag is already closed')

    def bag_information(self) -> dict[str, Any]:
        """Return the ``rosbag2_bagfile_information`` content for the messages so far."""
        time_range = self._writer.time_range
        start, duration = (time_range[0], time_range[1] - time_range[0]) if time_range \
            else (0, 0)
        files = [(f.name, f.start_ns, f.duration_ns, f.message_count)
                 for f in self._closed_files]
        files.append((self._final_name, start, duration, self._writer.message_count))
        spans = [(s, s + d) for _, s, d, count in files if count]
        first = min((s for s, _ in spans), default=0)
        last = max((e for _, e in spans), default=0)
        counts = self.topic_message_counts
        return bag_information(
            file_name=self._final_name, start_ns=first, duration_ns=last - first,
            topics=[(t.name, t.type_name, t.qos_profiles_yaml, t.type_hash, counts[t.name])
                    for t in self._topics.values()],
            files=files)

    def close(self) -> None:
        """
        Finish the MCAP file (summary and ``rosbag2`` record) and write metadata.yaml.

        A bag that could not be written on (:attr:`failure`) is closed as it is on disk, for
        ``softseq recover``; a failure while finishing raises BagWriterError saying so.
        """
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._stop.set()
            try:
                if self._failure is None:
                    self._finish_file_locked()
                    if self._writes_metadata_yaml:
                        write_metadata_yaml(self._directory, self.bag_information())
            except OSError as err:
                self._fail(err)
            finally:
                try:
                    self._file.close()
                except OSError as err:
                    self._fail(err)
        if self._flusher is not None and self._flusher is not threading.current_thread():
            self._flusher.join()
        if self._failure is not None:
            raise BagWriterError(self._failure)


def _lock(stream: BinaryIO, path: Path) -> None:
    """Mark ``path`` as being written, until ``stream`` is closed or its process ends."""
    if fcntl is None:
        return
    try:
        fcntl.lockf(stream.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as err:
        stream.close()
        raise BagWriterError(f'{path}: cannot lock the bag file for writing '
                             f'({err.strerror or err})') from None


def lock_state(path: str | os.PathLike) -> str:
    """
    'locked' while a writer (in another process) holds ``path``'s lock, else 'free'.

    'unknown' where locks cannot be tested (no fcntl, a file system without them). A POSIX
    lock does not conflict with its own process: a writer in the caller's own process is not
    seen, and (POSIX semantics) closing this test's descriptor drops that writer's lock.
    """
    if fcntl is None:
        return 'unknown'
    try:
        descriptor = os.open(path, os.O_RDONLY)
    except OSError:
        return 'unknown'
    try:
        fcntl.lockf(descriptor, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except OSError as err:
        return 'locked' if err.errno in (errno.EACCES, errno.EAGAIN) else 'unknown'
    else:
        fcntl.lockf(descriptor, fcntl.LOCK_UN)
        return 'free'
    finally:
        os.close(descriptor)


def _qos_profiles(topic: str, qos_profiles_yaml: str) -> list[Any]:
    try:
        return parse_qos_yaml(topic, qos_profiles_yaml)
    except QosFormError as err:
        raise BagWriterError(str(err)) from None


def bag_information(*, file_name: str, start_ns: int, duration_ns: int,
                    topics: Sequence[tuple[str, str, str, str, int]],
                    files: Sequence[tuple[str, int, int, int]] | None = None
                    ) -> dict[str, Any]:
    """
    Build rosbag2's ``rosbag2_bagfile_information`` (version 9).

    ``topics`` holds (name, type, offered QoS YAML string, type hash, message count) rows;
    ``files`` the (name, start, duration, message count) of each file of a split bag (None:
    the one file ``file_name``, spanning the bag). Field order follows rosbag2_storage/yaml.hpp.
    """
    message_count = sum(row[4] for row in topics)
    if files is None:
        files = [(file_name, start_ns, duration_ns, message_count)]
    return {
        'version': METADATA_VERSION,
        'storage_identifier': STORAGE_IDENTIFIER,
        'duration': {'nanoseconds': int(duration_ns)},
        'starting_time': {'nanoseconds_since_epoch': int(start_ns)},
        'message_count': message_count,
        'topics_with_message_count': [
            {'topic_metadata': {
                'name': name, 'type': type_name, 'serialization_format': MESSAGE_ENCODING,
                'offered_qos_profiles': _qos_profiles(name, qos_yaml),
                'type_description_hash': type_hash},
             'message_count': count}
            for name, type_name, qos_yaml, type_hash, count in topics],
        'compression_format': '',
        'compression_mode': '',
        'relative_file_paths': [name for name, _, _, _ in files],
        'files': [{'path': name,
                   'starting_time': {'nanoseconds_since_epoch': int(start)},
                   'duration': {'nanoseconds': int(duration)},
                   'message_count': int(count)}
                  for name, start, duration, count in files],
        'custom_data': None,
        'ros_distro': os.environ.get('ROS_DISTRO') or 'jazzy',
    }


def write_metadata_yaml(directory: str | os.PathLike, information: Mapping[str, Any]) -> Path:
    """Write ``metadata.yaml`` atomically (temporary file, fsync, rename) and return its path."""
    directory = Path(directory)
    path = directory / METADATA_FILE
    temporary = directory / (METADATA_FILE + '.tmp')
    with open(temporary, 'w', encoding='utf-8') as stream:
        stream.write(dump_yaml({'rosbag2_bagfile_information': dict(information)}))
        stream.flush()
        os.fsync(stream.fileno())
    temporary.replace(path)
    directory_fd = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(directory_fd)
    finally:
        os.close(directory_fd)
    return path
