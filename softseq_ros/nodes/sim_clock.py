"""
Simulated clock: publishes /clock with sim time running ``speedup`` times faster than wall time.

Nodes started with ``-p use_sim_time:=true`` follow it. Sim time is computed from the wall clock
at every tick (``start_s + speedup * wall time since start``), so it never drifts with timer
jitter. The defaults (100x, 1000 ticks per wall second, i.e. sim steps of 0.1 s) run the
paper's 2610 s programme in about 26 s; a node's timer can fire at most once per clock tick, so
a 50 Hz pump under this clock publishes every 0.1 s of sim time. /clock uses the QoS rclpy's
TimeSource subscribes with (best effort, depth 1).

The batch runner (``softseq run``) needs no clock: it steps the rig's cores on its own.
"""

import time
from typing import Any, Callable

from rclpy.node import Parameter
from rosgraph_msgs.msg import Clock

from softseq_ros.nodes.core_node import qos_profile
from softseq_ros.nodes.parameters import NodeConfigError, ParameterNode
from softseq_ros.nodes.runner import run_node
from softseq_ros.wire.contract import CLOCK


class SimClockNode(ParameterNode):
    """Publishes /clock at ``rate_hz`` wall ticks per second, ``speedup`` x wall time."""

    NODE_NAME = 'sim_clock'

    def __init__(self, *, wall_ns: Callable[[], int] | None = None, **kwargs: Any) -> None:
        """Declare parameters and start the clock; ``wall_ns`` replaces time.monotonic_ns."""
        super().__init__(self.NODE_NAME, **kwargs)
        if self.get_parameter('use_sim_time').value:
            raise NodeConfigError('use_sim_time: must be false for the sim_clock node itself '
                                  '(it would wait for its own /clock)')
        self.rate_hz = self.declare_number(
            'rate_hz', 1000.0, 'Clock messages per wall second [Hz].', minimum=0.0,
            open_minimum=True, maximum=10000.0)
        self.speedup = self.declare_number(
            'speedup', 100.0, 'Sim seconds per wall second.', minimum=0.0, open_minimum=True,
            maximum=1.0e6)
        # The largest second a builtin_interfaces/Time carries (int32), by far enough.
        start_s = self.declare_number('start_s', 0.0, 'Sim time at start [s].', minimum=0.0,
                                      maximum=float(2 ** 31 - 1), read_only=True)
        self._wall_ns = wall_ns or time.monotonic_ns
        self._origin_wall = self._wall_ns()
        self._origin_sim = int(round(start_s * 1e9))
        self.sim_ns = self._origin_sim
        self._clock_msg = Clock()
        self._publisher = self.create_publisher(Clock, CLOCK.name, qos_profile(CLOCK.qos))
        self._timer = self.create_timer(1.0 / self.rate_hz, self.tick)
        self.configured = True

    def tick(self) -> None:
        """Advance the sim time to match the wall clock and publish it."""
        elapsed = self._wall_ns() - self._origin_wall
        self.sim_ns = self._origin_sim + int(elapsed * self.speedup)
        stamp = self._clock_msg.clock
        stamp.sec, stamp.nanosec = divmod(self.sim_ns, 1_000_000_000)
        self._publisher.publish(self._clock_msg)

    def _parameters_changed(self, parameters: list[Parameter]) -> None:
        for parameter in parameters:
            if parameter.name == 'rate_hz':
                self.rate_hz = float(parameter.value)
                self._timer.timer_period_ns = int(round(1e9 / self.rate_hz))
            elif parameter.name == 'speedup':
                # Re-anchor so that the sim time stays continuous across the change.
                wall = self._wall_ns()
                self._origin_sim = self._origin_sim + int(
                    (wall - self._origin_wall) * self.speedup)
                self._origin_wall = wall
                self.speedup = float(parameter.value)


def main(args: list[str] | None = None) -> None:
    """Run the sim clock node."""
    run_node(SimClockNode, args)


if __name__ == '__main__':
    main()
