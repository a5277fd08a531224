"""Numbers that can be quoted (a metric that does not apply says why), runs, paper figures."""

import json
from pathlib import Path
import subprocess
import sys

from figure_checks import capture_figures, laid_out, png_pixels, share_of, titles, whole
import numpy as np
import pytest
from scenes import fast_asymmetric
import yaml

import softseq_ros
from softseq_ros.analysis.compare import compare_bags
from softseq_ros.analysis.report import write_report

CONFIG = Path(__file__).resolve().parents[1] / 'config'
ML = 1e-6


def _bag(folder: Path, source: str, legs: list[dict], triggers: list[float]) -> Path:
    """A batch bag of a shipped scene with a short, fast programme (20 mL/s at 50 Hz)."""
    scene = yaml.safe_load((CONFIG / source).read_text())
    scene['name'] = Path(source).stem + '_short'
    scene['pump'].update({'flow_rate_m3_per_s': 2.0e-5, 'rate_hz': 50, 'legs': legs,
                          'cycles': 1})
    scene['camera'] = {'rate_hz': 5, 'trigger_injected_m3': triggers}
    path = folder / f'{scene["name"]}.yaml'
    path.write_text(yaml.safe_dump(scene))
    bag = folder / scene['name']
    softseq_ros.run(path, bag, start_time_ns=10**18)
    return bag


@pytest.fixture(scope='module')
def linear(tmp_path_factory) -> Path:
    """Fig. 1 'none': two linear segments, 0 -> 65 mL -> 0, no camera trigger volumes."""
    return _bag(tmp_path_factory.mktemp('none'), 'fig1_none.yaml',
                [{'inflate_to_m3': 6.5e-5}, {'deflate_to_m3': 0.0}], [])


@pytest.fixture(scope='module')
def peaked(tmp_path_factory) -> Path:
    """Fig. 1 'symmetric': a pressure peak, inflation only (0 -> 65 mL), two steps."""
    return _bag(tmp_path_factory.mktemp('symmetric'), 'fig1_symmetric.yaml',
                [{'inflate_to_m3': 6.5e-5}], [2.0e-5, 5.0e-5])


def test_a_straight_line_has_no_plateau_and_a_none_sequence_no_switch(linear, tmp_path):
    metrics, text = write_report(linear, tmp_path, figures=False)
    assert metrics['sequence_type'] == 'none'
    # The pressure of two linear segments rises at one slope to the end: no plateau, whatever
    # its end pressure (24.4 kPa) is.
    assert metrics['plateau'] is None
    assert 'does not level off' in metrics['not_applicable']['plateau']
    assert metrics['switch'] is None
    assert 'none takes over' in metrics['not_applicable']['switch']
    # A full cycle: the hysteresis area applies (and is zero: one path both ways).
    assert 'hysteresis_area_j' not in metrics['not_applicable']
    assert abs(metrics['hysteresis_area_j']) < 1e-12
    lines = {line.split(':')[0]: line for line in text.splitlines()}
    assert lines['plateau'].startswith('plateau: does not apply (the pressure does not level')
    assert lines['switch'].startswith('switch: does not apply (no segment')
    saved = json.loads((tmp_path / 'metrics.json').read_text())
    assert saved['plateau'] is None and saved['not_applicable'] == metrics['not_applicable']
    report = (tmp_path / 'report.md').read_text()
    assert '| plateau | does not apply (the pressure does not level off' in report
    assert 'takes over | does not apply' not in report
    assert "inflow) | does not apply (no segment's share" in report


def test_a_falling_curve_has_no_plateau_and_no_deflation_no_hysteresis(peaked, tmp_path):
    metrics, text = write_report(peaked, tmp_path, figures=False)
    assert metrics['sequence_type'] == 'symmetric'
    # The peaked curve's pressure falls after its peak: the end of inflation is no plateau.
    assert metrics['plateau'] is None
    reason = metrics['not_applicable']['plateau']
    assert reason.startswith('the pressure falls during inflation') and 'a peak' in reason
    # A segment takes over: the switch applies.
    assert metrics['switch']['segment_taking_over'] == 'top'
    assert metrics['hysteresis_area_j'] is None and metrics['deflation_recorded'] is False
    assert 'no deflation' in metrics['not_applicable']['hysteresis_area_j']
    assert 'hysteresis area: does not apply (no deflation' in text


def test_the_report_writes_no_empty_figure(linear, tmp_path):
    metrics, _ = write_report(linear, tmp_path)
    # No trigger volumes, no snapshot: no shapes figure (it would be empty).
    assert 'shapes.png' not in metrics['figures'] and not (tmp_path / 'shapes.png').exists()
    assert {'pv.png', 'segments.png', 'volume_split.png', 'timeseries.png'} <= \
        set(metrics['figures'])


