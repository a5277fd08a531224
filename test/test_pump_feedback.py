"""
The pump's feedback: only the actuator's trustworthy answer to this pump's own commands counts.

The pump's states and their reasons are one table (softseq_ros.rig.pump.REACTIONS, documented
in docs/faults.md); every row is driven here from a fresh pump. Then every kind of feedback
that cannot be trusted, as an answer (holds at once) and from anyone else (warned once, then
the feedback timeout holds), and over real DDS: an actuator answering with garbage, and a
replay of the actuator's own answers after it died.
"""

import math
from pathlib import Path
import re

import pytest
from rclpy.node import Node
from rclpy.parameter import Parameter
from scenes import write_scene
from sensor_msgs.msg import JointState

from softseq_ros.nodes.actuator import ActuatorNode
from softseq_ros.nodes.core_node import qos_profile
from softseq_ros.nodes.syringe_pump import SyringePumpNode
from softseq_ros.rig.build import pump_core
from softseq_ros.rig.pump import REACTIONS, RECENT_COMMANDS, STATES
from softseq_ros.scene.loader import load_scene
from softseq_ros.scene.programme import Leg
from softseq_ros.testing import Collector, call_trigger, spinning, stamp_ns, wait_for
from softseq_ros.wire import contract
from softseq_ros.wire.values import WARNING, Notice, PumpCommand, PumpStatus, SegmentVolumes

NAMES = ('bottom', 'top')           # the segments of test/scenes.py's scene
GOOD_VOLUMES = [1.2e-5, 1.1e-5]
GOOD_GAUGE_PA = 5.0e3
TIMEOUT_S = 2.0
FAULTS_MD = Path(__file__).resolve().parents[1] / 'docs' / 'faults.md'


@pytest.fixture(scope='module')
def scene(tmp_path_factory):
    return load_scene(write_scene(tmp_path_factory.mktemp('scene')))


class Rig:
    """A pump core as the node builds it, on a test clock, and a hand-played actuator."""

    def __init__(self, scene, **settings) -> None:
        self.wall = [0]
        settings.setdefault('legs', (Leg.inflate(3.0e-5), Leg.hold(100.0)))
        self.pump, _ = pump_core(scene, feedback_timeout_s=TIMEOUT_S,
                                 feedback_clock=lambda: self.wall[0], **settings)
        self.pump.segment_names = NAMES      # as the node sets them from the scene
        self.outputs: list = []

    def tick(self, seconds: float) -> PumpCommand:
        """The pump's tick at ``seconds``; its command."""
        self.wall[0] = int(round(seconds * 1e9))
        self.outputs += self.pump.tick(self.wall[0])
        return [v for v in self.outputs if type(v) is PumpCommand][-1]

    def hear(self, stamp_ns: int, names=NAMES, volumes=GOOD_VOLUMES, gauge=GOOD_GAUGE_PA):
        """A volumes message stamped ``stamp_ns`` reaches the pump (one gauge for all)."""
        self.outputs += self.pump.handle(
            SegmentVolumes(stamp_ns, tuple(names), list(volumes), gauge), self.wall[0])

    def answer(self, command: PumpCommand, **fields) -> None:
        """The actuator's answer to ``command``: stamped with the command's stamp."""
        self.hear(command.stamp_ns, **fields)

    def run(self, until_s: float, step_s: float = 0.1, **fields) -> None:
        """Ticks every ``step_s`` up to ``until_s``, each answered (with ``fields``)."""
        seconds = self.wall[0] * 1e-9
        while seconds < until_s - 1e-9:
            seconds += step_s
            self.answer(self.tick(seconds), **fields)

    def statuses(self) -> list[PumpStatus]:
        return [v for v in self.outputs if type(v) is PumpStatus]

    def warnings(self) -> list[str]:
        return [v.text for v in self.outputs if type(v) is Notice and v.level == WARNING]


# ------------------------------------------------------------------------- the table, row by row

def _reset(rig):
    rig.run(0.5)
    rig.pump.stop(rig.wall[0])
    rig.outputs += rig.pump.reset(rig.wall[0]).outputs
    return {}


def _start(rig):
    rig.pump.autostart = False
    rig.tick(0.1)
    assert rig.pump.state == 'idle'
    rig.outputs += rig.pump.start(rig.wall[0]).outputs
    return {}


def _hold(rig):
    rig.run(0.5)
    rig.outputs += rig.pump.hold(rig.wall[0]).outputs
    return {}


