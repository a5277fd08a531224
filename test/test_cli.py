"""The softseq command as a user runs it: subcommands, output files, one-line errors."""

import csv
import os
from pathlib import Path
import subprocess
import sys

import numpy as np
import pytest

from softseq_ros.cli import build_parser
from softseq_ros.scene.loader import load_scene

LINEAR_SCENE = """
name: linear_pair
segments:
  - name: base
    length_m: 0.1
    linear: {rest_volume_m3: 1.0e-6, stiffness_pa_per_m3: 1.0e9, max_volume_m3: 1.0e-4,
             curvature_per_m_per_m3: 1.0e5}
  - name: tip
    length_m: 0.1
    linear: {rest_volume_m3: 2.0e-6, stiffness_pa_per_m3: 3.0e9, max_volume_m3: 1.0e-4,
             curvature_per_m_per_m3: 2.0e5}
pump:
  flow_rate_m3_per_s: 1.0e-6
  rate_hz: 10
  legs: [{inflate_to_m3: 2.0e-5}, {deflate_to_m3: 0.0}]
"""


def run_softseq(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, '-m', 'softseq_ros.cli', *args],
                          capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL)


def read_csv(path: Path) -> tuple[list[str], list[list[str]]]:
    with path.open() as handle:
        rows = list(csv.reader(handle))
    return rows[0], rows[1:]


@pytest.fixture
def linear_scene(tmp_path: Path) -> Path:
    path = tmp_path / 'linear.yaml'
    path.write_text(LINEAR_SCENE)
    return path


def test_help_lists_every_subcommand():
    parser = build_parser()
    names = set(parser._subparsers._group_actions[0].choices)
    result = run_softseq('--help')
    assert result.returncode == 0
    for name in names:
        assert name in result.stdout
    assert {'solve', 'classify', 'scenes'} <= names


def test_solve_linear_pair_splits_in_stiffness_ratio(linear_scene, tmp_path):
    history = tmp_path / 'history.csv'
    commands = [0.0, 5e-6, 2e-5, 1e-5, 0.0]
    history.write_text('injected_m3\n' + '\n'.join(repr(c) for c in commands) + '\n')
    out = tmp_path / 'out.csv'
    result = run_softseq('solve', str(linear_scene), '--path', str(history), '--out', str(out))
    assert result.returncode == 0, result.stderr
    header, rows = read_csv(out)
    assert header == ['injected_m3', 'pressure_pa', 'volume_base_m3', 'volume_tip_m3',
                      'curvature_base_per_m', 'curvature_tip_per_m', 'event']
    assert len(rows) == len(commands)
    for command, row in zip(commands, rows):
        injected, pressure, v_base, v_tip, k_base, k_tip = (float(x) for x in row[:6])
        # Springs in parallel: the softer base takes k_tip / (k_base + k_tip) = 3/4.
        assert injected == command
        assert v_base - 1e-6 == pytest.approx(0.75 * command, abs=1e-18)
        assert v_tip - 2e-6 == pytest.approx(0.25 * command, abs=1e-18)
        assert pressure == pytest.approx(1e9 * 0.75 * command, abs=1e-6)
        assert k_base == pytest.approx(1e5 * 0.75 * command, abs=1e-12)
        assert k_tip == pytest.approx(2e5 * 0.25 * command, abs=1e-12)
        assert row[6] == ''


def test_solve_without_path_sweeps_the_pump_profile(linear_scene, tmp_path):
    out = tmp_path / 'out.csv'
    result = run_softseq('solve', str(linear_scene), '--out', str(out))
    assert result.returncode == 0, result.stderr
    _, rows = read_csv(out)
    injected = np.array([float(r[0]) for r in rows])
    # 0 -> 20 mL -> 0 at 1 mL/s is 40 s; sampled at 10 Hz with both ends included.
    assert injected.size == 401
    assert injected.max() == pytest.approx(2e-5)
    assert injected[0] == 0.0 and injected[-1] == pytest.approx(0.0, abs=1e-18)


def test_solve_reports_snaps_on_the_asymmetric_scene(tmp_path):
    out = tmp_path / 'out.csv'
    result = run_softseq('solve', 'fig1_asymmetric', '--out', str(out))
    assert result.returncode == 0, result.stderr
    header, rows = read_csv(out)
    snaps = [float(r[0]) for r in rows if r[-1] == 'snap']
    assert len(snaps) >= 2
    # Hysteresis: the snaps on the way down happen at other volumes than on the way up.
    peak = int(np.argmax([float(r[0]) for r in rows]))
    up = {round(float(r[0]), 12) for r in rows[:peak] if r[-1] == 'snap'}
    down = {round(float(r[0]), 12) for r in rows[peak:] if r[-1] == 'snap'}
    assert up and down and not (up & down)
    # Every row: the volumes add up to the commanded total.
    scene = load_scene('fig1_asymmetric')
    rest = sum(s.rest_volume for s in scene.segments)
    names = scene.segment_names
    columns = [header.index(f'volume_{n}_m3') for n in names]
    for r in rows:
        total = sum(float(r[c]) for c in columns)
        assert total - rest == pytest.approx(float(r[0]), abs=1e-12 * scene.capacity)


