"""
Experiment files (measured PV curves, optionally with tip positions) and their comparison.

Format (``docs/analysis.md``, example ``config/experiments/example_synthetic.csv``): ``#`` comment
lines, of which ``# pressure_kind: gauge`` or ``# pressure_kind: absolute`` declares the pressure
(and ``# ambient_pressure_pa: 101325`` the ambient to subtract from absolute readings, 101325 Pa
when absent); a header; rows. Columns: ``injected_m3`` and ``pressure_pa`` (required),
``direction`` (``inflation`` / ``deflation``; when absent, taken from whether the injected volume
rises or falls), ``tip_x_m`` and ``tip_z_m`` (per-frame tip positions in ``softseq_base``,
optional), anything else is ignored.
"""

from dataclasses import dataclass, field
import math
import os
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from softseq_ros.analysis.metrics import Trace, monotone_leg
from softseq_ros.errors import UserError
from softseq_ros.scene.csv_columns import numeric_columns, read_rows
from softseq_ros.scene.plausibility import (
    absolute_problem,
    ambient_problem,
    small_pressure_problem,
)

FloatArray = NDArray[np.float64]
# The volume shift that aligns an experiment is found to this share of the volume span.
SHIFT_XATOL = 1e-6
DEFAULT_AMBIENT_PA = 101325.0
KINDS = ('gauge', 'absolute')
REQUIRED = ('injected_m3', 'pressure_pa')
# Undeclared pressures all between these look like absolute readings of a soft actuator.
ABSOLUTE_LOOKING_PA = (80e3, 130e3)
# How far the volume shift is searched, as a share of the model's injected range.
SHIFT_SEARCH = 0.5


class ExperimentError(UserError):
    """An experiment file that cannot be used; the message names the file, row and column."""


@dataclass
class Experiment:
    """A measured curve in SI with gauge pressure."""

    path: Path
    injected: FloatArray
    pressure: FloatArray                  # gauge [Pa]
    sign: NDArray[np.int8]                # +1 inflation, -1 deflation
    tip: FloatArray | None = None         # (n, 2) x, z [m]
    pressure_kind: str = 'gauge'
    declared: bool = False
    # Whether "# ambient_pressure_pa:" was given, or absolute readings took the default.
    ambient_declared: bool = False
    warnings: list[str] = field(default_factory=list)


def _directives(lines: list[str]) -> dict[str, str]:
    found = {}
    for line in lines:
        text = line.strip()
        if text.startswith('#') and ':' in text:
            key, _, value = text[1:].partition(':')
            found[key.strip().lower()] = value.strip()
    return found


def read_experiment(path: str | os.PathLike) -> Experiment:
    """Read and check an experiment file; absolute pressures become gauge."""
    path = Path(path)
    comments, header, rows = read_rows(path, ExperimentError, 'experiment file', REQUIRED)
    directives = _directives(comments)
    for required in REQUIRED:
        if required not in header:
            raise ExperimentError(f'{path}: no column {required} in the header '
                                  f'({",".join(header)}); expected {",".join(REQUIRED)}')
    has_tip = 'tip_x_m' in header or 'tip_z_m' in header
    if has_tip and not ('tip_x_m' in header and 'tip_z_m' in header):
        raise ExperimentError(f'{path}: tip positions need both tip_x_m and tip_z_m')
    if not rows:
        raise ExperimentError(f'{path}: no rows below the header')
    tips = ('tip_x_m', 'tip_z_m') if has_tip else ()
    values = numeric_columns(path, header, rows, REQUIRED + tips, ExperimentError,
                             allow_nan=tips)
    directions: list[int] = []
    if 'direction' in header:
        index = header.index('direction')
        for number, row in enumerate(rows, start=1):
            cell = row[index].strip().lower() if index < len(row) else ''
            if cell not in ('inflation', 'deflation'):
                raise ExperimentError(f'{path}: row {number}, column direction: must be '
                                      f'inflation or deflation, got {cell or "<missing>"!r}')
            directions.append(1 if cell == 'inflation' else -1)
    injected = np.asarray(values['injected_m3'])
    pressure = np.asarray(values['pressure_pa'])
    if np.any(injected < 0.0):
        row = int(np.argmax(injected < 0.0)) + 1
        raise ExperimentError(f'{path}: row {row}, column injected_m3: must be >= 0 (m^3), got '
                              f'{injected[row - 1]:g}')
    if np.max(injected) > 0.01:
        raise ExperimentError(f'{path}: column injected_m3 reaches {np.max(injected):g}: more '
                              'than 10 L; volumes must be in m^3 (1 mL = 1e-6 m^3)')
    experiment = Experiment(path, injected, pressure, _signs(injected, directions))
    kind = directives.get('pressure_kind')
    if kind is not None:
        if kind not in KINDS:
            raise ExperimentError(f'{path}: "# pressure_kind: {kind}": must be gauge or absolute')
        experiment.pressure_kind, experiment.declared = kind, True
    if kind == 'absolute':
        try:
            ambient = float(directives.get('ambient_pressure_pa', DEFAULT_AMBIENT_PA))
        except ValueError:
            ambient = math.nan
        problem = ambient_problem(ambient) if math.isfinite(ambient) else 'not a number'
        if problem is not None:
            raise ExperimentError(f'{path}: "# ambient_pressure_pa: '
                                  f'{directives["ambient_pressure_pa"]}": {problem}')
        # Readings declared absolute in kPa (101 to 110) would become -101 kPa gauge.
        problem = absolute_problem(pressure)
        if problem is not None:
            raise ExperimentError(f'{path}: column pressure_pa (declared absolute): {problem}')
        experiment.pressure = pressure - ambient
        experiment.ambient_declared = 'ambient_pressure_pa' in directives
    else:
        problem = small_pressure_problem(pressure)
        if problem is None and np.min(pressure) < -DEFAULT_AMBIENT_PA:
            problem = (f'a gauge pressure of {np.min(pressure):.6g} Pa is below vacuum '
                       f'({-DEFAULT_AMBIENT_PA:g} Pa gauge)')
        if problem is not None:
            said = 'declared gauge' if kind else 'undeclared, read as gauge'
            raise ExperimentError(f'{path}: column pressure_pa ({said}): {problem}')
    if kind is None:
        lo, hi = ABSOLUTE_LOOKING_PA
        if np.all((pressure > lo) & (pressure < hi)):
            experiment.warnings.append(
                f'{path}: pressures lie between {pressure.min() / 1e3:.1f} and '
                f'{pressure.max() / 1e3:.1f} kPa, which looks absolute, but the file does not '
                'say; read as gauge. Declare "# pressure_kind: absolute" (or gauge).')
        else:
            experiment.warnings.append(
                f'{path}: no "# pressure_kind:" line; pressures read as gauge')
    if has_tip:
        experiment.tip = np.column_stack([values['tip_x_m'], values['tip_z_m']])
    return experiment