def test_compare_says_which_metric_does_not_apply_and_why(linear, peaked):
    _, _, table = compare_bags(linear, peaked)
    rows = {line.split('|')[1].strip(): [c.strip() for c in line.split('|')[2:-1]]
            for line in table.splitlines() if line.startswith('| ')}
    assert rows['switch volume'][1] == 'does not apply'
    assert rows['switch volume'][3] == 'does not apply in A'
    assert rows['plateau pressure (gauge)'][1:] == ['does not apply', 'does not apply',
                                                    'does not apply in A and B']
    assert rows['hysteresis area'][2] == 'does not apply'
    reasons = table.split('Does not apply:')[1].splitlines()
    assert any(line.startswith('- A, switch volume: no segment') for line in reasons)
    assert any(line.startswith('- B, plateau pressure (gauge): the pressure falls')
               for line in reasons)
    assert any(line.startswith('- B, hysteresis area: no deflation') for line in reasons)


def _reset_once_at(volume_m3: float):
    """A batch run's ``wrap`` that stops and resets the pump once (as ~/stop and ~/reset do)."""
    done = []

    def wrap(label, function):
        if label != 'pump.tick':
            return function
        pump = function.__self__

        def tick(now):
            if not done and pump.volume_m3 >= volume_m3:
                done.append(now)
                return pump.stop(now).outputs + pump.reset(now).outputs + function(now)
            return function(now)
        return tick
    return wrap


@pytest.fixture(scope='module')
def two_runs(tmp_path_factory) -> Path:
    """
    A real two-run bag: the batch runner on the Fig. 1 asymmetric pair, 0 -> 50 mL -> 0, whose
    pump is stopped and reset at 3.8 mL (the command goes back to 0 mL in one step) and then
    runs its programme again from the start.
    """

    folder = tmp_path_factory.mktemp('two_runs')
    path = fast_asymmetric(folder, 'two_runs', camera_rate_hz=5, triggers=(2.5e-6, 2.5e-5))
    bag = folder / 'bag'
    softseq_ros.run(path, bag, start_time_ns=10**18, wrap=_reset_once_at(3.8 * ML))
    return bag


def test_a_bag_with_a_pump_reset_is_split_into_runs_each_reported(two_runs, tmp_path):
    from softseq_ros.analysis import figures
    from softseq_ros.analysis.recording import load_recording

    recording = load_recording(two_runs)
    # Both signs of the reset are seen: the command's jump back and the idle status.
    [start] = recording.run_starts
    assert 'jumped from 4.0000 mL to 0.0000 mL' in start.cause and 'idle again' in start.cause
    first, second = recording.runs()
    assert first.state_injected.max() == pytest.approx(4.0 * ML)
    assert second.state_injected.min() == 0.0 and second.state_injected.max() == \
        pytest.approx(50 * ML)
    metrics, text = write_report(two_runs, tmp_path)
    runs = metrics['runs']
    assert [r['run'] for r in runs] == [1, 2] and runs[1]['from_s'] == start.time_s
    # Run 1 ended at 4 mL without deflating; run 2 is the whole asymmetric cycle (four snaps,
    # as the single-run bag of the same pair has).
    assert runs[0]['hysteresis_area_j'] is None and runs[0]['injected_range_m3'][1] == \
        pytest.approx(4.0 * ML)
    assert runs[1]['sequence_type'] == 'asymmetric' and runs[1]['snap_count'] == 4
    assert runs[1]['hysteresis_area_j'] > 0.0
    # The numbers at the top are run 1's, and a warning says the bag holds two runs.
    assert metrics['snap_count'] == runs[0]['snap_count'] == 0
    assert any(w.startswith('the bag holds 2 pump runs') for w in metrics['warnings'])
    assert 'run 2 (from 0.220 s' in text and '## Runs' in (tmp_path / 'report.md').read_text()
    # No line of a figure joins the two runs: each drawn stretch lies within one run.
    boundary = int(recording.state_run_starts[0])
    for _, rows in figures._legs(recording):
        assert rows[-1] < boundary or rows[0] >= boundary


# ------------------------------------------------------------------------ figures for a paper


