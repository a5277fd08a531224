"""
Two recordings side by side: the same metrics, their difference (``softseq compare A B``).

For two resolutions of one scene, two scenes, or a quasi-static run against a dynamic one.
Values are shown in mL, kPa, mJ, mm and ms; the difference is B minus A. When either bag is
dynamic (a scene with a fluid network) the table adds its transients: each snap-through's
duration, fluid moved, which segments gave and took it, and peak exchange, and the lag
behind the quasi-static path, which needs the scene (``-`` without it, and for a bag that has
no such row). A metric that does not apply to a bag (a switch where no segment takes over, a
plateau on a curve that never levels off) shows as ``does not apply``, with the reason under
the table. With an output folder, ``compare.png`` lays both bags' curves over each other, and
``compare_transients.png`` their pressure and volume time series around each snap-through in
time (:func:`write_transients_overlay`).
"""

from dataclasses import dataclass
import os
from pathlib import Path

from softseq_ros.analysis.recording import load_recording
from softseq_ros.analysis.report import (
    not_applicable_reason,
    parties,
    recording_metrics,
    scene_notes,
)
from softseq_ros.analysis.text import duration_text
from softseq_ros.errors import writing


@dataclass(frozen=True)
class DoesNotApply:
    """A table cell for a metric that does not apply to a bag, and why."""

    reason: str


def _value(metrics: dict, key: str, value: object) -> object:
    """``value``, or DoesNotApply with the reason when metric ``key`` does not apply."""
    reason = not_applicable_reason(metrics, key)
    return DoesNotApply(reason) if value is None and reason else value


def _rows(metrics: dict) -> dict[str, tuple[object, str]]:
    """Quantity -> (value in display units, unit)."""
    rows: dict[str, tuple[object, str]] = {
        'sequence type': (metrics['sequence_type'], ''),
        'duration': (metrics['duration_s'], 's'),
        'injected volume, largest': (metrics['injected_range_m3'][1] * 1e6, 'mL'),
        'pressure at peak injection (gauge)': (metrics['peak_injection']['pressure_pa'] * 1e-3,
                                               'kPa'),
        'snap-throughs': (metrics['snap_count'], ''),
    }
    area = metrics['hysteresis_area_j']
    rows['hysteresis area'] = (_value(metrics, 'hysteresis_area_j',
                                      None if area is None else area * 1e3), 'mJ')
    lead = metrics.get('lead')
    if 'lead' in metrics:
        rows['segment leading the inflow (first to take 90 %)'] = (
            _value(metrics, 'lead', lead['segment_leading'] if lead else None), '')
        rows['leads from'] = (_value(metrics, 'lead',
                                     lead['injected_m3'] * 1e6 if lead else None), 'mL')
    switch = metrics.get('switch')
    rows['switch volume'] = (_value(metrics, 'switch',
                                    switch['injected_m3'] * 1e6 if switch else None), 'mL')
    rows['segment taking over at the switch'] = (
        _value(metrics, 'switch', switch['segment_taking_over'] if switch else None), '')
    plateau = metrics.get('plateau')
    rows['plateau pressure (gauge)'] = (
        _value(metrics, 'plateau', plateau['pressure_pa'] * 1e-3 if plateau else None), 'kPa')
    rows['plateau reached (95 %)'] = (
        _value(metrics, 'plateau', plateau['onset_injected_m3'] * 1e6 if plateau else None),
        'mL')
    for number, snap in enumerate(metrics['snaps'], start=1):
        rows[f'snap {number} ({snap["direction"]})'] = (snap['injected_m3'] * 1e6, 'mL')
        rows[f'snap {number} fluid moved'] = (snap['fluid_moved_m3'] * 1e6, 'mL')
    for step in metrics['steps']:
        key = f'step {step["step"]} ({step["direction"]})'
        rows[f'{key} volume'] = (step['injected_m3'] * 1e6, 'mL')
        rows[f'{key} tip x'] = (step['tip_m'][0] * 1e3, 'mm')
        rows[f'{key} tip z'] = (step['tip_m'][1] * 1e3, 'mm')
    return rows


