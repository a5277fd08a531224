"""
Actuator node: the segments' quasi-static response to the pump's commanded volume.

Each /pump/command moves the equilibrium tracker (``Tracker.step``) to the commanded injected
volume. The tracker's jump rule makes a dropped command harmless: a jump lands where a walk
through every volume in between lands. The node publishes the outputs the ``outputs`` parameter
lists (default: the scene's): /actuator/pressure (absolute: gauge + ``ambient_pressure_pa``),
/actuator/volumes (position = volumes, effort = gauge pressure per segment),
/actuator/curvatures, and one JSON object per snap-through on /actuator/events. A command equal
to the previous one is not solved again: the cached messages go out with the new stamp.

Resume: a restarted actuator must stay on the branch its history put it on (hysteresis). On
start it waits up to ``resume_timeout_s`` for the last /actuator/volumes (transient_local) from a
live publisher and resumes on the branch nearest those volumes. A DDS writer's history dies with
its process, so after a crash nobody may hold that message; ``state_file`` (a path, default off)
makes the node also write its state there after every change (atomically) and read it when no
message arrives. Commands that arrive while waiting are applied in order afterwards.

Bad commands (NaN, negative, a name count other than one, volumes outside the segment models)
are refused with a throttled warning; the state stays where it was.
"""

import json
import math
import os
from pathlib import Path
import time
from typing import Any

from rclpy.clock import Clock, ClockType
from rclpy.node import Parameter
from sensor_msgs.msg import FluidPressure, JointState
from std_msgs.msg import String

from softseq_ros.nodes.common import (
    DEFAULT_AMBIENT_PRESSURE_PA,
    OUTPUT_TOPICS,
    TOPICS,
    RigNode,
    outputs_reason,
    run_node,
    stamp_ns,
)
from softseq_ros.physics.equilibrium import DomainError, EquilibriumMap, Tracker

ACTUATOR_OUTPUTS = ('pressure', 'volumes', 'curvature', 'events')
RESUME_POLL_S = 0.02
MAX_BUFFERED_COMMANDS = 100_000


