"""
The figure of a transition graph (softseq_ros.quasistatic.graph): ``softseq graph``'s graph.png.

Left: every stable branch as a horizontal bar over the injected volume, labelled by its state
(each segment's piece, base to tip), with its snaps as vertical arrows at their volumes:
inflation's (blue, solid) point up, deflation's (vermillion, dashed) down; joins are thin grey
links. The default inflate-then-deflate path is drawn dark and thick; a branch no history
reaches from rest is hatched. For two segments, right: the volume plane (as the paper's
Fig. 1B), the equilibrium set with the stable branches and the snaps at constant total volume.
One key below both. Drawn in a :class:`~softseq_ros.analysis.figures.FigureStyle`, a page
wide in the paper style, as the report's figures.
"""

from pathlib import Path

import numpy as np

from softseq_ros.analysis.figures import (
    INJECTED,
    ML,
    PAGE_IN,
    PAPER,
    STYLE,
    UNSTABLE_COLOUR,
    FigureStyle,
    legend_below,
    new_figure,
    save_figure,
    total_volume_lines,
)
from softseq_ros.analysis.recording import DEFLATION, INFLATION
from softseq_ros.errors import UserError
from softseq_ros.quasistatic.graph import INFLATION as GRAPH_INFLATION
from softseq_ros.quasistatic.graph import JOIN, SNAP, GraphBranch, TransitionGraph
from softseq_ros.quasistatic.regulator import HysteronGraph

# The most stable branches graph.png draws. The figure has a row of bars per branch at most,
# and its height, so its pixels and memory, grow with the rows: three segments of 16 folds
# each (289 branches) take 7.6 s and 0.4 GB, of 24 folds (433) 13 s and 0.6 GB, and of
# dozens more ran out of memory after graph.json was written. The shipped scenes have at
# most 21. The graph itself is cheap (1,081 branches in 2 s).
MAX_FIGURE_BRANCHES = 300


class GraphTooLargeError(UserError):
    """A transition graph with more stable branches than its figure can show."""


def check_figure_size(graph: TransitionGraph, where: str) -> None:
    """Refuse (GraphTooLargeError naming ``where`` and the bound) a graph too large to draw."""
    count = len(graph.branches)
    if count > MAX_FIGURE_BRANCHES:
        raise GraphTooLargeError(
            f'{where}: {count} stable branches, more than the {MAX_FIGURE_BRANCHES} that '
            'graph.png can show (its height grows with them: 433 take 0.6 GB); nothing '
            'written. softseq_ros.graph(scene) gives the graph without a figure')


_PATH_COLOUR = '0.1'
_OTHER_COLOUR = '0.65'
# Text over the bars' snap arrows stays legible: on a white ground, the arrow behind it.
_GROUND = {'facecolor': 'white', 'edgecolor': 'none', 'alpha': 0.85, 'pad': 0.4}


def branch_rows(graph: TransitionGraph, label_share: float = 0.0) -> dict[int, float]:
    """
    A row per branch such that inflation snaps point up and deflation snaps down.

    ``label_share``: the fraction of the volume range one character of a bar's label takes,
    so that labels on one row do not run into each other.

    Each snap orders two branches (an inflation snap's target above its source, a deflation
    snap's below); a branch sits one level above the highest branch it must be above (the
    longest chain of such orders). Where the orders form a cycle, the edge closing it is left
    out. Branches on one level that overlap in volume get rows of their own.
    """
    n = len(graph.branches)
    above: dict[int, set[int]] = {i: set() for i in range(n)}   # i must be above these
    for t in graph.snaps():
        low, high = ((t.source, t.target) if t.direction == GRAPH_INFLATION
                     else (t.target, t.source))
        if low != high:
            above[high].add(low)
    level: dict[int, int] = {}
    visiting: set[int] = set()

    def depth(i: int) -> int:
        if i in level:
            return level[i]
        visiting.add(i)
        below = [depth(j) for j in sorted(above[i]) if j not in visiting]
        visiting.discard(i)
        level[i] = 1 + max(below, default=-1)
        return level[i]

    for i in range(n):
        depth(i)
    span = graph.injected_range[1] - graph.injected_range[0]
    least = graph.min_reversals()
    rows: dict[int, float] = {}
    row = 0
    for lvl in sorted(set(level.values())):
        members = sorted((i for i in range(n) if level[i] == lvl),
                         key=lambda i: graph.branches[i].injected_lo)
        lanes: list[float] = []   # the right end of each lane's last bar
        for i in members:
            b = graph.branches[i]
            right = max(b.injected_hi,
                        b.injected_lo + label_share * span * len(_bar_text(b, least[i])))
            lane = next((k for k, end in enumerate(lanes) if end < b.injected_lo), None)
            if lane is None:
                lanes.append(right)
                lane = len(lanes) - 1
            else:
                lanes[lane] = right
            rows[i] = float(row + lane)
        row += len(lanes)
    return rows


