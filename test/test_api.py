"""The package-level API a notebook uses: one function per job, each run here as documented."""

from dataclasses import replace
from pathlib import Path
import re
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import softseq_ros
from softseq_ros.bag.reader import bag_summary, read_bag
from softseq_ros.quasistatic.equilibrium import EquilibriumMap, Tracker
from softseq_ros.scene.loader import load_scene


def test_solve_follows_the_history_as_the_tracker_does():
    scene = softseq_ros.load_scene('fig1_asymmetric')
    assert softseq_ros.load_scene(scene) is scene
    emap = EquilibriumMap(scene.segments)
    top = 0.95 * emap.injected_range[1]
    history = np.concatenate([np.linspace(0.0, top, 300), np.linspace(top, 0.0, 300)])
    path = softseq_ros.solve(scene, history)
    reference = Tracker(emap).sweep(history)
    np.testing.assert_array_equal(path.volumes, reference.volumes)
    np.testing.assert_array_equal(path.pressure, reference.pressure)
    # The asymmetric pair snaps on the way up and again on the way down, at other volumes
    # (hysteresis): every inflation snap is above the last deflation snap.
    rows = np.flatnonzero(path.snap)
    up = [e.injected for e, row in zip(path.events, rows) if row < 300]
    down = [e.injected for e, row in zip(path.events, rows) if row >= 300]
    assert up and down and min(up) > min(down)
    assert not any(np.isclose(u, d, rtol=1e-6) for u in up for d in down)


def test_run_records_the_rig_into_a_bag(tmp_path):
    scene = load_scene('fig1_none')
    result = softseq_ros.run('fig1_none', tmp_path / 'bag', start_time_ns=10**18,
                             overrides={'pump': {'flow_rate_m3_per_s': 1.0e-5},
                                        'camera': {'rate_hz': 2.0}})
    assert result.pump_state == 'finished'
    summary = bag_summary(tmp_path / 'bag')
    assert summary.start_ns == 10**18
    commands = [m.msg.position[0] for m in read_bag(tmp_path / 'bag', ['/pump/command'])]
    assert max(commands) == pytest.approx(scene.pump.profile.max_injected())
    assert result.message_counts['/camera/backbone'] == pytest.approx(
        2.0 * result.sim_duration_s, abs=2)
    with pytest.raises(ValueError, match='unknown core'):
        softseq_ros.run('fig1_none', tmp_path / 'other', overrides={'pumps': {}})


def test_run_takes_a_scene_changed_in_memory_as_it_is(tmp_path):
    # A notebook: load the paper's scene, double its flow rate in memory, run it into a bag.
    scene = softseq_ros.load_scene('paper')
    faster = 2.0 * scene.pump.profile.flow_rate
    changed = replace(scene, pump=replace(scene.pump,
                                          profile=replace(scene.pump.profile, flow_rate=faster)))
    result = softseq_ros.run(changed, tmp_path / 'bag', start_time_ns=0)
    assert result.pump_state == 'finished'
    commands = [(m.log_time_ns, m.msg.position[0])
                for m in read_bag(tmp_path / 'bag', ['/pump/command'])]
    times = np.array([t for t, _ in commands]) * 1e-9
    volumes = np.array([v for _, v in commands])
    rising = volumes < 0.5 * scene.pump.profile.max_injected()
    rising[np.argmax(volumes):] = False
    slope = np.polyfit(times[rising], volumes[rising], 1)[0]
    assert slope == pytest.approx(faster, rel=1e-6)
    # The whole programme took half the time the file's flow rate would take.
    assert result.sim_duration_s == pytest.approx(changed.pump.profile.duration(), rel=1e-3)
    assert result.sim_duration_s < 0.51 * scene.pump.profile.duration()


def test_the_top_level_shows_the_notebook_functions_only(ros_env):
    # A fresh interpreter: in this one, other tests' imports add submodules as attributes.
    code = ('import softseq_ros, sys; '
            'print(sorted(n for n in dir(softseq_ros) if not n.startswith("_"))); '
            'print(sorted(n for n in vars(softseq_ros) if not n.startswith("_"))); '
            'print("softseq_ros.analysis.recording" in sys.modules)')
    out = subprocess.run([sys.executable, '-c', code], env=ros_env, capture_output=True,
                         text=True, check=True).stdout.splitlines()
    public = ['classify', 'graph', 'load_recording', 'load_scene', 'report', 'run', 'solve']
    assert out == [repr(public), repr(['classify', 'graph', 'load_scene', 'report', 'solve']),
                   'False']
    assert sorted(softseq_ros.__all__) == public


