"""
The actuator's model: what the segments do with the fluid the pump injects, and when.

The actuator core (softseq_ros.rig.actuator) knows its physics only through this seam:

- :meth:`ActuatorModel.command`: the pump's injected volume from a time on;
- :meth:`ActuatorModel.advance`: time passes with the last command held (``None``: nothing
  changed, nothing to publish);
- :meth:`ActuatorModel.state`: gauge pressure, segment volumes and curvatures now;
- :meth:`ActuatorModel.saved` and :meth:`ActuatorModel.resume`: a restarted actuator keeps the
  branch its history put it on;
- :meth:`ActuatorModel.check_programme` and :attr:`ActuatorModel.end_stop_m3`: the pump learns
  its reach from the model, not from the physics behind it;
- :meth:`ActuatorModel.take_warnings` and :meth:`ActuatorModel.take_notes`: lines for the
  actuator's log (a channel no longer laminar; a segment passing a fold of its curve).

A model with :attr:`ActuatorModel.rate_hz` wants :meth:`advance` called at that rate (by the
batch runner's clock or a node's timer); ``None`` means its state changes only on commands.

:class:`QuasiStaticModel` is the quasi-static physics (softseq_ros.quasistatic): every command
is answered at once with the equilibrium the volume history leads to, so time changes nothing
and a command equal to the last one is not solved again. One equilibrium map serves every
model of the same segments in a process
(:func:`softseq_ros.quasistatic.solve.scene_map`): the rig's pump, actuator and any second
actuator of the same scene share it.
"""

from dataclasses import dataclass
import math
from pathlib import Path
from typing import Protocol, Sequence

import numpy as np

from softseq_ros.dynamic.events import FoldCrossing, fold_crossing_line
from softseq_ros.dynamic.flow import NetworkDomainError, NetworkFlow
from softseq_ros.dynamic.network import laminar_range_warning, tube_law
from softseq_ros.dynamic.regulated import RegulatedNetwork, RegulatedRun
from softseq_ros.errors import UserError
from softseq_ros.quasistatic.equilibrium import DomainError, EquilibriumMap, SnapEvent, Tracker
from softseq_ros.quasistatic.reach import beyond_domain, check_reach, check_scene_reach
from softseq_ros.quasistatic.regulator import HysteronTracker, PressureDomainError
from softseq_ros.quasistatic.solve import scene_map, segments_graph
from softseq_ros.scene.limits import RELIEF_MARGIN
from softseq_ros.scene.loader import Scene, load_scene
from softseq_ros.scene.network import LAMINAR, NetworkSettings, channel_names
from softseq_ros.scene.programme import PumpProfile
from softseq_ros.scene.regulator import Regulator
from softseq_ros.scene.validation import SceneError
from softseq_ros.segments.models import Segment
from softseq_ros.segments.supply import CompliantSupply
from softseq_ros.wire.contract import NS_PER_S


class CommandRefusedError(UserError):
    """A command or a saved state the model cannot take; the message says why, in one line."""


class ModelState(Protocol):
    """The actuator's state: gauge pressure [Pa], segment volumes [m^3], curvatures [1/m]."""

    pressure: float
    volumes: list[float]
    curvatures: list[float]


class Snap(Protocol):
    """A snap-through: where it happened [m^3 injected] and the states before and after."""

    injected: float
    from_volumes: Sequence[float]
    to_volumes: Sequence[float]
    from_pressure: float
    to_pressure: float


@dataclass(frozen=True)
class TimedSnap:
    """
    A snap-through that took time (the dynamic model): a :class:`Snap` and its timing.

    Every exchange of fluid between the segments is one, a snap-through or not
    (``snap_through``: the state passed where the equilibrium is unstable).
    ``start_ns``: when the exchange began, on the driver's clock; ``duration_s``: 10 % to 90 %
    of the fluid moved; ``fluid_moved_m3`` and ``peak_exchange_m3_per_s``: between the
    segments, beyond the pump's own flow; ``giving`` and ``taking``: the names of the segments
    that gave the fluid and took it; ``peak_ns``: when the exchange peaked; ``cut_short``: the
    run ended while it was still under way (softseq_ros.dynamic.events.DynamicSnap).
    """

    injected: float
    from_volumes: list[float]
    to_volumes: list[float]
    from_pressure: float
    to_pressure: float
    start_ns: int
    duration_s: float
    fluid_moved_m3: float
    peak_exchange_m3_per_s: float
    giving: tuple[str, ...] = ()
    taking: tuple[str, ...] = ()
    snap_through: bool = True
    peak_ns: int | None = None
    cut_short: bool = False


