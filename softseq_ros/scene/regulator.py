"""
A pressure regulator in place of the syringe: a programme of target gauge pressures.

Many labs drive soft actuators with a pressure regulator instead of a syringe pump. A scene
says so in its ``supply`` block, and its ``pump`` programme is then one of gauge pressures
(docs/supply.md)::

    supply:
      regulator:
        time_constant_s: 0.0            # optional: its first-order response (0: at once)
        max_flow_m3_per_s: 1.0e-5       # optional: the most it delivers or vents (no limit)
        max_pressure_pa: 12000          # optional: its relief [Pa, gauge]; by default
                                        # RELIEF_MARGIN x the highest pressure on the curves
    pump:                               # the regulator's programme, from 0 Pa gauge at rest
      pressure_rate_pa_per_s: 100       # optional: the legs' rate unless a leg gives its own
      legs:
        - {inflate_to_pa: 8000}
        - {hold_s: 10}
        - {deflate_to_pa: 0, rate_pa_per_s: 50}
        - {profile: pressures.csv}      # time_s (from the leg's start) against gauge_pa
      cycles: 1
      rate_hz: 50                       # how often the path is sampled

The target pressure is piecewise linear in time, like the syringe's injected volume
(softseq_ros.scene.programme), and evaluated exactly. Every target must lie within what each
segment holds on a stable (rising) piece of its curve: above the lowest such top, some segment
has no state left to go to (quasi-statically no equilibrium, in time it runs off the end of
its curve), so the scene is refused before anything runs.
"""

from dataclasses import dataclass
import math
from pathlib import Path
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from softseq_ros.errors import UserError
from softseq_ros.scene.csv_columns import read_columns
from softseq_ros.scene.limits import RELIEF_MARGIN
from softseq_ros.scene.programme import breakpoints_problem
from softseq_ros.scene.validation import Context, join
from softseq_ros.segments.models import Segment

FloatArray = NDArray[np.float64]

# 100 Pa/s: the paper's segments' 10 kPa range in 100 s, about as long as the syringe's
# programme takes to reach their peaks at 0.05 mL/s.
DEFAULT_PRESSURE_RATE_PA_PER_S = 100.0
DEFAULT_REGULATOR_RATE_HZ = 50.0
PRESSURE_LEG_KEYS = ('inflate_to_pa', 'deflate_to_pa', 'hold_s', 'profile')
PRESSURE_RATE_KEY = 'rate_pa_per_s'
PRESSURE_PROFILE_COLUMNS = ('time_s', 'gauge_pa')
PUMP_KEYS = ('legs', 'pressure_rate_pa_per_s', 'cycles', 'rate_hz')
# The syringe's keys, which a regulator's programme does not take: said so by name.
SYRINGE_PUMP_KEYS = ('flow_rate_m3_per_s', 'start_injected_m3', 'start_history_m3',
                     'start_branch')
SYRINGE_LEG_KEYS = ('inflate_to_m3', 'deflate_to_m3', 'flow_rate_m3_per_s')
REGULATOR_KEYS = ('time_constant_s', 'max_flow_m3_per_s', 'max_pressure_pa')


class PressureProfileError(UserError):
    """A regulator's pressure profile file that cannot be read."""


@dataclass(frozen=True)
class PressureProgramme:
    """
    Target gauge pressures [Pa] at breakpoint times [s], followed linearly between them.

    Time 0 is the programme's start, at 0 Pa gauge (the segments at rest). ``corners``: the
    times where its legs meet (a profile's rows inside a leg are not among them); empty: every
    breakpoint is one.
    """

    times: tuple[float, ...]
    pressures: tuple[float, ...]
    corners: tuple[float, ...] = ()

    def duration(self) -> float:
        """When the last leg of the last cycle ends [s]."""
        return self.times[-1]

    def target_at(self, t: ArrayLike) -> FloatArray:
        """The target gauge pressure [Pa] at times ``t`` [s] (the ends held beyond them)."""
        return np.interp(np.asarray(t, dtype=float), self.times, self.pressures)

    def sample_times(self, rate_hz: float) -> FloatArray:
        """Times at ``rate_hz`` from 0 to the end, the end included, and every breakpoint."""
        regular = np.arange(0.0, self.duration(), 1.0 / rate_hz)
        return np.unique(np.concatenate([regular, self.times]))

    def highest(self) -> float:
        """The highest target [Pa]."""
        return max(self.pressures)


