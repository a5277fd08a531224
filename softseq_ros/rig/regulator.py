"""
The pressure regulator's core: the pump's state machine and safety, commanding pressures.

A scene whose supply is a pressure regulator (``supply.regulator``, docs/supply.md) has a
programme of target gauge pressures instead of volumes. Its core is the syringe pump's
(softseq_ros.rig.pump): the same states, services, feedback, fail-safe hold and relief, the
same setpoint mode. Only what it commands differs: each tick sends the programme's target
gauge pressure on ``pump/command`` (joint ``regulator``, effort), and a controller's setpoint
is a target gauge pressure (effort), reached at the programme's pressure rate.

- The relief (``max_pressure_pa``) acts on feedback as the pump's does (a gauge pressure heard
  above it stops the regulator), and on setpoints: a target above it is held at the relief,
  with a warning, counted as refused.
- A regulator has no syringe to run out of: no end stop (``max_injected_m3`` is infinite).
- Back in programme mode the programme starts from 0 Pa, as it always does: refused while the
  target is elsewhere (set 0 Pa first), so no command jumps.
"""

from dataclasses import dataclass
import math
from typing import Any

import numpy as np

from softseq_ros.rig.pump import (
    DEFAULT_FEEDBACK_TIMEOUT_S,
    SETPOINT,
    VACUUM_GAUGE_PA,
    PumpCore,
    Reply,
)
from softseq_ros.scene.regulator import PressureProgramme
from softseq_ros.wire.values import (
    WARNING,
    Notice,
    Output,
    PumpCommand,
    PumpSetpoint,
    regulator_command,
)


@dataclass(frozen=True)
class PressureSchedule:
    """
    A programme of target gauge pressures as the pump core walks one.

    The core's vocabulary is a syringe's: its "volume" is here the target gauge pressure [Pa]
    and its "flow" the target's rate [Pa/s]; ``flow_rate`` is the rate at which a setpoint's
    target is approached, ``start_injected`` where the target starts (0 Pa, at rest).
    """

    programme: PressureProgramme
    flow_rate: float
    start_injected: float = 0.0
    start_history: tuple[float, ...] = ()

    def duration(self) -> float:
        """When the programme ends [s]."""
        return self.programme.duration()

    def command_at(self, t: float) -> tuple[float, float]:
        """The target gauge pressure [Pa] and its rate [Pa/s] at ``t`` [s]."""
        targets, rates = self.commands_at(np.array([t]))
        return float(targets[0]), float(rates[0])

    def commands_at(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`command_at` of many times, as arrays."""
        times = np.asarray(self.programme.times, dtype=float)
        pressures = np.asarray(self.programme.pressures, dtype=float)
        t = np.asarray(t, dtype=float)
        targets = np.interp(t, times, pressures)
        if times.size < 2:
            return targets, np.zeros_like(t)
        leg = np.clip(np.searchsorted(times, t, side='right') - 1, 0, times.size - 2)
        span = times[leg + 1] - times[leg]
        slope = np.where(span > 0.0, (pressures[leg + 1] - pressures[leg])
                         / np.where(span > 0.0, span, 1.0), 0.0)
        rates = np.where((t >= times[0]) & (t < times[-1]), slope, 0.0)
        return targets, rates

    def max_injected(self) -> float:
        """The highest target [Pa] (the pump core's "largest volume")."""
        return self.programme.highest()


class RegulatorCore(PumpCore):
    """The pressure regulator without ROS: the pump core, commanding target pressures."""

    regulated = True

    def __init__(self, schedule: PressureSchedule, *, max_pressure_pa: float,
                 autostart: bool = True,
                 feedback_timeout_s: float = DEFAULT_FEEDBACK_TIMEOUT_S,
                 **settings: Any) -> None:
        """A regulator at rest (idle, 0 Pa) with its programme; settings as the pump core's."""
        super().__init__(schedule, autostart=autostart, max_pressure_pa=max_pressure_pa,
                         max_injected_m3=math.inf, feedback_timeout_s=feedback_timeout_s,
                         **settings)
        self.setpoints_held_at_relief = 0

    @property
    def target_pa(self) -> float:
        """The target gauge pressure now [Pa] (the core's "volume")."""
        return self.volume_m3

    def _command_value(self, now: int, target: float, rate: float) -> PumpCommand:
        return regulator_command(now, target)

    def load(self, now: int, profile: Any) -> Reply:
        """A regulator's programme is its scene's: a syringe programme cannot be loaded."""
        return self._reply(False, "a pressure regulator follows its scene's programme of "
                                  'target pressures; ~/load takes syringe legs')

    def set_mode(self, now: int, setpoint: bool) -> Reply:
        """As the pump's; back to the programme only from 0 Pa, where it starts."""
        if not setpoint and self.mode == SETPOINT and self.volume_m3 != 0.0:
            return self._reply(False, f'the programme starts from 0 Pa and the target is '
                                      f'{self.volume_m3:.6g} Pa: send a setpoint of 0 Pa '
                                      '(effort) first, so that no command jumps')
        return super().set_mode(now, setpoint)

    def take_setpoint(self, value: PumpSetpoint, now: int) -> list[Output]:
        """A target gauge pressure; one above the relief is held at the relief (warned)."""
        if value.kind == 'pressure' and self.mode == SETPOINT \
                and math.isfinite(value.value) and value.value > self.max_pressure_pa:
            self.setpoints_refused += 1
            self.setpoints_held_at_relief += 1
            fault = (f'target gauge pressure {value.value:.6g} Pa is above max_pressure_pa '
                     f'{self.max_pressure_pa:.6g} Pa: held at the relief')
            self.last_refused_setpoint = fault
            self.setpoint = PumpSetpoint(value.stamp_ns, gauge_pa=self.max_pressure_pa)
            said = self._setpoint_throttle.admit('relief', f'{self.setpoint_topic}: {fault}')
            return [] if said is None else [Notice(self.role, WARNING, said)]
        return super().take_setpoint(value, now)

    def _setpoint_fault(self, value: PumpSetpoint) -> str | None:
        if self.mode != SETPOINT:
            return super()._setpoint_fault(value)
        if value.kind != 'pressure':
            return (f'{value.kind} setpoint refused: the supply is a pressure regulator, which '
                    'is driven by a target gauge pressure (effort)')
        number = value.value
        if not math.isfinite(number):
            return f'pressure setpoint refused: {number} is not a finite number'
        if number < VACUUM_GAUGE_PA:
            return (f'target gauge pressure {number:.6g} Pa refused: below vacuum '
                    f'({VACUUM_GAUGE_PA:.6g} Pa gauge)')
        return None

    def _setpoint_step(self, setpoint: PumpSetpoint, here: float, step_s: float) -> float:
        """Towards the target pressure at the programme's pressure rate."""
        reach = self.profile.flow_rate * step_s
        target = float(setpoint.gauge_pa)
        return min(target, here + reach) if target >= here else max(target, here - reach)
