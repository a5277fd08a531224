"""
The fluid network a scene may declare: the fluid, the supply line and the channels.

A scene with a ``network`` block puts time into the physics (softseq_ros.dynamic): fluid flows
from the syringe through the supply line into the segment it feeds (the base unless ``feeds``
names another) and through one channel between each pair of neighbouring segments. Every tube
is circular, given by its length and radius; what follows from them (Hagen-Poiseuille
resistance, inertance, minor losses) is computed in softseq_ros.dynamic.network. Schema
(optional keys show their defaults)::

    network:
      fluid: {viscosity_pa_s: 1.0e-3, density_kg_per_m3: 998.0}   # water at 20 C
      supply: {length_m: 0.5, radius_m: 0.8e-3}      # syringe to the fed segment: optional,
                                                    # but needed behind a scene's supply line
      feeds: bottom                                 # the segment the syringe feeds: the base
      channels:                                     # base to tip, one per neighbouring pair
        - {length_m: 0.01, radius_m: 0.25e-3, inertance: false, minor_loss: 0.0,
           friction: laminar}                       # or blasius: turbulent above Re ~ 1190
      rate_hz: 200.0                                # the actuator's output rate
      rtol: 1.0e-6                                  # the integrator's relative tolerance

A scene without it is quasi-static, exactly as before, and computes nothing dynamic.
"""

from dataclasses import dataclass

from softseq_ros.scene.validation import Context, join

WATER_VISCOSITY_PA_S = 1.0e-3      # water at 20 C
WATER_DENSITY_KG_PER_M3 = 998.0
DEFAULT_NETWORK_RATE_HZ = 200.0
DEFAULT_NETWORK_RTOL = 1.0e-6
# The integrator's relative tolerance: from near round-off to a percent.
NETWORK_RTOL_RANGE = (1e-13, 1e-2)
MAX_NETWORK_RATE_HZ = 1.0e4
LAMINAR, BLASIUS = 'laminar', 'blasius'
FRICTION_LAWS = (LAMINAR, BLASIUS)
TUBE_KEYS = ('length_m', 'radius_m', 'inertance', 'minor_loss', 'friction')
# A scene's compliant supply line (its ``supply`` block) is followed in time through the supply
# tube: joined to the fed segment without one, the line would sit at that segment's pressure at
# every instant, a constraint instead of an equation in time, and one with no solution where the
# segment passes a fold of its curve faster than the line can follow.
NO_SUPPLY_TUBE = ('a compliant supply needs a supply tube between the line and the fed '
                  'segment: give network.supply (its length_m and radius_m)')
# A regulator holds the pressure at its outlet: with no tube between it and the fed segment, that
# segment's pressure would jump with the target at once, and its volume with it.
NO_REGULATOR_TUBE = ('a pressure regulator drives the fed segment through the supply tube: give '
                     'network.supply (its length_m and radius_m)')


@dataclass(frozen=True)
class Fluid:
    """Dynamic viscosity [Pa s] and density [kg/m^3] of the working fluid."""

    viscosity_pa_s: float = WATER_VISCOSITY_PA_S
    density_kg_per_m3: float = WATER_DENSITY_KG_PER_M3


@dataclass(frozen=True)
class Tube:
    """
    A circular tube: length [m], inner radius [m].

    ``inertance``: the fluid's inertia counts (the tube's flow becomes a state);
    ``minor_loss``: the loss coefficient K of its ends and bends (dimensionless), a pressure
    drop of K rho q |q| / (2 A^2) on top of the viscous one;
    ``friction``: ``laminar`` (Hagen-Poiseuille) or ``blasius`` (Hagen-Poiseuille, and
    Blasius's turbulent law where it gives the larger drop: softseq_ros.dynamic.network).
    """

    length_m: float
    radius_m: float
    inertance: bool = False
    minor_loss: float = 0.0
    friction: str = LAMINAR


@dataclass(frozen=True)
class NetworkSettings:
    """
    The declared network: the fluid, the supply line (None: ideal) and the channels.

    ``feed``: the index (base to tip) of the segment the syringe feeds; 0, the base, unless
    the scene's ``feeds`` names another.
    """

    fluid: Fluid
    supply: Tube | None
    channels: tuple[Tube, ...]
    rate_hz: float = DEFAULT_NETWORK_RATE_HZ
    rtol: float = DEFAULT_NETWORK_RTOL
    feed: int = 0