@dataclass(frozen=True)
class Regulator:
    """
    A pressure regulator: its programme, response and limits.

    ``time_constant_s``: the outlet follows the target as a first-order lag (0: at once);
    ``max_flow_m3_per_s``: the most it delivers or vents (inf: no limit);
    ``max_pressure_pa``: its relief [Pa, gauge], above every target;
    ``rate_hz``: how often a path is sampled (and the rig's regulator commands);
    ``pressure_rate_pa_per_s``: the programme's default rate, at which a controller's target
    pressure is approached on the rig.
    """

    programme: PressureProgramme
    time_constant_s: float = 0.0
    max_flow_m3_per_s: float = math.inf
    max_pressure_pa: float = math.inf
    rate_hz: float = DEFAULT_REGULATOR_RATE_HZ
    pressure_rate_pa_per_s: float = DEFAULT_PRESSURE_RATE_PA_PER_S

    def definition(self) -> dict[str, object]:
        """The regulator's numbers (its programme as breakpoints)."""
        return {'time_constant_s': self.time_constant_s,
                'max_flow_m3_per_s': self.max_flow_m3_per_s,
                'max_pressure_pa': self.max_pressure_pa,
                'times_s': list(self.programme.times),
                'target_pa': list(self.programme.pressures)}


def stable_tops(segments: Sequence[Segment]) -> list[float]:
    """Per segment, the highest gauge pressure [Pa] it holds on a rising piece of its curve."""
    return [max((piece.p_max for piece in segment.monotone_pieces() if piece.direction > 0),
                default=-math.inf) for segment in segments]


def _profile(ctx: Context, value: object, key_path: str,
             highest: float) -> tuple[list[float], list[float], Path]:
    """A ``profile`` leg's times and pressures (relative to the scene's folder)."""
    relative = Path(ctx.text(value, key_path))
    path = relative if relative.is_absolute() else ctx.folder / relative
    try:
        columns = read_columns(path, PRESSURE_PROFILE_COLUMNS, PressureProfileError,
                               'pressure profile')
    except PressureProfileError as err:
        raise ctx.error(key_path, str(err)) from None
    times, pressures = columns['time_s'].tolist(), columns['gauge_pa'].tolist()
    if len(times) < 2:
        raise ctx.error(key_path, f'{path}: a profile needs at least 2 rows of time_s and '
                                  'gauge_pa')
    if times[0] != 0.0:
        raise ctx.error(key_path, f"{path}: time_s starts at 0 s (the leg's start), got "
                                  f'{times[0]:g} s')
    for row in range(1, len(times)):
        if not times[row] > times[row - 1]:
            raise ctx.error(key_path, f'{path}: time_s in data row {row + 1}: {times[row]:g} s '
                                      f'does not come after the row before '
                                      f'({times[row - 1]:g} s)')
    for row, pressure in enumerate(pressures):
        if not 0.0 <= pressure <= highest:
            raise ctx.error(key_path, f'{path}: gauge_pa in data row {row + 1}: {pressure:g} Pa '
                                      f'is outside 0 to {highest:g} Pa')
    return times, pressures, path


def _legs(ctx: Context, value: object, default_rate: float, cycles: int, highest: float,
          why_highest: str) -> PressureProgramme:
    """The legs, walked as the regulator will run them, into breakpoints."""
    items = ctx.sequence(value, 'pump.legs')
    if not items:
        raise ctx.error('pump.legs', 'needs at least one leg')
    parsed = []
    for index, item in enumerate(items):
        where = f'pump.legs[{index}]'
        raw = ctx.mapping(item, where, (), PRESSURE_LEG_KEYS + (PRESSURE_RATE_KEY,)
                          + SYRINGE_LEG_KEYS)
        syringe = [key for key in SYRINGE_LEG_KEYS if key in raw]
        if syringe:
            raise ctx.error(join(where, syringe[0]), 'behind a pressure regulator the legs are '
                                                     'gauge pressures: give inflate_to_pa, '
                                                     'deflate_to_pa (rate_pa_per_s), hold_s or '
                                                     'profile')
        actions = [key for key in raw if key != PRESSURE_RATE_KEY]
        if len(actions) != 1:
            raise ctx.error(where, f'needs exactly one of {", ".join(PRESSURE_LEG_KEYS)}, got '
                                   f'{len(actions)} keys ({", ".join(actions) or "none"})')
        key = actions[0]
        rate = None
        if PRESSURE_RATE_KEY in raw:
            if key not in ('inflate_to_pa', 'deflate_to_pa'):
                raise ctx.error(join(where, PRESSURE_RATE_KEY),
                                'only an inflate_to_pa or deflate_to_pa leg takes a rate')
            rate = ctx.limited(raw[PRESSURE_RATE_KEY], join(where, PRESSURE_RATE_KEY),
                               'pump.legs.rate_pa_per_s')
        at = join(where, key)
        if key == 'hold_s':
            value = ctx.limited(raw[key], at, 'pump.legs.hold_s')
        elif key == 'profile':
            value = _profile(ctx, raw[key], at, highest)
        else:
            value = ctx.number(raw[key], at, ge=0.0)
            if value > highest:
                raise ctx.error(at, f'{value:g} Pa is above {why_highest}')
        parsed.append((index, key, value, rate))
    too_long = breakpoints_problem(
        [len(value[0]) - 1 if key == 'profile' else 1 for _, key, value, _ in parsed], cycles)
    if too_long is not None:
        raise ctx.error('pump.cycles', too_long)
    times, pressures, corners = [0.0], [0.0], [0.0]
    for cycle in range(1, cycles + 1):
        in_cycle = f' in cycle {cycle}' if cycles > 1 else ''
        for index, key, value, rate in parsed:
            at = f'pump.legs[{index}].{key}'
            now = pressures[-1]
            if key == 'hold_s':
                times.append(times[-1] + value)
                pressures.append(now)
            elif key == 'profile':
                leg_times, leg_pressures, path = value
                if leg_pressures[0] != now:
                    raise ctx.error(at, f'{path}: the profile starts at {leg_pressures[0]:g} Pa, '
                                        f'not at the target the leg starts from ({now:g} '
                                        f'Pa{in_cycle})')
                start = times[-1]
                times.extend(start + t for t in leg_times[1:])
                pressures.extend(leg_pressures[1:])
            else:
                target = value
                if key == 'inflate_to_pa' and not target > now:
                    raise ctx.error(at, f'{target:g} Pa must be above the target the leg starts '
                                        f'from ({now:g} Pa{in_cycle})')
                if key == 'deflate_to_pa' and not target < now:
                    raise ctx.error(at, f'{target:g} Pa must be below the target the leg starts '
                                        f'from ({now:g} Pa{in_cycle})')
                times.append(times[-1] + abs(target - now) / (rate or default_rate))
                pressures.append(target)
            corners.append(times[-1])
    return PressureProgramme(tuple(times), tuple(pressures), tuple(corners))


