"""
Input refused before anything starts, in one line: no traceback, no file written, exit 2.

Each case is a file, field or option that used to end in a traceback (deep YAML, integers
beyond a float, a CSV field beyond the csv module's limit, a start time a bag cannot carry, a
mesh of billions of cells) or in a run that could not finish (a programme of 1e11 s of rig
time, a bag of 24 GB), or that was taken silently (``--jobs 0``).
"""

import csv
from pathlib import Path
import subprocess
import sys

import pytest

from softseq_ros.scene.paths import config_dir

HUGE = '1' + '0' * 400  # an integer literal beyond a double (1e400)
PAPER = (config_dir() / 'paper.yaml').read_text(encoding='utf-8')


def paper(folder: Path, *replacements: tuple[str, str], top_table: Path | None = None) -> Path:
    """The shipped paper scene with text replaced, its tables found from ``folder``."""
    text = PAPER.replace('segments/paper_', str(config_dir() / 'segments' / 'paper_'))
    if top_table is not None:
        text = text.replace(str(config_dir() / 'segments' / 'paper_top.csv'), str(top_table))
    for old, new in replacements:
        assert old in text, old
        text = text.replace(old, new)
    path = folder / 'scene.yaml'
    path.write_text(text, encoding='utf-8')
    return path


def table(folder: Path, name: str, data: bytes) -> Path:
    path = folder / name
    path.write_bytes(data)
    return path


TOP = (config_dir() / 'segments' / 'paper_top.csv').read_bytes()

# (case id, scene maker(folder) -> scene path, what stderr must name)
SCENES = [
    ('nested_yaml', lambda d: _write(d / 'scene.yaml', 'name: deep\ndescription: '
                                     + '[' * 100_000 + ']' * 100_000 + '\n'),
     'nested too deeply'),
    ('integer_of_5000_digits',
     lambda d: paper(d, ('length_m: 0.111 ', f'length_m: 1{"0" * 5000} ')),
     'scene.yaml: YAML'),
    ('length_beyond_a_float', lambda d: paper(d, ('length_m: 0.111 ', f'length_m: {HUGE} ')),
     'segments[0].length_m'),
    ('rate_beyond_a_float', lambda d: paper(d, ('rate_hz: 50', f'rate_hz: {HUGE}')),
     'pump.rate_hz'),
    ('leg_beyond_a_float', lambda d: paper(d, ('inflate_to_m3: 6.5e-5', f'inflate_to_m3: {HUGE}')),
     'pump.legs[0].inflate_to_m3'),
    ('trigger_beyond_a_float', lambda d: paper(d, ('[5.0e-6, 1.5e-5', f'[5.0e-6, {HUGE}')),
     'camera.trigger_injected_m3[1]'),
    ('cycles_beyond_64_bits', lambda d: paper(d, ('cycles: 1', f'cycles: {HUGE}')),
     'pump.cycles'),
    ('csv_field_beyond_the_limit', lambda d: paper(d, top_table=table(
        d, 'long.csv', TOP + b'"' + b'9' * (csv.field_size_limit() + 10) + b'",0,0\n')),
     'long.csv'),
    ('latin1_table', lambda d: paper(d, top_table=table(
        d, 'latin.csv', TOP.replace(b'#', '# Mesur\u00e9'.encode('latin-1'), 1))),
     'latin.csv'),
    ('binary_table', lambda d: paper(d, top_table=table(d, 'binary.csv', bytes(range(256)) * 8)),
     'binary.csv'),
    # Programmes that cannot finish: refused from their duration, naming what makes them long
    # (the slowest flow a scene takes, 1 pL/s, over the paper's 65 mL is 1.3e11 s).
    ('flow_1_pL_per_s', lambda d: paper(d, ('flow_rate_m3_per_s: 5.0e-8',
                                            'flow_rate_m3_per_s: 1.0e-15')),
     'pump.legs[0].inflate_to_m3: 6.5e-05 m^3 at pump.flow_rate_m3_per_s 1e-15'),
    ('a_leg_of_its_own_at_1_pL_per_s',
     lambda d: paper(d, ('- deflate_to_m3: 0.0',
                         '- {deflate_to_m3: 0.0, flow_rate_m3_per_s: 1.0e-15}')),
     'pump.legs[2].deflate_to_m3: 6.5e-05 m^3 at pump.legs[2].flow_rate_m3_per_s 1e-15'),
    ('a_million_cycles', lambda d: paper(d, ('cycles: 1', 'cycles: 1000000')),
     'pump.cycles: 1000000 cycles of 2610 s'),
    ('a_hold_of_1e7_s', lambda d: paper(d, ('hold_s: 10', 'hold_s: 1.0e7')),
     'pump.legs[1].hold_s: 1e+07 s'),
    # ... and from the bag's estimated size: 1e4 commands a second, each answered on 3 topics
    # (1e8 messages over 2610 s), or 640 x 480 images at 10 Hz (24 GB).
    ('1e8_messages', lambda d: paper(d, ('rate_hz: 50', 'rate_hz: 10000')),
     'pump.rate_hz 10000 Hz'),
    ('24_GB_of_images', lambda d: paper(d, ('outputs: [pressure', 'outputs: [image, pressure')),
     'outputs curvature, events, image'),
]


