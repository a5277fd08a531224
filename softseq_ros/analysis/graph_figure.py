"""
The figure of a transition graph (softseq_ros.quasistatic.graph): ``softseq graph``'s graph.png.

Left: every stable branch as a horizontal bar over the injected volume, labelled by its state
(each segment's piece, base to tip), with its snaps as vertical arrows at their volumes:
inflation's (blue, solid) point up, deflation's (vermillion, dashed) down; joins are thin grey
links. The default inflate-then-deflate path is drawn dark and thick; a branch no history
reaches from rest is hatched. For two segments, right: the volume plane (Fig. 1B style), the
equilibrium set with the stable branches and the snaps at constant total volume.
"""

from pathlib import Path

import numpy as np

from softseq_ros.analysis.figures import (
    INJECTED,
    ML,
    STYLE,
    FigureStyle,
    new_figure,
    nice_step,
    save_figure,
)
from softseq_ros.analysis.recording import DEFLATION, INFLATION
from softseq_ros.quasistatic.graph import INFLATION as GRAPH_INFLATION
from softseq_ros.quasistatic.graph import JOIN, SNAP, GraphBranch, TransitionGraph

_PATH_COLOUR = '0.1'
_OTHER_COLOUR = '0.65'


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
               max_reversals: int | None = None, svg: bool = False) -> list[Path]:
    """Draw the graph to ``out`` (PNG); with ``emap`` and two segments, the volume plane too."""
    plane = emap is not None and len(graph.segment_names) == 2
    # A character of a 6-point label is about 0.05 in; the bars' axes are about 5 to 7 in wide.
    rows = branch_rows(graph, 0.05 / (5.2 if plane else 7.0))
    height = max(3.2, 0.42 * (max(rows.values()) + 2))
    fig, axes = new_figure(13.0 if plane else 8.5, max(height, 5.6 if plane else 0.0),
                           cols=2 if plane else 1,
                              margins={'left': 0.05 if plane else 0.07, 'right': 0.98,
                                    'wspace': 0.18, 'top': 0.9, 'bottom': 0.1})
    _draw_bars(axes[0, 0], graph, rows, max_reversals)
    if plane:
        _draw_plane(axes[0, 1], graph, emap)
    fig.suptitle(f'Transition graph: {len(graph.branches)} stable branches, '
                 f'{len(graph.snaps())} snaps; dark: the default inflate-then-deflate path',
                 fontsize=9)
    # Laid out for a screen, its titles a key to a figure of many parts; cropped to what is
    # drawn, at twice a screen's resolution.
    return save_figure(fig, out, svg, FigureStyle('paper', dpi=220))


def _draw_bars(ax: object, graph: TransitionGraph, rows: dict[int, float],
               max_reversals: int | None) -> None:
    least = graph.min_reversals()
    span = graph.injected_range[1] - graph.injected_range[0]
    for b in graph.branches:
        y = rows[b.index]
        colour = _PATH_COLOUR if b.default_path else _OTHER_COLOUR
        unreachable = least[b.index] is None or (max_reversals is not None
                                                 and least[b.index] > max_reversals)
        # A branch between two close folds may be a fraction of a percent of the range wide:
        # drawn at least that wide, so it shows.
        width = max(b.injected_hi - b.injected_lo, 0.004 * span)
        ax.barh(y, width * ML, left=b.injected_lo * ML, height=0.36,
                color='white' if unreachable else colour, edgecolor=colour,
                hatch='///' if unreachable else None, lw=0.8, zorder=2)
        ax.text(b.injected_lo * ML, y + 0.24, _bar_text(b, least[b.index]), fontsize=6,
                va='bottom', ha='left', color='black' if b.default_path else '0.35', zorder=4)
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
        ax.text(x + 0.005 * span * ML, 0.5 * (y0 + y1), f'{x:.2f}', fontsize=5.5,
                color=style['color'], va='center', ha='left', zorder=4)
    ax.plot([], [], color=STYLE[INFLATION]['color'], label='snap on inflation (up)')
    ax.plot([], [], color=STYLE[DEFLATION]['color'], ls='--', label='snap on deflation (down)')
    ax.plot([], [], color='0.6', ls=':', label='join (a segment passes a peak or valley)')
    ax.set_xlabel(INJECTED)
    ax.set_yticks([])
    ax.set_ylim(-0.8, max(rows.values()) + 1.0)
    ax.set_xlim(graph.injected_range[0] * ML - 0.02 * span * ML,
                graph.injected_range[1] * ML + 0.02 * span * ML)
    ax.grid(axis='x', alpha=0.2)
    ax.legend(fontsize=6.5, loc='lower right')
    names = ' | '.join(graph.segment_names)
    ax.set_title(f'Stable branches over the injected volume; state: {names}', fontsize=8.5)


def _draw_plane(ax: object, graph: TransitionGraph, emap: object) -> None:
    rest = np.asarray(emap.rest_volumes)
    limit = 0.0
    for curve in emap.equilibrium_set():
        dv = (np.asarray(curve.volumes) - rest) * ML
        stable = np.asarray(curve.stable)
        ax.plot(np.where(~stable, dv[:, 0], np.nan), np.where(~stable, dv[:, 1], np.nan),
                color='tab:red', lw=0.8, ls='--', alpha=0.6)
        limit = max(limit, float(np.nanmax(dv)))
    for b, branch in zip(graph.branches, emap.branches):
        dv = (np.asarray(branch.volumes) - rest) * ML
        ax.plot(dv[:, 0], dv[:, 1], color=_PATH_COLOUR if b.default_path else _OTHER_COLOUR,
                lw=2.2 if b.default_path else 1.6, zorder=2)
        middle = dv[dv.shape[0] // 2]
        ax.text(middle[0], middle[1], f' #{b.index}', fontsize=6, zorder=4)
    for t in graph.snaps():
        style = STYLE[INFLATION if t.direction == GRAPH_INFLATION else DEFLATION]
        start = (np.asarray(t.volumes_before) - rest) * ML
        end = (np.asarray(t.volumes_after) - rest) * ML
        ax.annotate('', xy=tuple(end), xytext=tuple(start), zorder=3,
                    arrowprops={'arrowstyle': '-|>', 'color': style['color'], 'ls': style['ls'],
                                'lw': 1.5 if t.default_path else 0.8})
    step = nice_step(2 * limit / 8) if limit > 0 else 1.0
    for total in np.arange(step, 2 * limit + step, step):
        ax.plot([0, total], [total, 0], color='0.8', lw=0.5, zorder=0)
    ax.plot([], [], color='tab:red', ls='--', label='unstable equilibria')
    ax.plot([], [], color=_PATH_COLOUR, lw=2.2, label='stable branch, default path')
    ax.plot([], [], color=_OTHER_COLOUR, lw=1.6, label='stable branch, off the default path')
    ax.set_xlabel(f'volume added to {graph.segment_names[0]} [mL]')
    ax.set_ylabel(f'volume added to {graph.segment_names[1]} [mL]')
    ax.set_aspect('equal', adjustable='box')
    ax.set_xlim(0, limit * 1.02 or 1.0)
    ax.set_ylim(0, limit * 1.02 or 1.0)
    ax.grid(alpha=0.2)
    ax.legend(fontsize=6.5, loc='upper right')
    ax.set_title('Volume plane; grey lines: constant total volume', fontsize=8.5)
