"""
Cores from a scene: the scene gives every setting's default, keywords override them.

The node adapters pass their parameters as the keywords, the batch runner its overrides, so
both build the same cores from the same scene the same way.
"""

from pathlib import Path
from typing import Any

from softseq_ros.errors import UserError
from softseq_ros.rig.actuator import ActuatorCore
from softseq_ros.rig.camera import CameraCore
from softseq_ros.rig.model import ActuatorModel, actuator_model, default_max_pressure_pa
from softseq_ros.rig.pump import (
    DEFAULT_FEEDBACK_TIMEOUT_S,
    DEFAULT_MAX_FLOW_M3_PER_S,
    PumpCore,
)
from softseq_ros.rig.regulator import PressureSchedule, RegulatorCore
from softseq_ros.scene.limits import LIMITS
from softseq_ros.scene.loader import Scene
from softseq_ros.scene.programme import Leg, ProgrammeError, PumpProfile, check_capacity
from softseq_ros.wire import contract


class SettingError(UserError):
    """A core setting that cannot run; the message names the setting."""


def _unknown(role: str, overrides: dict[str, Any], known: tuple[str, ...]) -> None:
    extra = sorted(set(overrides) - set(known))
    if extra:
        raise SettingError(f'{role}: unknown setting(s) {", ".join(extra)}; expected some of '
                           f'{", ".join(known)}')


PUMP_SETTINGS = ('rate_hz', 'flow_rate_m3_per_s', 'legs', 'cycles', 'start_injected_m3',
                 'autostart', 'max_pressure_pa', 'max_injected_m3', 'feedback_timeout_s',
                 'open_loop', 'feedback_clock', 'max_flow_m3_per_s')


def pump_profile(scene: Scene, *, flow_rate_m3_per_s: float | None = None,
                 legs: tuple[Leg, ...] | None = None, cycles: int | None = None,
                 start_injected_m3: float | None = None) -> PumpProfile:
    """
    The scene's pump programme with any of its parts replaced.

    The scene's start history stays where the programme still starts where it ends.
    """
    default = scene.pump.profile
    start = default.start_injected if start_injected_m3 is None else start_injected_m3
    try:
        profile = PumpProfile(
            legs=default.legs if legs is None else tuple(legs),
            flow_rate=default.flow_rate if flow_rate_m3_per_s is None else flow_rate_m3_per_s,
            cycles=default.cycles if cycles is None else cycles, start_injected=start,
            start_history=default.start_history if start == default.start_injected else ())
    except ValueError as err:
        raise SettingError(f'pump programme (legs, cycles, start_injected_m3): {err}') from None
    try:
        check_capacity(profile, scene.capacity)
    except ProgrammeError as err:
        raise SettingError(str(err)) from None
    return profile


def check_programme(scene: Scene, profile: PumpProfile, model: ActuatorModel) -> None:
    """
    Refuse a programme the actuator's model cannot run (it leaves the model's domain).

    The scene's own programme is refused as a scene error naming the file and the scene key;
    one the settings changed, naming the setting (``legs[0].inflate_to_m3``).
    """
    try:
        model.check_programme(scene, profile)
    except ProgrammeError as err:
        raise SettingError(str(err)) from None


def end_stop(model: ActuatorModel, profile: PumpProfile) -> float:
    """The pump's default end stop [m^3]: where the inflation ends, or the programme's peak."""
    return max(model.end_stop_m3, profile.max_injected())


# What a regulator's core takes: the pump's settings that do not belong to a syringe.
REGULATOR_SETTINGS = ('rate_hz', 'autostart', 'max_pressure_pa', 'feedback_timeout_s',
                      'open_loop', 'feedback_clock')


def regulator_core(scene: Scene, **settings: Any) -> tuple[RegulatorCore, float]:
    """
    The scene's pressure regulator (its ``pump`` block the programme of pressures) and rate.

    Its relief defaults to the scene's (``supply.regulator.max_pressure_pa``); a syringe's
    setting is refused by name.
    """
    syringe = sorted(set(settings) & (set(PUMP_SETTINGS) - set(REGULATOR_SETTINGS)))
    if syringe:
        raise SettingError(f'pump: {", ".join(syringe)}: a syringe setting, and the supply '
                           "is a pressure regulator (its programme is the scene's pressures)")
    _unknown('pump', settings, REGULATOR_SETTINGS)
    regulator = scene.regulator
    rate_hz = float(settings.get('rate_hz', regulator.rate_hz))
    reason = LIMITS['pump.rate_hz'].reason(rate_hz)
    if reason is not None:
        raise SettingError(f'pump: rate_hz {reason}')
    relief = settings.get('max_pressure_pa', regulator.max_pressure_pa)
    if relief < regulator.programme.highest():
        raise SettingError(f"pump: max_pressure_pa {relief:.6g} Pa is below the programme's "
                           f'highest target, {regulator.programme.highest():.6g} Pa')
    core = RegulatorCore(
        PressureSchedule(regulator.programme, regulator.pressure_rate_pa_per_s),
        autostart=settings.get('autostart', True), max_pressure_pa=relief,
        feedback_timeout_s=settings.get('feedback_timeout_s', DEFAULT_FEEDBACK_TIMEOUT_S),
        open_loop=settings.get('open_loop', False), segment_names=scene.segment_names,
        **({'feedback_clock': settings['feedback_clock']} if 'feedback_clock' in settings
           else {}))
    return core, rate_hz


