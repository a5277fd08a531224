"""
A batch run by blocks of instants records what the cores give one message at a time.

The batch runner hands most instants to the cores in blocks (softseq_ros.batch) and
encodes and writes them in bulk; the instants that are not plain (a start, a snap-through, a
snapshot, a stop, the programme's end) go one core at a time. The reference is the same run
with every instant one core at a time (``by_blocks=False``: the path the nodes' cores take,
message by message). Every message of every topic must agree: log and publish times, every
integer, string and name exactly, every float within 1e-12 of its magnitude; and since the
two paths do the same floating-point operations, the .mcap files are the same byte for byte
(chunks close after the same messages). Each run has a fresh process, so that nothing the one
computed and cached (the equilibrium map's cubics) serves the other.
"""

from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
import math
import multiprocessing
from pathlib import Path

from mcap.reader import make_reader
import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore
from test_bag_regression import _flatten

import softseq_ros
from softseq_ros.batch import BLOCK_STAGES
from softseq_ros.rig.model import CommandRefusedError
from softseq_ros.scene.programme import Leg

START_NS = 1_795_000_000 * 10**9
ML = 1e-6
RELATIVE = 1e-12


def _messages(bag: Path) -> dict[str, list[tuple[int, int, list[str], list[float]]]]:
    """Per topic, in file order: log time, publish time, the exact skeleton and the floats."""
    typestore = get_typestore(Stores.ROS2_JAZZY)
    topics = defaultdict(list)
    with open(next(bag.glob('*.mcap')), 'rb') as stream:
        for schema, channel, message in make_reader(stream).iter_messages(
                log_time_order=False):
            skeleton, floats = [], []
            _flatten(typestore.deserialize_cdr(message.data, schema.name), skeleton, floats)
            topics[channel.topic].append((message.log_time, message.publish_time, skeleton,
                                          floats))
    return topics


def _run(tmp_path: Path, label: str, scene: str, overrides: dict, by_blocks: bool,
         wrap=None) -> tuple[Path, object]:
    # The same bag name in both runs: the bag's metadata names its file.
    out = tmp_path / label / 'bag'
    out.parent.mkdir()
    result = softseq_ros.run(scene, out, overrides=overrides, start_time_ns=START_NS,
                             by_blocks=by_blocks, wrap=wrap)
    return out, result


def _run_counted(tmp_path: Path, label: str, scene: str, overrides: dict,
                 by_blocks: bool) -> tuple[Path, object, dict[str, int]]:
    """:func:`_run` (in a child process) and the calls of each block stage."""
    counter = _BlockCounter()
    out, result = _run(tmp_path, label, scene, overrides, by_blocks, wrap=counter)
    return out, result, dict(counter.calls)


class _BlockCounter:
    """A ``wrap`` that counts the block stages' calls and leaves every stage as it is."""

    def __init__(self) -> None:
        self.calls: dict[str, int] = defaultdict(int)

    def __call__(self, label, function):
        if label not in BLOCK_STAGES:
            return function
        calls = self.calls

        def counted(*args):
            calls[label] += 1
            return function(*args)
        return counted


