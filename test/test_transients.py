"""
The transients of a dynamic bag in the report and in ``softseq compare``: snap durations as the
actuator measured them, the lag behind the quasi-static path, the transients figure; and a
quasi-static bag's report without any of it.
"""

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

import softseq_ros
from softseq_ros.analysis.compare import compare_bags
from softseq_ros.analysis.recording import load_recording
from softseq_ros.analysis.report import markdown, recording_metrics, summary_text, write_report
from softseq_ros.analysis.text import duration_text
from softseq_ros.bag.reader import read_bag
from softseq_ros.quasistatic.solve import scene_map
from softseq_ros.scene.loader import load_scene
from softseq_ros.scene.validation import YamlLoader

FIG1 = Path(__file__).resolve().parents[1] / 'config' / 'fig1_asymmetric.yaml'
# Wide enough that the pair snaps within seconds, narrow enough that it lags visibly.
CHANNEL = {'length_m': 0.01, 'radius_m': 0.5e-3}
TOP = 3.0e-5          # past the quasi-static snap-through of inflation at 26.4 mL
FAST = 2e-7           # 0.2 mL/s


def fig1_with_network(directory: Path, flow: float, rate_hz: float) -> Path:
    """The Fig. 1 asymmetric pair joined by CHANNEL, inflated at ``flow`` to TOP (a file)."""
    data = yaml.load(FIG1.read_text(), Loader=YamlLoader)
    # The same injected volume per output at both flows: the slow run is no longer. A hold
    # after the inflation lets the snap's exchange run its course (at 0.2 mL/s it is still
    # under way at TOP): an exchange is an event once it has.
    data['pump'].update({'flow_rate_m3_per_s': flow,
                         'legs': [{'inflate_to_m3': TOP}, {'hold_s': 30.0}],
                         'rate_hz': rate_hz})
    data['camera'] = {'rate_hz': 0.1}
    data['network'] = {'channels': [CHANNEL], 'rate_hz': rate_hz}
    path = directory / f'fig1_network_{flow:g}.yaml'
    path.write_text(yaml.safe_dump(data))
    return path


def run(scene_file: Path, out: Path) -> Path:
    softseq_ros.run(load_scene(scene_file), out, start_time_ns=0)
    return out


@pytest.fixture(scope='module')
def fast(tmp_path_factory) -> tuple[Path, Path]:
    """(scene file, bag) at 0.2 mL/s, 50 Hz."""
    directory = tmp_path_factory.mktemp('fast')
    scene_file = fig1_with_network(directory, FAST, 50.0)
    return scene_file, run(scene_file, directory / 'bag')


@pytest.fixture(scope='module')
def slow(tmp_path_factory) -> tuple[Path, Path]:
    """(scene file, bag) at 0.02 mL/s, 5 Hz."""
    directory = tmp_path_factory.mktemp('slow')
    scene_file = fig1_with_network(directory, FAST / 10, 5.0)
    return scene_file, run(scene_file, directory / 'bag')


@pytest.fixture(scope='module')
def quasi_static(tmp_path_factory) -> Path:
    directory = tmp_path_factory.mktemp('quasi_static')
    data = yaml.load(FIG1.read_text(), Loader=YamlLoader)
    data['pump'].update({'flow_rate_m3_per_s': 1e-6, 'legs': [{'inflate_to_m3': TOP}]})
    data['camera'] = {'rate_hz': 0.1}
    path = directory / 'fig1.yaml'
    path.write_text(yaml.safe_dump(data))
    return run(path, directory / 'bag')


def events_in(bag: Path) -> list[dict]:
    """
    The snap-through events, read with the general reader (not the analysis's).

    Every exchange of fluid is an event; these are the ones that were snap-throughs.
    """
    events = [json.loads(m.msg.data) for m in read_bag(bag, ['/actuator/events'])]
    return [event for event in events if event.get('snap_through', True)]


