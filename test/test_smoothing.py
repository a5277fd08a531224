"""
Table smoothing keeps what the rows show: peaks and valleys at their height, knees in place.

Noisy synthetic measurements of thin balloons (Gent and Ogden laws, the project's BalloonSegment)
with seeded Gaussian noise: the smoothed table's peak and valley must lie within one noise
deviation of the noise-free rows' on every seed, and a sharp knee (the project's bulge tables,
a piecewise-linear curve) must not move by more than 1 % of the pressure. The former smoothing
(one cubic spline, its penalty by generalised cross-validation) raised the Gent peak of these
tests by 35 to 110 Pa, up to twelve deviations of the 0.25 % noise.
"""

import numpy as np
import pytest

from softseq_ros.segments.materials import Gent, Ogden
from softseq_ros.segments.models import BalloonSegment
from softseq_ros.segments.smoothing import smooth_table

PEAK_PA = 3809.0     # a latex balloon's peak, the curves scaled to it
SEEDS = range(10)
# law -> (material, largest stretch): each has a rounded peak, then a valley followed by a rise
# of more than 6 noise deviations (a smaller one is dropped as noise, by design).
LAWS = {
    'gent_jm30': (Gent(1.0, 30.0), 3.2),
    'gent_jm67': (Gent(1.0, 67.0), 4.5),
    'ogden_treloar': (Ogden((0.63, 0.0012, -0.01), (1.3, 5.0, -2.0)), 7.0),
}
# Rows either side of a peak or valley the rows need to resolve it at all (a balloon sampled
# evenly in volume peaks within its first few rows at 60 or 200 rows: no smoothing finds it).
RESOLVED_ROWS = 15


def balloon_rows(law, rows, spacing):
    """Volumes (evenly in stretch or in volume) and noise-free pressures, peak at PEAK_PA."""
    material, stretch = LAWS[law]
    segment = BalloonSegment('balloon', 0.1, material, 0.005, 0.0005, stretch)
    if spacing == 'stretch':
        volume = segment.rest_volume * np.linspace(1.0, stretch, rows) ** 3
    else:
        volume = np.linspace(segment.rest_volume, segment.max_volume, rows)
    pressure = segment.pressure(volume)
    return volume, pressure * PEAK_PA / pressure[np.argmax(np.diff(pressure) < 0.0)]


def peak_and_valley(pressure):
    """Rows of the first peak and of the valley after it."""
    slope = np.diff(pressure)
    peak = int(np.argmax(slope < 0.0))
    return peak, peak + int(np.argmax(slope[peak:] > 0.0))


CASES = [(law, spacing, rows) for law in LAWS for spacing in ('stretch', 'volume')
         for rows in (60, 200, 600)
         if min(np.diff([0, *peak_and_valley(balloon_rows(law, rows, spacing)[1]), rows - 1]))
         >= RESOLVED_ROWS]


def test_the_cases_cover_both_spacings_and_every_law():
    assert {law for law, _, _ in CASES} == set(LAWS)
    assert {spacing for _, spacing, _ in CASES} == {'stretch', 'volume'}
    assert {rows for _, _, rows in CASES} == {200, 600}


@pytest.mark.parametrize('law, spacing, rows', CASES)
@pytest.mark.parametrize('share', [0.0025, 0.005, 0.01])
def test_a_rounded_peak_and_valley_stay_within_one_noise_deviation(law, spacing, rows, share):
    volume, pressure = balloon_rows(law, rows, spacing)
    peak, valley = peak_and_valley(pressure)
    middle = (peak + valley) // 2
    sigma = share * PEAK_PA
    for seed in SEEDS:
        noisy = pressure + np.random.default_rng(seed).normal(0.0, sigma, rows)
        noisy[0] = pressure[0]
        smoothed = smooth_table(volume, noisy)
        # One peak and one valley, no more (the noise's wiggles are gone).
        assert np.count_nonzero(np.diff(np.sign(np.diff(smoothed)))) == 2, seed
        assert abs(smoothed[:middle].max() - pressure[peak]) <= sigma, seed
        assert abs(smoothed[middle:].min() - pressure[valley]) <= sigma, seed


def test_the_gent_peak_the_former_spline_moved_is_kept():
    # 10 Pa of noise on a 3809 Pa Gent peak, 200 rows evenly in stretch: the former spline gave
    # 3843 to 3851 Pa on 7 of these seeds and lost the peak on 3 (3348 Pa, the valley's side).
    volume, pressure = balloon_rows('gent_jm30', 200, 'stretch')
    peak, _ = peak_and_valley(pressure)
    for seed in SEEDS:
        noisy = pressure + np.random.default_rng(seed).normal(0.0, 10.0, volume.size)
        noisy[0] = pressure[0]
        assert abs(smooth_table(volume, noisy)[:2 * peak].max() - pressure[peak]) <= 10.0


def paper_rows(name, rows):
    """The project's bulge table (a plateau after a sharp knee), resampled to ``rows`` rows."""
    from pathlib import Path

    from softseq_ros.scene.tables import read_table

    folder = Path(__file__).resolve().parent.parent / 'config' / 'segments'
    segment = read_table(folder / f'paper_{name}.csv', length=0.111)
    volume = np.linspace(segment.rest_volume, segment.max_volume, rows)
    return volume, segment.pressure(volume)


def knee_bias(volume, pressure, sigma, seeds=range(20)):
    """The largest mean error over the seeds of any row [Pa], and the largest single error."""
    errors = []
    for seed in seeds:
        noisy = pressure + np.random.default_rng(seed).normal(0.0, sigma, volume.size)
        noisy[0] = pressure[0]
        errors.append(smooth_table(volume, noisy) - pressure)
    errors = np.array(errors)
    return float(np.max(np.abs(errors.mean(axis=0)))), float(np.max(np.abs(errors)))


@pytest.mark.parametrize('name', ['bottom', 'top'])
@pytest.mark.parametrize('rows', [60, 200])
@pytest.mark.parametrize('share', [1e-3, 0.0025, 0.01])
def test_a_sharp_knee_moves_by_less_than_1_percent(name, rows, share):
    volume, pressure = paper_rows(name, rows)
    span = np.ptp(pressure)
    bias, _ = knee_bias(volume, pressure, share * span)
    assert bias <= 0.01 * span


@pytest.mark.parametrize('rows', [200, 600])
def test_a_piecewise_linear_knee_stays_within_1_percent(rows):
    # The slope falls tenfold at 10 kPa; noise 0.25 % of it.
    volume = np.linspace(1e-6, 5e-5, rows)
    x = (volume - volume[0]) / (volume[-1] - volume[0])
    pressure = np.where(x < 0.3, 1e4 * x / 0.3, 1e4 + 2e3 * (x - 0.3))
    bias, worst = knee_bias(volume, pressure, 25.0)
    assert bias <= 0.01 * 1e4 and worst <= 0.01 * 1e4


def test_exact_rows_come_back_as_they_are():
    volume, pressure = balloon_rows('gent_jm30', 200, 'stretch')
    np.testing.assert_array_equal(smooth_table(volume, pressure, noise_std=0.0), pressure)
