"""
A bag split by size or duration, in rosbag2's layout: several .mcap files, each a valid MCAP,
listed in metadata.yaml, read whole by the independent readers and by our own tools.
"""

from pathlib import Path

from mcap.reader import make_reader
from mcap.stream_reader import StreamReader
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest
from rosbags.highlevel import AnyReader
import yaml

import softseq_ros
from softseq_ros.bag.info import bag_info, format_info
from softseq_ros.bag.reader import bag_summary
from softseq_ros.bag.recovery import recover
from softseq_ros.bag.writer import BagWriter, BagWriterError


@pytest.fixture(scope='module')
def rig_bag(tmp_path_factory) -> Path:
    """A short batch bag of the fig1_none rig (about 5 s of rig time)."""
    out = tmp_path_factory.mktemp('split') / 'whole'
    softseq_ros.run('fig1_none', out, start_time_ns=10**18,
                    overrides={'pump': {'flow_rate_m3_per_s': 2.5e-5, 'rate_hz': 50.0},
                               'camera': {'rate_hz': 5.0}})
    return out


def _messages(bag: Path) -> list[tuple[str, int, bytes]]:
    with AnyReader([bag]) as reader:
        return [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages()]


def _copy(source: Path, target: Path, **split) -> BagWriter:
    """The messages of ``source`` written again into ``target`` by a splitting writer."""
    with AnyReader([source]) as reader:
        writer = BagWriter(target, chunk_size=4096, flush_period_s=None, **split)
        for connection in reader.connections:
            writer.add_topic(connection.topic, connection.msgtype)
        for connection, log_time, raw in reader.messages():
            writer.write(connection.topic, raw, log_time)
    writer.close()
    return writer


def _metadata(bag: Path) -> dict:
    return yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']


@pytest.mark.parametrize('split', [{'max_file_duration_s': 1.0},
                                   {'max_file_size_bytes': 20_000}])
def test_a_split_bag_is_read_whole_by_every_reader(rig_bag, tmp_path, split):
    original = _messages(rig_bag)
    writer = _copy(rig_bag, tmp_path / 'split', **split)
    bag = tmp_path / 'split'
    names = writer.file_names
    assert len(names) >= 3 and names == [f'split_{i}.mcap' for i in range(len(names))]
    assert sorted(p.name for p in bag.glob('*.mcap')) == sorted(names)
    info = _metadata(bag)
    assert info['relative_file_paths'] == names
    per_file = []
    for entry, name in zip(info['files'], names):
        # Each file a valid MCAP on its own: CRCs hold, its summary counts what it holds, and
        # it names the schema of every message in it.
        with open(bag / name, 'rb') as stream:
            count = sum(type(r).__name__ == 'Message'
                        for r in StreamReader(stream, validate_crcs=True).records)
        with open(bag / name, 'rb') as stream:
            reader = make_reader(stream, decoder_factories=[DecoderFactory()])
            statistics = reader.get_summary().statistics
            decoded = sum(1 for _ in reader.iter_decoded_messages())
        assert count == statistics.message_count == decoded == entry['message_count'] > 0
        assert entry['path'] == name
        assert entry['starting_time']['nanoseconds_since_epoch'] == \
            statistics.message_start_time
        per_file.append((statistics.message_start_time, statistics.message_end_time))
        if 'max_file_duration_s' in split:
            assert statistics.message_end_time - statistics.message_start_time < 1e9
    assert all(a[1] <= b[0] for a, b in zip(per_file, per_file[1:]))
    assert info['message_count'] == len(original)
    # The independent reader, through metadata.yaml: every message byte for byte, in time
    # order (messages of one instant may come in another order of topics).
    read = _messages(bag)
    assert sorted(read) == sorted(original)
    assert [t for _, t, _ in read] == sorted(t for _, t, _ in read)
    summary = bag_summary(bag)
    assert summary.message_count == len(original)
    assert summary.start_ns == 10**18
    text = format_info(bag_info(bag))
    assert all(name in text for name in names)
    # The analysis reads the split bag as the whole one.
    whole, parts = softseq_ros.load_recording(rig_bag), softseq_ros.load_recording(bag)
    np.testing.assert_array_equal(parts.volumes, whole.volumes)
    np.testing.assert_array_equal(parts.pump_injected, whole.pump_injected)
    assert parts.events == whole.events


def test_a_killed_split_recording_is_recovered_file_by_file(rig_bag, tmp_path):
    bag = tmp_path / 'killed'
    writer = _copy(rig_bag, bag, max_file_duration_s=1.0)
    names = writer.file_names
    counts = [entry['message_count'] for entry in _metadata(bag)['files']]
    original = _messages(bag)
    # As a SIGKILL leaves it: no metadata.yaml, the last file cut inside its data.
    (bag / 'metadata.yaml').unlink()
    last = bag / names[-1]
    with open(last, 'rb') as stream:
        chunks = make_reader(stream).get_summary().chunk_indexes
    assert len(chunks) >= 2
    data = last.read_bytes()
    last.write_bytes(data[:chunks[-1].chunk_start_offset + 20])   # torn inside its last chunk
    result = recover(bag)
    assert not result.was_complete and result.mcap_path == last
    info = _metadata(bag)
    assert info['relative_file_paths'] == names
    recovered = [entry['message_count'] for entry in info['files']]
    assert recovered[:-1] == counts[:-1] and 0 < recovered[-1] < counts[-1]
    assert result.message_count == sum(recovered) == info['message_count']
    # What was recovered is what was written: all but the end of the last file.
    kept = _messages(bag)
    assert set(kept) <= set(original) and len(set(kept)) == sum(recovered)
    cut = max(t for _, t, _ in kept)
    assert {m for m in original if m[1] < cut} <= set(kept)
    assert (bag / (names[-1] + '.truncated')).is_file()

    # A writer killed right after it opened its next file: that file holds nothing and is
    # set aside; the bag is the files before it.
    empty = bag / f'killed_{len(names)}.mcap'
    empty.write_bytes(data[:8])
    (bag / 'metadata.yaml').unlink()
    result = recover(bag)
    assert _metadata(bag)['relative_file_paths'] == names
    assert (bag / (empty.name + '.truncated')).is_file() and not empty.exists()
    assert result.message_count == sum(recovered)


def test_bad_split_limits_are_refused(tmp_path):
    with pytest.raises(BagWriterError, match='max_file_size_bytes -1: must be a byte count'):
        BagWriter(tmp_path / 'a', max_file_size_bytes=-1)
    with pytest.raises(BagWriterError, match='max_file_duration_s inf: must be a finite'):
        BagWriter(tmp_path / 'b', max_file_duration_s=float('inf'))
    writer = BagWriter(tmp_path / 'c', flush_period_s=None, max_file_duration_s=1.0)
    writer.add_topic('/x', 'std_msgs/msg/String')
    with pytest.raises(BagWriterError, match='without splitting'):
        writer.appender('/x')
    writer.close()
