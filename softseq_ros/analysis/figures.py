"""
Figures of a rig run in the paper's style.

Humans read mL, kPa and mm here; the data stay SI underneath, and every pressure axis says
gauge. Inflation is drawn solid in blue, deflation dashed in orange throughout; a snap-through is
an arrow from the state before to the state after. Figures: the PV curve (Fig. 4A / 6), each
segment's volume and curvature against the injected volume (Fig. 3), the v1-v2 plane with stable
and unstable equilibria and lines of constant total volume (Fig. 1B / 4B), the tentacle's shape
at the camera's steps (Fig. 7), the time series and, for a dynamic bag, the transients around
its snap-throughs in time.

Figures are drawn with matplotlib's object API on the Agg canvas (no pyplot: it costs half a
second to import), and long recordings are thinned to a few thousand points per line, keeping
every snap-through, which is what a figure can show anyway.
"""

from dataclasses import dataclass
import os
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from softseq_ros.analysis.metrics import snap_rows
from softseq_ros.analysis.recording import DEFLATION, INFLATION, FloatArray, Recording
from softseq_ros.analysis.transients import Transients, TransientWindow, transient_windows
from softseq_ros.errors import OutputWriteError, writing

ML = 1e6
KPA = 1e-3
MM = 1e3
MAX_POINTS = 2000
STYLE = {INFLATION: {'color': 'tab:blue', 'ls': '-'},
         DEFLATION: {'color': 'tab:orange', 'ls': '--'}}
GAUGE = 'gauge pressure [kPa]'
INJECTED = 'injected volume [mL]'
# Snaps a transients figure shows side by side (more would be too narrow to read).
MAX_TRANSIENT_SNAPS = 4
SEGMENT_COLOURS = ['tab:green', 'tab:purple', 'tab:brown', 'tab:cyan', 'tab:olive']


@dataclass(frozen=True)
class ModelCurves:
    """
    What the figures draw of a scene's model, as plain arrays.

    Built from the equilibrium map in the process that has it (:meth:`from_map`), so a figure
    worker gets arrays and never unpickles the map: that would import scipy there, on the
    report's critical path.
    """

    names: tuple[str, ...]
    rest_volumes: FloatArray                          # (N,) m^3
    segment_curves: tuple[tuple[FloatArray, FloatArray], ...]    # added volume m^3, Pa
    equilibria: tuple[tuple[FloatArray, NDArray[np.bool_]], ...]  # volumes (n, N), stable

    @classmethod
    def from_map(cls, emap: object, samples: int = 600) -> 'ModelCurves':
        """Each segment's curve alone and the equilibrium set, from an EquilibriumMap."""
        curves = []
        for segment in emap.segments:
            v = np.linspace(segment.rest_volume, segment.max_volume, samples)
            curves.append((v - segment.rest_volume, np.asarray(segment.pressure(v))))
        return cls(tuple(s.name for s in emap.segments), np.asarray(emap.rest_volumes),
                   tuple(curves), tuple((np.asarray(c.volumes), np.asarray(c.stable))
                                        for c in emap.equilibrium_set()))


