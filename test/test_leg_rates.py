"""
A programme whose legs move at their own rates: the batch rig, the pump node's parameter and
the dynamic network's schedule follow the rates the legs give.
"""

from pathlib import Path

import numpy as np
import pytest
from scenes import shipped_scene_with

import softseq_ros
from softseq_ros.analysis.recording import load_recording
from softseq_ros.dynamic.path import programme_schedule
from softseq_ros.nodes.syringe_pump import parse_legs
from softseq_ros.scene.loader import load_scene

# Fill fast to 2 mL at 1 mL/s, step slowly to 3 mL at 0.01 mL/s, hold 1 s, empty at the
# pump's 20 mL/s: 2 s, 100 s, 1 s and 0.15 s.
LEGS = [{'inflate_to_m3': 2.0e-6, 'flow_rate_m3_per_s': 1.0e-6},
        {'inflate_to_m3': 3.0e-6, 'flow_rate_m3_per_s': 1.0e-8},
        {'hold_s': 1.0}, {'deflate_to_m3': 0.0}]


def stepped_scene(folder: Path) -> Path:
    return shipped_scene_with(folder, 'fig1_none.yaml', 'stepped.yaml',
                              pump={'flow_rate_m3_per_s': 2.0e-5, 'rate_hz': 50, 'legs': LEGS},
                              camera={'rate_hz': 1})


def test_a_batch_run_follows_each_leg_s_own_rate(tmp_path):
    result = softseq_ros.run(stepped_scene(tmp_path), tmp_path / 'bag')
    recording = load_recording(result.bag)
    t, injected = recording.pump_time_s, recording.pump_injected
    rising = slice(0, int(np.argmax(injected)) + 1)
    # When the commanded volume crosses 1, 2 and 2.5 mL on the way up: 1 s apart at 1 mL/s,
    # then 50 s for half a millilitre at 0.01 mL/s (to one pump tick, 0.02 s).
    crossing = np.interp([1.0e-6, 2.0e-6, 2.5e-6], injected[rising], t[rising])
    assert crossing[1] - crossing[0] == pytest.approx(1.0, abs=0.021)
    assert crossing[2] - crossing[1] == pytest.approx(50.0, abs=0.021)
    # The whole run: 2 + 100 + 1 + 0.15 s.
    falling = np.flatnonzero(injected == 0.0)
    assert t[falling[-1]] - crossing[0] == pytest.approx(103.15 - 1.0, abs=0.05)


def test_the_pump_node_s_legs_parameter_takes_a_leg_s_rate():
    legs = parse_legs('[{inflate_to_m3: 2.0e-6, flow_rate_m3_per_s: 1.0e-6}, {hold_s: 1}]')
    assert legs[0].flow_rate == 1.0e-6 and legs[1].flow_rate is None


def test_the_dynamic_network_pushes_each_leg_at_its_own_rate(tmp_path):
    profile = load_scene(stepped_scene(tmp_path)).pump.profile
    schedule, lead = programme_schedule(profile)
    assert lead == 0.0
    np.testing.assert_allclose(schedule.flows, [1.0e-6, 1.0e-8, 0.0, -2.0e-5], rtol=1e-12)
    np.testing.assert_allclose(schedule.times, [0.0, 2.0, 102.0, 103.0, 103.15], rtol=1e-12)
