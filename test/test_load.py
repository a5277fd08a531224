"""
Load: commands faster than the actuator answers, and a recorder that stalls.

The contract (docs/faults.md, Load; softseq_ros.rig.intake): while the actuator keeps up it
answers every command; once far behind it answers the newest and skips the rest, its state
walking through every skipped volume, counts what it skipped (passed over, or dropped by its
queue) and says so in its log; it never dies. Every answer topic's publisher keeps 1000
messages, so a recorder that stalls for a second at 200 Hz misses none.

The first tests drive the ROS-free parts on test clocks; the others run console-script nodes
as processes over DDS, for seconds of load each.
"""

import json
from pathlib import Path
import re
import signal
import struct
import time

from mcap.exceptions import McapError
from mcap.records import Channel, Message
from mcap.stream_reader import StreamReader
import numpy as np
import pytest
from rclpy.node import Node
from scenes import inside_the_hysteresis_loop, write_scene
from sensor_msgs.msg import JointState
from test_nodes_processes import PATIENT_FEEDBACK_TIMEOUT_S, STARTUP_TIMEOUT_S, node_processes

from softseq_ros.bag.reader import read_bag
from softseq_ros.nodes.core_node import qos_profile
from softseq_ros.quasistatic.equilibrium import EquilibriumMap, Tracker
from softseq_ros.rig.actuator import ActuatorCore
from softseq_ros.rig.intake import BACKLOG_COMMANDS, CommandIntake
from softseq_ros.rig.model import QuasiStaticModel
from softseq_ros.scene.loader import load_scene
from softseq_ros.testing import Collector, call_trigger, spinning, stamp_ns, wait_for
from softseq_ros.wire import contract
from softseq_ros.wire.values import PumpCommand

MS = 1_000_000
ML = 1.0e-6


# ------------------------------------------------------------------------- without ROS

def test_the_intake_answers_every_command_while_it_keeps_up_and_the_newest_when_behind():
    intake = CommandIntake()
    answered, sequence, now = [], 0, 0

    def arrive(count: int, every_ns: int, take_after_ns: int, take_every_ns: int):
        """``count`` commands arriving ``every_ns`` apart, the first taken ``take_after_ns``
        after its arrival and each next one ``take_every_ns`` after the one before."""
        nonlocal sequence, now
        first_arrival = now
        for k in range(count):
            sequence += 1
            arrival = first_arrival + k * every_ns
            taken_at = max(arrival, first_arrival + take_after_ns + k * take_every_ns)
            now = taken_at
            command = intake.take(sequence, sequence, arrival, now)
            if command is not None:
                answered.append(command)
        now += every_ns

    # A 100 Hz pump, each command taken 1 ms after it came: every one answered.
    arrive(200, 10 * MS, 1 * MS, 10 * MS)
    assert answered == list(range(1, 201)) and intake.skipped.total == 0
    # A stall of half a second (50 commands waiting) is caught up on, answer by answer.
    arrive(50, 10 * MS, 500 * MS, 100_000)
    assert answered[-50:] == list(range(201, 251)) and intake.skipped.total == 0
    assert intake.pending is None
    # A flood: 5000 commands 0.1 ms apart, taken every 0.5 ms. Behind: the newest waits.
    arrive(5000, 100_000, 100_000, 500_000)
    assert intake.behind and intake.pending == sequence
    assert intake.skipped.passed_over > 0
    # The queue dropped 3 commands before they were taken: a gap in the sequence.
    sequence += 3
    assert intake.take(sequence + 1, sequence + 1, now, now + 10_000 * MS) is None
    assert intake.skipped.dropped == 3
    # A report while the newest still waits says so; its totals miss that one command.
    (behind,) = intake.report()
    assert behind.text.endswith('still behind')
    assert f'{intake.answered} answered in all' in behind.text
    newest = intake.flush()
    assert newest == sequence + 1 and intake.flush() is None
    answered.append(newest)
    # Every command either answered or counted as skipped; the newest answered last.
    assert intake.answered == len(answered)
    assert intake.answered + intake.skipped.total == sequence + 1
    # Nothing skipped since, but the last report said 'still behind': once more, caught up,
    # with totals that account for every command.
    (report,) = intake.report()
    assert report.level == 'warning'
    assert f'{intake.skipped.total} skipped and {intake.answered} answered in all' in report.text
    assert '0 skipped since the last report' in report.text
    assert report.text.endswith('caught up')
    assert intake.report() == []     # said once
    (summary,) = intake.summary()
    assert f'skipped {intake.skipped.total}' in summary.text