class ActuatorModel(Protocol):
    """What the actuator core needs from a physics model of its segments."""

    segments: tuple[Segment, ...]
    # The segments and any other member of its physics (a supply line): what it is, by digest
    # (a model without this attribute is its segments alone).
    members: tuple[Segment, ...]
    rest_volume_m3: float
    rate_hz: float | None
    # The channels between the segments, base to tip (empty: the model has none to report).
    channel_names: tuple[str, ...]

    def command(self, injected_m3: float, now_ns: int) -> list[Snap] | None:
        """
        Take the pump's injected volume at ``now_ns``; the snap-throughs it caused.

        ``None`` when the state did not change (a repeated command); CommandRefusedError when
        the model cannot take the volume (its state stays as it was).
        """

    def advance(self, now_ns: int) -> list[Snap] | None:
        """Move time to ``now_ns``; ``None`` when the state did not change."""

    def finish(self, now_ns: int) -> list[Snap]:
        """
        The run ends at ``now_ns``: the exchanges paused or still under way, reported now.

        One still under way is cut short there (``cut_short``). Optional: a model without it
        has nothing left at the end.
        """

    def state(self) -> ModelState:
        """The state now."""

    def saved(self) -> dict[str, object]:
        """The state as JSON-able values, for :meth:`resume`."""

    def resume(self, injected_m3: float, volumes_m3: Sequence[float]) -> None:
        """Restart at ``injected_m3`` on the branch nearest ``volumes_m3``."""

    @property
    def end_stop_m3(self) -> float:
        """The largest injected volume the model can take on inflation [m^3]."""

    def check_programme(self, scene: Scene, profile: PumpProfile) -> None:
        """Refuse (ProgrammeError, or SceneError for the scene's own) a programme it cannot run."""

    def channel_state(self) -> tuple[list[float], list[float]]:
        """Each channel's flow [m^3/s] and pressure drop [Pa] now (empty lists: none)."""

    def take_warnings(self) -> list[str]:
        """What the model found doubtful since the last call (one line each)."""

    def take_notes(self) -> list[str]:
        """What the model saw happen since the last call, worth a log line (one line each)."""


class InstantModel:
    """What a model answering every command at once has: no time, no channels, no notes."""

    rate_hz = None   # nothing happens between commands
    channel_names: tuple[str, ...] = ()

    def advance(self, now_ns: int) -> None:
        """Time alone moves nothing in a quasi-static actuator."""
        return None

    def finish(self, now_ns: int) -> list[Snap]:
        """A quasi-static snap-through is over the instant it starts: nothing is left."""
        return []

    def channel_state(self) -> tuple[list[float], list[float]]:
        """No channels: the fluid is everywhere at once."""
        return [], []

    def take_warnings(self) -> list[str]:
        """The equilibrium has nothing to doubt."""
        return []

    def take_notes(self) -> list[str]:
        """The snap-throughs are its events; nothing else to note."""
        return []


