"""
Balloon and linear segments against closed forms, quadrature and finite differences.

A thin spherical balloon of rest radius R and thickness H at volume v = 4/3 pi R^3 lam^3 holds
p = H / (R lam^2) dW/dlam; for neo-Hookean that is p = 2 mu H / R (1/lam - 1/lam^7), with its
peak at lam = 7^(1/6), i.e. v = sqrt(7) v0. The stored energy is the integral of p dv from rest.
"""

import math

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.optimize import minimize_scalar

from softseq_ros.segments.materials import (
    ArrudaBoyce,
    Gent,
    MooneyRivlin,
    NeoHookean,
    Ogden,
    Yeoh,
)
from softseq_ros.segments.models import BalloonSegment, LinearSegment

R = 0.006
H = 0.6e-3
V0 = 4 / 3 * math.pi * R**3

MATERIALS = {
    'neo_hookean': NeoHookean(60e3),
    'mooney_rivlin': MooneyRivlin(25e3, 2.5e3),
    'gent': Gent(60e3, 40.0),
    'ogden': Ogden((6.3e5, 1.2e3, -1e4), (1.3, 5.0, -2.0)),
    'arruda_boyce': ArrudaBoyce(30e3, 3.5),
    'yeoh': Yeoh(17e3, -0.2e3, 0.023e3),
}
MAX_STRETCH = {'gent': 4.0}


def balloon(law, name='b', radius=R, thickness=H):
    return BalloonSegment(name, 0.1, MATERIALS[law], radius, thickness,
                          MAX_STRETCH.get(law, 5.0), curvature_gain=3e5)


def sample_volumes(seg, n=9):
    return np.linspace(seg.rest_volume, seg.max_volume, n + 2)[1:-1]


def test_neo_hookean_pressure_closed_form():
    mu = 60e3
    seg = balloon('neo_hookean')
    lam = np.linspace(1.0, 5.0, 41)
    expected = 2 * mu * H / R * (1 / lam - 1 / lam**7)
    np.testing.assert_allclose(seg.pressure(V0 * lam**3), expected, rtol=1e-12, atol=1e-9)
    assert seg.rest_volume == pytest.approx(V0, rel=1e-14)
    assert seg.max_volume == pytest.approx(V0 * 125, rel=1e-14)


def test_neo_hookean_peak_location_and_value():
    mu = 60e3
    seg = balloon('neo_hookean')
    res = minimize_scalar(lambda v: -float(seg.pressure(v)), bounds=(V0, 8 * V0),
                          method='bounded', options={'xatol': 1e-9 * V0})
    assert res.x == pytest.approx(math.sqrt(7) * V0, rel=1e-4)
    peak = 2 * mu * H / R * (7 ** (-1 / 6) - 7 ** (-7 / 6))
    assert -res.fun == pytest.approx(peak, rel=1e-10)


@pytest.mark.parametrize('law', sorted(MATERIALS))
def test_energy_is_integral_of_pressure(law):
    seg = balloon(law)
    for v in sample_volumes(seg, 6):
        integral, err = quad(lambda x: float(seg.pressure(x)), seg.rest_volume, v,
                             epsabs=0.0, epsrel=1e-12, limit=200)
        assert float(seg.energy(v)) == pytest.approx(integral, rel=1e-9)
    assert float(seg.energy(seg.rest_volume)) == pytest.approx(0.0, abs=1e-18)


@pytest.mark.parametrize('law', sorted(MATERIALS))
def test_stiffness_is_derivative_of_pressure(law):
    seg = balloon(law)
    v = sample_volumes(seg)
    h = 1e-4 * V0
    fd = (-seg.pressure(v + 2 * h) + 8 * seg.pressure(v + h) - 8 * seg.pressure(v - h)
          + seg.pressure(v - 2 * h)) / (12 * h)
    scale = float(np.abs(seg.pressure(v)).max()) / V0
    np.testing.assert_allclose(seg.stiffness(v), fd, rtol=1e-7, atol=1e-9 * scale)


@pytest.mark.parametrize('law', sorted(MATERIALS))
def test_small_strain_stiffness_from_shear_modulus(law):
    # p ~ 4 mu H / R * 3 e for lam = 1 + e, and v - v0 ~ 3 v0 e: dp/dv at rest = 4 mu H / (R v0).
    seg = balloon(law)
    mu0 = MATERIALS[law].shear_modulus
    v = V0 * (1 + 1e-5) ** 3
    assert float(seg.pressure(v)) / (v - V0) == pytest.approx(4 * mu0 * H / (R * V0), rel=1e-4)


def test_pressure_scales_with_thickness_over_radius_at_equal_stretch():
    thin, thick = balloon('gent', radius=0.01, thickness=1e-3), balloon('gent', thickness=1e-3)
    lam = np.array([1.2, 1.7, 2.9])
    ratio = thick.pressure(V0 * lam**3) / thin.pressure(4 / 3 * math.pi * 0.01**3 * lam**3)
    np.testing.assert_allclose(ratio, 0.01 / R, rtol=1e-12)


def test_curvature_is_proportional_to_added_volume():
    seg = balloon('neo_hookean')
    v = sample_volumes(seg)
    np.testing.assert_allclose(seg.curvature(v), 3e5 * (v - V0), rtol=1e-12)


def test_linear_segment_closed_forms():
    k, rest, top = 2.5e9, 4e-6, 30e-6
    seg = LinearSegment('lin', 0.1, rest, k, top, curvature_gain=1e5)
    v = np.linspace(rest, top, 7)
    np.testing.assert_allclose(seg.pressure(v), k * (v - rest), rtol=1e-14, atol=1e-9)
    np.testing.assert_allclose(seg.stiffness(v), k, rtol=1e-14)
    np.testing.assert_allclose(seg.energy(v), 0.5 * k * (v - rest) ** 2, rtol=1e-14, atol=1e-20)
    np.testing.assert_allclose(seg.curvature(v), 1e5 * (v - rest), rtol=1e-14, atol=1e-15)


@pytest.mark.parametrize('kwargs, word', [
    ({'radius': 0.0}, 'radius'),
    ({'thickness': -1e-3}, 'thickness'),
    ({'max_stretch': 1.0}, 'stretch'),
])
def test_bad_balloon_parameters_are_named(kwargs, word):
    args = {'name': 'x', 'length': 0.1, 'material': NeoHookean(1e3), 'radius': R,
            'thickness': H, 'max_stretch': 3.0}
    args.update(kwargs)
    with pytest.raises(ValueError, match=word):
        BalloonSegment(**args)


def test_gent_balloon_cannot_reach_the_lock():
    with pytest.raises(ValueError, match='stretch'):
        BalloonSegment('g', 0.1, Gent(1e3, 20.0), R, H, Gent(1e3, 20.0).max_stretch + 0.1)
