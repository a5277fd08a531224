"""
Planar piecewise-constant-curvature (PCC) backbone of a segmented actuator.

Frame: the base of the actuator sits at the origin and the unbent actuator points along +x.
Bending happens in the x-z plane. A point of the backbone is ``(x, z)`` in metres and its tangent
angle ``theta`` is measured from +x toward +z, so the unit tangent is ``(cos theta, sin theta)``.
Positive curvature increases ``theta`` along the arc: the backbone turns toward +z, which is
counter-clockwise when the plane is seen from the -y side (x to the right, z up). In 3-D this
orientation is a rotation by ``-theta`` about +y (see ``orientation_quaternions``).

Each segment is a circular arc of constant curvature ``k`` [1/m] and length ``L`` [m]. A point at
arc length ``s`` from a segment start ``(x0, z0, theta0)`` is reached along the chord

    dx = s cos(theta0 + k s / 2) sinc(k s / 2),  dz = s sin(theta0 + k s / 2) sinc(k s / 2)

with sinc(u) = sin(u) / u (1 at u = 0), which is exact for every ``k`` and has no division by
``k``: a straight segment and a slightly bent one share one formula.
"""

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

DEFAULT_POINTS_PER_SEGMENT = 20


@dataclass(frozen=True)
class Backbone:
    """
    Sampled backbone of one actuator state.

    ``points`` (M, 2) holds ``(x, z)`` [m] from the base to the tip, ``angles`` (M,) the tangent
    angles [rad], ``arc_length`` (M,) the distance from the base along the backbone [m], and
    ``segment_ends`` (N,) the index into ``points`` where each segment ends (the last one is the
    tip, M - 1). Point 0 is the base.
    """

    points: NDArray[np.float64]
    angles: NDArray[np.float64]
    arc_length: NDArray[np.float64]
    segment_ends: NDArray[np.intp]

    @property
    def tip(self) -> NDArray[np.float64]:
        """Tip position ``(x, z)`` [m]."""
        return self.points[-1]


def _check_inputs(curvatures: NDArray[np.float64], lengths: NDArray[np.float64],
                  points_per_segment: int) -> None:
    if lengths.ndim != 1 or lengths.size == 0:
        raise ValueError(f'lengths must be a non-empty 1-D array, got shape {lengths.shape}')
    if not np.all(np.isfinite(lengths)) or np.any(lengths <= 0.0):
        raise ValueError(f'lengths must be finite and > 0, got {lengths.tolist()}')
    if curvatures.ndim != 2 or curvatures.shape[1] != lengths.size:
        raise ValueError(f'curvatures must have shape (n, {lengths.size}), '
                         f'got {curvatures.shape}')
    if not np.all(np.isfinite(curvatures)):
        raise ValueError('curvatures must be finite')
    if isinstance(points_per_segment, bool) or not isinstance(points_per_segment,
                                                              (int, np.integer)):
        raise ValueError(f'points_per_segment must be an integer, got {points_per_segment!r}')
    if points_per_segment < 1:
        raise ValueError(f'points_per_segment must be >= 1, got {points_per_segment}')


def _sin_ratio(half_turn: NDArray[np.float64]) -> NDArray[np.float64]:
    """sin(h) / h, 1 at h = 0 (sin(h) / h is accurate down to the smallest h; only 0 is not)."""
    ratio = np.ones_like(half_turn)
    np.divide(np.sin(half_turn), half_turn, out=ratio, where=half_turn != 0.0)
    return ratio


def segment_end_indices(n_segments: int, points_per_segment: int) -> NDArray[np.intp]:
    """Index of each segment end in a backbone sampled with ``points_per_segment`` per segment."""
    return (np.arange(1, n_segments + 1) * points_per_segment).astype(np.intp)