def _silent(rig):
    rig.run(0.5)
    for seconds in (1.0, 2.0, 2.6):        # the actuator fell silent at 0.5 s
        rig.tick(seconds)
    return {'timeout': TIMEOUT_S, 'why': ''}


def _untrusted(rig):
    rig.run(0.5)
    rig.answer(rig.tick(0.6), volumes=[math.nan, 1.0e-5])
    return {'topic': 'actuator/volumes', 'fault': 'volume of bottom is nan'}


def _finished(rig):
    rig.run(102.0, step_s=0.5)          # 1.5 s of inflation, then 100 s held
    return {}


def _over_pressure(rig):
    rig.run(0.5)
    rig.answer(rig.tick(0.6), gauge=math.inf)
    return {'gauge': math.inf, 'limit': rig.pump.max_pressure_pa}


def _end_stop(rig):
    rig.pump.max_injected_m3 = 1.0e-5
    rig.run(1.0)
    return {'limit': 1.0e-5}


def _stop(rig):
    rig.run(0.5)
    rig.outputs += rig.pump.stop(rig.wall[0]).outputs
    return {}


def _setpoint_mode(rig):
    rig.run(0.5)
    rig.outputs += rig.pump.set_mode(rig.wall[0], True).outputs
    return {'topic': 'pump/setpoint'}


SCENARIOS = {'reset': _reset, 'start': _start, 'hold': _hold, 'silent': _silent,
             'untrusted': _untrusted, 'finished': _finished, 'over_pressure': _over_pressure,
             'end_stop': _end_stop, 'stop': _stop, 'setpoint_mode': _setpoint_mode}


@pytest.mark.parametrize('cause', sorted(REACTIONS))
def test_each_row_of_the_pumps_table(scene, cause):
    row = REACTIONS[cause]
    assert row.state in STATES
    rig = Rig(scene)
    fields = SCENARIOS[cause](rig)
    reason = row.reason.format(**fields)
    assert (rig.pump.state, rig.pump.reason) == (row.state, reason)
    # Said on the status topic and in the log, at the row's level.
    last = rig.statuses()[-1]
    assert (last.state, last.reason) == (row.state, reason)
    said = [v for v in rig.outputs if type(v) is Notice and v.text == f'pump {last.text}']
    assert said and said[-1].level == row.level


def test_the_documented_table_is_the_pumps_table():
    text = FAULTS_MD.read_text(encoding='utf-8')
    section = text.split("## The pump's states and why it enters them", 1)[1].split('\n## ')[0]
    rows = re.findall(r'^\| `(\w+)` \| [^|]+ \| `(\w+)` \|', section, flags=re.MULTILINE)
    assert dict(rows) == {cause: row.state for cause, row in REACTIONS.items()}
    for cause in REACTIONS:
        assert f'test_each_row_of_the_pumps_table[{cause}]' in section


# ------------------------------------------------------------------------- feedback that lies

# (what is wrong, the message's fields, what the pump says about it)
UNTRUSTED = [
    ('nan volume', {'volumes': [math.nan, 1.0e-5]}, 'volume of bottom is nan'),
    ('+inf volume', {'volumes': [1.0e-5, math.inf]}, 'volume of top is inf'),
    ('-inf volume', {'volumes': [-math.inf, 1.0e-5]}, 'volume of bottom is -inf'),
    ('negative volume', {'volumes': [1.0e-5, -2.0e-6]}, 'volume of top is negative (-2e-06 m^3)'),
    ('nan pressure', {'gauge': math.nan}, 'gauge pressure is nan'),
    ('-inf pressure', {'gauge': -math.inf}, 'gauge pressure -inf Pa is below vacuum (-101325 Pa)'),
    ('below vacuum', {'gauge': -2.0e5}, 'gauge pressure -200000 Pa is below vacuum (-101325 Pa)'),
    ('other joints', {'names': ('base', 'tip')},
     "joint names ['base', 'tip'] are not the scene's segments ['bottom', 'top']"),
    ('joints swapped', {'names': ('top', 'bottom')},
     "joint names ['top', 'bottom'] are not the scene's segments ['bottom', 'top']"),
    ('a joint missing', {'names': ('bottom',), 'volumes': [1.0e-5]},
     "joint names ['bottom'] are not the scene's segments ['bottom', 'top']"),
    ('too few volumes', {'volumes': [1.0e-5]}, '1 volumes (position) for 2 joints'),
    ('too many volumes', {'volumes': [1.0e-5] * 3}, '3 volumes (position) for 2 joints'),
]


