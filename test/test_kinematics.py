"""Planar PCC backbone against closed forms."""

import math

import numpy as np
import pytest

from softseq_ros.segments.kinematics import (
    backbone,
    backbone_batch,
    orientation_quaternions,
    segment_end_indices,
)


def test_zero_curvature_is_a_straight_line_along_x():
    result = backbone([0.0, 0.0], [0.1, 0.2], points_per_segment=10)
    assert result.points.shape == (21, 2)
    np.testing.assert_allclose(result.points[:, 1], 0.0, atol=0.0)
    np.testing.assert_allclose(result.points[:, 0], result.arc_length, rtol=1e-15, atol=1e-17)
    np.testing.assert_allclose(result.tip, [0.3, 0.0], rtol=1e-15)
    np.testing.assert_allclose(result.angles, 0.0, atol=0.0)
    assert result.segment_ends.tolist() == [10, 20]


def test_full_circle_returns_to_the_base():
    length = 0.15
    k = 2.0 * math.pi / length
    result = backbone([k, 0.0], [length, 0.05], points_per_segment=64)
    end = result.points[result.segment_ends[0]]
    np.testing.assert_allclose(end, [0.0, 0.0], atol=1e-15)
    assert result.angles[result.segment_ends[0]] == pytest.approx(2.0 * math.pi, rel=1e-14)
    # Every point of the first segment lies on the circle of radius 1/k centred at (0, 1/k).
    first = result.points[:result.segment_ends[0] + 1]
    np.testing.assert_allclose(np.hypot(first[:, 0], first[:, 1] - 1.0 / k), 1.0 / k, rtol=1e-13)


@pytest.mark.parametrize('sign', [1.0, -1.0])
def test_quarter_circle_endpoint_closed_form(sign):
    # A quarter turn of radius r ends at (r, +-r), tangent +-90 degrees: positive curvature
    # turns toward +z.
    r = 0.08
    length = 0.5 * math.pi * r
    result = backbone([sign / r, 0.0], [length, 0.1], points_per_segment=7)
    end = result.segment_ends[0]
    np.testing.assert_allclose(result.points[end], [r, sign * r], rtol=1e-14)
    assert result.angles[end] == pytest.approx(sign * 0.5 * math.pi, rel=1e-14)
    # The second, straight segment continues along the end tangent: straight up or down.
    np.testing.assert_allclose(result.tip, [r, sign * (r + 0.1)], rtol=1e-14)


def test_tangent_is_continuous_and_matches_the_chord_direction():
    kappa = np.array([12.0, -7.0, 30.0])
    lengths = np.array([0.05, 0.08, 0.04])
    result = backbone(kappa, lengths, points_per_segment=400)
    # Angles grow linearly in arc length within each segment with slope k: no jump at joints.
    ds = np.diff(result.arc_length)
    slopes = np.diff(result.angles) / ds
    expected = np.repeat(kappa, 400)
    np.testing.assert_allclose(slopes, expected, rtol=1e-10)
    # Finite-difference direction of the points agrees with the tangent at the midpoints.
    steps = np.diff(result.points, axis=0)
    mid_angle = 0.5 * (result.angles[1:] + result.angles[:-1])
    np.testing.assert_allclose(np.arctan2(steps[:, 1], steps[:, 0]), mid_angle, atol=1e-12)
    np.testing.assert_allclose(np.hypot(steps[:, 0], steps[:, 1]), ds, rtol=1e-5)


def test_tiny_curvature_matches_the_straight_limit():
    lengths = [0.111, 0.111]
    straight = backbone([0.0, 0.0], lengths).points
    bent = backbone([1e-13, -1e-13], lengths).points
    np.testing.assert_allclose(bent, straight, rtol=0.0, atol=1e-12)
    # A small but resolved curvature matches the Taylor series of (sin(ks), 1 - cos(ks)) / k.
    k, s = 1e-4, 0.111
    tip = backbone([k, 0.0], [s, 1e-9], points_per_segment=1).points[1]
    series = [s - k**2 * s**3 / 6.0, k * s**2 / 2.0 - k**3 * s**4 / 24.0]
    np.testing.assert_allclose(tip, series, rtol=1e-14)


def test_base_pose_moves_and_rotates_the_whole_backbone():
    kappa = [9.0, -4.0]
    lengths = [0.1, 0.07]
    base = backbone(kappa, lengths).points
    x0, z0, theta0 = 0.3, -0.2, 0.7
    moved = backbone(kappa, lengths, base_pose=(x0, z0, theta0))
    c, s = math.cos(theta0), math.sin(theta0)
    rotated = base @ np.array([[c, s], [-s, c]]) + [x0, z0]
    np.testing.assert_allclose(moved.points, rotated, atol=1e-15)
    assert moved.angles[0] == theta0


def test_batch_equals_single_states():
    rng = np.random.default_rng(3)
    kappa = rng.normal(scale=20.0, size=(50, 3))
    lengths = np.array([0.07, 0.08, 0.05])
    points, angles = backbone_batch(kappa, lengths, points_per_segment=9)
    assert points.shape == (50, 28, 2) and angles.shape == (50, 28)
    for row in range(50):
        single = backbone(kappa[row], lengths, points_per_segment=9)
        np.testing.assert_array_equal(points[row], single.points)
        np.testing.assert_array_equal(angles[row], single.angles)


def test_segment_end_indices():
    assert segment_end_indices(3, 5).tolist() == [5, 10, 15]


def test_orientation_quaternion_turns_x_onto_the_tangent():
    angles = np.array([0.0, 0.4, -1.2, math.pi])
    q = orientation_quaternions(angles)
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1.0)
    x, y, z, w = q.T
    # First column of the rotation matrix of (x, y, z, w).
    axis_x = np.stack([1 - 2 * (y**2 + z**2), 2 * (x * y + z * w), 2 * (x * z - y * w)], axis=-1)
    np.testing.assert_allclose(axis_x, np.stack([np.cos(angles), 0 * angles, np.sin(angles)],
                                                axis=-1), atol=1e-15)


@pytest.mark.parametrize('kappa, lengths, pps, message', [
    ([[1.0, 2.0]], [0.1], 5, 'curvatures must have shape'),
    ([1.0, 2.0], [0.1, -0.1], 5, 'lengths must be finite and > 0'),
    ([1.0, np.nan], [0.1, 0.1], 5, 'curvatures must be finite'),
    ([1.0, 2.0], [0.1, 0.1], 0, 'points_per_segment must be >= 1'),
    ([1.0, 2.0], [0.1, 0.1], 2.5, 'points_per_segment must be an integer'),
])
def test_bad_inputs(kappa, lengths, pps, message):
    with pytest.raises(ValueError, match=message):
        backbone_batch(kappa, lengths, points_per_segment=pps)
