"""
``softseq recover`` on MCAP files other writers made, without a metadata.yaml beside them.

Recover never makes a bag less readable than it was: what mcap's own reader reads in the file
is kept, or the file is refused and left as it was. The files are written here with mcap's
Python writer, chunked and not (Foxglove's writers make both), with the options a writer may
leave off: a summary that repeats no channel or schema, a second writer started on the file.
"""

import io
import json
from pathlib import Path
import subprocess
import sys

from mcap.writer import Writer
import pytest
from rosbags.rosbag2 import Reader
from std_msgs.msg import Float64, String

from softseq_ros.bag.forms import serialize
from softseq_ros.bag.msgdefs import message_definition
from softseq_ros.bag.reader import bag_summary

T0 = 1_700_000_000_000_000_000
MESSAGES = 3000


def softseq(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, '-m', 'softseq_ros.cli', *args], capture_output=True,
                          text=True, timeout=120, stdin=subprocess.DEVNULL)


def _write(stream: io.BytesIO, *, chunked: bool, json_topic: bool = False,
           **options) -> list[tuple[str, int, bytes]]:
    """A file of two ROS 2 topics (and a JSON one), as ``mcap.writer.Writer`` writes it."""
    writer = Writer(stream, use_chunking=chunked, chunk_size=16 * 1024, **options)
    writer.start(profile='ros2', library='another writer')
    channels = {}
    for topic, type_name in (('/a', 'std_msgs/msg/String'), ('/b', 'std_msgs/msg/Float64')):
        schema = writer.register_schema(type_name, 'ros2msg',
                                        message_definition(type_name).encode())
        channels[topic] = writer.register_channel(topic, 'cdr', schema)
    if json_topic:
        schema = writer.register_schema('Note', 'jsonschema', b'{"type": "object"}')
        channels['/notes'] = writer.register_channel('/notes', 'json', schema)
    written = []
    for i in range(MESSAGES):
        topic = ('/a', '/b', '/notes')[i % (3 if json_topic else 2)]
        data = _payload(topic, i)
        writer.add_message(channels[topic], T0 + 1000 * i, data, T0 + 1000 * i)
        written.append((topic, T0 + 1000 * i, data))
    writer.finish()
    return written


def _payload(topic: str, i: int) -> bytes:
    if topic == '/a':
        return serialize(String(data=f'message {i}'))
    if topic == '/b':
        return serialize(Float64(data=float(i)))
    return json.dumps({'i': i}).encode()


def _rosbags_messages(bag: Path) -> list[tuple[str, int, bytes]]:
    with Reader(bag) as reader:
        return [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages()]


@pytest.mark.parametrize('chunked', [False, True], ids=['unchunked', 'chunked'])
@pytest.mark.parametrize('how', ['summary_without_channels', 'started_twice'])
def test_recover_keeps_every_message_another_writers_complete_file_holds(tmp_path, chunked,
                                                                        how):
    # A summary without channels and schemas (repeatChannels and repeatSchemas off): recover
    # used to write a metadata.yaml of no topic and then fail its own read-back, leaving the
    # bag said complete with 0 messages. A second writer started on the file (mcap_ros2's
    # writer starts one of its own): 0 messages recovered of the file unchunked, "dropped"
    # chunked, exit 0 both, the original set aside.
    bag = tmp_path / 'bag'
    bag.mkdir()
    stream = io.BytesIO()
    if how == 'started_twice':
        Writer(stream).start(profile='ros2', library='a first writer')
        written = _write(stream, chunked=chunked)
    else:
        written = _write(stream, chunked=chunked, repeat_channels=False, repeat_schemas=False)
    path = bag / 'bag.mcap'
    path.write_bytes(stream.getvalue())

    result = softseq('recover', str(bag))

    assert result.returncode == 0, result.stderr
    assert f'recovered {MESSAGES} messages' in result.stdout
    assert 'nothing in the file dropped' in result.stdout
    assert sorted(_rosbags_messages(bag)) == sorted(written)
    assert bag_summary(bag).message_count == MESSAGES
    # The original is kept as it was.
    assert (bag / 'bag.mcap.truncated').read_bytes() == stream.getvalue()


@pytest.mark.parametrize('chunked', [False, True], ids=['unchunked', 'chunked'])
@pytest.mark.parametrize('cut', [False, True], ids=['whole', 'cut_short'])
def test_recover_refuses_a_file_whose_messages_a_bag_cannot_carry_and_leaves_it(tmp_path,
                                                                                 chunked, cut):
    # A JSON topic beside the ROS 2 ones (Foxglove's writers record both). Whole, recover
    # left a metadata.yaml behind that rosbags could not read; cut short, it kept the ROS 2
    # topics only, exit 0, and set the original aside: a reader of the file lost a third of
    # it.
    bag = tmp_path / 'bag'
    bag.mkdir()
    stream = io.BytesIO()
    _write(stream, chunked=chunked, json_topic=True)
    content = stream.getvalue()[:len(stream.getvalue()) * 2 // 3] if cut else stream.getvalue()
    path = bag / 'bag.mcap'
    path.write_bytes(content)

    result = softseq('recover', str(bag))

    assert result.returncode == 2, result.stdout
    line, = result.stderr.strip().splitlines()
    assert line.startswith(f'softseq recover: error: {path}: '), line
    assert 'messages: /notes holds json messages of a jsonschema schema, not cdr of ros2msg' \
        in line
    assert line.endswith('; nothing written or moved')
    if cut:
        assert 'a recovery would keep ' in line
    assert [p.name for p in bag.iterdir()] == ['bag.mcap']
    assert path.read_bytes() == content