def _write(path: Path, text: str) -> Path:
    path.write_text(text, encoding='utf-8')
    return path


def softseq(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, '-m', 'softseq_ros.cli', *args], capture_output=True,
                          text=True, timeout=240, stdin=subprocess.DEVNULL)


def assert_one_line(result: subprocess.CompletedProcess, command: str, names: str) -> None:
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2, result.stderr[-2000:]
    assert 'Traceback' not in result.stderr
    assert len(lines) == 1, result.stderr[-2000:]
    assert lines[0].startswith(f'softseq {command}: error: ')
    assert names in lines[0], lines[0]


@pytest.mark.parametrize('make, names', [case[1:] for case in SCENES],
                         ids=[case[0] for case in SCENES])
def test_run_refuses_a_scene_in_one_line(tmp_path, make, names):
    scene = make(tmp_path)
    out = tmp_path / 'bag'
    result = softseq('run', str(scene), '--out', str(out), '--quiet', '--no-report',
                     '--start-time', '0')
    assert_one_line(result, 'run', names)
    assert str(scene) in result.stderr or 'scene.yaml' in result.stderr
    assert not out.exists()


def test_solve_refuses_a_programme_too_long_to_sample_naming_the_scene(tmp_path):
    # A hold of 1e7 s at the pump's 50 Hz is 5e8 samples: a traceback before, and without a
    # --path history solve samples the whole programme.
    scene = paper(tmp_path, ('hold_s: 10', 'hold_s: 1.0e7'))
    out = tmp_path / 'path.csv'
    result = softseq('solve', str(scene), '--out', str(out))
    assert_one_line(result, 'solve', 'scene.yaml: pump.rate_hz: 50 Hz')
    assert 'give a volume history' in result.stderr
    assert not out.exists()


def test_allow_long_insists_on_a_long_programme(tmp_path):
    from softseq_ros.batch import LongRunError, run

    long_hold = paper(tmp_path, ('hold_s: 10', 'hold_s: 1.0e7'))
    with pytest.raises(LongRunError):
        run(long_hold, tmp_path / 'refused', start_time_ns=0)
    assert not (tmp_path / 'refused').exists()

    class BuiltError(Exception):
        pass

    def built(label, function):
        # The first stage handed to ``wrap``: the run passed its checks and built its cores.
        raise BuiltError(function.__self__.duration_s if label == 'pump.tick' else None)

    # Insisting is allowed: the run is built (and would run), nothing is written yet.
    with pytest.raises(BuiltError) as seen:
        run(long_hold, tmp_path / 'insisted', start_time_ns=0, allow_long=True, wrap=built)
    assert seen.value.args[0] > 1.0e7
    assert not (tmp_path / 'insisted').exists()


@pytest.mark.parametrize('when', ['-1', 'inf', 'nan', '1e10', '2262-04-12T00:00:00Z',
                                  '9999-01-01T00:00:00Z', 'yesterday'])
def test_run_refuses_a_start_time_a_bag_cannot_carry(tmp_path, when):
    out = tmp_path / 'bag'
    result = softseq('run', 'fig1_none', '--out', str(out), '--quiet', '--no-report',
                     f'--start-time={when}')
    assert_one_line(result, 'run', '--start-time')
    assert not out.exists()


def test_the_last_start_time_a_bag_carries_is_taken():
    from softseq_ros.cli import LAST_START_NS, start_time_ns

    assert start_time_ns('0') == 0
    assert LAST_START_NS - 10**9 < start_time_ns('2262-04-11T23:47:16Z') <= LAST_START_NS


@pytest.mark.parametrize('jobs', ['0', '-2', 'many'])
def test_library_refuses_a_job_count_below_one(tmp_path, jobs):
    out = tmp_path / 'library'
    result = softseq('library', str(config_dir() / 'library'), f'--jobs={jobs}',
                     '--out', str(out))
    assert_one_line(result, 'library', '--jobs')
    assert not out.exists()


@pytest.mark.parametrize('setting, names', [
    ('mesh.element_size_m=1e-6', 'hexahedra'),       # 5.6e11 cells over the unit cell
    ('mesh.thin_layer_cells=1000000', 'from 1 to'),  # a million planes of cells
])
def test_fem_refuses_a_mesh_of_billions_of_cells_before_meshing(tmp_path, setting, names):
    out, cache = tmp_path / 'table.csv', tmp_path / 'cache'
    result = softseq('fem', 'paper_top', '--set', setting, '--out', str(out),
                     '--cache-dir', str(cache), '--quiet')
    assert_one_line(result, 'fem', setting.split('=')[0])
    assert names in result.stderr
    assert not out.exists() and not cache.exists()


