"""Pump programme: durations and volumes against hand-computed values."""

import numpy as np
import pytest

from softseq_ros.scene.programme import Leg, PumpProfile

ML = 1e-6  # m^3 per mL


def paper_profile(hold_s: float = 10.0) -> PumpProfile:
    return PumpProfile(legs=(Leg.inflate(65 * ML), Leg.hold(hold_s), Leg.deflate(0.0)),
                       flow_rate=0.05 * ML)


def test_default_flow_rate_is_the_papers_pump():
    assert PumpProfile(legs=(Leg.inflate(1 * ML),)).flow_rate == pytest.approx(5e-8, rel=1e-15)


def test_paper_programme_duration_and_volumes():
    profile = paper_profile()
    # 65 mL at 0.05 mL/s is 1300 s each way, plus the 10 s hold.
    assert profile.duration() == pytest.approx(2610.0, rel=1e-12)
    times, volumes = profile.breakpoints()
    np.testing.assert_allclose(times, [0.0, 1300.0, 1310.0, 2610.0], rtol=1e-12)
    np.testing.assert_allclose(volumes, [0.0, 65 * ML, 65 * ML, 0.0], rtol=0, atol=1e-18)
    # 25 mL injected after 500 s; halfway down (1310 + 650 s) is 32.5 mL.
    assert profile.injected_at(500.0) == pytest.approx(25 * ML, rel=1e-12)
    assert profile.injected_at(1305.0) == pytest.approx(65 * ML, rel=1e-12)
    assert profile.injected_at(1960.0) == pytest.approx(32.5 * ML, rel=1e-12)


def test_injected_clamps_outside_the_programme():
    profile = PumpProfile(legs=(Leg.inflate(10 * ML),), start_injected=2 * ML)
    assert profile.injected_at(-5.0) == pytest.approx(2 * ML)
    assert profile.injected_at(1e6) == pytest.approx(10 * ML)
    assert profile.duration() == pytest.approx(8 * ML / 5e-8)


def test_cycles_repeat_the_legs():
    profile = PumpProfile(legs=(Leg.inflate(10 * ML), Leg.deflate(0.0)), flow_rate=1 * ML,
                          cycles=3)
    assert profile.duration() == pytest.approx(60.0)
    # Second cycle peak at 30 s, third cycle halfway up at 45 s.
    assert profile.injected_at(30.0) == pytest.approx(10 * ML)
    assert profile.injected_at(45.0) == pytest.approx(5 * ML)
    assert profile.max_injected() == pytest.approx(10 * ML)


def test_vectorised_equals_scalar():
    profile = paper_profile()
    t = np.linspace(-10.0, 2700.0, 1001).reshape(7, 143)
    vector = profile.injected_at(t)
    flows = profile.flow_at(t)
    assert vector.shape == t.shape and flows.shape == t.shape
    for ti, vi, fi in zip(t.ravel(), vector.ravel(), flows.ravel()):
        assert float(profile.injected_at(float(ti))) == vi
        assert float(profile.flow_at(float(ti))) == fi


def test_flow_sign_per_leg_and_zero_outside():
    profile = paper_profile()
    flow = 0.05 * ML
    assert profile.flow_at(-1.0) == 0.0
    assert profile.flow_at(0.0) == pytest.approx(flow)
    assert profile.flow_at(1299.0) == pytest.approx(flow)
    assert profile.flow_at(1300.0) == 0.0       # the hold starts here
    assert profile.flow_at(1400.0) == pytest.approx(-flow)
    assert profile.flow_at(2610.0) == 0.0
    # The flow integrates to the volume change (midpoint rule is exact for a step function).
    t = np.linspace(0.0, 2610.0, 26101)
    mid = 0.5 * (t[1:] + t[:-1])
    integral = np.cumsum(profile.flow_at(mid) * np.diff(t))
    np.testing.assert_allclose(integral, profile.injected_at(t[1:]), atol=1e-3 * ML)


def test_sample_includes_the_exact_end():
    profile = paper_profile(hold_s=10.03)
    t, u = profile.sample(50.0)
    assert t[0] == 0.0
    assert t[-1] == profile.duration()
    steps = np.diff(t)
    np.testing.assert_allclose(steps[:-1], 0.02, rtol=1e-9)
    assert 0.0 < steps[-1] <= 0.02
    np.testing.assert_allclose(u, profile.injected_at(t))


def test_sample_of_an_exact_multiple_has_no_sliver():
    t, _ = paper_profile().sample(10.0)
    assert t.size == 26101
    assert t[-1] == 2610.0
    np.testing.assert_allclose(np.diff(t), 0.1, rtol=1e-9)


