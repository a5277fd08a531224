"""
Segments behind an ideal pressure regulator: independent hysterons, against the closed form of
a Gent balloon, and a pair that no longer shares its fluid.
"""

import math

import numpy as np
import pytest
from scipy.optimize import brentq, minimize_scalar

from softseq_ros.quasistatic.regulator import PressureDomainError, regulated_path
from softseq_ros.segments.materials import Gent
from softseq_ros.segments.models import BalloonSegment

R, H, MU, JM, STRETCH = 0.006, 0.6e-3, 60e3, 30.0, 4.0
V0 = 4.0 / 3.0 * math.pi * R**3


def gent_pressure(stretch: float) -> float:
    """The thin-walled Gent sphere (docs/DESIGN): p = 2 mu H / R (1/l - 1/l^7) / (1 - I/Jm)."""
    return (2 * MU * H / R * (1 / stretch - stretch**-7)
            / (1 - (2 * stretch**2 + stretch**-4 - 3) / JM))


def test_a_gent_balloon_jumps_at_its_peak_and_back_at_its_valley():
    balloon = BalloonSegment('g', 0.1, Gent(MU, JM), R, H, STRETCH)
    # The closed form's peak and valley, and the stretches where the curve holds them again.
    top = minimize_scalar(lambda s: -gent_pressure(s), bounds=(1.0, 2.5), method='bounded',
                          options={'xatol': 1e-12})
    bottom = minimize_scalar(gent_pressure, bounds=(top.x, 3.5), method='bounded',
                             options={'xatol': 1e-12})
    peak, valley = gent_pressure(top.x), gent_pressure(bottom.x)
    up_to = brentq(lambda s: gent_pressure(s) - peak, bottom.x, STRETCH, xtol=1e-15)
    down_to = brentq(lambda s: gent_pressure(s) - valley, 1.0, top.x, xtol=1e-15)
    pressures = np.concatenate([np.linspace(0.0, 1.2 * peak, 61),
                                np.linspace(1.2 * peak, 0.0, 61)])
    path = regulated_path([balloon], pressures)
    assert len(path.flips) == 2
    up, down = path.flips
    assert up.pressure == pytest.approx(peak, rel=1e-9)
    assert up.from_volume == pytest.approx(V0 * top.x**3, rel=1e-6)
    assert up.to_volume == pytest.approx(V0 * up_to**3, rel=1e-9)
    assert down.pressure == pytest.approx(valley, rel=1e-9)
    assert down.to_volume == pytest.approx(V0 * down_to**3, rel=1e-9)
    # Between the flips the balloon is on its upper rising piece, at every pressure above
    # the valley, on the way up as on the way down: the hysteresis loop of one hysteron.
    assert up.row < down.row
    np.testing.assert_allclose(balloon.pressure(path.volumes[:, 0]), pressures, rtol=1e-9,
                               atol=1e-6)


def test_two_balloons_behind_a_regulator_flip_each_at_its_own_peak():
    # Different walls: different peaks. Under pressure control each flips when the pressure
    # passes its own peak, alone, and the other keeps its volume: the coupling is gone.
    thin = BalloonSegment('thin', 0.1, Gent(MU, JM), R, 0.5e-3, STRETCH)
    thick = BalloonSegment('thick', 0.1, Gent(MU, JM), R, 0.7e-3, STRETCH)
    peaks = [next(pc.p_at_hi for pc in s.monotone_pieces() if pc.direction > 0)
             for s in (thin, thick)]
    pressures = np.linspace(0.0, 1.1 * max(peaks), 200)
    path = regulated_path([thin, thick], pressures)
    assert [f.segment for f in path.flips] == [0, 1]
    for flip, peak in zip(path.flips, peaks):
        assert flip.pressure == pytest.approx(peak, rel=1e-12)
    # Each segment's volume is its own curve's at the common pressure, whatever the other's.
    alone = regulated_path([thin], pressures)
    np.testing.assert_array_equal(path.volumes[:, 0], alone.volumes[:, 0])
    # What the regulator let in: nothing at 0 Pa, and more at every higher pressure (each
    # balloon on a rising piece, or jumping to a larger volume).
    assert path.injected[0] == pytest.approx(0.0, abs=1e-20)
    assert np.all(np.diff(path.injected) > 0.0)
    # Counted from rest, also for a history that starts above 0 Pa.
    later = regulated_path([thin], [1000.0, 2000.0])
    expected = float(thin.invert(thin.monotone_pieces()[0], np.array([1000.0]))[0])
    assert later.injected[0] == pytest.approx(expected - thin.rest_volume, rel=1e-12)


def test_a_pressure_beyond_the_curves_is_refused_naming_the_segment():
    balloon = BalloonSegment('g', 0.1, Gent(MU, JM), R, H, STRETCH)
    with pytest.raises(PressureDomainError, match="row 1: .* segment 'g'"):
        regulated_path([balloon], [0.0, 1e7])
