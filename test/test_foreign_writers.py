"""
A rig's messages written by the other writers of the environment, read back as the rig's own.

rosbags (a rosbag2 folder with MCAP storage and its metadata.yaml), mcap's Python writer,
mcap-ros2-support's writer and Foxglove's TypeScript writer (@mcap/core's McapWriter; a bare
MCAP file each) copy a rig bag's messages; ``softseq info`` counts them, ``softseq recover``
keeps every one, ``softseq report`` finds what the rig's own bag gives, and ``softseq play``
publishes them all.
"""

import json
from pathlib import Path
import re
import subprocess
import sys

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest
from scenes import fast_asymmetric_bag

import softseq_ros
from softseq_ros.nodes.player import BagPlayer
from softseq_ros.testing import spinning

START_NS = 1_795_000_000 * 10**9
WRITERS = ('rosbags', 'mcap', 'mcap_ros2', 'foxglove')
# Copy an MCAP file's schemas, channels and messages with Foxglove's TypeScript writer.
COPY_BAG_JS = r"""
const fs = require('fs');
const { McapStreamReader, McapWriter } = require('@mcap/core');
const { loadDecompressHandlers } = require('@mcap/support');

class Memory {
  constructor() { this.parts = []; this.size = 0n; }
  position() { return this.size; }
  async write(buffer) {
    this.parts.push(Buffer.from(buffer));
    this.size += BigInt(buffer.byteLength);
  }
}

(async () => {
  const reader = new McapStreamReader({ decompressHandlers: await loadDecompressHandlers() });
  reader.append(fs.readFileSync(process.argv[2]));
  const out = new Memory();
  const writer = new McapWriter({ writable: out });
  await writer.start({ profile: 'ros2', library: 'Foxglove @mcap/core McapWriter' });
  const schemas = new Map();
  const channels = new Map();
  let record;
  while ((record = reader.nextRecord())) {
    if (record.type === 'Schema') {
      schemas.set(record.id, await writer.registerSchema(
        { name: record.name, encoding: record.encoding, data: record.data }));
    } else if (record.type === 'Channel') {
      channels.set(record.id, await writer.registerChannel({
        topic: record.topic, messageEncoding: record.messageEncoding,
        schemaId: schemas.get(record.schemaId), metadata: record.metadata }));
    } else if (record.type === 'Message') {
      await writer.addMessage({
        channelId: channels.get(record.channelId), sequence: record.sequence,
        logTime: record.logTime, publishTime: record.publishTime, data: record.data });
    }
  }
  await writer.end();
  fs.writeFileSync(process.argv[3], Buffer.concat(out.parts));
})().catch((err) => { console.error(String(err)); process.exit(1); });
"""


@pytest.fixture(scope='module')
def rig_bag(tmp_path_factory) -> Path:
    """A real rig bag: the Fig. 1 asymmetric pair over 5 s, two snaps each way."""
    return fast_asymmetric_bag(tmp_path_factory.mktemp('rig'), 'foreign_writers', START_NS)


def _read(bag: Path) -> tuple[list, dict, dict]:
    """The bag's messages in log-time order, and its channels and schemas by id."""
    with open(next(bag.glob('*.mcap')), 'rb') as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        messages = [(channel.id, message.log_time, message.publish_time, bytes(message.data))
                    for _, channel, message in reader.iter_messages(log_time_order=True)]
    return messages, summary.channels, summary.schemas


