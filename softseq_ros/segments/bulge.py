"""
Reduced-order model of a bending segment whose membranes bulge out as spherical caps.

A segment is a straight cavity closed on one side by a thick beam and on the other by a row of
thin membranes separated by short walls. Under pressure each membrane inflates like the sample
of a bulge test, the segment's side walls let the cavity swell a little, and the membrane side
grows longer than the beam side, so the segment bends towards the beam.

Cap geometry (base radius ``a``, height ``h`` above the clamped base plane, any ``h >= 0``,
including caps taller than a hemisphere)::

    R = (a**2 + h**2) / (2 h)              radius of the sphere the cap belongs to
    V = pi h (3 a**2 + h**2) / 6           volume between the cap and its base
    A = pi (a**2 + h**2)                   cap area
    s = 2 R theta, theta = atan2(a, R - h) meridian arc through the pole (theta > pi/2 past
                                           the hemisphere)

Membrane (thickness ``H`` at rest, incompressible, stretched uniformly and equibiaxially, the
usual bulge-test simplification)::

    lam = sqrt(A / (pi a**2)) = sqrt(1 + (h / a)**2)
    N   = H / (2 lam) dW/dlam             tension per current length (W from ``materials``)
    p   = 2 N / R = 2 H W'(lam) sqrt(lam**2 - 1) / (a lam**3)

The same ``p`` follows from energy: ``p = d(pi a**2 H W(lam)) / dV``, so the tables are
conservative (``integral p dV`` equals the stored membrane energy). For a constant tension the
pressure peaks at the hemisphere (``R`` is smallest there); a stiffening material brings it back
up at large stretch.
"""

from dataclasses import dataclass
import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from softseq_ros.errors import UserError
from softseq_ros.segments.materials import Material

# A length that is a whole number of pitches up to round-off holds that many.
PITCH_SLACK = 1e-9


class BulgeModelError(UserError):
    """Geometry or stretch outside what the cap model describes."""


def _positive(name: str, value: float) -> float:
    value = float(value)
    if not math.isfinite(value) or value <= 0.0:
        raise BulgeModelError(f'{name} must be a positive finite number, got {value!r}')
    return value


def _stretch_array(stretch: ArrayLike) -> NDArray[np.float64]:
    lam = np.asarray(stretch, dtype=float)
    if np.any(~np.isfinite(lam)) or np.any(lam < 1.0):
        raise BulgeModelError('cap stretch must be finite and >= 1 (1 = flat membrane)')
    return lam


def cap_height(stretch: ArrayLike, base_radius: float) -> NDArray[np.float64]:
    """Cap height ``h = a sqrt(lam**2 - 1)`` for the mean equibiaxial stretch ``lam``, in m."""
    a = _positive('base_radius', base_radius)
    lam = _stretch_array(stretch)
    return a * np.sqrt(lam**2 - 1.0)


def cap_stretch(height: ArrayLike, base_radius: float) -> NDArray[np.float64]:
    """Mean equibiaxial stretch ``lam = sqrt(1 + (h / a)**2)`` (cap area over base area)."""
    a = _positive('base_radius', base_radius)
    h = np.asarray(height, dtype=float)
    if np.any(h < 0.0):
        raise BulgeModelError('cap height must be >= 0')
    return np.sqrt(1.0 + (h / a) ** 2)


def cap_sphere_radius(height: ArrayLike, base_radius: float) -> NDArray[np.float64]:
    """Radius ``R = (a**2 + h**2) / (2 h)`` of the cap's sphere, in m (inf when flat)."""
    a = _positive('base_radius', base_radius)
    h = np.asarray(height, dtype=float)
    with np.errstate(divide='ignore'):
        return np.where(h > 0.0, (a**2 + h**2) / (2.0 * np.maximum(h, 1e-300)), np.inf)


def cap_volume(height: ArrayLike, base_radius: float) -> NDArray[np.float64]:
    """Volume ``pi h (3 a**2 + h**2) / 6`` between the cap and its base plane, in m^3."""
    a = _positive('base_radius', base_radius)
    h = np.asarray(height, dtype=float)
    return np.pi * h * (3.0 * a**2 + h**2) / 6.0


