"""
A rig recording as arrays: what the pump commanded, what the actuator did, what the camera saw.

Reads a bag written by the recorder or by ``softseq run``. Topics are found through the rig's
contract (:mod:`softseq_ros.wire.contract`): names are relative to the rig's namespace, which is
found from the bag's topics. Only the topics the analysis needs are read, straight into arrays
(:mod:`softseq_ros.bag.arrays`); everything is SI, pressures are gauge unless named absolute.

What belongs to this run: the run starts at the first pump command. A latched message stamped
before it (an actuator state or a snapshot kept by a transient-local publisher from an earlier
run) is left out and counted in ``ignored``; snap-through events carry no stamp and are all
kept. The scene the actuator said it runs (``actuator/scene``, published once when it starts,
so usually before the first command) is kept whenever it was said: it describes the actuator,
not one run. The JSON the String topics carry is read with the codecs that write it
(:mod:`softseq_ros.wire.payloads`).

What cannot be used is skipped and said (``skipped``, by topic and reason; the report and the
comparison list it): pump commands or volumes without positions (or volumes without
pressures), rows whose positions or pressures are NaN or infinite, and String payloads larger
than :data:`MAX_PAYLOAD_BYTES`. A bag with no usable pump command or volumes left is refused.

Several runs in one bag: a recorder left running while the pump is reset (``~/reset``: the
commanded volume goes back to the programme's start in one step) or restarted, or while the
actuator is restarted, holds several runs. Each new run is found (:func:`find_run_starts`) by
the pump's status going idle again after it had left idle, by the commanded volume jumping
(further in one command than the pump's flow moves it, by far), or by the actuator naming its
scene again after its first state; :meth:`Recording.runs` gives each run as a recording of its
own, and the report measures each.

A bag of a scene with a fluid network (docs/dynamic.md) also holds the channel flows
(:class:`ChannelFlows`) and snap-through events in time, whose JSON carries ``start_ns``,
``duration_s``, ``fluid_moved_m3`` and ``peak_exchange_m3_per_s``; a quasi-static bag has
neither, and reads as it always did.
"""

from dataclasses import dataclass, field
from functools import partial
import os
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from softseq_ros.bag.arrays import (
    BagArrayError,
    FluidPressureDecoder,
    JointStateDecoder,
    PoseArrayDecoder,
    StringDecoder,
    open_bag,
)
from softseq_ros.errors import UserError
from softseq_ros.wire import contract
from softseq_ros.wire.contract import NS_PER_S
from softseq_ros.wire.payloads import (
    PUMP_STATUS_JSON,
    REGULATOR_JOINT,
    SCENE_IDENTITY_JSON,
    SNAP_THROUGH_JSON,
    SNAPSHOT_STEP_JSON,
    JsonPayload,
    PayloadError,
)
from softseq_ros.wire.values import SceneIdentity

FloatArray = NDArray[np.float64]
# Pressure messages read to find the ambient pressure (absolute minus gauge): it is constant.
AMBIENT_SAMPLES = 2000
INFLATION, DEFLATION = 'inflation', 'deflation'
# A commanded volume that moves further in one command than this many times the pump's flow
# on the commands either side of it, over that time (or at all, by more than JUMP_SHARE of the
# range, while the pump says it does not move), jumps: the pump was reset or restarted.
JUMP_FACTOR = 4.0
JUMP_SHARE = 1e-3
# The pump's last states that end a programme before its end.
CUT_SHORT = ('stopped', 'held')
# Signs of one new run closer together than this are one (a reset's idle status and the jump of
# the command after it).
RUN_MERGE_S = 0.5
# The largest String payload (events, status, steps, scene) read: the rig's JSON is a few
# hundred bytes; a payload of megabytes is no rig message and is skipped, not parsed.
MAX_PAYLOAD_BYTES = 64 * 1024


class RecordingError(UserError):
    """A bag that lacks what an analysis needs; the message names the bag and the topic."""


@dataclass
class Snapshot:
    """The camera's backbone at one trigger volume: points (M, 2) as (x, z) in m."""

    time_s: float
    injected: float              # pump's commanded injected volume at the snapshot [m^3]
    points: FloatArray
    step: int | None = None      # 1-based index into the camera's trigger list
    trigger_injected: float | None = None
    direction: str = INFLATION
    cycle: int = 1               # 1-based: which inflation leg (with its deflation) it is in

    @property
    def tip(self) -> FloatArray:
        """Tip position (x, z) [m]."""
        return self.points[-1]


