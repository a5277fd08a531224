"""
Batch bags stay the same, topic by topic: the paper scene and the Fig. 1 asymmetric scene.

The digests in ``data/bag_digests.json`` were taken from bags that main wrote (commit 6b18066)
before the physics was split into segments / scene / quasistatic and the actuator got its
model seam; a restructuring must not change a single byte of what the rig records. A change
that alters the bags on purpose re-records them (``python test/test_bag_regression.py``) and
says why in its commit.
"""

import hashlib
import json
from pathlib import Path
import sys

from mcap.reader import make_reader
import pytest

from softseq_ros.batch import BatchRun

DIGESTS = Path(__file__).with_name('data') / 'bag_digests.json'
START_NS = 1_795_000_000 * 10**9   # a fixed start: the bag's times depend on nothing else
SCENES = ('paper', 'fig1_asymmetric')


def topic_digests(bag: Path) -> dict[str, dict]:
    """Per topic: message count and SHA-256 over (log time, publish time, CDR bytes) in order."""
    hashes: dict[str, hashlib._Hash] = {}
    counts: dict[str, int] = {}
    with open(next(bag.glob('*.mcap')), 'rb') as stream:
        for _, channel, message in make_reader(stream).iter_messages(log_time_order=True):
            digest = hashes.setdefault(channel.topic, hashlib.sha256())
            digest.update(message.log_time.to_bytes(8, 'little'))
            digest.update(message.publish_time.to_bytes(8, 'little'))
            digest.update(len(message.data).to_bytes(8, 'little'))
            digest.update(message.data)
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
    return {topic: {'count': counts[topic], 'sha256': hashes[topic].hexdigest()}
            for topic in sorted(hashes)}


def run_scene(name: str, out: Path) -> Path:
    BatchRun(name, out, start_time_ns=START_NS).run()
    return out


@pytest.mark.slow
@pytest.mark.parametrize('scene', SCENES)
def test_batch_bag_is_unchanged_topic_by_topic(scene, tmp_path):
    expected = json.loads(DIGESTS.read_text())[scene]
    found = topic_digests(run_scene(scene, tmp_path / scene))
    assert sorted(found) == sorted(expected)
    for topic in expected:
        assert found[topic] == expected[topic], topic


if __name__ == '__main__':
    import tempfile

    with tempfile.TemporaryDirectory() as folder:
        recorded = {name: topic_digests(run_scene(name, Path(folder) / name)) for name in SCENES}
    DIGESTS.write_text(json.dumps(recorded, indent=1, sort_keys=True) + '\n')
    sys.stdout.write(f'wrote {DIGESTS}\n')
