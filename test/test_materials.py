"""
Material laws under equibiaxial stretch, checked against closed forms derived here.

Equibiaxial stretch lam of an incompressible membrane: principal stretches (lam, lam, lam^-2),
so I1 = 2 lam^2 + lam^-4 and I2 = lam^4 + 2 lam^-2. A thin spherical balloon of reference radius
R and thickness H holds p = H / (R lam^2) dW/dlam, so the pressure in units of mu H / R is
p_hat(lam) = dW/dlam / (mu lam^2). Limit-point thresholds (derived by bisection on the closed
forms below, independently of the library; they match the literature values in DESIGN.md):
Gent J_m* = 17.6381, Mooney-Rivlin (C2/C1)* = 0.21446, Abaqus Arruda-Boyce lambda_m* = 2.26304.
"""

import math

import numpy as np
import pytest

from softseq_ros.segments.materials import (
    ArrudaBoyce,
    Gent,
    MooneyRivlin,
    NeoHookean,
    Ogden,
    Yeoh,
    make_material,
)

STRETCHES = np.array([1.0, 1.05, 1.3, 1.7, 2.2, 3.0, 4.5])
AB_C = (1 / 2, 1 / 20, 11 / 1050, 19 / 7000, 519 / 673750)


def i1(lam):
    return 2.0 * lam**2 + lam**-4


def i2(lam):
    return lam**4 + 2.0 * lam**-2


def closed_energy(law, params, lam):
    """Strain energy per reference volume, written out from the textbook forms."""
    if law == 'neo_hookean':
        (mu,) = params
        return mu / 2 * (i1(lam) - 3)
    if law == 'mooney_rivlin':
        c1, c2 = params
        return c1 * (i1(lam) - 3) + c2 * (i2(lam) - 3)
    if law == 'gent':
        mu, jm = params
        return -mu * jm / 2 * np.log(1 - (i1(lam) - 3) / jm)
    if law == 'ogden':
        mus, alphas = params
        return sum(m / a * (2 * lam**a + lam**(-2 * a) - 3) for m, a in zip(mus, alphas))
    if law == 'arruda_boyce':
        mu, lm = params
        return mu * sum(c / lm**(2 * k - 2) * (i1(lam)**k - 3**k) for k, c in enumerate(AB_C, 1))
    if law == 'yeoh':
        c1, c2, c3 = params
        x = i1(lam) - 3
        return c1 * x + c2 * x**2 + c3 * x**3
    raise AssertionError(law)


CASES = [
    ('neo_hookean', (40e3,), NeoHookean(40e3), 40e3),
    ('mooney_rivlin', (15e3, 3e3), MooneyRivlin(15e3, 3e3), 2 * (15e3 + 3e3)),
    ('gent', (50e3, 40.0), Gent(50e3, 40.0), 50e3),
    ('ogden', ((6.3e5, 1.2e3, -1e4), (1.3, 5.0, -2.0)),
     Ogden((6.3e5, 1.2e3, -1e4), (1.3, 5.0, -2.0)),
     0.5 * (6.3e5 * 1.3 + 1.2e3 * 5.0 + 1e4 * 2.0)),
    ('arruda_boyce', (30e3, 3.5), ArrudaBoyce(30e3, 3.5),
     # Abaqus: mu_0 = mu (1 + 3/(5 lm^2) + 99/(175 lm^4) + 513/(875 lm^6) + 42039/(67375 lm^8))
     30e3 * (1 + 3 / (5 * 3.5**2) + 99 / (175 * 3.5**4) + 513 / (875 * 3.5**6)
             + 42039 / (67375 * 3.5**8))),
    ('yeoh', (17e3, -0.2e3, 0.023e3), Yeoh(17e3, -0.2e3, 0.023e3), 34e3),
]
IDS = [c[0] for c in CASES]


@pytest.mark.parametrize('law, params, material, mu0', CASES, ids=IDS)
def test_energy_matches_closed_form(law, params, material, mu0):
    lam = STRETCHES[STRETCHES < 0.98 * min(material.max_stretch, 1e9)]
    expected = closed_energy(law, params, lam)
    np.testing.assert_allclose(material.energy(lam), expected, rtol=1e-12, atol=1e-12 * mu0)