def test_paper_figures_are_cropped_titleless_and_show_both_directions(linear, peaked, tmp_path,
                                                                      monkeypatch):
    from softseq_ros.analysis import figures
    from softseq_ros.analysis.experiment import synthetic_experiment
    from softseq_ros.analysis.recording import load_recording
    from softseq_ros.analysis.report import recording_trace

    recording = load_recording(linear)
    experiment_file = tmp_path / 'retraced.csv'
    # An experiment whose deflation retraces its inflation, as the model's does here.
    experiment_file.write_text(synthetic_experiment(recording_trace(recording), 0.0, 1.0,
                                                    rows=200))
    drawn = capture_figures(monkeypatch, figures)
    metrics, _ = write_report(peaked, tmp_path / 'peaked')
    metrics, _ = write_report(linear, tmp_path / 'linear', experiment_csv=experiment_file)
    # No titles: a paper's caption says what a figure shows.
    assert drawn and not any(titles(fig) for fig in drawn)
    for folder in ('peaked', 'linear'):
        for png in (tmp_path / folder).glob('*.png'):
            # Cropped to what is drawn: no blank band across a figure (the former shapes
            # figure had a fifth of its height blank under its legends).
            laid_out(png)
    pv = png_pixels(tmp_path / 'linear' / 'pv.png')
    # The deflation retraces the inflation: both must still show.
    for colour in (figures.STYLE['inflation']['color'], figures.STYLE['deflation']['color'],
                   figures.EXPERIMENT_STYLE['inflation']['color'],
                   figures.EXPERIMENT_STYLE['deflation']['color']):
        assert share_of(pv, colour) > 1e-4, colour


def test_a_report_without_a_scene_imports_no_scipy(linear, tmp_path, ros_env):
    # scipy costs a report half a second to import: without a scene or an experiment to fit
    # (which need it) nothing on the report's way may import it, its figures' neither.
    code = ('import sys\n'
            'from softseq_ros.analysis import figure_workers\n'
            'figure_workers.start_workers = lambda svg=False: None\n'
            'from softseq_ros.analysis.report import write_report\n'
            f'write_report({str(linear)!r}, {str(tmp_path)!r})\n'
            'print(sorted({m.split(".")[0] for m in sys.modules} & {"scipy", "matplotlib"}))')
    result = subprocess.run([sys.executable, '-c', code], env=ros_env, capture_output=True,
                            text=True, timeout=120, stdin=subprocess.DEVNULL)
    assert result.returncode == 0, result.stderr
    assert result.stdout.splitlines()[-1] == "['matplotlib']"
    assert (tmp_path / 'pv.png').exists()


def test_figure_size_and_resolution_are_settable_and_bad_ones_refused(linear, tmp_path):
    from PIL import Image

    from softseq_ros.analysis.figures import FigureStyle, FigureStyleError

    write_report(linear, tmp_path, style=FigureStyle('paper', width_in=3.0, dpi=100))
    with Image.open(tmp_path / 'pv.png') as image:
        assert image.info['dpi'] == pytest.approx((100, 100), abs=0.5)
        # 3 in at 100 dpi, cropped to what is drawn (the legend below may widen it a little).
        assert 240 <= image.size[0] <= 330
    for flags, message in ((('--dpi', '5'), '--dpi 5: a resolution'),
                           (('--width', '0.1'), '--width 0.1: a figure width'),
                           (('--style', 'poster'), "invalid choice: 'poster'")):
        result = subprocess.run([sys.executable, '-m', 'softseq_ros.cli', 'report', str(linear),
                                 '--out', str(tmp_path / 'refused'), *flags],
                                capture_output=True, text=True, timeout=120,
                                stdin=subprocess.DEVNULL)
        assert result.returncode == 2 and message in result.stderr, result.stderr
        assert not (tmp_path / 'refused').exists()
    with pytest.raises(FigureStyleError):
        FigureStyle('paper', dpi=2000)


