"""
The JSON in the rig's std_msgs/String topics: one codec per value type, both ways.

Each String topic's payload is defined once, in :mod:`softseq_ros.wire.payloads`, and both written
(nodes, batch bags) and read (the analysis) through it. Checked here: every String topic has a
codec and every writer uses it; what is encoded decodes to the same value; the bytes are the
ones bags have always held; a key the encoder writes is one the decoder needs; garbage is one
line naming the topic and the key, for a direct caller and through a recording.
"""

import dataclasses
import json
import math
import subprocess
import sys

from hypothesis import given, settings
from hypothesis import strategies as st
import numpy as np
import pytest

from softseq_ros.analysis import recording as recording_module
from softseq_ros.analysis.recording import RecordingError, load_recording
from softseq_ros.bag.writer import BagWriter
from softseq_ros.errors import UserError
from softseq_ros.wire import contract
from softseq_ros.wire.cdr import string_cdr
from softseq_ros.wire.payloads import (
    ENCODERS,
    JSON_PAYLOADS,
    JSON_PAYLOADS_BY_TOPIC,
    PUMP_STATUS_JSON,
    SCENE_IDENTITY_JSON,
    SNAP_THROUGH_JSON,
    SNAPSHOT_STEP_JSON,
    STAMP_KEY,
    InputError,
    JsonPayload,
    PayloadError,
    encode,
)
from softseq_ros.wire.values import (
    TOPIC_VALUE_TYPES,
    PumpCommand,
    PumpStatus,
    SceneIdentity,
    SegmentVolumes,
    Snapshot,
    SnapshotStep,
    SnapThrough,
)

EXAMPLES = settings(max_examples=150, deadline=None, derandomize=True, database=None)
STRING_TYPE = 'std_msgs/msg/String'
CODECS = list(JSON_PAYLOADS.values())
CODEC_IDS = [codec.value_type.__name__ for codec in CODECS]
SHA = 'a3' * 32

# ------------------------------------------------------------------------------- the values

stamps = st.integers(-2**63, 2**63 - 1)
numbers = st.floats(allow_nan=True, allow_infinity=True)
texts = st.text(max_size=30)
VALUES = {
    PumpStatus: st.builds(PumpStatus, stamps, texts, texts),
    SnapThrough: st.builds(SnapThrough, stamps, numbers, st.lists(numbers, max_size=6),
                           st.lists(numbers, max_size=6), numbers, numbers),
    SceneIdentity: st.builds(SceneIdentity, stamps, texts,
                             st.lists(texts, max_size=5).map(tuple),
                             st.text('0123456789abcdef', min_size=64, max_size=64)),
    SnapshotStep: st.builds(SnapshotStep, stamps, st.integers(-2**63, 2**63 - 1), numbers,
                            st.sampled_from(('inflation', 'deflation')), numbers),
}
EXAMPLE = {
    PumpStatus: PumpStatus(1_795_000_000_123_456_789, 'held', 'no pressure for 2.0 s'),
    SnapThrough: SnapThrough(5, 2.25e-05, [1.5e-05, 2e-05], [3e-05, 7.5e-06], 1234.5, 987.25),
    SceneIdentity: SceneIdentity(7, 'paper', ('bottom', 'top'), SHA),
    SnapshotStep: SnapshotStep(9, 3, 1e-05, 'deflation', 1.2500000000000002e-05),
}
# The texts bags hold for EXAMPLE: the format written before there was one codec.
EXAMPLE_TEXT = {
    PumpStatus: '{"state": "held", "reason": "no pressure for 2.0 s", '
                '"stamp_ns": 1795000000123456789}',
    SnapThrough: '{"injected_m3": 2.25e-05, "from_volumes_m3": [1.5e-05, 2e-05], '
                 '"to_volumes_m3": [3e-05, 7.5e-06], "from_pressure_pa": 1234.5, '
                 '"to_pressure_pa": 987.25}',
    SceneIdentity: f'{{"scene": "paper", "segments": ["bottom", "top"], "segments_sha256": '
                   f'"{SHA}", "stamp_ns": 7}}',
    SnapshotStep: '{"step": 3, "trigger_injected_m3": 1e-05, "direction": "deflation", '
                  '"injected_m3": 1.2500000000000002e-05, "stamp_ns": 9}',
}