def new_figure(width: float, height: float, rows: int = 1, cols: int = 1,  # noqa: ANN201
            margins: dict | None = None, **kwargs: object):
    """A figure on the Agg canvas with fixed margins (automatic layouts cost half the time)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height))
    FigureCanvasAgg(fig)
    fig.subplots_adjust(**{'left': 0.12, 'right': 0.97, 'bottom': 0.11, 'top': 0.92,
                           'hspace': 0.12, 'wspace': 0.08, **(margins or {})})
    axes = fig.subplots(rows, cols, squeeze=False, **kwargs)
    return fig, axes


def _thin(size: int, keep: NDArray[np.intp] | None = None) -> NDArray[np.intp]:
    """Row indices for plotting at most about MAX_POINTS rows, always keeping ``keep``."""
    if size <= MAX_POINTS:
        return np.arange(size)
    rows = np.linspace(0, size - 1, MAX_POINTS).astype(np.intp)
    if keep is not None and keep.size:
        rows = np.union1d(rows, np.clip(np.concatenate([keep - 1, keep]), 0, size - 1))
    return rows


def _legs(recording: Recording) -> list[tuple[str, NDArray[np.intp]]]:
    """
    Contiguous stretches of inflation and deflation rows, thinned, each with its direction.

    A new run of the pump (a reset or restart, :meth:`Recording.runs`) starts a new stretch:
    no line joins two runs.
    """
    sign = recording.state_flow_sign
    if not sign.size:
        return []
    breaks = np.union1d(np.flatnonzero(np.diff(sign) != 0) + 1,
                        recording.state_run_starts[recording.state_run_starts > 0])
    starts = np.concatenate([[0], breaks])
    stops = np.concatenate([breaks, [sign.size]])
    snaps = _snap_rows(recording)
    runs = []
    for start, stop in zip(starts.tolist(), stops.tolist()):
        keep = snaps[(snaps >= start) & (snaps < stop)] - start
        rows = start + _thin(stop - start, keep)
        # A snap is drawn as an arrow, not as a line across the gap.
        runs.append((INFLATION if sign[start] > 0 else DEFLATION, rows))
    return runs


def _snap_rows(recording: Recording) -> NDArray[np.intp]:
    if recording.snap_rows is not None:
        return recording.snap_rows
    span = float(np.ptp(recording.state_injected)) or 1.0
    return snap_rows(recording.state_injected, recording.volumes, span)[0]


def _broken(values: NDArray[np.float64], rows: NDArray[np.intp],
            snaps: NDArray[np.intp]) -> NDArray[np.float64]:
    """``values[rows]`` with NaN inserted before each snap row (no line across a snap)."""
    out = values[rows].astype(float)
    if not snaps.size:
        return out
    cut = np.isin(rows, snaps)
    if not cut.any():
        return out
    out = np.insert(out, np.flatnonzero(cut), np.nan, axis=0)
    return out


def _draw_legs(ax: object, recording: Recording, x: NDArray[np.float64],
               y: NDArray[np.float64], label: str = '', **extra: object) -> None:
    snaps = _snap_rows(recording)
    starts = recording.state_run_starts
    shown = set()
    for direction, rows in _legs(recording):
        style = dict(STYLE[direction])
        style.update(extra)
        # Runs after the first (a reset or restarted pump) are named and drawn fainter.
        run = int(np.searchsorted(starts, rows[0], side='right')) + 1 if starts.size else 0
        key = (run, direction)
        name = (f'{label}{f"run {run}, " if run else ""}{direction}' if key not in shown
                else None)
        shown.add(key)
        if run > 1:
            style['alpha'] = 0.5
        ax.plot(_broken(x, rows, snaps), _broken(y, rows, snaps), lw=1.5, label=name, **style)
    for row in snaps.tolist():
        direction = INFLATION if recording.state_flow_sign[row] > 0 else DEFLATION
        ax.annotate('', xy=(x[row], y[row]), xytext=(x[row - 1], y[row - 1]),
                    arrowprops={'arrowstyle': '->', 'color': STYLE[direction]['color'],
                                'lw': 1.4})


def _x_limits(ax: object, *ranges: tuple[float, float]) -> None:
    lo = min(r[0] for r in ranges)
    hi = max(r[1] for r in ranges)
    pad = 0.03 * (hi - lo or 1.0)
    ax.set_xlim(lo - pad, hi + pad)


def plot_pv(recording: Recording, model: ModelCurves | None, out: Path,
            experiment: object | None = None, svg: bool = False) -> list[Path]:
    """Gauge pressure against injected volume, inflation and deflation apart, snaps marked."""
    fig, axes = new_figure(6.4, 4.6)
    ax = axes[0, 0]
    u = recording.state_injected * ML
    ranges = [(float(u.min()), float(u.max()))]
    if model is not None:
        for name, (added, pressure) in zip(model.names, model.segment_curves):
            dv = added * ML
            shown = dv <= max(u.max() * 1.2, 1e-9)
            ax.plot(dv[shown], pressure[shown] * KPA, ':', lw=1,
                    label=f'segment {name} alone (vs its own added volume)')
    _draw_legs(ax, recording, u, recording.pressure * KPA, label='actuator, ')
    if experiment is not None:
        for direction, marker in ((1, 'o'), (-1, 's')):
            rows = experiment.sign == direction
            if rows.any():
                ax.plot(experiment.injected[rows] * ML, experiment.pressure[rows] * KPA, marker,
                        ms=2.5, mfc='none', color='tab:red' if direction > 0 else 'tab:purple',
                        label=f'experiment, {INFLATION if direction > 0 else DEFLATION}')
        ranges.append((float(experiment.injected.min() * ML),
                       float(experiment.injected.max() * ML)))
    _x_limits(ax, *ranges)
    ax.set_xlabel(INJECTED)
    ax.set_ylabel(GAUGE)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc='lower right')
    ax.set_title('Pressure-volume curve (Fig. 4A / 6 style); arrows: snap-throughs', fontsize=10)
    return save_figure(fig, out, svg)


def plot_segments(recording: Recording, out: Path, svg: bool = False) -> list[Path]:
    """Volume added to each segment and its curvature against injected volume (Fig. 3)."""
    n = len(recording.segment_names)
    fig, axes = new_figure(6.4, 5.8, 2, 1, {'top': 0.93, 'bottom': 0.09}, sharex=True)
    u = recording.state_injected * ML
    rest = recording.volumes[0]
    for j, name in enumerate(recording.segment_names):
        colour = SEGMENT_COLOURS[j % len(SEGMENT_COLOURS)]
        _draw_legs(axes[0, 0], recording, u, (recording.volumes[:, j] - rest[j]) * ML,
                   label=f'{name}, ', color=colour)
        if recording.curvatures.shape[0] == recording.volumes.shape[0]:
            _draw_legs(axes[1, 0], recording, u, recording.curvatures[:, j],
                       label=f'{name}, ', color=colour)
    axes[0, 0].set_ylabel('volume added to segment [mL]')
    axes[1, 0].set_ylabel('segment curvature [1/m]')
    axes[1, 0].set_xlabel(INJECTED)
    for ax in axes[:, 0]:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, ncol=max(1, n))
    axes[0, 0].set_title('Segment volume and curvature (Fig. 3 style); solid: inflation, '
                         'dashed: deflation', fontsize=9)
    return save_figure(fig, out, svg)


def plot_volume_split(recording: Recording, model: ModelCurves | None, out: Path,
                      svg: bool = False) -> list[Path]:
    """v1 against v2 (added volumes): equilibria, constant total volume, the recorded path."""
    fig, axes = new_figure(5.8, 5.6, margins={'left': 0.13, 'bottom': 0.1, 'top': 0.93})
    ax = axes[0, 0]
    names = recording.segment_names
    if len(names) != 2:
        return _segments_instead(fig, recording, out, svg)
    rest = model.rest_volumes if model is not None else recording.volumes[0]
    dv = (recording.volumes - rest) * ML
    limit = float(np.nanmax(dv)) * 1.1 or 1.0
    if model is not None:
        shown = set()
        for volumes, stable in model.equilibria:
            cv = (volumes - rest) * ML
            for mask, colour, label in ((stable, 'k', 'stable equilibria'),
                                        (~stable, 'tab:red', 'unstable equilibria')):
                if mask.any():
                    ax.plot(np.where(mask, cv[:, 0], np.nan), np.where(mask, cv[:, 1], np.nan),
                            color=colour, lw=0.9, alpha=0.6,
                            label=None if label in shown else label)
                    shown.add(label)
        limit = max(limit, 0.0)
    step = nice_step(2 * limit / 8)
    for total in np.arange(step, 2 * limit + step, step):
        ax.plot([0, total], [total, 0], color='0.75', lw=0.6, zorder=0)
        if total < limit:
            # Labelled next to the x axis, away from the path, which leaves the origin upward.
            ax.text(total - 0.03 * limit, 0.03 * limit, f'{total:g} mL', fontsize=6,
                    color='0.45', rotation=-45, ha='center', va='center')
    _draw_legs(ax, recording, dv[:, 0], dv[:, 1], label='recorded, ')
    ax.set_xlabel(f'volume added to {names[0]} [mL]')
    ax.set_ylabel(f'volume added to {names[1]} [mL]')
    ax.set_aspect('equal', adjustable='box')
    ax.set_xlim(0, limit)
    ax.set_ylim(0, limit)
    ax.grid(alpha=0.2)
    ax.legend(fontsize=7, loc='upper right')
    ax.set_title('Volume distribution (Fig. 1B / 4B style); grey: constant total volume',
                 fontsize=9)
    return save_figure(fig, out, svg)


def _segments_instead(fig: object, recording: Recording, out: Path, svg: bool) -> list[Path]:
    ax = fig.axes[0]
    u = recording.state_injected * ML
    rest = recording.volumes[0]
    for j, name in enumerate(recording.segment_names):
        _draw_legs(ax, recording, u, (recording.volumes[:, j] - rest[j]) * ML,
                   label=f'{name}, ')
    ax.set_xlabel(INJECTED)
    ax.set_ylabel('volume added to segment [mL]')
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    ax.set_title('Volume distribution', fontsize=10)
    return save_figure(fig, out, svg)


def nice_step(raw: float) -> float:
    """1, 2 or 5 times a power of ten, at least ``raw``: a spacing of grid or guide lines."""
    exponent = 10 ** np.floor(np.log10(raw)) if raw > 0 else 1.0
    for factor in (1, 2, 5, 10):
        if raw <= factor * exponent:
            return float(factor * exponent)
    return float(10 * exponent)


def plot_shapes(recording: Recording, out: Path, svg: bool = False) -> list[Path]:
    """The backbone at each step: inflation and deflation in two panels, one colour per step."""
    from matplotlib import colormaps

    fig, axes = new_figure(9.6, 5.2, 1, 2, {'left': 0.07, 'bottom': 0.3, 'top': 0.88},
                        sharex=True, sharey=True)
    steps = sorted({s.step for s in recording.snapshots if s.step is not None})
    palette = colormaps['tab10']
    colour = {step: palette(i % 10) for i, step in enumerate(steps)}
    for ax, direction in zip(axes[0], (INFLATION, DEFLATION)):
        shots = [s for s in recording.snapshots if s.direction == direction]
        for shot in shots:
            label = (f'step {shot.step}: {shot.injected * ML:.1f} mL' if shot.step is not None
                     else f'{shot.injected * ML:.1f} mL')
            ax.plot(shot.points[:, 0] * MM, shot.points[:, 1] * MM, '-', lw=2,
                    color=colour.get(shot.step, 'k'), label=label)
            ax.plot(*(shot.tip * MM), 'o', ms=3, color=colour.get(shot.step, 'k'))
        ax.plot([0], [0], 'ks', ms=6)
        ax.set_xlabel('x [mm]')
        ax.set_aspect('equal', adjustable='box')
        ax.grid(alpha=0.3)
        ax.set_title(f'{direction} ({len(shots)} snapshots)', fontsize=10)
        if shots:
            ax.legend(fontsize=7, loc='upper center', bbox_to_anchor=(0.5, -0.15), ncol=3,
                      frameon=False)
    axes[0, 0].set_ylabel('z [mm]')
    _square_limits(axes[0, 0], recording)
    fig.suptitle('Tentacle shape at the camera steps (Fig. 7 style)', fontsize=10)
    return save_figure(fig, out, svg)


def _square_limits(ax: object, recording: Recording) -> None:
    """Both panels show every snapshot at one scale (equal aspect, shared limits)."""
    if not recording.snapshots:
        return
    points = np.vstack([s.points for s in recording.snapshots] + [np.zeros((1, 2))]) * MM
    lo, hi = points.min(axis=0), points.max(axis=0)
    size = float(np.max(hi - lo)) * 1.08 or 1.0
    centre = 0.5 * (lo + hi)
    ax.set_xlim(centre[0] - size / 2, centre[0] + size / 2)
    ax.set_ylim(centre[1] - size / 2, centre[1] + size / 2)


def plot_timeseries(recording: Recording, out: Path, svg: bool = False) -> list[Path]:
    """Injected volume, gauge pressure and each segment's total volume against time."""
    fig, axes = new_figure(6.4, 6.4, 3, 1, {'top': 0.95, 'bottom': 0.08}, sharex=True)
    rows = _thin(recording.pump_time_s.size)
    axes[0, 0].plot(recording.pump_time_s[rows], recording.pump_injected[rows] * ML, 'k-')
    axes[0, 0].set_ylabel('injected (pump) [mL]')
    rows = _thin(recording.state_time_s.size, _snap_rows(recording))
    axes[1, 0].plot(recording.state_time_s[rows], recording.pressure[rows] * KPA, 'k-')
    axes[1, 0].set_ylabel(GAUGE)
    for j, name in enumerate(recording.segment_names):
        axes[2, 0].plot(recording.state_time_s[rows], recording.volumes[rows, j] * ML,
                        label=name)
    axes[2, 0].set_ylabel('segment volume, total [mL]')
    axes[2, 0].set_xlabel('time from the first pump command [s]')
    axes[2, 0].legend(fontsize=8)
    for ax in axes[:, 0]:
        ax.grid(alpha=0.3)
    # Where a new run of the pump begins (a reset or restart): a line and its number.
    for number, start in enumerate(recording.run_starts, start=2):
        for ax in axes[:, 0]:
            ax.axvline(start.time_s, color='0.4', lw=0.8, ls=':')
        axes[0, 0].annotate(f'run {number}', (start.time_s, 1.0), xycoords=('data',
                            'axes fraction'), xytext=(2, -2), textcoords='offset points',
                            ha='left', va='top', fontsize=7, color='0.3')
    return save_figure(fig, out, svg)