def test_a_restarted_or_second_pump_counts_no_false_gap():
    intake = CommandIntake()
    for seq in range(1, 11):
        intake.take(seq, seq, seq * MS, seq * MS + 1)
    # A restarted pump numbers from 1 again: a new publisher, not a gap.
    intake.take(1, 1, 11 * MS, 11 * MS + 1)
    intake.take(2, 2, 12 * MS, 12 * MS + 1)
    assert intake.skipped.dropped == 0
    # Two publishers interleave their numbers; the node says so and gaps are not counted.
    intake.one_publisher = False
    intake.take(500, 500, 13 * MS, 13 * MS + 1)
    assert intake.skipped.dropped == 0
    # Without arrival times (a middleware that gives none) every command is answered.
    blind = CommandIntake()
    assert all(blind.take(k, None, None, 10**12) == k for k in range(3 * BACKLOG_COMMANDS))


def test_the_state_file_is_written_at_a_bounded_rate_and_the_last_state_at_stop(tmp_path):
    scene = load_scene('fig1_asymmetric')
    emap = EquilibriumMap(scene.segments)
    middle, _, deflating = inside_the_hysteresis_loop(emap)
    clock = [0]
    state_file = tmp_path / 'actuator.json'
    core = ActuatorCore(QuasiStaticModel(emap, scene.segment_names), scene.segment_names,
                        state_file=state_file, save_period_s=0.1, save_clock=lambda: clock[0])
    top = 0.98 * emap.injected_range[1]
    volumes = np.concatenate([np.linspace(0.0, top, 500), np.linspace(top, middle, 500)])
    # A thousand commands within 50 ms: the first change is written at once, the rest wait.
    for i, volume in enumerate(volumes):
        clock[0] = i * 50_000
        core.handle(PumpCommand(i + 1, float(volume), 0.0), 0)
    assert core.state_writes == 1

    def saved():
        return json.loads(state_file.read_text(encoding='utf-8'))
    assert saved()['injected_m3'] == pytest.approx(volumes[0], abs=1e-15)
    # The driver's flush writes the newest state, once.
    assert core.flush_state() == [] and core.state_writes == 2
    core.flush_state()
    assert core.state_writes == 2
    np.testing.assert_allclose(saved()['volumes_m3'], deflating, rtol=1e-9)
    # A change a period after the last write is written at once.
    clock[0] += 200 * MS
    core.handle(PumpCommand(2000, float(middle) * 0.999, 0.0), 0)
    assert core.state_writes == 3
    # A clean stop writes the last state, closed, whatever the period.
    core.handle(PumpCommand(2001, float(middle), 0.0), 0)
    core.close()
    assert saved()['closed'] is True and core.state_writes == 4
    np.testing.assert_allclose(saved()['volumes_m3'], deflating, rtol=1e-9)


# ------------------------------------------------------------------------- processes over DDS

IN_ALL = re.compile(r'(\d+) skipped and (\d+) answered in all')


def _reports(log: Path) -> list[tuple[int, int]]:
    """(skipped, answered) of every report the actuator logged."""
    text = log.read_text(encoding='utf-8', errors='replace') if log.exists() else ''
    return [(int(a), int(b)) for a, b in IN_ALL.findall(text)]


