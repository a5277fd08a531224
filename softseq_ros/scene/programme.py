"""
Syringe-pump programme: the injected volume as a function of time.

The pump pushes (or withdraws) fluid at a constant flow rate, so a programme is a sequence of
legs: inflate to a target injected volume, deflate to a target injected volume, or hold for a
duration. The legs repeat ``cycles`` times. The injected volume is therefore piecewise linear in
time and is evaluated exactly, never by integrating the flow.

Units: m^3 for volumes, m^3/s for the flow rate, s for times. ``injected`` always means the
total fluid volume minus the sum of the segments' rest volumes.
"""

from bisect import bisect_right
from dataclasses import dataclass
import math
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from softseq_ros.errors import UserError

ACTIONS = ('inflate', 'deflate', 'hold', 'profile')

# 0.05 mL/s, the flow rate of the paper's syringe pump.
DEFAULT_FLOW_RATE = 5.0e-8
# A duration within this share of a sampling period of a whole number of periods is one.
SAMPLE_SLACK = 1e-9
# A sampled history longer than this would not fit in a workstation's memory (0.8 GB a column).
MAX_SAMPLES = 10**8
# What a batch run (softseq run) takes on without being told to insist: 1e6 s of rig time
# (11.6 days; the paper's programme is 2610 s), as many messages as solve's samples, and a
# bag of 10 GB. A rig's own pump node is not bound by them: a real rig may run for weeks.
# A programme holds its breakpoints for every cycle (times and targets, exact): ten million of
# them take some 0.5 GB with what is kept beside them, and a programme longer than that (a
# profile of thousands of rows repeated a million times) would exhaust the memory as it loads.
MAX_BREAKPOINTS = 10**7
MAX_RUN_S = 1.0e6
MAX_RUN_MESSAGES = MAX_SAMPLES
MAX_RUN_BYTES = 10.0e9


