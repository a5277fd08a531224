"""
FEM benchmarks: run time, unknowns and memory per segment and mesh density; the whole segment;
sweep throughput with 1 and 2 workers; the paper pair across Ecoflex 00-30 fits; figures.

    python bench/bench_fem.py [--part meshes|whole|sweep|materials|figures|all]
    python bench/bench_fem.py --quick

Benchmarks, not tests: nothing is asserted about time. Every run is a fresh process (its peak
resident memory is the run's), single-threaded BLAS, on a 2-core machine shared with other work
(the load average is written beside each part). Each part stores its numbers in
bench/fem_results.json and the whole of bench/fem_results.md is rewritten from that file, so
one part can be re-run alone. Figures go to docs/fem_*.png.

``--quick`` checks that the benchmark runs, in under 30 s, without a fine mesh: one coarse case
(the top unit cell at 2 mm, one thin-layer cell: the first case of the whole-segment part) in a
fresh process, the same design as a sweep of one (to 30 mL, one worker), the pair summary of
one fit's shipped tables in bench/fem_materials (no FEM run), the figures at 2 mm; the results
file, the report and the figures go to a temporary folder and the report is printed. The test
suite runs it (test/test_bench_quick.py).
"""

import argparse
from concurrent.futures import ProcessPoolExecutor
import json
import multiprocessing
import os
from pathlib import Path
import resource
import sys
import tempfile
import time

os.environ.setdefault('OMP_NUM_THREADS', '1')
os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')
os.environ.setdefault('MKL_NUM_THREADS', '1')

import numpy as np  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from softseq_ros.scene.design import load_design, with_changes  # noqa: E402
from softseq_ros.scene.tables import read_table  # noqa: E402

DESIGNS = REPO / 'config' / 'designs'
RESULTS = REPO / 'bench' / 'fem_results.json'
REPORT = REPO / 'bench' / 'fem_results.md'
MESH_SIZES = (0.001, 0.00075, 0.0005)
# Ecoflex 00-30 fits (Marechal et al. 2021 database, uniaxial data) and the Sorotoki Yeoh fit.
MATERIALS = {
    'neo-Hooke, mu 16.1 kPa (stretch <= 2)': {'law': 'neo_hookean', 'shear_modulus_pa': 16100.0},
    'Yeoh 7.83 / 0.103 / -0.001 kPa (stretch <= 4)': {
        'law': 'yeoh', 'c1_pa': 7830.0, 'c2_pa': 103.0, 'c3_pa': -1.0},
    'Arruda-Boyce mu 16.3 kPa, lambda_m 3.96 (stretch <= 4)': {
        'law': 'arruda_boyce', 'shear_modulus_pa': 16300.0, 'lambda_m': 3.96},
    'Arruda-Boyce mu 16.3 kPa, lambda_m 2.3': {
        'law': 'arruda_boyce', 'shear_modulus_pa': 16300.0, 'lambda_m': 2.3},
    'Yeoh 17 / -0.2 / 0.023 kPa (Sorotoki)': {
        'law': 'yeoh', 'c1_pa': 17000.0, 'c2_pa': -200.0, 'c3_pa': 23.0},
}


# --quick: the coarse case (the whole-segment part's first) and its sweep's volume.
QUICK_ELEMENT_M = 0.002
QUICK_CHANGES = {'mesh.model': 'unit_cell', 'mesh.element_size_m': QUICK_ELEMENT_M,
                 'mesh.thin_layer_cells': 1}
QUICK_SWEEP_M3 = 3e-5


def _load() -> dict:
    return json.loads(RESULTS.read_text()) if RESULTS.is_file() else {}


def _store(part: str, value: object) -> None:
    data = _load()
    data[part] = value
    RESULTS.write_text(json.dumps(data, indent=1, sort_keys=True) + '\n')


def _machine() -> dict:
    return {'cores': os.cpu_count(), 'load_average': [round(v, 2) for v in os.getloadavg()],
            'python': sys.version.split()[0], 'date_utc': time.strftime('%Y-%m-%d %H:%M',
                                                                         time.gmtime())}


