"""
The transition graph (softseq_ros.quasistatic.graph) against answers known without it.

Two identical neo-Hookean balloons make a pitchfork at their common peak (v = sqrt(7) v0 each);
three Gent balloons with nested hysteresis loops pass their peaks in the order of their peak
pressures and have branches only a history with reversals reaches; the Fig. 1 asymmetric scene
has the two hysteresis loops its file documents, each a 2-cycle of snaps, with energies checked
against the Gent law's closed-form energy. Every proposed history is run through the solver.
"""

import csv
import json
import math

from figure_checks import capture_figures, laid_out, share_of, titles, whole
import numpy as np
import pytest
import yaml

import softseq_ros
from softseq_ros.analysis.figures import STYLE
from softseq_ros.analysis.recording import load_recording
from softseq_ros.analysis.report import recording_metrics, summary_text
from softseq_ros.cli import main
from softseq_ros.quasistatic.assembly import Assembly
from softseq_ros.quasistatic.equilibrium import EquilibriumMap, Tracker, inflate_and_deflate
from softseq_ros.quasistatic.graph import (
    DEFLATION,
    END,
    INFLATION,
    JOIN,
    SNAP,
    piece_labels,
    stored_energy,
    transition_graph,
)
from softseq_ros.quasistatic.landing import FlowLandings, RedistributionFlow
from softseq_ros.quasistatic.numerics import SegmentNumerics
from softseq_ros.quasistatic.solve import equilibrium_map, scene_map
from softseq_ros.scene.loader import load_scene, scene_from_dict
from softseq_ros.segments.materials import NeoHookean
from softseq_ros.segments.models import BalloonSegment, TabulatedSegment

ML = 1e-6
R = 0.006
V0 = 4 / 3 * math.pi * R**3

@pytest.fixture(scope='module')
def nested():
    """
    The shipped three_nested_loops scene's file, map and graph (one assembly for the module).

    Three Gent balloons, base to tip from the highest peak and lowest valley to the lowest
    peak and highest valley: inflation passes the peaks tip, middle, base, and a history that
    turns between the middle's and the base's snaps finds states the full inflation and
    deflation never visit.
    """
    scene = load_scene('three_nested_loops')
    path = scene.path
    emap = scene_map(scene)
    return path, emap, transition_graph(emap)


@pytest.fixture(scope='module')
def asymmetric():
    emap = equilibrium_map(load_scene('fig1_asymmetric').segments)
    return emap, transition_graph(emap)


def run_history(emap, history):
    """Follow the turning volumes on the solver; the tracker and the snaps on the way."""
    tracker = Tracker(emap)
    events = []
    for volume in history[1:]:
        events.extend(tracker.move(volume))
    return tracker, events


def inflation_walk(graph):
    """The branches a monotone inflation from rest visits, in order, with the ends between."""
    branch, walk = graph.start_branch, []
    while True:
        end = graph.end(branch, INFLATION)
        walk.append((branch, end))
        if end.kind == END:
            return walk
        branch = end.target


# --------------------------------------------------------------------------- pitchfork

def test_two_identical_balloons_make_a_pitchfork_at_their_common_peak():
    segments = [BalloonSegment(n, 0.1, NeoHookean(60e3), R, 0.6e-3, 3.0) for n in ('base', 'tip')]
    emap = EquilibriumMap(segments)
    graph = transition_graph(emap)
    by_label = {b.pieces: b for b in graph.branches}
    assert set(by_label) == {('rising', 'rising'), ('falling', 'rising'), ('rising', 'falling')}
    symmetric = by_label[('rising', 'rising')]
    # Both at the neo-Hookean peak, v = sqrt(7) v0: the symmetric branch ends there.
    peak = 2 * (math.sqrt(7) - 1) * V0
    assert symmetric.injected_lo == pytest.approx(0.0, abs=1e-15)
    assert symmetric.injected_hi == pytest.approx(peak, rel=1e-6)
    for mirror in (('falling', 'rising'), ('rising', 'falling')):
        assert by_label[mirror].injected_lo == pytest.approx(peak, rel=1e-6)
    # Past the peak the symmetric state is unstable (both stiffnesses negative: the energy's
    # Hessian on v1 + v2 = V, k1 + k2, is negative), and no stable branch holds it.
    past = np.linspace(1.01, 2.5, 50) * math.sqrt(7) * V0
    assert np.all(2 * segments[0].stiffness(past) < 0.0)
    for branch in emap.branches:
        equal = np.abs(branch.volumes[:, 0] - branch.volumes[:, 1]) < 1e-6 * V0
        assert not np.any(equal & (branch.volumes[:, 0] > math.sqrt(7) * V0 * 1.001))
    # Inflation goes on smoothly (a join, no snap) onto the branch where the base takes more.
    up = graph.end(symmetric.index, INFLATION)
    assert (up.kind, graph.branches[up.target].pieces) == (JOIN, ('falling', 'rising'))
    assert up.fluid_moved == 0.0 and up.energy_released == 0.0
    assert graph.snaps() == []
    # Its mirror shares every volume, but no history from rest reaches it: both mirrors end
    # at the domain above and join the symmetric branch below, which always continues on the
    # base's side, and no snap lands anywhere.
    other = by_label[('rising', 'falling')]
    assert not other.default_path
    assert graph.end(other.index, DEFLATION).target == symmetric.index
    reach = graph.history_to(other.index)
    assert reach.reversals is None and reach.history == ()
    assert 'none is on it' in reach.reason
    assert graph.min_reversals() == {symmetric.index: 0, up.target: 0, other.index: None}


