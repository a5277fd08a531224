"""
Radau IIA for the fluid network's small state, without the cost of scipy's general wrappers.

The network (softseq_ros.dynamic.flow) has a state of a handful of entries, stiff where the
channels are short and wide, so it is integrated by Radau IIA (implicit, fifth order, its step
set by the error). For so few equations scipy's Radau spends more on argument checks, array
conversions and the checks around its LU calls than on the arithmetic, and a run calls the
network's rates thousands of times. So the default method (``'radau'``, :func:`new_integrator`)
runs scipy's algorithm without them:

* :class:`LeanRadau` for a state of several entries: scipy's own Radau with direct calls, the
  same numbers as scipy's to the bit;
* :class:`ScalarRadau` for a state of one entry (two segments, one channel without inertance):
  scipy's algorithm ported to plain floats, its results within the tolerance of scipy's.

``'scipy-radau'`` is scipy's Radau as it comes, kept for comparison. :class:`StepInterpolant`
reads a step's dense output at one instant or many without scipy's per-call checks.
bench/bench_dynamic.py times both classes against scipy's Radau on the same problem at equal
tolerances (bench/dynamic_results.md).
"""

import math
from typing import Callable

import numpy as np
from numpy.typing import NDArray
from scipy.integrate import DenseOutput, Radau
from scipy.linalg.lapack import dgetrf, dgetrs, zgetrf, zgetrs

FloatArray = NDArray[np.float64]
# 'radau': scipy's Radau IIA without scipy's general wrappers (the default); 'scipy-radau':
# scipy's Radau as it comes, for comparison.
METHODS = ('radau', 'scipy-radau')


class LeanRadau(Radau):
    """
    scipy's Radau IIA, step for step and to the bit, for a system of a handful of equations.

    The method, its error estimate, step-size control, Newton iteration and finite-difference
    Jacobian are scipy's own (its ``_step_impl`` runs unchanged). What changes is around them:
    the right-hand side is called without scipy's argument checks and copies, and the LU
    factorisations and solves go to LAPACK's getrf / getrs directly (what scipy's lu_factor /
    lu_solve call, so the same numbers), without the checks of finiteness and the array
    conversions that cost more than the solve of a 2 x 2 system. On three segments (two
    states) it takes about two thirds of scipy's time (bench/dynamic_results.md); the
    segments' pressures take most of the rest. It replaces callables scipy's Radau keeps as
    attributes (``fun``, ``lu``, ``solve_lu``), not a public interface: the tests check it
    still gives scipy's numbers to the bit.
    """

    def __init__(self, fun: Callable[[float, FloatArray], FloatArray], t0: float,
                 y0: FloatArray, t_bound: float, rtol: float, atol: FloatArray) -> None:
        super().__init__(fun, t0, y0, t_bound, rtol=rtol, atol=atol)
        self.fun = fun
        self.lu = self._factor
        self.solve_lu = _lu_solve

    def _factor(self, matrix: NDArray) -> tuple:
        self.nlu += 1
        getrf = zgetrf if np.iscomplexobj(matrix) else dgetrf
        lu, pivots, info = getrf(matrix, overwrite_a=True)
        if info < 0:
            raise ValueError(f'illegal value in argument {-info} of getrf')
        return lu, pivots, np.iscomplexobj(lu)


def _lu_solve(factors: tuple, rhs: NDArray) -> NDArray:
    lu, pivots, complex_ = factors
    solution, info = (zgetrs if complex_ else dgetrs)(lu, pivots, rhs, overwrite_b=True)
    if info != 0:
        raise ValueError(f'illegal value in argument {-info} of getrs')
    return solution


# scipy's Radau IIA (scipy.integrate._ivp.radau, Hairer & Wanner, Solving ODEs II, IV.8): the
# collocation nodes, the error estimate's weights, the eigenvalues and eigenvectors of the
# method's matrix, the dense output's coefficients, its Newton and step-size constants.
_S6 = 6.0 ** 0.5
_C = ((4.0 - _S6) / 10.0, (4.0 + _S6) / 10.0, 1.0)
_E = ((-13.0 - 7.0 * _S6) / 3.0, (-13.0 + 7.0 * _S6) / 3.0, -1.0 / 3.0)
_MU_REAL = 3.0 + 3.0 ** (2.0 / 3.0) - 3.0 ** (1.0 / 3.0)
_MU_COMPLEX = (3.0 + 0.5 * (3.0 ** (1.0 / 3.0) - 3.0 ** (2.0 / 3.0))
               - 0.5j * (3.0 ** (5.0 / 6.0) + 3.0 ** (7.0 / 6.0)))
