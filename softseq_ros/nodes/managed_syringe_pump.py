"""
The syringe pump as a managed (lifecycle) node, as the ROS 2 docs advise for hardware drivers.

The same pump as ``syringe_pump`` (parameters, topics, services, safety), driven through the
lifecycle state machine of rclpy.lifecycle, so a launch system or an operator brings it up
step by step and can take it down without killing the process:

- unconfigured (after start): its parameters are declared and can be set; nothing else.
- configure: the core is built from the parameters (the programme checked against the
  segments' equilibrium: a programme that cannot run fails the transition, saying why), its
  topics and services are created; it commands nothing yet (its services say it is inactive).
- activate: the command timer starts (``pump/command`` at ``rate_hz``) and the services act;
  with ``autostart`` the programme starts at the first tick.
- deactivate: a running pump holds (``held``, reason ``requested``) and the timer stops;
  activated again it stays held until ``~/start``.
- cleanup: topics, services and core are gone (unconfigured again; a new configure takes
  the parameters as they are then). The syringe's plunger stays where it was, and so does
  the fluid it pushed into the actuator: configured again, the pump starts from the volume
  it held (its ``start_injected_m3`` is set to it, and the programme runs from there), never
  from 0 with the fluid still in the segments.
- shutdown: a running or held pump is stopped first, then everything is released.

Transitions are requested with ``ros2 lifecycle set /syringe_pump configure`` (or the
``~/change_state`` service, lifecycle_msgs/srv/ChangeState) and read with
``ros2 lifecycle get`` (``~/get_state``). The ``rig`` executable and ``softseq run`` keep the
plain pump, which configures and activates itself at start.
"""

from typing import Any, Callable

from lifecycle_msgs.srv import ChangeState
from rclpy.lifecycle import LifecycleNodeMixin, LifecycleState, TransitionCallbackReturn
from rclpy.parameter import Parameter

from softseq_ros.nodes.parameters import NodeConfigError
from softseq_ros.nodes.runner import run_node
from softseq_ros.nodes.syringe_pump import SyringePumpNode
from softseq_ros.rig.build import SettingError
from softseq_ros.rig.pump import HELD, RUNNING
from softseq_ros.scene.validation import SceneError


class ManagedSyringePumpNode(LifecycleNodeMixin, SyringePumpNode):
    """The syringe pump, configured and activated through its lifecycle."""

    HELP_NOTES = SyringePumpNode.HELP_NOTES + (
        'A managed (lifecycle) node: it starts unconfigured; ros2 lifecycle set /syringe_pump '
        'configure, then activate, start it (softseq ros lifecycle set /syringe_pump configure '
        'without the ros2 command; ~/change_state and ~/get_state, lifecycle_msgs). '
        'Configure builds the pump from its parameters, activate starts its commands, '
        'deactivate holds it, cleanup releases it, shutdown stops it first.',)

    def __init__(self, **kwargs: Any) -> None:
        """Declare the parameters only: the node starts unconfigured."""
        SyringePumpNode.__init__(self, **kwargs)
        LifecycleNodeMixin.__init__(self, enable_communication_interface=True)
        # Where the plunger stood when the pump was last released (None: never configured).
        self._plunger_m3: float | None = None
        for service in self.services:
            if service.srv_type is ChangeState:
                service.callback = self._refusing_transitions(service.callback)

    def _refusing_transitions(self, change_state: Callable) -> Callable:
        """
        ``~/change_state`` that answers success False to a transition its state has not.

        rclpy's own answer raises out of the service (configure twice, cleanup while active,
        an unknown id, anything once finalized) and ends the process; the state machine refuses
        such a transition before it moves, so the node stays where it was and says so.
        """
        def guarded(request: ChangeState.Request,
                    response: ChangeState.Response) -> ChangeState.Response:
            try:
                return change_state(request, response)
            except Exception as err:  # noqa: BLE001 - rclpy's RCLError is not public
                self.get_logger().warning(
                    f'~/change_state: transition {request.transition.id} '
                    f'{request.transition.label!r} refused: {" ".join(str(err).split())}')
                response.success = False
                return response
        return guarded

    # SyringePumpNode.__init__ declares, configures and activates; here only the first step
    # runs at construction, the others are the lifecycle's transitions.
    def _configure_core(self) -> None:
        pass

    def _activate_timer(self) -> None:
        pass

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Build the core, its topics and services from the parameters as they are now."""
        try:
            self._start_at_the_plunger()
            SyringePumpNode._configure_core(self)
        except (SettingError, NodeConfigError, SceneError) as err:
            self.get_logger().error(f'configure failed: {" ".join(str(err).split())}')
            self._release()
            return TransitionCallbackReturn.FAILURE
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Start the command timer."""
        SyringePumpNode._activate_timer(self)
        return TransitionCallbackReturn.SUCCESS

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Hold a running pump and stop the command timer."""
        if self.core.state == RUNNING:
            self.send(self.core.hold(self.now_ns()).outputs)
        self._stop_timer()
        return TransitionCallbackReturn.SUCCESS

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Release the core, its topics and services."""
        self._release()
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Stop a pump in the middle of a programme, then release everything."""
        if self.core is not None and self.core.state in (RUNNING, HELD):
            self.send(self.core.stop(self.now_ns()).outputs)
        self._release()
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        """After a failed transition: stop and release, back to unconfigured."""
        return self.on_shutdown(state)

    def _stop_timer(self) -> None:
        if self._timer is not None:
            self.destroy_timer(self._timer)
            self._timer = None

    def _start_at_the_plunger(self) -> None:
        """A pump configured again starts where its plunger stands (else NodeConfigError)."""
        held = self._plunger_m3
        if self._scene.regulator is not None:
            # A regulator has no plunger: its programme of pressures starts from 0 Pa.
            if held:
                self.get_logger().warning(
                    f'configured again: the regulator held {held:.6g} Pa gauge before the '
                    'cleanup, and its programme starts from 0 Pa (the segments deflate to it)')
            return
        if held is None or held == self.get_parameter('start_injected_m3').value:
            return
        result, = self.set_parameters([Parameter('start_injected_m3', value=held)])
        if not result.successful:
            raise NodeConfigError(f'the syringe still holds {held * 1e6:.6g} mL pushed before '
                                  f'the cleanup, and the programme cannot start there: '
                                  f'{result.reason}')
        self.get_logger().info(f'configured again with {held * 1e6:.6g} mL in the actuator: '
                               'the programme starts there (start_injected_m3)')

    def _release(self) -> None:
        if self.core is not None:
            self._plunger_m3 = float(self.core.volume_m3)
        self._stop_timer()
        for service in self._pump_services:
            self.destroy_service(service)
        self._pump_services = []
        self.disconnect()
        self.core = None
        self.configured = False


def main(args: list[str] | None = None) -> None:
    """Run the managed syringe pump node (it starts unconfigured)."""
    run_node(ManagedSyringePumpNode, args)


if __name__ == '__main__':
    main()
