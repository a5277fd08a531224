"""`softseq design` on a tiny coarse grid: a target met and verified, refusals, interpolation."""

from pathlib import Path
import shutil

import numpy as np
import pytest
import yaml

import softseq_ros
from softseq_ros.fem.design_grid import cell_design, ensure_tables, grid_axes, grid_designs
from softseq_ros.fem.design_interpolation import SegmentFamily
from softseq_ros.fem.design_problem import load_problem
from softseq_ros.fem.design_search import search
from softseq_ros.scene.design import cache_path, load_design
from softseq_ros.scene.tables import read_table

# The shipped tiny problem: the paper's pair on the coarsest mesh, the top membrane varied over
# two grid points (the design benchmark's --quick mode runs the same file).
REPO = Path(__file__).resolve().parents[1]
TINY = REPO / 'config' / 'design_targets' / 'tiny.yaml'
# Its grid's tables, shipped for the design benchmark's --quick mode.
SHIPPED = REPO / 'bench' / 'fem_design' / 'tiny_cache'


def _problem(folder: Path, name: str = 'tiny.yaml', **changes: object) -> Path:
    """The tiny problem with dotted keys changed, written into ``folder``."""
    data = yaml.safe_load(TINY.read_text())
    for dotted, value in changes.items():
        node = data
        *parents, leaf = dotted.split('.')
        for key in parents:
            node = node[int(key)] if isinstance(node, list) else node[key]
        node[leaf] = value
    path = folder / name
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.fixture(scope='module')
def library(tmp_path_factory):
    """
    The tiny problem's cache: the shipped grid tables but one, which a real local Dask cluster
    computes again while the search runs (and it must match the shipped one).

    Returns the folder, the cache, the search's result and what it said, in order.
    """
    from distributed import LocalCluster

    folder = tmp_path_factory.mktemp('design')
    problem = load_problem(_problem(folder))
    cache = folder / 'cache'
    cache.mkdir()
    designs = [design for *_, design in grid_designs(problem)]
    for design in designs:
        if not cache_path(design, SHIPPED).is_file():
            pytest.fail(f'{SHIPPED} holds no table of {design.name} {design.digest()} (the FEM '
                        'code or felupe changed): python bench/bench_fem_design.py '
                        '--refresh-quick-cache')
    again = designs[-1]     # the top's stiffest corner
    for design in designs[:-1]:
        shutil.copy(cache_path(design, SHIPPED), cache)
    said = []
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=':0') as cluster:
        result = search(problem, cache_dir=cache, scheduler=cluster.scheduler_address,
                        verify=False, progress=lambda line: said.append(('progress', line)),
                        announce=lambda line: said.append(('announce', line)))
    assert result.fem_runs == 1
    computed, shipped = (read_table(cache_path(again, where), name='top', length=0.111)
                         for where in (cache, SHIPPED))
    np.testing.assert_allclose(computed.volumes, shipped.volumes, rtol=1e-9)
    np.testing.assert_allclose(computed.pressures, shipped.pressures, rtol=1e-6, atol=1e-6)
    return folder, cache, result, said


def _corner_pairs(cache: Path, problem_path: Path) -> dict[tuple[str, str], dict]:
    """The tiny problem's corner pairs assembled from their cached tables (no reach code)."""
    from softseq_ros.fem.assembly import pair_metrics

    problem = load_problem(problem_path)
    bottom = cell_design(problem, problem.segments[0], problem.materials[0], {})
    tops = {which: cell_design(problem, problem.segments[1], problem.materials[0],
                               {'membrane_thickness_m': value})
            for which, value in (('soft', 0.0004), ('stiff', 0.0006))}
    out = {}
    for which, top in tops.items():
        segments = [read_table(cache_path(d, cache), name=name, length=0.111)
                    for d, name in ((bottom, 'bottom'), (top, 'top'))]
        out[which] = pair_metrics(segments, 3e-5, samples=401, with_sequence=False)
    return out