class QuasiStaticModel(InstantModel):
    """The equilibrium the volume history leads to, at once (snap-throughs, hysteresis)."""

    def __init__(self, emap: EquilibriumMap, names: Sequence[str]) -> None:
        """A model at rest on the map ``emap`` of segments ``names`` (base to tip)."""
        self.emap = emap
        self.names = tuple(names)
        self.segments = tuple(emap.segments)
        self.members = tuple(emap.members)
        self.rest_volume_m3 = emap.total_rest_volume
        self.tracker = Tracker(emap)
        self.solves = 0
        self._last_command: float | None = None
        self._injected = 0.0
        self._state = emap.read(self.tracker.branch, self.tracker.total)

    def command(self, injected_m3: float, now_ns: int) -> list[Snap] | None:
        """Move to the equilibrium at ``injected_m3``; a repeated command is not solved again."""
        if injected_m3 == self._last_command:
            return None
        tracker = self.tracker
        branch, total = tracker.branch, tracker.total
        try:
            snaps = tracker.move(injected_m3)
        except DomainError as err:
            # The tracker stops at the edge of its branch; keep the state as it was.
            tracker.branch, tracker.total = branch, total
            raise CommandRefusedError(beyond_domain(injected_m3, err, self.emap, self.names)) \
                from None
        self.solves += 1
        self._last_command = self._injected = injected_m3
        self._state = self.emap.read(tracker.branch, tracker.total)
        return snaps

    def preview(self, injected_m3: 'np.ndarray') -> 'CommandBlock':
        """
        What :meth:`command` would give for each of ``injected_m3``, without changing the model.

        The commands (finite, >= 0) one after another: the states up to the first command that
        snaps or is refused (``count`` of them), the same numbers as one command at a time.
        """
        emap, tracker = self.emap, self.tracker
        totals = injected_m3 + emap.total_rest_volume
        n = totals.size
        if not n:
            return CommandBlock(injected_m3, np.empty(0, dtype=np.intp), totals,
                                np.empty((0, 2 * len(self.names) + 1)),
                                np.empty(0, dtype=bool), len(self.names))
        branch_ids = np.empty(n, dtype=np.intp)
        at = totals.copy()
        # A tracker of its own walks the commands: the model's stays where it is.
        probe = Tracker(emap)
        probe.branch, probe.total = tracker.branch, tracker.total
        # A command equal to the one before it is not walked: the state stays.
        previous = np.empty(n)
        previous[0] = math.nan if self._last_command is None else self._last_command
        previous[1:] = injected_m3[:-1]
        repeated = injected_m3 == previous
        i, count = 0, n
        while i < n:
            branch = emap.branches[probe.branch]
            rest = totals[i:]
            outside = np.flatnonzero(((rest < branch.lo) | (rest > branch.hi))
                                     & ~repeated[i:])
            j = int(outside[0]) if outside.size else rest.size
            branch_ids[i:i + j] = probe.branch
            i += j
            if i == n:
                break
            try:
                snaps = probe.move(float(injected_m3[i]))
            except DomainError:
                count = i
                break
            if snaps:
                count = i
                break
            branch_ids[i], at[i] = probe.branch, probe.total
            i += 1
        branch_ids, at, repeated = branch_ids[:count], at[:count], repeated[:count]
        if count and repeated.any():
            # A repeated command keeps the state of the last one walked (or the model's).
            last = np.where(~repeated, np.arange(count), -1)
            np.maximum.accumulate(last, out=last)
            kept = last < 0
            last[kept] = 0
            at, branch_ids = at[last], branch_ids[last]
            at[kept], branch_ids[kept] = tracker.total, tracker.branch
        values = emap.reader.rows_per_command(branch_ids, at)
        return CommandBlock(injected_m3[:count], branch_ids, at, values, repeated,
                            len(self.names))

    def commit(self, block: 'CommandBlock', count: int) -> None:
        """The state after the first ``count`` commands of ``block`` (a :meth:`preview`)."""
        if not count:
            return
        tracker = self.tracker
        last = count - 1
        tracker.branch, tracker.total = int(block.branches[last]), float(block.totals[last])
        self.solves += int(count - np.count_nonzero(block.repeated[:count]))
        self._last_command = self._injected = float(block.injected[last])
        self._state = self.emap.read(tracker.branch, tracker.total)

    def state(self) -> ModelState:
        """The equilibrium state of the last command (at rest before the first)."""
        return self._state

    def saved(self) -> dict[str, object]:
        """Injected volume and segment volumes, enough to find the branch again."""
        return {'injected_m3': self._injected, 'volumes_m3': list(self._state.volumes)}

    def resume(self, injected_m3: float, volumes_m3: Sequence[float]) -> None:
        """Put the tracker at ``injected_m3`` on the branch nearest ``volumes_m3``."""
        try:
            tracker = Tracker(self.emap, injected=injected_m3, volumes=list(volumes_m3))
        except DomainError as err:
            raise CommandRefusedError(str(err)) from None
        self.tracker = tracker
        self._last_command = None
        self._injected = injected_m3
        self._state = self.emap.read(tracker.branch, tracker.total)

    @property
    def end_stop_m3(self) -> float:
        """Where the inflation ends: the first segment reaches the end of its curve."""
        return self.emap.injected_range[1]

    def check_programme(self, scene: Scene, profile: PumpProfile) -> None:
        """Walk the programme on the equilibrium set (softseq_ros.quasistatic.reach)."""
        if profile == scene.pump.profile:
            check_scene_reach(scene, self.emap)
        else:
            check_reach(profile, self.emap, self.names)



class CommandBlock:
    """
    States of a block of commands (:meth:`QuasiStaticModel.preview`): ``count`` rows.

    ``values`` (count, 2N + 1) are (v_1..v_N, p, k_1..k_N) as the per-command read gives them.
    """

    def __init__(self, injected: 'np.ndarray', branches: 'np.ndarray', totals: 'np.ndarray',
                 values: 'np.ndarray', repeated: 'np.ndarray', n: int) -> None:
        self.count = injected.size
        self.injected, self.branches, self.totals = injected, branches, totals
        self.repeated = repeated   # commands equal to the one before (not solved again)
        self.volumes = values[:, :n]
        self.pressure = values[:, n]
        self.curvatures = values[:, n + 1:]


@dataclass(frozen=True)
class FlowState:
    """The dynamic actuator's state: pressure at the syringe, volumes, curvatures."""

    pressure: float
    volumes: list[float]
    curvatures: list[float]


