"""
Batch bags stay the same, topic by topic: the paper scene and the Fig. 1 asymmetric scene.

The fingerprints in ``data/bag_digests.json`` were taken from bags that main wrote (commit
6b18066) before the physics was split into segments / scene / quasistatic and the actuator got
its model seam, and re-recorded once since: when the camera's triggers stopped depending on the
last bits of the volumes' sum (a snapshot moved by one command in the scenes whose pump steps
exactly onto a trigger). A restructuring must not change what the rig records: per topic, the
message count, the log and publish times, every integer, string and name, and the structure of
every message must be exactly as recorded; the floating-point values must agree to 1e-9 of their
magnitude. Floats are not compared bit for bit because numpy's vectorised ``log`` and ``exp``
(the Gent balloons) may differ in the last bit between CPUs; on one machine the bags are
byte-identical, and a change that moves a value by more than round-off fails here.

A change that alters the bags on purpose re-records them (``python test/test_bag_regression.py``)
and says why in its commit.
"""

from concurrent.futures import ProcessPoolExecutor
import dataclasses
import functools
import hashlib
import itertools
import json
import math
import multiprocessing
import operator
import os
from pathlib import Path
import sys
from typing import Callable

from mcap.reader import make_reader
import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

import softseq_ros

DIGESTS = Path(__file__).with_name('data') / 'bag_digests.json'
START_NS = 1_795_000_000 * 10**9   # a fixed start: the bag's times depend on nothing else
SCENES = ('paper', 'fig1_asymmetric')
RELATIVE_TOLERANCE = 1e-9
WEIGHT_PERIOD = 97   # weights 1..97 make the weighted sum sensitive to where a value changed


def _float_template(value: object) -> tuple[str, Callable[[object], tuple]] | None:
    """
    For a message type made of floats only (Pose, Point, ...): its skeleton and a float getter.

    A type whose fields are floats and nested such types has one structure for every instance,
    so its skeleton is built once and its floats are read with one getter: the camera's pose
    arrays are most of the floats of a bag.
    """
    cls = type(value)
    if cls in _TEMPLATES:
        return _TEMPLATES[cls]
    if not dataclasses.is_dataclass(value):
        return None
    tokens: list[str] = []
    paths: list[str] = []

    def walk(message: object, prefix: str) -> bool:
        tokens.append(type(message).__name__)
        for field in dataclasses.fields(message):
            tokens.append(field.name)
            item = getattr(message, field.name)
            if type(item) is float:
                tokens.append('f')
                paths.append(prefix + field.name)
            elif not (dataclasses.is_dataclass(item) and walk(item, f'{prefix}{field.name}.')):
                return False
        return True

    template = None
    if walk(value, '') and len(paths) > 1:
        template = ('\x1f'.join(tokens), operator.attrgetter(*paths))
    _TEMPLATES[cls] = template
    return template


_TEMPLATES: dict[type, tuple[str, Callable[[object], tuple]] | None] = {}


@functools.cache
def _field_names(cls: type) -> tuple[str, ...]:
    return tuple(field.name for field in dataclasses.fields(cls))


def _flatten(value: object, skeleton: list[str], floats: list[float]) -> None:
    """Split a decoded message into its exact skeleton and its floats, in order."""
    if isinstance(value, float):
        skeleton.append('f')
        floats.append(value)
    elif isinstance(value, bool | int):
        skeleton.append(repr(value))
    elif isinstance(value, str):
        # The rig's JSON payloads are objects; names, frames and texts are kept as they are.
        if value[:1] != '{':
            skeleton.append(repr(value))
            return
        skeleton.append('json')
        _flatten(json.loads(value), skeleton, floats)
    elif isinstance(value, dict):
        for key in value:
            skeleton.append(repr(key))
            _flatten(value[key], skeleton, floats)
    elif isinstance(value, np.ndarray):
        skeleton.append(f'[{value.size}:{value.dtype.str}')
        if value.dtype.kind == 'f':
            floats.extend(value.tolist())
        else:
            skeleton.append(value.tobytes().hex())
    elif isinstance(value, list | tuple):
        skeleton.append(f'[{len(value)}')
        if value and all(type(item) is float for item in value):
            floats.extend(value)
            return
        template = _float_template(value[0]) if value else None
        if template is not None and all(type(item) is type(value[0]) for item in value):
            skeleton.extend(template[0] for _ in value)
            floats.extend(itertools.chain.from_iterable(map(template[1], value)))
            return
        for item in value:
            _flatten(item, skeleton, floats)
    elif value is None:
        skeleton.append('None')
    elif dataclasses.is_dataclass(value):
        template = _float_template(value)
        if template is not None:
            skeleton.append(template[0])
            floats.extend(template[1](value))
            return
        skeleton.append(type(value).__name__)
        for name in _field_names(type(value)):
            skeleton.append(name)
            _flatten(getattr(value, name), skeleton, floats)
    else:
        raise TypeError(f'cannot fingerprint a {type(value).__name__}')


def topic_fingerprints(bag: Path) -> dict[str, dict]:
    """Per topic: message count, a digest of everything but the floats, and sums of the floats."""
    typestore = get_typestore(Stores.ROS2_JAZZY)
    skeletons: dict[str, hashlib._Hash] = {}
    float_lists: dict[str, list[float]] = {}
    counts: dict[str, int] = {}
    with open(next(bag.glob('*.mcap')), 'rb') as stream:
        for schema, channel, message in make_reader(stream).iter_messages(log_time_order=True):
            decoded = typestore.deserialize_cdr(message.data, schema.name)
            skeleton = [str(message.log_time), str(message.publish_time)]
            _flatten(decoded, skeleton, float_lists.setdefault(channel.topic, []))
            digest = skeletons.setdefault(channel.topic, hashlib.sha256())
            digest.update('\x1f'.join(skeleton).encode() + b'\x1e')
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
    result = {}
    for topic in sorted(skeletons):
        values = np.asarray(float_lists[topic], dtype=np.float64)
        finite = values[np.isfinite(values)]
        weights = np.arange(values.size) % WEIGHT_PERIOD + 1
        result[topic] = {
            'count': counts[topic],
            'skeleton_sha256': skeletons[topic].hexdigest(),
            'floats': int(values.size),
            'non_finite': np.flatnonzero(~np.isfinite(values))[:20].tolist(),
            'sum': math.fsum(finite.tolist()),
            'sum_abs': math.fsum(np.abs(finite).tolist()),
            'weighted_sum': math.fsum((weights[np.isfinite(values)] * finite).tolist()),
            'min': float(finite.min()) if finite.size else 0.0,
            'max': float(finite.max()) if finite.size else 0.0,
        }
    return result


def fingerprint_scene(name: str, folder: str) -> dict[str, dict]:
    """Run a shipped scene in batch into ``folder`` and fingerprint its bag."""
    out = Path(folder) / name
    softseq_ros.run(name, out, start_time_ns=START_NS)
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
