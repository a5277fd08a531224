"""
The camera's core: the actuator's backbone as a side camera sees it.

It keeps the latest segment curvatures and, at each frame, gives the backbone poses, one line
per segment for markers and (when wanted) an rgb8 side view. Pose convention (as
softseq_ros.segments.kinematics): the base is the origin, the unbent actuator points along +x
and bends in the x-z plane (y = 0). Each pose's position is a backbone point; its orientation
is the frame whose +x axis is the backbone tangent (cos theta, 0, sin theta), theta measured
from +x toward +z: a rotation by -theta about +y, quaternion (0, -sin(theta/2), 0,
cos(theta/2)). Positive curvature turns the backbone toward +z.

Frames come from the driver's timer (``frame_trigger='timer'``: :meth:`tick`, like a camera
that is not synchronised with the rig), or with ``frame_trigger='state'`` as soon as new
curvatures arrive (the lowest latency from a pump command to its pose), at most about
``rate_hz`` frames per second: a state that comes less than half a period after the last frame
is not drawn (the next one is).

``noise_std_m`` adds Gaussian noise [m] to the x and z of every published point (a pose
extraction error; fresh at every frame, from a generator seeded by ``seed``, so a run is
reproducible). Orientations and the rendered image are noise free.

Snapshots: the segment volumes give the injected volume (their sum minus the rest volumes).
Each time it crosses a value of ``triggers`` (either direction), the backbone of the state at
the first command past the trigger is a :class:`Snapshot`, followed by a :class:`SnapshotStep`
saying which trigger (1-based step), in which direction. The actuator stamps volumes and
curvatures of one command alike, so the snapshot waits for the curvatures carrying that stamp.
A trigger counts as reached within :data:`TRIGGER_SLACK` of the volume held (rest plus the
largest trigger): the sum of the volumes carries their round-off, and a pump stepping exactly
onto a trigger must have its snapshot at that step, whatever the last bits of the sum.
"""

from bisect import bisect_right
import math
from typing import Sequence

import numpy as np

from softseq_ros.rig.render import SideViewRenderer
from softseq_ros.rig.throttle import Throttle
from softseq_ros.segments.kinematics import PoseSampler, segment_end_indices
from softseq_ros.wire import contract
from softseq_ros.wire.values import (
    WARNING,
    Backbone,
    Markers,
    Notice,
    Output,
    SegmentCurvatures,
    SegmentVolumes,
    SideImage,
    Snapshot,
    SnapshotStep,
)

CAMERA_OUTPUTS = ('poses', 'markers', 'image')
# A trigger within this share of the volume held counts as reached (see the module's text).
TRIGGER_SLACK = 1e-9
FRAME_TRIGGERS = ('timer', 'state')


