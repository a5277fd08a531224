"""
The syringe pump's core: its programme, its run/hold/stop state machine and its safety limits.

The commanded volume is the programme evaluated at the *run time*: the time since the start
minus the time spent held, so a hold pauses the programme and ``start`` resumes it. Every
``tick`` commands the current volume, also when idle, held or stopped (with flow 0), so the
actuator and a late recorder always see where the pump is.

States (each change is a :class:`PumpStatus`): ``idle`` (not started), ``running``, ``held``
(paused; ``start`` resumes), ``finished`` (the programme is over), ``stopped`` (by ``stop`` or a
safety limit; only ``reset`` leaves it). Safety, as a syringe pump with a pressure sensor:

- it stops when the actuator's gauge pressure (from its segment volumes message: the gauge
  pressure the actuator computed, so no second ambient pressure can disagree with it) exceeds
  ``max_pressure_pa``, and when the commanded volume would exceed ``max_injected_m3``;
- it holds when it has heard no pressure for ``feedback_timeout_s`` while running (the
  actuator died, or the topic is cut), and says why; only ``start`` resumes it. ``open_loop``
  runs without any feedback, for a pump with no actuator behind it.

The feedback timeout is measured on ``feedback_clock`` (default: the monotonic wall clock,
so that a simulated clock running 1000x faster does not make a healthy actuator look dead;
None: the driver's own time, as the batch runner wants for reproducible runs).
"""

from dataclasses import dataclass
import math
import time
from typing import Callable

from softseq_ros.rig import contract
from softseq_ros.rig.values import (
    INFO,
    WARNING,
    Notice,
    Output,
    PumpCommand,
    PumpStatus,
    SegmentVolumes,
)
from softseq_ros.scene.programme import PumpProfile

# Gauge pressure above which the pump stops by default: several times the highest pressure
# of the shipped segment models (about 20 kPa), far below what the silicone survives.
DEFAULT_MAX_PRESSURE_PA = 100.0e3
# An actuator answers every command within milliseconds; two seconds of silence while the
# pump pushes fluid is a dead or disconnected actuator.
DEFAULT_FEEDBACK_TIMEOUT_S = 2.0


@dataclass(frozen=True)
class Reply:
    """What a request to the pump (start, hold, stop, reset) answered, and what it sent."""

    success: bool
    message: str
    outputs: list[Output]