class DynamicModel:
    """
    The fluid network in time (softseq_ros.dynamic): the segments lag the pump's commands.

    A command says the injected volume at a time: the syringe pushed the flow that brings the
    injected volume there, evenly since the last command, and keeps pushing it (as a pump on
    a ramp does) for as long again; then it holds. A command older than the model's time (a
    late message) puts its difference into the base segment at once. The model advances at
    ``rate_hz`` on its driver's clock and says its state at that rate while a transient runs
    (fluid moving between the segments), else with the commands' answers; a snap-through
    (softseq_ros.dynamic.events.DynamicSnap) is reported when it has run its course. Its reach
    and end stop are the quasi-static ones (``reach``): a transient may still carry a segment
    past its curve, which is refused then.

    Behind a compliant supply line (``line``, a scene's ``supply``) the piston pushes into the
    line, whose pressure is the syringe's, and the supply tube passes the fluid on in time.
    """

    def __init__(self, segments: Sequence[Segment], names: Sequence[str],
                 network: NetworkSettings, reach: QuasiStaticModel,
                 line: CompliantSupply | None = None) -> None:
        """At rest; the clock starts at the first command or tick."""
        self.flow_network = NetworkFlow(segments, network, line=line)
        self.names = tuple(names)
        self.channel_names = channel_names(self.names)
        self._turbulent = [tube.friction != LAMINAR for tube in network.channels]
        self._warned = [False] * len(network.channels)
        self.segments = tuple(segments)
        # The line is part of the physics a bag names (its digest), as quasi-statically.
        self.members = self.segments + (() if line is None else (line,))
        self.rest_volume_m3 = self.flow_network.rest_total
        self.rate_hz = network.rate_hz
        self.reach = reach
        self._origin_ns: int | None = None
        self._last_command: tuple[float, float] | None = None   # (time [s], injected [m^3])
        self._flow_until = math.inf

    def _seconds(self, now_ns: int) -> float:
        if self._origin_ns is None:
            self._origin_ns = now_ns
        return (now_ns - self._origin_ns) / NS_PER_S

    def _run_to(self, t: float) -> None:
        """Integrate to ``t`` [s]; the pump's flow stops where its last command ran out."""
        network = self.flow_network
        try:
            if network.flow != 0.0 and self._flow_until < t:
                network.advance(self._flow_until)
                network.set_flow(0.0)
            network.advance(t)
        except NetworkDomainError as err:
            raise CommandRefusedError(str(err)) from None

    def command(self, injected_m3: float, now_ns: int) -> list[Snap]:
        """Push the flow that brings the injected volume to ``injected_m3`` at ``now_ns``."""
        t = self._seconds(now_ns)
        network = self.flow_network
        if t > network.t:
            # The catch-up: exactly the commanded volume at the command's instant.
            network.set_flow((injected_m3 - network.injected) / (t - network.t))
            self._flow_until = t
            self._run_to(t)
        elif injected_m3 != network.injected:
            network.inject_now(injected_m3 - network.injected)
        # From here the pump goes on at the rate of its last two commands, for as long as
        # the last interval lasted (a ramp's next command then finds the volume it names).
        previous, self._last_command = self._last_command, (t, injected_m3)
        if previous is not None and t > previous[0]:
            network.set_flow((injected_m3 - previous[1]) / (t - previous[0]))
            self._flow_until = t + (t - previous[0])
        else:
            network.set_flow(0.0)
            self._flow_until = t
        return self._take_snaps()

    def advance(self, now_ns: int) -> list[Snap] | None:
        """
        Let the fluid move until ``now_ns``; None when there is nothing new to say.

        That is, unless a transient runs (fluid moving between the segments) or a snap-through
        ended: while the segments only follow the pump, the commands' answers say it all.
        """
        t = self._seconds(now_ns)
        network = self.flow_network
        if t <= network.t:
            return None
        self._run_to(t)
        # A tick at the rig's rate, most often with nothing to say: the cheapest way out.
        if not network.new_snaps:
            return [] if network.exchanging else None
        return self._take_snaps()

    def finish(self, now_ns: int) -> list[Snap]:
        """The run ends at ``now_ns``: the exchange paused or under way, cut short if so."""
        t = self._seconds(now_ns)
        if t > self.flow_network.t:
            self._run_to(t)
        self.flow_network.finish_exchanges()
        return self._take_snaps()

    def _take_snaps(self) -> list[TimedSnap]:
        if not self.flow_network.new_snaps:
            return []
        origin = self._origin_ns or 0
        return [TimedSnap(snap.injected, snap.from_volumes, snap.to_volumes, snap.from_pressure,
                          snap.to_pressure, origin + round(snap.start_s * NS_PER_S),
                          snap.duration_s, snap.fluid_moved_m3, snap.peak_exchange_m3_per_s,
                          tuple(self.names[i] for i in snap.giving()),
                          tuple(self.names[i] for i in snap.taking()), snap.snap_through,
                          origin + round(snap.peak_s * NS_PER_S), snap.cut_short)
                for snap in self.flow_network.take_snaps()]

    def channel_state(self) -> tuple[list[float], list[float]]:
        """Each channel's flow [m^3/s] towards the tip and pressure drop [Pa] now."""
        _, pressures, flows = self.flow_network.now()
        return list(flows), [pressures[j] - pressures[j + 1] for j in range(len(flows))]

    def take_warnings(self) -> list[str]:
        """Once per channel: its flow left the laminar range (Reynolds number above 2300)."""
        return _laminar_warnings(self.channel_names, self.flow_network.peak_reynolds,
                                 self._turbulent, self._warned)

    def take_notes(self) -> list[str]:
        """Each segment's passage through a fold of its own curve, located in time."""
        return _fold_notes(self.flow_network.take_fold_crossings(), self._origin_ns)

    def state(self) -> ModelState:
        """Pressure at the syringe (gauge), segment volumes and curvatures now."""
        network = self.flow_network
        volumes, _, _ = network.now()
        return FlowState(network.syringe_pressure(), list(volumes),
                         [float(s.curvature(v)) for s, v in zip(self.segments, volumes)])

    def saved(self) -> dict[str, object]:
        """Injected volume and segment volumes (the channel flows are not kept)."""
        network = self.flow_network
        return {'injected_m3': network.injected,
                'volumes_m3': [float(v) for v in network.volumes()]}

    def resume(self, injected_m3: float, volumes_m3: Sequence[float]) -> None:
        """Restart at rest at these volumes."""
        self.flow_network.set_volumes(volumes_m3, injected_m3)
        self._last_command = None

    @property
    def end_stop_m3(self) -> float:
        """Where the quasi-static inflation ends."""
        return self.reach.end_stop_m3

    def check_programme(self, scene: Scene, profile: PumpProfile) -> None:
        """The quasi-static reach of the programme."""
        self.reach.check_programme(scene, profile)


