"""
Membrane laws fitted to measured inflations of one segment: from a measurement to a prediction.

A measured inflation is a table of the segment's volume [m^3] and gauge pressure [Pa]. The
segment is taken to be a thin-walled sphere, the project's balloon
(:class:`~softseq_ros.segments.models.BalloonSegment`): with the stretch
``lam = (v / v0)^(1/3)`` of a sphere of rest volume ``v0 = 4/3 pi R^3``,

    p(v) = H / (R lam^2) dW/dlam

for a membrane of reference radius ``R`` and thickness ``H`` and the law's strain energy ``W``
under equibiaxial stretch (:mod:`softseq_ros.segments.materials`). The pressure is the law's
moduli times ``H / R`` times a function of the stretch, so p(v) alone fixes:

- the moduli times ``H / R`` (``mu H / R``, ``C1 H / R``...): a modulus and the thickness
  over the radius cannot be told apart; with ``R`` and ``H`` given, the moduli follow;
- the law's shape parameters (Gent's ``Jm``, Ogden's ``alpha``), which set how the curve bends
  as the stretch grows: a locking ``Jm`` far beyond the measured stretch is not seen (its
  interval opens upwards);
- the rest volume ``v0`` (so ``R``), which sets the stretch scale, when ``R`` is not given.

The segment may instead be a cavity whose n membranes bulge out of circular holes of radius
``a`` as spherical caps (:class:`Bulge`, the paper's segment of
:mod:`softseq_ros.segments.bulge`): the pressure is the moduli times ``H / a`` times a function
of the caps' stretch, and the volume the cavity's rest volume ``V0``, plus what its side walls
swell by (compliance ``C`` times p), plus the caps' volume, ``n a^3`` times a function of the
stretch. p(v) then fixes the moduli times ``H / a``, the shape parameters, ``V0`` and ``n a^3``;
``a`` and ``n`` are given (so ``n a^3`` is), ``C`` too (0: rigid walls), and ``V0`` is fitted
when not given. Both are geometries of one fit (:class:`Sphere`, :class:`Bulge`).

Only these identifiable groups are fitted, by weighted nonlinear least squares
(``scipy.optimize.least_squares``); each inflation's rows are weighted by its own noise,
estimated from its raw rows (:func:`estimate_noise_std`). Every fitted or derived number comes
with a 95 % interval from the Jacobian at the optimum, ``(J^T J)^-1 s^2`` with the residual
variance ``s^2`` and Student's t, and beside it a percentile interval from a seeded
parametric bootstrap (synthetic inflations from the fitted curve with the fitted noise,
refitted). The laws are ranked by AICc, the small-sample Akaike criterion: the law expected to
predict new measurements best (BIC, stated beside it, penalises parameters more and aims at the
true law among those tried). docs/fit.md says more, and what is not covered.
"""

from dataclasses import dataclass, field
import math
from typing import Callable, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares

from softseq_ros.errors import UserError
from softseq_ros.segments.materials import (
    ArrudaBoyce,
    Gent,
    Material,
    MooneyRivlin,
    NeoHookean,
    Ogden,
    Yeoh,
    material_parameter_names,
)
from softseq_ros.segments.models import BalloonSegment

FloatArray = NDArray[np.float64]

# Rows an inflation needs: its noise comes from 4-row differences (at least 7 of them), and
# a law of three parameters from all rows together.
MIN_ROWS = 10
# A difference further than this many robust deviations from the median is the curve's own
# bend (the steep first rows of a balloon), not noise: left out of the noise's deviation.
NOISE_TRIM = 3.5
# The share of a normal deviation that its tails beyond NOISE_TRIM deviations carry, as a
# factor on the trimmed standard deviation: sqrt(1 - 2 c phi(c) / (2 Phi(c) - 1)), c = 3.5.
NOISE_TRIM_FACTOR = 0.996942
# The median absolute deviation of a normal sample times this is its standard deviation.
MAD_TO_STD = 1.482602
# A noise estimate of exactly 0 (synthetic or quantised rows) would weigh rows infinitely:
# the noise is taken as at least this share of the inflation's largest pressure.
NOISE_FLOOR = 1e-9
CONFIDENCE = 0.95
# Half an interval on a logarithm beyond this (a factor e^700) is an interval without end.
MAX_LOG_SPREAD = 700.0
BOOTSTRAP_RESAMPLES = 200
# The fit stops when a step changes the cost or the parameters by less than this share.
FIT_TOLERANCE = 1e-10
# Internal parameters (logarithms, or moduli over the pressure scale) stay within +-this:
# bounds wide enough never to be met by a real fit, that keep a wild step finite.
INTERNAL_BOUND = 40.0
# Rest volumes tried for a start when R is not given, as shares of the smallest volume
# measured (a measurement that starts at rest has its first row there).
REST_VOLUME_STARTS = np.geomspace(0.3, 1.0, 25)
# A bulge's rest volume (its cavity's) is the smallest volume measured less some share of the
# span measured, at most all of it: the shares tried for a start.
BULGE_REST_VOLUME_STARTS = np.concatenate([[0.0], np.geomspace(1e-3, 1.0, 24)])
# Compliant walls: the caps' rise is solved to this share of itself (or of 1), in at most so
# many steps, each slope from a forward difference of this share.
WALL_SOLVE_TOLERANCE = 1e-13
WALL_SOLVE_STEPS = 60
WALL_SOLVE_STEP = 1e-7
# Rows of the segment table written from a fitted law.
TABLE_ROWS = 201


class FitError(UserError):
    """Measurements or options that cannot be fitted; one line naming what is wrong."""


def _take_rows(branch: object, too_few: str) -> FloatArray:
    """
    A measured branch's volumes, its rows set on it as float arrays once checked.

    One volume to each pressure (and curvature), at least MIN_ROWS (else ``too_few``, with
    {rows} and {least}, says why), all finite.
    """
    volume = np.asarray(branch.volume, dtype=float)
    pressure = np.asarray(branch.pressure, dtype=float)
    object.__setattr__(branch, 'volume', volume)
    object.__setattr__(branch, 'pressure', pressure)
    if volume.ndim != 1 or volume.shape != pressure.shape:
        raise FitError(f'{branch.source}: volume and pressure need one row each, as many')
    _check_curvature(branch.source, branch.curvature, volume)
    if branch.curvature is not None:
        object.__setattr__(branch, 'curvature', np.asarray(branch.curvature, dtype=float))
    if volume.size < MIN_ROWS:
        raise FitError(f'{branch.source}: ' + too_few.format(rows=volume.size, least=MIN_ROWS))
    if not (np.all(np.isfinite(volume)) and np.all(np.isfinite(pressure))):
        raise FitError(f'{branch.source}: volumes and pressures must be finite')
    return volume


@dataclass(frozen=True)
class Inflation:
    """
    One measured inflation of the segment: volumes [m^3], strictly rising, gauge Pa.

    ``curvature`` [1/m], where measured: not fitted (p(v) says nothing of it), carried into
    the cleaned table.
    """

    volume: FloatArray
    pressure: FloatArray
    source: str = 'inflation'
    curvature: FloatArray | None = None

    def __post_init__(self) -> None:
        """Check the rows are usable: enough, finite and in rising volume."""
        volume = _take_rows(self, '{rows} rows are too few to fit: at least {least} (the noise '
                                  'is estimated from the rows themselves)')
        steps = np.diff(volume)
        if np.any(steps <= 0.0):
            row = int(np.argmax(steps <= 0.0)) + 2
            raise FitError(f'{self.source}: volume_m3 must rise strictly (one inflation); row '
                           f'{row} ({volume[row - 1]:.6g}) does not exceed row {row - 1} '
                           f'({volume[row - 2]:.6g})')
        if volume[0] <= 0.0:
            raise FitError(f"{self.source}: volume_m3 must be > 0 (the segment's whole "
                           f'volume, not the volume injected), got {volume[0]:.6g} in row 1')


def _check_curvature(source: str, curvature: ArrayLike | None, volume: FloatArray) -> None:
    if curvature is None:
        return
    values = np.asarray(curvature, dtype=float)
    if values.shape != volume.shape or not np.all(np.isfinite(values)):
        raise FitError(f'{source}: curvature_per_m needs one finite value a row')


