"""
Faults that would lose or misreport data: damaged bags, bags in use, full disks, FIFOs, signals.

Each test runs the real command (``python -m softseq_ros.cli``) or real writers in child
processes, on real MCAP files; the bags are read back with mcap's reader (CRCs checked) and
rosbags, two readers that share no code with ours.
"""

import io
import os
from pathlib import Path
import shutil
import signal
import subprocess
import sys
import textwrap
import threading

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import StreamReader, breakup_chunk
import pytest
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore
from scenes import fast_asymmetric
from sensor_msgs.msg import JointState

import softseq_ros
from softseq_ros.bag.forms import serialize
from softseq_ros.bag.writer import BagWriter

REPO = Path(__file__).resolve().parents[1]
CONFIG = REPO / 'config'
T0 = 1_700_000_000_000_000_000  # an arbitrary epoch time [ns]
TOPIC = '/actuator/volumes'


def softseq(*args: str, timeout: float = 120, **options) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, '-m', 'softseq_ros.cli', *args], capture_output=True,
                          text=True, timeout=timeout, stdin=subprocess.DEVNULL, **options)


def _volumes(i: int) -> JointState:
    msg = JointState()
    msg.header.frame_id = 'rig'
    msg.name = ['bottom', 'top']
    msg.position = [1e-6 * i, 2e-6 * i]
    msg.effort = [1.0e3 + i, 2.0e3 + i]
    return msg


def _bag_of_chunks(directory: Path, compression: str | None, chunks: int = 6,
                   per_chunk: int = 50) -> None:
    """A closed bag whose chunk k holds the messages k * per_chunk ... (k + 1) * per_chunk - 1."""
    with BagWriter(directory, compression=compression, flush_period_s=None) as bag:
        bag.add_topic(TOPIC, 'sensor_msgs/msg/JointState')
        for i in range(chunks * per_chunk):
            bag.write(TOPIC, serialize(_volumes(i)), T0 + 1000 * i)
            if i % per_chunk == per_chunk - 1:
                bag.flush()


def _chunks(path: Path) -> list[tuple[int, int, list[Message]]]:
    """(start, length, messages) of every chunk of a file, in file order, read via its index."""
    with open(path, 'rb') as stream:
        indexes = sorted(make_reader(stream).get_summary().chunk_indexes,
                         key=lambda index: index.chunk_start_offset)
        result = []
        for index in indexes:
            stream.seek(index.chunk_start_offset + 9)
            chunk = Chunk.read(ReadDataStream(io.BytesIO(stream.read(index.chunk_length - 9))))
            messages = [r for r in breakup_chunk(chunk, validate_crc=True)
                        if isinstance(r, Message)]
            result.append((index.chunk_start_offset, index.chunk_length, messages))
    return result


def _flip_a_bit(path: Path, offset: int) -> None:
    data = bytearray(path.read_bytes())
    data[offset] ^= 0x10
    path.write_bytes(bytes(data))


def _read_with_crcs(path: Path) -> list[Message]:
    """Every message, read by mcap's stream reader checking every chunk's CRC (raises if not)."""
    with open(path, 'rb') as stream:
        return [r for r in StreamReader(stream, validate_crcs=True).records
                if isinstance(r, Message)]


def _rosbags_messages(directory: Path) -> list[tuple[str, int, bytes]]:
    with Reader(directory) as reader:
        rows = [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages()]
        assert reader.message_count == len(rows)
    return rows


@pytest.fixture(scope='module')
def rig_bag(tmp_path_factory) -> Path:
    """A rig bag from the batch runner on a short programme (2.5 s in, 2.5 s out)."""
    folder = tmp_path_factory.mktemp('faults')
    scene = fast_asymmetric(folder, 'faults', pump_rate_hz=20, camera_rate_hz=2,
                            triggers=(2.5e-5,))
    softseq_ros.run(scene, folder / 'bag', start_time_ns=T0)
    return folder / 'bag'


# ---------------------------------------------------------------- recovery checks what it keeps


