"""
Batch runs: the rig's cores in one process, in lock-step simulated time, recorded to a bag.

The pump, actuator and camera cores (softseq_ros.rig) are built from the scene as the nodes
build them; this runner ticks every core that has a rate (the pump, the camera, and the
actuator when its model moves between commands) on a simulated clock, routes every value to
the cores that consume it (softseq_ros.rig.routing) and writes each one, encoded exactly as the
nodes publish it (softseq_ros.wire.payloads), into the bag. No rclpy and no
DDS: a run is as fast as the machine allows and deterministic (the same scene and start time
give the same bag, byte for byte). The simulated clock starts at the run's start time (wall
clock, or ``start_time_ns`` for reproducible bags), so a batch bag is dated like a recording.
"""

from dataclasses import dataclass, field
import math
import os
from pathlib import Path
import time
from typing import Any, Callable, TextIO

import numpy as np

from softseq_ros.bag.forms import offered_qos_yaml, qos_profile_dict
from softseq_ros.bag.mcap_file import RowBlock, row_dtype
from softseq_ros.bag.writer import BagWriter
from softseq_ros.errors import UserError
from softseq_ros.progress import is_terminal, write_progress
from softseq_ros.rig.build import actuator_core, camera_core, pump_core
from softseq_ros.rig.model import ActuatorModel, CommandBlock, load_rig_scene
from softseq_ros.rig.pump import FINISHED, HELD, STOPPED
from softseq_ros.rig.routing import Router
from softseq_ros.scene.loader import Scene
from softseq_ros.scene.programme import (
    MAX_RUN_BYTES,
    MAX_RUN_MESSAGES,
    MAX_RUN_S,
    longest_part,
)
from softseq_ros.stopping import HeldSignals
from softseq_ros.wire import contract
from softseq_ros.wire.contract import NS_PER_S
from softseq_ros.wire.payloads import ENCODERS, row_layout
from softseq_ros.wire.values import (
    ERROR,
    TOPIC_VALUE_TYPES,
    WARNING,
    Backbone,
    Markers,
    Notice,
    Pressure,
    PumpCommand,
    SegmentCurvatures,
    SegmentVolumes,
    regulator_command,
)

PROGRESS_PERIOD_S = 0.25
# The last instant a bag can carry: its times are int64 nanoseconds (2262-04-11).
LAST_NS = 2**63 - 1
# Bytes a message takes in the bag besides what it carries (MCAP record, chunk, index), and
# per element of its arrays; for an estimate of the bag's size before a run, not its size.
_RECORD_BYTES = 80
_JOINT_BYTES = 48       # a JointState joint: name, position, velocity, effort
_POSE_BYTES = 56        # a Pose: position and orientation
_POINT_BYTES = 24       # a marker's point
_PIXEL_BYTES = 3        # rgb8


# How often in rig time the runner counts what it has written against MAX_RUN_MESSAGES.
COUNT_CHECK_NS = 10 * NS_PER_S


class LongRunError(UserError):
    """A run beyond the limits of a batch run (scene/programme.py), refused before it starts."""


@dataclass
class BatchResult:
    """What a batch run did: where the bag is, how long it took, what it recorded."""

    bag: Path
    sim_duration_s: float
    wall_s: float
    message_counts: dict[str, int] = field(default_factory=dict)
    pump_state: str = ''
    warnings: list[str] = field(default_factory=list)
    start_time_ns: int = 0

    @property
    def speedup(self) -> float:
        """Simulated seconds per wall second."""
        return self.sim_duration_s / self.wall_s if self.wall_s > 0.0 else float('inf')


def qos_yaml(qos: contract.Qos) -> str:
    """A contract QoS as rosbag2 stores a publisher's offer in a bag's topic metadata."""
    return offered_qos_yaml([qos_profile_dict(
        depth=qos.depth, reliability='reliable' if qos.reliable else 'best_effort',
        durability='transient_local' if qos.latched else 'volatile')])


