"""Bags written by BagWriter read back with two independent readers, and crash recovery."""

import os
from pathlib import Path
import shutil
import signal
import subprocess
import sys
import textwrap
import time

from geometry_msgs.msg import PoseStamped
from mcap.reader import make_reader
from mcap.stream_reader import StreamReader
from mcap_ros2.decoder import DecoderFactory
import pytest
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, String
import yaml

from softseq_ros.bag.forms import offered_qos_yaml, qos_profile_dict, serialize
from softseq_ros.bag.msgdefs import SEPARATOR, MessageDefinitionError, message_definition
from softseq_ros.bag.reader import BagReadError, bag_summary, read_bag
from softseq_ros.bag.recovery import recover
from softseq_ros.bag.writer import BagWriter, BagWriterError

REPO = Path(__file__).resolve().parents[1]
T0 = 1_700_000_000_000_000_000  # an arbitrary epoch time [ns]
RELIABLE_LATCHED = qos_profile_dict(history='keep_last', depth=1, reliability='reliable',
                                    durability='transient_local')


def _pose(i: int) -> PoseStamped:
    msg = PoseStamped()
    msg.header.stamp.sec = 100 + i
    msg.header.stamp.nanosec = 250 * i
    msg.header.frame_id = 'actuator_base'
    msg.pose.position.x = 0.001 * i
    msg.pose.position.z = -0.222
    msg.pose.orientation.w = 1.0
    return msg


def _joints(i: int) -> JointState:
    msg = JointState()
    msg.header.frame_id = 'rig'
    msg.name = ['bottom', 'top']
    msg.position = [0.1 * i, -0.2 * i]
    msg.effort = [1.5e3, 2.5e3]
    return msg


# topic -> (type, list of (log_time_ns, publish_time_ns, message))
SAMPLE = {
    '/pump/injected_volume': ('std_msgs/msg/Float64', [
        (T0 + 10_000_000 * i, T0 + 10_000_000 * i - 1000, Float64(data=5e-7 * i))
        for i in range(25)]),
    '/rig/phase': ('std_msgs/msg/String', [
        (T0 + 5, T0 + 4, String(data='inflating')), (T0 + 200_000_000, T0 + 199_000_000,
                                                     String(data='deflating'))]),
    '/camera/tip_pose': ('geometry_msgs/msg/PoseStamped', [
        (T0 + 33_000_000 * i + 7, T0 + 33_000_000 * i, _pose(i)) for i in range(6)]),
    '/actuator/joints': ('sensor_msgs/msg/JointState', [
        (T0 + 50_000_000 * i + 3, T0 + 50_000_000 * i + 1, _joints(i)) for i in range(4)]),
}


def _write_sample(directory: Path, compression: str | None = 'zstd') -> Path:
    with BagWriter(directory, compression=compression) as bag:
        for topic, (type_name, _) in SAMPLE.items():
            qos = offered_qos_yaml([RELIABLE_LATCHED]) if topic == '/rig/phase' else ''
            bag.add_topic(topic, type_name, qos)
        rows = sorted((log, pub, topic, msg) for topic, (_, entries) in SAMPLE.items()
                      for log, pub, msg in entries)
        for log, pub, topic, msg in rows:
            bag.write(topic, serialize(msg), log, pub)
    return directory


def _expected_fields(topic: str, msg: object) -> tuple:
    """Reduce a message to comparable plain values (works for rclpy, rosbags and mcap_ros2)."""
    if topic == '/pump/injected_volume' or topic == '/rig/phase':
        return (msg.data,)
    if topic == '/camera/tip_pose':
        return (msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id,
                msg.pose.position.x, msg.pose.position.z, msg.pose.orientation.w)
    return (msg.header.frame_id, list(msg.name), [float(x) for x in msg.position],
            [float(x) for x in msg.effort], list(msg.velocity))


def _expected_rows() -> list[tuple]:
    return sorted((log, topic, type_name, _expected_fields(topic, msg))
                  for topic, (type_name, entries) in SAMPLE.items() for log, _, msg in entries)