def _signs(injected: FloatArray, directions: list[int]) -> NDArray[np.int8]:
    if directions:
        return np.asarray(directions, dtype=np.int8)
    step = np.sign(np.diff(injected, prepend=injected[0])).astype(np.int8)
    step[0] = 1
    # A repeated volume keeps the direction before it.
    last = np.maximum.accumulate(np.where(step != 0, np.arange(step.size), 0))
    return step[last]


def _model_curves(trace: Trace) -> dict[int, tuple[FloatArray, FloatArray]]:
    up, down = trace.legs()
    curves = {1: monotone_leg(trace.injected[up], trace.pressure[up], True)}
    if down is not None and trace.injected[down].size > 2:
        curves[-1] = monotone_leg(trace.injected[down], trace.pressure[down], False)
    return curves


def _model_at(curves: dict, u: FloatArray, sign: NDArray[np.int8]) -> tuple[FloatArray,
                                                                             NDArray[np.bool_]]:
    """The model's pressure at each (u, direction), and whether u is inside the model's range."""
    result = np.full(u.size, np.nan)
    for direction in (1, -1):
        rows = sign == direction
        curve = curves.get(direction, curves[1])
        cu, cp = curve
        inside = rows & (u >= cu[0]) & (u <= cu[-1])
        result[inside] = np.interp(u[inside], cu, cp)
    return result, np.isfinite(result)