def cap_meridian_length(height: ArrayLike, base_radius: float) -> NDArray[np.float64]:
    """
    Arc length of the cap's meridian from rim to rim through the pole, in m.

    ``s = 2 R theta`` with the half-angle ``theta = atan2(a, R - h)``; ``s = 2 a`` when flat,
    ``pi a`` at the hemisphere.
    """
    a = _positive('base_radius', base_radius)
    h = np.asarray(height, dtype=float)
    flat = h <= 0.0
    h_safe = np.where(flat, 1.0, h)
    radius = (a**2 + h_safe**2) / (2.0 * h_safe)
    arc = 2.0 * radius * np.arctan2(a, radius - h_safe)
    return np.where(flat, 2.0 * a, arc)


def membrane_tension(stretch: ArrayLike, thickness: float,
                     material: Material) -> NDArray[np.float64]:
    """Equibiaxial membrane tension ``N = H / (2 lam) dW/dlam`` in N/m (force per length)."""
    thickness = _positive('thickness', thickness)
    lam = _stretch_array(stretch)
    return thickness / (2.0 * lam) * np.asarray(material.energy_derivative(lam), dtype=float)


def cap_pressure(stretch: ArrayLike, base_radius: float, thickness: float,
                 material: Material) -> NDArray[np.float64]:
    """
    Gauge pressure holding a clamped membrane at mean stretch ``lam``, in Pa.

    Laplace's law for a spherical cap, ``p = 2 N / R``, which with the cap geometry becomes
    ``p = 2 H W'(lam) sqrt(lam**2 - 1) / (a lam**3)``. Zero for the flat membrane.
    """
    a = _positive('base_radius', base_radius)
    thickness = _positive('thickness', thickness)
    lam = _stretch_array(stretch)
    dw = np.asarray(material.energy_derivative(lam), dtype=float)
    return 2.0 * thickness * dw * np.sqrt(lam**2 - 1.0) / (a * lam**3)


def cap_energy(stretch: ArrayLike, base_radius: float, thickness: float,
               material: Material) -> NDArray[np.float64]:
    """Elastic energy ``pi a**2 H W(lam)`` stored in one cap, in J."""
    a = _positive('base_radius', base_radius)
    thickness = _positive('thickness', thickness)
    lam = _stretch_array(stretch)
    return np.pi * a**2 * thickness * np.asarray(material.energy(lam), dtype=float)


@dataclass(frozen=True)
class SegmentGeometry:
    """
    Dimensions of one bending segment, in m (Table I of the paper names them).

    ``membrane_length`` (b) and ``wall_length`` (a in the paper) alternate along the segment;
    ``membrane_thickness`` is the thickness of the bulging membranes and ``wall_thickness`` that
    of the walls that enclose the cavity sideways.
    """

    segment_length: float
    height: float
    beam_thickness: float
    cavity_width: float
    wall_length: float
    membrane_length: float
    membrane_thickness: float
    wall_thickness: float

    def __post_init__(self) -> None:
        """Check every dimension and that the section leaves room for a cavity."""
        for name in ('segment_length', 'height', 'beam_thickness', 'cavity_width',
                     'wall_length', 'membrane_length', 'membrane_thickness', 'wall_thickness'):
            _positive(name, getattr(self, name))
        if self.cavity_depth <= 0.0:
            raise BulgeModelError('height must exceed beam_thickness + membrane_thickness')
        if self.membrane_count < 1:
            raise BulgeModelError('segment_length is shorter than one wall + membrane pitch')

    @property
    def pitch(self) -> float:
        """Length of one wall plus one membrane, in m."""
        return self.wall_length + self.membrane_length

    @property
    def membrane_count(self) -> int:
        """Whole wall + membrane pitches that fit in the segment length."""
        return int(math.floor(self.segment_length / self.pitch + PITCH_SLACK))

    @property
    def cap_base_radius(self) -> float:
        """Radius of the round cap with the area of one membrane: sqrt(b g / pi), in m."""
        return math.sqrt(self.membrane_length * self.cavity_width / math.pi)

    @property
    def cavity_depth(self) -> float:
        """Cavity depth between the beam and the membranes, in m."""
        return self.height - self.beam_thickness - self.membrane_thickness

    @property
    def cavity_volume(self) -> float:
        """Rest volume of the cavity, width x depth x segment length, in m^3."""
        return self.cavity_width * self.cavity_depth * self.segment_length

    @property
    def bending_arm(self) -> float:
        """Distance from the beam's mid-plane to the membranes' mid-plane, in m."""
        return self.height - 0.5 * self.membrane_thickness - 0.5 * self.beam_thickness


