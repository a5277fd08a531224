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
    from softseq_ros.analysis.robustness import scene_features
    from softseq_ros.scene.loader import load_scene

    scene = load_scene('fig1_asymmetric')
    emap = EquilibriumMap(scene.segments)
    verdict = classify(emap)
    # Balloon laws have no noise (not an unknown one): the features the verdict rests on are
    # named with their depth (the peak less the valley of each balloon), nothing is flagged.
    used, unused = scene_features(scene, emap)
    lines, warnings = robustness_lines(verdict, used, unused)
    assert verdict == 'asymmetric' and not warnings and len(lines) == 2 and not unused
    depths = {f.segment: f.depth_pa for f in used}
    assert depths == pytest.approx({'bottom': 7665.0 - 6242.0, 'top': 7290.0 - 6528.0},
                                   abs=2.0)
    assert all('noise none (a closed-form law)' in line and 'snap-through' in line
               for line in lines)
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


# ----------------------------------------------------------------- a measured-looking balloon
#
# A latex balloon as a pressure sensor of 1 mbar resolution records it: the Gent model of a
# thin spherical membrane (A. N. Gent, Rubber Chem. Technol. 69 (1996) 59; the balloon law of
# softseq_ros.segments.materials.Gent), p = 2 (mu H / R) (1/l - 1/l^7) / (1 - (2 l^2 + l^-4 - 3)
# / Jm) at stretch l = (v / v0)^(1/3). Jm = 67 puts the valley a third below the peak; mu H / R
# is set for a peak of 87 kPa, so the valley lies 29 kPa below it. 56 rows evenly spaced in
# stretch from 1 to 5 (as a radius measurement gives: dense before the peak, sparse after it;
# at the end the pressure rises past the peak again), rounded to 100 Pa (1 mbar). A model, not
# a measurement: no published table of such a curve was at hand.
JM = 67.0
PEAK_PA = 87.0e3
QUANTUM_PA = 100.0       # 1 mbar
REST_M3 = 4.0 / 3.0 * np.pi * 0.005**3


def _gent_shape(stretch: np.ndarray) -> np.ndarray:
    i1 = 2 * stretch**2 + stretch**-4
    return 2 * (1 / stretch - 1 / stretch**7) / (1 - (i1 - 3) / JM)


def _balloon(stretch: np.ndarray, scale: float = 1.0,
             quantum: float | None = QUANTUM_PA) -> tuple[np.ndarray, np.ndarray]:
    peak = _gent_shape(np.linspace(1.0, 2.0, 20001)).max()
    pressure = scale * PEAK_PA * _gent_shape(stretch) / peak
    if quantum:
        pressure = np.round(pressure / quantum) * quantum
    return REST_M3 * stretch**3, pressure


def _balloon_table(path: Path, scale: float = 1.0) -> Path:
    volume, pressure = _balloon(np.linspace(1.0, 5.0, 56), scale)
    rows = ['volume_m3,pressure_pa,curvature_per_m']
    rows += [f'{v:.17g},{p:.17g},{2e5 * (v - REST_M3):.17g}' for v, p in zip(volume, pressure)]
    path.write_text('\n'.join(rows) + '\n')
    return path


def test_a_smooth_curve_has_next_to_no_noise_however_unevenly_sampled():
    from softseq_ros.analysis.robustness import estimated_noise

    rng = np.random.default_rng(7)
    stretch = np.concatenate([[1.0], np.sort(rng.uniform(1.0, 5.0, 54)), [5.0]])
    volume, pressure = _balloon(stretch, quantum=None)
    # The peak and valley are curved enough that second differences read them as 100s of Pa
    # of noise; the local fits' residuals stay below 10^-4 of the peak.
    assert estimated_noise(volume, pressure) < 1e-4 * PEAK_PA
    volume, pressure = _balloon(np.linspace(1.0, 5.0, 56), quantum=None)
    assert estimated_noise(volume, pressure) < 1e-4 * PEAK_PA


def test_quantisation_reads_as_the_quantisation_noise():
    from softseq_ros.analysis.robustness import estimated_noise

    volume, pressure = _balloon(np.linspace(1.0, 5.0, 56))
    # A 1 mbar quantum is uniform noise of deviation 100 Pa / sqrt(12) = 28.9 Pa.
    expected = QUANTUM_PA / np.sqrt(12.0)
    assert 0.6 * expected < estimated_noise(volume, pressure) < 1.6 * expected
    # White noise of a known deviation is found too (56 rows: within about a third).
    rng = np.random.default_rng(11)
    volume, smooth = _balloon(np.linspace(1.0, 5.0, 56), quantum=None)
    for deviation in (30.0, 300.0):
        noisy = smooth + rng.normal(0.0, deviation, smooth.size)
        assert 0.6 * deviation < estimated_noise(volume, noisy) < 1.5 * deviation


