"""Small scenes the tests write to files (no ROS needed to use them)."""

import json
from pathlib import Path

import yaml

CONFIG = Path(__file__).resolve().parents[1] / 'config'
# The Fig. 1 asymmetric pair pumped 0 -> 50 mL -> 0 at 20 mL/s: 5 s, two snaps each way.
FAST_ASYMMETRIC_PUMP = {'flow_rate_m3_per_s': 2.0e-5,
                        'legs': [{'inflate_to_m3': 5.0e-5}, {'deflate_to_m3': 0.0}]}

# Linear bottom and a neo-Hookean balloon top (the symmetric case of Fig. 1): the top passes its
# pressure peak at about 20 mL injected and then takes the bottom's fluid, so the path is
# strongly nonlinear. The pump runs 0 -> 30 mL -> 0 at 20 mL/s (3 s).
FAST_SCENE = {
    'name': 'fast_symmetric',
    'segments': [
        {'name': 'bottom', 'length_m': 0.111,
         'linear': {'rest_volume_m3': 1.0e-5, 'stiffness_pa_per_m3': 5.0e+8,
                    'max_volume_m3': 4.0e-5, 'curvature_per_m_per_m3': 8.0e+5}},
        {'name': 'top', 'length_m': 0.111,
         'balloon': {'material': {'law': 'neo_hookean', 'shear_modulus_pa': 34.0e+3},
                     'radius_m': 0.010, 'thickness_m': 2.0e-3, 'max_stretch': 2.6,
                     'curvature_per_m_per_m3': 4.0e+5}},
    ],
    'pump': {'flow_rate_m3_per_s': 2.0e-5, 'rate_hz': 100,
             'legs': [{'inflate_to_m3': 3.0e-5}, {'deflate_to_m3': 0.0}]},
    'camera': {'rate_hz': 20, 'trigger_injected_m3': [1.0e-5, 2.5e-5]},
    'outputs': ['pressure', 'volumes', 'curvature', 'poses', 'markers', 'image', 'events'],
}

def write_scene(folder, **changes) -> str:
    """Write FAST_SCENE (with top-level or pump changes) as YAML; return its path."""
    scene = json.loads(json.dumps(FAST_SCENE))
    for key, value in changes.items():
        if key in ('legs', 'flow_rate_m3_per_s', 'rate_hz'):
            scene['pump'][key] = value
        else:
            scene[key] = value
    path = folder / f'{scene["name"]}.yaml'
    path.write_text(yaml.safe_dump(scene), encoding='utf-8')
    return str(path)


def inside_the_hysteresis_loop(emap, samples: int = 1001):
    """
    The injected volume where inflation and deflation paths differ most, and both states there.

    Returns (injected, inflating volumes, deflating volumes) for a sweep up to 98 % of the
    range and back: the deflating state is where a history that went up and came back sits.
    """
    import numpy as np

    from softseq_ros.quasistatic.equilibrium import Tracker

    grid = np.linspace(0.0, 0.98 * emap.injected_range[1], samples)
    inflating = Tracker(emap).sweep(grid)
    deflating = Tracker(emap, injected=grid[-1], volumes=inflating.volumes[-1]).sweep(
        grid[::-1])
    gap = np.max(np.abs(deflating.volumes[::-1] - inflating.volumes), axis=1)
    row = int(np.argmax(gap))
    return float(grid[row]), inflating.volumes[row], deflating.volumes[::-1][row]


def shipped_scene_changed(folder: Path, source: str, name: str, pump: dict, camera: dict,
                          file_name: str | None = None) -> Path:
    """
    A shipped scene (``config/SOURCE``) renamed, with pump settings changed and its camera
    replaced, written to ``folder`` (its tables named by absolute path); return its path.
    """
    scene = yaml.safe_load((CONFIG / source).read_text(encoding='utf-8'))
    scene['name'] = name
    scene['pump'].update(pump)
    scene['camera'] = camera
    for segment in scene['segments']:
        if 'table' in segment:
            segment['table'] = str(CONFIG / segment['table'])
    path = folder / (file_name or f'{name}.yaml')
    path.write_text(yaml.safe_dump(scene), encoding='utf-8')
    return path


