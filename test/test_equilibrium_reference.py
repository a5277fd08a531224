"""
The equilibrium tracker against closed forms and against the slow reference in reference.py.

Stated tolerances (volume scale S = sum of the segments' volume spans, max - rest):
- volumes agree with the reference within 1e-6 S at every commanded row, except the rows within
  one commanded step of a snap-through or a bifurcation (there the branch is infinitely steep and
  either side of the fold is right to the resolution of the commanded grid);
- snap-through volumes agree within the tracker's own grid step (largest span / resolution);
- the states a snap lands on agree within 1e-5 S, the states it leaves within 1e-3 S (a fold:
  the volumes vary like the square root of the distance to it).
"""

import copy
import math
from pathlib import Path
import sys

import numpy as np
import pytest
from scipy.optimize import brentq

from softseq_ros.quasistatic.equilibrium import EquilibriumMap, Tracker, classify
from softseq_ros.scene.loader import load_scene
from softseq_ros.segments.materials import Gent, NeoHookean, Ogden
from softseq_ros.segments.models import BalloonSegment, LinearSegment, TabulatedSegment

sys.path.insert(0, str(Path(__file__).parent))
from reference import ReferenceTracker  # noqa: E402

CONFIG = Path(__file__).resolve().parent.parent / 'config'
R = 0.006
H = 0.6e-3
MU = 60e3
V0 = 4 / 3 * math.pi * R**3
VOLUME_TOL = 1e-6
LAND_TOL = 1e-5
LEAVE_TOL = 1e-3


def neo_pair():
    return [BalloonSegment(n, 0.1, NeoHookean(MU), R, H, 3.0) for n in ('bottom', 'top')]


def gent_pair():
    # The thicker, more extensible balloon has the highest peak (1.44 vs 1.29 mu H / R, in
    # units of the thin one) and the lowest valley (0.82 vs 1.16): the asymmetric sequence.
    return [BalloonSegment('bottom', 0.1, Gent(MU, 97.2), R, 1.15 * H, 6.5),
            BalloonSegment('top', 0.1, Gent(MU, 30.0), R, H, 3.2)]


def scene_pair():
    return list(load_scene(CONFIG / 'fig1_asymmetric.yaml').segments)


def span(segments):
    return sum(s.max_volume - s.rest_volume for s in segments)


def history(emap, n=500, frac=0.995):
    up = np.linspace(0.0, frac * emap.injected_range[1], n)
    return np.concatenate([up, up[::-1]])


def near(u, k, volumes):
    """True when row k of the commanded history u is within one step of any of volumes."""
    lo = u[max(k - 1, 0)]
    hi = u[min(k + 1, len(u) - 1)]
    lo, hi = min(lo, hi, u[k]), max(lo, hi, u[k])
    return any(lo <= v <= hi for v in volumes)


# --- the reference itself, against closed forms ----------------------------------------------

def phat(lam):
    return 2 * (1 / lam - 1 / lam**7)


def neo_pair_closed_form(total_over_v0):
    """Sorted volumes (in v0) of two identical neo-Hookean balloons holding total v0-units."""
    lam_peak = 7 ** (1 / 6)
    if total_over_v0 <= 2 * lam_peak**3:
        return np.array([total_over_v0 / 2, total_over_v0 / 2])
    # The small balloon is back on the rising branch, the large one beyond the peak.
    small = brentq(lambda a: phat(a) - phat((total_over_v0 - a**3) ** (1 / 3)),
                   1.0 + 1e-12, lam_peak, xtol=1e-15)
    return np.array([small**3, total_over_v0 - small**3])


def test_reference_matches_neo_hookean_pair_closed_form():
    segs = neo_pair()
    ref = ReferenceTracker(segs)
    u = np.linspace(0.0, 20 * V0, 120)
    path = ref.sweep(np.concatenate([u, u[::-1]]))
    assert path.events == []
    for k, uk in enumerate(np.concatenate([u, u[::-1]])):
        expected = neo_pair_closed_form(2 + uk / V0) * V0
        np.testing.assert_allclose(np.sort(path.volumes[k]), expected, rtol=0, atol=1e-9 * V0)


@pytest.mark.slow
def test_reference_snaps_leave_from_a_fold():
    # A snap starts where the stable branch ends: the restricted Hessian k1 + k2 vanishes there.
    segs = gent_pair()
    ref = ReferenceTracker(segs)
    u = np.linspace(0.0, 0.8 * ref.injected_range[1], 200)
    ref.sweep(np.concatenate([u, u[::-1]]))
    assert len(ref.events) == 4
    for event in ref.events:
        k = [float(s.stiffness(v)) for s, v in zip(segs, event.from_volumes)]
        k_scale = max(abs(x) for x in k)
        assert abs(sum(k)) < 2e-3 * k_scale
        assert np.abs(event.to_volumes - event.from_volumes).max() > 0.01 * span(segs)


