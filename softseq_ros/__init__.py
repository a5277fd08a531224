"""
softseq_ros: an emulated rig for soft actuators with a hardware-encoded inflation sequence.

One function per job, from a notebook or a script (the ``softseq`` command runs the same ones)::

    import softseq_ros
    scene = softseq_ros.load_scene('paper')                 # a shipped name or a YAML file
    path = softseq_ros.solve(scene, [0.0, 2.5e-5, 6.5e-5])  # injected volumes [m^3], in order
    print(softseq_ros.classify(scene))                      # 'partial'
    graph = softseq_ros.graph(scene)                        # every stable branch, every snap
    result = softseq_ros.run(scene, 'bags/mine')            # the whole rig, recorded to a bag
    recording = softseq_ros.load_recording('bags/mine')     # the bag's rig topics as arrays
    metrics, summary = softseq_ros.report('bags/mine')      # metrics.json, report.md, figures

These are the package's public API, with what their results hold; every other module is the
inside of one of them. Nothing here imports ROS; ``run`` steps the rig's cores without rclpy.
Each function imports what it needs when first called, so ``import softseq_ros`` stays cheap.
Launch-free tests of the ROS nodes have their helpers in :mod:`softseq_ros.testing`.
"""

import typing as _typing

if _typing.TYPE_CHECKING:
    from collections.abc import Sequence
    from os import PathLike
    from typing import Any

    from softseq_ros.analysis.recording import load_recording  # noqa: F401 - for type checkers
    from softseq_ros.batch import run  # noqa: F401 - for type checkers
    from softseq_ros.dynamic.path import DynamicPath, StartState
    from softseq_ros.quasistatic.equilibrium import SolvedPath
    from softseq_ros.quasistatic.graph import TransitionGraph
    from softseq_ros.quasistatic.regulator import HysteronGraph, RegulatedPath
    from softseq_ros.scene.loader import Scene

__version__ = '0.1.0'
__all__ = ['classify', 'graph', 'load_recording', 'load_scene', 'report', 'run', 'solve']


def load_scene(scene: 'str | PathLike | Scene') -> 'Scene':
    """
    A validated scene from a YAML file or a shipped scene's name (a Scene is returned as is).

    A ``pump.start_branch`` is looked up in the transition graph of the process's shared map.
    """
    from softseq_ros.quasistatic.solve import segments_graph
    from softseq_ros.scene.loader import Scene
    from softseq_ros.scene.loader import load_scene as _load

    return scene if isinstance(scene, Scene) else _load(scene, segments_graph)