def _run_in_child(design: object, table: str | None) -> dict:
    """One FEM run in this (fresh) process: result numbers, wall and CPU time, peak memory."""
    from softseq_ros.fem.table import run_design, write_table

    cpu = time.process_time()
    result = run_design(design)
    if table is not None:
        write_table(result, Path(table))
    peak_p, peak_v = result.peak
    return {'dofs': result.dofs, 'cells': result.cells, 'wall_s': round(result.wall_s, 1),
            'cpu_s': round(time.process_time() - cpu, 1),
            'max_rss_mb': round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 0),
            'newton_iterations': result.newton_iterations, 'states': len(result.volumes),
            'peak_pressure_pa': round(peak_p, 1), 'peak_injected_m3': peak_v,
            'final_injected_m3': float(result.injected[-1]),
            'final_pressure_pa': round(float(result.pressures[-1]), 1),
            'final_curvature_per_m': round(float(result.curvatures[-1]), 3),
            'stop_reason': result.stop_reason}


def fresh_run(design: object, table: str | None = None) -> dict:
    """Run a design in a new process (so its memory is measured alone)."""
    context = multiprocessing.get_context('spawn')
    with ProcessPoolExecutor(max_workers=1, mp_context=context) as pool:
        return pool.submit(_run_in_child, design, table).result()


def part_meshes() -> None:
    rows = []
    for name in ('top', 'bottom'):
        base = load_design(DESIGNS / f'paper_{name}_yeoh.yaml')
        for size in MESH_SIZES:
            design = with_changes(base, {'mesh.element_size_m': size})
            row = {'segment': name, 'element_size_m': size, **fresh_run(design)}
            print(row, flush=True)
            rows.append(row)
    _store('meshes', {'machine': _machine(), 'rows': rows})


def part_whole() -> None:
    # The unit cell and the whole segment on the same coarse mesh, with the shipped Yeoh fit
    # (the membranes' uniform inflation turns unstable past their common peak) and with the
    # Arruda-Boyce fit (it does not); then the whole segment on a finer mesh.
    yeoh = load_design(DESIGNS / 'paper_top_yeoh.yaml')
    arruda = load_design(DESIGNS / 'paper_top.yaml')
    cases = [('unit_cell', 0.002, 1, 'Yeoh', yeoh), ('whole_segment', 0.002, 1, 'Yeoh', yeoh),
             ('whole_segment', 0.002, 1, 'Arruda-Boyce', arruda),
             ('whole_segment', 0.0015, 2, 'Arruda-Boyce', arruda)]
    rows = []
    for model, size, thin, material, base in cases:
        design = with_changes(base, {'mesh.model': model, 'mesh.element_size_m': size,
                                     'mesh.thin_layer_cells': thin})
        table = REPO / 'bench' / f'fem_{model}_top_{material.split("-")[0].lower()}_' \
                                 f'{size * 1e3:g}mm.csv'
        row = {'segment': 'top', 'model': model, 'material': material, 'element_size_m': size,
               'thin_layer_cells': thin, **fresh_run(design, str(table))}
        print(row, flush=True)
        rows.append(row)
    _store('whole', {'machine': _machine(), 'rows': rows})


def part_sweep() -> None:
    from softseq_ros.fem.sweep import run_sweep, sweep_cases

    base = with_changes(load_design(DESIGNS / 'paper_top_yeoh.yaml'),
                        {'mesh.element_size_m': 0.0015, 'volume.max_injected_m3': 3e-5})
    cases = sweep_cases(base, {'geometry.membrane_thickness_m': [0.0005, 0.00075, 0.001,
                                                                 0.00125]})
    rows = []
    for workers in (1, 2):
        with tempfile.TemporaryDirectory() as folder:
            start = time.perf_counter()
            run_sweep(cases, Path(folder), workers=workers)
            wall = time.perf_counter() - start
        rows.append({'workers': workers, 'designs': len(cases), 'wall_s': round(wall, 1),
                     'designs_per_minute': round(60 * len(cases) / wall, 2)})
        print(rows[-1], flush=True)
    _store('sweep', {'machine': _machine(), 'rows': rows,
                     'case': 'paper_top, 1.5 mm elements, 0 to 30 mL, membrane 0.5-1.25 mm'})


# The shipped designs (the paper's law) at three refinements, and the Yeoh variants at the
# default mesh; the default mesh's tables are the shipped scenes' tables.
CONVERGENCE_DIR = REPO / 'bench' / 'fem_convergence'
SHIPPED_TABLES = {'paper_top': 'paper_fem_top', 'paper_bottom': 'paper_fem_bottom',
                  'paper_top_yeoh': 'paper_fem_yeoh_top',
                  'paper_bottom_yeoh': 'paper_fem_yeoh_bottom'}


