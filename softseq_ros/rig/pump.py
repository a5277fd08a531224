"""
The syringe pump's core: its programme, its run/hold/stop state machine and its safety limits.

The commanded volume is the programme evaluated at the *run time*: the time since the start
minus the time spent held, so a hold pauses the programme and ``start`` resumes it. While
running, every ``tick`` commands the current volume. While idle, held, finished or stopped
(flow 0) a tick commands only what changed (a new volume twice), or the same volume again
once :data:`HEARTBEAT_S` has passed, so the actuator and a late recorder still see where the
pump is and a recording of a pump left alone does not grow at the command rate.

States: ``idle`` (not started), ``running``, ``held`` (paused; ``start`` resumes),
``finished`` (the programme is over), ``stopped`` (only ``reset`` leaves it). Every change is a
:class:`PumpStatus`, and what makes the pump change, with the state it enters and the reason it
gives, is one table, :data:`REACTIONS` (documented in docs/faults.md). Safety, as a syringe
pump with a pressure sensor:

- it stops when a gauge pressure heard on the actuator's volumes (the gauge pressure the
  actuator computed, so no second ambient pressure can disagree with it) exceeds
  ``max_pressure_pa``, ``+inf`` included, whoever sent it: stopping never pushes fluid; and
  when the commanded volume would exceed ``max_injected_m3``;
- feedback is the actuator's *answer to this pump*: the actuator stamps its state with the
  stamp of the command it answers, so only a message stamped like one of the pump's last
  :data:`RECENT_COMMANDS` commands, not answered before, counts; and it answers every older
  command too (an actuator behind its commands answers the newest it has and walks through
  the ones it skipped, softseq_ros.rig.intake), so none of them counts afterwards. Anything
  else (another publisher, a replayed recording, the actuator's states between commands)
  keeps no pump running;
- feedback that cannot be trusted (segment names that are not the scene's, arrays of the
  wrong length, a volume that is NaN, infinite or negative, a pressure that is NaN, infinite
  or below vacuum) is no feedback: an answer like that holds the pump at once, any other such
  message is warned about once per kind of fault, naming the topic and what is wrong;
- it holds when no trustworthy answer came for ``feedback_timeout_s`` while running (the
  actuator died, or the topic is cut), and says why; only ``start`` resumes it. ``open_loop``
  runs without any feedback, for a pump with no actuator behind it.

Setpoint mode (``set_mode``): a controller, not the programme, says where the pump goes, on
``pump/setpoint`` (a target injected volume, reached at the programme's flow rate, or a signed
flow). The relief pressure, the end stop, the feedback timeout and untrusted answers act on it
as on a programme; a setpoint out of range, or one sent in programme mode, is refused with a
warning and counted. Back in programme mode the pump is idle with its programme starting from
where the controller left the syringe, so no command jumps.

The feedback timeout is measured on ``feedback_clock`` (default: the monotonic wall clock,
so that a simulated clock running 1000x faster does not make a healthy actuator look dead;
None: the driver's own time, as the batch runner wants for reproducible runs).
"""

from collections import deque
import dataclasses
from dataclasses import dataclass
import math
import time
from typing import Callable, Sequence

import numpy as np

from softseq_ros.rig.throttle import Throttle
from softseq_ros.scene.programme import PumpProfile
from softseq_ros.wire import contract
from softseq_ros.wire.values import (
    INFO,
    WARNING,
    Notice,
    Output,
    PumpCommand,
    PumpSetpoint,
    PumpStatus,
    SegmentVolumes,
)

