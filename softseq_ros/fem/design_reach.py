"""
What the parameter ranges of a problem can reach, checked before the grid and the search.

A target outside is refused naming the bound and the parameter to widen: the tip's reach
needs no FEM (at most the actuator's length); the plateau pressure and the plateau's start are
bounded soundly from each segment's softest and stiffest corner (:mod:`.bounds`: the premise
that thicker membranes and walls stiffen and a longer membrane softens, and envelopes for
curves with peaks). The corners are grid points: when some are not cached the command says so
before computing them, and the search reuses them. The switch, the leader and the sequence
type are not bounded (they follow from slopes, not levels); what the corner pairs do is shown
beside the bounds.
"""

from dataclasses import dataclass, field
import itertools
import math
from pathlib import Path
from typing import Any, Callable

import numpy as np

from softseq_ros.fem.design_evaluation import plain_metrics, predict
from softseq_ros.fem.design_grid import corner_designs, corner_values, ensure_tables
from softseq_ros.fem.design_interpolation import membrane_count, read_cell
from softseq_ros.fem.design_problem import Problem, SegmentSpace, Tolerance
from softseq_ros.scene.design import Design, DesignError, cache_path


class ReachError(DesignError):
    """A target outside what the parameter ranges can reach."""


@dataclass
class Reach:
    """What the parameter ranges can reach (docs/fem.md, 'What the ranges reach')."""

    bounds: dict[str, tuple[float, float]]     # sound: no design in the ranges lies outside
    corner_pairs: list[dict[str, Any]] = field(default_factory=list)   # what they do; no bound
    notes: list[str] = field(default_factory=list)    # what the check cannot prove, and why
    fem_runs: int = 0


# What the check cannot bound, and why (the target's other numbers).
NOT_BOUNDED = ('switch_injected_m3, leader and sequence: they follow from the slopes of both '
               'curves, not their levels, and move either way with each parameter (a thicker '
               'top membrane raises the level at which the top takes over, a thicker bottom one '
               'hands the top more of the fluid from the start); the corner pairs show what the '
               'ranges do at their ends, not a bound')
TIP_NOTE = ("tip_distance_m: at most the actuator's length (the chord of the backbone); the "
            'curvatures at a volume depend on how the pair splits it, so the corners bound '
            'nothing closer')


def _where(problem: Problem) -> str:
    return str(problem.path or '<design problem>')


def check_closed_form(problem: Problem) -> dict[str, tuple[float, float]]:
    """The bounds that need no FEM (the tip's reach); ReachError for a target beyond them."""
    lengths = [segment.design.geometry.length_m for segment in problem.segments]
    total = sum(lengths)
    tip = problem.target.tip_distance
    if tip is not None and tip.value - tip.tolerance > total:
        raise ReachError(
            f'{_where(problem)}: target.tip_distance_m: {tip.value:g} m (within '
            f'{tip.tolerance:g}) is beyond what any design reaches: the tip is at most the '
            f"actuator's length from its base, {total:g} m (the segments' length_m, "
            f'{" + ".join(f"{v:g}" for v in lengths)}, which the ranges do not vary); a longer '
            f'reach needs longer segment designs')
    return {'tip_distance_m': (0.0, total)}


def _membrane_counts(segment: SegmentSpace) -> tuple[int, int]:
    """The fewest and the most membranes a segment of the ranges has."""
    lo, hi = segment.ranges.get('membrane_length_m', (None, None))
    if lo is None:
        return (segment.design.geometry.membranes,) * 2
    return (membrane_count(segment.design, {'membrane_length_m': hi}),
            membrane_count(segment.design, {'membrane_length_m': lo}))


def _corners_text(problem: Problem, which: str) -> str:
    parts = [f'{segment.name}: ' + ', '.join(f'{k} {v:g}' for k, v in
                                              corner_values(segment, which).items())
             for segment in problem.segments if segment.varied]
    return '; '.join(parts) or 'every segment as designed'


def _widen_text(problem: Problem, which: str) -> str:
    parts = []
    for segment in problem.segments:
        for k in segment.varied:
            lo, hi = segment.ranges[k]
            up = (which == 'stiff') != (k == 'membrane_length_m')
            parts.append(f'{segment.name} {k} {"above" if up else "below"} {hi if up else lo:g}')
    return ('widen ' + ', '.join(parts)) if parts else \
        'nothing varies: give a range under vary, or another material fit'


def _ranges_text(problem: Problem) -> str:
    parts = [f'{segment.name} {k} [{segment.ranges[k][0]:g}, {segment.ranges[k][1]:g}]'
             for segment in problem.segments for k in segment.varied]
    return ('widen the ranges at either end (' + '; '.join(parts) + ')') if parts else \
        'nothing varies: give a range under vary, or another material fit'