def _former_text(value: object) -> str:
    """The JSON each encoder wrote before the codecs (as softseq_ros.wire.payloads had it)."""
    if isinstance(value, PumpStatus):
        return json.dumps({'state': value.state, 'reason': value.reason,
                           'stamp_ns': value.stamp_ns})
    if isinstance(value, SnapThrough):
        return json.dumps({
            'injected_m3': value.injected_m3, 'from_volumes_m3': value.from_volumes_m3,
            'to_volumes_m3': value.to_volumes_m3, 'from_pressure_pa': value.from_pressure_pa,
            'to_pressure_pa': value.to_pressure_pa})
    if isinstance(value, SceneIdentity):
        return json.dumps({'scene': value.scene, 'segments': list(value.segments),
                           'segments_sha256': value.segments_sha256,
                           'stamp_ns': value.stamp_ns})
    assert isinstance(value, SnapshotStep)
    return json.dumps({
        'step': value.step, 'trigger_injected_m3': value.trigger_injected_m3,
        'direction': value.direction, 'injected_m3': value.injected_m3,
        'stamp_ns': value.stamp_ns})


def _cdr_text(data: bytes) -> str:
    """The text of a std_msgs/String's CDR bytes."""
    size = int.from_bytes(data[4:8], 'little')
    assert data[:4] == b'\x00\x01\x00\x00' and len(data) == 8 + size and data[-1] == 0
    return data[8:-1].decode()


def _same(a: object, b: object) -> bool:
    """Equal values, field by field and type by type (a NaN equals a NaN)."""
    if type(a) is not type(b):
        return False
    if isinstance(a, float):
        return a == b or (math.isnan(a) and math.isnan(b))
    if isinstance(a, list | tuple):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if dataclasses.is_dataclass(a):
        return all(_same(getattr(a, f.name), getattr(b, f.name))
                   for f in dataclasses.fields(a))
    return a == b


def _stamp(value: object) -> dict:
    """The message time a decoder needs for ``value`` (its stamp when the payload has none)."""
    codec = JSON_PAYLOADS[type(value)]
    return {} if codec.carries_stamp else {'stamp_ns': value.stamp_ns}


any_value = st.one_of(*VALUES.values())

# ------------------------------------------------------------------ one codec per String topic


def test_every_string_topic_has_a_codec_and_every_writer_uses_it():
    strings = {topic.name for topic in contract.RIG_TOPICS if topic.type_name == STRING_TYPE}
    assert strings == set(JSON_PAYLOADS_BY_TOPIC) == {'pump/status', 'actuator/events',
                                                      'actuator/scene',
                                                      'camera/snapshot_steps'}
    carried = {kind for kind in TOPIC_VALUE_TYPES if kind.topic.type_name == STRING_TYPE}
    assert carried == set(JSON_PAYLOADS)
    for kind, codec in JSON_PAYLOADS.items():
        assert codec.value_type is kind and codec.topic is kind.topic
        assert JSON_PAYLOADS_BY_TOPIC[kind.topic.name] is codec
        assert ENCODERS[kind] == codec.encode, f'{kind.__name__} is not written by its codec'


@pytest.mark.parametrize('kind', list(EXAMPLE), ids=lambda kind: kind.__name__)
def test_the_bytes_are_the_ones_bags_hold(kind):
    value = EXAMPLE[kind]
    assert JSON_PAYLOADS[kind].text(value) == EXAMPLE_TEXT[kind]
    assert encode(value) == string_cdr(EXAMPLE_TEXT[kind])
    assert _same(JSON_PAYLOADS[kind].decode(EXAMPLE_TEXT[kind], **_stamp(value)), value)


@EXAMPLES
@given(any_value)
def test_encoding_is_byte_for_byte_the_former_encoders(value):
    data = encode(value)
    assert data == string_cdr(_former_text(value))
    assert _cdr_text(data) == JSON_PAYLOADS[type(value)].text(value)


@EXAMPLES
@given(any_value)
def test_what_is_encoded_decodes_to_the_same_value(value):
    codec = JSON_PAYLOADS[type(value)]
    decoded = codec.decode(_cdr_text(encode(value)), **_stamp(value))
    assert _same(decoded, value), (decoded, value)
    assert codec.encode(decoded) == encode(value)


