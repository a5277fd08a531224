"""
Segment models: each gives pressure, stiffness, stored energy and curvature as functions of volume.

A segment is one elastic inflatable actuator. Everything the equilibrium solver needs from it is
here: ``pressure(v)`` (gauge, Pa), ``stiffness(v) = dp/dv`` (Pa/m^3), ``energy(v)`` (J, the
integral of p dv from the rest volume) and ``curvature(v)`` (1/m), plus its split into monotone
pieces (rising or falling stretches of the pressure-volume curve), which the solver
assembles.
"""

from abc import ABC, abstractmethod
from bisect import bisect_right
from dataclasses import dataclass
import math
from typing import Iterable, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import PchipInterpolator
from scipy.optimize import brentq

from softseq_ros.errors import UserError
from softseq_ros.segments.identity import exact, exact_list
from softseq_ros.segments.materials import Material, material_definition
from softseq_ros.tolerances import DEFAULT_TOLERANCES, ConvergenceLog, Tolerances

FloatArray = NDArray[np.float64]
# A turning volume of a law's curve is found to this share of its largest volume.
TURN_XTOL = 1e-15
# The central difference of dW/dlambda steps this share of the stretch: a millionth balances
# truncation against round-off in double precision.
STRETCH_STEP = 1e-6


# Why a curve that falls or stays level from its first row to its last is refused.
NEVER_RISES = ('its pressure never rises with its volume (it falls or stays level from the '
               'first row to the last): no state of it is stable')


class TableError(UserError):
    """A segment table that cannot be used; the message starts with the file name."""


@dataclass(frozen=True)
class Piece:
    """A stretch [v_lo, v_hi] of a PV curve on which the pressure rises (+1) or falls (-1)."""

    v_lo: float
    v_hi: float
    direction: int
    p_at_lo: float
    p_at_hi: float

    @property
    def p_min(self) -> float:
        """Lowest pressure on the piece."""
        return min(self.p_at_lo, self.p_at_hi)

    @property
    def p_max(self) -> float:
        """Highest pressure on the piece."""
        return max(self.p_at_lo, self.p_at_hi)


def newton_start(piece: Piece, target: FloatArray,
                 ulps: float) -> tuple[FloatArray, FloatArray, FloatArray, float]:
    """
    Where the safeguarded Newton on ``piece`` starts for pressures ``target``.

    The bracket (lo, hi: the piece's ends), the first guess (linear in the pressure across the
    piece) and the residual that counts as round-off; shared by every inversion of a piece.
    """
    lo = np.full(target.shape, piece.v_lo)
    hi = np.full(target.shape, piece.v_hi)
    span = piece.p_at_hi - piece.p_at_lo
    guess = piece.v_lo + (piece.v_hi - piece.v_lo) * np.clip(
        (target - piece.p_at_lo) / span, 0.0, 1.0) if span else 0.5 * (lo + hi)
    x = np.broadcast_to(guess, target.shape).astype(float)
    floor = ulps * np.finfo(float).eps * max(abs(piece.p_at_lo), abs(piece.p_at_hi), 1e-300)
    return lo, hi, x, floor


def at_piece_ends(piece: Piece, target: FloatArray, volumes: FloatArray) -> FloatArray:
    """
    ``volumes``, with a pressure at one of the piece's ends mapped to that end exactly.

    Near a peak the pressure is flat to round-off over a stretch of volume, and the junctions
    between pieces must agree.
    """
    volumes = np.where(target == piece.p_at_lo, piece.v_lo, volumes)
    return np.where(target == piece.p_at_hi, piece.v_hi, volumes)



def rising_pieces(segment: 'Segment') -> list[Piece]:
    """A segment's rising pieces, base to top: where it is stable alone at a held pressure."""
    return [piece for piece in segment.monotone_pieces() if piece.direction > 0]


def piece_holding(rising: Sequence[Piece], pressure: float, order: Iterable[int]) -> int | None:
    """The first rising piece, of the indices in ``order``, that reaches ``pressure``."""
    return next((k for k in order if rising[k].p_min <= pressure <= rising[k].p_max), None)

