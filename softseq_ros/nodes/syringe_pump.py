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

A controller drives the pump instead of the programme (docs/controllers.md): ``~/setpoint_mode``
(std_srvs/SetBool, true: setpoints, false: back to the programme, which then starts where the
syringe is) and ``pump/setpoint`` (sensor_msgs/JointState, joint ``syringe``: position = target
injected volume [m^3], reached at ``flow_rate_m3_per_s``, or velocity = flow [m^3/s]). The relief
valve, the end stop and the feedback rules act on setpoints as on the programme; a setpoint out
of range is refused with a warning and counted on /diagnostics.
"""

from typing import Any

from rclpy.node import Parameter
from std_srvs.srv import SetBool, Trigger

from softseq_ros.nodes.core_node import CoreNode
from softseq_ros.nodes.diagnostics import ERROR_LEVEL, OK_LEVEL, WARN_LEVEL, Health, worst
from softseq_ros.nodes.parameters import NodeConfigError
from softseq_ros.nodes.runner import run_node
from softseq_ros.rig.build import (
    SettingError,
    check_programme,
    end_stop,
    pump_core,
    pump_profile,
)
from softseq_ros.rig.model import RELIEF_MARGIN, actuator_model, default_max_pressure_pa
from softseq_ros.rig.pump import (
    DEFAULT_FEEDBACK_TIMEOUT_S,
    DEFAULT_MAX_FLOW_M3_PER_S,
    IDLE,
    REACTIONS,
    STOPPED,
    Reply,
)
from softseq_ros.scene.limits import LIMITS
from softseq_ros.scene.loader import legs_from_text
from softseq_ros.scene.programme import MAX_RUN_S, Leg, PumpProfile, longest_part
from softseq_ros.scene.validation import SceneError
from softseq_ros.wire import contract
from softseq_ros.wire.contract import NS_PER_S
from softseq_ros.wire.values import WARNING

_LOADED = 'set at run time, it is taken by ~/load or ~/reset when the pump is not running'


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
        'stop': '-> stopped', 'reset': "-> idle at the programme's start volume (a programme "
        'set since the last load is taken)',
        'load': 'idle, finished or stopped -> idle with the programme set in the parameters '
        'legs, cycles, flow_rate_m3_per_s, start_injected_m3 (refused while running or held)'}
    PROGRAMME_PARAMETERS = ('legs', 'cycles', 'flow_rate_m3_per_s', 'start_injected_m3')
    HELP_NOTES = (
        'legs is YAML text: on the command line it needs quotes of its own inside the '
        "shell's, or rcl reads it as a list and refuses it: "
        '-p "legs:=\'[{inflate_to_m3: 2.0e-5}, {deflate_to_m3: 0.0}]\'". In a parameters '
        'file it is a string: legs: "[{inflate_to_m3: 2.0e-5}, {deflate_to_m3: 0.0}]".',
        '~/setpoint_mode (std_srvs/srv/SetBool): data true hands the pump to a controller on '
        'pump/setpoint (running, holding its volume until a setpoint comes; refused while '
        'stopped); false returns to the programme, idle, starting where the syringe is. '
        'docs/controllers.md has the contract and an example.')

    def __init__(self, **kwargs: Any) -> None:
        """Declare parameters (defaults from the scene), build the core, start the timer."""
        super().__init__(self.NODE_NAME, **kwargs)
        self._declare_all()
        self._configure_core()
        self._activate_timer()

    def _declare_all(self) -> None:
        """Every parameter, with the scene's defaults; the core is built from their values."""
        self.last_gauge_pa: float | None = None   # the highest of the last feedback's
        self._timer: Any = None
        self._pump_services: list[Any] = []
        scene = self.declare_scene()
        if scene.regulator is not None:
            self._declare_regulator(scene)
            return
        default = scene.pump.profile
        self.rate_hz = self.declare_number(
            'rate_hz', scene.pump.rate_hz, 'Command publishing rate [Hz].',
            **LIMITS['pump.rate_hz'].bounds())
        # The programme's parameters can be set at run time: a new programme is checked at
        # once and taken by ~/load (or ~/reset) when the pump is not in the middle of one.
        self.declare_number(
            'flow_rate_m3_per_s', default.flow_rate, 'Pump flow rate [m^3/s]; ' + _LOADED,
            **LIMITS['pump.flow_rate_m3_per_s'].bounds())
        self.declare_text(
            'legs', '', 'Programme legs as a YAML list in the scene syntax, e.g. '
            '[{inflate_to_m3: 5.0e-6, flow_rate_m3_per_s: 1.0e-6}, {hold_s: 2}, '
            '{deflate_to_m3: 0.0}] (a leg without its own flow_rate_m3_per_s moves at the '
            "pump's); empty: the scene's; " + _LOADED, check=_legs_reason)
        self.declare_integer('cycles', default.cycles, 'Programme repetitions; ' + _LOADED,
                             **LIMITS['pump.cycles'].bounds())
        self.declare_number(
            'start_injected_m3', default.start_injected,
            'Injected volume at run time 0 [m^3]; ' + _LOADED, minimum=0.0,
            maximum=scene.capacity)
        self.declare_flag(
            'autostart', True, 'Start running at the first tick (else wait for ~/start).',
            read_only=True)
        self.declare_number(
            'max_pressure_pa', default_max_pressure_pa(scene),
            'Stop when the actuator gauge pressure exceeds this [Pa] (default: '
            f"{RELIEF_MARGIN:g} x the highest pressure on the scene's segment curves, plus "
            "the supply tube's drop at the programme's fastest flow).", minimum=0.0,
            open_minimum=True)
        self.declare_number(
            'feedback_timeout_s', DEFAULT_FEEDBACK_TIMEOUT_S,
            'Hold when no pressure came from the actuator for this long while running '
            '[s, wall clock].', minimum=0.0, open_minimum=True, maximum=3600.0)
        self.declare_number(
            'max_flow_m3_per_s', DEFAULT_MAX_FLOW_M3_PER_S,
            'The fastest flow a setpoint on pump/setpoint may ask for [m^3/s]; faster ones are '
            'refused.', minimum=0.0, open_minimum=True, maximum=DEFAULT_MAX_FLOW_M3_PER_S)
        self.declare_flag(
            'open_loop', False, 'Run without pressure feedback (no actuator behind the pump): '
            'no relief valve, no feedback timeout.', read_only=True)
        # The segments' equilibrium gives the pump its limits: the programme must stay in its
        # domain, and the end stop defaults to where the inflation ends.
        self._scene = scene
        self._model = actuator_model(scene)
        self._pending: PumpProfile | None = None   # a programme set, not loaded yet
        self.declare_number(
            'max_injected_m3', end_stop(self._model, self._programme({})),
            'Stop when the commanded injected volume would exceed this [m^3] '
            "(default: where the segments' inflation ends).", minimum=0.0,
            open_minimum=True)
        self.declarations_done = True

    def _declare_regulator(self, scene: Any) -> None:
        """
        The scene's supply is a pressure regulator: the pump node drives it.

        Its programme of target pressures is the scene's; the syringe's parameters (flow,
        legs, end stop) do not exist here.
        """
        regulator = scene.regulator
        self.rate_hz = self.declare_number(
            'rate_hz', regulator.rate_hz, 'Command publishing rate [Hz].',
            **LIMITS['pump.rate_hz'].bounds())
        self.declare_flag(
            'autostart', True, 'Start running at the first tick (else wait for ~/start).',
            read_only=True)
        self.declare_number(
            'max_pressure_pa', regulator.max_pressure_pa,
            "The regulator's relief: stop when the actuator gauge pressure exceeds this, and "
            'hold a target setpoint above it at it [Pa] (default: '
            'supply.regulator.max_pressure_pa of the scene).',
            minimum=regulator.programme.highest(), open_minimum=False)
        self.declare_number(
            'feedback_timeout_s', DEFAULT_FEEDBACK_TIMEOUT_S,
            'Hold when no pressure came from the actuator for this long while running '
            '[s, wall clock].', minimum=0.0, open_minimum=True, maximum=3600.0)
        self.declare_flag(
            'open_loop', False, 'Run without pressure feedback (no actuator behind the '
            'regulator): no relief, no feedback timeout.', read_only=True)
        self._scene = scene
        self._model = actuator_model(scene)
        self._pending = None
        self.declarations_done = True

    def _configure_core(self) -> None:
        """The core from the parameters, its topics and services (no commands yet)."""
        common = ('autostart', 'max_pressure_pa', 'feedback_timeout_s', 'open_loop', 'rate_hz')
        regulated = self._scene.regulator is not None
        value = {name: self.get_parameter(name).value for name in common + (
            () if regulated else ('max_injected_m3', 'max_flow_m3_per_s'))}
        self.rate_hz = float(value['rate_hz'])
        settings = {'autostart': value['autostart'],
                    'max_pressure_pa': float(value['max_pressure_pa']),
                    'feedback_timeout_s': float(value['feedback_timeout_s']),
                    'open_loop': value['open_loop']}
        if regulated:
            self.core, _ = pump_core(self._scene, self._model, **settings)
        else:
            profile = self._programme({})
            self._pending = None
            self.core, _ = pump_core(
                self._scene, self._model, flow_rate_m3_per_s=profile.flow_rate,
                cycles=profile.cycles, start_injected_m3=profile.start_injected,
                legs=profile.legs, **settings)
            self.core.max_injected_m3 = float(value['max_injected_m3'])
            self.core.max_flow_m3_per_s = float(value['max_flow_m3_per_s'])
        # Warnings name the feedback and setpoint topics as resolved here.
        self.connect(self._scene.outputs)
        volumes = self.subscription(contract.VOLUMES)
        if volumes is not None:
            self.core.feedback_topic = volumes.topic_name
        setpoints = self.subscription(contract.PUMP_SETPOINT)
        if setpoints is not None:
            self.core.setpoint_topic = setpoints.topic_name
        self._pump_services.append(self.create_service(
            SetBool, '~/setpoint_mode', self._setpoint_mode_service))
        for name in self.SERVICES:
            request = getattr(self, f'_{name}_request', None) or getattr(self.core, name)
            self._pump_services.append(
                self.create_service(Trigger, f'~/{name}', self._service(request)))
        self._use_sim_time = bool(self.get_parameter('use_sim_time').value)
        self.configured = True

    def _activate_timer(self) -> None:
        """Commands at rate_hz from now on; the current state said on pump/status."""
        self._timer = self.create_timer(1.0 / self.rate_hz, self.tick)
        if self.core.state == IDLE:
            self.send(self.core.begin(self.now_ns()))
        core = self.core
        stop = ('a pressure regulator: its programme of target gauge pressures'
                if self._scene.regulator is not None else
                f'end stop at {core.max_injected_m3 * 1e6:.4g} mL injected (max_injected_m3)')
        self.get_logger().info(
            f'relief at {core.max_pressure_pa * 1e-3:.4g} kPa gauge (max_pressure_pa), {stop}'
            + ('; open loop: no relief' if core.open_loop else ''))
        if self.core.duration_s > MAX_RUN_S and self._scene.regulator is None:
            # A rig may run for days, so this is said, not refused (softseq run refuses it).
            self.get_logger().warning(
                f'the programme runs {self.core.duration_s:.6g} s of rig time, more than '
                f'{MAX_RUN_S:g} s ({longest_part(self.core.profile, "pump.")})')

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
            'state': core.state, 'reason': core.reason,
            ('target_pa (gauge)' if self._scene.regulator is not None else 'injected_m3'):
                core.volume_m3,
            'max_pressure_pa (gauge)': core.max_pressure_pa,
            'max_injected_m3': core.max_injected_m3,
            'open_loop': core.open_loop, 'mode': core.mode,
            'setpoints_taken': core.setpoints_taken,
            'setpoints_refused': core.setpoints_refused}
        if core.setpoint is not None:
            values['setpoint'] = f'{core.setpoint.kind} {core.setpoint.value:.6g} (SI)'
        if core.last_refused_setpoint:
            values['last_refused_setpoint'] = core.last_refused_setpoint
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
            if self._timer is None:
                # A managed pump that is configured but not active: it commands nothing.
                response.success = False
                response.message = 'the pump node is inactive: activate it first (lifecycle)'
                return response
            reply: Reply = request(self.now_ns())
            self.send(reply.outputs)
            response.success, response.message = reply.success, reply.message
            return response
        return serve

    def _setpoint_mode_service(self, request: SetBool.Request,
                               response: SetBool.Response) -> SetBool.Response:
        """~/setpoint_mode: data true follows pump/setpoint, false the programme."""
        if self._timer is None:
            response.success = False
            response.message = 'the pump node is inactive: activate it first (lifecycle)'
            return response
        reply = self.core.set_mode(self.now_ns(), bool(request.data))
        self.send(reply.outputs)
        response.success, response.message = reply.success, reply.message
        return response

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

    def _programme(self, changes: dict[str, Any]) -> PumpProfile:
        """The programme of the parameters now, with ``changes``; SettingError if it cannot run."""
        values = {name: self.get_parameter(name).value for name in self.PROGRAMME_PARAMETERS}
        values.update(changes)
        legs = str(values['legs'])
        profile = pump_profile(
            self._scene, flow_rate_m3_per_s=float(values['flow_rate_m3_per_s']),
            legs=parse_legs(legs) if legs else None, cycles=int(values['cycles']),
            start_injected_m3=float(values['start_injected_m3']))
        check_programme(self._scene, profile, self._model)
        return profile

    def _validate_together(self, parameters: list[Parameter]) -> str | None:
        changes = {p.name: p.value for p in parameters if p.name in self.PROGRAMME_PARAMETERS}
        if not changes:
            return None
        try:
            self._programme(changes)
        except (SettingError, NodeConfigError) as err:
            return ' '.join(str(err).split())
        return None

    def _load_request(self, now: int) -> Reply:
        if self._pending is None:
            return Reply(False, 'nothing to load: set legs, cycles, flow_rate_m3_per_s or '
                                'start_injected_m3 first', [])
        return self._take_pending(now, self.core.load)

    def _reset_request(self, now: int) -> Reply:
        if self._pending is None:
            return self.core.reset(now)
        # A reset leaves the programme in any state, so it takes a new one too.
        return self._take_pending(now, self.core.reset)

    def _take_pending(self, now: int, load: Any) -> Reply:
        profile = self._pending
        reply = load(now, profile)
        if reply.success:
            self._pending = None
            own = sum(leg.flow_rate is not None for leg in profile.legs)
            self.get_logger().info(
                f'programme loaded: {len(profile.legs)} legs x {profile.cycles} cycles at '
                f'{profile.flow_rate * 1e6:.6g} mL/s'
                + (f' ({own} at their own rates)' if own else '')
                + f' from {profile.start_injected * 1e6:.6g} mL, {profile.duration():.6g} s')
            if profile.duration() > MAX_RUN_S:
                self.get_logger().warning(
                    f'the programme runs {profile.duration():.6g} s of rig time, more than '
                    f'{MAX_RUN_S:g} s ({longest_part(profile, "pump.")})')
            reply = Reply(True, f'{reply.message} with the new programme '
                                f'({profile.duration():.6g} s)', reply.outputs)
        return reply

    def _parameters_changed(self, parameters: list[Parameter]) -> None:
        if any(p.name in self.PROGRAMME_PARAMETERS for p in parameters):
            self._pending = self._programme({})
        for parameter in parameters:
            if parameter.name == 'rate_hz':
                self.rate_hz = float(parameter.value)
                if self._timer is not None:
                    self._timer.timer_period_ns = int(round(1e9 / self.rate_hz))
            elif parameter.name in ('max_pressure_pa', 'max_injected_m3', 'feedback_timeout_s',
                                    'max_flow_m3_per_s'):
                setattr(self.core, parameter.name, float(parameter.value))


def main(args: list[str] | None = None) -> None:
    """Run the syringe pump node."""
    run_node(SyringePumpNode, args)


if __name__ == '__main__':
    main()