class PumpCore:
    """The syringe pump without ROS: ``tick(now)``, ``handle(SegmentVolumes, now)``, requests."""

    role = contract.PUMP

    def __init__(self, profile: PumpProfile, *, autostart: bool = True,
                 max_pressure_pa: float = DEFAULT_MAX_PRESSURE_PA,
                 max_injected_m3: float = math.inf,
                 feedback_timeout_s: float = DEFAULT_FEEDBACK_TIMEOUT_S,
                 open_loop: bool = False,
                 feedback_clock: Callable[[], int] | None = time.monotonic_ns) -> None:
        """A pump at rest (idle) at the programme's start volume."""
        self.profile = profile
        self.autostart = autostart
        self.max_pressure_pa = max_pressure_pa
        self.max_injected_m3 = max_injected_m3
        self.feedback_timeout_s = feedback_timeout_s
        self.open_loop = open_loop
        self._feedback_clock = feedback_clock
        self._last_feedback: int | None = None
        self.duration_s = profile.duration()
        self.state = 'idle'
        self.reason = ''
        self._elapsed_ns = 0           # run time accumulated before the current run
        self._running_since: int | None = None
        self._frozen_volume: float | None = None  # where a stop left the pump
        self._started = False
        self._out: list[Output] = []
        self.volume_m3 = profile.start_injected

    # ---------------------------------------------------------------- state machine

    def begin(self, now: int) -> list[Output]:
        """The first status (idle), for the drivers to publish before any tick."""
        self._set_state(now, 'idle')
        return self._take()

    def _take(self) -> list[Output]:
        out, self._out = self._out, []
        return out

    def _set_state(self, now: int, state: str, reason: str = '') -> None:
        self.state, self.reason = state, reason
        status = PumpStatus(now, state, reason)
        # A state the pump entered by itself, for a reason, is worth a warning.
        level = WARNING if reason and reason != 'requested' else INFO
        self._out.append(Notice(self.role, level, f'pump {status.text}'))
        self._out.append(status)

    @property
    def status(self) -> str:
        """``state`` or ``state: reason``."""
        return f'{self.state}: {self.reason}' if self.reason else self.state

    def run_time_s(self, now: int) -> float:
        """Programme time [s]: time since the start minus the time held."""
        elapsed = self._elapsed_ns
        if self._running_since is not None:
            elapsed += max(0, now - self._running_since)
        return elapsed * 1e-9

    def start(self, now: int) -> Reply:
        """Run (from idle or held)."""
        return self._reply(*self._start(now))

    def hold(self, now: int) -> Reply:
        """Pause the programme (running -> held)."""
        return self._reply(*self._hold(now))

    def stop(self, now: int, reason: str = 'requested') -> Reply:
        """Stop where the pump is; only ``reset`` leaves the stopped state."""
        return self._reply(*self._stop(now, reason))

    def reset(self, now: int) -> Reply:
        """Back to idle at the programme's start volume and run time 0."""
        self._elapsed_ns = 0
        self._running_since = None
        self._frozen_volume = None
        self._started = False
        self._set_state(now, 'idle')
        return self._reply(True, 'idle')

    def _reply(self, success: bool, message: str) -> Reply:
        return Reply(success, message, self._take())

    # The requests' state changes; their outputs wait in self._out for the caller to take.

    def _start(self, now: int) -> tuple[bool, str]:
        if self.state in ('idle', 'held'):
            self._running_since = now
            self._started = True
            # The actuator gets a full timeout to answer the first command of this run.
            self._last_feedback = self._feedback_time(now)
            self._set_state(now, 'running')
            return True, 'running'
        if self.state == 'running':
            return True, 'already running'
        return False, f'cannot start while {self.status}; call ~/reset first'

    def _hold(self, now: int) -> tuple[bool, str]:
        if self.state != 'running':
            return False, f'cannot hold while {self.status}'
        self._pause(now)
        self._set_state(now, 'held')
        return True, 'held'

    def _stop(self, now: int, reason: str) -> tuple[bool, str]:
        if self.state == 'stopped':
            return True, f'already {self.status}'
        self._frozen_volume = self._volume_at(now)
        self._pause(now)
        self._set_state(now, 'stopped', reason)
        return True, self.status

    def _feedback_time(self, now: int) -> int:
        return now if self._feedback_clock is None else self._feedback_clock()

    def _feedback_lost(self, now: int) -> bool:
        last = self._last_feedback
        return (last is not None
                and self._feedback_time(now) - last > self.feedback_timeout_s * 1e9)

    def _pause(self, now: int) -> None:
        if self._running_since is not None:
            self._elapsed_ns += max(0, now - self._running_since)
            self._running_since = None

    def _volume_at(self, now: int) -> float:
        if self._frozen_volume is not None:
            return self._frozen_volume
        return self.profile.command_at(self.run_time_s(now))[0]

    # ---------------------------------------------------------------- inputs and ticks

    def handle(self, value: SegmentVolumes, now: int) -> list[Output]:
        """The actuator's state: stop when its gauge pressure exceeds ``max_pressure_pa``."""
        gauge = value.gauge_pa
        if not math.isfinite(gauge):
            return []
        self._last_feedback = self._feedback_time(now)
        if gauge > self.max_pressure_pa and self.state in ('running', 'held'):
            return self.stop(now, f'gauge pressure {gauge:.6g} Pa exceeds max_pressure_pa '
                                  f'{self.max_pressure_pa:.6g} Pa').outputs
        return []

    def tick(self, now: int) -> list[Output]:
        """The command for ``now``: injected volume and signed flow (and any state change)."""
        if self.autostart and not self._started and self.state == 'idle':
            self._start(now)
        if self.state == 'running' and not self.open_loop and self._feedback_lost(now):
            self._pause(now)
            self._set_state(now, 'held', f'no pressure from the actuator for '
                                         f'{self.feedback_timeout_s:g} s (feedback_timeout_s); '
                                         'call ~/start to go on')
        run_time = self.run_time_s(now)
        volume, programme_flow = self.profile.command_at(run_time)
        if self._frozen_volume is not None:
            volume = self._frozen_volume
        flow = 0.0
        if self.state == 'running':
            if volume > self.max_injected_m3:
                self._frozen_volume = volume = self.max_injected_m3
                self._stop(now, 'injected volume reached max_injected_m3 '
                                f'{self.max_injected_m3:.6g} m^3')
            elif run_time >= self.duration_s:
                self._pause(now)
                self._set_state(now, 'finished')
            else:
                flow = programme_flow
        self.volume_m3 = volume
        self._out.append(PumpCommand(now, volume, flow))
        return self._take()
