"""
What a circular tube does to a flow: viscous resistance, inertance, minor losses, Reynolds number.

For a tube of length l and radius r carrying a fluid of viscosity mu and density rho, and a
volume flow q [m^3/s]:

- Hagen-Poiseuille resistance R = 8 mu l / (pi r^4) [Pa s/m^3]: a pressure drop R q in
  laminar flow;
- inertance L = rho l / (pi r^2) [Pa s^2/m^3]: a pressure drop L dq/dt to accelerate the fluid;
- minor loss: K rho q |q| / (2 A^2) with A = pi r^2, for the tube's ends and bends;
- Reynolds number Re = 2 rho |q| / (pi r mu); above about 2300 the flow leaves the laminar
  range, and Hagen-Poiseuille underestimates the drop.

The pressure drop over a tube is therefore ``L dq/dt + f(q) + a q |q|`` with a = K rho / (2 A^2)
and f the friction law the tube declares:

- ``laminar`` (default): f(q) = R q;
- ``blasius``: the larger of R q and Blasius's smooth-pipe law for turbulent flow, Darcy
  friction factor 0.316 Re^(-1/4), a drop 0.316 Re^(-1/4) (l / 2r) rho u^2 / 2 = c |q|^(7/4)
  (u = q / A). The two meet at Re = (64 / 0.316)^(4/3), about 1190, so the law is continuous
  and rises with the flow (what an implicit integrator needs); between 1190 and the laminar
  limit of about 2300 it is the more resistive of the two, above it Blasius's own range
  (measured to Re of about 1e5). A tube that stays laminar gets the same drop either way.
"""

from dataclasses import dataclass
import math

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import brentq

from softseq_ros.scene.network import BLASIUS, Fluid, Tube

LAMINAR_REYNOLDS = 2300.0
BLASIUS_COEFFICIENT = 0.316     # Darcy friction factor = 0.316 Re^(-1/4)
BLASIUS_EXPONENT = 1.75         # the drop rises as |q|^(7/4)


def laminar_range_warning(channel: str, peak_reynolds: float, turbulent_law: bool) -> str | None:
    """The line saying that a channel's flow left the laminar range, or None while it stayed."""
    if not peak_reynolds > LAMINAR_REYNOLDS:
        return None
    law = ('its friction follows Blasius' if turbulent_law else
           'the laminar law underestimates its drop: give it friction: blasius')
    return (f'channel {channel}: Reynolds number {peak_reynolds:.0f} above '
            f'{LAMINAR_REYNOLDS:.0f}, no longer laminar ({law})')


@dataclass(frozen=True)
class TubeLaw:
    """The coefficients of one tube's pressure drop: L dq/dt + friction(q) + a q |q|."""

    resistance: float       # R [Pa s/m^3]
    inertance: float        # L [Pa s^2/m^3]; 0 when the tube's inertia is left out
    quadratic: float        # a [Pa s^2/m^6]
    reynolds_per_flow: float  # Re / |q| [s/m^3]
    turbulent: float = 0.0  # c [Pa (s/m^3)^(7/4)] of Blasius's drop c |q|^(7/4); 0: laminar only

    def _magnitude_drop(self, flow: float) -> float:
        """The steady drop [Pa] of a flow magnitude ``flow`` >= 0."""
        friction = self.resistance * flow
        if self.turbulent > 0.0:
            friction = max(friction, self.turbulent * flow ** BLASIUS_EXPONENT)
        return friction + self.quadratic * flow * flow

    def flow(self, drop_pa: float) -> float:
        """The steady flow [m^3/s] a pressure drop drives (no inertia): drop(q) = drop_pa."""
        size = abs(drop_pa)
        a, r = self.quadratic, self.resistance
        if self.turbulent == 0.0:
            if a == 0.0:
                return drop_pa / r
            # The root of a q^2 + R q - |drop| = 0, written so that it stays exact as a -> 0.
            magnitude = 2.0 * size / (r + math.sqrt(r * r + 4.0 * a * size))
            return math.copysign(magnitude, drop_pa)
        # The friction alone: the smaller of the laminar and the Blasius flow (the larger drop).
        bound = min(size / r, (size / self.turbulent) ** (1.0 / BLASIUS_EXPONENT))
        if a == 0.0 or size == 0.0:
            return math.copysign(bound, drop_pa)
        # The drop rises with the flow, and the friction alone reaches |drop| at ``bound``.
        magnitude = brentq(lambda q: self._magnitude_drop(q) - size, 0.0, bound,
                           xtol=1e-300, rtol=4.0 * 2.0 ** -52)
        return math.copysign(magnitude, drop_pa)

    def flow_rows(self, drops_pa: NDArray[np.float64]) -> NDArray[np.float64]:
        """:meth:`flow` of many drops [Pa] at once (exact arithmetic where the law is linear)."""
        drops = np.asarray(drops_pa, dtype=float)
        if self.quadratic == 0.0 and self.turbulent == 0.0:
            return drops / self.resistance
        return np.array([self.flow(d) for d in drops.tolist()])

    def drop(self, flow: float) -> float:
        """The steady pressure drop [Pa] of a flow (no inertia)."""
        return math.copysign(self._magnitude_drop(abs(flow)), flow)

    def flow_slope(self, drop_pa: float) -> float:
        """The conductance d flow / d drop [m^3/(s Pa)] of the tube at a drop."""
        magnitude = abs(self.flow(drop_pa))
        slope = self.resistance
        if self.turbulent > 0.0 and \
                self.turbulent * magnitude ** BLASIUS_EXPONENT > self.resistance * magnitude:
            slope = BLASIUS_EXPONENT * self.turbulent * magnitude ** (BLASIUS_EXPONENT - 1.0)
        return 1.0 / (slope + 2.0 * self.quadratic * magnitude)

    def reynolds(self, flow: float) -> float:
        """The Reynolds number of a flow [m^3/s]."""
        return self.reynolds_per_flow * abs(flow)


def tube_law(tube: Tube, fluid: Fluid) -> TubeLaw:
    """The pressure-drop coefficients of a tube carrying ``fluid``."""
    area = math.pi * tube.radius_m ** 2
    resistance = 8.0 * fluid.viscosity_pa_s * tube.length_m / (math.pi * tube.radius_m ** 4)
    inertance = fluid.density_kg_per_m3 * tube.length_m / area if tube.inertance else 0.0
    quadratic = tube.minor_loss * fluid.density_kg_per_m3 / (2.0 * area * area)
    reynolds = 2.0 * fluid.density_kg_per_m3 / (math.pi * tube.radius_m * fluid.viscosity_pa_s)
    turbulent = 0.0
    if tube.friction == BLASIUS:
        # 0.316 Re^(-1/4) (l / 2r) rho u^2 / 2 with Re = reynolds |q| and u = |q| / A.
        turbulent = (BLASIUS_COEFFICIENT * reynolds ** -0.25 * tube.length_m
                     / (2.0 * tube.radius_m) * fluid.density_kg_per_m3 / (2.0 * area * area))
    return TubeLaw(resistance, inertance, quadratic, reynolds, turbulent)