def _bar_text(branch: GraphBranch, reversals: int | None) -> str:
    reach = ('unreachable' if reversals is None
             else f'{reversals} reversal' + ('s' if reversals != 1 else ''))
    return f'#{branch.index} {branch.label}  ({reach})'


def plot_graph(graph: TransitionGraph, out: Path, emap: object | None = None,
               max_reversals: int | None = None, svg: bool = False,
               style: FigureStyle = PAPER) -> list[Path]:
    """Draw the graph to ``out`` in ``style``; with ``emap`` and two segments, the plane too."""
    with style.context():
        return _plot_graph(graph, out, emap, max_reversals, svg, style)


def _plot_graph(graph: TransitionGraph, out: Path, emap: object | None,
                max_reversals: int | None, svg: bool, style: FigureStyle) -> list[Path]:
    from matplotlib import rcParams

    plane = emap is not None and len(graph.segment_names) == 2
    # A page wide by default; the figure's final width in inches, its type size in points.
    width = style.size(PAGE_IN, 1.0)[0]
    type_in = rcParams['font.size'] / 72
    # The plane beside the bars on a page, below them in a column (beside, both would be
    # too narrow to read).
    beside = plane and width >= 5.0
    bars_in = width - 4.2 * type_in - (0.4 * width if beside else 0.0)
    # A label's characters are about 0.55 of its type size wide ('small': 5/6 of the type).
    rows = branch_rows(graph, 0.55 * type_in * 5 / 6 / bars_in)
    pitch = 2.4 * type_in   # a row of bars, its label above it
    bars_height = max(pitch * (max(rows.values()) + 1.8), 1.2)
    below = plane and not beside
    plane_height = width - 5.5 * type_in if below else 0.0
    # Room under each panel for its tick labels and x label, and at the top for the snaps'
    # volumes.
    axis_in = 4.0 * type_in
    height = bars_height + axis_in + (plane_height + axis_in if below else 0.0)
    if beside:
        bars_height = max(bars_height, 0.4 * width)
        height = bars_height + axis_in
    margins = {'left': 4.2 * type_in / width, 'right': 0.99, 'wspace': 0.13,
               'bottom': axis_in / height, 'top': 1 - 0.05 / height,
               'hspace': axis_in / (0.5 * (bars_height + plane_height))}
    fig, axes = new_figure(width, height, rows=2 if below else 1, cols=2 if beside else 1,
                           margins=margins,
                           gridspec_kw={'width_ratios': [1.5, 1.0]} if beside else
                           {'height_ratios': [bars_height, plane_height]} if below else {})
    least = graph.min_reversals()
    unreachable = _draw_bars(axes[0, 0], graph, rows, max_reversals, least)
    # Rows as far apart whatever the panel's height: a taller panel centres them.
    spare = 0.5 * (bars_height / pitch - (max(rows.values()) + 1.8))
    axes[0, 0].set_ylim(-0.8 - spare, max(rows.values()) + 1.0 + spare)
    plane_key = _draw_plane(axes[0, 1] if beside else axes[1, 0], graph, emap) if plane else []
    _legend(fig, graph, plane_key, unreachable, max_reversals, ncol=3 if width >= 5.0 else 2)
    names = ' | '.join(graph.segment_names)
    # Above the snaps' volumes over the bars.
    style.title(axes[0, 0], f'Transition graph: {len(graph.branches)} stable branches, '
                f'{len(graph.snaps())} snaps (state: {names})',
                pad=42.0 if graph.snaps() else None)
    return save_figure(fig, out, svg, style)


