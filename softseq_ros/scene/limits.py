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
}