@dataclass
class ChannelFlows:
    """
    The flows through a fluid network's channels (``actuator/channel_flows``), base to tip.

    ``flow`` [m^3/s] is positive towards the tip, ``drop`` [Pa] is the pressure drop along the
    channel; both (n, channels), one row per time in ``time_s``.
    """

    names: tuple[str, ...]       # '<segment>_to_<segment>'
    time_s: FloatArray
    flow: FloatArray
    drop: FloatArray


@dataclass
class Recording:
    """Time series of one rig run (times in s from the first pump command)."""

    path: Path
    segment_names: tuple[str, ...]
    pump_time_s: FloatArray
    pump_injected: FloatArray
    state_time_s: FloatArray
    state_injected: FloatArray
    pressure: FloatArray                # gauge, Pa
    volumes: FloatArray                 # (n, N), m^3
    curvature_time_s: FloatArray
    curvatures: FloatArray              # (m, N), 1/m
    events: list[dict] = field(default_factory=list)
    snapshots: list[Snapshot] = field(default_factory=list)
    backbone_count: int = 0
    namespace: str = '/'
    state_flow_sign: NDArray[np.int8] = field(default_factory=lambda: np.zeros(0, np.int8))
    curvature_injected: FloatArray = field(default_factory=lambda: np.zeros(0))
    ambient_pressure_pa: float | None = None
    status: list[tuple[float, str, str]] = field(default_factory=list)
    counts: dict[str, int] = field(default_factory=dict)
    ignored: dict[str, int] = field(default_factory=dict)
    start_ns: int = 0
    # Rows a snap-through lands on, when already known (a thinned copy keeps the original's).
    snap_rows: NDArray[np.intp] | None = None
    # Behind a pressure regulator: its target gauge pressure per pump command [Pa] (None: a
    # syringe's bag). The injected volume is then what the segments took since the first
    # recorded state, from their volumes.
    target_pressure: FloatArray | None = None
    # The distinct scenes the actuator said it runs, in the order said (none in older bags;
    # more than one when an actuator was restarted on other segments during the recording).
    scenes: list[SceneIdentity] = field(default_factory=list)
    # A scene with a fluid network only: the flows through its channels.
    channel_flows: ChannelFlows | None = None
    # Messages left out as unusable: topic -> reason -> count.
    skipped: dict[str, dict[str, int]] = field(default_factory=dict)
    # Where each run after the first begins (s from the first pump command) and why.
    run_starts: list['RunStart'] = field(default_factory=list)
    # Each snap-through event's receive time (s from the first pump command).
    event_times_s: FloatArray = field(default_factory=lambda: np.zeros(0))
    # This recording's run: its number (1-based) and where it begins and ends [s].
    run: int = 1
    run_span_s: tuple[float, float] | None = None

    def skipped_lines(self) -> list[str]:
        """One line per topic and reason of what was skipped, for a report's warnings."""
        return [f'{topic}: {count} message{"s" if count != 1 else ""} skipped ({why})'
                for topic, reasons in sorted(self.skipped.items())
                for why, count in sorted(reasons.items())]

    @property
    def scene(self) -> SceneIdentity | None:
        """The scene the recording was made with (the first said), None when not recorded."""
        return self.scenes[0] if self.scenes else None

    @property
    def state_run_starts(self) -> NDArray[np.intp]:
        """The state rows at which the runs after the first begin."""
        return np.searchsorted(self.state_time_s, [r.time_s for r in self.run_starts])

    def runs(self) -> list['Recording']:
        """
        The recording split into its runs (itself when it holds one), each a Recording.

        A run's times stay those of the whole bag (from its first pump command); its snapshots
        and events are those of its time span.
        """
        if not self.run_starts:
            return [self]
        edges = [-np.inf] + [r.time_s for r in self.run_starts] + [np.inf]
        return [self._between(number, lo, hi)
                for number, (lo, hi) in enumerate(zip(edges[:-1], edges[1:]), start=1)]

    def _between(self, number: int, lo: float, hi: float) -> 'Recording':
        from dataclasses import replace

        def rows(times: FloatArray) -> slice:
            return slice(int(np.searchsorted(times, lo)), int(np.searchsorted(times, hi)))

        pump, state = rows(self.pump_time_s), rows(self.state_time_s)
        curves = state if self.curvature_time_s is self.state_time_s else \
            rows(self.curvature_time_s)
        events = (self.event_times_s >= lo) & (self.event_times_s < hi)
        shown = (max(lo, float(self.pump_time_s[0])),
                 min(hi, float(self.pump_time_s[-1])))
        return replace(
            self, pump_time_s=self.pump_time_s[pump], pump_injected=self.pump_injected[pump],
            target_pressure=(None if self.target_pressure is None
                             else self.target_pressure[pump]),
            state_time_s=self.state_time_s[state], state_injected=self.state_injected[state],
            pressure=self.pressure[state], volumes=self.volumes[state],
            state_flow_sign=self.state_flow_sign[state],
            curvature_time_s=self.curvature_time_s[curves],
            curvatures=self.curvatures[curves] if self.curvatures.shape[0] else self.curvatures,
            curvature_injected=(self.curvature_injected[curves]
                                if self.curvature_injected.size else self.curvature_injected),
            events=[e for e, keep in zip(self.events, events) if keep],
            event_times_s=self.event_times_s[events],
            # A snapshot at a run's first command saw the jump that ended the run before.
            snapshots=[s for s in self.snapshots if lo < s.time_s <= hi],
            status=[s for s in self.status if lo <= s[0] < hi],
            snap_rows=None, run_starts=[], run=number, run_span_s=shown, channel_flows=None)

    def cut_short(self) -> tuple[float, str, str] | None:
        """
        The pump's last status when it ended the programme early: (time [s], state, reason).

        None when the pump finished, or the bag says nothing of it. A stopped or held pump's
        run ends there: every number of it is that of the part it ran.
        """
        if self.status and self.status[-1][1] in CUT_SHORT:
            return self.status[-1]
        return None

    @property
    def inflating(self) -> NDArray[np.bool_]:
        """Per state: on an inflation leg (a hold counts with the leg before it)."""
        return self.state_flow_sign > 0

    @property
    def deflating(self) -> NDArray[np.bool_]:
        """Per state: on a deflation leg."""
        return self.state_flow_sign < 0


