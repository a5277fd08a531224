"""
Camera node: the camera core (softseq_ros.rig.camera) behind ROS topics.

Listens to ``actuator/curvatures`` and ``actuator/volumes``; publishes ``camera/backbone``
(geometry_msgs/PoseArray in ``softseq_base``), ``camera/markers`` (one LINE_STRIP per
segment), ``camera/snapshots`` with ``camera/snapshot_steps`` (which trigger each snapshot
belongs to) and ``camera/image`` (rgb8 side view, rendered only while someone subscribes).
Frames come from a free-running timer at ``rate_hz`` (``frame_trigger: timer``) or follow
the actuator's state (``frame_trigger: state``); see the core for the conventions.

Poses and markers go out already serialised: their layout never changes, so each frame is a
template with new stamps and numbers (softseq_ros.wire.payloads), a few microseconds instead of
filling dozens of rclpy Pose objects. Subscribers receive ordinary PoseArray and MarkerArray
messages.
"""

from typing import Any, Callable

from rclpy.clock import Clock, ClockType
from rclpy.node import Parameter

from softseq_ros.nodes.core_node import CoreNode
from softseq_ros.nodes.diagnostics import Health
from softseq_ros.nodes.parameters import outputs_reason
from softseq_ros.nodes.runner import run_node
from softseq_ros.rig.build import camera_core
from softseq_ros.rig.camera import FRAME_TRIGGERS
from softseq_ros.scene.limits import LIMITS
from softseq_ros.wire import contract

# How often a state-triggered camera looks whether anyone wants its image.
IMAGE_CHECK_S = 0.05


def _triggers_reason(reach_m3: float, reach: str) -> Callable[[list[float]], str | None]:
    """The check of trigger volumes: increasing, >= 0 and within ``reach_m3``."""
    def reason(value: list[float]) -> str | None:
        if any(not b > a for a, b in zip(value, value[1:])):
            return 'must be increasing'
        if any(v < 0.0 for v in value):
            return 'must be >= 0'
        beyond = [v for v in value if v > reach_m3]
        if beyond:
            return f'{beyond[0]:g} m^3 is never reached: {reach} {reach_m3:g} m^3'
        return None
    return reason


class CameraNode(CoreNode):
    """Publishes backbone poses, markers, snapshots and (on demand) a side-view image."""

    NODE_NAME = contract.NODE_NAMES[contract.CAMERA]

    def __init__(self, **kwargs: Any) -> None:
        """Declare parameters (defaults from the scene) and set up the outputs."""
        super().__init__(self.NODE_NAME, **kwargs)
        scene = self.declare_scene()
        cam = scene.camera
        rate_hz = self.declare_number('rate_hz', cam.rate_hz, 'Frame rate [Hz].',
                                      **LIMITS['camera.rate_hz'].bounds())
        frame_trigger = self.declare_text(
            'frame_trigger', 'timer', 'What takes a frame: timer (free running at rate_hz) or '
            'state (each new actuator/curvatures, at most about rate_hz).', read_only=True,
            check=lambda value: None if value in FRAME_TRIGGERS
            else f'must be timer or state, got {value!r}')
        noise = self.declare_number(
            'noise_std_m', cam.noise_std_m, 'Gaussian noise on every point [m].',
            **LIMITS['camera.noise_std_m'].bounds())
        seed = self.declare_integer('seed', cam.seed, 'Noise generator seed.', read_only=True,
                                    **LIMITS['camera.seed'].bounds())
        points = self.declare_integer(
            'points_per_segment', cam.points_per_segment, 'Backbone points per segment.',
            read_only=True, **LIMITS['camera.points_per_segment'].bounds())
        # A trigger no volume of the programme reaches would never take its snapshot. In the
        # rig the pump's programme is known; a camera on its own knows what the segments hold.
        pump = self.local.nodes.get(contract.PUMP) if self.local is not None else None
        if pump is not None:
            reach = _triggers_reason(pump.core.profile.max_injected(),
                                     "the pump's programme goes up to")
        else:
            reach = _triggers_reason(scene.capacity, 'the segments hold together')
        triggers = self.declare_numbers(
            'trigger_injected_m3', cam.trigger_injected_m3,
            'Injected volumes [m^3] at which a snapshot is taken (increasing, within reach).',
            read_only=True, check=reach)
        width = self.declare_integer('width', cam.image_width_px, 'Image width [px].',
                                     read_only=True, **LIMITS['camera.image_width_px'].bounds())
        height = self.declare_integer('height', cam.image_height_px, 'Image height [px].',
                                      read_only=True,
                                      **LIMITS['camera.image_height_px'].bounds())
        outputs = self.declare_texts(
            'outputs', sorted(scene.outputs), 'Outputs to publish (scene output names); the '
            'camera serves poses, markers and image.', read_only=True, check=outputs_reason)
        self.core = camera_core(
            scene, rate_hz=rate_hz, frame_trigger=frame_trigger, noise_std_m=noise, seed=seed,
            points_per_segment=points, trigger_injected_m3=triggers, width=width,
            height=height, outputs=frozenset(outputs))
        self.connect(frozenset(outputs))
        self._image_publisher = self.publisher(contract.IMAGE)
        self._update_image_wanted()
        self._timer = None
        if frame_trigger == 'timer':
            self._timer = self.create_timer(1.0 / rate_hz, self.tick)
        elif self._image_publisher is not None:
            self.create_timer(IMAGE_CHECK_S, self._update_image_wanted,
                              clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.configured = True
        when = f'at {rate_hz:g} Hz' if frame_trigger == 'timer' else f'on each {frame_trigger}'
        self.get_logger().info(
            f'ready: scene {scene.name}, frames {when}, {len(triggers)} snapshot volumes, '
            f'publishing {", ".join(sorted(self.core.outputs))}')

    DIAGNOSTIC_TASK = 'camera'

    def health(self) -> Health:
        """For /diagnostics: the frame rate asked for and the images rendered, with the rest."""
        base = super().health()
        base.values = {'rate_hz': self.core.rate_hz,
                       'images_rendered': self.core.images_rendered,
                       'refused_states': self.core.refused_states, **base.values}
        return base

    def _update_image_wanted(self) -> None:
        # Rendering is the costliest output: only while someone looks.
        publisher = self._image_publisher
        self.core.image_wanted = (publisher is not None
                                  and publisher.get_subscription_count() > 0)

    def tick(self) -> None:
        """The frame timer: publish the latest backbone, markers and (when wanted) image."""
        self._update_image_wanted()
        self.send(self.core.tick(self.now_ns()))

    def _parameters_changed(self, parameters: list[Parameter]) -> None:
        for parameter in parameters:
            if parameter.name == 'rate_hz':
                self.core.rate_hz = float(parameter.value)
                if self._timer is not None:
                    self._timer.timer_period_ns = int(round(1e9 / self.core.rate_hz))
            elif parameter.name == 'noise_std_m':
                self.core.noise_std_m = float(parameter.value)


def main(args: list[str] | None = None) -> None:
    """Run the camera node."""
    run_node(CameraNode, args)


if __name__ == '__main__':
    main()
