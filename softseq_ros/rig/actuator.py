"""
The actuator's core: the segments' response to the pump's commanded volume, through a model.

Each :class:`PumpCommand` goes to the actuator's model (softseq_ros.rig.model: the quasi-static
equilibrium by default, whose jump rule makes a dropped command harmless). The outputs the
``outputs`` set lists go out stamped with the command's stamp (the state at the commanded
instant, so a listener pairs them exactly): pressure (absolute: gauge +
``ambient_pressure_pa``), volumes (with the gauge pressure), curvatures, the channel flows
of a model with channels, and one :class:`SnapThrough` per snap (with its duration when the
model lives it in time). The model's warnings (a channel no longer laminar) go to the log.
A model whose state moves between commands (one with a ``rate_hz``) is advanced by
:meth:`ActuatorCore.tick`, whose outputs carry the tick's time.

At start (:meth:`begin`) it says once which scene's segments it runs (name, segment names,
the SHA-256 of their definitions), on a latched topic, so every recording can name its physics.

Resume: a restarted actuator must stay on the branch its history put it on (hysteresis).
While :attr:`waiting` (the driver looks for a previous state), commands are buffered and
answered in order once the wait ends (:meth:`end_wait`). ``state_file`` (None: off; the
actuator node gives one in the ROS home by default) makes the core write its state there,
atomically, and :meth:`resume_from_file` read it back. It writes a change at once when the last
write is ``save_period_s`` old or more, else the driver's next :meth:`flush_state` writes the
newest state: a write costs a millisecond or more (the rename), more than an answer, so an
actuator commanded at kilohertz writes ten times a second, not at every command; a ``kill -9``
loses at most the last ``save_period_s`` of state, and a resume from it walks to the next
command through the volumes in between (the jump rule). A clean stop
(:meth:`close`) writes the last state once more with ``"closed": true``: only an actuator that
ended abnormally (a crash, ``kill -9``) is resumed, loudly; after a clean stop the next run
starts at rest, as one experiment after another must. The flag is written into the file, not
by removing or renaming it, so the last state stays readable where the user expects it and
one atomic replace marks both the state and how the run ended.

Bad commands (NaN, negative, volumes outside the segment models) are refused with a throttled
warning; the state stays where it was.
"""

from collections import deque
import json
import math
import os
from pathlib import Path
import time
from typing import Callable

import numpy as np

from softseq_ros.rig.model import (
    ActuatorModel,
    CommandBlock,
    CommandRefusedError,
    Snap,
    TimedSnap,
)
from softseq_ros.rig.throttle import Throttle
from softseq_ros.segments.identity import segments_sha256
from softseq_ros.wire import contract
from softseq_ros.wire.values import (
    INFO,
    WARNING,
    ChannelFlows,
    Notice,
    Output,
    Pressure,
    PumpCommand,
    SceneIdentity,
    SegmentCurvatures,
    SegmentVolumes,
    SnapThrough,
)

ACTUATOR_OUTPUTS = ('pressure', 'volumes', 'curvature', 'events', 'flows')
# Commands kept while waiting for a previous state (the newest; older ones are skipped, and
# the jump rule walks through them): as many as the command queue holds.
MAX_BUFFERED_COMMANDS = contract.PUMP_COMMAND.qos.depth
# The state file is written at most this often (and always at a clean stop).
STATE_SAVE_PERIOD_S = 0.1