def solve(scene: 'str | PathLike | Scene', injected: 'Sequence[float] | None' = None,
          resolution: int | None = None,
          times: 'Sequence[float] | None' = None) -> 'SolvedPath | DynamicPath':
    """
    The scene's path along a history of injected volumes [m^3] from rest (``softseq solve``).

    The history matters (snap-throughs, hysteresis): the volumes are followed in order;
    without one, the scene's pump programme is sampled at the pump's rate (and refused, naming
    the scene file, where it goes beyond what the segments take). A quasi-static scene gives a
    :class:`~softseq_ros.quasistatic.equilibrium.SolvedPath`: per row the injected volume, the
    gauge pressure [Pa], the segment volumes [m^3] and curvatures [1/m], and the snap-throughs
    on the way (``events``); ``resolution`` overrides the scene's solver resolution. A scene
    with a ``network`` gives the path in time, a
    :class:`~softseq_ros.dynamic.path.DynamicPath` (the history pushed at the pump's flow rate,
    row by row, or with ``times`` [s] at each row's time, holds included; every segment's own
    pressure beside the syringe's; snap-throughs with their durations in ``snaps``). A
    quasi-static path depends on the order of the volumes only: ``times`` do not change it.

    A scene behind a pressure regulator (``supply.regulator``) follows its programme of
    pressures, sampled at its rate: quasi-statically a
    :class:`~softseq_ros.quasistatic.regulator.RegulatedPath` (each segment an independent
    hysteron, its flips on the way), with a network a
    :class:`~softseq_ros.dynamic.path.DynamicPath` in time
    (softseq_ros.dynamic.regulated); it takes no volume history.
    """
    import numpy as np

    loaded = load_scene(scene)
    if loaded.regulator is not None:
        if injected is not None or times is not None:
            raise _regulator_refusal(loaded, "a volume history is a syringe's: the regulator "
                                     'follows its programme of pressures (pump.legs)')
        return _solve_regulated(loaded)
    history = None if injected is None else np.asarray(injected, dtype=float)
    if times is not None and history is None:
        raise ValueError('times come with a history of injected volumes, one time per volume')
    if history is None:
        _check_samples(loaded)
    if loaded.network is not None:
        from softseq_ros.dynamic.path import history_path, programme_path

        profile = loaded.pump.profile
        if history is None:
            return programme_path(loaded.segments, loaded.network, profile,
                                  rate_hz=loaded.pump.rate_hz, line=loaded.supply,
                                  start=_network_start(loaded))
        return history_path(loaded.segments, loaded.network, history, profile.flow_rate,
                            times=times, line=loaded.supply)
    from softseq_ros.quasistatic.equilibrium import Tracker
    from softseq_ros.quasistatic.reach import check_scene_reach, start_tracker
    from softseq_ros.quasistatic.solve import equilibrium_map

    emap = equilibrium_map(loaded.segments, resolution or loaded.solver.resolution,
                           loaded.supply)
    if history is None:
        check_scene_reach(loaded, emap)
        profile = loaded.pump.profile
        _, history = profile.sample(loaded.pump.rate_hz)
        if profile.start_history:
            # From the state the stated history led to, not from rest.
            return start_tracker(profile, emap, loaded.segment_names).sweep(history)
    return Tracker(emap).sweep(history)


def _solve_regulated(scene: 'Scene') -> 'RegulatedPath | DynamicPath':
    """A regulator scene's programme of pressures, quasi-static or in time."""
    regulator = scene.regulator
    programme = regulator.programme
    _check_sample_count(scene, programme.duration(), regulator.rate_hz)
    if scene.network is not None:
        from softseq_ros.dynamic.regulated import regulated_network_path

        return regulated_network_path(scene.segments, scene.network, regulator)
    from dataclasses import replace

    from softseq_ros.quasistatic.regulator import regulated_path

    times = programme.sample_times(regulator.rate_hz)
    return replace(regulated_path(scene.segments, programme.target_at(times)), time_s=times)


def _regulator_refusal(scene: 'Scene', reason: str) -> Exception:
    from softseq_ros.scene.validation import SceneError

    where = scene.path if scene.path is not None else '<scene>'
    return SceneError(f'{where}: supply.regulator: {reason}')


def _network_start(scene: 'Scene') -> 'StartState | None':
    """Where a programme with a start history starts, at rest: the balanced state it led to."""
    from softseq_ros.dynamic.path import StartState
    from softseq_ros.quasistatic.reach import start_tracker
    from softseq_ros.quasistatic.solve import scene_map

    profile = scene.pump.profile
    if not profile.start_history:
        return None
    state = start_tracker(profile, scene_map(scene), scene.segment_names).state
    return StartState(profile.start_injected, tuple(float(v) for v in state.volumes))


def _check_samples(scene: 'Scene') -> None:
    """Refuse, naming the scene and its keys, a programme too long to sample at the pump's rate."""
    _check_sample_count(scene, scene.pump.profile.duration(), scene.pump.rate_hz)


