"""
Independent solvers the benchmark measures softseq_ros.quasistatic.equilibrium against.

None of them imports the equilibrium module; they ask the segments for ``pressure(v)``,
``stiffness(v)``, ``rest_volume`` and ``max_volume`` only.

- :class:`NaiveTracker`: the obvious way to follow a history, one root solve per command,
  starting from the previous state. Two segments: walk downhill on E(v1) = E1(v1) + E2(V - v1)
  in small fixed steps until p1 - p2 changes sign, then brentq to ``xtol``. More segments:
  ``scipy.optimize.root`` on the equilibrium equations from the previous state, with a gradient
  flow (LSODA) when the root is unstable or far away (a snap-through).
- :func:`dynamic_path`: segments exchanging fluid with the pump's manifold through equal small
  resistances, integrated with a stiff solver (Radau with the exact Jacobian). ``slowness`` is
  the pressure drop across one resistance at the pump's flow rate, in units of the pressure
  scale: the quasi-static path is its limit as ``slowness`` goes to 0.
- :func:`fold_totals_pair`: the total volumes at which the equilibrium set of two segments folds
  (p1' + p2' = 0 on p1(v1) = p2(v2)), by dense scanning and brentq: the exact snap volumes.
- :func:`polish_states`: Newton on the bordered equilibrium system to round-off, batched.
- :func:`interp_floor`: ``numpy.interp`` of every output column, the cost floor of a lookup.
"""

import math
from typing import Sequence

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import brentq, root


class OutOfRangeError(ValueError):
    """A command the naive tracker cannot follow (a segment would leave its model's range)."""


def _pressures(segments, volumes: np.ndarray) -> np.ndarray:
    return np.stack([s.pressure(volumes[..., i]) for i, s in enumerate(segments)], axis=-1)


def _stiffnesses(segments, volumes: np.ndarray) -> np.ndarray:
    return np.stack([s.stiffness(volumes[..., i]) for i, s in enumerate(segments)], axis=-1)


def restricted_hessian_min(stiffness: np.ndarray) -> np.ndarray:
    """Smallest eigenvalue of diag(k) restricted to sum(dv) = 0, row by row."""
    k = np.atleast_2d(stiffness)
    n = k.shape[1]
    basis = np.linalg.qr(np.eye(n) - 1.0 / n)[0][:, : n - 1]
    hessians = np.einsum('ia,ni,ib->nab', basis, k, basis)
    return np.linalg.eigvalsh(hessians)[:, 0]


