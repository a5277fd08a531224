"""
The syringe's line as one more member of the equilibrium: trapped gas and a swelling line.

A syringe line always holds some air, and its tubing swells. At gauge pressure p the line takes
up part of what the piston pushed, instead of passing it on to the segments:

    s(p) = V_g (1 - (p_a / (p_a + p))^(1/n)) + C p

with V_g the volume of the trapped gas at the ambient (absolute) pressure p_a, n its polytropic
exponent (1: isothermal, the default; 1.4: adiabatic air) and C the line's compliance
[m^3/Pa]. The piston's displacement V is then the segments' fluid plus s(p): quasi-statically
the line is one more member of the assembly, at the common pressure, with a rising curve p(s)
(the inverse of s), no bending and the stored energy of the gas's compression and the line's
swelling, integral of p ds. The equilibrium, its stability (the Hessian gains the line's
stiffness dp/ds), the snaps' energies and the graph follow without a second solver
(softseq_ros.quasistatic.equilibrium takes it as ``supply``).
"""

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from softseq_ros.segments.models import Segment, exact

FloatArray = NDArray[np.float64]

# The standard atmosphere [Pa, absolute]: the ambient pressure by default.
STANDARD_AMBIENT_PA = 101325.0
# Newton steps on s(p) = v for a line with both gas and compliance (quadratic convergence from
# a start below the root, then monotone from above: a handful reach round-off).
INVERSION_STEPS = 60
EPSILON = float(np.finfo(float).eps)


