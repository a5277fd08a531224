"""
Syringe pump node: publishes the commanded injected volume on /pump/command at ``rate_hz``.

The programme (legs at ``flow_rate_m3_per_s``, repeated ``cycles`` times) comes from the scene
unless the parameters give it. The volume is the programme evaluated at the *run time*: the time
since the start minus the time spent held, so a hold pauses the programme and ~/start resumes it.
The pump publishes its current command at every tick, also when idle, held or stopped (with
velocity 0), so the actuator and a late recorder always see where the pump is.

States, published on /pump/status (transient_local) as ``<state>`` or ``<state>: <reason>``:
``idle`` (not started), ``running``, ``held`` (paused; ~/start resumes), ``finished`` (the
programme is over), ``stopped: <reason>`` (by ~/stop or a safety limit; only ~/reset leaves it).

Services (std_srvs/Trigger): ~/start (idle or held -> running), ~/hold (running -> held),
~/stop (-> stopped), ~/reset (-> idle at the programme's start volume, run time 0).

Safety: the pump stops when the actuator's gauge pressure (/actuator/pressure is absolute;
``ambient_pressure_pa`` is subtracted) exceeds ``max_pressure_pa``, and when the commanded volume
would exceed ``max_injected_m3``, where it stays.
"""

import math
from typing import Any

from rclpy.node import Parameter
from sensor_msgs.msg import FluidPressure, JointState
from std_msgs.msg import String
from std_srvs.srv import Trigger
import yaml

from softseq_ros.nodes.common import (
    DEFAULT_AMBIENT_PRESSURE_PA,
    NodeConfigError,
    RigNode,
    run_node,
    set_timer_rate,
    stamp_header,
)
from softseq_ros.physics.profile import Leg, PumpProfile

# Gauge pressure above which the pump stops by default: several times the highest pressure
# of the shipped segment models (about 20 kPa), far below what the silicone survives.
DEFAULT_MAX_PRESSURE_PA = 100.0e3
LEG_KEYS = ('inflate_to_m3', 'deflate_to_m3', 'hold_s')


def parse_legs(text: str) -> tuple[Leg, ...]:
    """
    Legs from a YAML list in the scene's syntax.

    Example: ``[{inflate_to_m3: 5.0e-6}, {hold_s: 2}, {deflate_to_m3: 0.0}]``. Raises
    NodeConfigError naming the leg and key that is wrong.
    """
    try:
        items = yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise NodeConfigError(f'legs: not valid YAML ({" ".join(str(err).split())})') from None
    if not isinstance(items, list) or not items:
        raise NodeConfigError('legs: must be a non-empty YAML list such as '
                              '[{inflate_to_m3: 5.0e-6}, {deflate_to_m3: 0.0}]')
    legs = []
    for index, item in enumerate(items):
        where = f'legs[{index}]'
        if not isinstance(item, dict) or len(item) != 1:
            raise NodeConfigError(f'{where}: must be a mapping with one of {", ".join(LEG_KEYS)}')
        (key, amount), = item.items()
        if key not in LEG_KEYS:
            raise NodeConfigError(f'{where}: unknown key {key!r}; expected one of '
                                  f'{", ".join(LEG_KEYS)} (SI units)')
        try:
            # YAML 1.1 reads 5e-6 (no dot) as text; a number is meant.
            number = float(amount)
        except (TypeError, ValueError):
            raise NodeConfigError(f'{where}.{key}: must be a number, got {amount!r}') from None
        try:
            if key == 'hold_s':
                legs.append(Leg.hold(number))
            elif key == 'inflate_to_m3':
                legs.append(Leg.inflate(number))
            else:
                legs.append(Leg.deflate(number))
        except ValueError as err:
            raise NodeConfigError(f'{where}.{key}: {err}') from None
    return tuple(legs)


def _legs_reason(text: str) -> str | None:
    if not text:
        return None
    try:
        parse_legs(text)
    except NodeConfigError as err:
        return str(err)
    return None