def estimate_noise_std(volume: ArrayLike, pressure: ArrayLike) -> float:
    """
    Standard deviation [Pa] of the pressure noise, from the raw rows of one inflation.

    Each run of four rows gives a third divided difference, which a quadratic through them
    cancels; scaled by its coefficients, it is one sample of the noise's deviation on a
    locally smooth curve (for equally spaced rows: the third difference over sqrt(20)). Those
    further than :data:`NOISE_TRIM` robust deviations (the median absolute deviation) from
    their median are where the curve bends faster (the first rows of a balloon) and are left
    out; the deviation of the rest is the estimate (nearly the efficiency of a standard
    deviation, about 10 % on 100 rows). Smoothed rows would hide the noise: give the rows as
    measured.
    """
    v = np.asarray(volume, dtype=float)
    p = np.asarray(pressure, dtype=float)
    if v.size < 4:
        raise FitError(f'the noise needs at least 4 rows, got {v.size}')
    x = [v[k:v.size - 3 + k] for k in range(4)]
    # Lagrange weights of the third divided difference on each run of four rows.
    weights = [1.0 / np.prod([x[j] - x[k] for k in range(4) if k != j], axis=0)
               for j in range(4)]
    scale = np.sqrt(sum(w**2 for w in weights))
    samples = sum(w * p[j:p.size - 3 + j] for j, w in enumerate(weights)) / scale
    centred = samples - np.median(samples)
    robust = MAD_TO_STD * float(np.median(np.abs(centred)))
    kept = centred[np.abs(centred) <= NOISE_TRIM * robust] if robust > 0.0 else centred
    return float(np.sqrt(np.mean(kept**2)) / (NOISE_TRIM_FACTOR if robust > 0.0 else 1.0))


def sphere_stretch(volume: ArrayLike, rest_volume: float) -> FloatArray:
    """The membrane's equibiaxial stretch at ``volume`` of a sphere of ``rest_volume``."""
    return np.cbrt(np.asarray(volume, dtype=float) / rest_volume)


def sphere_pressure(material: Material, stretch: ArrayLike,
                    thickness_over_radius: float = 1.0) -> FloatArray:
    """
    Gauge pressure [Pa] of a thin sphere: ``H / (R lam^2) dW/dlam``, as BalloonSegment has it.

    With ``thickness_over_radius`` 1 the moduli of ``material`` stand for the moduli times
    ``H / R``: the groups that p(v) determines.
    """
    lam = np.asarray(stretch, dtype=float)
    return thickness_over_radius / lam**2 * material.energy_derivative(lam)


def radius_of(rest_volume: float) -> float:
    """The reference radius [m] of a sphere of ``rest_volume`` [m^3]."""
    return math.cbrt(3.0 * rest_volume / (4.0 * math.pi))


def rest_volume_of(radius: float) -> float:
    """The volume [m^3] of a sphere of ``radius`` [m]."""
    return 4.0 / 3.0 * math.pi * radius**3


def cap_rise(injected: ArrayLike, caps_scale: float) -> FloatArray:
    """
    The caps' rise ``s = h / a`` [-] when the caps together hold ``injected`` [m^3].

    The caps hold ``caps_scale pi s (3 + s^2) / 6`` with ``caps_scale`` = n a^3 (n caps on
    holes of radius a), the volume of a spherical cap of height h = a s; its one real root by
    Cardano's formula, written so that it neither cancels nor loses the sign: a volume below
    rest turns the caps inwards (s < 0), as the same membranes pushed the other way.
    """
    q = 3.0 * np.asarray(injected, dtype=float) / (math.pi * caps_scale)
    t = np.cbrt(np.abs(q) + np.sqrt(q**2 + 1.0))
    return np.sign(q) * (t - 1.0 / t)


def caps_volume(rise: ArrayLike, caps_scale: float) -> FloatArray:
    """What caps of rise ``s = h / a`` hold together [m^3], ``caps_scale`` = n a^3."""
    s = np.asarray(rise, dtype=float)
    return caps_scale * math.pi * s * (3.0 + s**2) / 6.0


def bulge_pressure(material: Material, rise: ArrayLike,
                   thickness_over_hole_radius: float = 1.0) -> FloatArray:
    """
    Gauge pressure [Pa] of a membrane bulging out of a hole as a cap of rise ``s = h / a``.

    ``2 (H / a) W'(lam) s / lam^3`` with ``lam = sqrt(1 + s^2)``, as
    :func:`~softseq_ros.segments.bulge.cap_pressure` has it; odd in s (a cap turned inwards
    pulls back as hard). With ``thickness_over_hole_radius`` 1 the moduli of ``material``
    stand for the moduli times ``H / a``: the groups that p(v) determines.
    """
    s = np.asarray(rise, dtype=float)
    lam = np.sqrt(1.0 + s**2)
    return 2.0 * thickness_over_hole_radius * material.energy_derivative(lam) * s / lam**3


Locked = Callable[[FloatArray], NDArray[np.bool_]]


@dataclass(frozen=True)
class MembraneLaw:
    """
    A membrane law as fitted: its identifiable groups and how to build it.

    ``groups``: the fitted parameters' names on the sphere (moduli first: each a law modulus
    times H / R, in Pa; then the shape parameters); :meth:`Geometry.group_names` renames the
    moduli for another geometry. ``positive``: which are fitted as logarithms (they
    cannot change sign: an interval of a positive quantity stays positive). ``shape_starts``:
    values of the one shape parameter tried for a start, the moduli solved linearly for each.
    ``locked``: where the law has no pressure at the stretches given (past Gent's locking
    stretch), None where it has one everywhere; the material's own ``max_stretch`` says the
    same, at the cost of a polynomial's roots on every call of a fit.
    """

    name: str
    groups: tuple[str, ...]
    moduli: int
    positive: tuple[bool, ...]
    shape_starts: tuple[float, ...]
    build: Callable[[Sequence[float]], Material]
    locked: Callable[[Sequence[float], FloatArray], NDArray[np.bool_]] | None = None

    def material(self, groups: Sequence[float], thickness_over_radius: float = 1.0) -> Material:
        """The law with moduli = groups over ``thickness_over_radius`` (H / R, or H / a)."""
        values = [g / thickness_over_radius if i < self.moduli else g
                  for i, g in enumerate(groups)]
        return self.build(values)

    def law_parameter_names(self) -> tuple[str, ...]:
        """The law's own parameters as a scene file names them (``shear_modulus_pa``, ``jm``)."""
        return material_parameter_names(self.name)

    def lock(self, groups: Sequence[float]) -> 'Locked | None':
        """Where the law with these groups has no pressure, as a test of the stretch."""
        if self.locked is None:
            return None
        locked = self.locked
        return lambda lam: locked(groups, lam)


# The name the sphere's fit has always had.
SphereLaw = MembraneLaw

MEMBRANE_LAWS = {
    'neo_hookean': MembraneLaw('neo_hookean', ('shear_modulus_h_over_r_pa',), 1, (True,), (),
                               lambda g: NeoHookean(g[0])),
    'mooney_rivlin': MembraneLaw('mooney_rivlin', ('c1_h_over_r_pa', 'c2_h_over_r_pa'), 2,
                                 (False, False), (), lambda g: MooneyRivlin(g[0], g[1])),
    # Jm from nearly rigid chains to nearly neo-Hookean; alpha over what rubbers show.
    'gent': MembraneLaw('gent', ('shear_modulus_h_over_r_pa', 'jm'), 1, (True, True),
                        tuple(np.geomspace(0.3, 3e3, 41)), lambda g: Gent(g[0], g[1]),
                        lambda g, lam: 2.0 * lam**2 + lam**-4 - 3.0 >= g[1]),
    'ogden': MembraneLaw('ogden', ('mu_h_over_r_pa', 'alpha'), 1, (True, True),
                         tuple(np.geomspace(0.2, 20.0, 41)), lambda g: Ogden((g[0],), (g[1],))),
    # Yeoh: the three moduli enter linearly; C1 > 0 (the initial shear modulus is 2 C1), C2
    # and C3 of either sign (C2 < 0 softens before C3 stiffens, as filled rubbers do).
    'yeoh': MembraneLaw('yeoh', ('c1_h_over_r_pa', 'c2_h_over_r_pa', 'c3_h_over_r_pa'), 3,
                        (True, False, False), (), lambda g: Yeoh(g[0], g[1], g[2])),
    # Arruda-Boyce (Abaqus' five terms): lambda_m from chains near full extension at rest to
    # nearly neo-Hookean.
    'arruda_boyce': MembraneLaw('arruda_boyce', ('shear_modulus_h_over_r_pa', 'lambda_m'), 1,
                                (True, True), tuple(np.geomspace(1.05, 50.0, 41)),
                                lambda g: ArrudaBoyce(g[0], g[1])),
}
SPHERE_LAWS = MEMBRANE_LAWS
FIT_LAWS = tuple(MEMBRANE_LAWS)
# The sphere's groups name their length R; another geometry puts its own in its place.
SPHERE_GROUP_SUFFIX = '_h_over_r_pa'


