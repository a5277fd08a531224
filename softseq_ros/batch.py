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
import os
from pathlib import Path
import time
from typing import Any, Callable, TextIO

from softseq_ros.bag.forms import offered_qos_yaml, qos_profile_dict
from softseq_ros.bag.writer import BagWriter
from softseq_ros.errors import UserError
from softseq_ros.progress import is_terminal, write_progress
from softseq_ros.rig.build import actuator_core, camera_core, pump_core
from softseq_ros.rig.model import ActuatorModel
from softseq_ros.rig.routing import Router
from softseq_ros.scene.loader import Scene, load_scene
from softseq_ros.scene.programme import (
    MAX_RUN_BYTES,
    MAX_RUN_MESSAGES,
    MAX_RUN_S,
    longest_part,
)
from softseq_ros.stopping import HeldSignals
from softseq_ros.wire import contract
from softseq_ros.wire.contract import NS_PER_S
from softseq_ros.wire.payloads import ENCODERS
from softseq_ros.wire.values import ERROR, TOPIC_VALUE_TYPES, WARNING, Notice

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


# The stages a ``wrap`` hook of :func:`run` sees, by label.
STAGES = ('pump.tick', 'pump.handle', 'actuator.tick', 'actuator.handle',
          'actuator.model.command', 'camera.tick', 'camera.handle', 'encode', 'append')


class _BatchRun:
    """One lock-step run of a scene into a bag directory (what :func:`run` builds and runs)."""

    def __init__(self, scene: 'Scene | str | os.PathLike', out: str | os.PathLike, *,
                 overrides: dict[str, dict[str, Any]] | None = None,
                 progress: TextIO | None = None, log: TextIO | None = None,
                 start_time_ns: int | None = None, namespace: str = '/',
                 wrap: Callable[[str, Stage], Stage] | None = None,
                 model: ActuatorModel | None = None, allow_long: bool = False) -> None:
        """
        Load the scene (unless given loaded) and build the cores; ``out`` must not exist.

        A run longer than :data:`~softseq_ros.scene.programme.MAX_RUN_S` of rig time, or whose
        bag would hold more than ``MAX_RUN_MESSAGES`` messages or ``MAX_RUN_BYTES`` bytes, is
        refused here (LongRunError), before anything is written, unless ``allow_long``.
        """
        self.scene = scene if isinstance(scene, Scene) else load_scene(scene)
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
        self.outputs = self.actuator.outputs | self.camera.outputs
        self.progress = progress
        self.log = log
        self.namespace = namespace
        self.start_time_ns = time.time_ns() if start_time_ns is None else int(start_time_ns)
        self._now_ns = self.start_time_ns
        self._check_length(allow_long)
        if wrap is not None:
            self._wrap_cores(wrap)
        self._router = Router(self.cores, lambda: self._now_ns)
        self._channels: dict[type, _Channel] = {}
        self.warnings: list[str] = []

    def estimate(self) -> tuple[float, float]:
        """About how many messages and bytes the run's bag will hold (from rates and sizes)."""
        duration = self.pump.duration_s
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
        duration = profile.duration()
        where = f'{self.scene.path or self.scene.name}: '
        insist = 'shorten the programme, or insist with --allow-long (allow_long=True)'
        if duration > MAX_RUN_S and not allow_long:
            raise LongRunError(f'{where}the programme runs {duration:.3g} s of rig time, more '
                               f'than {MAX_RUN_S:.0e} s ({longest_part(profile, "pump.")}): '
                               f'{insist}')
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
                setattr(core, method, wrap(f'{role}.{method}', getattr(core, method)))
        model = self.actuator.model
        model.command = wrap('actuator.model.command', model.command)

    def run(self) -> BatchResult:
        """Run the scene's pump programme to its end; the bag is complete on return."""
        wall_start = time.perf_counter()
        # A stop signal ends the run between two steps, never inside a chunk being written.
        with HeldSignals() as held, BagWriter(self.out, flush_period_s=None) as writer:
            self._open_channels(writer)
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
            if not contract.enabled(topic, self.outputs):
                continue
            name = contract.resolve(topic.name, self.namespace)
            writer.add_topic(name, topic.type_name, qos_yaml(topic.qos))
            encode, append = ENCODERS[kind], writer.appender(name)
            if self.wrap is not None:
                encode, append = self.wrap('encode', encode), self.wrap('append', append)
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
        duration = pump.duration_s
        next_report = wall_start + PROGRESS_PERIOD_S
        # The actuator names its scene first, then the pump gives its status.
        self._record(router.run(self.actuator.begin(start) + pump.begin(start)))
        while True:
            clock = min(clocks)
            now, _, core, period = clock
            # A stop acts only between two instants: every core due at the last one has
            # ticked, so the bag holds the whole of each instant it reached, as a run that goes
            # on holds it (a stop between the pump's and the camera's tick of one instant
            # would leave that instant's frame out).
            if stop_signals and now > self._now_ns:
                held.check()
            self._now_ns = now
            self._record(router.run(core.tick(now)))
            clock[0] = now + period
            if core is pump and pump.state in ('finished', 'stopped'):
                # Every other core shows the last state once more, at the pump's last instant.
                for other in clocks:
                    if other is not clock:
                        self._record(router.run(other[2].tick(now)))
                return
            if self.progress is not None and time.perf_counter() >= next_report:
                next_report += PROGRESS_PERIOD_S
                self._report(wall_start, duration)

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
        model: ActuatorModel | None = None, allow_long: bool = False) -> BatchResult:
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
    counts it). The stages and their labels are in :data:`STAGES`.

    A run longer than :data:`~softseq_ros.scene.programme.MAX_RUN_S` of rig time, or whose bag
    would hold more than ``MAX_RUN_MESSAGES`` messages or ``MAX_RUN_BYTES`` bytes, is refused
    before anything is written (LongRunError), unless ``allow_long``.
    """
    return _BatchRun(scene, out, overrides=overrides, progress=progress, log=log,
                     start_time_ns=start_time_ns, namespace=namespace, wrap=wrap, model=model,
                     allow_long=allow_long).run()


__all__ = ['STAGES', 'BatchResult', 'LongRunError', 'qos_yaml', 'run']
