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

The pressure drop over a tube is therefore ``L dq/dt + R q + a q |q|`` with a = K rho / (2 A^2).
"""

from dataclasses import dataclass
import math

from softseq_ros.scene.network import Fluid, Tube

LAMINAR_REYNOLDS = 2300.0


@dataclass(frozen=True)
class TubeLaw:
    """The coefficients of one tube's pressure drop: L dq/dt + R q + a q |q|."""

    resistance: float       # R [Pa s/m^3]
    inertance: float        # L [Pa s^2/m^3]; 0 when the tube's inertia is left out
    quadratic: float        # a [Pa s^2/m^6]
    reynolds_per_flow: float  # Re / |q| [s/m^3]

    def flow(self, drop_pa: float) -> float:
        """The steady flow [m^3/s] a pressure drop drives (no inertia): R q + a q|q| = drop."""
        if self.quadratic == 0.0:
            return drop_pa / self.resistance
        a, r = self.quadratic, self.resistance
        # The root of a q^2 + R q - |drop| = 0, written so that it stays exact as a -> 0.
        magnitude = 2.0 * abs(drop_pa) / (r + math.sqrt(r * r + 4.0 * a * abs(drop_pa)))
        return math.copysign(magnitude, drop_pa)

    def drop(self, flow: float) -> float:
        """The steady pressure drop [Pa] of a flow (no inertia)."""
        return self.resistance * flow + self.quadratic * flow * abs(flow)

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
    return TubeLaw(resistance, inertance, quadratic, reynolds)
