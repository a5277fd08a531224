"""Sweeps of segment designs: local worker processes and a real local Dask cluster agree."""

import csv
import os
from pathlib import Path

import pytest

from softseq_ros.fem.sweep import run_sweep, sweep_cases
from softseq_ros.scene.design import load_design, with_changes

REPO = Path(__file__).resolve().parents[1]
QUICK = {'mesh.element_size_m': 0.003, 'mesh.thin_layer_cells': 1,
         'volume.max_injected_m3': 3e-6, 'volume.max_step_m3': 1e-6}
GRID = {'geometry.membrane_thickness_m': [0.0005, 0.001]}


def _summary(path: Path) -> list[dict]:
    return list(csv.DictReader(line for line in path.read_text().splitlines()
                               if not line.startswith('#')))


@pytest.fixture(scope='module')
def cases():
    os.environ['OMP_NUM_THREADS'] = '1'
    base = with_changes(load_design(REPO / 'config' / 'designs' / 'paper_top.yaml'), QUICK)
    return sweep_cases(base, GRID)


def test_local_sweep_writes_tables_and_summary(cases, tmp_path):
    summary = run_sweep(cases, tmp_path, workers=2)
    rows = _summary(summary)
    assert [row['parameters'] for row in rows] == [
        'geometry.membrane_thickness_m=0.0005', 'geometry.membrane_thickness_m=0.001']
    for row in rows:
        table = (tmp_path / row['table']).read_text()
        assert 'volume_m3,pressure_pa,curvature_per_m' in table
        assert float(row['final_injected_m3']) == pytest.approx(3e-6)
    # A thicker membrane needs more pressure for the same fluid.
    assert float(rows[1]['final_pressure_pa']) > 1.1 * float(rows[0]['final_pressure_pa'])


def test_dask_cluster_sweep_matches_the_local_one(cases, tmp_path):
    from distributed import LocalCluster

    local = run_sweep(cases, tmp_path / 'local', workers=1)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster:
        remote = run_sweep(cases, tmp_path / 'dask', scheduler=cluster.scheduler_address)
    local_rows, remote_rows = _summary(local), _summary(remote)
    assert [r['table'] for r in local_rows] == [r['table'] for r in remote_rows]
    for row in local_rows:
        # Same numbers whichever machine ran them (the run time aside).
        assert ((tmp_path / 'dask' / row['table']).read_text()
                == (tmp_path / 'local' / row['table']).read_text())


def test_softseq_fem_sweep_from_the_command_line(tmp_path, capsys):
    from softseq_ros.cli import main

    quick = [item for key, value in QUICK.items() for item in ('--set', f'{key}={value}')]
    code = main(['fem', str(REPO / 'config' / 'designs' / 'paper_bottom.yaml'), *quick, '--quiet',
                 '--sweep', 'geometry.wall_thickness_m=0.001,0.002', '--out-dir',
                 str(tmp_path), '--workers', '1'])
    assert code == 0
    assert '2 designs on 1 local workers' in capsys.readouterr().out
    rows = _summary(tmp_path / 'summary.csv')
    assert [row['table'] for row in rows] == ['paper_bottom__wall_thickness_m=0.001.csv',
                                              'paper_bottom__wall_thickness_m=0.002.csv']
    assert all((tmp_path / row['table']).is_file() for row in rows)
