"""
Stress tests of the equilibrium solver: random piecewise-monotone tables and random histories.

Tables have peaks, valleys, flat plateaus of exactly zero slope, near-vertical walls, 2 to a few
hundred rows at irregular spacing; 2 to 5 segments; histories mix ramps, reversals, holds and
large jumps. On every step (checked here, from the segment models alone):

- the volumes add up to the commanded total to round-off (1e-12 of the volume scale);
- the pressures agree: |p_i(v_i) - p| <= 1e-6 p_scale + |dp_i/dv_i| 1e-6 v_scale (a volume error
  of a millionth of the range, which on a near-vertical wall is a large pressure);
- the state is stable: the Hessian diag(dp_i/dv_i) restricted to sum(dv) = 0 has no eigenvalue
  below -1e-6 p_scale / v_scale (PSD to the tolerance; exactly singular at a fold);
- nothing is NaN;
and over a history: a jump lands where a fine walk lands, the same history gives the same branch
sequence every time, scaling volumes and pressures scales the answer, and 10^6 steps neither
drift nor grow memory.

Hypothesis runs derandomized (a fixed example sequence) so that CI is deterministic.
"""

import tracemalloc

from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
import numpy as np
import pytest

from softseq_ros.quasistatic.equilibrium import DomainError, EquilibriumMap, Tracker
from softseq_ros.scene.tables import read_table
from softseq_ros.segments.models import TabulatedSegment
from softseq_ros.segments.smoothing import estimate_noise, smooth_table

# Tolerances stated in the module docstring.
SUM_TOL = 1e-12
PRESSURE_TOL = 1e-6
VOLUME_TOL = 1e-6
HESSIAN_TOL = 1e-6