# Gauge pressure above which a pump core built without a scene stops; one built from a scene
# (softseq_ros.rig.build) takes a relief from the scene's curves instead.
DEFAULT_MAX_PRESSURE_PA = 100.0e3
# How often a pump that is not running repeats its unchanged command [s].
HEARTBEAT_S = 1.0
# An actuator answers every command within milliseconds; two seconds of silence while the
# pump pushes fluid is a dead or disconnected actuator.
DEFAULT_FEEDBACK_TIMEOUT_S = 2.0
# How many of its last commands the pump takes answers to. The actuator's command queue keeps
# 1000, so no answer comes later than that behind the newest command it got; ten times as many
# leave room for commands in flight and for an actuator answering what it buffered at start.
RECENT_COMMANDS = 10 * contract.PUMP_COMMAND.qos.depth
# A gauge pressure below minus one standard atmosphere would be an absolute pressure below
# vacuum: no liquid in the segments can be there.
VACUUM_GAUGE_PA = -contract.DEFAULT_AMBIENT_PRESSURE_PA

IDLE, RUNNING, HELD, FINISHED, STOPPED = 'idle', 'running', 'held', 'finished', 'stopped'
STATES = (IDLE, RUNNING, HELD, FINISHED, STOPPED)
# Who says where the pump goes: its programme, or a controller's setpoints.
PROGRAMME, SETPOINT = 'programme', 'setpoint'
# The fastest flow a setpoint may ask for [m^3/s] by default: the fastest a scene's pump runs.
DEFAULT_MAX_FLOW_M3_PER_S = 1.0e-3


@dataclass(frozen=True)
class Reaction:
    """One row of the pump's table: what happened, the state it enters and the reason it gives."""

    cause: str       # the row's name, as docs/faults.md and the tests name it
    state: str
    reason: str      # str.format template ('' for none); the status and the log show it
    level: str       # the log level of the change: a change the pump made by itself warns
    when: str        # what happened, in words


REACTIONS: dict[str, Reaction] = {reaction.cause: reaction for reaction in (
    Reaction('reset', IDLE, '', INFO, 'the pump starts, or ~/reset'),
    Reaction('start', RUNNING, '', INFO,
             '~/start from idle or held, or the first tick with autostart'),
    Reaction('hold', HELD, '', INFO, '~/hold while running'),
    Reaction('setpoint_mode', RUNNING, 'following setpoints on {topic}', INFO,
             '~/setpoint_mode true, from any state but stopped'),
    Reaction('silent', HELD,
             'no pressure from the actuator for {timeout:g} s (feedback_timeout_s){why}; '
             'call ~/start to go on', WARNING,
             'no trustworthy answer to its commands for feedback_timeout_s while running'),
    Reaction('untrusted', HELD,
             '{topic}: {fault}; feedback that cannot be trusted is no feedback; '
             'call ~/start to go on', WARNING,
             'an answer to its command that cannot be trusted, while running'),
    Reaction('finished', FINISHED, '', INFO, 'the programme is over'),
    Reaction('over_pressure', STOPPED,
             'gauge pressure {gauge:.6g} Pa exceeds max_pressure_pa {limit:.6g} Pa', WARNING,
             'a gauge pressure above max_pressure_pa (+inf too) while running or held'),
    Reaction('end_stop', STOPPED, 'injected volume reached max_injected_m3 {limit:.6g} m^3',
             WARNING, 'the commanded volume would exceed max_injected_m3'),
    Reaction('stop', STOPPED, 'requested', INFO, '~/stop'),
)}


@dataclass(frozen=True)
class Reply:
    """What a request to the pump (start, hold, stop, reset) answered, and what it sent."""

    success: bool
    message: str
    outputs: list[Output]