def test_a_payload_without_a_stamp_is_stamped_by_the_message_time():
    text = SNAP_THROUGH_JSON.text(EXAMPLE[SnapThrough])
    assert STAMP_KEY not in json.loads(text) and not SNAP_THROUGH_JSON.carries_stamp
    assert SNAP_THROUGH_JSON.decode(text, stamp_ns=42).stamp_ns == 42
    with pytest.raises(TypeError, match='needs stamp_ns'):
        SNAP_THROUGH_JSON.decode(text)
    # A payload that carries its stamp keeps it; the message time stands in only when absent.
    status = PUMP_STATUS_JSON.text(EXAMPLE[PumpStatus])
    assert PUMP_STATUS_JSON.decode(status, stamp_ns=42) == EXAMPLE[PumpStatus]
    unstamped = json.dumps({'state': 'idle', 'reason': ''})
    assert PUMP_STATUS_JSON.decode(unstamped, stamp_ns=42) == PumpStatus(42, 'idle', '')
    with pytest.raises(PayloadError, match='no key stamp_ns'):
        PUMP_STATUS_JSON.decode(unstamped)


# ------------------------------------------------------------------ no key on one side only


@pytest.mark.parametrize('codec', CODECS, ids=CODEC_IDS)
def test_the_keys_written_are_the_fields_and_each_is_needed_to_decode(codec):
    value = EXAMPLE[codec.value_type]
    written = json.loads(codec.text(value))
    assert tuple(written) == codec.names
    fields = {field.name for field in dataclasses.fields(codec.value_type)}
    assert set(written) | {STAMP_KEY} | {key for key, _ in codec.optional} == fields
    # A key the encoder writes but the decoder does not read would survive its removal.
    for key in written:
        partial = json.dumps({k: v for k, v in written.items() if k != key})
        with pytest.raises(PayloadError) as refused:
            codec.decode(partial, **_stamp(value))
        assert refused.value.field == key
    # Keys the decoder does not know are left alone (a newer writer may add some).
    extra = json.dumps({**written, 'added_later': [1, 2]})
    assert _same(codec.decode(extra, **_stamp(value)), value)


def test_a_snap_through_in_time_adds_its_timing_after_the_keys_a_quasi_static_one_has():
    instant = EXAMPLE[SnapThrough]
    timed = dataclasses.replace(instant, start_ns=1_700_000_000_123_456_789, duration_s=0.0125,
                                fluid_moved_m3=2.3e-5, peak_exchange_m3_per_s=1.5e-6)
    text = SNAP_THROUGH_JSON.text(timed)
    written = json.loads(text)
    # The quasi-static keys first, in their order and with their values; the timing after.
    assert list(written)[:len(SNAP_THROUGH_JSON.names)] == list(SNAP_THROUGH_JSON.names)
    assert text.startswith(SNAP_THROUGH_JSON.text(instant)[:-1] + ', ')
    assert written['start_ns'] == 1_700_000_000_123_456_789 and written['duration_s'] == 0.0125
    decoded = SNAP_THROUGH_JSON.decode(text, stamp_ns=instant.stamp_ns)
    assert decoded == timed
    # Without them a snap-through reads back as instantaneous.
    assert SNAP_THROUGH_JSON.decode(SNAP_THROUGH_JSON.text(instant),
                                    stamp_ns=instant.stamp_ns).duration_s is None
    with pytest.raises(PayloadError) as refused:
        SNAP_THROUGH_JSON.decode(json.dumps({**written, 'duration_s': 'long'}),
                                 stamp_ns=instant.stamp_ns)
    assert refused.value.field == 'duration_s'


def test_a_codec_whose_keys_are_not_its_values_fields_is_refused_at_once():
    with pytest.raises(TypeError, match=r"fields left out: \['reason'\]"):
        JsonPayload(PumpStatus, 'pump status', (('state', 'str'), (STAMP_KEY, 'int')))
    with pytest.raises(TypeError, match=r"not fields: \['colour'\]"):
        JsonPayload(PumpStatus, 'pump status', (('state', 'str'), ('reason', 'str'),
                                                ('colour', 'str'), (STAMP_KEY, 'int')))
    with pytest.raises(TypeError):
        JsonPayload(PumpStatus, 'pump status', (('state', 'str'), ('reason', 'text'),
                                                (STAMP_KEY, 'int')))


# ------------------------------------------------------------------------------ garbage


