"""
A slow, simple reference for quasi-static volume sharing between inflatable segments.

It shares no code with softseq_ros.quasistatic.equilibrium and asks the segments for nothing but
``pressure(v)``, ``rest_volume`` and ``max_volume``: stored energies come from its own Simpson
tables of the pressure, and the state follows the history by discrete steepest descent of the
total energy E(v) = sum_i E_i(v_i) on the plane sum_i v_i = V, starting from the previous state.

How a snap-through is recognised: a commanded step whose descent moves the volumes by more than
``jump_fraction`` of the volume scale is bisected; if the move stays that large when the step has
shrunk to ``min_step_fraction`` of the scale, the old energy well has vanished (a fold) and the
move is recorded as a snap. A continuous but steep change (a pitchfork, the approach to a fold)
shrinks with the step and is not recorded.

Accuracy: the stable state is polished to round-off (brentq on p1 - p2 for two segments, a
root solve for more); the volume at which a snap is recorded is within about
``(step_fraction)**2`` of the scale of the fold (the lattice can see over a well narrower than
one lattice step) plus ``min_step_fraction`` of the scale.
"""

from dataclasses import dataclass
from itertools import permutations

import numpy as np
from scipy.optimize import brentq, root


@dataclass
class ReferenceSnap:
    """A snap-through seen by the reference: where (injected volume) and between which states."""

    injected: float
    from_volumes: np.ndarray
    to_volumes: np.ndarray
    row: int = -1


@dataclass
class ReferencePath:
    """States of the reference along a commanded history."""

    injected: np.ndarray
    volumes: np.ndarray
    pressure: np.ndarray
    events: list


class EnergyTable:
    """E(v) = integral of p from the rest volume, by composite Simpson on a fine table."""

    def __init__(self, segment, points: int = 20001) -> None:
        self.segment = segment
        self.rest = float(segment.rest_volume)
        self.top = float(segment.max_volume)
        self.v = np.linspace(self.rest, self.top, points)
        self.h = self.v[1] - self.v[0]
        p = np.asarray(segment.pressure(self.v), dtype=float)
        p_mid = np.asarray(segment.pressure(self.v[:-1] + 0.5 * self.h), dtype=float)
        pieces = self.h / 6.0 * (p[:-1] + 4.0 * p_mid + p[1:])
        self.e = np.concatenate([[0.0], np.cumsum(pieces)])

    def __call__(self, v) -> np.ndarray:
        """Energy at volumes v: the table up to the node below, then one Simpson panel."""
        v = np.asarray(v, dtype=float)
        j = np.clip(((v - self.rest) / self.h).astype(int), 0, len(self.v) - 2)
        vj = self.v[j]
        # One call for the three Simpson nodes of every panel: the segment's per-call cost
        # dominates the reference's run time.
        flat_vj, flat_v = np.ravel(vj), np.ravel(v)
        p = np.asarray(self.segment.pressure(
            np.concatenate([flat_vj, 0.5 * (flat_vj + flat_v), flat_v])), dtype=float)
        p_j, p_mid, p_v = p.reshape(3, -1)
        panel = (flat_v - flat_vj) / 6.0 * (p_j + 4.0 * p_mid + p_v)
        return (np.ravel(self.e[j]) + panel).reshape(v.shape)