@dataclass(frozen=True)
class HysteronState:
    """The segments under a held pressure: the pressure [Pa, gauge], volumes, curvatures."""

    pressure: float
    volumes: list[float]
    curvatures: list[float]


@dataclass(frozen=True)
class RegulatedBlock:
    """States of a block of target pressures (:meth:`RegulatedModel.preview`): ``count`` rows."""

    count: int
    pressure: 'np.ndarray'      # the targets [Pa, gauge]
    volumes: 'np.ndarray'       # (count, N) [m^3]
    curvatures: 'np.ndarray'    # (count, N) [1/m]


class RegulatedModel(InstantModel):
    """
    The segments behind a pressure regulator, quasi-statically: each an independent hysteron.

    Its commands are target gauge pressures (:meth:`command_pressure`): each segment sits at
    that pressure on a rising piece of its own curve and flips at its peak and back at its
    valley (softseq_ros.quasistatic.regulator). A flip goes out as a snap-through at its
    pressure, the fluid it takes coming from the regulator.
    """

    end_stop_m3 = math.inf   # a regulator has no syringe to run out of

    def __init__(self, segments: Sequence[Segment], names: Sequence[str]) -> None:
        self.segments = self.members = tuple(segments)
        self.names = tuple(names)
        self.rest_volume_m3 = float(sum(s.rest_volume for s in self.segments))
        self.tracker = HysteronTracker(self.segments)
        self._last_command: float | None = None
        self._state = self._state_at(0.0, self.tracker.move(0.0)[0])

    def _state_at(self, pressure: float, volumes: Sequence[float]) -> HysteronState:
        return HysteronState(pressure, [float(v) for v in volumes],
                             [float(s.curvature(v)) for s, v in zip(self.segments, volumes)])

    @property
    def injected_m3(self) -> float:
        """What the regulator has let in since rest [m^3]."""
        return sum(self._state.volumes) - self.rest_volume_m3

    def command(self, injected_m3: float, now_ns: int) -> list[Snap] | None:
        """A volume cannot drive segments behind a regulator: refused."""
        raise CommandRefusedError(
            f'injected volume {injected_m3:.6g} m^3 refused: the supply is a pressure '
            'regulator, which is driven by a target gauge pressure (joint regulator, effort)')

    def command_pressure(self, gauge_pa: float, now_ns: int) -> list[Snap] | None:
        """
        Hold every segment at ``gauge_pa`` [Pa]; the flips on the way, as snap-throughs.

        ``None`` for a repeated command; CommandRefusedError when some segment holds the
        pressure on no rising piece (its state stays as it was).
        """
        if gauge_pa == self._last_command:
            return None
        tracker = self.tracker
        places = list(tracker.current)
        rising = gauge_pa > self._state.pressure
        try:
            volumes, flips = tracker.move(gauge_pa)
        except PressureDomainError as err:
            raise CommandRefusedError(str(err).removeprefix('row 0: ')) from None
        snaps = []
        # In the order the pressure passes them: each flip sees the flips before it landed.
        for flip in sorted(flips, key=lambda f: f.pressure, reverse=not rising):
            at = [flip.from_volume if i == flip.segment else
                  float(s.invert(tracker.pieces[i][places[i]], np.array([flip.pressure]))[0])
                  for i, s in enumerate(self.segments)]
            landed = list(at)
            landed[flip.segment] = flip.to_volume
            places[flip.segment] = tracker.current[flip.segment]
            snaps.append(SnapEvent(sum(at) - self.rest_volume_m3, np.array(at),
                                   np.array(landed), flip.pressure, flip.pressure))
        self._last_command = gauge_pa
        self._state = self._state_at(gauge_pa, volumes)
        return snaps

    def preview(self, targets: 'np.ndarray') -> 'RegulatedBlock':
        """
        What :meth:`command_pressure` would give for each of ``targets``, without changing.

        The states up to the first target that some segment's present piece does not hold
        (a flip, or a refusal): the same numbers as one command at a time (the inversion is
        elementwise).
        """
        count = targets.size
        pieces = [rising[at] for rising, at in zip(self.tracker.pieces, self.tracker.current)]
        for piece in pieces:
            outside = np.flatnonzero(~((targets >= piece.p_min) & (targets <= piece.p_max)))
            if outside.size:
                count = min(count, int(outside[0]))
        held = targets[:count]
        volumes = np.empty((count, len(self.segments)))
        curvatures = np.empty_like(volumes)
        for i, (segment, piece) in enumerate(zip(self.segments, pieces)):
            volumes[:, i] = segment.invert(piece, held)
            curvatures[:, i] = segment.curvature(volumes[:, i])
        return RegulatedBlock(count, held, volumes, curvatures)

    def commit(self, block: 'RegulatedBlock', count: int) -> None:
        """The state after the first ``count`` commands of ``block`` (a :meth:`preview`)."""
        if not count:
            return
        last = count - 1
        self._last_command = float(block.pressure[last])
        self._state = HysteronState(self._last_command, block.volumes[last].tolist(),
                                    block.curvatures[last].tolist())

    def state(self) -> ModelState:
        """Every segment at the last target pressure (at rest before the first)."""
        return self._state

    def saved(self) -> dict[str, object]:
        """What was let in and the segment volumes, enough to find each one's piece again."""
        return {'injected_m3': self.injected_m3, 'volumes_m3': list(self._state.volumes)}

    def resume(self, injected_m3: float, volumes_m3: Sequence[float]) -> None:
        """Each segment on the rising piece nearest its saved volume, at that pressure."""
        pressures = [float(s.pressure(v)) for s, v in zip(self.segments, volumes_m3)]
        self.tracker.place(volumes_m3)
        try:
            volumes, _ = self.tracker.move(float(np.mean(pressures)))
        except PressureDomainError as err:
            raise CommandRefusedError(str(err).removeprefix('row 0: ')) from None
        self._last_command = None
        self._state = self._state_at(float(np.mean(pressures)), volumes)

    def check_programme(self, scene: Scene, profile: object) -> None:
        """The scene's programme was checked when it loaded (every target within reach)."""