@pytest.mark.parametrize('law, params, material, mu0', CASES, ids=IDS)
def test_energy_derivative_is_derivative_of_closed_form(law, params, material, mu0):
    lam = STRETCHES[STRETCHES < 0.98 * min(material.max_stretch, 1e9)]
    h = 1e-5
    # Fourth-order central difference of the closed form: error ~ h^4, far below 1e-8.
    fd = (-closed_energy(law, params, lam + 2 * h) + 8 * closed_energy(law, params, lam + h)
          - 8 * closed_energy(law, params, lam - h)
          + closed_energy(law, params, lam - 2 * h)) / (12 * h)
    np.testing.assert_allclose(material.energy_derivative(lam), fd, rtol=1e-8, atol=1e-8 * mu0)


@pytest.mark.parametrize('law, params, material, mu0', CASES, ids=IDS)
def test_shear_modulus_from_small_strain_energy(law, params, material, mu0):
    # Linear elasticity, incompressible: W = mu eps_ij eps_ij = mu (e^2 + e^2 + (2e)^2) = 6 mu e^2
    # for the equibiaxial strain (e, e, -2e); so W(1 + e) / (6 e^2) -> mu as e -> 0.
    assert material.shear_modulus == pytest.approx(mu0, rel=1e-12)
    e = 1e-4
    w = float(material.energy(1.0 + e))
    assert w / (6 * e**2) == pytest.approx(mu0, rel=1e-3)
    assert float(material.energy(1.0)) == pytest.approx(0.0, abs=1e-12 * mu0)
    assert float(material.energy_derivative(1.0)) == pytest.approx(0.0, abs=1e-12 * mu0)


def test_ogden_one_term_alpha_two_is_neo_hookean():
    lam = STRETCHES
    np.testing.assert_allclose(Ogden((7e3,), (2.0,)).energy(lam), NeoHookean(7e3).energy(lam),
                               rtol=1e-13, atol=1e-9)
    np.testing.assert_allclose(Ogden((7e3,), (2.0,)).energy_derivative(lam),
                               NeoHookean(7e3).energy_derivative(lam), rtol=1e-13, atol=1e-9)
    assert Ogden((7e3,), (2.0,)).shear_modulus == pytest.approx(7e3, rel=1e-15)


@pytest.mark.parametrize('material', [Yeoh(9e3, 0.0, 0.0), MooneyRivlin(9e3, 0.0)],
                         ids=['yeoh', 'mooney_rivlin'])
def test_reduces_to_neo_hookean_with_mu_twice_c1(material):
    reference = NeoHookean(18e3)
    np.testing.assert_allclose(material.energy(STRETCHES), reference.energy(STRETCHES),
                               rtol=1e-13, atol=1e-9)
    np.testing.assert_allclose(material.energy_derivative(STRETCHES),
                               reference.energy_derivative(STRETCHES), rtol=1e-13, atol=1e-9)
    assert material.shear_modulus == pytest.approx(18e3, rel=1e-15)


def test_gent_locks_where_i1_minus_3_reaches_jm():
    for jm in (5.0, 17.638, 97.2):
        lam = Gent(1.0, jm).max_stretch
        assert i1(lam) - 3 == pytest.approx(jm, rel=1e-10)


def test_make_material_builds_each_law_from_scene_names():
    built = {
        'neo_hookean': make_material('neo_hookean', {'shear_modulus_pa': 40e3}),
        'mooney_rivlin': make_material('mooney_rivlin', {'c1_pa': 15e3, 'c2_pa': 3e3}),
        'gent': make_material('gent', {'shear_modulus_pa': 50e3, 'jm': 40.0}),
        'ogden': make_material('ogden', {'mu_pa': [6.3e5, 1.2e3, -1e4],
                                         'alpha': [1.3, 5.0, -2.0]}),
        'arruda_boyce': make_material('arruda_boyce', {'shear_modulus_pa': 30e3,
                                                       'lambda_m': 3.5}),
        'yeoh': make_material('yeoh', {'c1_pa': 17e3, 'c2_pa': -0.2e3, 'c3_pa': 0.023e3}),
    }
    for law, params, _, _ in CASES:
        np.testing.assert_allclose(built[law].energy(STRETCHES[:5]),
                                   closed_energy(law, params, STRETCHES[:5]), rtol=1e-12)