_T = ((0.09443876248897524, -0.14125529502095421, 0.03002919410514742),
      (0.25021312296533332, 0.20412935229379994, -0.38294211275726192),
      (1.0, 1.0, 0.0))
_TI = ((4.17871859155190428, 0.32768282076106237, 0.52337644549944951),
       (-4.17871859155190428, -0.32768282076106237, 0.47662355450055044),
       (0.50287263494578682, -2.57192694985560522, 0.59603920482822492))
_TI_COMPLEX = tuple(a + 1j * b for a, b in zip(_TI[1], _TI[2]))
_P = ((13.0 / 3.0 + 7.0 * _S6 / 3.0, -23.0 / 3.0 - 22.0 * _S6 / 3.0, 10.0 / 3.0 + 5.0 * _S6),
      (13.0 / 3.0 - 7.0 * _S6 / 3.0, -23.0 / 3.0 + 22.0 * _S6 / 3.0, 10.0 / 3.0 - 5.0 * _S6),
      (1.0 / 3.0, -8.0 / 3.0, 10.0 / 3.0))
_NEWTON_MAXITER = 6
_MIN_FACTOR = 0.2
_MAX_FACTOR = 10.0
_EPS = float(np.finfo(float).eps)
# scipy's finite-difference Jacobian (scipy.integrate._ivp.common.num_jac): its step control.
_DIFF_REJECT = _EPS ** 0.875
_DIFF_SMALL = _EPS ** 0.75
_DIFF_BIG = _EPS ** 0.25
_MIN_JAC_FACTOR = 1e3 * _EPS


def _predict_factor(h_abs: float, h_abs_old: float | None, error_norm: float,
                    error_norm_old: float | None) -> float:
    """The step-size factor of scipy's Radau (Hairer & Wanner's predictive controller)."""
    if error_norm_old is None or h_abs_old is None or error_norm == 0.0:
        multiplier = 1.0
    else:
        multiplier = h_abs / h_abs_old * (error_norm_old / error_norm) ** 0.25
    if error_norm == 0.0:
        return math.inf
    return min(1.0, multiplier) * error_norm ** -0.25


class ScalarRadauDense:
    """One step's interpolant in the layout of scipy's RadauDenseOutput (one equation)."""

    order = 2

    def __init__(self, t_old: float, t: float, y_old: float, q: tuple[float, ...]) -> None:
        self.t_old, self.t, self.h = t_old, t, t - t_old
        self.y_old = np.array([y_old])
        self.Q = np.array([q])

    def __call__(self, t: float | FloatArray) -> FloatArray:
        """The state at ``t`` (one time or many), as scipy's dense outputs give it."""
        x = (np.asarray(t, dtype=float) - self.t_old) / self.h
        q0, q1, q2 = self.Q[0]
        return np.asarray(q0 * x + q1 * (x * x) + q2 * (x * x * x) + self.y_old[0])[None]


