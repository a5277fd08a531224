"""Playback analysis: the array reader, metrics against the solver, experiments, bad bags."""

import json
from pathlib import Path
import subprocess
import sys

import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer
from scenes import shipped_scene_changed

import softseq_ros
from softseq_ros.analysis.experiment import compare, read_experiment, synthetic_experiment
from softseq_ros.analysis.recording import RecordingError, load_recording
from softseq_ros.analysis.report import SceneMismatchError, recording_trace, write_report
from softseq_ros.bag.arrays import BagArrayError, JointStateDecoder, open_bag
from softseq_ros.bag.reader import read_bag
from softseq_ros.quasistatic.equilibrium import EquilibriumMap, Tracker
from softseq_ros.scene.loader import load_scene
from softseq_ros.segments.identity import segments_sha256
from softseq_ros.wire import contract
from softseq_ros.wire.values import SceneIdentity

CONFIG = Path(__file__).resolve().parents[1] / 'config'
ML = 1e-6


def _scene(tmp_path_factory, source: str, name: str, pump: dict, camera: dict) -> Path:
    return shipped_scene_changed(tmp_path_factory.mktemp(name), source, name, pump, camera)


@pytest.fixture(scope='module')
def asymmetric(tmp_path_factory) -> tuple[Path, Path]:
    """The Fig. 1 asymmetric pair, 0 -> 50 mL -> 0 at 20 mL/s: two snaps each way."""
    scene = _scene(tmp_path_factory, 'fig1_asymmetric.yaml', 'fast_asymmetric',
                   {'flow_rate_m3_per_s': 2.0e-5, 'rate_hz': 50,
                    'legs': [{'inflate_to_m3': 5.0e-5}, {'deflate_to_m3': 0.0}]},
                   {'rate_hz': 10, 'trigger_injected_m3': [5.0e-6, 2.5e-5, 4.5e-5]})
    bag = scene.parent / 'bag'
    softseq_ros.run(scene, bag)
    return scene, bag


@pytest.fixture(scope='module')
def paper(tmp_path_factory) -> tuple[Path, Path]:
    """The paper's actuator, 0 -> 65 mL -> 0 at 1 mL/s (the paper's steps as triggers)."""
    scene = _scene(tmp_path_factory, 'paper.yaml', 'fast_paper',
                   {'flow_rate_m3_per_s': 1.0e-6, 'rate_hz': 50},
                   {'rate_hz': 5,
                    'trigger_injected_m3': [5.0e-6, 1.5e-5, 2.5e-5, 4.5e-5, 6.0e-5]})
    bag = scene.parent / 'bag'
    softseq_ros.run(scene, bag)
    return scene, bag


# ------------------------------------------------------------------------ the array reader


def test_array_reader_matches_rosbags_message_for_message(asymmetric):
    _, bag = asymmetric
    topic = contract.resolve(contract.VOLUMES.name, '/')
    decoder = JointStateDecoder(topic)
    open_bag(bag).read([decoder], validate_crcs=True)
    ours = decoder.result()
    with AnyReader([bag]) as reader:
        connections = [c for c in reader.connections if c.topic == topic]
        theirs = [(t, reader.deserialize(raw, c.msgtype))
                  for c, t, raw in reader.messages(connections=connections)]
    assert len(theirs) == ours['stamp_ns'].size > 100
    np.testing.assert_array_equal(ours['log_time_ns'], [t for t, _ in theirs])
    np.testing.assert_array_equal(ours['stamp_ns'], [m.header.stamp.sec * 10**9
                                                     + m.header.stamp.nanosec for _, m in theirs])
    np.testing.assert_array_equal(ours['position'], [m.position for _, m in theirs])
    np.testing.assert_array_equal(ours['effort'], [m.effort for _, m in theirs])
    assert decoder.names == tuple(theirs[0][1].name)


def _joint_state_bag(directory: Path, count: int) -> Path:
    from sensor_msgs.msg import JointState

    from softseq_ros.bag.forms import serialize
    from softseq_ros.bag.writer import BagWriter

    with BagWriter(directory, chunk_size=2048, compression=None, flush_period_s=None) as bag:
        bag.add_topic('/actuator/volumes', 'sensor_msgs/msg/JointState')
        for i in range(count):
            msg = JointState(name=['bottom', 'top'], position=[1e-6 * i, 2e-6 * i],
                             effort=[float(i), float(i)])
            msg.header.stamp.sec, msg.header.stamp.nanosec = 1000 + i // 10, (i % 10) * 10**8
            bag.write('/actuator/volumes', serialize(msg), 10**18 + 10**8 * i)
    return directory


