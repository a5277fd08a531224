"""The paper_fem scene: committed FEM tables of Table I, run end to end like the paper scene."""

from pathlib import Path
import re
import subprocess
import sys

import numpy as np
import pytest
import yaml

from softseq_ros.quasistatic.equilibrium import Tracker
from softseq_ros.quasistatic.solve import build_map
from softseq_ros.scene.design import load_design
from softseq_ros.scene.loader import load_scene

CONFIG = Path(__file__).resolve().parents[1] / 'config'


@pytest.mark.parametrize('name', ['bottom', 'top'])
def test_committed_fem_tables_come_from_the_shipped_designs(name):
    table = (CONFIG / 'segments' / f'paper_fem_{name}.csv').read_text()
    design = load_design(CONFIG / 'designs' / f'paper_{name}.yaml')
    # A changed design (or FEM code or felupe) has another hash: regenerate the table with
    # `softseq fem paper_<name> --out config/segments/paper_fem_<name>.csv`.
    assert f'design hash {design.digest()}' in table
    assert re.search(r'^# Range: .*reached the requested volume', table, re.M)


@pytest.fixture(scope='module')
def paper_fem_path():
    scene = load_scene('paper_fem')
    emap = build_map(scene.segments, scene.solver.resolution)
    history = np.linspace(0.0, 65e-6, 6501)
    return scene, Tracker(emap).sweep(history), history


def test_paper_fem_pair_behaves_as_the_paper_reports(paper_fem_path):
    scene, path, history = paper_fem_path
    bottom, top = scene.segments
    # The thin-membrane top segment levels off lower than the bottom one.
    assert top.pressures.max() < 0.92 * bottom.pressures.max()
    at = {ml: int(np.argmin(np.abs(history - ml * 1e-6))) for ml in (25, 40, 45, 60, 65)}
    # Combined plateau reached near 40 mL: within 1 % of the highest pressure from there on.
    assert path.pressure[at[40]] > 0.99 * path.pressure.max()
    # From step 4 (45 mL) to step 5 (60 mL) nearly all the fluid goes into the top segment.
    flow = path.volumes[at[60]] - path.volumes[at[45]]
    assert flow[1] > 0.9 * (history[at[60]] - history[at[45]])
    # Both bend at first; from step 3 on the top curls much more.
    assert path.curvatures[at[25], 0] > 1.0 and path.curvatures[at[60], 1] > 4 * \
        path.curvatures[at[60], 0]
    assert not path.events  # quasi-static without snap-throughs on inflation


def test_paper_fem_scene_runs_end_to_end(tmp_path):
    # The paper's programme at 100x the flow, so the bag and report stay small and quick.
    scene = yaml.safe_load((CONFIG / 'paper_fem.yaml').read_text())
    scene['pump'].update(flow_rate_m3_per_s=5.0e-6, legs=[{'inflate_to_m3': 6.5e-5},
                                                          {'deflate_to_m3': 0.0}])
    for segment in scene['segments']:
        segment['table'] = str(CONFIG / segment['table'])
    scene_path = tmp_path / 'paper_fem_fast.yaml'
    scene_path.write_text(yaml.safe_dump(scene))
    out = tmp_path / 'run'
    result = subprocess.run([sys.executable, '-m', 'softseq_ros.cli', 'run', str(scene_path),
                             '--out', str(out), '--quiet'], capture_output=True, text=True,
                            timeout=300, stdin=subprocess.DEVNULL)
    assert result.returncode == 0, result.stderr
    assert (out / 'metadata.yaml').is_file()
    for name in ('pv.png', 'volume_split.png', 'shapes.png', 'summary.txt'):
        assert (out / 'report' / name).stat().st_size > 0
    summary = (out / 'report' / 'summary.txt').read_text()
    assert 'symmetric' in summary or 'partial' in summary