STRESS = settings(max_examples=15, deadline=None, derandomize=True, database=None,
                  suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def make_table(rest: float, moves: list, row_counts: list, seed: int) -> tuple:
    """
    Rows of a piecewise-monotone PV table.

    ``moves`` is a list of (kind, width, size): 'rise' and 'fall' change the pressure smoothly
    over ``width`` of volume, 'flat' keeps it exactly constant, 'wall' rises steeply over a
    thousandth of the width. Pressures start at 0 at the rest volume and stay positive.
    """
    rng = np.random.default_rng(seed)
    volumes, pressures = [rest], [0.0]
    v, p = rest, 0.0
    for (kind, width, size), count in zip(moves, row_counts):
        if kind == 'wall':
            width *= 1e-3
            target = p + 5.0 * size
        elif kind == 'rise':
            target = p + size
        elif kind == 'fall':
            target = p * (1.0 - min(0.6, size / 2e4))
        else:
            target = p
        # Irregular spacing: sorted uniform positions inside the move, ends included.
        t = np.sort(rng.uniform(0.0, 1.0, max(count - 1, 0)))
        t = np.unique(np.concatenate([t, [1.0]]))
        t = t[t > 0.0]
        shape = t + 0.3 * np.sin(2.0 * np.pi * t) / (2.0 * np.pi)  # monotone in t
        volumes.extend(v + width * t)
        pressures.extend(p + (target - p) * shape)
        v, p = v + width, target
    volumes = np.asarray(volumes)
    keep = np.concatenate([[True], np.diff(volumes) > 0.0])
    return volumes[keep], np.asarray(pressures)[keep]


def random_table(rng: np.random.Generator, max_moves: int, name: str,
                 may_fall: bool = True) -> TabulatedSegment:
    """One random table: short (2-3 rows), medium or long, with a random mix of moves."""
    rest = rng.uniform(1e-6, 1e-5)
    length_kind = rng.choice(['short', 'medium', 'long'], p=[0.15, 0.55, 0.3])
    if length_kind == 'short':
        # 2 or 3 rows: a rise, then maybe a peak, a flat or a further rise.
        p1 = rng.uniform(2e3, 2e4)
        volumes = [rest, rest + rng.uniform(5e-6, 3e-5)]
        pressures = [0.0, p1]
        last = rng.choice(['none', 'rise', 'flat', 'fall'] if may_fall else
                          ['none', 'rise', 'flat'])
        if last != 'none':
            volumes.append(volumes[-1] + rng.uniform(5e-6, 3e-5))
            pressures.append({'rise': 1.5 * p1, 'flat': p1, 'fall': 0.7 * p1}[last])
        volumes, pressures = np.array(volumes), np.array(pressures)
    else:
        moves = [('rise', rng.uniform(3e-6, 2e-5), rng.uniform(2e3, 2e4))]
        for _ in range(rng.integers(0, max_moves)):
            kind = (rng.choice(['rise', 'fall', 'flat', 'wall'], p=[0.3, 0.4, 0.15, 0.15])
                    if may_fall else rng.choice(['rise', 'flat', 'wall'], p=[0.6, 0.2, 0.2]))
            moves.append((kind, rng.uniform(3e-6, 2e-5), rng.uniform(5e2, 1e4)))
        per_move = (2, 9) if length_kind == 'medium' else (40, 151)
        counts = [int(rng.integers(*per_move)) for _ in moves]
        volumes, pressures = make_table(rest, moves, counts, int(rng.integers(2**31)))
    curvature = (volumes - volumes[0]) * 1e5
    return TabulatedSegment(name, 0.1, volumes, pressures, curvature)


@st.composite
def actuators(draw) -> list:
    """2 to 5 random tables (the shapes come from a drawn seed, so derandomized runs vary)."""
    count = draw(st.sampled_from([2, 2, 2, 3, 3, 4, 5]))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    # Fewer turning points per segment as the count grows, and at most two segments with
    # falling pieces, keep the assembly quick: with three or more, a snap's redistribution
    # flow can take minutes (reported; see bench/README.md).
    max_moves = {2: 5, 3: 4, 4: 3, 5: 2}[count]
    return [random_table(rng, max_moves, f'seg{i}', may_fall=i < 2) for i in range(count)]


@st.composite
def histories(draw) -> list:
    """Fractions of the injected range: ramps, reversals, holds and large jumps."""
    commands = [0.0]
    for kind in draw(st.lists(st.sampled_from(['ramp', 'hold', 'jump', 'reverse']),
                              min_size=1, max_size=8)):
        here = commands[-1]
        if kind == 'hold':
            commands.extend([here] * draw(st.integers(1, 5)))
        elif kind == 'jump':
            commands.append(draw(st.floats(0.0, 1.0)))
        else:
            target = draw(st.floats(0.0, 1.0)) if kind == 'ramp' else 1.0 - here
            commands.extend(np.linspace(here, target, draw(st.integers(2, 80)))[1:].tolist())
    return commands


def restricted_hessian_min(stiffness: np.ndarray) -> np.ndarray:
    """Smallest eigenvalue of diag(k) restricted to sum(dv) = 0, for each row of k."""
    n = stiffness.shape[1]
    basis = np.linalg.qr(np.eye(n) - 1.0 / n)[0][:, : n - 1]
    return np.linalg.eigvalsh(np.einsum('ia,ni,ib->nab', basis, stiffness, basis))[:, 0]


def check_states(emap, totals, volumes, pressure) -> None:
    segments = emap.segments
    assert np.all(np.isfinite(volumes)) and np.all(np.isfinite(pressure))
    assert np.max(np.abs(volumes.sum(axis=1) - totals)) <= SUM_TOL * emap.v_scale
    each = np.stack([s.pressure(volumes[:, i]) for i, s in enumerate(segments)], axis=1)
    k = np.stack([s.stiffness(volumes[:, i]) for i, s in enumerate(segments)], axis=1)
    allowed = PRESSURE_TOL * emap.p_scale + np.abs(k) * VOLUME_TOL * emap.v_scale
    assert np.all(np.abs(each - pressure[:, None]) <= allowed), \
        f'pressure mismatch {np.max(np.abs(each - pressure[:, None]) - allowed):.3g} Pa'
    lowest = restricted_hessian_min(k * emap.v_scale / emap.p_scale)
    assert np.all(lowest >= -HESSIAN_TOL), f'unstable state: eigenvalue {lowest.min():.3g}'


def describe(emap, path) -> None:
    """Tell the statistics (--hypothesis-show-statistics) what the examples covered."""
    event(f'{len(emap.segments)} segments')
    pieces = [p.direction for s in emap.segments for p in s.monotone_pieces()]
    event(f'falling pieces: {pieces.count(-1) > 0}, flat pieces: {pieces.count(0) > 0}')
    event('domain error' if path is None else f'snaps: {min(len(path.events), 3)}+')


def follow(emap, fractions):
    """Sweep a history given as fractions of the injected range; stop at a domain end."""
    lo, hi = emap.injected_range
    commands = lo + (hi - lo) * np.asarray(fractions)
    tracker = Tracker(emap)
    try:
        return commands, tracker.sweep(commands), None
    except DomainError as error:
        return commands, None, error


@STRESS
@given(actuators(), histories())
def test_every_step_is_a_balanced_stable_equilibrium(segments, fractions):
    emap = EquilibriumMap(segments)
    commands, path, error = follow(emap, fractions)
    describe(emap, path)
    if error is not None:
        # Allowed only where the current branch really ends at a segment's table edge.
        stepper = Tracker(emap)
        with pytest.raises(DomainError):
            for u in commands:
                stepper.step(u)
        edge = stepper.state.volumes
        assert (np.any(np.isclose(edge, emap.max_volumes, rtol=0, atol=1e-9 * emap.v_scale))
                or np.any(np.isclose(edge, emap.rest_volumes, rtol=0,
                                     atol=1e-9 * emap.v_scale))), str(error)
        return
    check_states(emap, commands + emap.total_rest_volume, path.volumes, path.pressure)
    # One step at a time gives the same states as the sweep.
    stepper = Tracker(emap)
    stepped = np.array([stepper.step(u).volumes for u in commands])
    np.testing.assert_allclose(stepped, path.volumes, rtol=0, atol=1e-12 * emap.v_scale)


@STRESS
@given(actuators(), st.floats(0.0, 1.0), st.floats(0.0, 1.0), st.floats(0.0, 1.0))
def test_a_jump_lands_where_a_fine_walk_lands(segments, a, b, c):
    emap = EquilibriumMap(segments)
    lo, hi = emap.injected_range
    start, middle, end = (lo + (hi - lo) * x for x in (a, b, c))
    jumper, walker = Tracker(emap), Tracker(emap)
    try:
        walker.sweep(np.linspace(lo, start, 400))
        walker.sweep(np.linspace(start, middle, 400))
        walked = walker.sweep(np.linspace(middle, end, 400))
    except DomainError:
        with pytest.raises(DomainError):
            for u in (start, middle, end):
                jumper.step(u)
        return
    for u in (start, middle):
        jumper.step(u)
    jumped = jumper.step(end)
    assert jumped.branch == walked.branch[-1]
    np.testing.assert_allclose(jumped.volumes, walked.volumes[-1], rtol=0,
                               atol=1e-12 * emap.v_scale)
    # The snaps met on the way are reported by the jump too (same volumes, same order).
    walked_snaps = [e.injected for e in walked.events]
    assert [e.injected for e in jumped.snaps] == pytest.approx(walked_snaps, abs=1e-15)


@settings(STRESS, max_examples=6)
@given(actuators(), histories())
def test_the_same_history_gives_the_same_branches_every_time(segments, fractions):
    lo_hi = EquilibriumMap(segments).injected_range
    fractions = list(fractions) + list(reversed(fractions))  # inflate, then deflate back
    runs = []
    for _ in range(2):
        emap = EquilibriumMap(segments)  # rebuilt: the assembly is deterministic as well
        assert emap.injected_range == lo_hi
        _, path, error = follow(emap, fractions)
        runs.append((None, None, str(error)) if path is None else
                    (path.branch, path.volumes, [e.injected for e in path.events]))
    if runs[0][0] is None:
        assert runs[0] == runs[1]
        return
    np.testing.assert_array_equal(runs[0][0], runs[1][0])
    np.testing.assert_array_equal(runs[0][1], runs[1][1])
    assert runs[0][2] == runs[1][2]


def peak_valley_pair(volume_factor=1.0, pressure_factor=1.0):
    """Two tables with a peak and a valley each: snap-throughs on inflation and deflation."""
    def table(name, rest, rise, peak, valley, seed):
        moves = [('rise', 8e-6, peak), ('fall', 10e-6, 2e4 * (1 - valley / peak)),
                 ('rise', 30e-6, 3.0 * peak)]
        v, p = make_table(rest, moves, [30, 30, 40], seed)
        return TabulatedSegment(name, 0.1, v * volume_factor, p * pressure_factor,
                                (v - v[0]) * 1e5)
    return [table('bottom', 2e-6, 8e-6, 8000.0, 6000.0, 1),
            table('top', 1e-6, 6e-6, 7000.0, 6500.0, 2)]


@pytest.mark.parametrize('volume_factor, pressure_factor', [
    (1e-4, 1e-4),   # micro-litre volumes (1e-9 m^3), pascal pressures
    (1e-4, 1e2),    # micro-litre, megapascal
    (1e2, 1e-4),    # litre (1e-3 m^3), pascal
    (1e2, 1e2),     # litre, megapascal
    (3.7, 0.013),
])
def test_scaling_volumes_and_pressures_scales_the_answer(volume_factor, pressure_factor):
    base = EquilibriumMap(peak_valley_pair())
    scaled = EquilibriumMap(peak_valley_pair(volume_factor, pressure_factor))
    lo, hi = base.injected_range
    fractions = np.concatenate([np.linspace(0, 1, 1500), np.linspace(1, 0, 1500)])
    history = lo + (hi - lo) * fractions
    path = Tracker(base).sweep(history)
    scaled_path = Tracker(scaled).sweep(history * volume_factor)
    assert len(path.events) >= 2, 'the reference pair must snap on both legs'
    np.testing.assert_array_equal(path.branch, scaled_path.branch)
    np.testing.assert_allclose(scaled_path.volumes / volume_factor, path.volumes, rtol=0,
                               atol=1e-9 * base.v_scale)
    np.testing.assert_allclose(scaled_path.pressure / pressure_factor, path.pressure, rtol=0,
                               atol=1e-9 * base.p_scale)
    assert [e.injected / volume_factor for e in scaled_path.events] == pytest.approx(
        [e.injected for e in path.events], rel=0, abs=1e-9 * base.v_scale)


def test_a_million_steps_neither_drift_nor_grow_memory():
    emap = EquilibriumMap(peak_valley_pair())
    lo, hi = emap.injected_range
    period = 10_000
    wave = np.abs(((np.arange(period) / period) * 2.0) - 1.0)  # 1 -> 0 -> 1 triangle
    cycle = lo + (hi - lo) * (1.0 - wave)
    history = np.tile(cycle, 100)  # 10^6 commands, 100 full inflate/deflate cycles
    tracker = Tracker(emap)
    tracemalloc.start()
    try:
        baseline = tracemalloc.get_traced_memory()[0]
        peaks = []
        for _ in range(3):
            path = None  # the previous output is dropped before the next sweep
            before = tracemalloc.get_traced_memory()[0]
            tracemalloc.reset_peak()
            path = tracker.sweep(history)
            peaks.append(tracemalloc.get_traced_memory()[1] - before)
        leftover = tracemalloc.get_traced_memory()[0] - baseline
    finally:
        tracemalloc.stop()
    totals = history + emap.total_rest_volume
    output_bytes = sum(a.nbytes for a in (path.injected, path.pressure, path.volumes,
                                          path.curvatures, path.branch, path.snap))
    # The volume balance holds on every one of the 10^6 rows.
    assert np.max(np.abs(path.volumes.sum(axis=1) - totals)) <= SUM_TOL * emap.v_scale
    # No drift: the last cycle repeats the second one exactly (the first starts from rest).
    np.testing.assert_array_equal(path.volumes[-period:], path.volumes[period:2 * period])
    np.testing.assert_array_equal(path.branch[-period:], path.branch[period:2 * period])
    np.testing.assert_array_equal(path.snap[-period:], path.snap[period:2 * period])
    assert path.snap[period:2 * period].sum() >= 2, 'each cycle snaps on both legs'
    # Memory: the peak of a sweep is a small multiple of its output, the same every time, and
    # nothing stays behind once the output is dropped (the events list aside).
    assert max(peaks) <= 4.0 * output_bytes, (peaks, output_bytes)
    assert max(peaks) <= 1.05 * min(peaks), peaks
    assert leftover - output_bytes <= 2_000_000, (leftover, output_bytes)


# ------------------------------------------------------------------------- noisy tables

def paper_tables(rows):
    """The paper scene's two tables resampled to ``rows`` rows: a partial sequence."""
    from pathlib import Path
    folder = Path(__file__).resolve().parent.parent / 'config' / 'segments'
    tables = []
    for name in ('bottom', 'top'):
        segment = read_table(folder / f'paper_{name}.csv', length=0.111)
        v = np.linspace(segment.rest_volume, segment.max_volume, rows)
        tables.append((v, segment.pressure(v), segment.curvature(v)))
    return tables


@pytest.mark.parametrize('seed', range(3))
def test_smoothing_removes_spurious_snaps_at_the_documented_noise_level(seed):
    # docs/benchmarks.md: on these 60-row tables, noise of 1% of the pressure range makes
    # spurious peaks and valleys (and snap-throughs); smoothing restores the clean picture.
    rng = np.random.default_rng(seed)
    clean = paper_tables(60)
    clean_map = EquilibriumMap([TabulatedSegment(f'c{i}', 0.111, *t)
                                for i, t in enumerate(clean)])
    lo, hi = clean_map.injected_range
    history = np.concatenate([np.linspace(lo, 0.999 * hi, 1500),
                              np.linspace(0.999 * hi, lo, 1500)])
    clean_path = Tracker(clean_map).sweep(history)
    segments = []
    for i, (v, p, c) in enumerate(clean):
        sigma = 0.01 * np.ptp(p)
        noisy = p + rng.normal(0.0, sigma, p.size)
        noisy[0] = p[0]
        smoothed = smooth_table(v, noisy)
        # Accuracy: the smoothed rows are closer to the truth than the worst noisy row, and
        # within 2 sigma everywhere.
        assert np.max(np.abs(smoothed - p)) <= 2.0 * sigma
        assert np.max(np.abs(smoothed - p)) < np.max(np.abs(noisy - p))
        segments.append(TabulatedSegment(f'n{i}', 0.111, v, smoothed, c))
        assert len(segments[-1].monotone_pieces()) == 1  # no invented peak or valley
    emap = EquilibriumMap(segments)
    path = Tracker(emap).sweep(np.clip(history, *emap.injected_range))
    assert not path.events
    # The volume split follows the clean one to a few per cent of the range.
    assert np.max(np.abs(path.volumes - clean_path.volumes)) <= 0.05 * clean_map.v_scale


def test_smoothing_keeps_real_peaks_and_valleys():
    rng = np.random.default_rng(7)
    v = np.linspace(1e-6, 5e-5, 200)
    x = (v - v[0]) / (v[-1] - v[0])
    # A balloon-like curve: rise, peak (prominence ~ 2 kPa), valley, stiff rise.
    p = 8e3 * np.sin(np.pi * np.minimum(x / 0.3, 1.0) / 2) - 2e3 * np.clip((x - 0.3) / 0.3, 0,
                                                                          1) ** 2
    p = np.where(x > 0.6, p[np.searchsorted(x, 0.6)] + 4e4 * (x - 0.6) ** 2, p)
    sigma = 50.0
    noisy = p + rng.normal(0.0, sigma, p.size)
    noisy[0] = p[0]
    smoothed = smooth_table(v, noisy)
    slope = np.sign(np.diff(smoothed))
    assert np.all(slope != 0.0)  # no exactly flat stretch is invented
    assert np.count_nonzero(np.diff(slope)) == 2  # exactly one peak and one valley
    assert np.max(np.abs(smoothed - p)) <= 3.0 * sigma
    assert estimate_noise(v, noisy) == pytest.approx(sigma, rel=0.25)


def test_smoothing_refuses_what_it_cannot_smooth():
    v = np.linspace(0.0, 1.0, 10)
    with pytest.raises(ValueError, match='at least 5 rows'):
        smooth_table(v[:4], v[:4])
    with pytest.raises(ValueError, match='increase strictly'):
        smooth_table(v[::-1], v)
    with pytest.raises(ValueError, match='finite'):
        smooth_table(v, np.where(v > 0.5, np.nan, v))


@pytest.mark.parametrize('build', ['peak_valley_pair', 'fig1_asymmetric', 'three_segments'])
def test_snapping_scenes_hold_the_invariants_on_every_step(build):
    # Random tables seldom snap; these do, on both legs (the shipped scenes where present).
    if build == 'peak_valley_pair':
        segments = peak_valley_pair()
    else:
        from softseq_ros.scene.loader import load_scene
        from softseq_ros.scene.paths import scene_path
        try:
            segments = list(load_scene(scene_path(build)).segments)
        except ValueError:
            pytest.skip(f'scene {build} is not shipped')
    emap = EquilibriumMap(segments)
    lo, hi = emap.injected_range
    top = lo + 0.9999 * (hi - lo)
    history = np.concatenate([np.linspace(lo, top, 3000), np.linspace(top, lo, 3000),
                              lo + (top - lo) * np.random.default_rng(3).uniform(size=500)])
    path = Tracker(emap).sweep(history)
    check_states(emap, history + emap.total_rest_volume, path.volumes, path.pressure)
    if build != 'three_segments':
        assert len(path.events) >= 2