class RegulatedFlowModel:
    """
    The segments and channels behind a pressure regulator in time (softseq_ros.dynamic.regulated).

    Its commands are target gauge pressures (:meth:`command_pressure`). Between two commands
    the target follows the line through them (the catch-up: exactly the commanded target at
    the command's instant); after the last it goes on at the rate of the last two for as long
    as the last interval lasted, then holds, as the syringe's model does with volumes. The
    regulator's outlet follows the target (with its time constant), the supply tube and the
    channels carry the water; each segment's passage through a fold of its curve is a note,
    and each flip (from a peak passed filling, or a valley passed emptying, to where the
    segment lands on its next rising piece at that pressure) a snap-through in time, its fluid
    given or taken by the regulator (softseq_ros.dynamic.regulated.RegulatedFlip). The pressure
    it says is the outlet's, gauge. It advances at ``rate_hz`` on its driver's clock.
    """

    end_stop_m3 = math.inf   # a regulator has no syringe to run out of

    def __init__(self, segments: Sequence[Segment], names: Sequence[str],
                 network: NetworkSettings, regulator: Regulator) -> None:
        """At rest; the clock starts at the first command or tick."""
        self.run = RegulatedRun(RegulatedNetwork(segments, network, regulator))
        self.names = tuple(names)
        self.channel_names = channel_names(self.names)
        self._turbulent = [tube.friction != LAMINAR for tube in network.channels]
        self._warned = [False] * len(network.channels)
        self._laws = [tube_law(tube, network.fluid) for tube in network.channels]
        self.segments = self.members = tuple(segments)
        self.rest_volume_m3 = self.run.network.rest_total
        self.rate_hz = network.rate_hz
        self._origin_ns: int | None = None
        self._last_command: tuple[float, float] | None = None   # (time [s], target [Pa])
        # A flow below this moves, in a second, no more than the integrator can tell [m^3/s].
        self._quiet_flow = float(self.run.network.atol[0])

    def _seconds(self, now_ns: int) -> float:
        if self._origin_ns is None:
            self._origin_ns = now_ns
        return (now_ns - self._origin_ns) / NS_PER_S

    def _run_to(self, t: float) -> None:
        try:
            self.run.advance(t)
        except NetworkDomainError as err:
            raise CommandRefusedError(str(err)) from None

    def command(self, injected_m3: float, now_ns: int) -> list[Snap] | None:
        """A volume cannot drive segments behind a regulator: refused."""
        raise CommandRefusedError(
            f'injected volume {injected_m3:.6g} m^3 refused: the supply is a pressure '
            'regulator, which is driven by a target gauge pressure (joint regulator, effort)')

    def command_pressure(self, gauge_pa: float, now_ns: int) -> list[Snap]:
        """Follow the target to ``gauge_pa`` [Pa] at ``now_ns``; then on at the last rate."""
        t = self._seconds(now_ns)
        run = self.run
        if t > run.t:
            run.follow(run.target(run.t), (gauge_pa - run.target(run.t)) / (t - run.t), t)
            self._run_to(t)
        previous, self._last_command = self._last_command, (t, gauge_pa)
        if previous is not None and t > previous[0]:
            run.follow(gauge_pa, (gauge_pa - previous[1]) / (t - previous[0]),
                       t + (t - previous[0]))
        else:
            run.follow(gauge_pa, 0.0, math.inf)
        return self._flips(run.take_flips())

    def advance(self, now_ns: int) -> list[Snap] | None:
        """Let the water move until ``now_ns``; None while nothing moves."""
        t = self._seconds(now_ns)
        if t <= self.run.t:
            return None
        self._run_to(t)
        flips = self._flips(self.run.take_flips())
        _, _, flows, outlet, supply = self.run.state()
        moving = max([abs(supply)] + [abs(q) for q in flows.tolist()]) > self._quiet_flow
        return flips if flips or moving or outlet != self.run.target(self.run.t) else None

    def finish(self, now_ns: int) -> list[Snap]:
        """The run ends at ``now_ns``: the flips landed, and those under way cut short."""
        t = self._seconds(now_ns)
        if t > self.run.t:
            self._run_to(t)
        return self._flips(self.run.finish())

    def _flips(self, flips: list) -> list[TimedSnap]:
        """Each flip as a snap-through in time: the regulator gave the fluid, or took it."""
        origin = self._origin_ns or 0
        snaps = []
        for flip in flips:
            name = (self.names[flip.segment],)
            snaps.append(TimedSnap(
                flip.injected, flip.from_volumes, flip.to_volumes, flip.from_pressure,
                flip.to_pressure, origin + round(flip.start_s * NS_PER_S), flip.duration_s,
                flip.moved_m3, flip.peak_rate_m3_per_s, () if flip.filling else name,
                name if flip.filling else (), True,
                origin + round(flip.peak_s * NS_PER_S) if math.isfinite(flip.peak_s) else None,
                flip.cut_short))
        return snaps

    def state(self) -> ModelState:
        """The regulator's outlet pressure (gauge), segment volumes and curvatures now."""
        volumes, _, _, outlet, _ = self.run.state()
        return FlowState(float(outlet), volumes.tolist(),
                         [float(s.curvature(v)) for s, v in zip(self.segments, volumes)])

    def saved(self) -> dict[str, object]:
        """What was let in and the segment volumes (the channel flows are not kept)."""
        volumes, *_ = self.run.state()
        return {'injected_m3': float(self.run.y[self.run.network.at_injected]),
                'volumes_m3': volumes.tolist()}

    def resume(self, injected_m3: float, volumes_m3: Sequence[float]) -> None:
        """Restart at rest at these volumes, the target at the fed segment's pressure."""
        self.run.set_rest(volumes_m3, injected_m3)
        self._last_command = None

    def check_programme(self, scene: Scene, profile: object) -> None:
        """The scene's programme was checked when it loaded (every target within reach)."""

    def channel_state(self) -> tuple[list[float], list[float]]:
        """Each channel's flow [m^3/s] towards the tip and pressure drop [Pa] now."""
        _, pressures, flows, _, _ = self.run.state()
        return flows.tolist(), [float(pressures[j] - pressures[j + 1])
                                for j in range(flows.size)]

    def take_warnings(self) -> list[str]:
        """Once per channel: its flow left the laminar range (Reynolds number above 2300)."""
        peaks = [law.reynolds(flow) for law, flow in zip(self._laws, self.run.peak_flows)]
        return _laminar_warnings(self.channel_names, peaks, self._turbulent, self._warned)

    def take_notes(self) -> list[str]:
        """Each segment's passage through a fold of its own curve, located in time."""
        return _fold_notes(self.run.take_fold_crossings(), self._origin_ns)