@pytest.mark.parametrize('what, fields, fault', UNTRUSTED, ids=[u[0] for u in UNTRUSTED])
def test_an_untrustworthy_answer_holds_the_pump_at_once_and_says_why(scene, what, fields,
                                                                     fault):
    rig = Rig(scene)
    rig.run(0.5)
    assert rig.pump.state == 'running'
    command = rig.tick(0.6)
    rig.answer(command, **fields)
    assert rig.pump.state == 'held'
    assert rig.pump.reason.startswith(f'actuator/volumes: {fault}; ')
    # Held: no more flow, whatever the actuator goes on saying.
    for seconds in (0.7, 0.8, 0.9):
        later = rig.tick(seconds)
        rig.answer(later, **fields)
        assert later.flow_m3_per_s == 0.0 and later.injected_m3 == command.injected_m3
    # The status said it; the log says it once (with the status), not per message.
    assert [w for w in rig.warnings() if fault in w] == [f'pump held: {rig.pump.reason}']


@pytest.mark.parametrize('what, fields, fault', UNTRUSTED, ids=[u[0] for u in UNTRUSTED])
def test_untrustworthy_messages_from_anyone_are_warned_once_and_are_no_feedback(
        scene, what, fields, fault):
    rig = Rig(scene)
    rig.run(0.5)
    # A garbage publisher beside a silent actuator: two hundred messages in 2.5 s.
    for i in range(1, 26):
        seconds = 0.5 + 0.1 * i
        rig.tick(seconds)
        for k in range(8):
            rig.hear(rig.wall[0] + k + 1, **fields)
    assert [w for w in rig.warnings() if fault in w] == [
        f'actuator/volumes: {fault}: not taken as feedback (said once per kind of fault)',
        f'pump held: {rig.pump.reason}']
    assert rig.pump.state == 'held'
    assert rig.pump.reason == (
        'no pressure from the actuator for 2 s (feedback_timeout_s); what came on '
        f'actuator/volumes could not be trusted ({fault}); call ~/start to go on')


def test_pressures_that_do_not_match_the_joints_are_no_feedback(scene):
    # The node hands the message over field by field: one pressure per joint.
    rig = Rig(scene)
    rig.run(0.5)
    command = rig.tick(0.6)
    rig.outputs += rig.pump.feedback(rig.wall[0], command.stamp_ns, NAMES, GOOD_VOLUMES,
                                     [GOOD_GAUGE_PA])
    assert rig.pump.state == 'held'
    assert rig.pump.reason.startswith('actuator/volumes: 1 pressures (effort) for 2 joints; ')


@pytest.mark.parametrize('over', [math.inf, 1.0e300, 1.00001])
@pytest.mark.parametrize('as_answer', [True, False], ids=['answer', 'anyone'])
def test_a_pressure_above_the_limit_stops_whoever_says_it(scene, over, as_answer):
    # +inf is an over-pressure (the relief's reaction: stopped), not a missing reading.
    rig = Rig(scene)
    limit = rig.pump.max_pressure_pa
    gauge = over * limit
    rig.run(0.5)
    command = rig.tick(0.6)
    rig.hear(command.stamp_ns if as_answer else 12345, gauge=gauge)
    assert rig.pump.state == 'stopped'
    assert rig.pump.reason == REACTIONS['over_pressure'].reason.format(gauge=gauge,
                                                                       limit=limit)
    # Nothing moves any more, even with good answers.
    rig.run(3.0)
    assert rig.pump.state == 'stopped' and rig.tick(3.1).flow_m3_per_s == 0.0


def test_only_answers_to_its_own_recent_commands_are_feedback(scene):
    rig = Rig(scene)
    rig.run(0.5)
    first = rig.tick(0.6)
    rig.answer(first)
    # A replay of a recording (stamps of another run), a live forger stamping with the time
    # of day, and the actuator's own answers over again: none is an answer now.
    recorded_at = 1_700_000_000_000_000_000
    for i in range(1, 40):
        seconds = 0.6 + 0.1 * i
        command = rig.tick(seconds)
        rig.hear(recorded_at + 10_000_000 * i)      # a recording's stamps
        rig.hear(command.stamp_ns + 1)              # "now", but not a command's stamp
        rig.answer(first)                           # answered before: a replay of it
    assert rig.pump.state == 'held'
    assert rig.pump.reason == (
        'no pressure from the actuator for 2 s (feedback_timeout_s); the 60 messages on '
        "actuator/volumes in that time answered none of the pump's commands; "
        'call ~/start to go on')
    # Plausible messages from elsewhere are no fault: the hold says it, nothing else warns.
    assert rig.warnings() == [f'pump held: {rig.pump.reason}']


