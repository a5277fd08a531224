"""
Camera node: the actuator's backbone as a side camera sees it.

It keeps the latest /actuator/curvatures and, at ``rate_hz``, publishes the backbone poses on
/camera/backbone (geometry_msgs/PoseArray, frame ``softseq_base``) and one LINE_STRIP marker per
segment on /camera/markers. Pose convention (as softseq_ros.physics.kinematics): the base is the
origin, the unbent actuator points along +x and bends in the x-z plane (y = 0). Each pose's
position is a backbone point; its orientation is the frame whose +x axis is the backbone tangent
(cos theta, 0, sin theta), where theta is the tangent angle from +x toward +z: a rotation by
-theta about +y, quaternion (x, y, z, w) = (0, -sin(theta/2), 0, cos(theta/2)). Positive
curvature turns the backbone toward +z.

Frames come from a free-running timer at ``rate_hz`` (``frame_trigger: timer``, like a camera
that is not synchronised with the rig), or, with ``frame_trigger: state``, as soon as a new
/actuator/curvatures arrives (a camera triggered by the actuator's state: the lowest latency
from a pump command to its pose), at most about ``rate_hz`` frames per second: a state that
comes less than half a period after the last frame is not drawn (the next one is).

``noise_std_m`` adds Gaussian noise [m] to the x and z of every published point (a pose
extraction error; fresh at every frame, from a generator seeded by ``seed``, so a run is
reproducible). Orientations and the rendered image are noise free.

Snapshots: /actuator/volumes gives the injected volume (sum of volumes minus the rest volumes).
Each time it crosses a value of ``trigger_injected_m3`` (either direction), one PoseArray of the
state at the first command past the trigger goes to /camera/snapshots (transient_local). The
actuator stamps volumes and curvatures of one command alike, so the snapshot waits for the
curvatures carrying that stamp.

/camera/image (rgb8 side view, softseq_ros.physics.render) is rendered only while someone
subscribes (or, in batch mode, when the outputs list ``image``).

Poses and markers go out already serialised (``Publisher.publish`` takes CDR bytes): their
layout never changes, so each frame is a template with new stamps and numbers
(softseq_ros.bag.cdr.FixedLayout), a few microseconds instead of filling dozens of rclpy Pose
and Point objects. Subscribers receive ordinary PoseArray and MarkerArray messages.
"""

from array import array
from bisect import bisect_right
import math
from typing import Any

from builtin_interfaces.msg import Duration
from geometry_msgs.msg import Point, Pose, PoseArray
import numpy as np
from rclpy.node import Parameter
from sensor_msgs.msg import Image, JointState
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from softseq_ros.bag.cdr import FixedLayout
from softseq_ros.nodes.common import (
    FRAME_ID,
    OUTPUT_TOPICS,
    RigNode,
    outputs_reason,
    run_node,
    set_timer_rate,
    stamp_header,
    stamp_ns,
)
from softseq_ros.physics.kinematics import PoseSampler, segment_end_indices
from softseq_ros.physics.render import SEGMENT_RGB, SideViewRenderer

CAMERA_OUTPUTS = ('poses', 'markers', 'image')
MARKER_WIDTH_M = 0.015  # the paper's 15 x 15 mm section


def _increasing_reason(value: list[float]) -> str | None:
    if any(not b > a for a, b in zip(value, value[1:])):
        return 'must be increasing'
    if any(v < 0.0 for v in value):
        return 'must be >= 0'
    return None