CASES = {
    # Paper scene, 0 -> 10 -> 0 mL: two snapshots each way, frames at every fifth command.
    'paper': ('paper', {'pump': {'legs': (Leg.inflate(10 * ML), Leg.deflate(0.0))}}),
    # Four snap-throughs (events and their notices), at ten times the paper's flow.
    'snaps': ('fig1_asymmetric', {'pump': {'flow_rate_m3_per_s': 5.0e-7}}),
    # A hold (repeated commands), a noisy camera at 7 Hz (frames between the pump's ticks).
    'hold_noise': ('paper', {'pump': {'legs': (Leg.inflate(4 * ML), Leg.hold(30.0),
                                                Leg.deflate(0.0))},
                             'camera': {'rate_hz': 7.0, 'noise_std_m': 1e-4, 'seed': 3}}),
    # The pump's end stop halfway up: the run ends stopped.
    'end_stop': ('paper', {'pump': {'legs': (Leg.inflate(10 * ML), Leg.deflate(0.0)),
                                    'max_injected_m3': 6 * ML}}),
    # An over-pressure stop heard on the actuator's answers.
    'over_pressure': ('paper', {'pump': {'legs': (Leg.inflate(10 * ML), Leg.deflate(0.0)),
                                         'max_pressure_pa': 2000.0}}),
    # No volumes: the pump runs open loop (its commands unanswered), the camera on curvatures.
    'open_loop': ('paper', {'pump': {'legs': (Leg.inflate(5 * ML), Leg.deflate(0.0))},
                            'actuator': {'outputs': frozenset({'pressure', 'curvature'})},
                            'camera': {'outputs': frozenset({'poses'})}}),
    # Pressure and volumes only: no curvatures, no frames, the pump's feedback still on.
    'few_outputs': ('paper', {'pump': {'legs': (Leg.inflate(5 * ML), Leg.deflate(0.0))},
                              'actuator': {'outputs': frozenset({'pressure', 'volumes'})},
                              'camera': {'outputs': frozenset()}}),
    # Behind a pressure regulator: target pressures commanded, four flips as events.
    'regulator': ('fig1_regulator_quasistatic', {}),
}


@pytest.mark.parametrize('case', sorted(CASES))
def test_blocks_record_every_message_as_one_at_a_time(case, tmp_path):
    scene, overrides = CASES[case]
    context = multiprocessing.get_context('spawn')
    with ProcessPoolExecutor(max_workers=2, mp_context=context) as pool:
        fast_run = pool.submit(_run_counted, tmp_path, 'blocks', scene, overrides, True)
        slow_run = pool.submit(_run_counted, tmp_path, 'messages', scene, overrides, False)
        (fast_bag, fast, calls), (slow_bag, slow, _) = fast_run.result(), slow_run.result()
    # The blocks did the work (else this compares the per-message path with itself).
    assert calls['block.append'] > 0
    assert fast.message_counts == slow.message_counts
    assert fast.pump_state == slow.pump_state
    assert fast.warnings == slow.warnings
    assert fast.sim_duration_s == slow.sim_duration_s
    expected, found = _messages(slow_bag), _messages(fast_bag)
    assert sorted(found) == sorted(expected)
    for topic, messages in expected.items():
        assert len(found[topic]) == len(messages), topic
        for index, (want, got) in enumerate(zip(messages, found[topic])):
            assert got[:3] == want[:3], f'{topic} message {index}'
            assert len(got[3]) == len(want[3]), f'{topic} message {index}'
            for a, b in zip(got[3], want[3]):
                if math.isfinite(b):
                    assert abs(a - b) <= RELATIVE * max(abs(a), abs(b)), \
                        f'{topic} message {index}: {a!r} against {b!r}'
                else:
                    assert repr(a) == repr(b), f'{topic} message {index}'
    assert next(fast_bag.glob('*.mcap')).read_bytes() == \
        next(slow_bag.glob('*.mcap')).read_bytes()


def test_the_cases_reach_what_they_are_for(tmp_path):
    # Each case must hold what it is named for, or the comparison above proves less.
    def counts(case):
        scene, overrides = CASES[case]
        _, result = _run(tmp_path, case, scene, overrides, True)
        return result
    snaps = counts('snaps')
    assert snaps.message_counts['/actuator/events'] >= 2
    paper = counts('paper')
    assert paper.message_counts['/camera/snapshots'] >= 2
    assert counts('end_stop').pump_state == 'stopped'
    assert counts('over_pressure').pump_state == 'stopped'
    assert counts('regulator').message_counts['/actuator/events'] == 4