def test_the_report_of_a_dynamic_bag_shows_the_measured_snap_durations(fast, tmp_path):
    _, bag = fast
    metrics, summary = write_report(bag, tmp_path / 'report')
    events = events_in(bag)
    assert len(events) == 1 and events[0]['duration_s'] > 0
    transients = metrics['transients']
    assert transients['channels'] == ['bottom_to_top']
    snaps = transients['snaps']
    assert [s['duration_s'] for s in snaps] == [e['duration_s'] for e in events]
    assert [s['fluid_moved_m3'] for s in snaps] == [e['fluid_moved_m3'] for e in events]
    assert [s['start_time_s'] for s in snaps] == [e['start_ns'] / 1e9 for e in events]
    snap = snaps[0]
    # Fluid flows from the top into the bottom through the channel: against its direction.
    peak_flow = snap['peak_channel_flow_m3_per_s']['bottom_to_top']
    assert peak_flow < 0
    assert abs(peak_flow) == pytest.approx(snap['peak_exchange_m3_per_s'], rel=0.05)
    # Without the scene there is no quasi-static path to lag behind.
    assert transients['lag'] is None and snap['delay_injected_m3'] is None
    assert f'10-90 % in {duration_text(events[0]["duration_s"])}' in summary
    # Which segments gave the fluid and which took it, as the event named them.
    assert events[0]['giving_segments'] == ['top'] and events[0]['taking_segments'] == ['bottom']
    assert (snap['giving_segments'], snap['taking_segments']) == (['top'], ['bottom'])
    assert 'moved (top -> bottom)' in summary
    assert 'lag behind the quasi-static path: needs the scene' in summary
    # So are the channels' sizes, for their Reynolds numbers.
    assert transients['peak_reynolds'] is None
    assert 'peak Reynolds number per channel: needs the scene (--scene)' in summary
    report = (tmp_path / 'report' / 'report.md').read_text()
    assert '## Transients (fluid network)' in report
    assert '![transients.png](transients.png)' in report
    figure = tmp_path / 'report' / 'transients.png'
    assert figure.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    assert 'transients.png' in metrics['figures']
    written = json.loads((tmp_path / 'report' / 'metrics.json').read_text())
    assert written['transients']['snaps'][0]['duration_s'] == events[0]['duration_s']


