"""
What ``softseq fit`` writes: fit.json, segment.csv, fit.png and segment_unloading.csv.

Each is described in docs/fit.md; the last only where the files hold deflations.

- ``fit.json``: every number of :class:`~softseq_ros.segments.fit.MembraneFit`, SI units: each
  inflation's noise, per law its parameters with standard errors, Jacobian and bootstrap
  95 % intervals, chi-square, AICc, BIC, Akaike weight, and the law chosen.
- ``segment.csv``: the chosen law's curve as a segment table (``volume_m3,pressure_pa,
  curvature_per_m``), read by :func:`softseq_ros.scene.tables.read_table` as any other; its
  ``#`` lines say where it comes from (the files, the noise, the law and its intervals) and
  give its ``length_m``, as ``softseq library`` reads it.
- ``segment_unloading.csv``: where the files hold deflations, the unloading branch's chosen
  curve, as segment.csv is the loading branch's: a scene runs with either.
- ``cleaned.csv``: the measured rows themselves, smoothed by the project's table smoothing
  (which keeps peaks and valleys where they are) with the noise estimated from the raw rows,
  and each row's uncertainty band; a segment table too. ``cleaned_unloading.csv`` likewise for
  the deflations.
- ``fit.png``: the measured rows, each law's curve, and below their residuals beside the
  noise, in the report's figure styles; with deflations, their rows and the unloading curve.
"""

import json
import math
from pathlib import Path
from typing import Sequence

import numpy as np

from softseq_ros.analysis.figures import (
    COLUMN_IN,
    KPA,
    ML,
    PAPER,
    SEGMENT_COLOURS,
    FigureStyle,
    legend_below,
    new_figure,
    save_figure,
)
from softseq_ros.errors import write_text
from softseq_ros.segments.fit import CycleFit, Estimate, MembraneFit, Sphere
from softseq_ros.segments.smoothing import smooth_table_deviation

FIT_JSON = 'fit.json'
SEGMENT_CSV = 'segment.csv'
UNLOADING_CSV = 'segment_unloading.csv'
CLEANED_CSV = 'cleaned.csv'
CLEANED_UNLOADING_CSV = 'cleaned_unloading.csv'
# The cleaned table's band: its pressure +- this many of its rows' deviations. The deviation
# is the noise left after the local fit, not the fit's bias, which the smoothing keeps below
# it but not at 0: two deviations held the truth on 90 % of the rows of a noisy Gent curve
# on average (some seeds 60 %), three on 98 % (docs/fit.md).
BAND_DEVIATIONS = 3.0
FIT_PNG = 'fit.png'
# The laws' colours in the figure, one each, always the same.
LAW_COLOURS = {'neo_hookean': SEGMENT_COLOURS[3], 'mooney_rivlin': SEGMENT_COLOURS[1],
               'gent': SEGMENT_COLOURS[0], 'ogden': SEGMENT_COLOURS[2]}
LAW_LABELS = {'neo_hookean': 'neo-Hookean', 'mooney_rivlin': 'Mooney-Rivlin', 'gent': 'Gent',
              'ogden': 'Ogden'}
MEASURED_MARKERS = ('o', 's', '^', 'v', 'D')
CURVE_POINTS = 400
UNLOADING_COLOUR = '#D55E00'
MJ = 1e3


def write_fit_outputs(fit: MembraneFit | CycleFit, out: Path, length: float | None = None,
                      style: FigureStyle = PAPER) -> list[Path]:
    """
    fit.json, segment.csv and fit.png of ``fit`` in the folder ``out`` (made when missing).

    With deflations (a :class:`CycleFit`) also segment_unloading.csv, and the unloading
    fit and the hysteresis in fit.json and fit.png. ``length`` [m]: the segment's, for the
    tables' ``# length_m:`` line (default: the sphere's diameter, or the bulge's holes side by
    side). A failed write is one line
    naming the file.
    """
    out.mkdir(parents=True, exist_ok=True)
    loading = fit.loading if isinstance(fit, CycleFit) else fit
    report = loading.to_dict()
    written = [out / FIT_JSON, out / SEGMENT_CSV]
    tables = [segment_table_text(loading, length)]
    if isinstance(fit, CycleFit):
        unloading = fit.unloading.to_dict()
        unloading['deflations'] = unloading.pop('inflations')
        report['unloading'] = unloading
        report['hysteresis'] = fit.hysteresis.to_dict()
        written.append(out / UNLOADING_CSV)
        tables.append(segment_table_text(fit.unloading, length, branch='deflation'))
    written.append(out / CLEANED_CSV)
    tables.append(cleaned_table_text(loading, length))
    if isinstance(fit, CycleFit):
        written.append(out / CLEANED_UNLOADING_CSV)
        tables.append(cleaned_table_text(fit.unloading, length, branch='deflation'))
    write_text(written[0], json.dumps(finite_json(report), indent=1, allow_nan=False) + '\n')
    for path, text in zip(written[1:], tables):
        write_text(path, text)
    written.append(out / FIT_PNG)
    plot_fit(fit, written[-1], style)
    return written