def test_a_target_is_met_and_the_best_design_verified_by_direct_fem(library, capsys,
                                                                   monkeypatch, tmp_path):
    from softseq_ros.cli import main

    folder, cache, _, _ = library
    out = folder / 'found'
    code = main(['design', str(_problem(folder)), '--cache-dir', str(cache), '--out', str(out),
                 '--workers', '2', '--quiet'])
    printed = capsys.readouterr().out
    assert code == 0, printed
    # The grid came from the Dask cluster's cache; only the verification ran now.
    assert '(1 FEM runs now' in printed
    assert 'verification (direct FEM of the best design): partial, top leads' in printed
    assert 'meets the target' in printed and 'NOT' not in printed
    results = yaml.safe_load((out / 'results.yaml').read_text())
    assert results['verified'] is True
    best = results['ranked'][0]
    thickness = best['parameters']['top']['membrane_thickness_m']
    assert 0.0004 <= thickness <= 0.0006
    # Predicted and verified plateau both within the target's tolerance.
    for numbers in (best['predicted'], results['verification']):
        assert numbers['sequence'] == 'partial' and numbers['leader'] == 'top'
        assert abs(numbers['plateau_pressure_pa'] - 2500.0) <= 200.0
    # The designs found are design files `softseq fem` reads.
    top = load_design(out / best['designs']['top'])
    assert top.geometry.membrane_thickness_m == pytest.approx(thickness)
    assert top.material.law == 'arruda_boyce'
    # What the ranges reach, and what the check could not bound, are in the results too.
    low, high = results['reach']['plateau_pressure_pa']
    assert low <= results['verification']['plateau_pressure_pa'] <= high
    assert any(note.startswith('switch_injected_m3, leader and sequence')
               for note in results['reach_notes'])
    assert {tuple(pair['corners']) for pair in results['corner_pairs']} == {
        ('soft', 'soft'), ('soft', 'stiff')}   # the bottom is fixed: its corners are one
    assert 'reach of the ranges: plateau' in printed
    # The console says the search's mesh and the mesh the written designs keep.
    problem = yaml.safe_load(_problem(folder).read_text())
    grid_mm = problem.get('grid', {}).get('element_size_m', 0.002) * 1e3
    assert (f'the search meshed its grid tables at grid.element_size_m {grid_mm:g} mm; the '
            f'design files keep their own mesh ({top.mesh.element_size_m * 1e3:g} mm)'
            in printed)
    # A scene of the best design, with how to run it: its tables first, at their own mesh.
    scene_file = out / f'{problem["name"]}_best.yaml'
    assert f'a scene of the best design: {scene_file}' in printed
    assert f'softseq fem {out / best["designs"]["top"]}' in printed
    assert f'softseq run {scene_file}' in printed
    from softseq_ros.scene.loader import load_scene
    from softseq_ros.scene.validation import SceneError

    monkeypatch.setenv('SOFTSEQ_FEM_CACHE', str(tmp_path / 'fem'))
    with pytest.raises(SceneError, match=r'no FEM table of this design .* make it once with '
                                         r'`softseq fem '):
        load_scene(scene_file)
    # With its tables made (here: the verification's, the same pair at the grid's mesh), it
    # runs as it is.
    problem_spec = load_problem(_problem(folder))
    for segment in problem_spec.segments:
        verified = cell_design(problem_spec, segment, problem_spec.materials[0],
                               best['parameters'][segment.name])
        target = cache_path(load_design(out / best['designs'][segment.name]))
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(cache_path(verified, cache), target)
    assert softseq_ros.classify(load_scene(scene_file)) == 'partial'


def test_the_corners_are_announced_before_they_run_and_the_grid_reuses_them(library):
    _, _, _, said = library
    assert said[0] == ('announce', 'reach: 1 of the 3 corner designs must be computed before '
                                   'the target can be checked against the ranges (unit cells '
                                   "on the search's mesh; grid points all, so the search "
                                   'reuses them)')
    assert said[1] == ('progress', 'reach (corners): 1/1 unit-cell tables computed')
    assert ('progress', 'grid: 3 unit-cell tables from the cache') in said


def test_every_pair_of_the_ranges_lies_within_the_reach(library):
    folder, cache, result, _ = library
    bounds = result.reach.bounds
    pairs = _corner_pairs(cache, _problem(folder))
    # Sound: the corner pairs (assembled here from their tables) and every design the search
    # found lie within the bounds; and useful: the corner pairs are near the pressure bounds.
    low, high = bounds['plateau_pressure_pa']
    assert low <= pairs['soft']['plateau_pressure_pa'] <= 1.03 * low
    assert high / 1.03 <= pairs['stiff']['plateau_pressure_pa'] <= high
    first, last = bounds['plateau_from_m3']
    for metrics in [*pairs.values(), *(e.metrics for e in result.ranked)]:
        assert low <= metrics['plateau_pressure_pa'] <= high
        assert first <= metrics['plateau_from_m3'] <= last
    assert bounds['tip_distance_m'] == (0.0, pytest.approx(0.222))
    assert not any('premise fails' in note for note in result.reach.notes)