def _check_sample_count(scene: 'Scene', duration_s: float, rate_hz: float) -> None:
    from softseq_ros.scene.programme import MAX_SAMPLES
    from softseq_ros.scene.validation import SceneError

    samples = duration_s * rate_hz
    if samples > MAX_SAMPLES:
        raise SceneError(
            f'{scene.path if scene.path is not None else "<scene>"}: pump.rate_hz: '
            f"{rate_hz:g} Hz over the programme's {duration_s:.6g} "
            f's (pump.legs, pump.cycles) gives {samples:.3g} samples, more than '
            f'{MAX_SAMPLES:.0e}: lower the rate or shorten the programme'
            + ('' if scene.regulator is not None else ', or give a volume history'))


def classify(scene: 'str | PathLike | Scene') -> str:
    """
    The scene's sequence type (the paper's Fig. 1): none, partial, symmetric or asymmetric.

    From the quasi-static equilibrium (a scene's network changes how fast, not which): inflated
    over the segments' whole range and deflated back (``softseq classify``). The scene's own
    programme is checked as ``solve`` checks it.
    """
    from softseq_ros.quasistatic.equilibrium import classify as _classify
    from softseq_ros.quasistatic.reach import check_scene_reach
    from softseq_ros.quasistatic.solve import scene_map

    loaded = load_scene(scene)
    if loaded.regulator is not None:
        raise _regulator_refusal(loaded, 'the sequence types are those of segments sharing '
                                 'the volume a syringe pushes; behind a regulator each segment '
                                 'is an independent hysteron: softseq graph shows its flips')
    emap = scene_map(loaded)
    check_scene_reach(loaded, emap)
    return _classify(emap)


def graph(scene: 'str | PathLike | Scene') -> 'TransitionGraph | HysteronGraph':
    """
    Every stable state of the scene's segments and how they connect (``softseq graph``).

    Its branches carry their volume intervals and labels, its transitions the joins and snaps
    (fluid moved, energy released); ``history_to(index)`` gives the fewest reversals of a
    volume history from rest that reaches a branch. Behind a pressure regulator
    (``supply.regulator``), the graph of independent hysterons
    (:class:`~softseq_ros.quasistatic.regulator.HysteronGraph`): its states and flips.
    """
    from softseq_ros.quasistatic.graph import transition_graph
    from softseq_ros.quasistatic.regulator import hysteron_graph
    from softseq_ros.quasistatic.solve import scene_map

    loaded = load_scene(scene)
    if loaded.regulator is not None:
        return hysteron_graph(loaded.segments)
    return transition_graph(scene_map(loaded))


def report(bag: 'str | PathLike', out: 'str | PathLike | None' = None, *,
           scene: 'str | PathLike | None' = None, experiment: 'str | PathLike | None' = None,
           reference: 'str | PathLike | None' = None, namespace: str | None = None,
           svg: bool = False, style: 'Any' = None,
           workers: object | None = None) -> 'tuple[dict, str]':
    """
    Analyse a rig bag into ``out`` (default ``BAG/report``): the metrics and the summary text.

    Writes metrics.json (SI, gauge pressures), report.md, summary.txt and the figures, as
    ``softseq report`` does; ``scene`` adds the quasi-static prediction, ``experiment`` a
    measured CSV beside it, ``namespace`` picks one rig of several, ``style`` is a
    :class:`softseq_ros.analysis.figures.FigureStyle`. ``workers``: a figure worker a command
    started before its imports (:mod:`softseq_ros.analysis.figure_workers`); else one is
    started here.
    """
    from pathlib import Path

    from softseq_ros.analysis.report import write_report

    folder = Path(out) if out is not None else Path(bag) / 'report'
    return write_report(bag, folder, None if scene is None else str(scene), experiment,
                        reference, namespace, svg, workers=workers, style=style)


# Loaded on first use: the bag readers, numpy and the rig's cores take about a second to import.
_LAZY = {'load_recording': 'softseq_ros.analysis.recording', 'run': 'softseq_ros.batch'}


def __getattr__(name: str) -> _typing.Any:
    """``load_recording`` and ``run``, imported from their modules when first asked for."""
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
    import importlib

    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
