"""
Every exchange of fluid between the segments is one event, whatever its speed, ringing included.

Each case is checked against the volumes' own exchange episodes, computed here from the
recorded volumes alone: between two samples the fluid that moved between the segments beyond
the pump's push is half of sum_i |dv_i| less |du| (positive exactly where some segment moved
against the pump), and an episode of the volumes is a run of samples where it is positive.
"""

import numpy as np
import pytest

from softseq_ros.analysis.rates import programme_times, scene_at
from softseq_ros.dynamic.flow import NetworkFlow
from softseq_ros.dynamic.path import programme_path
from softseq_ros.scene.loader import load_scene
from softseq_ros.scene.network import Fluid, NetworkSettings, Tube

ML = 1e-6


def volume_episodes(time_s, injected, volumes, least: float) -> list[tuple[float, float, float]]:
    """(start, end [s], fluid moved [m^3]) of each run of samples where fluid was exchanged."""
    moved = 0.5 * np.maximum(np.abs(np.diff(volumes, axis=0)).sum(axis=1)
                             - np.abs(np.diff(injected)), 0.0)
    episodes, run = [], None
    for k, fluid in enumerate(moved.tolist()):
        if fluid > least:
            run = [time_s[k], time_s[k + 1], fluid] if run is None else \
                [run[0], time_s[k + 1], run[2] + fluid]
        elif run is not None:
            episodes.append(tuple(run))
            run = None
    if run is not None:
        episodes.append(tuple(run))
    return episodes


def test_a_slow_exchange_through_a_narrow_channel_is_one_event_with_the_volumes_fluid():
    # The rate_inversion pair pumped at 0.03 mL/s through a 0.2 mm channel: the base runs
    # ahead past its peak, and the tip then draws about 9 mL from it over some 14 minutes,
    # never faster than the pump (before, a snap had to outrun the pump fivefold: no event).
    scene = scene_at(load_scene('rate_inversion'), 3.0e-8, 0.2e-3)
    profile = scene.pump.profile
    times = programme_times(profile, 6000)
    path = programme_path(scene.segments, scene.network, profile, times=times,
                          line=scene.supply)
    exchanges = path.snaps
    # The volumes' own exchanges (a sample's round-off moves femtolitres, an exchange uL).
    episodes = volume_episodes(path.time_s, path.injected, path.volumes, 1e-12)
    big = [e for e in episodes if e[2] > 0.01 * ML]
    slow = max(big, key=lambda e: e[2])
    assert 5.0 * ML < slow[2] and slow[1] - slow[0] > 600.0
    # Its one event: the base gives, the tip takes, the fluid the volumes moved.
    (event,) = [e for e in exchanges if e.start_s < slow[1] and e.end_s > slow[0]]
    assert event.giving() == [0] and event.taking() == [1]
    assert event.start_s == pytest.approx(slow[0], abs=2.0)
    assert event.end_s == pytest.approx(slow[1], abs=10.0)
    assert event.fluid_moved_m3 == pytest.approx(slow[2], rel=0.01)
    assert event.peak_exchange_m3_per_s < 5.0 * 3.0e-8   # slower than the old threshold
    assert 0.0 < event.duration_s < event.end_s - event.start_s
    # Its start, fluid moved, duration and peak are said; and every exchange the volumes show
    # (more than 10 uL) is one event, and no event is anything else.
    for episode in big:
        inside = [e for e in exchanges if e.start_s < episode[1] and e.end_s > episode[0]]
        assert len(inside) == 1, (episode, inside)
        assert inside[0].fluid_moved_m3 == pytest.approx(episode[2], rel=0.02)
    assert len(exchanges) == len(big)


