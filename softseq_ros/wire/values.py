"""
The typed values the rig's cores take and give: one class per topic of the contract, plus notices.

A core never sees a ROS message: a node adapter turns received messages into these values and
the values a core returns into CDR bytes (:mod:`softseq_ros.wire.payloads`), the batch runner
writes those same bytes into a bag, and the one-process rig hands the values straight from core
to core. Each class names its topic (``topic``), so routing needs no parallel table. Times are
nanoseconds on the driver's clock (ROS time, sim time or the batch runner's clock).
"""

from dataclasses import dataclass
import math
from typing import ClassVar

import numpy as np

from softseq_ros.wire import contract
from softseq_ros.wire.contract import Topic


@dataclass(slots=True)
class PumpCommand:
    """
    The syringe's commanded injected volume [m^3] and signed flow [m^3/s].

    Behind a pressure regulator (a scene whose supply is one) the command is its target gauge
    pressure ``gauge_pa`` [Pa] instead, and the volume and flow are NaN: a regulator sets the
    pressure, the segments take the fluid it needs (:attr:`regulated`).
    """

    topic: ClassVar[Topic] = contract.PUMP_COMMAND
    stamp_ns: int
    injected_m3: float
    flow_m3_per_s: float
    gauge_pa: float | None = None

    @property
    def regulated(self) -> bool:
        """A regulator's target pressure, not a syringe's volume."""
        return self.gauge_pa is not None


def regulator_command(stamp_ns: int, gauge_pa: float) -> PumpCommand:
    """A regulator's command: its target gauge pressure [Pa] at ``stamp_ns``."""
    return PumpCommand(stamp_ns, math.nan, math.nan, gauge_pa)


@dataclass(slots=True)
class PumpSetpoint:
    """
    A controller's setpoint for the pump, one of three (None: not given).

    A target injected volume [m^3], a signed flow [m^3/s] or a target gauge pressure [Pa].
    """

    topic: ClassVar[Topic] = contract.PUMP_SETPOINT
    stamp_ns: int
    injected_m3: float | None = None
    flow_m3_per_s: float | None = None
    gauge_pa: float | None = None

    @property
    def kind(self) -> str:
        """'volume', 'flow' or 'pressure': which field it gives."""
        if self.injected_m3 is not None:
            return 'volume'
        return 'flow' if self.flow_m3_per_s is not None else 'pressure'

    @property
    def value(self) -> float:
        """The number it gives, in SI units."""
        given = (self.injected_m3, self.flow_m3_per_s, self.gauge_pa)
        return next(value for value in given if value is not None)


@dataclass(slots=True)
class PumpStatus:
    """The pump's state (idle, running, held, finished, stopped) and why, since ``stamp_ns``."""

    topic: ClassVar[Topic] = contract.PUMP_STATUS
    stamp_ns: int
    state: str
    reason: str = ''

    @property
    def text(self) -> str:
        """``state`` or ``state: reason``, as logs show it."""
        return f'{self.state}: {self.reason}' if self.reason else self.state


@dataclass(slots=True)
class Pressure:
    """The actuator's fluid pressure, absolute [Pa] (gauge + ambient, as FluidPressure has it)."""

    topic: ClassVar[Topic] = contract.PRESSURE
    stamp_ns: int
    absolute_pa: float


@dataclass(slots=True)
class SegmentVolumes:
    """Each segment's volume [m^3] base to tip, and the common gauge pressure [Pa]."""

    topic: ClassVar[Topic] = contract.VOLUMES
    stamp_ns: int
    names: tuple[str, ...]
    volumes_m3: list[float]
    gauge_pa: float


@dataclass(slots=True)
class SegmentCurvatures:
    """Each segment's curvature [1/m], base to tip."""

    topic: ClassVar[Topic] = contract.CURVATURES
    stamp_ns: int
    names: tuple[str, ...]
    curvatures_per_m: list[float]


@dataclass(slots=True)
class ChannelFlows:
    """Each channel's flow [m^3/s] (positive towards the tip) and pressure drop [Pa]."""

    topic: ClassVar[Topic] = contract.CHANNEL_FLOWS
    stamp_ns: int
    names: tuple[str, ...]
    flows_m3_per_s: list[float]
    drops_pa: list[float]