# --- (a) two identical neo-Hookean balloons --------------------------------------------------

def test_identical_neo_hookean_share_then_split_without_snap():
    segs = neo_pair()
    emap = EquilibriumMap(segs)
    u = history(emap, n=400, frac=0.5)
    path = Tracker(emap).sweep(u)
    ref = ReferenceTracker(segs).sweep(u)
    assert path.events == [] and not path.snap.any() and ref.events == []
    pitchfork = 2 * V0 * (math.sqrt(7) - 1)
    scale = span(segs)
    for k, uk in enumerate(u):
        vols = np.sort(path.volumes[k])
        if uk <= pitchfork - 1e-9 * scale:
            # Equal sharing up to the peak volume of each balloon (v = sqrt(7) v0).
            assert vols[1] - vols[0] <= 1e-9 * scale
        elif not near(u, k, [pitchfork]):
            assert vols[1] - vols[0] > 0.0
            np.testing.assert_allclose(vols, neo_pair_closed_form(2 + uk / V0) * V0,
                                       rtol=0, atol=VOLUME_TOL * scale)
            np.testing.assert_allclose(path.volumes[k], ref.volumes[k], rtol=0,
                                       atol=VOLUME_TOL * scale)
    assert u.max() > 3 * pitchfork, 'the history must go well past the peak'


def test_two_linear_segments_split_in_stiffness_ratio():
    k1, k2 = 3e9, 1.2e9
    segs = [LinearSegment('a', 0.1, 2e-6, k1, 40e-6), LinearSegment('b', 0.1, 5e-6, k2, 50e-6)]
    emap = EquilibriumMap(segs)
    u = np.linspace(0.0, 0.95 * emap.injected_range[1], 37)
    path = Tracker(emap).sweep(u)
    np.testing.assert_allclose(path.volumes[:, 0] - 2e-6, u * k2 / (k1 + k2), rtol=1e-12,
                               atol=1e-15 * u.max())
    np.testing.assert_allclose(path.volumes[:, 1] - 5e-6, u * k1 / (k1 + k2), rtol=1e-12,
                               atol=1e-15 * u.max())
    np.testing.assert_allclose(path.pressure, u * k1 * k2 / (k1 + k2), rtol=1e-12,
                               atol=1e-12 * k1 * u.max())
    ref = ReferenceTracker(segs).sweep(u)
    np.testing.assert_allclose(ref.volumes, path.volumes, rtol=0, atol=1e-12 * span(segs))


# --- (b) peak-valley pairs: snaps on inflation, different ones on deflation -----------------

@pytest.mark.slow
@pytest.mark.parametrize('make', [gent_pair, scene_pair], ids=['gent_pair', 'fig1_asymmetric'])
def test_asymmetric_pair_follows_reference_with_hysteresis(make):
    segs = make()
    emap = EquilibriumMap(segs)
    u = history(emap)
    path = Tracker(emap).sweep(u)
    ref = ReferenceTracker(segs).sweep(u)
    scale = span(segs)
    top = emap.injected_range[1]

    # Snap-throughs: same number, same order, same volumes to the tracker's resolution.
    assert len(ref.events) >= 2
    assert len(path.events) == len(ref.events)
    grid = max(s.max_volume - s.rest_volume for s in segs) / 2000
    for mine, theirs in zip(path.events, ref.events):
        assert mine.injected == pytest.approx(theirs.injected, abs=grid)
        np.testing.assert_allclose(mine.to_volumes, theirs.to_volumes, rtol=0,
                                   atol=LAND_TOL * scale)
        np.testing.assert_allclose(mine.from_volumes, theirs.from_volumes, rtol=0,
                                   atol=LEAVE_TOL * scale)

    # Hysteresis: inflation and deflation snap at different volumes.
    n_up = len(u) // 2
    up = [e.injected for e in ref.events if e.row < n_up]
    down = [e.injected for e in ref.events if e.row >= n_up]
    assert up and down
    assert min(abs(a - b) for a in up for b in down) > 0.01 * top

    # Volumes everywhere else.
    snap_volumes = [e.injected for e in ref.events]
    checked = 0
    for k in range(len(u)):
        if near(u, k, snap_volumes):
            continue
        np.testing.assert_allclose(path.volumes[k], ref.volumes[k], rtol=0,
                                   atol=VOLUME_TOL * scale, err_msg=f'row {k}, u={u[k]}')
        checked += 1
    assert checked > 0.95 * len(u)

    # The snap flags of the path sit on the rows where the reference snapped.
    assert np.nonzero(path.snap)[0].tolist() == sorted({e.row for e in ref.events})


