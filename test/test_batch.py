"""Batch runs: deterministic bags that agree with the solver and with the same nodes over DDS."""

import json
from pathlib import Path
import signal
import struct
import subprocess
import sys
import time

from mcap.reader import make_reader
import numpy as np
import pytest
from rclpy.parameter import Parameter
from rosbags.rosbag2 import Reader
from scenes import fast_asymmetric
import yaml

import softseq_ros
from softseq_ros.analysis.recording import load_recording
from softseq_ros.bag.reader import bag_summary, read_bag
from softseq_ros.nodes.actuator import ActuatorNode
from softseq_ros.nodes.camera import CameraNode
from softseq_ros.nodes.recorder import Recorder
from softseq_ros.nodes.syringe_pump import SyringePumpNode
from softseq_ros.quasistatic.equilibrium import EquilibriumMap, Tracker
from softseq_ros.rig.build import actuator_core
from softseq_ros.scene.loader import load_scene
from softseq_ros.segments.identity import segments_sha256
from softseq_ros.testing import spinning, wait_for
from softseq_ros.wire import contract
from softseq_ros.wire.payloads import encode, pump_command
from softseq_ros.wire.values import Notice

CONFIG = Path(__file__).resolve().parents[1] / 'config'
# A quasi-static scene has no channels: no channel flows.
# What the rig's own cores publish (no controller's setpoints), without image and flows.
RECORDED = tuple(contract.resolve(topic.name) for topic in contract.RIG_TOPICS
                 if topic not in (contract.IMAGE, contract.CHANNEL_FLOWS)
                 and topic.producer in contract.NODE_NAMES)
START_NS = 1_795_000_000 * 10**9   # 2026-11-18, a fixed date for reproducible bags


@pytest.fixture(scope='module')
def fast_scene(tmp_path_factory) -> Path:
    """The Fig. 1 asymmetric pair, pumped 0 -> 50 mL -> 0 at 20 mL/s: four snaps in 5 s."""
    return fast_asymmetric(tmp_path_factory.mktemp('scene'), 'fast_asymmetric')


def messages(bag: Path, topic: str) -> list:
    return [m.msg for m in read_bag(bag, topics=[topic])]


def read_raw(bag: Path, topic: str) -> list[tuple[int, bytes]]:
    """(log time, CDR bytes) of every message of ``topic``, in log-time order."""
    with open(next(bag.glob('*.mcap')), 'rb') as stream:
        return [(message.log_time, message.data) for _, _, message in
                make_reader(stream).iter_messages(topics=[topic], log_time_order=True)]


def _stamp(msg) -> int:
    return msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec


def check_bag_against_solver(bag: Path, scene_path: Path, complete: bool = True) -> None:
    """
    Every recorded actuator state is the solver's answer to the recorded command history.

    Answers are paired with commands by stamp. ``complete``: every command has its answer
    (a batch bag); otherwise (a recording over DDS, closed while the rig still ran) the last
    few answers may be missing.
    """
    scene = load_scene(scene_path)
    emap = EquilibriumMap(scene.segments)
    commands = messages(bag, '/pump/command')
    solved = Tracker(emap).sweep([m.position[0] for m in commands])
    row_of = {_stamp(m): row for row, m in enumerate(commands)}
    for topic, column in (('/actuator/volumes', solved.volumes),
                          ('/actuator/curvatures', solved.curvatures)):
        answers = messages(bag, topic)
        rows = [row_of.get(_stamp(m)) for m in answers]
        if complete:
            assert rows == list(range(len(commands))), topic
        else:
            # At the end the recorder may hold an answer whose command it had not written.
            unpaired = [row for row in rows if row is None]
            answers = [m for m, row in zip(answers, rows) if row is not None]
            rows = [row for row in rows if row is not None]
            assert len(unpaired) <= 5 and len(rows) >= len(commands) - 5, topic
        np.testing.assert_allclose([m.position for m in answers], column[rows], rtol=1e-12,
                                   atol=1e-12 * (emap.v_scale if 'volumes' in topic else 1.0))


