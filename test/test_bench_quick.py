"""
Every benchmark in bench/ still runs: its ``--quick`` mode, end to end, in a subprocess.

A benchmark is not a test (no time is asserted here), but one that no longer runs after a
change of the package is found here rather than at its next full run. Each quick mode works on
small inputs, prints its tables and writes nothing into the repository: the checks below look
for the tables it promises, with numbers in them, and that its results files were left alone.
The DDS parts (bench_rig's processes, latency and baseline parts, bench_soak's real-time part)
are not in the quick modes: they take minutes of real time.
"""

import os
from pathlib import Path
import re
import subprocess
import sys
import time

import pytest

REPO = Path(__file__).resolve().parent.parent
TIMEOUT_S = 300

# script -> (what its output must contain, patterns of table rows with numbers, results files
# its full mode writes and its quick mode must leave alone)
QUICK = {
    'bench_rig.py': (
        ['## 1. Batch run', '### Where the time goes',
         '| component (stage) | calls | own time [s] | share | per call [us] |',
         '### Skipping what a scene does not need', 'Actuator alone'],
        [r'\| actuator: equilibrium solve [^|]*\(`actuator\.model\.command`\) \| [1-9]\d* \| '
         r'\d+\.\d+ \| \d+ % \| \d+\.\d+ \|',
         r'\| camera: frame [^|]*\(`camera\.tick`\) \| [1-9]\d* \|',
         r'\| bag writing [^|]*\(`append`\) \| [1-9]\d* \|',
         r'\| bag writing of a block [^|]*\(`block\.append`\) \| [1-9]\d* \|',
         r'\| actuator: states of a block [^|]*\(`block\.actuator`\) \| [1-9]\d* \|',
         r'\| \d+\.\d \| \d+\.\d \| \*\*\d+x\*\* \| \d+x \| [1-9]\d* \| [\d,]+ \|',
         r'\| pump hold: [^|]* \| \d+\.\d\d \| \d+\.\d\d \| \d+x \| \d+ % \| \d+ \| '
         r'[1-9]\d* / [1-9]\d* \(rejected 0\) \|',
         r'a moving volume costs \d+\.\d us per command \([1-9]\d* solves\)'],
        ['bench/rig_results.md']),
    'bench_soak.py': (
        ['## 1. Batch soak', 'complete = True', 'per-topic counts equal to the run',
         '| cycle | messages | wall [s] |', 'pump state at the end `finished`'],
        [r'\*\*[\d,]+ messages\*\* in \d+ s wall',
         r'\*\*End / start: RSS \d+\.\d{3}\*\*',
         r'\*\*last / first \d+\.\d\d\*\*',
         r'\| 2 \| [\d,]+ \| \d+\.\d \| [\d,]+ \| \d+\.\d \| \d+\.\d \| [\d,]+ \|'],
        ['bench/soak_results.md']),
    'bench_solver.py': (
        ['## fig1_asymmetric', '## chain3', '## Targets', '## Scaling', '## Noisy tables',
         '| method | split err | split err off snaps |'],
        [r'\| ours r=2000 polish=2 \| \d\.\d\de-\d\d \| \d\.\d\de-\d\d \|',
         r'\| naive root-finding \| \d\.\d\de-\d\d \|',
         r'\| dynamic Radau QR/p=0\.001 \| \d\.\d\de-\d\d \|',
         r'\| fig1_asymmetric \| \d+x \(',
         r'\| monotone chain, 3 segments \| \d+\.\d\d \| \d+\.\d \|',
         r'\| 60 \| 0\.002 \| yes \| \d/2 \|'],
        ['docs/benchmarks.md', 'docs/bench_solver.png']),
    'bench_analysis.py': (
        ['All three readers return identical arrays (checked)',
         '| whole report of the paper bag | time |'],
        [r'\| ours \(`softseq_ros\.bag\.arrays`\) \| \d+\.\d\d s \(CPU \d+\.\d\d s\) \| 1x \|',
         r'\| rosbags [^|]* \| \d+\.\d\d s \| \d+x \|',
         r'\| mcap-ros2-support [^|]* \| \d+\.\d\d s \| \d+x \|',
         r'\| in-process: read, metrics, 5 figures as PNG \| \d+\.\d\d s \|',
         r'\| paper style \(the default\), PNG \| \d+\.\d\d s \([^|]*\| \d+\.\d\d s \| '
         r'\d+\.\d\dx, \d+\.\d\dx \|',
         r'\| with `--scene paper` \| \d+\.\d\d s \([^|]*\| \d+\.\d\d s \| \d+\.\d\dx',
         r'\| paper bag \| [\d,]+ \| \d+ \|'],
        ['bench/analysis_results.md']),
    'bench_restructure.py': (
        ['# Restructuring: speed old against new', '| job | command | old [s] | new [s] |'],
        [r'\| sweep \| `softseq classify fig1_asymmetric` \| \d+\.\d\d \| \d+\.\d\d \| '
         r'\d\.\d{3} \(',
         r'\| assembly \| `softseq classify three_segments` \| \d+\.\d\d \| \d+\.\d\d \|'],
        ['bench/restructure_results.md']),
    'bench_dynamic.py': (
        ['## paper', '## fig1_asymmetric', '| ours: rtol | run time [s] | steps | error / range |',
         '## Batch rig: the paper scene with the network on',
         "## The integrators alone, against scipy's Radau"],
        [r'\| 1e-03 \| \d+\.\d{3} \| [1-9]\d* \| \d\.\d\de-\d\d \|',
         r'\| 1e-05 \| \d+\.\d{3} \| [1-9]\d* \| \d\.\d\de-\d\d \|',
         # FONSim runs when its own environment exists, and is said to be skipped otherwise.
         r'(\| 2 \| \d+\.\d\d \| [1-9]\d* \| \d\.\d\de-\d\d \||\*\*FONSim skipped\*\*)',
         r'\| quasi-static \| \(pump 50\) \| \d+ \| \d+\.\d \| \d+\.\d \| [\d,]+ \| '
         r'\*\*\d+x\*\* \| \d+x \| 1\.00 \|',
         r'\| network \| 200 \| \d+ \| \d+\.\d \| \d+\.\d \| [\d,]+ \| \*\*\d+x\*\* \| \d+x \| '
         r'\d+\.\d\d \|',
         r'\| paper \| 1 \| ScalarRadau \| 1e-03 \| \d+\.\d\d \| [1-9]\d* \| \d+\.\d\d \| '
         r'[1-9]\d* \| \*\*\d+\.\d\d\*\* \| \d\.\de-\d\d \|',
         # LeanRadau is scipy's Radau step for step: no difference at all.
         r'\| three_segments \| 2 \| LeanRadau \| 1e-03 \| \d+\.\d\d \| [1-9]\d* \| \d+\.\d\d \| '
         r'[1-9]\d* \| \*\*\d+\.\d\d\*\* \| 0\.0e\+00 \|'],
        ['bench/dynamic_results.md']),
    'bench_graph.py': (
        ['# Equilibrium map and transition graph: N peaked segments',
         '| N | law | configurations tried / brute force | branches | snaps | map + graph [s] |'],
        [r'\| 2 \| table \| 8 / 9 \| 9 \| 4 \| \d+\.\d\d \| \d+\.\d\d \| \d+\.\d\d \| '
         r'\d+\.\d\d \| \d+\.\dx \| (bit-identical|same ends and landings, intervals to '
         r'\de-1[3-9]) \| - \| - \|',
         r'\| 3 \| table \| 20 / 27 \| 21 \| 12 \| \d+\.\d\d \| \d+\.\d\d \| - \|'],
        ['bench/graph_results.md']),
    'bench_landing_sweep.py': (
        ['| set | tables | parameters', '8 sets, 0 failed'],
        [r'\| 2 \| 4 identical, 100 Pa \| [^|]* \| [1-9]\d* \| [1-9]\d* \| \d+\.\d \| pass \|',
         r'\| 16 \| 3 identical, 10 Pa \| [^|]* \| [1-9]\d* \| [1-9]\d* \| \d+\.\d \| pass \|'],
        ['bench/landing_sweep_results.md']),
    'bench_supply.py': (
        ['| scene | supply | sequence type | inflation snaps |'],
        [r'\| fig1_asymmetric \| ideal syringe \| asymmetric \| \d+\.\d\d mL at ',
         r'\| fig1_asymmetric \| 1 mL of air \| asymmetric \| \d+\.\d\d mL at \d\.\d{3} kPa, '
         r'[^|]+ \| [^|]+ \| \d+\.\d+ s \(\d+\.\d\d\) \|'],
        ['bench/supply_results.md']),
    'bench_fit.py': (
        ['## Coverage of the 95 % intervals', '## Noise estimate',
         '## The criterion names the law', '## Time per fit'],
        [r'\| gent \| given \| 80 \| 1 % \| jm \| \d+ / 10 \| \d+ / 10 \| \d\.\d\d \|',
         r'\| ogden \| fitted \| 30 \| 5 % \| rest_volume_m3 \| \d+ / 10 \| \d+ / 10 \| '
         r'\d\.\d\d \|',
         r'\| 100 \| third differences, trimmed \(fit\) \| \d\.\d{3} \| \d\.\d{3} \| \d+ % \|',
         r'\| mooney_rivlin \| \d+ / 10 \| \d+ / 10 \| [^|]+ \|',
         r'\| gent \| \d+\.\d ms \| \d+\.\d ms \| \d+\.\d\d s \|'],
        ['bench/fit_results.md']),
    'bench_fit_fonsim.py': (
        ["| law | c: volume at the syringe's zero [mL] (95 % profile) | fitted parameters"],
        # FONSim's balloon when its own environment exists, a synthetic one otherwise.
        [r'(rows from FONSim \d+\.\d+\.\d+|FONSim skipped: .*a synthetic balloon instead)',
         r'\| (\*\*)?Gent(\*\*)? \| \d+\.\d\d \(\d+\.\d\d to \d+\.\d\d[^|]*\) \| '
         r'shear_modulus_h_over_r_pa [\d.]+ kPa \([^|]*bootstrap [^|]*\); jm [^|]+ \| '
         r'[\d.e+]+ \| \d+\.\d \([^|]+\) \| [\d.]+, [\d.]+, \d+ / 56 \|',
         r'\| (\*\*)?Yeoh(\*\*)? \| \d+\.\d\d \([^|]+\) \| c1_h_over_r_pa [^|]+ \| [\d.e+]+ \|'],
        ['docs/fit.md', 'docs/fit_fonsim.png']),
    'bench_fem.py': (
        ['## Unit cell: time, unknowns and memory per mesh density', '## Sweep throughput',
         '## The paper pair across Ecoflex 00-30 fits', 'fem_mesh.png'],
        [r'\| top \| 2 \| [1-9]\d* \| [1-9]\d* \| \d+\.\d \| \d+\.\d \| \d+ \| \d+\.\d \|',
         r'\| top \| unit_cell \| Yeoh \| 2 \| 1 \| [1-9]\d* \|',
         r'\| 1 \| 1 \| \d+\.\d \| \d+\.\d+ \|',
         r'\| neo-Hooke[^|]* \| \d+\.\d \| \d+\.\d \| \w+ \|'],
        ['bench/fem_results.json', 'bench/fem_results.md', 'docs/fem_mesh.png',
         'docs/fem_pv.png']),
    'bench_fem_actuator.py': (
        ['# The whole actuator against the assembly of its segment tables', '## Run times'],
        [r'\| whole actuator \(one cavity\) \| [1-9]\d* \| \d+\.\d \|',
         r'\| unit cell tables \| \w+ \| [+-]\d+\.\d \(',
         r'- unit cells: tables and assembly \d+\.\d s, \*\*\d+\.\dx\*\*'],
        ['bench/fem_actuator_results.json', 'bench/fem_actuator_results.md',
         'docs/fem_actuator.png']),
    'bench_adversarial.py': (
        ['| class | what is tried | tried | held | broken |', '(quick sample)'],
        [r'\*\*[1-9]\d* bad inputs tried, [1-9]\d* held, 0 broken\*\*',
         r'\| scene \| [^|]+ \| 1 \| 1 \| 0 \|', r'\| topic \| [^|]+ \| 1 \| 1 \| 0 \|',
         r'\| file \| [^|]+ \| 1 \| 1 \| 0 \|',
         r'\| node_parameter \| [^|]+ \| 1 \| 1 \| 0 \|'],
        ['bench/adversarial_results.md', 'docs/faults.md']),
    'bench_fem_design.py': (
        # The shipped grid tables are current (else: --refresh-quick-cache): one FEM run.
        ['# softseq design: FEM calls and wall time to meet a target',
         'quick: 3 of the 3 grid tables from bench/fem_design/tiny_cache\n'],
        [r'\| tiny \| local2 \| 1 \| 3 \| [1-9]\d* \| [1-9]\d* \| [\d.]+ / [\d.]+ / [\d.]+ / '
         r'[\d.]+ \| [\d.]+ \| True \|'],
        ['bench/fem_design_results.json', 'bench/fem_design_results.md']),
    'bench_scatter.py': (
        ['# softseq scatter: samples per second, locally and on Dask',
         'Identical samples on the four: yes.'],
        [r'\| this process \(1 worker\) \| \d+\.\d\d \| \d+\.\d\d \| \d+ \| 1\.00 \|',
         r'\| local processes \(2 workers\) \| \d+\.\d\d \| \d+\.\d\d \| \d+ \| \d+\.\d\d \|',
         r'\| local Dask cluster \(2 workers x 1 thread\) \| \d+\.\d\d \| \d+\.\d\d \| \d+ \| '
         r'\d+\.\d\d \|',
         r'\| running local Dask cluster, by its address \(2 workers x 1 thread\) \| \d+\.\d\d \| '
         r'\d+\.\d\d \| \d+ \| \d+\.\d\d \|',
         r'P\(symmetric\) = 0\.\d{3} \(95 % interval 0\.\d{3} to 0\.\d{3}\)'],
        ['bench/scatter_results.md']),
}