def _current_table(path: Path) -> bool:
    """Whether a stored table exists and was made by the current FEM code (else: recompute)."""
    from softseq_ros.scene.design import FEM_CODE_VERSION

    if not path.is_file():
        return False
    with path.open() as handle:
        header = ''.join(line for line in handle if line.startswith('#'))
    return f'FEM code {FEM_CODE_VERSION},' in header


def convergence_cases(sizes: tuple[float, ...] = MESH_SIZES) -> list:
    """Sweep cases: the Arruda-Boyce pair at each size, the Yeoh pair at the default only."""
    from softseq_ros.fem.sweep import SweepCase

    cases = []
    for name in ('paper_top', 'paper_bottom', 'paper_top_yeoh', 'paper_bottom_yeoh'):
        base = load_design(DESIGNS / f'{name}.yaml')
        for size in sizes:
            if name.endswith('_yeoh') and size != base.mesh.element_size_m:
                continue
            design = (base if size == base.mesh.element_size_m
                      else with_changes(base, {'mesh.element_size_m': size}))
            cases.append(SweepCase(label=f'{name}__{size * 1e3:g}mm',
                                   changes={'mesh.element_size_m': size}, design=design))
    # Longest first, so two workers finish together.
    return sorted(cases, key=lambda c: (c.design.mesh.element_size_m,
                                        c.design.geometry.membrane_thickness_m))


def part_convergence(sizes: tuple[float, ...] = MESH_SIZES, out: Path = CONVERGENCE_DIR,
                     ship: bool = True) -> None:
    """The paper pair's plateau and sequence at three meshes; the shipped tables refreshed."""
    import shutil

    from softseq_ros.fem.sweep import run_sweep

    cases = convergence_cases(sizes)
    missing = [case for case in cases if not _current_table(out / f'{case.label}.csv')]
    if missing:
        run_sweep(missing, out, workers=2, progress=print)
    if ship:
        for case in cases:
            if case.design.mesh.element_size_m == 0.00075:
                shutil.copyfile(out / f'{case.label}.csv', REPO / 'config' / 'segments'
                                / f'{SHIPPED_TABLES[case.design.name]}.csv')
    rows = []
    for size in sizes:
        for law in ('', '_yeoh'):
            tables = {n: out / f'paper_{n}{law}__{size * 1e3:g}mm.csv' for n in ('bottom', 'top')}
            if not all(t.is_file() for t in tables.values()):
                continue
            walls = {n: _table_wall_s(t) for n, t in tables.items()}
            rows.append({'material': 'Yeoh' if law else 'Arruda-Boyce',
                         'element_size_m': size, 'bottom_wall_s': walls['bottom'],
                         'top_wall_s': walls['top'],
                         **_pair_summary(tables['bottom'], tables['top'])})
            print(rows[-1], flush=True)
    _store('convergence', {'machine': _machine(), 'rows': rows})


def part_comparison() -> None:
    """The README's table: the paper's reported facts, the stand-ins and the FEM scenes."""
    from softseq_ros.fem.assembly import pair_metrics, summary_numbers
    from softseq_ros.scene.loader import load_scene

    rows = {}
    for scene_name in ('paper', 'paper_fem', 'paper_fem_yeoh'):
        scene = load_scene(scene_name)
        metrics = pair_metrics(list(scene.segments), 65e-6, samples=6501)
        numbers = summary_numbers(metrics)
        path = metrics['path']
        history = metrics['history_m3']
        at = {ml: int(np.argmin(np.abs(history - ml * 1e-6))) for ml in (25, 40, 45, 60, 65)}
        volumes = np.asarray(path.volumes)
        flow = volumes[at[65]] - volumes[at[40]]
        lengths = np.array([s.length for s in scene.segments])
        numbers['top_flow_share_40_65'] = float(flow[1] / (history[at[65]] - history[at[40]]))
        numbers['bending_deg'] = {ml: [round(float(np.degrees(k * L)), 0) for k, L in
                                       zip(np.asarray(path.curvatures)[at[ml]], lengths)]
                                  for ml in (25, 45, 60)}
        numbers['segment_peaks_pa'] = [round(float(np.max(s.pressures)), 1)
                                       for s in scene.segments]
        numbers['segment_peak_at_m3'] = [float(s.volumes[int(np.argmax(s.pressures))]
                                               - s.volumes[0]) for s in scene.segments]
        rows[scene_name] = numbers
        print(scene_name, numbers, flush=True)
    _store('comparison', {'machine': _machine(), 'rows': rows})