@dataclass(frozen=True)
class RunStart:
    """Where a new run begins in a bag (s from its first pump command) and what shows it."""

    time_s: float
    cause: str


def find_run_starts(pump_time_s: FloatArray, pump_u: FloatArray,
                    flow_sign: NDArray[np.int8], status: list[tuple[float, str, str]],
                    scene_stamps_s: list[float], first_state_s: float) -> list[RunStart]:
    """
    Where the runs after the first begin: at the first command of each, with the causes.

    A run begins where the pump's status goes idle after it had left idle (a reset, or a
    restarted pump node), where the commanded volume jumps (moves further in one command than
    JUMP_FACTOR times the flow of the commands either side over that time, or by more than
    JUMP_SHARE of the range while the pump says it stands still), and where the actuator names
    its scene again after its first state (a restarted actuator). Signs within RUN_MERGE_S are
    one start.
    """
    found: list[tuple[float, str]] = []
    was_active, previous = False, 'idle'
    for time_s, state, _ in status:
        if state == 'idle' and was_active:
            found.append((time_s, f'the pump went idle again after {previous} (reset or '
                                  'restarted)'))
        was_active = was_active or state != 'idle'
        previous = state
    if pump_u.size > 1:
        for row in volume_jumps(pump_time_s, pump_u, flow_sign).tolist():
            found.append((float(pump_time_s[row + 1]),
                          f'the commanded volume jumped from {pump_u[row] * 1e6:.4f} mL to '
                          f'{pump_u[row + 1] * 1e6:.4f} mL in one command'))
    for stamp_s in scene_stamps_s[1:]:
        if stamp_s > first_state_s:
            found.append((stamp_s, 'the actuator started again (it named its scene anew)'))
    starts: list[RunStart] = []
    for time_s, cause in sorted(found):
        if time_s <= float(pump_time_s[0]):
            continue
        if starts and time_s - starts[-1].time_s <= RUN_MERGE_S:
            if cause not in starts[-1].cause:
                starts[-1] = RunStart(starts[-1].time_s, f'{starts[-1].cause}; {cause}')
            continue
        # The run begins at the first command at or after the sign.
        row = min(int(np.searchsorted(pump_time_s, time_s)), pump_time_s.size - 1)
        starts.append(RunStart(float(pump_time_s[row]), cause))
    return starts


