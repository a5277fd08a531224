"""
Invariants every state the tracker outputs must satisfy, on several inflate-deflate sweeps.

Stated tolerances: volumes add up to the commanded total within 1e-12 of the volume range
(sum of max - rest); segment pressures agree with the path's pressure within 1e-6 of the
pressure scale (largest |p| any segment reaches); the restricted Hessian of the energy on
sum v = V, built here from the segments' own stiffness, is positive definite; nothing is NaN.
Every shipped scene (config/*.yaml) is swept too.
"""

import math
from pathlib import Path

import numpy as np
import pytest

from softseq_ros.quasistatic.equilibrium import EquilibriumMap, Tracker
from softseq_ros.scene.loader import load_scene
from softseq_ros.segments.materials import Gent, NeoHookean, Ogden
from softseq_ros.segments.models import BalloonSegment, LinearSegment

CONFIG = Path(__file__).resolve().parent.parent / 'config'
SCENES = sorted(CONFIG.glob('*.yaml'))
R = 0.006
H = 0.6e-3


def built_cases():
    return {
        'linear_pair': [LinearSegment('a', 0.1, 2e-6, 3e9, 40e-6),
                        LinearSegment('b', 0.1, 5e-6, 1.2e9, 50e-6)],
        'neo_pair': [BalloonSegment(n, 0.1, NeoHookean(60e3), R, H, 3.0) for n in 'ab'],
        'gent_pair': [BalloonSegment('a', 0.1, Gent(60e3, 97.2), R, 1.15 * H, 6.5),
                      BalloonSegment('b', 0.1, Gent(60e3, 30.0), R, H, 3.2)],
        # Treloar's rubber (Ogden 1972), three balloons of different wall thickness.
        'ogden_three': [BalloonSegment(f's{i}', 0.1,
                                       Ogden((6.3e5, 1.2e3, -1e4), (1.3, 5.0, -2.0)),
                                       R, H * f, 4.0) for i, f in enumerate((1.0, 1.1, 1.25))],
        'balloon_and_spring': [BalloonSegment('b', 0.1, NeoHookean(60e3), R, H, 3.5),
                               LinearSegment('s', 0.1, 1e-6, 2e8, 60e-6)],
    }


def inflate_deflate(emap, n=300):
    up = np.linspace(0.0, 0.995 * emap.injected_range[1], n)
    return np.concatenate([up, up[::-1]])


def check_invariants(segments, emap, u, path):
    n_seg = len(segments)
    rest = np.array([s.rest_volume for s in segments])
    top = np.array([s.max_volume for s in segments])
    volume_range = float((top - rest).sum())
    grid = [np.linspace(s.rest_volume, s.max_volume, 4001) for s in segments]
    pressure_scale = max(float(np.abs(s.pressure(g)).max()) for s, g in zip(segments, grid))

    assert path.volumes.shape == (len(u), n_seg)
    for name in ('injected', 'pressure', 'volumes', 'curvatures'):
        assert np.all(np.isfinite(getattr(path, name))), f'{name} has NaN or inf'
    np.testing.assert_allclose(path.injected, u, rtol=0, atol=1e-12 * volume_range)

    # Volume conservation: the fluid the pump pushed sits in the segments.
    np.testing.assert_allclose(path.volumes.sum(axis=1), rest.sum() + u, rtol=0,
                               atol=1e-12 * volume_range)
    assert np.all(path.volumes >= rest - 1e-12 * volume_range)
    assert np.all(path.volumes <= top + 1e-12 * volume_range)

    # One shared fluid: one pressure.
    for i, s in enumerate(segments):
        np.testing.assert_allclose(s.pressure(path.volumes[:, i]), path.pressure, rtol=0,
                                   atol=1e-6 * pressure_scale, err_msg=f'segment {s.name}')
        # The curvature belongs to the segment's volume. Volumes are exact only to a
        # round-off-level tolerance, which a steep curvature table amplifies by dk/dv.
        slack = np.abs(s.curvature_slope(path.volumes[:, i])) * 1e-9 * volume_range
        np.testing.assert_array_less(
            np.abs(s.curvature(path.volumes[:, i]) - path.curvatures[:, i]),
            1e-9 * np.abs(path.curvatures[:, i]) + slack + 1e-12, err_msg=f'segment {s.name}')

    # Stability: Hessian of E = sum E_i(v_i) restricted to sum v = V, in the basis
    # e_i - e_N (i < N): diag(k_1..k_{N-1}) + k_N * ones.
    k = np.stack([s.stiffness(path.volumes[:, i]) for i, s in enumerate(segments)], axis=1)
    k_scale = float(np.abs(k).max())
    for row, kr in enumerate(k):
        hessian = np.diag(kr[:-1]) + kr[-1] * np.ones((n_seg - 1, n_seg - 1))
        smallest = float(np.linalg.eigvalsh(hessian).min())
        assert smallest > 0.0, (f'row {row} (injected {u[row]:.6g} m^3) unstable: '
                                f'smallest restricted Hessian eigenvalue {smallest:.3g} '
                                f'(stiffness scale {k_scale:.3g})')


@pytest.mark.parametrize('case', sorted(built_cases()))
def test_built_sweeps_keep_invariants(case):
    segments = built_cases()[case]
    emap = EquilibriumMap(segments)
    u = inflate_deflate(emap)
    check_invariants(segments, emap, u, Tracker(emap).sweep(u))


def test_scenes_are_shipped():
    # A missing config directory must fail loudly, not skip the scene sweeps below.
    assert len(SCENES) >= 4, f'expected the shipped scenes in {CONFIG}'


@pytest.mark.parametrize('path', SCENES, ids=[p.stem for p in SCENES])
def test_scene_sweeps_keep_invariants(path):
    scene = load_scene(path)
    segments = list(scene.segments)
    resolution = scene.solver.resolution
    emap = EquilibriumMap(segments) if resolution is None else \
        EquilibriumMap(segments, resolution=resolution)
    u = inflate_deflate(emap)
    check_invariants(segments, emap, u, Tracker(emap).sweep(u))


def test_step_by_step_equals_sweep():
    segments = built_cases()['gent_pair']
    emap = EquilibriumMap(segments)
    u = inflate_deflate(emap, n=120)
    swept = Tracker(emap).sweep(u)
    stepper = Tracker(emap)
    stepped = np.array([stepper.step(float(x)).volumes for x in u])
    scale = sum(s.max_volume - s.rest_volume for s in segments)
    np.testing.assert_allclose(stepped, swept.volumes, rtol=0, atol=1e-9 * scale)
    assert math.isfinite(stepper.state.pressure)