class PumpCore:
    """
    The syringe pump without ROS: ``tick(now)``, ``handle(SegmentVolumes, now)``, requests.

    ``feedback`` takes a volumes message field by field, as a node receives it.
    """

    role = contract.PUMP
    regulated = False   # commands volumes (a syringe), not target pressures

    def __init__(self, profile: PumpProfile, *, autostart: bool = True,
                 max_pressure_pa: float = DEFAULT_MAX_PRESSURE_PA,
                 max_injected_m3: float = math.inf,
                 feedback_timeout_s: float = DEFAULT_FEEDBACK_TIMEOUT_S,
                 open_loop: bool = False,
                 feedback_clock: Callable[[], int] | None = time.monotonic_ns,
                 segment_names: Sequence[str] | None = None,
                 feedback_topic: str = contract.VOLUMES.name,
                 max_flow_m3_per_s: float = DEFAULT_MAX_FLOW_M3_PER_S) -> None:
        """
        A pump at rest (idle) at the programme's start volume.

        ``segment_names``: the scene's segments, base to tip, that feedback must name (None:
        not checked); ``feedback_topic``: the topic's name as warnings give it;
        ``max_flow_m3_per_s``: the fastest flow a setpoint may ask for.
        """
        self.profile = profile
        self.autostart = autostart
        self.max_pressure_pa = max_pressure_pa
        self.max_injected_m3 = max_injected_m3
        self.feedback_timeout_s = feedback_timeout_s
        self.open_loop = open_loop
        self._feedback_clock = feedback_clock
        self._last_feedback: int | None = None
        self.segment_names = None if segment_names is None else tuple(segment_names)
        self.feedback_topic = feedback_topic
        # The stamps of the last commands not answered yet (nor any newer one), oldest first,
        # and the same as a set.
        self._sent: deque[int] = deque()
        self._unanswered: set[int] = set()
        self._warned: set[str] = set()       # kinds of untrusted feedback already warned about
        self._last_fault: str | None = None  # since the last trustworthy answer
        self._foreign = 0                    # plausible ones that answered no command, too
        self.duration_s = profile.duration()
        self.state = IDLE
        self.reason = ''
        self.cause = 'reset'           # the row of REACTIONS that gave the state
        self._elapsed_ns = 0           # run time accumulated before the current run
        self._running_since: int | None = None
        self._frozen_volume: float | None = None  # where a stop left the pump
        self._started = False
        self._out: list[Output] = []
        self.volume_m3 = profile.start_injected
        self.mode = PROGRAMME
        self._last_command: PumpCommand | None = None
        self._last_values = (math.nan, math.nan)   # the last command's volume and flow
        self._settled = False       # the last command repeated the volume of the one before
        self.max_flow_m3_per_s = max_flow_m3_per_s
        self.setpoint_topic = contract.PUMP_SETPOINT.name
        self.setpoint: PumpSetpoint | None = None   # the one followed in setpoint mode
        self._last_tick: int | None = None
        self.setpoints_taken = 0
        self.setpoints_refused = 0
        self.last_refused_setpoint = ''
        self._setpoint_throttle = Throttle()

    # ---------------------------------------------------------------- state machine

    def begin(self, now: int) -> list[Output]:
        """The first status (idle), for the drivers to publish before any tick."""
        self._enter(now, 'reset')
        return self._take()

    def _take(self) -> list[Output]:
        out, self._out = self._out, []
        return out

    def _enter(self, now: int, cause: str, **fields: object) -> None:
        """Enter the state of the table's row ``cause``; ``fields`` fill in its reason."""
        reaction = REACTIONS[cause]
        reason = reaction.reason.format(**fields)
        self.state, self.reason = reaction.state, reason
        self.cause = cause
        status = PumpStatus(now, reaction.state, reason)
        self._out.append(Notice(self.role, reaction.level, f'pump {status.text}'))
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

    def stop(self, now: int) -> Reply:
        """Stop where the pump is; only ``reset`` leaves the stopped state."""
        return self._reply(*self._stop(now, 'stop'))

    def reset(self, now: int, profile: PumpProfile | None = None) -> Reply:
        """Back to idle at the programme's start volume and run time 0 (with ``profile``)."""
        if profile is not None:
            self.profile = profile
            self.duration_s = profile.duration()
            self.volume_m3 = profile.start_injected
        self.mode, self.setpoint = PROGRAMME, None
        self._elapsed_ns = 0
        self._running_since = None
        self._frozen_volume = None
        self._started = False
        self._warned.clear()
        self._enter(now, 'reset')
        return self._reply(True, IDLE)

    def load(self, now: int, profile: PumpProfile) -> Reply:
        """
        Take a new programme, idle at its start volume; refused while running or held.

        A held pump is in the middle of a programme: stop it (or let it finish) first, so
        that nothing the pump was doing is replaced under its feet.
        """
        if self.state in (RUNNING, HELD):
            return self._reply(False, f'cannot load a programme while {self.status}; call '
                                      '~/stop (or wait until it has finished) first')
        return self.reset(now, profile)

    def set_mode(self, now: int, setpoint: bool) -> Reply:
        """
        Follow setpoints (``setpoint`` True) or the programme; refused while stopped.

        Into setpoint mode the pump runs, holding its volume until a setpoint comes. Back into
        programme mode it is idle with its programme starting where the syringe is: refused
        when the programme cannot start there (a first leg inflating to below it).
        """
        if self.state == STOPPED:
            return self._reply(False, f'cannot change mode while {self.status}; call ~/reset '
                                      'first (it returns to the programme)')
        wanted = SETPOINT if setpoint else PROGRAMME
        if wanted == self.mode:
            return self._reply(True, f'already in {wanted} mode')
        if setpoint:
            self._pause(now)
            self.mode, self.setpoint, self._last_tick = SETPOINT, None, now
            self._running_since, self._started = now, True
            self._last_feedback = self._feedback_time(now)
            self._last_fault, self._foreign = None, 0
            self._enter(now, 'setpoint_mode', topic=self.setpoint_topic)
            return self._reply(True, f'{RUNNING} in setpoint mode')
        here = self.volume_m3
        try:
            profile = dataclasses.replace(self.profile, start_injected=here, start_history=())
        except ValueError as err:
            return self._reply(False, f"the programme cannot start from the syringe's "
                                      f'{here:.6g} m^3 ({err}); load one that can, or stay in '
                                      'setpoint mode')
        reply = self.reset(now, profile)
        return Reply(True, f'{IDLE} in programme mode, the programme starting from {here:.6g} '
                           'm^3', reply.outputs)

    def take_setpoint(self, value: PumpSetpoint, now: int) -> list[Output]:
        """Follow ``value`` from the next tick, or refuse it (a warning, counted)."""
        fault = self._setpoint_fault(value)
        if fault is not None:
            self.setpoints_refused += 1
            self.last_refused_setpoint = fault
            said = self._setpoint_throttle.admit(value.kind, f'{self.setpoint_topic}: {fault}')
            return [] if said is None else [Notice(self.role, WARNING, said)]
        self.setpoints_taken += 1
        self.setpoint = value
        return []

    def _setpoint_fault(self, value: PumpSetpoint) -> str | None:
        """What is wrong with a setpoint here and now, or None."""
        if self.mode != SETPOINT:
            return ('setpoint refused: the pump follows its programme; call ~/setpoint_mode '
                    '(true) first')
        number, kind = value.value, value.kind
        if kind == 'pressure':
            return ('target gauge pressure refused: the supply is a syringe, which is driven '
                    'by volume; give a target volume (position) or a flow (velocity)')
        if not math.isfinite(number):
            return f'{kind} setpoint refused: {number} is not a finite number'
        if kind == 'volume' and not 0.0 <= number <= self.max_injected_m3:
            return (f'target injected volume {number:.6g} m^3 refused: outside 0 to '
                    f'max_injected_m3 {self.max_injected_m3:.6g} m^3')
        if kind == 'flow' and abs(number) > self.max_flow_m3_per_s:
            return (f'flow setpoint {number:.6g} m^3/s refused: faster than max_flow_m3_per_s '
                    f'{self.max_flow_m3_per_s:.6g} m^3/s')
        return None

    def _reply(self, success: bool, message: str) -> Reply:
        return Reply(success, message, self._take())

    # The requests' state changes; their outputs wait in self._out for the caller to take.

    def _start(self, now: int) -> tuple[bool, str]:
        if self.state in (IDLE, HELD):
            self._running_since = now
            self._started = True
            # The actuator gets a full timeout to answer the first command of this run.
            self._last_feedback = self._feedback_time(now)
            self._last_fault, self._foreign = None, 0
            self._enter(now, 'start')
            return True, RUNNING
        if self.state == RUNNING:
            return True, 'already running'
        return False, f'cannot start while {self.status}; call ~/reset first'

    def _hold(self, now: int) -> tuple[bool, str]:
        if self.state != RUNNING:
            return False, f'cannot hold while {self.status}'
        self._pause(now)
        self._enter(now, 'hold')
        return True, HELD

    def _stop(self, now: int, cause: str, **fields: object) -> tuple[bool, str]:
        if self.state == STOPPED:
            return True, f'already {self.status}'
        self._frozen_volume = self._volume_at(now)
        self._pause(now)
        self._enter(now, cause, **fields)
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
        if self.mode == SETPOINT:
            return self.volume_m3
        return self.profile.command_at(self.run_time_s(now))[0]

    # ---------------------------------------------------------------- inputs and ticks

    def handle(self, value: SegmentVolumes | PumpSetpoint, now: int) -> list[Output]:
        """The actuator's state (its gauge pressure stands for every segment's), or a setpoint."""
        if type(value) is PumpSetpoint:
            return self.take_setpoint(value, now)
        names = value.names
        pressures = [value.gauge_pa] * len(names) if names else [value.gauge_pa]
        return self.feedback(now, value.stamp_ns, names, value.volumes_m3, pressures)

    def feedback(self, now: int, stamp_ns: int, names: Sequence[str],
                 volumes_m3: Sequence[float], gauge_pa: Sequence[float]) -> list[Output]:
        """
        A message on the actuator's volumes, field by field (``gauge_pa``: one per joint).

        A pressure above ``max_pressure_pa`` stops the pump whoever sent it; only a
        trustworthy answer to one of the pump's recent commands counts as feedback, and an
        untrustworthy one holds a running pump (the module's docstring has the rules).
        """
        limit = self.max_pressure_pa
        if self.state in (RUNNING, HELD):
            for gauge in gauge_pa:
                if gauge > limit:
                    self._stop(now, 'over_pressure', gauge=gauge, limit=limit)
                    return self._take()
        unanswered = self._unanswered
        answer = stamp_ns in unanswered
        if answer:
            # It answers the older commands too (those the actuator skipped).
            sent = self._sent
            while True:
                oldest = sent.popleft()
                unanswered.discard(oldest)
                if oldest == stamp_ns:
                    break
        fault = self._fault(names, volumes_m3, gauge_pa)
        if fault is not None:
            kind, text = fault
            if answer and self.state == RUNNING and not self.open_loop:
                self._pause(now)
                self._warned.add(kind)  # the status says it; no second warning
                self._enter(now, 'untrusted', topic=self.feedback_topic, fault=text)
                return self._take()
            self._last_fault = text
            if kind not in self._warned:
                self._warned.add(kind)
                return [Notice(self.role, WARNING, f'{self.feedback_topic}: {text}: not taken '
                                                   'as feedback (said once per kind of fault)')]
            return []
        if not answer:
            self._foreign += 1
            return []
        self._last_feedback = self._feedback_time(now)
        self._last_fault, self._foreign = None, 0
        return []

    def _fault(self, names: Sequence[str], volumes: Sequence[float],
               pressures: Sequence[float]) -> tuple[str, str] | None:
        """(kind, what is wrong) with a volumes message, or None when it can be trusted."""
        expected = self.segment_names
        if expected is not None and names is not expected and tuple(names) != expected:
            return 'names', (f"joint names {list(names)} are not the scene's segments "
                             f'{list(expected)}')
        if not names:
            return 'names', 'no joints'
        if len(volumes) != len(names):
            return 'volumes length', f'{len(volumes)} volumes (position) for {len(names)} joints'
        if len(pressures) != len(names):
            return 'pressures length', (f'{len(pressures)} pressures (effort) for {len(names)} '
                                        'joints')
        # One chained comparison per value in the common case (it is false for NaN too).
        for name, volume in zip(names, volumes):
            if not 0.0 <= volume < math.inf:
                if not math.isfinite(volume):
                    return 'volume not finite', f'volume of {name} is {volume}'
                return 'volume negative', f'volume of {name} is negative ({volume:.6g} m^3)'
        for gauge in pressures:
            if not VACUUM_GAUGE_PA <= gauge < math.inf:
                if gauge < VACUUM_GAUGE_PA:
                    return 'pressure below vacuum', (f'gauge pressure {gauge:.6g} Pa is below '
                                                     f'vacuum ({VACUUM_GAUGE_PA:.6g} Pa)')
                return 'pressure not finite', f'gauge pressure is {gauge}'
        return None

    def _silent_why(self) -> str:
        if self._last_fault is not None:
            return (f'; what came on {self.feedback_topic} could not be trusted '
                    f'({self._last_fault})')
        if self._foreign:
            return (f'; the {self._foreign} messages on {self.feedback_topic} in that time '
                    "answered none of the pump's commands")
        return ''

    def _sent_command(self, stamp: int) -> None:
        sent = self._sent
        if len(sent) == RECENT_COMMANDS:
            self._unanswered.discard(sent.popleft())
        sent.append(stamp)
        self._unanswered.add(stamp)

    # ---------------------------------------------------------------- blocks of ticks

    def plan(self, times: 'np.ndarray',
             answered: bool = True) -> tuple[int, 'np.ndarray', 'np.ndarray']:
        """
        The commands of ticks at ``times`` (int64 ns, increasing) that change no state.

        ``(count, volumes, flows)``: the first ``count`` ticks are a running pump's plain
        commands, as :meth:`tick` gives them when each is answered at once by a trustworthy
        answer (``answered``; else by none), with no start, hold, finish or end stop among
        them; a driver hands them to :meth:`commit_plan` instead of ticking. Count 0 when the
        next tick is not plain.
        """
        empty = np.empty(0)
        if self.state != RUNNING or self._frozen_volume is not None or self.mode != PROGRAMME \
                or (not self.open_loop and self._feedback_clock is not None) \
                or self._running_since is None:
            return 0, empty, empty
        if not self.open_loop and self._feedback_lost(int(times[0])):
            return 0, empty, empty
        elapsed = self._elapsed_ns + np.maximum(0, times - self._running_since)
        run_time = elapsed.astype(float) * 1e-9
        volumes, flows = self.profile.commands_at(run_time)
        plain = (volumes <= self.max_injected_m3) & (run_time < self.duration_s)
        timeout = self.feedback_timeout_s * 1e9
        if not self.open_loop and answered and times.size > 1:
            # Each answer renews the feedback: only a gap longer than the timeout loses it.
            plain[1:] &= np.diff(times) <= timeout
        elif not self.open_loop and not answered and self._last_feedback is not None:
            plain &= times - self._last_feedback <= timeout
        count = int(np.argmin(plain)) if not plain.all() else times.size
        return count, volumes[:count], flows[:count]

    def trusted(self, names: Sequence[str], volumes: 'np.ndarray', gauge: 'np.ndarray') -> int:
        """
        How many of these answers :meth:`handle` would take as plain feedback.

        Rows of volumes and gauge pressures: no over-pressure stop, nothing untrustworthy.
        """
        if not len(gauge):
            return 0
        expected = self.segment_names
        if (expected is not None and tuple(names) != expected) or not names \
                or volumes.shape[1] != len(names):
            return 0
        good = ((volumes >= 0.0) & (volumes < math.inf)).all(axis=1)
        good &= (gauge >= VACUUM_GAUGE_PA) & (gauge < math.inf)
        if self.state in (RUNNING, HELD):
            good &= ~(gauge > self.max_pressure_pa)
        return int(np.argmin(good)) if not good.all() else good.size

    def commit_plan(self, times: 'np.ndarray', volumes: 'np.ndarray', answered: bool) -> None:
        """
        The state after ticks at ``times`` commanding ``volumes`` (from :meth:`plan`).

        Each was answered at once by a trustworthy answer when ``answered`` (else by none).
        """
        count = times.size
        if not count:
            return
        self.volume_m3 = float(volumes[-1])
        sent = self._sent
        if answered:
            # Every answer pops its command and every older one.
            sent.clear()
            self._unanswered.clear()
            self._last_feedback = int(times[-1])
            self._last_fault, self._foreign = None, 0
            return
        for stamp in times[-RECENT_COMMANDS:].tolist():
            self._sent_command(stamp)

    def tick(self, now: int) -> list[Output]:
        """The command for ``now``: injected volume and signed flow (and any state change)."""
        if self.autostart and not self._started and self.state == IDLE:
            self._start(now)
        if self.state == RUNNING and not self.open_loop and self._feedback_lost(now):
            self._pause(now)
            self._enter(now, 'silent', timeout=self.feedback_timeout_s, why=self._silent_why())
        if self.mode == SETPOINT:
            return self._follow_setpoint(now)
        run_time = self.run_time_s(now)
        volume, programme_flow = self.profile.command_at(run_time)
        if self._frozen_volume is not None:
            volume = self._frozen_volume
        flow = 0.0
        if self.state == RUNNING:
            if volume > self.max_injected_m3:
                self._frozen_volume = volume = self.max_injected_m3
                self._stop(now, 'end_stop', limit=self.max_injected_m3)
            elif run_time >= self.duration_s:
                self._pause(now)
                self._enter(now, 'finished')
            else:
                flow = programme_flow
        self.volume_m3 = volume
        return self._command(now, volume, flow)

    def _follow_setpoint(self, now: int) -> list[Output]:
        """The command for ``now`` in setpoint mode: a step towards the setpoint since the last."""
        last, self._last_tick = self._last_tick, now
        volume, flow = self.volume_m3, 0.0
        setpoint = self.setpoint
        step_s = max(0, now - last) * 1e-9 if last is not None else 0.0
        if self.state == RUNNING and setpoint is not None and step_s > 0.0:
            moved = self._setpoint_step(setpoint, volume, step_s)
            if moved > self.max_injected_m3:
                moved = self.volume_m3 = self.max_injected_m3
                self._stop(now, 'end_stop', limit=self.max_injected_m3)
            flow = (moved - volume) / step_s if self.state == RUNNING else 0.0
            volume = moved
        self.volume_m3 = volume
        return self._command(now, volume, flow)

    def _setpoint_step(self, setpoint: PumpSetpoint, here: float, step_s: float) -> float:
        """Where a setpoint takes the syringe in ``step_s`` from ``here`` [m^3]."""
        if setpoint.injected_m3 is not None:
            reach = self.profile.flow_rate * step_s
            target = setpoint.injected_m3
            return min(target, here + reach) if target >= here else max(target, here - reach)
        # An empty syringe gives nothing back: the flow stops at 0 injected.
        return max(0.0, here + setpoint.flow_m3_per_s * step_s)

    def _command_value(self, now: int, volume: float, flow: float) -> PumpCommand:
        """The command a tick sends: the syringe's volume and flow."""
        return PumpCommand(now, volume, flow)

    def _command(self, now: int, volume: float, flow: float) -> list[Output]:
        """
        The tick's outputs: its command, unless a pump at rest would only repeat itself.

        The first command at a volume is said twice: a listener that takes the rate of the
        last two commands as the pump's (an actuator in time does) learns at once that the
        pump stands, instead of a heartbeat later.
        """
        last = self._last_command
        if self.state != RUNNING and not self._out and last is not None and self._settled \
                and (volume, flow) == self._last_values \
                and now - last.stamp_ns < HEARTBEAT_S * 1e9:
            return []
        self._settled = last is not None and volume == self._last_values[0]
        self._sent_command(now)
        command = self._last_command = self._command_value(now, volume, flow)
        self._last_values = (volume, flow)
        self._out.append(command)
        return self._take()