@pytest.mark.parametrize('build, message', [
    (lambda: PumpProfile(legs=()), 'at least one leg'),
    (lambda: PumpProfile(legs=(Leg.inflate(1e-6),), flow_rate=-1e-8), 'flow_rate must be > 0'),
    (lambda: PumpProfile(legs=(Leg.inflate(1e-6),), flow_rate=0.0), 'flow_rate must be > 0'),
    (lambda: PumpProfile(legs=(Leg.inflate(1e-6),), cycles=0), 'cycles must be >= 1'),
    (lambda: PumpProfile(legs=(Leg.inflate(1e-6),), cycles=1.5), 'cycles must be an integer'),
    (lambda: PumpProfile(legs=(Leg.inflate(1e-6),), start_injected=-1e-6),
     'start_injected must be >= 0'),
    (lambda: PumpProfile(legs=(Leg.inflate(1e-6),), start_injected=2e-6),
     'cycle 1, legs[0]: inflate target'),
    (lambda: PumpProfile(legs=(Leg.deflate(1e-6),)), 'cycle 1, legs[0]: deflate target'),
    (lambda: PumpProfile(legs=(Leg.inflate(1e-6), Leg.hold(1.0)), cycles=2),
     'cycle 2, legs[0]: inflate target'),
    (lambda: Leg('pump', to_m3=1e-6), 'leg action must be one of'),
    (lambda: Leg.hold(0.0), 'hold duration_s must be > 0'),
    (lambda: Leg('hold', to_m3=1e-6), 'takes duration_s, not to_m3'),
    (lambda: Leg('inflate', duration_s=1.0), 'takes to_m3, not duration_s'),
    (lambda: Leg.inflate(float('nan')), 'must be finite'),
    (lambda: Leg.deflate(-1e-6), 'must be >= 0'),
    (lambda: PumpProfile(legs=(Leg.inflate(1e-6),)).sample(0.0), 'rate_hz must be > 0'),
    (lambda: Leg.inflate(1e-6, flow_rate=0.0), 'inflate flow_rate must be > 0'),
    (lambda: Leg.deflate(0.0, flow_rate=-1e-8), 'deflate flow_rate must be > 0'),
    (lambda: Leg.inflate(1e-6, flow_rate=float('inf')), 'must be finite'),
    (lambda: Leg('hold', duration_s=1.0, flow_rate=1e-8), 'takes no flow_rate'),
])
def test_invalid_programmes_are_refused(build, message):
    with pytest.raises(ValueError, match=message.replace('(', r'\(').replace('[', r'\[')):
        build()


def test_each_leg_moves_at_its_own_rate_and_the_others_at_the_pumps():
    # Fill fast (1 mL/s to 20 mL), step slowly through the snaps (0.01 mL/s to 30 mL), hold
    # 5 s, and empty at the pump's 0.05 mL/s: 20 s, 1000 s, 5 s and 600 s by hand.
    profile = PumpProfile(legs=(Leg.inflate(20 * ML, flow_rate=1 * ML),
                                Leg.inflate(30 * ML, flow_rate=0.01 * ML), Leg.hold(5.0),
                                Leg.deflate(0.0)), flow_rate=0.05 * ML)
    times, volumes = profile.breakpoints()
    np.testing.assert_allclose(times, [0.0, 20.0, 1020.0, 1025.0, 1625.0], rtol=1e-13)
    np.testing.assert_allclose(volumes, [0.0, 20 * ML, 30 * ML, 30 * ML, 0.0], rtol=1e-15)
    probes = np.array([10.0, 520.0, 1022.0, 1325.0])
    np.testing.assert_allclose(profile.injected_at(probes), [10 * ML, 25 * ML, 30 * ML, 15 * ML],
                               rtol=1e-12)
    flows = [1 * ML, 0.01 * ML, 0.0, -0.05 * ML]
    assert profile.flow_at(probes).tolist() == flows
    assert profile.commands_at(probes)[1].tolist() == flows
    assert [profile.command_at(float(t))[1] for t in probes] == flows
    # Cycled, the legs keep their rates.
    twice = PumpProfile(legs=profile.legs, flow_rate=0.05 * ML, cycles=2)
    assert twice.duration() == pytest.approx(2 * 1625.0, rel=1e-13)
    assert twice.flow_at(1625.0 + 10.0) == pytest.approx(1 * ML, rel=1e-15)


def test_command_at_equals_the_vectorised_volume_and_flow():
    profile = PumpProfile(legs=(Leg.inflate(6.5e-5), Leg.hold(10.0), Leg.deflate(1.0e-5)),
                          flow_rate=5.0e-8, cycles=2, start_injected=0.0)
    times, _ = profile.breakpoints()
    probes = np.concatenate([[-1.0, 0.0, profile.duration() + 5.0], times,
                             np.linspace(-3.0, profile.duration() + 3.0, 2001)])
    for t in probes:
        volume, flow = profile.command_at(float(t))
        assert volume == pytest.approx(float(profile.injected_at(t)), rel=1e-14, abs=1e-20)
        assert flow == float(profile.flow_at(t))
