"""
A controller on the rig: the pump's setpoint mode and the example PI pressure hold, as cores.

The pump, the actuator and the controller are routed by the contract (softseq_ros.rig.routing)
on a test clock, as the one-process rig routes them: the controller reads the actuator's
volumes and gives the pump setpoints, the pump keeps its relief valve, end stop and feedback
rules. The PI's accuracy is checked against the actuator's own quasi-static equilibrium.
"""

import math

import numpy as np
import pytest
from test_pump_feedback import GOOD_GAUGE_PA, Rig, write_scene

from softseq_ros.quasistatic.equilibrium import EquilibriumMap, Tracker
from softseq_ros.rig.build import actuator_core, pump_core
from softseq_ros.rig.controller import PressureHold
from softseq_ros.rig.model import actuator_model
from softseq_ros.rig.pump import HELD, IDLE, PROGRAMME, RUNNING, SETPOINT, STOPPED
from softseq_ros.rig.routing import Router
from softseq_ros.scene.loader import load_scene
from softseq_ros.scene.programme import Leg
from softseq_ros.wire import contract
from softseq_ros.wire.values import WARNING, Notice, PumpCommand, PumpSetpoint, SegmentVolumes

PUMP_PERIOD_NS = 20_000_000     # the paper scene's 50 Hz


@pytest.fixture(scope='module')
def scene(tmp_path_factory):
    return load_scene(write_scene(tmp_path_factory.mktemp('scene')))


def _setpoint_rig(scene, **settings):
    rig = Rig(scene, **settings)
    rig.run(0.5)
    rig.outputs += rig.pump.set_mode(rig.wall[0], True).outputs
    assert (rig.pump.mode, rig.pump.state) == (SETPOINT, RUNNING)
    return rig


def _give(rig, **field):
    rig.outputs += rig.pump.handle(PumpSetpoint(rig.wall[0], **field), rig.wall[0])


# ------------------------------------------------------------------------- the pump's side

def test_a_target_volume_is_reached_at_the_pumps_flow_rate_and_held(scene):
    rig = _setpoint_rig(scene)
    start = rig.pump.volume_m3
    rate = rig.pump.profile.flow_rate
    target = start + 0.5 * rate            # half a second away at the pump's rate
    _give(rig, injected_m3=target)
    seconds = rig.wall[0] * 1e-9
    command = rig.tick(seconds + 0.1)
    # 0.1 s at the programme's rate, with that flow commanded.
    assert command.injected_m3 == pytest.approx(start + 0.1 * rate, rel=1e-12)
    assert command.flow_m3_per_s == pytest.approx(rate, rel=1e-9)
    rig.run(seconds + 0.1 + 0.5 + 1.0)
    last = rig.tick(rig.wall[0] * 1e-9 + 0.1)
    assert (last.injected_m3, last.flow_m3_per_s) == (target, 0.0)
    # Back down to a lower target, at the same rate.
    _give(rig, injected_m3=start)
    down = rig.tick(rig.wall[0] * 1e-9 + 0.1)
    assert down.flow_m3_per_s == pytest.approx(-rate, rel=1e-9)
    assert rig.pump.setpoints_taken == 2 and rig.pump.setpoints_refused == 0


def test_a_flow_setpoint_is_integrated_and_stops_at_an_empty_syringe(scene):
    rig = _setpoint_rig(scene)
    start = rig.pump.volume_m3
    _give(rig, flow_m3_per_s=2.0e-7)
    seconds = rig.wall[0] * 1e-9
    rig.run(seconds + 1.0)
    assert rig.pump.volume_m3 == pytest.approx(start + 2.0e-7, rel=1e-9)
    _give(rig, flow_m3_per_s=-1.0e-5)
    rig.run(rig.wall[0] * 1e-9 + 1.0)
    assert rig.pump.volume_m3 == 0.0
    assert rig.tick(rig.wall[0] * 1e-9 + 0.1).flow_m3_per_s == 0.0
    assert rig.pump.state == RUNNING