def _classified_pair(path: Path, base: tuple[str, Path], tip: tuple[str, Path],
                     length: float = 0.111, smoothing: str | None = None) -> tuple:
    """A scene of two table segments: its verdict, the features used and not, lines, warnings."""
    from softseq_ros.analysis.robustness import scene_features
    from softseq_ros.scene.loader import load_scene

    smoothed = '' if smoothing is None else f', smoothing: {smoothing}'
    rows = '\n'.join(f'  - {{name: {name}, length_m: {length}, table: {table}{smoothed}}}'
                     for name, table in (base, tip))
    path.write_text(f'name: {path.stem}\nsegments:\n{rows}\npump:\n'
                    '  flow_rate_m3_per_s: 1.0e-6\n'
                    '  legs: [{inflate_to_m3: 2.0e-5}, {deflate_to_m3: 0.0}]\n')
    scene = load_scene(path)
    emap = EquilibriumMap(scene.segments)
    verdict = classify(emap)
    used, unused = scene_features(scene, emap)
    return (verdict, used, unused, *robustness_lines(verdict, used, unused))


def test_a_real_peak_and_valley_measured_at_1_mbar_is_not_flagged(tmp_path):
    strong = _balloon_table(tmp_path / 'latex.csv')
    weak = _balloon_table(tmp_path / 'latex_weaker.csv', scale=0.95)
    verdict, used, unused, lines, warnings = _classified_pair(
        tmp_path / 'latex_pair.yaml', ('strong', strong), ('weak', weak), length=0.1)
    assert verdict == 'asymmetric'
    # The verdict rests on each balloon's one peak-valley, about 29 kPa deep (and 27.6 kPa for
    # the weaker one), not on the equal readings the quantisation makes.
    assert sorted(f.segment for f in used) == ['strong', 'weak'] and not unused
    depth = {f.segment: f.depth_pa for f in used}
    assert depth['strong'] == pytest.approx(29.0e3, abs=0.3e3)
    assert depth['weak'] == pytest.approx(0.95 * 29.0e3, abs=0.3e3)
    assert all(f.noise_source == 'estimated from the table rows' for f in used)
    assert all(10.0 < f.noise_pa < 60.0 for f in used)
    assert not warnings
    assert lines[0].startswith('robustness: the asymmetric verdict rests on segment strong: '
                               'peak 86.9 kPa')
    assert 'snap-through' in lines[0]


def test_a_verdict_resting_on_noise_sized_features_is_flagged(tmp_path):
    noise = 50.0
    noisy = _table(tmp_path / 'noisy.csv', SEGMENTS / 'paper_top.csv', noise_pa=noise, every=6,
                   seed=3)
    verdict, used, _, _, warnings = _classified_pair(
        tmp_path / 'noisy_pair.yaml', ('bottom', SEGMENTS / 'paper_bottom.csv'), ('top', noisy))
    # The paper's partial pair turns asymmetric or symmetric on noise wiggles alone: what it
    # rests on is noise-sized, and said so.
    assert verdict in ('symmetric', 'asymmetric') and used
    assert all(f.segment == 'top' and f.depth_pa < NOISE_FACTOR * f.noise_pa for f in used)
    assert len(warnings) == 1 and 'may be noise' in warnings[0] and 'segment top' in warnings[0]


def _noisy_balloon_table(path: Path, deviation: float, scale: float = 1.0,
                         seed: int = 0) -> Path:
    """The latex balloon's 56 rows (not quantised) with seeded Gaussian noise, the first kept."""
    volume, pressure = _balloon(np.linspace(1.0, 5.0, 56), scale, quantum=None)
    noisy = pressure + np.random.default_rng(seed).normal(0.0, deviation, pressure.size)
    noisy[0] = pressure[0]
    rows = ['volume_m3,pressure_pa,curvature_per_m']
    rows += [f'{v:.17g},{p:.17g},{2e5 * (v - REST_M3):.17g}' for v, p in zip(volume, noisy)]
    path.write_text('\n'.join(rows) + '\n')
    return path


@pytest.mark.parametrize('smoothing, source', [
    ('{}', 'estimated from the table rows as read, before smoothing'),
    ('{noise_std_pa: 300.0}', 'declared'),
])
def test_a_smoothed_table_is_judged_by_the_noise_of_its_rows_as_read(tmp_path, smoothing,
                                                                     source):
    deviation = 300.0
    strong = _noisy_balloon_table(tmp_path / 'strong.csv', deviation, seed=1)
    weak = _noisy_balloon_table(tmp_path / 'weak.csv', deviation, scale=0.95, seed=2)
    verdict, used, _, lines, _ = _classified_pair(
        tmp_path / 'smoothed_pair.yaml', ('strong', strong), ('weak', weak), length=0.1,
        smoothing=smoothing)
    assert verdict == 'asymmetric' and sorted(f.segment for f in used) == ['strong', 'weak']
    # The noise put on the rows, not what the smoothing left of it (a fraction: the features
    # would read many times more significant than they are).
    for feature in used:
        assert 0.6 * deviation < feature.noise_pa < 1.5 * deviation
        assert feature.significance < 29.0e3 / (0.6 * deviation)
        assert feature.noise_source == source
    assert all(f'({source})' in line for line in lines if line.startswith('robustness: the'))
