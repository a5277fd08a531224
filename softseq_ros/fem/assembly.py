"""
Segment tables assembled on one syringe: the quasi-static path and the numbers a designer reads.

The assembly is the paper's: each segment's pressure-volume table, equal pressures and volumes
that add up (:mod:`softseq_ros.quasistatic`). :func:`pair_metrics` inflates it from 0 to the
programme's largest injected volume and reports what a design is judged by:

- ``sequence``: the paper's type (none, partial, symmetric, asymmetric), from the inflation and
  deflation paths (:func:`softseq_ros.quasistatic.equilibrium.classify`);
- ``leader``: the segment that takes over (the larger share of the inflow at the end);
- ``switch_injected_m3``: where the leader's share of the inflow, dv_lead/dV, is half-way
  between its first and its last value (the take-over; None when no share changes by a quarter);
- ``plateau_pressure_pa``: the largest pressure on the path, and ``plateau_from_m3`` the
  injected volume from which the pressure stays within 1 % of it;
- pressures, the top segment's share of the fluid and the tip position at the paper's steps;
- ``min_share``: the smallest share of the inflow any segment takes (below -0.02 a segment gives
  fluid back: the symmetric verdict), the margin of a partial verdict.
"""

from typing import Any, Sequence

import numpy as np

from softseq_ros.quasistatic.equilibrium import Tracker, classify
from softseq_ros.quasistatic.solve import equilibrium_map
from softseq_ros.segments.kinematics import backbone_batch

# The paper's simulated steps 3 to 5 (25, 45, 60 mL), 40 mL (its plateau) and the end.
REPORT_VOLUMES_ML = (25, 40, 45, 60, 65)
PLATEAU_BAND = 0.01


def assembled_path(segments: Sequence[Any], injected: np.ndarray,
                   resolution: int | None = None) -> tuple[Any, Any]:
    """The equilibrium map of the segments and its inflation path over ``injected`` [m^3]."""
    emap = equilibrium_map(segments, resolution)
    return emap, Tracker(emap).sweep(injected)


def share_of_inflow(path: Any) -> np.ndarray:
    """dv_i/dV along a path, one row per step (snap steps left out)."""
    dv = np.diff(np.asarray(path.volumes), axis=0)
    d_total = np.diff(np.asarray(path.injected))
    keep = ~np.asarray(path.snap)[1:] & (d_total > 0)
    return dv[keep] / d_total[keep, None]


def switch_volume(path: Any, leader: int) -> float | None:
    """Injected volume [m^3] where the leader's share of the inflow is half-way to its last."""
    share = share_of_inflow(path)
    injected = np.asarray(path.injected)[1:][~np.asarray(path.snap)[1:]
                                             & (np.diff(np.asarray(path.injected)) > 0)]
    if share.shape[0] < 3 or np.ptp(share[:, leader]) <= 0.25:
        return None
    first, last = share[0, leader], share[-1, leader]
    half = 0.5 * (first + last)
    above = np.nonzero(share[:, leader] >= half)[0] if last > first else \
        np.nonzero(share[:, leader] <= half)[0]
    return float(injected[above[0]]) if above.size else None


def tip_positions(segments: Sequence[Any], curvatures: np.ndarray) -> np.ndarray:
    """Tip (x, z) [m] of the piecewise-constant-curvature backbone, one row per state."""
    lengths = [segment.length for segment in segments]
    points, _ = backbone_batch(np.atleast_2d(curvatures), lengths, points_per_segment=1)
    return points[:, -1, :]


def pair_metrics(segments: Sequence[Any], max_injected_m3: float = 65e-6,
                 samples: int = 1301, resolution: int | None = None,
                 with_sequence: bool = True,
                 report_volumes_ml: Sequence[float] = REPORT_VOLUMES_ML) -> dict[str, Any]:
    """The design numbers of segments on one syringe, 0 -> ``max_injected_m3`` (see the module)."""
    capacity = sum(s.max_volume - s.rest_volume for s in segments)
    top_ml = min(max_injected_m3, capacity * 0.999)
    history = np.linspace(0.0, top_ml, samples)
    emap, path = assembled_path(segments, history, resolution)
    out: dict[str, Any] = {f'{s.name}_peak_pa': round(float(np.max(s.pressures)), 1)
                           for s in segments if hasattr(s, 'pressures')}
    if with_sequence:
        out['sequence'] = classify(emap)
    pressure = np.asarray(path.pressure)
    volumes = np.asarray(path.volumes)
    rest = np.array([s.rest_volume for s in segments])
    tips = tip_positions(segments, np.asarray(path.curvatures))
    last = segments[-1]
    for ml in report_volumes_ml:
        i = int(np.argmin(np.abs(history - ml * 1e-6)))
        if abs(history[i] - ml * 1e-6) < 0.5 * (history[1] - history[0]) + 1e-12:
            out[f'p_at_{ml:g}_ml_pa'] = round(float(pressure[i]), 1)
            out[f'{last.name}_share_at_{ml:g}_ml'] = round(
                float((volumes[i, -1] - rest[-1]) / max(history[i], 1e-12)), 3)
            out[f'tip_at_{ml:g}_ml_m'] = [round(float(v), 5) for v in tips[i]]
    top_index = int(np.argmax(pressure))
    out['plateau_pressure_pa'] = round(float(pressure[top_index]), 1)
    out['plateau_peak_injected_m3'] = float(history[top_index])
    near = np.nonzero(pressure >= (1 - PLATEAU_BAND) * pressure[top_index])[0]
    out['plateau_from_m3'] = float(history[near[0]])
    share = share_of_inflow(path)
    leader = int(np.argmax(share[-1])) if share.size else 0
    out['leader'] = segments[leader].name
    out['switch_injected_m3'] = switch_volume(path, leader)
    out['min_share'] = round(float(share.min()), 4) if share.size else None
    out['snap_throughs'] = len(path.events)
    out['reached_m3'] = float(history[-1])
    out['tip_m'] = tips
    out['history_m3'] = history
    out['path'] = path
    return out


def summary_numbers(metrics: dict[str, Any]) -> dict[str, Any]:
    """The metrics without the arrays (for JSON and tables)."""
    return {k: v for k, v in metrics.items() if k not in ('tip_m', 'history_m3', 'path')}