def volume_jumps(pump_time_s: FloatArray, pump_u: FloatArray,
                  flow_sign: NDArray[np.int8]) -> NDArray[np.intp]:
    """
    The steps ``k`` (command ``k`` to ``k + 1``) whose commanded volume jumps.

    A jump moves further than JUMP_FACTOR times the flow of the steps either side over its time
    (a step where the pump stands still, or of no time, has no flow), and at all by more than
    JUMP_SHARE of the range. Only the steps beyond that share are looked at further: a long
    bag's columns have millions of rows, and the rule's terms as whole columns cost the report
    of an 18-cycle bag 115 MB of temporaries.
    """
    du = np.diff(pump_u)
    np.abs(du, out=du)
    span = float(np.ptp(pump_u)) or 1.0
    rows = np.flatnonzero(du > JUMP_SHARE * span)
    if not rows.size:
        return rows

    def flow(steps: NDArray[np.intp]) -> FloatArray:
        inside = (steps >= 0) & (steps < du.size)
        steps = np.clip(steps, 0, du.size - 1)
        dt = pump_time_s[steps + 1] - pump_time_s[steps]
        moving = inside & (dt > 0) & (flow_sign[steps + 1] != 0)
        return np.where(moving, du[steps] / np.where(dt > 0, dt, 1.0), 0.0)

    # The flow on the steps either side: a jump is far beyond both.
    local = np.maximum(flow(rows - 1), flow(rows + 1))
    dt = pump_time_s[rows + 1] - pump_time_s[rows]
    allowed = np.where(flow_sign[rows + 1] != 0, JUMP_FACTOR * local * dt, 0.0)
    return rows[du[rows] > np.maximum(allowed, JUMP_SHARE * span)]


def _topic(namespace: str, spec: contract.Topic) -> str:
    return contract.resolve(spec.name, namespace)


def find_namespace(topics: list[str], path: Path, namespace: str | None) -> str:
    """The rig namespace of a bag: the one given, or the only one its topics hold."""
    found = contract.find_namespaces(topics)
    if namespace is not None:
        wanted = '/' + namespace.strip('/') if namespace.strip('/') else '/'
        if wanted not in found:
            raise RecordingError(
                f'{path}: no rig in namespace {wanted} (found: {", ".join(found) or "none"})')
        return wanted
    if not found:
        raise RecordingError(f'{path}: no {contract.PUMP_COMMAND.name} topic in any namespace: '
                             f'not a rig recording (topics: {", ".join(topics) or "none"})')
    if len(found) > 1:
        raise RecordingError(f'{path}: holds rigs in namespaces {", ".join(found)}; choose one '
                             'with --namespace')
    return found[0]