@dataclass(frozen=True)
class Sphere:
    """
    A thin sphere of reference radius R, the project's balloon: the fit's first geometry.

    ``lam = (v / v0)^(1/3)`` with ``v0 = 4/3 pi R^3``, ``p = (H / R) W'(lam) / lam^2``.
    ``radius`` [m]: given, or None: the rest volume is fitted.
    """

    radius: float | None = None

    name = 'sphere'
    description = 'a thin sphere'
    group_suffix = SPHERE_GROUP_SUFFIX

    def __post_init__(self) -> None:
        """A given radius is a length."""
        _check_length('radius', self.radius)

    @property
    def rest_volume(self) -> float | None:
        """The rest volume [m^3] the radius gives, or None: fitted."""
        return None if self.radius is None else rest_volume_of(self.radius)

    def group_names(self, law: MembraneLaw) -> tuple[str, ...]:
        """The law's fitted groups as this geometry names them."""
        return law.groups

    def pressure_and_stretch(self, material: Material, volume: ArrayLike, rest_volume: float,
                             walls: bool = True, locked: Locked | None = None,
                             ) -> tuple[FloatArray, FloatArray]:
        """The pressure [Pa] at ``volume`` and the membrane's stretch there."""
        lam = sphere_stretch(volume, rest_volume)
        return sphere_pressure(material, lam), lam

    def rest_volume_starts(self, volume: FloatArray, volume_scale: float) -> list[float]:
        """Rest volumes tried for a start when it is fitted."""
        return list(volume_scale * REST_VOLUME_STARTS)

    def length(self, rest_volume: float) -> float:
        """The length [m] the moduli are divided by in the groups: R."""
        return radius_of(rest_volume)

    def derived_geometry(self, rest_volume: Callable[[FloatArray], float]) -> list[tuple]:
        """What follows from a fitted rest volume: the radius."""
        return [('radius_m', False, True, lambda x: radius_of(rest_volume(x)))]

    def table_volumes(self, fit: 'LawFit', top: float, rows: int) -> FloatArray:
        """The table's volumes, evenly spaced in stretch (the balloon's features sit low)."""
        lam = np.linspace(1.0, np.cbrt(top / fit.rest_volume), rows)
        return fit.rest_volume * lam**3

    def default_length(self, fit: 'LawFit') -> float:
        """The segment length a table gets when none is given: the sphere's diameter."""
        return 2.0 * fit.radius

    def report(self, fit: 'LawFit') -> dict[str, object]:
        """The geometry, as fit.json holds it."""
        return {'radius_m': {'given': self.radius, 'used_by_chosen_law': fit.radius}}

    def given_lines(self) -> list[str]:
        """The geometry given, as a table's ``#`` lines."""
        return [] if self.radius is None else [f'# radius_m: {self.radius:.6g} (given)']

    def measured_volume_note(self, smallest: float) -> str | None:
        """A warning where the volumes look injected, not whole."""
        if self.radius is None or smallest >= 0.5 * self.rest_volume:
            return None
        return (f'the smallest volume measured ({smallest:.6g} m^3) is less than half the rest '
                f'volume of a sphere of radius {self.radius:g} m ({self.rest_volume:.6g} m^3): '
                'is the volume column the injected volume? It must be the whole')


@dataclass(frozen=True)
class Bulge:
    """
    Membranes bulging as spherical caps out of circular holes in a cavity: the paper's segment.

    As :class:`~softseq_ros.segments.bulge.BulgeSegment` has it: n caps of hole radius a, each
    of rise ``s = h / a`` (stretch ``lam = sqrt(1 + s^2)``) at pressure
    ``p = 2 (H / a) W'(lam) s / lam^3``, on a cavity of rest volume V0 whose side walls swell
    by a compliance C: ``v = V0 + C p + n a^3 pi s (3 + s^2) / 6``. ``hole_radius`` a [m] and
    ``membrane_count`` n give the caps' volume scale n a^3; ``rest_volume`` V0 [m^3] is fitted
    when None; ``wall_compliance`` C [m^3/Pa], 0 for rigid walls.
    """

    hole_radius: float
    membrane_count: int = 1
    rest_volume: float | None = None
    wall_compliance: float = 0.0

    name = 'bulge'
    description = 'membranes bulging out of circular holes'
    group_suffix = '_h_over_a_pa'

    def __post_init__(self) -> None:
        """Every size a finite one: lengths and the rest volume > 0, the compliance >= 0."""
        if self.hole_radius is None:
            raise FitError('hole_radius: a bulge needs the radius of the holes its membranes '
                           'bulge out of [m]')
        _check_length('hole_radius', self.hole_radius)
        count = self.membrane_count
        if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or count < 1:
            raise FitError(f'membrane_count: a whole number of membranes >= 1, got {count!r}')
        if self.rest_volume is not None and not (math.isfinite(self.rest_volume)
                                                 and self.rest_volume > 0.0):
            raise FitError(f'rest_volume: must be a finite volume > 0 m^3, got '
                           f'{self.rest_volume}')
        if not (math.isfinite(self.wall_compliance) and self.wall_compliance >= 0.0):
            raise FitError(f'wall_compliance: must be a finite compliance >= 0 m^3/Pa, got '
                           f'{self.wall_compliance}')

    @property
    def caps_scale(self) -> float:
        """The caps' volume scale n a^3 [m^3]: they hold it times pi s (3 + s^2) / 6."""
        return self.membrane_count * self.hole_radius**3

    def group_names(self, law: MembraneLaw) -> tuple[str, ...]:
        """The law's fitted groups as this geometry names them: moduli times H / a."""
        return tuple(name.replace(SPHERE_GROUP_SUFFIX, self.group_suffix) for name in law.groups)

    def pressure_and_stretch(self, material: Material, volume: ArrayLike, rest_volume: float,
                             walls: bool = True, locked: Locked | None = None,
                             ) -> tuple[FloatArray, FloatArray]:
        """
        The pressure [Pa] at ``volume`` and the caps' stretch there.

        With compliant walls the caps hold what the walls do not, which depends on the
        pressure: their rise is the root of ``caps(s) + C p(s) = v - V0``, bracketed between
        0 and the rise of rigid walls (the walls only take volume from the caps), found by
        Newton's steps kept inside the bracket by bisection. ``walls`` False: as if rigid (a
        start's linear solve). ``locked``: where the law has no pressure (past Gent's locking
        stretch); the walls' solve takes the pressure there as infinite, as it grows towards
        it, so that the root stays short of it.
        """
        injected = np.asarray(volume, dtype=float) - rest_volume
        rise = cap_rise(injected, self.caps_scale)
        if walls and self.wall_compliance > 0.0:
            rise = self._compliant_rise(material, injected, rise, locked)
        pressure = bulge_pressure(material, rise)
        return pressure, np.sqrt(1.0 + rise**2)

    def _compliant_rise(self, material: Material, injected: FloatArray, rigid: FloatArray,
                        locked: Locked | None) -> FloatArray:
        def excess(s: FloatArray) -> FloatArray:
            pressure = bulge_pressure(material, s)
            if locked is not None:
                pressure = np.where(locked(np.sqrt(1.0 + s**2)), np.sign(s) * np.inf, pressure)
            return caps_volume(s, self.caps_scale) + self.wall_compliance * pressure - injected

        low, high = np.minimum(0.0, rigid), np.maximum(0.0, rigid)
        rise = rigid.copy()
        with np.errstate(all='ignore'):   # a slope across a lock is no slope: bisected
            return self._bracketed_root(excess, rise, low, high)

    @staticmethod
    def _bracketed_root(excess: Callable[[FloatArray], FloatArray], rise: FloatArray,
                        low: FloatArray, high: FloatArray) -> FloatArray:
        for _ in range(WALL_SOLVE_STEPS):
            value = excess(rise)
            # The bracket keeps excess(low) <= 0 <= excess(high) whatever the curve's shape.
            high = np.where(value > 0.0, rise, high)
            low = np.where(value < 0.0, rise, low)
            step = WALL_SOLVE_STEP * np.maximum(1.0, np.abs(rise))
            slope = (excess(rise + step) - value) / step
            newton = rise - value / slope
            inside = np.isfinite(newton) & (newton > low) & (newton < high)
            following = np.where(inside, newton, 0.5 * (low + high))
            done = np.abs(following - rise) <= WALL_SOLVE_TOLERANCE * np.maximum(1.0,
                                                                               np.abs(rise))
            rise = following
            if np.all(done | (value == 0.0)):
                break
        return rise

    def rest_volume_starts(self, volume: FloatArray, volume_scale: float) -> list[float]:
        """
        Rest volumes tried for a start when it is fitted.

        At the smallest volume measured and below it by shares of the span measured (a
        measurement may start after some injection), and shares of the smallest as the
        sphere's.
        """
        span = float(np.max(volume)) - volume_scale
        below = volume_scale - BULGE_REST_VOLUME_STARTS * span
        return sorted({float(v) for v in np.concatenate([below, volume_scale
                                                         * REST_VOLUME_STARTS]) if v > 0.0})

    def length(self, rest_volume: float) -> float:
        """The length [m] the moduli are divided by in the groups: a."""
        return self.hole_radius

    def derived_geometry(self, rest_volume: Callable[[FloatArray], float]) -> list[tuple]:
        """A fitted rest volume gives no other size: the caps' scale is given."""
        return []

    def table_volumes(self, fit: 'LawFit', top: float, rows: int) -> FloatArray:
        """The table's volumes, evenly spaced in the caps' stretch, as the sphere's."""
        material = fit.law.material(fit.groups)
        _, lam_top = self.pressure_and_stretch(material, np.array([top]), fit.rest_volume,
                                               locked=fit.law.lock(fit.groups))
        rise = np.sqrt(np.linspace(1.0, float(lam_top[0]), rows)**2 - 1.0)
        pressure = bulge_pressure(material, rise)
        return fit.rest_volume + self.wall_compliance * pressure + caps_volume(rise,
                                                                               self.caps_scale)

    def default_length(self, fit: 'LawFit') -> float:
        """The segment length a table gets when none is given: the holes side by side."""
        return 2.0 * self.hole_radius * self.membrane_count

    def report(self, fit: 'LawFit') -> dict[str, object]:
        """The geometry, as fit.json holds it."""
        return {'hole_radius_m': self.hole_radius, 'membrane_count': int(self.membrane_count),
                'wall_compliance_m3_per_pa': self.wall_compliance,
                'rest_volume_m3': {'given': self.rest_volume,
                                   'used_by_chosen_law': fit.rest_volume}}

    def given_lines(self) -> list[str]:
        """The geometry given, as a table's ``#`` lines."""
        lines = [f'# hole_radius_m: {self.hole_radius:.6g} (given)',
                 f'# membrane_count: {int(self.membrane_count)} (given)',
                 f'# wall_compliance_m3_per_pa: {self.wall_compliance:.6g} (given)']
        if self.rest_volume is not None:
            lines.append(f'# rest_volume_m3: {self.rest_volume:.6g} (given)')
        return lines

    def measured_volume_note(self, smallest: float) -> str | None:
        """A warning where the volumes look injected, not whole."""
        if self.rest_volume is None or smallest >= 0.5 * self.rest_volume:
            return None
        return (f'the smallest volume measured ({smallest:.6g} m^3) is less than half the rest '
                f'volume given ({self.rest_volume:.6g} m^3): is the volume column the injected '
                'volume? It must be the whole')