def shipped_scene_with(folder: Path, source: str, file_name: str, **sections: object) -> Path:
    """
    A shipped scene (``config/SOURCE``) with whole top-level sections set (``pump``,
    ``camera``, ``network``, ``supply``...), written to ``folder/FILE_NAME``; return its path.
    """
    scene = yaml.safe_load((CONFIG / source).read_text(encoding='utf-8'))
    scene.update(sections)
    for segment in scene['segments']:
        if 'table' in segment:
            segment['table'] = str(CONFIG / segment['table'])
    path = folder / file_name
    path.write_text(yaml.safe_dump(scene), encoding='utf-8')
    return path


def fast_asymmetric(folder: Path, name: str, pump_rate_hz: float = 50,
                    camera_rate_hz: float = 10,
                    triggers: tuple[float, ...] = (5.0e-6, 2.5e-5, 4.5e-5),
                    file_name: str | None = None) -> Path:
    """The Fig. 1 asymmetric pair, 0 -> 50 mL -> 0 at 20 mL/s, as ``folder/NAME.yaml``."""
    return shipped_scene_changed(
        folder, 'fig1_asymmetric.yaml', name,
        {**FAST_ASYMMETRIC_PUMP, 'rate_hz': pump_rate_hz},
        {'rate_hz': camera_rate_hz, 'trigger_injected_m3': list(triggers)}, file_name)


# The closed-form flip of `softseq scatter` (test_scatter.py, bench/bench_scatter.py): a linear
# bottom segment ending at FLIP_P_MAX beside a neo-Hookean balloon top whose pressure peaks at
# p* = (12/7) 7^(-1/6) mu H / R. Where p* < FLIP_P_MAX the top passes its peak and empties the
# bottom into itself (symmetric); where p* > FLIP_P_MAX the bottom ends first and the top only
# takes over (partial): the type flips at the thickness FLIP_H.
FLIP_MU, FLIP_RADIUS, FLIP_P_MAX, FLIP_STIFFNESS = 34e3, 0.01, 8000.0, 5e8
NEO_HOOKEAN_PEAK = 12.0 / 7.0 * 7.0 ** (-1.0 / 6.0)   # a thin sphere's p* / (mu H / R)
FLIP_H = FLIP_P_MAX * FLIP_RADIUS / (NEO_HOOKEAN_PEAK * FLIP_MU)


def fast_asymmetric_bag(folder: Path, name: str, start_time_ns: int) -> Path:
    """A real rig bag of :func:`fast_asymmetric` (over 5 s, two snaps each way), in ``folder``."""
    import softseq_ros

    scene = fast_asymmetric(folder, name, file_name='scene.yaml')
    softseq_ros.run(scene, folder / 'bag', start_time_ns=start_time_ns)
    return folder / 'bag'



def flip_document(thickness: float = FLIP_H) -> dict:
    """The flip pair as a scene's parsed YAML, its balloon ``thickness`` [m] thick."""
    return {'name': 'flip', 'segments': [
        {'name': 'bottom', 'length_m': 0.111,
         'linear': {'rest_volume_m3': 1e-5, 'stiffness_pa_per_m3': FLIP_STIFFNESS,
                    'max_volume_m3': 1e-5 + FLIP_P_MAX / FLIP_STIFFNESS}},
        {'name': 'top', 'length_m': 0.111,
         'balloon': {'material': {'law': 'neo_hookean', 'shear_modulus_pa': FLIP_MU},
                     'radius_m': FLIP_RADIUS, 'thickness_m': thickness, 'max_stretch': 2.6}}],
        'pump': {'legs': [{'inflate_to_m3': 1e-6}]}}