GARBAGE = [
    ('', None, 'not JSON'),
    ('running: requested', None, 'not JSON'),
    ('{"state": ', None, 'not JSON'),
    ('[1, 2]', None, 'not a JSON object: [1, 2]'),
    ('"text"', None, 'not a JSON object: "text"'),
    ('null', None, 'not a JSON object: null'),
    ('[' * 100_000, None, 'not JSON'),
    ('1' * 5000, None, 'not JSON'),
]
# Per kind of key: JSON values it must refuse.
WRONG = {
    'int': ['"12"', '1.5', 'true', 'null', '[1]'],
    'float': ['"1.0"', 'true', 'null', '[1.0]', '1' + '0' * 400],
    'str': ['1', 'true', 'null', '["a"]'],
    'floats': ['1.0', '["1.0"]', '[true]', '[[1.0]]', '{"a": 1.0}'],
    'strs': ['"bottom"', '[1]', '[null]', '[["a"]]'],
}


def _one_line_naming(err: PayloadError, codec: JsonPayload, key: str | None) -> None:
    text = str(err)
    assert '\n' not in text and text.startswith(f'{codec.topic.name}: not a {codec.what} (')
    assert err.field == key
    if key is not None:
        assert key in err.problem
    assert isinstance(err, InputError) and isinstance(err, UserError)


@pytest.mark.parametrize('codec', CODECS, ids=CODEC_IDS)
@pytest.mark.parametrize('text, key, problem', GARBAGE)
def test_garbage_is_refused_in_one_line_naming_the_topic(codec, text, key, problem):
    with pytest.raises(PayloadError) as refused:
        codec.decode(text, stamp_ns=1)
    _one_line_naming(refused.value, codec, key)
    assert refused.value.problem.startswith(problem)


@pytest.mark.parametrize('codec', CODECS, ids=CODEC_IDS)
def test_a_key_of_the_wrong_kind_is_refused_naming_the_key(codec):
    value = EXAMPLE[codec.value_type]
    written = json.loads(codec.text(value))
    for key, kind in codec.keys:
        for wrong in WRONG[kind]:
            text = codec.text(value).replace(f'"{key}": {json.dumps(written[key])}',
                                             f'"{key}": {wrong}')
            assert text != codec.text(value)
            with pytest.raises(PayloadError) as refused:
                codec.decode(text, **_stamp(value))
            _one_line_naming(refused.value, codec, key)


def test_values_a_key_may_not_take():
    bad_digest = SCENE_IDENTITY_JSON.text(dataclasses.replace(EXAMPLE[SceneIdentity],
                                                              segments_sha256='abc'))
    with pytest.raises(PayloadError, match='segments_sha256 must be 64 hexadecimal digits'):
        SCENE_IDENTITY_JSON.decode(bad_digest)
    not_hex = SCENE_IDENTITY_JSON.text(dataclasses.replace(EXAMPLE[SceneIdentity],
                                                           segments_sha256='g' * 64))
    with pytest.raises(PayloadError, match='segments_sha256'):
        SCENE_IDENTITY_JSON.decode(not_hex)
    sideways = SNAPSHOT_STEP_JSON.text(dataclasses.replace(EXAMPLE[SnapshotStep],
                                                           direction='sideways'))
    with pytest.raises(PayloadError, match="direction must be inflation or deflation, got "
                                           "'sideways'") as refused:
        SNAPSHOT_STEP_JSON.decode(sideways)
    assert refused.value.field == 'direction'
    # Integers in a number's place are numbers (a hand-written trigger of 0).
    step = SNAPSHOT_STEP_JSON.decode('{"step": 1, "trigger_injected_m3": 0, "direction": '
                                     '"inflation", "injected_m3": 0, "stamp_ns": 3}')
    assert step == SnapshotStep(3, 1, 0.0, 'inflation', 0.0)
    assert type(step.trigger_injected_m3) is float


# ------------------------------------------------------------------ through a recording

T0 = 1_795_000_000 * 10**9
NS = '/'


def _topic(spec: contract.Topic) -> str:
    return contract.resolve(spec.name, NS)


def _bag(path, extra: list[tuple[contract.Topic, int, bytes]]):
    """A small rig bag: three commands and states, a snapshot, and ``extra`` String messages."""
    values = []
    for k in range(3):
        stamp = T0 + k * 10**8
        values.append(PumpCommand(stamp, k * 1e-6, 1e-5))
        values.append(SegmentVolumes(stamp, ('bottom', 'top'), [1e-6 + k * 5e-7] * 2, 100.0 * k))
    values.append(Snapshot(T0 + 10**8, np.zeros((4, 7))))
    with BagWriter(path) as writer:
        for spec in contract.RIG_TOPICS:
            writer.add_topic(_topic(spec), spec.type_name)
        for value in values:
            writer.write(_topic(value.topic), encode(value), value.stamp_ns)
        for spec, log_time, data in sorted(extra, key=lambda e: e[1]):
            writer.write(_topic(spec), data, log_time)
    return path