@pytest.mark.parametrize('compression', ['zstd', None])
def test_recover_drops_the_chunk_that_fails_its_crc_keeps_the_others_and_says_so(
        tmp_path, compression):
    directory = tmp_path / 'bag'
    _bag_of_chunks(directory, compression)
    path = directory / 'bag_0.mcap'
    chunks = _chunks(path)
    assert len(chunks) == 6
    start, length, lost = chunks[2]
    # One bit in the middle of the third chunk's records; the summary and the other chunks
    # are untouched, so the file still looks complete.
    _flip_a_bit(path, start + length // 2)
    damaged = path.read_bytes()
    with pytest.raises(Exception, match='(?i)crc'):
        _read_with_crcs(path)

    result = softseq('recover', str(directory))

    assert result.returncode == 0, result.stderr
    assert f'dropped chunk at bytes {start}-{start + length}, {len(lost)} messages' \
        in result.stdout
    assert 'dropped: 1 part(s), 50 messages' in result.stdout
    assert (directory / 'bag_0.mcap.truncated').read_bytes() == damaged
    kept = [i for i in range(300) if not 100 <= i < 150]
    expected = [serialize(_volumes(i)) for i in kept]
    assert [bytes(m.data) for m in _read_with_crcs(path)] == expected
    assert [raw for _, _, raw in _rosbags_messages(directory)] == expected
    assert [t for _, t, _ in _rosbags_messages(directory)] == [T0 + 1000 * i for i in kept]
    # And a second recovery finds the bag complete, every chunk passing its CRC.
    again = softseq('recover', str(directory))
    assert again.returncode == 0 and 'complete, 250 messages' in again.stdout


def test_a_rig_bag_with_a_flipped_bit_keeps_its_other_chunks_and_their_topics(tmp_path,
                                                                             rig_bag):
    directory = tmp_path / 'bag'
    shutil.copytree(rig_bag, directory)
    path = next(directory.glob('*.mcap'))
    chunks = _chunks(path)
    assert len(chunks) >= 2
    # The first chunk written carries every schema and channel record: with it dropped, the
    # intact summary still says what the other chunks' channels are.
    start, length, lost = chunks[0]
    _flip_a_bit(path, start + length // 2)
    with open(rig_bag / path.name, 'rb') as stream:
        channels = make_reader(stream).get_summary().channels

    result = softseq('recover', str(directory))

    assert result.returncode == 0, result.stderr
    assert f'dropped chunk at bytes {start}-{start + length}, {len(lost)} messages' \
        in result.stdout
    kept = [m for _, _, messages in chunks[1:] for m in messages]
    assert len(kept) > 0
    read = _read_with_crcs(path)
    assert sorted((m.log_time, bytes(m.data)) for m in read) == \
        sorted((m.log_time, bytes(m.data)) for m in kept)
    rows = _rosbags_messages(directory)
    assert sorted((t, raw) for _, t, raw in rows) == \
        sorted((m.log_time, bytes(m.data)) for m in kept)
    # Their channel records were in the dropped chunk: the topics come from the summary.
    assert {topic for topic, _, _ in rows} == {channels[m.channel_id].topic for m in kept}
    typestore = get_typestore(Stores.ROS2_JAZZY)
    with Reader(directory) as reader:
        for connection, _, raw in reader.messages():
            typestore.deserialize_cdr(raw, connection.msgtype)


@pytest.mark.parametrize('content, why', [
    (b'', 'the file is empty'),
    (b'\x89MCAP0\r\n', 'only the MCAP magic bytes'),
    (b'\x89MCAP0\r\n' + bytes(range(7, 256)) * 12, 'no MCAP header after the magic bytes'),
])
def test_recover_refuses_a_file_with_nothing_to_recover(tmp_path, content, why):
    directory = tmp_path / 'bag'
    directory.mkdir()
    path = directory / 'bag_0.mcap'
    path.write_bytes(content)

    result = softseq('recover', str(directory))

    assert result.returncode == 2, result.stdout
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1
    assert lines[0].startswith(f'softseq recover: error: nothing to recover in {path}: ')
    assert why in lines[0]
    assert path.read_bytes() == content
    assert [p.name for p in directory.iterdir()] == ['bag_0.mcap']


# ---------------------------------------------------------------- a bag in use

WRITER = textwrap.dedent("""
    import sys, time
    from sensor_msgs.msg import JointState
    from softseq_ros.bag.forms import serialize
    from softseq_ros.bag.writer import BagWriter
    directory, mode = sys.argv[1], sys.argv[2]
    bag = BagWriter(directory, flush_period_s=0.05)
    bag.add_topic('/actuator/volumes', 'sensor_msgs/msg/JointState')
    i = 0
    while True:
        msg = JointState()
        msg.position = [float(i)]
        bag.write('/actuator/volumes', serialize(msg), 1000 + i)
        i += 1
        if mode == 'close' and i == 200:
            bag.close()
            print('closed', flush=True)
            time.sleep(600)
        if i % 100 == 0:
            print(i, flush=True)
        time.sleep(0.001)
""")


def _start_writer(tmp_path: Path, directory: Path, mode: str, ros_env) -> subprocess.Popen:
    script = tmp_path / 'writer.py'
    script.write_text(WRITER)
    return subprocess.Popen([sys.executable, str(script), str(directory), mode],
                            stdout=subprocess.PIPE, text=True, env=ros_env)


def test_recover_refuses_a_bag_whose_writer_is_alive_and_never_moves_it(tmp_path, ros_env):
    from softseq_ros.testing import wait_for

    directory = tmp_path / 'live'
    writer = _start_writer(tmp_path, directory, 'open', ros_env)
    try:
        assert writer.stdout.readline().strip() == '100'
        path = directory / 'live_0.mcap'
        inode = path.stat().st_ino

        result = softseq('recover', str(directory))

        assert result.returncode == 2, result.stdout
        assert result.stderr.strip().splitlines() == [
            f'softseq recover: error: {directory}: in use: live_0.mcap is being written by '
            'another process (its writer holds the lock); recover it after the recording has '
            'ended or its writer was killed']
        assert sorted(p.name for p in directory.iterdir()) == ['live_0.mcap']
        assert path.stat().st_ino == inode
        # The writer goes on writing into the file it holds, under the same name.
        size = path.stat().st_size
        wait_for(lambda: path.stat().st_size > size, 'the writer to write on')
        assert writer.poll() is None and path.stat().st_ino == inode
        # Killed, the writer's lock goes with it: the recording is recoverable at once.
        writer.send_signal(signal.SIGKILL)
        writer.wait(timeout=30)
    finally:
        if writer.poll() is None:
            writer.kill()
            writer.wait(timeout=30)
    result = softseq('recover', str(directory))
    assert result.returncode == 0, result.stderr
    values = [_position(raw) for _, _, raw in _rosbags_messages(directory)]
    assert len(values) >= 100 and values == [float(i) for i in range(len(values))]


def _position(raw: bytes) -> float:
    typestore = get_typestore(Stores.ROS2_JAZZY)
    return float(typestore.deserialize_cdr(raw, 'sensor_msgs/msg/JointState').position[0])


def test_the_writer_releases_its_lock_when_it_closes(tmp_path, ros_env):
    directory = tmp_path / 'closed'
    writer = _start_writer(tmp_path, directory, 'close', ros_env)
    try:
        lines = [writer.stdout.readline().strip() for _ in range(2)]
        assert lines == ['100', 'closed']
        result = softseq('recover', str(directory))
        assert writer.poll() is None, 'the writing process is still alive'
    finally:
        writer.kill()
        writer.wait(timeout=30)
    assert result.returncode == 0, result.stderr
    assert 'complete, 200 messages' in result.stdout


# ---------------------------------------------------------------- a full disk under the report


@pytest.mark.parametrize('name', ['metrics.json', 'report.md', 'pv.png', 'timeseries.png'])
def test_report_on_a_full_disk_is_one_line_naming_the_file(tmp_path, rig_bag, name):
    out = tmp_path / 'report'
    out.mkdir()
    # /dev/full fails every write with ENOSPC, as a full disk does.
    (out / name).symlink_to('/dev/full')

    result = softseq('report', str(rig_bag), '--out', str(out))

    assert result.returncode == 2, result.stderr
    assert result.stderr.strip().splitlines() == [
        f'softseq report: error: {out / name}: cannot write (No space left on device)']


def test_library_on_a_full_disk_is_one_line_naming_the_file(tmp_path):
    folder = tmp_path / 'tables'
    folder.mkdir()
    shutil.copy(sorted((CONFIG / 'library').glob('*.csv'))[0], folder)
    out = tmp_path / 'out'
    out.mkdir()
    (out / 'library.json').symlink_to('/dev/full')

    result = softseq('library', str(folder), '--out', str(out), '--jobs', '1')

    assert result.returncode == 2, result.stderr
    assert result.stderr.strip().splitlines()[-1] == (
        f'softseq library: error: {out / "library.json"}: cannot write (No space left on '
        'device)')


# ---------------------------------------------------------------- a FIFO among the tables


def test_library_skips_a_fifo_named_like_a_table_instead_of_hanging(tmp_path):
    folder = tmp_path / 'tables'
    folder.mkdir()
    os.mkfifo(folder / 'x.csv')

    result = softseq('library', str(folder), '--out', str(tmp_path / 'out'), timeout=60)

    assert result.returncode == 2
    assert f'library: note: {folder / "x.csv"} is a FIFO, not a table file; skipped' \
        in result.stderr
    assert result.stderr.strip().splitlines()[-1] == (
        f'softseq library: error: {folder}: no segment tables (*.csv regular files) in this '
        'folder')
    # Beside a real table the FIFO is skipped and the table read.
    table = sorted((CONFIG / 'library').glob('*.csv'))[0]
    shutil.copy(table, folder / table.name)
    listed = subprocess.run(
        [sys.executable, '-c', 'import sys; from softseq_ros.analysis.library import '
         'library_entries; print([e.name for e in library_entries(sys.argv[1])])',
         str(folder)], capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL)
    assert listed.returncode == 0, listed.stderr
    assert listed.stdout.strip() == str([table.stem])
    assert 'x.csv is a FIFO' in listed.stderr


# ---------------------------------------------------------------- softseq play and stop signals


def _ignore_sigint() -> None:
    # What a shell does to a job started with '&': SIGINT ignored from the start.
    signal.signal(signal.SIGINT, signal.SIG_IGN)


@pytest.mark.ros
@pytest.mark.parametrize('signum, code, word, ignored', [
    (signal.SIGINT, 130, 'interrupted', False),
    (signal.SIGINT, 130, 'interrupted', True),
    (signal.SIGTERM, 143, 'terminated', False),
])
def test_play_stopped_by_a_signal_exits_as_run_does(context, rig_bag, ros_env, signum, code,
                                                    word, ignored):
    from rclpy.node import Node
    from rosgraph_msgs.msg import Clock

    from softseq_ros.nodes.player import CLOCK_QOS
    from softseq_ros.testing import spinning, wait_for

    listener = Node('play_signal_listener', context=context)
    ticks: list[int] = []
    lock = threading.Lock()

    def tick(_msg: Clock) -> None:
        with lock:
            ticks.append(1)
    listener.create_subscription(Clock, '/clock', tick, CLOCK_QOS)
    # Five seconds of rig time at a fiftieth of their pace: minutes, unless the signal acts.
    player = subprocess.Popen(
        [sys.executable, '-m', 'softseq_ros.cli', 'play', str(rig_bag), '--clock', '--rate',
         '0.02'], stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True, env=ros_env, preexec_fn=_ignore_sigint if ignored else None)
    try:
        with spinning(context, listener):
            wait_for(lambda: len(ticks) >= 2, 'the replay to publish')
            player.send_signal(signum)
            _, stderr = player.communicate(timeout=60)
    finally:
        if player.poll() is None:
            player.kill()
            player.wait(timeout=30)
        listener.destroy_node()
    assert player.returncode == code, stderr
    assert stderr.strip().splitlines() == [f'softseq play: {word}']


@pytest.mark.parametrize('record', ['chunk', 'message_index'])
@pytest.mark.parametrize('change', [+1, -1])
def test_a_damaged_record_length_loses_nothing_when_the_summary_is_intact(tmp_path, record,
                                                                          change):
    directory = tmp_path / 'bag'
    _bag_of_chunks(directory, 'zstd')
    path = directory / 'bag_0.mcap'
    chunks = _chunks(path)
    start, length, _ = chunks[2]
    # The length field of the third chunk, or of the message index after it, says more than
    # the record holds (running over the next chunk) or less (ending inside the record): the
    # walk loses its footing there.
    at = start if record == 'chunk' else start + length
    data = bytearray(path.read_bytes())
    assert data[at] == (Opcode.CHUNK if record == 'chunk' else Opcode.MESSAGE_INDEX)
    held = int.from_bytes(data[at + 1:at + 9], 'little')
    wrong = chunks[4][0] - at - 9 if change > 0 else held // 2
    data[at + 1:at + 9] = wrong.to_bytes(8, 'little')
    path.write_bytes(bytes(data))

    result = softseq('recover', str(directory))

    # mcap's indexed reader reads every chunk by its index in the intact summary: so does the
    # recovery. A chunk is read to the end its index gives; past another record, the walk
    # resumes at the next indexed chunk.
    assert result.returncode == 0, result.stderr
    if record == 'chunk':
        assert 'nothing in the file dropped' in result.stdout
        assert f'the length field of the chunk at byte {start} disagrees with its index' \
            in result.stdout
    else:
        assert f'dropped damaged records at bytes {at}-{chunks[3][0]}, 0 messages' \
            in result.stdout
    assert [bytes(m.data) for m in _read_with_crcs(path)] == \
        [serialize(_volumes(i)) for i in range(300)]
    assert len(_rosbags_messages(directory)) == 300
