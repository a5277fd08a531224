"""
A quick part of the landing sweep (bench/bench_landing_sweep.py): every snap of a few random
sets of stepped and smooth Gent tables lands on balanced pressures at a stable or neutral
state, conserves the volume and releases energy.

The full sweep (70 sets) runs as the benchmark; these sets are among them, picked to include
identical tables in 10 Pa and 100 Pa steps, and take a few seconds together.
"""

from pathlib import Path
import sys

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'bench'))

import bench_landing_sweep as sweep  # noqa: E402


def test_the_sweep_generates_what_it_promises():
    sets = sweep.generate_sets()
    assert len(sets) == 70
    assert sum(s.identical for s in sets) == 28
    assert {len(s.tables) for s in sets} == {2, 3, 4}
    assert {s.step for s in sets} == {0.0, 10.0, 100.0}
    rows = [t.rows for s in sets for t in s.tables]
    assert min(rows) >= 40 and max(rows) <= 600
    # Seeded: the same sets every time.
    assert sweep.generate_sets() == sets
    quick = [sets[i] for i in sweep.QUICK]
    assert any(s.identical and s.step and len(s.tables) >= 3 for s in quick)


def test_the_checker_catches_a_snap_that_stores_energy():
    # A snap that lands uphill, unbalanced and on two falling segments: every check says so.
    segments = sweep.segments_of(sweep.generate_sets()[7])

    class Snap:
        source, target, direction = 0, 1, 'inflation'
        volumes_before = (segments[0].max_volume * 0.5, segments[1].rest_volume * 1.5)
        volumes_after = (segments[0].max_volume * 0.4, segments[1].rest_volume * 1.5
                         + segments[0].max_volume * 0.1)
        pressure_before = 1e4
        energy_released = -1e-3

    class Graph:
        def snaps(self):
            return [Snap()]

    faults = sweep.snap_faults(segments, Graph())
    assert any('releases' in f for f in faults)
    assert any('unbalanced' in f for f in faults)


@pytest.mark.parametrize('index', sweep.QUICK)
def test_every_snap_of_a_quick_sweep_set_lands(index):
    sweep_set = sweep.generate_sets()[index]
    result = sweep.run_set(sweep_set)
    assert result['faults'] == [], f'set {index} ({sweep_set.describe()}): {result["faults"]}'
    assert result['snaps'] > 0


def test_a_stable_stretch_between_two_unstable_samples_is_assembled_and_landed_on():
    # Set 40: two different tables in 10 Pa steps. Near 10 kPa one segment rises and the other
    # falls with stiffnesses that nearly cancel, and the falling table's stiffness, a
    # quadratic between two of its rows, turns between two samples that are both unstable:
    # stable from 10000.3 to 10005.8 Pa, between samples at 10000.0 and 10005.9 Pa. A snap's
    # flow came to rest there, where the map had no branch. The assembly now looks at every
    # turn of a table's stiffness between two unstable samples, and the stretch is a branch.
    from softseq_ros.quasistatic.equilibrium import EquilibriumMap

    sweep_set = sweep.generate_sets()[40]
    emap = EquilibriumMap(sweep.segments_of(sweep_set))
    assert any(10000.0 < b.pressure.min() and b.pressure.max() < 10006.0
               and b.pressure.max() - b.pressure.min() > 5.0 for b in emap.branches)
    result = sweep.run_set(sweep_set)
    assert result['faults'] == [] and result['snaps'] > 0