def test_the_lag_shrinks_when_the_pump_is_ten_times_slower(fast, slow):
    # Both scenes have the same segments (only the pump differs): one map serves both.
    scene = load_scene(fast[0])
    emap = scene_map(scene)
    every = [recording_metrics(load_recording(bag), load_scene(scene_file), emap)
             for scene_file, bag in (fast, slow)]
    lags = [metrics['transients'] for metrics in every]
    quick, slower = lags
    # Each channel's peak Reynolds number, 2 rho |q| / (pi r mu) at the largest flow recorded
    # (read here with the general reader), water at 20 C. Pumped slowly, the pair snaps from
    # its fold with the whole pressure gap across the channel: a faster exchange than the fast
    # pump's, past the laminar range (said as a warning, as the actuator words it).
    peaks = []
    for (_, bag), lag in zip((fast, slow), lags):
        largest = max(abs(m.msg.velocity[0])
                      for m in read_bag(bag, ['/actuator/channel_flows']))
        peaks.append(2 * 998.0 * largest / (math.pi * CHANNEL['radius_m'] * 1.0e-3))
        assert lag['peak_reynolds'] == {'bottom_to_top': pytest.approx(peaks[-1], rel=1e-12)}
    assert 1000 < peaks[0] < 2300 < peaks[1]
    assert (f'peak Reynolds number per channel (recorded flows; laminar below about 2300): '
            f'bottom_to_top {peaks[0]:.0f}') in summary_text(every[0])
    assert f'Peak Reynolds number per channel (recorded flows; laminar below about 2300): ' \
           f'bottom_to_top {peaks[0]:.0f}.' in markdown(every[0])
    turbulent = [[w for w in metrics['warnings'] if 'no longer laminar' in w] for metrics in every]
    assert turbulent == [[], [f'channel bottom_to_top: Reynolds number {peaks[1]:.0f} above '
                              '2300, no longer laminar (the laminar law underestimates its '
                              'drop: give it friction: blasius)']]
    # The dynamic snap's exchange starts near the quasi-static one (26.39 mL), a little before
    # it where the top starts to give the bottom fluid on the stable branch (the bottom past
    # its peak), and peaks after it, by a positive volume.
    for (_, bag), lag in zip((fast, slow), lags):
        snap = lag['snaps'][0]
        assert snap['quasi_static_injected_m3'] == pytest.approx(2.639e-5, abs=2e-8)
        assert abs(snap['injected_m3'] - snap['quasi_static_injected_m3']) < 0.2e-6
        (event,) = events_in(bag)
        peak_injected = np.interp((event['peak_ns'] - load_recording(bag).start_ns) / 1e9,
                                  *zip(*[(m.log_time_ns / 1e9, m.msg.position[0])
                                         for m in read_bag(bag, ['/pump/command'])]))
        assert snap['delay_injected_m3'] == pytest.approx(
            peak_injected - snap['quasi_static_injected_m3'])
        assert snap['delay_injected_m3'] > 0
    # At the snaps: the snap's window and the fold passage's approach, as far before the
    # quasi-static snap as the recorded one came after it (there the quasi-static volumes run
    # away like the square root of the distance to the fold, and the lag is the passage's).
    for (_, bag), lag in zip((fast, slow), lags):
        recording = load_recording(bag)
        injected = recording.volumes.sum(axis=1) - emap.total_rest_volume
        snap = lag['snaps'][0]
        reach = snap['quasi_static_injected_m3'] - abs(snap['delay_injected_m3'])
        inside = (recording.state_time_s <= snap['window_s'][1]) & (
            (injected >= reach) | (recording.state_time_s >= snap['window_s'][0]))
        assert lag['lag']['at_snaps']['states'] == int(np.sum(inside))
        assert lag['lag']['off_snaps']['states'] == int(np.sum(~inside))
    # Off the snaps the state trails the slow manifold by about its time constant times the
    # pump's flow: first order, ten times less.
    for statistic in ('largest_m3', 'median_m3'):
        ratio = quick['lag']['off_snaps'][statistic] / slower['lag']['off_snaps'][statistic]
        assert 5 < ratio < 20, (statistic, ratio)
    assert 1e-3 < quick['lag']['off_snaps']['largest_share_of_range'] < 1e-2
    # A snap passes through a fold: it comes late by a delay that shrinks like Q^(2/3)
    # (10^(2/3) = 4.6).
    delays = [lag['snaps'][0]['delay_injected_m3'] for lag in lags]
    assert 3 < delays[0] / delays[1] < 10
    # At the snaps the distance is the jump itself: most of the volume range at both rates.
    for lag in lags:
        assert lag['lag']['at_snaps']['largest_share_of_range'] > 0.5
        assert lag['lag']['quasi_static_snaps_not_followed_m3'] == []
    delay = quick['snaps'][0]['delay_injected_m3']
    assert f'late by {delay * 1e6:.3f} mL injected after the quasi-static snap' in \
        summary_text(every[0])
    off = quick['lag']['off_snaps']['largest_m3']
    assert f'| off the snaps | {off * 1e6:.4f} mL' in markdown(every[0])