def plot_transients(windows: list[TransientWindow], segment_names: tuple[str, ...],
                    channel_names: tuple[str, ...], out: Path, svg: bool = False) -> list[Path]:
    """
    Each snap in time: gauge pressure and channel flow above, segment volumes below.

    Time runs from the snap's start; dashed: the quasi-static volumes at the same injected
    volume (when the scene was given).
    """
    count = len(windows)
    width = 3.6 * count + 0.6
    # Fixed margins in inches, whatever the number of panels: room for both y labels.
    fig, axes = new_figure(width, 6.0, 2, count,
                        {'left': 0.75 / width, 'right': 1 - 0.65 / width, 'top': 0.88,
                         'bottom': 0.09, 'wspace': 0.55}, sharex='col')
    for column, window in enumerate(windows):
        snap = window.snap
        # Short snaps read in ms, long ones in s.
        scale, unit = (1e3, 'ms') if snap.window_s[1] - snap.window_s[0] < 2.0 else (1.0, 's')
        top, bottom = axes[0, column], axes[1, column]
        top.plot(window.time_s * scale, window.pressure * KPA, 'k-', lw=1.3,
                 label='gauge pressure (syringe)')
        if window.flow.size:
            flow_axis = top.twinx()
            for j, name in enumerate(channel_names):
                flow_axis.plot(window.flow_time_s * scale, window.flow[:, j] * ML, '-', lw=1.1,
                               color=f'C{j + 3}', label=f'flow {name}')
            flow_axis.set_ylabel('channel flow, towards the tip [mL/s]', fontsize=8)
            flow_axis.tick_params(labelsize=7)
            flow_axis.legend(fontsize=6, loc='lower right')
        for j, name in enumerate(segment_names):
            colour = SEGMENT_COLOURS[j % len(SEGMENT_COLOURS)]
            bottom.plot(window.time_s * scale, window.volumes[:, j] * ML, '-', lw=1.4,
                        color=colour, label=name)
            if window.quasi_static_volumes is not None:
                bottom.plot(window.time_s * scale, window.quasi_static_volumes[:, j] * ML, '--',
                            lw=1.0, color=colour, label=f'{name}, quasi-static')
        for ax in (top, bottom):
            ax.axvline(0.0, color='0.5', lw=0.8, ls=':')
            ax.grid(alpha=0.3)
            ax.tick_params(labelsize=7)
        top.set_title(f'snap {snap.number} ({snap.direction}) at {snap.injected * ML:.2f} mL\n'
                      f'10-90 %: {snap.duration_s * 1e3:.4g} ms', fontsize=8)
        top.legend(fontsize=6, loc='upper right')
        bottom.legend(fontsize=6)
        bottom.set_xlabel(f"time from the snap's start [{unit}]", fontsize=8)
    axes[0, 0].set_ylabel(GAUGE, fontsize=8)
    axes[1, 0].set_ylabel('segment volume, total [mL]', fontsize=8)
    fig.suptitle('Snap-throughs in time (dotted: start; dashed: quasi-static)', fontsize=10)
    return save_figure(fig, out, svg)


