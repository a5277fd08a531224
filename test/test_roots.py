"""
brent_roots, the equilibrium map's fold solver, against scipy's brentq: the same roots to the bit.
"""

import numpy as np
import pytest
from scipy.optimize import brentq

from softseq_ros.quasistatic.roots import brent_roots


def family(seed: int, count: int):
    """Smooth functions with one sign change on [0, 1], and a few flat or steep ones."""
    rng = np.random.default_rng(seed)
    c = rng.normal(size=(count, 4))
    r = rng.uniform(0.2, 0.8, count)
    power = rng.choice([1.0, 3.0, 5.0], count)   # odd powers: roots of high multiplicity

    def f(i, x):
        s = x - r[i]
        scale = c[i, 0] ** 2 + 0.1 + 0.1 * abs(c[i, 1]) * x * x
        return (np.sign(s) * np.abs(s) ** power[i] * scale
                + c[i, 2] * 1e-6 * np.sin(7.0 * x) * s + c[i, 3] * 1e-9 * s)

    return f


@pytest.mark.parametrize('xtol, rtol', [(1e-14, 1e-15), (1e-6, 1e-12), (2e-12, 8.9e-16)])
def test_the_roots_are_scipys_to_the_bit(xtol, rtol):
    count = 400
    f = family(7, count)
    a, b = np.zeros(count), np.ones(count)
    f_a = np.array([float(f(i, 0.0)) for i in range(count)])
    f_b = np.array([float(f(i, 1.0)) for i in range(count)])
    calls = []

    def evaluate(indices, x):
        calls.append(indices.size)
        return np.array([float(f(i, v)) for i, v in zip(indices.tolist(), x.tolist())])

    roots = brent_roots(evaluate, a, b, f_a, f_b, xtol, rtol)
    expected = [brentq(lambda x, i=i: float(f(i, x)), 0.0, 1.0, xtol=xtol, rtol=rtol)
                for i in range(count)]
    assert roots.tolist() == expected
    # Side by side: one call per step for all the roots still going, not one per root.
    assert len(calls) < 100 and calls[0] == count


def test_a_zero_end_is_the_root_and_a_bracket_without_a_sign_change_is_refused():
    roots = brent_roots(lambda i, x: x - 0.5, np.array([0.0, 0.5]), np.array([0.5, 1.0]),
                        np.array([-0.5, 0.0]), np.array([0.0, 0.5]), 1e-14, 1e-15)
    assert roots.tolist() == [0.5, 0.5]
    with pytest.raises(ValueError, match='does not change sign'):
        brent_roots(lambda i, x: x, np.array([1.0]), np.array([2.0]), np.array([1.0]),
                    np.array([2.0]), 1e-14, 1e-15)
    with pytest.raises(RuntimeError, match='did not converge within 3 iterations'):
        brent_roots(lambda i, x: np.tanh(50 * (x - 0.3)), np.array([0.0]), np.array([1.0]),
                    np.array([np.tanh(-15.0)]), np.array([np.tanh(35.0)]), 1e-14, 1e-15,
                    max_iterations=3)
