"""Foreign messages in a rig bag: the analysis skips what it cannot use, says so, or refuses."""

import json
from pathlib import Path
import subprocess
import sys
from typing import Callable, Iterable

from mcap.reader import make_reader
import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore
from scenes import fast_asymmetric_bag

import softseq_ros
from softseq_ros.analysis.recording import MAX_PAYLOAD_BYTES
from softseq_ros.bag.writer import BagWriter
from softseq_ros.wire import contract
from softseq_ros.wire.cdr import joint_state_cdr, string_cdr

CONFIG = Path(__file__).resolve().parents[1] / 'config'
START_NS = 1_795_000_000 * 10**9
COMMAND = contract.resolve(contract.PUMP_COMMAND.name, '/')
VOLUMES = contract.resolve(contract.VOLUMES.name, '/')
EVENTS = contract.resolve(contract.EVENTS.name, '/')
JOINT_STATE = 'sensor_msgs/msg/JointState'
TYPES = get_typestore(Stores.ROS2_JAZZY)

Message = tuple[str, int, bytes]                  # topic, log time, CDR bytes
Edit = Callable[[str, int, bytes], Iterable[Message]]


@pytest.fixture(scope='module')
def rig_bag(tmp_path_factory) -> Path:
    """A real rig bag: the Fig. 1 asymmetric pair over 5 s, two snaps each way."""
    return fast_asymmetric_bag(tmp_path_factory.mktemp('rig'), 'foreign_asymmetric', START_NS)


def rewrite(source: Path, target: Path, edit: Edit) -> Path:
    """Copy a bag with our writer, each message replaced by what ``edit`` makes of it."""
    with open(next(source.glob('*.mcap')), 'rb') as stream, \
            BagWriter(target, flush_period_s=None) as writer:
        reader = make_reader(stream)
        for channel in reader.get_summary().channels.values():
            schema = reader.get_summary().schemas[channel.schema_id]
            writer.add_topic(channel.topic, schema.name,
                             channel.metadata.get('offered_qos_profiles', ''))
        for _, channel, message in reader.iter_messages(log_time_order=True):
            for topic, log_time, data in edit(channel.topic, message.log_time,
                                              bytes(message.data)):
                writer.write(topic, data, log_time)
    return target


def with_joint_state(data: bytes, **fields: list[float]) -> bytes:
    """A JointState's CDR bytes with some of its arrays replaced."""
    message = TYPES.deserialize_cdr(data, JOINT_STATE)
    for name, values in fields.items():
        setattr(message, name, np.array(values, dtype=np.float64))
    return bytes(TYPES.serialize_cdr(message, JOINT_STATE))


def no_position(data: bytes) -> bytes:
    message = TYPES.deserialize_cdr(data, JOINT_STATE)
    return joint_state_cdr(message.header.stamp.sec, message.header.stamp.nanosec,
                           message.header.frame_id, message.name, [], list(message.velocity),
                           list(message.effort))


def softseq(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, '-m', 'softseq_ros.cli', *args], capture_output=True,
                          text=True, timeout=300, stdin=subprocess.DEVNULL)


def report(bag: Path, out: Path) -> tuple[dict, str]:
    """Report the bag (it must succeed); its metrics.json and summary.txt."""
    result = softseq('report', str(bag), '--out', str(out))
    assert result.returncode == 0, result.stderr
    assert 'Traceback' not in result.stderr
    return json.loads((out / 'metrics.json').read_text()), (out / 'summary.txt').read_text()


def every(count: int, each: int) -> Callable[[], bool]:
    """True for the first ``count`` of every ``each``-th call."""
    calls = [0, 0]

    def pick() -> bool:
        calls[0] += 1
        if calls[0] % each == 0 and calls[1] < count:
            calls[1] += 1
            return True
        return False
    return pick


def test_pump_commands_without_positions_are_skipped_and_said(rig_bag, tmp_path):
    # A foreign publisher on the command topic: three JointStates without positions beside
    # the pump's own, at the pump's times.
    pick = every(3, 40)

    def edit(topic, log_time, data):
        yield topic, log_time, data
        if topic == COMMAND and pick():
            yield topic, log_time, no_position(data)
    bag = rewrite(rig_bag, tmp_path / 'foreign', edit)
    metrics, summary = report(bag, tmp_path / 'report')
    line = f'{COMMAND}: 3 messages skipped (no position)'
    assert line in metrics['warnings'] and line in summary
    assert metrics['skipped_as_unusable'] == {COMMAND: {'no position': 3}}
    original, _ = report(rig_bag, tmp_path / 'original')
    assert metrics['snap_count'] == original['snap_count']
    compared = softseq('compare', str(rig_bag), str(bag))
    assert compared.returncode == 0, compared.stderr
    assert f'B skipped:\n- {line}' in compared.stdout
    assert 'A skipped' not in compared.stdout