def test_a_hook_that_changes_a_core_stage_runs_one_message_at_a_time(tmp_path):
    counter = _BlockCounter()

    def wrap(label, function):
        if label == 'pump.tick':
            return lambda now: function(now)
        return counter(label, function)

    _, result = _run(tmp_path, 'hooked', *CASES['paper'], True, wrap=wrap)
    assert result.pump_state == 'finished'
    assert not counter.calls


@pytest.mark.parametrize('scene', ['paper', 'fig1_asymmetric'])
def test_a_models_preview_gives_the_states_of_one_command_at_a_time(scene):
    # Ramps up and down with holds, through the snap-throughs, past the end of the domain
    # and a NaN: each preview stops at the first command that is not plain (a snap, a
    # refusal), whose states before it are those of the commands one at a time.
    from softseq_ros.rig.build import actuator_core
    from softseq_ros.scene.loader import load_scene
    loaded = load_scene(scene)
    step_by_step = actuator_core(loaded).model
    by_blocks = actuator_core(loaded).model
    top = step_by_step.end_stop_m3
    up = np.linspace(0.0, top, 3001)
    commands = np.concatenate([up, np.full(50, top), up[::-1], up[:700], [top * 1.5],
                               up[700:1400], [np.nan], up[1400:2000]])
    index, previews, cut = 0, 0, 0
    while index < commands.size:
        block = by_blocks.preview(commands[index:index + 257]) \
            if np.isfinite(commands[index:index + 257]).all() else None
        count = block.count if block is not None else 0
        for row in range(count):
            assert step_by_step.command(float(commands[index + row]), 0) in (None, [])
            state = step_by_step.state()
            assert list(block.volumes[row]) == list(state.volumes)
            assert block.pressure[row] == state.pressure
            assert list(block.curvatures[row]) == list(state.curvatures)
        if block is not None:
            by_blocks.commit(block, count)
            previews += 1
        index += count
        if index < commands.size and count < min(257, commands.size - index):
            # Not plain (or a NaN in reach): one command at a time, on both models.
            cut += 1
            for model in (step_by_step, by_blocks):
                try:
                    model.command(float(commands[index]), 0)
                except CommandRefusedError:
                    pass
            index += 1
        assert by_blocks.state() == step_by_step.state()
    assert by_blocks.solves == step_by_step.solves
    assert previews > 10 and cut >= 2


def test_a_regulated_models_preview_gives_the_states_of_one_target_at_a_time():
    # Ramps of target pressures up and down through both segments' peaks and valleys, a hold,
    # and a target beyond what the top holds: each preview stops at the first flip or refusal.
    from softseq_ros.rig.build import actuator_core
    from softseq_ros.scene.loader import load_scene
    loaded = load_scene('fig1_regulator_quasistatic')
    step_by_step = actuator_core(loaded).model
    by_blocks = actuator_core(loaded).model
    up = np.linspace(0.0, 8000.0, 2001)
    commands = np.concatenate([up, np.full(50, 8000.0), up[::-1], up[:1900], [1e6],
                               up[1900:]])
    index, previews, cut = 0, 0, 0
    while index < commands.size:
        block = by_blocks.preview(commands[index:index + 257])
        for row in range(block.count):
            assert step_by_step.command_pressure(float(commands[index + row]), 0) in (None, [])
            state = step_by_step.state()
            assert list(block.volumes[row]) == list(state.volumes)
            assert block.pressure[row] == state.pressure
            assert list(block.curvatures[row]) == list(state.curvatures)
        by_blocks.commit(block, block.count)
        previews += block.count > 0
        index += block.count
        if index < commands.size and block.count < min(257, commands.size - index):
            cut += 1
            for model in (step_by_step, by_blocks):
                try:
                    model.command_pressure(float(commands[index]), 0)
                except CommandRefusedError:
                    pass
            index += 1
        assert by_blocks.state() == step_by_step.state()
    # Both segments flip up, back down, up again (7.6 kPa passes both peaks), and the refusal:
    # seven cuts.
    assert previews > 10 and cut == 7