@dataclass(eq=False)
class _Channel:
    """A recorded topic of a run: how its values are encoded and written."""

    topic: str
    encode: Callable[[Any], bytes]
    append: Callable[[bytes, int, int], None]
    count: int = 0


Stage = Callable[..., Any]


# The stages a ``wrap`` hook of :func:`run` sees, by label: first those of one message at a
# time, then those of a block of instants (BLOCK_STAGES).
STEP_STAGES = ('pump.tick', 'pump.handle', 'actuator.tick', 'actuator.handle',
               'actuator.model.command', 'camera.tick', 'camera.handle', 'encode', 'append')
BLOCK_STAGES = ('block.pump', 'block.actuator', 'block.camera', 'block.encode',
                'block.append')
STAGES = STEP_STAGES + BLOCK_STAGES
# Pump ticks a block holds at most, and at first (a block cut short starts small again).
MAX_BLOCK = 4096
FIRST_BLOCK = 64


class _Blocks:
    """
    The run's plain instants a block at a time: the same values, the same bag.

    Most instants of a run are plain: the pump commands the next volume of its programme,
    the actuator answers with its equilibrium (no snap-through, no refusal), the pump takes the
    answer as feedback and the camera takes the state (no trigger crossed) and, on its timer,
    a frame. For a block of pump ticks each core says how many of them are plain
    (``PumpCore.plan``, ``ActuatorCore.preview``, ``PumpCore.trusted``,
    ``CameraCore.plain_states``) with the same numbers as one instant after another; those
    are committed to the cores, encoded per topic in bulk (softseq_ros.wire.payloads.RowLayout)
    and written as rows of records (ChunkedMcapWriter.add_rows), message for message and byte
    for byte what the per-message path writes. The first instant that is not plain (a start,
    a snap-through, a snapshot, the programme's end) goes through the per-message path.
    """

    def __init__(self, run: '_BatchRun', writer: BagWriter,
                 wrap: Callable[[str, Stage], Stage] | None) -> None:
        self.run = run
        pump, actuator, camera = run.pump, run.actuator, run.camera
        channel_ids, self.add_rows = writer.row_writer()
        channels = run._channels
        names = actuator.names
        n = len(names)
        self.names = names
        self.size = FIRST_BLOCK
        self.ambient = actuator.ambient_pressure_pa
        # What the actuator answers with, by its outputs (as it decides itself).
        self.volumes_sent = 'volumes' in actuator.outputs
        self.curvatures_sent = 'curvature' in actuator.outputs
        # The topics of a pump instant: its command, then the answers (as the actuator
        # sends them); of a camera instant: backbone, then markers.
        # A regulator's command is its target pressure alone (softseq_ros.rig.regulator).
        self.regulated = pump.regulated
        command = regulator_command(0, 0.0) if pump.regulated else PumpCommand(0, 0.0, 0.0)
        samples = [(command, True),
                   (Pressure(0, 0.0), 'pressure' in actuator.outputs),
                   (SegmentVolumes(0, names, [0.0] * n, 0.0), self.volumes_sent),
                   (SegmentCurvatures(0, names, [0.0] * n), self.curvatures_sent)]
        points = np.zeros((camera.n_points, 3))
        frame_samples = [(Backbone(0, np.zeros((camera.n_points, 7))), 'poses'),
                         (Markers(0, [points[a:b] for a, b in camera.marker_lines]), 'markers')]
        self.slots = self._slots(samples, channels, channel_ids)
        self.frame_slots = self._slots([(value, output in camera.outputs)
                                        for value, output in frame_samples],
                                       channels, channel_ids)
        self.line_rows = camera.marker_lines
        stage = wrap or (lambda _label, function: function)
        self.plan = stage('block.pump', pump.plan)
        self.preview = stage('block.actuator', actuator.preview)
        self.plain_states = stage('block.camera', camera.plain_states)
        self.frames = stage('block.camera', camera.frames)
        self.encode = stage('block.encode', self._encode)
        self.append = stage('block.append', self.add_rows)

    @staticmethod
    def _slots(samples: list, channels: dict, channel_ids: dict[str, int]) -> list:
        slots = []
        for value, sent in samples:
            channel = channels.get(type(value))
            if sent and channel is not None:
                slots.append((type(value), row_layout(value), channel,
                              channel_ids[channel.topic]))
        return slots

    @staticmethod
    def usable(run: '_BatchRun') -> bool:
        """Whether the run's cores take blocks (else every instant goes one at a time)."""
        actuator, camera = run.actuator, run.camera
        return (getattr(actuator.model, 'preview', None) is not None
                and actuator.rate_hz is None and actuator.state_file is None
                and 'flows' not in actuator.outputs and camera.frame_trigger == 'timer'
                and not camera.image_wanted)

    def step(self, clocks: list) -> bool:
        """
        Run a block of plain instants from the pump's next tick on.

        False when the next instant is not plain: the caller runs it one core at a time.
        """
        run = self.run
        pump_clock = clocks[0]
        start, period = pump_clock[0], pump_clock[3]
        times = start + period * np.arange(self.size, dtype=np.int64)
        count, volumes, flows = self.plan(times, self.volumes_sent)
        block = self.preview(volumes) if count else None
        if block is not None:
            count = block.count
            answers = block.volumes[:count]
            if count and self.volumes_sent:
                count = min(count, run.pump.trusted(self.names, answers, block.pressure[:count]))
            below = None
            if count and (self.volumes_sent or self.curvatures_sent):
                seen, below = self.plain_states(
                    self.names, block.volumes[:count] if self.volumes_sent else None,
                    block.curvatures[:count] if self.curvatures_sent else None)
                count = min(count, seen)
        if not count or block is None:
            self.size = FIRST_BLOCK
            return False
        self.size = min(2 * self.size, MAX_BLOCK) if count == times.size else FIRST_BLOCK
        times, volumes, flows = times[:count], volumes[:count], flows[:count]
        last = int(times[-1])
        # The camera's frames up to the last instant, each of the state at its time.
        camera_clock = next((clock for clock in clocks if clock[2] is run.camera), None)
        frame_times = np.empty(0, dtype=np.int64)
        frame_rows = np.empty(0, dtype=np.intp)
        if camera_clock is not None and camera_clock[0] <= last:
            frame_times = np.arange(camera_clock[0], last + 1, camera_clock[3], dtype=np.int64)
            camera_clock[0] = int(frame_times[-1]) + camera_clock[3]
            frame_rows = np.searchsorted(times, frame_times, side='right') - 1
        camera = run.camera
        frame_states = None
        if frame_times.size and self.curvatures_sent:
            frame_states = block.curvatures[frame_rows]
            if camera.held_curvatures is not None:
                frame_states[frame_rows < 0] = camera.held_curvatures
            else:
                frame_times, frame_rows = frame_times[frame_rows >= 0], \
                    frame_rows[frame_rows >= 0]
                frame_states = frame_states[-frame_times.size:] if frame_times.size else None
        run.pump.commit_plan(times, volumes, answered=self.volumes_sent)
        run.actuator.commit(block, count)
        camera.commit_states(times, block.curvatures[:count] if self.curvatures_sent else None,
                             below)
        poses = (self.frames(frame_times, frame_states) if frame_states is not None
                 else None)
        self.append(self.encode(times, volumes, flows, block, count, frame_times, frame_rows,
                                poses))
        pump_clock[0] = last + period
        run._now_ns = last
        return True

    def _encode(self, times: np.ndarray, volumes: np.ndarray, flows: np.ndarray,
                block: CommandBlock, count: int, frame_times: np.ndarray,
                frame_rows: np.ndarray, poses: np.ndarray | None) -> list[RowBlock]:
        """The rows of records of a block's instants: one per pump instant, one per frame."""
        n = len(self.names)
        values = {PumpCommand: [volumes] if self.regulated else [volumes, flows],
                  Pressure: [block.pressure[:count] + self.ambient],
                  SegmentVolumes: [block.volumes[:count],
                                   np.repeat(block.pressure[:count, None], n, axis=1)],
                  SegmentCurvatures: [block.curvatures[:count]]}
        parts = [self._rows(self.slots, times, values, 2 * np.arange(count))]
        if poses is not None and self.frame_slots:
            lines = [np.ascontiguousarray(poses[:, a:b, :3]) for a, b in self.line_rows]
            values = {Backbone: [poses], Markers: lines}
            parts.append(self._rows(self.frame_slots, frame_times, values,
                                    2 * frame_rows + 1))
        return parts

    @staticmethod
    def _rows(slots: list, times: np.ndarray, values: dict, keys: np.ndarray) -> RowBlock:
        rows = np.empty(times.size, dtype=row_dtype([layout.dtype for _, layout, _, _ in slots]))
        for index, (kind, layout, channel, _) in enumerate(slots):
            layout.fill(rows[f'p{index}'], times, values[kind])
            channel.count += times.size
        return RowBlock(rows, tuple(slot[3] for slot in slots),
                        tuple(slot[1].size for slot in slots), times, keys)