def test_batch_bag_is_deterministic_and_matches_the_solver(fast_scene, tmp_path):
    # Same bag name in two places: the name is part of the bag's own metadata.
    first = softseq_ros.run(fast_scene, tmp_path / 'a' / 'run', start_time_ns=START_NS)
    softseq_ros.run(fast_scene, tmp_path / 'b' / 'run', start_time_ns=START_NS)
    assert first.pump_state == 'finished'
    # Same scene, same bag, byte for byte (no wall-clock time and no padding garbage in it).
    bag = tmp_path / 'a' / 'run'
    twin = tmp_path / 'b' / 'run' / 'run_0.mcap'
    assert (bag / 'run_0.mcap').read_bytes() == twin.read_bytes()
    # 0 -> 50 -> 0 mL at 20 mL/s is 5 s: 250 pump periods of 20 ms, both ends included.
    assert first.message_counts['/pump/command'] == 251
    assert first.sim_duration_s == pytest.approx(5.0)
    summary = bag_summary(bag)
    assert {t: s.message_count for t, s in summary.topics.items()} == first.message_counts
    # The bag is dated at its start time; every topic the outputs switch on is in it.
    assert summary.start_ns == START_NS
    assert set(summary.topics) == set(RECORDED)
    check_bag_against_solver(bag, fast_scene)
    events = [json.loads(m.data) for m in messages(bag, '/actuator/events')]
    assert len(events) == 4
    # Three triggers crossed on the way up and again on the way down, each snapshot saying
    # which; the pump's status is stamped with the instant of each change.
    assert len(messages(bag, '/camera/snapshots')) == 6
    steps = [json.loads(m.data) for m in messages(bag, '/camera/snapshot_steps')]
    assert [(s['step'], s['direction']) for s in steps] == [
        (1, 'inflation'), (2, 'inflation'), (3, 'inflation'),
        (3, 'deflation'), (2, 'deflation'), (1, 'deflation')]
    statuses = [json.loads(m.data) for m in messages(bag, '/pump/status')]
    assert [s['state'] for s in statuses] == ['idle', 'running', 'finished']
    assert statuses[-1]['stamp_ns'] == START_NS + 5 * 10**9
    # The bag names the scene and the digest of its segments, once, at the start.
    identity, = [json.loads(m.data) for m in messages(bag, '/actuator/scene')]
    assert identity == {'scene': 'fast_asymmetric', 'segments': ['bottom', 'top'],
                        'segments_sha256': segments_sha256(load_scene(fast_scene).segments),
                        'stamp_ns': START_NS}


def test_a_batch_bag_without_snaps_still_has_its_events_topic_and_starts_now(tmp_path):
    scene = yaml.safe_load((CONFIG / 'fig1_none.yaml').read_text())
    scene['pump'].update(flow_rate_m3_per_s=2.0e-5, legs=[{'inflate_to_m3': 1.0e-5}])
    scene['camera'] = {'rate_hz': 10}
    path = tmp_path / 'none.yaml'
    path.write_text(yaml.safe_dump(scene))
    before = time.time_ns()
    result = softseq_ros.run(path, tmp_path / 'bag')
    summary = bag_summary(tmp_path / 'bag')
    assert summary.topics['/actuator/events'].message_count == 0
    assert result.message_counts['/actuator/events'] == 0
    assert before <= summary.start_ns <= time.time_ns()