def _outside(tolerance: Tolerance | None, lo: float, hi: float) -> str | None:
    """'above' or 'below' when no value within the tolerance lies in [lo, hi]."""
    if tolerance is None:
        return None
    if tolerance.value - tolerance.tolerance > hi:
        return 'above'
    if tolerance.value + tolerance.tolerance < lo:
        return 'below'
    return None


def pressure_reach(problem: Problem, cells: dict[tuple[int, int, str], tuple[np.ndarray,
                                                                               np.ndarray]]
                   ) -> tuple[dict[str, tuple[float, float]], list[str]]:
    """
    Sound bounds on the plateau pressure and the plateau's start, and notes.

    From the corner cells ((segment, material, 'soft' or 'stiff') -> (cell injected volumes,
    pressures)); none when the corners contradict the premise (:mod:`softseq_ros.fem.bounds`).
    """
    from softseq_ros.fem.assembly import PLATEAU_BAND
    from softseq_ros.fem.bounds import premise_violation, pressure_band, segment_envelope

    target = problem.target
    v_max = target.max_injected_m3
    counts = [_membrane_counts(segment) for segment in problem.segments]
    # The path reaches at least this far (the interpolated segments' capacity may fall short).
    v_end = min(v_max, 0.999 * sum(v_max * fewest / most for fewest, most in counts))
    totals = np.unique(np.append(np.linspace(0.0, v_max, 401), v_end))
    step = v_max / 400       # the assembled path's sampling (predict: 401 samples)
    plateaus, starts, notes = [], [], []
    for m, material in enumerate(problem.materials):
        envelopes = []
        for s, segment in enumerate(problem.segments):
            soft, stiff = cells[(s, m, 'soft')], cells[(s, m, 'stiff')]
            excess, at = premise_violation(soft, stiff)
            if excess > 0:
                notes.append(f'the premise fails at the corners of {segment.name} '
                             f"({material.law}): the stiff corner's pressure is {excess:.0f} Pa "
                             f"below the soft one's at {at * 1e9:.0f} uL per cell, so no "
                             'pressure bound is claimed')
                return {}, notes
            envelopes.append(segment_envelope(soft, stiff, *counts[s], v_max))
        p_low, p_high = pressure_band(envelopes, totals)
        # The path passes every volume up to its end: its plateau is above each P_low there.
        lowest = float(p_low[totals <= v_end].max())
        highest = float(p_high[-1])
        plateaus.append((lowest, highest))
        # The plateau's start: where the pressure first comes within the band of its plateau.
        reach = np.nonzero(p_high >= (1 - PLATEAU_BAND) * lowest)[0]
        earliest = float(totals[max(reach[0] - 1, 0)]) if reach.size else 0.0
        sure = np.nonzero(p_low >= (1 - PLATEAU_BAND) * highest)[0]
        latest = min(float(totals[sure[0]]) + step, v_max) if sure.size else v_max
        starts.append((earliest, latest))
    # Outward to the 0.1 Pa the assembly's numbers are rounded to (what the target is judged by).
    bounds = {'plateau_pressure_pa': (math.floor(10 * min(lo for lo, _ in plateaus)) / 10,
                                      math.ceil(10 * max(hi for _, hi in plateaus)) / 10),
              'plateau_from_m3': (min(lo for lo, _ in starts), max(hi for _, hi in starts))}
    return bounds, notes


def corner_pairs(problem: Problem, paths: dict[str, Path],
                 corners: list[tuple[int, int, str, Design]]) -> list[dict[str, Any]]:
    """What each pair of corners does (assembled): information beside the bounds, no bound."""
    from softseq_ros.scene.tables import read_table

    designs = {(s, m, which): d for s, m, which, d in corners}
    out, seen = [], set()
    for m, material in enumerate(problem.materials):
        for whiches in itertools.product(('soft', 'stiff'), repeat=len(problem.segments)):
            pair = [designs[(s, m, w)] for s, w in enumerate(whiches)]
            key = tuple(d.digest() for d in pair)
            if key in seen:
                continue
            seen.add(key)
            segments = [read_table(paths[d.digest()], name=segment.name,
                                   length=d.geometry.length_m)
                        for d, segment in zip(pair, problem.segments)]
            try:
                metrics = predict(problem.target, segments)
            except Exception as err:  # noqa: BLE001 (a pair the assembly cannot solve)
                out.append({'material': material.law, 'corners': list(whiches),
                            'error': str(err)})
                continue
            out.append({'material': material.law, 'corners': list(whiches),
                        **{k: v for k, v in plain_metrics(metrics).items()
                           if k not in ('min_share', 'snap_throughs')}})
    return out