class CompliantSupply(Segment):
    """
    The line between the piston and the segments: trapped gas and compliance, as a member.

    ``gas_volume_m3`` (V_g, >= 0) at ``ambient_pa`` (absolute), ``polytropic_exponent`` n >= 1,
    ``line_compliance_m3_per_pa`` C >= 0, at least one of V_g and C above 0. The member's
    volume is what the line takes up, from 0 at 0 Pa gauge to its value at ``max_pressure_pa``
    (beyond every pressure the segments reach). It does not bend.
    """

    def __init__(self, gas_volume_m3: float = 0.0, *, ambient_pa: float = STANDARD_AMBIENT_PA,
                 polytropic_exponent: float = 1.0, line_compliance_m3_per_pa: float = 0.0,
                 max_pressure_pa: float) -> None:
        """Check the line's numbers; its volume range follows from ``max_pressure_pa``."""
        values = {'gas_volume_m3': gas_volume_m3, 'ambient_pa': ambient_pa,
                  'polytropic_exponent': polytropic_exponent,
                  'line_compliance_m3_per_pa': line_compliance_m3_per_pa,
                  'max_pressure_pa': max_pressure_pa}
        for key, value in values.items():
            if isinstance(value, bool) or not isinstance(value, (int, float)) \
                    or not math.isfinite(value):
                raise ValueError(f'supply {key}: must be a finite number, got {value!r}')
        if gas_volume_m3 < 0.0 or line_compliance_m3_per_pa < 0.0:
            raise ValueError('supply gas_volume_m3 and line_compliance_m3_per_pa must be >= 0')
        if not gas_volume_m3 > 0.0 and not line_compliance_m3_per_pa > 0.0:
            raise ValueError('supply: a compliant supply needs gas_volume_m3 or '
                             'line_compliance_m3_per_pa above 0 (without both it is the ideal '
                             'syringe: give no supply)')
        if not ambient_pa > 0.0:
            raise ValueError(f'supply ambient_pa must be > 0 Pa (absolute), got {ambient_pa}')
        if polytropic_exponent < 1.0:
            raise ValueError(f'supply polytropic_exponent must be >= 1 (1: isothermal, 1.4: '
                             f'adiabatic air), got {polytropic_exponent}')
        if not max_pressure_pa > 0.0:
            raise ValueError(f'supply max_pressure_pa must be > 0 Pa, got {max_pressure_pa}')
        self.gas_volume = float(gas_volume_m3)
        self.ambient = float(ambient_pa)
        self.exponent = float(polytropic_exponent)
        self.compliance = float(line_compliance_m3_per_pa)
        self.max_pressure = float(max_pressure_pa)
        # Not Segment.__init__: the line has no length (it does not bend).
        self.name = 'supply'
        self.length = 0.0
        self.rest_volume = 0.0
        self.max_volume = float(self.taken_up(self.max_pressure))
        self._pieces = None

    def definition(self) -> dict[str, object]:
        """The line's numbers, exact."""
        return {'name': self.name, 'model': 'compliant_supply',
                'gas_volume_m3': exact(self.gas_volume), 'ambient_pa': exact(self.ambient),
                'polytropic_exponent': exact(self.exponent),
                'line_compliance_m3_per_pa': exact(self.compliance),
                'max_pressure_pa': exact(self.max_pressure)}

    # ------------------------------------------------------------------ the line's law

    def taken_up(self, p: ArrayLike) -> FloatArray:
        """s(p) [m^3]: what the line takes up at gauge pressure ``p`` [Pa]."""
        p = np.asarray(p, dtype=float)
        gas = self.gas_volume * -np.expm1(-np.log1p(p / self.ambient) / self.exponent)
        return gas + self.compliance * p

    def taken_up_slope(self, p: ArrayLike) -> FloatArray:
        """ds/dp [m^3/Pa] at gauge pressure ``p``: the line's compliance there."""
        p = np.asarray(p, dtype=float)
        gas = self.gas_volume / (self.exponent * self.ambient) * np.exp(
            -(1.0 / self.exponent + 1.0) * np.log1p(p / self.ambient))
        return gas + self.compliance

    def _taken_up_integral(self, p: FloatArray) -> FloatArray:
        """Integral of s(q) dq from 0 to ``p`` [J]."""
        n, pa = self.exponent, self.ambient
        if n == 1.0:
            gas = p - pa * np.log1p(p / pa)
        else:
            m = 1.0 - 1.0 / n
            gas = p - pa * np.expm1(m * np.log1p(p / pa)) / m
        return self.gas_volume * gas + 0.5 * self.compliance * p * p

    # ------------------------------------------------------------------ as a member

    def pressure(self, v: ArrayLike) -> FloatArray:
        """Gauge pressure [Pa] at which the line has taken up ``v`` [m^3] (the inverse of s)."""
        scalar = isinstance(v, float)
        s = np.clip(np.asarray(v, dtype=float), 0.0, self.max_volume)
        if self.compliance == 0.0:
            # Gas alone: s = V_g (1 - (p_a / (p_a + p))^(1/n)), inverted exactly.
            p = self.ambient * np.expm1(-self.exponent * np.log1p(-s / self.gas_volume))
        elif self.gas_volume == 0.0:
            p = s / self.compliance
        else:
            p = self._newton(s)
        return float(p) if scalar else p

    def _newton(self, s: FloatArray) -> FloatArray:
        # s(p) is concave and rising: from p = s / s'(0), below the root, one step lands above
        # it and the steps then fall monotonically onto it.
        p = s / self.taken_up_slope(0.0)
        for _ in range(INVERSION_STEPS):
            step = (self.taken_up(p) - s) / self.taken_up_slope(p)
            p = np.maximum(p - step, 0.0)
            if np.all(np.abs(step) <= 4.0 * np.finfo(float).eps * np.maximum(p, 1e-300)):
                break
        return p

    def line_pressure(self, s: float) -> float:
        """
        Gauge pressure [Pa] at which the line holds ``s`` [m^3], on plain floats, unbounded.

        What the network in time follows (softseq_ros.dynamic.flow): its transients are not
        bounded by the member's range. A pump that outruns the supply tube compresses the line
        beyond ``max_volume``; one that withdraws faster than the tube lets the fluid back
        draws it below its ambient state, where the gas expands (its gauge pressure tends to
        -p_a, absolute zero, as s falls without bound) and the line's swelling turns to
        shrinking (-s / C). Within the member's range it is :meth:`pressure`, to round-off.
        Gas alone cannot take up its own volume: at s >= V_g the pressure is infinite (nan,
        which the integrator refuses as a step it must shorten).
        """
        if self.compliance == 0.0:
            if s >= self.gas_volume:
                return math.nan
            return self.ambient * math.expm1(-self.exponent * math.log1p(-s / self.gas_volume))
        if self.gas_volume == 0.0:
            return s / self.compliance
        # s(p) rises and is concave on (-p_a, inf), so Newton's iteration from below the root
        # rises monotonically onto it. From below: for s >= 0 the tangent at 0 lies above the
        # curve, so s / s'(0) is short of the root; for s < 0 the root has C p < 0, so the gas
        # alone would need less pressure to take up s: its exact inverse is short of the root.
        if s >= 0.0:
            p = s / (self.gas_volume / (self.exponent * self.ambient) + self.compliance)
        else:
            p = self.ambient * math.expm1(-self.exponent * math.log1p(-s / self.gas_volume))
        for _ in range(INVERSION_STEPS):
            relative = math.log1p(p / self.ambient)
            taken = self.gas_volume * -math.expm1(-relative / self.exponent) + self.compliance * p
            slope = self.gas_volume / (self.exponent * self.ambient) * math.exp(
                -(1.0 / self.exponent + 1.0) * relative) + self.compliance
            step = (taken - s) / slope
            p -= step
            if abs(step) <= 4.0 * EPSILON * abs(p):
                break
        return p

    def stiffness(self, v: ArrayLike) -> FloatArray:
        """dp/ds [Pa/m^3]: the inverse of the line's compliance at its pressure."""
        return 1.0 / self.taken_up_slope(self.pressure(v))

    def energy(self, v: ArrayLike) -> FloatArray:
        """Integral of p ds from 0 to ``v`` [J]: p s - integral of s dp, by parts."""
        s = np.clip(np.asarray(v, dtype=float), 0.0, self.max_volume)
        p = np.asarray(self.pressure(s), dtype=float)
        return p * s - self._taken_up_integral(p)

    def curvature(self, v: ArrayLike) -> FloatArray:
        """The line does not bend: 0."""
        return np.zeros(np.shape(v))

    def curvature_slope(self, v: ArrayLike) -> FloatArray:
        """0."""
        return np.zeros(np.shape(v))

    def _turning_volumes(self) -> list[float]:
        return []
