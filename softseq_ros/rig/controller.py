"""
An example controller on the rig: a PI hold of the actuator's gauge pressure, by flow setpoints.

It reads ``actuator/volumes`` (effort: the gauge pressure the actuator computed) and answers
each new state with a flow setpoint on ``pump/setpoint``:

    q = K (e + I / T_i),   e = p_target - p,   I = integral of e dt

clamped to +-``max_flow_m3_per_s``. The integral grows only while the flow is not clamped (or
while the error pulls it back inside), so a long fill at the clamp does not wind it up. Under
volume control the pump integrates the flow and the actuator's stiffness k = dp/dV turns it into
pressure, so the loop is dp/dt = k q: with the loop gain k K and T_i = 1 / (k K) ... 4 / (k K)
it settles without ringing. The defaults suit the paper's segments near 5 kPa, where k is about
285 Pa/mL: k K = 2 /s, T_i = 2 s (critically damped), a fill at 2 mL/s.

Nothing here imports rclpy: the node (softseq_ros.nodes.pressure_hold) and the batch runner
host the same core. The pump must be in setpoint mode for its setpoints to count
(softseq_ros.rig.pump).
"""

import math

from softseq_ros.rig.throttle import Throttle
from softseq_ros.wire import contract
from softseq_ros.wire.values import WARNING, Notice, Output, PumpSetpoint, SegmentVolumes

DEFAULT_TARGET_GAUGE_PA = 5.0e3
DEFAULT_GAIN_M3_PER_S_PER_PA = 7.0e-9
DEFAULT_INTEGRAL_TIME_S = 2.0
DEFAULT_MAX_FLOW_M3_PER_S = 2.0e-6


class PressureHold:
    """The PI pressure hold: ``handle(SegmentVolumes, now)`` gives a flow setpoint."""

    role = contract.CONTROLLER

    def __init__(self, target_gauge_pa: float = DEFAULT_TARGET_GAUGE_PA, *,
                 gain_m3_per_s_per_pa: float = DEFAULT_GAIN_M3_PER_S_PER_PA,
                 integral_time_s: float = DEFAULT_INTEGRAL_TIME_S,
                 max_flow_m3_per_s: float = DEFAULT_MAX_FLOW_M3_PER_S,
                 active: bool = True) -> None:
        """
        Hold ``target_gauge_pa``; ``active`` False stays silent until :attr:`active` is set.

        Raises ValueError naming the setting that is not a finite number in its range.
        """
        for name, value, low in (('target_gauge_pa', target_gauge_pa, -math.inf),
                                 ('gain_m3_per_s_per_pa', gain_m3_per_s_per_pa, 0.0),
                                 ('integral_time_s', integral_time_s, 0.0),
                                 ('max_flow_m3_per_s', max_flow_m3_per_s, 0.0)):
            if not (math.isfinite(value) and value > low):
                raise ValueError(f'{name}: must be a finite number above {low:g}, got {value!r}')
        self.target_gauge_pa = float(target_gauge_pa)
        self.gain = float(gain_m3_per_s_per_pa)
        self.integral_time_s = float(integral_time_s)
        self.max_flow_m3_per_s = float(max_flow_m3_per_s)
        self.active = active
        self.integral_pa_s = 0.0
        self.last_gauge_pa: float | None = None
        self.last_flow_m3_per_s = 0.0
        self._last_stamp: int | None = None
        self._throttle = Throttle()

    def handle(self, value: SegmentVolumes, now: int) -> list[Output]:
        """A flow setpoint for a new actuator state (none for an old, unusable or muted one)."""
        if type(value) is not SegmentVolumes or not self.active:
            return []
        gauge, stamp = value.gauge_pa, value.stamp_ns
        if not math.isfinite(gauge):
            said = self._throttle.admit('gauge', f'{contract.VOLUMES.name}: gauge pressure '
                                                 f'{gauge} is no measurement; no setpoint sent')
            return [] if said is None else [Notice(self.role, WARNING, said)]
        last, self._last_stamp = self._last_stamp, stamp
        if last is not None and stamp <= last:
            self._last_stamp = last
            return []      # a state older than one already used: the loop has moved on
        step_s = 0.0 if last is None else (stamp - last) * 1e-9
        error = self.target_gauge_pa - gauge
        integral = self.integral_pa_s + error * step_s
        flow = self.gain * (error + integral / self.integral_time_s)
        limit = self.max_flow_m3_per_s
        clamped = min(max(flow, -limit), limit)
        if clamped == flow or (flow > clamped) != (error > 0.0):
            self.integral_pa_s = integral
        else:
            clamped = min(max(self.gain * (error + self.integral_pa_s / self.integral_time_s),
                              -limit), limit)
        self.last_gauge_pa = gauge
        self.last_flow_m3_per_s = clamped
        return [PumpSetpoint(now, flow_m3_per_s=clamped)]
