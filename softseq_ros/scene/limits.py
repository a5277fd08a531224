"""
One set of limits for the settings a scene and a node both take.

The scene loader refuses a value outside them naming the scene key, the nodes declare the same
range on their parameter (``ros2 param describe`` shows it) and refuse it naming the
parameter; so a scene that loads also runs. The upper bounds are far above any rig's needs and
below what would exhaust the memory or stall a run: a pump commanding at 10 kHz, a camera at
1 kHz, 10^4 backbone points per segment, 8192 x 8192 images, 10^5 solver samples, 10^6 cycles.
"""

from dataclasses import dataclass


@dataclass(frozen=True)
class Limit:
    """An allowed range; ``open_minimum`` excludes the minimum itself."""

    minimum: float | None = None
    maximum: float | None = None
    open_minimum: bool = False

    def reason(self, value: float) -> str | None:
        """Why ``value`` is outside the range (``must be <= 1000, got 1e+09``), or None."""
        if self.minimum is not None:
            if self.open_minimum and not value > self.minimum:
                return f'must be > {self.minimum:g}, got {value:g}'
            if not self.open_minimum and not value >= self.minimum:
                return f'must be >= {self.minimum:g}, got {value:g}'
        if self.maximum is not None and not value <= self.maximum:
            return f'must be <= {self.maximum:g}, got {value:g}'
        return None

    def bounds(self) -> dict[str, float | bool | None]:
        """As the nodes' ``declare_number`` / ``declare_integer`` keywords."""
        bounds: dict[str, float | bool | None] = {'minimum': self.minimum,
                                                  'maximum': self.maximum}
        if self.open_minimum:
            bounds['open_minimum'] = True
        return bounds


# The relief by default: this multiple of the highest pressure on any segment's curve (a rig 50 %
# beyond anything its segments hold is blocked or broken, and a real relief is set so). The
# syringe pump's adds its supply tube's steady drop (softseq_ros.rig.model); a regulator's is
# at its outlet.
RELIEF_MARGIN = 1.5

# Keyed by the scene's key path; the node parameter of the same meaning uses the same entry.
LIMITS: dict[str, Limit] = {
    'pump.rate_hz': Limit(0.0, 1.0e4, open_minimum=True),
    # From 1 pL/s (below the slowest syringe pumps) to 1 L/s (far above the fastest).
    'pump.flow_rate_m3_per_s': Limit(1.0e-15, 1.0e-3),
    'pump.cycles': Limit(1, 1_000_000),
    'pump.legs.hold_s': Limit(0.0, 1.0e7, open_minimum=True),
    'camera.rate_hz': Limit(0.0, 1.0e3, open_minimum=True),
    'camera.noise_std_m': Limit(0.0, 1.0),
    'camera.seed': Limit(0, 2**63 - 1),
    'camera.points_per_segment': Limit(1, 10_000),
    'camera.image_width_px': Limit(16, 8192),
    'camera.image_height_px': Limit(16, 8192),
    'solver.resolution': Limit(16, 100_000),
    # The syringe line: trapped air up to a litre, a compliance up to 1e-6 m^3/Pa (a metre of
    # very soft tubing holds far less), an ambient from 10 kPa to 1 MPa absolute, and a
    # polytropic exponent from isothermal (1) to beyond any gas's (5/3 for a monatomic one).
    'supply.trapped_gas_m3': Limit(0.0, 1.0e-3),
    'supply.line_compliance_m3_per_pa': Limit(0.0, 1.0e-6),
    'supply.ambient_pa': Limit(1.0e4, 1.0e6),
    'supply.polytropic_exponent': Limit(1.0, 2.0),
    # A pressure regulator: a response from at once to three hours, a flow limit as a pump's,
    # a relief up to 10 MPa (far above any soft actuator), ramps from 1 mPa/s to 1 GPa/s.
    'supply.regulator.time_constant_s': Limit(0.0, 1.0e4),
    'supply.regulator.max_flow_m3_per_s': Limit(1.0e-15, 1.0e-3),
    'supply.regulator.max_pressure_pa': Limit(0.0, 1.0e7, open_minimum=True),
    'pump.pressure_rate_pa_per_s': Limit(1.0e-3, 1.0e9),
    'pump.legs.rate_pa_per_s': Limit(1.0e-3, 1.0e9),
    # A segment from a micrometre to 10 m (the paper's: 0.111 m).
    'segments.length_m': Limit(0.0, 10.0, open_minimum=True),
    # From a gas (air: 1.8e-5 Pa s) to a silicone gum (1e4 Pa s); water: 1e-3 Pa s. Beyond,
    # a channel's resistance leaves the numbers a double holds (1e-300 Pa s divided by zero).
    'network.fluid.viscosity_pa_s': Limit(1.0e-6, 1.0e4),
    # From a thin gas to beyond mercury (13,500 kg/m^3).
    'network.fluid.density_kg_per_m3': Limit(1.0e-2, 3.0e4),
    # A tube from microfluidics (1 um) to 10 cm across, and up to 1 km long.
    'network.tube.radius_m': Limit(1.0e-6, 0.1),
    'network.tube.length_m': Limit(1.0e-6, 1.0e3),
    # A loss coefficient of ends and bends: a sharp orifice is about 1e3.
    'network.tube.minor_loss': Limit(0.0, 1.0e6),
}
