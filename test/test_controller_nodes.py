"""
The example controller node on the emulated rig: real rclpy nodes over DDS, on sim time.

Built on softseq_ros.testing as a user's own controller test would be (the README shows it).
"""

import json

import pytest
from rclpy.parameter import Parameter

from softseq_ros.nodes.actuator import ActuatorNode
from softseq_ros.nodes.pressure_hold import PressureHoldNode
from softseq_ros.nodes.sim_clock import SimClockNode
from softseq_ros.nodes.syringe_pump import SyringePumpNode
from softseq_ros.testing import Collector, spinning, stamp_ns, wait_for

pytestmark = pytest.mark.ros

TARGET_PA = 5.0e3
HOLD_BY_S = 20.0


def test_the_pressure_hold_node_holds_5_kpa_within_1_percent_in_20_s_of_rig_time(context):
    sim = [Parameter('use_sim_time', value=True)]
    paper = [Parameter('scene', value='paper')]
    clock = SimClockNode(context=context, parameter_overrides=[Parameter('speedup', value=2.0)])
    pump = SyringePumpNode(context=context, parameter_overrides=sim + paper + [
        Parameter('autostart', value=False)])
    actuator = ActuatorNode(context=context, parameter_overrides=sim + paper + [
        Parameter('resume_timeout_s', value=0.0), Parameter('state_file', value='')])
    controller = PressureHoldNode(context=context, parameter_overrides=sim + [
        Parameter('target_gauge_pa', value=TARGET_PA)])
    collector = Collector(['actuator/volumes', 'pump/setpoint', 'pump/status'], context)
    volumes = collector.messages('actuator/volumes')
    with spinning(context, clock, pump, actuator, controller, collector):
        wait_for(lambda: controller.core.active, 'the pump to take setpoints')
        wait_for(lambda: volumes and stamp_ns(volumes[-1].header) >= (HOLD_BY_S + 2.0) * 1e9,
                 f'{HOLD_BY_S + 2:g} s of rig time', timeout=120.0)
        health = pump.health()
    late = [m.effort[0] for m in volumes if stamp_ns(m.header) >= HOLD_BY_S * 1e9]
    assert late and max(abs(p - TARGET_PA) for p in late) < 0.01 * TARGET_PA
    # The setpoints went over DDS, the pump took every one and says so on /diagnostics.
    assert len(collector.messages('pump/setpoint')) > 100
    assert health.values['mode'] == 'setpoint'
    assert health.values['setpoints_taken'] >= 100 and health.values['setpoints_refused'] == 0
    states = [json.loads(m.data)['state'] for m in collector.messages('pump/status')]
    assert states[-1] == 'running'


def test_the_actuator_says_its_rest_state_once_latched_for_a_controller_that_starts_later(
        context):
    actuator = ActuatorNode(context=context, parameter_overrides=[
        Parameter('scene', value='paper'), Parameter('resume_timeout_s', value=0.0),
        Parameter('state_file', value='')])
    with spinning(context, actuator):
        wait_for(lambda: not actuator.resuming, 'the actuator to start')
        # No pump, nothing commanded: a reader that joins now still gets where it rests.
        late = Collector(['actuator/volumes'], context)
        with spinning(context, late):
            got = late.wait_for_count('actuator/volumes', 1)
    rest = actuator.core.model.state()
    assert list(got[0].position) == pytest.approx(rest.volumes, rel=1e-12)
    assert list(got[0].effort) == [0.0, 0.0]