def load_recording(directory: str | os.PathLike, namespace: str | None = None) -> Recording:
    """Read a rig bag into arrays; raises RecordingError when the pump or actuator is missing."""
    path = Path(directory)
    try:
        bag = open_bag(path)
    except BagArrayError as err:
        raise RecordingError(str(err)) from None
    ns = find_namespace(bag.topics, path, namespace)
    names = {spec: _topic(ns, spec) for spec in contract.RIG_TOPICS}
    for spec, topic in names.items():
        info = bag.channels.get(topic)
        if info is not None and info.type_name != spec.type_name:
            raise RecordingError(f'{path}: topic {topic} has type '
                                 f'{info.type_name or "none (no schema)"}, expected '
                                 f'{spec.type_name}')
    if names[contract.VOLUMES] not in bag.channels:
        raise RecordingError(f'{path}: no {names[contract.VOLUMES]} topic: the actuator did not '
                             'run or its volumes were not recorded')

    # Only what the analysis uses is kept: on a 10^7-message bag every column costs 18 MB.
    pump = JointStateDecoder(names[contract.PUMP_COMMAND], ('position', 'velocity'),
                             log_times=False, signs=('velocity',), required=('position',))
    state = JointStateDecoder(names[contract.VOLUMES], ('position', 'effort'), log_times=False,
                              mean=('effort',), required=('position', 'effort'))
    strings = partial(StringDecoder, max_bytes=MAX_PAYLOAD_BYTES)
    decoders: list = [pump, state]
    optional = {}
    for spec, decoder in ((contract.CURVATURES,
                           lambda t: JointStateDecoder(t, ('position',), log_times=False,
                                                       required=('position',))),
                          (contract.PRESSURE, lambda t: FluidPressureDecoder(t, AMBIENT_SAMPLES)),
                          (contract.EVENTS, strings), (contract.PUMP_STATUS, strings),
                          (contract.SNAPSHOTS, PoseArrayDecoder),
                          (contract.SNAPSHOT_STEPS, strings),
                          (contract.SCENE, strings),
                          (contract.CHANNEL_FLOWS,
                           lambda t: JointStateDecoder(t, ('velocity', 'effort'),
                                                       log_times=False))):
        if names[spec] in bag.channels:
            optional[spec] = decoder(names[spec])
            decoders.append(optional[spec])
    try:
        bag.read(decoders)
    except BagArrayError as err:
        raise RecordingError(str(err)) from None

    skipped: dict[str, dict[str, int]] = {}
    for decoder in decoders:
        for why, count in getattr(decoder, 'skipped', {}).items():
            _count_skipped(skipped, decoder.topic, why, count)
    command_topic = names[contract.PUMP_COMMAND]
    commands = _finite_rows(pump.release(), ('position',), command_topic, skipped)
    targets = None
    if not commands.get('stamp_ns', np.zeros(0)).size \
            and skipped.get(command_topic, {}).get('no position'):
        # No command gives a volume: a pressure regulator's bag gives target pressures.
        targets = _regulator_commands(bag, command_topic, skipped)
        if targets is not None:
            commands = targets
    _refuse_unusable(path, command_topic, commands, skipped,
                     'not a rig recording, or the pump never ran')
    states = _finite_rows(state.release(), ('position', 'effort'), names[contract.VOLUMES],
                          skipped)
    _refuse_unusable(path, names[contract.VOLUMES], states, skipped,
                     'the actuator did not run or its volumes were not recorded')
    # Arrays are taken as views where possible and converted in place: on a long bag every
    # extra column is tens of MB.
    pump_stamp = commands['stamp_ns']
    if targets is None:
        pump_u = commands['position'][:, 0]
        pump_flow = commands['velocity'][:, 0] if commands['velocity'].size else \
            np.sign(np.gradient(pump_u)).astype(np.int8)
        target = None
    else:
        target = commands['effort'][:, 0]
        pump_u = _regulated_injected(pump_stamp, states['stamp_ns'], states['position'])
        pump_flow = np.sign(np.gradient(target)).astype(np.int8) if target.size > 1 else \
            np.zeros(target.size, np.int8)
    if np.any(pump_stamp[1:] < pump_stamp[:-1]):
        order = np.argsort(pump_stamp, kind='stable')
        pump_stamp, pump_u, pump_flow = pump_stamp[order], pump_u[order], pump_flow[order]
        target = None if target is None else target[order]
    t0 = int(pump_stamp[0])
    ignored: dict[str, int] = {}
    flow_sign = _leg_sign(pump_flow)
    del pump_flow, commands

    state_stamp, volumes, pressure = states['stamp_ns'], states['position'], states['effort']
    keep = state_stamp >= t0
    if not keep.all():
        _count_ignored(ignored, names[contract.VOLUMES], keep)
        state_stamp, volumes, pressure = state_stamp[keep], volumes[keep], pressure[keep]
    del keep, states
    index = _command_index(pump_stamp, state_stamp)
    recording = Recording(
        path=path, segment_names=state.names, pump_time_s=np.zeros(0),
        pump_injected=pump_u, state_time_s=np.zeros(0), state_injected=pump_u[index],
        pressure=pressure[:, 0], volumes=volumes,
        curvature_time_s=np.zeros(0), curvatures=np.zeros((0, volumes.shape[1])),
        namespace=ns, state_flow_sign=flow_sign[index],
        counts={topic: info.message_count for topic, info in bag.channels.items()},
        ignored=ignored, start_ns=t0, skipped=skipped, target_pressure=target)
    del index
    recording.backbone_count = bag.channels[names[contract.BACKBONE]].message_count \
        if names[contract.BACKBONE] in bag.channels else 0

    if contract.CURVATURES in optional:
        curves = _finite_rows(optional[contract.CURVATURES].release(), ('position',),
                              names[contract.CURVATURES], skipped)
        if curves.get('stamp_ns', np.zeros(0)).size:
            stamps, values = curves['stamp_ns'], curves['position']
            del curves
            if np.array_equal(stamps, state_stamp):
                # The actuator answers each command with both: share the state's columns
                # (the times are set below, with the state's).
                recording.curvature_injected = recording.state_injected
                recording.curvatures = values
            else:
                keep = stamps >= t0
                _count_ignored(ignored, names[contract.CURVATURES], keep)
                stamps, values = stamps[keep], values[keep]
                recording.curvature_time_s = _seconds(stamps, t0)
                recording.curvature_injected = pump_u[_command_index(pump_stamp, stamps)]
                recording.curvatures = values
            del stamps
    if contract.PRESSURE in optional:
        # Only the first AMBIENT_SAMPLES are read: what is skipped is counted among those.
        recording.ambient_pressure_pa = _ambient(
            _finite_rows(optional[contract.PRESSURE].result(), ('fluid_pressure',),
                         names[contract.PRESSURE], skipped),
            state_stamp, recording.pressure)
    recording.state_time_s = _seconds(state_stamp, t0, in_place=True)
    if recording.curvature_time_s.size == 0 and recording.curvatures.shape[0]:
        recording.curvature_time_s = recording.state_time_s
    if contract.PUMP_STATUS in optional:
        recording.status = [_status(text, log_time, t0)
                            for log_time, text in optional[contract.PUMP_STATUS].messages]
    if contract.EVENTS in optional:
        messages = optional[contract.EVENTS].messages
        recording.events = _events(messages, names[contract.EVENTS])
        recording.event_times_s = _seconds(np.array([t for t, _ in messages], np.int64), t0)
    if contract.SNAPSHOTS in optional:
        steps = optional.get(contract.SNAPSHOT_STEPS)
        recording.snapshots = _snapshots(
            optional[contract.SNAPSHOTS].messages, steps.messages if steps else None,
            names[contract.SNAPSHOT_STEPS], pump_stamp, pump_u, flow_sign, t0, ignored,
            names[contract.SNAPSHOTS])
    scene_stamps_s: list[float] = []
    if contract.SCENE in optional:
        recording.scenes, stamps = _scenes(optional[contract.SCENE].messages,
                                           names[contract.SCENE])
        scene_stamps_s = [(stamp - t0) / NS_PER_S for stamp in stamps]
    if contract.CHANNEL_FLOWS in optional:
        recording.channel_flows = _channel_flows(optional[contract.CHANNEL_FLOWS],
                                                 names[contract.CHANNEL_FLOWS], t0, ignored)
    recording.pump_time_s = _seconds(pump_stamp, t0, in_place=True)
    # Behind a regulator the volume jumps at every flip: a new run shows in the target.
    recording.run_starts = find_run_starts(
        recording.pump_time_s, pump_u if target is None else target, flow_sign,
        recording.status, scene_stamps_s,
        float(recording.state_time_s[0]) if recording.state_time_s.size else 0.0)
    return recording


