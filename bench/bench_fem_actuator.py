"""
The whole actuator on one cavity against the assembly of its segments' tables (the paper's
Fig. 6A and 7B check): PV curves, volume split, tip positions at the paper's steps, run times.

    python bench/bench_fem_actuator.py [--element-size-m 0.002]
    python bench/bench_fem_actuator.py --quick

Every FEM run is a fresh process, single-threaded, all at the same mesh (the whole actuator
cannot afford the unit cells' default 0.75 mm): the whole actuator (both Table I segments,
Arruda-Boyce, 0 -> 65 mL), each segment's unit cell and each segment's whole-segment model.
The assembly (:mod:`softseq_ros.fem.assembly`) puts the two tables of each kind on one syringe.
Run times are measured in the same run: the whole actuator against the two segment tables plus
their assembly, and against the assembly alone (tables from a library). Results go to
bench/fem_actuator_results.json and .md, the figure to docs/fem_actuator.png.

``--quick`` checks that it runs, in a few seconds of CPU: two short segments (two pitches each)
on a coarse mesh to 1.5 mL, each run in a forked process, into a temporary folder, the report
printed.
"""

import argparse
from concurrent.futures import ProcessPoolExecutor
import json
import multiprocessing
import os
from pathlib import Path
import sys
import tempfile
import time

os.environ.setdefault('OMP_NUM_THREADS', '1')
os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')

import numpy as np  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from softseq_ros.scene.design import load_design, with_changes  # noqa: E402

DESIGNS = REPO / 'config' / 'designs'
STEPS_ML = (25, 45, 60)   # the paper's simulated steps 3, 4, 5
QUICK_ML = 1.5            # --quick: two short segments to this volume


def _actuator_child(designs: list, folder: str) -> dict:
    from softseq_ros.fem.actuator import run_actuator, write_actuator_table

    result = run_actuator(designs)
    top = max(d.volume.max_injected_m3 for d in designs)
    write_actuator_table(result, Path(folder) / 'actuator.csv', top)
    # In the rig's frame: the base at the origin, bending toward +z (the FEM's z points from
    # the beam to the membranes, and the actuator bends toward its beam).
    base = result.lines[0][0]
    flip = np.array([1.0, -1.0])

    def rig(points: np.ndarray) -> np.ndarray:
        return (np.asarray(points) - base) * flip

    lines = {}
    for ml in STEPS_ML:
        if result.injected[-1] >= ml * 1e-6:
            row = int(np.argmin(np.abs(result.injected - ml * 1e-6)))
            lines[ml] = rig(result.lines[row]).tolist()
    at = {}
    for ml in STEPS_ML:
        values = result.at(ml * 1e-6)
        values['tip_m'] = rig(values['tip_m'])
        at[ml] = {k: (v.tolist() if hasattr(v, 'tolist') else v) for k, v in values.items()}
    return {'wall_s': result.wall_s, 'dofs': result.dofs, 'stop_reason': result.stop_reason,
            'newton_iterations': result.newton_iterations, 'lines': lines,
            'injected_m3': result.injected.tolist(), 'pressure_pa': result.pressures.tolist(),
            'by_segment_m3': result.injected_by_segment().tolist(),
            'tip_m': rig(result.ends[:, -1, :]).tolist(), 'at': at}


def _table_child(design: object, path: str) -> dict:
    from softseq_ros.fem.table import run_design, write_table

    result = run_design(design)
    write_table(result, Path(path))
    return {'wall_s': result.wall_s, 'dofs': result.dofs, 'stop_reason': result.stop_reason}


# How each FEM run's process starts: 'spawn' (a fresh interpreter: its time and memory are
# the run's own) for the measurements, 'fork' for --quick (no interpreter and imports to pay
# five times over for runs of a second).
START_METHOD = 'spawn'


def _fresh(function: object, *args: object) -> dict:
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context(START_METHOD)) as pool:
        return pool.submit(function, *args).result()


def _assembly(tables: dict, max_ml: float, lengths: dict) -> tuple[dict, float]:
    from softseq_ros.fem.assembly import pair_metrics
    from softseq_ros.scene.tables import read_table

    start = time.perf_counter()
    segments = [read_table(tables[name], name=name, length=lengths[name])
                for name in ('bottom', 'top')]
    metrics = pair_metrics(segments, max_ml * 1e-6, samples=1301)
    return metrics, time.perf_counter() - start