def _comparison_lines(rows: dict) -> list[str]:
    """The README's comparison table from the stored numbers."""
    def cell(name: str) -> dict:
        return rows[name]

    def kpa(v: float) -> str:
        return f'{v / 1e3:.2f}'

    lines = ['| on one syringe, 0 -> 65 mL | paper (reported) | `paper` (stand-ins) | '
             '`paper_fem` (FEM unit cells, Arruda-Boyce) | `paper_fem_yeoh` (FEM, Yeoh) |',
             '|---|---|---|---|---|']
    names = ('paper', 'paper_fem', 'paper_fem_yeoh')
    lower = []
    for n in names:
        b, t = cell(n)['segment_peaks_pa']
        where = cell(n)['segment_peak_at_m3'][1] * 1e6
        lower.append(f'{"top" if t < b else "bottom"}: {kpa(t)} kPa (highest at {where:.0f} mL) '
                     f'vs {kpa(b)} kPa')
    lines.append('| segment that levels off lower | top | ' + ' | '.join(lower) + ' |')
    lines.append('| sequence | partial | ' + ' | '.join(
        f'{cell(n)["sequence"]} (smallest share of the inflow {cell(n)["min_share"]:+.3f})'
        for n in names) + ' |')
    lines.append('| combined plateau | reached at 40 mL (a slight slope in the experiment) | '
                 + ' | '.join(f'within 1 % of its top ({kpa(cell(n)["plateau_pressure_pa"])} '
                              f'kPa at {cell(n)["plateau_peak_injected_m3"] * 1e6:.0f} mL) '
                              f'from {cell(n)["plateau_from_m3"] * 1e6:.0f} mL on'
                              for n in names) + ' |')
    lines.append('| top takes over (its share of the inflow half-way) | - | ' + ' | '.join(
        f'{cell(n)["switch_injected_m3"] * 1e6:.0f} mL' if cell(n)['switch_injected_m3']
        else '-' for n in names) + ' |')
    lines.append('| pressure at 25 / 40 / 65 mL [kPa] | - | ' + ' | '.join(
        ' / '.join(kpa(cell(n)[f'p_at_{v}_ml_pa']) for v in (25, 40, 65)) for n in names)
        + ' |')
    lines.append("| top's share of the flow, 40 -> 65 mL | nearly all | " + ' | '.join(
        f'{cell(n)["top_flow_share_40_65"]:.0%}' for n in names) + ' |')
    lines.append('| bending of bottom / top at steps 3, 4, 5 (25 / 45 / 60 mL) [degrees] | both '
                 'bend, then only the top curls | ' + ' | '.join(
                     ', '.join('/'.join(f'{v:.0f}' for v in (cell(n)['bending_deg'].get(ml)
                                                              or cell(n)['bending_deg'][str(ml)]))
                               for ml in (25, 45, 60)) for n in names) + ' |')
    return lines


def _table_wall_s(path: Path) -> float | None:
    """The run time a sweep's summary.csv beside the table gives for it."""
    import csv

    summary = path.parent / 'summary.csv'
    if not summary.is_file():
        return None
    lines = [line for line in summary.read_text().splitlines() if not line.startswith('#')]
    for row in csv.DictReader(lines):
        if row['table'] == path.name:
            return float(row['wall_s'])
    return None


def part_materials() -> None:
    from softseq_ros.fem.sweep import SweepCase, run_sweep

    cases = []
    for label, material in MATERIALS.items():
        for name in ('bottom', 'top'):
            base = load_design(DESIGNS / f'paper_{name}.yaml')
            data_changes = {'mesh.element_size_m': 0.001}
            design = with_changes(base, data_changes)
            design = _with_material(design, material, label)
            slug = f'{name}__' + ''.join(c if c.isalnum() else '_' for c in label)[:40]
            cases.append(SweepCase(label=slug, changes={'material': label}, design=design))
    out = REPO / 'bench' / 'fem_materials'
    # Tables of the current FEM code are kept (delete the folder to recompute them all).
    missing = [case for case in cases if not _current_table(out / f'{case.label}.csv')]
    if missing:
        run_sweep(missing, out, workers=2, progress=print)
    rows = []
    for label in MATERIALS:
        slug = ''.join(c if c.isalnum() else '_' for c in label)[:40]
        tables = {name: out / f'{name}__{slug}.csv' for name in ('bottom', 'top')}
        rows.append({'material': label, **_pair_summary(tables['bottom'], tables['top'])})
        print(rows[-1], flush=True)
    _store('materials', {'machine': _machine(), 'rows': rows, 'element_size_m': 0.001})


