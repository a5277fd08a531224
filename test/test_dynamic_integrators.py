"""
The network's integrators and its many-outputs call agree with what they stand in for.

``NetworkFlow.advance_through`` must give what one ``advance`` per output gives, to the bit;
the default integrator must give what scipy's Radau gives: to the bit for a state of several
entries (the same algorithm, the same LAPACK calls), and for a state of one (the port to plain
floats, whose steps drift from scipy's by round-off) within the tolerance over a whole run.
"""

import numpy as np
import pytest
from scipy.integrate import Radau

from softseq_ros.dynamic.flow import NetworkFlow
from softseq_ros.dynamic.integrators import LeanRadau, ScalarRadau, new_integrator
from softseq_ros.scene.loader import load_scene
from softseq_ros.scene.network import Fluid, NetworkSettings, Tube

ML = 1e-6
WATER = Fluid()


def network(count: int, rtol: float = 1e-6, inertance: bool = False) -> NetworkSettings:
    return NetworkSettings(WATER, None, tuple(Tube(0.01, 0.4e-3, inertance=inertance)
                                              for _ in range(count - 1)), rtol=rtol)


def one_by_one(flow: NetworkFlow, times: np.ndarray) -> np.ndarray:
    rows = []
    for t in times:
        flow.advance(float(t))
        rows.append(flow.y.copy())
    return np.array(rows)


@pytest.mark.parametrize('integrator', ['radau', 'scipy-radau'])
def test_many_outputs_at_once_are_the_outputs_one_by_one_to_the_bit(integrator):
    # Fig. 1 asymmetric through both snap-throughs, outputs at 2 Hz plus some on step ends
    # and repeated: the same states, steps, snaps and Reynolds numbers.
    segments = load_scene('fig1_asymmetric').segments
    times = np.sort(np.concatenate([np.arange(0.5, 900.0, 0.5), [0.0, 10.0, 10.0, 899.9]]))
    flows = []
    for _ in range(2):
        flow = NetworkFlow(segments, network(2, rtol=1e-4), integrator=integrator)
        flow.set_flow(0.05 * ML)
        flows.append(flow)
    expected = one_by_one(flows[0], times)
    got = flows[1].advance_through(times)
    assert np.array_equal(got, expected)
    assert flows[1].steps == flows[0].steps
    assert flows[1].peak_reynolds == flows[0].peak_reynolds
    snaps = flows[1].take_snaps()
    assert sum(snap.snap_through for snap in snaps) == 2 and snaps == flows[0].take_snaps()
    assert flows[1].t == flows[0].t and np.array_equal(flows[1].volumes(), flows[0].volumes())
    # And it goes on from there as advance does.
    later = np.arange(900.5, 1000.0, 0.5)
    assert np.array_equal(flows[1].advance_through(later), one_by_one(flows[0], later))


def test_for_several_states_the_default_is_scipys_radau_to_the_bit():
    # Three segments (two states) and, with inertance, four: scipy's steps, its numbers.
    segments = load_scene('three_segments').segments
    for inertance in (False, True):
        times = np.arange(1.0, 400.0, 1.0)
        runs = []
        for integrator in ('radau', 'scipy-radau'):
            flow = NetworkFlow(segments, network(3, rtol=1e-5, inertance=inertance),
                               integrator=integrator)
            flow.set_flow(0.05 * ML)
            runs.append((flow.advance_through(times), flow.steps))
        assert runs[0][0].shape[1] == (4 if inertance else 2)
        assert np.array_equal(runs[0][0], runs[1][0]) and runs[0][1] == runs[1][1]


def test_for_one_state_the_port_lands_where_scipys_radau_lands():
    # The paper pair: a whole run at the default tolerance with the port to plain floats
    # lands where scipy's Radau does, within the tolerance's reach.
    scene = load_scene('paper')
    times = np.arange(1.0, 1300.0, 1.0)
    ends = []
    for integrator in ('radau', 'scipy-radau'):
        run = NetworkFlow(scene.segments, network(2), integrator=integrator)
        run.set_flow(0.05 * ML)
        ends.append(run.states_volumes(run.advance_through(times), 0.05 * ML * times))
    assert np.max(np.abs(ends[0] - ends[1])) < 1e-5 * run.v_scale


def test_an_unknown_integrator_is_refused():
    with pytest.raises(ValueError, match='integrator must be one of radau, scipy-radau'):
        NetworkFlow(load_scene('paper').segments, network(2), integrator='rk4')


def test_the_default_ports_a_state_of_one_entry_to_floats_and_leaves_several_to_scipy():
    def rates(t, y):
        return -y

    def rate_of_one(t, v):
        return -v

    def made(method, y0):
        return new_integrator(method, rates, rate_of_one, 0.0, np.array(y0), 1.0, 1e-6,
                              np.full(len(y0), 1e-9))

    assert isinstance(made('radau', [1.0]), ScalarRadau)
    assert isinstance(made('radau', [1.0, 2.0]), LeanRadau)
    assert type(made('scipy-radau', [1.0])) is Radau
    with pytest.raises(ValueError, match='method must be one of radau, scipy-radau'):
        made('rk4', [1.0])