def run(designs: dict, folder: Path, max_ml: float) -> dict:
    """Every model of the pair at one mesh, and their comparison."""
    out: dict = {'element_size_m': designs['bottom'].mesh.element_size_m, 'max_ml': max_ml,
                 'dofs': {}, 'wall_s': {},
                 'lengths_m': [designs[n].geometry.length_m for n in ('bottom', 'top')]}
    print('whole actuator ...', flush=True)
    actuator = _fresh(_actuator_child, [designs['bottom'], designs['top']], str(folder))
    out['actuator'] = actuator
    out['dofs']['actuator'] = actuator['dofs']
    out['wall_s']['actuator'] = actuator['wall_s']
    assemblies = {}
    for model in ('unit_cell', 'whole_segment'):
        tables = {}
        for name in ('bottom', 'top'):
            design = with_changes(designs[name], {'mesh.model': model})
            print(f'{model} {name} ...', flush=True)
            path = folder / f'{model}_{name}.csv'
            run_info = _fresh(_table_child, design, str(path))
            out['dofs'][f'{model}_{name}'] = run_info['dofs']
            out['wall_s'][f'{model}_{name}'] = run_info['wall_s']
            tables[name] = path
        metrics, assembly_s = _assembly(tables, max_ml, {n: d.geometry.length_m
                                                         for n, d in designs.items()})
        out['wall_s'][f'{model}_assembly'] = assembly_s
        assemblies[model] = metrics
    out['comparison'] = compare(actuator, assemblies, max_ml)
    out['assemblies'] = {model: {'injected_m3': m['history_m3'].tolist(),
                                 'pressure_pa': np.asarray(m['path'].pressure).tolist(),
                                 'by_segment_m3': (np.asarray(m['path'].volumes)
                                                   - np.asarray(m['path'].volumes)[0]).tolist(),
                                 'tip_m': m['tip_m'].tolist(),
                                 'curvatures': np.asarray(m['path'].curvatures).tolist()}
                         for model, m in assemblies.items()}
    return out


def compare(actuator: dict, assemblies: dict, max_ml: float) -> dict:
    """Largest PV difference, volume split and tip at the paper's steps, per assembly."""
    injected = np.asarray(actuator['injected_m3'])
    pressure = np.asarray(actuator['pressure_pa'])
    rows = {}
    for model, metrics in assemblies.items():
        history = metrics['history_m3']
        path_p = np.asarray(metrics['path'].pressure)
        common = (injected > 0) & (injected <= history[-1])
        assembled = np.interp(injected[common], history, path_p)
        diff = assembled - pressure[common]
        worst = int(np.argmax(np.abs(diff)))
        row = {'largest_pv_difference_pa': float(diff[worst]),
               'largest_pv_difference_share': float(diff[worst] / pressure[common][worst]),
               'at_injected_m3': float(injected[common][worst]),
               'sequence': metrics.get('sequence'), 'steps': {}}
        volumes = np.asarray(metrics['path'].volumes)
        for ml in STEPS_ML:
            if ml > max_ml or ml * 1e-6 > injected[-1]:
                continue
            i = int(np.argmin(np.abs(history - ml * 1e-6)))
            split = volumes[i] - volumes[0]
            fem = actuator['at'][ml]
            row['steps'][ml] = {
                'top_share_assembly': float(split[1] / split.sum()),
                'top_share_actuator': float(fem['injected_by_segment_m3'][1]
                                            / sum(fem['injected_by_segment_m3'])),
                'pressure_assembly_pa': float(path_p[i]),
                'pressure_actuator_pa': float(fem['pressure_pa']),
                'tip_assembly_m': [float(v) for v in metrics['tip_m'][i]],
                'tip_actuator_m': [float(v) for v in fem['tip_m']],
                'curvatures_assembly': [float(v) for v in
                                        np.asarray(metrics['path'].curvatures)[i]],
                'curvatures_actuator': [float(v) for v in fem['curvatures_per_m']]}
        rows[model] = row
    return rows


