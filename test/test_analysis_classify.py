"""Honest classification: the domain's edge is no error, and verdicts say what they rest on."""

from pathlib import Path
import subprocess
import sys

import numpy as np
import pytest

from softseq_ros.analysis.robustness import NOISE_FACTOR, robustness_lines, smallest_features
from softseq_ros.quasistatic.equilibrium import EquilibriumMap, Tracker, classify
from softseq_ros.scene.tables import read_table

SEGMENTS = Path(__file__).resolve().parents[1] / 'config' / 'segments'


def _table(path: Path, source: Path, scale: float = 1.0, noise_pa: float = 0.0,
           every: int = 1, declare: float | None = None, seed: int = 0) -> Path:
    """A copy of a segment table: pressures scaled, optional seeded noise, every n-th row."""
    rng = np.random.default_rng(seed)
    rows = [line for line in source.read_text().splitlines() if line and line[0].isdigit()]
    out = ([f'# noise_std_pa: {declare}'] if declare is not None else []) + \
        ['volume_m3,pressure_pa,curvature_per_m']
    kept = rows[::every] if rows[::every][-1] == rows[-1] else rows[::every] + [rows[-1]]
    for number, line in enumerate(kept):
        v, p, k = line.split(',')[:3]
        noise = rng.normal(0.0, noise_pa) if number else 0.0
        out.append(f'{v},{float(p) * scale + noise!r},{k}')
    path.write_text('\n'.join(out) + '\n')
    return path


def test_tables_ending_at_the_same_volume_classify(tmp_path):
    top = SEGMENTS / 'paper_top.csv'
    stiffer = _table(tmp_path / 'top_x1.3.csv', top, scale=1.3)
    scene = tmp_path / 'pair.yaml'
    scene.write_text(f"""name: pair
segments:
  - {{name: soft, length_m: 0.111, table: {top}}}
  - {{name: stiff, length_m: 0.111, table: {stiffer}}}
pump:
  flow_rate_m3_per_s: 5.0e-8
  legs: [{{inflate_to_m3: 1.0e-5}}, {{deflate_to_m3: 0.0}}]
""")
    result = subprocess.run([sys.executable, '-m', 'softseq_ros.cli', 'classify', str(scene)],
                            capture_output=True, text=True, timeout=120,
                            stdin=subprocess.DEVNULL)
    assert result.returncode == 0, result.stderr
    # Monotone curves: the verdict rests on no peak or valley, so nothing more is said.
    assert result.stdout.splitlines() == ['pair: partial'] and not result.stderr
    # The edge itself, reached by the solver's own range, is inside the domain both ways.
    segments = [read_table(top, 'soft', 0.111),
                read_table(stiffer, 'stiff', 0.111)]
    emap = EquilibriumMap(segments)
    lo, hi = emap.injected_range
    up = Tracker(emap).sweep(np.linspace(lo, hi, 101))
    back = Tracker(emap, injected=hi, volumes=up.volumes[-1]).sweep(np.linspace(hi, lo, 101))
    np.testing.assert_allclose(back.volumes[0], up.volumes[-1], rtol=0, atol=1e-12)
    np.testing.assert_allclose(up.volumes[-1].sum(), hi + emap.total_rest_volume, rtol=1e-12)
    # Past the edge by more than round-off is still refused.
    with pytest.raises(ValueError, match='beyond what the segment models cover'):
        Tracker(emap).step(hi * (1 + 1e-6))


def test_a_verdict_on_noise_wiggles_is_flagged(tmp_path):
    noise = 50.0
    noisy = _table(tmp_path / 'noisy.csv', SEGMENTS / 'paper_top.csv', noise_pa=noise, every=6,
                   seed=3)
    segment = read_table(noisy, 'top', 0.111)
    features = smallest_features([segment])
    assert len(features) == 1
    feature = features[0]
    assert feature.noise_source == 'estimated from the table rows'
    assert feature.noise_pa == pytest.approx(noise, rel=0.4)
    assert feature.depth_pa < NOISE_FACTOR * noise
    lines, warnings = robustness_lines('asymmetric', features)
    assert len(warnings) == 1 and 'may be noise' in warnings[0] and 'top' in warnings[0]
    declared = _table(tmp_path / 'declared.csv', SEGMENTS / 'paper_top.csv', noise_pa=noise,
                      every=6, declare=noise, seed=3)
    feature = smallest_features([read_table(declared, 'top', 0.111)])[0]
    assert feature.noise_source == 'declared' and feature.noise_pa == noise


def test_a_real_peak_is_not_flagged():
    from softseq_ros.scene.loader import load_scene

    scene = load_scene('fig1_asymmetric')
    verdict = classify(EquilibriumMap(scene.segments))
    # Balloon laws have no noise (not an unknown one): the depth is reported, nothing flagged.
    lines, warnings = robustness_lines(verdict, smallest_features(list(scene.segments)))
    assert verdict == 'asymmetric' and not warnings and len(lines) == 2
    assert all('smallest peak-valley depth' in line and
               line.endswith('noise none (a closed-form law)') for line in lines)
    assert smallest_features(list(load_scene('paper').segments)) == []


def test_one_rule_decides_the_sequence_type_of_solved_paths_and_recordings():
    from softseq_ros.quasistatic.sequence import (
        RECORDED_HYSTERESIS_TOLERANCE,
        SOLVED_HYSTERESIS_TOLERANCE,
        sequence_type,
    )

    even = np.full((50, 2), 0.5)
    takeover = np.column_stack([np.linspace(0.9, 0.1, 50), np.linspace(0.1, 0.9, 50)])
    turning = takeover - [0.0, 0.2]
    assert sequence_type(False, 0.0, 1e-9, even) == 'none'
    assert sequence_type(False, 0.0, 1e-9, takeover) == 'partial'
    assert sequence_type(False, 0.0, 1e-9, turning) == 'symmetric'
    assert sequence_type(True, 0.0, 1e-9, even) == 'asymmetric'
    # A gap counts only beyond the tolerance of where the paths come from.
    assert sequence_type(False, 2e-9, 1e-9, even) == 'asymmetric'
    assert sequence_type(False, 1e-9, 1e-9, even) == 'none'
    assert SOLVED_HYSTERESIS_TOLERANCE < RECORDED_HYSTERESIS_TOLERANCE