def quantised_gent_table(name: str, rows: int, shear_modulus: float = 60e3,
                         gent_limit: float = 30.0, wall: float = 0.6e-3,
                         max_stretch: float = 4.0, step: float = 100.0) -> TabulatedSegment:
    """
    A peaked Gent balloon (by default 60 kPa, Jm 30, 0.6 mm wall, stretched to 4) as a table
    with its pressures in 1 mbar (or in ``step`` Pa).

    The thin-walled sphere's closed form, p = 2 mu H / R (1/l - 1/l^7) / (1 - (2 l^2 + l^-4 - 3)
    / Jm), at ``rows`` stretches l from 1 to ``max_stretch``, each pressure rounded to 100 Pa
    as a logger of 1 mbar resolution writes it: near the peak and the valley several rows in a
    row read the same pressure, at the same pressures in identical tables.
    """
    stretch = np.linspace(1.0, max_stretch, rows)
    pressure = (2 * shear_modulus * wall / R * (1 / stretch - stretch**-7)
                / (1 - (2 * stretch**2 + stretch**-4 - 3) / gent_limit))
    return TabulatedSegment(name, 0.074, V0 * stretch**3, np.round(pressure / step) * step,
                            np.zeros(rows))


def assert_snaps_land_on_balanced_stable_states(segments, graph, base_takes_more=True):
    """
    Every snap lands where the pressures balance, on a stable or neutral state, releasing
    energy; where identical segments shared the fluid alike, the one nearer the base takes
    more (``base_takes_more``).
    """
    snaps = graph.snaps()
    assert snaps
    # Stiffnesses to the segments' own scale (the steepest one's pressure range over its volume
    # range): round-off where a flat piece meets a falling one is not a falling segment.
    k_scale = max(np.ptp(s.pressure(v)) / np.ptp(v) for s, v in
                  ((s, np.linspace(s.rest_volume, s.max_volume, 201)) for s in segments))
    for snap in snaps:
        after, before = np.array(snap.volumes_after), np.array(snap.volumes_before)
        assert after.sum() == pytest.approx(before.sum(), rel=1e-9)
        pressures = np.array([float(s.pressure(v)) for s, v in zip(segments, after)])
        assert np.ptp(pressures) < 1e-6 * 100.0
        k = np.array([float(s.stiffness(v)) for s, v in zip(segments, after)]) / k_scale
        assert np.sum(k < -1e-9) <= 1
        assert sum(np.prod(np.delete(k, i)) for i in range(k.size)) >= -1e-9
        assert snap.energy_released >= -1e-12 * abs(snap.pressure_before) * after.sum()
        for i in range(len(segments) if base_takes_more else 0):
            for j in range(i + 1, len(segments)):
                if before[i] == before[j] and after[i] != after[j]:
                    assert after[i] > after[j]


def test_a_table_in_steps_is_read_through_the_middles_of_its_runs_of_equal_readings():
    # A Gent balloon logged in 1 mbar steps: its curve passes through the middle of every run
    # of equal readings, has no flat piece, stays within one step of every reading and within
    # 1.5 steps of the closed form it was logged from, and keeps the table's range; the
    # segment is still defined by the rows as read. A table without repeated readings is
    # interpolated through its rows as they are.
    step, rows = 100.0, 400
    stretch = np.linspace(1.0, 4.0, rows)
    exact = 2 * 60e3 * 0.6e-3 / R * (1 / stretch - stretch**-7) / (
        1 - (2 * stretch**2 + stretch**-4 - 3) / 30.0)
    readings = np.round(exact / step) * step
    volumes = V0 * stretch**3
    segment = TabulatedSegment('logged', 0.074, volumes, readings, np.zeros(rows))
    assert np.sum(np.diff(readings) == 0.0) > 20
    assert all(pc.direction != 0 for pc in segment.monotone_pieces())
    curve = segment.pressure(volumes)
    assert np.max(np.abs(curve - readings)) <= step * (1 + 1e-12)
    assert np.max(np.abs(curve - exact)) <= 1.5 * step * (1 + 1e-12)
    assert (segment.rest_volume, segment.max_volume) == (volumes[0], volumes[-1])
    starts = np.flatnonzero(np.diff(readings, prepend=np.nan) != 0.0)
    stops = np.append(starts[1:], rows) - 1
    interior = [(a, b) for a, b in zip(starts, stops) if 0 < a < b < rows - 1]
    assert len(interior) > 5
    for a, b in interior:
        middle = 0.5 * (volumes[a] + volumes[b])
        assert segment.pressure(middle) == pytest.approx(readings[a], abs=1e-9)
    assert segment.definition()['pressure_pa'] == [float(p) for p in readings]
    smooth = TabulatedSegment('smooth', 0.074, volumes, exact, np.zeros(rows))
    assert np.array_equal(smooth.knots(), volumes)
    np.testing.assert_allclose(smooth.pressure(volumes), exact, rtol=1e-15, atol=0.0)