def _regulator_commands(bag: Any, topic: str,
                        skipped: dict[str, dict[str, int]]) -> dict[str, np.ndarray] | None:
    """
    A pressure regulator's commands (joint ``regulator``, effort: target gauge pressure).

    None when the topic holds none (its commands without positions were no regulator's).
    The commands the syringe's reading skipped for want of a position are then not skipped.
    """
    decoder = JointStateDecoder(topic, ('effort',), log_times=False, required=('effort',))
    try:
        bag.read([decoder])
    except BagArrayError:
        return None
    if decoder.names != (REGULATOR_JOINT,):
        return None
    columns = decoder.release()
    if not columns.get('stamp_ns', np.zeros(0)).size:
        return None
    reasons = skipped[topic]
    del reasons['no position']
    if not reasons:
        del skipped[topic]
    for why, count in decoder.skipped.items():
        _count_skipped(skipped, topic, why, count)
    return _finite_rows(columns, ('effort',), topic, skipped)


def _regulated_injected(command_stamps: NDArray[np.int64], state_stamps: NDArray[np.int64],
                        volumes: FloatArray) -> FloatArray:
    """
    What a regulator had let in at each command [m^3]: the segments' fluid beyond the first state.

    The actuator answers a command with its state stamped as the command: each command gets
    the last state stamped at or before it (the first state before any).
    """
    order = np.argsort(state_stamps, kind='stable')
    totals = volumes.sum(axis=1)[order]
    row = np.searchsorted(state_stamps[order], command_stamps, side='right') - 1
    return totals[np.maximum(row, 0)] - totals[0]


def _channel_flows(decoder: JointStateDecoder, topic: str, t0: int,
                   ignored: dict[str, int]) -> ChannelFlows | None:
    flows = decoder.release()
    stamps = flows.get('stamp_ns', np.zeros(0, np.int64))
    if not stamps.size:
        return None
    keep = stamps >= t0
    _count_ignored(ignored, topic, keep)
    return ChannelFlows(decoder.names, _seconds(stamps[keep], t0), flows['velocity'][keep],
                        flows['effort'][keep])


