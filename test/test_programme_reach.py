"""A pump programme is checked against what the segments can follow before anything runs."""

import subprocess
import sys

import numpy as np
import pytest
from scenes import write_scene
import yaml

from softseq_ros.quasistatic.equilibrium import EquilibriumMap, Tracker
from softseq_ros.quasistatic.reach import check_reach
from softseq_ros.rig.build import SettingError, pump_core
from softseq_ros.rig.model import QuasiStaticModel
from softseq_ros.scene.loader import load_scene
from softseq_ros.scene.programme import Leg, ProgrammeError, PumpProfile
from softseq_ros.segments.models import LinearSegment

# Two linear segments: p = k (v - rest). The stiffer-at-its-end one, the top, is full first:
# its pressure at max volume is 2e8 * 3e-5 = 6 kPa, the bottom's 1e8 * 8e-5 = 8 kPa.
K = (1.0e8, 2.0e8)
REST = (1.0e-5, 2.0e-5)
FULL = (9.0e-5, 5.0e-5)


def linear_pair():
    return [LinearSegment('bottom', 0.1, REST[0], K[0], FULL[0]),
            LinearSegment('top', 0.1, REST[1], K[1], FULL[1])]


def test_the_domain_of_two_linear_segments_ends_where_the_closed_form_puts_it():
    emap = EquilibriumMap(linear_pair())
    p_end = min(k * (full - rest) for k, rest, full in zip(K, REST, FULL))
    end = sum(p_end / k for k in K)          # injected when the first segment is full
    capacity = sum(full - rest for rest, full in zip(REST, FULL))
    assert end < capacity
    check_reach(PumpProfile(legs=(Leg.inflate(0.999 * end), Leg.deflate(0.0))), emap,
                ('bottom', 'top'))
    target = 0.5 * (end + capacity)          # what the segments hold, but not in equilibrium
    with pytest.raises(ProgrammeError) as caught:
        check_reach(PumpProfile(legs=(Leg.hold(1.0), Leg.inflate(target))), emap,
                    ('bottom', 'top'), prefix='pump.')
    err = caught.value
    assert err.key == 'pump.legs[1].inflate_to_m3'
    assert err.reason.startswith(f"{target:g} m^3 is beyond the equilibrium's domain: segment "
                                 'top reaches the end of its curve')
    assert f'at {end:.6g} m^3 injected' in err.reason


def test_every_cycle_is_walked_and_a_million_cycles_cost_two():
    emap = EquilibriumMap(linear_pair())
    legs = (Leg.inflate(2.0e-5), Leg.deflate(1.0e-5))
    check_reach(PumpProfile(legs=legs, cycles=1_000_000), emap, ('bottom', 'top'))
    # Starting beyond the domain is named as the start volume.
    with pytest.raises(ProgrammeError, match=r'^start_injected_m3: 0\.0001 m\^3 is beyond'):
        check_reach(PumpProfile(legs=(Leg.deflate(0.0),), start_injected=1.0e-4), emap,
                    ('bottom', 'top'))


def _beyond_the_domain(tmp_path) -> tuple[str, float, str]:
    """FAST_SCENE with a leg between the domain's end and what the segments hold."""
    scene = load_scene(write_scene(tmp_path))
    emap = EquilibriumMap(scene.segments)
    end, capacity = emap.injected_range[1], scene.capacity
    assert end < 0.99 * capacity
    # The segment at the end of its range at the domain's end, from the solver's own state.
    state = Tracker(emap).sweep(np.array([end])).volumes[0]
    full = np.array([s.max_volume for s in scene.segments])
    first = scene.segment_names[int(np.argmin(np.abs(full - state) / full))]
    target = float(f'{0.5 * (end + capacity):.4g}')
    path = write_scene(tmp_path, legs=[{'inflate_to_m3': target}, {'deflate_to_m3': 0.0}])
    return path, target, first


@pytest.mark.parametrize('command', [['run', '--quiet', '--no-report', '--out', 'BAG'],
                                     ['classify'], ['solve', '--out', 'OUT']])
def test_run_classify_and_solve_refuse_it_with_the_same_line(tmp_path, command):
    path, target, first = _beyond_the_domain(tmp_path)
    bag, out = tmp_path / 'bag', tmp_path / 'path.csv'
    args = [str(bag) if a == 'BAG' else str(out) if a == 'OUT' else a for a in command]
    result = subprocess.run([sys.executable, '-m', 'softseq_ros.cli', command[0], path,
                             *args[1:]], capture_output=True, text=True, timeout=120,
                            stdin=subprocess.DEVNULL)
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith(
        f'softseq {command[0]}: error: {path}: pump.legs[0].inflate_to_m3: {target:g} m^3 is '
        f"beyond the equilibrium's domain: segment {first} reaches the end of its curve"), \
        lines[0]
    # Refused before it started: nothing written.
    assert not bag.exists() and not out.exists()


def test_the_pump_takes_its_limits_from_the_segments(tmp_path):
    scene = load_scene(write_scene(tmp_path))
    emap = EquilibriumMap(scene.segments)
    model = QuasiStaticModel(emap, scene.segment_names)
    core, _ = pump_core(scene, model)
    # The end stop is where the inflation ends, not the sum of what the segments hold.
    assert core.max_injected_m3 == pytest.approx(emap.injected_range[1], rel=1e-12)
    assert core.max_injected_m3 < scene.capacity
    path, target, first = _beyond_the_domain(tmp_path)
    with pytest.raises(SettingError, match=r'^legs\[0\]\.inflate_to_m3: .* segment '
                                           f'{first} reaches'):
        pump_core(scene, model, legs=(Leg.inflate(target), Leg.deflate(0.0)))
    with pytest.raises(SettingError, match=r'^legs\[0\]\.inflate_to_m3: .* exceeds what the '
                                           r'segments hold'):
        pump_core(scene, legs=(Leg.inflate(2 * scene.capacity),))


def test_the_pump_node_refuses_legs_beyond_the_domain_at_start(tmp_path, ros_env):
    _, target, _ = _beyond_the_domain(tmp_path)
    (tmp_path / 'good').mkdir()
    fast = write_scene(tmp_path / 'good')
    legs = yaml.safe_dump([{'inflate_to_m3': target}], default_flow_style=True).strip()
    result = subprocess.run(
        [sys.executable, '-m', 'softseq_ros.nodes.syringe_pump', '--ros-args',
         '-p', f'scene:={fast}', '-p', f"legs:='{legs}'"],
        capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL, env=ros_env)
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith(f'syringe_pump: error: legs[0].inflate_to_m3: {target:g} m^3 is '
                               "beyond the equilibrium's domain"), lines[0]