def _laminar_warnings(channels: Sequence[str], peak_reynolds: Sequence[float],
                      turbulent: Sequence[bool], warned: list[bool]) -> list[str]:
    """Once per channel (``warned`` keeps which): its flow left the laminar range."""
    lines = []
    for j, peak in enumerate(peak_reynolds):
        if warned[j]:
            continue
        line = laminar_range_warning(channels[j], peak, turbulent[j])
        if line is not None:
            warned[j] = True
            lines.append(line)
    return lines


def _fold_notes(crossings: Sequence[FoldCrossing], origin_ns: int | None) -> list[str]:
    """A line per fold crossing, its time on the driver's clock (from ``origin_ns``)."""
    origin = (origin_ns or 0) / NS_PER_S
    return [fold_crossing_line(crossing, origin) for crossing in crossings]


def default_max_pressure_pa(scene: Scene) -> float:
    """
    The pump's relief by default [Pa, gauge], from the scene's own curves.

    :data:`RELIEF_MARGIN` times the highest pressure on any segment's curve, with a network
    plus its supply tube's steady drop at the programme's fastest flow. The paper's segments
    reach 15.6 kPa, so 23 kPa, where a fixed 100 kPa let a blocked line go six times past them.
    """
    highest = max(max(piece.p_max for piece in segment.monotone_pieces())
                  for segment in scene.segments)
    drop = 0.0
    network = scene.network
    if network is not None and network.supply is not None:
        drop = tube_law(network.supply, network.fluid).drop(scene.pump.profile.max_flow_rate())
    return RELIEF_MARGIN * (max(highest, 0.0) + drop)


