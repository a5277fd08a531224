"""
Syringe pump node: the pump core (softseq_ros.rig.pump) on a ROS timer, with services.

Publishes ``pump/command`` (sensor_msgs/JointState, joint ``syringe``: injected volume [m^3]
and signed flow [m^3/s]) at ``rate_hz`` and ``pump/status`` (JSON with state, reason and
stamp; transient_local, depth 1: a late joiner gets the current state only). Listens to
``actuator/volumes`` for the actuator's gauge pressure: its relief valve (``max_pressure_pa``)
and its feedback, which is only the actuator's answer to this pump's own commands, checked
against the scene's segments (it holds on an answer that cannot be trusted, and after
``feedback_timeout_s`` without a good one; ``open_loop`` for a pump with no actuator; the
rules are softseq_ros.rig.pump's). The programme (legs at ``flow_rate_m3_per_s``,
repeated ``cycles`` times) comes from the scene unless the parameters give it.

Services (std_srvs/Trigger): ``~/start`` (idle or held -> running), ``~/hold`` (running ->
held), ``~/stop`` (-> stopped), ``~/reset`` (-> idle at the programme's start volume).
"""

from typing import Any

from rclpy.node import Parameter
from std_srvs.srv import Trigger

from softseq_ros.nodes.core_node import CoreNode
from softseq_ros.nodes.diagnostics import ERROR_LEVEL, OK_LEVEL, WARN_LEVEL, Health, worst
from softseq_ros.nodes.parameters import NodeConfigError
from softseq_ros.nodes.runner import run_node
from softseq_ros.rig import contract
from softseq_ros.rig.build import pump_core
from softseq_ros.rig.model import actuator_model
from softseq_ros.rig.pump import (
    DEFAULT_FEEDBACK_TIMEOUT_S,
    DEFAULT_MAX_PRESSURE_PA,
    REACTIONS,
    STOPPED,
    Reply,
)
from softseq_ros.rig.values import WARNING
from softseq_ros.rig.wire import NS_PER_S
from softseq_ros.scene.limits import LIMITS
from softseq_ros.scene.loader import legs_from_text
from softseq_ros.scene.programme import MAX_RUN_S, Leg, longest_part
from softseq_ros.scene.validation import SceneError


def parse_legs(text: str) -> tuple[Leg, ...]:
    """
    Legs from a YAML list in the scene's syntax (softseq_ros.scene.loader.legs_from_text).

    Example: ``[{inflate_to_m3: 5.0e-6}, {hold_s: 2}, {deflate_to_m3: 0.0}]``. Raises
    NodeConfigError naming the leg and key that is wrong.
    """
    try:
        return legs_from_text(text)
    except SceneError as err:
        raise NodeConfigError(str(err)) from None


def _legs_reason(text: str) -> str | None:
    if not text:
        return None
    try:
        parse_legs(text)
    except NodeConfigError as err:
        return str(err)
    return None