def _with_material(design: object, material: dict, label: str) -> object:
    """The design with another material; its description (a table's provenance) says which."""
    from dataclasses import replace

    from softseq_ros.scene.design import Material

    # The design's own description names its own material: keep only what it says of the shape.
    shape = design.description.split(';')[0]
    return replace(design, material=Material(law=material['law'],
                                             params={k: v for k, v in material.items()
                                                     if k != 'law'}),
                   description=f'{shape}; Ecoflex 00-30 as {label}, one of the fits compared '
                               'in docs/fem.md.')


def _pair_summary(bottom: Path, top: Path) -> dict:
    """Sequence type and path numbers of the two tables on one syringe (0 -> 65 mL)."""
    from softseq_ros.fem.assembly import pair_metrics, summary_numbers

    segments = (read_table(bottom, name='bottom', length=0.111),
                read_table(top, name='top', length=0.111))
    out = summary_numbers(pair_metrics(segments))
    # The report's names for the plateau.
    out['combined_peak_pa'] = out['plateau_pressure_pa']
    out['combined_peak_injected_m3'] = out['plateau_peak_injected_m3']
    out['within_1pct_of_peak_from_m3'] = out['plateau_from_m3']
    return out


def _boundary_faces(cells: np.ndarray) -> np.ndarray:
    """Faces of a hexahedral mesh that belong to one cell only (its surface), as quads."""
    local = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]
    faces = np.concatenate([cells[:, list(f)] for f in local])
    keys = np.sort(faces, axis=1)
    _, index, counts = np.unique(keys, axis=0, return_index=True, return_counts=True)
    return faces[index[counts == 1]]


def _draw_mesh(ax: object, points: np.ndarray, cells: np.ndarray, title: str) -> None:
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    faces = _boundary_faces(cells)
    mm = points * 1e3
    ax.add_collection3d(Poly3DCollection(mm[faces], facecolor='#9ecae1', edgecolor='#08519c',
                                         linewidth=0.3, alpha=0.9))
    lo, hi = mm.min(axis=0), mm.max(axis=0)
    centre, span = (lo + hi) / 2, (hi - lo).max() / 2
    for axis, setter in enumerate((ax.set_xlim, ax.set_ylim, ax.set_zlim)):
        setter(centre[axis] - span, centre[axis] + span)
    ax.set_xlabel('x [mm]')
    ax.set_ylabel('y [mm]')
    ax.set_zlabel('z [mm]')
    ax.set_title(title, fontsize=9)
    ax.view_init(elev=22, azim=-60)