@pytest.mark.parametrize('field, value, said', [
    ('injected_m3', -1.0e-6, 'outside 0 to max_injected_m3'),
    ('injected_m3', 1.0, 'outside 0 to max_injected_m3'),
    ('injected_m3', math.nan, 'not a finite number'),
    ('flow_m3_per_s', math.inf, 'not a finite number'),
    ('flow_m3_per_s', -2.0e-3, 'faster than max_flow_m3_per_s'),
    ('gauge_pa', 5.0e3, 'the supply is a syringe'),
])
def test_a_setpoint_out_of_range_is_refused_counted_and_said(scene, field, value, said):
    rig = _setpoint_rig(scene)
    _give(rig, injected_m3=rig.pump.volume_m3 + 1.0e-7)
    kept = rig.pump.setpoint
    _give(rig, **{field: value})
    assert rig.pump.setpoint is kept            # the last good one is still followed
    assert (rig.pump.setpoints_taken, rig.pump.setpoints_refused) == (1, 1)
    assert said in rig.pump.last_refused_setpoint
    assert any(said in text and text.startswith('pump/setpoint: ') for text in rig.warnings())
    assert rig.pump.state == RUNNING


def test_setpoints_in_programme_mode_are_refused_and_the_programme_goes_on(scene):
    rig = Rig(scene)
    rig.run(0.5)
    before = rig.pump.volume_m3
    _give(rig, flow_m3_per_s=-1.0e-6)
    rig.run(1.0)
    assert rig.pump.mode == PROGRAMME and rig.pump.volume_m3 > before
    assert rig.pump.setpoints_refused == 1 and 'setpoint_mode' in rig.pump.last_refused_setpoint


def test_the_end_stop_acts_on_a_flow_setpoint(scene):
    rig = _setpoint_rig(scene)
    limit = rig.pump.volume_m3 + 1.0e-7
    rig.pump.max_injected_m3 = limit
    _give(rig, flow_m3_per_s=1.0e-6)
    rig.run(rig.wall[0] * 1e-9 + 1.0)
    assert (rig.pump.state, rig.pump.cause) == (STOPPED, 'end_stop')
    assert rig.pump.volume_m3 == limit
    assert [c.injected_m3 for c in rig.outputs if type(c) is PumpCommand][-1] == limit


def test_missing_or_untrusted_feedback_holds_a_pump_in_setpoint_mode(scene):
    silent = _setpoint_rig(scene)
    _give(silent, flow_m3_per_s=1.0e-7)
    seconds = silent.wall[0] * 1e-9
    for later in (1.0, 2.0, 2.6):            # no answer after the switch
        silent.tick(seconds + later)
    assert (silent.pump.state, silent.pump.cause) == (HELD, 'silent')
    held = silent.pump.volume_m3
    silent.tick(seconds + 3.0)
    assert silent.pump.volume_m3 == held     # held: the setpoint's flow no longer moves it
    untrusted = _setpoint_rig(scene)
    _give(untrusted, flow_m3_per_s=1.0e-7)
    untrusted.answer(untrusted.tick(untrusted.wall[0] * 1e-9 + 0.1), volumes=[math.nan, 1e-5])
    assert (untrusted.pump.state, untrusted.pump.cause) == (HELD, 'untrusted')
    # ~/start resumes following the setpoint.
    untrusted.outputs += untrusted.pump.start(untrusted.wall[0]).outputs
    before = untrusted.pump.volume_m3
    untrusted.run(untrusted.wall[0] * 1e-9 + 0.5)
    assert untrusted.pump.volume_m3 == pytest.approx(before + 0.5e-7, rel=1e-6)


def test_the_relief_valve_stops_a_pump_in_setpoint_mode(scene):
    rig = _setpoint_rig(scene, max_pressure_pa=GOOD_GAUGE_PA)
    _give(rig, flow_m3_per_s=1.0e-7)
    rig.answer(rig.tick(rig.wall[0] * 1e-9 + 0.1), gauge=2.0 * GOOD_GAUGE_PA)
    assert (rig.pump.state, rig.pump.cause) == (STOPPED, 'over_pressure')