def report(data: dict, note: str = '') -> str:
    w = data['wall_s']
    lines = ['# The whole actuator against the assembly of its segment tables', '',
             f'Written by `python bench/bench_fem_actuator.py`{note}. Table I pair, Arruda-Boyce '
             f'(mu 16.3 kPa, lambda_m 3.96), every model at {data["element_size_m"] * 1e3:g} mm '
             f'elements, 0 -> {data["max_ml"]:g} mL; each FEM run single-threaded in a '
             f'{"forked" if data.get("start_method") == "fork" else "fresh"} process. Machine: '
             f'{data.get("machine")}.', '',
             '## Run times', '',
             '| model | unknowns | wall [s] |', '|---|---:|---:|',
             f'| whole actuator (one cavity) | {data["dofs"]["actuator"]} | '
             f'{w["actuator"]:.1f} |']
    for model in ('unit_cell', 'whole_segment'):
        for name in ('bottom', 'top'):
            lines.append(f'| {model.replace("_", " ")} table, {name} | '
                         f'{data["dofs"][f"{model}_{name}"]} | {w[f"{model}_{name}"]:.1f} |')
        lines.append(f'| assembly of the two {model.replace("_", " ")} tables | - | '
                     f'{w[f"{model}_assembly"]:.2f} |')
    lines.append('')
    for model in ('unit_cell', 'whole_segment'):
        tables = w[f'{model}_bottom'] + w[f'{model}_top']
        both = tables + w[f'{model}_assembly']
        lines.append(f'- {model.replace("_", " ")}s: tables and assembly {both:.1f} s, '
                     f'**{w["actuator"] / both:.1f}x** faster than the whole actuator; the '
                     f'assembly alone (tables from a library) {w[f"{model}_assembly"]:.2f} s, '
                     f'**{w["actuator"] / w[f"{model}_assembly"]:.0f}x**.')
    lines += ['', "## PV curve, volume split and tip at the paper's steps", '',
              '| assembly of | sequence | largest PV difference [Pa] (share) at [mL] |',
              '|---|---|---|']
    for model, row in data['comparison'].items():
        lines.append(f'| {model.replace("_", " ")} tables | {row["sequence"]} | '
                     f'{row["largest_pv_difference_pa"]:+.1f} '
                     f'({row["largest_pv_difference_share"]:+.1%}) at '
                     f'{row["at_injected_m3"] * 1e6:.1f} |')
    lines += ['', '| step [mL] | model | pressure [Pa] | top share of the fluid | curvature '
              'bottom / top [1/m] | tip x, z [mm] |', '|---:|---|---:|---:|---|---|']
    for ml in STEPS_ML:
        first = True
        for model, row in data['comparison'].items():
            step = row['steps'].get(ml) if isinstance(row['steps'], dict) else None
            step = step or row['steps'].get(str(ml)) if isinstance(row['steps'], dict) else None
            if step is None:
                continue
            if first:
                tip = step['tip_actuator_m']
                k = step['curvatures_actuator']
                lines.append(f'| {ml} | whole actuator | {step["pressure_actuator_pa"]:.0f} | '
                             f'{step["top_share_actuator"]:.3f} | {k[0]:.1f} / {k[1]:.1f} | '
                             f'{tip[0] * 1e3:.1f}, {tip[1] * 1e3:.1f} |')
                first = False
            tip = step['tip_assembly_m']
            k = step['curvatures_assembly']
            lines.append(f'| {ml} | assembly, {model.replace("_", " ")}s | '
                         f'{step["pressure_assembly_pa"]:.0f} | {step["top_share_assembly"]:.3f} '
                         f'| {k[0]:.1f} / {k[1]:.1f} | {tip[0] * 1e3:.1f}, {tip[1] * 1e3:.1f} |')
    lines.append('')
    return '\n'.join(lines)