def channel_names(segment_names: tuple[str, ...] | list[str]) -> tuple[str, ...]:
    """The channels' names, base to tip: ``<segment>_to_<next segment>``."""
    return tuple(f'{a}_to_{b}' for a, b in zip(segment_names, segment_names[1:]))


def _tube(ctx: Context, value: object, key_path: str) -> Tube:
    raw = ctx.mapping(value, key_path, ('length_m', 'radius_m'),
                      ('inertance', 'minor_loss', 'friction'))
    length = ctx.limited(raw['length_m'], join(key_path, 'length_m'), 'network.tube.length_m')
    radius = ctx.limited(raw['radius_m'], join(key_path, 'radius_m'), 'network.tube.radius_m')
    if radius > length:
        # Hagen-Poiseuille needs a tube, not an orifice.
        raise ctx.error(join(key_path, 'radius_m'), f'{radius:g} m exceeds the length '
                                                     f'({length:g} m): not a tube')
    inertance = raw.get('inertance', False)
    if not isinstance(inertance, bool):
        raise ctx.error(join(key_path, 'inertance'), f'must be true or false, got {inertance!r}')
    minor_loss = ctx.limited(raw.get('minor_loss', 0.0), join(key_path, 'minor_loss'),
                             'network.tube.minor_loss')
    friction = raw.get('friction', LAMINAR)
    if friction not in FRICTION_LAWS:
        raise ctx.error(join(key_path, 'friction'), f'must be one of {", ".join(FRICTION_LAWS)}, '
                                                     f'got {friction!r}')
    return Tube(length, radius, inertance, minor_loss, friction)


def read_network(ctx: Context, value: object,
                 segment_names: tuple[str, ...]) -> NetworkSettings | None:
    """The ``network`` block of a scene of segments ``segment_names`` (None: it has none)."""
    if value is None:
        return None
    segment_count = len(segment_names)
    raw = ctx.mapping(value, 'network', ('channels',),
                      ('fluid', 'supply', 'feeds', 'rate_hz', 'rtol'))
    fluid_raw = ctx.mapping(raw.get('fluid', {}), 'network.fluid', (),
                            ('viscosity_pa_s', 'density_kg_per_m3'))
    fluid = Fluid(
        ctx.limited(fluid_raw.get('viscosity_pa_s', WATER_VISCOSITY_PA_S),
                    'network.fluid.viscosity_pa_s'),
        ctx.limited(fluid_raw.get('density_kg_per_m3', WATER_DENSITY_KG_PER_M3),
                    'network.fluid.density_kg_per_m3'))
    supply = None if raw.get('supply') is None else _tube(ctx, raw['supply'], 'network.supply')
    feeds = raw.get('feeds', segment_names[0])
    if feeds not in segment_names:
        raise ctx.error('network.feeds', f'must name one of the segments '
                                         f'({", ".join(segment_names)}), got {feeds!r}')
    items = ctx.sequence(raw['channels'], 'network.channels')
    if len(items) != segment_count - 1:
        raise ctx.error('network.channels', f'needs one channel per pair of neighbouring '
                                            f'segments ({segment_count - 1}), got {len(items)}')
    channels = tuple(_tube(ctx, item, f'network.channels[{index}]')
                     for index, item in enumerate(items))
    rate = ctx.number(raw.get('rate_hz', DEFAULT_NETWORK_RATE_HZ), 'network.rate_hz', gt=0.0)
    if rate > MAX_NETWORK_RATE_HZ:
        raise ctx.error('network.rate_hz', f'must be <= {MAX_NETWORK_RATE_HZ:g}, got {rate:g}')
    rtol = ctx.number(raw.get('rtol', DEFAULT_NETWORK_RTOL), 'network.rtol', gt=0.0)
    low, high = NETWORK_RTOL_RANGE
    if not low <= rtol <= high:
        raise ctx.error('network.rtol', f'must be within {low:g} and {high:g}, got {rtol:g}')
    return NetworkSettings(fluid, supply, channels, rate, rtol, segment_names.index(feeds))