def _legend(fig: object, graph: TransitionGraph, plane_key: list, unreachable: bool,
            max_reversals: int | None, ncol: int) -> None:
    """
    One key for both panels, below them, naming what is drawn.

    ``plane_key``: what the volume plane draws beyond the bars (its lines, named).
    """
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    kinds = {(t.kind, t.direction) for t in graph.transitions if t.target is not None}
    handles = []
    if (SNAP, GRAPH_INFLATION) in kinds:
        handles.append(Line2D([], [], color=STYLE[INFLATION]['color'],
                              label='snap on inflation (up)'))
    if any(kind == SNAP and direction != GRAPH_INFLATION for kind, direction in kinds):
        handles.append(Line2D([], [], color=STYLE[DEFLATION]['color'], ls='--',
                              label='snap on deflation (down)'))
    if any(kind == JOIN for kind, _ in kinds):
        handles.append(Line2D([], [], color='0.6', ls=':',
                              label='join (a peak or valley)'))
    handles.append(Patch(color=_PATH_COLOUR, label='branch on the default path'))
    if not all(b.default_path for b in graph.branches):
        handles.append(Patch(color=_OTHER_COLOUR, label='branch off it'))
    if unreachable:
        handles.append(Patch(facecolor='white', edgecolor=_OTHER_COLOUR, hatch='///',
                             label='branch no history reaches' if max_reversals is None
                             else f'branch not reached within {max_reversals} reversals'))
    handles += plane_key
    legend_below(fig, handles, ncol)


def _draw_bars(ax: object, graph: TransitionGraph, rows: dict[int, float],
               max_reversals: int | None, least: dict[int, int | None]) -> bool:
    """The branches as bars with their snaps and joins; whether one is unreachable."""
    hatched = False
    volumes: dict[float, str] = {}   # each snap's volume [mL], its direction's colour
    span = graph.injected_range[1] - graph.injected_range[0]
    for b in graph.branches:
        y = rows[b.index]
        colour = _PATH_COLOUR if b.default_path else _OTHER_COLOUR
        unreachable = least[b.index] is None or (max_reversals is not None
                                                 and least[b.index] > max_reversals)
        hatched = hatched or unreachable
        # A branch between two close folds may be a fraction of a percent of the range wide:
        # drawn at least that wide, so it shows.
        width = max(b.injected_hi - b.injected_lo, 0.004 * span)
        ax.barh(y, width * ML, left=b.injected_lo * ML, height=0.36,
                color='white' if unreachable else colour, edgecolor=colour,
                hatch='///' if unreachable else None, lw=0.8, zorder=2)
        ax.text(b.injected_lo * ML, y + 0.22, _bar_text(b, least[b.index]), fontsize='small',
                va='bottom', ha='left', color='black' if b.default_path else '0.35', zorder=4,
                bbox=_GROUND)
    for t in graph.transitions:
        if t.target is None:
            continue
        x, y0, y1 = t.injected * ML, rows[t.source], rows[t.target]
        if t.kind == JOIN:
            ax.plot([x, x], [y0, y1], color='0.6', lw=0.6, ls=':', zorder=1)
            continue
        if t.kind != SNAP:
            continue
        style = STYLE[INFLATION if t.direction == GRAPH_INFLATION else DEFLATION]
        ax.annotate('', xy=(x, y1), xytext=(x, y0), zorder=3,
                    arrowprops={'arrowstyle': '-|>', 'color': style['color'],
                                'ls': style['ls'], 'lw': 1.8 if t.default_path else 0.9,
                                'alpha': 1.0 if t.default_path else 0.55,
                                'shrinkA': 2, 'shrinkB': 2})
        volumes.setdefault(round(x, 2), style['color'])
    ax.set_xlabel(INJECTED)
    ax.set_yticks([])
    names = ' | '.join(graph.segment_names)
    ax.set_ylabel(f'stable branches (state: {names})')
    ax.set_xlim(graph.injected_range[0] * ML - 0.02 * span * ML,
                graph.injected_range[1] * ML + 0.02 * span * ML)
    ax.grid(axis='x', alpha=0.2)
    _snap_volumes(ax, volumes)
    return hatched