class Segment(ABC):
    """One inflatable segment: its PV curve, stored energy and curvature."""

    def __init__(self, name: str, length: float, rest_volume: float, max_volume: float) -> None:
        """Check the geometry every model shares."""
        if not name:
            raise ValueError('a segment needs a name')
        if not (math.isfinite(length) and length > 0.0):
            raise ValueError(f'segment {name!r}: length must be > 0 m, got {length}')
        if not (math.isfinite(rest_volume) and rest_volume >= 0.0):
            raise ValueError(f'segment {name!r}: rest volume must be >= 0 m^3, got {rest_volume}')
        if not (math.isfinite(max_volume) and max_volume > rest_volume):
            raise ValueError(f'segment {name!r}: max volume ({max_volume} m^3) must exceed the '
                             f'rest volume ({rest_volume} m^3)')
        self.name = name
        self.length = float(length)
        self.rest_volume = float(rest_volume)
        self.max_volume = float(max_volume)
        self._pieces: list[Piece] | None = None

    @abstractmethod
    def pressure(self, v: ArrayLike) -> FloatArray:
        """Gauge pressure at volume v, in Pa."""

    @abstractmethod
    def stiffness(self, v: ArrayLike) -> FloatArray:
        """Derivative dp/dv at volume v, in Pa/m^3."""

    @abstractmethod
    def energy(self, v: ArrayLike) -> FloatArray:
        """Stored energy, integral of p dv from the rest volume to v, in J."""

    @abstractmethod
    def curvature(self, v: ArrayLike) -> FloatArray:
        """Backbone curvature at volume v, in 1/m."""

    @abstractmethod
    def curvature_slope(self, v: ArrayLike) -> FloatArray:
        """Derivative of the curvature with respect to volume, in 1/m per m^3."""

    @abstractmethod
    def _turning_volumes(self) -> list[float]:
        """Volumes where the pressure changes direction."""

    def knots(self) -> FloatArray:
        """Volumes where the model is less smooth than elsewhere (a table's rows)."""
        return np.empty(0)

    def pressure_cubics(self) -> tuple[FloatArray, FloatArray, FloatArray] | None:
        """
        The pressure as a piecewise polynomial, when it is one; None for a closed-form model.

        Breaks (m + 1,), coefficients of the pressure (k, m) and of the stiffness (k - 1, m).
        Coefficients in scipy's PPoly layout (highest power of v - breaks[i] first), so a
        solver can evaluate many volumes with array arithmetic alone (:func:`polynomial_at`
        gives the numbers :meth:`pressure` and :meth:`stiffness` give).
        """
        return None

    def definition(self) -> dict[str, object]:
        """
        What defines this segment, as exact JSON-able values (floats round-trip through JSON).

        Its name, its length and its model's data: a table's rows as read, a model's
        parameters; never curves sampled from them (a transcendental function may differ in
        the last bit between machines). :mod:`softseq_ros.segments.identity` hashes it.
        """
        raise NotImplementedError(f'segment {self.name!r} ({type(self).__name__}) does not '
                                  'say what defines it: give it a definition() method')

    def _named(self, model: str, **data: object) -> dict[str, object]:
        """A definition: name, length [m], model and its data."""
        return {'name': self.name, 'length_m': exact(self.length), 'model': model, **data}

    def monotone_pieces(self) -> list[Piece]:
        """Split the PV curve into rising and falling pieces, base to top."""
        if self._pieces is None:
            self._pieces = self._build_pieces()
        return self._pieces

    def _build_pieces(self) -> list[Piece]:
        edges = sorted({self.rest_volume, self.max_volume, *self._turning_volumes()})
        pieces: list[Piece] = []
        for lo, hi in zip(edges[:-1], edges[1:]):
            if hi <= lo:
                continue
            p_lo, p_hi = (float(x) for x in self.pressure([lo, hi]))
            if p_hi == p_lo:
                raise ValueError(f'segment {self.name!r}: its pressure is the same at '
                                 f'{lo:.6g} and {hi:.6g} m^3; a curve needs no flat stretch')
            direction = 1 if p_hi > p_lo else -1
            if pieces and pieces[-1].direction == direction:
                last = pieces.pop()
                lo, p_lo = last.v_lo, last.p_at_lo
            pieces.append(Piece(lo, hi, direction, p_lo, p_hi))
        return pieces

    def invert(self, piece: Piece, p: ArrayLike,
               tolerances: Tolerances = DEFAULT_TOLERANCES,
               log: ConvergenceLog | None = None) -> FloatArray:
        """
        Volumes on a rising or falling ``piece`` where the pressure equals ``p``.

        Safeguarded Newton, vectorised: a Newton step where it stays inside the bracket the
        piece gives, a halving where it would not. It cannot fail on a monotone piece and
        reaches round-off in a few steps (at most 64 halvings near a peak, where the slope
        vanishes) within ``tolerances.inversion_steps``; ``log`` counts whether it did.
        Pressures outside the piece's range return the nearer end.
        """
        target = np.asarray(p, dtype=float)
        sign = float(piece.direction)
        ulps = tolerances.round_off_ulps
        lo, hi, x, floor = newton_start(piece, target, ulps)
        converged = False
        for _ in range(tolerances.inversion_steps):
            residual = sign * (self.pressure(x) - target)
            above = residual > 0.0
            hi = np.where(above, x, hi)
            lo = np.where(above, lo, x)
            done = (np.abs(residual) <= floor) | (
                hi - lo <= ulps * np.spacing(np.maximum(np.abs(hi), 1e-300)))
            if np.all(done):
                converged = True
                break
            slope = sign * self.stiffness(x)
            with np.errstate(divide='ignore', invalid='ignore'):
                step = x - residual / slope
            inside = np.isfinite(step) & (step > lo) & (step < hi)
            x = np.where(done, x, np.where(inside, step, 0.5 * (lo + hi)))
        if log is not None:
            log.record('inversion', converged)
        return at_piece_ends(piece, target, x)

    def _arclength(self, v: FloatArray) -> FloatArray:
        """Cumulative length along the PV curve, volume and pressure scaled by their ranges."""
        if not hasattr(self, '_p_range'):
            probe = self.pressure(np.linspace(self.rest_volume, self.max_volume, 1025))
            self._p_range = max(float(np.ptp(probe)), 1e-300)
        step = np.hypot(np.diff(v) / (self.max_volume - self.rest_volume),
                        np.diff(self.pressure(v)) / self._p_range)
        return np.concatenate([[0.0], np.cumsum(step)])

    def arclength_share(self, piece: Piece) -> float:
        """Fraction of the whole PV curve's (scaled) length that lies on ``piece``."""
        whole = self._arclength(np.linspace(self.rest_volume, self.max_volume, 8193))[-1]
        part = self._arclength(np.linspace(piece.v_lo, piece.v_hi, 1025))[-1]
        return float(part / whole) if whole > 0.0 else 1.0

    def arclength_samples(self, piece: Piece, count: int) -> FloatArray:
        """
        ``count`` volumes on ``piece`` evenly spaced along its PV curve.

        Distances are measured in volume and pressure scaled by the segment's own ranges, so a
        sharp peak gets as many samples as a long flat stretch.
        """
        fine = np.linspace(piece.v_lo, piece.v_hi, 8 * count + 1)
        arc = self._arclength(fine)
        if arc[-1] <= 0.0:
            return np.linspace(piece.v_lo, piece.v_hi, count)
        return np.interp(np.linspace(0.0, arc[-1], count), arc, fine)