def _write_rosbags(out: Path, bag: Path) -> int:
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.rosbag2.metadata import parse_qos
    from rosbags.typesys import Stores, get_typestore

    types = get_typestore(Stores.ROS2_JAZZY)

    messages, channels, schemas = _read(bag)
    with Writer(out, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connections = {}
        for cid, channel in channels.items():
            schema = schemas[channel.schema_id]
            qos = channel.metadata.get('offered_qos_profiles', '')
            connections[cid] = writer.add_connection(
                channel.topic, schema.name, typestore=types,
                offered_qos_profiles=parse_qos(qos) if qos else ())
        for cid, log_time, _, data in messages:
            writer.write(connections[cid], log_time, data)
    return len(messages)


def _write_mcap(out: Path, bag: Path) -> int:
    from mcap.writer import Writer

    messages, channels, schemas = _read(bag)
    out.mkdir()
    with open(out / 'copy.mcap', 'wb') as stream:
        writer = Writer(stream)
        writer.start(profile='ros2', library='mcap python writer')
        schema_ids = {sid: writer.register_schema(s.name, s.encoding, s.data)
                      for sid, s in schemas.items()}
        ids = {cid: writer.register_channel(c.topic, c.message_encoding,
                                            schema_ids[c.schema_id], c.metadata)
               for cid, c in channels.items()}
        for cid, log_time, publish_time, data in messages:
            writer.add_message(ids[cid], log_time, data, publish_time)
        writer.finish()
    return len(messages)


def _write_mcap_ros2(out: Path, bag: Path) -> int:
    from mcap_ros2.writer import Writer

    messages, channels, schemas = _read(bag)
    decoders = DecoderFactory()
    out.mkdir()
    with open(out / 'copy.mcap', 'wb') as stream:
        writer = Writer(stream)
        registered = {sid: writer.register_msgdef(s.name, s.data.decode())
                      for sid, s in schemas.items()}
        for cid, log_time, publish_time, data in messages:
            channel = channels[cid]
            schema = schemas[channel.schema_id]
            decoded = decoders.decoder_for(channel.message_encoding, schema)(data)
            writer.write_message(channel.topic, registered[channel.schema_id], decoded,
                                 log_time, publish_time)
        writer.finish()
    return len(messages)


def _write_foxglove(out: Path, bag: Path) -> int:
    from test_bag_foxglove import _reader_dir

    reader_dir = _reader_dir()
    script = reader_dir / 'copy_bag.js'
    script.write_text(COPY_BAG_JS)
    out.mkdir()
    done = subprocess.run(['node', str(script), str(next(bag.glob('*.mcap'))),
                           str(out / 'copy.mcap')], cwd=reader_dir, capture_output=True,
                          text=True, timeout=120, stdin=subprocess.DEVNULL)
    assert done.returncode == 0, done.stderr
    return len(_read(bag)[0])


def _copy(writer: str, out: Path, bag: Path) -> int:
    return {'rosbags': _write_rosbags, 'mcap': _write_mcap, 'mcap_ros2': _write_mcap_ros2,
            'foxglove': _write_foxglove}[writer](out, bag)


def softseq(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, '-m', 'softseq_ros.cli', *args], capture_output=True,
                          text=True, timeout=300, stdin=subprocess.DEVNULL)


def _numbers(metrics: dict) -> dict:
    """The metrics' numbers and words, without what names the file they came from."""
    return {key: value for key, value in metrics.items()
            if key not in ('bag', 'source', 'provenance', 'recorded_by')}


@pytest.fixture(scope='module')
def own_metrics(rig_bag, tmp_path_factory) -> dict:
    out = tmp_path_factory.mktemp('own_report')
    metrics, _ = softseq_ros.report(rig_bag, out)
    return metrics


@pytest.mark.parametrize('writer', WRITERS)
def test_another_writer_s_copy_is_counted_recovered_and_reported_as_the_rig_s_own(
        rig_bag, own_metrics, tmp_path, writer):
    copy = tmp_path / 'copy'
    count = _copy(writer, copy, rig_bag)
    info = softseq('info', str(copy))
    assert info.returncode == 0, info.stderr
    assert re.search(rf'^Messages: +{count}$', info.stdout, re.MULTILINE), info.stdout
    recovered = softseq('recover', str(copy))
    assert recovered.returncode == 0, recovered.stderr
    assert not list(copy.glob('*.truncated'))
    whole, theirs = softseq_ros.load_recording(rig_bag), softseq_ros.load_recording(copy)
    np.testing.assert_array_equal(theirs.pump_injected, whole.pump_injected)
    np.testing.assert_array_equal(theirs.volumes, whole.volumes)
    assert len(theirs.events) == len(whole.events) > 0
    report = softseq('report', str(copy), '--out', str(tmp_path / 'report'))
    assert report.returncode == 0, report.stderr
    metrics = json.loads((tmp_path / 'report' / 'metrics.json').read_text())
    mine = _numbers(json.loads(json.dumps(own_metrics)))
    theirs_numbers = _numbers(metrics)
    assert theirs_numbers.keys() == mine.keys()
    differing = [key for key in mine if mine[key] != theirs_numbers[key]]
    assert differing == [], {key: (mine[key], theirs_numbers[key]) for key in differing}


@pytest.mark.ros
@pytest.mark.parametrize('writer', WRITERS)
def test_another_writer_s_copy_is_played_whole(context, rig_bag, tmp_path, writer):
    copy = tmp_path / 'copy'
    count = _copy(writer, copy, rig_bag)
    player = BagPlayer(str(copy), rate=1000.0, clock=False, context=context)
    try:
        with spinning(context, player):
            result = player.play()
    finally:
        player.destroy_node()
    assert result.messages == count