def test_the_reader_reads_every_message_across_many_small_chunks(tmp_path):
    bag = _joint_state_bag(tmp_path / 'bag', 500)
    decoder = JointStateDecoder('/actuator/volumes')
    opened = open_bag(bag)
    opened.read([decoder], validate_crcs=True)
    result = decoder.result()
    assert len(opened.summaries[bag / 'bag_0.mcap'].chunk_indexes) > 20
    i = np.arange(500)
    np.testing.assert_array_equal(result['position'], np.c_[1e-6 * i, 2e-6 * i])
    np.testing.assert_array_equal(result['stamp_ns'], (1000 + i // 10) * 10**9
                                  + (i % 10) * 10**8)
    np.testing.assert_array_equal(result['log_time_ns'], 10**18 + 10**8 * i)


def test_a_message_record_running_past_its_chunk_is_named(tmp_path):
    # Chunks are read in batches: a record must still end inside its own chunk.
    from mcap.reader import make_reader

    bag = _joint_state_bag(tmp_path / 'bag', 200)
    path = bag / 'bag_0.mcap'
    raw = bytearray(path.read_bytes())
    with open(path, 'rb') as stream:
        first = sorted(make_reader(stream).get_summary().chunk_indexes,
                       key=lambda c: c.chunk_start_offset)[0]
    # The first chunk's last message: with no compression its records follow the chunk's
    # 49-byte header (opcode, length, times, size, crc, empty compression name, data length).
    last = max(int(i) for i in _record_offsets(raw, first))
    at = first.chunk_start_offset + 49 + last + 1
    length = int.from_bytes(raw[at:at + 8], 'little')
    raw[at:at + 8] = (length + 40).to_bytes(8, 'little')
    path.write_bytes(bytes(raw))
    with pytest.raises(BagArrayError, match=r'bag_0.mcap \(chunk at byte \d+\).*runs past '
                       'its chunk'):
        open_bag(bag).read([JointStateDecoder('/actuator/volumes')])


def _record_offsets(raw: bytes, index: object) -> list[int]:
    """Message record offsets in a chunk, from its message index records."""
    offsets = []
    for position in index.message_index_offsets.values():
        length = int.from_bytes(raw[position + 11:position + 15], 'little')
        entries = np.frombuffer(bytes(raw[position + 15:position + 15 + length]), '<u8')
        offsets.extend(entries[1::2].tolist())
    return offsets


# ------------------------------------------------------------------------ metrics vs solver


def test_batch_bag_gives_the_solvers_sequence_type_and_snap_volumes(asymmetric, tmp_path):
    scene_path, bag = asymmetric
    metrics, _ = write_report(bag, tmp_path / 'report', scene_name=str(scene_path),
                              svg=False, figures=False)
    scene = load_scene(scene_path)
    emap = EquilibriumMap(scene.segments)
    recording = load_recording(bag)
    solved = Tracker(emap).sweep(recording.pump_injected)
    assert metrics['sequence_type'] == metrics['sequence_type_of_scene'] == 'asymmetric'
    # The snaps are found in the recorded volumes, independently of the events topic.
    assert len(solved.events) == metrics['snap_count'] == 4
    step = float(np.max(np.abs(np.diff(recording.pump_injected))))
    for ours, theirs in zip(metrics['snaps'], solved.events):
        # A snap lands on the first command past the fold.
        assert 0.0 <= abs(ours['injected_m3'] - theirs.injected) <= step
        moved = 0.5 * np.sum(np.abs(theirs.to_volumes - theirs.from_volumes))
        assert ours['fluid_moved_m3'] == pytest.approx(moved, rel=0.2)
    assert [s['direction'] for s in metrics['snaps']] == ['inflation'] * 2 + ['deflation'] * 2
    # A loop: inflation runs at higher pressure than deflation.
    assert metrics['hysteresis_area_j'] > 0.0


def test_a_run_the_relief_stopped_says_so_in_the_summary_and_the_metrics(asymmetric, tmp_path):
    # The paper's rig stopped by its relief (here at 5 kPa, 17.8 mL) read 'sequence type: none'
    # with no word of the stop: every number of such a run is that of the part it ran.
    _, whole = asymmetric
    metrics, text = write_report(whole, tmp_path / 'whole', figures=False)
    assert metrics['pump_end']['state'] == 'finished'
    assert 'cut short' not in text and 'did not run to its end' not in text
    bag = tmp_path / 'relief'
    result = softseq_ros.run('paper', bag, start_time_ns=0,
                             overrides={'pump': {'max_pressure_pa': 5000.0}})
    assert result.pump_state == 'stopped'
    metrics, text = write_report(bag, tmp_path / 'report', figures=False)
    end = metrics['pump_end']
    assert end['state'] == 'stopped' and 'max_pressure_pa' in end['reason']
    commands = [m.msg.position[0] for m in read_bag(bag, ['/pump/command'])]
    assert end['injected_m3'] == pytest.approx(commands[-1], abs=1e-15)
    assert f'pump stopped at {end["time_s"]:.3f} s' in text
    assert '(from the recording, cut short)' in text
    assert any('did not run to its end' in w for w in metrics['warnings'])
    assert 'did not run to its end' in (tmp_path / 'report' / 'report.md').read_text()
    # The time series marks where the pump ended it, in its own colour; a finished run not.
    from figure_checks import png_pixels

    from softseq_ros.analysis.figures import STOP_COLOUR, plot_timeseries

    stop = np.array([int(STOP_COLOUR[i:i + 2], 16) for i in (1, 3, 5)])
    for source, marked in ((bag, True), (whole, False)):
        out = tmp_path / f'{source.name}_timeseries.png'
        plot_timeseries(load_recording(source), out)
        near = np.all(np.abs(png_pixels(out) - stop) <= 12, axis=2)
        assert (near.sum() > 200) == marked, (source, near.sum())


def test_paper_scene_is_partial_with_the_top_taking_over_and_meets_the_reference(paper,
                                                                                  tmp_path):
    scene_path, bag = paper
    metrics, text = write_report(bag, tmp_path / 'report', scene_name=str(scene_path),
                                 reference_file=CONFIG / 'reference' / 'milana2018.yaml',
                                 svg=False, figures=False)
    assert metrics['sequence_type'] == metrics['sequence_type_of_scene'] == 'partial'
    assert metrics['snap_count'] == 0
    assert abs(metrics['hysteresis_area_j']) < 1e-9
    switch = metrics['switch']
    assert switch['segment_taking_over'] == 'top'
    assert 20 * ML < switch['injected_m3'] < 40 * ML
    # The tables were calibrated to reach 95 % of the 65 mL pressure at 40 mL.
    assert metrics['plateau']['onset_injected_m3'] == pytest.approx(40 * ML, abs=1 * ML)
    checks = {c['what'].split(' (')[0]: c for c in metrics['reference']['checks']}
    assert all(c['agrees'] for c in metrics['reference']['checks'] if 'agrees' in c)
    assert checks['step 4 volume']['experiment_difference_m3'] == pytest.approx(-5 * ML,
                                                                         abs=0.05 * ML)
    steps = [(s['step'], s['direction']) for s in metrics['steps']]
    assert steps == [(n, 'inflation') for n in range(1, 6)] + \
        [(n, 'deflation') for n in range(5, 0, -1)]
    saved = json.loads((tmp_path / 'report' / 'metrics.json').read_text())
    assert saved['sequence_type'] == 'partial'
    assert 'partial' in (tmp_path / 'report' / 'report.md').read_text()


# ------------------------------------------------------------------------ experiments


@pytest.mark.parametrize(('shift', 'scale'), [(3.0 * ML, 1.08), (-2.0 * ML, 0.9)])
def test_a_synthetic_perturbation_is_recovered(paper, tmp_path, shift, scale):
    _, bag = paper
    trace = recording_trace(load_recording(bag))
    path = tmp_path / 'experiment.csv'
    path.write_text(synthetic_experiment(trace, shift, scale, rows=300))
    result = compare(trace, read_experiment(path))
    align = result['alignment']
    # Stated tolerance: 0.02 mL and 0.2 % on a 300-row file.
    assert align['volume_shift_m3'] == pytest.approx(shift, abs=0.02 * ML)
    assert align['pressure_scale'] == pytest.approx(scale, rel=2e-3)
    assert align['rmse_after_pa'] < 1e-3 * result['pv_rmse_pa']
    # Without alignment the error is what the perturbation makes.
    assert result['pv_rmse_pa'] > 100.0


def test_absolute_pressure_is_converted_and_undeclared_absolute_is_flagged(paper, tmp_path):
    _, bag = paper
    trace = recording_trace(load_recording(bag))
    declared = tmp_path / 'absolute.csv'
    declared.write_text(synthetic_experiment(trace, 0.0, 1.0, rows=200,
                                             absolute_ambient_pa=101325.0))
    experiment = read_experiment(declared)
    assert experiment.pressure_kind == 'absolute' and not experiment.warnings
    assert compare(trace, experiment)['pv_rmse_pa'] < 1.0
    undeclared = tmp_path / 'undeclared.csv'
    undeclared.write_text('\n'.join(line for line in declared.read_text().splitlines()
                                    if 'pressure_kind' not in line and 'ambient' not in line))
    experiment = read_experiment(undeclared)
    assert len(experiment.warnings) == 1 and 'looks absolute' in experiment.warnings[0]
    assert compare(trace, experiment)['pv_rmse_pa'] > 90e3


def test_tip_errors_per_step(paper, tmp_path):
    scene_path, bag = paper
    recording = load_recording(bag)
    trace = recording_trace(recording)
    path = tmp_path / 'tips.csv'
    path.write_text(synthetic_experiment(trace, 0.0, 1.0, rows=2000,
                                         lengths=load_scene(scene_path).lengths,
                                         tip_offset_m=(0.002, 0.0)))
    errors = compare(trace, read_experiment(path), recording.snapshots)['tip_errors']
    assert len(errors) == len(recording.snapshots) == 10
    for error in errors:
        assert error['error_m'] == pytest.approx(0.002, abs=2e-4)


def test_experiment_beyond_the_recording_widens_the_axis(paper, tmp_path, monkeypatch):
    from softseq_ros.analysis import figures

    _, bag = paper
    recording = load_recording(bag)
    trace = recording_trace(recording)
    path = tmp_path / 'beyond.csv'
    path.write_text(synthetic_experiment(trace, 10 * ML, 1.0, rows=100))
    experiment = read_experiment(path)
    drawn = []
    monkeypatch.setattr(figures, 'save_figure',
                        lambda fig, out, svg, style=None: drawn.append(fig) or [out])
    figures.plot_pv(recording, None, tmp_path / 'pv.png', experiment, svg=False)
    low, high = drawn[0].axes[0].get_xlim()
    assert high >= experiment.injected.max() * 1e6 > recording.state_injected.max() * 1e6
    assert low <= 0.0
    assert compare(trace, experiment)['rows_outside_model_range'] > 0


@pytest.mark.parametrize(('content', 'message'), [
    ('injected_m3,pressure\n0,1\n', 'no column pressure_pa'),
    ('# pressure_kind: vacuum\ninjected_m3,pressure_pa\n0,1\n', 'must be gauge or absolute'),
    ('injected_m3,pressure_pa\n0,abc\n', 'row 1, column pressure_pa: not a number'),
    ('injected_m3,pressure_pa\n65,1000\n', r'volumes must be in m\^3'),
    ('injected_m3,pressure_pa,direction\n0,1,up\n', 'must be inflation or deflation'),
])
def test_bad_experiment_files_are_one_line(tmp_path, content, message):
    path = tmp_path / 'bad.csv'
    path.write_text(content)
    with pytest.raises(ValueError, match=message) as error:
        read_experiment(path)
    assert str(path) in str(error.value) and '\n' not in str(error.value)


# ------------------------------------------------------------------------ other bags


def _copy_bag(source: Path, target: Path, rename=lambda topic: topic, extra=(),
              drop=()) -> None:
    """
    Rewrite a bag with rosbags (an independent writer): renamed topics, extra messages.

    ``drop`` names topics left out (as an older bag or another recorder would).
    """
    with AnyReader([source]) as reader, \
            Writer(target, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connections = {}
        for c in reader.connections:
            if c.topic not in drop:
                connections[c.topic] = writer.add_connection(
                    rename(c.topic), c.msgtype, msgdef=c.msgdef.data, rihs01=c.digest)
        extras = list(extra)
        for c in {e[0] for e in extras} - set(connections):
            connections[c] = writer.add_connection(
                c, 'std_msgs/msg/String', typestore=reader.typestore)
        for c, timestamp, raw in reader.messages():
            while extras and extras[0][1] <= timestamp:
                topic, when, data = extras.pop(0)
                writer.write(connections[topic], when, data)
            if c.topic not in drop:
                writer.write(connections[c.topic], timestamp, raw)


def _string_cdr(text: str) -> bytes:
    encoded = text.encode() + b'\x00'
    return b'\x00\x01\x00\x00' + len(encoded).to_bytes(4, 'little') + encoded


def test_snapshot_steps_pair_by_stamp_and_a_latched_snapshot_is_no_step(asymmetric, tmp_path):
    _, bag = asymmetric
    snapshots = contract.resolve(contract.SNAPSHOTS.name, '/')
    with AnyReader([bag]) as reader:
        shots = [(t, raw) for c, t, raw in reader.messages(
            connections=[c for c in reader.connections if c.topic == snapshots])]
        first_command = next(t for c, t, raw in reader.messages() if c.topic.endswith(
            contract.PUMP_COMMAND.name))
    # A latched snapshot from an earlier run: stamped 5 s before this run's first command.
    stale = bytearray(shots[0][1])
    stale[4:8] = (-5).to_bytes(4, 'little', signed=True)
    steps_topic = contract.resolve(contract.SNAPSHOT_STEPS.name, '/')
    status_topic = contract.resolve(contract.PUMP_STATUS.name, '/')
    extra = [(snapshots, first_command, bytes(stale)),
             (status_topic, first_command, _string_cdr(json.dumps(
                 {'state': 'running', 'reason': '', 'stamp_ns': first_command})))]
    for number, (t, raw) in enumerate(shots):
        stamp = int.from_bytes(raw[4:8], 'little', signed=True) * 10**9 + \
            int.from_bytes(raw[8:12], 'little')
        extra.append((steps_topic, t, _string_cdr(json.dumps(
            {'step': 7 + number, 'trigger_injected_m3': 1e-6 * number, 'direction': 'inflation',
             'injected_m3': 0.0, 'stamp_ns': stamp}))))
    extra.sort(key=lambda e: e[1])
    copy = tmp_path / 'copy'
    _copy_bag(bag, copy, extra=extra)
    recording = load_recording(copy)
    assert [s.step for s in recording.snapshots] == [7 + n for n in range(len(shots))]
    assert recording.ignored == {snapshots: 1}
    assert ('running', 0.0) in [(state, t) for t, state, _ in recording.status]


def test_two_rigs_in_one_bag_need_a_namespace(asymmetric, tmp_path, capsys):
    _, bag = asymmetric
    copy = tmp_path / 'one'
    _copy_bag(bag, copy, rename=lambda topic: '/rig2' + topic)
    assert load_recording(copy).namespace == '/rig2'
    assert load_recording(copy, '/rig2').namespace == '/rig2'
    with pytest.raises(RecordingError, match='no rig in namespace /rig9'):
        load_recording(copy, 'rig9')
    both = tmp_path / 'both'
    with AnyReader([copy]) as reader, \
            Writer(both, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        out = {}
        for c in reader.connections:
            for ns in ('/rig2', '/rig3'):
                out[(c.topic, ns)] = writer.add_connection(
                    c.topic.replace('/rig2', ns), c.msgtype, msgdef=c.msgdef.data,
                    rihs01=c.digest)
        for c, t, raw in reader.messages():
            for ns in ('/rig2', '/rig3'):
                writer.write(out[(c.topic, ns)], t, raw)
    with pytest.raises(RecordingError, match='namespaces /rig2, /rig3; choose one with '
                                             '--namespace'):
        load_recording(both)
    assert load_recording(both, 'rig3').namespace == '/rig3'


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, '-m', 'softseq_ros.cli', *args], capture_output=True,
                          text=True, timeout=120, stdin=subprocess.DEVNULL)


def test_foreign_and_broken_bags_are_one_clear_line(asymmetric, tmp_path):
    _, bag = asymmetric
    foreign = tmp_path / 'foreign'
    foreign.mkdir()
    (foreign / 'data.mcap').write_bytes(b'SQLite format 3\x00' + bytes(100))
    truncated = tmp_path / 'truncated'
    truncated.mkdir()
    data = next(bag.glob('*.mcap')).read_bytes()
    (truncated / 'cut.mcap').write_bytes(data[:len(data) // 2])
    no_rig = tmp_path / 'no_rig'
    _copy_bag(bag, no_rig, rename=lambda topic: topic.replace('pump', 'syringe'))
    cases = [(foreign, 'not an MCAP file'), (truncated, 'softseq recover'),
             (no_rig, 'not a rig recording'), (tmp_path / 'missing', 'no such bag')]
    for path, message in cases:
        result = _cli('report', str(path), '--out', str(tmp_path / 'out'))
        assert result.returncode == 2, (path, result.stderr)
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and message in lines[0] and str(path) in lines[0], lines


def test_compare_puts_two_scenes_side_by_side(asymmetric, paper, tmp_path):
    result = _cli('compare', str(paper[1]), str(asymmetric[1]), '--out', str(tmp_path))
    assert result.returncode == 0, result.stderr
    rows = {line.split('|')[1].strip(): [c.strip() for c in line.split('|')[2:-1]]
            for line in result.stdout.splitlines() if line.startswith('| ')}
    assert rows['sequence type'] == ['', 'partial', 'asymmetric', 'differs']
    assert rows['snap-throughs'] == ['', '0', '4', '4']
    assert rows['snap 1 (inflation)'][1:3] == ['-', rows['snap 1 (inflation)'][2]]
    saved = json.loads((tmp_path / 'compare.json').read_text())
    assert saved['a']['sequence_type'] == 'partial' and saved['b']['snap_count'] == 4


def _message_paths(node) -> list[str]:
    """Every string in a Foxglove layout that names a topic (``/topic.field[0]`` or a topic)."""
    if isinstance(node, dict):
        found = [key for key in node if isinstance(key, str) and key.startswith('/')]
        return found + [p for value in node.values() for p in _message_paths(value)]
    if isinstance(node, list):
        return [p for value in node for p in _message_paths(value)]
    return [node] if isinstance(node, str) and node.startswith('/') else []


def test_foxglove_layout_names_only_topics_and_fields_a_bag_has(asymmetric):
    _, bag = asymmetric
    layout = json.loads((CONFIG / 'foxglove' / 'softseq_rig.json').read_text())
    paths = _message_paths(layout)
    assert len(paths) >= 10
    with AnyReader([bag]) as reader:
        first = {}
        for connection, _, raw in reader.messages():
            first.setdefault(connection.topic, reader.deserialize(raw, connection.msgtype))
    for path in paths:
        topic, _, fields = path.partition('.')
        assert topic in first, f'{path}: no topic {topic} in a rig bag'
        value = first[topic]
        for part in filter(None, fields.split('.')):
            name, _, index = part.partition('[')
            assert hasattr(value, name), f'{path}: {type(value).__name__} has no {name}'
            value = getattr(value, name)
            if index:
                value = value[int(index.rstrip(']'))]
        if fields:
            assert isinstance(value, float), f'{path}: not a number'


def test_thinned_figures_keep_every_snap_and_invent_none(asymmetric, monkeypatch):
    from softseq_ros.analysis import figures

    _, bag = asymmetric
    recording = load_recording(bag)
    monkeypatch.setattr(figures, 'MAX_POINTS', 16)
    small = figures.thinned(recording)
    assert small.volumes.shape[0] < recording.volumes.shape[0] // 2
    snaps = figures._snap_rows(recording)
    assert snaps.size == 4
    # The thinned copy points at the same states: each snap row and the row before it.
    np.testing.assert_array_equal(small.volumes[small.snap_rows], recording.volumes[snaps])
    np.testing.assert_array_equal(small.volumes[small.snap_rows - 1],
                                  recording.volumes[snaps - 1])


def test_report_writes_every_figure_as_png_and_svg(asymmetric, tmp_path):
    scene_path, bag = asymmetric
    metrics, _ = write_report(bag, tmp_path, scene_name=str(scene_path), svg=True)
    names = {'pv', 'segments', 'volume_split', 'shapes', 'timeseries'}
    assert set(metrics['figures']) == {f'{n}.{ext}' for n in names for ext in ('png', 'svg')}
    for name in metrics['figures']:
        data = (tmp_path / name).read_bytes()
        assert data.startswith(b'\x89PNG') if name.endswith('.png') else b'<svg' in data[:400]
    assert '![pv.png](pv.png)' in (tmp_path / 'report.md').read_text()


def test_the_report_command_writes_svg_only_when_asked(asymmetric, tmp_path):
    _, bag = asymmetric
    names = {'pv', 'segments', 'volume_split', 'shapes', 'timeseries'}
    for flags, svgs in (((), set()), (('--svg',), {f'{n}.svg' for n in names})):
        out = tmp_path / ('svg' if flags else 'png')
        result = _cli('report', str(bag), *flags, '--out', str(out))
        assert result.returncode == 0, result.stderr
        assert {p.name for p in out.glob('*.png')} == {f'{n}.png' for n in names}
        assert {p.name for p in out.glob('*.svg')} == svgs


@pytest.mark.parametrize('layout', ['lz4, chunk indexes only', 'no chunks', 'no indexes'])
def test_other_mcap_layouts_read_the_same(asymmetric, tmp_path, layout):
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, IndexType
    from mcap.writer import Writer as McapWriter

    _, bag = asymmetric
    options = {'lz4, chunk indexes only': {'compression': CompressionType.LZ4,
                                           'index_types': IndexType.CHUNK, 'chunk_size': 8192},
               'no chunks': {'use_chunking': False},
               'no indexes': {'index_types': IndexType.NONE, 'chunk_size': 8192}}[layout]
    copy = tmp_path / 'copy'
    copy.mkdir()
    with open(next(bag.glob('*.mcap')), 'rb') as source, \
            open(copy / 'copy.mcap', 'wb') as target:
        reader = make_reader(source)
        writer = McapWriter(target, **options)
        writer.start(profile='ros2', library='test')
        schemas, channels = {}, {}
        summary = reader.get_summary()
        for schema in summary.schemas.values():
            schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
        for channel in summary.channels.values():
            channels[channel.id] = writer.register_channel(
                channel.topic, channel.message_encoding, schemas[channel.schema_id],
                channel.metadata)
        for _, channel, message in reader.iter_messages():
            writer.add_message(channels[channel.id], message.log_time, message.data,
                               message.publish_time, message.sequence)
        writer.finish()
    ours, theirs = load_recording(bag), load_recording(copy)
    for name in ('pump_injected', 'state_injected', 'pressure', 'volumes', 'curvatures',
                 'state_time_s'):
        np.testing.assert_array_equal(getattr(theirs, name), getattr(ours, name), name)
    assert [s.step for s in theirs.snapshots] == [s.step for s in ours.snapshots]
    assert theirs.events == ours.events


def test_joint_names_that_change_within_a_recording_are_refused(asymmetric, tmp_path):
    from mcap.reader import make_reader
    from mcap.writer import Writer as McapWriter

    _, bag = asymmetric
    volumes = contract.resolve(contract.VOLUMES.name, '/')
    copy = tmp_path / 'renamed'
    copy.mkdir()
    with open(next(bag.glob('*.mcap')), 'rb') as source, \
            open(copy / 'renamed.mcap', 'wb') as target:
        reader = make_reader(source)
        summary = reader.get_summary()
        writer = McapWriter(target, chunk_size=4096)
        writer.start(profile='ros2', library='test')
        schemas = {s.id: writer.register_schema(s.name, s.encoding, s.data)
                   for s in summary.schemas.values()}
        channels = {c.id: writer.register_channel(c.topic, c.message_encoding,
                                                  schemas[c.schema_id], c.metadata)
                    for c in summary.channels.values()}
        seen = 0
        for _, channel, message in reader.iter_messages():
            data = message.data
            if channel.topic == volumes:
                seen += 1
                if seen > 100:  # same length, another joint name: same size, other layout
                    data = data.replace(b'bottom\x00', b'bottoX\x00')
            writer.add_message(channels[channel.id], message.log_time, data,
                               message.publish_time)
        writer.finish()
    with pytest.raises(RecordingError, match=r'changes its names or frame id') as error:
        load_recording(copy)
    assert volumes in str(error.value) and '\n' not in str(error.value)


def test_an_experiment_saved_as_csv_utf8_with_a_byte_order_mark_is_read(tmp_path):
    rows = '# pressure: gauge\ninjected_m3,pressure_pa\n0.0,0.0\n1.0e-5,5000.0\n2.0e-5,8000.0\n'
    plain, marked = tmp_path / 'plain.csv', tmp_path / 'marked.csv'
    plain.write_text(rows, encoding='utf-8')
    marked.write_bytes(b'\xef\xbb\xbf' + rows.encode())
    a, b = read_experiment(plain), read_experiment(marked)
    assert np.array_equal(a.injected, b.injected) and np.array_equal(a.pressure, b.pressure)


# ------------------------------------------------------------------------ the scene that made it

SCENE_TOPIC = contract.resolve(contract.SCENE.name, '/')


def test_the_bag_names_its_scene_and_a_scene_with_other_segments_is_refused(asymmetric,
                                                                           tmp_path):
    scene, bag = asymmetric
    recorded = segments_sha256(load_scene(scene).segments)
    recording = load_recording(bag)
    assert recording.scene == SceneIdentity(recording.scene.stamp_ns, 'fast_asymmetric',
                                            ('bottom', 'top'), recorded)
    # fig1_symmetric has segments named bottom and top too: only the digest tells them apart.
    other = segments_sha256(load_scene('fig1_symmetric').segments)
    assert other != recorded
    out = tmp_path / 'report'
    result = _cli('report', str(bag), '--scene', 'fig1_symmetric', '--out', str(out))
    assert result.returncode == 2, result.stderr
    assert result.stderr.strip() == (
        f"softseq report: error: {bag}: recorded by scene 'fast_asymmetric' (segments sha256 "
        f"{recorded[:12]}), not by scene 'fig1_symmetric' (segments sha256 {other[:12]}): "
        'their segments (or supply lines) differ')
    assert result.stdout == '' and not out.exists()
    with pytest.raises(SceneMismatchError):
        write_report(bag, out, 'fig1_symmetric', figures=False)
    assert not out.exists()


def test_the_same_segments_under_another_scene_name_are_accepted_with_a_note(asymmetric,
                                                                           tmp_path):
    _, bag = asymmetric
    # The bag's scene is fig1_asymmetric with a faster pump, saved as fast_asymmetric.
    metrics, text = write_report(bag, tmp_path, 'fig1_asymmetric', figures=False)
    digest = segments_sha256(load_scene('fig1_asymmetric').segments)
    assert metrics['recorded_scene']['segments_sha256'] == digest
    assert metrics['recorded_scene']['scene'] == 'fast_asymmetric'
    assert metrics['notes'] == [f"recorded as scene 'fast_asymmetric', which has the same "
                                f"segments as scene 'fig1_asymmetric' (sha256 {digest[:12]})"]
    assert f'note: {metrics["notes"][0]}' in text
    assert f'scene: fast_asymmetric (segments bottom, top, sha256 {digest[:12]}; checked' in text
    assert json.loads((tmp_path / 'metrics.json').read_text())['recorded_scene'] == \
        metrics['recorded_scene']


def test_a_bag_without_the_scene_topic_is_reported_with_a_note_that_it_was_not_checked(
        asymmetric, tmp_path):
    _, bag = asymmetric
    older = tmp_path / 'older'
    _copy_bag(bag, older, drop={SCENE_TOPIC})
    assert load_recording(older).scene is None
    result = _cli('report', str(older), '--scene', 'fig1_symmetric', '--no-svg',
                  '--out', str(tmp_path / 'report'))
    assert result.returncode == 0, result.stderr
    assert (f'note: the bag records no {SCENE_TOPIC} (an older bag, or another recorder): '
            "whether scene 'fig1_symmetric' made it could not be checked") in result.stdout
    metrics = json.loads((tmp_path / 'report' / 'metrics.json').read_text())
    assert metrics['recorded_scene'] is None and len(metrics['notes']) == 1
    # Without a scene there is nothing to check and nothing to say.
    metrics, text = write_report(older, tmp_path / 'plain', figures=False)
    assert metrics['notes'] == [] and 'scene:' not in text


def test_an_actuator_restarted_on_other_segments_is_a_warning(asymmetric, tmp_path):
    _, bag = asymmetric
    other = segments_sha256(load_scene('fig1_symmetric').segments)
    first = load_recording(bag).start_ns
    second = {'scene': 'fig1_symmetric', 'segments': ['bottom', 'top'],
              'segments_sha256': other, 'stamp_ns': first + 10**9}
    copy = tmp_path / 'restarted'
    _copy_bag(bag, copy, extra=[(SCENE_TOPIC, first + 10**9, _string_cdr(json.dumps(second)))])
    recording = load_recording(copy)
    assert [s.scene for s in recording.scenes] == ['fast_asymmetric', 'fig1_symmetric']
    metrics, _ = write_report(copy, tmp_path / 'report', 'fig1_symmetric', figures=False)
    assert any('restarted on other segments' in w for w in metrics['warnings'])


def _wrong_type_bag(path: Path, namespace: str = '', wrong: str = 'pump/command') -> Path:
    """A bag with the rig's topics, one of them of another type than the contract's."""
    from softseq_ros.bag.writer import BagWriter
    from softseq_ros.wire.payloads import encode
    from softseq_ros.wire.values import PumpCommand, SegmentVolumes

    values = [PumpCommand(1, 0.0, 0.0), SegmentVolumes(1, ('bottom', 'top'), [1e-6, 1e-6], 0.0)]
    with BagWriter(path) as writer:
        for value in values:
            topic = f'{namespace}/{value.topic.name}'
            if value.topic.name == wrong:
                writer.add_topic(topic, 'std_msgs/msg/String')
                writer.write(topic, _string_cdr('not a command'), 1)
            else:
                writer.add_topic(topic, value.topic.type_name)
                writer.write(topic, encode(value), 1)
        if wrong == 'actuator/scene':
            topic = f'{namespace}/{wrong}'
            writer.add_topic(topic, 'sensor_msgs/msg/JointState')
            writer.write(topic, encode(values[1]), 1)
    return path


@pytest.mark.parametrize('namespace, wrong, expected', [
    ('', 'pump/command', 'std_msgs/msg/String, expected sensor_msgs/msg/JointState'),
    ('/rig2', 'pump/command', 'std_msgs/msg/String, expected sensor_msgs/msg/JointState'),
    ('', 'actuator/volumes', 'std_msgs/msg/String, expected sensor_msgs/msg/JointState'),
    ('', 'actuator/scene', 'sensor_msgs/msg/JointState, expected std_msgs/msg/String'),
])
def test_a_topic_of_another_type_is_one_line(tmp_path, namespace, wrong, expected):
    bag = _wrong_type_bag(tmp_path / 'bag', namespace, wrong)
    for scene in ((), ('--scene', 'fig1_none')):
        result = _cli('report', str(bag), *scene, '--out', str(tmp_path / 'out'))
        assert result.returncode == 2, result.stderr
        assert result.stderr == (f'softseq report: error: {bag}: topic {namespace}/{wrong} '
                                 f'has type {expected}\n')
        assert not (tmp_path / 'out').exists()


def test_a_scene_message_that_is_no_identity_is_one_line(asymmetric, tmp_path):
    _, bag = asymmetric
    copy = tmp_path / 'garbled'
    first = load_recording(bag).start_ns
    _copy_bag(bag, copy, extra=[(SCENE_TOPIC, first, _string_cdr('{"scene": "paper"}'))])
    result = _cli('report', str(copy), '--out', str(tmp_path / 'out'))
    assert result.returncode == 2
    assert result.stderr.strip() == (
        f"softseq report: error: {SCENE_TOPIC}: message 1 is not a scene identity (JSON with "
        "scene, segments, segments_sha256): '{\"scene\": \"paper\"}'")