def test_compare_shows_the_snap_durations_and_a_quasi_static_bag_has_no_transients(
        fast, quasi_static):
    _, bag = fast
    metrics_a, metrics_b, table = compare_bags(quasi_static, bag)
    assert 'transients' not in metrics_a
    duration = events_in(bag)[0]['duration_s']
    row = next(line for line in table.splitlines() if 'duration (10-90 %)' in line)
    assert row.split('|')[3:5] == [' - ', f' {duration * 1e3:.4g} ']
    row = next(line for line in table.splitlines() if 'fluid from -> to' in line)
    assert row.split('|')[3:6] == [' - ', ' top -> bottom ', ' only in B ']
    # Without the scene there is no quasi-static path to measure the lag against.
    lag_rows = [line for line in table.splitlines() if 'lag behind the quasi-static' in line]
    assert len(lag_rows) == 4
    assert all(line.endswith('| - | - | - |') for line in lag_rows)
    _, _, same = compare_bags(quasi_static, quasi_static)
    assert 'in time' not in same and 'lag' not in same


def test_a_quasi_static_report_has_no_transients(quasi_static, tmp_path):
    metrics, summary = write_report(quasi_static, tmp_path / 'report', figures=False)
    assert 'transients' not in metrics
    assert 'transients' not in summary
    assert 'Transients' not in (tmp_path / 'report' / 'report.md').read_text()


def test_softseq_compare_with_the_scene_shows_the_lag(fast, quasi_static, capsys):
    from softseq_ros.cli import main

    scene_file, bag = fast
    assert main(['compare', str(quasi_static), str(bag), '--scene', str(scene_file)]) == 0
    table = capsys.readouterr().out
    lag_rows = [line for line in table.splitlines() if 'lag behind the quasi-static' in line]
    assert len(lag_rows) == 4
    # Measured for the dynamic bag (B), absent for the quasi-static one (A).
    assert all(line.split('|')[3].strip() == '-' and float(line.split('|')[4]) > 0.0
               for line in lag_rows)
    # And the channel's peak Reynolds number, which needs the scene's channel too.
    (row,) = [line for line in table.splitlines() if 'peak Reynolds number' in line]
    assert row.split('|')[1:4] == [' peak Reynolds number, bottom_to_top ', '  ', ' - ']
    assert 1000 < float(row.split('|')[4]) < 2300


def test_compare_lays_both_bags_transients_over_each_other(fast, slow, quasi_static, tmp_path,
                                                           capsys):
    import numpy as np

    from softseq_ros.analysis.compare import transients_overlay, write_transients_overlay
    from softseq_ros.cli import main

    recordings = [load_recording(bag) for _, bag in (fast, slow)]
    overlay = transients_overlay(*recordings, ('A', 'B'))
    assert len(overlay.windows) == 1
    # Each bag's own stretch of recording around its own snap, as the actuator reported it:
    # pressure and volumes as recorded, time from that snap's start.
    for window, recording, (_, bag) in zip(overlay.windows[0], recordings, (fast, slow)):
        event = events_in(bag)[0]
        assert window.snap.duration_s == event['duration_s']
        assert window.snap.start_s == pytest.approx(event['start_ns'] / 1e9, abs=1e-9)
        assert window.time_s[0] < 0.0 < window.time_s[-1]
        rows = np.searchsorted(recording.state_time_s, window.time_s + window.snap.start_s - 1e-9)
        np.testing.assert_allclose(window.pressure, recording.pressure[rows])
        np.testing.assert_allclose(window.volumes, recording.volumes[rows])
    # The faster pump's snap starts later (in injected volume): it lags further behind.
    assert overlay.windows[0][0].snap.injected > overlay.windows[0][1].snap.injected
    # A quasi-static bag has no snap in time: the other's alone; two of them: no figure.
    only_b = transients_overlay(load_recording(quasi_static), recordings[0], ('A', 'B'))
    assert only_b.windows[0][0] is None and only_b.windows[0][1] is not None
    assert transients_overlay(*[load_recording(quasi_static)] * 2, ('A', 'B')) is None
    out = tmp_path / 'compare'
    assert main(['compare', str(fast[1]), str(slow[1]), '--out', str(out),
                 '--style', 'screen']) == 0
    assert 'compare_transients.png' in capsys.readouterr().out
    assert (out / 'compare_transients.png').read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    assert write_transients_overlay(quasi_static, quasi_static, tmp_path / 'none') == []
    assert not (tmp_path / 'none').exists()