def test_a_ringing_chain_gives_one_event_per_exchange_not_one_per_swing():
    # The Fig. 1 pair through a 50 mm channel of 1 mm radius with its inertia, at 0.05 mL/s:
    # after the first snap the channel's flow rings, swinging through the pump's own range
    # (fluid back and forth between the segments). Before, each swing larger than five times
    # the pump's flow was a snap-through of its own (four events for two snaps).
    segments = load_scene('fig1_asymmetric').segments
    tube = Tube(0.05, 1.0e-3, inertance=True)
    flow_rate = 5.0e-8
    flow = NetworkFlow(segments, NetworkSettings(Fluid(), None, (tube,)))
    flow.set_flow(flow_rate)
    times = np.arange(0.0, 1000.0, 0.01)
    states = flow.advance_through(times)
    injected, volumes, _, _ = flow.read_states(times, states)
    exchanges = flow.take_snaps()
    # The volumes ring: several exchanges of the volumes' own (swings, fluid going back) after
    # the first snap starts, where the fluid moved most.
    episodes = volume_episodes(times, injected, volumes, 1e-13)
    snap_start = max(episodes, key=lambda e: e[2])[0]
    swings = [e for e in episodes if snap_start <= e[0] < snap_start + 30.0]
    assert len(swings) >= 3, swings
    directions = set()
    for start, end, _ in swings:
        rows = (times >= start) & (times <= end)
        directions.add(int(np.sign(volumes[rows][-1, 0] - volumes[rows][0, 0])))
    assert directions == {-1, 1}   # the bottom fills, gives back, fills: it rings
    # Every exchange of the volumes (10 uL or more: ten times the tolerance, F, of 1 uL; a
    # ring's last swing, at F, can fall off its end) overlaps one event, the swings the first
    # snap's, with the fluid the volumes moved in them all.
    (first,) = [e for e in exchanges if e.start_s - 0.02 <= snap_start <= e.end_s]
    for start, end, _ in [e for e in episodes if e[2] > 0.01 * ML]:
        assert len([e for e in exchanges if e.start_s - 0.02 <= end and start <= e.end_s + 0.02
                    ]) == 1, (start, end)
    inside = [e for e in swings if e[1] <= first.end_s + 0.02]
    assert len(inside) >= 3
    assert first.fluid_moved_m3 == pytest.approx(sum(e[2] for e in inside), rel=0.01)
    # Three events: the two snap-throughs, and an exchange without instability before them:
    # past the bottom's peak (2.6 mL) it gives the top some fluid on the stable branch.
    assert len(exchanges) == 3
    assert [e.snap_through for e in exchanges] == [False, True, True]
    assert exchanges[0].end_s < first.start_s and exchanges[0].giving() == [0]
    assert first is exchanges[1]


def test_an_exchange_still_under_way_when_the_path_ends_is_reported_cut_short():
    # The same slow exchange, the path's samples ending halfway through it: the tip is still
    # drawing fluid from the base at the last sample. Before, that exchange was never
    # reported (an episode was said only once it had run its course).
    scene = scene_at(load_scene('rate_inversion'), 3.0e-8, 0.2e-3)
    profile = scene.pump.profile
    times = programme_times(profile, 6000)
    whole = programme_path(scene.segments, scene.network, profile, times=times,
                           line=scene.supply)
    slow = max(whole.snaps, key=lambda e: e.fluid_moved_m3)
    cut_at = 0.5 * (slow.start_s + slow.end_s)
    path = programme_path(scene.segments, scene.network, profile,
                          times=times[times <= cut_at], line=scene.supply)
    last = path.time_s[-1]
    *before, cut = path.snaps
    # Those that ended before the cut are the whole path's, and none of them is cut short.
    ended = [e for e in whole.snaps if e.end_s < last]
    assert len(before) == len(ended) >= 1
    assert [e.fluid_moved_m3 for e in before] == pytest.approx(
        [e.fluid_moved_m3 for e in ended], rel=1e-9)
    assert not any(e.cut_short for e in before) and not any(e.cut_short for e in whole.snaps)
    # The cut one: where the whole one starts, ending at the last sample, with the fluid the
    # volumes moved up to there (less than the whole exchange's), its own end state.
    assert cut.cut_short
    assert cut.start_s == pytest.approx(slow.start_s, abs=1e-6 * last)
    assert cut.end_s == pytest.approx(last, rel=1e-12)
    (episode,) = [e for e in volume_episodes(path.time_s, path.injected, path.volumes, 1e-12)
                  if e[1] > cut.start_s and e[2] > 0.01 * ML]
    assert episode[1] == last
    assert cut.fluid_moved_m3 == pytest.approx(episode[2], rel=0.01)
    assert cut.fluid_moved_m3 < 0.9 * slow.fluid_moved_m3
    assert cut.to_volumes == pytest.approx(path.volumes[-1].tolist(), rel=1e-6)
    assert cut.giving() == [0] and cut.taking() == [1]
