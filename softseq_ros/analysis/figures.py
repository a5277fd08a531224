"""
Figures of a rig run, fit for a paper.

Humans read mL, kPa, mm and degrees here; the data stay SI underneath, and every pressure axis
says gauge. Inflation is drawn solid and thick, deflation dashed and thin on top of it, so both
show where they coincide (blue and vermillion where colour is free, the segment's colour in
per-segment figures); a snap-through is an arrow from the state before to the state after.
Figures: the PV curve (Fig. 4A / 6), each segment's volume, curvature and bend angle against
the injected volume (Fig. 3), the v1-v2 plane with stable and unstable equilibria and lines of
constant total volume (Fig. 1B / 4B), the tentacle's shape at the camera's steps with an
experiment's tips (Fig. 7), the time series and, for a dynamic bag, the transients around its
snap-throughs in time.

A :class:`FigureStyle` sets how they look: ``paper`` (the default: no titles, a caption says
what a figure shows; sized for a 3.5 in journal column or a 7.2 in page, 8 pt type, 300 dpi,
cropped to what is drawn) or ``screen`` (short titles, larger, 110 dpi, for a quick look;
cropped too); the width and the resolution can be set for either. ``softseq library``,
``softseq rates`` and ``softseq graph`` draw their figures in the same styles, through the
same helpers (:class:`FigureStyle`, :func:`new_figure`, :func:`save_figure`).

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
from softseq_ros.analysis.text import duration_text
from softseq_ros.analysis.transients import Transients, TransientWindow, transient_windows
from softseq_ros.errors import OutputWriteError, UserError, writing
from softseq_ros.parallel import end_with_parent

ML = 1e6
KPA = 1e-3
MM = 1e3
MAX_POINTS = 2000
# Okabe-Ito colours, told apart with every common colour-vision deficiency. Deflation is drawn
# thinner and on top of inflation, so a path that retraces itself shows both.
STYLE = {INFLATION: {'color': '#0072B2', 'ls': '-', 'lw': 2.0, 'zorder': 2},
         DEFLATION: {'color': '#D55E00', 'ls': (0, (3.5, 2.0)), 'lw': 1.1, 'zorder': 3}}
GAUGE = 'gauge pressure [kPa]'
INJECTED = 'injected volume [mL]'
# Snaps a transients figure shows side by side (more would be too narrow to read).
MAX_TRANSIENT_SNAPS = 4
SEGMENT_COLOURS = ['#009E73', '#CC79A7', '#E69F00', '#56B4E9', '#000000']
UNSTABLE_COLOUR = '#CC79A7'
# Where the pump ended its programme early (stopped, held for good).
STOP_COLOUR = '#D55E00'
# A journal's column and page widths [in]: what the paper style sizes its figures for.
COLUMN_IN = 3.5
PAGE_IN = 7.2
# An experiment's markers: about this many per direction, inflation's pointing up.
EXPERIMENT_MARKERS = 24
EXPERIMENT_STYLE = {INFLATION: {'marker': '^', 'color': '#555555'},
                    DEFLATION: {'marker': 'v', 'color': '#999999'}}


class FigureStyleError(UserError):
    """A figure style, width or resolution that cannot be drawn (one line, naming the option)."""


@dataclass(frozen=True)
class FigureStyle:
    """
    How the figures look: ``paper`` or ``screen``, a width and a resolution.

    ``width_in`` (None: each figure's own) sets every figure's width in inches, its height
    following the figure's proportions; ``dpi`` the PNG's resolution.
    """

    name: str = 'paper'
    width_in: float | None = None
    dpi: float | None = None

    def __post_init__(self) -> None:
        """Refuse a style, width or resolution that cannot be drawn."""
        if self.name not in FIGURE_STYLES:
            raise FigureStyleError(f'--style {self.name}: expected one of '
                                   f'{", ".join(FIGURE_STYLES)}')
        if self.width_in is not None and not 1.0 <= self.width_in <= 40.0:
            raise FigureStyleError(f'--width {self.width_in:g}: a figure width in inches, from '
                                   '1 to 40 (3.5 is a journal column, 7.2 a page)')
        if self.dpi is not None and not 30.0 <= self.dpi <= 1200.0:
            raise FigureStyleError(f'--dpi {self.dpi:g}: a resolution from 30 to 1200 dots per '
                                   'inch')

    @property
    def paper(self) -> bool:
        """No titles, print sizes (the screen style: short titles, 1.6 times larger)."""
        return self.name == 'paper'

    @property
    def resolution(self) -> float:
        """The PNG's dots per inch."""
        return self.dpi if self.dpi is not None else (300.0 if self.paper else 110.0)

    def size(self, width: float, height: float) -> tuple[float, float]:
        """
        A figure's size in inches, from its paper size (``width`` x ``height``).

        The screen style draws everything 1.6 times larger; a set width scales both sides.
        """
        if not self.paper:
            width, height = 1.6 * width, 1.6 * height
        if self.width_in is not None:
            width, height = self.width_in, height * self.width_in / width
        return width, height

    def title(self, ax: object, text: str, pad: float | None = None) -> None:
        """A short title on screen, ``pad`` points above the axes; none in a paper."""
        if not self.paper:
            ax.set_title(text, fontsize=9, pad=pad)

    def context(self) -> object:
        """The settings of matplotlib for this style, for drawing and saving."""
        import matplotlib

        base = {'font.size': 8.0, 'axes.labelsize': 8.0, 'axes.titlesize': 8.0,
                'xtick.labelsize': 7.0, 'ytick.labelsize': 7.0, 'legend.fontsize': 6.5,
                'legend.frameon': False, 'legend.handlelength': 2.6,
                'axes.linewidth': 0.6, 'xtick.major.width': 0.6, 'ytick.major.width': 0.6,
                'xtick.major.size': 3.0, 'ytick.major.size': 3.0, 'grid.linewidth': 0.4,
                'lines.markersize': 3.5, 'savefig.pad_inches': 0.03,
                'svg.fonttype': 'none'}
        if not self.paper:
            base.update({'font.size': 10.0, 'axes.labelsize': 10.0, 'xtick.labelsize': 9.0,
                         'ytick.labelsize': 9.0, 'legend.fontsize': 8.0})
        return matplotlib.rc_context(base)


FIGURE_STYLES = ('paper', 'screen')
PAPER = FigureStyle()


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


def legend_below(fig: object, handles: list, ncol: int = 2) -> None:
    """
    One key for every panel of ``fig``, just below all that is drawn (its x labels included).

    ``handles``: the artists to name, each with its label.
    """
    renderer = fig.canvas.get_renderer()
    bottom = min(ax.get_tightbbox(renderer).y0 for ax in fig.axes if ax.get_visible())
    fig.legend(handles=handles, loc='upper center', ncol=ncol, borderaxespad=0.0,
               bbox_to_anchor=(0.5, bottom / fig.bbox.height))


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


def darker(colour: object) -> tuple[float, float, float]:
    """A darker shade of ``colour``: a segment's deflation, dashed over its inflation."""
    from matplotlib.colors import to_rgb

    return tuple(0.5 * c for c in to_rgb(colour))


def direction_key(ax: object) -> None:
    """Legend entries that say which line style is which direction (per-segment colours)."""
    for direction, shade in ((INFLATION, '0.55'), (DEFLATION, '0.15')):
        style = {k: v for k, v in STYLE[direction].items() if k in ('ls', 'lw')}
        ax.plot([], [], color=shade, label=direction, **style)


def _draw_legs(ax: object, recording: Recording, x: NDArray[np.float64],
               y: NDArray[np.float64], label: str = '', directions: bool = True,
               **extra: object) -> None:
    """
    The recorded path, leg by leg, with its snap-throughs as arrows.

    ``label`` starts each leg's legend entry; with ``directions`` it ends with the leg's
    direction, else only the first inflation leg is named (a figure with a colour per segment
    says once, with :func:`direction_key`, which style is which direction). A colour given in
    ``extra`` is the inflation's; deflation is drawn in a darker shade of it.
    """
    snaps = _snap_rows(recording)
    starts = recording.state_run_starts
    shown = set()
    for direction, rows in _legs(recording):
        style = dict(STYLE[direction])
        style.update(extra)
        if 'color' in extra and direction == DEFLATION:
            style['color'] = darker(extra['color'])
        # Runs after the first (a reset or restarted pump) are named and drawn fainter.
        run = int(np.searchsorted(starts, rows[0], side='right')) + 1 if starts.size else 0
        key = (run, direction)
        prefix = f'{label}{f"run {run}, " if run else ""}'
        if directions:
            name = f'{prefix}{direction}' if key not in shown else None
        else:
            name = prefix.rstrip(', ') if key not in shown and direction == INFLATION else None
        shown.add(key)
        if run > 1:
            style['alpha'] = 0.5
        ax.plot(_broken(x, rows, snaps), _broken(y, rows, snaps), label=name, **style)
    for row in snaps.tolist():
        direction = INFLATION if recording.state_flow_sign[row] > 0 else DEFLATION
        ax.annotate('', xy=(x[row], y[row]), xytext=(x[row - 1], y[row - 1]),
                    arrowprops={'arrowstyle': '->', 'color': extra.get(
                        'color', STYLE[direction]['color']), 'lw': 1.0,
                        'shrinkA': 0, 'shrinkB': 0}, zorder=4)


def _x_limits(ax: object, *ranges: tuple[float, float]) -> None:
    lo = min(r[0] for r in ranges)
    hi = max(r[1] for r in ranges)
    pad = 0.03 * (hi - lo or 1.0)
    ax.set_xlim(lo - pad, hi + pad)


def _draw_experiment(ax: object, experiment: object) -> tuple[float, float]:
    """An experiment's PV points, inflation and deflation apart; its injected range [mL]."""
    for direction, sign in ((INFLATION, 1), (DEFLATION, -1)):
        rows = np.flatnonzero(experiment.sign == sign)
        if not rows.size:
            continue
        every = max(1, rows.size // EXPERIMENT_MARKERS)
        # Deflation's markers sit between inflation's: a curve that retraces itself shows both.
        offset = every // 2 if sign < 0 else 0
        style = EXPERIMENT_STYLE[direction]
        ax.plot(experiment.injected[rows] * ML, experiment.pressure[rows] * KPA, '-',
                lw=0.6, color=style['color'], marker=style['marker'], ms=3.2, mfc='none',
                mew=0.7, markevery=(offset, every), label=f'experiment, {direction}',
                zorder=1)
    return float(experiment.injected.min() * ML), float(experiment.injected.max() * ML)


def plot_pv(recording: Recording, model: ModelCurves | None, out: Path,
            experiment: object | None = None, svg: bool = False,
            style: FigureStyle = PAPER) -> list[Path]:
    """Gauge pressure against injected volume, inflation and deflation apart, snaps marked."""
    fig, axes = new_figure(*style.size(3.5, 2.6), margins={'left': 0.14, 'bottom': 0.16,
                                                            'top': 0.97})
    ax = axes[0, 0]
    u = recording.state_injected * ML
    ranges = [(float(u.min()), float(u.max()))]
    if model is not None:
        for j, (name, (added, pressure)) in enumerate(zip(model.names, model.segment_curves)):
            dv = added * ML
            shown = dv <= max(u.max() * 1.2, 1e-9)
            ax.plot(dv[shown], pressure[shown] * KPA, ':', lw=1.0,
                    color=SEGMENT_COLOURS[j % len(SEGMENT_COLOURS)],
                    label=f'{name} alone (vs its added volume)')
    _draw_legs(ax, recording, u, recording.pressure * KPA)
    if experiment is not None:
        ranges.append(_draw_experiment(ax, experiment))
    _x_limits(ax, *ranges)
    ax.set_xlabel(INJECTED)
    ax.set_ylabel(GAUGE)
    ax.grid(alpha=0.3)
    # Below the axes: a PV curve fills its box, any corner may hold data.
    ax.legend(loc='upper center', bbox_to_anchor=(0.5, -0.155), ncol=2)
    style.title(ax, 'Pressure-volume curve; arrows: snap-throughs')
    return save_figure(fig, out, svg, style)


def plot_segments(recording: Recording, out: Path, svg: bool = False,
                  lengths: FloatArray | None = None, style: FigureStyle = PAPER) -> list[Path]:
    """
    Volume added to each segment, its curvature and its bend angle against injected volume.

    The bend angle of a segment is its curvature times its length (``lengths``, from the scene
    or the camera's backbone; without them the panel is left out); the tip's is their sum.
    """
    curved = recording.curvatures.shape[0] == recording.volumes.shape[0]
    angles = curved and lengths is not None
    panels = 1 + curved + angles
    fig, axes = new_figure(*style.size(3.5, 1.45 * panels + 0.45), panels, 1,
                           {'left': 0.15, 'bottom': 0.4 / (1.45 * panels + 0.45),
                            'top': 0.985, 'hspace': 0.1}, sharex=True)
    u = recording.state_injected * ML
    rest = recording.volumes[0]
    for j, name in enumerate(recording.segment_names):
        colour = SEGMENT_COLOURS[j % len(SEGMENT_COLOURS)]
        _draw_legs(axes[0, 0], recording, u, (recording.volumes[:, j] - rest[j]) * ML,
                   label=name, directions=False, color=colour)
        if curved:
            _draw_legs(axes[1, 0], recording, u, recording.curvatures[:, j],
                       label=name, directions=False, color=colour)
        if angles:
            _draw_legs(axes[2, 0], recording, u,
                       np.degrees(recording.curvatures[:, j] * lengths[j]),
                       label=name, directions=False, color=colour)
    direction_key(axes[0, 0])
    if angles:
        _draw_legs(axes[2, 0], recording, u,
                   np.degrees(recording.curvatures @ np.asarray(lengths)),
                   label='tip (sum)', directions=False, color='0.35')
        axes[2, 0].set_ylabel('bend angle [deg]')
    axes[0, 0].set_ylabel('volume added\nto segment [mL]')
    if curved:
        axes[1, 0].set_ylabel('curvature [1/m]')
    axes[-1, 0].set_xlabel(INJECTED)
    for ax in axes[:, 0]:
        ax.grid(alpha=0.3)
    axes[0, 0].legend(ncol=2, loc='upper left')
    if angles:
        axes[2, 0].legend(loc='upper left')
    style.title(axes[0, 0], 'Segment volume, curvature and bend angle')
    return save_figure(fig, out, svg, style)


def plot_volume_split(recording: Recording, model: ModelCurves | None, out: Path,
                      svg: bool = False, style: FigureStyle = PAPER) -> list[Path]:
    """v1 against v2 (added volumes): equilibria, constant total volume, the recorded path."""
    names = recording.segment_names
    if len(names) != 2:
        return _segments_instead(recording, out, svg, style)
    fig, axes = new_figure(*style.size(3.3, 3.2), margins={'left': 0.15, 'bottom': 0.13,
                                                            'top': 0.98, 'right': 0.98})
    ax = axes[0, 0]
    rest = model.rest_volumes if model is not None else recording.volumes[0]
    dv = (recording.volumes - rest) * ML
    limit = float(np.nanmax(dv)) * 1.1 or 1.0
    if model is not None:
        shown = set()
        for volumes, stable in model.equilibria:
            cv = (volumes - rest) * ML
            for mask, colour, label in ((stable, '0.2', 'stable equilibria'),
                                        (~stable, UNSTABLE_COLOUR, 'unstable equilibria')):
                if mask.any():
                    ax.plot(np.where(mask, cv[:, 0], np.nan), np.where(mask, cv[:, 1], np.nan),
                            color=colour, lw=0.7, alpha=0.7, zorder=1,
                            label=None if label in shown else label)
                    shown.add(label)
    total_volume_lines(ax, limit)
    _draw_legs(ax, recording, dv[:, 0], dv[:, 1])
    ax.set_xlabel(f'volume added to {names[0]} [mL]')
    ax.set_ylabel(f'volume added to {names[1]} [mL]')
    ax.set_aspect('equal', adjustable='box')
    ax.set_xlim(0, limit)
    ax.set_ylim(0, limit)
    ax.grid(alpha=0.2)
    # Below the axes, as the PV curve's: the path may run through any corner of the plane.
    ax.legend(loc='upper center', bbox_to_anchor=(0.5, -0.13), ncol=2)
    style.title(ax, 'Volume distribution; grey: constant total volume')
    return save_figure(fig, out, svg, style)


def _segments_instead(recording: Recording, out: Path, svg: bool,
                      style: FigureStyle) -> list[Path]:
    """The volume added to each segment against injected volume (not two segments)."""
    fig, axes = new_figure(*style.size(3.5, 2.6), margins={'left': 0.14, 'bottom': 0.16,
                                                            'top': 0.97})
    ax = axes[0, 0]
    u = recording.state_injected * ML
    rest = recording.volumes[0]
    for j, name in enumerate(recording.segment_names):
        _draw_legs(ax, recording, u, (recording.volumes[:, j] - rest[j]) * ML,
                   label=name, directions=False, color=SEGMENT_COLOURS[j % len(SEGMENT_COLOURS)])
    direction_key(ax)
    ax.set_xlabel(INJECTED)
    ax.set_ylabel('volume added to segment [mL]')
    ax.grid(alpha=0.3)
    ax.legend()
    style.title(ax, 'Volume distribution')
    return save_figure(fig, out, svg, style)


def total_volume_lines(ax: object, limit: float) -> float:
    """
    Grey lines of constant total added volume on a v1-v2 plane of ``limit`` mL; their spacing.

    Named once in the legend with their spacing: a label on the plane would sit on the path
    wherever it runs along an axis.
    """
    step = nice_step(2 * limit / 8) if limit > 0 else 1.0
    for k, total in enumerate(np.arange(step, 2 * limit + step, step)):
        ax.plot([0, total], [total, 0], color='0.8', lw=0.5, zorder=0,
                label=None if k else f'total volume, every {step:g} mL')
    return step


def nice_step(raw: float) -> float:
    """1, 2 or 5 times a power of ten, at least ``raw``: a spacing of grid or guide lines."""
    exponent = 10 ** np.floor(np.log10(raw)) if raw > 0 else 1.0
    for factor in (1, 2, 5, 10):
        if raw <= factor * exponent:
            return float(factor * exponent)
    return float(10 * exponent)


def segment_joints(points: FloatArray, count: int) -> FloatArray:
    """
    Where each segment of a camera backbone ends and the next begins: (count - 1, 2) x, z [m].

    The backbone holds 1 + count x k points, k per segment (softseq_ros.segments.kinematics);
    empty when it has no such layout (a foreign camera's).
    """
    intervals = len(points) - 1
    if count < 2 or intervals < count or intervals % count:
        return np.zeros((0, 2))
    per_segment = intervals // count
    return np.asarray(points[per_segment:intervals:per_segment][:count - 1, :2], dtype=float)


def plot_shapes(recording: Recording, out: Path, svg: bool = False,
                experiment: object | None = None, style: FigureStyle = PAPER) -> list[Path]:
    """
    The backbone at each step: inflation and deflation in two panels, one colour per step.

    Each step is labelled with its injected volume and tip angle; an experiment's tip at the
    same volume and direction (where its file has tips) is an open circle of the step's colour.
    """
    from matplotlib import colormaps

    from softseq_ros.analysis.experiment import tip_errors
    from softseq_ros.analysis.metrics import bend_angles

    # Two square panels side by side, the legends below them: no room left over between.
    fig, axes = new_figure(*style.size(5.6, 3.3), 1, 2,
                           {'left': 0.09, 'right': 0.99, 'bottom': 0.14, 'top': 0.99,
                            'wspace': 0.05}, sharex=True, sharey=True)
    steps = sorted({s.step for s in recording.snapshots if s.step is not None})
    palette = colormaps['viridis']
    colour = {step: palette(0.9 * i / max(len(steps) - 1, 1)) for i, step in enumerate(steps)}
    measured = {(t['step'], t['direction'], t['injected_m3']): t['experiment_tip_m']
                for t in (tip_errors(experiment, recording.snapshots) if experiment else [])}
    count = len(recording.segment_names)
    joined = False
    for ax, direction in zip(axes[0], (INFLATION, DEFLATION)):
        shots = [s for s in recording.snapshots if s.direction == direction]
        for shot in shots:
            tip_angle = float(np.degrees(np.sum(bend_angles(shot.points, count) or [np.nan])))
            label = (f'{"step " + str(shot.step) + ": " if shot.step is not None else ""}'
                     f'{shot.injected * ML:.1f} mL, {tip_angle:.0f}°')
            shade = colour.get(shot.step, 'k')
            ax.plot(shot.points[:, 0] * MM, shot.points[:, 1] * MM, '-', lw=1.6,
                    color=shade, label=label)
            ax.plot(*(shot.tip * MM), 'o', ms=3, color=shade)
            joints = segment_joints(shot.points, count)
            if joints.size:
                joined = True
                ax.plot(joints[:, 0] * MM, joints[:, 1] * MM, 'o', ms=3.2, mfc='white',
                        mec=shade, mew=0.9, zorder=3)
            tip = measured.get((shot.step, shot.direction, shot.injected))
            if tip is not None:
                ax.plot(tip[0] * MM, tip[1] * MM, 'o', ms=6, mfc='none', mew=1.0,
                        color=shade)
        if joined and direction == INFLATION:
            # Named once, in the first panel's key.
            ax.plot([], [], 'o', ms=3.2, mfc='white', mec='0.3', mew=0.9,
                    label='segment joint')
        ax.plot([0], [0], 'ks', ms=5)
        ax.set_xlabel('x [mm]')
        ax.set_aspect('equal', adjustable='box')
        ax.grid(alpha=0.3)
        ax.text(0.02, 0.98, f'{direction}', transform=ax.transAxes, ha='left', va='top',
                fontsize=8, fontweight='bold')
        if shots:
            ax.legend(loc='upper center', bbox_to_anchor=(0.5, -0.13), ncol=2,
                      handlelength=1.2, columnspacing=1.0)
    axes[0, 0].set_ylabel('z [mm]')
    if measured:
        axes[0, 1].text(0.98, 0.98, "open circles: the experiment's tip", ha='right',
                        va='top', fontsize=6.5, transform=axes[0, 1].transAxes)

    _square_limits(axes[0, 0], recording, list(measured.values()))
    style.title(axes[0, 0], 'Tentacle shape at the camera steps')
    return save_figure(fig, out, svg, style)


def _square_limits(ax: object, recording: Recording, extra: list) -> None:
    """Both panels show every snapshot (and experiment tip) at one scale."""
    if not recording.snapshots:
        return
    points = np.vstack([s.points for s in recording.snapshots] + [np.zeros((1, 2))]
                       + [np.asarray(extra).reshape(-1, 2)]) * MM
    lo, hi = points.min(axis=0), points.max(axis=0)
    size = float(np.max(hi - lo)) * 1.08 or 1.0
    centre = 0.5 * (lo + hi)
    ax.set_xlim(centre[0] - size / 2, centre[0] + size / 2)
    ax.set_ylim(centre[1] - size / 2, centre[1] + size / 2)


def held_spans(recording: Recording) -> list[tuple[float, float]]:
    """
    When the pump was held [s, from the first pump command]: each span to its next status.

    A hold the run ends in reaches the last recorded state.
    """
    spans = []
    status = recording.status
    end = float(recording.state_time_s[-1]) if recording.state_time_s.size else 0.0
    for k, (at, state, _) in enumerate(status):
        if state == 'held':
            spans.append((float(at), float(status[k + 1][0]) if k + 1 < len(status) else end))
    return spans


def plot_timeseries(recording: Recording, out: Path, svg: bool = False,
                    style: FigureStyle = PAPER) -> list[Path]:
    """Injected volume, gauge pressure and each segment's total volume against time."""
    fig, axes = new_figure(*style.size(3.5, 4.2), 3, 1, {'left': 0.15, 'top': 0.985,
                                                          'bottom': 0.09, 'hspace': 0.1},
                           sharex=True)
    rows = _thin(recording.pump_time_s.size)
    axes[0, 0].plot(recording.pump_time_s[rows], recording.pump_injected[rows] * ML, 'k-',
                    lw=1.0)
    axes[0, 0].set_ylabel('injected\n(pump) [mL]')
    rows = _thin(recording.state_time_s.size, _snap_rows(recording))
    axes[1, 0].plot(recording.state_time_s[rows], recording.pressure[rows] * KPA, 'k-', lw=1.0)
    axes[1, 0].set_ylabel(GAUGE.replace(' [', '\n['))
    for j, name in enumerate(recording.segment_names):
        axes[2, 0].plot(recording.state_time_s[rows], recording.volumes[rows, j] * ML,
                        lw=1.2, color=SEGMENT_COLOURS[j % len(SEGMENT_COLOURS)], label=name)
    axes[2, 0].set_ylabel('segment volume,\ntotal [mL]')
    axes[2, 0].set_xlabel('time from the first pump command [s]')
    axes[2, 0].legend()
    for ax in axes[:, 0]:
        ax.grid(alpha=0.3)
    # Where a new run of the pump begins (a reset or restart): a line and its number.
    for number, start in enumerate(recording.run_starts, start=2):
        for ax in axes[:, 0]:
            ax.axvline(start.time_s, color='0.4', lw=0.8, ls=':')
        axes[0, 0].annotate(f'run {number}', (start.time_s, 1.0), xycoords=('data',
                            'axes fraction'), xytext=(2, -2), textcoords='offset points',
                            ha='left', va='top', fontsize=7, color='0.3')
    for begin, until in held_spans(recording):
        # Held (by ~/hold, or for want of feedback): the programme paused there.
        for ax in axes[:, 0]:
            ax.axvspan(begin, until, color='0.85', lw=0, zorder=0)
        axes[0, 0].annotate('held', (begin, 1.0), xycoords=('data', 'axes fraction'),
                            xytext=(2, -2), textcoords='offset points', ha='left', va='top',
                            fontsize=7, color='0.3')
    ended = recording.cut_short()
    if ended is not None:
        # The programme did not run to its end: where and why the pump ended it.
        for ax in axes[:, 0]:
            ax.axvline(ended[0], color=STOP_COLOUR, lw=1.0, ls='--')
        axes[0, 0].annotate(f'pump {ended[1]}', (ended[0], 1.0),
                            xycoords=('data', 'axes fraction'), xytext=(-4, -2),
                            textcoords='offset points', ha='right', va='top', fontsize=7,
                            color=STOP_COLOUR)
    style.title(axes[0, 0], 'Time series')
    return save_figure(fig, out, svg, style)


BAG_COLOURS = ('#0072B2', '#D55E00')


def plot_overlay(recordings: list[tuple[str, Recording]], out: Path, svg: bool = False,
                 style: FigureStyle = PAPER) -> list[Path]:
    """
    Two recordings over each other (``softseq compare``): PV curves and v1-v2 planes.

    The planes when both have two segments; a colour per recording, inflation solid,
    deflation dashed.
    """
    plane = all(len(r.segment_names) == 2 for _, r in recordings)
    # The square plane beside the wider PV curve, without room left over between them.
    fig, axes = new_figure(*style.size(6.0 if plane else 3.5, 2.9), 1, 1 + plane,
                           {'left': 0.08 if plane else 0.14, 'bottom': 0.15, 'top': 0.97,
                            'right': 0.98, 'wspace': 0.2},
                           gridspec_kw={'width_ratios': [1.35, 1] if plane else [1]})
    ranges = []
    limit = 0.0
    for (label, recording), colour in zip(recordings, BAG_COLOURS):
        u = recording.state_injected * ML
        ranges.append((float(u.min()), float(u.max())))
        _draw_legs(axes[0, 0], recording, u, recording.pressure * KPA, label=label,
                   directions=False, color=colour)
        if plane:
            dv = (recording.volumes - recording.volumes[0]) * ML
            limit = max(limit, float(np.nanmax(dv)) * 1.05)
            _draw_legs(axes[0, 1], recording, dv[:, 0], dv[:, 1], label=label,
                       directions=False, color=colour)
    _x_limits(axes[0, 0], *ranges)
    axes[0, 0].set_xlabel(INJECTED)
    axes[0, 0].set_ylabel(GAUGE)
    direction_key(axes[0, 0])
    axes[0, 0].legend(loc='upper center', bbox_to_anchor=(0.5, -0.155), ncol=2)
    if plane:
        names = [r.segment_names for _, r in recordings]
        same = names[0] == names[1]
        axes[0, 1].set_xlabel(f'volume added to {names[0][0] if same else "segment 1"} [mL]')
        axes[0, 1].set_ylabel(f'volume added to {names[0][1] if same else "segment 2"} [mL]')
        axes[0, 1].set_aspect('equal', adjustable='box')
        axes[0, 1].set_xlim(0, limit or 1.0)
        axes[0, 1].set_ylim(0, limit or 1.0)
    for ax in axes[0]:
        ax.grid(alpha=0.3)
    style.title(axes[0, 0], 'Both recordings: pressure-volume curve')
    return save_figure(fig, out, svg, style)


# A snap's panels take this many inches of a page's width; more snaps than fit wrap onto rows.
TRANSIENT_PANEL_IN = 2.25


def plot_transients(windows: list[TransientWindow], segment_names: tuple[str, ...],
                    channel_names: tuple[str, ...], out: Path, svg: bool = False,
                    style: FigureStyle = PAPER) -> list[Path]:
    """
    Each snap in time: gauge pressure and channel flow above, segment volumes below.

    Time runs from the snap's start; dashed: the quasi-static volumes at the same injected
    volume (when the scene was given). As many snaps side by side as a page holds, the rest
    on rows below; one key under all of them, so that no legend sits on a curve.
    """
    from matplotlib.lines import Line2D

    count = len(windows)
    # As few rows as the page needs, the snaps spread evenly over them.
    rows = -(-count // max(1, int(PAGE_IN // TRANSIENT_PANEL_IN)))
    columns = -(-count // rows)
    width, height = style.size(TRANSIENT_PANEL_IN * columns + 0.4, 3.4 * rows + 0.3)
    # Per row of snaps: pressure, volumes, and a gap for the x label and the next titles.
    ratios = [1.0, 1.0, 0.42] * rows
    fig, axes = new_figure(width, height, 3 * rows, columns,
                           {'left': 0.6 / width, 'right': 1 - 0.6 / width,
                            'top': 1 - 0.35 / height, 'bottom': 0.02, 'wspace': 0.55,
                            'hspace': 0.12}, gridspec_kw={'height_ratios': ratios})
    for gap in axes[2::3].ravel():
        gap.set_visible(False)
    flows_drawn = quasi_static_drawn = False
    for number, window in enumerate(windows):
        row, column = divmod(number, columns)
        snap = window.snap
        # Short snaps read in ms, long ones in s.
        scale, unit = (1e3, 'ms') if snap.window_s[1] - snap.window_s[0] < 2.0 else (1.0, 's')
        top, bottom = axes[3 * row, column], axes[3 * row + 1, column]
        top.sharex(bottom)
        top.tick_params(labelbottom=False)
        top.plot(window.time_s * scale, window.pressure * KPA, 'k-', lw=1.3)
        if window.flow.size:
            flows_drawn = True
            flow_axis = top.twinx()
            for j in range(len(channel_names)):
                flow_axis.plot(window.flow_time_s * scale, window.flow[:, j] * ML, '-', lw=1.1,
                               color=f'C{j + 3}')
            if column == columns - 1 or number == count - 1:
                flow_axis.set_ylabel('channel flow to the tip [mL/s]', fontsize=8)
            flow_axis.tick_params(labelsize=7)
        for j in range(len(segment_names)):
            colour = SEGMENT_COLOURS[j % len(SEGMENT_COLOURS)]
            bottom.plot(window.time_s * scale, window.volumes[:, j] * ML, '-', lw=1.4,
                        color=colour)
            if window.quasi_static_volumes is not None:
                quasi_static_drawn = True
                bottom.plot(window.time_s * scale, window.quasi_static_volumes[:, j] * ML, '--',
                            lw=1.0, color=colour)
        for ax in (top, bottom):
            ax.axvline(0.0, color='0.5', lw=0.8, ls=':')
            ax.grid(alpha=0.3)
            ax.tick_params(labelsize=7)
        top.set_title(f'snap {snap.number} ({snap.direction}) at {snap.injected * ML:.2f} mL\n'
                      f'10-90 %: {duration_text(snap.duration_s)}', fontsize=8)
        bottom.set_xlabel(f"time from the snap's start [{unit}]", fontsize=8)
        if column == 0:
            top.set_ylabel(GAUGE, fontsize=8)
            bottom.set_ylabel('segment volume [mL]', fontsize=8)
    for number in range(count, rows * columns):
        row, column = divmod(number, columns)
        axes[3 * row, column].set_visible(False)
        axes[3 * row + 1, column].set_visible(False)
    handles = [Line2D([], [], color='k', lw=1.3, label='gauge pressure at the syringe')]
    if flows_drawn:
        handles += [Line2D([], [], color=f'C{j + 3}', lw=1.1, label=f'flow {name}')
                    for j, name in enumerate(channel_names)]
    handles += [Line2D([], [], color=SEGMENT_COLOURS[j % len(SEGMENT_COLOURS)], lw=1.4,
                       label=name) for j, name in enumerate(segment_names)]
    if quasi_static_drawn:
        handles.append(Line2D([], [], color='0.3', ls='--', lw=1.0,
                              label='quasi-static at the same injected volume'))
    handles.append(Line2D([], [], color='0.5', ls=':', lw=0.8, label="the snap's start"))
    legend_below(fig, handles, ncol=min(len(handles), 3))
    if not style.paper:
        fig.suptitle('Snap-throughs in time', fontsize=10)
    return save_figure(fig, out, svg, style)


def _draw(name: str, args: tuple) -> list[Path]:
    style = next((a for a in args if isinstance(a, FigureStyle)), PAPER)
    with style.context():
        return _FIGURE_FUNCTIONS[name](*args)


def _draw_split(jobs: list[tuple[str, tuple]], split: int) -> list[list[Path]]:
    """Draw ``jobs[:split]`` here and the rest in a fork (which has matplotlib loaded)."""
    ours, theirs = jobs[:split], jobs[split:]
    # The fork's one-line error (a figure it could not write) comes back through a pipe.
    read_end, write_end = os.pipe() if theirs else (-1, -1)
    parent = os.getpid()
    child = os.fork() if theirs else 0
    if theirs and child == 0:
        status = 0
        try:
            end_with_parent(parent)   # a fork does not inherit its parent's setting
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
    svg = next(a for a in args if isinstance(a, bool))
    return [out, out.with_suffix('.svg')] if svg else [out]


def draw(name: str, *args: object) -> list[Path]:
    """Draw figure ``name`` here, in its style's settings (the style among ``args``)."""
    return _draw(name, args)


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
        target_pressure=(None if recording.target_pressure is None
                         else recording.target_pressure[pump]),
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
                  transients: Transients | None = None,
                  style: FigureStyle = PAPER) -> list[Path]:
    """
    All figures of a run into ``directory`` (PNG, and SVG as well with ``svg``), in ``style``.

    ``transients`` (a dynamic recording's, with a snap in time) add ``transients.png``. The
    bend-angle panel of ``segments.png`` takes the segments' lengths from the scene's model,
    else from a camera snapshot's backbone.

    Drawing is most of a report's time: with ``workers`` (from
    :func:`softseq_ros.analysis.figure_workers.start_workers`) the figures are drawn in those
    processes, in parallel.
    """
    directory.mkdir(parents=True, exist_ok=True)
    # Windows are cut from the whole recording: thinning could lose a short snap.
    windows = transient_windows(recording, transients, MAX_TRANSIENT_SNAPS, MAX_POINTS) \
        if transients is not None else []
    from softseq_ros.analysis.metrics import segment_lengths

    recording = thinned(recording)
    model = ModelCurves.from_map(emap) if emap is not None else None
    lengths = (np.array([segment.length for segment in emap.segments]) if emap is not None
               else segment_lengths(recording.snapshots, len(recording.segment_names)))
    jobs = [('pv', (recording, model, directory / 'pv.png', experiment, svg, style)),
            ('segments', (recording, directory / 'segments.png', svg, lengths, style)),
            ('volume_split', (recording, model, directory / 'volume_split.png', svg, style))]
    # A figure with nothing to show is not drawn: no snapshot (a scene without trigger
    # volumes) leaves no shapes to draw.
    if recording.snapshots:
        jobs.append(('shapes', (recording, directory / 'shapes.png', svg, experiment, style)))
    jobs.append(('timeseries', (recording, directory / 'timeseries.png', svg, style)))
    if windows:
        jobs.append(('transients', (windows, recording.segment_names, transients.channel_names,
                                    directory / 'transients.png', svg, style)))
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
                     'overlay': plot_overlay,
                     'shapes': plot_shapes, 'timeseries': plot_timeseries,
                     'transients': plot_transients}


def save_figure(fig: object, out: Path, svg: bool, style: FigureStyle) -> list[Path]:
    """
    Write ``fig`` as PNG (and SVG), a failed write naming the file; the paths written.

    At the style's resolution, cropped to what is drawn: no blank margins, and nothing cut off
    (a screen figure's title above its axes, a legend below them).
    """
    # 0.03 in: at a screen's 110 dpi 0.02 in left a spine on the image's last pixel.
    crop = {'bbox_inches': 'tight', 'pad_inches': 0.03}
    # zlib's fastest level: a fifth of a figure's time at the default level, for 7 % more bytes.
    with writing(out):
        fig.savefig(out, dpi=style.resolution, pil_kwargs={'compress_level': 1}, **crop)
    written = [out]
    if svg:
        with writing(out.with_suffix('.svg')):
            fig.savefig(out.with_suffix('.svg'), **crop)
        written.append(out.with_suffix('.svg'))
    return written