def test_the_summary_metrics_and_transients_count_the_same_snaps_in_time(fast, tmp_path):
    # In time a snap is an exchange over many states, no jump between two commands: the
    # summary's snap-through lines and metrics.json's snaps are the actuator's events too.
    _, bag = fast
    metrics, summary = write_report(bag, tmp_path / 'report')
    events = events_in(bag)
    assert metrics['snap_count'] == len(metrics['transients']['snaps']) == len(events) >= 1
    for snap, event in zip(metrics['snaps'], events):
        assert snap['injected_m3'] == event['injected_m3']
        assert snap['fluid_moved_m3'] == event['fluid_moved_m3']
        assert snap['to_volumes_m3'] == event['to_volumes_m3']
        assert f'snap-through at {snap["injected_m3"] * 1e6:.3f} mL' in summary
    assert 'snap-throughs: none' not in summary
    written = json.loads((tmp_path / 'report' / 'metrics.json').read_text())
    assert written['snap_count'] == len(events)


@pytest.mark.parametrize('snaps', [1, 4, 7])
def test_the_transients_figure_fits_a_page_with_its_key_below_every_curve(fast, tmp_path,
                                                                         monkeypatch, snaps):
    from dataclasses import replace

    from figure_checks import capture_figures, laid_out, png_dpi

    from softseq_ros.analysis import figures
    from softseq_ros.analysis.figures import PAGE_IN, PAPER, plot_transients
    from softseq_ros.analysis.transients import analyse_transients, transient_windows

    _, bag = fast
    recording = load_recording(bag)
    found = analyse_transients(recording)
    window = transient_windows(recording, found, 1, 400)[0]
    # As many snaps as a busy run has (the same one again, numbered on).
    windows = [replace(window, snap=replace(window.snap, number=k + 1)) for k in range(snaps)]
    drawn = capture_figures(monkeypatch, figures)
    out = tmp_path / 'transients.png'
    with PAPER.context():
        plot_transients(windows, recording.segment_names, ('bottom_to_top',), out)
    pixels = laid_out(out)
    assert pixels.shape[1] / png_dpi(out)[0] <= PAGE_IN + 0.05
    fig, = drawn
    # One key, the figure's, under the panels: none inside an axes, on the curves.
    assert not [ax for ax in fig.axes if ax.get_legend() is not None]
    assert len(fig.legends) == 1
    key_top = fig.legends[0].get_window_extent().y1
    renderer = fig.canvas.get_renderer()
    assert all(key_top <= ax.get_tightbbox(renderer).y0 + 1.0
               for ax in fig.axes if ax.get_visible())