def test_a_recording_reads_every_string_payload_with_its_codec(tmp_path):
    status = PumpStatus(T0, 'running', '')
    event = SnapThrough(T0 + 10**8, 1e-6, [1e-6, 1e-6], [2e-6, 0.0], 120.0, 80.5)
    scene = SceneIdentity(T0 - 10**9, 'paper', ('bottom', 'top'), SHA)
    step = SnapshotStep(T0 + 10**8, 2, 1e-6, 'inflation', 1.0e-6)
    bag = _bag(tmp_path / 'bag', [
        (contract.PUMP_STATUS, T0, encode(status)),
        (contract.EVENTS, T0 + 10**8, encode(event)),
        (contract.SCENE, T0, encode(scene)),
        (contract.SNAPSHOT_STEPS, T0 + 10**8, encode(step)),
        # A status of an older bag: plain text.
        (contract.PUMP_STATUS, T0 + 2 * 10**8, string_cdr('finished: programme done')),
    ])
    recording = load_recording(bag)
    assert recording.status == [(0.0, 'running', ''), (0.2, 'finished', 'programme done')]
    assert recording.events == [json.loads(SNAP_THROUGH_JSON.text(event))]
    assert recording.scenes == [SceneIdentity(T0 - 10**9, 'paper', ('bottom', 'top'), SHA)]
    shot, = recording.snapshots
    assert (shot.step, shot.trigger_injected, shot.direction) == (2, 1e-6, 'inflation')


def test_a_status_that_is_no_status_json_reads_as_text():
    # pump/status is informational: what its codec refuses is kept as the plain text of older
    # bags rather than failing the recording.
    assert recording_module._status('{"state": 5}', T0 + 10**9, T0) == (1.0, '{"state"', '5}')
    assert recording_module._status('held: no pressure', T0, T0) == (0.0, 'held', 'no pressure')
    text = PUMP_STATUS_JSON.text(PumpStatus(T0 + 5 * 10**8, 'held', 'a: b'))
    assert recording_module._status(text, T0 + 10**9, T0) == (0.5, 'held', 'a: b')


@pytest.mark.parametrize('spec, codec, keys', [
    (contract.EVENTS, SNAP_THROUGH_JSON,
     'injected_m3, from_volumes_m3, to_volumes_m3, from_pressure_pa, to_pressure_pa'),
    (contract.SCENE, SCENE_IDENTITY_JSON, 'scene, segments, segments_sha256'),
    (contract.SNAPSHOT_STEPS, SNAPSHOT_STEP_JSON,
     'step, trigger_injected_m3, direction, injected_m3, stamp_ns'),
], ids=['events', 'scene', 'steps'])
@pytest.mark.parametrize('garbage', ['garbage', '{"injected_m3": "1"}', '[]'])
def test_a_garbled_payload_in_a_recording_is_one_line_naming_the_topic(tmp_path, spec, codec,
                                                                       keys, garbage):
    good = encode(EXAMPLE[codec.value_type])
    bag = _bag(tmp_path / 'bag', [(spec, T0, good), (spec, T0 + 1, string_cdr(garbage))])
    with pytest.raises(RecordingError) as refused:
        load_recording(bag)
    assert str(refused.value) == (f'{_topic(spec)}: message 2 is not a {codec.what} (JSON with '
                                  f'{keys}): {garbage!r}')


def test_the_command_exits_2_with_one_line_for_a_garbled_event(tmp_path):
    bag = _bag(tmp_path / 'bag', [(contract.EVENTS, T0, string_cdr('{"injected_m3": []}'))])
    result = subprocess.run([sys.executable, '-m', 'softseq_ros.cli', 'report', str(bag),
                             '--out', str(tmp_path / 'out')], capture_output=True, text=True,
                            timeout=120, stdin=subprocess.DEVNULL)
    assert result.returncode == 2, result.stderr
    assert result.stderr == (
        f"softseq report: error: {_topic(contract.EVENTS)}: message 1 is not a snap-through "
        "event (JSON with injected_m3, from_volumes_m3, to_volumes_m3, from_pressure_pa, "
        "to_pressure_pa): '{\"injected_m3\": []}'\n")
    assert not (tmp_path / 'out').exists()