def compare(trace: Trace, experiment: Experiment, snapshots: list | None = None) -> dict:
    """
    PV error, the best volume shift and pressure scale, and per-step tip errors.

    The alignment finds ``shift`` and ``scale`` with experiment(u) ~ scale * model(u - shift)
    in the least-squares sense over the rows inside the shifted model's range.
    """
    curves = _model_curves(trace)
    u, p, sign = experiment.injected, experiment.pressure, experiment.sign
    model, inside = _model_at(curves, u, sign)
    result: dict = {'file': str(experiment.path), 'rows': int(u.size),
                    'pressure_kind_in_file': experiment.pressure_kind,
                    'pressure_kind_declared': experiment.declared,
                    'rows_outside_model_range': int(np.count_nonzero(~inside))}
    if inside.sum() < 2:
        result['pv_rmse_pa'] = result['pv_max_error_pa'] = None
    else:
        error = p[inside] - model[inside]
        result['pv_rmse_pa'] = float(np.sqrt(np.mean(error ** 2)))
        result['pv_max_error_pa'] = float(np.max(np.abs(error)))
    span = float(np.ptp(curves[1][0])) or 1e-300

    def misfit(shift: float) -> tuple[float, float, int]:
        shifted, ok = _model_at(curves, u - shift, sign)
        if ok.sum() < max(4, u.size // 4):
            return math.inf, 1.0, 0
        m, e = shifted[ok], p[ok]
        scale = float(np.dot(m, e) / max(np.dot(m, m), 1e-300))
        return float(np.sqrt(np.mean((scale * m - e) ** 2))), scale, int(ok.sum())

    from scipy.optimize import minimize_scalar  # only when a comparison is asked for

    grid = np.linspace(-SHIFT_SEARCH * span, SHIFT_SEARCH * span, 201)
    costs = [misfit(s)[0] for s in grid]
    best = int(np.argmin(costs))
    if math.isfinite(costs[best]):
        lo, hi = grid[max(best - 1, 0)], grid[min(best + 1, grid.size - 1)]
        # Where too few rows overlap the misfit is infinite; scipy's bounded search needs
        # finite values (inf - inf ends in NaN and a RuntimeWarning): a finite ceiling.
        ceiling = 1.0e6 * (costs[best] + 1.0)
        found = minimize_scalar(lambda s: min(misfit(s)[0], ceiling), bounds=(lo, hi),
                                method='bounded', options={'xatol': SHIFT_XATOL * span})
        shift = float(found.x) if found.fun <= costs[best] else float(grid[best])
        rmse, scale, used = misfit(shift)
        result['alignment'] = {'volume_shift_m3': shift, 'pressure_scale': scale,
                               'rmse_after_pa': rmse, 'rows_used': used}
    else:
        result['alignment'] = None
    result['tip_errors'] = tip_errors(experiment, snapshots or [])
    return result


def tip_errors(experiment: Experiment, snapshots: list) -> list[dict]:
    """At each snapshot, the experiment's tip at the same volume and direction, and the gap."""
    if experiment.tip is None:
        return []
    errors = []
    for shot in snapshots:
        direction = 1 if shot.direction == 'inflation' else -1
        rows = (experiment.sign == direction) & np.all(np.isfinite(experiment.tip), axis=1)
        if rows.sum() < 2:
            continue
        u = experiment.injected[rows]
        order = np.argsort(u, kind='stable')
        u, tips = u[order], experiment.tip[rows][order]
        if not (u[0] <= shot.injected <= u[-1]):
            continue
        measured = np.array([np.interp(shot.injected, u, tips[:, k]) for k in (0, 1)])
        errors.append({'step': shot.step, 'direction': shot.direction,
                       'injected_m3': shot.injected,
                       'model_tip_m': [float(x) for x in shot.tip],
                       'experiment_tip_m': [float(x) for x in measured],
                       'error_m': float(np.hypot(*(measured - shot.tip)))})
    return errors


def synthetic_experiment(trace: Trace, shift_m3: float, scale: float, rows: int = 400,
                         lengths: tuple[float, ...] | None = None,
                         tip_offset_m: tuple[float, float] = (0.0, 0.0),
                         absolute_ambient_pa: float | None = None) -> str:
    """
    A synthetic experiment file made from a model run: a known perturbation to recover.

    Rows follow the first cycle; each holds experiment(u) = scale * model(u - shift) (gauge, or
    absolute with ``absolute_ambient_pa`` added and declared). With ``lengths`` the file carries
    the tip of the same shifted state (the model's tip at u - shift), moved by ``tip_offset_m``.
    """
    from softseq_ros.segments.kinematics import backbone_batch

    up, down = trace.legs()
    legs = [(1, up)] + ([(-1, down)] if down is not None else [])
    lines = ['# SYNTHETIC experiment made from a model run (not a measurement): '
             f'experiment(u) = {scale:g} * model(u - {shift_m3:g} m^3)',
             f'# pressure_kind: {"gauge" if absolute_ambient_pa is None else "absolute"}']
    if absolute_ambient_pa is not None:
        lines.append(f'# ambient_pressure_pa: {absolute_ambient_pa:g}')
    header = ['injected_m3', 'pressure_pa', 'direction']
    if lengths is not None:
        header += ['tip_x_m', 'tip_z_m']
    lines.append(','.join(header))
    for sign, leg in legs:
        u, cols = monotone_leg(trace.injected[leg], np.column_stack(
            [trace.pressure[leg], trace.curvatures[leg] if trace.curvatures is not None
             else np.zeros((trace.injected[leg].size, 0))]), sign > 0)
        grid = np.linspace(u[0], u[-1], rows // len(legs))
        if sign < 0:
            grid = grid[::-1]
        pressure = scale * np.interp(grid, u, cols[:, 0])
        if absolute_ambient_pa is not None:
            pressure = pressure + absolute_ambient_pa
        values = [grid + shift_m3, pressure]
        if lengths is not None:
            kappa = np.column_stack([np.interp(grid, u, cols[:, 1 + j])
                                     for j in range(len(lengths))])
            points, _ = backbone_batch(kappa, lengths, points_per_segment=20)
            values += [points[:, -1, 0] + tip_offset_m[0], points[:, -1, 1] + tip_offset_m[1]]
        direction = 'inflation' if sign > 0 else 'deflation'
        for row in range(grid.size):
            if values[0][row] < 0.0:
                continue  # shifted below an empty actuator: no such measurement
            cells = [f'{values[0][row]:.9e}', f'{values[1][row]:.6f}', direction]
            cells += [f'{column[row]:.6e}' for column in values[2:]]
            lines.append(','.join(cells))
    return '\n'.join(lines) + '\n'