def wall_compliance(geometry: SegmentGeometry, shear_modulus: float) -> float:
    """
    Linear compliance dV/dp of the cavity from its side walls, in m^3/Pa.

    A thin-walled tube of radius ``r = g / 2`` and wall thickness ``d`` in plane strain,
    incompressible: hoop stress ``p r / d = 4 mu eps``, and the cavity section grows by
    ``2 eps``, so ``dV / V0 = p r / (2 mu d)``.
    """
    mu = _positive('shear_modulus', shear_modulus)
    radius = 0.5 * geometry.cavity_width
    return geometry.cavity_volume * radius / (2.0 * mu * geometry.wall_thickness)


@dataclass(frozen=True)
class BulgeSegment:
    """
    A segment whose state is the common stretch of all its membrane caps.

    ``curvature_transfer`` is the fraction of the caps' extra meridian length that lengthens the
    membrane side of the segment (the rest only bulges outwards); ``wall_compliance_factor``
    scales the thin-tube compliance of the side walls (1 = the closed form of
    ``wall_compliance``). Both are calibration factors.
    """

    geometry: SegmentGeometry
    material: Material
    curvature_transfer: float = 1.0
    wall_compliance_factor: float = 1.0

    def __post_init__(self) -> None:
        """Check the calibration factors."""
        _positive('curvature_transfer', self.curvature_transfer)
        if not math.isfinite(self.wall_compliance_factor) or self.wall_compliance_factor < 0.0:
            raise BulgeModelError('wall_compliance_factor must be a finite number >= 0, '
                                  f'got {self.wall_compliance_factor!r}')

    @property
    def cavity_compliance(self) -> float:
        """Linear compliance dV/dp of the side walls, in m^3/Pa (factor x closed form)."""
        return self.wall_compliance_factor * wall_compliance(self.geometry,
                                                             self.material.shear_modulus)

    @property
    def rest_volume(self) -> float:
        """Fluid volume of the unpressurised segment (the cavity), in m^3."""
        return self.geometry.cavity_volume

    def pressure(self, stretch: ArrayLike) -> NDArray[np.float64]:
        """Gauge pressure at the caps' stretch, in Pa (all caps share it)."""
        g = self.geometry
        return cap_pressure(stretch, g.cap_base_radius, g.membrane_thickness, self.material)

    def volume(self, stretch: ArrayLike) -> NDArray[np.float64]:
        """Segment fluid volume: cavity + wall swelling + all caps, in m^3."""
        g = self.geometry
        height = cap_height(stretch, g.cap_base_radius)
        walls = self.cavity_compliance * self.pressure(stretch)
        return g.cavity_volume + walls + g.membrane_count * cap_volume(height, g.cap_base_radius)

    def curvature(self, stretch: ArrayLike) -> NDArray[np.float64]:
        """
        Segment curvature, in 1/m.

        Each membrane's axial length b grows by the caps' relative meridian excess,
        ``b (s / 2a - 1)``, times ``curvature_transfer``; the beam side keeps its length L, so
        ``kappa = n_membranes * extra / (L * arm)`` with ``arm`` the beam-to-membrane distance.
        """
        g = self.geometry
        a = g.cap_base_radius
        arc = cap_meridian_length(cap_height(stretch, a), a)
        extra = self.curvature_transfer * g.membrane_length * (arc / (2.0 * a) - 1.0)
        return g.membrane_count * extra / (g.segment_length * g.bending_arm)

    def energy(self, stretch: ArrayLike) -> NDArray[np.float64]:
        """Stored elastic energy (caps + linear walls), in J; equals integral p dV from rest."""
        g = self.geometry
        caps = g.membrane_count * cap_energy(stretch, g.cap_base_radius, g.membrane_thickness,
                                             self.material)
        walls = 0.5 * self.cavity_compliance * self.pressure(stretch)**2
        return caps + walls