@pytest.mark.parametrize('compression', ['zstd', None])
def test_round_trip_with_rosbags_reader_and_jazzy_typestore(tmp_path, compression):
    bag = _write_sample(tmp_path / 'bag', compression)
    # The typestore comes with rosbags (Jazzy's definitions), independent of the bag's schemas.
    typestore = get_typestore(Stores.ROS2_JAZZY)
    with Reader(bag) as reader:
        assert reader.message_count == sum(len(e) for _, e in SAMPLE.values())
        assert {t: (i.msgtype, i.msgcount) for t, i in reader.topics.items()} == {
            t: (type_name, len(entries)) for t, (type_name, entries) in SAMPLE.items()}
        all_logs = [log for _, entries in SAMPLE.values() for log, _, _ in entries]
        assert reader.start_time == min(all_logs)
        for connection in reader.connections:
            # The stored RIHS01 hash equals the one rosbags computes from Jazzy's definitions.
            assert connection.digest == typestore.hash_rihs01(connection.msgtype)
            assert connection.ext.serialization_format == 'cdr'
        phase = next(c for c in reader.connections if c.topic == '/rig/phase')
        assert len(phase.ext.offered_qos_profiles) == 1
        assert phase.ext.offered_qos_profiles[0].durability.name == 'TRANSIENT_LOCAL'
        rows = sorted(
            (log, c.topic, c.msgtype,
             _expected_fields(c.topic, typestore.deserialize_cdr(raw, c.msgtype)))
            for c, log, raw in reader.messages())
    assert rows == _expected_rows()