def load_rig_scene(path: str | Path) -> Scene:
    """
    A scene file (or shipped scene name) for the rig's cores.

    The rig's drivers know no physics, this seam does: a ``pump.start_branch`` is looked up in
    the transition graph of the process's shared map, the one the actuator's model runs on.
    """
    return load_scene(path, segments_graph)


def actuator_model(scene: Scene) -> 'QuasiStaticModel | DynamicModel | RegulatedModel':
    """
    The model a scene asks for, on the process's shared map of its segments.

    The fluid network in time when the scene declares one (``network``), else the quasi-static
    equilibrium (behind the scene's ``supply`` line, if any), at rest or where the
    programme's ``start_history`` led. Behind a pressure regulator, the segments as
    independent hysterons (:class:`RegulatedModel`).
    """
    if scene.regulator is not None:
        if scene.network is not None:
            return RegulatedFlowModel(scene.segments, scene.segment_names, scene.network,
                                      scene.regulator)
        return RegulatedModel(scene.segments, scene.segment_names)
    quasistatic = QuasiStaticModel(scene_map(scene),
                                   scene.segment_names)
    # A programme that starts from a stated history: the actuator is where it led.
    for index, volume in enumerate(scene.pump.profile.start_history):
        try:
            quasistatic.command(volume, 0)
        except CommandRefusedError as err:
            raise SceneError(f'{scene.path if scene.path is not None else "<scene>"}: '
                             f'pump.start_history_m3[{index}]: {err}') from None
    if scene.network is None:
        return quasistatic
    dynamic = DynamicModel(scene.segments, scene.segment_names, scene.network, quasistatic,
                           scene.supply)
    if scene.pump.profile.start_history:
        # At rest where the history led: a balanced state, no fluid moving between segments.
        dynamic.resume(scene.pump.profile.start_injected, quasistatic.state().volumes)
    return dynamic