class ActuatorNode(RigNode):
    """Tracks the equilibrium of the scene's segments under the commanded injected volume."""

    NODE_NAME = 'actuator'

    def __init__(self, **kwargs: Any) -> None:
        """Declare parameters, assemble the equilibrium map and start (or resume)."""
        super().__init__(self.NODE_NAME, **kwargs)
        scene = self.declare_scene()
        outputs = self.declare_texts(
            'outputs', sorted(scene.outputs), 'Outputs to publish (scene output names); the '
            'actuator serves pressure, volumes, curvature and events.', read_only=True,
            check=outputs_reason)
        self.ambient_pressure_pa = self.declare_number(
            'ambient_pressure_pa', DEFAULT_AMBIENT_PRESSURE_PA,
            'Added to the gauge pressure on /actuator/pressure [Pa].', minimum=0.0)
        self.resume_timeout_s = self.declare_number(
            'resume_timeout_s', 1.0, 'How long to wait at start for the last /actuator/volumes '
            'to resume from [s]; 0 starts fresh at once.', minimum=0.0, maximum=60.0,
            read_only=True)
        state_file = self.declare_text(
            'state_file', '', 'File the state is written to after every change and resumed '
            'from when no /actuator/volumes arrives at start; empty: off.', read_only=True)
        self.state_file = Path(state_file) if state_file else None

        resolution = scene.solver.resolution
        self.emap = (EquilibriumMap(scene.segments, resolution=resolution) if resolution
                     else EquilibriumMap(scene.segments))
        self.tracker = Tracker(self.emap)
        self.names = list(scene.segment_names)
        n = len(self.names)
        self.outputs = frozenset(name for name in outputs if name in ACTUATOR_OUTPUTS)
        for name in sorted(self.outputs):
            for topic in OUTPUT_TOPICS[name]:
                self._make_publisher(topic)

        # Preallocated messages, filled in place at every command.
        self._pressure = FluidPressure(variance=0.0)
        self._volumes = JointState(name=self.names, position=[0.0] * n, effort=[0.0] * n)
        self._curvatures = JointState(name=self.names, position=[0.0] * n)
        self._event = String()
        # What goes out at every command, in this order.
        self._outgoing = [(topic, msg) for name, topic, msg in (
            ('pressure', '/actuator/pressure', self._pressure),
            ('volumes', '/actuator/volumes', self._volumes),
            ('curvature', '/actuator/curvatures', self._curvatures)) if name in self.outputs]
        self._last_command: float | None = None
        self._cached = False
        self.rejected_commands = 0
        self.solves = 0

        self._subscribe('/pump/command', self.on_pump_command)
        self._resuming = False
        self._buffered: list[JointState] = []
        if not self.batch_mode:
            self._begin_resume()
        self.configured = True

    # ---------------------------------------------------------------- resume

    def _begin_resume(self) -> None:
        """Listen for the last /actuator/volumes for resume_timeout_s (wall time)."""
        self._resuming = True
        self._resume_deadline = time.monotonic() + self.resume_timeout_s
        spec = TOPICS['/actuator/volumes']
        self._resume_subscription = self.create_subscription(
            spec.msg_type, '/actuator/volumes', self._on_resume_volumes, spec.qos)
        # Wall clock: with use_sim_time the ROS clock may not move until /clock arrives.
        self._resume_timer = self.create_timer(
            RESUME_POLL_S, self._resume_poll, clock=Clock(clock_type=ClockType.STEADY_TIME))

    def _on_resume_volumes(self, msg: JointState) -> None:
        if not self._resuming:
            return
        if self._resume_from(list(msg.name), list(msg.position), 'the last /actuator/volumes'):
            self._end_resume()

    def _resume_poll(self) -> None:
        if self._resuming and time.monotonic() >= self._resume_deadline:
            if not self._resume_from_file():
                self.log_info('no previous state found: starting at rest')
            self._end_resume()

    def _resume_from_file(self) -> bool:
        if self.state_file is None or not self.state_file.is_file():
            return False
        try:
            saved = json.loads(self.state_file.read_text(encoding='utf-8'))
            names, volumes = list(saved['names']), [float(v) for v in saved['volumes_m3']]
        except (OSError, ValueError, KeyError, TypeError) as err:
            self.log_warning(f'state_file {self.state_file}: unreadable ({err}); '
                                      'starting at rest')
            return False
        return self._resume_from(names, volumes, f'state_file {self.state_file}')

    def _resume_from(self, names: list[str], volumes: list[float], source: str) -> bool:
        """Resume on the branch nearest ``volumes``; False (and a warning) when unusable."""
        if names != self.names or not all(math.isfinite(v) for v in volumes):
            self.log_warning(f'{source} does not fit this scene (segments {names}, '
                                      f'expected {self.names}); not resuming from it')
            return False
        injected = sum(volumes) - self.emap.total_rest_volume
        try:
            self.resume(injected, volumes)
        except DomainError as err:
            self.log_warning(f'{source}: cannot resume ({err})')
            return False
        self.log_info(f'resumed from {source} at {injected * 1e6:.4f} mL injected')
        return True

    def _end_resume(self) -> None:
        self._resuming = False
        self.destroy_timer(self._resume_timer)
        # Destroyed before the first publication, so the node never hears itself.
        self.destroy_subscription(self._resume_subscription)
        buffered, self._buffered = self._buffered, []
        for msg in buffered:
            self.on_pump_command(msg)

    def resume(self, injected: float, volumes: list[float]) -> None:
        """Put the tracker at ``injected`` on the branch nearest ``volumes`` (a restart)."""
        self.tracker = Tracker(self.emap, injected=injected, volumes=volumes)
        self._last_command = None
        self._cached = False

    # ---------------------------------------------------------------- commands

    def on_pump_command(self, msg: JointState) -> None:
        """Move to the commanded injected volume and publish the outputs."""
        if self._resuming:
            if len(self._buffered) < MAX_BUFFERED_COMMANDS:
                self._buffered.append(msg)
            return
        injected = self._check_command(msg)
        if injected is None:
            return
        # The outputs describe the actuator at the commanded instant: they carry the command's
        # stamp, so any listener pairs them exactly (an unstamped command gets the node time).
        now = stamp_ns(msg.header) or self.now_ns()
        if self._cached and injected == self._last_command:
            self._send(now, ())
            return
        tracker = self.tracker
        branch, total = tracker.branch, tracker.total
        try:
            snaps = tracker.move(injected)
        except DomainError as err:
            # The tracker stops at the edge of its branch; keep the state as it was.
            tracker.branch, tracker.total = branch, total
            self._reject('domain', f'command refused: {err}')
            return
        self.solves += 1
        self._last_command = injected
        values = self.emap.values_at(tracker.branch, tracker.total)
        self._fill(values)
        self._send(now, snaps)
        if self.state_file is not None:
            self._save(injected, values)

    def _check_command(self, msg: JointState) -> float | None:
        if len(msg.name) != 1 or len(msg.position) != 1:
            self._reject('shape', f'command refused: expected one joint (syringe) with one '
                                  f'position, got names {list(msg.name)} and '
                                  f'{len(msg.position)} positions')
            return None
        if msg.name[0] != 'syringe':
            self._reject('name', f'command refused: joint name must be syringe, '
                                 f'got {msg.name[0]!r}')
            return None
        injected = float(msg.position[0])
        if not math.isfinite(injected):
            self._reject('finite', f'command refused: injected volume {injected} is not finite')
            return None
        if injected < 0.0:
            self._reject('negative', f'command refused: injected volume {injected:.6g} m^3 is '
                                     'negative')
            return None
        return injected

    def _reject(self, key: str, text: str) -> None:
        self.rejected_commands += 1
        self.warn_throttled(key, text)

    def _fill(self, values: list[float]) -> None:
        """Fill the outgoing messages from (v_1..v_N, p, k_1..k_N)."""
        n = len(self.names)
        pressure = values[n]
        self._pressure.fluid_pressure = pressure + self.ambient_pressure_pa
        volume, effort = self._volumes.position, self._volumes.effort
        curvature = self._curvatures.position
        for i in range(n):
            volume[i] = values[i]
            effort[i] = pressure
            curvature[i] = values[n + 1 + i]
        self._cached = True

    def _send(self, now: int, snaps: Any) -> None:
        outputs = self.outputs
        sec, nanosec = divmod(now, 1_000_000_000)
        for topic, msg in self._outgoing:
            stamp = msg.header.stamp
            stamp.sec, stamp.nanosec = sec, nanosec
            self._publish(topic, msg)
        if 'events' in outputs:
            for snap in snaps:
                self._event.data = json.dumps({
                    'injected_m3': float(snap.injected),
                    'from_volumes_m3': [float(v) for v in snap.from_volumes],
                    'to_volumes_m3': [float(v) for v in snap.to_volumes],
                    'from_pressure_pa': float(snap.from_pressure),
                    'to_pressure_pa': float(snap.to_pressure)})
                self.log_info(f'snap-through at {snap.injected * 1e6:.4f} mL injected')
                self._publish('/actuator/events', self._event)

    def _save(self, injected: float, values: list[float]) -> None:
        """Write the state atomically, so a kill mid-write leaves the previous one."""
        data = json.dumps({'names': self.names, 'injected_m3': injected,
                           'volumes_m3': values[:len(self.names)]})
        temporary = self.state_file.with_name(self.state_file.name + '.tmp')
        try:
            temporary.write_text(data, encoding='utf-8')
            os.replace(temporary, self.state_file)
        except OSError as err:
            self.warn_throttled('state_file', f'state_file {self.state_file}: cannot write '
                                              f'({err.strerror})')

    def _parameters_changed(self, parameters: list[Parameter]) -> None:
        for parameter in parameters:
            if parameter.name == 'ambient_pressure_pa':
                self.ambient_pressure_pa = float(parameter.value)
                self._cached = False


def main(args: list[str] | None = None) -> None:
    """Run the actuator node."""
    run_node(ActuatorNode, args)


if __name__ == '__main__':
    main()