Geometry = Sphere | Bulge


def _check_length(option: str, value: float | None) -> None:
    if value is not None and not (math.isfinite(value) and value > 0.0):
        raise FitError(f'{option}: must be a finite length > 0 m, got {value}')


@dataclass(frozen=True)
class Estimate:
    """
    One fitted or derived number: its value, standard error and two 95 % intervals.

    ``interval``: from the Jacobian at the optimum (Student's t on the linearised model; for
    a positive quantity on its logarithm, so it stays positive). ``bootstrap``: the 2.5 and
    97.5 percentiles of the parametric bootstrap's refits (None without a bootstrap).
    ``fitted``: a parameter of the fit itself, or else a quantity derived from them.
    """

    name: str
    value: float
    standard_error: float
    interval: tuple[float, float]
    bootstrap: tuple[float, float] | None
    fitted: bool

    def holds(self, value: float) -> bool:
        """Whether the Jacobian interval holds ``value``."""
        return self.interval[0] <= value <= self.interval[1]

    def to_dict(self) -> dict[str, object]:
        """The numbers as fit.json holds them."""
        return {'value': self.value, 'standard_error': self.standard_error,
                'ci95': list(self.interval),
                'bootstrap_ci95': None if self.bootstrap is None else list(self.bootstrap),
                'fitted': self.fitted}


@dataclass(frozen=True)
class _Problem:
    """The rows of every inflation together, with each row's noise and the fit's scales."""

    volume: FloatArray
    pressure: FloatArray
    sigma: FloatArray
    pressure_scale: float
    volume_scale: float
    rest_volume: float | None   # known (given, or from R), or None: fitted

    @property
    def rows(self) -> int:
        return int(self.volume.size)


@dataclass
class LawFit:
    """
    One law fitted to the measurements: its groups, intervals, residuals and criteria.

    ``estimates``: every number by name (the fitted groups, ``rest_volume_m3`` when fitted,
    and derived ones: ``radius_m``, the initial shear modulus times H / R, and with a
    thickness the law's own parameters). ``reduced_chi_square``: the weighted residuals'
    mean square per degree of freedom, about 1 when the law follows the data to their
    noise. ``aicc``, ``bic``: the criteria (lower is better). ``curve``: the pressure as a
    function of the internal parameters and the volumes, for the curve's own uncertainty.
    """

    law: MembraneLaw
    internal: FloatArray
    covariance: FloatArray
    estimates: dict[str, Estimate]
    groups: tuple[float, ...]
    rest_volume: float
    rows: int
    parameters: int
    chi_square: float
    reduced_chi_square: float
    aicc: float
    bic: float
    converged: bool
    at_bound: bool
    message: str
    bootstrap_resamples: int = 0
    bootstrap_failed: int = 0
    curve: Callable[[FloatArray, FloatArray], FloatArray] | None = None
    geometry: Geometry = field(default_factory=Sphere)

    def pressure(self, volume: ArrayLike) -> FloatArray:
        """The fitted curve: gauge pressure [Pa] at ``volume`` [m^3]."""
        return self.geometry.pressure_and_stretch(self.law.material(self.groups), volume,
                                                  self.rest_volume,
                                                  locked=self.law.lock(self.groups))[0]

    def pressure_standard_error(self, volume: ArrayLike) -> FloatArray:
        """
        The fitted curve's standard error [Pa] at ``volume`` [m^3], from the covariance.

        By the delta method: how far the curve itself is uncertain, far less than one row's
        noise where many rows determine it. 0 at a given rest volume, where p = 0 for any
        parameters.
        """
        if self.curve is None:
            raise ValueError('this fit keeps no curve of its parameters')
        volume = np.atleast_1d(np.asarray(volume, dtype=float))
        slopes = np.empty((volume.size, self.internal.size))
        for i in range(self.internal.size):
            step = 1e-6 * max(1.0, abs(float(self.internal[i])))
            up, down = self.internal.copy(), self.internal.copy()
            up[i] += step
            down[i] -= step
            slopes[:, i] = (self.curve(up, volume) - self.curve(down, volume)) / (2.0 * step)
        variance = np.einsum('ij,jk,ik->i', slopes, self.covariance, slopes)
        return np.sqrt(np.maximum(variance, 0.0))

    @property
    def radius(self) -> float:
        """The sphere's reference radius [m] (given, or from the fitted rest volume)."""
        if not isinstance(self.geometry, Sphere):
            raise ValueError(f'a {self.geometry.name} has no sphere radius')
        return radius_of(self.rest_volume)

    def material(self, thickness: float) -> Material:
        """The law itself for a membrane ``thickness`` [m] thick (moduli = groups R / H, a / H)."""
        return self.law.material(self.groups,
                                 thickness / self.geometry.length(self.rest_volume))

    def balloon(self, name: str, length: float, thickness: float,
                max_stretch: float) -> BalloonSegment:
        """The fitted law as a balloon segment (its curve does not depend on ``thickness``)."""
        return BalloonSegment(name, length, self.material(thickness), self.radius, thickness,
                              max_stretch)

    def to_dict(self) -> dict[str, object]:
        """Every number of the fit, as fit.json holds it."""
        return {'parameters': {name: e.to_dict() for name, e in self.estimates.items()},
                'rows': self.rows, 'fitted_parameters': self.parameters,
                'chi_square': self.chi_square, 'reduced_chi_square': self.reduced_chi_square,
                'aicc': self.aicc, 'bic': self.bic, 'converged': self.converged,
                'at_bound': self.at_bound, 'message': self.message,
                'bootstrap_resamples': self.bootstrap_resamples,
                'bootstrap_failed': self.bootstrap_failed}