def _draw(name: str, args: tuple) -> list[Path]:
    return _FIGURE_FUNCTIONS[name](*args)


def _draw_split(jobs: list[tuple[str, tuple]], split: int) -> list[list[Path]]:
    """Draw ``jobs[:split]`` here and the rest in a fork (which has matplotlib loaded)."""
    ours, theirs = jobs[:split], jobs[split:]
    # The fork's one-line error (a figure it could not write) comes back through a pipe.
    read_end, write_end = os.pipe() if theirs else (-1, -1)
    child = os.fork() if theirs else 0
    if theirs and child == 0:
        status = 0
        try:
            os.close(read_end)
            for name, args in theirs:
                _draw(name, args)
        except OutputWriteError as err:
            os.write(write_end, str(err).encode()[:4096])
            status = 2
        except BaseException:  # noqa: BLE001 - reported through the exit status
            import traceback

            traceback.print_exc()
            status = 1
        finally:
            os._exit(status)
    if theirs:
        os.close(write_end)
    try:
        drawn = [_draw(name, args) for name, args in ours]
    finally:
        if theirs:
            _, status = os.waitpid(child, 0)
            message = os.read(read_end, 4096).decode(errors='replace')
            os.close(read_end)
    if theirs and status != 0:
        if message:
            raise OutputWriteError(message)
        raise RuntimeError(f'drawing {", ".join(n for n, _ in theirs)} failed (see above)')
    return drawn + [_outputs(name, args) for name, args in theirs]