class ScalarRadau:
    """
    scipy's Radau IIA for one equation, on plain floats.

    Two segments joined by one channel without inertance have one state (the base's
    volume; mass gives the tip's), and scipy's Radau spends on that one number far more in
    array handling than in arithmetic. This is its algorithm, line for line (the step,
    the simplified Newton iteration on the collocation system, the error estimate and its
    refinement after a rejection, the predictive step-size control, the finite-difference
    Jacobian and its adaptive increment, the initial step), with the 1 x 1 and complex
    1 x 1 linear systems solved by division. Its sums are not in scipy's order to the last
    bit, and the error estimate (a small difference of large numbers) magnifies that: its
    step sizes leave scipy's by about 1e-8 relative, its results differ from scipy's by
    what the tolerance allows. On the paper pair it takes about a sixth of scipy's time
    (bench/dynamic_results.md).
    ``solver.y``, ``t``, ``status``, ``step()`` and ``dense_output()`` as scipy's solvers.
    """

    TOO_SMALL_STEP = 'Required step size is less than spacing between numbers.'

    def __init__(self, fun: Callable[[float, float], float], t0: float, y0: float,
                 t_bound: float, rtol: float, atol: float) -> None:
        self.fun = fun
        self.t, self._y, self.t_bound = float(t0), float(y0), float(t_bound)
        self.rtol, self.atol = max(float(rtol), 100.0 * _EPS), float(atol)
        self.status = 'running'
        self.f = fun(self.t, self._y)
        self.h_abs = self._initial_step()
        self.h_abs_old: float | None = None
        self.error_norm_old: float | None = None
        self.newton_tol = max(10.0 * _EPS / self.rtol, min(0.03, self.rtol ** 0.5))
        self.sol: tuple[float, float, float, tuple[float, ...]] | None = None
        self.jac_factor: float | None = None
        self.njev = self.nlu = 0
        self.J = self._jacobian(self.t, self._y, self.f)
        self.current_jac = True
        self.lu_real: float | None = None
        self.lu_complex: complex | None = None

    @property
    def y(self) -> FloatArray:
        """The state now, as a one-entry array (as scipy's solvers have it)."""
        return np.array([self._y])

    def dense_output(self) -> ScalarRadauDense:
        """The last step's interpolant."""
        t_old, h, y_old, q = self.sol
        return ScalarRadauDense(t_old, t_old + h, y_old, q)

    def step(self) -> str | None:
        """One step, as scipy's ``OdeSolver.step``: None, or why it failed."""
        if self.t == self.t_bound:
            self.status = 'finished'
            return None
        success, message = self._step_impl()
        if not success:
            self.status = 'failed'
        elif self.t >= self.t_bound:
            self.status = 'finished'
        return message

    def _initial_step(self) -> float:
        """The initial step of scipy (select_initial_step) for one equation, order 3."""
        t0, y0, f0 = self.t, self._y, self.f
        interval = abs(self.t_bound - t0)
        if interval == 0.0:
            return 0.0
        scale = self.atol + abs(y0) * self.rtol
        d0, d1 = abs(y0 / scale), abs(f0 / scale)
        h0 = 1e-6 if d0 < 1e-5 or d1 < 1e-5 else 0.01 * d0 / d1
        h0 = min(h0, interval)
        f1 = self.fun(t0 + h0, y0 + h0 * f0)
        d2 = abs((f1 - f0) / scale) / h0
        if d1 <= 1e-15 and d2 <= 1e-15:
            h1 = max(1e-6, h0 * 1e-3)
        else:
            h1 = (0.01 / max(d1, d2)) ** 0.25
        return min(100.0 * h0, h1, interval)

    def _jacobian(self, t: float, y: float, f: float) -> float:
        """The finite-difference Jacobian of scipy (num_jac) for one equation."""
        self.njev += 1
        factor = _EPS ** 0.5 if self.jac_factor is None else self.jac_factor
        y_scale = (1.0 if f >= 0.0 else -1.0) * max(self.atol, abs(y))
        h = (y + factor * y_scale) - y
        while h == 0.0:
            factor *= 10.0
            h = (y + factor * y_scale) - y
        f_new = self.fun(t, y + h)
        diff = f_new - f
        max_diff = abs(diff)
        scale = max(abs(f), abs(f_new))
        if max_diff < _DIFF_REJECT * scale:
            new_factor = 10.0 * factor
            h_new = (y + new_factor * y_scale) - y
            f_new = self.fun(t, y + h_new)
            diff_new = f_new - f
            max_diff_new = abs(diff_new)
            scale_new = max(abs(f), abs(f_new))
            if max_diff * scale_new < max_diff_new * scale:
                factor, h, diff = new_factor, h_new, diff_new
                scale, max_diff = scale_new, max_diff_new
        jac = diff / h
        if max_diff < _DIFF_SMALL * scale:
            factor *= 10.0
        if max_diff > _DIFF_BIG * scale:
            factor *= 0.1
        self.jac_factor = max(factor, _MIN_JAC_FACTOR)
        return jac

    def _predicted(self, t: float) -> float:
        t_old, h, y_old, (q0, q1, q2) = self.sol
        x = (t - t_old) / h
        return q0 * x + q1 * (x * x) + q2 * (x * x * x) + y_old

    def _collocation(self, t: float, y: float, h: float, z0: tuple[float, float, float],
                     scale: float, lu_real: float, lu_complex: complex
                     ) -> tuple[bool, int, tuple[float, float, float], float | None]:
        """The simplified Newton iteration on the collocation system, as scipy has it."""
        fun, tol = self.fun, self.newton_tol
        m_real, m_complex = _MU_REAL / h, _MU_COMPLEX / h
        (a0, a1, a2), (b0, b1, b2), (c0, c1, c2) = _TI
        w0 = a0 * z0[0] + a1 * z0[1] + a2 * z0[2]
        w1 = b0 * z0[0] + b1 * z0[1] + b2 * z0[2]
        w2 = c0 * z0[0] + c1 * z0[1] + c2 * z0[2]
        z = z0
        ch = (h * _C[0], h * _C[1], h * _C[2])
        k1, k2, k3 = _TI_COMPLEX
        (t00, t01, t02), (t10, t11, t12), _ = _T
        dw_norm_old = None
        rate = None
        converged = False
        k = 0
        for k in range(_NEWTON_MAXITER):
            f0 = fun(t + ch[0], y + z[0])
            f1 = fun(t + ch[1], y + z[1])
            f2 = fun(t + ch[2], y + z[2])
            if not (math.isfinite(f0) and math.isfinite(f1) and math.isfinite(f2)):
                break
            f_real = a0 * f0 + a1 * f1 + a2 * f2 - m_real * w0
            f_complex = k1 * f0 + k2 * f1 + k3 * f2 - m_complex * (w1 + 1j * w2)
            d0 = f_real / lu_real
            d_complex = f_complex / lu_complex
            d1, d2 = d_complex.real, d_complex.imag
            dw_norm = math.sqrt(((d0 / scale) ** 2 + (d1 / scale) ** 2 + (d2 / scale) ** 2)
                                / 3.0)
            if dw_norm_old is not None:
                rate = dw_norm / dw_norm_old
            if rate is not None and (rate >= 1.0 or rate ** (_NEWTON_MAXITER - k)
                                     / (1.0 - rate) * dw_norm > tol):
                break
            w0, w1, w2 = w0 + d0, w1 + d1, w2 + d2
            z = (t00 * w0 + t01 * w1 + t02 * w2, t10 * w0 + t11 * w1 + t12 * w2, w0 + w1)
            if dw_norm == 0.0 or rate is not None and rate / (1.0 - rate) * dw_norm < tol:
                converged = True
                break
            dw_norm_old = dw_norm
        return converged, k + 1, z, rate

    def _step_impl(self) -> tuple[bool, str | None]:
        t, y, f = self.t, self._y, self.f
        rtol, atol = self.rtol, self.atol
        min_step = 10.0 * abs(math.nextafter(t, math.inf) - t)
        if self.h_abs < min_step:
            h_abs, h_abs_old, error_norm_old = min_step, None, None
        else:
            h_abs, h_abs_old, error_norm_old = self.h_abs, self.h_abs_old, self.error_norm_old
        jac, lu_real, lu_complex = self.J, self.lu_real, self.lu_complex
        current_jac = self.current_jac
        rejected = False
        while True:
            if h_abs < min_step:
                return False, self.TOO_SMALL_STEP
            t_new = min(t + h_abs, self.t_bound)
            h = t_new - t
            h_abs = abs(h)
            if self.sol is None:
                z0 = (0.0, 0.0, 0.0)
            else:
                z0 = tuple(self._predicted(t + h * c) - y for c in _C)
            scale = atol + abs(y) * rtol
            converged = False
            while not converged:
                if lu_real is None or lu_complex is None:
                    self.nlu += 2
                    lu_real = _MU_REAL / h - jac
                    lu_complex = _MU_COMPLEX / h - jac
                converged, n_iter, z, rate = self._collocation(t, y, h, z0, scale, lu_real,
                                                               lu_complex)
                if not converged:
                    if current_jac:
                        break
                    jac = self._jacobian(t, y, f)
                    current_jac = True
                    lu_real = lu_complex = None
            if not converged:
                h_abs *= 0.5
                lu_real = lu_complex = None
                continue
            y_new = y + z[2]
            ze = (z[0] * _E[0] + z[1] * _E[1] + z[2] * _E[2]) / h
            error = (f + ze) / lu_real
            scale = atol + max(abs(y), abs(y_new)) * rtol
            error_norm = abs(error / scale)
            safety = 0.9 * (2 * _NEWTON_MAXITER + 1) / (2 * _NEWTON_MAXITER + n_iter)
            if rejected and error_norm > 1.0:
                error = (self.fun(t, y + error) + ze) / lu_real
                error_norm = abs(error / scale)
            if error_norm > 1.0:
                factor = _predict_factor(h_abs, h_abs_old, error_norm, error_norm_old)
                h_abs *= max(_MIN_FACTOR, safety * factor)
                lu_real = lu_complex = None
                rejected = True
            else:
                break
        recompute_jac = n_iter > 2 and rate > 1e-3
        factor = min(_MAX_FACTOR, safety * _predict_factor(h_abs, h_abs_old, error_norm,
                                                           error_norm_old))
        if not recompute_jac and factor < 1.2:
            factor = 1.0
        else:
            lu_real = lu_complex = None
        f_new = self.fun(t_new, y_new)
        if recompute_jac:
            jac = self._jacobian(t_new, y_new, f_new)
            current_jac = True
        else:
            current_jac = False
        self.h_abs_old = self.h_abs
        self.error_norm_old = error_norm
        self.h_abs = h_abs * factor
        self.t, self._y, self.f = t_new, y_new, f_new
        self.lu_real, self.lu_complex = lu_real, lu_complex
        self.current_jac, self.J = current_jac, jac
        # The dense output's cubic: Q = Z^T P.
        self.sol = (t, h, y, tuple(z[0] * _P[0][m] + z[1] * _P[1][m] + z[2] * _P[2][m]
                                   for m in range(3)))
        return True, None