class TabulatedSegment(Segment):
    """
    A segment given by a table of volume, pressure and curvature (from FEM or from the rig).

    Pressure and curvature are interpolated with PCHIP: monotone wherever the data are, with
    extrema only at table rows, so no wiggles are invented and the monotone pieces follow from the
    data's own slopes. The energy is PCHIP's exact antiderivative.
    """

    def __init__(self, name: str, length: float, volume: ArrayLike, pressure: ArrayLike,
                 curvature: ArrayLike, source: str = '') -> None:
        """Build the interpolants; ``source`` names the file in error messages."""
        where = source or f'segment {name!r}'
        vol = np.asarray(volume, dtype=float)
        prs = np.asarray(pressure, dtype=float)
        cur = np.asarray(curvature, dtype=float)
        if not (vol.ndim == prs.ndim == cur.ndim == 1 and vol.size == prs.size == cur.size):
            raise TableError(f'{where}: volume, pressure and curvature need the same length')
        if vol.size < 2:
            raise TableError(f'{where}: needs at least 2 rows, got {vol.size}')
        if not (np.all(np.isfinite(vol)) and np.all(np.isfinite(prs))
                and np.all(np.isfinite(cur))):
            raise TableError(f'{where}: values must be finite (no NaN or inf)')
        steps = np.diff(vol)
        if np.any(steps <= 0.0):
            row = int(np.argmax(steps <= 0.0)) + 2
            raise TableError(f'{where}: volume_m3 must increase strictly; row {row} '
                             f'({vol[row - 1]:.6g}) does not exceed row {row - 1} '
                             f'({vol[row - 2]:.6g})')
        if vol[0] < 0.0:
            raise TableError(f'{where}: volume_m3 must be >= 0, got {vol[0]:.6g} in row 1')
        super().__init__(name, length, float(vol[0]), float(vol[-1]))
        self.source = source
        self.volumes = vol
        self.pressures = prs
        self.curvatures = cur
        # What the table was made from when its pressures are not the rows as read: the
        # pressures read and each smoothing's options (see :meth:`smoothed`).
        self.table_pressures = prs
        self.smoothing: tuple[dict[str, float | None], ...] = ()
        # The identity of the segment design whose FEM table this is (geometry, material,
        # mesh, volume range, code versions), when it is one: the segment is defined by that,
        # not by rows that a FEM run on another machine may round otherwise.
        self.design: dict[str, object] | None = None
        self.knot_volumes, self.knot_pressures = dequantised(vol, prs)
        if self.knot_pressures.size == 2 and self.knot_pressures[0] == self.knot_pressures[1]:
            raise TableError(f'{where}: column pressure_pa: {NEVER_RISES}')
        self._p = PchipInterpolator(self.knot_volumes, self.knot_pressures, extrapolate=False)
        self._dp = self._p.derivative()
        self._e = self._p.antiderivative()
        self._k = PchipInterpolator(vol, cur, extrapolate=False)
        self._dk = self._k.derivative()
        self._p_at = _PiecewiseAtOne(self._p)
        self._k_at = _PiecewiseAtOne(self._k)

    def smoothed(self, pressures: ArrayLike, *, noise_std_pa: float | None = None,
                 prominence_pa: float | None = None) -> 'TabulatedSegment':
        """
        This table with its pressures replaced by smoothed ones, the other columns kept.

        ``noise_std_pa`` and ``prominence_pa`` are the smoothing's options as given (None:
        estimated, default). The result is still defined by the rows as read and these
        options (:meth:`definition`), not by the smoothed numbers, which come out of a fit.
        """
        segment = TabulatedSegment(self.name, self.length, self.volumes, pressures,
                                   self.curvatures, source=f'{self.source} (smoothed)')
        segment.table_pressures = self.table_pressures
        segment.design = self.design
        segment.smoothing = (*self.smoothing, {
            'noise_std_pa': None if noise_std_pa is None else exact(noise_std_pa),
            'prominence_pa': None if prominence_pa is None else exact(prominence_pa)})
        return segment

    def definition(self) -> dict[str, object]:
        """
        Name, length and the rows as read (and the smoothing options, when smoothed).

        A segment design's FEM table is defined by the design's identity instead: the same
        design gives the same digest on every machine, though each machine's FEM may round
        the last digits of its rows differently.
        """
        if self.design is not None:
            data = self._named('design', design=self.design)
        else:
            data = self._named('table', volume_m3=exact_list(self.volumes),
                               pressure_pa=exact_list(self.table_pressures),
                               curvature_per_m=exact_list(self.curvatures))
        if self.smoothing:
            data['smoothing'] = [dict(options) for options in self.smoothing]
        return data

    def knots(self) -> FloatArray:
        """The pressure curve's knots (:func:`dequantised`): PCHIP is once differentiable there."""
        return self.knot_volumes

    def pressure_cubics(self) -> tuple[FloatArray, FloatArray, FloatArray] | None:
        """PCHIP's breaks (the table's volumes), its cubics and their derivatives."""
        return self._p.x, self._p.c, self._dp.c

    def _clip(self, v: ArrayLike) -> FloatArray:
        # np.clip's numbers by its two ufuncs: np.clip's dispatch costs more than the
        # arithmetic at the sizes the solvers ask for, thousands of times per map.
        return np.minimum(np.maximum(np.asarray(v, dtype=float), self.rest_volume),
                          self.max_volume)

    def pressure(self, v: ArrayLike) -> FloatArray:
        """Gauge pressure at volume v, in Pa (clamped to the table's range)."""
        if isinstance(v, float):   # numpy's float64 too
            return self._p_at(min(max(float(v), self.rest_volume), self.max_volume))
        return self._p(self._clip(v))

    def stiffness(self, v: ArrayLike) -> FloatArray:
        """Derivative dp/dv, in Pa/m^3."""
        return self._dp(self._clip(v))

    def energy(self, v: ArrayLike) -> FloatArray:
        """Integral of p dv from the first row, in J."""
        return self._e(self._clip(v))

    def curvature(self, v: ArrayLike) -> FloatArray:
        """Curvature, in 1/m."""
        if isinstance(v, float):
            return self._k_at(min(max(float(v), self.rest_volume), self.max_volume))
        return self._k(self._clip(v))

    def curvature_slope(self, v: ArrayLike) -> FloatArray:
        """D(curvature)/dv, in 1/m per m^3."""
        return self._dk(self._clip(v))

    def _turning_volumes(self) -> list[float]:
        secant = np.sign(np.diff(self.knot_pressures))
        return [float(self.knot_volumes[i + 1]) for i in range(secant.size - 1)
                if secant[i] != secant[i + 1]]


