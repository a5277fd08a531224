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

Every state under volume control knows whether it is stable: the bordered matrix is factored
without pivoting, an L D L^T factorization whose negative pivots count its negative eigenvalues,
and a stable state has one only (the constraint's). Where the ramp can go no further, or only
through unstable states, the solid snaps through at constant volume as a syringe-driven one
does: :meth:`InflationModel.settle_at_volume` follows that snap as a damped motion until it comes
to rest on a stable state, and the ramp goes on from there.

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


@dataclass(frozen=True)
class SettleSettings:
    """
    The budgets and thresholds of a snap-through followed at constant volume.

    Lengths are in units of the model's size, forces of its force scale
    (:meth:`InflationModel.settle_at_volume`).
    """

    # Damped steps before giving up.
    max_steps: int = 1000
    # Newton iterations allowed for one damped step, and for the static solve at rest.
    damped_iterations: int = 12
    final_iterations: int = 8
    # A step whose Newton solve needed at most this many iterations lets the time step double.
    easy_iterations: int = 4
    # A failed damped step cuts the time step by this factor, down to this shortest step.
    step_cut: float = 0.25
    min_time_step: float = 1e-6
    # At rest: forces below this share of the force scale (and below this share of those at
    # the last failed static solve) and a last step below this share of the model's size.
    rest_force: float = 1e-3
    rest_force_drop: float = 0.1
    rest_motion: float = 1e-3
    # The static solve's tolerance, and how far its equilibrium may lie from where the
    # motion came to rest (share of the model's size).
    tolerance: float = 1e-6
    final_agreement: float = 1e-2
    # A push off a saddle: this share of the model's size, at most this many times; the time
    # step is held short until the solid is this many pushes away from the saddle.
    kick: float = 1e-3
    max_kicks: int = 3
    clear_of_saddle: float = 10.0


class ConvergenceError(RuntimeError):
    """Newton's method did not converge for one load level."""


class MotionStoppedError(RuntimeError):
    """A snap-through's motion reached a state the caller stops at (contact, for example)."""


@dataclass
class State:
    """One converged equilibrium: volume [m^3], gauge pressure [Pa], reduced coordinates."""

    volume: float
    pressure: float
    q: NDArray[np.float64]
    iterations: int = 0
    # Under volume control: a local minimum of the energy among states of this volume (None:
    # not known, e.g. a state of a pressure-controlled or arc-length run).
    stable: bool | None = None
    # The last Newton correction of the pressure [Pa]: the error left in it is smaller still
    # (quadratic convergence), so it bounds the solver's scatter of a table's rows.
    pressure_correction: float = 0.0


@dataclass(frozen=True)
class Snap:
    """A snap-through at constant volume: the path ended, the solid settled on another one."""

    index: int               # of the state it landed in, in PathResult.states
    volume: float            # [m^3] where it snapped (the landing state's volume)
    pressure_before: float   # [Pa] gauge, the last state before it
    pressure_after: float    # [Pa] gauge, the state it settled in
    cause: str


@dataclass
class PathResult:
    """Converged states along the volume ramp, and why the ramp ended."""

    states: list[State] = field(default_factory=list)
    stop_reason: str = 'reached the requested volume'
    newton_iterations: int = 0
    snaps: list[Snap] = field(default_factory=list)

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
    # The farthest a point may move in one step of a snap-through, over the model's size: the
    # solid moves continuously, and so must its path.
    MAX_MOVE = 0.05
    # A volume step whose largest motion per volume is this many times the last step's has
    # jumped off the path, not followed it.
    MAX_PACE_JUMP = 10.0

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
                     max_iterations: int = 25, tolerance: float = 1e-6,
                     damping: NDArray[np.float64] | None = None) -> State:
        """
        Equilibrium at the fluid volume ``target`` [m^3], starting from (q0, p0).

        With ``damping`` (one coefficient per unknown), one implicit Euler step of the damped
        motion ``damping * dq/dt = -R`` of unit time from q0 instead: the residual gains
        ``damping * (q - q0)`` and the matrix its diagonal, which makes it regular where the
        static equilibrium is unstable or absent.
        """
        q, p = q0.copy(), float(p0)
        for iteration in range(1, max_iterations + 1):
            x, residual, tangent, b = self._system(q, p)
            if damping is not None:
                residual = residual + damping * (q - q0)
                tangent = (tangent + sp.diags(damping)).tocsc()
            constraint = self.cavity.volume(x) - target
            bordered = self._bordered(tangent, b)
            rhs = np.concatenate([-residual, [constraint]])
            try:
                step = self._bordered_solver.solve(bordered, rhs)
            except RuntimeError as err:  # an exactly singular matrix
                raise ConvergenceError(f'singular bordered matrix ({err})') from None
            if damping is not None and self._stable() is False:
                # A damped step this long no longer goes downhill (see settle_at_volume).
                raise ConvergenceError('the damped matrix is indefinite at constant volume')
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
                self._check_orientation(q)
                return State(volume=target, pressure=p, q=q, iterations=iteration,
                             stable=self._stable() if damping is None else None,
                             pressure_correction=abs(float(step[-1])))
            if np.max(np.abs(step[:-1])) > 0.5 * self.length_scale:
                raise ConvergenceError('Newton step larger than half the model size')
        raise ConvergenceError(f'no convergence in {max_iterations} iterations')

    @staticmethod
    def _bordered(tangent: sp.spmatrix, b: NDArray[np.float64]) -> sp.csc_matrix:
        """The volume-controlled system's matrix [[A, -b], [-b^T, 0]]."""
        return sp.bmat([[tangent, -b[:, None]], [-b[None, :], None]], format='csc')

    def _check_orientation(self, q: NDArray[np.float64]) -> None:
        """
        Refuse a solution with cells turned inside out (det F <= 0 somewhere).

        Newton's method may converge there from a poor start beyond a sharp turn of the path
        (a balloon pushed through its own centre): an equilibrium of the equations, not of a
        solid.
        """
        self._load(q)
        gradient = self.field.extract()[0]
        if not np.all(np.linalg.det(np.moveaxis(gradient, (0, 1), (-2, -1))) > 0):
            raise ConvergenceError('cells turned inside out')

    def largest_stretch(self, q: NDArray[np.float64]) -> float:
        """The largest principal stretch anywhere in the solid (at its quadrature points)."""
        self._load(q)
        gradient = np.moveaxis(self.field.extract()[0], (0, 1), (-2, -1))
        return float(np.sqrt(np.linalg.eigvalsh(
            np.swapaxes(gradient, -1, -2) @ gradient)[..., -1].max()))

    def _stable(self) -> bool | None:
        """
        Whether the state of the last bordered solve is stable under volume control.

        The bordered matrix has one negative eigenvalue from the constraint itself and one
        more for every direction of falling energy among the states of the same volume.
        """
        negatives = self._bordered_solver.negative_pivots()
        return None if negatives is None else negatives <= 1

    def _falling_direction(self, damping: NDArray[np.float64], shift: float = 0.0,
                           iterations: int = 12) -> tuple | None:
        """
        The mode of falling energy at constant volume, and its rate (None: none found).

        It uses the last bordered factorization, of [[A + shift D, -b], [-b^T, 0]]: its
        solutions for a right-hand side [D z, 0] keep the volume, so inverse iteration converges
        to the mode of A z = lambda D z at constant volume whose lambda lies nearest -shift:
        the one that just went unstable with no shift, the most unstable one with a shift just
        beyond it.
        Returns the unit mode and lambda (negative) [1 / unit time of the damped motion].
        """
        n = self.space.size
        z = np.random.default_rng(0).standard_normal(n)
        image = z
        for _ in range(iterations):
            z = image / np.linalg.norm(image)
            solution = self._bordered_solver.solve_again(np.concatenate([damping * z, [0.0]]))
            if solution is None or not np.all(np.isfinite(solution)):
                return None
            image = solution[:n]
        rate = float(z @ (damping * z)) / float(z @ (damping * image)) - shift
        return (z, rate) if rate < 0 else None

    def _factor(self, q: NDArray[np.float64], p: float, target: float,
                damping: NDArray[np.float64] | None = None) -> None:
        """Factor the (damped) bordered matrix at (q, p), for :meth:`_falling_direction`."""
        x, residual, tangent, b = self._system(q, p)
        if damping is not None:
            tangent = tangent + sp.diags(damping)
        self._bordered_solver.solve(self._bordered(tangent, b), np.concatenate(
            [-residual, [self.cavity.volume(x) - target]]))
        self.reset_to(q)

    def _lumped_damping(self, q: NDArray[np.float64]) -> NDArray[np.float64]:
        """
        Damping coefficients of the unknowns [N/m per unit time], lumped like a mass.

        Each point's share of the solid's volume times the shear modulus over the model size
        squared. Soft thin parts move as freely as the stiff ones; the stiffness' own diagonal
        would not do (on the cavity's faces the pressure term can cancel it).
        """
        region = self.field[0].region
        cells = region.mesh.cells
        shares = np.zeros(self.reference.shape[0])
        np.add.at(shares, cells, (region.dV.sum(axis=0) / cells.shape[1])[:, None])
        jac = self.space.jacobian(q)
        modulus = self.force_scale / self.length_scale**2
        per_unknown = jac.multiply(jac).T @ np.repeat(shares, 3)
        return modulus / self.length_scale**2 * np.maximum(per_unknown, 1e-12 * per_unknown.max())

    def _kick(self, q: NDArray[np.float64], falling: tuple, kick: float) -> tuple:
        """Push the solid off a saddle along its falling mode; the time step that lets it grow."""
        direction, rate = falling
        q = q + kick * self.length_scale * direction / np.abs(direction).max()
        self.reset_to(q)
        # The mode grows by 1 / (1 - |rate| dt) per implicit Euler step: at least twice while
        # dt stays below 1 / (2 |rate|).
        return q, 0.5 / abs(rate)

    def settle_at_volume(self, start: State, target: float,
                         settings: 'SettleSettings | None' = None,
                         on_motion: Callable[[NDArray[np.float64]], str | None] | None = None
                         ) -> State:
        """
        The stable equilibrium at the volume ``target`` [m^3] that the solid comes to rest in.

        Where the quasi-static path ends (the volume turns back: a snap-back) or goes on only
        unstably (past a bifurcation), the syringe still pushes: the solid snaps through at
        constant volume. This follows that snap as a damped motion, ``D dq/dt = -R(q, p)``
        with the volume held at ``target``, by implicit Euler steps (``D`` lumped like a
        mass, :meth:`_lumped_damping`). The time step doubles while Newton's method converges
        easily, and is cut where it does not, where a point would move too far, or where the damped
        matrix turns indefinite at constant volume (its inertia, from the factorization):
        longer steps would no longer follow the motion downhill. When the forces left are
        small a static Newton solve finds the equilibrium. If that is unstable (the motion
        came to rest on a saddle, or started on one), the solid is pushed off it by ``kick``
        times the model size along the mode of falling energy, and the time step is held
        short enough for that mode to grow (implicit Euler with long steps damps growing modes
        too) until the solid is well away. This is the way a slowly pushed solid settles, not
        a dynamic simulation (no inertia, no flow resistance). ``settings`` name every budget
        and threshold (:class:`SettleSettings`); a motion that does not come to rest within
        them raises ConvergenceError. ``on_motion`` sees the coordinates after every step and
        may give a reason to stop (:class:`MotionStoppedError`).
        """
        settings = settings or SettleSettings()
        kick = settings.kick
        q, p = start.q.copy(), float(start.pressure)
        self.reset_to(q)
        damping = self._lumped_damping(q)
        time_step, kicks, iterations = 1.0, 0, 0
        saddle: NDArray[np.float64] | None = None  # where the last kick pushed off from
        longest = np.inf                            # time step allowed while leaving it
        failed_at = np.inf  # the forces left when a static solve last failed
        good_step: float | None = None  # the last time step whose damped solve succeeded
        for _ in range(settings.max_steps):
            try:
                step = self.solve_volume(q, p, target,
                                         max_iterations=settings.damped_iterations,
                                         damping=damping / time_step)
                if np.max(np.abs(step.q - q)) > self.MAX_MOVE * self.length_scale:
                    raise ConvergenceError('too far in one step')
            except ConvergenceError:
                self.reset_to(q)
                time_step *= settings.step_cut
                if time_step >= settings.min_time_step:
                    continue
                # Stalled on a saddle: the falling mode is not there to grow, and any longer
                # step runs up the others'. Push off it along its most unstable mode.
                stalled = (f'the damped motion stalled, largest stretch '
                           f'{self.largest_stretch(q):.2f}')
                if kicks == settings.max_kicks or good_step is None:
                    raise ConvergenceError(stalled) from None
                self._factor(q, p, target, damping / good_step)
                if (falling := self._falling_direction(damping, 1.0 / good_step)) is None:
                    raise ConvergenceError(stalled) from None
                saddle = q
                q, longest = self._kick(q, falling, kick)
                time_step, kicks = min(1.0, longest), kicks + 1
                continue
            iterations += step.iterations
            good_step = time_step
            motion = np.max(np.abs(step.q - q))
            forces = np.linalg.norm(damping * (step.q - q)) / time_step
            q, p = step.q, step.pressure
            if on_motion is not None and (reason := on_motion(q)):
                raise MotionStoppedError(reason)
            if step.iterations <= settings.easy_iterations:
                time_step = min(2.0 * time_step, longest)
            if saddle is not None:
                clear = settings.clear_of_saddle * kick * self.length_scale
                if np.max(np.abs(q - saddle)) < clear:
                    continue
                saddle, longest = None, np.inf
            # At rest: the forces left are small, and so is the last step (with a long time
            # step the first alone says little).
            if (forces > min(settings.rest_force * self.force_scale,
                             settings.rest_force_drop * failed_at)
                    or motion > settings.rest_motion * self.length_scale):
                continue
            try:
                # Near an equilibrium Newton's method needs a few iterations; more means
                # there is none yet (a slow passage past where one vanished).
                final = self.solve_volume(q, p, target, max_iterations=settings.final_iterations,
                                          tolerance=settings.tolerance)
                if np.max(np.abs(final.q - q)) > settings.final_agreement * self.length_scale:
                    raise ConvergenceError('not the equilibrium the motion came to')
            except ConvergenceError:
                self.reset_to(q)
                failed_at = forces
                continue
            failed_at = np.inf
            iterations += final.iterations
            if final.stable is not False:
                final.iterations = iterations
                return final
            falling = self._falling_direction(damping)
            if kicks == settings.max_kicks or falling is None:
                raise ConvergenceError('the damped motion came to rest on an unstable state')
            saddle = final.q
            q, longest = self._kick(final.q, falling, kick)
            p = final.pressure
            time_step, kicks = min(1.0, longest), kicks + 1
        raise ConvergenceError(f'the damped motion did not come to rest in {settings.max_steps} '
                               'steps')

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
            matrix = sp.vstack([self._bordered(tangent, b),
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
                self._check_orientation(q)
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
        rest, result = self._start(on_state)
        volume_scale = max_volume - self.rest_volume
        scales = (self.length_scale * np.sqrt(rest.q.size), volume_scale,
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

    def _start(self, on_state: Callable[[State], str | None] | None = None
               ) -> tuple[State, PathResult]:
        """The solid back at rest, and a path that begins there (``on_state`` sees it)."""
        q = np.zeros(self.space.size)
        self.reset_to(q)
        rest = State(volume=self.rest_volume, pressure=0.0, q=q.copy())
        if on_state is not None:
            on_state(rest)
        return rest, PathResult(states=[rest])

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
                    predictor: bool = False, snaps: bool = True,
                    max_snaps: int = 50,
                    on_motion: Callable[[NDArray[np.float64]], str | None] | None = None
                    ) -> PathResult:
        """
        Inflate from rest to ``max_volume`` [m^3] with adaptive volume steps [m^3].

        A failed step is retried at half the size down to ``min_step``; steps grow again after
        easy convergence. ``on_state`` sees every converged state and may return a reason to
        stop (contact, for example). The result always holds the rest state first.
        ``predictor`` starts each step from the secant extrapolation of the last two states
        instead of the last state; on the segments it cost a third more Newton iterations, so
        it is off by default (the bordered system passes extrema without it).

        With ``snaps`` the ramp goes on, as a syringe does, where the quasi-static path ends
        (no equilibrium near the next volume, however small the step) or goes on unstably:
        the solid settles at ``min_step`` beyond the last state, or at the unstable state's
        own volume (:meth:`settle_at_volume`), and the ramp continues from there. Each such
        snap-through is recorded in ``PathResult.snaps``; ``on_motion`` watches the motion of
        each (it may stop the ramp, as ``on_state`` does).
        """
        rest, result = self._start(on_state)
        step = first_step
        previous: State | None = None
        pace: float | None = None  # the last step's largest motion per volume
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
            cause, unstable = None, False
            try:
                state = self.solve_volume(q_guess, p_guess, target)
                move = np.max(np.abs(state.q - current.q)) / step
                if pace is not None and move > self.MAX_PACE_JUMP * pace:
                    # Much farther per volume than the last step: beyond a turn Newton's
                    # method may find another part of the path, or an equilibrium of the
                    # equations that no solid reaches (a balloon pushed through its centre).
                    raise ConvergenceError('the step left the path')
            except ConvergenceError as err:
                shorter = self._shorter(current, step, min_step, err, result)
                if shorter is not None:
                    step = shorter
                    continue
                if not snaps or len(result.snaps) == max_snaps:
                    return result
                cause = f'no equilibrium near the next volume ({err})'
                start, target = current, min(current.volume + min_step, max_volume)
            else:
                if snaps and state.stable is False and len(result.snaps) < max_snaps:
                    cause = 'the equilibrium at the next volume is unstable'
                    start, unstable = state, True
            if cause is not None:
                try:
                    state = self.settle_at_volume(start, target, on_motion=on_motion)
                except MotionStoppedError as stop:
                    self.reset_to(current.q)
                    result.stop_reason = (f'{stop} during the snap-through at '
                                          'the next volume')
                    return result
                except ConvergenceError as err:
                    self.reset_to(current.q)
                    result.stop_reason = (f'no equilibrium beyond the last state, and no '
                                          f'snap-through found ({err})')
                    return result
                result.stop_reason = 'reached the requested volume'
                moved = np.max(np.abs(state.q - start.q)) > 0.01 * self.length_scale
                if not (moved or unstable):
                    # It settled next to the path: a hard step, not a snap-through.
                    move, step, cause = (np.max(np.abs(state.q - current.q))
                                         / (state.volume - current.volume), min_step, None)
            if cause is None:
                previous, pace = current, move
            else:
                result.snaps.append(Snap(index=len(result.states), volume=state.volume,
                                         pressure_before=current.pressure,
                                         pressure_after=state.pressure, cause=cause))
                previous, pace, step = None, None, first_step
            current = state
            if self._accepted(result, state, on_state):
                return result
            if cause is None and state.iterations <= 6:
                step = min(step * 1.5, max_step)
        return result

    def ramp_pressure(self, pressures: NDArray[np.float64]) -> PathResult:
        """Load control through the given increasing pressures [Pa]; stops where Newton fails."""
        _, result = self._start()
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