class _BatchRun:
    """One lock-step run of a scene into a bag directory (what :func:`run` builds and runs)."""

    def __init__(self, scene: 'Scene | str | os.PathLike', out: str | os.PathLike, *,
                 overrides: dict[str, dict[str, Any]] | None = None,
                 progress: TextIO | None = None, log: TextIO | None = None,
                 start_time_ns: int | None = None, namespace: str = '/',
                 wrap: Callable[[str, Stage], Stage] | None = None,
                 model: ActuatorModel | None = None, allow_long: bool = False,
                 by_blocks: bool = True, controller: Any = None,
                 controlled_s: float | None = None) -> None:
        """
        Load the scene (unless given loaded) and build the cores; ``out`` must not exist.

        ``by_blocks`` False runs every instant one core at a time (the reference the block
        path is checked against); blocks are also off when ``wrap`` changes a per-message
        stage (a hook that changes what a core does sees every call).

        A run longer than :data:`~softseq_ros.scene.programme.MAX_RUN_S` of rig time, or whose
        bag would hold more than ``MAX_RUN_MESSAGES`` messages or ``MAX_RUN_BYTES`` bytes, is
        refused here (LongRunError), before anything is written, unless ``allow_long``.
        """
        self.scene = scene if isinstance(scene, Scene) else load_rig_scene(scene)
        self.out = Path(out)
        self.wrap = wrap
        overrides = overrides or {}
        unknown = sorted(set(overrides) - set(contract.NODE_NAMES))
        if unknown:
            raise ValueError(f'overrides: unknown core(s) {", ".join(unknown)}; expected '
                             f'{", ".join(contract.NODE_NAMES)}')
        self.actuator = actuator_core(self.scene, model, **overrides.get(contract.ACTUATOR, {}))
        # The pump's feedback timeout runs on the simulated clock here (the actuator answers
        # within the same tick); without a volumes output there is no feedback to wait for.
        pump_settings = {'feedback_clock': None,
                         'open_loop': 'volumes' not in self.actuator.outputs,
                         **overrides.get(contract.PUMP, {})}
        self.pump, self.pump_rate_hz = pump_core(self.scene, self.actuator.model,
                                                  **pump_settings)
        self.camera = camera_core(self.scene, **overrides.get(contract.CAMERA, {}))
        self.cores = {contract.PUMP: self.pump, contract.ACTUATOR: self.actuator,
                      contract.CAMERA: self.camera}
        # A controller drives the pump by setpoints for ``controlled_s`` of rig time instead of
        # its programme; every value between them is routed like any other core's.
        if (controller is None) != (controlled_s is None):
            raise ValueError('controller and controlled_s go together: a controller drives '
                             'the pump for controlled_s seconds of rig time')
        if controlled_s is not None and not (math.isfinite(controlled_s) and controlled_s > 0):
            raise ValueError(f'controlled_s: must be a finite time > 0 s, got {controlled_s}')
        self.controlled_s = controlled_s
        if controller is not None:
            self.cores[contract.CONTROLLER] = controller
        self.outputs = self.actuator.outputs | self.camera.outputs
        self.progress = progress
        self.log = log
        self.namespace = namespace
        self.start_time_ns = time.time_ns() if start_time_ns is None else int(start_time_ns)
        self._now_ns = self.start_time_ns
        self.allow_long = allow_long
        self._next_count_check = self.start_time_ns
        self._check_length(allow_long)
        self._changed_stages = False
        if wrap is not None:
            self._wrap_cores(wrap)
        self._router = Router(self.cores, lambda: self._now_ns)
        self._channels: dict[type, _Channel] = {}
        self._blocks: _Blocks | None = None
        # Blocks of instants unless asked not to, a hook changes a per-message stage or a
        # controller reads every answer.
        self.by_blocks = by_blocks and not self._changed_stages and controller is None
        self.warnings: list[str] = []

    @property
    def duration_s(self) -> float:
        """The rig time the run lasts: the programme's, or the controller's."""
        return self.pump.duration_s if self.controlled_s is None else self.controlled_s

    def estimate(self) -> tuple[float, float]:
        """About how many messages and bytes the run's bag will hold (from rates and sizes)."""
        duration = self.duration_s
        segments = len(self.scene.segments)
        answers = self.pump_rate_hz + (self.actuator.rate_hz or 0.0)
        frames = self.camera.rate_hz or 0.0
        width, height = self.camera.image_size
        points = self.camera.points_per_segment * segments + 1
        # Per topic (relative name): messages per second and bytes per message. Topics that
        # publish once or per snap-through or trigger are too few to count.
        per_topic = {
            'pump/command': (self.pump_rate_hz, _JOINT_BYTES),
            'actuator/pressure': (answers, 0),
            'actuator/volumes': (answers, segments * _JOINT_BYTES),
            'actuator/curvatures': (answers, segments * _JOINT_BYTES),
            'actuator/channel_flows': (answers, (segments - 1) * _JOINT_BYTES),
            'camera/backbone': (frames, points * _POSE_BYTES),
            'camera/markers': (frames, points * _POINT_BYTES),
            'camera/image': (frames, width * height * _PIXEL_BYTES),
        }
        messages = size = 0.0
        for kind in TOPIC_VALUE_TYPES:
            if kind.topic.name in per_topic and contract.enabled(kind.topic, self.outputs):
                rate, payload = per_topic[kind.topic.name]
                messages += rate * duration
                size += rate * duration * (_RECORD_BYTES + payload)
        return messages, size

    def _check_length(self, allow_long: bool) -> None:
        profile = self.pump.profile  # the scene's, or the one an override gave
        duration = self.duration_s
        where = f'{self.scene.path or self.scene.name}: '
        insist = 'shorten the programme, or insist with --allow-long (allow_long=True)'
        if duration > MAX_RUN_S and not allow_long:
            part = 'pump.legs' if self.scene.regulator is not None else \
                longest_part(profile, 'pump.')
            raise LongRunError(f'{where}the programme runs {duration:.3g} s of rig time, more '
                               f'than {MAX_RUN_S:.0e} s ({part}): {insist}')
        if self.start_time_ns < 0 or self.start_time_ns + duration * NS_PER_S > LAST_NS:
            raise LongRunError(f'{where}start time {self.start_time_ns} ns plus the '
                               f"programme's {duration:.6g} s is outside what a bag can carry "
                               f'(int64 ns from 1970 to 2262)')
        if allow_long:
            return
        messages, size = self.estimate()
        if messages > MAX_RUN_MESSAGES or size > MAX_RUN_BYTES:
            rates = (f'pump.rate_hz {self.pump_rate_hz:g} Hz, camera.rate_hz '
                     f'{self.camera.rate_hz or 0:g} Hz, outputs {", ".join(sorted(self.outputs))}')
            raise LongRunError(f'{where}the bag would hold about {messages:.2g} messages, '
                               f'{size / 1e9:.3g} GB over {duration:.6g} s of rig time ({rates}), '
                               f'more than {MAX_RUN_MESSAGES:.0e} messages or '
                               f'{MAX_RUN_BYTES / 1e9:g} GB: lower the rates or drop outputs, '
                               f'{insist}')

    def _wrap_cores(self, wrap: Callable[[str, Stage], Stage]) -> None:
        # Instance attributes shadow the methods: the router and the loop call the wrappers.
        for role, core in self.cores.items():
            for method in ('tick', 'handle'):
                original = getattr(core, method)
                wrapped = wrap(f'{role}.{method}', original)
                self._changed_stages |= wrapped is not original
                setattr(core, method, wrapped)
        model = self.actuator.model
        original = model.command
        model.command = wrap('actuator.model.command', original)
        self._changed_stages |= model.command is not original

    def run(self) -> BatchResult:
        """Run the scene's pump programme to its end; the bag is complete on return."""
        wall_start = time.perf_counter()
        # A stop signal ends the run between two steps, never inside a chunk being written.
        with HeldSignals() as held, BagWriter(self.out, flush_period_s=None) as writer:
            self._open_channels(writer)
            if self.by_blocks and _Blocks.usable(self):
                self._blocks = _Blocks(self, writer, self.wrap)
            self._loop(wall_start, held)
        wall = time.perf_counter() - wall_start
        if self.progress is not None:
            self.progress.write('\n' if is_terminal(self.progress) else '')
        counts = {channel.topic: channel.count for channel in self._channels.values()}
        return BatchResult(self.out, (self._now_ns - self.start_time_ns) / NS_PER_S, wall,
                           counts, self.pump.state, self.warnings, self.start_time_ns)

    def _open_channels(self, writer: BagWriter) -> None:
        # Every topic the outputs switch on is in the bag, even one that gets no message
        # (a run without snap-throughs still has its events topic).
        for kind in TOPIC_VALUE_TYPES:
            topic = kind.topic
            if topic.producer not in self.cores or not contract.enabled(topic, self.outputs):
                continue
            name = contract.resolve(topic.name, self.namespace)
            writer.add_topic(name, topic.type_name, qos_yaml(topic.qos))
            encode, append = ENCODERS[kind], writer.appender(name)
            if self.wrap is not None:
                wrapped = self.wrap('encode', encode), self.wrap('append', append)
                self._changed_stages |= wrapped != (encode, append)
                encode, append = wrapped
            self._channels[kind] = _Channel(name, encode, append)

    def _record(self, values: list) -> None:
        channels = self._channels
        now = self._now_ns
        for value in values:
            channel = channels.get(type(value))
            if channel is not None:
                channel.append(channel.encode(value), now, now)
                channel.count += 1
            elif type(value) is Notice:
                self._notice(value)

    def _notice(self, notice: Notice) -> None:
        if notice.level in (WARNING, ERROR):
            line = f'{contract.NODE_NAMES.get(notice.source, notice.source)}: {notice.text}'
            self.warnings.append(line)
            if self.log is not None:
                # After a progress line that \r keeps rewriting, start on a line of its own.
                self.log.write(('\n' if is_terminal(self.progress) else '') + line + '\n')

    def _loop(self, wall_start: float, held: HeldSignals) -> None:
        pump, router = self.pump, self._router
        stop_signals = held.pending
        start = self.start_time_ns
        # [next tick, order, core, period] for every core with a rate. At equal times the pump
        # goes first (a frame shows the command of its instant), then the actuator's model.
        rates = ((pump, self.pump_rate_hz), (self.actuator, self.actuator.rate_hz),
                 (self.camera, self.camera.rate_hz))
        clocks = [[start, order, core, round(NS_PER_S / rate)]
                  for order, (core, rate) in enumerate(rates) if rate is not None]
        duration = self.duration_s
        end = None if self.controlled_s is None else start + round(duration * NS_PER_S)
        # A programme's pump finishes at the first tick past its duration: a run still going
        # two ticks later has a rig that no longer says where it is, and would never end.
        overdue = start + round(duration * NS_PER_S) + 2 * round(NS_PER_S / self.pump_rate_hz)
        next_report = wall_start + PROGRESS_PERIOD_S
        # The actuator names its scene first, then the pump gives its status.
        self._record(router.run(self.actuator.begin(start) + pump.begin(start)))
        if end is not None:
            self._record(router.run(pump.set_mode(start, True).outputs))
        blocks = self._blocks
        while True:
            clock = min(clocks)
            now, _, core, period = clock
            # A stop acts only between two instants: every core due at the last one has
            # ticked, so the bag holds the whole of each instant it reached, as a run that goes
            # on holds it (a stop between the pump's and the camera's tick of one instant
            # would leave that instant's frame out).
            if stop_signals and now > self._now_ns:
                held.check()
            if blocks is not None and core is pump and blocks.step(clocks):
                if self.progress is not None and time.perf_counter() >= next_report:
                    next_report = time.perf_counter() + PROGRESS_PERIOD_S
                    self._report(wall_start, duration)
                continue
            self._now_ns = now
            self._record(router.run(core.tick(now)))
            clock[0] = now + period
            over = self._over_limits(now, overdue if end is None else None) \
                if core is pump else None
            if core is pump and (pump.state in (FINISHED, STOPPED, HELD)
                                 or (end is not None and now >= end) or over):
                if over:
                    self._notice(Notice(contract.PUMP, WARNING, over))
                elif pump.state == HELD:
                    self._held_for_good()
                # Every other core shows the last state once more, at the pump's last instant.
                for other in clocks:
                    if other is not clock:
                        self._record(router.run(other[2].tick(now)))
                self._record(router.run(self.actuator.finish(now)))
                return
            if self.progress is not None and time.perf_counter() >= next_report:
                next_report += PROGRESS_PERIOD_S
                self._report(wall_start, duration)

    def _over_limits(self, now: int, overdue: int | None) -> str | None:
        """
        Why the run must end now though its pump has not finished, or None.

        The limits checked before the start hold while it runs too: rig time past the end of
        the programme, and (unless ``allow_long``) more messages than ``MAX_RUN_MESSAGES``.
        """
        if overdue is not None and now > overdue:
            rig_time = (now - self.start_time_ns) / NS_PER_S
            return (f'the pump had not finished its {self.duration_s:.6g} s programme at '
                    f'{rig_time:.6g} s of rig time ({self.pump.status}): the run ends here, '
                    'its bag complete up to now')
        if not self.allow_long and now >= self._next_count_check:
            self._next_count_check = now + COUNT_CHECK_NS
            written = sum(channel.count for channel in self._channels.values())
            if written > MAX_RUN_MESSAGES:
                return (f'the bag holds {written} messages, more than {MAX_RUN_MESSAGES:.0e}: '
                        'the run ends here, its bag complete up to now (insist with '
                        '--allow-long)')
        return None

    def _held_for_good(self) -> None:
        """
        Say why the run ends with its pump held: nothing in a batch run can start it again.

        A pump holds when its actuator stops answering (no pressure within its feedback
        timeout: a refused command, a state that is no number); on a rig an operator calls
        ``~/start``, in a batch run nobody can, and the rig would tick on forever.
        """
        self._notice(Notice(contract.PUMP, WARNING,
                            'the pump is held and nothing in a batch run starts it again: the '
                            'run ends here, its bag complete up to now'))

    def _report(self, wall_start: float, duration: float) -> None:
        sim = (self._now_ns - self.start_time_ns) / NS_PER_S
        wall = time.perf_counter() - wall_start
        text = (f'{self.scene.name}: {sim:8.1f} / {duration:.1f} s simulated '
                f'({100.0 * sim / max(duration, 1e-9):3.0f} %), {sim / max(wall, 1e-9):6.0f}x '
                'real time')
        write_progress(self.progress, text)


