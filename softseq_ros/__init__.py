"""
softseq_ros: an emulated rig for soft actuators with a hardware-encoded inflation sequence.

From a notebook or a script::

    import softseq_ros
    scene = softseq_ros.load_scene('paper')                 # a shipped name or a YAML file
    path = softseq_ros.solve(scene, [0.0, 2.5e-5, 6.5e-5])  # injected volumes [m^3]
    print(path.pressure, path.volumes, path.events)         # gauge Pa, m^3 per segment, snaps
    result = softseq_ros.run(scene, 'bags/mine')            # the whole rig, recorded to a bag
    recording = softseq_ros.load_recording('bags/mine')     # the bag's rig topics as arrays

Nothing here imports ROS; ``run`` steps the rig's cores without rclpy. Each function imports
what it needs when first called, so ``import softseq_ros`` stays cheap. Launch-free tests of
the ROS nodes have their helpers in :mod:`softseq_ros.testing`.
"""

import typing as _typing

if _typing.TYPE_CHECKING:
    from collections.abc import Sequence
    from os import PathLike
    from typing import Any

    from softseq_ros.analysis.recording import load_recording  # noqa: F401 - for type checkers
    from softseq_ros.batch import BatchResult
    from softseq_ros.quasistatic.equilibrium import SolvedPath
    from softseq_ros.scene.loader import Scene

__version__ = '0.1.0'
__all__ = ['load_recording', 'load_scene', 'run', 'solve']


def load_scene(scene: 'str | PathLike | Scene') -> 'Scene':
    """A validated scene from a YAML file or a shipped scene's name (a Scene is returned as is)."""
    from softseq_ros.scene.loader import Scene
    from softseq_ros.scene.loader import load_scene as _load

    return scene if isinstance(scene, Scene) else _load(scene)


def solve(scene: 'str | PathLike | Scene', injected: 'Sequence[float]',
          resolution: int | None = None) -> 'SolvedPath':
    """
    The quasi-static path along a history of injected volumes [m^3], from rest.

    The history matters (snap-throughs, hysteresis): the volumes are followed in order. The
    result holds per row the injected volume, the gauge pressure [Pa], the segment volumes
    [m^3] and curvatures [1/m], and the snap-throughs on the way (``events``).
    """
    from softseq_ros.quasistatic.equilibrium import Tracker
    from softseq_ros.quasistatic.solve import equilibrium_map

    loaded = load_scene(scene)
    emap = equilibrium_map(loaded.segments, resolution or loaded.solver.resolution)
    return Tracker(emap).sweep(injected)


def run(scene: 'str | PathLike | Scene', out: 'str | PathLike', *,
        start_time_ns: int | None = None, overrides: 'dict[str, dict[str, Any]] | None' = None,
        namespace: str = '/') -> 'BatchResult':
    """
    Run the rig (pump, actuator, camera) on the scene's programme into the bag ``out``.

    A loaded scene runs as it is in memory (``dataclasses.replace`` a part to change it); a
    path or shipped name is loaded first. The same cores as the ROS nodes, stepped on a
    simulated clock that starts at ``start_time_ns`` (default: now); ``overrides`` replace
    core settings by role, e.g. ``{'camera': {'rate_hz': 30.0}}``.
    """
    from softseq_ros.batch import BatchRun

    return BatchRun(scene, out, overrides=overrides, start_time_ns=start_time_ns,
                    namespace=namespace).run()


# Loaded on first use: the bag readers and numpy take about a second to import.
_LAZY = {'load_recording': 'softseq_ros.analysis.recording'}


def __getattr__(name: str) -> _typing.Any:
    """``load_recording`` (softseq_ros.analysis.recording's), imported when first asked for."""
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
    import importlib

    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