def _transient_rows(metrics: dict) -> dict[str, tuple[object, str]]:
    """A dynamic recording's transients, quantity -> (value in display units, unit)."""
    transients = metrics.get('transients')
    if transients is None:
        return {}
    rows: dict[str, tuple[object, str]] = {}
    for number, snap in enumerate(transients['snaps'], start=1):
        key = f'snap {number} in time ({snap["direction"]})'
        rows[f'{key} injected at its start'] = (snap['injected_m3'] * 1e6, 'mL')
        rows[f'{key} duration (10-90 %)'] = (snap['duration_s'] * 1e3, 'ms')
        rows[f'{key} fluid moved'] = (snap['fluid_moved_m3'] * 1e6, 'mL')
        rows[f'{key} fluid from -> to'] = (parties(snap), '')
        rows[f'{key} peak exchange'] = (snap['peak_exchange_m3_per_s'] * 1e6, 'mL/s')
        delay = snap['delay_injected_m3']
        rows[f'{key} late behind the quasi-static snap'] = (
            delay * 1e6 if delay is not None else None, 'mL')
    for name, peak in (transients.get('peak_reynolds') or {}).items():
        rows[f'peak Reynolds number, {name}'] = (peak, '')
    lag = transients['lag'] or {}
    for where, label in (('off_snaps', 'off the snaps'), ('at_snaps', 'at the snaps')):
        spread = lag.get(where) or {}
        for statistic in ('largest', 'median'):
            value = spread.get(f'{statistic}_m3')
            rows[f'lag behind the quasi-static path {label}, {statistic}'] = (
                value * 1e6 if value is not None else None, 'mL')
    return rows


def _cell(value: object) -> str:
    if value is None:
        return '-'
    if isinstance(value, DoesNotApply):
        return 'does not apply'
    if isinstance(value, float):
        return f'{value:.4g}'
    return str(value)


def write_overlay(bag_a: str | os.PathLike, bag_b: str | os.PathLike, out: Path,
                  namespace_a: str | None = None, namespace_b: str | None = None,
                  style: object | None = None, svg: bool = False) -> list[Path]:
    """
    ``compare.png`` in ``out``: both bags' PV curves (and v1-v2 planes) over each other.

    ``style``: a :class:`softseq_ros.analysis.figures.FigureStyle` (default: paper).
    """
    from softseq_ros.analysis.figures import PAPER, draw, thinned

    recordings = [(f'A: {Path(bag_a).name}', thinned(load_recording(bag_a, namespace_a))),
                  (f'B: {Path(bag_b).name}', thinned(load_recording(bag_b, namespace_b)))]
    with writing(out):
        out.mkdir(parents=True, exist_ok=True)
    return draw('overlay', recordings, out / 'compare.png', svg, style or PAPER)