class SyringePumpNode(CoreNode):
    """The syringe pump: programme, run/hold/stop state machine and safety limits."""

    NODE_NAME = contract.NODE_NAMES[contract.PUMP]
    # Its std_srvs/Trigger services (~/name), each the core's method of that name; --help
    # lists them from here.
    SERVICES: dict[str, str] = {
        'start': 'idle or held -> running', 'hold': 'running -> held',
        'stop': '-> stopped', 'reset': "-> idle at the programme's start volume"}

    def __init__(self, **kwargs: Any) -> None:
        """Declare parameters (defaults from the scene), build the core, start the timer."""
        super().__init__(self.NODE_NAME, **kwargs)
        self.last_gauge_pa: float | None = None   # the highest of the last feedback's
        scene = self.declare_scene()
        default = scene.pump.profile
        self.rate_hz = self.declare_number(
            'rate_hz', scene.pump.rate_hz, 'Command publishing rate [Hz].',
            **LIMITS['pump.rate_hz'].bounds())
        flow = self.declare_number(
            'flow_rate_m3_per_s', default.flow_rate, 'Pump flow rate [m^3/s].',
            read_only=True, **LIMITS['pump.flow_rate_m3_per_s'].bounds())
        legs_text = self.declare_text(
            'legs', '', 'Programme legs as a YAML list in the scene syntax, e.g. '
            '[{inflate_to_m3: 5.0e-6}, {hold_s: 2}, {deflate_to_m3: 0.0}]; empty: the scene.',
            read_only=True, check=_legs_reason)
        cycles = self.declare_integer('cycles', default.cycles, 'Programme repetitions.',
                                      read_only=True, **LIMITS['pump.cycles'].bounds())
        start = self.declare_number(
            'start_injected_m3', default.start_injected, 'Injected volume at run time 0 [m^3].',
            minimum=0.0, maximum=scene.capacity, read_only=True)
        autostart = self.declare_flag(
            'autostart', True, 'Start running at the first tick (else wait for ~/start).',
            read_only=True)
        max_pressure = self.declare_number(
            'max_pressure_pa', DEFAULT_MAX_PRESSURE_PA,
            'Stop when the actuator gauge pressure exceeds this [Pa].', minimum=0.0,
            open_minimum=True)
        feedback_timeout = self.declare_number(
            'feedback_timeout_s', DEFAULT_FEEDBACK_TIMEOUT_S,
            'Hold when no pressure came from the actuator for this long while running '
            '[s, wall clock].', minimum=0.0, open_minimum=True, maximum=3600.0)
        open_loop = self.declare_flag(
            'open_loop', False, 'Run without pressure feedback (no actuator behind the pump): '
            'no relief valve, no feedback timeout.', read_only=True)
        # The segments' equilibrium gives the pump its limits: the programme must stay in its
        # domain, and the end stop defaults to where the inflation ends.
        self.core, _ = pump_core(
            scene, actuator_model(scene), flow_rate_m3_per_s=flow, cycles=cycles,
            start_injected_m3=start, legs=parse_legs(legs_text) if legs_text else None,
            autostart=autostart, max_pressure_pa=max_pressure,
            feedback_timeout_s=feedback_timeout, open_loop=open_loop)
        self.core.max_injected_m3 = self.declare_number(
            'max_injected_m3', self.core.max_injected_m3,
            'Stop when the commanded injected volume would exceed this [m^3] '
            "(default: where the segments' inflation ends).", minimum=0.0,
            open_minimum=True)
        # Warnings name the feedback topic as resolved here.
        self.connect(scene.outputs)
        volumes = self.subscription(contract.VOLUMES)
        if volumes is not None:
            self.core.feedback_topic = volumes.topic_name
        for name in self.SERVICES:
            self.create_service(Trigger, f'~/{name}', self._service(getattr(self.core, name)))
        self._use_sim_time = bool(self.get_parameter('use_sim_time').value)
        self._timer = self.create_timer(1.0 / self.rate_hz, self.tick)
        self.send(self.core.begin(self.now_ns()))
        if self.core.duration_s > MAX_RUN_S:
            # A rig may run for days, so this is said, not refused (softseq run refuses it).
            self.get_logger().warning(
                f'the programme runs {self.core.duration_s:.6g} s of rig time, more than '
                f'{MAX_RUN_S:g} s ({longest_part(self.core.profile, "pump.")})')
        self.configured = True

    DIAGNOSTIC_TASK = 'syringe pump'

    def health(self) -> Health:
        """
        The pump's state, its relief valve and its feedback, for /diagnostics.

        A stop the pump made by itself (relief valve, end stop) is an ERROR, a hold it made by
        itself (no or untrusted feedback) a WARN; a state asked for (idle, running, held or
        stopped by a service, finished) is OK. The node's own warnings count as in every node.
        """
        base = super().health()
        core = self.core
        reaction = REACTIONS[core.cause]
        level = OK_LEVEL
        if reaction.level == WARNING:
            level = ERROR_LEVEL if reaction.state == STOPPED else WARN_LEVEL
        values: dict[str, object] = {
            'state': core.state, 'reason': core.reason, 'injected_m3': core.volume_m3,
            'max_pressure_pa (gauge)': core.max_pressure_pa,
            'max_injected_m3': core.max_injected_m3,
            'open_loop': core.open_loop}
        if self.last_gauge_pa is not None:
            values['gauge_pressure_pa'] = self.last_gauge_pa
            values['relief_margin_pa'] = core.max_pressure_pa - self.last_gauge_pa
        values.update(base.values)
        message = core.status if level != OK_LEVEL or base.level == OK_LEVEL else base.message
        return Health(worst(level, base.level), message, values)

    @property
    def state(self) -> str:
        """The pump's state: idle, running, held, finished or stopped."""
        return self.core.state

    def _service(self, request: Any) -> Any:
        def serve(_request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
            reply: Reply = request(self.now_ns())
            self.send(reply.outputs)
            response.success, response.message = reply.success, reply.message
            return response
        return serve

    def start(self) -> tuple[bool, str]:
        """Start (or resume) the programme now, as ~/start does."""
        reply = self.core.start(self.now_ns())
        self.send(reply.outputs)
        return reply.success, reply.message

    def tick(self) -> None:
        """The timer: command the volume of now (and any state change)."""
        now = self.now_ns()
        if now == 0 and self._use_sim_time:
            return  # no /clock received yet: the time is unknown
        self.send(self.core.tick(now))

    def _receive(self, topic: contract.Topic, decode: Any, msg: Any) -> None:
        if topic is not contract.VOLUMES:
            super()._receive(topic, decode, msg)
            return
        # Field by field, not through the decoded value: that keeps one gauge pressure, and
        # a message whose pressures (effort) do not match its joints must be seen as such.
        stamp = msg.header.stamp
        if msg.effort:
            self.last_gauge_pa = max(msg.effort)
        self.send(self.core.feedback(self.now_ns(), stamp.sec * NS_PER_S + stamp.nanosec,
                                     tuple(msg.name), list(msg.position), list(msg.effort)))

    def _parameters_changed(self, parameters: list[Parameter]) -> None:
        for parameter in parameters:
            if parameter.name == 'rate_hz':
                self.rate_hz = float(parameter.value)
                self._timer.timer_period_ns = int(round(1e9 / self.rate_hz))
            elif parameter.name in ('max_pressure_pa', 'max_injected_m3', 'feedback_timeout_s'):
                setattr(self.core, parameter.name, float(parameter.value))


def main(args: list[str] | None = None) -> None:
    """Run the syringe pump node."""
    run_node(SyringePumpNode, args)


if __name__ == '__main__':
    main()