class ReferenceTracker:
    """History-following equilibrium of N segments sharing one incompressible fluid volume."""

    def __init__(self, segments, step_fraction: float = 1e-4, jump_fraction: float = 5e-2,
                 min_step_fraction: float = 1e-11, table_points: int = 20001) -> None:
        self.segments = list(segments)
        self.n = len(self.segments)
        if self.n < 2:
            raise ValueError('the reference needs at least two segments')
        self.rest = np.array([s.rest_volume for s in self.segments], dtype=float)
        self.top = np.array([s.max_volume for s in self.segments], dtype=float)
        self.tables = [EnergyTable(s, table_points) for s in self.segments]
        span = self.top - self.rest
        self.scale = float(span.sum())
        self.lattice_step = step_fraction * float(span.min())
        self.jump_tolerance = jump_fraction * float(span.min())
        self.min_step = min_step_fraction * self.scale
        self.directions = []
        for i, j in permutations(range(self.n), 2):
            d = np.zeros(self.n)
            d[i], d[j] = 1.0, -1.0
            self.directions.append(d)
        self.directions = np.array(self.directions)
        self.volumes = self.rest.copy()
        self.injected = 0.0
        self._step = self.scale
        self.events: list[ReferenceSnap] = []

    @property
    def injected_range(self) -> tuple[float, float]:
        """Smallest and largest injected volume the segments can hold, in m^3."""
        return 0.0, float((self.top - self.rest).sum())

    def energy(self, volumes) -> np.ndarray:
        """Total stored energy of states (..., N), from the reference's own tables."""
        volumes = np.asarray(volumes, dtype=float)
        return sum(t(volumes[..., i]) for i, t in enumerate(self.tables))

    def pressures(self, volumes) -> np.ndarray:
        """Pressure of every segment at the given volumes (N,)."""
        return np.array([float(s.pressure(v)) for s, v in zip(self.segments, volumes)])

    # --- one commanded step --------------------------------------------------------------

    def _project(self, x: np.ndarray, total: float) -> np.ndarray:
        """Put x into the box [rest, top] with sum(x) = total, moving free entries equally."""
        x = np.clip(x, self.rest, self.top)
        for _ in range(4 * self.n):
            residual = total - x.sum()
            if abs(residual) <= 1e-15 * self.scale:
                break
            free = (x < self.top) if residual > 0 else (x > self.rest)
            x = np.clip(x + residual * free / max(free.sum(), 1), self.rest, self.top)
        return x

    def _descend(self, x: np.ndarray, total: float, limit: float = np.inf,
                 refine: float = 1.0) -> tuple[np.ndarray, float, bool]:
        """
        Discrete steepest descent on the lattice x + h (e_i - e_j); returns (x, h, finished).

        Gives up (finished False) once the walk has gone further than ``limit`` from its start.
        """
        origin = x
        slack = min(total - self.rest.sum(), self.top.sum() - total)
        h = min(self.lattice_step, 0.25 * slack) * refine
        if h <= 1e-14 * self.scale:
            return x, h, True
        e0 = float(self.energy(x))
        ray = np.arange(1, 65, dtype=float)[:, None]
        while True:
            cand = x + h * self.directions
            ok = np.all((cand >= self.rest) & (cand <= self.top), axis=1)
            if not ok.any():
                return x, h, True
            dirs = self.directions[ok]
            e = self.energy(cand[ok])
            k = int(np.argmin(e))
            if not e[k] < e0:
                return x, h, True
            if np.abs(x - origin).max() > limit:
                return x, h, False
            # Keep going along the steepest direction while the energy keeps falling: the first
            # lattice minimum on that ray, exactly what repeated single moves would reach.
            d = dirs[k]
            while True:
                pts = x + h * ray * d
                inside = np.all((pts >= self.rest) & (pts <= self.top), axis=1)
                n_in = int(np.argmin(inside)) if not inside.all() else len(pts)
                if n_in == 0:
                    break
                e_ray = np.concatenate([[e0], self.energy(pts[:n_in])])
                rising = np.nonzero(np.diff(e_ray) >= 0.0)[0]
                stop = int(rising[0]) if len(rising) else n_in
                if stop > 0:
                    x, e0 = pts[stop - 1], float(e_ray[stop])
                if len(rising) or n_in < len(pts):
                    break

    def _polish_two(self, x: np.ndarray, total: float, h: float) -> np.ndarray:
        s1, s2 = self.segments
        lo = max(self.rest[0], total - self.top[1])
        hi = min(self.top[0], total - self.rest[1])

        def gap(v1):
            return s1.pressure(v1) - s2.pressure(total - v1)

        def root_in(a: float, b: float) -> float:
            ga, gb = float(gap(a)), float(gap(b))
            if ga == 0.0 or gb == 0.0:
                return a if ga == 0.0 else b
            return brentq(lambda v: float(gap(v)), a, b, xtol=1e-15 * self.scale, maxiter=200)

        x1 = float(np.clip(x[0], lo, hi))
        a, b = max(lo, x1 - h), min(hi, x1 + h)
        ga, gx, gb = (float(gap(v)) for v in (a, x1, b))
        if ga <= 0.0 <= gx and a < x1:
            v1 = root_in(a, x1)
        elif gx <= 0.0 <= gb and x1 < b:
            v1 = root_in(x1, b)
        else:
            # Near a fold the Simpson energies cannot resolve the last shallow slope; follow
            # the exact gradient p1 - p2 downhill instead until it vanishes or a bound holds.
            direction = -np.sign(gx)
            v1 = x1
            while direction != 0.0:
                pts = np.clip(v1 + direction * h * np.arange(1, 257), lo, hi)
                g = gap(pts)
                flip = np.nonzero(np.sign(g) != np.sign(gx))[0]
                if len(flip):
                    k = int(flip[0])
                    v1 = root_in(v1 if k == 0 else float(pts[k - 1]), float(pts[k]))
                    break
                v1 = float(pts[-1])
                if v1 in (lo, hi):
                    break
        return np.array([v1, total - v1])

    def _polish_many(self, x: np.ndarray, total: float, h: float) -> np.ndarray:
        if h <= 1e-14 * self.scale:
            return x
        # A shallow well next to a fold can defeat the root solve from a coarse lattice point:
        # descend again on finer lattices before giving up.
        for refine in (1.0, 1e-1, 1e-2, 1e-3):
            if refine < 1.0:
                x, h, _ = self._descend(x, total, refine=refine)
            v = self._root_many(x, total, h)
            if v is not None:
                return v
        raise RuntimeError(f'reference: polishing failed near {x} at V={total}')

    def _root_many(self, x: np.ndarray, total: float, h: float) -> np.ndarray | None:

        def gaps(y: np.ndarray) -> np.ndarray:
            v = np.append(y, total - y.sum())
            p = self.pressures(v)
            return (p[:-1] - p[-1]) / max(abs(p).max(), 1.0)

        sol = root(gaps, x[:-1], method='hybr', options={'xtol': 1e-14})
        v = np.append(sol.x, total - sol.x.sum())
        # hybr reports failure when xtol cannot be met at round-off; judge by the residual.
        converged = sol.success or float(np.abs(gaps(sol.x)).max()) <= 1e-11
        if converged and np.abs(v - x).max() <= 4.0 * h and np.all(v >= self.rest) \
                and np.all(v <= self.top):
            return v
        return None

    def _relax(self, x_old: np.ndarray, total: float, limit: float = np.inf) -> np.ndarray:
        start = self._project(x_old + (total - x_old.sum()) / self.n, total)
        x, h, finished = self._descend(start, total, limit)
        if not finished:
            return x
        if self.n != 2:
            return self._polish_many(x, total, h)
        x = self._polish_two(x, total, h)
        if np.abs(x - x_old).max() > self.jump_tolerance and h > 0.0:
            # Before calling it a snap, look for a well narrower than one lattice step next to
            # the start (the last moments of a branch before its fold): p1 - p2 crossing zero
            # upwards, resolved to a thousandth of a lattice step.
            s1, s2 = self.segments
            lo = max(self.rest[0], total - self.top[1])
            hi = min(self.top[0], total - self.rest[1])
            pts = np.clip(start[0] + np.linspace(-2.0 * h, 2.0 * h, 4001), lo, hi)
            g = s1.pressure(pts) - s2.pressure(total - pts)
            up = np.nonzero((g[:-1] < 0.0) & (g[1:] >= 0.0))[0]
            if len(up):
                k = int(up[np.argmin(np.abs(pts[up] - start[0]))])
                v1 = brentq(lambda v: float(s1.pressure(v) - s2.pressure(total - v)),
                            pts[k], pts[k + 1], xtol=1e-15 * self.scale)
                x = np.array([v1, total - v1])
        return x

    def go_to(self, injected: float) -> list[ReferenceSnap]:
        """Move the commanded injected volume to ``injected``; return the snaps on the way."""
        lo, hi = self.injected_range
        if not lo <= injected <= hi:
            raise ValueError(f'injected volume {injected} outside [{lo}, {hi}]')
        base = self.rest.sum()
        new_events = []
        step = max(self._step, self.min_step)
        while self.injected != injected:
            remaining = injected - self.injected
            if abs(remaining) <= step:
                target = injected
            else:
                target = self.injected + np.sign(remaining) * step
            # Walks longer than a snap would be are cut short unless the step is already at
            # its floor: they only say that the step must be halved.
            final = abs(target - self.injected) <= self.min_step
            x = self._relax(self.volumes, base + target,
                            np.inf if final else 2.0 * self.jump_tolerance)
            jump = float(np.abs(x - self.volumes).max())
            if jump <= self.jump_tolerance or final:
                if jump > self.jump_tolerance:
                    new_events.append(ReferenceSnap(target, self.volumes.copy(), x.copy()))
                self.volumes, self.injected = x, target
                step = min(2.0 * step, self.scale)
            else:
                # Too large a move for one step: halve it until the move shrinks with the step
                # (a steep but continuous branch) or the step is negligible (a snap-through).
                step = 0.5 * abs(target - self.injected)
        self._step = step
        self.events.extend(new_events)
        return new_events

    def sweep(self, injected) -> ReferencePath:
        """Visit every commanded injected volume in order; states after each."""
        injected = np.asarray(injected, dtype=float)
        vols = np.empty((len(injected), self.n))
        press = np.empty(len(injected))
        events = []
        for k, u in enumerate(injected):
            for event in self.go_to(float(u)):
                event.row = k
                events.append(event)
            vols[k] = self.volumes
            press[k] = float(self.segments[0].pressure(self.volumes[0]))
        return ReferencePath(injected, vols, press, events)


def two_segment_equilibria(segments, injected: float, points: int = 200001) -> list[tuple]:
    """
    Every equilibrium of two segments at one injected volume, by sign changes of p1 - p2.

    Returns (v1, v2, stable) tuples; stable when p1 - p2 crosses zero upwards (an energy minimum).
    """
    s1, s2 = segments
    total = s1.rest_volume + s2.rest_volume + injected
    lo = max(s1.rest_volume, total - s2.max_volume)
    hi = min(s1.max_volume, total - s2.rest_volume)
    v1 = np.linspace(lo, hi, points)
    gap = s1.pressure(v1) - s2.pressure(total - v1)
    out = []
    for k in np.nonzero(np.sign(gap[:-1]) != np.sign(gap[1:]))[0]:
        r = brentq(lambda x: float(s1.pressure(x) - s2.pressure(total - x)), v1[k], v1[k + 1],
                   xtol=1e-15 * total)
        out.append((r, total - r, bool(gap[k + 1] > gap[k])))
    return out