def write_figures(folder: Path = REPO / 'docs', element_size_m: float = 0.001) -> None:
    """fem_mesh.png (meshes, undeformed and inflated) and fem_pv.png (curves) in ``folder``."""
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    from softseq_ros.fem.segment import build_segment

    top = with_changes(load_design(DESIGNS / 'paper_top.yaml'),
                       {'mesh.element_size_m': element_size_m})
    segment = build_segment(top)
    model = segment.model
    factor = segment.volume_factor
    result = model.ramp_volume(model.rest_volume + 30e-6 / factor, 5e-7 / factor,
                               2e-6 / factor, 5e-7 / factor / 256)
    deformed = model.positions(result.states[-1].q)
    whole = build_segment(with_changes(top, {'mesh.model': 'whole_segment',
                                             'mesh.element_size_m': 0.002,
                                             'mesh.thin_layer_cells': 1}))
    cells = segment.mesh.cells
    fig = plt.figure(figsize=(13, 4.6))
    _draw_mesh(fig.add_subplot(1, 3, 1, projection='3d'), model.reference, cells,
               f'top unit cell, {element_size_m * 1e3:g} mm elements ({segment.dofs} '
               'unknowns)')
    _draw_mesh(fig.add_subplot(1, 3, 2, projection='3d'), deformed, cells,
               f'inflated: {(result.states[-1].volume - model.rest_volume) * factor * 1e6:.0f}'
               f' mL into the segment, {result.states[-1].pressure / 1e3:.2f} kPa')
    _draw_mesh(fig.add_subplot(1, 3, 3, projection='3d'), whole.model.reference,
               whole.mesh.cells, f'whole top segment, 2 mm ({whole.dofs} unknowns)')
    fig.suptitle('Table I segment meshes (half width; x along the segment, z from the beam to '
                 'the membranes)', fontsize=10)
    fig.tight_layout()
    fig.savefig(folder / 'fem_mesh.png', dpi=130)
    plt.close(fig)

    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2))
    segs = REPO / 'config' / 'segments'
    for name, colour in (('bottom', 'tab:blue'), ('top', 'tab:red')):
        for kind, style in (('paper_fem', '-'), ('paper', ':')):
            table = read_table(segs / f'{kind}_{name}.csv', name=name,
                                              length=0.111)
            injected = (table.volumes - table.volumes[0]) * 1e6
            label = f'{name}, {"FEM" if kind == "paper_fem" else "stand-in"}'
            axes[0].plot(injected, table.pressures / 1e3, style, color=colour, label=label)
            axes[1].plot(injected, table.curvatures, style, color=colour, label=label)
    axes[0].set_ylabel('gauge pressure [kPa]')
    axes[1].set_ylabel('curvature [1/m]')
    materials = REPO / 'bench' / 'fem_materials'
    for index, label in enumerate(MATERIALS):
        slug = ''.join(c if c.isalnum() else '_' for c in label)[:40]
        for name, style in (('bottom', '--'), ('top', '-')):
            path = materials / f'{name}__{slug}.csv'
            if not path.is_file():
                continue
            table = read_table(path, name=name, length=0.111)
            axes[2].plot((table.volumes - table.volumes[0]) * 1e6, table.pressures / 1e3, style,
                         color=f'C{index}', label=f'{label}' if name == 'top' else None)
    axes[2].set_ylabel('gauge pressure [kPa] (top solid, bottom dashed)')
    axes[2].legend(fontsize=6)
    for ax in axes:
        ax.set_xlabel('fluid injected into the segment [mL]')
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    axes[0].set_title("PV: FEM (Arruda-Boyce, the paper's law) vs stand-ins", fontsize=9)
    axes[1].set_title('curvature of the beam', fontsize=9)
    axes[2].set_title('FEM unit cells (1 mm) across Ecoflex 00-30 fits', fontsize=9)
    fig.tight_layout()
    fig.savefig(folder / 'fem_pv.png', dpi=130)
    plt.close(fig)
    print(f'wrote {folder / "fem_mesh.png"}, {folder / "fem_pv.png"}')


PARTS = {'meshes': part_meshes, 'whole': part_whole, 'sweep': part_sweep,
         'materials': part_materials, 'convergence': part_convergence,
         'comparison': part_comparison}


def quick(folder: Path) -> None:
    """``--quick``: one coarse case through every part's code, no fine mesh; into ``folder``."""
    from softseq_ros.fem.sweep import run_sweep, sweep_cases

    yeoh = with_changes(load_design(DESIGNS / 'paper_top_yeoh.yaml'), QUICK_CHANGES)
    print(f'quick: top unit cell at {QUICK_ELEMENT_M * 1e3:g} mm in a fresh process ...',
          flush=True)
    result = fresh_run(yeoh, str(folder / 'quick_top.csv'))
    print(result, flush=True)
    # The same run shown as the first row of the meshes part and of the whole-segment part.
    _store('meshes', {'machine': _machine(), 'rows': [
        {'segment': 'top', 'element_size_m': QUICK_ELEMENT_M, **result}]})
    _store('whole', {'machine': _machine(), 'rows': [
        {'segment': 'top', 'model': 'unit_cell', 'material': 'Yeoh',
         'element_size_m': QUICK_ELEMENT_M, 'thin_layer_cells': 1, **result}]})

    print(f'quick: the same design to {QUICK_SWEEP_M3 * 1e6:g} mL as a sweep of one ...',
          flush=True)
    base = with_changes(yeoh, {'volume.max_injected_m3': QUICK_SWEEP_M3})
    cases = sweep_cases(base, {'geometry.membrane_thickness_m': [0.0005]})
    start = time.perf_counter()
    run_sweep(cases, folder / 'sweep', workers=1)
    wall = time.perf_counter() - start
    _store('sweep', {'machine': _machine(), 'rows': [
        {'workers': 1, 'designs': len(cases), 'wall_s': round(wall, 1),
         'designs_per_minute': round(60 * len(cases) / wall, 2)}],
        'case': f'paper_top, {QUICK_ELEMENT_M * 1e3:g} mm elements, 0 to '
                f'{QUICK_SWEEP_M3 * 1e6:g} mL, membrane 0.5 mm (quick check)'})

    label = next(iter(MATERIALS))
    slug = ''.join(c if c.isalnum() else '_' for c in label)[:40]
    tables = {name: REPO / 'bench' / 'fem_materials' / f'{name}__{slug}.csv'
              for name in ('bottom', 'top')}
    if all(path.is_file() for path in tables.values()):
        print('quick: the pair summary of one fit (shipped tables) ...', flush=True)
        row = {'material': label, **_pair_summary(tables['bottom'], tables['top'])}
        _store('materials', {'machine': _machine(), 'rows': [row], 'element_size_m': 0.001})
    else:
        print(f'quick: no shipped tables for {label} in bench/fem_materials; materials '
              'skipped', flush=True)

    print('quick: figures ...', flush=True)
    write_figures(folder, QUICK_ELEMENT_M)