class CameraNode(RigNode):
    """Publishes backbone poses, markers, snapshots and (on demand) a side-view image."""

    NODE_NAME = 'camera'

    def __init__(self, **kwargs: Any) -> None:
        """Declare parameters (defaults from the scene) and set up the outputs."""
        super().__init__(self.NODE_NAME, **kwargs)
        scene = self.declare_scene()
        cam = scene.camera
        self.rate_hz = self.declare_number('rate_hz', cam.rate_hz, 'Frame rate [Hz].',
                                           minimum=0.0, open_minimum=True, maximum=1000.0)
        self.frame_trigger = self.declare_text(
            'frame_trigger', 'timer', 'What takes a frame: timer (free running at rate_hz) or '
            'state (each new /actuator/curvatures, at most about rate_hz).', read_only=True,
            check=lambda value: None if value in ('timer', 'state')
            else f'must be timer or state, got {value!r}')
        self._last_frame_ns: int | None = None
        self.noise_std_m = self.declare_number(
            'noise_std_m', cam.noise_std_m, 'Gaussian noise on every point [m].', minimum=0.0)
        seed = self.declare_integer('seed', cam.seed, 'Noise generator seed.', minimum=0,
                                    read_only=True)
        self.points_per_segment = self.declare_integer(
            'points_per_segment', cam.points_per_segment, 'Backbone points per segment.',
            minimum=1, maximum=10000, read_only=True)
        self.triggers = self.declare_numbers(
            'trigger_injected_m3', cam.trigger_injected_m3,
            'Injected volumes [m^3] at which a snapshot is taken (increasing).',
            read_only=True, check=_increasing_reason)
        width = self.declare_integer('width', cam.image_width_px, 'Image width [px].',
                                     minimum=16, maximum=8192, read_only=True)
        height = self.declare_integer('height', cam.image_height_px, 'Image height [px].',
                                      minimum=16, maximum=8192, read_only=True)
        outputs = self.declare_texts(
            'outputs', sorted(scene.outputs), 'Outputs to publish (scene output names); the '
            'camera serves poses, markers and image.', read_only=True, check=outputs_reason)
        self.outputs = frozenset(name for name in outputs if name in CAMERA_OUTPUTS)
        for name in sorted(self.outputs):
            for topic in OUTPUT_TOPICS[name]:
                self._make_publisher(topic)

        self.lengths = np.array(scene.lengths)
        self.rest_total = float(sum(s.rest_volume for s in scene.segments))
        n = len(scene.segments)
        self.n_segments = n
        self.segment_ends = segment_end_indices(n, self.points_per_segment)
        self._sampler = PoseSampler(self.lengths, self.points_per_segment)
        self.n_points = self._sampler.n_points
        self._rng = np.random.default_rng(seed)
        self._renderer = SideViewRenderer(width, height,
                                          half_extent_m=1.05 * float(self.lengths.sum()))

        self._curvatures: list[float] | None = None
        self._backbone_stale = False
        self._curvature_stamp = -1
        self._poses = np.zeros((self.n_points, 7))
        self._watch_triggers = bool(self.triggers) and 'poses' in self.outputs
        self._triggers_below: int | None = None
        self._pending_stamp: int | None = None
        self._pending_count = 0
        self.images_rendered = 0

        poses = PoseArray(poses=[Pose() for _ in range(self.n_points)])
        poses.header.frame_id = FRAME_ID
        self._pose_layout = FixedLayout(poses, 'geometry_msgs/msg/PoseArray')
        markers = MarkerArray(markers=[
            Marker(ns='backbone', id=i, type=Marker.LINE_STRIP, action=Marker.ADD,
                   lifetime=Duration(), frame_locked=False,
                   points=[Point() for _ in range(self.points_per_segment + 1)],
                   color=ColorRGBA(r=rgb[0] / 255.0, g=rgb[1] / 255.0, b=rgb[2] / 255.0,
                                   a=1.0))
            for i, rgb in ((i, SEGMENT_RGB[i % len(SEGMENT_RGB)]) for i in range(n))])
        for marker in markers.markers:
            marker.header.frame_id = FRAME_ID
            marker.pose.orientation.w = 1.0
            marker.scale.x = MARKER_WIDTH_M
        self._marker_layout = FixedLayout(markers, 'visualization_msgs/msg/MarkerArray')
        # Segment i's line runs from its start point to its end point (shared with the next).
        starts = [0, *self.segment_ends[:-1].tolist()]
        self._marker_rows = [(a, b + 1) for a, b in zip(starts, self.segment_ends.tolist())]
        self._image = Image(height=height, width=width, encoding='rgb8', is_bigendian=0,
                            step=3 * width)
        self._image.header.frame_id = FRAME_ID

        self._subscribe('/actuator/curvatures', self.on_curvatures)
        self._subscribe('/actuator/volumes', self.on_volumes)
        self._timer = (self._make_timer(self.rate_hz, self.tick)
                       if self.frame_trigger == 'timer' else None)
        self.configured = True

    # ---------------------------------------------------------------- inputs

    def _usable(self, values: Any) -> bool:
        return len(values) == self.n_segments and all(map(math.isfinite, values))

    def on_curvatures(self, msg: JointState) -> None:
        """Keep the latest curvatures; complete a pending snapshot of this command."""
        position = msg.position
        if not self._usable(position):
            self.warn_throttled('curvatures', f'ignoring /actuator/curvatures with '
                                              f'{len(position)} values (expected '
                                              f'{self.n_segments} finite)')
            return
        # A copy: the message's buffer may be reused by its sender.
        curvatures = position.tolist() if type(position) is array else list(position)
        if curvatures != self._curvatures:
            self._curvatures = curvatures
            # The backbone is computed when a frame or a snapshot needs it, not at the
            # actuator's rate: most curvature messages are never drawn.
            self._backbone_stale = True
        self._curvature_stamp = stamp_ns(msg.header)
        if self._pending_stamp is not None and self._curvature_stamp >= self._pending_stamp:
            self._take_snapshots()
        if self.frame_trigger == 'state':
            now = self.now_ns()
            last = self._last_frame_ns
            if last is None or now - last >= 500_000_000 / self.rate_hz:
                self._frame(now)

    def on_volumes(self, msg: JointState) -> None:
        """Detect trigger crossings of the injected volume."""
        position = msg.position
        if not self._usable(position):
            self.warn_throttled('volumes', 'ignoring /actuator/volumes of the wrong size')
            return
        if not self._watch_triggers:
            return
        # Triggers at or below the injected volume: a crossing changes this count.
        below = bisect_right(self.triggers, sum(position) - self.rest_total)
        previous, self._triggers_below = self._triggers_below, below
        if previous is None or below == previous:
            return
        self._pending_count += abs(below - previous)
        stamp = stamp_ns(msg.header)
        if self._pending_stamp is None or stamp > self._pending_stamp:
            self._pending_stamp = stamp
        if self._curvatures is not None and self._curvature_stamp >= self._pending_stamp:
            self._take_snapshots()

    def _update_backbone(self) -> None:
        if self._backbone_stale:
            self._poses = self._sampler.poses(self._curvatures)
            self._backbone_stale = False

    def _take_snapshots(self) -> None:
        self._update_backbone()
        snapshot = self._pose_layout.encode(self.now_ns(), [self._noisy_poses()])
        for _ in range(self._pending_count):
            self._publish('/camera/snapshots', snapshot)
        self._pending_stamp = None
        self._pending_count = 0

    # ---------------------------------------------------------------- outputs

    def _noisy_poses(self) -> np.ndarray:
        """The poses with noise on every point's x and z (the clean poses when off)."""
        if self.noise_std_m > 0.0:
            noisy = self._poses.copy()
            noisy[:, [0, 2]] += self._rng.normal(0.0, self.noise_std_m, (self.n_points, 2))
            return noisy
        return self._poses

    def image_wanted(self) -> bool:
        """True when the image must be rendered this frame."""
        if 'image' not in self.outputs:
            return False
        if self.batch_mode:
            return True
        return self._rig_publishers['/camera/image'].get_subscription_count() > 0

    def tick(self) -> None:
        """The frame timer: publish the latest backbone, markers and (when wanted) the image."""
        if self._curvatures is None or self.frame_trigger != 'timer':
            return
        self._frame(self.now_ns())

    def _frame(self, now: int) -> None:
        self._last_frame_ns = now
        self._update_backbone()
        poses = self._noisy_poses()
        if 'poses' in self.outputs:
            self._publish('/camera/backbone', self._pose_layout.encode(now, [poses]))
        if 'markers' in self.outputs:
            points = poses[:, :3]
            self._publish('/camera/markers', self._marker_layout.encode(
                now, [points[start:end] for start, end in self._marker_rows]))
        if self.image_wanted():
            pixels = self._renderer.render(self._poses[:, [0, 2]], self.segment_ends)
            self.images_rendered += 1
            stamp_header(self._image.header, now)
            self._image.data = pixels.tobytes()
            self._publish('/camera/image', self._image)

    def _parameters_changed(self, parameters: list[Parameter]) -> None:
        for parameter in parameters:
            if parameter.name == 'rate_hz':
                self.rate_hz = float(parameter.value)
                set_timer_rate(self._timer, self.rate_hz)
            elif parameter.name == 'noise_std_m':
                self.noise_std_m = float(parameter.value)


def main(args: list[str] | None = None) -> None:
    """Run the camera node."""
    run_node(CameraNode, args)


if __name__ == '__main__':
    main()