@dataclass
class MembraneFit:
    """
    Every law fitted to the inflations of one segment, and the one AICc chooses.

    ``noise_std``: each inflation's noise [Pa], from its raw rows; ``pooled_noise_std``: their
    mean square, each weighted by its number of differences. ``geometry``: the segment's, with
    what was given of it.
    """

    inflations: tuple[Inflation, ...]
    noise_std: tuple[float, ...]
    pooled_noise_std: float
    geometry: Geometry
    thickness: float | None
    laws: dict[str, LawFit]
    chosen: str
    bootstrap_resamples: int
    seed: int
    notes: list[str] = field(default_factory=list)

    @property
    def best(self) -> LawFit:
        """The chosen law's fit."""
        return self.laws[self.chosen]

    @property
    def radius_given(self) -> float | None:
        """The sphere's radius where it was given (None for another geometry)."""
        return self.geometry.radius if isinstance(self.geometry, Sphere) else None

    def by_bic(self) -> str:
        """The law BIC would choose (said beside AICc's choice when they differ)."""
        return min(self.laws, key=lambda name: self.laws[name].bic)

    def table(self, rows: int = TABLE_ROWS) -> tuple[FloatArray, FloatArray]:
        """
        The chosen law's curve as a segment table: volumes [m^3] and gauge pressures [Pa].

        From the rest volume to the largest volume measured, evenly spaced in stretch (the
        balloon's features sit at small volumes).
        """
        fit = self.best
        top = max(float(np.max(i.volume)) for i in self.inflations)
        if top <= fit.rest_volume:
            raise FitError(f'the fitted rest volume ({fit.rest_volume:.6g} m^3) is beyond the '
                           f'largest volume measured ({top:.6g} m^3): no curve to tabulate')
        volume = self.geometry.table_volumes(fit, top, rows)
        volume[0], volume[-1] = fit.rest_volume, top
        return volume, fit.pressure(volume)

    def table_noise_std(self) -> float:
        """
        The uncertainty [Pa] of the table's peaks and valleys: what they are weighed against.

        ``softseq classify`` weighs each peak-valley feature of a table against the noise its
        ``# noise_std_pa:`` line declares. The rows here are a law's, so their uncertainty is
        its parameters', far less than one measured row's noise: the chosen curve's largest
        standard error at its turning rows (a peak's or valley's pressure is known as well as
        the curve is there, its slope being 0), or along the whole curve when it has none.
        Not the steep start, where an uncertain rest volume moves the pressure a lot at one
        volume but no feature lies.
        """
        volume, pressure = self.table()
        error = self.best.pressure_standard_error(volume)
        turning = np.flatnonzero(np.diff(np.sign(np.diff(pressure)))) + 1
        if turning.size == 0:
            return float(np.max(error))
        near = np.unique(np.clip(np.concatenate([turning - 1, turning, turning + 1]), 0,
                                 volume.size - 1))
        return float(np.max(error[near]))

    def to_dict(self) -> dict[str, object]:
        """Every number, SI, as fit.json holds it."""
        weights = akaike_weights([self.laws[name].aicc for name in self.laws])
        best = self.best
        return {
            'geometry': self.geometry.name,
            'inflations': [{'source': i.source, 'rows': int(i.volume.size),
                            'noise_std_pa': s} for i, s in zip(self.inflations, self.noise_std)],
            'noise_std_pa': self.pooled_noise_std,
            'table_noise_std_pa': self.table_noise_std(),
            **self.geometry.report(best),
            'thickness_m': self.thickness,
            'criterion': 'AICc',
            'chosen_law': self.chosen,
            'chosen_by_bic': self.by_bic(),
            'confidence': CONFIDENCE,
            'bootstrap': {'resamples': self.bootstrap_resamples, 'seed': self.seed},
            'laws': {name: {**fit.to_dict(), 'delta_aicc': fit.aicc - best.aicc,
                            'akaike_weight': weight}
                     for (name, fit), weight in zip(self.laws.items(), weights)},
            'notes': list(self.notes),
        }


# The name the sphere's fit has always had.
SphereFit = MembraneFit


def akaike_weights(criteria: Sequence[float]) -> list[float]:
    """Each model's weight of evidence, exp(-delta / 2) normalised (delta from the lowest)."""
    values = np.asarray(criteria, dtype=float)
    relative = np.exp(-0.5 * (values - np.min(values)))
    return (relative / relative.sum()).tolist()


def information_criteria(chi_square: float, rows: int, parameters: int) -> tuple[float, float]:
    """
    AICc and BIC of a least-squares fit whose noise scale is estimated with it.

    ``parameters`` counts the fitted ones; the noise scale makes one more. The constant every
    law shares (the weights' logarithms) is left out: only differences mean something.
    """
    k = parameters + 1
    # A law through every row exactly (synthetic rows) would have no logarithm.
    fit_term = rows * math.log(max(chi_square, 1e-300) / rows)
    aicc = fit_term + 2.0 * k + (2.0 * k * (k + 1) / (rows - k - 1) if rows > k + 1
                                 else math.inf)
    return aicc, fit_term + k * math.log(rows)


class _LawModel:
    """One law on one geometry: internal parameters <-> groups, and the weighted residuals."""

    def __init__(self, law: MembraneLaw, problem: _Problem, geometry: Geometry) -> None:
        self.law = law
        self.problem = problem
        self.geometry = geometry
        self.size = len(law.groups) + (problem.rest_volume is None)

    def groups(self, internal: FloatArray) -> tuple[float, ...]:
        scale = self.problem.pressure_scale
        values = []
        for i, positive in enumerate(self.law.positive):
            unit = scale if i < self.law.moduli else 1.0
            values.append(float(unit * (math.exp(internal[i]) if positive else internal[i])))
        return tuple(values)

    def rest_volume(self, internal: FloatArray) -> float:
        if self.problem.rest_volume is not None:
            return self.problem.rest_volume
        return float(self.problem.volume_scale * math.exp(internal[-1]))

    def internal(self, groups: Sequence[float], rest_volume: float) -> FloatArray:
        scale = self.problem.pressure_scale
        values = []
        for i, (g, positive) in enumerate(zip(groups, self.law.positive)):
            g = g / scale if i < self.law.moduli else g
            values.append(math.log(g) if positive else g)
        if self.problem.rest_volume is None:
            values.append(math.log(rest_volume / self.problem.volume_scale))
        return np.asarray(values)

    def curve(self, internal: FloatArray, volume: FloatArray) -> FloatArray:
        material = self.law.material(self.groups(internal))
        with np.errstate(all='ignore'):
            pressure, lam = self.geometry.pressure_and_stretch(
                material, volume, self.rest_volume(internal),
                locked=self.law.lock(self.groups(internal)))
        if self.law.locked is None:
            return pressure
        # Past a locking stretch (Gent) the law has no pressure: no step may go there.
        return np.where(self.law.locked(self.groups(internal), lam), np.inf, pressure)

    def residuals(self, internal: FloatArray, pressure: FloatArray) -> FloatArray:
        return (self.curve(internal, self.problem.volume) - pressure) / self.problem.sigma

    def start(self) -> FloatArray:
        """
        A start near the optimum: the moduli solved linearly on a grid of the rest.

        The pressure is linear in the moduli, so for each rest volume and shape parameter
        tried their weighted least-squares values are exact; the best of the grid starts the
        nonlinear fit.
        """
        problem = self.problem
        rests = ([problem.rest_volume] if problem.rest_volume is not None
                 else self.geometry.rest_volume_starts(problem.volume, problem.volume_scale))
        weight = 1.0 / problem.sigma
        target = problem.pressure * weight
        best, best_cost = None, math.inf
        for shape in self.law.shape_starts or (None,):
            shape_values = [] if shape is None else [shape]
            # One material per modulus, the others 0: the columns of the linear problem.
            units = [self.law.build([float(i == m) for i in range(self.law.moduli)]
                                    + shape_values) for m in range(self.law.moduli)]
            for rest in rests:
                # Compliant walls make the stretch depend on the moduli: the start takes
                # them rigid, and the fit itself what they take.
                with np.errstate(all='ignore'):
                    columns = [self.geometry.pressure_and_stretch(m, problem.volume, rest,
                                                                  walls=False) for m in units]
                lam = columns[0][1]
                if self.law.locked is not None and np.any(
                        self.law.locked([1.0, *shape_values], lam)):
                    continue
                design = np.column_stack([pressure for pressure, _ in columns]) \
                    * weight[:, None]
                moduli, *_ = np.linalg.lstsq(design, target, rcond=None)
                if any(p and m <= 0.0 for p, m in zip(self.law.positive, moduli)):
                    continue
                cost = float(np.sum((design @ moduli - target) ** 2))
                if cost < best_cost:
                    best = self.internal([*moduli.tolist(), *shape_values], rest)
                    best_cost = cost
        if best is None:
            raise FitError(f'{self.law.name}: no start found: the pressures do not rise with '
                           "the volume as an inflated membrane's do")
        return best

    def solve(self, pressure: FloatArray, start: FloatArray) -> object:
        bound = np.full(self.size, INTERNAL_BOUND)
        return least_squares(self.residuals, np.clip(start, -bound, bound), args=(pressure,),
                             bounds=(-bound, bound), method='trf', x_scale=1.0,
                             ftol=FIT_TOLERANCE, xtol=FIT_TOLERANCE, gtol=FIT_TOLERANCE)

    def quantities(self, thickness: float | None) -> list[tuple[str, bool, bool, Callable]]:
        """
        What is reported, as (name, fitted, positive, function of the internal parameters).

        The fitted groups (and rest volume) first, then what follows from them.
        """
        law, geometry = self.law, self.geometry
        found: list[tuple[str, bool, bool, Callable]] = []
        for i, (name, positive) in enumerate(zip(geometry.group_names(law), law.positive)):
            found.append((name, True, positive, lambda x, i=i: self.groups(x)[i]))
        if self.problem.rest_volume is None:
            found.append(('rest_volume_m3', True, True, self.rest_volume))
            found += geometry.derived_geometry(self.rest_volume)
        if law.name in ('mooney_rivlin', 'ogden'):
            found.append((f'shear_modulus{geometry.group_suffix}', False, law.name == 'ogden',
                          lambda x: law.material(self.groups(x)).shear_modulus))
        if thickness is not None:
            for i, (name, positive) in enumerate(zip(law.law_parameter_names(), law.positive)):
                if i >= law.moduli:
                    break
                found.append((name, False, positive, lambda x, i=i: self.groups(x)[i]
                              * geometry.length(self.rest_volume(x)) / thickness))
        return found