class CameraCore:
    """Backbone poses, markers, snapshots at trigger volumes and a side-view image."""

    role = contract.CAMERA

    def __init__(self, lengths: Sequence[float], rest_volume_m3: float, *,
                 rate_hz: float, outputs: frozenset[str] = frozenset(CAMERA_OUTPUTS),
                 frame_trigger: str = 'timer', noise_std_m: float = 0.0, seed: int = 0,
                 points_per_segment: int = 20, triggers: Sequence[float] = (),
                 image_size: tuple[int, int] = (640, 480),
                 segment_names: Sequence[str] | None = None) -> None:
        """
        A camera for segments of ``lengths`` [m] holding ``rest_volume_m3`` at rest.

        ``segment_names``: the segments, base to tip, a state must name (None: not checked).
        """
        if frame_trigger not in FRAME_TRIGGERS:
            raise ValueError(f'frame_trigger must be timer or state, got {frame_trigger!r}')
        self.rate_hz = rate_hz
        self.outputs = frozenset(name for name in outputs if name in CAMERA_OUTPUTS)
        self.frame_trigger = frame_trigger
        self.noise_std_m = noise_std_m
        self.triggers = list(triggers)
        self.lengths = np.asarray(lengths, dtype=float)
        self.rest_total = float(rest_volume_m3)
        self.n_segments = n = self.lengths.size
        self.points_per_segment = points_per_segment
        self.segment_ends = segment_end_indices(n, points_per_segment)
        self._sampler = PoseSampler(self.lengths, points_per_segment)
        self.n_points = self._sampler.n_points
        self._rng = np.random.default_rng(seed)
        width, height = image_size
        self.image_size = (width, height)
        self._renderer = SideViewRenderer(width, height,
                                          half_extent_m=1.05 * float(self.lengths.sum()))
        # Segment i's line runs from its start point to its end point (shared with the next).
        starts = [0, *self.segment_ends[:-1].tolist()]
        self._line_rows = [(a, b + 1) for a, b in zip(starts, self.segment_ends.tolist())]
        # Whether someone wants the image now; the driver keeps it up to date.
        self.image_wanted = 'image' in self.outputs
        self.images_rendered = 0
        self.segment_names = None if segment_names is None else tuple(segment_names)
        self.refused_states = 0   # states it could not use (another actuator's, NaN, a size)
        self._throttle = Throttle()

        self._curvatures: list[float] | None = None
        self._backbone_stale = False
        self._curvature_stamp = -1
        self._poses = np.zeros((self.n_points, 7))
        self._last_frame_ns: int | None = None
        self._watch_triggers = bool(self.triggers) and 'poses' in self.outputs
        self._triggers_below: int | None = None
        self._trigger_slack = TRIGGER_SLACK * (self.rest_total + max(map(abs, self.triggers),
                                                                     default=0.0))
        self._pending_stamp: int | None = None
        self._pending: list[tuple[int, str]] = []   # (0-based trigger, direction)
        self._pending_injected = 0.0

    # ---------------------------------------------------------------- inputs

    def _fault(self, names: Sequence[str], values: Sequence[float]) -> str | None:
        """What makes a state unusable (another actuator's joints, a size, a NaN), or None."""
        expected = self.segment_names
        if expected is not None and tuple(names) != expected:
            shown = list(names[:4]) + (['...'] if len(names) > 4 else [])
            return f'joints {shown} are not the segments {list(expected)}'
        if len(values) != self.n_segments:
            return f'{len(values)} values for {self.n_segments} segments'
        if not all(map(math.isfinite, values)):
            return 'a value that is not finite'
        return None

    def _refuse(self, key: str, text: str) -> list[Output]:
        """Count an unusable state and warn (throttled per kind); the last good one stays."""
        self.refused_states += 1
        admitted = self._throttle.admit(key, text)
        return [] if admitted is None else [Notice(self.role, WARNING, admitted)]

    def handle(self, value: SegmentCurvatures | SegmentVolumes, now: int) -> list[Output]:
        """Take new curvatures (maybe a frame) or volumes (maybe a trigger crossing)."""
        if type(value) is SegmentCurvatures:
            return self._on_curvatures(value, now)
        if type(value) is SegmentVolumes:
            return self._on_volumes(value, now)
        raise TypeError(f'the camera takes segment curvatures or volumes, not {value!r}')

    def _on_curvatures(self, value: SegmentCurvatures, now: int) -> list[Output]:
        curvatures = value.curvatures_per_m
        fault = self._fault(value.names, curvatures)
        if fault is not None:
            return self._refuse('curvatures', f'ignoring curvatures: {fault}')
        curvatures = list(curvatures)  # the sender may reuse its buffer
        if curvatures != self._curvatures:
            self._curvatures = curvatures
            # The backbone is computed when a frame or a snapshot needs it, not at the
            # actuator's rate: most curvature messages are never drawn.
            self._backbone_stale = True
        self._curvature_stamp = value.stamp_ns
        out: list[Output] = []
        if self._pending_stamp is not None and self._curvature_stamp >= self._pending_stamp:
            self._take_snapshots(now, out)
        if self.frame_trigger == 'state':
            last = self._last_frame_ns
            if last is None or now - last >= 500_000_000 / self.rate_hz:
                self._frame(now, out)
        return out

    def _on_volumes(self, value: SegmentVolumes, now: int) -> list[Output]:
        if not self._watch_triggers:
            return []   # the volumes serve the snapshots only
        volumes = value.volumes_m3
        fault = self._fault(value.names, volumes)
        if fault is None and min(volumes) < 0.0:
            fault = 'a negative volume'
        if fault is not None:
            return self._refuse('volumes', f'ignoring volumes: {fault}')
        injected = sum(volumes) - self.rest_total
        # Triggers at or below the injected volume: a crossing changes this count.
        below = bisect_right(self.triggers, injected + self._trigger_slack)
        previous, self._triggers_below = self._triggers_below, below
        if previous is None or below == previous:
            return []
        if below > previous:
            self._pending.extend((i, 'inflation') for i in range(previous, below))
        else:
            self._pending.extend((i, 'deflation') for i in range(previous - 1, below - 1, -1))
        self._pending_injected = injected
        stamp = value.stamp_ns
        if self._pending_stamp is None or stamp > self._pending_stamp:
            self._pending_stamp = stamp
        out: list[Output] = []
        if self._curvatures is not None and self._curvature_stamp >= self._pending_stamp:
            self._take_snapshots(now, out)
        return out

    def _update_backbone(self) -> None:
        if self._backbone_stale:
            self._poses = self._sampler.poses(self._curvatures)
            self._backbone_stale = False

    def _take_snapshots(self, now: int, out: list[Output]) -> None:
        self._update_backbone()
        poses = self._noisy_poses().copy()
        for index, direction in self._pending:
            out.append(Snapshot(now, poses))
            out.append(SnapshotStep(now, index + 1, self.triggers[index], direction,
                                    self._pending_injected))
        self._pending_stamp = None
        self._pending = []

    # ---------------------------------------------------------------- blocks of states

    @property
    def marker_lines(self) -> list[tuple[int, int]]:
        """Each segment's rows of the backbone's points, as its marker line holds them."""
        return self._line_rows

    @property
    def held_curvatures(self) -> list[float] | None:
        """The curvatures of the last state taken (None before the first): a frame shows them."""
        return self._curvatures

    def plain_states(self, names: Sequence[str], volumes: np.ndarray | None,
                     curvatures: np.ndarray | None) -> tuple[int, np.ndarray | None]:
        """
        How many states the camera takes without a word, a snapshot or a state's frame.

        States are rows: each state's volumes, then its curvatures, as :meth:`handle` takes
        them. Also the triggers below each (None when the volumes are not watched).

        A driver hands those to :meth:`commit_states` instead of :meth:`handle`, and takes
        the timer's frames with :meth:`frames`. 0 when the camera takes states one at a time
        (frames on states, the image, a snapshot waiting for its curvatures).
        """
        if self.frame_trigger != 'timer' or self.image_wanted \
                or self._pending_stamp is not None:
            return 0, None
        rows = [block for block in (volumes, curvatures) if block is not None]
        if not rows:
            return 0, None
        count = rows[0].shape[0]
        expected = self.segment_names
        if (expected is not None and tuple(names) != expected) \
                or any(block.shape[1] != self.n_segments for block in rows):
            return 0, None
        good = np.ones(count, dtype=bool)
        if curvatures is not None:
            good &= np.isfinite(curvatures).all(axis=1)
        below = None
        if volumes is not None and self._watch_triggers:
            if self.triggers != sorted(self.triggers):
                return 0, None
            good &= (np.isfinite(volumes) & (volumes >= 0.0)).all(axis=1)
            # sum(volumes) - rest, as the per-state path adds them: left to right.
            injected = volumes[:, 0].copy()
            for j in range(1, volumes.shape[1]):
                injected = injected + volumes[:, j]
            injected = injected - self.rest_total
            below = np.searchsorted(np.asarray(self.triggers, dtype=float),
                                    injected + self._trigger_slack, side='right')
            previous = np.empty(count, dtype=below.dtype)
            previous[1:] = below[:-1]
            previous[0] = below[0] if self._triggers_below is None else self._triggers_below
            good &= below == previous
        count = int(np.argmin(good)) if not good.all() else count
        return count, (None if below is None else below[:count])

    def commit_states(self, stamps: np.ndarray, curvatures: np.ndarray | None,
                      below: np.ndarray | None) -> None:
        """The camera after the plain states of :meth:`plain_states` (their stamps)."""
        if not stamps.size:
            return
        if curvatures is not None:
            self._curvatures = curvatures[-1].tolist()
            self._backbone_stale = True
            self._curvature_stamp = int(stamps[-1])
        if below is not None:
            self._triggers_below = int(below[-1])

    def frames(self, times: np.ndarray, curvatures: np.ndarray) -> np.ndarray:
        """
        The timer's frames at ``times`` of the states ``curvatures`` (rows): (frames, M, 7).

        Noisy as :meth:`tick` gives them (the generator drawn frame by frame).
        """
        poses = self._sampler.poses_many(curvatures)
        if self.noise_std_m > 0.0:
            for frame in poses:
                frame[:, [0, 2]] += self._rng.normal(0.0, self.noise_std_m, (self.n_points, 2))
        if times.size:
            self._last_frame_ns = int(times[-1])
        return poses

    # ---------------------------------------------------------------- frames

    def _noisy_poses(self) -> np.ndarray:
        """The poses with noise on every point's x and z (the clean poses when off)."""
        if self.noise_std_m > 0.0:
            noisy = self._poses.copy()
            noisy[:, [0, 2]] += self._rng.normal(0.0, self.noise_std_m, (self.n_points, 2))
            return noisy
        return self._poses

    def tick(self, now: int) -> list[Output]:
        """The frame timer: the latest backbone, markers and (when wanted) the image."""
        if self._curvatures is None or self.frame_trigger != 'timer':
            return []
        out: list[Output] = []
        self._frame(now, out)
        return out

    def _frame(self, now: int, out: list[Output]) -> None:
        self._last_frame_ns = now
        self._update_backbone()
        poses = self._noisy_poses()
        if poses is self._poses:
            poses = poses.copy()  # the sampler reuses its array at the next state
        if 'poses' in self.outputs:
            out.append(Backbone(now, poses))
        if 'markers' in self.outputs:
            points = poses[:, :3]
            out.append(Markers(now, [points[start:end] for start, end in self._line_rows]))
        if self.image_wanted:
            pixels = self._renderer.render(self._poses[:, [0, 2]], self.segment_ends)
            self.images_rendered += 1
            width, height = self.image_size
            out.append(SideImage(now, width, height, pixels.tobytes()))
