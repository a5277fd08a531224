"""
Two recordings side by side: the same metrics, their difference (``softseq compare A B``).

For two resolutions of one scene, two scenes, or a quasi-static run against a later dynamic
model. Values are shown in mL, kPa, mJ and mm; the difference is B minus A.
"""

import os

from softseq_ros.analysis.recording import load_recording
from softseq_ros.analysis.report import recording_metrics


def _rows(metrics: dict) -> dict[str, tuple[object, str]]:
    """Quantity -> (value in display units, unit)."""
    rows: dict[str, tuple[object, str]] = {
        'sequence type': (metrics['sequence_type'], ''),
        'duration': (metrics['duration_s'], 's'),
        'injected volume, largest': (metrics['injected_range_m3'][1] * 1e6, 'mL'),
        'pressure at peak injection (gauge)': (metrics['peak_injection']['pressure_pa'] * 1e-3,
                                               'kPa'),
        'snap-throughs': (metrics['snap_count'], ''),
        'hysteresis area': (metrics['hysteresis_area_j'] * 1e3, 'mJ'),
    }
    switch = metrics.get('switch')
    rows['switch volume'] = (switch['injected_m3'] * 1e6 if switch else None, 'mL')
    rows['segment taking over at the switch'] = (switch['segment_taking_over'] if switch
                                                 else None, '')
    plateau = metrics.get('plateau') or {}
    rows['plateau pressure (gauge)'] = (plateau.get('pressure_pa', 0.0) * 1e-3, 'kPa')
    onset = plateau.get('onset_injected_m3')
    rows['plateau reached (95 %)'] = (onset * 1e6 if onset is not None else None, 'mL')
    for number, snap in enumerate(metrics['snaps'], start=1):
        rows[f'snap {number} ({snap["direction"]})'] = (snap['injected_m3'] * 1e6, 'mL')
        rows[f'snap {number} fluid moved'] = (snap['fluid_moved_m3'] * 1e6, 'mL')
    for step in metrics['steps']:
        key = f'step {step["step"]} ({step["direction"]})'
        rows[f'{key} volume'] = (step['injected_m3'] * 1e6, 'mL')
        rows[f'{key} tip x'] = (step['tip_m'][0] * 1e3, 'mm')
        rows[f'{key} tip z'] = (step['tip_m'][1] * 1e3, 'mm')
    return rows


def _cell(value: object) -> str:
    if value is None:
        return '-'
    if isinstance(value, float):
        return f'{value:.4g}'
    return str(value)


def compare_bags(bag_a: str | os.PathLike, bag_b: str | os.PathLike,
                 namespace_a: str | None = None,
                 namespace_b: str | None = None) -> tuple[dict, dict, str]:
    """Metrics of both bags and a Markdown table of them side by side."""
    metrics_a = recording_metrics(load_recording(bag_a, namespace_a))
    metrics_b = recording_metrics(load_recording(bag_b, namespace_b))
    rows_a, rows_b = _rows(metrics_a), _rows(metrics_b)
    keys = list(rows_a) + [key for key in rows_b if key not in rows_a]
    lines = [f'A: {bag_a}', f'B: {bag_b}', '',
             '| quantity | unit | A | B | B - A |', '|---|---|---:|---:|---:|']
    for key in keys:
        a, unit = rows_a.get(key, (None, rows_b.get(key, (None, ''))[1]))
        b = rows_b.get(key, (None, unit))[0]
        numeric = isinstance(a, (int, float)) and isinstance(b, (int, float)) and \
            not isinstance(a, bool)
        if numeric:
            difference = _cell(float(b) - float(a))
        elif a is None or b is None:
            difference = 'only in ' + ('B' if a is None else 'A')
        else:
            difference = 'same' if a == b else 'differs'
        lines.append(f'| {key} | {unit} | {_cell(a)} | {_cell(b)} | {difference} |')
    return metrics_a, metrics_b, '\n'.join(lines) + '\n'