class Flooder(Node):
    """Publishes pump commands as fast as a publisher can."""

    def __init__(self, context) -> None:
        super().__init__('flooder', context=context)
        self.publisher = self.create_publisher(JointState, contract.PUMP_COMMAND.name,
                                               qos_profile(contract.PUMP_COMMAND.qos))

    def send(self, stamp: int, injected_m3: float) -> None:
        msg = JointState(name=['syringe'], position=[injected_m3], velocity=[0.0])
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
        self.publisher.publish(msg)


@pytest.mark.ros
def test_a_flooded_actuator_answers_the_newest_counts_what_it_skipped_and_lives(
        context, ros_env, tmp_path):
    scene = load_scene('fig1_asymmetric')
    emap = EquilibriumMap(scene.segments)
    middle, inflating, deflating = inside_the_hysteresis_loop(emap)
    top = 0.98 * emap.injected_range[1]
    count = 10_000
    # Up past the loop and back into it: the answer to the last command is on the deflation
    # branch only if the skipped volumes were walked through.
    volumes = np.concatenate([np.linspace(0.0, top, count // 2),
                              np.linspace(top, middle, count - count // 2)])
    flooder = Flooder(context)
    collector = Collector(['actuator/volumes'], context)
    answers = collector.messages('actuator/volumes')
    log = tmp_path / 'actuator.log'
    with node_processes(ros_env, tmp_path) as start, spinning(context, flooder, collector):
        actuator = start('actuator', 'actuator', scene='fig1_asymmetric', resume_timeout_s=0.0,
                         state_file="''")
        wait_for(lambda: flooder.publisher.get_subscription_count() == 1
                 and collector.matched('actuator/volumes'), 'the actuator',
                 timeout=STARTUP_TIMEOUT_S)
        # One command answered first: the actuator has seen the flooder's first number.
        flooder.send(1, 0.0)
        wait_for(lambda: any(stamp_ns(m.header) == 1 for m in answers),
                 'the answer to the first command', timeout=STARTUP_TIMEOUT_S)
        for i, volume in enumerate(volumes):
            flooder.send(i + 2, float(volume))
        last = count + 1
        wait_for(lambda: any(stamp_ns(m.header) == last for m in answers),
                 'the answer to the last command', timeout=60.0,
                 explain=lambda: f'{len(answers)} answers; log: {_reports(log)[-1:]}')
        wait_for(lambda: any(s + a == count + 1 for s, a in _reports(log)),
                 'a report that accounts for every command', timeout=30.0,
                 explain=lambda: f'reports (skipped, answered): {_reports(log)}')
        assert actuator.poll() is None
        actuator.send_signal(signal.SIGINT)
        assert actuator.wait(timeout=30) == 0
    final = next(m for m in answers if stamp_ns(m.header) == last)
    expected = Tracker(emap).sweep(np.concatenate([[0.0], volumes])).volumes[-1]
    np.testing.assert_allclose(final.position, expected, rtol=1e-9, atol=1e-9 * emap.v_scale)
    np.testing.assert_allclose(final.position, deflating, rtol=1e-9, atol=1e-9 * emap.v_scale)
    assert np.max(np.abs(np.array(final.position) - inflating)) > 1e-3 * emap.v_scale
    skipped, answered = next((s, a) for s, a in _reports(log) if s + a == count + 1)
    # The count is honest: the test received exactly the answers the actuator says it gave,
    # and most commands were skipped (a flood, not a pace it keeps up with).
    # (Its rest state, said once at start, answers no command.)
    assert len({stamp_ns(m.header) for m in answers} & set(range(1, last + 1))) == answered
    assert skipped > count // 2
    assert f'answered {answered} commands; skipped {skipped}' in log.read_text()


@pytest.mark.ros
def test_an_actuator_under_a_10_khz_pump_lives_and_keeps_the_pump_running(
        context, ros_env, tmp_path):
    scene = load_scene('fig1_asymmetric')
    emap = EquilibriumMap(scene.segments)
    target = 0.6 * emap.injected_range[1]
    legs = f"'[{{inflate_to_m3: {target!r}}}, {{hold_s: 600.0}}]'"
    collector = Collector(['pump/status', 'actuator/volumes'], context)
    answers = collector.messages('actuator/volumes')
    rest = emap.total_rest_volume
    with node_processes(ros_env, tmp_path) as start, spinning(context, collector):
        actuator = start('actuator', 'actuator', scene='fig1_asymmetric', resume_timeout_s=0.0,
                         state_file="''")
        # Patient as a loaded machine needs: the actuator process may stall for seconds.
        pump = start('pump', 'syringe_pump', scene='fig1_asymmetric', rate_hz=10000,
                     autostart='false', legs=legs, flow_rate_m3_per_s=target,
                     feedback_timeout_s=PATIENT_FEEDBACK_TIMEOUT_S)
        collector.wait_for_publishers(timeout=STARTUP_TIMEOUT_S)
        assert call_trigger(collector, 'syringe_pump/start').success
        # The programme reaches its hold in 1 s of run time; the pump runs on as long as the
        # actuator's answers come (each answers the commands before it too).
        wait_for(lambda: any(abs(sum(m.position) - rest - target) < 1e-12 * emap.v_scale
                             for m in answers[-50:]), 'an answer at the hold', timeout=60.0,
                 explain=lambda: f'{len(answers)} answers; states {collector.states()}')
        before = len(answers)
        collector.wait_for_count('actuator/volumes', before + 300, timeout=60.0)
        # Running since its start and never tripped: the idle it said before may have gone
        # before the collector's subscription matched on a loaded machine.
        assert collector.states() in (['idle', 'running'], ['running'])
        assert actuator.poll() is None and pump.poll() is None
        pump.send_signal(signal.SIGINT)
        assert pump.wait(timeout=30) == 0
        actuator.send_signal(signal.SIGINT)
        assert actuator.wait(timeout=30) == 0
    final = np.array(answers[-1].position)
    expected = Tracker(emap).sweep(np.linspace(0.0, target, 1001)).volumes[-1]
    np.testing.assert_allclose(final, expected, rtol=1e-9, atol=1e-9 * emap.v_scale)
    # Whatever it skipped on this machine, it said so consistently.
    text = (tmp_path / 'actuator.log').read_text(encoding='utf-8', errors='replace')
    assert 'Traceback' not in text
    reports = _reports(tmp_path / 'actuator.log')
    assert all(later[0] >= earlier[0] for earlier, later in zip(reports, reports[1:]))


def _recorded(bag: Path) -> dict[str, set[int]]:
    """The header stamps per topic in the bag a recorder is writing (its flushed part)."""
    stamps: dict[str, set[int]] = {}
    files = sorted(bag.glob('*.mcap'))
    if not files:
        return stamps
    topics: dict[int, str] = {}
    with open(files[0], 'rb') as stream:
        try:
            for record in StreamReader(stream).records:
                if isinstance(record, Channel):
                    topics[record.id] = record.topic
                elif isinstance(record, Message) and record.channel_id in topics:
                    # CDR: a 4-byte encapsulation header, then the Header's stamp.
                    order = '<' if record.data[1] & 1 else '>'
                    sec, nanosec = struct.unpack_from(order + 'iI', record.data, 4)
                    stamps.setdefault(topics[record.channel_id], set()).add(
                        sec * 1_000_000_000 + nanosec)
        except (McapError, struct.error, EOFError):
            pass   # the end of what is on disk so far
    return stamps


@pytest.mark.ros
def test_a_recorder_that_stalls_at_200_hz_keeps_every_answer_a_probe_got(
        context, ros_env, tmp_path):
    scene_path = write_scene(tmp_path, rate_hz=200, flow_rate_m3_per_s=1.0e-6,
                             legs=[{'inflate_to_m3': 3.0e-5}, {'deflate_to_m3': 0.0}])
    answer_topics = ['actuator/volumes', 'actuator/pressure', 'actuator/curvatures']
    probe = Collector(['pump/command', *answer_topics], context)
    bag = tmp_path / 'bag'
    with node_processes(ros_env, tmp_path) as start, spinning(context, probe):
        recorder = start('recorder', 'recorder', output=str(bag))
        start('actuator', 'actuator', scene=scene_path, resume_timeout_s=0.0,
              state_file="''")
        pump = start('pump', 'syringe_pump', scene=scene_path, autostart='false',
                     feedback_timeout_s=PATIENT_FEEDBACK_TIMEOUT_S)
        probe.wait_for_publishers(timeout=STARTUP_TIMEOUT_S)
        assert call_trigger(probe, 'syringe_pump/start').success

        recorded = ['pump/command', *answer_topics]
        # Every topic reached the recorder: its subscriptions matched the publishers (what
        # was published before is not its to record).
        wait_for(lambda: all(_recorded(bag).get('/' + t) for t in recorded),
                 'the recorder to write every topic', timeout=STARTUP_TIMEOUT_S)
        firsts = {t: min(_recorded(bag)['/' + t]) for t in recorded}
        stalled_from = time.time_ns()

        def stamped_since_stall(topic: str) -> int:
            return len({stamp_ns(m.header) for m in probe.messages(topic)
                        if stamp_ns(m.header) >= stalled_from})
        # A loaded machine, made certain: the recorder's process stops for a second or more
        # while the actuator answers 200 commands a second (its old depth of 1 on
        # actuator/volumes kept one of them for the recorder, 100 on pressure and curvatures
        # half of them). Counted by stamp, not by arrival: a busy probe may still be taking
        # in what was published before the stall.
        recorder.send_signal(signal.SIGSTOP)
        try:
            wait_for(lambda: all(stamped_since_stall(t) >= 200 for t in recorded),
                     'the probe to get 200 messages per topic while the recorder stands still',
                     timeout=60.0,
                     explain=lambda: str({t: stamped_since_stall(t) for t in recorded}))
        finally:
            recorder.send_signal(signal.SIGCONT)
        probe.wait_for_count('actuator/volumes', len(probe.messages('actuator/volumes')) + 50)
        until = stamp_ns(probe.messages('pump/command')[-1].header)

        def missing() -> dict[str, int]:
            """Per topic, what the probe got from the recorder's first message to ``until``
            and the recorder has not written (yet)."""
            have = _recorded(bag)
            return {t: len({stamp_ns(m.header) for m in probe.messages(t)
                            if firsts[t] <= stamp_ns(m.header) <= until}
                           - have.get('/' + t, set())) for t in recorded}
        # What the recorder missed while it stood still reaches it again from the publishers'
        # history (a reliable writer repeats it when asked, at the latest at its heartbeat,
        # every 3 s); the publishers stay up meanwhile.
        wait_for(lambda: not any(missing().values()), 'the recorder to catch up', timeout=60.0,
                 explain=lambda: f'missing {missing()}')
        for process in (pump, recorder):
            process.send_signal(signal.SIGINT)
            assert process.wait(timeout=60) == 0
    in_bag: dict[str, set[int]] = {}
    for item in read_bag(bag, topics=['/' + t for t in recorded]):
        in_bag.setdefault(item.topic, set()).add(stamp_ns(item.msg.header))
    # The closed bag holds it all, and the stall fell inside what it holds.
    for topic in recorded:
        got = {stamp_ns(m.header) for m in probe.messages(topic)
               if firsts[topic] <= stamp_ns(m.header) <= until}
        assert got <= in_bag['/' + topic], f'{topic}: {len(got - in_bag["/" + topic])} missing'
        assert firsts[topic] < stalled_from
        assert len({s for s in got if s >= stalled_from}) >= 200
