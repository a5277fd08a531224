"""
What ``softseq scatter`` writes: scatter.json, scatter.png and summary.txt (docs/scatter.md).

- ``scatter.json``: every number of :class:`~softseq_ros.analysis.scatter.ScatterResult`, SI
  (m^3, Pa): the settings, the parameters and their distributions, every sample (its values
  and its sequence), the summary (each probability with its interval, the spread of each
  volume and pressure), whether the run stopped at the width asked for, and the Sobol indices
  per output with their intervals;
- ``scatter.png``: the sequence types' probabilities with their intervals, the switch and snap
  volumes, the plateau pressure, and the Sobol indices, in the report's figure styles;
- ``summary.txt``: what the command prints.

The files are written under temporary names beside their place and renamed into it once all
are written: a run that fails or is stopped leaves none of them half written.
"""

import json
import os
from pathlib import Path
from typing import Sequence

import numpy as np

from softseq_ros.analysis.figures import (
    KPA,
    ML,
    PAGE_IN,
    PAPER,
    SEGMENT_COLOURS,
    FigureStyle,
    legend_below,
    new_figure,
    save_figure,
)
from softseq_ros.analysis.fit_outputs import finite_json
from softseq_ros.analysis.library import TYPE_COLOURS
from softseq_ros.analysis.scatter import SEQUENCE_TYPES, ScatterResult
from softseq_ros.errors import write_text

SCATTER_JSON = 'scatter.json'
SCATTER_PNG = 'scatter.png'
SUMMARY_TXT = 'summary.txt'
# An index below this total share of the variance is not named among what matters.
MATTERS = 0.05
# Outputs drawn in the Sobol panel, at most.
SOBOL_PANEL_OUTPUTS = 5
_OUTPUT_LABELS = {'switch_injected_m3': 'switch volume', 'plateau_pressure_pa': 'plateau pressure',
                  'plateau_onset_m3': 'plateau onset', 'inflation_snap_count': 'snaps on infl.',
                  'first_inflation_snap_m3': 'first infl. snap',
                  'deflation_snap_count': 'snaps on defl.',
                  'first_deflation_snap_m3': 'first defl. snap'}


def write_scatter_outputs(result: ScatterResult, out: Path,
                          style: FigureStyle = PAPER) -> list[Path]:
    """scatter.json, scatter.png and summary.txt in ``out``, all or none (temporary names)."""
    out.mkdir(parents=True, exist_ok=True)
    final = [out / SCATTER_JSON, out / SCATTER_PNG, out / SUMMARY_TXT]
    partial = [path.with_name(f'.{path.stem}.partial{path.suffix}') for path in final]
    try:
        write_text(partial[0], json.dumps(finite_json(result.to_dict()), indent=1,
                                          allow_nan=False) + '\n')
        plot_scatter(result, partial[1], style)
        write_text(partial[2], '\n'.join(summary_lines(result, final)) + '\n')
        for temporary, path in zip(partial, final):
            os.replace(temporary, path)
    finally:
        for temporary in partial:
            if temporary.exists():
                temporary.unlink()
    return final


def _interval(p: dict) -> str:
    low, high = p['interval']
    return f'{p["probability"]:.3g} ({low:.3g} to {high:.3g})'


def _spread_text(spread: dict, scale: float, unit: str) -> str:
    q = spread['quantiles']
    low, high = spread['mean_interval']
    return (f'mean {spread["mean"] * scale:.4g} {unit} ({low * scale:.4g} to {high * scale:.4g}),'
            f' deviation {spread["std"] * scale:.3g} {unit}, middle 95 % of samples '
            f'{q["2.5"] * scale:.4g} to {q["97.5"] * scale:.4g} {unit}')