def test_load_recording_at_the_top_level_is_the_analysis_loader(tmp_path):
    from softseq_ros.analysis.recording import load_recording

    assert softseq_ros.load_recording is load_recording
    softseq_ros.run('fig1_none', tmp_path / 'bag', start_time_ns=0,
                    overrides={'pump': {'flow_rate_m3_per_s': 2.0e-5},
                               'camera': {'rate_hz': 1.0}})
    recording = softseq_ros.load_recording(tmp_path / 'bag')
    assert recording.segment_names == ('bottom', 'top')
    # Every state is the rest volumes plus what the pump injected (linear segments, 3 : 5).
    np.testing.assert_allclose(recording.volumes.sum(axis=1) - 2.0e-5,
                               recording.state_injected, atol=1e-15)
    with pytest.raises(AttributeError, match="no attribute 'load_recordings'"):
        softseq_ros.load_recordings  # noqa: B018


def test_run_at_the_top_level_is_the_batch_runner():
    from softseq_ros.batch import run

    assert softseq_ros.run is run


@pytest.mark.parametrize('kind', ['none', 'partial', 'symmetric', 'asymmetric'])
def test_classify_names_the_sequence_type_of_the_papers_fig1_scenes(kind):
    # The shipped Fig. 1 scenes reproduce the paper's four types, one each.
    assert softseq_ros.classify(f'fig1_{kind}') == kind


def test_solve_of_a_scene_with_a_network_is_its_path_in_time():
    from softseq_ros.dynamic.path import history_path

    scene = softseq_ros.load_scene('rate_inversion')
    history = np.linspace(0.0, 20e-6, 41)
    path = softseq_ros.solve(scene, history)
    reference = history_path(scene.segments, scene.network, history, scene.pump.profile.flow_rate)
    np.testing.assert_array_equal(path.time_s, reference.time_s)
    np.testing.assert_array_equal(path.volumes, reference.volumes)
    # Pushed at the pump's flow rate: the last row is reached after the history's volume / rate.
    assert path.time_s[-1] == pytest.approx(20e-6 / scene.pump.profile.flow_rate, rel=1e-9)
    # The same scene without its network is the quasi-static path, along the same volumes.
    slow = softseq_ros.solve(replace(scene, network=None), history)
    np.testing.assert_array_equal(slow.injected, history)


def test_solve_without_a_history_follows_the_scenes_programme():
    scene = softseq_ros.load_scene('fig1_asymmetric')
    path = softseq_ros.solve(scene)
    _, programme = scene.pump.profile.sample(scene.pump.rate_hz)
    np.testing.assert_array_equal(path.injected, programme)
    assert path.events


def test_graph_holds_every_branch_the_paths_visit():
    scene = softseq_ros.load_scene('fig1_asymmetric')
    graph = softseq_ros.graph(scene)
    path = softseq_ros.solve(scene)
    # Every state of the default path sits on one of the graph's stable branches, and the
    # graph has snaps on inflation and deflation (the asymmetric type's two snap-throughs).
    on_path = [b for b in graph.branches if b.default_path]
    assert len(on_path) >= 2 and len(graph.snaps()) >= 2
    for total in path.injected[::50]:
        assert any(b.injected_lo - 1e-12 <= total <= b.injected_hi + 1e-12
                   for b in on_path)


def test_the_readmes_python_section_runs_as_written(tmp_path, monkeypatch):
    # The README shows one function per job; its first code block runs here as it stands.
    text = (Path(__file__).resolve().parents[1] / 'README.md').read_text(encoding='utf-8')
    section = text.split('## From Python\n', 1)[1].split('\n## ', 1)[0]
    block = re.search(r'\n\n((?:    .*\n)+)', section).group(1)
    code = textwrap.dedent(block)
    for job in ('solve', 'classify', 'graph', 'run', 'load_recording', 'report'):
        assert f'softseq_ros.{job}(' in code, job
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    exec(compile(code, 'README.md', 'exec'), namespace)  # noqa: S102
    assert namespace['metrics']['sequence_type'] == 'partial'
    assert namespace['metrics']['sequence_type_of_scene'] == 'partial'
    assert (tmp_path / 'bags' / 'mine' / 'report' / 'metrics.json').is_file()
    assert (tmp_path / 'bags' / 'mine' / 'report' / 'report.md').is_file()