def _noise_of(inflation: Inflation) -> float:
    sigma = estimate_noise_std(inflation.volume, inflation.pressure)
    return max(sigma, NOISE_FLOOR * float(np.max(np.abs(inflation.pressure))))


def _problem(inflations: Sequence[Inflation], noise: Sequence[float],
             rest_volume: float | None) -> _Problem:
    volume = np.concatenate([i.volume for i in inflations])
    pressure = np.concatenate([i.pressure for i in inflations])
    sigma = np.concatenate([np.full(i.volume.size, s) for i, s in zip(inflations, noise)])
    scale = float(np.max(np.abs(pressure)))
    return _Problem(volume, pressure, sigma, scale if scale > 0.0 else 1.0,
                    float(min(np.min(i.volume) for i in inflations)), rest_volume)


def _interval(value: float, spread: float, positive: bool,
              quantile: float) -> tuple[float, float, float]:
    """
    Standard error and interval of a quantity from its spread (see Estimate).

    ``spread``: the standard deviation of the quantity, or of its logarithm when positive.
    """
    if positive:
        # A quantity the data do not fix (Gent's Jm far beyond the stretches measured) has a
        # spread whose exponential overflows: its interval is open to infinity.
        half = min(quantile * spread, MAX_LOG_SPREAD)
        return (abs(value) * spread, value * math.exp(-half),
                value * math.exp(half) if half < MAX_LOG_SPREAD else math.inf)
    return spread, value - quantile * spread, value + quantile * spread


def fit_law(law: str | MembraneLaw, inflations: Sequence[Inflation],
            noise_std: Sequence[float] | None = None, radius: float | None = None,
            thickness: float | None = None, bootstrap: int = 0,
            seed: int = 0, geometry: Geometry | None = None) -> LawFit:
    """
    One law fitted to the inflations of a sphere or a bulge (see the module's description).

    ``noise_std``: each inflation's noise [Pa] (estimated from its rows when None).
    ``radius`` [m]: the sphere's reference radius when known (else its rest volume is
    fitted); ``thickness`` [m]: the membrane's, to report the law's own moduli.
    ``bootstrap``: parametric resamples for the percentile intervals (0: none), from
    ``seed``. ``geometry``: a :class:`Bulge` (or a :class:`Sphere`) in place of ``radius``.
    """
    from scipy.stats import t as student_t  # 0.3 s to import: only where a fit runs

    law = MEMBRANE_LAWS[law] if isinstance(law, str) else law
    geometry = _geometry(geometry, radius)
    inflations = tuple(inflations)
    noise = [_noise_of(i) for i in inflations] if noise_std is None else list(noise_std)
    problem = _problem(inflations, noise, geometry.rest_volume)
    model = _LawModel(law, problem, geometry)
    result = model.solve(problem.pressure, model.start())
    x = np.asarray(result.x, dtype=float)
    rows, k = problem.rows, model.size
    chi_square = float(np.sum(result.fun**2))
    dof = rows - k
    if dof < 1:
        raise FitError(f'{law.name}: {rows} rows cannot fit {k} parameters')
    reduced = chi_square / dof
    jacobian = np.asarray(result.jac, dtype=float)
    # (J^T J)^-1 s^2 by the pseudo-inverse: a direction the data do not fix gets no
    # spurious precision from round-off, and shows as a huge interval instead.
    covariance = np.linalg.pinv(jacobian.T @ jacobian) * reduced
    aicc, bic = information_criteria(chi_square, rows, k)
    quantile = float(student_t.ppf(0.5 + CONFIDENCE / 2.0, dof))
    quantities = model.quantities(thickness)
    samples = _bootstrap(model, x, reduced, bootstrap, seed, quantities) if bootstrap else None
    estimates = {}
    for index, (name, fitted, positive, function) in enumerate(quantities):
        value = float(function(x))
        gradient = _gradient(function, x, positive)
        spread = float(math.sqrt(max(gradient @ covariance @ gradient, 0.0)))
        error, low, high = _interval(value, spread, positive, quantile)
        percentiles = None
        if samples is not None and samples[0].size:
            column = samples[0][:, index]
            percentiles = (float(np.percentile(column, 2.5)), float(np.percentile(column, 97.5)))
        estimates[name] = Estimate(name, value, error, (low, high), percentiles, fitted)
    return LawFit(law, x, covariance, estimates, model.groups(x), model.rest_volume(x), rows, k,
                  chi_square, reduced, aicc, bic, bool(result.success),
                  bool(np.any(np.abs(x) >= INTERNAL_BOUND * (1.0 - 1e-9))),
                  str(result.message), bootstrap,
                  0 if samples is None else samples[1], curve=model.curve, geometry=geometry)


def _geometry(geometry: Geometry | None, radius: float | None) -> Geometry:
    if geometry is None:
        return Sphere(radius)
    if radius is not None:
        raise FitError("radius: a sphere's; the geometry given takes its own sizes")
    return geometry


def _gradient(function: Callable, x: FloatArray, positive: bool) -> FloatArray:
    """D(quantity)/d(internal) by central differences (of its logarithm when positive)."""
    def value(at: FloatArray) -> float:
        q = float(function(at))
        return math.log(q) if positive else q

    gradient = np.empty(x.size)
    for i in range(x.size):
        step = 1e-6 * max(1.0, abs(x[i]))
        up, down = x.copy(), x.copy()
        up[i] += step
        down[i] -= step
        gradient[i] = (value(up) - value(down)) / (2.0 * step)
    return gradient


def _bootstrap(model: _LawModel, x: FloatArray, reduced: float, resamples: int, seed: int,
               quantities: list) -> tuple[FloatArray, int]:
    """
    The quantities refitted on ``resamples`` synthetic inflations, and how many failed.

    Each is the fitted curve plus normal noise of each row's deviation times the fit's
    residual scale (so the bootstrap and the Jacobian intervals assume the same noise), refit
    from the optimum.
    """
    rng = np.random.default_rng(seed)
    curve = model.curve(x, model.problem.volume)
    deviation = model.problem.sigma * math.sqrt(reduced)
    rows, failed = [], 0
    for _ in range(resamples):
        synthetic = curve + deviation * rng.standard_normal(curve.size)
        result = model.solve(synthetic, x)
        if not result.success:
            failed += 1
            continue
        rows.append([float(function(result.x)) for *_, function in quantities])
    return np.asarray(rows, dtype=float).reshape(-1, len(quantities)), failed