def test_two_identical_tables_in_one_millibar_steps_snap_onto_stable_states():
    segments = [quantised_gent_table(name, 600) for name in ('base', 'tip')]
    readings = segments[0].pressures
    last = int(np.argmax(np.diff(readings) < 0))     # the last row before the first fall
    peak = readings[last]
    first = last - int(np.argmax(readings[last::-1] != peak)) + 1
    assert last - first + 1 > 5     # the peak is a run of rows at one reading
    # Read as one peak at the run's middle, not as a plateau.
    pieces = segments[0].monotone_pieces()
    assert [pc.direction for pc in pieces] == [1, -1, 1]
    assert pieces[0].v_hi == pytest.approx(0.5 * (segments[0].volumes[first]
                                                 + segments[0].volumes[last]), rel=1e-12)
    assert pieces[0].p_at_hi == peak
    emap = EquilibriumMap(segments)
    graph = transition_graph(emap)
    assert_snaps_land_on_balanced_stable_states(segments, graph)
    # Some snaps start where both share the fluid alike (the tie-break is tested on them).
    assert any(t.volumes_before[0] == t.volumes_before[1] != t.volumes_after[0]
               for t in graph.snaps())
    # Inflated to the end of the range and deflated to rest, as softseq solve does: every
    # state balanced, and rest again at the end.
    for path in inflate_and_deflate(emap, 801):
        pressures = np.stack([s.pressure(path.volumes[:, i]) for i, s in enumerate(segments)])
        assert np.max(np.ptp(pressures, axis=0)) < 1e-6 * 100.0
    assert path.injected[-1] == pytest.approx(0.0, abs=1e-15)


