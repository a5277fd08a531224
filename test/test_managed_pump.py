"""The managed (lifecycle) syringe pump, driven through ~/change_state and ~/get_state."""

import json

from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
import pytest
from rclpy.node import Node
from rclpy.parameter import Parameter

from softseq_ros.nodes.managed_syringe_pump import ManagedSyringePumpNode
from softseq_ros.testing import Collector, call_trigger, spinning, wait_for

pytestmark = pytest.mark.ros


class Operator:
    """What ``ros2 lifecycle set/get`` does: calls to the node's lifecycle services."""

    def __init__(self, node: Node, target: str) -> None:
        self.node = node
        self.change = node.create_client(ChangeState, f'{target}/change_state')
        self.get = node.create_client(GetState, f'{target}/get_state')

    def _call(self, client, request):
        assert client.wait_for_service(timeout_sec=15.0)
        future = client.call_async(request)
        wait_for(future.done, f'the answer of {client.srv_name}')
        return future.result()

    def state(self) -> str:
        return self._call(self.get, GetState.Request()).current_state.label

    def set(self, transition: int) -> bool:
        request = ChangeState.Request()
        request.transition.id = transition
        return self._call(self.change, request).success


def test_configure_activate_deactivate_cleanup_shutdown(context):
    pump = ManagedSyringePumpNode(context=context, parameter_overrides=[
        Parameter('scene', value='fig1_none'), Parameter('autostart', value=False),
        Parameter('open_loop', value=True), Parameter('flow_rate_m3_per_s', value=2e-6),
        Parameter('legs', value='[{inflate_to_m3: 2.0e-6}, {deflate_to_m3: 0.0}]')])
    rig = Collector(['pump/command', 'pump/status'], context)
    operator = Operator(rig, '/syringe_pump')
    with spinning(context, pump, rig):
        # Unconfigured: parameters only, no pump topics or services.
        assert operator.state() == 'unconfigured'
        assert pump.core is None and not rig.matched('pump/command')
        assert pump.has_parameter('max_pressure_pa')
        # A programme the segments cannot run is refused at once, as on the plain pump.
        refused, = pump.set_parameters([Parameter('legs', value='[{inflate_to_m3: 1.0e-3}]')])
        assert not refused.successful and 'legs[0]' in refused.reason

        assert operator.set(Transition.TRANSITION_CONFIGURE)
        assert operator.state() == 'inactive'
        rig.wait_for_publishers()
        answer = call_trigger(rig, 'syringe_pump/start')
        assert not answer.success and 'inactive' in answer.message
        assert rig.messages('pump/command') == []    # configured, not commanding

        assert operator.set(Transition.TRANSITION_ACTIVATE)
        assert operator.state() == 'active'
        assert call_trigger(rig, 'syringe_pump/start').success
        wait_for(lambda: rig.states()[-1:] == ['running'], 'running')
        rig.wait_for_count('pump/command', 5)

        # Deactivated: the pump holds and commands nothing more.
        assert operator.set(Transition.TRANSITION_DEACTIVATE)
        assert operator.state() == 'inactive'
        wait_for(lambda: rig.states()[-1:] == ['held'], 'the hold')
        assert pump.core.state == 'held'
        held_at = len(rig.messages('pump/command'))
        # Active again: still held until ~/start, then the programme goes on to its end.
        assert operator.set(Transition.TRANSITION_ACTIVATE)
        assert pump.core.state == 'held'
        assert call_trigger(rig, 'syringe_pump/start').success
        wait_for(lambda: rig.states()[-1:] == ['finished'], 'the end of the programme')
        assert len(rig.messages('pump/command')) > held_at
        assert max(m.position[0] for m in rig.messages('pump/command')) <= 2.0e-6 * (1 + 1e-12)

        # Cleanup: the pump's topics go; configured again, it takes the parameters of then.
        assert operator.set(Transition.TRANSITION_DEACTIVATE)
        assert operator.set(Transition.TRANSITION_CLEANUP)
        assert operator.state() == 'unconfigured'
        wait_for(lambda: not rig.matched('pump/command'), 'the command publisher to go')
        assert pump.set_parameters([Parameter('cycles', value=3)])[0].successful
        assert operator.set(Transition.TRANSITION_CONFIGURE)
        assert pump.core.profile.cycles == 3
        assert operator.set(Transition.TRANSITION_ACTIVATE)
        assert call_trigger(rig, 'syringe_pump/start').success
        wait_for(lambda: rig.states()[-1:] == ['running'], 'running again')

        # Shutdown from active: the pump stops first, then it is finalized.
        assert operator.set(Transition.TRANSITION_ACTIVE_SHUTDOWN)
        assert operator.state() == 'finalized'
        wait_for(lambda: rig.states()[-1:] == ['stopped'], 'the stop')
        last = json.loads(rig.messages('pump/status')[-1].data)
        assert last['reason'] == 'requested'
        assert pump.core is None


