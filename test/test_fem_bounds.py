"""The reach's pressure band (softseq_ros/fem/bounds.py) against closed forms and brute force."""

import numpy as np
from scipy.interpolate import PchipInterpolator

from softseq_ros.fem.bounds import premise_violation, pressure_band, segment_envelope

CELL_TOP_M3 = 1e-6


def _linear(stiffness: float, rows: int) -> tuple[np.ndarray, np.ndarray]:
    volumes = np.linspace(0.0, CELL_TOP_M3, rows)
    return volumes, stiffness * volumes


def _balloon(scale: float, rows: int) -> tuple[np.ndarray, np.ndarray]:
    """A thin neo-Hookean balloon's curve (a pressure peak at stretch 7^(1/6)), as table rows."""
    volumes = np.linspace(0.0, CELL_TOP_M3, rows)
    stretch = (1 + 8 * volumes / CELL_TOP_M3) ** (1 / 3)     # to stretch 2.08: past the peak
    return volumes, scale * 2 * (1 / stretch - stretch ** -7)


def test_linear_segments_give_the_closed_forms_of_the_softest_and_the_stiffest_pair():
    # Springs p = k U / (4 n): on one syringe P = V / sum(4 n / k), softest and stiffest.
    n = 10
    v_max = 4 * n * CELL_TOP_M3
    envelopes = [segment_envelope(_linear(1e9, 2001), _linear(2e9, 2001), n, n, v_max),
                 segment_envelope(_linear(3e9, 2001), _linear(5e9, 2001), n, n, v_max)]
    totals = np.linspace(0.0, v_max, 9)
    low, high = pressure_band(envelopes, totals)
    softest = totals / (4 * n / 1e9 + 4 * n / 3e9)
    stiffest = totals / (4 * n / 2e9 + 4 * n / 5e9)
    # Never inside the closed forms (sound), and as tight as the tables' rows allow.
    assert np.all(low <= softest + 1e-9) and np.all(high >= stiffest - 1e-9)
    np.testing.assert_allclose(low, softest, atol=2e-3 * softest[-1])
    np.testing.assert_allclose(high, stiffest, atol=2e-3 * stiffest[-1])


def _equilibrium_pressures(curves: list, total: float) -> np.ndarray:
    """Every equilibrium of two segments at ``total`` by brute force: the sign changes of
    p1(U) - p2(total - U) on a fine grid, each refined by bisection (all at once)."""
    def gap(u: np.ndarray) -> np.ndarray:
        return curves[0](u) - curves[1](total - u)

    u = np.linspace(0.0, total, 4001)
    g = gap(u)
    where = np.nonzero(np.sign(g[:-1]) != np.sign(g[1:]))[0]
    a, b, sign = u[where], u[where + 1], np.sign(g[where])
    for _ in range(50):
        m = 0.5 * (a + b)
        left = np.sign(gap(m)) == sign
        a, b = np.where(left, m, a), np.where(left, b, m)
    return curves[0](0.5 * (a + b))


def test_every_equilibrium_of_peaked_segments_in_the_box_lies_in_the_band():
    # Each segment a balloon-like cell whose pressure scale grows with a thickness and falls
    # a little with a membrane length, and whose membrane count (6 to 11, rounded) falls with
    # that length: at a segment volume the pressure is then not monotone in the length (one
    # membrane fewer: more fluid per cell). Read with PCHIP as the assembly reads its tables.
    ranges = [(0.9, 1.1), (0.6, 0.8)]
    fewest, most = 6, 11
    v_max = 4 * fewest * CELL_TOP_M3     # what the fewest membranes of the stiff table hold
    rows = 400
    envelopes = [segment_envelope(_balloon(1000 * thin * 0.98, rows),
                                  _balloon(1000 * thick * 1.02, rows), fewest, most, v_max)
                 for thin, thick in ranges]
    totals = np.linspace(0.1, 1.0, 10) * v_max
    low, high = pressure_band(envelopes, totals)
    assert np.all(np.isfinite(high)) and low[-1] > 0   # bounded on both sides

    def designs(thin: float, thick: float, lengths: tuple[float, ...]) -> list:
        out = []
        for thickness in (thin, thick):
            for length in lengths:    # either side of each change of the membrane count
                count = int(round(most - length * (most - fewest)))
                cell = PchipInterpolator(*_balloon(1000 * thickness * (1.02 - 0.04 * length),
                                                   rows), extrapolate=False)
                out.append(lambda U, c=cell, n=count: np.nan_to_num(
                    c(np.asarray(U) / (4 * n)), nan=np.inf))
        return out

    checked = 0
    for first in designs(*ranges[0], (0.0, 0.09, 0.11, 0.49, 0.51, 1.0)):
        for second in designs(*ranges[1], (0.0, 0.11, 0.51, 1.0)):
            for total, lo, hi in zip(totals, low, high):
                pressures = _equilibrium_pressures([first, second], total)
                assert np.all((pressures >= lo - 1e-9) & (pressures <= hi + 1e-9)), \
                    (total, lo, hi, pressures)
                checked += pressures.size
    assert checked > 960   # several equilibria at the volumes past the peaks


def test_the_premise_is_checked_at_the_corners():
    soft, stiff = _balloon(1000.0, 30), _balloon(1100.0, 30)
    assert premise_violation(soft, stiff) == (0.0, 0.0)
    # Stiff below soft past some volume: found, with where.
    crossed = (stiff[0], np.where(stiff[0] > 0.5 * CELL_TOP_M3, 0.8 * stiff[1], stiff[1]))
    excess, at = premise_violation(soft, crossed)
    assert excess > 100 and at > 0.5 * CELL_TOP_M3