def _snap_volumes(ax: object, volumes: dict[float, str]) -> None:
    """
    The snaps' volumes [mL] above the bars, upright, each joined to its place on the axis.

    Labels closer than their own height are spread apart (in order), so none covers another.
    """
    if not volumes:
        return
    from matplotlib import rcParams

    fig = ax.get_figure()
    box = ax.get_position()
    width_in, height_in = box.width * fig.get_figwidth(), box.height * fig.get_figheight()
    lo, hi = ax.get_xlim()
    # One label's height, 'small' type with a little room, in mL.
    gap = 1.15 * rcParams['font.size'] * 5 / 6 / 72 * (hi - lo) / width_in
    xs = np.array(sorted(volumes))
    placed = xs.copy()
    for k in range(1, xs.size):
        placed[k] = max(placed[k], placed[k - 1] + gap)
    # Centred on the volumes they label, as far as the spread allows.
    placed -= max(0.0, 0.5 * (placed[-1] - xs[-1]))
    for k in range(1, xs.size):
        placed[k] = max(placed[k], placed[k - 1] + gap)
    lift = 1.0 + 0.12 / height_in
    for x, at in zip(xs, placed):
        ax.annotate(f'{x:.2f}', xy=(x, 1.0), xycoords=('data', 'axes fraction'),
                    xytext=(at, lift), textcoords=('data', 'axes fraction'), rotation=90,
                    ha='center', va='bottom', fontsize='small', color=volumes[x],
                    arrowprops={'arrowstyle': '-', 'color': volumes[x], 'lw': 0.5,
                                'shrinkA': 0, 'shrinkB': 0})


def _branch_label(ax: object, dv: np.ndarray, text: str, limit: float) -> None:
    """
    A branch's name beside its middle, across its line.

    Above it rather than right of it, right rather than left; up and right of a branch by the
    v2 axis (``limit``: the axes' size), never over the axis.
    """
    k = dv.shape[0] // 2
    tangent = dv[min(k + 1, dv.shape[0] - 1)] - dv[max(k - 1, 0)]
    normal = np.array([-tangent[1], tangent[0]])
    normal = normal / (np.hypot(*normal) or 1.0)
    if normal[1] + 0.5 * normal[0] < 0:
        normal = -normal
    if normal[0] < 0 and dv[k, 0] < 0.1 * limit:
        normal = np.array([0.6, 0.8])
    ha = 'left' if normal[0] > 0.3 else 'right' if normal[0] < -0.3 else 'center'
    va = 'bottom' if normal[1] > 0.3 else 'top' if normal[1] < -0.3 else 'center'
    ax.annotate(text, tuple(dv[k]), xytext=tuple(4.0 * normal), textcoords='offset points',
                fontsize='small', zorder=4, bbox={**_GROUND, 'pad': 0.15}, ha=ha, va=va)