def fit_sphere(inflations: Sequence[Inflation], radius: float | None = None,
               thickness: float | None = None, laws: Sequence[str] = FIT_LAWS,
               bootstrap: int = BOOTSTRAP_RESAMPLES, seed: int = 0) -> MembraneFit:
    """
    Every law of ``laws`` fitted to the inflations of one sphere, the best chosen by AICc.

    ``radius``, ``thickness`` [m]: the sphere's, where known (see :func:`fit_law`).
    ``bootstrap``: parametric resamples per law for the percentile intervals (0: none), each
    law's from ``seed``. FitError (one line) for options that cannot be used.
    """
    _check_length('radius', radius)
    return fit_membrane(inflations, Sphere(radius), thickness, laws, bootstrap, seed)


def fit_bulge(inflations: Sequence[Inflation], hole_radius: float, membrane_count: int = 1,
              rest_volume: float | None = None, wall_compliance: float = 0.0,
              thickness: float | None = None, laws: Sequence[str] = FIT_LAWS,
              bootstrap: int = BOOTSTRAP_RESAMPLES, seed: int = 0) -> MembraneFit:
    """
    Every law of ``laws`` fitted to the inflations of one bulge segment, the best by AICc.

    ``hole_radius`` [m] and ``membrane_count``: the holes the membranes bulge out of;
    ``rest_volume`` [m^3]: the cavity's at rest, fitted when None; ``wall_compliance``
    [m^3/Pa]: the side walls' (0: rigid); ``thickness`` [m]: the membrane's, to report the
    law's own moduli (see :class:`Bulge`). The rest as :func:`fit_sphere`.
    """
    return fit_membrane(inflations, Bulge(hole_radius, membrane_count, rest_volume,
                                          wall_compliance), thickness, laws, bootstrap, seed)


def fit_membrane(inflations: Sequence[Inflation], geometry: Geometry,
                 thickness: float | None = None, laws: Sequence[str] = FIT_LAWS,
                 bootstrap: int = BOOTSTRAP_RESAMPLES, seed: int = 0) -> MembraneFit:
    """
    Every law of ``laws`` fitted to the inflations of one segment, the best chosen by AICc.

    ``geometry``: a :class:`Sphere` or a :class:`Bulge`; see :func:`fit_sphere` and
    :func:`fit_bulge`.
    """
    inflations = tuple(inflations)
    if not inflations:
        raise FitError('no inflation to fit')
    _check_length('thickness', thickness)
    unknown = [name for name in laws if name not in MEMBRANE_LAWS]
    if unknown or not laws:
        raise FitError(f'unknown law {", ".join(unknown) or "(none)"}; the fit knows '
                       f'{", ".join(FIT_LAWS)}')
    if bootstrap < 0:
        raise FitError(f'bootstrap: a number of resamples >= 0, got {bootstrap}')
    noise = [_noise_of(i) for i in inflations]
    counts = [i.volume.size - 3 for i in inflations]
    pooled = math.sqrt(sum(c * s**2 for c, s in zip(counts, noise)) / sum(counts))
    notes = []
    note = geometry.measured_volume_note(min(float(np.min(i.volume)) for i in inflations))
    if note is not None:
        notes.append(note)
    fits = {name: fit_law(name, inflations, noise, None, thickness, bootstrap, seed, geometry)
            for name in laws}
    chosen = min(fits, key=lambda name: fits[name].aicc)
    for name, fit in fits.items():
        if not fit.converged:
            notes.append(f'{name}: the fit did not converge ({fit.message})')
        if fit.at_bound:
            notes.append(f'{name}: a parameter ran to the edge of its range; its intervals '
                         'do not hold')
    return MembraneFit(inflations, tuple(noise), pooled, geometry, thickness, fits, chosen,
                       bootstrap, seed, notes)


# ---------------------------------------------------------------------------------------------
# Inflation and deflation: the unloading branch and the hysteresis between the two

# A cycle's deflation must end within this share of its swept volume of where its inflation
# began: a loop left open has no area that means a cycle's dissipation.
LOOP_CLOSURE_SHARE = 0.05
# The softening is averaged where the loading pressure is at least this share of its largest
# over the shared volumes: near the rest volume both pressures vanish and their ratio says
# nothing.
SOFTENING_FLOOR = 0.2
# Points of the Gauss-Legendre rule that integrates the fitted curves (smooth, so far more than
# enough) and of the grid the softening is averaged on.
LOOP_QUADRATURE_POINTS = 64
SOFTENING_POINTS = 401


@dataclass(frozen=True)
class Deflation:
    """
    One measured deflation of the segment: volumes [m^3] strictly falling, gauge Pa.

    The rows after the cycle's largest volume, which its inflation ends on: at the turn the
    pressure drops at nearly the same volume (a viscoelastic membrane relaxes), so that row
    is the loading's. :meth:`rising` gives the same rows in rising volume, as the fit takes a
    branch.
    """

    volume: FloatArray
    pressure: FloatArray
    source: str = 'deflation'
    curvature: FloatArray | None = None

    def __post_init__(self) -> None:
        """Check the rows are usable: enough, finite and in falling volume."""
        volume = _take_rows(self, 'the deflation (the rows after the largest volume) has '
                                  '{rows} rows, too few to fit: at least {least} (its noise is '
                                  'estimated from its own rows)')
        steps = np.diff(volume)
        if np.any(steps >= 0.0):
            row = int(np.argmax(steps >= 0.0)) + 2
            raise FitError(f'{self.source}: volume_m3 must fall strictly in the deflation '
                           f'(after the largest volume; one cycle per file); deflation row '
                           f'{row} ({volume[row - 1]:.6g}) is not below row {row - 1} '
                           f'({volume[row - 2]:.6g})')
        if volume[-1] <= 0.0:
            raise FitError(f"{self.source}: volume_m3 must be > 0 (the segment's whole "
                           f'volume, not the volume injected), got {volume[-1]:.6g} at the '
                           "deflation's end")

    def rising(self) -> Inflation:
        """The rows in rising volume: the unloading branch as the fit takes it."""
        return Inflation(self.volume[::-1].copy(), self.pressure[::-1].copy(), self.source,
                         None if self.curvature is None else self.curvature[::-1].copy())


@dataclass(frozen=True)
class Cycle:
    """One measured file: its inflation, and its deflation when the volume falls again."""

    inflation: Inflation
    deflation: Deflation | None = None

    @property
    def source(self) -> str:
        """The file the cycle was read from."""
        return self.inflation.source

    def loop_area(self) -> float:
        """
        The measured loop's area, the integral of p dv around it [J], by trapezoids.

        From the raw rows, with no law: a check on the fitted curves' number. The deflation's
        last row is joined to the inflation's first by a straight line (the cycle closes
        there within :data:`LOOP_CLOSURE_SHARE`), as the turn joins their other ends.
        """
        if self.deflation is None:
            raise FitError(f'{self.source}: an inflation alone has no loop')
        volume = np.concatenate([self.inflation.volume, self.deflation.volume,
                                 self.inflation.volume[:1]])
        pressure = np.concatenate([self.inflation.pressure, self.deflation.pressure,
                                   self.inflation.pressure[:1]])
        return float(np.sum(0.5 * (pressure[1:] + pressure[:-1]) * np.diff(volume)))


def split_cycle(volume: ArrayLike, pressure: ArrayLike, source: str = 'measurement',
                curvature: ArrayLike | None = None) -> Cycle:
    """
    One file's rows as a cycle: the inflation up to the largest volume, the deflation after.

    Rows whose volume rises to its end are an inflation alone, as before. Rows whose volume
    rises and then falls are an inflation up to the largest volume and a deflation of the rows
    after it; the deflation must fall strictly, have :data:`MIN_ROWS` rows and close the loop
    (end within :data:`LOOP_CLOSURE_SHARE` of the swept volume of where the inflation
    began). FitError, one line naming ``source``, otherwise.
    """
    v = np.asarray(volume, dtype=float)
    p = np.asarray(pressure, dtype=float)
    if v.ndim != 1 or v.shape != p.shape:
        raise FitError(f'{source}: volume and pressure need one row each, as many')
    k = None if curvature is None else np.asarray(curvature, dtype=float)
    if v.size == 0 or not np.all(np.isfinite(v)):
        return Cycle(Inflation(v, p, source, k))   # Inflation names what is wrong
    top = int(np.argmax(v))
    if top == v.size - 1:
        return Cycle(Inflation(v, p, source, k))
    inflation = Inflation(v[:top + 1], p[:top + 1], source, None if k is None else k[:top + 1])
    deflation = Deflation(v[top + 1:], p[top + 1:], source, None if k is None else k[top + 1:])
    swept = float(v[top] - v[0])
    gap = float(deflation.volume[-1] - v[0])
    if abs(gap) > LOOP_CLOSURE_SHARE * swept:
        raise FitError(f'{source}: the loop does not close: the deflation ends at '
                       f'{deflation.volume[-1]:.6g} m^3, {100.0 * abs(gap) / swept:.3g} % of the '
                       f'swept volume from where the inflation began ({v[0]:.6g} m^3); at most '
                       f'{100.0 * LOOP_CLOSURE_SHARE:g} %')
    return Cycle(inflation, deflation)