def test_back_to_the_programme_it_starts_where_the_syringe_is_or_is_refused(scene):
    rig = _setpoint_rig(scene, legs=(Leg.inflate(3.0e-5), Leg.deflate(0.0)))
    _give(rig, injected_m3=1.0e-5)
    rig.run(rig.wall[0] * 1e-9 + 1.0e-5 / rig.pump.profile.flow_rate + 1.0)
    reply = rig.pump.set_mode(rig.wall[0], False)
    assert reply.success and (rig.pump.mode, rig.pump.state) == (PROGRAMME, IDLE)
    assert rig.pump.profile.start_injected == 1.0e-5
    assert rig.tick(rig.wall[0] * 1e-9 + 0.1).injected_m3 == 1.0e-5     # no jump
    # A programme whose first leg inflates to below the syringe cannot start there.
    beyond = _setpoint_rig(scene, legs=(Leg.inflate(3.0e-5), Leg.deflate(0.0)))
    _give(beyond, injected_m3=3.5e-5)
    beyond.run(beyond.wall[0] * 1e-9 + 3.5e-5 / beyond.pump.profile.flow_rate + 1.0)
    refused = beyond.pump.set_mode(beyond.wall[0], False)
    assert not refused.success and 'cannot start from' in refused.message
    assert beyond.pump.mode == SETPOINT
    # Stopped, it says to reset first.
    beyond.pump.stop(beyond.wall[0])
    assert not beyond.pump.set_mode(beyond.wall[0], True).success


# ------------------------------------------------------------------------- the PI on the rig

class ControlledRig:
    """Pump, actuator and a controller on one test clock, routed by the contract."""

    def __init__(self, scene, controller, **pump_settings) -> None:
        model = actuator_model(scene)
        self.actuator = actuator_core(scene, model)
        self.pump, rate_hz = pump_core(scene, model, feedback_clock=None, **pump_settings)
        self.period_ns = int(round(1e9 / rate_hz))
        self.now = 0
        self.router = Router({contract.PUMP: self.pump, contract.ACTUATOR: self.actuator,
                              contract.CONTROLLER: controller}, lambda: self.now)
        self.volumes: list[SegmentVolumes] = []
        self.notices: list[Notice] = []
        self._record(self.router.run(self.pump.begin(0)))
        self._record(self.router.run(self.pump.set_mode(0, True).outputs))
        # The actuator says its rest state, as its node does at start.
        self._record(self.router.run(self.actuator.announce(0)))

    def _record(self, outputs) -> None:
        self.volumes += [v for v in outputs if type(v) is SegmentVolumes]
        self.notices += [v for v in outputs if type(v) is Notice]

    def run(self, until_s: float) -> None:
        while self.now < until_s * 1e9:
            self.now += self.period_ns
            self._record(self.router.run(self.pump.tick(self.now)))


def test_the_example_pi_holds_5_kpa_on_the_paper_rig_within_1_percent_in_20_s():
    scene = load_scene('paper')
    controller = PressureHold(5.0e3)
    rig = ControlledRig(scene, controller)
    rig.run(20.0)
    late = [v.gauge_pa for v in rig.volumes if v.stamp_ns >= 20e9 - 1e9]
    assert late and max(abs(p - 5.0e3) for p in late) < 0.01 * 5.0e3
    # And it stays there: ten more seconds within the band.
    rig.run(30.0)
    held = [v.gauge_pa for v in rig.volumes if v.stamp_ns > 20e9]
    assert max(abs(p - 5.0e3) for p in held) < 0.01 * 5.0e3
    # The state is the actuator's own equilibrium at the injected volume the pump reached.
    emap = EquilibriumMap(scene.segments)
    expected = Tracker(emap).sweep(np.array([0.0, rig.pump.volume_m3])).pressure[-1]
    assert rig.volumes[-1].gauge_pa == pytest.approx(expected, rel=1e-9)
    assert rig.pump.setpoints_refused == 0 and rig.pump.state == RUNNING
    assert not [n for n in rig.notices if n.level == WARNING]


def test_a_target_beyond_the_relief_pressure_is_held_at_the_relief():
    scene = load_scene('paper')
    relief = 4.0e3
    rig = ControlledRig(scene, PressureHold(5.0e3), max_pressure_pa=relief)
    rig.run(20.0)
    assert (rig.pump.state, rig.pump.cause) == (STOPPED, 'over_pressure')
    pressures = [v.gauge_pa for v in rig.volumes]
    # Stopped at the first state over the relief: one pump period of flow past it, no more.
    over = [p for p in pressures if p > relief]
    assert len(over) >= 1 and max(over) < relief * 1.01
    # The syringe stays where it stopped, so the pressure stays at the relief.
    assert pressures[-1] == pytest.approx(max(over), rel=1e-12)
    stopped_at = rig.pump.volume_m3
    rig.run(25.0)
    assert rig.pump.volume_m3 == stopped_at