def test_round_trip_with_mcap_ros2_reader(tmp_path):
    bag = _write_sample(tmp_path / 'bag')
    mcap_file = bag / 'bag_0.mcap'
    publish_times = {(topic, log): pub for topic, (_, entries) in SAMPLE.items()
                     for log, pub, _ in entries}
    rows = []
    with open(mcap_file, 'rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            assert channel.message_encoding == 'cdr'
            assert schema.encoding == 'ros2msg'
            assert message.publish_time == publish_times[(channel.topic, message.log_time)]
            rows.append((message.log_time, channel.topic, schema.name,
                         _expected_fields(channel.topic, decoded)))
    assert sorted(rows) == _expected_rows()


def test_any_reader_accepts_schemas_and_hashes_and_read_bag_decodes(tmp_path):
    bag = _write_sample(tmp_path / 'bag')
    # AnyReader builds its types from the stored schema text and rejects the bag when their
    # RIHS01 hash differs from the stored one: a check of the dependency blocks.
    with AnyReader([bag]) as reader:
        assert len(reader.connections) == len(SAMPLE)
    rows = sorted((log, topic, type_name, _expected_fields(topic, msg))
                  for topic, type_name, log, msg in read_bag(bag))
    assert rows == _expected_rows()
    only = list(read_bag(bag, topics=['/rig/phase']))
    assert [m.msg.data for m in only] == ['inflating', 'deflating']
    with pytest.raises(BagReadError, match='/nope'):
        list(read_bag(bag, topics=['/nope']))


def test_schema_text_holds_each_dependency_once_depth_first_sorted():
    text = message_definition('geometry_msgs/msg/PoseStamped')
    blocks = text.split('\n' + SEPARATOR + '\n')
    installed = Path(sys.prefix) / 'share' / 'geometry_msgs' / 'msg' / 'PoseStamped.msg'
    assert blocks[0] == installed.read_text()
    assert 'std_msgs/Header header' in blocks[0]
    # PoseStamped -> Pose -> (Point, Quaternion), then Header -> Time: depth first, sorted.
    assert [b.split('\n', 1)[0] for b in blocks[1:]] == [
        'MSG: geometry_msgs/Pose', 'MSG: geometry_msgs/Point', 'MSG: geometry_msgs/Quaternion',
        'MSG: std_msgs/Header', 'MSG: builtin_interfaces/Time']
    joint_text = message_definition('sensor_msgs/msg/JointState')
    assert joint_text.count('MSG: ') == 2
    assert joint_text.count('\nMSG: std_msgs/Header\n') == 1
    assert 'string[] name' in joint_text


def test_file_layout_matches_rosbag2(tmp_path):
    bag = _write_sample(tmp_path / 'bag')
    assert sorted(p.name for p in bag.iterdir()) == ['bag_0.mcap', 'metadata.yaml']
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert list(info) == [
        'version', 'storage_identifier', 'duration', 'starting_time', 'message_count',
        'topics_with_message_count', 'compression_format', 'compression_mode',
        'relative_file_paths', 'files', 'custom_data', 'ros_distro']
    assert info['version'] == 9 and info['storage_identifier'] == 'mcap'
    assert info['relative_file_paths'] == ['bag_0.mcap']
    all_logs = [log for _, entries in SAMPLE.values() for log, _, _ in entries]
    assert info['duration']['nanoseconds'] == max(all_logs) - min(all_logs)
    assert info['files'][0]['message_count'] == len(all_logs)
    phase = next(t for t in info['topics_with_message_count']
                 if t['topic_metadata']['name'] == '/rig/phase')
    assert phase['topic_metadata']['offered_qos_profiles'][0]['durability'] == 'transient_local'
    with open(bag / 'bag_0.mcap', 'rb') as stream:
        reader = make_reader(stream)
        assert reader.get_header().profile == 'ros2'
        summary = reader.get_summary()
        assert summary.statistics.message_count == len(all_logs)
        channel = next(c for c in summary.channels.values() if c.topic == '/rig/phase')
        assert yaml.safe_load(channel.metadata['offered_qos_profiles']) == [RELIABLE_LATCHED]
        assert channel.metadata['topic_type_hash'].startswith('RIHS01_')
        records = list(reader.iter_metadata())
    assert [r.name for r in records] == ['rosbag2']
    stored = yaml.safe_load(records[0].metadata['serialized_metadata'])
    assert stored == info


def test_bad_input_is_reported_with_names(tmp_path):
    occupied = tmp_path / 'occupied'
    occupied.mkdir()
    (occupied / 'x').write_text('')
    with pytest.raises(BagWriterError, match='occupied'):
        BagWriter(occupied)
    with BagWriter(tmp_path / 'bag') as bag:
        with pytest.raises(MessageDefinitionError, match='no_such_msgs'):
            bag.add_topic('/a', 'no_such_msgs/msg/Thing')
        with pytest.raises(MessageDefinitionError, match='pkg/msg/Type'):
            bag.add_topic('/a', 'Float64')
        with pytest.raises(BagWriterError, match='/b.*add_topic'):
            bag.write('/b', b'\x00\x01\x00\x00', 1)
        bag.add_topic('/a', 'std_msgs/msg/Float64')
        with pytest.raises(BagWriterError, match='/a.*std_msgs/msg/Float64'):
            bag.add_topic('/a', 'std_msgs/msg/String')
        with pytest.raises(BagWriterError, match='offered_qos_profiles'):
            bag.add_topic('/c', 'std_msgs/msg/String', 'history: [')
    with pytest.raises(BagWriterError, match='closed'):
        bag.write('/a', serialize(Float64(data=1.0)), 1)


def _messages_on_disk(mcap_file: Path) -> int:
    count = 0
    with open(mcap_file, 'rb') as stream:
        try:
            for record in StreamReader(stream).records:
                count += type(record).__name__ == 'Message'
        except Exception:  # noqa: S110 - the unfinished tail ends the scan
            pass
    return count


def test_flush_puts_written_messages_on_disk_before_close(tmp_path):
    with BagWriter(tmp_path / 'bag', flush_period_s=None) as bag:
        bag.add_topic('/a', 'std_msgs/msg/Float64')
        for i in range(7):
            bag.write('/a', serialize(Float64(data=float(i))), T0 + i)
        bag.flush()
        assert _messages_on_disk(bag.mcap_path) == 7
        summary = bag_summary(bag.directory)
        assert not summary.complete
        assert summary.topics['/a'].message_count == 7


def test_recover_truncated_file_keeps_every_complete_chunk(tmp_path):
    directory = tmp_path / 'bag'
    with BagWriter(directory, flush_period_s=None) as bag:
        bag.add_topic('/a', 'std_msgs/msg/Float64')
        for i in range(50):
            bag.write('/a', serialize(Float64(data=float(i))), T0 + 1000 * i)
            if i % 10 == 9:
                bag.flush()
    whole = (directory / 'bag_0.mcap').read_bytes()
    with open(directory / 'bag_0.mcap', 'rb') as stream:
        chunk_indexes = sorted(make_reader(stream).get_summary().chunk_indexes,
                               key=lambda index: index.chunk_start_offset)
    assert len(chunk_indexes) == 5
    typestore = get_typestore(Stores.ROS2_JAZZY)
    for number, index in enumerate(chunk_indexes, start=1):
        chunk_end = index.chunk_start_offset + index.chunk_length
        # Cut inside chunk `number`, right after it, and a few bytes into what follows it.
        for cut, complete_chunks in ((chunk_end - 1, number - 1), (chunk_end, number),
                                     (chunk_end + 3, number)):
            case = tmp_path / f'cut_{cut}'
            case.mkdir()
            (case / 'bag_0.mcap').write_bytes(whole[:cut])
            result = recover(case)
            assert not result.was_complete
            assert result.message_count == 10 * complete_chunks
            with Reader(case) as reader:
                values = [typestore.deserialize_cdr(raw, c.msgtype).data
                          for c, _, raw in reader.messages()]
                assert reader.message_count == 10 * complete_chunks
                # The channel record travels in the first chunk, so it is lost with it.
                assert list(reader.topics) == (['/a'] if complete_chunks else [])
            assert values == [float(i) for i in range(10 * complete_chunks)]
            assert bag_summary(case).message_count == 10 * complete_chunks
            assert (case / 'bag_0.mcap.truncated').stat().st_size == cut


def test_recover_complete_file_only_rewrites_metadata(tmp_path):
    bag = _write_sample(tmp_path / 'bag')
    original = yaml.safe_load((bag / 'metadata.yaml').read_text())
    (bag / 'metadata.yaml').unlink()
    result = recover(bag)
    assert result.was_complete and result.damaged_copy is None
    assert yaml.safe_load((bag / 'metadata.yaml').read_text()) == original


CHILD = textwrap.dedent("""
    import sys, time
    from std_msgs.msg import Float64
    from softseq_ros.bag.forms import serialize
    from softseq_ros.bag.writer import BagWriter
    bag = BagWriter(sys.argv[1])
    bag.add_topic('/pump/injected_volume', 'std_msgs/msg/Float64')
    progress = open(sys.argv[2], 'w', buffering=1)
    i = 0
    while True:
        bag.write('/pump/injected_volume', serialize(Float64(data=float(i))), time.time_ns())
        progress.write(f'{i} {time.time()}\\n')
        i += 1
        time.sleep(0.002)
""")


def test_sigkill_loses_at_most_the_last_second(tmp_path):
    directory = tmp_path / 'killed'
    progress = tmp_path / 'progress.txt'
    script = tmp_path / 'child.py'
    script.write_text(CHILD)
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join(filter(None, [str(REPO), env.get('PYTHONPATH')]))
    child = subprocess.Popen([sys.executable, str(script), str(directory), str(progress)],
                             env=env)
    try:
        deadline = time.monotonic() + 60
        started = None
        while time.monotonic() < deadline and child.poll() is None:
            lines = progress.read_text().splitlines() if progress.exists() else []
            if lines:
                started = started or float(lines[0].split()[1])
                if float(lines[-1].split()[1]) - started >= 3.0:
                    break
            time.sleep(0.05)
        assert child.poll() is None, 'the writing child died before it was killed'
        killed_at = time.time()
        child.send_signal(signal.SIGKILL)
        child.wait(timeout=30)
    finally:
        if child.poll() is None:
            child.kill()
    written = [line.split() for line in progress.read_text().splitlines() if line.count(' ') == 1]
    must_survive = [int(i) for i, t in written if float(t) < killed_at - 1.0]
    assert must_survive, 'the child wrote nothing older than one second'
    result = recover(directory)
    assert not result.was_complete
    typestore = get_typestore(Stores.ROS2_JAZZY)
    with Reader(directory) as reader:
        values = [typestore.deserialize_cdr(raw, c.msgtype).data
                  for c, _, raw in reader.messages()]
        assert reader.message_count == len(values)
    # Every message up to the last one that must survive is there, in order, without gaps.
    assert values[:max(must_survive) + 1] == [float(i) for i in range(max(must_survive) + 1)]
    assert values == [float(i) for i in range(len(values))]


@pytest.mark.parametrize('compression', ['zstd', 'lz4', None])
def test_every_index_points_at_its_record(tmp_path, compression):
    """Chunk and message indexes, checked by parsing what they point at (readers seek by them)."""
    import io
    import zlib

    import lz4.frame
    from mcap.data_stream import ReadDataStream
    from mcap.records import Chunk, Message, MessageIndex
    import zstandard

    directory = tmp_path / 'bag'
    with BagWriter(directory, compression=compression, chunk_size=300) as bag:
        for topic, (type_name, _) in SAMPLE.items():
            bag.add_topic(topic, type_name)
        # Out of time order on purpose: indexes hold log times, not positions.
        for topic, (_, entries) in SAMPLE.items():
            for log, pub, msg in entries:
                bag.write(topic, serialize(msg), log, pub)
    raw = (directory / 'bag_0.mcap').read_bytes()

    def record_at(buffer: bytes, offset: int, opcode: int, cls):
        assert buffer[offset] == opcode
        length = int.from_bytes(buffer[offset + 1:offset + 9], 'little')
        stream = ReadDataStream(io.BytesIO(buffer[offset + 9:offset + 9 + length]))
        return cls.read(stream, length) if cls is Message else cls.read(stream)

    with open(directory / 'bag_0.mcap', 'rb') as stream:
        summary = make_reader(stream).get_summary()
    channels = {c.id: c.topic for c in summary.channels.values()}
    seen = []
    assert len(summary.chunk_indexes) > 3
    for index in summary.chunk_indexes:
        chunk = record_at(raw, index.chunk_start_offset, 0x06, Chunk)
        assert index.chunk_length == 9 + int.from_bytes(
            raw[index.chunk_start_offset + 1:index.chunk_start_offset + 9], 'little')
        if compression == 'zstd':
            data = zstandard.ZstdDecompressor().decompress(
                chunk.data, max_output_size=chunk.uncompressed_size)
        else:
            data = lz4.frame.decompress(chunk.data) if compression == 'lz4' else chunk.data
        assert len(data) == chunk.uncompressed_size and zlib.crc32(data) == chunk.uncompressed_crc
        times = []
        for channel_id, offset in index.message_index_offsets.items():
            message_index = record_at(raw, offset, 0x07, MessageIndex)
            assert message_index.channel_id == channel_id
            for log_time, record_offset in message_index.records:
                message = record_at(data, record_offset, 0x05, Message)
                assert (message.channel_id, message.log_time) == (channel_id, log_time)
                seen.append((channels[channel_id], log_time, message.publish_time))
                times.append(log_time)
        assert (index.message_start_time, index.message_end_time) == (min(times), max(times))
    expected = [(topic, log, pub) for topic, (_, entries) in SAMPLE.items()
                for log, pub, _ in entries]
    assert sorted(seen) == sorted(expected)
    assert summary.statistics.message_count == len(expected)
    assert summary.statistics.message_start_time == min(log for _, log, _ in expected)


def test_appender_writes_what_write_writes_and_only_without_the_flusher(tmp_path):
    rows = [(T0 + 10 * i, T0 + 10 * i - 3, serialize(_joints(i))) for i in range(5)]
    for name, use_appender in (('written', False), ('appended', True)):
        with BagWriter(tmp_path / name / 'bag', flush_period_s=None) as bag:
            bag.add_topic('/joints', 'sensor_msgs/msg/JointState')
            append = bag.appender('/joints') if use_appender else None
            for log, pub, data in rows:
                if append:
                    append(data, log, pub)
                else:
                    bag.write('/joints', data, log, pub)
    assert ((tmp_path / 'written' / 'bag' / 'bag_0.mcap').read_bytes()
            == (tmp_path / 'appended' / 'bag' / 'bag_0.mcap').read_bytes())
    with BagWriter(tmp_path / 'flushed', flush_period_s=0.5) as bag:
        bag.add_topic('/joints', 'sensor_msgs/msg/JointState')
        with pytest.raises(BagWriterError, match='only for a writer without the periodic flush'):
            bag.appender('/joints')
    with BagWriter(tmp_path / 'unflushed', flush_period_s=None) as bag:
        with pytest.raises(BagWriterError, match='topic /other: not registered'):
            bag.appender('/other')


def _truncated_bag(tmp_path: Path, messages: int = 60) -> tuple[Path, int]:
    """A bag cut short in a chunk, as a SIGKILL leaves it, and how many messages are intact."""
    directory = tmp_path / 'bag'
    with BagWriter(directory, flush_period_s=None) as bag:
        bag.add_topic('/a', 'std_msgs/msg/Float64')
        for i in range(messages):
            bag.write('/a', serialize(Float64(data=float(i))), T0 + 1000 * i)
            if i % 10 == 9:
                bag.flush()
    path = directory / 'bag_0.mcap'
    whole = path.read_bytes()
    path.write_bytes(whole[:len(whole) // 2])
    (directory / 'metadata.yaml').unlink()
    # What a recovery of an untouched copy finds: the reference for every later recovery.
    reference = tmp_path / 'reference'
    shutil.copytree(directory, reference)
    intact = recover(reference).message_count
    assert 0 < intact < messages
    return directory, intact


def test_recover_never_loses_the_only_full_copy_and_can_be_repeated(tmp_path, monkeypatch):
    directory, intact = _truncated_bag(tmp_path)
    original = (directory / 'bag_0.mcap').read_bytes()
    # A recovery cut short (here: the disk fills up after 20 messages) leaves the damaged
    # original as it was and says so in one line.
    real_write = BagWriter.write
    calls = {'n': 0}

    def failing_write(self, *args, **kwargs):
        calls['n'] += 1
        if calls['n'] > 20:
            raise OSError(28, 'No space left on device')
        return real_write(self, *args, **kwargs)

    monkeypatch.setattr(BagWriter, 'write', failing_write)
    with pytest.raises(BagWriterError, match=r'No space left on device.*bag_0\.mcap is '
                                             'untouched'):
        recover(directory)
    monkeypatch.setattr(BagWriter, 'write', real_write)
    assert (directory / 'bag_0.mcap').read_bytes() == original
    assert not list(directory.glob('*.recovering'))
    # Recovered, then recovered again and again: the damaged original is kept, every time
    # the same messages come out of it.
    for _ in range(3):
        result = recover(directory)
        assert result.message_count == intact
        assert (directory / 'bag_0.mcap.truncated').read_bytes() == original
        assert bag_summary(directory).message_count == intact
    # A recovery killed after the damaged file was set aside, before the new one took its
    # name: the next one starts from the damaged original.
    (directory / 'bag_0.mcap').unlink()
    result = recover(directory)
    assert not result.was_complete and result.message_count == intact
    assert (directory / 'bag_0.mcap.truncated').read_bytes() == original
    # And a partial output left by a cut-short recovery is replaced by a full one.
    (directory / 'bag_0.mcap').write_bytes(original[:len(original) // 3])
    result = recover(directory, keep_damaged=False)
    assert result.message_count == intact and result.damaged_copy is None
    assert not (directory / 'bag_0.mcap.truncated').exists()
    with Reader(directory) as reader:
        assert reader.message_count == intact


def test_recover_refuses_what_is_not_an_mcap_file(tmp_path):
    for name, content in (('noise', bytes(range(256)) * 40), ('text', b'hello, rig\n' * 50)):
        directory = tmp_path / name
        directory.mkdir()
        (directory / f'{name}_0.mcap').write_bytes(content)
        with pytest.raises(BagWriterError, match='not an MCAP file'):
            recover(directory)
        assert (directory / f'{name}_0.mcap').read_bytes() == content
        assert sorted(p.name for p in directory.iterdir()) == [f'{name}_0.mcap']


def test_a_full_disk_stops_the_bag_in_one_line_and_keeps_what_was_flushed(tmp_path,
                                                                          monkeypatch):
    from softseq_ros.bag import mcap_file

    directory = tmp_path / 'full'
    bag = BagWriter(directory, flush_period_s=None)
    bag.add_topic('/a', 'std_msgs/msg/Float64')
    for i in range(30):
        bag.write('/a', serialize(Float64(data=float(i))), T0 + i)
    bag.flush()
    real_flush = mcap_file.ChunkedMcapWriter.flush

    def disk_full(self):
        raise OSError(28, 'No space left on device')

    monkeypatch.setattr(mcap_file.ChunkedMcapWriter, 'flush', disk_full)
    for i in range(30, 40):
        bag.write('/a', serialize(Float64(data=float(i))), T0 + i)
    with pytest.raises(BagWriterError) as stopped:
        bag.flush()
    text = str(stopped.value)
    assert 'No space left on device' in text and 'softseq recover' in text
    assert str(directory) in text and '\n' not in text
    with pytest.raises(BagWriterError, match='No space left'):
        bag.write('/a', serialize(Float64(data=99.0)), T0 + 99)
    monkeypatch.setattr(mcap_file.ChunkedMcapWriter, 'flush', real_flush)
    with pytest.raises(BagWriterError, match='No space left'):
        bag.close()
    assert bag.closed and not (directory / 'metadata.yaml').exists()
    # Everything flushed before the disk filled up comes back.
    result = recover(directory)
    assert result.message_count == 30
    values = [m.msg.data for m in read_bag(directory)]
    assert values == [float(i) for i in range(30)]


@pytest.mark.parametrize('params, expected', [
    (['output:={tmp}/a_file/bag'], 'cannot create the bag'),
    (["topics:=['not a topic!']"], 'is not a valid topic name'),
])
def test_recorder_start_up_mistakes_are_one_line(tmp_path, params, expected):
    (tmp_path / 'a_file').write_text('not a folder')
    args = [sys.executable, '-m', 'softseq_ros.nodes.recorder', '--ros-args']
    for param in params:
        args += ['-p', param.format(tmp=tmp_path)]
    if not any(p.startswith('output') for p in params):
        args += ['-p', f'output:={tmp_path}/bag']
    env = dict(os.environ, PYTHONUNBUFFERED='1')
    result = subprocess.run(args, env=env, capture_output=True, text=True, timeout=60,
                            stdin=subprocess.DEVNULL)
    assert result.returncode == 1, result.stderr
    assert 'Traceback' not in result.stderr
    lines = [line for line in result.stderr.splitlines() if line.startswith('recorder: ')]
    assert len(lines) == 1 and expected in lines[0], result.stderr


def test_a_long_recording_keeps_a_few_hundred_bytes_per_chunk_for_its_summary(tmp_path):
    # A recorder closes a chunk at every flush, several a second: what it keeps per chunk for
    # the summary's index is what its memory grows by over a day.
    import tracemalloc

    chunks = 3000
    message = serialize(Float64(data=1.0))
    with BagWriter(tmp_path / 'bag', flush_period_s=None, compression=None) as bag:
        bag.add_topic('/a', 'std_msgs/msg/Float64')
        bag.add_topic('/b', 'std_msgs/msg/Float64')
        for i in range(100):    # warm up, so lazy first-time allocations are not counted
            bag.write('/a', message, T0 + i)
            bag.flush()
        tracemalloc.start()
        before, _ = tracemalloc.get_traced_memory()
        for i in range(chunks):
            bag.write('/a', message, T0 + 100 + i)
            bag.write('/b', message, T0 + 100 + i)
            bag.flush()
        after, _ = tracemalloc.get_traced_memory()
        tracemalloc.stop()
    assert (after - before) / chunks < 300
    summary = bag_summary(tmp_path / 'bag')
    assert summary.complete and summary.message_count == 100 + 2 * chunks
    # Every chunk is indexed: an independent reader finds every message through the index.
    with Reader(tmp_path / 'bag') as reader:
        assert sum(1 for _ in reader.messages()) == 100 + 2 * chunks


def test_bulk_topics_fill_chunks_of_their_own_which_readers_merge_in_time(tmp_path):
    # A reader of the small state topics then decompresses none of the camera frames' bytes.
    directory = tmp_path / 'bag'
    with BagWriter(directory, chunk_size=4096, flush_period_s=None) as bag:
        bag.add_topic('/small', 'std_msgs/msg/Float64')
        bag.add_topic('/frames', 'std_msgs/msg/String')
        written = []
        for i in range(300):
            bag.write('/small', serialize(Float64(data=float(i))), T0 + 1000 * i)
            written.append(('/small', T0 + 1000 * i))
            if i % 4 == 0:
                bag.write('/frames', serialize(String(data=f'{i:04d}' * 400)), T0 + 1000 * i + 1)
                written.append(('/frames', T0 + 1000 * i + 1))
    with open(bag.mcap_path, 'rb') as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        ids = {c.topic: c.id for c in summary.channels.values()}
        lanes = [set(index.message_index_offsets) for index in summary.chunk_indexes]
        assert all(lane in ({ids['/small']}, {ids['/frames']}) for lane in lanes)
        assert lanes.count({ids['/small']}) > 1 and lanes.count({ids['/frames']}) > 1
        ordered = [(c.topic, m.log_time) for _, c, m in reader.iter_messages(log_time_order=True)]
    assert ordered == written
    with AnyReader([directory]) as reader:
        assert [(c.topic, t) for c, t, _ in reader.messages()] == written
    # Read in file order (as recovery does), each channel record comes before its messages.
    seen, first_message = set(), {}
    with open(bag.mcap_path, 'rb') as stream:
        for record in StreamReader(stream).records:
            kind = type(record).__name__
            if kind == 'Channel':
                seen.add(record.id)
            elif kind == 'Message':
                first_message.setdefault(record.channel_id, record.channel_id in seen)
    assert first_message == {ids['/small']: True, ids['/frames']: True}
