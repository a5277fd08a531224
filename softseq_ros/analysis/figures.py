"""
Figures of a rig run in the paper's style, and the short text summary.

Humans read mL, kPa and mm here; the data stay SI underneath. Figures: the PV curves (Fig. 4A / 6),
the volume split with its stable and unstable equilibria (Fig. 1B / 4B), the tentacle's shape at
the camera's trigger volumes (Fig. 7) and the time series of the run.
"""

from pathlib import Path

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from softseq_ros.analysis.recording import Recording  # noqa: E402
from softseq_ros.physics.equilibrium import EquilibriumMap, classify  # noqa: E402

ML = 1e6
KPA = 1e-3
MM = 1e3


def plot_pv(recording: Recording, emap: EquilibriumMap | None, out: Path,
            experiment: tuple[np.ndarray, np.ndarray] | None = None) -> Path:
    """Segment PV curves and the actuator's recorded pressure against injected volume."""
    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    if emap is not None:
        for segment in emap.segments:
            v = np.linspace(segment.rest_volume, segment.max_volume, 600)
            ax.plot((v - segment.rest_volume) * ML, segment.pressure(v) * KPA, '--', lw=1,
                    label=f'segment {segment.name} alone')
    ax.plot(recording.state_injected * ML, recording.pressure * KPA, 'k-', lw=1.6,
            label='actuator (recorded)')
    if experiment is not None:
        ax.plot(experiment[0] * ML, experiment[1] * KPA, '.', ms=3, color='tab:red',
                label='experiment')
    ax.set_xlabel('injected volume [mL]')
    ax.set_ylabel('pressure [kPa]')
    top = max(recording.state_injected.max(), 1e-12) * ML * 1.15
    ax.set_xlim(0, top)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title('Pressure-volume curves')
    return _save(fig, out)


def plot_volume_split(recording: Recording, emap: EquilibriumMap | None, out: Path) -> Path:
    """Volume of each segment; for two segments, v1 against v2 with the equilibrium set."""
    fig, ax = plt.subplots(figsize=(5.6, 5.0))
    names = recording.segment_names
    if emap is not None and len(names) == 2:
        rest = emap.rest_volumes
        shown_stable = shown_unstable = False
        for curve in emap.equilibrium_set():
            dv = (curve.volumes - rest) * ML
            for mask, colour, label, shown in ((curve.stable, 'tab:blue', 'stable', shown_stable),
                                                (~curve.stable, 'tab:red', 'unstable',
                                                 shown_unstable)):
                if mask.any():
                    ax.plot(np.where(mask, dv[:, 0], np.nan), np.where(mask, dv[:, 1], np.nan),
                            color=colour, lw=1.2, label=None if shown else label)
            shown_stable |= bool(curve.stable.any())
            shown_unstable |= bool((~curve.stable).any())
        dv = (recording.volumes - rest) * ML
        ax.plot(dv[:, 0], dv[:, 1], 'k.', ms=1.5, label='recorded')
        ax.set_xlabel(f'{names[0]} [mL]')
        ax.set_ylabel(f'{names[1]} [mL]')
        ax.set_aspect('equal', adjustable='box')
        limit = np.nanmax(dv) * 1.1
        ax.set_xlim(0, limit)
        ax.set_ylim(0, limit)
        ax.set_title('Volume distribution (Fig. 1B style)')
    else:
        rest = recording.volumes[0]
        for j, name in enumerate(names):
            ax.plot(recording.state_injected * ML, (recording.volumes[:, j] - rest[j]) * ML,
                    '.', ms=1.5, label=name)
        ax.set_xlabel('injected volume [mL]')
        ax.set_ylabel('segment volume change [mL]')
        ax.set_title('Volume distribution')
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, markerscale=4)
    return _save(fig, out)