def read_regulator(ctx: Context, supply: object, pump: object,
                   segments: Sequence[Segment]) -> Regulator:
    """The ``supply.regulator`` block and the ``pump`` block as its programme of pressures."""
    raw = ctx.mapping(supply, 'supply.regulator', (), REGULATOR_KEYS)
    tops = stable_tops(segments)
    curve_highest = max(max(piece.p_max for piece in s.monotone_pieces()) for s in segments)
    relief = (ctx.limited(raw['max_pressure_pa'], 'supply.regulator.max_pressure_pa')
              if 'max_pressure_pa' in raw else RELIEF_MARGIN * max(curve_highest, 0.0))
    lowest_top = min(tops)
    weakest = segments[tops.index(lowest_top)].name
    if lowest_top <= 0.0:
        raise ctx.error('supply.regulator', f'segment {weakest} holds no gauge pressure above '
                                            '0 Pa on a stable piece: a regulator has nothing to '
                                            'hold it at')
    if relief <= lowest_top:
        highest, why = relief, f"the regulator's relief (supply.regulator.max_pressure_pa, " \
                               f'{relief:g} Pa)'
    else:
        highest, why = lowest_top, (f'the highest pressure segment {weakest} holds on a stable '
                                    f'piece of its curve ({lowest_top:g} Pa): beyond it the '
                                    'segment has no state left to go to')
    pump_raw = ctx.mapping(pump, 'pump', ('legs',), PUMP_KEYS + SYRINGE_PUMP_KEYS)
    syringe = [key for key in SYRINGE_PUMP_KEYS if key in pump_raw]
    if syringe:
        raise ctx.error(join('pump', syringe[0]), 'a pressure regulator drives this scene from '
                                                  'rest: its programme takes legs, '
                                                  'pressure_rate_pa_per_s, cycles and rate_hz')
    default_rate = ctx.limited(pump_raw.get('pressure_rate_pa_per_s',
                                            DEFAULT_PRESSURE_RATE_PA_PER_S),
                               'pump.pressure_rate_pa_per_s')
    cycles = int(ctx.limited(pump_raw.get('cycles', 1), 'pump.cycles', integer=True))
    rate_hz = ctx.limited(pump_raw.get('rate_hz', DEFAULT_REGULATOR_RATE_HZ), 'pump.rate_hz')
    programme = _legs(ctx, pump_raw['legs'], default_rate, cycles, highest, why)
    return Regulator(
        programme,
        time_constant_s=ctx.limited(raw.get('time_constant_s', 0.0),
                                    'supply.regulator.time_constant_s'),
        max_flow_m3_per_s=(ctx.limited(raw['max_flow_m3_per_s'],
                                       'supply.regulator.max_flow_m3_per_s')
                           if 'max_flow_m3_per_s' in raw else math.inf),
        max_pressure_pa=relief, rate_hz=rate_hz, pressure_rate_pa_per_s=default_rate)