def _finite(value: object, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
        raise ValueError(f'{what} must be a number, got {type(value).__name__} {value!r}')
    number = float(value)
    if not math.isfinite(number):
        raise ValueError(f'{what} must be finite, got {number}')
    return number


@dataclass(frozen=True)
class Leg:
    """
    One step of a pump programme.

    ``inflate`` and ``deflate`` move to the injected volume ``to_m3`` at the leg's own
    ``flow_rate`` [m^3/s], or at the pump's when it has none; ``hold`` keeps the volume for
    ``duration_s`` seconds. Use the ``inflate``, ``deflate`` and ``hold`` constructors rather
    than filling the fields by hand.
    """

    action: str
    to_m3: float | None = None
    duration_s: float | None = None
    flow_rate: float | None = None
    # A profile leg: the injected volume [m^3] at times [s] from the leg's start (the first
    # at 0), followed linearly between them; ``source`` names where they were read.
    times: tuple[float, ...] = ()
    volumes: tuple[float, ...] = ()
    source: str = ''

    def __post_init__(self) -> None:
        """Check that the leg names a known action and carries exactly the value it needs."""
        if self.action not in ACTIONS:
            raise ValueError(f'leg action must be one of {", ".join(ACTIONS)}, '
                             f'got {self.action!r}')
        if self.action == 'profile':
            self._check_profile()
            return
        if self.action == 'hold':
            if self.to_m3 is not None:
                raise ValueError('a hold leg takes duration_s, not to_m3')
            if self.duration_s is None:
                raise ValueError('a hold leg needs duration_s')
            if self.flow_rate is not None:
                raise ValueError('a hold leg moves nothing: it takes no flow_rate')
            duration = _finite(self.duration_s, 'hold duration_s')
            if duration <= 0.0:
                raise ValueError(f'hold duration_s must be > 0, got {duration}')
            object.__setattr__(self, 'duration_s', duration)
        else:
            if self.duration_s is not None:
                raise ValueError(f'an {self.action} leg takes to_m3, not duration_s')
            if self.to_m3 is None:
                raise ValueError(f'an {self.action} leg needs to_m3')
            target = _finite(self.to_m3, f'{self.action} to_m3')
            if target < 0.0:
                # Below zero injected the segments would be sucked under their rest volume,
                # which no segment model covers.
                raise ValueError(f'{self.action} to_m3 must be >= 0, got {target}')
            object.__setattr__(self, 'to_m3', target)
            if self.flow_rate is not None:
                rate = _finite(self.flow_rate, f'{self.action} flow_rate')
                if rate <= 0.0:
                    raise ValueError(f'{self.action} flow_rate must be > 0, got {rate}')
                object.__setattr__(self, 'flow_rate', rate)

    def _check_profile(self) -> None:
        where = self.source or 'a profile leg'
        times = tuple(_finite(t, f'{where}: time_s') for t in self.times)
        volumes = tuple(_finite(v, f'{where}: injected_m3') for v in self.volumes)
        if len(times) < 2 or len(times) != len(volumes):
            raise ValueError(f'{where}: a profile needs at least 2 rows of time_s and '
                             'injected_m3')
        if times[0] != 0.0:
            raise ValueError(f"{where}: time_s starts at 0 s (the leg's start), got "
                             f'{times[0]:g} s')
        for row in range(1, len(times)):
            if not times[row] > times[row - 1]:
                raise ValueError(f'{where}: time_s in data row {row + 1}: {times[row]:g} s does '
                                 f'not come after the row before ({times[row - 1]:g} s)')
        if any(v < 0.0 for v in volumes):
            raise ValueError(f'{where}: injected_m3 must be >= 0')
        if self.to_m3 is not None or self.duration_s is not None or self.flow_rate is not None:
            raise ValueError(f'{where}: a profile leg takes its times and volumes only')
        object.__setattr__(self, 'times', times)
        object.__setattr__(self, 'volumes', volumes)

    @classmethod
    def profile(cls, times: Sequence[float], volumes: Sequence[float],
                source: str = '') -> 'Leg':
        """Follow ``volumes`` [m^3] at ``times`` [s] from the leg's start, linearly between."""
        return cls('profile', times=tuple(times), volumes=tuple(volumes), source=source)

    @classmethod
    def inflate(cls, to_m3: float, flow_rate: float | None = None) -> 'Leg':
        """Inflate to the injected volume ``to_m3`` [m^3], at ``flow_rate`` [m^3/s] if given."""
        return cls('inflate', to_m3=to_m3, flow_rate=flow_rate)

    @classmethod
    def deflate(cls, to_m3: float, flow_rate: float | None = None) -> 'Leg':
        """Deflate to the injected volume ``to_m3`` [m^3], at ``flow_rate`` [m^3/s] if given."""
        return cls('deflate', to_m3=to_m3, flow_rate=flow_rate)

    @classmethod
    def hold(cls, duration_s: float) -> 'Leg':
        """Keep the injected volume for ``duration_s`` [s]."""
        return cls('hold', duration_s=duration_s)


def breakpoints_problem(per_leg: Sequence[int], cycles: int) -> str | None:
    """
    Why a programme of legs with these breakpoints each, repeated ``cycles`` times, is too long.

    None when it holds at most :data:`MAX_BREAKPOINTS`.
    """
    per_cycle = sum(per_leg)
    total = per_cycle * cycles
    if total <= MAX_BREAKPOINTS:
        return None
    return (f"{cycles} cycles of {per_cycle} breakpoints each (the legs, a profile's rows) make "
            f'{total:.3g}, more than the {MAX_BREAKPOINTS:.0e} a programme holds: give fewer '
            'cycles, or a profile of fewer rows')


@dataclass(frozen=True)
class PumpProfile:
    """
    A pump programme: ``legs`` repeated ``cycles`` times.

    Each leg moves at its own flow rate, or at ``flow_rate`` [m^3/s] when it gives none.
    Time 0 is the start of the first leg, where the injected volume is ``start_injected``.
    ``start_history`` (injected volumes [m^3], in order, from rest) is how the actuator got
    there when not straight from rest: its last volume is ``start_injected``.
    Raises ValueError when a leg cannot be run from the volume it starts at (an inflate target
    not above it, a deflate target not below it), naming the cycle and leg.
    """

    legs: tuple[Leg, ...]
    flow_rate: float = DEFAULT_FLOW_RATE
    cycles: int = 1
    start_injected: float = 0.0
    start_history: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        """Validate the programme and precompute its breakpoints."""
        legs = tuple(self.legs)
        if not legs:
            raise ValueError('a pump profile needs at least one leg')
        for index, leg in enumerate(legs):
            if not isinstance(leg, Leg):
                raise ValueError(f'legs[{index}] must be a Leg, got {type(leg).__name__}')
        object.__setattr__(self, 'legs', legs)
        if isinstance(self.cycles, int) and not isinstance(self.cycles, bool):
            too_long = breakpoints_problem(
                [len(leg.times) - 1 if leg.action == 'profile' else 1 for leg in legs],
                self.cycles)
            if too_long is not None:
                raise ValueError(f'cycles: {too_long}')
        flow = _finite(self.flow_rate, 'flow_rate')
        if flow <= 0.0:
            raise ValueError(f'flow_rate must be > 0, got {flow}')
        object.__setattr__(self, 'flow_rate', flow)
        if isinstance(self.cycles, bool) or not isinstance(self.cycles, (int, np.integer)):
            raise ValueError(f'cycles must be an integer, got {self.cycles!r}')
        if self.cycles < 1:
            raise ValueError(f'cycles must be >= 1, got {self.cycles}')
        start = _finite(self.start_injected, 'start_injected')
        if start < 0.0:
            raise ValueError(f'start_injected must be >= 0, got {start}')
        object.__setattr__(self, 'start_injected', start)
        history = tuple(_finite(v, f'start_history[{i}]')
                        for i, v in enumerate(self.start_history))
        if any(v < 0.0 for v in history):
            raise ValueError('start_history volumes must be >= 0')
        if history and history[-1] != start:
            raise ValueError(f'start_history ends at {history[-1]:g} m^3, not at '
                             f'start_injected {start:g} m^3')
        object.__setattr__(self, 'start_history', history)

        times = [0.0]
        volumes = [start]
        rates = []      # per interval between breakpoints: the flow's magnitude (0 on a hold)
        for cycle in range(int(self.cycles)):
            for index, leg in enumerate(legs):
                where = f'cycle {cycle + 1}, legs[{index}]'
                now = volumes[-1]
                if leg.action == 'hold':
                    times.append(times[-1] + leg.duration_s)
                    volumes.append(now)
                    rates.append(0.0)
                    continue
                if leg.action == 'profile':
                    if leg.volumes[0] != now:
                        raise ValueError(f'{where}: the profile starts at {leg.volumes[0]:g} '
                                         f'm^3, not at the injected volume {now:g} m^3 it '
                                         'starts from')
                    start_t = times[-1]
                    for t0, t1, v0, v1 in zip(leg.times[:-1], leg.times[1:], leg.volumes[:-1],
                                              leg.volumes[1:]):
                        times.append(start_t + t1)
                        volumes.append(v1)
                        rates.append(abs(v1 - v0) / (t1 - t0))
                    continue
                if leg.action == 'inflate' and not leg.to_m3 > now:
                    raise ValueError(f'{where}: inflate target {leg.to_m3:g} m^3 is not above '
                                     f'the injected volume {now:g} m^3 it starts from')
                if leg.action == 'deflate' and not leg.to_m3 < now:
                    raise ValueError(f'{where}: deflate target {leg.to_m3:g} m^3 is not below '
                                     f'the injected volume {now:g} m^3 it starts from')
                rate = flow if leg.flow_rate is None else leg.flow_rate
                times.append(times[-1] + abs(leg.to_m3 - now) / rate)
                volumes.append(leg.to_m3)
                rates.append(rate)
        object.__setattr__(self, '_times', np.array(times))
        object.__setattr__(self, '_rates', np.array(rates))
        object.__setattr__(self, '_rate_list', rates)
        object.__setattr__(self, '_volumes', np.array(volumes))
        object.__setattr__(self, '_time_list', [float(x) for x in times])
        object.__setattr__(self, '_volume_list', [float(x) for x in volumes])

    def duration(self) -> float:
        """Total run time of all cycles [s]."""
        return float(self._times[-1])

    def breakpoints(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Times [s] and injected volumes [m^3] at the start and at the end of every leg."""
        return self._times.copy(), self._volumes.copy()

    def max_flow_rate(self) -> float:
        """The fastest the programme moves the syringe [m^3/s], in either direction."""
        return max(self._rate_list, default=self.flow_rate)

    def max_injected(self) -> float:
        """Largest injected volume the programme reaches [m^3]."""
        return float(self._volumes.max())

    def injected_at(self, t: ArrayLike) -> NDArray[np.float64]:
        """
        Injected volume [m^3] at times ``t`` [s] (any shape).

        Before 0 it is ``start_injected``; after the end it stays at the final volume.
        """
        return np.asarray(np.interp(np.asarray(t, dtype=float), self._times, self._volumes),
                          dtype=float)

    def flow_at(self, t: ArrayLike) -> NDArray[np.float64]:
        """
        Signed flow [m^3/s] at times ``t`` [s]: positive while inflating, 0 outside the programme.

        At a breakpoint the flow of the leg that starts there is returned.
        """
        times = np.asarray(t, dtype=float)
        leg_index = np.searchsorted(self._times, times, side='right') - 1
        n_legs = self._times.size - 1
        inside = (leg_index >= 0) & (leg_index < n_legs)
        safe = np.clip(leg_index, 0, n_legs - 1)
        direction = np.sign(self._volumes[safe + 1] - self._volumes[safe])
        return np.where(inside, direction * self._rates[safe], 0.0)

    def command_at(self, t: float) -> tuple[float, float]:
        """
        Injected volume [m^3] and signed flow [m^3/s] at one time ``t`` [s].

        The same values as ``injected_at`` and ``flow_at``, for the pump's per-tick path, where
        numpy's overhead on a single number dominates.
        """
        times, volumes = self._time_list, self._volume_list
        leg = bisect_right(times, t) - 1
        if leg < 0:
            return volumes[0], 0.0
        if leg >= len(times) - 1:
            return volumes[-1], 0.0
        t0, t1, v0, v1 = times[leg], times[leg + 1], volumes[leg], volumes[leg + 1]
        volume = v0 + (v1 - v0) * (t - t0) / (t1 - t0) if t1 > t0 else v1
        rate = self._rate_list[leg]
        flow = rate if v1 > v0 else (-rate if v1 < v0 else 0.0)
        return volume, flow

    def commands_at(self, t: NDArray[np.float64]) -> tuple[NDArray[np.float64],
                                                          NDArray[np.float64]]:
        """
        :meth:`command_at` of many times: the same operations, so the same numbers.

        For a batch run's blocks of pump ticks; volumes and flows as arrays.
        """
        times = np.asarray(self._time_list, dtype=float)
        volumes = np.asarray(self._volume_list, dtype=float)
        t = np.asarray(t, dtype=float)
        leg = np.searchsorted(times, t, side='right') - 1
        last = times.size - 1
        inside = (leg >= 0) & (leg < last)
        safe = np.clip(leg, 0, max(last - 1, 0))
        t0, t1 = times[safe], times[np.minimum(safe + 1, last)]
        v0, v1 = volumes[safe], volumes[np.minimum(safe + 1, last)]
        with np.errstate(invalid='ignore', divide='ignore'):
            ramp = v0 + (v1 - v0) * (t - t0) / (t1 - t0)
        volume = np.where(inside, np.where(t1 > t0, ramp, v1),
                          np.where(leg < 0, volumes[0], volumes[-1]))
        rate = self._rates[safe]
        flow = np.where(inside, np.where(v1 > v0, rate, np.where(v1 < v0, -rate, 0.0)), 0.0)
        return volume, flow

    def sample(self, rate_hz: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """
        Times at ``rate_hz`` from 0 to the end, the exact end time included, and the volumes there.

        Returns ``(t, injected)``; the last interval is shorter when the duration is not a
        multiple of the period.
        """
        rate = _finite(rate_hz, 'rate_hz')
        if rate <= 0.0:
            raise ValueError(f'rate_hz must be > 0, got {rate}')
        end = self.duration()
        if end * rate > MAX_SAMPLES:
            raise ValueError(f"{rate:g} Hz over the programme's {end:.6g} s gives "
                             f'{end * rate:.3g} samples, more than {MAX_SAMPLES:.0e}: '
                             'lower the rate or shorten the programme')
        # Round so that a duration that is a multiple of the period up to rounding does not
        # produce a sliver of an interval at the end.
        whole = int(math.floor(end * rate + SAMPLE_SLACK))
        t = np.arange(whole + 1, dtype=float) / rate
        if end - t[-1] > SAMPLE_SLACK / rate:
            t = np.append(t, end)
        else:
            t[-1] = end
        return t, self.injected_at(t)


def longest_part(profile: 'PumpProfile', prefix: str = '') -> str:
    """
    What makes a programme long, as its keys say it: one leg, or the number of cycles.

    E.g. ``pump.legs[0].inflate_to_m3: 6.5e-05 m^3 at pump.flow_rate_m3_per_s 1e-15 m^3/s
    takes 6.5e+10 s`` or ``pump.cycles: 1000000 cycles of 2610 s``.
    """
    times, volumes = profile.breakpoints()
    spans = np.diff(times)
    longest = int(np.argmax(spans))
    if profile.cycles > 1 and spans[longest] < 0.5 * profile.duration():
        per_cycle = float(times[-1] - times[-1 - len(profile.legs)])
        return f'{prefix}cycles: {profile.cycles} cycles of {per_cycle:.6g} s'
    # Each leg's first interval among the breakpoints, in a cycle.
    firsts = np.cumsum([0] + [len(leg.times) - 1 if leg.action == 'profile' else 1
                              for leg in profile.legs])
    index = int(np.searchsorted(firsts, longest % firsts[-1], side='right')) - 1
    leg = profile.legs[index]
    key = leg_key(index, leg, prefix)
    if leg.action in ('hold', 'profile'):
        return f'{key}: {spans[longest]:.6g} s'
    moved = abs(float(volumes[longest + 1] - volumes[longest]))
    if leg.flow_rate is None:
        rate_key, rate = f'{prefix}flow_rate_m3_per_s', profile.flow_rate
    else:
        rate_key, rate = f'{prefix}legs[{index}].flow_rate_m3_per_s', leg.flow_rate
    return f'{key}: {moved:.6g} m^3 at {rate_key} {rate:g} m^3/s takes {spans[longest]:.6g} s'


class ProgrammeError(UserError):
    """A programme the segments cannot follow; ``key`` names the leg, ``reason`` says why."""

    def __init__(self, key: str, reason: str) -> None:
        """``<key>: <reason>``, e.g. ``legs[0].inflate_to_m3: 0.00011 m^3 is beyond ...``."""
        super().__init__(f'{key}: {reason}')
        self.key = key
        self.reason = reason


def leg_key(index: int, leg: Leg, prefix: str = '') -> str:
    """The key of a leg's value, as a scene or a node parameter spells it."""
    field = {'hold': 'hold_s', 'profile': 'profile'}.get(leg.action, f'{leg.action}_to_m3')
    return f'{prefix}legs[{index}].{field}'


def check_capacity(profile: PumpProfile, capacity: float, prefix: str = '') -> None:
    """Refuse a start volume or leg beyond ``capacity`` [m^3], what the segments hold."""
    for index, volume in enumerate(profile.start_history):
        if volume > capacity:
            raise ProgrammeError(f'{prefix}start_history_m3[{index}]',
                                 f'{volume:g} m^3 exceeds what the segments hold '
                                 f'({capacity:g} m^3 injected)')
    if profile.start_injected > capacity:
        raise ProgrammeError(f'{prefix}start_injected_m3',
                             f'{profile.start_injected:g} m^3 exceeds what the segments hold '
                             f'({capacity:g} m^3 injected)')
    for index, leg in enumerate(profile.legs):
        for volume in leg_targets(leg):
            if volume > capacity:
                raise ProgrammeError(leg_key(index, leg, prefix),
                                     f'{volume:g} m^3 exceeds what the segments hold '
                                     f'({capacity:g} m^3 injected)')


def leg_targets(leg: Leg) -> tuple[float, ...]:
    """The injected volumes [m^3] a leg moves to, in order (none for a hold)."""
    if leg.action == 'hold':
        return ()
    return leg.volumes[1:] if leg.action == 'profile' else (leg.to_m3,)
