"""
Brent's root finder on many brackets at once: scipy's ``brentq``, step for step, in arrays.

The equilibrium map refines every fold of every configuration (D = 0 between two samples of
opposite stability). Each evaluation of D inverts every segment's piece at one pressure, so one
root at a time costs N small inversions per step; side by side, each step inverts each piece once
for all the folds that ask. The iteration is scipy's (``scipy/optimize/Zeros/brentq.c``): the
same operations in the same order on each element, so each root is the number ``brentq`` gives
for the same function and bracket, to the bit (test/test_roots.py checks it).
"""

from typing import Callable

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
# scipy's default iteration budget for brentq.
MAX_ITERATIONS = 100


def brent_roots(evaluate: Callable[[NDArray[np.intp], FloatArray], FloatArray],
                a: FloatArray, b: FloatArray, f_a: FloatArray, f_b: FloatArray,
                xtol: float, rtol: float, max_iterations: int = MAX_ITERATIONS) -> FloatArray:
    """
    Roots of many functions, one per bracket [a, b] (f_a, f_b: the values at its ends).

    ``evaluate(indices, x)`` gives the functions ``indices`` at the points ``x``. Each
    bracket must change sign (or have a zero end, which is its root). Raises RuntimeError
    when a root does not converge within ``max_iterations``, as ``brentq`` does.
    """
    x_pre, x_cur = np.array(a, dtype=float), np.array(b, dtype=float)
    f_pre, f_cur = np.array(f_a, dtype=float), np.array(f_b, dtype=float)
    size = x_pre.size
    if np.any((f_pre != 0.0) & (f_cur != 0.0) & (np.signbit(f_pre) == np.signbit(f_cur))):
        raise ValueError('brent_roots: a bracket does not change sign')
    x_blk, f_blk = np.zeros(size), np.zeros(size)
    s_pre, s_cur = np.zeros(size), np.zeros(size)
    roots = np.where(f_pre == 0.0, x_pre, x_cur)
    active = np.flatnonzero((f_pre != 0.0) & (f_cur != 0.0))
    for _ in range(max_iterations):
        if active.size == 0:
            return roots
        xp, xc, fp, fc = x_pre[active], x_cur[active], f_pre[active], f_cur[active]
        xb, fb, sp, sc = x_blk[active], f_blk[active], s_pre[active], s_cur[active]
        opposite = (fp != 0.0) & (fc != 0.0) & (np.signbit(fp) != np.signbit(fc))
        xb, fb = np.where(opposite, xp, xb), np.where(opposite, fp, fb)
        sp = np.where(opposite, xc - xp, sp)
        sc = np.where(opposite, xc - xp, sc)
        swap = np.abs(fb) < np.abs(fc)
        xp, xc, xb = np.where(swap, xc, xp), np.where(swap, xb, xc), np.where(swap, xc, xb)
        fp, fc, fb = np.where(swap, fc, fp), np.where(swap, fb, fc), np.where(swap, fc, fb)
        delta = (xtol + rtol * np.abs(xc)) / 2
        s_bis = (xb - xc) / 2
        done = (fc == 0.0) | (np.abs(s_bis) < delta)
        with np.errstate(divide='ignore', invalid='ignore', over='ignore'):
            interpolate = -fc * (xc - xp) / (fc - fp)
            d_pre = (fp - fc) / (xp - xc)
            d_blk = (fb - fc) / (xb - xc)
            extrapolate = -fc * (fb * d_blk - fp * d_pre) / (d_blk * d_pre * (fb - fp))
        s_try = np.where(xp == xb, interpolate, extrapolate)
        tried = (np.abs(sp) > delta) & (np.abs(fc) < np.abs(fp))
        short = tried & (2 * np.abs(s_try) < np.minimum(np.abs(sp), 3 * np.abs(s_bis) - delta))
        sp, sc = np.where(short, sc, s_bis), np.where(short, s_try, s_bis)
        step = np.where(np.abs(sc) > delta, sc, np.where(s_bis > 0, delta, -delta))
        roots[active[done]] = xc[done]
        going = ~done
        active = active[going]
        x_pre[active], f_pre[active] = xc[going], fc[going]
        x_cur[active] = xc[going] + step[going]
        x_blk[active], f_blk[active] = xb[going], fb[going]
        s_pre[active], s_cur[active] = sp[going], sc[going]
        if active.size:
            f_cur[active] = evaluate(active, x_cur[active])
    if active.size:
        raise RuntimeError(f'brent_roots: {active.size} roots did not converge within '
                           f'{max_iterations} iterations')
    return roots