@pytest.mark.parametrize('rows', [100, 200, 600])
def test_three_identical_tables_in_one_millibar_steps_get_past_symmetric_saddles(rows):
    # Two of them past their peak together stay equal along a flow (the same equations to the
    # bit): it comes to rest on a saddle (balanced on two falling pieces) and has to go on
    # from there. The peak and the valley are runs of rows at one reading, read as one peak
    # and one valley at the runs' middles. (A flow that passes near such a saddle may leave
    # it either way, by round-off: the mirror states it lands on are equally stable, so which
    # of two equal segments takes more is not asserted here.)
    segments = [quantised_gent_table(name, rows) for name in ('base', 'middle', 'tip')]
    readings = segments[0].pressures
    assert np.sum(readings == readings[np.argmax(readings[:rows // 2])]) > 1
    assert [pc.direction for pc in segments[0].monotone_pieces()] == [1, -1, 1]
    emap = EquilibriumMap(segments)
    assert_snaps_land_on_balanced_stable_states(segments, transition_graph(emap),
                                                base_takes_more=False)


def test_three_identical_tables_with_a_one_row_peak_land_beside_it_on_a_stretch_samples_miss():
    # At 80 rows the peak is a single row. One segment just past it and one just before it
    # balance on stable stretches under 1 Pa long (the two cubics beside the peak row bend
    # differently), shorter than the samples' spacing, against the end of their
    # configurations' range, where every stiffness is 0: the flow from a snap came to rest
    # where the samples had found no branch. The assembly now looks just inside such an
    # unstable end and finds them the first time; the walk passes through them.
    segments = [quantised_gent_table(name, 80) for name in ('base', 'middle', 'tip')]
    peak = next(pc.p_at_lo for pc in segments[0].monotone_pieces() if pc.direction < 0)
    emap = EquilibriumMap(segments)
    graph = transition_graph(emap)
    assert_snaps_land_on_balanced_stable_states(segments, graph, base_takes_more=False)
    short = {j for j, b in enumerate(emap.branches)
             if np.ptp(b.pressure) < 1.0 and abs(b.pressure[0] - peak) < 1.0}
    assert short
    assert any(t.target in short for t in graph.transitions)
    # Every branch the walk needs is in the first assembly.
    first = Assembly(SegmentNumerics(segments), emap.resolution).branches
    assert [b.pressure.tolist() for b in first] == [b.pressure.tolist() for b in emap.branches]


def test_a_snap_from_a_fold_whose_total_barely_turns_lands_past_it():
    # Three identical 60-row tables in 1 mbar steps: near their common valley one branch (two
    # segments rising, one falling) has a fold where its total volume turns by 2e-12 m^3 over
    # 0.5 Pa. At the fold's own total the flow from a step off it met balanced pressures at
    # once, on the branch it left, from either side: no landing. The flow now starts a step
    # past the fold as well, at a total the branch does not reach, and lands.
    segments = [quantised_gent_table(name, 60) for name in ('base', 'middle', 'tip')]
    assert_snaps_land_on_balanced_stable_states(
        segments, transition_graph(EquilibriumMap(segments)), base_takes_more=False)


def gent_closed_form_table(name, rows, shear_modulus, gent_limit, wall, max_stretch):
    """A Gent balloon's table at ``rows`` stretches, not quantised."""
    stretch = np.linspace(1.0, max_stretch, rows)
    pressure = (2.0 * shear_modulus * wall / R * (1.0 / stretch - stretch**-7)
                / (1.0 - (2.0 * stretch**2 + stretch**-4 - 3.0) / gent_limit))
    return TabulatedSegment(name, 0.074, V0 * stretch**3, pressure, np.zeros(rows))


# Tables on which a landing once went wrong (docs/graph.md, "How a snap lands", says how):
# each map is built and every snap checked.
FORMER_LANDING_FAULTS = {
    # One branch of three identical tables changes its total volume by 3e-11 m^3 over 4 Pa,
    # less than the step off a fold: the flows rested beside its fold.
    'three identical 25-row tables in 1 mbar steps': lambda: [
        quantised_gent_table(name, 25) for name in ('base', 'middle', 'tip')],
    # Run up close to the limit stretch (a pressure scale of 13 MPa): flows resting on one
    # plateau were placed on another a step away, releasing -4e-7 J.
    'two identical 540-row tables in 10 Pa steps near their limit stretch': lambda: [
        quantised_gent_table(name, 540, shear_modulus=74977.6, gent_limit=28.375,
                             wall=0.4328e-3, max_stretch=4.1223, step=10.0)
        for name in ('base', 'tip')],
    # A flow rested 3e-12 m^3 from the fold it left, and a branch 1.5e-7 m^3 away was taken
    # as its landing (-5e-10 J).
    'four identical 67-row tables in 10 Pa steps': lambda: [
        quantised_gent_table(name, 67, shear_modulus=70612.41235070789,
                             gent_limit=29.903998171980756, wall=0.0007135674243820239,
                             max_stretch=3.659971665019998, step=10.0)
        for name in ('s0', 's1', 's2', 's3')],
    # Mirror branches 3.2e-10 m^3 long next to the common valley, a few times the step off a
    # fold: which way the flow pointed was round-off, and it went back.
    'two identical 199-row smooth tables': lambda: [
        gent_closed_form_table(name, 199, 45512.91103394532, 39.67499858546575,
                               0.00040109885904106567, 3.5584224496238015)
        for name in ('base', 'tip')],
    # A coarse stepped table climbs from one run of rows to the next inside one interval: a
    # ball was certified convex from samples that missed the steep stretch.
    'a 55-row and a 589-row table in 1 mbar steps': lambda: [
        quantised_gent_table('base', 55, 54298.43, 38.897918, 0.72497884e-3, 3.6973943),
        quantised_gent_table('tip', 589, 59086.779, 27.716980, 0.64555800e-3, 3.7502197)],
    # A flow balanced to the rest tolerance 2e-11 m^3 short of where an equilibrium is.
    'three different tables in 1 mbar steps': lambda: [
        quantised_gent_table('base', 448, 76640.611, 38.388274, 0.59286988e-3, 4.1591353),
        quantised_gent_table('middle', 292, 61786.709, 26.205711, 0.58140537e-3, 4.0526822),
        quantised_gent_table('tip', 444, 65296.255, 29.741466, 0.78119106e-3, 4.2764615)],
}


@pytest.mark.parametrize('case', sorted(FORMER_LANDING_FAULTS))
def test_tables_that_once_broke_a_landing_land_on_balanced_stable_states(case):
    segments = FORMER_LANDING_FAULTS[case]()
    graph = transition_graph(EquilibriumMap(segments))
    assert graph.snaps()
    assert_snaps_land_on_balanced_stable_states(segments, graph, base_takes_more=False)


def test_flows_of_different_stepped_tables_end_in_certain_basins(monkeypatch):
    # Three different balloons logged in 1 mbar steps. Read as written, runs of rows at one
    # pressure made plateaus: some snaps ended on one (two segments on flat rows at one
    # pressure, the third stiffening), balanced with a stiffness sum of 0, where no basin is
    # certain and round-off walked the flow along the plateau. Read through the runs'
    # middles, the curves have no flats: every flow ends in a basin certain to hold it,
    # together with the others, none at rest short of one and none alone.
    segments = [
        quantised_gent_table('base', 529, 76.7e3, 20.8, 0.611e-3, 3.56),
        quantised_gent_table('middle', 297, 65.7e3, 37.1, 0.637e-3, 3.76),
        quantised_gent_table('tip', 590, 73.6e3, 30.2, 0.604e-3, 3.65)]
    ends = []
    land = FlowLandings.land

    def recording(self, *args, **kwargs):
        found = land(self, *args, **kwargs)
        ends.extend(landing.why for landing in found if landing.branch < 0)
        return found

    def alone(self, start):
        raise AssertionError(f'a flow from {start} was integrated alone')

    monkeypatch.setattr(FlowLandings, 'land', recording)
    monkeypatch.setattr(RedistributionFlow, 'integrate', alone)
    emap = EquilibriumMap(segments)
    assert ends == []
    assert_snaps_land_on_balanced_stable_states(segments, transition_graph(emap),
                                                base_takes_more=False)


# --------------------------------------------------------------------------- three segments

def test_three_segments_pass_their_peaks_in_the_order_of_their_peak_pressures(nested):
    _, emap, graph = nested
    peaks = [max(pc.p_at_hi for pc in s.monotone_pieces() if pc.direction > 0
                 and pc.v_hi < s.max_volume) for s in emap.segments]
    assert len(set(peaks)) == 3
    assert [piece_labels(s) for s in emap.segments] == [['rising-1', 'falling', 'rising-2']] * 3
    passed, where = [], {}
    for branch, _ in inflation_walk(graph):
        for i, piece in enumerate(graph.branches[branch].pieces):
            if piece != 'rising-1' and i not in passed:
                passed.append(i)
                where[i] = graph.branches[branch].injected_lo
    assert passed == list(np.argsort(peaks)) == [2, 1, 0]
    assert where[2] < where[1] < where[0]
    # The first passes its peak smoothly, at its own peak pressure.
    first = next(end for branch, end in inflation_walk(graph)
                 if graph.branches[end.target].pieces[2] == 'falling')
    assert first.kind == JOIN
    assert first.pressure_before == pytest.approx(peaks[2], rel=1e-9)


def test_every_reachable_branch_is_reached_by_its_proposed_history(nested):
    _, emap, graph = nested
    least = graph.min_reversals()
    for branch in graph.branches:
        reach = graph.history_to(branch.index)
        if reach.reversals is None:
            continue
        assert reach.history[0] == 0.0
        assert len(reach.history) == reach.reversals + 2
        assert least[branch.index] == reach.reversals
        tracker, _ = run_history(emap, reach.history)
        assert tracker.branch == branch.index, reach
    # Monotone inflation reaches exactly the inflation walk's branches; one reversal more
    # than the default path visits: the nested loops hold states only a turn reaches.
    assert graph.reachable(0) == {b for b, _ in inflation_walk(graph)}
    default = {b.index for b in graph.branches if b.default_path}
    assert default < graph.reachable(1)
    assert graph.reachable(1) < graph.reachable(3)


def test_every_transition_of_the_nested_scene_is_reproduced_by_softseq_solve(nested, tmp_path,
                                                                           capsys):
    # three_nested_loops is the shipped three-segment scene with peaks (three_segments is
    # monotone: one branch, no transition). For every snap and join a history can cross: the
    # history the graph gives onto its branch, moving its way, then one command beyond it.
    # All of them run in one `softseq solve --path` (each history starts at rest: deflating
    # to 0 injected brings every history back there, the one state at that volume).
    path, emap, graph = nested
    crossable, histories = [], []
    for transition in graph.transitions:
        if transition.kind == END:
            continue
        reach = graph.history_to(transition.source, transition.direction)
        if reach.reversals is None:
            # Only transitions out of branches no history reaches are left out.
            assert graph.min_reversals()[transition.source] is None
            continue
        target = graph.branches[transition.target]
        far = (target.injected_hi if transition.direction == INFLATION
               else target.injected_lo)
        crossable.append(transition)
        histories.append([*reach.history, transition.injected
                          + 0.5 * (far - transition.injected)])
    assert sum(t.kind == SNAP for t in crossable) == len(graph.snaps()) == 12
    assert sum(t.kind == JOIN for t in crossable) >= 10
    csv_path = tmp_path / 'histories.csv'
    csv_path.write_text('injected_m3\n' + ''.join(f'{v!r}\n' for h in histories for v in h),
                        encoding='utf-8')
    out = tmp_path / 'solved.csv'
    assert main(['solve', str(path), '--path', str(csv_path), '--out', str(out)]) == 0
    assert 'snap-throughs:' in capsys.readouterr().out
    with open(out, encoding='utf-8') as handle:
        rows = list(csv.DictReader(row for row in handle if not row.startswith('#')))
    assert len(rows) == sum(len(h) for h in histories)
    names = [s.name for s in emap.segments]

    def state(row):
        return np.array([float(row[f'volume_{n}_m3']) for n in names])

    def on(branch, row):
        total = float(row['injected_m3']) + emap.total_rest_volume
        return np.max(np.abs(emap.read(branch, np.array([total])).volumes[0] - state(row)))

    end = 0
    for transition, history in zip(crossable, histories):
        end += len(history)
        before, after = rows[end - 2], rows[end - 1]
        # Before the last command the state is on the transition's branch; the last command
        # crosses the transition alone: a snap where the graph has one, none at a join, and
        # the state lands on the branch the graph says.
        assert on(transition.source, before) < 1e-12, transition
        assert on(transition.target, after) < 1e-12, transition
        assert after['event'] == ('snap' if transition.kind == SNAP else ''), transition
        if transition.kind == SNAP:
            assert transition.energy_released > 0.0
            moved = 0.5 * np.sum(np.abs(np.array(transition.volumes_after)
                                        - np.array(transition.volumes_before)))
            assert transition.fluid_moved == pytest.approx(moved, rel=1e-12)


def test_softseq_graph_proposes_a_history_that_softseq_solve_lands_on(nested, tmp_path,
                                                                        capsys):
    path, emap, graph = nested
    assert main(['graph', str(path), '--out', str(tmp_path / 'g'), '--reversals', '1']) == 0
    data = json.loads((tmp_path / 'g' / 'graph.json').read_text(encoding='utf-8'))
    assert (tmp_path / 'g' / 'graph.png').stat().st_size > 10_000
    assert len(data['branches']) == len(graph.branches) == 21
    # A branch no monotone inflation and deflation visits, which one reversal reaches.
    off = [b for b in data['branches'] if not b['default_path'] and b['min_reversals'] == 1]
    assert off, 'the nested scene has a branch only a turning history reaches'
    target = off[0]
    assert target['reachable_within_reversals'] is True
    history = target['history_injected_m3']
    csv_path = tmp_path / 'history.csv'
    csv_path.write_text('injected_m3\n' + ''.join(f'{v!r}\n' for v in history),
                        encoding='utf-8')
    out = tmp_path / 'solved.csv'
    assert main(['solve', str(path), '--path', str(csv_path), '--out', str(out)]) == 0
    with open(out, encoding='utf-8') as handle:
        last = list(csv.DictReader(row for row in handle if not row.startswith('#')))[-1]
    names = [s.name for s in emap.segments]
    landed = np.array([float(last[f'volume_{n}_m3']) for n in names])
    total = history[-1] + emap.total_rest_volume
    expected = emap.read(target['index'], np.array([total])).volumes[0]
    np.testing.assert_allclose(landed, expected, rtol=0, atol=1e-12)
    # ... and not on the branch the default path holds at that volume.
    others = [b.index for b in graph.branches if b.default_path
              and b.injected_lo <= history[-1] <= b.injected_hi]
    assert others
    for index in others:
        assert np.max(np.abs(emap.read(index, np.array([total])).volumes[0] - landed)) > 1 * ML
    printed = capsys.readouterr().out
    assert f"branch {target['index']} ({target['label']}): 1 reversals" in printed
    # softseq solve names the branch it ends on, in the graph's numbering and words.
    assert (f"ends at {history[-1] * 1e6:.4g} mL injected on branch {target['index']} "
            f"({target['label']}) of softseq graph") in printed


def test_the_shipped_three_segment_scene_has_one_branch_and_no_snap():
    # Jm 16 is below the peak's onset: each curve rises monotonically, so the graph is one
    # branch from rest to the end of the domain, and no snap exists to reproduce.
    emap = equilibrium_map(load_scene('three_segments').segments)
    graph = transition_graph(emap)
    assert [b.pieces for b in graph.branches] == [('rising', 'rising', 'rising')]
    assert [t.kind for t in graph.transitions] == [END, END]
    assert graph.branches[0].injected_hi == pytest.approx(emap.injected_range[1], rel=1e-12)
    inflation, deflation = inflate_and_deflate(emap, 201)
    assert set(inflation.branch) == set(deflation.branch) == {0}


# --------------------------------------------------------------------------- Fig. 1 asymmetric

def gent_energy(segment, v):
    """The thin balloon's stored energy in closed form: 4 pi R^2 H W(lam), Gent's W."""
    lam = (v / segment.rest_volume) ** (1 / 3)
    mu, jm = segment.material.mu, segment.material.jm
    w = -0.5 * mu * jm * math.log(1 - (2 * lam**2 + lam**-4 - 3) / jm)
    return 4 * math.pi * segment.radius**2 * segment.thickness * w


def test_the_asymmetric_pair_has_its_hysteresis_loops_as_two_cycles_of_snaps(asymmetric):
    emap, graph = asymmetric
    up = sorted((t for t in graph.snaps() if t.direction == INFLATION), key=lambda t: t.injected)
    down = sorted((t for t in graph.snaps() if t.direction == DEFLATION),
                  key=lambda t: t.injected)
    # config/fig1_asymmetric.yaml: snaps at 26.4 and 38.7 mL inflating, 5.2 and 35.2 deflating
    # (from a scan to about 0.1 mL).
    np.testing.assert_allclose([t.injected / ML for t in up], [26.4, 38.7], atol=0.1)
    np.testing.assert_allclose([t.injected / ML for t in down], [5.2, 35.2], atol=0.1)
    first = up[0]
    np.testing.assert_allclose(
        (np.array(first.volumes_before) - emap.rest_volumes)[0] / ML, 2.0, atol=0.1)
    np.testing.assert_allclose(
        (np.array(first.volumes_after) - emap.rest_volumes)[0] / ML, 25.7, atol=0.1)
    # Each loop: inflating from the state one deflation snap lands on meets the inflation
    # snap, and deflating from where that lands meets the deflation snap, which lands back.
    for rise, fall in ((up[0], down[0]), (up[1], down[1])):
        assert graph.next_snap(rise.target, DEFLATION) == fall
        assert graph.next_snap(fall.target, INFLATION) == rise
        assert rise.default_path and fall.default_path
    assert graph.next_snap(graph.start_branch, INFLATION) == up[0]
    # The solver's default path finds the same snaps at the same volumes.
    inflation, deflation = inflate_and_deflate(emap, 2001)
    found = sorted(e.injected for e in inflation.events + deflation.events)
    np.testing.assert_allclose(found, sorted(t.injected for t in graph.snaps()), rtol=0,
                               atol=1e-12 * ML)


def test_snap_energy_and_fluid_agree_with_the_closed_form(asymmetric):
    emap, graph = asymmetric
    for snap in graph.snaps():
        before = sum(gent_energy(s, v) for s, v in zip(emap.segments, snap.volumes_before))
        after = sum(gent_energy(s, v) for s, v in zip(emap.segments, snap.volumes_after))
        assert snap.energy_released == pytest.approx(before - after, rel=1e-8)
        assert snap.energy_released > 0.0
        assert sum(snap.volumes_before) == pytest.approx(sum(snap.volumes_after), rel=1e-12)
        moved = 0.5 * sum(abs(a - b) for a, b in zip(snap.volumes_after, snap.volumes_before))
        assert snap.fluid_moved == pytest.approx(moved, rel=1e-12)
        # The quadrature itself, from rest, against the closed form.
        assert stored_energy(emap.segments, np.array(snap.volumes_before)) == pytest.approx(
            before, rel=1e-10)
    largest = max(graph.snaps(), key=lambda t: t.fluid_moved)
    assert largest.injected == pytest.approx(26.39 * ML, abs=0.01 * ML)
    assert largest.fluid_moved == pytest.approx(23.6 * ML, abs=0.1 * ML)


def test_a_table_s_stored_energy_is_the_integral_of_its_pressure():
    """A table's energy (its cubics' antiderivative) against adaptive quadrature of its curve."""
    from scipy.integrate import quad

    balloon = BalloonSegment('b', 0.074, NeoHookean(60.0e3), 0.006, 0.6e-3, 3.0)
    rows = balloon.rest_volume * np.linspace(1.0, 3.0, 37) ** 3
    pressure = balloon.pressure(rows) + 200.0 * np.sin(np.arange(rows.size))   # kinks
    table = TabulatedSegment('t', 0.074, rows, pressure, np.zeros(rows.size))
    ends = np.array([rows[0], rows[3], 0.5 * (rows[10] + rows[11]), rows[-1]])
    for end in ends:
        inside = rows[(rows > rows[0]) & (rows < end)]
        expected = quad(table.pressure, rows[0], end, points=inside, limit=200,
                        epsabs=0.0, epsrel=1e-13)[0] if end > rows[0] else 0.0
        got = stored_energy([table, balloon], np.array([end, balloon.rest_volume]))
        assert got == pytest.approx(expected, rel=1e-11, abs=1e-18)


def test_softseq_graph_writes_si_json_and_the_figure(tmp_path, capsys, monkeypatch):
    from softseq_ros.analysis import graph_figure

    drawn = capture_figures(monkeypatch, graph_figure)
    assert main(['graph', 'fig1_asymmetric', '--out', str(tmp_path)]) == 0
    data = json.loads((tmp_path / 'graph.json').read_text(encoding='utf-8'))
    assert data['segments'] == ['bottom', 'top']
    assert data['pieces']['bottom'] == ['rising-1', 'falling', 'rising-2']
    assert len(data['branches']) == 9 and len(data['transitions']) == 18
    branch = data['branches'][0]
    assert {'injected_lo_m3', 'injected_hi_m3', 'gauge_pressure_lo_pa', 'label', 'pieces',
            'default_path', 'min_reversals', 'history_injected_m3'} <= set(branch)
    snaps = [t for t in data['transitions'] if t['kind'] == SNAP]
    assert len(snaps) == 4
    assert {'injected_m3', 'fluid_moved_m3', 'energy_released_j', 'volumes_before_m3',
            'gauge_pressure_after_pa'} <= set(snaps[0])
    assert all(t['energy_released_j'] > 0 for t in snaps)
    assert '9 stable branches, 4 snaps, 9 on the default path' in capsys.readouterr().out
    # The figure in the paper style: no title, 300 dpi, a page wide, cropped to what is drawn.
    [fig] = drawn
    assert not titles(fig)
    pixels = laid_out(tmp_path / 'graph.png')
    assert 6.5 * 300 <= pixels.shape[1] <= 7.3 * 300
    # Each snap's direction in its colour: inflation's blue, deflation's vermillion.
    for direction in ('inflation', 'deflation'):
        assert share_of(pixels, STYLE[direction]['color']) > 1e-4, direction


def test_the_graph_figure_takes_the_style_width_and_resolution_asked_for(tmp_path, monkeypatch):
    from softseq_ros.analysis import graph_figure

    drawn = capture_figures(monkeypatch, graph_figure)
    assert main(['graph', 'fig1_partial', '--out', str(tmp_path / 'column'), '--width', '3.5',
                 '--dpi', '100']) == 0
    # 3.5 in at 100 dpi, cropped to what is drawn (the key below may widen it a little).
    assert 300 <= laid_out(tmp_path / 'column' / 'graph.png', dpi=100).shape[1] <= 390
    assert main(['graph', 'fig1_partial', '--out', str(tmp_path / 'screen'), '--style',
                 'screen']) == 0
    whole(tmp_path / 'screen' / 'graph.png', dpi=110)
    assert titles(drawn[-1])


def test_softseq_graph_refuses_a_negative_number_of_reversals(tmp_path, capsys):
    assert main(['graph', 'fig1_asymmetric', '--out', str(tmp_path), '--reversals', '-1']) == 2
    assert '--reversals must be >= 0, got -1' in capsys.readouterr().err


def _default_walk(graph, top: float) -> list[int]:
    """The branches of the graph's inflate-to-``top``-then-deflate-to-rest path, in order."""
    branch, walk = graph.start_branch, [graph.start_branch]
    for direction, beyond in ((INFLATION, lambda v: v > top), (DEFLATION, lambda v: v <= 0)):
        while True:
            end = graph.end(branch, direction)
            if end.kind == END or beyond(end.injected):
                break
            branch = end.target
            walk.append(branch)
    return walk


def test_the_report_of_a_rig_bag_lists_the_branches_of_the_graphs_default_path(tmp_path):
    # The rig (its actuator's tracker) and the graph (the map's branch ends) agree on which
    # branches an inflation to 65 mL and back visits, in order: a report marks them.
    data = yaml.safe_load(load_scene('fig1_asymmetric').path.read_text(encoding='utf-8'))
    data['pump']['flow_rate_m3_per_s'] = 1e-6
    data['camera'] = {'rate_hz': 1}
    scene = scene_from_dict(data, tmp_path / 'fast.yaml')
    softseq_ros.run(scene, tmp_path / 'bag', start_time_ns=0)
    emap = scene_map(scene)
    metrics = recording_metrics(load_recording(tmp_path / 'bag'), scene, emap)
    visited = [stay['branch'] for stay in metrics['branches_visited']]
    graph = transition_graph(emap)
    assert visited == _default_walk(graph, data['pump']['legs'][0]['inflate_to_m3'])
    assert len(set(visited)) >= 4   # the two snaps each way leave and land on other branches
    labels = {b.index: b.label for b in graph.branches}
    assert all(stay['state'] == labels[stay['branch']] for stay in metrics['branches_visited'])
    assert 'branches visited (softseq graph numbering): #' in summary_text(metrics)