def run(scene: 'Scene | str | os.PathLike', out: str | os.PathLike, *,
        overrides: dict[str, dict[str, Any]] | None = None,
        progress: TextIO | None = None, log: TextIO | None = None,
        start_time_ns: int | None = None, namespace: str = '/',
        wrap: Callable[[str, Stage], Stage] | None = None,
        model: ActuatorModel | None = None, allow_long: bool = False,
        by_blocks: bool = True, controller: Any = None,
        controlled_s: float | None = None) -> BatchResult:
    """
    Run the rig (pump, actuator, camera) on the scene's programme into the bag ``out``.

    ``scene`` is a loaded :class:`Scene` (run as it is in memory: ``dataclasses.replace`` a
    part to change it) or a scene file or shipped name; ``out`` must not exist, and the bag is
    complete on return. The same cores as the ROS nodes, stepped on a simulated clock that
    starts at ``start_time_ns`` (default: now), so the same scene and start give the same bag.

    ``overrides`` replace core settings by role (``{'camera': {'rate_hz': 1.0}}``; the names of
    softseq_ros.rig.build). ``namespace`` is the rig's namespace in the bag's topic names.
    ``progress`` gets a progress line, ``log`` the cores' warnings (also kept in the result).
    ``model`` is the actuator's model (softseq_ros.rig.model; default: the one the scene asks
    for); one with a rate is advanced at that rate on the run's clock.

    ``wrap`` lets a benchmark or a profiler see every stage of the run without touching the
    runner: it is called once per stage as ``wrap(label, function)`` before anything is
    written and returns the function to call instead (the same one, or one that times or
    counts it). The stages and their labels are in :data:`STAGES`: those of one message at a
    time (:data:`STEP_STAGES`) and those of a block of instants (:data:`BLOCK_STAGES`).

    Most instants are run by blocks: the cores say how many of the next instants are plain
    (no start, snap-through, snapshot, refusal, stop or end among them), those are committed
    to the cores and encoded and written in bulk, with the same numbers and the same bag, byte
    for byte, as one message at a time; the other instants go one core at a time. A ``wrap``
    that changes a per-message stage (returns another function for it) makes every instant
    go one core at a time, so that it sees every call; ``by_blocks=False`` does so too (the
    reference the blocks are checked against). Blocks need the quasi-static model, a camera
    on its timer without the image and no state file; otherwise every instant goes one at a
    time.

    A run longer than :data:`~softseq_ros.scene.programme.MAX_RUN_S` of rig time, or whose bag
    would hold more than ``MAX_RUN_MESSAGES`` messages or ``MAX_RUN_BYTES`` bytes, is refused
    before anything is written (LongRunError), unless ``allow_long``.

    ``controller`` (a controller core, e.g. softseq_ros.rig.controller.PressureHold) drives
    the pump by its setpoints instead of the programme, for ``controlled_s`` seconds of rig
    time: the pump is put in setpoint mode at the start, the controller reads every answer of
    the actuator, and its setpoints are in the bag (``pump/setpoint``), every instant one core
    at a time.
    """
    return _BatchRun(scene, out, overrides=overrides, progress=progress, log=log,
                     start_time_ns=start_time_ns, namespace=namespace, wrap=wrap, model=model,
                     allow_long=allow_long, by_blocks=by_blocks, controller=controller,
                     controlled_s=controlled_s).run()


__all__ = ['BLOCK_STAGES', 'STAGES', 'STEP_STAGES', 'BatchResult', 'LongRunError', 'qos_yaml',
           'run']