def check_reach(problem: Problem, cache_dir: Path | None, workers: int,
                scheduler: str | None, progress: Callable[[str], None] | None,
                announce: Callable[[str], None] | None = None) -> Reach:
    """
    What the ranges reach; ReachError for a target outside (docs/fem.md).

    First what needs no FEM (the tip's reach), then the corners' unit cells (said beforehand
    when some must be computed; grid points all, cached, so the search reuses them).
    """
    bounds = check_closed_form(problem)
    corners = corner_designs(problem)
    unique = list({d.digest(): d for *_, d in corners}.values())
    missing = sum(not cache_path(d, cache_dir).is_file() for d in unique)
    if missing and announce is not None:
        announce(f'reach: {missing} of the {len(unique)} corner designs must be computed before '
                 "the target can be checked against the ranges (unit cells on the search's "
                 'mesh; grid points all, so the search reuses them)')
    paths, runs = ensure_tables(unique, cache_dir, workers, scheduler, progress,
                                'reach (corners)')
    cells = {(s, m, which): read_cell(paths[d.digest()], d)[1:3]
             for s, m, which, d in corners}
    pressure, notes = pressure_reach(problem, cells)
    bounds.update(pressure)
    notes += [NOT_BOUNDED, TIP_NOTE]
    target = problem.target
    if 'plateau_pressure_pa' in pressure:
        lo, hi = pressure['plateau_pressure_pa']
        side = _outside(target.plateau, lo, hi)
        if side is not None:
            which = 'stiff' if side == 'above' else 'soft'
            limit = f'at most {hi:.0f}' if side == 'above' else f'at least {lo:.0f}'
            raise ReachError(
                f'{_where(problem)}: target.plateau_pressure_pa: {target.plateau.value:g} Pa '
                f'(within {target.plateau.tolerance:g}) is {side} what the ranges reach: '
                f'{limit} Pa, both segments at their {which}est corners '
                f'({_corners_text(problem, which)}); {_widen_text(problem, which)}')
        lo, hi = pressure['plateau_from_m3']
        side = _outside(target.plateau_from, lo, hi)
        if side is not None:
            first = (f"from {hi * 1e6:.1f} mL on at the latest (there the softest corners' "
                     "lowest pressure is within 1 % of the stiffest corners' highest plateau)"
                     if side == 'above' else
                     f'from {lo * 1e6:.1f} mL on at the earliest (before it the stiffest '
                     "corners' highest pressure stays below 99 % of the softest corners' "
                     'lowest plateau)')
            raise ReachError(
                f'{_where(problem)}: target.plateau_from_m3: {target.plateau_from.value * 1e6:g} '
                f'mL (within {target.plateau_from.tolerance * 1e6:g}) is '
                f'{"later" if side == "above" else "earlier"} than the ranges reach: the '
                f'pressure is within 1 % of its plateau {first}; {_ranges_text(problem)}')
    return Reach(bounds=bounds, corner_pairs=corner_pairs(problem, paths, corners),
                 notes=notes, fem_runs=runs)


def reach_text(reach: Reach) -> str:
    """The reach in one line for people: the bounds, and what the corner pairs do."""
    b = reach.bounds
    parts = []
    if 'plateau_pressure_pa' in b:
        lo, hi = b['plateau_pressure_pa']
        parts.append(f'plateau {lo:.0f} to {hi:.0f} Pa')
        lo, hi = b['plateau_from_m3']
        parts.append(f'plateau from {lo * 1e6:.1f} to {hi * 1e6:.1f} mL')
    parts.append(f'tip at most {b["tip_distance_m"][1] * 1e3:.0f} mm from the base')
    pairs = [p for p in reach.corner_pairs if 'error' not in p]
    seen = []
    if pairs:
        switches = sorted({round(p['switch_injected_m3'] * 1e6, 1) for p in pairs
                           if p.get('switch_injected_m3') is not None})
        found = (f'{switches[0]:.1f} to {switches[-1]:.1f} mL' if len(switches) > 1 else
                 f'{switches[0]:.1f} mL' if switches else '')
        if any(p.get('switch_injected_m3') is None for p in pairs):
            found = f'{found} or none' if found else 'none'
        seen.append(f'switch {found}')
        seen.append('leader ' + '/'.join(sorted({p['leader'] for p in pairs})))
        seen.append('sequence ' + '/'.join(sorted({p['sequence'] for p in pairs})))
    text = 'reach of the ranges: ' + ', '.join(parts)
    if seen:
        text += f'; not bounded, the corner pairs give: {", ".join(seen)}'
    return text
