"""A bag from BagWriter decoded by Foxglove's TypeScript readers (@mcap/core and rosmsg2)."""

import json
import os
from pathlib import Path
import shutil
import subprocess

from geometry_msgs.msg import PoseStamped
import pytest
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, String

from softseq_ros.bag.forms import serialize
from softseq_ros.bag.writer import BagWriter

NPM_PACKAGES = ['@mcap/core', '@mcap/support', '@foxglove/rosmsg',
                '@foxglove/rosmsg2-serialization']
# Installed once per user, outside the repository; override with SOFTSEQ_TS_READER_DIR.
READER_DIR = Path(os.environ.get('SOFTSEQ_TS_READER_DIR',
                                 Path.home() / '.cache' / 'softseq_ros' / 'ts-reader'))

READ_BAG_JS = r"""
// Decode every message of an MCAP file with Foxglove's readers; print one JSON line each.
const fs = require('fs');
const { McapStreamReader } = require('@mcap/core');
const { loadDecompressHandlers } = require('@mcap/support');
const { parse } = require('@foxglove/rosmsg');
const { MessageReader } = require('@foxglove/rosmsg2-serialization');

function plain(value) {
  if (typeof value === 'bigint') return value.toString();
  if (ArrayBuffer.isView(value)) return Array.from(value, plain);
  if (Array.isArray(value)) return value.map(plain);
  if (value && typeof value === 'object') {
    return Object.fromEntries(Object.entries(value).map(([k, v]) => [k, plain(v)]));
  }
  return value;
}

(async () => {
  const reader = new McapStreamReader({
    decompressHandlers: await loadDecompressHandlers(), validateCrcs: true });
  reader.append(fs.readFileSync(process.argv[2]));
  const schemas = new Map();
  const channels = new Map();
  const decoders = new Map();
  let record;
  while ((record = reader.nextRecord())) {
    if (record.type === 'Header') {
      console.log(JSON.stringify({ profile: record.profile }));
    } else if (record.type === 'Schema') {
      schemas.set(record.id, record);
    } else if (record.type === 'Channel') {
      channels.set(record.id, record);
      const text = new TextDecoder().decode(schemas.get(record.schemaId).data);
      decoders.set(record.id, new MessageReader(parse(text, { ros2: true })));
    } else if (record.type === 'Message') {
      const channel = channels.get(record.channelId);
      const schema = schemas.get(channel.schemaId);
      console.log(JSON.stringify({
        topic: channel.topic, schema: schema.name, schemaEncoding: schema.encoding,
        messageEncoding: channel.messageEncoding, logTime: record.logTime.toString(),
        publishTime: record.publishTime.toString(),
        message: plain(decoders.get(record.channelId).readMessage(record.data)),
      }));
    }
  }
  if (!reader.done()) throw new Error('MCAP stream ended early');
})().catch((err) => { console.error(String(err)); process.exit(1); });
"""


def _reader_dir() -> Path:
    if shutil.which('node') is None or shutil.which('npm') is None:
        pytest.skip('node/npm not installed: Foxglove TypeScript readers not checked')
    modules = READER_DIR / 'node_modules'
    if not all((modules / name / 'package.json').is_file() for name in NPM_PACKAGES):
        READER_DIR.mkdir(parents=True, exist_ok=True)
        if not (READER_DIR / 'package.json').exists():
            (READER_DIR / 'package.json').write_text(
                '{"name": "softseq-ts-reader", "private": true}\n')
        try:
            done = subprocess.run(
                ['npm', 'install', '--no-audit', '--no-fund', '--ignore-scripts', *NPM_PACKAGES],
                cwd=READER_DIR, capture_output=True, text=True, timeout=300)
        except subprocess.TimeoutExpired:
            pytest.skip('npm registry did not answer within 300 s')
        if done.returncode != 0:
            last = (done.stderr.strip().splitlines() or ['no output'])[-1]
            pytest.skip(f'npm install of the Foxglove readers failed (registry unreachable?): '
                        f'{last}')
    return READER_DIR


@pytest.mark.parametrize('compression', ['zstd', 'lz4', None])
def test_foxglove_typescript_readers_decode_the_bag(tmp_path, compression):
    reader_dir = _reader_dir()
    pose = PoseStamped()
    pose.header.stamp.sec = 12
    pose.header.stamp.nanosec = 345
    pose.header.frame_id = 'camera'
    pose.pose.position.y = -0.05
    pose.pose.orientation.w = 1.0
    joints = JointState()
    joints.name = ['bottom', 'top']
    joints.position = [0.25, -0.5]
    written = [
        ('/pump/injected_volume', 'std_msgs/msg/Float64', Float64(data=2.5e-5), 1000, 990),
        ('/rig/phase', 'std_msgs/msg/String', String(data='deflating'), 2000, 1990),
        ('/camera/tip_pose', 'geometry_msgs/msg/PoseStamped', pose, 3000, 2990),
        ('/actuator/joints', 'sensor_msgs/msg/JointState', joints, 4000, 3990),
    ]
    bag = tmp_path / 'bag'
    with BagWriter(bag, compression=compression) as writer:
        for topic, type_name, msg, log, publish in written:
            writer.add_topic(topic, type_name)
            writer.write(topic, serialize(msg), log, publish)
    script = tmp_path / 'read_bag.cjs'
    script.write_text(READ_BAG_JS)
    env = dict(os.environ, NODE_PATH=str(reader_dir / 'node_modules'))
    done = subprocess.run(['node', str(script), str(bag / 'bag_0.mcap')], env=env,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    lines = [json.loads(line) for line in done.stdout.splitlines()]
    assert lines[0] == {'profile': 'ros2'}
    decoded = lines[1:]
    assert [(d['topic'], d['schema'], d['schemaEncoding'], d['messageEncoding'],
             int(d['logTime']), int(d['publishTime'])) for d in decoded] == [
        (topic, type_name, 'ros2msg', 'cdr', log, publish)
        for topic, type_name, _, log, publish in written]
    assert decoded[0]['message'] == {'data': 2.5e-5}
    assert decoded[1]['message'] == {'data': 'deflating'}
    assert decoded[2]['message']['header'] == {'stamp': {'sec': 12, 'nanosec': 345},
                                               'frame_id': 'camera'}
    assert decoded[2]['message']['pose']['position'] == {'x': 0.0, 'y': -0.05, 'z': 0.0}
    assert decoded[3]['message']['name'] == ['bottom', 'top']
    assert decoded[3]['message']['position'] == [0.25, -0.5]
    assert decoded[3]['message']['velocity'] == []