def _outputs(name: str, args: tuple) -> list[Path]:
    """The files a figure job writes (what the forked half drew)."""
    out = next(a for a in args if isinstance(a, Path))
    return [out, out.with_suffix('.svg')] if args[-1] else [out]


def thinned(recording: Recording) -> Recording:
    """
    The rows a figure can show: at most about MAX_POINTS per leg, every snap and its row before.

    Drawing a million points shows nothing more than a few thousand, and the thinned copy is
    what goes to the figure workers (small to send).
    """
    from dataclasses import replace

    states = np.unique(np.concatenate([rows for _, rows in _legs(recording)] or
                                      [np.zeros(0, np.intp)]))
    # Snaps are found on every row: between thinned rows a fast but continuous exchange of
    # fluid would look like one.
    snaps = np.searchsorted(states, _snap_rows(recording))
    pump = _thin(recording.pump_time_s.size) if recording.pump_time_s.size > 4 * MAX_POINTS \
        else np.arange(recording.pump_time_s.size)
    aligned = recording.curvatures.shape[0] == recording.volumes.shape[0]
    curves = states if aligned else _thin(recording.curvatures.shape[0])
    curvature_time = recording.curvature_time_s
    curvature_injected = recording.curvature_injected
    return replace(
        recording,
        pump_time_s=recording.pump_time_s[pump], pump_injected=recording.pump_injected[pump],
        state_time_s=recording.state_time_s[states],
        state_injected=recording.state_injected[states], pressure=recording.pressure[states],
        volumes=recording.volumes[states], state_flow_sign=recording.state_flow_sign[states],
        curvatures=recording.curvatures[curves] if recording.curvatures.shape[0] else
        recording.curvatures,
        curvature_time_s=curvature_time[curves] if curvature_time.size else curvature_time,
        curvature_injected=(curvature_injected[curves] if curvature_injected.size
                            else curvature_injected),
        snap_rows=snaps, channel_flows=None)