def test_nan_and_infinite_volumes_and_pressures_are_skipped_and_said(rig_bag, tmp_path):
    pick, changed = every(5, 30), []

    def edit(topic, log_time, data):
        if topic == VOLUMES and pick():
            # A NaN pressure (effort) in some, an infinite volume (position) in the others.
            message = TYPES.deserialize_cdr(data, JOINT_STATE)
            if len(changed) % 2:
                data = with_joint_state(data, position=list(message.position[:-1]) + [np.inf])
            else:
                data = with_joint_state(data, effort=[np.nan] + list(message.effort[1:]))
            changed.append(log_time)
        yield topic, log_time, data
    bag = rewrite(rig_bag, tmp_path / 'nan', edit)
    metrics, summary = report(bag, tmp_path / 'report')
    line = f'{VOLUMES}: 5 messages skipped (position or effort not finite (NaN or infinite))'
    assert line in metrics['warnings'] and line in summary
    assert np.isfinite(metrics['peak_injection']['pressure_pa'])
    compared = softseq('compare', str(bag), str(rig_bag))
    assert compared.returncode == 0, compared.stderr
    assert f'A skipped:\n- {line}' in compared.stdout


def test_an_event_of_megabytes_is_skipped_and_said(rig_bag, tmp_path):
    inserted = []

    def edit(topic, log_time, data):
        yield topic, log_time, data
        if topic == EVENTS and not inserted:
            # Valid JSON of a snap-through, padded to 2 MB: no rig message is that large.
            text = json.loads(string_text(data))
            text['padding'] = 'x' * 2_000_000
            inserted.append(log_time)
            yield topic, log_time, string_cdr(json.dumps(text))
    bag = rewrite(rig_bag, tmp_path / 'large', edit)
    assert inserted
    metrics, summary = report(bag, tmp_path / 'report')
    line = f'{EVENTS}: 1 message skipped (larger than {MAX_PAYLOAD_BYTES} bytes)'
    assert line in metrics['warnings'] and line in summary
    original, _ = report(rig_bag, tmp_path / 'original')
    assert metrics['snap_events_topic'] == original['snap_events_topic']


def string_text(data: bytes) -> str:
    length = int.from_bytes(data[4:8], 'little')
    return data[8:8 + length - 1].decode()


@pytest.mark.parametrize('topic, make, why', [
    (COMMAND, no_position, 'no position'),
    (VOLUMES, lambda data: with_joint_state(data, effort=[float('nan')] * 2),
     'position or effort not finite (NaN or infinite)'),
], ids=['commands-without-positions', 'nan-pressures'])
def test_nothing_usable_left_is_refused_in_one_line(rig_bag, tmp_path, topic, make, why):
    count = []

    def edit(name, log_time, data):
        if name == topic:
            count.append(1)
            data = make(data)
        yield name, log_time, data
    bag = rewrite(rig_bag, tmp_path / 'unusable', edit)
    for command in (('report', str(bag), '--out', str(tmp_path / 'out')),
                    ('compare', str(rig_bag), str(bag))):
        result = softseq(*command)
        assert result.returncode == 2, result.stderr
        assert result.stderr == (f'softseq {command[0]}: error: {bag}: no usable {topic} '
                                 f'messages: all skipped ({len(count)} {why})\n')
    assert not (tmp_path / 'out').exists()


def test_recover_keeps_every_message_of_a_complete_unchunked_bag(rig_bag, tmp_path):
    # Some writers put every record at the top level, with no chunks, and no metadata.yaml
    # beside the file (messages in the order they came): recover must keep every message, and
    # only add the metadata.
    from mcap.writer import Writer

    from softseq_ros.bag.recovery import recover

    folder = tmp_path / 'unchunked'
    folder.mkdir()
    source = next(rig_bag.glob('*.mcap'))
    with open(source, 'rb') as stream, open(folder / 'unchunked.mcap', 'wb') as out:
        reader, writer = make_reader(stream), Writer(out, use_chunking=False)
        writer.start(profile='ros2', library='another writer')
        summary = reader.get_summary()
        schemas = {i: writer.register_schema(s.name, s.encoding, s.data)
                   for i, s in summary.schemas.items()}
        channels = {i: writer.register_channel(c.topic, c.message_encoding,
                                               schemas[c.schema_id], c.metadata)
                    for i, c in summary.channels.items()}
        count = 0
        for _, channel, message in reader.iter_messages(log_time_order=True):
            writer.add_message(channels[channel.id], message.log_time, message.data,
                               message.publish_time)
            count += 1
        writer.finish()
    result = recover(folder)
    assert result.was_complete and result.message_count == count
    assert not list(folder.glob('*.truncated'))
    whole, copy = softseq_ros.load_recording(rig_bag), softseq_ros.load_recording(folder)
    np.testing.assert_array_equal(copy.pump_injected, whole.pump_injected)
    np.testing.assert_array_equal(copy.volumes, whole.volumes)
    assert len(copy.events) == len(whole.events) > 0
