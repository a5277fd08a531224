"""
Batch bags stay the same, topic by topic: the paper scene and the Fig. 1 asymmetric scene.

The fingerprints in ``data/bag_digests.json`` were taken from bags that main wrote (commit
6b18066) before the physics was split into segments / scene / quasistatic and the actuator got
its model seam. A restructuring must not change what the rig records: per topic, the message
count, the log and publish times, every integer, string and name, and the structure of every
message must be exactly as recorded; the floating-point values must agree to 1e-9 of their
magnitude. Floats are not compared bit for bit because numpy's vectorised ``log`` and ``exp``
(the Gent balloons) may differ in the last bit between CPUs; on one machine the bags are
byte-identical, and a change that moves a value by more than round-off fails here.

A change that alters the bags on purpose re-records them (``python test/test_bag_regression.py``)
and says why in its commit.
"""

from concurrent.futures import ProcessPoolExecutor
import hashlib
import json
import math
import multiprocessing
import os
from pathlib import Path
import sys

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
import pytest

from softseq_ros.batch import BatchRun

DIGESTS = Path(__file__).with_name('data') / 'bag_digests.json'
START_NS = 1_795_000_000 * 10**9   # a fixed start: the bag's times depend on nothing else
SCENES = ('paper', 'fig1_asymmetric')
RELATIVE_TOLERANCE = 1e-9
WEIGHT_PERIOD = 97   # weights 1..97 make the weighted sum sensitive to where a value changed


def _flatten(value: object, skeleton: list[str], floats: list[float]) -> None:
    """Split a decoded message into its exact skeleton and its floats, in order."""
    if isinstance(value, float):
        skeleton.append('f')
        floats.append(value)
    elif isinstance(value, bool | int):
        skeleton.append(repr(value))
    elif isinstance(value, str):
        try:
            parsed = json.loads(value)
        except ValueError:
            skeleton.append(repr(value))
            return
        skeleton.append('json')
        _flatten(parsed, skeleton, floats)
    elif isinstance(value, dict):
        for key in value:
            skeleton.append(repr(key))
            _flatten(value[key], skeleton, floats)
    elif isinstance(value, list | tuple | bytes):
        skeleton.append(f'[{len(value)}')
        if all(type(item) is float for item in value):
            floats.extend(value)
            return
        for item in value:
            _flatten(item, skeleton, floats)
    elif value is None:
        skeleton.append('None')
    else:
        skeleton.append(type(value).__name__)
        for slot in value.__slots__:
            skeleton.append(slot)
            _flatten(getattr(value, slot), skeleton, floats)


def topic_fingerprints(bag: Path) -> dict[str, dict]:
    """Per topic: message count, a digest of everything but the floats, and sums of the floats."""
    skeletons: dict[str, hashlib._Hash] = {}
    float_lists: dict[str, list[float]] = {}
    counts: dict[str, int] = {}
    with open(next(bag.glob('*.mcap')), 'rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, channel, message, decoded in reader.iter_decoded_messages(log_time_order=True):
            skeleton = [str(message.log_time), str(message.publish_time)]
            _flatten(decoded, skeleton, float_lists.setdefault(channel.topic, []))
            digest = skeletons.setdefault(channel.topic, hashlib.sha256())
            digest.update('\x1f'.join(skeleton).encode() + b'\x1e')
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
    result = {}
    for topic in sorted(skeletons):
        values = float_lists[topic]
        finite = [x for x in values if math.isfinite(x)]
        result[topic] = {
            'count': counts[topic],
            'skeleton_sha256': skeletons[topic].hexdigest(),
            'floats': len(values),
            'non_finite': [i for i, x in enumerate(values) if not math.isfinite(x)][:20],
            'sum': math.fsum(finite),
            'sum_abs': math.fsum(abs(x) for x in finite),
            'weighted_sum': math.fsum((i % WEIGHT_PERIOD + 1) * x
                                      for i, x in enumerate(values) if math.isfinite(x)),
            'min': min(finite, default=0.0),
            'max': max(finite, default=0.0),
        }
    return result


def fingerprint_scene(name: str, folder: str) -> dict[str, dict]:
    """Run a shipped scene in batch into ``folder`` and fingerprint its bag."""
    out = Path(folder) / name
    BatchRun(name, out, start_time_ns=START_NS).run()
    return topic_fingerprints(out)


def fingerprint_all(folder: str) -> dict[str, dict]:
    """Every scene's fingerprints, one process per scene (decoding is most of the time)."""
    context = multiprocessing.get_context('spawn')
    with ProcessPoolExecutor(max_workers=min(len(SCENES), os.cpu_count() or 1),
                             mp_context=context) as pool:
        futures = {name: pool.submit(fingerprint_scene, name, folder) for name in SCENES}
        return {name: future.result() for name, future in futures.items()}


@pytest.fixture(scope='module')
def fingerprints(tmp_path_factory):
    return fingerprint_all(str(tmp_path_factory.mktemp('bags')))


@pytest.mark.slow
@pytest.mark.parametrize('scene', SCENES)
def test_batch_bag_is_unchanged_topic_by_topic(scene, fingerprints):
    expected = json.loads(DIGESTS.read_text())[scene]
    found = fingerprints[scene]
    assert sorted(found) == sorted(expected)
    for topic, want in expected.items():
        got = found[topic]
        for key in ('count', 'skeleton_sha256', 'floats', 'non_finite'):
            assert got[key] == want[key], f'{topic}: {key}'
        scale = max(want['sum_abs'], 1e-300)
        for key, factor in (('sum', 1), ('sum_abs', 1), ('weighted_sum', WEIGHT_PERIOD)):
            assert got[key] == pytest.approx(want[key], rel=0,
                                             abs=RELATIVE_TOLERANCE * factor * scale), \
                f'{topic}: {key}'
        extent = max(abs(want['min']), abs(want['max']), 1e-300)
        for key in ('min', 'max'):
            assert got[key] == pytest.approx(want[key], rel=0,
                                             abs=RELATIVE_TOLERANCE * extent), f'{topic}: {key}'


if __name__ == '__main__':
    import tempfile

    with tempfile.TemporaryDirectory() as folder:
        recorded = fingerprint_all(folder)
    DIGESTS.write_text(json.dumps(recorded, indent=1, sort_keys=True) + '\n')
    sys.stdout.write(f'wrote {DIGESTS}\n')