def test_answers_keep_it_running_even_late_and_out_of_order_but_not_too_late(scene):
    rig = Rig(scene)
    rig.run(0.5)
    # Every command answered 1.5 s late, in swapped pairs: the pump runs on. The answer to the
    # newer of a pair answers the older one too (an actuator behind its commands answers the
    # newest and skips the others), so the older one's own answer comes too late to count.
    commands = []
    for i in range(1, 400):
        commands.append(rig.tick(0.5 + 0.01 * i))
        late = i - 150
        if late >= 0:
            rig.answer(commands[late ^ 1])
    assert rig.pump.state == 'running'
    # An answer to a command older than the last RECENT_COMMANDS is no answer.
    unanswered = commands[300]
    for i in range(RECENT_COMMANDS):
        rig.tick(4.5 + 1e-6 * i)
    rig.answer(unanswered)
    rig.tick(6.6)
    assert rig.pump.state == 'held'
    # That one and the older of the last swapped pair.
    assert rig.pump.reason.endswith("the 2 messages on actuator/volumes in that time answered "
                                    "none of the pump's commands; call ~/start to go on")


def test_an_answer_to_a_newer_command_answers_the_older_ones(scene):
    rig = Rig(scene)
    rig.run(0.5)
    # An actuator behind its commands answers only every tenth, the newest it has: each
    # answer is feedback, and answers the nine before it.
    commands = []
    for i in range(1, 301):
        commands.append(rig.tick(0.5 + 0.01 * i))
        if i % 10 == 0:
            rig.answer(commands[-1])
    rig.run(4.5)
    assert rig.pump.state == 'running'
    # A skipped command's stamp, heard afterwards (a replay, a forger), is no answer any more.
    for i, skipped in enumerate(commands[:-1]):
        rig.tick(4.7 + 0.001 * i)
        rig.answer(skipped)
    rig.tick(6.8)
    assert rig.pump.state == 'held'
    assert f'the {len(commands) - 1} messages on actuator/volumes in that time answered none' \
        in rig.pump.reason


def test_open_loop_takes_no_feedback_and_holds_on_nothing(scene):
    rig = Rig(scene, open_loop=True)
    rig.run(1.0, volumes=[math.nan, 1.0e-5])
    assert rig.pump.state == 'running'
    assert rig.warnings() == ['actuator/volumes: volume of bottom is nan: not taken as feedback '
                              '(said once per kind of fault)']


# ------------------------------------------------------------------------- real nodes over DDS

LEGS = '[{inflate_to_m3: 3.0e-5}, {hold_s: 100}]'


def _pump(context, scene_path, namespace, **params):
    return SyringePumpNode(context=context, cli_args=['--ros-args', '-r', f'__ns:={namespace}'],
                           parameter_overrides=[Parameter('scene', value=scene_path),
                                                Parameter('legs', value=LEGS)]
                           + [Parameter(k, value=v) for k, v in params.items()])


class GarbageActuator(Node):
    """Answers every pump command, stamped with it, with one pressure for two joints."""

    def __init__(self, context, namespace: str) -> None:
        super().__init__('actuator', namespace=namespace, context=context)
        self.answered = 0
        self.out = self.create_publisher(JointState, 'actuator/volumes',
                                         qos_profile(contract.VOLUMES.qos))
        self.create_subscription(JointState, 'pump/command', self._answer,
                                 qos_profile(contract.PUMP_COMMAND.qos))

    def _answer(self, command: JointState) -> None:
        self.out.publish(JointState(header=command.header, name=list(NAMES),
                                    position=list(GOOD_VOLUMES), effort=[GOOD_GAUGE_PA]))
        self.answered += 1


@pytest.mark.ros
def test_an_actuator_answering_garbage_holds_the_pump_which_says_why_once(context, tmp_path):
    # A long feedback timeout: only the garbage itself can hold the pump within the test.
    pump = _pump(context, write_scene(tmp_path), '/lab', feedback_timeout_s=3600.0)
    warnings = []
    pump.log = lambda level, text: warnings.append((level, text))
    fake = GarbageActuator(context, '/lab')
    with spinning(context, pump, fake):
        wait_for(lambda: pump.state == 'held', 'the pump to hold')
        # The first command after the hold gives the volume of the instant it held at.
        answered = fake.answered
        wait_for(lambda: fake.answered > answered, 'one more garbage answer')
        held_at = pump.core.volume_m3
        # Held, the pump repeats its command once a second (HEARTBEAT_S): each repeat is
        # answered with garbage again, and none is said again.
        answered = fake.answered
        wait_for(lambda: fake.answered >= answered + 3, 'three more garbage answers')
        assert pump.state == 'held' and pump.core.volume_m3 == held_at
    assert pump.core.reason == (
        '/lab/actuator/volumes: 1 pressures (effort) for 2 joints; feedback that cannot be '
        'trusted is no feedback; call ~/start to go on')
    reason = pump.core.reason
    said = [(level, text) for level, text in warnings if '1 pressures (effort)' in text]
    assert said == [('warning', f'pump held: {reason}')]