def test_the_pi_refuses_settings_outside_their_range():
    for settings in ({'gain_m3_per_s_per_pa': 0.0}, {'integral_time_s': -1.0},
                     {'max_flow_m3_per_s': math.nan}):
        with pytest.raises(ValueError, match=next(iter(settings))):
            PressureHold(5.0e3, **settings)
    with pytest.raises(ValueError, match='target_gauge_pa'):
        PressureHold(math.inf)


def test_the_pi_sends_nothing_for_garbage_or_stale_feedback():
    controller = PressureHold(5.0e3)
    names = ('bottom', 'top')
    first = controller.handle(SegmentVolumes(10, names, [1e-5, 1e-5], 100.0), 10)
    assert first and first[0].flow_m3_per_s > 0.0
    assert controller.handle(SegmentVolumes(5, names, [1e-5, 1e-5], 100.0), 11) == []
    said = controller.handle(SegmentVolumes(20, names, [1e-5, 1e-5], math.nan), 12)
    assert [type(v) for v in said] == [Notice]
    muted = PressureHold(5.0e3, active=False)
    assert muted.handle(SegmentVolumes(10, names, [1e-5, 1e-5], 100.0), 10) == []


def test_a_setpoint_message_that_is_not_one_is_refused_with_what_is_wrong():
    from sensor_msgs.msg import JointState

    from softseq_ros.wire.payloads import InputError, pump_setpoint

    good = pump_setpoint(JointState(name=['syringe'], velocity=[1e-7]))
    assert (good.kind, good.value) == ('flow', 1e-7)
    for msg, said in ((JointState(name=['piston'], velocity=[1e-7]), "names ['piston']"),
                      (JointState(name=['syringe']), 'position 0, velocity 0, effort 0'),
                      (JointState(name=['syringe'], position=[1e-6], velocity=[1e-7]),
                       'position 1, velocity 1, effort 0'),
                      (JointState(name=['syringe'], effort=[1.0, 2.0]), 'effort 2')):
        with pytest.raises(InputError, match=said.replace('[', r'\[').replace(']', r'\]')):
            pump_setpoint(msg)


def test_the_batch_runner_hosts_the_same_controller_and_records_its_setpoints(tmp_path):
    import softseq_ros
    from softseq_ros.bag.reader import read_bag

    result = softseq_ros.run('paper', tmp_path / 'held', start_time_ns=0,
                             controller=PressureHold(5.0e3), controlled_s=25.0)
    assert result.sim_duration_s == pytest.approx(25.0)
    assert result.pump_state == RUNNING and not result.warnings
    assert result.message_counts['/pump/setpoint'] > 1000
    gauges = [(m.log_time_ns, m.msg.effort[0])
              for m in read_bag(tmp_path / 'held', ['/actuator/volumes'])]
    late = [p for stamp, p in gauges if stamp >= 20e9]
    assert late and max(abs(p - 5.0e3) for p in late) < 0.01 * 5.0e3
    with pytest.raises(ValueError, match='go together'):
        softseq_ros.run('paper', tmp_path / 'x', controller=PressureHold(5.0e3))


def test_softseq_run_holds_a_pressure_with_the_example_controller(tmp_path, capsys):
    from softseq_ros.analysis.recording import load_recording
    from softseq_ros.cli import main

    out = tmp_path / 'held'
    assert main(['run', 'paper', '--hold-gauge-pa', '5000', '--hold-for-s', '25', '--out',
                 str(out), '--quiet', '--no-report']) == 0
    assert 'pump running' in capsys.readouterr().out
    recording = load_recording(out)
    late = recording.pressure[recording.state_time_s >= 20.0]
    assert late.size and np.max(np.abs(late - 5.0e3)) < 0.01 * 5.0e3
    for argv, said in ((['--hold-for-s', '25'], 'goes with --hold-gauge-pa'),
                       (['--hold-gauge-pa', '5000'], 'needs --hold-for-s'),
                       (['--hold-gauge-pa', 'nan', '--hold-for-s', '25'], 'finite'),
                       (['--hold-gauge-pa', '5000', '--hold-for-s', '-1'], '> 0')):
        assert main(['run', 'paper', '--out', str(tmp_path / 'x'), *argv]) == 2
        error = capsys.readouterr().err.strip().splitlines()
        assert len(error) == 1 and said in error[0]
        assert not (tmp_path / 'x').exists()
