"""
A candidate pair judged: the assembly's numbers for it, and its score against the target.

The assembly of the two segments (:func:`softseq_ros.fem.assembly.pair_metrics`) is the inner
model; the score is the sum of squared errors over their tolerances, plus a penalty for a
wrong sequence type or leader.
"""

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from softseq_ros.fem.assembly import pair_metrics
from softseq_ros.fem.design_problem import Target
from softseq_ros.quasistatic.sequence import sequence_type

# A design whose sequence or leader is wrong scores at least this (a met design scores < n).
MISMATCH_PENALTY = 100.0


@dataclass
class Evaluation:
    """One candidate pair: its parameters, predicted numbers, score and whether it meets."""

    material: int
    values: list[dict[str, float]]
    metrics: dict[str, Any]
    score: float
    meets: bool
    errors: dict[str, float] = field(default_factory=dict)


def inflation_sequence(metrics: dict[str, Any]) -> str:
    """The sequence type from the inflation path alone (no snap: the same path back)."""
    from softseq_ros.fem.assembly import share_of_inflow

    path = metrics['path']
    return sequence_type(bool(path.events), 0.0, 1.0, share_of_inflow(path))


def judge(target: Target, metrics: dict[str, Any], sequence: str
          ) -> tuple[float, bool, dict[str, float]]:
    """Score (sum of squared errors in tolerances, plus penalties) and whether it meets."""
    errors: dict[str, float] = {}
    score = 0.0
    meets = True
    if sequence != target.sequence:
        score += MISMATCH_PENALTY
        meets = False
    if target.leader is not None and metrics['leader'] != target.leader:
        score += MISMATCH_PENALTY
        meets = False
    checks = [('switch_injected_m3', target.switch, metrics.get('switch_injected_m3')),
              ('plateau_pressure_pa', target.plateau, metrics.get('plateau_pressure_pa')),
              ('plateau_from_m3', target.plateau_from, metrics.get('plateau_from_m3'))]
    if target.tip_distance is not None:
        checks.append(('tip_distance_m', target.tip_distance, metrics.get('tip_distance_m')))
    for key, tolerance, got in checks:
        if tolerance is None:
            continue
        error = tolerance.error(got)
        errors[key] = error
        score += min(error * error, MISMATCH_PENALTY)
        meets = meets and abs(error) <= 1.0
    return score, meets, errors


def predict(target: Target, segments: list[Any], full: bool = False) -> dict[str, Any]:
    """The assembly's numbers for a pair (``full``: classified from inflation and deflation)."""
    volumes = (target.tip_at_m3 * 1e6,) if target.tip_at_m3 is not None else ()
    metrics = pair_metrics(segments, target.max_injected_m3, samples=401,
                           with_sequence=full, report_volumes_ml=volumes)
    if target.tip_at_m3 is not None:
        i = int(np.argmin(np.abs(metrics['history_m3'] - target.tip_at_m3)))
        metrics['tip_distance_m'] = float(np.hypot(*metrics['tip_m'][i]))
    if not full:
        metrics['sequence'] = inflation_sequence(metrics)
    return metrics


def plain_metrics(metrics: dict[str, Any]) -> dict[str, Any]:
    """A pair's numbers worth writing down, as plain Python values."""
    keep = ('sequence', 'leader', 'switch_injected_m3', 'plateau_pressure_pa',
            'plateau_from_m3', 'min_share', 'tip_distance_m', 'snap_throughs')
    return {k: (float(v) if isinstance(v, (float, np.floating)) else v)
            for k, v in metrics.items() if k in keep}