class SyringePumpNode(RigNode):
    """The syringe pump: programme, run/hold/stop state machine and safety limits."""

    NODE_NAME = 'syringe_pump'

    def __init__(self, **kwargs: Any) -> None:
        """Declare parameters (defaults from the scene), build the programme, start the timer."""
        super().__init__(self.NODE_NAME, **kwargs)
        scene = self.declare_scene()
        default = scene.pump.profile
        self.rate_hz = self.declare_number(
            'rate_hz', scene.pump.rate_hz, 'Command publishing rate [Hz].', minimum=0.0,
            open_minimum=True, maximum=10000.0)
        flow = self.declare_number(
            'flow_rate_m3_per_s', default.flow_rate, 'Pump flow rate [m^3/s].', minimum=0.0,
            open_minimum=True, read_only=True)
        legs_text = self.declare_text(
            'legs', '', 'Programme legs as a YAML list in the scene syntax, e.g. '
            '[{inflate_to_m3: 5.0e-6}, {hold_s: 2}, {deflate_to_m3: 0.0}]; empty: the scene.',
            read_only=True, check=_legs_reason)
        cycles = self.declare_integer('cycles', default.cycles, 'Programme repetitions.',
                                      minimum=1, read_only=True)
        start = self.declare_number(
            'start_injected_m3', default.start_injected, 'Injected volume at run time 0 [m^3].',
            minimum=0.0, read_only=True)
        self.autostart = self.declare_flag(
            'autostart', True, 'Start running at the first tick (else wait for ~/start).',
            read_only=True)
        self.max_pressure_pa = self.declare_number(
            'max_pressure_pa', DEFAULT_MAX_PRESSURE_PA,
            'Stop when the actuator gauge pressure exceeds this [Pa].', minimum=0.0,
            open_minimum=True)
        self.max_injected_m3 = self.declare_number(
            'max_injected_m3', scene.capacity,
            'Stop when the commanded injected volume would exceed this [m^3] '
            '(default: what the segments hold).', minimum=0.0, open_minimum=True)
        self.ambient_pressure_pa = self.declare_number(
            'ambient_pressure_pa', DEFAULT_AMBIENT_PRESSURE_PA,
            'Ambient pressure subtracted from /actuator/pressure [Pa].', minimum=0.0)
        legs = parse_legs(legs_text) if legs_text else default.legs
        try:
            self.profile = PumpProfile(legs=legs, flow_rate=flow, cycles=cycles,
                                       start_injected=start)
        except ValueError as err:
            raise NodeConfigError(f'pump programme (legs, cycles, start_injected_m3): '
                                  f'{err}') from None

        self._duration = self.profile.duration()
        self.state = 'idle'
        self.reason = ''
        self._elapsed_ns = 0           # run time accumulated before the current run
        self._running_since: int | None = None
        self._frozen_volume: float | None = None  # where a stop left the pump
        self._started = False
        self._command = JointState(name=['syringe'], position=[start], velocity=[0.0])
        self._status = String()

        self._make_publisher('/pump/command')
        self._make_publisher('/pump/status')
        self._subscribe('/actuator/pressure', self.on_pressure)
        if not self.batch_mode:
            for name, handler in (('start', self.start), ('stop', self.stop),
                                  ('hold', self.hold), ('reset', self.reset)):
                self.create_service(Trigger, f'~/{name}', self._service(handler))
        self._timer = self._make_timer(self.rate_hz, self.tick)
        self._set_state('idle')
        self.configured = True

    # ---------------------------------------------------------------- state machine

    def _set_state(self, state: str, reason: str = '') -> None:
        self.state, self.reason = state, reason
        self._status.data = f'{state}: {reason}' if reason else state
        if state == 'stopped' and reason != 'requested':
            self.log_warning(f'pump {self._status.data}')
        else:
            self.log_info(f'pump {self._status.data}')
        self._publish('/pump/status', self._status)

    def run_time_s(self, now_ns: int | None = None) -> float:
        """Programme time [s]: time since the start minus the time held."""
        elapsed = self._elapsed_ns
        if self._running_since is not None:
            now = self.now_ns() if now_ns is None else now_ns
            elapsed += max(0, now - self._running_since)
        return elapsed * 1e-9

    def start(self) -> tuple[bool, str]:
        """Run (from idle or held); returns (success, message)."""
        if self.state in ('idle', 'held'):
            self._running_since = self.now_ns()
            self._started = True
            self._set_state('running')
            return True, 'running'
        if self.state == 'running':
            return True, 'already running'
        return False, f'cannot start while {self._status.data}; call ~/reset first'

    def hold(self) -> tuple[bool, str]:
        """Pause the programme (running -> held)."""
        if self.state != 'running':
            return False, f'cannot hold while {self._status.data}'
        self._pause()
        self._set_state('held')
        return True, 'held'

    def stop(self, reason: str = 'requested') -> tuple[bool, str]:
        """Stop where the pump is; only ~/reset leaves the stopped state."""
        if self.state == 'stopped':
            return True, f'already {self._status.data}'
        self._frozen_volume = self._volume_now()
        self._pause()
        self._set_state('stopped', reason)
        return True, self._status.data

    def reset(self) -> tuple[bool, str]:
        """Back to idle at the programme's start volume and run time 0."""
        self._elapsed_ns = 0
        self._running_since = None
        self._frozen_volume = None
        self._started = False
        self._set_state('idle')
        return True, 'idle'

    def _pause(self) -> None:
        if self._running_since is not None:
            self._elapsed_ns += max(0, self.now_ns() - self._running_since)
            self._running_since = None

    def _service(self, handler: Any) -> Any:
        def serve(_request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
            response.success, response.message = handler()
            return response
        return serve

    def _volume_now(self, now_ns: int | None = None) -> float:
        if self._frozen_volume is not None:
            return self._frozen_volume
        return self.profile.command_at(self.run_time_s(now_ns))[0]

    # ---------------------------------------------------------------- ROS entry points

    def on_pressure(self, msg: FluidPressure) -> None:
        """Stop when the actuator's gauge pressure exceeds max_pressure_pa."""
        gauge = msg.fluid_pressure - self.ambient_pressure_pa
        if math.isfinite(gauge) and gauge > self.max_pressure_pa and self.state in (
                'running', 'held'):
            self.stop(f'gauge pressure {gauge:.6g} Pa exceeds max_pressure_pa '
                      f'{self.max_pressure_pa:.6g} Pa')

    def tick(self) -> None:
        """Publish the command for now(): injected volume and signed flow."""
        now = self.now_ns()
        if now == 0 and self._now_fn is None and self.get_parameter('use_sim_time').value:
            return  # no /clock received yet: the time is unknown
        if self.autostart and not self._started and self.state == 'idle':
            self.start()
        run_time = self.run_time_s(now)
        volume, programme_flow = self.profile.command_at(run_time)
        if self._frozen_volume is not None:
            volume = self._frozen_volume
        flow = 0.0
        if self.state == 'running':
            if volume > self.max_injected_m3:
                self._frozen_volume = volume = self.max_injected_m3
                self.stop(f'injected volume reached max_injected_m3 {self.max_injected_m3:.6g} '
                          'm^3')
            elif run_time >= self._duration:
                self._pause()
                self._set_state('finished')
            else:
                flow = programme_flow
        command = self._command
        stamp_header(command.header, now)
        command.position[0] = volume
        command.velocity[0] = flow
        self._publish('/pump/command', command)

    def _parameters_changed(self, parameters: list[Parameter]) -> None:
        for parameter in parameters:
            if parameter.name == 'rate_hz':
                self.rate_hz = float(parameter.value)
                set_timer_rate(self._timer, self.rate_hz)
            elif parameter.name in ('max_pressure_pa', 'max_injected_m3',
                                    'ambient_pressure_pa'):
                setattr(self, parameter.name, float(parameter.value))


def main(args: list[str] | None = None) -> None:
    """Run the syringe pump node."""
    run_node(SyringePumpNode, args)


if __name__ == '__main__':
    main()
