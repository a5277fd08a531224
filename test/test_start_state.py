"""
A programme that starts from a stated history, not from rest: solve, the reach check and the
batch rig start where the history led (a hysteresis branch a straight start never reaches).
"""

from pathlib import Path

import numpy as np
import pytest
from scenes import shipped_scene_with

import softseq_ros
from softseq_ros import cli
from softseq_ros.analysis.recording import load_recording
from softseq_ros.quasistatic.solve import scene_map
from softseq_ros.scene.loader import load_scene
from softseq_ros.scene.validation import SceneError


def scene_file(folder: Path, pump: dict, network: bool = False) -> Path:
    channels = {'network': {'channels': [{'length_m': 0.01, 'radius_m': 5e-4}]}} if network \
        else {}
    return shipped_scene_with(folder, 'fig1_asymmetric.yaml', 'start.yaml',
                              pump={'flow_rate_m3_per_s': 2.0e-5, 'rate_hz': 50, **pump},
                              camera={'rate_hz': 1}, **channels)


def reversal_branch():
    """A branch of the Fig. 1 pair that only a history with a reversal reaches, and it."""
    graph = softseq_ros.graph('fig1_asymmetric')
    for branch in graph.branches:
        reach = graph.history_to(branch.index)
        if reach.reversals == 1:
            return branch.index, reach.history
    raise AssertionError('no branch needs a reversal')


def test_a_programme_starts_where_its_start_history_led(tmp_path):
    target, history = reversal_branch()
    start = history[-1]
    legs = [{'inflate_to_m3': start + 2.0e-6}]
    stated = softseq_ros.solve(scene_file(tmp_path, {'start_history_m3': list(history),
                                                     'legs': legs}))
    straight = softseq_ros.solve(scene_file(tmp_path, {'start_injected_m3': start,
                                                       'legs': legs}))
    assert stated.injected[0] == pytest.approx(start, rel=1e-15)
    assert int(stated.branch[0]) == target
    assert int(straight.branch[0]) != target
    # Where the history led: the branch's own state at the start volume.
    emap = scene_map(load_scene('fig1_asymmetric'))
    expected = emap.read(target, start + emap.total_rest_volume)
    np.testing.assert_allclose(stated.volumes[0], expected.volumes, rtol=1e-12)


def test_the_batch_rig_starts_where_the_history_led(tmp_path):
    target, history = reversal_branch()
    start = history[-1]
    path = scene_file(tmp_path, {'start_history_m3': list(history),
                                 'legs': [{'hold_s': 0.5}, {'inflate_to_m3': start + 1e-6}]})
    result = softseq_ros.run(path, tmp_path / 'bag')
    recording = load_recording(result.bag)
    emap = scene_map(load_scene('fig1_asymmetric'))
    expected = emap.read(target, start + emap.total_rest_volume)
    np.testing.assert_allclose(recording.volumes[0], expected.volumes, rtol=1e-12)
    assert recording.state_injected[0] == pytest.approx(start, rel=1e-15)


@pytest.mark.parametrize('pump, key, words', [
    ({'start_history_m3': [3.0e-5, 1.0e-5], 'start_injected_m3': 1.0e-5},
     'pump.start_history_m3', 'give start_injected_m3 or this, not both'),
    ({'start_history_m3': []}, 'pump.start_history_m3', 'needs at least one injected volume'),
    ({'start_history_m3': [3.0e-5, -1.0e-5]}, 'pump.start_history_m3[1]', 'must be >= 0'),
    ({'start_history_m3': [3.0e-5, 1.0]}, 'pump.start_history_m3[1]',
     'exceeds what the segments hold'),
], ids=['both', 'empty', 'negative', 'beyond_capacity'])
def test_a_bad_start_history_is_refused_naming_its_key(tmp_path, pump, key, words):
    legs = {'legs': [{'hold_s': 1.0}]}
    with pytest.raises(SceneError) as caught:
        load_scene(scene_file(tmp_path, {**legs, **pump}))
    assert f': {key}: ' in str(caught.value) and words in str(caught.value)


def test_a_start_history_beyond_the_domain_is_refused_before_anything_runs(tmp_path, capsys):
    # Within what the segments hold, beyond where the equilibrium's inflation ends.
    # (the pair holds 98.3 mL; its inflation ends at 93.8 mL).
    path = scene_file(tmp_path, {'start_history_m3': [9.6e-5, 1.0e-5],
                                 'legs': [{'hold_s': 1.0}]})
    code = cli.main(['run', str(path), '--out', str(tmp_path / 'bag')])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert "pump.start_history_m3[0]: 9.6e-05 m^3 is beyond the equilibrium's domain" in err[0]
    assert not (tmp_path / 'bag').exists()


def test_a_start_history_with_a_network_starts_at_rest_where_it_led(tmp_path):
    from softseq_ros.quasistatic.equilibrium import Tracker
    from softseq_ros.rig.model import actuator_model

    _, history = reversal_branch()
    scene = load_scene(scene_file(tmp_path, {'start_history_m3': list(history),
                                             'legs': [{'hold_s': 2.0}]}, network=True))
    # The balanced state the history leads to, walked by hand on the quasi-static map.
    tracker = Tracker(scene_map(scene))
    for volume in history:
        tracker.move(volume)
    expected = np.asarray(tracker.state.volumes)
    scale = scene_map(scene).v_scale
    # In time: at rest there, no fluid moving between the segments, and it stays there.
    path = softseq_ros.solve(scene)
    assert path.injected[0] == pytest.approx(history[-1], rel=1e-15)
    np.testing.assert_allclose(path.volumes[0], expected, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(path.volumes[-1], expected, rtol=0, atol=1e-9 * scale)
    assert np.max(np.abs(path.channel_flows)) < 1e-9 * scale
    # The rig's model, and the batch rig's first answer, start there too.
    np.testing.assert_allclose(actuator_model(scene).state().volumes, expected, rtol=0,
                               atol=1e-12 * scale)
    result = softseq_ros.run(scene, tmp_path / 'bag', start_time_ns=0)
    first = load_recording(result.bag).volumes[0]
    np.testing.assert_allclose(first, expected, rtol=0, atol=1e-12 * scale)
