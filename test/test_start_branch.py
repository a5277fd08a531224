"""
A programme that starts on a branch of the scene's transition graph (``pump.start_branch``):
the actuator, ``solve`` and the batch rig start where the graph's shortest history from rest
onto that branch leads, numbered as ``softseq graph`` numbers the branches.
"""

from pathlib import Path

import numpy as np
import pytest
from scenes import shipped_scene_with

import softseq_ros
from softseq_ros.analysis.recording import load_recording
from softseq_ros.quasistatic.equilibrium import Tracker
from softseq_ros.quasistatic.graph import nearest_branches, transition_graph
from softseq_ros.quasistatic.solve import scene_map
from softseq_ros.rig.model import actuator_model
from softseq_ros.scene.loader import load_scene
from softseq_ros.scene.validation import SceneError

HOLD = [{'hold_s': 1.0}]


def scene_file(folder: Path, shipped: str, pump: dict, **sections: object) -> Path:
    """The shipped scene ``shipped`` (by name) with this pump block, as a file in ``folder``."""
    return shipped_scene_with(folder, f'{shipped}.yaml', 'start_branch.yaml',
                              pump={'flow_rate_m3_per_s': 2.0e-5, 'rate_hz': 50, **pump},
                              camera={'rate_hz': 1}, **sections)


def walked_by_hand(shipped: str, branch: int):
    """
    The shipped scene's own graph, its history onto ``branch`` walked on a tracker from rest.

    Returns (map, history, reversals, segment volumes where the walk ends).
    """
    emap = scene_map(load_scene(shipped))
    reach = transition_graph(emap).history_to(branch)
    tracker = Tracker(emap)
    for volume in reach.history:
        tracker.move(volume)
    return emap, reach.history, reach.reversals, np.asarray(tracker.state.volumes)


# fig1_asymmetric's branches 3 and 6 and three_nested_loops' branch 12 take one, one and three
# reversals: a programme started straight from rest at the same volume is elsewhere.
@pytest.mark.parametrize('shipped, branch', [('fig1_asymmetric', 3),
                                            ('fig1_asymmetric', 6),
                                            ('three_nested_loops', 12)])
def test_the_actuator_starts_where_the_graphs_history_onto_the_branch_leads(
        tmp_path, shipped, branch):
    emap, history, reversals, expected = walked_by_hand(shipped, branch)
    assert reversals >= 1
    scene = softseq_ros.load_scene(scene_file(tmp_path, shipped, {'start_branch': branch,
                                                                 'legs': HOLD}))
    assert scene.pump.profile.start_history == history
    assert scene.pump.profile.start_injected == history[-1]
    first = np.asarray(actuator_model(scene).state().volumes)
    np.testing.assert_allclose(first, expected, rtol=1e-12)
    assert nearest_branches(emap, first[None, :])[0] == branch
    solved = softseq_ros.solve(scene)
    assert int(solved.branch[0]) == branch
    straight = softseq_ros.solve(scene_file(tmp_path, shipped, {'start_injected_m3': history[-1],
                                                               'legs': HOLD}))
    assert int(straight.branch[0]) != branch


def test_the_batch_rig_starts_on_the_branch(tmp_path):
    _, history, _, expected = walked_by_hand('fig1_asymmetric', 3)
    start = history[-1]
    path = scene_file(tmp_path, 'fig1_asymmetric',
                      {'start_branch': 3,
                       'legs': [{'hold_s': 0.5}, {'inflate_to_m3': start + 1e-6}]})
    result = softseq_ros.run(path, tmp_path / 'bag')
    recording = load_recording(result.bag)
    np.testing.assert_allclose(recording.volumes[0], expected, rtol=1e-12)
    assert recording.state_injected[0] == pytest.approx(start, rel=1e-15)


def test_the_legs_are_checked_from_the_branchs_start(tmp_path):
    _, history, _, _ = walked_by_hand('fig1_asymmetric', 3)
    below = 0.5 * history[-1]
    with pytest.raises(SceneError) as caught:
        softseq_ros.load_scene(scene_file(tmp_path, 'fig1_asymmetric',
                                          {'start_branch': 3,
                                           'legs': [{'inflate_to_m3': below}]}))
    assert (f': pump.legs[0].inflate_to_m3: {below:g} m^3 must be above the injected volume '
            f'the leg starts from ({history[-1]:g} m^3)') in str(caught.value)


@pytest.mark.parametrize('pump, words', [
    ({'start_branch': 17}, 'branch 17 does not exist: the graph of this scene has 9 branches '
                           '(0 to 8), see softseq graph'),
    ({'start_branch': -1}, 'must be >= 0, got -1'),
    ({'start_branch': 2.0}, 'must be an integer, got float 2.0'),
    ({'start_branch': '3'}, "must be an integer, got str '3'"),
    ({'start_branch': True}, 'must be an integer, got bool True'),
    ({'start_branch': 3, 'start_injected_m3': 1.0e-5},
     'give start_injected_m3 or this, not both'),
    ({'start_branch': 3, 'start_history_m3': [3.0e-5, 1.0e-5]},
     'give start_history_m3 or this, not both'),
], ids=['missing', 'negative', 'float', 'text', 'bool', 'with_start_injected',
        'with_start_history'])
def test_a_bad_start_branch_is_refused_in_one_line_naming_it(tmp_path, pump, words):
    with pytest.raises(SceneError) as caught:
        softseq_ros.load_scene(scene_file(tmp_path, 'fig1_asymmetric',
                                          {**pump, 'legs': HOLD}))
    message = str(caught.value)
    assert '\n' not in message
    assert ': pump.start_branch: ' in message and words in message


def test_a_start_branch_with_a_network_starts_in_time_on_the_branch(tmp_path):
    path = scene_file(tmp_path, 'fig1_asymmetric', {'start_branch': 3, 'legs': HOLD},
                      network={'channels': [{'length_m': 0.01, 'radius_m': 5e-4}]})
    scene = softseq_ros.load_scene(path)
    history = transition_graph(scene_map(scene)).history_to(3).history
    assert scene.pump.profile.start_history == tuple(history)
    solved = softseq_ros.solve(scene)
    emap = scene_map(scene)
    assert nearest_branches(emap, solved.volumes[:1])[0] == 3


def test_a_branch_no_history_reaches_is_refused(tmp_path):
    # rate_inversion's pair without its network: its branch 3 is reached by no history.
    assert transition_graph(scene_map(load_scene('rate_inversion'))).min_reversals()[3] is None
    path = scene_file(tmp_path, 'rate_inversion', {'start_branch': 3, 'legs': HOLD},
                      network=None)
    with pytest.raises(SceneError, match=r'pump\.start_branch: no history reaches branch 3: '
                                         r'.* a programme cannot start there'):
        softseq_ros.load_scene(path)


def test_a_reader_without_the_graph_refuses_a_start_branch_clearly(tmp_path):
    path = scene_file(tmp_path, 'fig1_asymmetric', {'start_branch': 3, 'legs': HOLD})
    with pytest.raises(SceneError, match='pump.start_branch: names a branch of the transition '
                                         'graph, which this reader of scenes cannot build'):
        load_scene(path)