def compare_bags(bag_a: str | os.PathLike, bag_b: str | os.PathLike,
                 namespace_a: str | None = None, namespace_b: str | None = None,
                 scene: object | None = None) -> tuple[dict, dict, str]:
    """
    Metrics of both bags and a Markdown table of them side by side.

    ``scene`` (a loaded scene whose segments made both bags) gives a dynamic bag's lag behind
    the quasi-static path; it is checked against each bag as the report checks it.
    """
    recording_a = load_recording(bag_a, namespace_a)
    recording_b = load_recording(bag_b, namespace_b)
    emap = None
    notes_a = notes_b = []
    if scene is not None:
        notes_a, notes_b = scene_notes(recording_a, scene), scene_notes(recording_b, scene)
        from softseq_ros.quasistatic.solve import scene_map

        emap = scene_map(scene)
    metrics_a = recording_metrics(recording_a, scene, emap)
    metrics_b = recording_metrics(recording_b, scene, emap)
    metrics_a['notes'].extend(notes_a)
    metrics_b['notes'].extend(notes_b)
    rows_a, rows_b = _rows(metrics_a), _rows(metrics_b)
    keys = list(rows_a) + [key for key in rows_b if key not in rows_a]
    timed_a, timed_b = _transient_rows(metrics_a), _transient_rows(metrics_b)
    rows_a.update(timed_a)
    rows_b.update(timed_b)
    timed = list(timed_a) + [key for key in timed_b if key not in timed_a]
    reasons: dict[tuple[str, str], str] = {}   # (bag, reason) -> the first row it explains
    lines = [f'A: {bag_a}', f'B: {bag_b}', '',
             '| quantity | unit | A | B | B - A |', '|---|---|---:|---:|---:|']
    for key in keys + timed:
        a, unit = rows_a.get(key, (None, rows_b.get(key, (None, ''))[1]))
        b = rows_b.get(key, (None, unit))[0]
        numeric = isinstance(a, (int, float)) and isinstance(b, (int, float)) and \
            not isinstance(a, bool)
        missing = [label for label, value in (('A', a), ('B', b))
                   if isinstance(value, DoesNotApply)]
        for label, value in (('A', a), ('B', b)):
            if isinstance(value, DoesNotApply) and (label, value.reason) not in reasons:
                reasons[(label, value.reason)] = key
        if missing:
            difference = f'does not apply in {" and ".join(missing)}'
        elif numeric:
            difference = _cell(float(b) - float(a))
        elif a is None and b is None and key in timed:
            difference = '-'
        elif a is None or b is None:
            difference = 'only in ' + ('B' if a is None else 'A')
        else:
            difference = 'same' if a == b else 'differs'
        lines.append(f'| {key} | {unit} | {_cell(a)} | {_cell(b)} | {difference} |')
    if reasons:
        lines += ['', 'Does not apply:']
        lines += [f'- {label}, {key}: {reason}' for (label, reason), key in reasons.items()]
    # What either analysis skipped as unusable is said under the table, not only in metrics.
    for label, recording in (('A', recording_a), ('B', recording_b)):
        skipped = recording.skipped_lines()
        if skipped:
            lines += ['', f'{label} skipped:'] + [f'- {line}' for line in skipped]
    return metrics_a, metrics_b, '\n'.join(lines) + '\n'


# ---------------------------------------------------------------- the transients of both bags

TRANSIENTS_FIGURE = 'compare_transients.png'
# Per segment, base to tip, in either bag's colour.
SEGMENT_LINES = ('-', '--', ':', '-.')


@dataclass(frozen=True)
class TransientsOverlay:
    """
    Both bags' windows around their snap-throughs in time, paired by number (1st with 1st).

    ``windows[k]``: (A's window, B's window) of snap k + 1, None where a bag has no such snap
    (a quasi-static bag has none); each window's time runs from its own snap's start.
    """

    labels: tuple[str, str]
    segment_names: tuple[tuple[str, ...], tuple[str, ...]]
    windows: list[tuple[object | None, object | None]]


def transients_overlay(recording_a: object, recording_b: object,
                       labels: tuple[str, str]) -> TransientsOverlay | None:
    """The windows to lay over each other; None when neither bag has a snap-through in time."""
    from softseq_ros.analysis.figures import MAX_POINTS, MAX_TRANSIENT_SNAPS
    from softseq_ros.analysis.transients import analyse_transients, transient_windows

    windows = []
    for recording in (recording_a, recording_b):
        found = analyse_transients(recording)
        windows.append(transient_windows(recording, found, MAX_TRANSIENT_SNAPS, MAX_POINTS)
                       if found is not None else [])
    count = max(len(w) for w in windows)
    if not count:
        return None
    pairs = [tuple(w[k] if k < len(w) else None for w in windows) for k in range(count)]
    return TransientsOverlay(labels, (recording_a.segment_names, recording_b.segment_names),
                             pairs)