def write_figures(recording: Recording, emap: object | None, directory: Path,
                  experiment: object | None = None, svg: bool = False,
                  workers: object | None = None,
                  transients: Transients | None = None) -> list[Path]:
    """
    All figures of a run into ``directory`` (PNG, and SVG as well with ``svg``).

    ``transients`` (a dynamic recording's, with a snap in time) add ``transients.png``.

    Drawing is most of a report's time: with ``workers`` (from
    :func:`softseq_ros.analysis.figure_workers.start_workers`) the figures are drawn in those
    processes, in parallel.
    """
    directory.mkdir(parents=True, exist_ok=True)
    # Windows are cut from the whole recording: thinning could lose a short snap.
    windows = transient_windows(recording, transients, MAX_TRANSIENT_SNAPS, MAX_POINTS) \
        if transients is not None else []
    recording = thinned(recording)
    model = ModelCurves.from_map(emap) if emap is not None else None
    jobs = [('pv', (recording, model, directory / 'pv.png', experiment, svg)),
            ('segments', (recording, directory / 'segments.png', svg)),
            ('volume_split', (recording, model, directory / 'volume_split.png', svg))]
    # A figure with nothing to show is not drawn: no snapshot (a scene without trigger
    # volumes) leaves no shapes to draw.
    if recording.snapshots:
        jobs.append(('shapes', (recording, directory / 'shapes.png', svg)))
    jobs.append(('timeseries', (recording, directory / 'timeseries.png', svg)))
    if windows:
        jobs.append(('transients', (windows, recording.segment_names, transients.channel_names,
                                    directory / 'transients.png', svg)))
    if workers is None:
        return [path for name, args in jobs for path in _draw(name, args)]
    # Two halves of about equal drawing time, PNG or SVG: shapes and time series (and the
    # transients) against the other three.
    first = [job for job in jobs if job[0] in SECOND_HALF]
    order = first + [job for job in jobs if job[0] not in SECOND_HALF]
    drawn = dict(zip((name for name, _ in order),
                     workers.apply(_draw_split, (order, len(first)))))
    return [path for name, _ in jobs for path in drawn[name]]


# Drawn by the worker's fork while the worker draws the rest (about half the time each).
SECOND_HALF = ('shapes', 'timeseries', 'transients')


_FIGURE_FUNCTIONS = {'pv': plot_pv, 'segments': plot_segments, 'volume_split': plot_volume_split,
                     'shapes': plot_shapes, 'timeseries': plot_timeseries,
                     'transients': plot_transients}


def save_figure(fig: object, out: Path, svg: bool) -> list[Path]:
    """Write ``fig`` as PNG (and SVG), a failed write naming the file; the paths written."""
    # zlib's fastest level: a fifth of a figure's time at the default level, for 7 % more bytes.
    with writing(out):
        fig.savefig(out, dpi=110, pil_kwargs={'compress_level': 1})
    written = [out]
    if svg:
        with writing(out.with_suffix('.svg')):
            fig.savefig(out.with_suffix('.svg'))
        written.append(out.with_suffix('.svg'))
    return written