def dequantised(volumes: FloatArray, pressures: FloatArray) -> tuple[FloatArray, FloatArray]:
    """
    The knots of a table's pressure curve: each run of rows at one pressure read as one point.

    A logger reads pressure in steps of its resolution q, so a table from a rig repeats a
    reading over a run of rows while the true pressure moves through the step. Interpolated as
    read, every run would be a flat (a plateau of neutral equilibria that the true curve does
    not have) joined to the next by a cubic with zero slope at both ends. Each run of two or
    more equal readings stands instead for one point at the run's middle volume (the first
    and the last row stay where they are, so the table's range is kept): the curve then passes
    through every run's middle, is monotone between them, and lies within one step of every
    reading (within 1.5 steps of the true pressure). A table without repeated readings is
    unchanged, row for row.
    """
    same = np.flatnonzero(pressures[1:] == pressures[:-1])
    if same.size == 0:
        return volumes, pressures
    # Runs of equal readings: [start, stop) row ranges.
    new_run = np.ones(pressures.size, dtype=bool)
    new_run[1:] = pressures[1:] != pressures[:-1]
    starts = np.flatnonzero(new_run)
    stops = np.append(starts[1:], pressures.size)
    last = pressures.size - 1
    knot_v, knot_p = [], []
    for start, stop in zip(starts.tolist(), stops.tolist()):
        if start == 0 and stop - 1 == last:
            ends = [volumes[0], volumes[last]]
        elif start == 0:
            ends = [volumes[0]]
        elif stop - 1 == last:
            ends = [volumes[last]]
        else:
            ends = [0.5 * (volumes[start] + volumes[stop - 1])]
        knot_v.extend(ends)
        knot_p.extend([pressures[start]] * len(ends))
    return np.array(knot_v), np.array(knot_p)