def finite_json(value: object) -> object:
    """``value`` with every number that JSON cannot hold (inf, nan) as None."""
    if isinstance(value, dict):
        return {key: finite_json(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_json(item) for item in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def estimate_text(estimate: Estimate) -> str:
    """A number with its two intervals, on one line: '30010 (95 % CI 29840 to 30170; ...)'."""
    low, high = estimate.interval
    text = f'{estimate.value:.6g} (95 % CI {low:.6g} to {high:.6g}'
    if estimate.bootstrap is not None:
        text += f'; bootstrap {estimate.bootstrap[0]:.6g} to {estimate.bootstrap[1]:.6g}'
    return text + ')'


def segment_table_text(fit: MembraneFit, length: float | None = None,
                       branch: str = 'inflation') -> str:
    """
    The chosen law's curve as a segment table, its provenance in ``#`` lines.

    ``branch``: what was fitted, ``inflation`` (the loading branch) or ``deflation`` (the
    unloading branch, its rows read in rising volume).
    """
    best = fit.best
    volume, pressure = fit.table()
    length = fit.geometry.default_length(best) if length is None else length
    sources = ', '.join(f'{i.source} ({i.volume.size} rows, noise {s:.6g} Pa)'
                        for i, s in zip(fit.inflations, fit.noise_std))
    lines = [
        f'# softseq fit: the {best.law.name} law on {fit.geometry.description}, fitted to '
        'measured '
        + ('inflations' if branch == 'inflation' else 'deflations (the unloading branch)')
        + ' (docs/fit.md); rows from its closed form',
        f'# source: {sources}',
        f'# measured_noise_std_pa: {fit.pooled_noise_std:.6g} (pooled; each {branch}' + "'s from "
        'its raw rows)',
        f'# noise_std_pa: {fit.table_noise_std():.6g} (the uncertainty of these rows at their '
        "peaks and valleys: the fitted curve's standard error, from the fit's covariance)",
        f'# fit: {best.law.name} chosen by AICc (BIC: {fit.by_bic()}), reduced chi-square '
        f'{best.reduced_chi_square:.4g}, {best.rows} rows, weighted least squares',
    ]
    for name, estimate in best.estimates.items():
        lines.append(f'# {name}: {estimate_text(estimate)}'
                     + ('' if estimate.fitted else ' (derived)'))
    lines += fit.geometry.given_lines()
    if fit.thickness is not None:
        lines.append(f'# thickness_m: {fit.thickness:.6g} (given)')
    if isinstance(fit.geometry, Sphere):
        lines.append('# curvature_per_m: 0 (a sphere does not bend)')
    else:
        lines.append('# curvature_per_m: 0 (p(v) says nothing of how the segment bends: give it '
                     'a curvature of its own)')
    lines.append(f'# length_m: {length!r}')
    lines.append('volume_m3,pressure_pa,curvature_per_m')
    lines += [f'{v!r},{p!r},0.0' for v, p in zip(volume.tolist(), pressure.tolist())]
    return '\n'.join(lines) + '\n'


def cleaned_rows(fit: MembraneFit) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                             np.ndarray | None]:
    """
    The measured rows smoothed: volumes [m^3], pressures and their deviations [Pa], curvature.

    Every inflation's rows together in rising volume (rows of one volume in several files
    become their mean), smoothed by :func:`~softseq_ros.segments.smoothing.smooth_table` with
    the pooled noise the fit estimated from the raw rows. The curvature [1/m] is the rows' own,
    as measured (their mean at one volume), where every inflation has one; else None.
    """
    volume = np.concatenate([i.volume for i in fit.inflations])
    pressure = np.concatenate([i.pressure for i in fit.inflations])
    volume, index = np.unique(volume, return_inverse=True)
    counts = np.bincount(index)
    pressure = np.bincount(index, weights=pressure) / counts
    curvature = None
    if all(i.curvature is not None for i in fit.inflations):
        measured = np.concatenate([i.curvature for i in fit.inflations])
        curvature = np.bincount(index, weights=measured) / counts
    smoothed, deviation = smooth_table_deviation(volume, pressure, fit.pooled_noise_std)
    return volume, smoothed, deviation, curvature


def cleaned_table_text(fit: MembraneFit, length: float | None = None,
                       branch: str = 'inflation') -> str:
    """
    The measured rows smoothed, with their band, as a segment table (docs/fit.md).

    Columns ``volume_m3,pressure_pa,curvature_per_m`` as every segment table's, then
    ``pressure_std_pa`` and the band ``pressure_low_pa``, ``pressure_high_pa``
    (:data:`BAND_DEVIATIONS` deviations either side).
    """
    volume, pressure, deviation, curvature = cleaned_rows(fit)
    length = fit.geometry.default_length(fit.best) if length is None else length
    sources = ', '.join(f'{i.source} ({i.volume.size} rows, noise {s:.6g} Pa)'
                        for i, s in zip(fit.inflations, fit.noise_std))
    turning = np.flatnonzero(np.diff(np.sign(np.diff(pressure)))) + 1
    feature_deviation = float(np.max(deviation[turning] if turning.size else deviation))
    lines = [
        '# softseq fit: the measured '
        + ('inflations' if branch == 'inflation' else 'deflations (the unloading branch)')
        + ' cleaned: their rows smoothed by the table smoothing, which keeps peaks and valleys '
        'where they are (softseq_ros/segments/smoothing.py; docs/fit.md)',
        f'# source: {sources}',
        f'# measured_noise_std_pa: {fit.pooled_noise_std:.6g} (pooled; each {branch}' + "'s from "
        'its raw rows; the smoothing used it)',
        f"# noise_std_pa: {feature_deviation:.6g} (the largest pressure_std_pa at these rows' "
        'peaks and valleys, or along them when they have none)',
        '# pressure_std_pa: the noise times the leverage of the local quadratic each row was '
        "fitted with (the noise left in the row; not the fit's bias)",
        f'# pressure_low_pa, pressure_high_pa: pressure_pa -+ {BAND_DEVIATIONS:g} pressure_std_pa',
        ('# curvature_per_m: as measured with the rows, not smoothed' if curvature is not None
         else '# curvature_per_m: 0 (no curvature was measured with the rows: give the segment '
         'a curvature of its own)'),
        f'# length_m: {length!r}',
        'volume_m3,pressure_pa,curvature_per_m,pressure_std_pa,pressure_low_pa,pressure_high_pa',
    ]
    band = BAND_DEVIATIONS * deviation
    bend = np.zeros(volume.size) if curvature is None else curvature
    lines += [f'{v!r},{p!r},{k!r},{d!r},{p - b!r},{p + b!r}'
              for v, p, k, d, b in zip(volume.tolist(), pressure.tolist(), bend.tolist(),
                                       deviation.tolist(), band.tolist())]
    return '\n'.join(lines) + '\n'


def plot_fit(fit: MembraneFit | CycleFit, out: Path, style: FigureStyle = PAPER) -> list[Path]:
    """
    fit.png: the rows and each law's curve above, their residuals below (kPa, mL).

    With deflations, their rows (filled markers) and the unloading branch's chosen curve and
    residuals too.
    """
    with style.context():
        return _plot_fit(fit, out, style)


def _plot_fit(cycle: MembraneFit | CycleFit, out: Path, style: FigureStyle) -> list[Path]:
    fit = cycle.loading if isinstance(cycle, CycleFit) else cycle
    fig, axes = new_figure(*style.size(COLUMN_IN, 3.6), rows=2, sharex=True,
                           margins={'left': 0.16, 'right': 0.97, 'top': 0.97, 'bottom': 0.2,
                                    'hspace': 0.08},
                           gridspec_kw={'height_ratios': (2.2, 1.0)})
    curve_ax, residual_ax = axes[0, 0], axes[1, 0]
    handles = []
    for k, (inflation, sigma) in enumerate(zip(fit.inflations, fit.noise_std)):
        marker = MEASURED_MARKERS[k % len(MEASURED_MARKERS)]
        grey = str(0.35 + 0.3 * (k % 3) / 2)
        (line,) = curve_ax.plot(inflation.volume * ML, inflation.pressure * KPA, marker,
                                ls='none', ms=2.6, mfc='none', mew=0.6, color=grey, zorder=1,
                                label=f'{Path(inflation.source).name} ({sigma:.3g} Pa noise)')
        handles.append(line)
    volume = np.concatenate([i.volume for i in fit.inflations])
    pressure = np.concatenate([i.pressure for i in fit.inflations])
    grid = np.linspace(float(volume.min()), float(volume.max()), CURVE_POINTS)
    for name, law in fit.laws.items():
        chosen = name == fit.chosen
        colour = LAW_COLOURS.get(name, '#000000')
        label = (f'{LAW_LABELS.get(name, name)}: '
                 + ('chosen' if chosen else f'$\\Delta$AICc {law.aicc - fit.best.aicc:.3g}')
                 + f', $\\chi^2_\\nu$ {law.reduced_chi_square:.3g}')
        (line,) = curve_ax.plot(grid * ML, law.pressure(grid) * KPA, color=colour,
                                lw=1.6 if chosen else 0.9, ls='-' if chosen else (0, (4, 2)),
                                zorder=3 if chosen else 2, label=label)
        handles.append(line)
        residual_ax.plot(volume * ML, (pressure - law.pressure(volume)) * KPA, '.',
                         ms=2.0 if chosen else 1.4, color=colour, zorder=3 if chosen else 2)
    worst = float(np.max(np.abs(pressure - fit.best.pressure(volume)))) * KPA
    if isinstance(cycle, CycleFit):
        handles += _plot_unloading(cycle, curve_ax, residual_ax)
        unloading = cycle.unloading
        volume = np.concatenate([i.volume for i in unloading.inflations])
        pressure = np.concatenate([i.pressure for i in unloading.inflations])
        worst = max(worst, float(np.max(np.abs(pressure - unloading.best.pressure(volume))))
                    * KPA)
    band = 2.0 * fit.pooled_noise_std * KPA
    residual_ax.axhspan(-band, band, color='0.88', lw=0, zorder=0)
    residual_ax.axhline(0.0, color='0.5', lw=0.5, zorder=1)
    # The residuals within a few noise deviations fill the panel; a law far off leaves it.
    reach = max(3.0 * band, 1.3 * worst)
    residual_ax.set_ylim(-reach, reach)
    curve_ax.set_ylabel('gauge pressure [kPa]')
    residual_ax.set_ylabel('residual [kPa]')
    residual_ax.set_xlabel('segment volume [mL]')
    for ax in (curve_ax, residual_ax):
        ax.grid(alpha=0.3)
    handles.append(_band_handle(band))
    legend_below(fig, handles, ncol=1)
    shape = 'a sphere' if isinstance(fit.geometry, Sphere) else 'a bulge'
    title = f'Membrane laws fitted to {shape}; {fit.chosen} chosen by AICc'
    if isinstance(cycle, CycleFit):
        title += (f'; loop {cycle.hysteresis.dissipated.value * MJ:.3g} mJ, unloading '
                  f'{cycle.unloading.chosen}')
    style.title(curve_ax, title)
    return save_figure(fig, out, False, style)


def _plot_unloading(cycle: CycleFit, curve_ax: object, residual_ax: object) -> list:
    """The deflations' rows and the unloading branch's chosen curve and residuals."""
    unloading = cycle.unloading
    handles = []
    for k, (deflation, sigma) in enumerate(zip(unloading.inflations, unloading.noise_std)):
        marker = MEASURED_MARKERS[k % len(MEASURED_MARKERS)]
        (line,) = curve_ax.plot(deflation.volume * ML, deflation.pressure * KPA, marker,
                                ls='none', ms=2.2, mew=0, color=UNLOADING_COLOUR, alpha=0.45,
                                zorder=1, label=f'{Path(deflation.source).name}, deflation '
                                f'({sigma:.3g} Pa noise)')
        handles.append(line)
    best = unloading.best
    volume = np.concatenate([i.volume for i in unloading.inflations])
    pressure = np.concatenate([i.pressure for i in unloading.inflations])
    grid = np.linspace(float(volume.min()), float(volume.max()), CURVE_POINTS)
    law = LAW_LABELS.get(unloading.chosen, unloading.chosen)
    (line,) = curve_ax.plot(grid * ML, best.pressure(grid) * KPA, color=UNLOADING_COLOUR,
                            lw=1.6, ls=(0, (6, 1.5, 1.5, 1.5)), zorder=3,
                            label=f'unloading, {law} chosen, $\\chi^2_\\nu$ '
                            f'{best.reduced_chi_square:.3g}; loop '
                            f'{cycle.hysteresis.dissipated.value * MJ:.3g} mJ')
    handles.append(line)
    residual_ax.plot(volume * ML, (pressure - best.pressure(volume)) * KPA, '.', ms=2.0,
                     color=UNLOADING_COLOUR, zorder=3)
    return handles


def _band_handle(band_kpa: float) -> object:
    from matplotlib.patches import Patch

    return Patch(color='0.88', label=f'$\\pm$2 noise deviations ({band_kpa:.3g} kPa)')


def summary_lines(cycle: MembraneFit | CycleFit, written: Sequence[Path]) -> list[str]:
    """What ``softseq fit`` prints: the choice, each law's fit and parameters, the files.

    With deflations, then the unloading branch's chosen law and the hysteresis. The fit's
    notes (a law that did not converge, a parameter at its bound) are not among them: the
    command says those as warnings.
    """
    fit = cycle.loading if isinstance(cycle, CycleFit) else cycle
    rows = sum(i.volume.size for i in fit.inflations)
    lines = [f'{len(fit.inflations)} inflation(s), {rows} rows, noise '
             f'{fit.pooled_noise_std:.4g} Pa: {fit.chosen} chosen by AICc'
             + ('' if fit.by_bic() == fit.chosen else f' (BIC would choose {fit.by_bic()})')
             + f' -> {", ".join(str(p) for p in written)}']
    for name, law in sorted(fit.laws.items(), key=lambda item: item[1].aicc):
        lines.append(f'  {name}: reduced chi-square {law.reduced_chi_square:.4g}, delta AICc '
                     f'{law.aicc - fit.best.aicc:.4g}')
        for estimate in law.estimates.values():
            lines.append(f'    {estimate.name}: {estimate_text(estimate)}')
    if isinstance(cycle, CycleFit):
        lines += unloading_lines(cycle)
    return lines


def unloading_lines(cycle: CycleFit) -> list[str]:
    """The unloading branch's choice and parameters, and the hysteresis, in a few lines."""
    unloading, loop = cycle.unloading, cycle.hysteresis
    best = unloading.best
    rows = sum(i.volume.size for i in unloading.inflations)
    lines = [f'unloading: {len(unloading.inflations)} deflation(s), {rows} rows, noise '
             f'{unloading.pooled_noise_std:.4g} Pa: {unloading.chosen} chosen by AICc'
             + ('' if unloading.by_bic() == unloading.chosen
                else f' (BIC would choose {unloading.by_bic()})')
             + f', reduced chi-square {best.reduced_chi_square:.4g}']
    for estimate in best.estimates.values():
        lines.append(f'    {estimate.name}: {estimate_text(estimate)}')
    energy, share, softening = loop.dissipated, loop.dissipated_share, loop.softening
    lines.append(
        f'hysteresis: {energy.value * MJ:.4g} mJ dissipated per cycle (95 % CI '
        f'{energy.interval[0] * MJ:.4g} to {energy.interval[1] * MJ:.4g}), '
        f'{100.0 * share.value:.3g} % of the loading work '
        f'({100.0 * share.interval[0]:.3g} to {100.0 * share.interval[1]:.3g} %); unloading '
        f'over loading pressure {softening.value:.4g} (95 % CI {softening.interval[0]:.4g} to '
        f'{softening.interval[1]:.4g})')
    return lines