# --- three segments (the reference's N > 2 mode covers snap-free paths) -----------------------

def ogden_three():
    # Treloar's rubber (Ogden 1972), three balloons of different wall thickness.
    return [BalloonSegment(f's{i}', 0.1, Ogden((6.3e5, 1.2e3, -1e4), (1.3, 5.0, -2.0)),
                           R, H * f, 4.0) for i, f in enumerate((1.0, 1.1, 1.25))]


def three_scene():
    return list(load_scene(CONFIG / 'three_segments.yaml').segments)


@pytest.mark.parametrize('make', [three_scene, ogden_three], ids=['three_segments', 'ogden'])
def test_three_segments_follow_reference(make):
    segs = make()
    emap = EquilibriumMap(segs)
    u = history(emap, n=200)
    path = Tracker(emap).sweep(u)
    ref = ReferenceTracker(segs).sweep(u)
    assert ref.events == [] and path.events == []
    np.testing.assert_allclose(path.volumes, ref.volumes, rtol=0,
                               atol=VOLUME_TOL * span(segs))


# --- (c) a jump equals the walk ---------------------------------------------------------------

@pytest.mark.slow
@pytest.mark.parametrize('make', [gent_pair, scene_pair], ids=['gent_pair', 'fig1_asymmetric'])
def test_jump_equals_walk(make):
    segs = make()
    emap = EquilibriumMap(segs)
    scale = span(segs)
    top = 0.995 * emap.injected_range[1]
    rng = np.random.default_rng(20261123)
    pairs = [tuple(p) for p in rng.uniform(0.0, top, size=(6, 2))]
    trips = pairs + [(b, a) for a, b in pairs]
    # Every start is reached by inflating from rest; the reference gets there once, in order.
    ref = ReferenceTracker(segs)
    at_start = {}
    for start in sorted({s for s, _ in trips}):
        ref.go_to(start)
        at_start[start] = copy.deepcopy(ref)
    crossed = 0
    for start, end in trips:
        jumper = Tracker(emap)
        jumper.step(start)
        jumped = jumper.step(end)
        walker = Tracker(emap)
        walker.step(start)
        walked = walker.sweep(np.linspace(start, end, 400))
        ref = copy.deepcopy(at_start[start])
        ref_snaps = ref.go_to(end)
        crossed += bool(ref_snaps)
        np.testing.assert_allclose(jumped.volumes, walked.volumes[-1], rtol=0,
                                   atol=VOLUME_TOL * scale)
        np.testing.assert_allclose(jumped.volumes, ref.volumes, rtol=0, atol=VOLUME_TOL * scale)
        assert len(jumped.snaps) == len(ref_snaps) == len(walked.events)
    assert crossed >= 3, 'the random pairs must cross snap-throughs'


# --- (d) classify --------------------------------------------------------------------------

def plateau_segment():
    # Rising, a flat plateau at 5 kPa from 6 to 20 mL, rising again: PCHIP keeps it flat.
    v = np.array([1, 2, 4, 6, 10, 15, 20, 24, 28]) * 1e-6
    p = np.array([0, 1.8, 4.0, 5.0, 5.0, 5.0, 5.0, 9.0, 16.0]) * 1e3
    return TabulatedSegment('plateau', 0.1, v, p, np.zeros_like(v))


def test_classify_intended_types():
    linear = [LinearSegment('a', 0.1, 1e-6, 1e9, 30e-6), LinearSegment('b', 0.1, 1e-6, 3e9, 30e-6)]
    assert classify(EquilibriumMap(linear)) == 'none'

    partial = [plateau_segment(), LinearSegment('stiff', 0.1, 1e-6, 0.5e9, 30e-6)]
    assert classify(EquilibriumMap(partial)) == 'partial'

    # One peak, and a partner stiffer than the steepest fall of the peak: no snap-through.
    balloon = BalloonSegment('balloon', 0.1, NeoHookean(MU), R, H, 3.0)
    v = np.linspace(balloon.rest_volume, balloon.max_volume, 20001)
    steepest_fall = -float(np.min(balloon.stiffness(v)))
    stiff = LinearSegment('stiff', 0.1, 1e-6, 3.0 * steepest_fall, 40e-6)
    assert classify(EquilibriumMap([balloon, stiff])) == 'symmetric'

    assert classify(EquilibriumMap(gent_pair())) == 'asymmetric'