def summary_lines(result: ScatterResult, written: Sequence[Path] = ()) -> list[str]:
    """What ``softseq scatter`` prints: the types, the numbers, the stop, what matters."""
    summary = result.summary
    level = f'{result.confidence * 100:g} %'
    lines = [f'{result.scene}: {summary["samples"]} samples (seed {result.seed}), '
             f'probabilities with their {level} Wilson intervals:']
    for parameter in result.parameters:
        lines.append(f'  {parameter.name}: {parameter.distribution.describe()} (scene: '
                     f'{parameter.nominal:.6g})')
    if result.correlation is not None:
        lines.append('  correlated (their normal scores): ' + ', '.join(
            f'{a} with {b} {rho:g}' for a, b, rho in result.correlation.pairs))
    lines += [f'  note: {note}' for note in result.notes]
    types = summary['sequence_type']
    lines.append('  sequence type: ' + ', '.join(
        f'{kind} {_interval(types[kind])}' for kind in
        sorted(SEQUENCE_TYPES, key=lambda k: -types[k]['count'])))
    for key, label, scale, unit in (('switch_injected_m3', 'switch', ML, 'mL'),
                                    ('plateau_pressure_pa', 'plateau pressure', KPA, 'kPa'),
                                    ('plateau_onset_m3', 'plateau reached at', ML, 'mL')):
        found = summary[key]
        text = f'  {label}: found in {_interval(found["found"])}'
        if found['mean'] is not None:
            text += f'; {_spread_text(found, scale, unit)}'
        lines.append(text)
    for leg in ('inflation', 'deflation'):
        snaps = summary[f'{leg}_snaps']
        lines.append(f'  snap-throughs on {leg}: ' + ', '.join(
            f'{count}: {_interval(p)}' for count, p in snaps['count'].items()))
        for j, spread in enumerate(snaps['injected_m3']):
            lines.append(f'    snap {j + 1}: {_spread_text(spread, ML, "mL")}')
    stop = result.stop
    if stop['until_width'] is not None:
        verdict = ('reached' if stop['reached'] else
                   f'not reached within {stop["at_most"]} samples (--samples)')
        lines.append(f'  stop: widest interval {stop["widest_interval"]:.3g} against '
                     f'{stop["until_width"]:g} asked for: {verdict}, after '
                     f'{stop["samples"]} samples')
    else:
        lines.append(f'  widest interval {stop["widest_interval"]:.3g} after {stop["samples"]} '
                     'samples')
    if summary['unconverged_samples']:
        lines.append(f'  {summary["unconverged_samples"]} samples whose solver ran out of its '
                     'budget: their numbers may be off by more than round-off')
    lines += sobol_lines(result)
    if written:
        lines.append('written: ' + ', '.join(str(path) for path in written))
    return lines


def sobol_lines(result: ScatterResult) -> list[str]:
    """Per output with indices, the parameters that matter (total index at least MATTERS)."""
    if not result.sobol_base:
        return ['  Sobol indices: none asked for (--sobol 0)']
    if not result.sobol:
        return []   # none to compute: the notes say why
    lines = [f'  Sobol indices ({result.sobol_base} base samples, '
             f'{len(result.sobol_samples)} evaluations), first-order / total:']
    for output, indices in result.sobol.items():
        if 'reason' in indices:
            continue
        ranked = sorted(indices.items(), key=lambda item: -item[1]['total'])
        named = [f'{name} {i["first_order"]:.2f} / {i["total"]:.2f} '
                 f'(+-{i["total_interval_half_width"]:.2f})'
                 for name, i in ranked if i['total'] >= MATTERS]
        lines.append(f'    {output}: ' + (', '.join(named) if named else
                                          f'no parameter reaches {MATTERS:g}'))
    if len(lines) == 1:
        lines.append('    no output varies over the design: no parameter matters')
    return lines


def plot_scatter(result: ScatterResult, out: Path, style: FigureStyle = PAPER) -> list[Path]:
    """scatter.png: types, volumes, plateau pressure and Sobol indices (mL, kPa)."""
    with style.context():
        return _plot_scatter(result, out, style)