@pytest.mark.ros
def test_batch_bag_agrees_with_a_bag_of_the_nodes_over_dds(context, fast_scene, tmp_path):
    batch_bag, dds_bag = tmp_path / 'batch', tmp_path / 'dds'
    softseq_ros.run(fast_scene, batch_bag, start_time_ns=START_NS)

    scene = [Parameter('scene', value=str(fast_scene))]
    pump = SyringePumpNode(context=context, parameter_overrides=[
        *scene, Parameter('autostart', value=False)])
    actuator = ActuatorNode(context=context, parameter_overrides=[
        *scene, Parameter('resume_timeout_s', value=0.0)])
    camera = CameraNode(context=context, parameter_overrides=scene)
    recorder = Recorder(context=context, parameter_overrides=[
        Parameter('topics', value=list(RECORDED)), Parameter('output', value=str(dds_bag))])
    with spinning(context, pump, actuator, camera, recorder) as executor:
        try:
            wait_for(lambda: set(recorder.recorded_topics) == set(RECORDED),
                     'the recorder to subscribe to every rig topic', timeout=60.0)
            wait_for(lambda: not actuator.resuming, 'the actuator to start')
            executor.create_task(pump.start)
            wait_for(lambda: pump.state == 'finished', 'the pump programme to finish',
                     timeout=60.0)
            time.sleep(1.0)  # the pump keeps commanding its end volume; let the run settle
        finally:
            recorder.close_bag()

    batch, dds = bag_summary(batch_bag), bag_summary(dds_bag)
    assert {t: s.type_name for t, s in batch.topics.items()} == \
        {t: s.type_name for t, s in dds.topics.items()}
    # Message by message: the actuator's answers in the DDS bag are, byte for byte, what the
    # batch runner's cores write for the same commands (the same core, the same encoding).
    # Each answer carries its command's stamp (CDR bytes 4..12), which pairs them: the
    # recorder may close before the answers to the last commands arrive.
    cores = actuator_core(load_scene(fast_scene))
    answers = ('/actuator/pressure', '/actuator/volumes', '/actuator/curvatures')
    raw = {topic: [data for _, data in read_raw(dds_bag, topic)]
           for topic in (*answers, '/actuator/events')}
    expected = {topic: {} for topic in answers}
    expected_events = []
    for msg in messages(dds_bag, '/pump/command'):
        for value in cores.handle(pump_command(msg), 0):
            if type(value) is Notice:
                continue
            topic = contract.resolve(value.topic.name)
            if topic == '/actuator/events':
                expected_events.append(encode(value))
            else:
                expected[topic][value.stamp_ns] = encode(value)
    for topic in answers:
        paired = 0
        for data in raw[topic]:
            sec, nanosec = struct.unpack_from('<iI', data, 4)
            want = expected[topic].get(sec * 10**9 + nanosec)
            if want is not None:
                assert data == want, topic
                paired += 1
        assert paired >= len(expected[topic]) - 5 and paired >= len(raw[topic]) - 5, topic
    assert raw['/actuator/events'] == expected_events
    assert len(raw['/actuator/volumes']) > 100
    # Over DDS the same physics answers to whatever commands arrived, in order.
    check_bag_against_solver(dds_bag, fast_scene, complete=False)
    # The snap-throughs sit at the folds, not at the commands, so both runs report the same.
    batch_events = [json.loads(m.data) for m in messages(batch_bag, '/actuator/events')]
    dds_events = [json.loads(m.data) for m in messages(dds_bag, '/actuator/events')]
    assert len(dds_events) == len(batch_events) == 4
    for ours, theirs in zip(batch_events, dds_events):
        assert theirs['injected_m3'] == pytest.approx(ours['injected_m3'], rel=1e-12)
        np.testing.assert_allclose(theirs['to_volumes_m3'], ours['to_volumes_m3'], rtol=1e-9)
    assert len(messages(dds_bag, '/camera/snapshots')) == \
        len(messages(batch_bag, '/camera/snapshots'))
    # Both name the same scene and segments; only the instant the actuator started differs.
    # The actuator said it before the recorder existed: the latched sample reached it.
    batch_scene, = [json.loads(m.data) for m in messages(batch_bag, '/actuator/scene')]
    dds_scene, = [json.loads(m.data) for m in messages(dds_bag, '/actuator/scene')]
    assert batch_scene.pop('stamp_ns') == START_NS and dds_scene.pop('stamp_ns') > 0
    assert dds_scene == batch_scene
    # Both runs end where the programme ends: back at rest.
    for bag in (batch_bag, dds_bag):
        recording = load_recording(bag)
        assert recording.pump_injected[-1] == pytest.approx(0.0, abs=1e-15)