@pytest.mark.parametrize('history, fragment', [
    ('volume\n0\n', 'no column injected_m3'),
    ('injected_m3\n0\nabc\n', 'row 2, column injected_m3: not a number'),
    ('injected_m3\n0\nnan\n', 'row 2, column injected_m3: must be finite'),
    ('injected_m3\n', 'no rows below the header'),
    ('injected_m3\n0\n1.0\n', "data row 2: 1 m^3 is beyond the equilibrium's domain: segment"),
    ('injected_m3\n-1e-6\n',
     "data row 1: -1e-06 m^3 is below the equilibrium's domain: it starts at 0 m^3"),
])
def test_bad_history_is_one_line_and_exit_2(linear_scene, tmp_path, history, fragment):
    path = tmp_path / 'history.csv'
    path.write_text(history)
    result = run_softseq('solve', str(linear_scene), '--path', str(path),
                         '--out', str(tmp_path / 'out.csv'))
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert fragment in lines[0]
    assert 'Traceback' not in result.stderr


def test_missing_scene_is_one_line_and_exit_2(tmp_path):
    result = run_softseq('solve', str(tmp_path / 'nope.yaml'), '--out', str(tmp_path / 'o.csv'))
    assert result.returncode == 2
    assert 'nope.yaml' in result.stderr and len(result.stderr.strip().splitlines()) == 1


def test_classify_prints_the_sequence_type_of_shipped_scenes():
    result = run_softseq('classify', 'fig1_none')
    assert result.returncode == 0
    assert result.stdout.strip() == 'fig1_none: none'



def test_recover_makes_a_truncated_recording_readable(tmp_path):
    from softseq_ros.bag.reader import bag_summary
    from softseq_ros.bag.writer import BagWriter

    bag = tmp_path / 'killed'
    writer = BagWriter(bag, chunk_size=4096, flush_period_s=None)
    writer.add_topic('/pump/command', 'sensor_msgs/msg/JointState')
    for i in range(2000):
        writer.write('/pump/command', bytes(84), i * 1000, i * 1000)
    writer.flush()
    for i in range(2000, 2100):
        writer.write('/pump/command', bytes(84), i * 1000, i * 1000)
    # A recorder killed mid-write: what was flushed is on disk, followed by a torn record;
    # no summary, no metadata.yaml.
    mcap = bag / 'killed_0.mcap'
    with mcap.open('ab') as handle:
        handle.write(b'\x06' + bytes(40))
    assert not (bag / 'metadata.yaml').exists()
    result = run_softseq('recover', str(bag))
    assert result.returncode == 0, result.stderr
    assert 'recovered' in result.stdout
    summary = bag_summary(bag)
    assert summary.complete
    assert summary.topics['/pump/command'].message_count == 2000


def test_help_of_every_subcommand_works():
    for name in build_parser()._subparsers._group_actions[0].choices:
        result = run_softseq(name, '--help')
        assert result.returncode == 0, (name, result.stderr)
        assert 'usage: softseq' in result.stdout


def test_only_a_users_mistake_is_one_line_and_exit_2_a_bug_keeps_its_traceback(monkeypatch,
                                                                               capsys):
    from softseq_ros import cli
    from softseq_ros.errors import UserError
    from softseq_ros.scene.validation import SceneError

    # Every error class a user's input can cause derives from the one root.
    assert issubclass(SceneError, UserError)

    def mistaken(_args):
        raise SceneError('config/x.yaml: pump.rate_hz: must be > 0, got -1')

    def buggy(_args):
        raise ValueError('operands could not be broadcast together')

    monkeypatch.setattr(cli, '_scenes', mistaken)
    assert cli.main(['scenes']) == 2
    assert capsys.readouterr().err == ('softseq scenes: error: config/x.yaml: pump.rate_hz: '
                                       'must be > 0, got -1\n')
    # A ValueError that is not a user's mistake is a bug: it is not dressed up as one.
    monkeypatch.setattr(cli, '_scenes', buggy)
    with pytest.raises(ValueError, match='could not be broadcast'):
        cli.main(['scenes'])


def test_scenes_lists_each_shipped_scene_with_its_description():
    import yaml

    from softseq_ros.scene.paths import config_dir, shipped_scenes

    result = run_softseq('scenes')
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()[1:]
    assert [line.split()[0] for line in lines] == list(shipped_scenes())
    for name, line in zip(shipped_scenes(), lines):
        data = yaml.safe_load((config_dir() / f'{name}.yaml').read_text())
        # Which scenes run in time (a network: the pump's rate matters), and their description.
        kind = 'in time, a network' if 'network' in data else 'quasi-static'
        # A regulator's scene says so: the rig refuses it.
        kind += ', a pressure regulator' if 'regulator' in data.get('supply', {}) else ''
        assert line.split(None, 1)[1] == f'[{kind}] ' + ' '.join(data['description'].split())
    assert any('[in time, a network]' in line for line in lines)
    assert any('[in time, a network, a pressure regulator]' in line for line in lines)


@pytest.mark.parametrize('args', [('scenes',), ('classify', 'fig1_asymmetric')])
def test_a_reader_that_leaves_the_pipe_ends_the_command_quietly(args):
    # `softseq scenes | head -1`: the reader closes its end; the command stops as a filter does
    # (128 + SIGPIPE), with nothing on stderr, not "error: [Errno 32] Broken pipe".
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        done = subprocess.run([sys.executable, '-m', 'softseq_ros.cli', *args], stdout=write_end,
                              stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL,
                              timeout=120)
    finally:
        os.close(write_end)
    assert (done.returncode, done.stderr) == (141, '')


def test_a_broken_pipe_that_is_not_the_output_is_still_an_error(monkeypatch, capsys):
    from softseq_ros import cli

    def handler(args):
        raise BrokenPipeError(32, 'Broken pipe')
    parser = cli.build_parser()
    monkeypatch.setattr(cli, 'build_parser', lambda: parser)
    parser.commands['scenes'].set_defaults(handler=handler)
    assert cli.main(['scenes']) == 2
    assert capsys.readouterr().err == 'softseq scenes: error: [Errno 32] Broken pipe\n'
