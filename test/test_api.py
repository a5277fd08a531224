"""The package-level entry points a notebook uses: load_scene, solve, run."""

from dataclasses import replace
import subprocess
import sys

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
    public = ['load_recording', 'load_scene', 'run', 'solve']
    assert out == [repr(public), repr(['load_scene', 'run', 'solve']), 'False']
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