def test_the_shapes_mark_where_one_segment_ends_and_the_next_begins(tmp_path, monkeypatch):
    from figure_checks import capture_figures

    from softseq_ros.analysis import figures
    from softseq_ros.analysis.figures import PAPER, plot_shapes, segment_joints

    # Two segments of three chords each: the joint is the fourth point.
    backbone = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.1], [3.0, 0.3], [4.0, 0.7],
                         [5.0, 1.2], [6.0, 2.0]])
    np.testing.assert_array_equal(segment_joints(backbone, 2), [[3.0, 0.3]])
    assert segment_joints(backbone[:6], 2).shape == (0, 2)     # no such layout: none
    data = yaml.load(FIG1.read_text(), Loader=YamlLoader)
    data['pump'].update({'flow_rate_m3_per_s': 5e-6, 'rate_hz': 20,
                         'legs': [{'inflate_to_m3': 4e-5}, {'deflate_to_m3': 0.0}]})
    data['camera'] = {'rate_hz': 1, 'trigger_injected_m3': [1e-5, 3e-5]}
    scene_file = tmp_path / 'steps.yaml'
    scene_file.write_text(yaml.safe_dump(data))
    recording = load_recording(run(scene_file, tmp_path / 'bag'))
    drawn = capture_figures(monkeypatch, figures)
    with PAPER.context():
        plot_shapes(recording, tmp_path / 'shapes.png')
    fig, = drawn
    inflation = fig.axes[0]
    assert 'segment joint' in [text.get_text() for text in inflation.get_legend().get_texts()]
    # One white dot per snapshot of the panel, at its backbone's joint.
    shots = [s for s in recording.snapshots if s.direction == 'inflation']
    dots = [line for line in inflation.get_lines()
            if line.get_marker() == 'o' and line.get_markerfacecolor() == 'white'
            and len(line.get_xdata())]
    assert len(dots) == len(shots) >= 1
    for line, shot in zip(dots, shots):
        joint = segment_joints(shot.points, len(recording.segment_names))[0]
        assert line.get_xdata()[0] == pytest.approx(joint[0] * 1e3)


def test_the_hysteresis_in_time_splits_into_the_curves_own_and_the_flows_loss(tmp_path):
    # The segments' own hysteresis is the quasi-static path's along the same injected volumes,
    # whatever the pump's speed; the rest is viscous, and at a laminar channel's drop R q it
    # falls in proportion to the flow.
    parts = {}
    for flow in (FAST, FAST / 4):
        data = yaml.load(FIG1.read_text(), Loader=YamlLoader)
        data['pump'].update({'flow_rate_m3_per_s': flow, 'rate_hz': 20.0,
                             'legs': [{'inflate_to_m3': TOP}, {'deflate_to_m3': 0.0}]})
        data['camera'] = {'rate_hz': 0.1}
        data['network'] = {'channels': [CHANNEL], 'rate_hz': 20.0}
        scene_file = tmp_path / f'fig1_{flow:g}.yaml'
        scene_file.write_text(yaml.safe_dump(data))
        bag = run(scene_file, tmp_path / f'bag_{flow:g}')
        metrics, summary = write_report(bag, tmp_path / f'report_{flow:g}', str(scene_file),
                                        figures=False)
        total = metrics['hysteresis_area_j']
        elastic = metrics['hysteresis_area_quasi_static_j']
        viscous = metrics['hysteresis_area_rate_dependent_j']
        assert elastic + viscous == pytest.approx(total, rel=1e-12)
        assert "is the flow's viscous loss" in summary
        parts[flow] = elastic, viscous
    (elastic_fast, viscous_fast), (elastic_slow, viscous_slow) = parts[FAST], parts[FAST / 4]
    # The quasi-static loop of this pair, independent of the speed (its snaps' losses).
    assert elastic_fast > 0.0 and elastic_fast == pytest.approx(elastic_slow, rel=0.02)
    assert 0.0 < viscous_slow < 0.5 * viscous_fast


def test_the_time_series_shades_where_the_pump_was_held(quasi_static, tmp_path, monkeypatch):
    from figure_checks import capture_figures

    from softseq_ros.analysis import figures
    from softseq_ros.analysis.figures import PAPER, held_spans, plot_timeseries

    recording = load_recording(quasi_static)
    # A hold from 10 s to 25 s, as a rig's ~/hold and ~/start put it on pump/status.
    recording.status = sorted(recording.status + [(10.0, 'held', ''), (25.0, 'running', '')])
    assert held_spans(recording) == [(10.0, 25.0)]
    drawn = capture_figures(monkeypatch, figures)
    with PAPER.context():
        plot_timeseries(recording, tmp_path / 'timeseries.png')
    fig, = drawn
    for ax in fig.axes:
        spans = [patch.get_x() for patch in ax.patches]
        assert 10.0 in spans, spans
    assert 'held' in [text.get_text() for text in fig.axes[0].texts]
