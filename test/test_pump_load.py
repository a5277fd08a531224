"""A new pump programme without restarting the node: set as parameters, taken by ~/load."""

import json

import pytest
from rclpy.parameter import Parameter

from softseq_ros.nodes.syringe_pump import SyringePumpNode
from softseq_ros.testing import Collector, call_trigger, spinning, wait_for

pytestmark = pytest.mark.ros


def test_a_programme_set_at_run_time_is_checked_at_once_and_loaded_when_idle(context):
    pump = SyringePumpNode(context=context, parameter_overrides=[
        Parameter('scene', value='fig1_none'), Parameter('autostart', value=False),
        Parameter('open_loop', value=True), Parameter('rate_hz', value=50)])
    rig = Collector(['pump/command', 'pump/status'], context)
    scene_programme = pump.core.profile
    with spinning(context, pump, rig):
        rig.wait_for_publishers()
        # Checked as at start, against the segments' equilibrium: refused with the reason.
        result, = pump.set_parameters([Parameter('legs', value='[{inflate_to_m3: 1.0e-3}]')])
        assert not result.successful and 'legs[0]' in result.reason, result.reason
        result, = pump.set_parameters([Parameter('cycles', value=0)])
        assert not result.successful and 'cycles' in result.reason
        answer = call_trigger(rig, 'syringe_pump/load')
        assert not answer.success and answer.message.startswith('nothing to load')

        for parameter in (Parameter('flow_rate_m3_per_s', value=2e-6),
                          Parameter('legs', value='[{inflate_to_m3: 2.0e-6}, '
                                                  '{deflate_to_m3: 0.0}]')):
            result, = pump.set_parameters([parameter])
            assert result.successful, result.reason
        assert pump.core.profile is scene_programme       # set, not taken yet
        answer = call_trigger(rig, 'syringe_pump/load')
        assert answer.success and answer.message.startswith('idle with the new programme')
        assert pump.core.profile.flow_rate == 2e-6 and pump.core.duration_s == pytest.approx(2.0)

        assert call_trigger(rig, 'syringe_pump/start').success
        # Set while running: accepted, kept for later; loading it now is refused, saying why.
        assert pump.set_parameters([Parameter('cycles', value=2)])[0].successful
        answer = call_trigger(rig, 'syringe_pump/load')
        assert not answer.success and 'cannot load a programme while running' in answer.message
        wait_for(lambda: rig.states()[-1] == 'finished', 'the first programme to end')
        peak = max(m.position[0] for m in rig.messages('pump/command'))
        # The new programme's 2 mL, not the scene's 65 mL (a loaded machine's pump may skip
        # the ticks at the top).
        assert 0.0 < peak <= 2.0e-6 * (1.0 + 1e-12)
        assert pump.core.profile.cycles == 1
        # Finished: ~/reset takes what was set (as ~/load would), at the start volume.
        answer = call_trigger(rig, 'syringe_pump/reset')
        assert answer.success and 'new programme' in answer.message
        assert pump.core.profile.cycles == 2 and pump.core.duration_s == pytest.approx(4.0)
        assert json.loads(rig.messages('pump/status')[-1].data)['state'] == 'idle'
        assert not call_trigger(rig, 'syringe_pump/load').success   # nothing new since