def polynomial_at(coefficients: FloatArray, offset: FloatArray) -> FloatArray:
    """
    One piece of a piecewise polynomial (scipy's PPoly layout) at ``offset`` from its break.

    sum_m coefficients[m] offset^(k - 1 - m), highest power first, each element with its own
    coefficients (k rows, each shaped like ``offset``). The same floating-point operations in
    the same order as scipy's PPoly (powers of the offset built up by products, terms added
    from the constant up), so the same numbers to the bit, without the call's interval search,
    checks and array handling.
    """
    order = len(coefficients)
    value = coefficients[order - 1]
    power = offset
    value = value + coefficients[order - 2] * power
    for m in range(order - 3, -1, -1):
        power = power * offset
        value = value + coefficients[m] * power
    return value


class _PiecewiseAtOne:
    """
    A piecewise polynomial (scipy's PPoly) at one volume given as a float.

    The same polynomial of the same interval, by Horner's rule on plain floats (equal to
    round-off). The fluid network asks for one segment's pressure at one volume thousands
    of times; the general call's checks and array handling cost ten times the arithmetic.
    """

    def __init__(self, poly: PchipInterpolator) -> None:
        self.breaks = poly.x.tolist()
        self.last = len(self.breaks) - 2
        self.coefficients = poly.c.T.tolist()   # per interval, highest power first

    def __call__(self, v: float) -> float:
        if v != v:
            return v
        interval = min(max(bisect_right(self.breaks, v) - 1, 0), self.last)
        offset = v - self.breaks[interval]
        value = 0.0
        for coefficient in self.coefficients[interval]:
            value = value * offset + coefficient
        return value