def _stamp(relative: str) -> tuple[int, int] | None:
    path = REPO / relative
    if not path.exists():
        return None
    info = path.stat()
    return info.st_mtime_ns, info.st_size


def _soak_scenes() -> set[str]:
    return {path.name for path in (REPO / 'config').glob('soak_*.yaml')}


@pytest.mark.slow
@pytest.mark.parametrize('script', sorted(QUICK))
def test_benchmark_quick_mode_runs(script, tmp_path):
    texts, rows, results = QUICK[script]
    before = {relative: _stamp(relative) for relative in results}
    scenes = _soak_scenes()
    env = dict(os.environ, PYTHONUNBUFFERED='1', MPLBACKEND='Agg', TMPDIR=str(tmp_path))
    start = time.monotonic()
    done = subprocess.run([sys.executable, str(REPO / 'bench' / script), '--quick'], cwd=REPO,
                          env=env, capture_output=True, text=True, timeout=TIMEOUT_S)
    took = time.monotonic() - start
    output = done.stdout
    assert done.returncode == 0, (f'{script} --quick failed ({done.returncode}) after '
                                  f'{took:.0f} s:\n{output[-3000:]}\n{done.stderr[-5000:]}')
    missing = [text for text in texts if text not in output]
    assert not missing, f'{script} --quick printed none of {missing}:\n{output[-5000:]}'
    unmatched = [row for row in rows if not re.search(row, output)]
    assert not unmatched, f'{script} --quick: no line matches {unmatched}:\n{output[-5000:]}'
    # Nothing written into the repository: its results files as they were, no scene left.
    assert {relative: _stamp(relative) for relative in results} == before
    assert _soak_scenes() == scenes
    # Its temporary folders are removed.
    assert list(tmp_path.iterdir()) == []