def write_report(note: str = '') -> None:
    data = _load()
    lines = ['# FEM benchmark results', '',
             'Written by `python bench/bench_fem.py` (see its docstring for the method). '
             'Times on a 2-core machine shared with other work; each run single-threaded in a '
             "fresh process; memory is the run's peak resident set." + note, '']
    if 'meshes' in data:
        part = data['meshes']
        lines += ['## Unit cell: time, unknowns and memory per mesh density', '',
                  f'Machine: {part["machine"]}', '',
                  '| segment | element [mm] | unknowns | Newton iterations | wall [s] | CPU [s] '
                  '| memory [MB] | peak pressure [Pa] | at [mL] | curvature at the end [1/m] |',
                  '|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|']
        for row in part['rows']:
            lines.append(f'| {row["segment"]} | {row["element_size_m"] * 1e3:g} | {row["dofs"]} '
                         f'| {row["newton_iterations"]} | {row["wall_s"]} | {row["cpu_s"]} | '
                         f'{row["max_rss_mb"]:.0f} | {row["peak_pressure_pa"]} | '
                         f'{row["peak_injected_m3"] * 1e6:.1f} | {row["final_curvature_per_m"]} |')
        lines += ['', 'Mesh convergence of the plateau (peak) pressure, change per refinement:',
                  '']
        for name in ('top', 'bottom'):
            rows = [r for r in part['rows'] if r['segment'] == name]
            if len(rows) < 2:
                continue   # one mesh (--quick): nothing to compare
            changes = [f'{(b["peak_pressure_pa"] / a["peak_pressure_pa"] - 1) * 100:+.2f} %'
                       for a, b in zip(rows[:-1], rows[1:])]
            lines.append(f'- {name}: ' + ', '.join(
                f'{a["element_size_m"] * 1e3:g} -> {b["element_size_m"] * 1e3:g} mm: {c}'
                for a, b, c in zip(rows[:-1], rows[1:], changes)))
        lines.append('')
    if 'whole' in data:
        part = data['whole']
        lines += ['## Whole segment (half-width symmetry) against the unit cell, same mesh', '',
                  f'Machine: {part["machine"]}', '',
                  '| segment | model | material | element [mm] | thin-layer cells | unknowns '
                  '| Newton iterations | wall [s] | memory [MB] | reached [mL] '
                  '| peak pressure [Pa] | at [mL] | stop |',
                  '|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|']
        for row in part['rows']:
            lines.append(f'| {row["segment"]} | {row["model"]} | {row["material"]} | '
                         f'{row["element_size_m"] * 1e3:g} | '
                         f'{row["thin_layer_cells"]} | {row["dofs"]} | '
                         f'{row["newton_iterations"]} | {row["wall_s"]} | '
                         f'{row["max_rss_mb"]:.0f} | {row["final_injected_m3"] * 1e6:.1f} | '
                         f'{row["peak_pressure_pa"]} | {row["peak_injected_m3"] * 1e6:.1f} | '
                         f'{row["stop_reason"]} |')
        lines.append('')
    if 'sweep' in data:
        part = data['sweep']
        lines += ['## Sweep throughput', '',
                  f'Case: {part["case"]}. Machine: {part["machine"]}', '',
                  '| workers | designs | wall [s] | designs per minute |', '|---:|---:|---:|---:|']
        for row in part['rows']:
            lines.append(f'| {row["workers"]} | {row["designs"]} | {row["wall_s"]} | '
                         f'{row["designs_per_minute"]} |')
        lines.append('')
    if 'materials' in data:
        part = data['materials']
        lines += ['## The paper pair across Ecoflex 00-30 fits', '',
                  f'Unit cells at {part["element_size_m"] * 1e3:g} mm; both segments on one '
                  'syringe, 0 -> 65 mL. Machine: ' + str(part['machine']), '',
                  '| material | bottom peak [Pa] | top peak [Pa] | sequence | p at 25 / 45 / 60 '
                  'mL [Pa] | top share of the fluid at 45 / 60 mL | combined peak [Pa] at [mL] '
                  '| within 1 % of it from [mL] |', '|---|---:|---:|---|---|---|---:|---:|']
        for row in part['rows']:
            ps = ' / '.join(str(row.get(f'p_at_{v}_ml_pa', '-')) for v in (25, 45, 60))
            share = ' / '.join(str(row.get(f'top_share_at_{v}_ml', '-')) for v in (45, 60))
            lines.append(f'| {row["material"]} | {row["bottom_peak_pa"]} | {row["top_peak_pa"]} '
                         f'| {row["sequence"]} | {ps} | {share} | {row["combined_peak_pa"]} at '
                         f'{row["combined_peak_injected_m3"] * 1e6:.1f} | '
                         f'{row["within_1pct_of_peak_from_m3"] * 1e6:.1f} |')
        lines.append('')
    if 'convergence' in data:
        part = data['convergence']
        lines += ["## The paper pair on the paper's law: mesh convergence", '',
                  'Unit cells, full PV curves, both segments on one syringe, 0 -> 65 mL; run on '
                  'two worker processes. Machine: ' + str(part['machine']), '',
                  '| material | element [mm] | bottom peak [Pa] | top peak [Pa] | '
                  'sequence | smallest share of the inflow | plateau [Pa] | within 1 % from '
                  '[mL] | top takes over at [mL] | p at 25 / 45 / 60 mL [Pa] | wall bottom / top '
                  '[s] |', '|---|---:|---:|---:|---|---:|---:|---:|---:|---|---|']
        for row in part['rows']:
            ps = ' / '.join(str(row.get(f'p_at_{v}_ml_pa', '-')) for v in (25, 45, 60))
            switch = row.get('switch_injected_m3')
            lines.append(
                f'| {row["material"]} | {row["element_size_m"] * 1e3:g} | '
                f'{row["bottom_peak_pa"]} | {row["top_peak_pa"]} | {row["sequence"]} | '
                f'{row["min_share"]} | {row["plateau_pressure_pa"]} | '
                f'{row["plateau_from_m3"] * 1e6:.1f} | '
                f'{"-" if switch is None else f"{switch * 1e6:.1f}"} | {ps} | '
                f'{row.get("bottom_wall_s")} / {row.get("top_wall_s")} |')
        arruda = [r for r in part['rows'] if r['material'] == 'Arruda-Boyce']
        arruda.sort(key=lambda r: -r['element_size_m'])
        lines += ['', 'Plateau pressure change per refinement (Arruda-Boyce):', '']
        for key, label in (('bottom_peak_pa', 'bottom peak'), ('top_peak_pa', 'top peak'),
                           ('plateau_pressure_pa', 'pair plateau')):
            lines.append(f'- {label}: ' + ', '.join(
                f'{a["element_size_m"] * 1e3:g} -> {b["element_size_m"] * 1e3:g} mm: '
                f'{(b[key] / a[key] - 1) * 100:+.2f} %' for a, b in zip(arruda[:-1], arruda[1:])))
        lines.append('')
    if 'comparison' in data:
        lines += ["## The paper's facts, the stand-ins and the FEM scenes", '',
                  *_comparison_lines(data['comparison']['rows']), '']
    REPORT.write_text('\n'.join(lines) + '\n')


def main() -> None:
    global RESULTS, REPORT
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--part', choices=[*PARTS, 'figures', 'report', 'all'], default='all')
    parser.add_argument('--quick', action='store_true',
                        help='a check that the benchmark runs: one coarse case, about 30 s, '
                        'nothing written into the repository (the report is printed)')
    args = parser.parse_args()
    if args.quick:
        if args.part != 'all':
            parser.error('--quick runs its own coarse case of every part: no --part with it')
        with tempfile.TemporaryDirectory(prefix='bench_fem_') as folder:
            RESULTS = Path(folder) / 'fem_results.json'
            REPORT = Path(folder) / 'fem_results.md'
            quick(Path(folder))
            write_report(' **Quick check** (`--quick`): one coarse case, the numbers show that '
                         'the benchmark runs.')
            print('\n' + REPORT.read_text())
        return
    names = list(PARTS) + ['figures'] if args.part == 'all' else [args.part]
    for name in names:
        if name == 'figures':
            write_figures()
        elif name != 'report':
            PARTS[name]()
    write_report()
    print(f'wrote {REPORT}')


if __name__ == '__main__':
    main()