class _SmoothSegment(Segment):
    """A segment with a smooth closed-form PV curve; turning points found by root finding."""

    _samples = 4097

    def _turning_volumes(self) -> list[float]:
        grid = self._turn_search_grid()
        slope = self.stiffness(grid)
        turns = []
        for i in np.flatnonzero(np.sign(slope[:-1]) * np.sign(slope[1:]) < 0.0):
            turns.append(brentq(lambda x: float(self.stiffness(x)), grid[i], grid[i + 1],
                                xtol=TURN_XTOL * self.max_volume, rtol=4 * np.finfo(float).eps))
        return turns

    def _turn_search_grid(self) -> FloatArray:
        return np.linspace(self.rest_volume, self.max_volume, self._samples)


class LinearSegment(_SmoothSegment):
    """p = stiffness (v - rest_volume): the 'no sequence' building block."""

    def __init__(self, name: str, length: float, rest_volume: float, stiffness: float,
                 max_volume: float, curvature_gain: float = 0.0) -> None:
        """Stiffness in Pa/m^3; curvature_gain in (1/m) per m^3 of inflation."""
        super().__init__(name, length, rest_volume, max_volume)
        if not (math.isfinite(stiffness) and stiffness > 0.0):
            raise ValueError(f'segment {name!r}: stiffness must be > 0 Pa/m^3, got {stiffness}')
        self.k = float(stiffness)
        self.curvature_gain = float(curvature_gain)

    def definition(self) -> dict[str, object]:
        """Name, length and the scene's ``linear`` parameters."""
        return self._named('linear', rest_volume_m3=exact(self.rest_volume),
                           stiffness_pa_per_m3=exact(self.k),
                           max_volume_m3=exact(self.max_volume),
                           curvature_per_m_per_m3=exact(self.curvature_gain))

    def pressure(self, v: ArrayLike) -> FloatArray:
        """Gauge pressure, in Pa."""
        return self.k * (np.asarray(v, dtype=float) - self.rest_volume)

    def stiffness(self, v: ArrayLike) -> FloatArray:
        """Constant dp/dv, in Pa/m^3."""
        return np.full(np.shape(v), self.k)

    def energy(self, v: ArrayLike) -> FloatArray:
        """Stored energy, in J."""
        return 0.5 * self.k * (np.asarray(v, dtype=float) - self.rest_volume) ** 2

    def curvature(self, v: ArrayLike) -> FloatArray:
        """Curvature, in 1/m."""
        return self.curvature_gain * (np.asarray(v, dtype=float) - self.rest_volume)

    def curvature_slope(self, v: ArrayLike) -> FloatArray:
        """Constant d(curvature)/dv, in 1/m per m^3."""
        return np.full(np.shape(v), self.curvature_gain)