def pump_core(scene: Scene, model: ActuatorModel | None = None,
              **settings: Any) -> tuple[PumpCore, float]:
    """
    The scene's pump (settings from PUMP_SETTINGS override it) and its rate [Hz].

    With the actuator's model the programme is checked against the model's domain first, and
    ``max_injected_m3`` defaults to where the inflation ends (else to what the segments hold).
    Behind a pressure regulator, the regulator's core (:func:`regulator_core`).
    """
    if scene.regulator is not None:
        return regulator_core(scene, **settings)
    _unknown('pump', settings, PUMP_SETTINGS)
    rate_hz = float(settings.get('rate_hz', scene.pump.rate_hz))
    reason = LIMITS['pump.rate_hz'].reason(rate_hz)
    if reason is not None:
        raise SettingError(f'pump: rate_hz {reason}')
    profile = pump_profile(scene, flow_rate_m3_per_s=settings.get('flow_rate_m3_per_s'),
                           legs=settings.get('legs'), cycles=settings.get('cycles'),
                           start_injected_m3=settings.get('start_injected_m3'))
    default_stop = scene.capacity
    if model is not None:
        check_programme(scene, profile, model)
        default_stop = end_stop(model, profile)
    core = PumpCore(
        profile, autostart=settings.get('autostart', True),
        max_pressure_pa=settings.get('max_pressure_pa', default_max_pressure_pa(scene)),
        max_injected_m3=settings.get('max_injected_m3', default_stop),
        feedback_timeout_s=settings.get('feedback_timeout_s', DEFAULT_FEEDBACK_TIMEOUT_S),
        open_loop=settings.get('open_loop', False), segment_names=scene.segment_names,
        max_flow_m3_per_s=settings.get('max_flow_m3_per_s', DEFAULT_MAX_FLOW_M3_PER_S),
        **({'feedback_clock': settings['feedback_clock']} if 'feedback_clock' in settings
           else {}))
    return core, rate_hz


ACTUATOR_SETTINGS = ('outputs', 'ambient_pressure_pa', 'state_file')


def actuator_core(scene: Scene, model: ActuatorModel | None = None,
                  **settings: Any) -> ActuatorCore:
    """
    The scene's actuator (settings from ACTUATOR_SETTINGS override it) on ``model``.

    By default the model is the one the scene asks for (softseq_ros.rig.model.actuator_model).
    """
    _unknown('actuator', settings, ACTUATOR_SETTINGS)
    state_file = settings.get('state_file')
    return ActuatorCore(
        model if model is not None else actuator_model(scene), scene.segment_names,
        outputs=frozenset(settings.get('outputs', scene.outputs)),
        ambient_pressure_pa=settings.get('ambient_pressure_pa',
                                         contract.DEFAULT_AMBIENT_PRESSURE_PA),
        state_file=Path(state_file) if state_file else None, scene_name=scene.name)


CAMERA_SETTINGS = ('rate_hz', 'frame_trigger', 'noise_std_m', 'seed', 'points_per_segment',
                   'trigger_injected_m3', 'width', 'height', 'outputs')


def camera_core(scene: Scene, **settings: Any) -> CameraCore:
    """The scene's camera (settings from CAMERA_SETTINGS override it)."""
    _unknown('camera', settings, CAMERA_SETTINGS)
    cam = scene.camera
    try:
        return CameraCore(
            scene.lengths, sum(segment.rest_volume for segment in scene.segments),
            rate_hz=float(settings.get('rate_hz', cam.rate_hz)),
            outputs=frozenset(settings.get('outputs', scene.outputs)),
            frame_trigger=settings.get('frame_trigger', 'timer'),
            noise_std_m=float(settings.get('noise_std_m', cam.noise_std_m)),
            seed=int(settings.get('seed', cam.seed)),
            points_per_segment=int(settings.get('points_per_segment', cam.points_per_segment)),
            triggers=tuple(settings.get('trigger_injected_m3', cam.trigger_injected_m3)),
            image_size=(int(settings.get('width', cam.image_width_px)),
                        int(settings.get('height', cam.image_height_px))),
            segment_names=scene.segment_names)
    except ValueError as err:
        raise SettingError(f'camera: {err}') from None