def plot_shapes(recording: Recording, out: Path) -> Path:
    """The backbone at each camera trigger volume (the paper's numbered steps)."""
    fig, ax = plt.subplots(figsize=(6.4, 4.8))
    colours = plt.cm.viridis(np.linspace(0.0, 0.9, max(len(recording.snapshots), 1)))
    for number, (shot, colour) in enumerate(zip(recording.snapshots, colours), start=1):
        ax.plot(shot.points[:, 0] * MM, shot.points[:, 1] * MM, '-', color=colour, lw=2,
                label=f'step {number}: {shot.injected * ML:.1f} mL')
    ax.plot([0], [0], 'ks', ms=6)
    ax.set_xlabel('x [mm]')
    ax.set_ylabel('z [mm]')
    ax.set_aspect('equal', adjustable='datalim')
    ax.grid(alpha=0.3)
    if recording.snapshots:
        ax.legend(fontsize=8)
    ax.set_title('Tentacle shape at the trigger volumes (Fig. 7 style)')
    return _save(fig, out)


def plot_timeseries(recording: Recording, out: Path) -> Path:
    """Commanded volume, pressure and segment volumes against time."""
    fig, axes = plt.subplots(3, 1, figsize=(6.4, 6.4), sharex=True)
    axes[0].plot(recording.pump_time_s, recording.pump_injected * ML, 'k-')
    axes[0].set_ylabel('injected [mL]')
    axes[1].plot(recording.state_time_s, recording.pressure * KPA, 'k-')
    axes[1].set_ylabel('pressure [kPa]')
    for j, name in enumerate(recording.segment_names):
        axes[2].plot(recording.state_time_s, recording.volumes[:, j] * ML, label=name)
    axes[2].set_ylabel('volume [mL]')
    axes[2].set_xlabel('time [s]')
    axes[2].legend(fontsize=8)
    for ax in axes:
        ax.grid(alpha=0.3)
    return _save(fig, out)


def write_figures(recording: Recording, emap: EquilibriumMap | None, directory: Path,
                  experiment: tuple[np.ndarray, np.ndarray] | None = None) -> list[Path]:
    """All figures of a run into ``directory``."""
    directory.mkdir(parents=True, exist_ok=True)
    return [plot_pv(recording, emap, directory / 'pv.png', experiment),
            plot_volume_split(recording, emap, directory / 'volume_split.png'),
            plot_shapes(recording, directory / 'shapes.png'),
            plot_timeseries(recording, directory / 'timeseries.png')]


def summary(recording: Recording, emap: EquilibriumMap | None = None,
            counts: dict[str, int] | None = None) -> str:
    """A few lines a researcher reads first: sequence, snaps, pressures, shapes."""
    lines = [f'recording: {recording.path}']
    duration = recording.pump_time_s[-1] if recording.pump_time_s.size else 0.0
    lines.append(f'duration: {duration:.1f} s of rig time, peak injected '
                 f'{recording.pump_injected.max() * ML:.2f} mL')
    if emap is not None:
        lines.append(f'sequence type: {classify(emap)}')
    top = int(np.argmax(recording.state_injected))
    rest = recording.volumes[0]
    share = (recording.volumes[top] - rest) / max(float(np.sum(recording.volumes[top] - rest)),
                                                  1e-300)
    split = ', '.join(f'{n} {s * 100:.0f} %' for n, s in zip(recording.segment_names, share))
    lines.append(f'at peak injection: pressure {recording.pressure[top] * KPA:.2f} kPa, '
                 f'split {split}')
    if recording.events:
        for event in recording.events:
            lines.append(f'snap-through at {event["injected_m3"] * ML:.3f} mL: pressure '
                         f'{event["from_pressure_pa"] * KPA:.2f} -> '
                         f'{event["to_pressure_pa"] * KPA:.2f} kPa')
    else:
        lines.append('snap-throughs: none')
    for number, shot in enumerate(recording.snapshots, start=1):
        tip = shot.points[-1]
        lines.append(f'step {number} at {shot.injected * ML:.1f} mL: tip at x {tip[0] * MM:.1f} '
                     f'mm, z {tip[1] * MM:.1f} mm')
    if counts:
        lines.append('messages: ' + ', '.join(f'{t} {n}' for t, n in sorted(counts.items())))
    return '\n'.join(lines)


def _save(fig: plt.Figure, out: Path) -> Path:
    fig.tight_layout()
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out
