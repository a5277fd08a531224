"""
A ``profile`` leg: the pump follows a CSV of time against injected volume, linearly between its
rows, in the batch rig, in solve and in the dynamic network's schedule alike.
"""

from pathlib import Path

import numpy as np
import pytest
from scenes import shipped_scene_with

import softseq_ros
from softseq_ros.analysis.recording import load_recording
from softseq_ros.dynamic.path import programme_schedule
from softseq_ros.scene.loader import load_scene
from softseq_ros.scene.programme import Leg, PumpProfile
from softseq_ros.scene.validation import SceneError

# A fast fill to 20 mL in 2 s, a hold of 8 s, 10 mL more over 50 s.
ROWS = [(0.0, 0.0), (2.0, 2.0e-5), (10.0, 2.0e-5), (60.0, 3.0e-5)]


def profile_scene(folder: Path, rows=ROWS, legs=None, network: bool = False) -> Path:
    (folder / 'fill.csv').write_text(
        '# a planned fill\ntime_s,injected_m3\n' + ''.join(f'{t!r},{v!r}\n' for t, v in rows))
    channels = {'network': {'channels': [{'length_m': 0.01, 'radius_m': 5e-4}]}} if network \
        else {}
    return shipped_scene_with(
        folder, 'fig1_asymmetric.yaml', 'profile.yaml',
        pump={'flow_rate_m3_per_s': 2.0e-6, 'rate_hz': 10,
              'legs': legs or [{'profile': 'fill.csv'}, {'deflate_to_m3': 0.0}]},
        camera={'rate_hz': 1}, **channels)


def test_a_profile_leg_is_followed_linearly_between_its_rows():
    times, volumes = zip(*ROWS)
    profile = PumpProfile(legs=(Leg.inflate(1.0e-5), Leg.profile(times, np.add(volumes, 1e-5)),
                                Leg.deflate(0.0)), flow_rate=1.0e-6)
    # 10 s to 10 mL at the pump's rate, then the profile's rows from there, then 30 s back.
    t, v = profile.breakpoints()
    np.testing.assert_allclose(t, [0.0, 10.0, 12.0, 20.0, 70.0, 110.0], rtol=1e-14)
    np.testing.assert_allclose(v, [0.0, 1e-5, 3e-5, 3e-5, 4e-5, 0.0], rtol=1e-14)
    probes = np.array([11.0, 15.0, 45.0])
    np.testing.assert_allclose(profile.injected_at(probes), [2e-5, 3e-5, 3.5e-5], rtol=1e-14)
    assert profile.flow_at(probes).tolist() == pytest.approx([1e-5, 0.0, 2e-7], rel=1e-12)
    assert [profile.command_at(float(x))[1] for x in probes] == profile.flow_at(probes).tolist()


def test_the_batch_rig_solve_and_the_network_follow_a_profile_file(tmp_path):
    path = profile_scene(tmp_path)
    scene = load_scene(path)
    assert scene.pump.profile.duration() == pytest.approx(60.0 + 15.0, rel=1e-14)
    recording = load_recording(softseq_ros.run(path, tmp_path / 'bag').bag)
    t0 = recording.pump_time_s[0]
    np.testing.assert_allclose(recording.pump_injected,
                               scene.pump.profile.injected_at(recording.pump_time_s - t0),
                               rtol=0, atol=1e-12 * scene.capacity)
    solved = softseq_ros.solve(path)
    assert solved.injected.max() == pytest.approx(3.0e-5, rel=1e-14)
    dynamic = load_scene(profile_scene(tmp_path, network=True))
    schedule, _ = programme_schedule(dynamic.pump.profile)
    np.testing.assert_allclose(schedule.flows, [1e-5, 0.0, 2e-7, -2e-6], rtol=1e-12)


@pytest.mark.parametrize('rows, legs, key, words', [
    ([(0.0, 0.0), (2.0, 1e-5), (2.0, 2e-5)], None, 'pump.legs[0].profile',
     'time_s in data row 3: 2 s does not come after the row before'),
    ([(1.0, 0.0), (2.0, 1e-5)], None, 'pump.legs[0].profile', 'time_s starts at 0 s'),
    ([(0.0, 0.0), (2.0, -1e-5)], None, 'pump.legs[0].profile', 'injected_m3 must be >= 0'),
    ([(0.0, 0.0)], None, 'pump.legs[0].profile', 'at least 2 rows'),
    (ROWS, [{'inflate_to_m3': 5e-6}, {'profile': 'fill.csv'}], 'pump.legs[1].profile',
     'the profile starts at 0 m^3, not at the injected volume the leg starts from (5e-06 m^3)'),
    (ROWS, [{'profile': 'missing.csv'}], 'pump.legs[0].profile', 'missing.csv: cannot read'),
    (ROWS, [{'profile': 'fill.csv', 'flow_rate_m3_per_s': 1e-6}],
     'pump.legs[0].flow_rate_m3_per_s', 'moves at the rates of its own rows'),
    ([(0.0, 0.0), (2.0, 1.0)], None, 'pump.legs[0].profile', 'exceeds what the segments hold'),
], ids=['time_repeated', 'not_from_0_s', 'negative_volume', 'one_row', 'not_continuous',
        'missing_file', 'a_rate_too', 'beyond_capacity'])
def test_a_bad_profile_is_refused_in_one_line_naming_the_leg(tmp_path, rows, legs, key, words):
    path = profile_scene(tmp_path, rows, legs)
    with pytest.raises(SceneError) as caught:
        load_scene(path)
    message = str(caught.value)
    assert '\n' not in message and f'{path}: {key}: ' in message and words in message, message


def test_a_programme_too_long_to_hold_is_refused_before_it_is_built(tmp_path):
    # A profile of a thousand rows repeated 100,000 times took 49 s and 12.6 GB to load, and a
    # million cycles (which pump.cycles takes) would exhaust the memory: refused at once.
    from softseq_ros.scene.programme import MAX_BREAKPOINTS
    rows = [(float(t), 1e-8 * t) for t in range(1000)]
    path = profile_scene(tmp_path, rows)
    text = path.read_text().replace('rate_hz: 10', 'rate_hz: 10\n  cycles: 100000')
    path.write_text(text)
    with pytest.raises(SceneError) as caught:
        load_scene(path)
    message = str(caught.value)
    assert f'{path}: pump.cycles: 100000 cycles of 1000 breakpoints each' in message, message
    assert f'{MAX_BREAKPOINTS:.0e}' in message
    # The programme itself refuses it too, whoever builds it (a pump node's parameters).
    leg = Leg.profile([r[0] for r in rows], [r[1] for r in rows])
    with pytest.raises(ValueError, match='^cycles: 100000 cycles of 1000 breakpoints'):
        PumpProfile(legs=(leg, Leg.deflate(0.0)), cycles=100000)
