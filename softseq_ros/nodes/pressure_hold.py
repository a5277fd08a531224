"""
Example controller node: holds the actuator's gauge pressure with a PI loop on the pump.

It reads ``actuator/volumes`` (effort: gauge pressure [Pa]) and publishes a flow setpoint
[m^3/s] on ``pump/setpoint`` for each new state (softseq_ros.rig.controller has the law and its
tuning). At start it hands the pump to itself through the pump's ``~/setpoint_mode`` service
(``pump_node``, in this node's namespace) and publishes nothing until the pump has agreed;
``take_over`` false leaves that to the user. The pump keeps its relief valve, end stop and
feedback rules: a target above ``max_pressure_pa`` ends with the pump stopped at the relief.
A copy of this node is where a controller of one's own starts (docs/controllers.md).
"""

from typing import Any

from rclpy.node import Parameter
from std_srvs.srv import SetBool

from softseq_ros.nodes.core_node import CoreNode
from softseq_ros.nodes.diagnostics import Health
from softseq_ros.nodes.runner import run_node
from softseq_ros.rig.controller import (
    DEFAULT_GAIN_M3_PER_S_PER_PA,
    DEFAULT_INTEGRAL_TIME_S,
    DEFAULT_MAX_FLOW_M3_PER_S,
    DEFAULT_TARGET_GAUGE_PA,
    PressureHold,
)
from softseq_ros.wire import contract

# How often it looks whether the pump's service is there, until the pump has agreed [s].
TAKE_OVER_POLL_S = 0.2


class PressureHoldNode(CoreNode):
    """A PI pressure hold on the pump's setpoints."""

    NODE_NAME = 'pressure_hold'
    ROLE = contract.CONTROLLER
    DIAGNOSTIC_TASK = 'pressure hold'

    def __init__(self, **kwargs: Any) -> None:
        """Declare the parameters, build the controller and ask the pump for setpoint mode."""
        super().__init__(self.NODE_NAME, **kwargs)
        target = self.declare_number(
            'target_gauge_pa', DEFAULT_TARGET_GAUGE_PA, 'Gauge pressure to hold [Pa].',
            minimum=-contract.DEFAULT_AMBIENT_PRESSURE_PA, maximum=1.0e7)
        gain = self.declare_number(
            'gain_m3_per_s_per_pa', DEFAULT_GAIN_M3_PER_S_PER_PA,
            'Proportional gain: flow per pressure error [m^3/s per Pa].', minimum=0.0,
            open_minimum=True, maximum=1.0)
        integral_time = self.declare_number(
            'integral_time_s', DEFAULT_INTEGRAL_TIME_S, 'Integral time T_i [s].', minimum=0.0,
            open_minimum=True, maximum=1.0e6)
        max_flow = self.declare_number(
            'max_flow_m3_per_s', DEFAULT_MAX_FLOW_M3_PER_S,
            'Largest flow it asks for [m^3/s] (the pump refuses more than its own '
            'max_flow_m3_per_s).', minimum=0.0, open_minimum=True, maximum=1.0e-3)
        self.take_over = self.declare_flag(
            'take_over', True, "Call the pump's ~/setpoint_mode at start and publish only once "
            'it agreed (false: publish at once; the pump must be put in setpoint mode by hand).',
            read_only=True)
        pump_node = self.declare_text(
            'pump_node', contract.NODE_NAMES[contract.PUMP],
            "The pump node whose ~/setpoint_mode is called (relative: in this node's "
            'namespace).', read_only=True)
        self.core = PressureHold(target, gain_m3_per_s_per_pa=gain,
                                 integral_time_s=integral_time, max_flow_m3_per_s=max_flow,
                                 active=not self.take_over)
        self.connect(frozenset())
        self._mode_client = None
        self._asked = False
        if self.take_over:
            self._mode_client = self.create_client(SetBool, f'{pump_node}/setpoint_mode')
            self._take_over_timer = self.create_timer(TAKE_OVER_POLL_S, self._ask_the_pump)
        self.configured = True
        self.get_logger().info(
            f'ready: holding {target:.6g} Pa gauge (gain {gain:.3g} m^3/s/Pa, integral time '
            f'{integral_time:.3g} s, at most {max_flow:.3g} m^3/s)'
            + (f', asking {self._mode_client.srv_name} for setpoint mode'
               if self._mode_client is not None else ''))

    def _ask_the_pump(self) -> None:
        if self._asked or not self._mode_client.service_is_ready():
            return
        self._asked = True
        future = self._mode_client.call_async(SetBool.Request(data=True))
        future.add_done_callback(self._pump_answered)

    def _pump_answered(self, future: Any) -> None:
        reply = future.result()
        if reply is not None and reply.success:
            self.destroy_timer(self._take_over_timer)
            self.core.active = True
            self.get_logger().info(f'the pump follows: {reply.message}')
            return
        # Refused (stopped, say): asked again at the next poll, said once.
        self.log('warning', f'{self._mode_client.srv_name} refused: '
                            f'{reply.message if reply is not None else "no answer"}; asking '
                            'again')
        self._asked = False

    def health(self) -> Health:
        """The controller's target, last pressure and flow, for /diagnostics."""
        base = super().health()
        core = self.core
        values: dict[str, object] = {
            'active': core.active, 'target_gauge_pa': core.target_gauge_pa,
            'last_flow_m3_per_s': core.last_flow_m3_per_s,
            'integral_pa_s': core.integral_pa_s}
        if core.last_gauge_pa is not None:
            values['gauge_pressure_pa'] = core.last_gauge_pa
            values['error_pa'] = core.target_gauge_pa - core.last_gauge_pa
        values.update(base.values)
        return Health(base.level, base.message, values)

    def _parameters_changed(self, parameters: list[Parameter]) -> None:
        names = {'target_gauge_pa': 'target_gauge_pa', 'gain_m3_per_s_per_pa': 'gain',
                 'integral_time_s': 'integral_time_s', 'max_flow_m3_per_s': 'max_flow_m3_per_s'}
        for parameter in parameters:
            if parameter.name in names:
                setattr(self.core, names[parameter.name], float(parameter.value))


def main(args: list[str] | None = None) -> None:
    """Run the pressure hold node."""
    run_node(PressureHoldNode, args)


if __name__ == '__main__':
    main()