@pytest.mark.parametrize('command', [
    ['library', str(CONFIG / 'library')],
    ['rates', 'rate_inversion', '--flows', '1e-7', '--radii', '2e-4'],
    ['graph', 'fig1_asymmetric'],
])
def test_every_command_that_draws_refuses_a_bad_figure_option_before_any_work(tmp_path, capsys,
                                                                               command):
    from softseq_ros.cli import main

    for flags, message in ((('--dpi', '5'), '--dpi 5: a resolution'),
                           (('--width', '0.1'), '--width 0.1: a figure width')):
        out = tmp_path / flags[0].strip('-')
        assert main([*command, '--out', str(out), *flags]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and message in err[0], err
        assert not out.exists()


def test_screen_figures_have_their_titles_and_nothing_cut_off(linear, tmp_path, monkeypatch):
    from softseq_ros.analysis import figures

    drawn = capture_figures(monkeypatch, figures)
    write_report(linear, tmp_path, style=figures.FigureStyle('screen'))
    assert drawn and all(titles(fig) for fig in drawn)
    for png in tmp_path.glob('*.png'):
        # The title above the axes and the legend below them were cut by the canvas once.
        whole(png, dpi=110)


def test_steps_say_how_far_the_tip_bends(peaked, tmp_path):
    from softseq_ros.analysis.metrics import segment_lengths
    from softseq_ros.analysis.recording import load_recording

    recording = load_recording(peaked)
    # From the backbone's geometry alone, the segments' lengths of the scene (0.111 m each).
    np.testing.assert_allclose(segment_lengths(recording.snapshots, 2), [0.111, 0.111],
                               rtol=1e-9)
    metrics, text = write_report(peaked, tmp_path, figures=False)
    assert len(metrics['steps']) == 2
    for step, shot in zip(metrics['steps'], recording.snapshots):
        # Against curvature times length at the state the snapshot shows.
        row = int(np.searchsorted(recording.state_time_s, shot.time_s))
        expected = recording.curvatures[row] * 0.111
        np.testing.assert_allclose(step['bend_angles_rad'], expected, rtol=1e-6, atol=1e-9)
        assert step['tip_angle_rad'] == pytest.approx(expected.sum(), rel=1e-6)
    assert 'tip angle' in text


def test_compare_writes_an_overlay_figure_of_both_bags(linear, peaked, tmp_path):
    from softseq_ros.analysis.figures import BAG_COLOURS

    result = subprocess.run([sys.executable, '-m', 'softseq_ros.cli', 'compare', str(linear),
                             str(peaked), '--out', str(tmp_path), '--dpi', '120'],
                            capture_output=True, text=True, timeout=120,
                            stdin=subprocess.DEVNULL)
    assert result.returncode == 0, result.stderr
    pixels = laid_out(tmp_path / 'compare.png', dpi=120)
    assert all(share_of(pixels, colour) > 1e-3 for colour in BAG_COLOURS)
    assert str(tmp_path / 'compare.png') in result.stdout


def test_what_starts_a_run_and_what_does_not():
    from softseq_ros.analysis.recording import find_run_starts

    # A pump at 1 mL/s, 50 Hz: a tick skipped (twice the step over twice the time), a hold
    # (flow 0, the volume kept), then a leg three times as fast: one run.
    time = np.arange(0, 400) * 0.02
    time = np.delete(time, 50)
    rate = np.where(time < 4.0, 1e-6, 3e-6)
    moving = (time < 2.0) | (time >= 3.0)
    u = np.concatenate([[0.0], np.cumsum(np.where(moving[1:], rate[1:], 0.0) * np.diff(time))])
    sign = moving.astype(np.int8)
    status = [(0.0, 'idle', ''), (0.0, 'running', ''), (2.0, 'held', ''), (3.0, 'running', '')]
    assert find_run_starts(time, u, sign, status, [-0.5], 0.0) == []
    # An actuator that names its scene again after its first state started again.
    [start] = find_run_starts(time, u, sign, status, [-0.5, 5.001], 0.0)
    assert start.time_s == pytest.approx(5.02) and 'actuator started again' in start.cause


def _jumps_step_by_step(time: np.ndarray, u: np.ndarray, sign: np.ndarray) -> list[int]:
    """The jump rule as its docstring says it, one step at a time (the reference)."""
    from softseq_ros.analysis.recording import JUMP_FACTOR, JUMP_SHARE

    def flow(k: int) -> float:
        if not 0 <= k < u.size - 1 or sign[k + 1] == 0 or time[k + 1] <= time[k]:
            return 0.0
        return abs(u[k + 1] - u[k]) / (time[k + 1] - time[k])

    span = float(np.ptp(u)) or 1.0
    found = []
    for k in range(u.size - 1):
        allowed = JUMP_FACTOR * max(flow(k - 1), flow(k + 1)) * (time[k + 1] - time[k]) \
            if sign[k + 1] != 0 else 0.0
        if abs(u[k + 1] - u[k]) > max(allowed, JUMP_SHARE * span):
            found.append(k)
    return found


def testvolume_jumps_follow_the_rule_and_take_no_column_sized_temporaries():
    import tracemalloc

    from softseq_ros.analysis.recording import volume_jumps

    rng = np.random.default_rng(7)
    for _ in range(300):
        n = int(rng.integers(2, 30))
        time = np.cumsum(rng.choice([0.0, 0.01, 0.02, 0.04], n))
        u = np.concatenate([[0.0], np.cumsum(rng.choice([0.0, 1e-3, 5e-3, 0.5, -0.3], n - 1)
                                             * rng.random(n - 1))])
        sign = rng.choice([-1, 0, 1], n).astype(np.int8)
        assert volume_jumps(time, u, sign).tolist() == _jumps_step_by_step(time, u, sign)
    # Two million commands of a pump at 1 mL/s with one reset: found while holding no more
    # than the steps and their mask beside the columns (the rule as whole columns held seven).
    time = np.arange(2_000_000) * 0.02
    u = np.concatenate([np.arange(1_000_000), np.arange(1_000_000)]) * 2e-8
    sign = np.ones(u.size, np.int8)
    tracemalloc.start()
    try:
        assert volume_jumps(time, u, sign).tolist() == [999_999]
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 1.5 * u.nbytes