class NaiveTracker:
    """One root solve per command, starting from the previous state."""

    def __init__(self, segments: Sequence, xtol_fraction: float = 1e-13,
                 walk_fraction: float = 1e-3) -> None:
        self.segments = list(segments)
        self.rest = np.array([s.rest_volume for s in segments])
        self.top = np.array([s.max_volume for s in segments])
        self.v_scale = float(np.sum(self.top - self.rest))
        self.p_scale = max(float(np.max(np.abs(s.pressure(np.linspace(s.rest_volume,
                                                                        s.max_volume, 257)))))
                           for s in segments) or 1.0
        self.xtol = xtol_fraction * self.v_scale
        self.walk = walk_fraction * self.v_scale
        self.volumes = self.rest.copy()
        self.snaps: list[float] = []

    @property
    def injected(self) -> float:
        return float(self.volumes.sum() - self.rest.sum())

    def step(self, injected: float) -> np.ndarray:
        total = injected + float(self.rest.sum())
        if len(self.segments) == 2:
            self.volumes = self._step_pair(total)
        else:
            self.volumes = self._step_many(total)
        return self.volumes

    def sweep(self, injected: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        volumes = np.empty((len(injected), len(self.segments)))
        for row, u in enumerate(injected):
            volumes[row] = self.step(float(u))
        pressure = _pressures(self.segments, volumes).mean(axis=1)
        return volumes, pressure

    # -------------------------------------------------------------- two segments
    def _step_pair(self, total: float) -> np.ndarray:
        a, b = self.segments

        def excess(v1: float) -> float:
            # dE/dv1 on the line v1 + v2 = total: positive means v1 should shrink.
            return float(a.pressure(v1) - b.pressure(total - v1))

        lo = max(a.rest_volume, total - b.max_volume)
        hi = min(a.max_volume, total - b.rest_volume)
        if lo > hi + 1e-12 * self.v_scale:
            raise OutOfRangeError(f'total volume {total:.6g} m^3 outside what the segments hold')
        hi = max(hi, lo)
        x = min(max(float(self.volumes[0]), lo), hi)
        fx = excess(x)
        if fx == 0.0:
            return np.array([x, total - x])
        direction = -math.copysign(1.0, fx)
        start = x
        while True:
            y = x + direction * self.walk
            y = min(max(y, lo), hi)
            fy = excess(y)
            if fy == 0.0:
                x = y
                break
            if math.copysign(1.0, fy) != math.copysign(1.0, fx):
                x = brentq(excess, min(x, y), max(x, y), xtol=self.xtol, rtol=1e-15)
                break
            if y in (lo, hi):
                raise OutOfRangeError(f'total volume {total:.6g} m^3: no stable state before a '
                                 'segment leaves its range')
            x, fx = y, fy
        if abs(x - start) > 2.0 * self.walk:
            self.snaps.append(total - float(self.rest.sum()))
        return np.array([x, total - x])

    # -------------------------------------------------------------- N segments
    def _equations(self, v: np.ndarray, total: float) -> np.ndarray:
        p = _pressures(self.segments, v)
        return np.concatenate([(p[:-1] - p[-1]) / self.p_scale,
                               [(v.sum() - total) / self.v_scale]])

    def _jacobian(self, v: np.ndarray, total: float) -> np.ndarray:
        k = _stiffnesses(self.segments, v) / self.p_scale
        n = v.size
        jac = np.zeros((n, n))
        jac[np.arange(n - 1), np.arange(n - 1)] = k[:-1]
        jac[: n - 1, n - 1] = -k[-1]
        jac[n - 1, :] = 1.0 / self.v_scale
        return jac

    def _solve(self, start: np.ndarray, total: float) -> tuple[np.ndarray, bool]:
        sol = root(self._equations, start, args=(total,), jac=self._jacobian, method='hybr',
                   options={'xtol': 1e-14})
        # hybr reports 'no further improvement' at round-off: judge by the residual instead.
        converged = bool(np.max(np.abs(self._equations(sol.x, total))) < 1e-11)
        return sol.x, converged

    def _stable(self, v: np.ndarray) -> bool:
        k = _stiffnesses(self.segments, v) * self.v_scale / self.p_scale
        return bool(restricted_hessian_min(k)[0] > -1e-9)

    def _step_many(self, total: float) -> np.ndarray:
        previous = self.volumes
        start = np.clip(previous + (total - previous.sum()) / previous.size, self.rest, self.top)
        v, converged = self._solve(start, total)
        inside = np.all(v >= self.rest - self.xtol) and np.all(v <= self.top + self.xtol)
        moved = float(np.max(np.abs(v - start)))
        if converged and inside and moved <= 2.0 * self.walk and self._stable(v):
            return v
        landed = flow_to_rest(self.segments, start, self.v_scale, self.p_scale)
        v, converged = self._solve(landed, total)
        if not converged or not self._stable(v):
            raise OutOfRangeError(f'total volume {total:.6g} m^3: no stable state found')
        self.snaps.append(total - float(self.rest.sum()))
        return v


def flow_to_rest(segments, start: np.ndarray, v_scale: float, p_scale: float) -> np.ndarray:
    """Integrate dv_i/dt = -(p_i - mean p) (equal conductances) until the flow stops."""
    rest = np.array([s.rest_volume for s in segments])
    top = np.array([s.max_volume for s in segments])

    def rhs(_t, y):
        v = np.clip(y * v_scale, rest, top)
        p = _pressures(segments, v) / p_scale
        return -(p - p.mean())

    y, t = start / v_scale, 0.0
    for horizon in np.logspace(0, 12, 25):
        sol = solve_ivp(rhs, (t, horizon), y, method='LSODA', rtol=1e-11, atol=1e-15)
        y, t = sol.y[:, -1], horizon
        if np.max(np.abs(rhs(t, y))) < 1e-12:
            break
    return np.clip(y * v_scale, rest, top)


def polish_states(segments, volumes: np.ndarray, totals: np.ndarray,
                  iterations: int = 6) -> np.ndarray:
    """
    Newton on p_i(v_i) = p, sum v_i = V, batched over rows, from nearby states.

    A row whose Newton step would move it by more than 1e-4 of the volume scale (the system is
    singular at a fold) keeps its previous iterate.
    """
    v = np.array(volumes, dtype=float)
    n = v.shape[1]
    v_scale = float(sum(s.max_volume - s.rest_volume for s in segments))
    for _ in range(iterations):
        p = _pressures(segments, v)
        k = _stiffnesses(segments, v)
        # Unknowns dv (n) and dp: k_i dv_i - dp = -(p_i - 0), sum dv = V - sum v, bordered.
        a = np.zeros((v.shape[0], n + 1, n + 1))
        a[:, np.arange(n), np.arange(n)] = k
        a[:, :n, n] = -1.0
        a[:, n, :n] = 1.0
        rhs = np.concatenate([-(p - p.mean(axis=1, keepdims=True)),
                              (totals - v.sum(axis=1))[:, None]], axis=1)
        with np.errstate(all='ignore'):
            ok = np.abs(np.linalg.det(a)) > 0.0
            step = np.zeros_like(rhs)
            if ok.any():
                step[ok] = np.linalg.solve(a[ok], rhs[ok][..., None])[..., 0]
        dv = step[:, :n]
        good = ok & np.all(np.isfinite(dv), axis=1) & (np.max(np.abs(dv), axis=1)
                                                          <= 1e-4 * v_scale)
        v[good] += dv[good]
    return v


def fold_totals_pair(seg_a, seg_b, samples: int = 40001) -> np.ndarray:
    """
    Total volumes where the equilibrium set of two segments folds (p_a' + p_b' = 0).

    Every v_a on a dense grid is paired with each v_b on each monotone stretch of p_b that has the
    same pressure (vectorised bisection); sign changes of p_a' + p_b' along the pairs are refined
    by brentq on v_a. Returns the sorted fold totals (m^3).
    """
    grid_b = np.linspace(seg_b.rest_volume, seg_b.max_volume, 200001)
    slope_sign = np.sign(np.diff(seg_b.pressure(grid_b)))
    edges = [0] + [i + 1 for i in range(slope_sign.size - 1)
                   if slope_sign[i] != slope_sign[i + 1] and slope_sign[i + 1] != 0.0
                   and slope_sign[i] != 0.0] + [grid_b.size - 1]
    stretches = [(grid_b[i], grid_b[j]) for i, j in zip(edges[:-1], edges[1:])]
    v_a = np.linspace(seg_a.rest_volume, seg_a.max_volume, samples)
    folds = []
    for lo, hi in stretches:
        p_lo, p_hi = float(seg_b.pressure(lo)), float(seg_b.pressure(hi))
        rising = p_hi > p_lo

        def partner(p, lo=lo, hi=hi, rising=rising):
            left = np.full(np.shape(p), lo)
            right = np.full(np.shape(p), hi)
            for _ in range(80):
                mid = 0.5 * (left + right)
                above = (seg_b.pressure(mid) > p) == rising
                right = np.where(above, mid, right)
                left = np.where(above, left, mid)
            return 0.5 * (left + right)

        p_a = seg_a.pressure(v_a)
        inside = (p_a >= min(p_lo, p_hi)) & (p_a <= max(p_lo, p_hi))
        if inside.sum() < 2:
            continue
        xs = v_a[inside]
        vb = partner(seg_a.pressure(xs))
        g = seg_a.stiffness(xs) + seg_b.stiffness(vb)
        contiguous = np.diff(np.flatnonzero(inside)) == 1
        for i in np.flatnonzero((np.sign(g[:-1]) * np.sign(g[1:]) < 0) & contiguous):
            def stability(x):
                return float(seg_a.stiffness(x) + seg_b.stiffness(partner(seg_a.pressure(x))))
            x = brentq(stability, xs[i], xs[i + 1], xtol=1e-15 * seg_a.max_volume, rtol=1e-15)
            folds.append(x + float(partner(seg_a.pressure(x))))
    return np.sort(np.array(folds))


def dynamic_path(segments, injected: np.ndarray, slowness: float, p_scale: float,
                 start: np.ndarray | None = None, method: str = 'Radau',
                 rtol: float = 1e-8) -> np.ndarray:
    """
    Volumes along a history driven at a constant pump rate through small resistances.

    With resistance R between the manifold and each segment and pump flow Q, the segments obey
    dv_i/dt = Q/N + (mean p - p_i)/R. With the injected volume s as the clock (ds = |Q| dt) that
    is dv_i/ds = sign/N + (mean p - p_i) / (slowness p_scale), slowness = |Q| R / p_scale.
    ``injected`` must be a piecewise-monotone history of commands; the returned volumes are the
    states when the pump has delivered each command.
    """
    rest = np.array([s.rest_volume for s in segments])
    top = np.array([s.max_volume for s in segments])
    n = len(segments)
    u = np.asarray(injected, dtype=float)
    clock = np.concatenate([[0.0], np.cumsum(np.abs(np.diff(u)))])
    gain = 1.0 / (slowness * p_scale)

    def direction(s):
        i = min(max(int(np.searchsorted(clock, s, side='right')) - 1, 0), u.size - 2)
        return math.copysign(1.0, u[i + 1] - u[i]) if u[i + 1] != u[i] else 0.0

    def rhs(s, v):
        p = _pressures(segments, np.clip(v, rest, top))
        return direction(s) / n + (p.mean() - p) * gain

    def jac(_s, v):
        k = _stiffnesses(segments, np.clip(v, rest, top))
        return (np.tile(k / n, (n, 1)) - np.diag(k)) * gain

    # Without a start the history must begin at rest (injected 0).
    v0 = rest.copy() if start is None else np.asarray(start, dtype=float)
    # Each monotone leg is integrated on its own, so the clock's kinks fall on step ends.
    turns = [0] + [i for i in range(1, u.size - 1)
                   if (u[i] - u[i - 1]) * (u[i + 1] - u[i]) < 0.0] + [u.size - 1]
    out = np.empty((u.size, n))
    out[0] = v0
    v = v0
    for a, b in zip(turns[:-1], turns[1:]):
        sol = solve_ivp(rhs, (clock[a], clock[b]), v, method=method, jac=jac,
                        t_eval=clock[a:b + 1], rtol=rtol,
                        atol=rtol * 1e-3 * float(np.sum(top - rest)))
        if not sol.success:
            raise RuntimeError(f'dynamic reference failed: {sol.message}')
        out[a:b + 1] = sol.y.T
        v = sol.y[:, -1]
    return out


def interp_floor(tables: list[tuple[np.ndarray, np.ndarray]], queries: np.ndarray) -> list:
    """``numpy.interp`` of each (x, y) table at ``queries``: the floor of a table lookup."""
    return [np.interp(queries, x, y) for x, y in tables]