def backbone_batch(curvatures: ArrayLike, lengths: ArrayLike,
                   points_per_segment: int = DEFAULT_POINTS_PER_SEGMENT,
                   base_pose: tuple[float, float, float] = (0.0, 0.0, 0.0),
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """
    Backbones of many states at once.

    ``curvatures`` (n, N) [1/m], one row per state, segments from base to tip; ``lengths`` (N,)
    [m]. Each segment is sampled at ``points_per_segment`` points after its start, so every
    backbone has M = 1 + N * points_per_segment points. ``base_pose`` is ``(x, z, theta)`` of the
    base. Returns ``points`` (n, M, 2) [m] and ``angles`` (n, M) [rad].
    """
    kappa = np.asarray(curvatures, dtype=float)
    if kappa.ndim == 1:
        kappa = kappa[np.newaxis, :]
    length = np.asarray(lengths, dtype=float)
    _check_inputs(kappa, length, points_per_segment)
    x0, z0, theta0 = (float(value) for value in base_pose)
    n_states, n_segments = kappa.shape

    # Arc length from each segment start to its samples: (P,) fractions times (N,) lengths.
    fractions = np.arange(1, points_per_segment + 1, dtype=float) / points_per_segment
    s = fractions[np.newaxis, :] * length[:, np.newaxis]                  # (N, P)
    half_turn = 0.5 * kappa[:, :, np.newaxis] * s[np.newaxis, :, :]       # (n, N, P)

    # Tangent angle at each segment start: the base angle plus every earlier segment's turn.
    turns = kappa * length[np.newaxis, :]                                  # (n, N)
    start_angle = theta0 + np.concatenate(
        [np.zeros((n_states, 1)), np.cumsum(turns, axis=1)[:, :-1]], axis=1)

    chord_angle = start_angle[:, :, np.newaxis] + half_turn
    chord = s[np.newaxis, :, :] * _sin_ratio(half_turn)
    dx = chord * np.cos(chord_angle)
    dz = chord * np.sin(chord_angle)

    # Segment start positions: the base plus every earlier segment's full chord.
    end_dx = np.concatenate([np.zeros((n_states, 1)), np.cumsum(dx[:, :, -1], axis=1)], axis=1)
    end_dz = np.concatenate([np.zeros((n_states, 1)), np.cumsum(dz[:, :, -1], axis=1)], axis=1)
    x = x0 + end_dx[:, :-1, np.newaxis] + dx
    z = z0 + end_dz[:, :-1, np.newaxis] + dz
    angle = start_angle[:, :, np.newaxis] + 2.0 * half_turn

    n_points = 1 + n_segments * points_per_segment
    points = np.empty((n_states, n_points, 2))
    points[:, 0, 0] = x0
    points[:, 0, 1] = z0
    points[:, 1:, 0] = x.reshape(n_states, -1)
    points[:, 1:, 1] = z.reshape(n_states, -1)
    angles = np.empty((n_states, n_points))
    angles[:, 0] = theta0
    angles[:, 1:] = angle.reshape(n_states, -1)
    return points, angles


def backbone(curvatures: ArrayLike, lengths: ArrayLike,
             points_per_segment: int = DEFAULT_POINTS_PER_SEGMENT,
             base_pose: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> Backbone:
    """
    Backbone of one state: ``curvatures`` (N,) [1/m] and ``lengths`` (N,) [m], base to tip.

    See ``backbone_batch`` for the sampling and ``base_pose``.
    """
    kappa = np.asarray(curvatures, dtype=float)
    if kappa.ndim != 1:
        raise ValueError(f'curvatures must be 1-D for one state, got shape {kappa.shape}')
    points, angles = backbone_batch(kappa[np.newaxis, :], lengths, points_per_segment, base_pose)
    length = np.asarray(lengths, dtype=float)
    fractions = np.arange(1, points_per_segment + 1, dtype=float) / points_per_segment
    starts = np.concatenate([[0.0], np.cumsum(length)[:-1]])
    arc = np.concatenate([[0.0], (starts[:, np.newaxis]
                                  + fractions[np.newaxis, :] * length[:, np.newaxis]).ravel()])
    return Backbone(points=points[0], angles=angles[0], arc_length=arc,
                    segment_ends=segment_end_indices(length.size, points_per_segment))


def orientation_quaternions(angles: ArrayLike) -> NDArray[np.float64]:
    """
    Quaternions ``(x, y, z, w)`` (shape (..., 4)) of the 3-D frames whose +x axis is the tangent.

    A tangent angle ``theta`` (from +x toward +z) is a rotation by ``-theta`` about +y.
    """
    half = -0.5 * np.asarray(angles, dtype=float)
    quaternions = np.zeros(half.shape + (4,))
    quaternions[..., 1] = np.sin(half)
    quaternions[..., 3] = np.cos(half)
    return quaternions


class PoseSampler:
    """
    Backbone poses of one state after another, for one geometry: the camera's per-frame call.

    ``backbone_batch`` checks its inputs and builds its sampling grid at every call, which
    costs more than the arithmetic for a single state. Here the grid is built once and
    :meth:`poses` repeats ``backbone_batch``'s arithmetic operation for operation (sums in the
    same order), so both give the same numbers, bit for bit.
    """

    def __init__(self, lengths: ArrayLike, points_per_segment: int) -> None:
        """``lengths`` (N,) [m] base to tip; ``points_per_segment`` samples after each start."""
        length = np.asarray(lengths, dtype=float)
        _check_inputs(np.zeros((1, length.size)), length, points_per_segment)
        self._lengths = length.tolist()
        fractions = np.arange(1, points_per_segment + 1, dtype=float) / points_per_segment
        self._s = fractions[np.newaxis, :] * length[:, np.newaxis]            # (N, P)
        self.n_points = 1 + length.size * points_per_segment
        self._poses = np.zeros((self.n_points, 7))
        self._poses[0, 6] = 1.0

    def poses(self, curvatures: Sequence[float]) -> NDArray[np.float64]:
        """
        Poses ``(x, y, z, qx, qy, qz, qw)`` (M, 7) of the state ``curvatures`` (N,) [1/m].

        Positions are the backbone points (y = 0); orientations are
        ``orientation_quaternions`` of the tangent angles. The base is the origin with angle 0.
        The array is reused by the next call.
        """
        kappa = [float(k) for k in curvatures]
        start, angle = [0.0], 0.0
        for k, length in zip(kappa[:-1], self._lengths):
            angle += k * length
            start.append(angle)
        s = self._s
        half_turn = 0.5 * np.array(kappa)[:, np.newaxis] * s
        start_angle = np.array(start)[:, np.newaxis]
        chord_angle = start_angle + half_turn
        if 0.0 in kappa:
            chord = s * _sin_ratio(half_turn)
        else:
            chord = s * (np.sin(half_turn) / half_turn)
        dx = chord * np.cos(chord_angle)
        dz = chord * np.sin(chord_angle)
        x0 = z0 = 0.0
        starts_x, starts_z = [0.0], [0.0]
        for end_x, end_z in zip(dx[:-1, -1].tolist(), dz[:-1, -1].tolist()):
            x0 += end_x
            z0 += end_z
            starts_x.append(x0)
            starts_z.append(z0)
        poses = self._poses
        poses[1:, 0] = (np.array(starts_x)[:, np.newaxis] + dx).ravel()
        poses[1:, 2] = (np.array(starts_z)[:, np.newaxis] + dz).ravel()
        half = -0.5 * (start_angle + 2.0 * half_turn).ravel()
        poses[1:, 4] = np.sin(half)
        poses[1:, 6] = np.cos(half)
        return poses

    def poses_many(self, curvatures: NDArray[np.float64]) -> NDArray[np.float64]:
        """
        :meth:`poses` of many states (k, N): (k, M, 7), a new array.

        The same operations as :meth:`poses`, state by state (sums in the same order, the
        same choice of sin(h) / h per state), so the same numbers.
        """
        kappa = np.asarray(curvatures, dtype=float)
        count, n = kappa.shape
        lengths = self._lengths
        start = np.zeros((count, n))
        angle = np.zeros(count)
        for j in range(n - 1):
            angle = angle + kappa[:, j] * lengths[j]
            start[:, j + 1] = angle
        s = self._s[np.newaxis]
        half_turn = (0.5 * kappa)[:, :, np.newaxis] * s
        start_angle = start[:, :, np.newaxis]
        chord_angle = start_angle + half_turn
        with np.errstate(invalid='ignore', divide='ignore'):
            ratio = np.sin(half_turn) / half_turn
        # A state with a zero curvature takes sin(h) / h = 1 where h is 0 (_sin_ratio).
        ratio[(kappa == 0.0).any(axis=1)[:, np.newaxis, np.newaxis] & (half_turn == 0.0)] = 1.0
        chord = s * ratio
        dx = chord * np.cos(chord_angle)
        dz = chord * np.sin(chord_angle)
        starts_x = np.zeros((count, n))
        starts_z = np.zeros((count, n))
        x0 = np.zeros(count)
        z0 = np.zeros(count)
        for j in range(n - 1):
            x0 = x0 + dx[:, j, -1]
            z0 = z0 + dz[:, j, -1]
            starts_x[:, j + 1] = x0
            starts_z[:, j + 1] = z0
        poses = np.zeros((count, self.n_points, 7))
        poses[:, 0, 6] = 1.0
        poses[:, 1:, 0] = (starts_x[:, :, np.newaxis] + dx).reshape(count, -1)
        poses[:, 1:, 2] = (starts_z[:, :, np.newaxis] + dz).reshape(count, -1)
        half = -0.5 * (start_angle + 2.0 * half_turn).reshape(count, -1)
        poses[:, 1:, 4] = np.sin(half)
        poses[:, 1:, 6] = np.cos(half)
        return poses