# The transitions each primary state has (the ROS 2 managed-node design); every other id is
# one the state machine must refuse.
ALLOWED = {
    'unconfigured': {Transition.TRANSITION_CONFIGURE, Transition.TRANSITION_UNCONFIGURED_SHUTDOWN},
    'inactive': {Transition.TRANSITION_CLEANUP, Transition.TRANSITION_ACTIVATE,
                 Transition.TRANSITION_INACTIVE_SHUTDOWN},
    'active': {Transition.TRANSITION_DEACTIVATE, Transition.TRANSITION_ACTIVE_SHUTDOWN},
    'finalized': set(),
}


def test_a_transition_the_state_has_not_is_refused_and_the_node_lives_on(context):
    pump = ManagedSyringePumpNode(context=context, parameter_overrides=[
        Parameter('scene', value='fig1_none'), Parameter('autostart', value=False),
        Parameter('open_loop', value=True)])
    rig = Collector(['pump/status'], context)
    operator = Operator(rig, '/syringe_pump')
    path = [('unconfigured', Transition.TRANSITION_CONFIGURE),
            ('inactive', Transition.TRANSITION_ACTIVATE),
            ('active', Transition.TRANSITION_ACTIVE_SHUTDOWN), ('finalized', None)]
    with spinning(context, pump, rig):
        for state, onwards in path:
            assert operator.state() == state
            for transition in sorted((set(range(0, 12)) | {99, 255}) - ALLOWED[state]):
                assert not operator.set(transition), (state, transition)
                assert operator.state() == state, (state, transition)
            if onwards is not None:
                assert operator.set(onwards)


def test_a_pump_configured_again_starts_where_its_plunger_stands(context):
    # Cleanup does not empty the actuator: the fluid pushed stays, and so does the plunger.
    # In a namespace of its own: a pump another test left in this domain, still publishing
    # on /pump/command, must not answer for this one.
    pump = ManagedSyringePumpNode(context=context, cli_args=[
        '--ros-args', '-r', '__ns:=/plunger'], parameter_overrides=[
        Parameter('scene', value='fig1_none'), Parameter('autostart', value=True),
        Parameter('open_loop', value=True), Parameter('flow_rate_m3_per_s', value=2e-6),
        Parameter('legs', value='[{inflate_to_m3: 4.0e-6}, {deflate_to_m3: 0.0}]')])
    rig = Collector(['pump/command', 'pump/status'], context, namespace='/plunger')
    operator = Operator(rig, '/plunger/syringe_pump')
    with spinning(context, pump, rig):
        assert operator.set(Transition.TRANSITION_CONFIGURE)
        assert operator.set(Transition.TRANSITION_ACTIVATE)
        wait_for(lambda: any(m.position[0] > 0.5e-6 for m in rig.messages('pump/command')),
                 'half a millilitre pushed')
        assert operator.set(Transition.TRANSITION_DEACTIVATE)
        held = pump.core.volume_m3
        assert 0.5e-6 < held < 4.0e-6
        assert operator.set(Transition.TRANSITION_CLEANUP)
        assert operator.set(Transition.TRANSITION_CONFIGURE)
        assert pump.core.volume_m3 == held
        assert pump.get_parameter('start_injected_m3').value == held
        before = len(rig.messages('pump/command'))
        assert operator.set(Transition.TRANSITION_ACTIVATE)
        assert call_trigger(rig, '/plunger/syringe_pump/start').success
        rig.wait_for_count('pump/command', before + 5)
        # The commands go on from the volume held, never back to 0 with fluid in the actuator.
        after = [m.position[0] for m in rig.messages('pump/command')[before:]]
        assert min(after) >= held - 1e-15
