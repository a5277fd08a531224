"""
``softseq info BAG`` on real bags made by the batch runner: what ros2 bag info shows, and ours.

The expected values come from elsewhere: the counts from rosbags' reader of the same bag, the
start time the run was given, the digest from the scene's segments
(softseq_ros.segments.identity), the compression from the mcap library's own summary.
"""

import io
from pathlib import Path
import shutil

from mcap.reader import make_reader
from mcap.records import Channel, Message
from mcap.stream_reader import StreamReader
import pytest
from rosbags.rosbag2 import Reader
from scenes import fast_asymmetric
from std_msgs.msg import Float64

import softseq_ros
from softseq_ros import cli
from softseq_ros.bag.forms import serialize
from softseq_ros.bag.writer import BagWriter
from softseq_ros.scene.loader import load_scene
from softseq_ros.segments.identity import segments_sha256

CONFIG = Path(__file__).resolve().parents[1] / 'config'
START_NS = 1_795_000_000 * 10**9   # 2026-11-18 11:06:40 UTC


@pytest.fixture(scope='module')
def made(tmp_path_factory):
    """A scene pumped 0 -> 50 mL -> 0 at 20 mL/s (5 s) and its batch bag in /rig_b."""
    folder = tmp_path_factory.mktemp('info')
    path = fast_asymmetric(folder, 'fast_asymmetric', triggers=(5.0e-6, 2.5e-5))
    bag = folder / 'bag'
    softseq_ros.run(path, bag, start_time_ns=START_NS, namespace='/rig_b')
    return path, bag


def _info(bag, capsys) -> tuple[int, str, str]:
    code = cli.main(['info', str(bag)])
    out, err = capsys.readouterr()
    return code, out, err


def _field(out: str, name: str) -> str:
    return next(line.split(':', 1)[1].strip() for line in out.splitlines()
                if line.startswith(f'{name}:'))


def test_info_shows_topics_counts_times_compression_and_the_scene(made, capsys):
    scene_path, bag = made
    code, out, err = _info(bag, capsys)
    assert code == 0, err
    with Reader(bag) as reader:
        expected = {c.topic: (c.msgtype, c.msgcount) for c in reader.connections}
        total = reader.message_count
    for topic, (type_name, count) in expected.items():
        assert f'Topic: {topic} | Type: {type_name} | Count: {count} |' in out
    assert len([line for line in out.splitlines() if 'Topic: ' in line]) == len(expected)
    assert _field(out, 'Messages') == str(total)
    assert _field(out, 'Start').endswith('(1795000000.000000000)')
    assert _field(out, 'Start').startswith('2026-11-18 11:06:40.000 UTC')
    # 0 -> 50 -> 0 mL at 20 mL/s: the last command 5 s after the first.
    assert _field(out, 'Duration') == '5.000000000 s'
    assert _field(out, 'End').endswith('(1795000005.000000000)')
    with open(next(bag.glob('*.mcap')), 'rb') as stream:
        chunks = make_reader(stream).get_summary().chunk_indexes
    assert _field(out, 'Compression') == f'{chunks[0].compression} (MCAP chunks)'
    assert _field(out, 'Complete').startswith('yes')
    assert _field(out, 'Namespaces') == '/rig_b'
    digest = segments_sha256(load_scene(scene_path).segments)
    assert _field(out, 'Scene') == (f'fast_asymmetric in /rig_b: segments bottom, top (base to '
                                    f'tip), segments SHA-256 {digest}')


def test_info_on_an_unfinished_recording_says_it_is_incomplete(made, tmp_path, capsys):
    _, bag = made
    killed = tmp_path / 'killed'
    killed.mkdir()
    mcap = next(bag.glob('*.mcap'))
    data = mcap.read_bytes()
    # What a killed recorder leaves: no metadata.yaml, the file cut before its summary.
    with open(mcap, 'rb') as stream:
        summary_start = make_reader(stream).get_summary().chunk_indexes[-1].chunk_start_offset
    (killed / mcap.name).write_bytes(data[:summary_start])
    code, out, err = _info(killed, capsys)
    assert code == 0, err
    complete = _field(out, 'Complete')
    assert complete.startswith('no: no metadata.yaml; ')
    assert f'{mcap.name} has no MCAP summary' in complete
    assert 'softseq recover' in complete
    # The scene is said at the start: an unfinished bag still names it.
    assert _field(out, 'Scene').startswith('fast_asymmetric in /rig_b: ')


def test_info_on_a_file_cut_short_beside_its_metadata_counts_what_the_file_holds(
        made, tmp_path, capsys):
    # metadata.yaml says what the writer meant to finish; a file cut short holds less, and the
    # counts shown are what a scan of the file finds.
    _, bag = made
    cut = tmp_path / 'cut'
    cut.mkdir()
    mcap = next(bag.glob('*.mcap'))
    (cut / 'metadata.yaml').write_bytes((bag / 'metadata.yaml').read_bytes())
    with open(mcap, 'rb') as stream:
        summary = make_reader(stream).get_summary()
    last = max(summary.chunk_indexes, key=lambda index: index.chunk_start_offset)
    middle = last.chunk_start_offset + last.chunk_length // 2   # the last chunk torn
    written = sum(summary.statistics.channel_message_counts.values())
    (cut / mcap.name).write_bytes(mcap.read_bytes()[:middle])
    # mcap's own stream reader on what is left, to where the cut ends it.
    kept = 0
    try:
        for record in StreamReader(io.BytesIO((cut / mcap.name).read_bytes())).records:
            kept += isinstance(record, Message)
    except Exception:  # noqa: S110 - the cut tail ends the reading
        pass
    code, out, err = _info(cut, capsys)
    assert code == 0, err
    assert 0 < kept < written
    assert _field(out, 'Messages') == str(kept)
    assert _field(out, 'Complete').startswith(f'no: {mcap.name} has no MCAP summary')