def write_transients_overlay(bag_a: str | os.PathLike, bag_b: str | os.PathLike, out: Path,
                             namespace_a: str | None = None, namespace_b: str | None = None,
                             style: object | None = None, svg: bool = False) -> list[Path]:
    """
    ``compare_transients.png`` in ``out``: both bags around each snap-through in time.

    Nothing is written (and nothing returned) when neither bag has a snap-through in time.
    ``style``: a :class:`softseq_ros.analysis.figures.FigureStyle` (default: paper).
    """
    from softseq_ros.analysis.figures import PAPER

    overlay = transients_overlay(load_recording(bag_a, namespace_a),
                                 load_recording(bag_b, namespace_b),
                                 (f'A: {Path(bag_a).name}', f'B: {Path(bag_b).name}'))
    if overlay is None:
        return []
    style = style or PAPER
    with writing(out):
        out.mkdir(parents=True, exist_ok=True)
    with style.context():
        return plot_transients_overlay(overlay, out / TRANSIENTS_FIGURE, svg, style)


def plot_transients_overlay(overlay: TransientsOverlay, out: Path, svg: bool = False,
                            style: object | None = None) -> list[Path]:
    """
    Per snap number, gauge pressure above and segment volumes below, both bags over each other.

    A colour per bag (as in ``compare.png``), a line style per segment; time from each bag's
    own snap start (dotted), in s, or in ms when every window is shorter than 2 s.
    """
    from softseq_ros.analysis.figures import (
        BAG_COLOURS,
        GAUGE,
        KPA,
        ML,
        PAPER,
        new_figure,
        save_figure,
    )

    style = style or PAPER
    count = len(overlay.windows)
    width, height = style.size(2.3 * count + 0.5, 3.8)
    fig, axes = new_figure(width, height, 2, count,
                           {'left': 0.6 / width, 'right': 1 - 0.15 / width, 'top': 0.9,
                            'bottom': 0.16, 'wspace': 0.35}, sharex='col')
    spans = [w.snap.window_s[1] - w.snap.window_s[0]
             for pair in overlay.windows for w in pair if w is not None]
    scale, unit = (1e3, 'ms') if max(spans) < 2.0 else (1.0, 's')
    for column, pair in enumerate(overlay.windows):
        top, bottom = axes[0, column], axes[1, column]
        said = []
        for window, label, names, colour in zip(pair, overlay.labels, overlay.segment_names,
                                                BAG_COLOURS):
            if window is None:
                said.append(f'{label[0]}: none')
                continue
            time = window.time_s * scale
            top.plot(time, window.pressure * KPA, '-', lw=1.2, color=colour, label=label)
            for j, name in enumerate(names):
                bottom.plot(time, window.volumes[:, j] * ML, SEGMENT_LINES[j % len(SEGMENT_LINES)],
                            lw=1.1, color=colour, label=f'{label[0]}: {name}')
            duration = window.snap.duration_s
            said.append(f'{label[0]}: {duration_text(duration)}')
        for ax in (top, bottom):
            ax.axvline(0.0, color='0.5', lw=0.8, ls=':')
            ax.grid(alpha=0.3)
        top.set_title(f'snap {column + 1}, 10-90 % ' + ', '.join(said), fontsize=7)
        bottom.set_xlabel(f"time from the snap's start [{unit}]")
        if column == 0:
            top.set_ylabel(GAUGE)
            bottom.set_ylabel('segment volume [mL]')
            top.legend(loc='best')
    handles, labels = axes[1, 0].get_legend_handles_labels()
    for column in range(1, count):
        for handle, label in zip(*axes[1, column].get_legend_handles_labels()):
            if label not in labels:
                handles.append(handle)
                labels.append(label)
    fig.legend(handles, labels, loc='lower center', ncol=min(len(labels), 4))
    if not style.paper:
        fig.suptitle('Both recordings around each snap-through in time', fontsize=10)
    return save_figure(fig, out, svg, style)
