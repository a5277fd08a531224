"""
Whether a pump programme stays in the equilibrium's domain, checked before anything runs.

For the pump node, ``softseq run``, ``classify`` and ``solve`` alike (the scene loader checks
the cheaper bound, what the segments hold: softseq_ros.scene.programme.check_capacity).
:func:`check_reach` walks the programme on the equilibrium set: the inflation ends where the
first segment reaches the end of its model, which is often well below the sum of what the
segments hold (the paper's pair holds 120 mL, its inflation ends at 106 mL), and depends on the
branch the history took. A refusal names the leg, its volume and the segment whose model ends
first.
"""

from typing import Sequence

import numpy as np

from softseq_ros.quasistatic.equilibrium import DomainError, EquilibriumMap, Tracker
from softseq_ros.scene.loader import Scene, SceneError, require_syringe
from softseq_ros.scene.programme import ProgrammeError, PumpProfile, leg_key, leg_targets


def check_reach(profile: PumpProfile, emap: EquilibriumMap, names: Sequence[str],
                prefix: str = '') -> None:
    """
    Refuse a programme that leaves the equilibrium's domain on the way the pump takes it.

    Every cycle after the first starts from the state the one before ended in; once such a
    state comes back the cycles repeat, so the walk stops there (a million cycles cost two).
    """
    tracker = start_tracker(profile, emap, names, prefix)
    seen: set[tuple[int, float]] = set()
    for cycle in range(1, profile.cycles + 1):
        for index, leg in enumerate(profile.legs):
            for volume in leg_targets(leg):
                try:
                    tracker.move(volume)
                except DomainError as err:
                    in_cycle = f' (cycle {cycle})' if profile.cycles > 1 else ''
                    reason = beyond_domain(volume, err, emap, names, in_cycle)
                    raise ProgrammeError(leg_key(index, leg, prefix), reason) from None
        state = (tracker.branch, tracker.total)
        if state in seen:
            return
        seen.add(state)


def start_tracker(profile: PumpProfile, emap: EquilibriumMap, names: Sequence[str],
                  prefix: str = '') -> Tracker:
    """
    The state the programme starts from, on a tracker.

    From rest, moved to ``start_injected``, or walked through the programme's
    ``start_history`` in order. A volume beyond the domain raises :class:`ProgrammeError`
    naming its key.
    """
    tracker = Tracker(emap)
    steps = ([(f'{prefix}start_history_m3[{i}]', v) for i, v in
              enumerate(profile.start_history)] if profile.start_history
             else [(f'{prefix}start_injected_m3', profile.start_injected)])
    for key, volume in steps:
        try:
            tracker.move(volume)
        except DomainError as err:
            raise ProgrammeError(key, beyond_domain(volume, err, emap, names)) from None
    return tracker


def beyond_domain(target: float, err: DomainError, emap: EquilibriumMap,
                  names: Sequence[str], in_cycle: str = '') -> str:
    """Why ``target`` [m^3] is refused: where the domain ends, and which segment ends it."""
    if err.edge_injected is None or err.edge_volumes is None:
        return f"{target:g} m^3{in_cycle} is outside the equilibrium's domain ({err})"
    # The segment at the end of its model: nearest to an end of its volume range, relatively.
    volumes = np.asarray(err.edge_volumes, dtype=float)
    rest, full = np.asarray(emap.rest_volumes), np.asarray(emap.max_volumes)
    at_rest = volumes - rest <= emap.tolerances.same_volume * (full - rest)
    if target < err.edge_injected and np.all(at_rest):
        return (f"{target:g} m^3{in_cycle} is below the equilibrium's domain: it starts at "
                f'{err.edge_injected:.6g} m^3 injected, every segment at its rest volume')
    segment = int(np.argmin(np.minimum(full - volumes, volumes - rest) / (full - rest)))
    if full[segment] - volumes[segment] <= volumes[segment] - rest[segment]:
        reaches = f'the end of its curve ({full[segment]:.6g} m^3)'
    else:
        reaches = f'its rest volume ({rest[segment]:.6g} m^3)'
    return (f"{target:g} m^3{in_cycle} is beyond the equilibrium's domain: segment "
            f'{names[segment]} reaches {reaches} first, at {err.edge_injected:.6g} m^3 '
            f'injected ({err.edge_injected * 1e6:.4g} mL)')


def check_scene_reach(scene: Scene, emap: EquilibriumMap) -> None:
    """:func:`check_reach` for the scene's own programme; the refusal names the scene file."""
    try:
        check_reach(require_syringe(scene, 'a volume programme').profile, emap,
                    scene.segment_names, 'pump.')
    except ProgrammeError as err:
        raise SceneError(f'{scene.path if scene.path is not None else "<scene>"}: {err}') \
            from None