def test_info_refuses_a_damaged_or_foreign_bag_in_one_line(made, tmp_path, capsys):
    _, bag = made
    garbage = tmp_path / 'garbage'
    garbage.mkdir()
    (garbage / 'garbage_0.mcap').write_bytes(b'not an mcap file at all')
    code, out, err = _info(garbage, capsys)
    assert code == 2 and out == ''
    assert err == (f'softseq info: error: {garbage / "garbage_0.mcap"}: not an MCAP file (it '
                   'does not start with the MCAP magic)\n')

    sqlite = tmp_path / 'sqlite'
    sqlite.mkdir()
    (sqlite / 'sqlite_0.db3').write_bytes(b'SQLite format 3\x00')
    code, out, err = _info(sqlite, capsys)
    assert code == 2
    assert err == (f'softseq info: error: {sqlite}: not an MCAP bag: a sqlite3 bag '
                   '(sqlite_0.db3); softseq reads MCAP bags only\n')

    broken = tmp_path / 'broken'
    shutil.copytree(bag, broken)
    (broken / 'metadata.yaml').write_text('rosbag2_bagfile_information: {version: 9}\n',
                                          encoding='utf-8')
    code, out, err = _info(broken, capsys)
    assert code == 2 and len(err.splitlines()) == 1
    assert err.startswith(f'softseq info: error: {broken / "metadata.yaml"}: ')

    code, out, err = _info(tmp_path / 'nowhere', capsys)
    assert code == 2
    assert err == f'softseq info: error: {tmp_path / "nowhere"}: no such bag folder\n'


def _two_topic_bag(folder: Path, messages: int) -> Path:
    """A closed bag of ``messages`` messages on /a and /b, the second topic every third one."""
    with BagWriter(folder, flush_period_s=None, chunk_size=4096) as writer:
        writer.add_topic('/a', 'std_msgs/msg/Float64')
        writer.add_topic('/b', 'std_msgs/msg/Float64')
        for i in range(messages):
            writer.write('/b' if i % 3 == 2 else '/a', serialize(Float64(data=float(i))),
                         START_NS + 1000 * i)
    return folder


def _mcap_counts(bag: Path) -> dict[str, int]:
    """Messages per topic that mcap's stream reader reads in the bag's file, to where it stops."""
    counts: dict[str, int] = {}
    topics = {}
    try:
        for record in StreamReader(io.BytesIO(next(bag.glob('*.mcap')).read_bytes())).records:
            if isinstance(record, Channel):
                topics[record.id] = record.topic
            elif isinstance(record, Message):
                counts[topics[record.channel_id]] = counts.get(topics[record.channel_id], 0) + 1
    except Exception:  # noqa: S110 - a cut tail ends the reading
        pass
    return counts


@pytest.mark.parametrize('case', ['more_than_it_says', 'fewer_than_it_says', 'cut_short'])
def test_info_shows_the_scans_counts_and_what_metadata_yaml_says_where_they_disagree(
        tmp_path, capsys, case):
    # A metadata.yaml written at an earlier flush beside a file that has grown since, or one
    # of a longer recording beside a file that holds fewer: info showed metadata.yaml's counts
    # (a complete bag), or the scan's without a word of metadata.yaml (a file cut short).
    held, said = {'more_than_it_says': (300, 90), 'fewer_than_it_says': (90, 300),
                  'cut_short': (300, 300)}[case]
    bag = _two_topic_bag(tmp_path / 'bag', held)
    other = _two_topic_bag(tmp_path / 'other', said)
    (bag / 'metadata.yaml').write_bytes((other / 'metadata.yaml').read_bytes()
                                        .replace(b'other_0.mcap', b'bag_0.mcap'))
    if case == 'cut_short':
        mcap = bag / 'bag_0.mcap'
        mcap.write_bytes(mcap.read_bytes()[:mcap.stat().st_size * 2 // 3])
    expected = _mcap_counts(bag)
    assert sum(expected.values()) != said

    code, out, err = _info(bag, capsys)

    assert code == 0, err
    assert _field(out, 'Messages') == str(sum(expected.values()))
    assert _field(out, 'Counts') == (f'from a scan of the .mcap files; metadata.yaml '
                                     f'disagrees: it says {said} messages')
    for topic, count in expected.items():
        assert f'Topic: {topic} | Type: std_msgs/msg/Float64 | Count: {count} |' in out


def test_info_says_where_its_counts_come_from(tmp_path, capsys):
    bag = _two_topic_bag(tmp_path / 'bag', 300)
    code, out, err = _info(bag, capsys)
    assert code == 0, err
    assert _field(out, 'Messages') == '300'
    assert _field(out, 'Counts') == 'from metadata.yaml (the .mcap files hold as many)'
    (bag / 'metadata.yaml').unlink()
    code, out, err = _info(bag, capsys)
    assert code == 0, err
    assert _field(out, 'Messages') == '300'
    assert _field(out, 'Counts') == 'from a scan of the .mcap files (no metadata.yaml)'