def _draw_plane(ax: object, graph: TransitionGraph, emap: object) -> list:
    """The volume plane with the branches and snaps; the key to its other lines."""
    from matplotlib.lines import Line2D

    rest = np.asarray(emap.rest_volumes)
    limit = 0.0
    key = []
    for curve in emap.equilibrium_set():
        dv = (np.asarray(curve.volumes) - rest) * ML
        stable = np.asarray(curve.stable)
        ax.plot(np.where(~stable, dv[:, 0], np.nan), np.where(~stable, dv[:, 1], np.nan),
                color=UNSTABLE_COLOUR, lw=0.8, ls='--', alpha=0.8)
        limit = max(limit, float(np.nanmax(dv)))
        if not stable.all() and not key:
            key.append(Line2D([], [], color=UNSTABLE_COLOUR, ls='--', label='unstable equilibria'))
    for b, branch in zip(graph.branches, emap.branches):
        # The segments' columns: a supply line is a member of the branches too.
        dv = (np.asarray(branch.volumes)[:, :rest.size] - rest) * ML
        ax.plot(dv[:, 0], dv[:, 1], color=_PATH_COLOUR if b.default_path else _OTHER_COLOUR,
                lw=2.2 if b.default_path else 1.6, zorder=2)
        # A branch too short to hold its name here is named in the bars only.
        if np.ptp(dv, axis=0).max() > 0.05 * limit:
            _branch_label(ax, dv, f'#{b.index}', limit)
    for t in graph.snaps():
        style = STYLE[INFLATION if t.direction == GRAPH_INFLATION else DEFLATION]
        start = (np.asarray(t.volumes_before) - rest) * ML
        end = (np.asarray(t.volumes_after) - rest) * ML
        ax.annotate('', xy=tuple(end), xytext=tuple(start), zorder=3,
                    arrowprops={'arrowstyle': '-|>', 'color': style['color'], 'ls': style['ls'],
                                'lw': 1.5 if t.default_path else 0.8})
    step = total_volume_lines(ax, limit * 1.02)
    ax.set_xlabel(f'volume added to {graph.segment_names[0]} [mL]')
    ax.set_ylabel(f'volume added to {graph.segment_names[1]} [mL]')
    ax.set_aspect('equal', adjustable='box')
    ax.set_xlim(0, limit * 1.02 or 1.0)
    ax.set_ylim(0, limit * 1.02 or 1.0)
    ax.grid(alpha=0.2)
    return key + [Line2D([], [], color='0.8', lw=0.5, label=f'total volume, every {step:g} mL')]


def plot_hysteron_graph(graph: HysteronGraph, out: Path, svg: bool = False,
                        style: FigureStyle = PAPER) -> list[Path]:
    """
    The states behind a regulator as bars over the gauge pressure each holds at, and the flips.

    Each state (each segment's rising piece, base to tip) is a bar from its highest valley to
    its lowest peak; a flip is an arrow at its pressure from the state it leaves to the one it
    lands in, up (blue) or down (vermillion, dashed); one into no state ends at a cross.
    """
    with style.context():
        from matplotlib import rcParams
        from matplotlib.lines import Line2D

        width = style.size(PAGE_IN, 1.0)[0]
        type_in = rcParams['font.size'] / 72
        rows = len(graph.states)
        height = max(2.4 * type_in * (rows + 1.5), 1.2) + 4.0 * type_in
        fig, axes = new_figure(width, height, margins={
            'left': 4.2 * type_in / width, 'right': 0.99, 'bottom': 4.0 * type_in / height,
            'top': 1 - 0.05 / height})
        ax = axes[0, 0]
        for state in graph.states:
            ax.barh(state.index, (state.p_high - state.p_low) * 1e-3, left=state.p_low * 1e-3,
                    height=0.36, color=_PATH_COLOUR, lw=0.8, zorder=2)
            ax.text(state.p_low * 1e-3, state.index + 0.22, f'{state.index}: {state.label}',
                    fontsize='small', va='bottom', ha='left', zorder=4, bbox=_GROUND)
        for flip in graph.flips:
            x = flip.pressure * 1e-3
            look = STYLE[INFLATION if flip.up else DEFLATION]
            if flip.target is None:
                ax.plot([x], [flip.source], marker='x', color=look['color'], zorder=3)
                continue
            ax.annotate('', xy=(x, flip.target), xytext=(x, flip.source), zorder=3,
                        arrowprops={'arrowstyle': '->', 'color': look['color'],
                                    'ls': '-' if flip.up else '--', 'lw': 0.9})
        ax.set_xlabel('gauge pressure [kPa]')
        ax.set_yticks([])
        ax.set_ylim(-0.8, rows - 0.2)
        handles = [Line2D([], [], color=STYLE[INFLATION]['color'],
                          label='flip up, past a peak'),
                   Line2D([], [], color=STYLE[DEFLATION]['color'], ls='--',
                          label='flip down, past a valley')]
        legend_below(fig, handles, 2)
        style.title(ax, f'Behind a pressure regulator: {rows} stable states (state: '
                    f'{" | ".join(graph.names)} rising piece)')
        return save_figure(fig, out, svg, style)