@pytest.mark.parametrize('law, params, word', [
    ('neo_hookean', {}, 'shear_modulus_pa'),
    ('gent', {'shear_modulus_pa': 1.0, 'jm': 3.0, 'jn': 2.0}, 'jn'),
    ('rubber', {'shear_modulus_pa': 1.0}, 'rubber'),
])
def test_make_material_names_the_bad_key(law, params, word):
    with pytest.raises(ValueError, match=word):
        make_material(law, params)


# --- limit points of a thin spherical balloon ------------------------------------------------

def normalised_pressure(material, lam):
    """p in units of mu H / R: dW/dlam / (mu lam^2)."""
    return material.energy_derivative(lam) / (material.shear_modulus * lam**2)


def has_limit_point(material, top=40.0):
    """True when p_hat(lam) falls somewhere on 1 < lam < min(top, lock)."""
    end = min(top, 0.99999 * material.max_stretch)
    lam = np.linspace(1.0, end, 400001)
    return bool(np.any(np.diff(normalised_pressure(material, lam)) < 0.0))


def bisect_threshold(make, without, with_, tol=1e-4):
    """The parameter at which a limit point appears, between a value without and one with."""
    assert not has_limit_point(make(without))
    assert has_limit_point(make(with_))
    while abs(with_ - without) > tol:
        mid = 0.5 * (without + with_)
        if has_limit_point(make(mid)):
            with_ = mid
        else:
            without = mid
    return 0.5 * (without + with_)


def test_neo_hookean_balloon_peak_location_and_value():
    material = NeoHookean(1.0)
    lam = np.linspace(1.0, 3.0, 2000001)
    p = normalised_pressure(material, lam)
    np.testing.assert_allclose(p, 2 * (1 / lam - 1 / lam**7), rtol=1e-12, atol=1e-15)
    k = int(np.argmax(p))
    assert lam[k] == pytest.approx(7 ** (1 / 6), abs=2e-6)
    assert p[k] == pytest.approx(2 * (7 ** (-1 / 6) - 7 ** (-7 / 6)), rel=1e-11)


def test_gent_monotone_exactly_below_jm_17_638():
    assert not has_limit_point(Gent(1.0, 17.5))
    assert has_limit_point(Gent(1.0, 17.8))
    jm = bisect_threshold(lambda j: Gent(1.0, j), 17.5, 17.8)
    assert jm == pytest.approx(17.638, abs=0.01)
    assert jm == pytest.approx(17.6381, abs=2e-3)


def test_mooney_rivlin_limit_point_exactly_below_ratio_0_2145():
    assert has_limit_point(MooneyRivlin(1.0, 0.20))
    assert not has_limit_point(MooneyRivlin(1.0, 0.23))
    ratio = bisect_threshold(lambda r: MooneyRivlin(1.0, r), 0.23, 0.20)
    assert ratio == pytest.approx(0.2145, abs=0.01)
    assert ratio == pytest.approx(0.21446, abs=2e-4)


def test_arruda_boyce_limit_point_exactly_above_lambda_m_2_263():
    assert not has_limit_point(ArrudaBoyce(1.0, 2.2))
    assert has_limit_point(ArrudaBoyce(1.0, 2.35))
    lm = bisect_threshold(lambda m: ArrudaBoyce(1.0, m), 2.2, 2.35)
    assert lm == pytest.approx(2.263, abs=0.01)
    assert lm == pytest.approx(2.26304, abs=2e-3)


def test_thresholds_do_not_depend_on_modulus():
    # The limit point is a property of the shape of p_hat: scaling mu must not move it.
    assert has_limit_point(Gent(3e5, 17.8)) and not has_limit_point(Gent(3e5, 17.5))
    assert math.isclose(normalised_pressure(Gent(3e5, 30.0), 1.7),
                        normalised_pressure(Gent(1.0, 30.0), 1.7), rel_tol=1e-13)