class ActuatorCore:
    """The actuator's model driven by the commanded injected volume, its state as outputs."""

    role = contract.ACTUATOR

    def __init__(self, model: ActuatorModel, names: tuple[str, ...], *,
                 outputs: frozenset[str] = frozenset(ACTUATOR_OUTPUTS),
                 ambient_pressure_pa: float = contract.DEFAULT_AMBIENT_PRESSURE_PA,
                 state_file: Path | None = None, scene_name: str = '',
                 save_period_s: float = STATE_SAVE_PERIOD_S,
                 save_clock: Callable[[], int] = time.monotonic_ns) -> None:
        """
        An actuator at rest; ``outputs`` are scene output names (others are ignored).

        ``save_clock`` (ns) times the state file's writes, ``save_period_s`` apart at most.
        """
        self.model = model
        self.rate_hz = model.rate_hz
        self.names = tuple(names)
        self.scene_name = scene_name
        # The digest of the segments (and supply line) the model runs: what this actuator is.
        # A model of the segments alone need not say its members.
        self.segments_sha256 = segments_sha256(getattr(model, 'members', model.segments))
        # The channel flows go with the volumes, for a model with channels (none: no topic).
        derived = {'flows'} if model.channel_names and \
            contract.DERIVED_OUTPUTS['flows'] in outputs else set()
        self.outputs = frozenset(name for name in outputs if name in ACTUATOR_OUTPUTS) | derived
        self.ambient_pressure_pa = ambient_pressure_pa
        self.state_file = state_file
        self._state_folder_made = False
        self.save_period_ns = int(save_period_s * 1e9)
        self._save_clock = save_clock
        self._last_save_ns: int | None = None
        self._unsaved = False
        self.state_writes = 0
        self.rejected_commands = 0
        self.skipped_while_waiting = 0
        self.waiting = False
        self._buffered: deque[tuple[PumpCommand, int]] = deque()
        self._throttle = Throttle()
        self._send_pressure = 'pressure' in self.outputs
        self._send_volumes = 'volumes' in self.outputs
        self._send_curvatures = 'curvature' in self.outputs
        self._send_events = 'events' in self.outputs
        self._send_flows = 'flows' in self.outputs

    def begin(self, now: int) -> list[Output]:
        """What the actuator says once at start: which scene's segments it runs."""
        return [SceneIdentity(now, self.scene_name, self.names, self.segments_sha256)]

    def announce(self, now: int) -> list[Output]:
        """
        The state now, said before any command is answered (a node says it once at start).

        On the latched volumes topic, so a controller or camera started first, or later, sees
        where the actuator is (at rest, or where it resumed) before the pump moves.
        """
        return self._outputs(now, [])

    # ---------------------------------------------------------------- commands

    def handle(self, value: PumpCommand, now: int) -> list[Output]:
        """Move to the commanded injected volume; the outputs of that state."""
        if self.waiting:
            if len(self._buffered) == MAX_BUFFERED_COMMANDS:
                # The oldest goes unanswered; the answer to a newer one walks through it.
                self._buffered.popleft()
                self.skipped_while_waiting += 1
            self._buffered.append((value, now))
            return []
        if value.regulated:
            return self._handle_pressure(value, now)
        if getattr(self.model, 'command_pressure', None) is not None:
            return self.refuse('supply', f'command refused: injected volume '
                                         f'{value.injected_m3:.6g} m^3, and the supply is a '
                                         'pressure regulator, driven by a target gauge pressure '
                                         '(joint regulator, effort)')
        injected = value.injected_m3
        if not math.isfinite(injected):
            return self.refuse('finite', f'command refused: injected volume {injected} is '
                                         'not finite')
        if injected < 0.0:
            return self.refuse('negative', f'command refused: injected volume {injected:.6g} '
                                           'm^3 is negative')
        # An unstamped command gets the driver's time.
        stamp = value.stamp_ns or now
        return self._answer(stamp, self.model.command, injected)

    def _answer(self, stamp: int, command: Callable[[float, int], list[Snap] | None],
                value: float) -> list[Output]:
        """The model's answer to ``command(value, stamp)``, or the refusal, as outputs."""
        try:
            snaps = command(value, stamp)
        except CommandRefusedError as err:
            # The model keeps the state it had.
            return self.refuse('domain', f'command refused: {err}')
        # A repeated command changes nothing: the same numbers go out with the new stamp.
        outputs = self._outputs(stamp, snaps or [])
        if snaps is not None and self.state_file is not None:
            self._changed(outputs)
        return outputs

    def _handle_pressure(self, value: PumpCommand, now: int) -> list[Output]:
        """A regulator's target gauge pressure: every segment held there (a regulated model)."""
        gauge = value.gauge_pa
        command_pressure = getattr(self.model, 'command_pressure', None)
        if command_pressure is None:
            return self.refuse('supply', f'command refused: target gauge pressure {gauge:.6g} '
                                         "Pa, and this actuator's supply is a syringe, driven "
                                         'by volume (joint syringe, position)')
        if not math.isfinite(gauge):
            return self.refuse('finite', f'command refused: target gauge pressure {gauge} is '
                                         'not finite')
        return self._answer(value.stamp_ns or now, command_pressure, gauge)

    def preview(self, injected_m3: 'np.ndarray') -> 'CommandBlock | None':
        """
        The answers to a block of commands (one after another) as arrays, without answering.

        The states of the commands :meth:`handle` would answer with pressure, volumes and
        curvatures only (no refusal, snap-through, note or warning), up to the first that is
        not such (``count``); :meth:`commit` then takes them as handled.

        None when this actuator answers one command at a time only (a model without blocks,
        a state file, a wait for a previous state, outputs beyond those three).
        """
        preview = getattr(self.model, 'preview', None)
        if preview is None or self.waiting or self.state_file is not None \
                or self._send_flows or not injected_m3.size:
            return None
        plain = np.isfinite(injected_m3) & (injected_m3 >= 0.0)
        count = int(np.argmin(plain)) if not plain.all() else plain.size
        return preview(injected_m3[:count]) if count else None

    def commit(self, block: 'CommandBlock', count: int) -> None:
        """Take the first ``count`` commands of a :meth:`preview` as handled."""
        self.model.commit(block, count)

    def tick(self, now: int) -> list[Output]:
        """Let the model's time run to ``now``; outputs only when its state moved."""
        if self.waiting:
            return []
        try:
            snaps = self.model.advance(now)
        except CommandRefusedError as err:
            # Time alone carried the model out of its range (a transient past a segment's
            # curve): the state stays at its last good instant, and the log says why.
            return self.refuse('domain', f'state held: {err}')
        if snaps is None:
            return []
        outputs = self._outputs(now, snaps)
        if self.state_file is not None:
            self._changed(outputs)
        return outputs

    def finish(self, now: int) -> list[Output]:
        """
        The run ends at ``now``: the exchange of fluid paused or still under way is said.

        A batch run's time stops with its pump; an exchange it would not see end is published
        cut short (``cut_short``), so the bag does not hide fluid moving at its end.
        """
        # A model of one's own from before the seam asked for it may have no finish.
        finish = getattr(self.model, 'finish', None)
        if self.waiting or finish is None:
            return []
        try:
            snaps = finish(now)
        except CommandRefusedError as err:
            return self.refuse('domain', f'state held: {err}')
        return self._events(now, snaps)

    def refuse(self, key: str, text: str) -> list[Output]:
        """Count a refused command and warn (throttled per kind of refusal)."""
        self.rejected_commands += 1
        admitted = self._throttle.admit(key, text)
        return [] if admitted is None else [Notice(self.role, WARNING, admitted)]

    def _outputs(self, stamp: int, snaps: list[Snap]) -> list[Output]:
        state = self.model.state()
        pressure = state.pressure
        out: list[Output] = []
        if self._send_pressure:
            out.append(Pressure(stamp, pressure + self.ambient_pressure_pa))
        if self._send_volumes:
            out.append(SegmentVolumes(stamp, self.names, state.volumes, pressure))
        if self._send_curvatures:
            out.append(SegmentCurvatures(stamp, self.names, state.curvatures))
        if self._send_flows:
            flows, drops = self.model.channel_state()
            out.append(ChannelFlows(stamp, self.model.channel_names, flows, drops))
        out += self._events(stamp, snaps)
        for line in self.model.take_notes():
            out.append(Notice(self.role, INFO, line))
        for line in self.model.take_warnings():
            out.append(Notice(self.role, WARNING, line))
        return out

    def _events(self, stamp: int, snaps: list[Snap]) -> list[Output]:
        """Each snap-through or exchange: its log line, and its event when events are sent."""
        out: list[Output] = []
        for snap in snaps:
            event = SnapThrough(stamp, float(snap.injected),
                                [float(v) for v in snap.from_volumes],
                                [float(v) for v in snap.to_volumes],
                                float(snap.from_pressure), float(snap.to_pressure))
            said = f'snap-through at {snap.injected * 1e6:.4f} mL injected'
            if isinstance(snap, TimedSnap):
                event.snap_through = bool(snap.snap_through)
                event.peak_ns = snap.peak_ns
                if snap.cut_short:
                    event.cut_short = True
                if not snap.snap_through:
                    said = f'exchange of fluid at {snap.injected * 1e6:.4f} mL injected'
                event.start_ns = snap.start_ns
                event.duration_s = float(snap.duration_s)
                event.fluid_moved_m3 = float(snap.fluid_moved_m3)
                event.peak_exchange_m3_per_s = float(snap.peak_exchange_m3_per_s)
                event.giving_segments = list(snap.giving)
                event.taking_segments = list(snap.taking)
                said += (f', {snap.fluid_moved_m3 * 1e6:.3f} mL moved from '
                         f'{" and ".join(snap.giving) or "-"} to '
                         f'{" and ".join(snap.taking) or "-"} in {snap.duration_s:.3g} s '
                         '(10-90 %)')
                if snap.cut_short:
                    said += ', still under way when the run ended'
            out.append(Notice(self.role, INFO, said))
            if self._send_events:
                out.append(event)
        return out

    # ---------------------------------------------------------------- state

    @property
    def volumes(self) -> list[float]:
        """The segments' volumes [m^3] now."""
        return self.model.state().volumes

    def set_ambient_pressure(self, ambient_pa: float) -> None:
        """Change the ambient pressure added to the gauge pressure."""
        self.ambient_pressure_pa = ambient_pa

    def close(self) -> list[Output]:
        """
        Mark the state file closed (a clean stop): the next start is at rest, not resumed.

        Written also when nothing changed in this run, so that a run that resumed and then
        stopped cleanly leaves a closed file; not while still :attr:`waiting`, when the model
        holds no state of its own yet and the file the last run left is still to be read.
        """
        outputs: list[Output] = []
        if self.state_file is not None and not self.waiting:
            self._save(outputs, closed=True)
        return outputs

    def _changed(self, outputs: list[Output]) -> None:
        """The state changed: write it now, or at the next flush when the last write is recent."""
        now = self._save_clock()
        last = self._last_save_ns
        if last is None or now - last >= self.save_period_ns:
            self._save(outputs)
        else:
            self._unsaved = True

    def flush_state(self) -> list[Output]:
        """Write a state not yet written (the driver calls this every ``save_period_s``)."""
        outputs: list[Output] = []
        if self._unsaved and self.state_file is not None:
            self._save(outputs)
        return outputs

    def _save(self, outputs: list[Output], closed: bool = False) -> None:
        """Write the state atomically, so a kill mid-write leaves the previous one."""
        self._unsaved = False
        self._last_save_ns = self._save_clock()
        self.state_writes += 1
        data = json.dumps({'names': list(self.names), 'segments_sha256': self.segments_sha256,
                           **self.model.saved(), 'closed': closed})
        temporary = self.state_file.with_name(self.state_file.name + '.tmp')
        try:
            if not self._state_folder_made:
                self.state_file.parent.mkdir(parents=True, exist_ok=True)
                self._state_folder_made = True
            temporary.write_text(data, encoding='utf-8')
            os.replace(temporary, self.state_file)
        except OSError as err:
            admitted = self._throttle.admit('state_file', f'state_file {self.state_file}: '
                                                          f'cannot write ({err.strerror})')
            if admitted is not None:
                outputs.append(Notice(self.role, WARNING, admitted))

    # ---------------------------------------------------------------- resume

    def begin_wait(self) -> None:
        """Buffer commands until :meth:`end_wait` (the driver looks for a previous state)."""
        self.waiting = True

    def end_wait(self, now: int) -> list[Output]:
        """Stop waiting; answer the buffered commands in order."""
        self.waiting = False
        buffered, self._buffered = self._buffered, deque()
        out: list[Output] = []
        for command, received in buffered:
            out.extend(self.handle(command, received))
        return out

    def resume_from(self, names: list[str], volumes: list[float],
                    source: str) -> tuple[bool, list[Output]]:
        """Resume on the branch nearest ``volumes``; (False, a warning) when unusable."""
        if list(names) != list(self.names) or not all(math.isfinite(v) for v in volumes):
            return False, [Notice(self.role, WARNING,
                                  f'{source} does not fit this scene (segments {list(names)}, '
                                  f'expected {list(self.names)}); not resuming from it')]
        injected = sum(volumes) - self.model.rest_volume_m3
        try:
            self.model.resume(injected, volumes)
        except CommandRefusedError as err:
            return False, [Notice(self.role, WARNING, f'{source}: cannot resume ({err})')]
        return True, [Notice(self.role, INFO,
                             f'resumed from {source} at {injected * 1e6:.4f} mL injected')]

    def resume_from_file(self) -> tuple[bool, list[Output]]:
        """
        Resume from ``state_file`` when the last run there ended abnormally and its state fits.

        A closed file (the last run stopped cleanly) gives (False, []): a start at rest needs
        no word. A resume is a warning naming the file, the volume and how to start at rest.
        """
        if self.state_file is None or not self.state_file.is_file():
            return False, []
        try:
            saved = json.loads(self.state_file.read_text(encoding='utf-8'))
            if saved.get('closed') is True:
                return False, []
            names, volumes = list(saved['names']), [float(v) for v in saved['volumes_m3']]
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as err:
            return False, [Notice(self.role, WARNING, f'state_file {self.state_file}: '
                                                      f'unreadable ({err}); starting at rest')]
        written_for = saved.get('segments_sha256')
        if written_for is not None and written_for != self.segments_sha256:
            # Same segment names, other curves: the saved volumes mean nothing here.
            return False, [Notice(self.role, WARNING, f'state_file {self.state_file} was '
                                  f'written for other segments (sha256 {str(written_for)[:12]}, '
                                  f'these are {self.segments_sha256[:12]}); starting at rest')]
        resumed, notices = self.resume_from(names, volumes, f'state_file {self.state_file}')
        if resumed:
            # Loud: a resumed state is physics the user did not ask for in this run.
            notices = [Notice(self.role, WARNING, f'{notice.text}: the last run there did not '
                              'stop cleanly (crash or kill); to start at rest instead, delete '
                              f'{self.state_file} or start with --ros-args -p "state_file:=\'\'"')
                       for notice in notices]
        return resumed, notices