def test_softseq_run_writes_bag_summary_and_figures(fast_scene, tmp_path):
    out = tmp_path / 'run'
    result = subprocess.run([sys.executable, '-m', 'softseq_ros.cli', 'run', str(fast_scene),
                             '--out', str(out), '--quiet'], capture_output=True, text=True,
                            timeout=300, stdin=subprocess.DEVNULL)
    assert result.returncode == 0, result.stderr
    assert (out / 'metadata.yaml').is_file() and (out / 'run_0.mcap').is_file()
    for name in ('pv.png', 'volume_split.png', 'shapes.png', 'timeseries.png', 'summary.txt'):
        assert (out / 'report' / name).stat().st_size > 0
    summary = (out / 'report' / 'summary.txt').read_text()
    assert summary.count('snap-through at') == 4
    # An existing bag is never overwritten.
    again = subprocess.run([sys.executable, '-m', 'softseq_ros.cli', 'run', str(fast_scene),
                            '--out', str(out), '--quiet'], capture_output=True, text=True,
                           timeout=300, stdin=subprocess.DEVNULL)
    assert again.returncode == 2
    assert 'already exists' in again.stderr and len(again.stderr.strip().splitlines()) == 1


def test_softseq_run_start_time_dates_the_bag(fast_scene, tmp_path):
    out = tmp_path / 'dated'
    result = subprocess.run([sys.executable, '-m', 'softseq_ros.cli', 'run', str(fast_scene),
                             '--out', str(out), '--quiet', '--no-report',
                             '--start-time', '2026-01-01T00:00:00Z'], capture_output=True,
                            text=True, timeout=300, stdin=subprocess.DEVNULL)
    assert result.returncode == 0, result.stderr
    assert bag_summary(out).start_ns == 1_767_225_600 * 10**9
    bad = subprocess.run([sys.executable, '-m', 'softseq_ros.cli', 'run', str(fast_scene),
                          '--out', str(tmp_path / 'never'), '--start-time', 'yesterday'],
                         capture_output=True, text=True, timeout=300, stdin=subprocess.DEVNULL)
    assert bad.returncode == 2 and 'ISO 8601' in bad.stderr
    assert not (tmp_path / 'never').exists()


@pytest.mark.parametrize('signal_name, exit_code', [('SIGINT', 130), ('SIGTERM', 143)])
def test_softseq_run_stopped_by_a_signal_closes_its_bag(tmp_path, signal_name, exit_code):
    out = tmp_path / 'stopped'
    process = subprocess.Popen([sys.executable, '-m', 'softseq_ros.cli', 'run', 'paper',
                                '--out', str(out), '--quiet', '--no-report'],
                               stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
    try:
        mcap = out / 'stopped_0.mcap'
        deadline = time.monotonic() + 120
        # Stop it in the middle of the run: once the bag holds a few chunks.
        while not (mcap.exists() and mcap.stat().st_size > 3_000_000):
            assert process.poll() is None, process.communicate()
            assert time.monotonic() < deadline, 'the run wrote nothing'
            time.sleep(0.05)
        process.send_signal(getattr(signal, signal_name))
        _, stderr = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == exit_code, stderr
    assert len(stderr.strip().splitlines()) == 1 and 'softseq run:' in stderr
    # Complete: summary, index and metadata.yaml, readable by an independent reader.
    summary = bag_summary(out)
    assert summary.complete
    commands = summary.topics['/pump/command'].message_count
    assert 1000 < commands < 130_501
    with Reader(out) as reader:
        assert reader.message_count == summary.message_count