def _count_skipped(skipped: dict[str, dict[str, int]], topic: str, why: str,
                   count: int) -> None:
    if count:
        reasons = skipped.setdefault(topic, {})
        reasons[why] = reasons.get(why, 0) + count


def _finite_rows(columns: dict[str, np.ndarray], fields: tuple[str, ...], topic: str,
                 skipped: dict[str, dict[str, int]]) -> dict[str, np.ndarray]:
    """The columns without rows whose ``fields`` hold a NaN or an infinity (counted)."""
    rows = columns.get('stamp_ns', np.zeros(0)).size
    if not rows:
        return columns
    bad = np.zeros(rows, dtype=bool)
    for name in fields:
        values = columns[name]
        bad |= ~np.isfinite(values.reshape(rows, -1)).all(axis=1)
    if not bad.any():
        return columns
    _count_skipped(skipped, topic, f'{" or ".join(fields)} not finite (NaN or infinite)',
                   int(np.count_nonzero(bad)))
    keep = ~bad
    return {name: values[keep] for name, values in columns.items()}


def _refuse_unusable(path: Path, topic: str, columns: dict[str, np.ndarray],
                     skipped: dict[str, dict[str, int]], otherwise: str) -> None:
    if columns.get('stamp_ns', np.zeros(0)).size:
        return
    if topic in skipped:
        reasons = ', '.join(f'{count} {why}' for why, count in sorted(skipped[topic].items()))
        raise RecordingError(f'{path}: no usable {topic} messages: all skipped ({reasons})')
    raise RecordingError(f'{path}: no {topic} messages: {otherwise}')


def _seconds(stamps: NDArray[np.int64], t0: int, in_place: bool = False) -> FloatArray:
    """Seconds from ``t0``; ``in_place`` reuses the stamps' memory (blockwise, no copy)."""
    if not in_place:
        seconds = stamps.astype(np.float64)
        seconds -= float(t0)
        seconds /= NS_PER_S
        return seconds
    seconds = stamps.view(np.float64)
    block = 1 << 20
    for start in range(0, stamps.size, block):
        part = slice(start, start + block)
        seconds[part] = (stamps[part] - t0) / NS_PER_S
    return seconds


def _count_ignored(ignored: dict[str, int], topic: str, keep: NDArray[np.bool_]) -> None:
    dropped = int(keep.size - np.count_nonzero(keep))
    if dropped:
        ignored[topic] = ignored.get(topic, 0) + dropped


def _command_index(pump_stamp: NDArray[np.int64], at: NDArray[np.int64]) -> NDArray[np.intp]:
    """The last pump command at or before each stamp (an answer carries its command's stamp)."""
    index = np.searchsorted(pump_stamp, at, side='right')
    index -= 1
    return np.clip(index, 0, pump_stamp.size - 1, out=index)


def _leg_sign(flow: FloatArray) -> NDArray[np.int8]:
    """+1 on inflation, -1 on deflation; a hold (no flow) belongs to the leg before it."""
    sign = (flow > 0).view(np.int8) - (flow < 0).view(np.int8)
    moving = np.flatnonzero(sign)
    if not moving.size:
        return np.ones_like(sign)
    # Forward fill over holds: the last moving row at or before each row (int32 indices).
    last = np.zeros(sign.size, dtype=np.int32)
    last[moving] = moving
    np.maximum.accumulate(last, out=last)
    filled = sign[last]
    filled[:moving[0]] = sign[moving[0]]
    return filled


def _ambient(pressure: dict, state_stamp: NDArray[np.int64], gauge: FloatArray) -> float | None:
    stamps = pressure.get('stamp_ns', np.zeros(0, np.int64))
    if not stamps.size or not state_stamp.size:
        return None
    at = np.searchsorted(state_stamp, stamps)
    matched = (at < state_stamp.size) & (state_stamp[np.minimum(at, state_stamp.size - 1)]
                                         == stamps)
    if not matched.any():
        return None
    difference = pressure['fluid_pressure'][matched, 0] - gauge[at[matched]]
    return float(np.median(difference))