def _plot_scatter(result: ScatterResult, out: Path, style: FigureStyle) -> list[Path]:
    fig, axes = new_figure(*style.size(PAGE_IN, 4.4), rows=2, cols=2,
                           margins={'left': 0.08, 'right': 0.98, 'top': 0.96, 'bottom': 0.16,
                                    'hspace': 0.45, 'wspace': 0.25})
    types_ax, volume_ax, plateau_ax, sobol_ax = axes.ravel()
    summary = result.summary
    chances = summary['sequence_type']
    for x, kind in enumerate(SEQUENCE_TYPES):
        p = chances[kind]
        low, high = p['interval']
        types_ax.bar(x, p['probability'], color=TYPE_COLOURS[kind], width=0.6)
        # max(0, ...): the interval holds its probability up to round-off.
        types_ax.errorbar(x, p['probability'], yerr=[[max(0.0, p['probability'] - low)],
                                                     [max(0.0, high - p['probability'])]],
                          color='0.2', capsize=3, lw=0.8)
    types_ax.set_xticks(range(len(SEQUENCE_TYPES)), SEQUENCE_TYPES)
    types_ax.set_ylim(0.0, 1.05)
    types_ax.set_ylabel('probability')
    style.title(types_ax, f'Sequence type, {summary["samples"]} samples, '
                          f'{result.confidence * 100:g} % intervals')
    volumes = {'switch': [s['switch_injected_m3'] for s in result.samples
                          if s['switch_injected_m3'] is not None]}
    for leg in ('inflation', 'deflation'):
        for j in range(len(summary[f'{leg}_snaps']['injected_m3'])):
            volumes[f'snap {j + 1} on {leg}'] = [s[f'{leg}_snaps_m3'][j] for s in result.samples
                                                 if len(s[f'{leg}_snaps_m3']) > j]
    _histograms(volume_ax, volumes, ML, 'injected volume [mL]')
    style.title(volume_ax, 'Switch and snap-through volumes')
    pressures = {'plateau': [s['plateau_pressure_pa'] for s in result.samples
                             if s['plateau_pressure_pa'] is not None]}
    _histograms(plateau_ax, pressures, KPA, 'plateau pressure [kPa]')
    style.title(plateau_ax, 'Plateau pressure')
    handles = _sobol_panel(sobol_ax, result)
    style.title(sobol_ax, 'Sobol indices')
    if handles:
        legend_below(fig, handles, ncol=min(4, len(handles)))
    return save_figure(fig, out, False, style)


def _histograms(ax: object, series: dict[str, list[float]], scale: float, label: str) -> None:
    drawn = {name: np.asarray(values) * scale for name, values in series.items() if values}
    if not drawn:
        ax.text(0.5, 0.5, f'{" or ".join(series)}: in no sample', ha='center', va='center',
                transform=ax.transAxes, color='0.4')
        ax.set_xticks([])
        ax.set_yticks([])
        return
    everything = np.concatenate(list(drawn.values()))
    # A little room either side; one value alone gets a bin of its own width.
    margin = 0.03 * float(np.ptp(everything)) or 0.01 * abs(float(everything[0])) or 1.0
    bins = int(np.clip(np.sqrt(everything.size), 8, 40))
    edges = np.linspace(everything.min() - margin, everything.max() + margin, bins + 1)
    for k, (name, values) in enumerate(drawn.items()):
        ax.hist(values, bins=edges, color=SEGMENT_COLOURS[k % len(SEGMENT_COLOURS)],
                alpha=0.75, label=f'{name} ({values.size})')
    ax.set_xlabel(label)
    ax.set_ylabel('samples')
    ax.legend(loc='best')


def _sobol_panel(ax: object, result: ScatterResult) -> list:
    """Per output with indices, a group of bars: each parameter's total (light), first (dark)."""
    from matplotlib.patches import Patch

    shown = [(output, indices) for output, indices in result.sobol.items()
             if 'reason' not in indices][:SOBOL_PANEL_OUTPUTS]
    if not shown:
        why = ('none asked for' if not result.sobol_base else
               'one correlated group' if not result.sobol else 'no output varies')
        ax.text(0.5, 0.5, f'Sobol indices: {why}', ha='center', va='center',
                transform=ax.transAxes, color='0.4')
        ax.set_xticks([])
        ax.set_yticks([])
        return []
    names = list(shown[0][1])   # the parameters, or their groups where draws are correlated
    width = 0.8 / (2 * len(names))
    for x, (_, indices) in enumerate(shown):
        for k, name in enumerate(names):
            colour = SEGMENT_COLOURS[k % len(SEGMENT_COLOURS)]
            for j, (key, alpha) in enumerate((('first_order', 1.0), ('total', 0.4))):
                at = x - 0.4 + (2 * k + j + 0.5) * width
                value = indices[name][key]
                ax.bar(at, value, width=width * 0.9, color=colour, alpha=alpha)
                ax.errorbar(at, value, yerr=indices[name][f'{key}_interval_half_width'],
                            color='0.2', lw=0.6, capsize=1.5)
    ax.axhline(0.0, color='0.5', lw=0.5)
    ax.set_xticks(range(len(shown)),
                  [_OUTPUT_LABELS.get(o, o.replace('is_', 'type ')) for o, _ in shown],
                  rotation=20, ha='right')
    ax.set_ylim(min(0.0, ax.get_ylim()[0]), max(1.1, ax.get_ylim()[1]))
    ax.set_ylabel('index')
    return ([Patch(color=SEGMENT_COLOURS[k % len(SEGMENT_COLOURS)], label=name)
             for k, name in enumerate(names)]
            + [Patch(color='0.4', label='first order (left)'),
               Patch(color='0.4', alpha=0.4, label='total (right)')])