@pytest.mark.parametrize('change, says', [
    ({'target.plateau_pressure_pa': {'value': 9000.0, 'tolerance': 500.0}},
     ['target.plateau_pressure_pa: 9000 Pa (within 500) is above what the ranges reach: at '
      'most ', ' Pa, both segments at their stiffest corners (top: membrane_thickness_m '
      '0.0006); widen top membrane_thickness_m above 0.0006']),
    ({'target.plateau_pressure_pa': {'value': 1500.0, 'tolerance': 100.0}},
     ['target.plateau_pressure_pa: 1500 Pa (within 100) is below what the ranges reach: at '
      'least ', ' Pa, both segments at their softest corners (top: membrane_thickness_m '
      '0.0004); widen top membrane_thickness_m below 0.0004']),
    ({'target.plateau_from_m3': {'value': 5e-6, 'tolerance': 2e-6}},
     ['target.plateau_from_m3: 5 mL (within 2) is earlier than the ranges reach: the pressure '
      'is within 1 % of its plateau from ', ' mL on at the earliest', 'widen the ranges at '
      'either end (top membrane_thickness_m [0.0004, 0.0006])']),
])
def test_a_target_beyond_the_ranges_is_refused_naming_the_bound(library, capsys, change, says):
    from softseq_ros.cli import main

    folder, cache, _, _ = library
    problem = _problem(folder, 'beyond.yaml', **change)
    out = folder / 'refused'
    assert main(['design', str(problem), '--cache-dir', str(cache), '--out', str(out),
                 '--quiet']) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f'softseq design: error: {problem}: ')
    assert all(part in lines[0] for part in says), lines[0]
    assert not out.exists()
    # The bound it names holds for the corner pair at that end (assembled here).
    bound = float(lines[0].split(says[0])[1].split(says[1])[0])
    pairs = _corner_pairs(cache, problem)
    if 'plateau_pressure_pa: 9000' in says[0]:
        assert bound >= pairs['stiff']['plateau_pressure_pa']
    elif 'plateau_pressure_pa' in says[0]:
        assert bound <= pairs['soft']['plateau_pressure_pa']
    else:
        assert bound <= min(p['plateau_from_m3'] for p in pairs.values()) * 1e6


def test_a_tip_beyond_the_actuators_length_is_refused_before_any_work(tmp_path, capsys):
    from softseq_ros.cli import main

    problem = _problem(tmp_path, **{'target.tip_distance_m': {'injected_m3': 2e-5,
                                                              'value': 0.3, 'tolerance': 0.02}})
    assert main(['design', str(problem), '--cache-dir', str(tmp_path / 'cache')]) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1
    assert ('target.tip_distance_m: 0.3 m (within 0.02) is beyond what any design reaches: the '
            "tip is at most the actuator's length from its base, 0.222 m") in lines[0]
    # Nothing computed, nothing announced: the paper's segments are 111 mm each.
    assert not (tmp_path / 'cache').exists() and 'reach:' not in captured.out


def test_interpolated_curve_matches_a_direct_fem_run_off_the_grid(library):
    folder, cache, result, _ = library
    problem = load_problem(_problem(folder))
    grid = grid_designs(problem)
    paths, runs = ensure_tables([d for *_, d in grid], cache, 1, None, None, 'grid')
    assert runs == 0
    top = problem.segments[1]
    family = SegmentFamily.from_tables(top, grid_axes(problem, top),
                                       {i: (paths[d.digest()], d) for s, _, i, d in grid
                                        if s == 1})
    # Half-way between the grid points: where linear interpolation is worst.
    design = cell_design(problem, top, problem.materials[0], {'membrane_thickness_m': 0.0005})
    direct_path, _ = ensure_tables([design], cache, 1, None, None, 'direct')
    direct = read_table(direct_path[design.digest()], name='top', length=0.111)
    interpolated = family.build({'membrane_thickness_m': 0.0005})
    assert interpolated.rest_volume == pytest.approx(direct.rest_volume, rel=1e-12)
    volumes = direct.volumes[1:]
    error = interpolated.pressure(volumes) / direct.pressures[1:] - 1
    assert np.max(np.abs(error)) < 0.02
    assert interpolated.pressures.max() == pytest.approx(direct.pressures.max(), rel=0.01)
    assert np.max(np.abs(interpolated.curvature(volumes) - direct.curvatures[1:])) < \
        0.01 * direct.curvatures.max()
    # A design between the corners, by direct FEM, lies within what the ranges reach.
    from softseq_ros.fem.assembly import pair_metrics

    bottom = cell_design(problem, problem.segments[0], problem.materials[0], {})
    pair = pair_metrics([read_table(cache_path(bottom, cache), name='bottom', length=0.111),
                         direct], 3e-5, samples=401, with_sequence=False)
    low, high = result.reach.bounds['plateau_pressure_pa']
    assert low <= pair['plateau_pressure_pa'] <= high
    first, last = result.reach.bounds['plateau_from_m3']
    assert first <= pair['plateau_from_m3'] <= last