def figure(data: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    act = data['actuator']
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.4))
    styles = {'unit_cell': ('--', 'assembly of unit cells'),
              'whole_segment': (':', 'assembly of whole segments')}
    axes[0].plot(np.asarray(act['injected_m3']) * 1e6, np.asarray(act['pressure_pa']) / 1e3,
                 'k-', label='whole actuator (one cavity)')
    by = np.asarray(act['by_segment_m3'])
    axes[1].plot(np.asarray(act['injected_m3']) * 1e6, by[:, 0] * 1e6, 'C0-',
                 label='bottom, whole actuator')
    axes[1].plot(np.asarray(act['injected_m3']) * 1e6, by[:, 1] * 1e6, 'C3-',
                 label='top, whole actuator')
    for model, (style, label) in styles.items():
        asm = data['assemblies'][model]
        v = np.asarray(asm['injected_m3']) * 1e6
        axes[0].plot(v, np.asarray(asm['pressure_pa']) / 1e3, style, label=label)
        split = np.asarray(asm['by_segment_m3']) * 1e6
        axes[1].plot(v, split[:, 0], 'C0' + style, label=f'bottom, {label}')
        axes[1].plot(v, split[:, 1], 'C3' + style, label=f'top, {label}')
    axes[0].set_ylabel('gauge pressure [kPa]')
    axes[1].set_ylabel('fluid injected into the segment [mL]')
    for ax in axes[:2]:
        ax.set_xlabel('fluid injected into the actuator [mL]')
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    axes[0].set_title('PV curve', fontsize=9)
    axes[1].set_title('volume split', fontsize=9)
    from softseq_ros.segments.kinematics import backbone

    ax = axes[2]
    for index, ml in enumerate(STEPS_ML):
        line = act['lines'].get(ml) or act['lines'].get(str(ml))
        if line is None:
            continue
        line = np.asarray(line)
        ax.plot(line[:, 0] * 1e3, line[:, 1] * 1e3, '-', color=f'C{index + 4}',
                label=f'{ml} mL, whole actuator')
        for model, (style, label) in styles.items():
            asm = data['assemblies'][model]
            i = int(np.argmin(np.abs(np.asarray(asm['injected_m3']) - ml * 1e-6)))
            bone = backbone(np.asarray(asm['curvatures'][i]), data['lengths_m'])
            ax.plot(bone.points[:, 0] * 1e3, bone.points[:, 1] * 1e3, style,
                    color=f'C{index + 4}', label=f'{ml} mL, {label}' if index == 0 else None)
    ax.set_aspect('equal')
    ax.set_xlabel('x [mm] (unbent actuator)')
    ax.set_ylabel('z [mm] (toward the membranes)')
    ax.set_title("backbones at the paper's steps 3-5", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def _designs(element: float, thin: int, extra: dict | None = None) -> dict:
    changes = {'mesh.element_size_m': element, 'mesh.thin_layer_cells': thin, **(extra or {})}
    return {name: with_changes(load_design(DESIGNS / f'paper_{name}.yaml'), changes)
            for name in ('bottom', 'top')}


def _machine() -> dict:
    return {'cores': os.cpu_count(), 'load_average': [round(v, 2) for v in os.getloadavg()],
            'date_utc': time.strftime('%Y-%m-%d %H:%M', time.gmtime())}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--quick', action='store_true', help='a check that it runs: two short '
                        'segments, a coarse mesh, 1.5 mL; nothing written into the repository')
    parser.add_argument('--element-size-m', type=float, default=0.002)
    args = parser.parse_args()
    if args.quick:
        global START_METHOD
        START_METHOD = 'fork'
        designs = _designs(0.003, 1, {'geometry.length_m': 0.02,
                                      'volume.max_injected_m3': QUICK_ML * 1e-6,
                                      'volume.max_step_m3': 1e-6})
        with tempfile.TemporaryDirectory(prefix='bench_fem_actuator_') as folder:
            data = run(designs, Path(folder), QUICK_ML)
            data['machine'] = _machine()
            data['start_method'] = START_METHOD
            figure(data, Path(folder) / 'fem_actuator.png')
            print(report(data, ' --quick (two short segments, coarse: the numbers show that '
                               'it runs)'))
        return
    designs = _designs(args.element_size_m, 1)
    folder = REPO / 'bench' / 'fem_actuator'
    folder.mkdir(exist_ok=True)
    data = run(designs, folder, 65.0)
    data['machine'] = _machine()
    (REPO / 'bench' / 'fem_actuator_results.json').write_text(json.dumps(
        data, indent=1, default=float) + '\n')
    figure(data, REPO / 'docs' / 'fem_actuator.png')
    text = report(data)
    (REPO / 'bench' / 'fem_actuator_results.md').write_text(text)
    print(text)


if __name__ == '__main__':
    main()
