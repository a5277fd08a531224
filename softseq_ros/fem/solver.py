"""
Volume-controlled quasi-static inflation: a bordered Newton method on felupe's solid.

The cavity is filled with an incompressible fluid whose volume is prescribed; the gauge pressure
p is the Lagrange multiplier of that constraint (as Abaqus' ``*FLUID CAVITY`` with a
``*FLUID FLUX``). At each volume V* the solver finds q (reduced coordinates, see
:mod:`softseq_ros.fem.constraints`) and p with

    R(q, p) = J^T (f_int(x) - p dV/dx) = 0        C(q) = V(x) - V* = 0

by Newton's method on the bordered system [[A, -b], [-b^T, 0]] [dq, dp] = [-R, C], where
A = J^T (K - p d2V/dx2) J + (second-order term of the map) and b = J^T dV/dx. The bordered matrix
stays regular at a pressure peak, where A alone is singular and pressure control stops.

Where the volume itself turns back along the path (a snap-back: a membrane of several on one
cavity bulges while the others shrink back, and the fluid they give up is more than it takes),
volume control is singular in turn. :meth:`InflationModel.trace_path` then follows the path by
its arc length over the whole state (pseudo-arc-length continuation): the volume becomes an
unknown and one more row [t_q, t_p, t_V] keeps each step a given distance along the last secant
of (displacements, pressure, volume), so the path goes on through both kinds of turning point,
and through the exchange of fluid between membranes at almost constant volume and pressure.

felupe's nearly-incompressible solid updates its cell-wise pressure and dilatation each time it
is handed the field: the vector is assembled with the field exactly once per iteration and the
matrix without it, which keeps the tangent consistent (quadratic convergence).
"""

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
from numpy.typing import NDArray
import scipy.sparse as sp

from softseq_ros.fem.cavity import Cavity
from softseq_ros.fem.constraints import ReducedSpace
from softseq_ros.fem.ordering import SparseSolver


class ConvergenceError(RuntimeError):
    """Newton's method did not converge for one load level."""


@dataclass
class State:
    """One converged equilibrium: volume [m^3], gauge pressure [Pa], reduced coordinates."""

    volume: float
    pressure: float
    q: NDArray[np.float64]
    iterations: int = 0


@dataclass
class PathResult:
    """Converged states along the volume ramp, and why the ramp ended."""

    states: list[State] = field(default_factory=list)
    stop_reason: str = 'reached the requested volume'
    newton_iterations: int = 0

    @property
    def volume_turns(self) -> list[int]:
        """Indices of states where the volume stops growing and turns back (snap-backs)."""
        v = np.array([state.volume for state in self.states])
        return [i for i in range(1, v.size - 1) if v[i] > v[i - 1] and v[i + 1] < v[i]]