class BalloonSegment(_SmoothSegment):
    """
    A thin spherical membrane of reference radius R and thickness H.

    With stretch lam = (v / v0)^(1/3): p = H / (R lam^2) dW/dlam, and the stored energy is the
    membrane's material volume times W, 4 pi R^2 H W(lam) (exact, no quadrature).
    """

    def __init__(self, name: str, length: float, material: Material, radius: float,
                 thickness: float, max_stretch: float, curvature_gain: float = 0.0) -> None:
        """Radius and thickness in m; max_stretch bounds the model's range."""
        if not (math.isfinite(radius) and radius > 0.0):
            raise ValueError(f'segment {name!r}: radius must be > 0 m, got {radius}')
        if not (math.isfinite(thickness) and thickness > 0.0):
            raise ValueError(f'segment {name!r}: thickness must be > 0 m, got {thickness}')
        if not (max_stretch > 1.0):
            raise ValueError(f'segment {name!r}: max stretch must be > 1, got {max_stretch}')
        if max_stretch >= material.max_stretch:
            raise ValueError(f'segment {name!r}: max stretch {max_stretch} reaches the '
                             f'material limit {material.max_stretch:.6g}')
        rest = 4.0 / 3.0 * math.pi * radius**3
        super().__init__(name, length, rest, rest * max_stretch**3)
        self.material = material
        self.radius = float(radius)
        self.thickness = float(thickness)
        self.max_stretch = float(max_stretch)
        self.curvature_gain = float(curvature_gain)

    def definition(self) -> dict[str, object]:
        """Name, length and the scene's ``balloon`` parameters (the material's law too)."""
        return self._named('balloon', material=material_definition(self.material),
                           radius_m=exact(self.radius), thickness_m=exact(self.thickness),
                           max_stretch=exact(self.max_stretch),
                           curvature_per_m_per_m3=exact(self.curvature_gain))

    def stretch(self, v: ArrayLike) -> FloatArray:
        """Equibiaxial stretch of the membrane at volume v."""
        if isinstance(v, float):   # one volume: plain floats, as the fluid network asks
            return math.cbrt(min(max(float(v), self.rest_volume), self.max_volume)
                             / self.rest_volume)
        clipped = np.minimum(np.maximum(np.asarray(v, dtype=float), self.rest_volume),
                             self.max_volume)   # np.clip's numbers, without its dispatch
        return np.cbrt(clipped / self.rest_volume)

    def pressure(self, v: ArrayLike) -> FloatArray:
        """Gauge pressure, in Pa."""
        lam = self.stretch(v)
        return self.thickness / (self.radius * lam**2) * self.material.energy_derivative(lam)

    def stiffness(self, v: ArrayLike) -> FloatArray:
        """dp/dv by the chain rule through the stretch (central difference of dW/dlam)."""
        lam = self.stretch(v)
        h = STRETCH_STEP * lam
        dwl = self.material.energy_derivative(lam)
        d2w = (self.material.energy_derivative(lam + h)
               - self.material.energy_derivative(lam - h)) / (2.0 * h)
        dp_dlam = self.thickness / self.radius * (d2w / lam**2 - 2.0 * dwl / lam**3)
        return dp_dlam / (3.0 * self.rest_volume * lam**2)

    def energy(self, v: ArrayLike) -> FloatArray:
        """Stored energy, in J."""
        lam = self.stretch(v)
        return (4.0 * math.pi * self.radius**2 * self.thickness
                * (self.material.energy(lam) - self.material.energy(1.0)))

    def curvature(self, v: ArrayLike) -> FloatArray:
        """Curvature, in 1/m."""
        return self.curvature_gain * (np.asarray(v, dtype=float) - self.rest_volume)

    def curvature_slope(self, v: ArrayLike) -> FloatArray:
        """Constant d(curvature)/dv, in 1/m per m^3."""
        return np.full(np.shape(v), self.curvature_gain)

    def _turn_search_grid(self) -> FloatArray:
        # Uniform in stretch: the balloon's features (peak near lam = 1.38) sit at small volumes.
        lam = np.linspace(1.0, np.cbrt(self.max_volume / self.rest_volume), self._samples)
        return np.clip(self.rest_volume * lam**3, self.rest_volume, self.max_volume)