class StepInterpolant:
    """
    The solver's dense output of one step, evaluated at one instant at a time.

    scipy's generic call checks and reshapes its argument on every call, which costs more
    than the cubic itself; the rig asks for one instant per output. Radau's interpolant is
    y_old + Q [x, x^2, x^3], x = (t - t_old) / h, evaluated here on plain floats (the same
    terms, summed in another order: equal to round-off). Another interpolant is called as it
    is.
    """

    def __init__(self, dense: DenseOutput) -> None:
        self.dense = dense
        self.fast = all(hasattr(dense, name) for name in ('t_old', 'h', 'Q', 'order', 'y_old'))
        if self.fast:
            # Plain floats: a network's state has a handful of entries.
            self.rows = dense.Q.tolist()
            self.start = dense.y_old.tolist()

    def __call__(self, t: float) -> FloatArray:
        """The state at ``t``."""
        if not self.fast:
            return self.dense(t)
        return np.array(self.at(t))

    def at(self, t: float) -> list[float]:
        """The state at ``t`` as plain floats (the numbers a call gives)."""
        dense = self.dense
        if not self.fast:
            return np.asarray(dense(t), dtype=float).tolist()
        x = (t - dense.t_old) / dense.h
        powers = [x]
        for _ in range(dense.order):
            powers.append(powers[-1] * x)
        return [start + sum(q * p for q, p in zip(row, powers))
                for start, row in zip(self.start, self.rows)]

    def many(self, times: FloatArray) -> FloatArray:
        """The state at each of ``times`` (rows): the same operations as a call, per time."""
        dense = self.dense
        if not self.fast:
            return np.asarray(dense(times), dtype=float).T.reshape(times.size, -1)
        x = (times - dense.t_old) / dense.h
        power = x
        total = np.multiply.outer(x, dense.Q[:, 0])
        for m in range(1, dense.order + 1):
            power = power * x
            total = total + np.multiply.outer(power, dense.Q[:, m])
        return dense.y_old + total


# What the network steps with: scipy's Radau (LeanRadau is one) or the scalar port.
Integrator = Radau | ScalarRadau


def new_integrator(method: str, rates: Callable[[float, FloatArray], FloatArray],
                   rate_of_one: Callable[[float, float], float], t0: float, y0: FloatArray,
                   t_bound: float, rtol: float, atol: FloatArray) -> Integrator:
    """
    The integrator ``method`` (one of METHODS) names, for the state ``y0`` from ``t0``.

    'radau': :class:`ScalarRadau` on ``rate_of_one`` (the rate of a state of one entry, on a
    float) when ``y0`` has one entry, :class:`LeanRadau` on ``rates`` otherwise;
    'scipy-radau': scipy's Radau on ``rates``.
    """
    if method not in METHODS:
        raise ValueError(f'method must be one of {", ".join(METHODS)}, got {method!r}')
    if method == 'scipy-radau':
        return Radau(rates, t0, y0, t_bound, rtol=rtol, atol=atol)
    if y0.size == 1:
        return ScalarRadau(rate_of_one, t0, float(y0[0]), t_bound, rtol, float(atol[0]))
    return LeanRadau(rates, t0, y0, t_bound, rtol, atol)