def _decode(codec: JsonPayload, topic: str, number: int, text: str,
            log_time_ns: int | None = None) -> Any:
    """
    Message ``number`` of ``topic`` through its codec; RecordingError naming both if garbled.

    ``log_time_ns`` stands for the stamp of a payload that carries none.
    """
    try:
        return codec.decode(text, stamp_ns=log_time_ns)
    except PayloadError:
        keys = ', '.join(codec.required(stamp_given=log_time_ns is not None))
        raise RecordingError(f'{topic}: message {number} is not a {codec.what} (JSON with '
                             f'{keys}): {text[:60]!r}') from None


def _status(text: str, log_time_ns: int, t0: int) -> tuple[float, str, str]:
    """Pump status: JSON {"state", "reason", "stamp_ns"}, or plain text in older bags."""
    if text.startswith('{'):
        try:
            status = PUMP_STATUS_JSON.decode(text, stamp_ns=log_time_ns)
            return (status.stamp_ns - t0) / NS_PER_S, status.state, status.reason
        except PayloadError:
            pass
    state, _, reason = text.partition(':')
    return (log_time_ns - t0) / NS_PER_S, state.strip(), reason.strip()


def _events(messages: list[tuple[int, str]], topic: str) -> list[dict]:
    """
    The snap-through events as their JSON objects (they carry no stamp to sort out by).

    A snap in time keeps its optional keys (``start_ns``, ``duration_s``, ...); a quasi-static
    one has none.
    """
    return [SNAP_THROUGH_JSON.fields(_decode(SNAP_THROUGH_JSON, topic, number, text, log_time))
            for number, (log_time, text) in enumerate(messages, start=1)]


def _scenes(messages: list[tuple[int, str]], topic: str) -> tuple[list[SceneIdentity],
                                                                     list[int]]:
    """
    The distinct scene identities of ``actuator/scene``, in the order said, and every stamp.

    An actuator names its scene each time it starts: a stamp after its first state is a restart.
    """
    scenes: list[SceneIdentity] = []
    stamps = []
    for number, (log_time, text) in enumerate(messages, start=1):
        said = _decode(SCENE_IDENTITY_JSON, topic, number, text, log_time)
        stamps.append(said.stamp_ns)
        if not any(said.names() == seen.names() for seen in scenes):
            scenes.append(said)
    return scenes, stamps


def _snapshots(shots: list, steps: list[tuple[int, str]] | None, steps_topic: str,
               pump_stamp: NDArray[np.int64], pump_u: FloatArray, flow_sign: NDArray[np.int8],
               t0: int, ignored: dict[str, int], topic: str) -> list[Snapshot]:
    parsed = []
    for number, (_, text) in enumerate(steps or [], start=1):
        # Steps pair with snapshots by stamp: a step must carry its own.
        step = _decode(SNAPSHOT_STEP_JSON, steps_topic, number, text)
        parsed.append((step.stamp_ns, step.step, step.trigger_injected_m3, step.direction))
    used = [False] * len(parsed)
    result = []
    # Rows where a new inflation leg starts after a deflation: the cycles' boundaries.
    starts = np.flatnonzero((flow_sign[1:] > 0) & (flow_sign[:-1] < 0)) + 1
    for _, stamp, points in shots:
        if stamp < t0:
            ignored[topic] = ignored.get(topic, 0) + 1
            continue
        index = int(_command_index(pump_stamp, np.array([stamp]))[0])
        shot = Snapshot((stamp - t0) / NS_PER_S, float(pump_u[index]), points[:, [0, 2]],
                        direction=INFLATION if flow_sign[index] >= 0 else DEFLATION,
                        cycle=int(np.searchsorted(starts, index, side='right')) + 1)
        # Pair by stamp, in order: the first unused step message with this snapshot's stamp.
        for k, (step_stamp, step, trigger, direction) in enumerate(parsed):
            if not used[k] and step_stamp == stamp:
                used[k] = True
                shot.step, shot.trigger_injected, shot.direction = step, trigger, direction
                break
        result.append(shot)
    if steps is None:
        _number_steps(result)
    return result


def _number_steps(shots: list[Snapshot]) -> None:
    """
    Older bags carry no step messages: number each inflation leg's snapshots 1, 2, ...

    A deflation snapshot takes the number of the nearest-volume snapshot of the inflation leg
    before it.
    """
    rising: list[Snapshot] = []
    previous = None
    for shot in shots:
        if shot.direction == INFLATION:
            if previous == DEFLATION:
                rising = []
            rising.append(shot)
            shot.step = len(rising)
        elif rising:
            shot.step = min(rising, key=lambda s: abs(s.injected - shot.injected)).step
        previous = shot.direction