class InflationModel:
    """
    A felupe solid with a fluid cavity and symmetry constraints, solved by volume control.

    ``solid`` is a felupe ``SolidBodyNearlyIncompressible`` on ``field`` (a FieldContainer with
    one displacement field); ``force_scale`` [N] sets the residual tolerance (shear modulus times
    a length squared of the model).
    """

    # Path following: the cosine of the largest turn of the path within one step (about 37 deg).
    MAX_TURN_COSINE = 0.8

    def __init__(self, solid: Any, field: Any, space: ReducedSpace, cavity: Cavity,
                 force_scale: float, length_scale: float) -> None:
        self.solid = solid
        self.field = field
        self.space = space
        self.cavity = cavity
        self.force_scale = force_scale
        self.length_scale = length_scale
        self.reference = space.reference
        self.rest_volume = cavity.volume(self.reference)
        self._bordered_solver = SparseSolver()
        self._tangent_solver = SparseSolver()
        self._arc_solver = SparseSolver(border=2)

    def positions(self, q: NDArray[np.float64]) -> NDArray[np.float64]:
        """Deformed point positions [m]."""
        return self.space.positions(q)

    def _load(self, q: NDArray[np.float64]) -> NDArray[np.float64]:
        x = self.space.positions(q)
        self.field[0].values[:] = x - self.reference
        return x

    def reset_to(self, q: NDArray[np.float64]) -> None:
        """Put the solid's internal state back at a converged q (after a failed attempt)."""
        self._load(q)
        # The second call sees no increment, so the cell-wise dilatation equals the true one.
        self.solid.assemble.vector(self.field)
        self.solid.assemble.vector(self.field)

    def _system(self, q: NDArray[np.float64], p: float) -> tuple:
        x = self._load(q)
        f_int = np.asarray(self.solid.assemble.vector(self.field).todense()).ravel()
        stiffness = self.solid.assemble.matrix()
        grad = self.cavity.gradient(x).ravel()
        force = f_int - p * grad
        jac = self.space.jacobian(q)
        tangent = (jac.T @ ((stiffness - p * self.cavity.hessian(x)) @ jac)
                   + self.space.second_order(q, force))
        return x, jac.T @ force, tangent.tocsc(), jac.T @ grad

    def solve_volume(self, q0: NDArray[np.float64], p0: float, target: float,
                     max_iterations: int = 25, tolerance: float = 1e-6) -> State:
        """Equilibrium at the fluid volume ``target`` [m^3], starting from (q0, p0)."""
        q, p = q0.copy(), float(p0)
        for iteration in range(1, max_iterations + 1):
            x, residual, tangent, b = self._system(q, p)
            constraint = self.cavity.volume(x) - target
            bordered = sp.bmat([[tangent, -b[:, None]], [-b[None, :], None]], format='csc')
            rhs = np.concatenate([-residual, [constraint]])
            try:
                step = self._bordered_solver.solve(bordered, rhs)
            except RuntimeError as err:  # an exactly singular matrix
                raise ConvergenceError(f'singular bordered matrix ({err})') from None
            if not np.all(np.isfinite(step)):
                raise ConvergenceError('non-finite Newton step')
            q += step[:-1]
            p += step[-1]
            # Converged when the correction is negligible: near the solution Newton's method
            # converges quadratically, so the residual after such a step is far smaller still
            # (the residual before it only guards against a stalled iteration).
            small_step = np.max(np.abs(step[:-1])) <= tolerance * self.length_scale
            if (small_step and np.linalg.norm(residual) <= 1e3 * tolerance * self.force_scale
                    and abs(constraint) <= tolerance * self.rest_volume):
                return State(volume=target, pressure=p, q=q, iterations=iteration)
            if np.max(np.abs(step[:-1])) > 0.5 * self.length_scale:
                raise ConvergenceError('Newton step larger than half the model size')
        raise ConvergenceError(f'no convergence in {max_iterations} iterations')

    def solve_arc(self, start: State, direction: NDArray[np.float64], distance: float,
                  guess: State, scales: tuple[float, float, float], max_iterations: int = 25,
                  tolerance: float = 1e-6) -> State:
        """
        The equilibrium ``distance`` along ``direction`` from ``start``, in scaled states.

        A state scales to (q / q scale, V / volume scale, p / pressure scale) with ``scales``
        (q, volume, pressure); ``direction`` is a unit vector in that space. The step lands
        where the path crosses the hyperplane through start + distance * direction normal to
        ``direction``. Newton's method starts from ``guess``.
        """
        q_scale, volume_scale, pressure_scale = scales
        t_q, t_v, t_p = direction[:-2], float(direction[-2]), float(direction[-1])
        q, p, volume = guess.q.copy(), float(guess.pressure), float(guess.volume)
        n = q.size
        border = sp.csr_matrix(np.concatenate([t_q / q_scale, [t_p / pressure_scale]])[None, :])
        column = sp.csc_matrix((np.array([1.0, t_v / volume_scale]),
                                (np.array([n, n + 1]), np.zeros(2, dtype=int))),
                               shape=(n + 2, 1))
        for iteration in range(1, max_iterations + 1):
            # A trial state beyond a sharp turn may invert cells: felupe's energy is then NaN,
            # and the non-finite step below rejects it (a shorter step follows).
            with np.errstate(invalid='ignore', divide='ignore'):
                x, residual, tangent, b = self._system(q, p)
            constraint = self.cavity.volume(x) - volume
            arc = (t_q @ (q - start.q) / q_scale + t_v * (volume - start.volume) / volume_scale
                   + t_p * (p - start.pressure) / pressure_scale - distance)
            matrix = sp.vstack([sp.bmat([[tangent, -b[:, None]], [-b[None, :], None]]),
                                border])
            matrix = sp.hstack([matrix, column], format='csc')
            rhs = np.concatenate([-residual, [constraint, -arc]])
            try:
                step = self._arc_solver.solve(matrix, rhs)
            except RuntimeError as err:
                raise ConvergenceError(f'singular path-following matrix ({err})') from None
            if not np.all(np.isfinite(step)):
                raise ConvergenceError('non-finite Newton step')
            q += step[:n]
            p += step[n]
            volume += step[n + 1]
            small_step = np.max(np.abs(step[:n])) <= tolerance * self.length_scale
            if (small_step and np.linalg.norm(residual) <= 1e3 * tolerance * self.force_scale
                    and abs(constraint) <= tolerance * self.rest_volume
                    and abs(arc) <= tolerance):
                return State(volume=volume, pressure=p, q=q, iterations=iteration)
            if np.max(np.abs(step[:n])) > 0.5 * self.length_scale:
                raise ConvergenceError('Newton step larger than half the model size')
        raise ConvergenceError(f'no convergence in {max_iterations} iterations')

    def trace_path(self, max_volume: float, first_step: float, max_step: float,
                   min_step: float,
                   on_state: Callable[[State], str | None] | None = None,
                   max_states: int = 5000) -> PathResult:
        """
        Inflate from rest to ``max_volume`` [m^3], following the path by its arc length.

        The same path as :meth:`ramp_volume` where the volume grows, and on through points
        where it turns back and grows again. The arc length is measured over the whole state:
        the displacements (root mean square, over the model's size), the volume (over the
        requested range) and the pressure (over the material's stiffness,
        ``force_scale / length_scale**2``). Near a turn the volume and the pressure barely
        move while the membranes exchange fluid: the displacements carry the path there.
        ``first_step``, ``max_step`` and ``min_step`` [m^3] are volume steps where the path
        runs along the volume. Each step starts from the secant extrapolation of the last two
        states. The last state is at ``max_volume`` exactly when the path gets there.
        """
        q = np.zeros(self.space.size)
        self.reset_to(q)
        rest = State(volume=self.rest_volume, pressure=0.0, q=q.copy())
        result = PathResult(states=[rest])
        if on_state is not None:
            on_state(rest)
        volume_scale = max_volume - self.rest_volume
        scales = (self.length_scale * np.sqrt(q.size), volume_scale,
                  self.force_scale / self.length_scale**2)

        def scaled(state: State) -> NDArray[np.float64]:
            return np.concatenate([state.q / scales[0],
                                   [state.volume / scales[1], state.pressure / scales[2]]])

        current = self.solve_volume(rest.q, 0.0, rest.volume + first_step)
        previous = rest
        if self._accepted(result, current, on_state):
            return result
        # Steps in arc length; the first one's volume step is ``first_step``.
        secant = scaled(current) - scaled(previous)
        per_volume = float(np.linalg.norm(secant)) / (first_step / volume_scale)
        step, largest, smallest = (first_step / volume_scale * per_volume,
                                   max_step / volume_scale * per_volume,
                                   min_step / volume_scale * per_volume)
        while len(result.states) < max_states:
            secant = scaled(current) - scaled(previous)
            length = float(np.linalg.norm(secant))
            direction = secant / length
            ratio = step / length
            growing = direction[-2] > 0
            if growing and current.volume + ratio * (current.volume - previous.volume) \
                    >= max_volume:
                try:
                    final = self.solve_volume(current.q, current.pressure, max_volume)
                except ConvergenceError:
                    final = None
                if final is not None:
                    self._accepted(result, final, on_state)
                    return result
                self.reset_to(current.q)
            guess = State(volume=current.volume + ratio * (current.volume - previous.volume),
                          pressure=current.pressure
                          + ratio * (current.pressure - previous.pressure),
                          q=current.q + ratio * (current.q - previous.q))
            try:
                state = self.solve_arc(current, direction, step, guess, scales)
                # The step's projection on the last direction is ``step``; a chord much longer
                # than that turned sharply, and may have landed on another part of the path
                # (the plane it is solved on crosses the path again beyond a turn).
                chord = float(np.linalg.norm(scaled(state) - scaled(current)))
                if chord * self.MAX_TURN_COSINE > step:
                    raise ConvergenceError('the path turned by more than the step allows')
            except ConvergenceError as err:
                step = self._shorter(current, step, smallest, err, result)
                if step is None:
                    return result
                continue
            previous, current = current, state
            if self._accepted(result, state, on_state):
                return result
            if state.iterations <= 6:
                step = min(step * 1.5, largest)
        result.stop_reason = f'stopped after {max_states} states'
        return result

    @staticmethod
    def _accepted(result: PathResult, state: State,
                  on_state: Callable[[State], str | None] | None) -> bool:
        """Record a converged state; True when ``on_state`` gives a reason to stop (kept)."""
        result.newton_iterations += state.iterations
        result.states.append(state)
        if on_state is not None and (reason := on_state(state)):
            result.stop_reason = reason
            return True
        return False

    def _shorter(self, current: State, step: float, smallest: float, error: Exception,
                 result: PathResult) -> float | None:
        """After a failed step: back at ``current`` with half the step, None below ``smallest``."""
        self.reset_to(current.q)
        step *= 0.5
        if step < smallest:
            result.stop_reason = f'no convergence beyond the last state ({error})'
            return None
        return step

    def solve_pressure(self, q0: NDArray[np.float64], pressure: float,
                       max_iterations: int = 25, tolerance: float = 1e-6) -> State:
        """Equilibrium at the prescribed gauge pressure [Pa] (the usual load control)."""
        q = q0.copy()
        for iteration in range(1, max_iterations + 1):
            x, residual, tangent, _ = self._system(q, pressure)
            try:
                step = self._tangent_solver.solve(tangent, -residual)
            except RuntimeError as err:
                raise ConvergenceError(f'singular tangent ({err})') from None
            if not np.all(np.isfinite(step)):
                raise ConvergenceError('non-finite Newton step')
            q += step
            if (np.linalg.norm(residual) <= tolerance * self.force_scale
                    and np.max(np.abs(step)) <= tolerance * self.length_scale):
                x = self.space.positions(q)
                return State(volume=self.cavity.volume(x), pressure=pressure, q=q,
                             iterations=iteration)
            if np.max(np.abs(step)) > 0.5 * self.length_scale:
                raise ConvergenceError('Newton step larger than half the model size')
        raise ConvergenceError(f'no convergence in {max_iterations} iterations')

    def ramp_volume(self, max_volume: float, first_step: float, max_step: float,
                    min_step: float,
                    on_state: Callable[[State], str | None] | None = None,
                    predictor: bool = False) -> PathResult:
        """
        Inflate from rest to ``max_volume`` [m^3] with adaptive volume steps [m^3].

        A failed step is retried at half the size down to ``min_step``; steps grow again after
        easy convergence. ``on_state`` sees every converged state and may return a reason to
        stop (contact, for example). The result always holds the rest state first.
        ``predictor`` starts each step from the secant extrapolation of the last two states
        instead of the last state; on the segments it cost a third more Newton iterations, so
        it is off by default (the bordered system passes extrema without it).
        """
        q = np.zeros(self.space.size)
        self.reset_to(q)
        rest = State(volume=self.rest_volume, pressure=0.0, q=q.copy())
        result = PathResult(states=[rest])
        if on_state is not None:
            on_state(rest)
        step = first_step
        previous: State | None = None
        current = rest
        while current.volume < max_volume * (1 - 1e-12):
            step = min(step, max_volume - current.volume)
            target = current.volume + step
            q_guess, p_guess = current.q, current.pressure
            if predictor and previous is not None:
                # Secant predictor along the path: follows the pressure through its extrema.
                ratio = step / (current.volume - previous.volume)
                q_guess = current.q + ratio * (current.q - previous.q)
                p_guess = current.pressure + ratio * (current.pressure - previous.pressure)
            try:
                state = self.solve_volume(q_guess, p_guess, target)
            except ConvergenceError as err:
                step = self._shorter(current, step, min_step, err, result)
                if step is None:
                    return result
                continue
            previous, current = current, state
            if self._accepted(result, state, on_state):
                return result
            if state.iterations <= 6:
                step = min(step * 1.5, max_step)
        return result

    def ramp_pressure(self, pressures: NDArray[np.float64]) -> PathResult:
        """Load control through the given increasing pressures [Pa]; stops where Newton fails."""
        q = np.zeros(self.space.size)
        self.reset_to(q)
        result = PathResult(states=[State(volume=self.rest_volume, pressure=0.0, q=q.copy())])
        for pressure in pressures:
            try:
                state = self.solve_pressure(result.states[-1].q, float(pressure))
            except ConvergenceError as err:
                result.stop_reason = f'no convergence at {pressure:.6g} Pa ({err})'
                return result
            result.newton_iterations += state.iterations
            result.states.append(state)
        result.stop_reason = 'reached the requested pressure'
        return result