@pytest.mark.parametrize('change, expected', [
    ({'target.sequence': 'spiral'}, "target.sequence: unknown sequence type 'spiral'"),
    ({'target.leader': 'middle'}, "target.leader: 'middle' is none of the segments"),
    ({'segments.1.vary': {'membrane_thickness_m': [0.0006, 0.0004]}},
     'segments[1].vary.membrane_thickness_m: high (0.0004) is below low (0.0006)'),
    ({'segments.1.vary': {'membrane_thickness_m': [0.0004, 0.02]}},
     'segments[1].vary.membrane_thickness_m: 0.02 is no valid design'),
    ({'segments.1.vary': {'membrane_thickness_mm': [0.4, 0.6]}},
     'segments[1].vary.membrane_thickness_mm: wrong or missing unit suffix'),
    ({'target.switch_injected_m3': {'value': 7e-5, 'tolerance': 5e-6}},
     'target.switch_injected_m3.value: must be below target.max_injected_m3'),
    ({'segments.1.design': 'no_such_design'}, 'segments[1].design: no_such_design'),
    ({'grid.points': 20}, 'grid.points: must be at most 6'),
])
def test_bad_problems_are_refused_in_one_line_before_any_work(change, expected, tmp_path,
                                                              capsys):
    from softseq_ros.cli import main

    problem = _problem(tmp_path, **change)
    assert main(['design', str(problem), '--cache-dir', str(tmp_path / 'cache')]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and expected in lines[0], lines
    assert not (tmp_path / 'cache').exists()


def test_the_tip_reach_is_the_chord_of_the_backbone_and_judged_in_tolerances():
    from softseq_ros.fem.design_evaluation import judge, predict
    from softseq_ros.fem.design_problem import Target, Tolerance
    from softseq_ros.segments.models import TabulatedSegment

    # Two segments bent at one constant curvature: the backbone is one arc of 0.222 m.
    k = 8.0
    volumes = np.linspace(1e-5, 5e-5, 9)
    segments = [TabulatedSegment(name, 0.111, volumes, 1e3 + 1e8 * (volumes - 1e-5) * stiff,
                                 np.full(volumes.size, k))
                for name, stiff in (('bottom', 2.0), ('top', 1.0))]
    target = Target(sequence='none', tip_distance=Tolerance(0.2, 0.005), tip_at_m3=3e-5,
                    max_injected_m3=6e-5)
    metrics = predict(target, segments)
    chord = 2 * np.sin(k * 0.222 / 2) / k
    assert metrics['tip_distance_m'] == pytest.approx(chord, rel=1e-9)
    score, meets, errors = judge(target, metrics, metrics['sequence'])
    assert errors['tip_distance_m'] == pytest.approx((chord - 0.2) / 0.005)
    assert meets == (abs(chord - 0.2) <= 0.005) and metrics['sequence'] == 'none'
    # The softer top takes two thirds of the fluid throughout: it leads, and nothing switches.
    assert metrics['leader'] == 'top' and metrics['switch_injected_m3'] is None


def test_the_reach_premise_is_checked_along_every_axis_of_the_grid():
    # A grid of cell curves: the pressure rises with the membrane thickness and falls with the
    # membrane length at every cell volume, as the reach's bounds assume.
    volumes = np.linspace(0.0, 1e-6, 5)
    thickness = np.array([4e-4, 5e-4, 6e-4])
    length = np.array([5e-3, 7e-3])
    level = thickness[:, None, None] / length[None, :, None] * volumes[None, None, :] * 3e10
    axes = {'membrane_thickness_m': thickness, 'membrane_length_m': length}
    family = SegmentFamily(segment=None, axes=axes, rest=None, curves=None, cell_u=volumes,
                           pressures=level)
    assert family.ordering_violation() == (0.0, '')
    # The middle thickness 30 % softer than the thinnest at the last volume: found, and where.
    broken = level.copy()
    broken[1, 0, -1] = 0.7 * broken[0, 0, -1]
    excess, where = SegmentFamily(None, axes, None, None, volumes, broken).ordering_violation()
    assert excess == pytest.approx(0.3 * level[0, 0, -1] - 0.002 * level[0, 0, -1], rel=1e-9)
    assert where == 'membrane_thickness_m 0.0004 -> 0.0005 at 1000 uL per cell'
    # A longer membrane stiffer than the shorter: found on the other axis.
    broken = level.copy()
    broken[2, 1, 2] = 1.5 * broken[2, 0, 2]
    excess, where = SegmentFamily(None, axes, None, None, volumes, broken).ordering_violation()
    assert excess > 0 and where.startswith('membrane_length_m 0.005 -> 0.007')