class Replayer(Node):
    """Publishes recorded actuator/volumes messages over and over, as a bag player would."""

    def __init__(self, context, namespace: str, messages) -> None:
        super().__init__('player', namespace=namespace, context=context)
        self.messages, self.sent = list(messages), 0
        self.out = self.create_publisher(JointState, 'actuator/volumes',
                                         qos_profile(contract.VOLUMES.qos))
        self.create_timer(0.01, self._play)

    def _play(self) -> None:
        self.out.publish(self.messages[self.sent % len(self.messages)])
        self.sent += 1


@pytest.mark.ros
def test_a_replay_of_the_actuators_answers_keeps_no_pump_running_once_it_died(context,
                                                                              tmp_path):
    scene_path = write_scene(tmp_path)
    pump = _pump(context, scene_path, '/lab', autostart=False)   # 2 s feedback timeout
    actuator = ActuatorNode(context=context, cli_args=['--ros-args', '-r', '__ns:=/lab'],
                            parameter_overrides=[Parameter('scene', value=scene_path),
                                                 Parameter('resume_timeout_s', value=0.0),
                                                 Parameter('state_file', value='')])
    recorder = Collector(['actuator/volumes', 'pump/command'], context, '/lab')
    answers = recorder.received['/lab/actuator/volumes']
    commands = recorder.received['/lab/pump/command']
    with spinning(context, pump, recorder):
        with spinning(context, actuator):
            wait_for(lambda: pump.publisher(contract.PUMP_COMMAND).get_subscription_count()
                     == 2, 'the actuator and the recorder on pump/command')
            wait_for(lambda: recorder.matched('/lab/actuator/volumes'), 'the actuator')
            assert call_trigger(recorder, '/lab/syringe_pump/start').success
            # The real actuator answers: the pump runs on its answers. Counted by the
            # commands they answer (the actuator's latched rest state answers none).

            def answered() -> int:
                stamps = {stamp_ns(c.header) for c in commands}
                return sum(stamp_ns(m.header) in stamps for m in answers)
            wait_for(lambda: answered() > 50, 'the actuator to answer 50 commands')
            assert pump.state == 'running'
        # The actuator is gone. Its own recorded answers, played back into the namespace:
        # plausible volumes, each stamped with one of this pump's commands.
        stamps = {stamp_ns(c.header) for c in commands}
        recorded = [m for m in answers if stamp_ns(m.header) in stamps]
        assert len(recorded) > 50
        player = Replayer(context, '/lab', recorded)
        with spinning(context, player):
            wait_for(lambda: pump.state == 'held', 'the pump to hold')
            wait_for(lambda: player.sent > len(recorded), 'the whole recording played')
            reason = pump.core.reason
            held_at = pump.core.volume_m3
            wait_for(lambda: player.sent > 2 * len(recorded), 'the recording played twice')
            assert pump.state == 'held' and pump.core.volume_m3 == held_at
    assert reason.startswith('no pressure from the actuator for 2 s (feedback_timeout_s); the ')
    assert "messages on /lab/actuator/volumes in that time answered none of the pump's " \
        'commands' in reason


def test_the_relief_by_default_is_half_again_the_highest_pressure_the_segments_hold():
    from softseq_ros.scene.csv_columns import read_columns
    from softseq_ros.scene.validation import SceneError

    scene = load_scene('paper')
    # The highest pressure row of the paper's tables, read straight from the files.
    highest = 0.0
    for segment in scene.segments:
        table = Path(scene.path).parent / 'segments' / f'paper_{segment.name}.csv'
        highest = max(highest, float(read_columns(table, ('pressure_pa',), SceneError,
                                                  'segment table')['pressure_pa'].max()))
    pump, _ = pump_core(scene)
    assert pump.max_pressure_pa == pytest.approx(1.5 * highest, rel=1e-9)
    assert 10e3 < pump.max_pressure_pa < 40e3       # not the 100 kPa of before
    # Given, it is taken as given.
    assert pump_core(scene, max_pressure_pa=5.0e3)[0].max_pressure_pa == 5.0e3
