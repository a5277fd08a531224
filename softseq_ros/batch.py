"""
Batch runs: the rig's own nodes in one process, in lock-step simulated time, recorded to a bag.

The pump, actuator and camera nodes are built in batch mode (their ``emit`` and ``now`` hooks):
they create no publishers or timers, and this runner calls their ``tick()`` at their rates on a
simulated clock and hands every message they emit to the subscribers' handlers (by the rig's
routing table) and, serialised exactly as a publisher would, to the bag. No node logic is
repeated here and nothing goes through DDS, so a run is as fast as the machine allows and
deterministic: the same scene gives the same bag contents.
"""

from dataclasses import dataclass, field
import os
from pathlib import Path
import sys
import time
from typing import Any, Callable, TextIO

import rclpy
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from softseq_ros.bag.cdr import encoder_for
from softseq_ros.bag.writer import (
    BagWriter,
    message_type_name,
    offered_qos_yaml,
    qos_profile_dict,
    serialize,
)
from softseq_ros.nodes.actuator import ActuatorNode
from softseq_ros.nodes.camera import CameraNode
from softseq_ros.nodes.common import TOPICS, LocalRoutes
from softseq_ros.nodes.syringe_pump import SyringePumpNode
from softseq_ros.physics.scene import scene_path

NS_PER_S = 1_000_000_000
NODE_CLASSES = (SyringePumpNode, ActuatorNode, CameraNode)
PROGRESS_PERIOD_S = 0.25


@dataclass
class BatchResult:
    """What a batch run did: where the bag is, how long it took, what it recorded."""

    bag: Path
    sim_duration_s: float
    wall_s: float
    message_counts: dict[str, int] = field(default_factory=dict)
    pump_state: str = ''

    @property
    def speedup(self) -> float:
        """Simulated seconds per wall second."""
        return self.sim_duration_s / self.wall_s if self.wall_s > 0.0 else float('inf')


@dataclass(eq=False)
class _Channel:
    """A recorded topic of a run: how its messages are encoded, written and routed."""

    encode: Callable[[Any], bytes]
    append: Callable[[bytes, int, int], None]
    routed: bool
    count: int = 0


def qos_yaml(profile: QoSProfile) -> str:
    """A publisher's QoS as rosbag2 stores it in a bag's topic metadata."""
    return offered_qos_yaml([qos_profile_dict(
        depth=profile.depth,
        reliability=('reliable' if profile.reliability == ReliabilityPolicy.RELIABLE
                     else 'best_effort'),
        durability=('transient_local' if profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
                    else 'volatile'))])


class BatchRun:
    """One lock-step run of a scene; ``parameters`` override node parameters by node name."""

    def __init__(self, scene: str | os.PathLike, out: str | os.PathLike, *,
                 parameters: dict[str, list[Parameter]] | None = None,
                 progress: TextIO | None = None) -> None:
        """Resolve the scene; the bag directory ``out`` must not exist yet (or be empty)."""
        self.scene = scene_path(scene)
        self.out = Path(out)
        self.parameters = parameters or {}
        self.progress = progress
        self._now_ns = 0
        self._channels: dict[str, _Channel] = {}
        self._routes = LocalRoutes([cls.NODE_NAME for cls in NODE_CLASSES])

    def _now(self) -> int:
        return self._now_ns

    def run(self) -> BatchResult:
        """Run the scene's pump programme to its end; the bag is complete on return."""
        context = rclpy.Context()
        rclpy.init(context=context, args=[])
        nodes: dict[str, Any] = {}
        self.nodes = nodes  # the run's nodes by name, for inspection after the run
        wall_start = time.perf_counter()
        try:
            with BagWriter(self.out, flush_period_s=None) as writer:
                self._writer = writer
                common = {'context': context, 'emit': self._emit, 'now': self._now,
                              'start_parameter_services': False, 'enable_rosout': False}
                for cls in NODE_CLASSES:
                    overrides = [Parameter('scene', value=str(self.scene)),
                                 *self.parameters.get(cls.NODE_NAME, [])]
                    nodes[cls.NODE_NAME] = cls(parameter_overrides=overrides, **common)
                    self._routes.add(nodes[cls.NODE_NAME])
                self._loop(nodes['syringe_pump'], nodes['camera'], wall_start)
        finally:
            for node in nodes.values():
                node.destroy_node()
            rclpy.try_shutdown(context=context)
        wall = time.perf_counter() - wall_start
        if self.progress is not None:
            self.progress.write('\n' if _is_terminal(self.progress) else '')
        counts = {topic: channel.count for topic, channel in self._channels.items()}
        return BatchResult(self.out, self._now_ns / NS_PER_S, wall, counts,
                           nodes['syringe_pump'].state)

    def _loop(self, pump: SyringePumpNode, camera: CameraNode, wall_start: float) -> None:
        pump_period = round(NS_PER_S / pump.rate_hz)
        camera_period = round(NS_PER_S / camera.rate_hz)
        duration = pump.profile.duration()
        next_pump = next_camera = 0
        next_report = wall_start + PROGRESS_PERIOD_S
        while True:
            # The pump goes first at equal times: a frame shows the command of its instant.
            if next_pump <= next_camera:
                self._now_ns = next_pump
                pump.tick()
                self._routes.drain()
                next_pump += pump_period
                if pump.state in ('finished', 'stopped'):
                    camera.tick()
                    self._routes.drain()
                    return
            else:
                self._now_ns = next_camera
                camera.tick()
                self._routes.drain()
                next_camera += camera_period
            if self.progress is not None and time.perf_counter() >= next_report:
                next_report += PROGRESS_PERIOD_S
                self._report(wall_start, duration)

    def _open_topic(self, topic: str) -> '_Channel':
        spec = TOPICS[topic]
        type_name = message_type_name(spec.msg_type())
        self._writer.add_topic(topic, type_name, qos_yaml(spec.qos))
        return _Channel(encoder_for(type_name) or serialize, self._writer.appender(topic),
                        self._routes.carries(topic))

    def _emit(self, topic: str, msg: Any) -> None:
        channel = self._channels.get(topic)
        if channel is None:
            channel = self._channels[topic] = self._open_topic(topic)
        now = self._now_ns
        # A node may send a message already serialised (as rclpy's publish allows).
        channel.append(msg if type(msg) is bytes else channel.encode(msg), now, now)
        channel.count += 1
        if channel.routed:
            self._routes.send(topic, msg)

    def _report(self, wall_start: float, duration: float) -> None:
        sim = self._now_ns / NS_PER_S
        wall = time.perf_counter() - wall_start
        text = (f'{self.scene.stem}: {sim:8.1f} / {duration:.1f} s simulated '
                f'({100.0 * sim / max(duration, 1e-9):3.0f} %), {sim / max(wall, 1e-9):6.0f}x '
                'real time')
        if _is_terminal(self.progress):
            self.progress.write('\r' + text)
        else:
            self.progress.write(text + '\n')
        self.progress.flush()


def _is_terminal(stream: TextIO | None) -> bool:
    return bool(stream is not None and getattr(stream, 'isatty', lambda: False)())


def run_scene(scene: str | os.PathLike, out: str | os.PathLike,
              show_progress: bool = True) -> BatchResult:
    """Run a scene in batch mode into the bag directory ``out``."""
    return BatchRun(scene, out, progress=sys.stderr if show_progress else None).run()