# A reference file is read before the bag: a malformed one is refused whatever the bag.
REFERENCES = [
    ('reported: [partial]\n', 'a mapping "reported"'),
    ('- reported\n', 'a mapping "reported"'),
    ('reported:\n  sequence_type: 3\n', 'reported.sequence_type'),
    ('reported:\n  plateau_onset_injected_m3: .nan\n', 'reported.plateau_onset_injected_m3'),
    ('reported:\n  plateau_onset_tolerance_m3: [1]\n', 'reported.plateau_onset_tolerance_m3'),
    ('reported:\n  steps: {step: 3}\n', 'reported.steps'),
    ('reported:\n  steps: [1, 2]\n', 'reported.steps[0]'),
    ('reported:\n  steps:\n    - {step: three}\n', 'reported.steps[0].step'),
    ('reported:\n  steps:\n    - {step: 3, experiment_injected_m3: -1.0e-5}\n',
     'reported.steps[0].experiment_injected_m3'),
    ('reported: ' + '[' * 100_000 + '\n', 'nested too deeply'),
]


@pytest.mark.parametrize('text, names', REFERENCES,
                         ids=[f'ref{i}' for i in range(len(REFERENCES))])
def test_report_refuses_a_malformed_reference_file_naming_the_key(tmp_path, text, names):
    reference = _write(tmp_path / 'reference.yaml', text)
    result = softseq('report', str(tmp_path / 'bag'), '--reference', str(reference),
                     '--out', str(tmp_path / 'report'))
    assert_one_line(result, 'report', names)
    assert str(reference) in result.stderr
    assert not (tmp_path / 'report').exists()


# (arguments, the one line's command, what it must name); argparse printed its usage first.
ARGUMENT_MISTAKES = [
    (['run'], 'run', 'the following arguments are required: scene, --out'),
    (['solve', 'fig1_none', '--out', 'p.csv', '--bogus'], 'solve',
     'unrecognized arguments: --bogus'),
    (['scenes', '--bogus'], 'scenes', 'unrecognized arguments: --bogus'),
    (['play', 'bag', '--rate', 'abc'], 'play', "argument --rate: invalid float value: 'abc'"),
    (['report', 'bag', '--style', 'ugly'], 'report', 'argument --style: invalid choice'),
    (['solve', 'fig1_none', '--out', '/proc/no/such/p.csv'], 'solve',
     '/proc/no: No such file or directory'),
    (['library', str(config_dir() / 'segments'), '--length-m', 'nan'], 'library',
     '--length-m: must be a finite length > 0 (m), got nan'),
]


@pytest.mark.parametrize('arguments, command, names', ARGUMENT_MISTAKES,
                         ids=[' '.join(a[:1] + a[-2:]) for a, _, _ in ARGUMENT_MISTAKES])
def test_argument_mistakes_are_one_line_of_the_subcommand(tmp_path, monkeypatch, capsys,
                                                          arguments, command, names):
    from softseq_ros.cli import main

    monkeypatch.chdir(tmp_path)
    try:
        code = main(arguments)
    except SystemExit as exit_:
        code = exit_.code
    stderr = capsys.readouterr().err
    lines = stderr.strip().splitlines()
    assert code == 2 and len(lines) == 1, stderr
    assert lines[0].startswith(f'softseq {command}: error: ') and names in lines[0], lines[0]
    assert 'usage:' not in stderr


def test_play_options_are_refused_naming_them(tmp_path, capsys):
    from softseq_ros.cli import main

    # Refused before the bag is opened (this one does not exist) and before rclpy starts.
    for option, value in (('--rate', '0'), ('--start-offset', '-1'),
                          ('--wait-for-subscribers', '-1'), ('--wait-for-subscribers', 'nan')):
        assert main(['play', str(tmp_path / 'bag'), option, value]) == 2
        (line,) = capsys.readouterr().err.strip().splitlines()
        assert line.startswith(f'softseq play: error: {option}: must be '), line


def test_a_reference_naming_a_segment_the_recording_lacks_is_refused(tmp_path):
    from softseq_ros.analysis.report import (
        ReferenceFileError,
        check_reference_segments,
        load_reference,
    )

    reference = _write(tmp_path / 'reference.yaml',
                       'reported:\n  segment_plateau_lower: middle\n')
    loaded = load_reference(reference)
    check_reference_segments(reference, load_reference(_write(
        tmp_path / 'good.yaml', 'reported:\n  segment_plateau_lower: top\n')), ('bottom', 'top'))
    with pytest.raises(ReferenceFileError, match=r"reference\.yaml: reported\."
                       r"segment_plateau_lower: 'middle' is no segment of this recording "
                       r'\(bottom, top\)'):
        check_reference_segments(reference, loaded, ('bottom', 'top'))