@dataclass(frozen=True)
class Hysteresis:
    """
    What the loop between the loading and unloading fits says, from their chosen laws.

    Over the volumes both branches measured (``volume_range``): ``dissipated`` [J], the
    integral of the loading minus the unloading pressure, the energy one cycle turns into heat;
    ``loading_work`` [J], the integral of the loading pressure there; ``dissipated_share``,
    their ratio; ``softening``, the volume-mean of the unloading over the loading pressure
    where the loading pressure is at least :data:`SOFTENING_FLOOR` of its largest
    (``softening_range``). Intervals by the delta method on both fits' covariances, the two
    branches measured independently, with the normal quantile. ``measured_loops``: each
    file's loop area from its raw rows, with no law.
    """

    loading_law: str
    unloading_law: str
    volume_range: tuple[float, float]
    softening_range: tuple[float, float]
    dissipated: Estimate
    loading_work: Estimate
    dissipated_share: Estimate
    softening: Estimate
    measured_loops: tuple[tuple[str, float], ...]

    def to_dict(self) -> dict[str, object]:
        """The numbers as fit.json holds them (J, m^3; the share and ratio without unit)."""
        return {
            'loading_law': self.loading_law, 'unloading_law': self.unloading_law,
            'volume_range_m3': list(self.volume_range),
            'dissipated_energy_j': self.dissipated.to_dict(),
            'loading_work_j': self.loading_work.to_dict(),
            'dissipated_share_of_loading_work': self.dissipated_share.to_dict(),
            'softening_ratio': self.softening.to_dict(),
            'softening_volume_range_m3': list(self.softening_range),
            'measured_loop_area_j': [{'source': source, 'value': area}
                                     for source, area in self.measured_loops],
        }


def hysteresis(loading: LawFit, unloading: LawFit, volume_range: tuple[float, float],
               cycles: Sequence[Cycle] = ()) -> Hysteresis:
    """
    The loop between a loading and an unloading fit over ``volume_range`` [m^3].

    See :class:`Hysteresis`. ``cycles``: the measured files, for their raw loop areas.
    """
    low, high = volume_range
    if not high > low:
        raise FitError(f'the loading and unloading branches share no volumes (from {low:.6g} '
                       f'to {high:.6g} m^3)')
    if loading.curve is None or unloading.curve is None:
        raise ValueError('the hysteresis needs fits that keep their curves')
    nodes, weights = np.polynomial.legendre.leggauss(LOOP_QUADRATURE_POINTS)
    volume = 0.5 * (high - low) * nodes + 0.5 * (high + low)
    weights = 0.5 * (high - low) * weights
    grid = np.linspace(low, high, SOFTENING_POINTS)
    loading_grid = loading.pressure(grid)
    kept = grid[loading_grid >= SOFTENING_FLOOR * float(np.max(loading_grid))]
    if kept.size == 0:
        raise FitError('the loading pressure is nowhere above zero over the shared volumes: '
                       'no softening to measure')

    def work(x: FloatArray) -> float:
        return float(weights @ loading.curve(x, volume))

    def dissipated(x: FloatArray, y: FloatArray) -> float:
        return float(weights @ (loading.curve(x, volume) - unloading.curve(y, volume)))

    def share(x: FloatArray, y: FloatArray) -> float:
        return dissipated(x, y) / work(x)

    def softening(x: FloatArray, y: FloatArray) -> float:
        return float(np.mean(unloading.curve(y, kept) / loading.curve(x, kept)))

    def estimate(name: str, function: Callable[[FloatArray, FloatArray], float]) -> Estimate:
        x, y = loading.internal, unloading.internal
        value = float(function(x, y))
        variance = 0.0
        for fit, gradient in ((loading, _gradient(lambda at: function(at, y), x, False)),
                              (unloading, _gradient(lambda at: function(x, at), y, False))):
            variance += float(gradient @ fit.covariance @ gradient)
        error = math.sqrt(max(variance, 0.0))
        quantile = _normal_quantile()
        return Estimate(name, value, error, (value - quantile * error, value + quantile * error),
                        None, False)

    loops = tuple((c.source, c.loop_area()) for c in cycles if c.deflation is not None)
    return Hysteresis(loading.law.name, unloading.law.name, (float(low), float(high)),
                      (float(kept[0]), float(kept[-1])),
                      estimate('dissipated_energy_j', dissipated),
                      estimate('loading_work_j', lambda x, _y: work(x)),
                      estimate('dissipated_share_of_loading_work', share),
                      estimate('softening_ratio', softening), loops)


def _normal_quantile() -> float:
    from scipy.stats import norm  # as student_t in fit_law: only where a fit runs

    return float(norm.ppf(0.5 + CONFIDENCE / 2.0))


@dataclass
class CycleFit:
    """
    The laws fitted to both branches of measured cycles, and the hysteresis between them.

    ``loading``: the fit of the inflations (every file's), as without deflations;
    ``unloading``: the same laws fitted to the deflations, each file's rows weighted by their
    own noise; ``hysteresis``: the loop between the two chosen laws.
    """

    cycles: tuple[Cycle, ...]
    loading: MembraneFit
    unloading: MembraneFit
    hysteresis: Hysteresis

    @property
    def notes(self) -> list[str]:
        """Both branches' warnings, the unloading's marked so."""
        return self.loading.notes + self.unloading.notes


def shared_volumes(cycles: Sequence[Cycle]) -> tuple[float, float]:
    """
    The volumes [m^3] the loop spans, from the two branches' smallest to the turn.

    From the higher of the branches' smallest volumes to the turn, the smallest largest
    volume of the cycles with a deflation. The unloading curve reaches the turn from its
    first row, one row's step below: the loop's top belongs to it, and a law's closed form
    extrapolates that far without harm.
    """
    inflations = [c.inflation for c in cycles]
    deflations = [c.deflation for c in cycles if c.deflation is not None]
    low = max(min(float(np.min(i.volume)) for i in inflations),
              min(float(np.min(d.volume)) for d in deflations))
    high = min(float(np.max(c.inflation.volume)) for c in cycles if c.deflation is not None)
    return low, high


def fit_cycles(cycles: Sequence[Cycle], radius: float | None = None,
               thickness: float | None = None, laws: Sequence[str] = FIT_LAWS,
               bootstrap: int = BOOTSTRAP_RESAMPLES, seed: int = 0,
               geometry: Geometry | None = None) -> MembraneFit | CycleFit:
    """
    Every law fitted to the measured cycles of one segment, loading and unloading.

    The loading branch always; where any file has a deflation, the unloading branch too and
    the hysteresis between them.

    Inflations alone give the :class:`MembraneFit` of :func:`fit_sphere` (or, with a
    :class:`Bulge` as ``geometry``, of :func:`fit_bulge`), as ever; with deflations, a
    :class:`CycleFit`. The options are :func:`fit_sphere`'s, for both branches (each rest
    volume fitted on its own when neither ``radius`` nor the geometry's rest volume is given:
    a softened membrane may keep a residual stretch).
    """
    cycles = tuple(cycles)
    _check_length('radius', radius)
    geometry = _geometry(geometry, radius)
    loading = fit_membrane([c.inflation for c in cycles], geometry, thickness, laws, bootstrap,
                           seed)
    deflations = [c.deflation.rising() for c in cycles if c.deflation is not None]
    if not deflations:
        return loading
    unloading = fit_membrane(deflations, geometry, thickness, laws, bootstrap, seed)
    unloading.notes[:] = [f'unloading: {note}' for note in unloading.notes]
    low, high = shared_volumes(cycles)
    best = unloading.best
    if best.curve is not None and not np.all(np.isfinite(best.curve(best.internal,
                                                                    np.array([high])))):
        # A Gent unloading law may lock in the one row's step between its data and the turn.
        top = max(float(np.max(d.volume)) for d in deflations)
        unloading.notes.append(f'unloading: the {unloading.chosen} law has no pressure at the '
                               f'turn ({high:.6g} m^3); the loop is measured up to the '
                               f'largest deflation volume ({top:.6g} m^3)')
        high = top
    loop = hysteresis(loading.best, unloading.best, (low, high), cycles)
    return CycleFit(cycles, loading, unloading, loop)