@dataclass(slots=True)
class SnapThrough:
    """
    A snap-through at ``injected_m3``: from one state to another (gauge pressures).

    An exchange in time (the dynamic model: every exchange of fluid between the segments,
    docs/dynamic.md) says more: when it started (``start_ns``), how long it took
    (``duration_s``, 10 % to 90 % of the fluid moved), the fluid it moved between the segments,
    its peak exchange flow, which segments gave the fluid and which took it
    (``giving_segments``, ``taking_segments``: names, base to tip), and whether it was a
    snap-through (``snap_through``: the state passed where the equilibrium is unstable; an
    exchange in time without the key, from an older bag, was one) and when its exchange
    peaked (``peak_ns``); None for a quasi-static one (instantaneous, always a snap-through).
    ``cut_short`` is True when the run ended while the exchange was still under way (its
    numbers are those up to the run's end), and absent otherwise.
    """

    topic: ClassVar[Topic] = contract.EVENTS
    stamp_ns: int
    injected_m3: float
    from_volumes_m3: list[float]
    to_volumes_m3: list[float]
    from_pressure_pa: float
    to_pressure_pa: float
    start_ns: int | None = None
    duration_s: float | None = None
    fluid_moved_m3: float | None = None
    peak_exchange_m3_per_s: float | None = None
    giving_segments: list[str] | None = None
    taking_segments: list[str] | None = None
    snap_through: bool | None = None
    peak_ns: int | None = None
    cut_short: bool | None = None


@dataclass(slots=True)
class SceneIdentity:
    """The scene the actuator runs: its name, segment names and the segments' SHA-256."""

    topic: ClassVar[Topic] = contract.SCENE
    stamp_ns: int
    scene: str
    segments: tuple[str, ...]
    segments_sha256: str

    def names(self) -> tuple[str, tuple[str, ...], str]:
        """What tells one scene from another (not when it was said)."""
        return self.scene, tuple(self.segments), self.segments_sha256

    def as_dict(self) -> dict:
        """The identity as metrics.json holds it."""
        return {'scene': self.scene, 'segments': list(self.segments),
                'segments_sha256': self.segments_sha256, 'stamp_ns': self.stamp_ns}


@dataclass(slots=True)
class Backbone:
    """A camera frame: poses (M, 7) as (x, y, z, qx, qy, qz, qw) in ``softseq_base``."""

    topic: ClassVar[Topic] = contract.BACKBONE
    stamp_ns: int
    poses: np.ndarray


@dataclass(slots=True)
class Snapshot:
    """The backbone at a trigger crossing (one of the paper's steps)."""

    topic: ClassVar[Topic] = contract.SNAPSHOTS
    stamp_ns: int
    poses: np.ndarray


@dataclass(slots=True)
class SnapshotStep:
    """Which trigger a snapshot belongs to: 1-based ``step``, its volume and the direction."""

    topic: ClassVar[Topic] = contract.SNAPSHOT_STEPS
    stamp_ns: int
    step: int
    trigger_injected_m3: float
    direction: str           # 'inflation' or 'deflation'
    injected_m3: float       # the injected volume of the state shown


@dataclass(slots=True)
class Markers:
    """One line per segment: its points (K, 3) in ``softseq_base``."""

    topic: ClassVar[Topic] = contract.MARKERS
    stamp_ns: int
    lines: list[np.ndarray]


@dataclass(slots=True)
class SideImage:
    """An rgb8 side view of the actuator."""

    topic: ClassVar[Topic] = contract.IMAGE
    stamp_ns: int
    width: int
    height: int
    rgb: bytes


INFO = 'info'
WARNING = 'warning'
ERROR = 'error'


@dataclass(slots=True)
class Notice:
    """A line for the log of the node hosting ``source`` (a core role); not a topic."""

    topic: ClassVar[Topic | None] = None
    source: str
    level: str
    text: str


TOPIC_VALUE_TYPES = (PumpCommand, PumpSetpoint, PumpStatus, Pressure, SegmentVolumes,
                     SegmentCurvatures, ChannelFlows, SnapThrough, SceneIdentity, Backbone,
                     Snapshot, SnapshotStep, Markers, SideImage)
TopicValue = (PumpCommand | PumpSetpoint | PumpStatus | Pressure | SegmentVolumes
              | SegmentCurvatures | ChannelFlows | SnapThrough | SceneIdentity | Backbone
              | Snapshot | SnapshotStep | Markers | SideImage)
Output = TopicValue | Notice
