"""
The equilibrium map's batched work gives the numbers of one piece, one branch, one ball at a time.

The map inverts every piece for all configurations at once, reads many branches in one call and
certifies the landing balls of many folds together; each of these is claimed elementwise, so
the numbers must equal those of the plain per-piece, per-branch and per-centre computations, to
the bit. The references here are those plain computations, written out again.
"""

import numpy as np
import pytest

from softseq_ros.quasistatic.landing import PROBES, RADII, certified_radii
from softseq_ros.quasistatic.numerics import SegmentNumerics, cofactor_sum
from softseq_ros.quasistatic.solve import equilibrium_map
from softseq_ros.scene.loader import load_scene
from softseq_ros.segments.materials import Gent
from softseq_ros.segments.models import BalloonSegment, TabulatedSegment


def gent_segments(table: bool) -> list:
    """Three peaked Gent balloons, as closed-form laws or as 300-row tables of them."""
    built = []
    for i, (jm, thickness) in enumerate(((40.0, 0.600e-3), (35.0, 0.582e-3), (30.0, 0.564e-3))):
        balloon = BalloonSegment(f's{i}', 0.074, Gent(60.0e3, jm), 0.006, thickness, 3.6)
        if table:
            stretch = np.linspace(1.0, 3.6, 300)
            volume = balloon.rest_volume * stretch**3
            balloon = TabulatedSegment(balloon.name, 0.074, volume, balloon.pressure(volume),
                                       np.zeros(300))
        built.append(balloon)
    return built


def remember_own_samples(numerics: SegmentNumerics, count: int) -> None:
    """Each piece's pressures at ``count`` volumes along it, as the map's sampling leaves them."""
    for i, segment in enumerate(numerics.segments):
        for piece in numerics.pieces[i]:
            volumes = np.linspace(piece.v_lo, piece.v_hi, count)
            pressure = segment.pressure(volumes)
            order = np.argsort(pressure, kind='stable')
            numerics.remember_inversions(i, piece, pressure[order], volumes[order])


@pytest.mark.parametrize('remembered', [False, True], ids=['piece-wide', 'from-samples'])
@pytest.mark.parametrize('table', [True, False], ids=['tables', 'closed-form'])
def test_inverting_all_pieces_at_once_gives_each_piece_s_numbers(table, remembered):
    numerics = SegmentNumerics(gent_segments(table))
    if remembered:
        remember_own_samples(numerics, 57)
    rng = np.random.default_rng(5)
    rows = 300
    pieces = np.stack([rng.integers(0, len(p), rows) for p in numerics.pieces], axis=1)
    # Pressures inside, at the ends of and outside the pieces' ranges.
    pressure = rng.uniform(-500.0, 9000.0, rows)
    pressure[:6] = [numerics.pieces[0][pieces[r, 0]].p_at_lo for r in range(3)] + \
        [numerics.pieces[1][pieces[r, 1]].p_at_hi for r in range(3, 6)]
    volumes, stiffness = numerics.states_at(pieces, pressure)
    for i, segment_pieces in enumerate(numerics.pieces):
        for a, piece in enumerate(segment_pieces):
            at = np.flatnonzero(pieces[:, i] == a)
            alone = numerics.invert_piece(i, piece, pressure[at])
            assert volumes[at, i].tolist() == alone.tolist()
            assert stiffness[at, i].tolist() == numerics.piece_stiffness(
                i, piece, alone).tolist()


@pytest.mark.parametrize('table', [True, False], ids=['tables', 'closed-form'])
def test_an_inversion_started_between_known_samples_lands_on_the_same_volume(table):
    """Started between two sampled volumes or across the whole piece: one volume, to round-off."""
    plain = SegmentNumerics(gent_segments(table))
    sampled = SegmentNumerics(gent_segments(table))
    remember_own_samples(sampled, 41)
    rng = np.random.default_rng(11)
    for i, segment in enumerate(plain.segments):
        for piece in plain.pieces[i]:
            # Inside the piece, at its ends, and beyond them (the nearer end).
            pressure = np.concatenate([rng.uniform(piece.p_min, piece.p_max, 200),
                                       [piece.p_min, piece.p_max, piece.p_min - 1.0,
                                        piece.p_max + 1.0]])
            far = plain.invert_piece(i, piece, pressure)
            near = sampled.invert_piece(i, piece, pressure)
            assert plain.convergence.converged and sampled.convergence.converged
            assert np.all((near >= piece.v_lo) & (near <= piece.v_hi))
            assert np.max(np.abs(near - far)) <= 1e-12 * (piece.v_hi - piece.v_lo)
            inside = slice(0, 200)
            assert np.max(np.abs(segment.pressure(near[inside]) - pressure[inside])) <= (
                1e-9 * max(abs(piece.p_min), abs(piece.p_max)))
            assert near[-4:].tolist() == [piece.v_lo if piece.direction > 0 else piece.v_hi,
                                          piece.v_hi if piece.direction > 0 else piece.v_lo] * 2


def test_every_table_evaluated_side_by_side_gives_each_table_s_numbers():
    """The landings' one evaluation of all tables equals each table's own calls, to the bit."""
    segments = gent_segments(True)
    segments[1] = gent_segments(False)[1]     # a closed form among the tables is called as is
    numerics = SegmentNumerics(segments)
    rng = np.random.default_rng(3)
    # Random volumes, a table's rows (where its cubics meet) and the ends of its range.
    volumes = np.stack([np.concatenate([
        rng.uniform(s.rest_volume, s.max_volume, 500),
        s.knots()[:50] if s.knots().size else np.linspace(s.rest_volume, s.max_volume, 50),
        [s.rest_volume, s.max_volume]]) for s in segments], axis=1)
    pressure, stiffness = numerics.model_pressures(volumes), numerics.model_stiffnesses(volumes)
    for i, segment in enumerate(segments):
        assert pressure[:, i].tolist() == segment.pressure(volumes[:, i]).tolist()
        assert stiffness[:, i].tolist() == segment.stiffness(volumes[:, i]).tolist()


def test_reading_many_branches_at_once_gives_each_branch_s_numbers():
    emap = equilibrium_map(load_scene('fig1_asymmetric').segments)
    index, total = [], []
    for b, branch in enumerate(emap.branches):
        # Across the branch, and next to its ends, where the states are solved exactly.
        inside = np.linspace(branch.lo, branch.hi, 25)
        near = [branch.lo + 1e-7 * (branch.hi - branch.lo),
                branch.hi - 1e-7 * (branch.hi - branch.lo)]
        for t in [*inside, *near]:
            index.append(b)
            total.append(t)
    many = emap.reader.rows_many(np.array(index), np.array(total))
    assert any(branch.any_rough for branch in emap.branches)
    for b in range(len(emap.branches)):
        rows = np.flatnonzero(np.array(index) == b)
        one = emap.reader.rows(b, np.array(total)[rows])
        assert many[rows].tolist() == one.tolist()


def least_between_rows(segment, lo, hi):
    """A table's least stiffness on the intervals between rows that [lo, hi] reaches."""
    breaks, _, slope = segment.pressure_cubics()
    first = min(max(int(np.searchsorted(breaks, lo, side='right')) - 1, 0), breaks.size - 2)
    last = min(max(int(np.searchsorted(breaks, hi, side='left')), first + 1), breaks.size - 1)
    least = np.inf
    for i in range(first, last):
        derivative = np.poly1d(slope[:, i])
        width = breaks[i + 1] - breaks[i]
        turns = [s.real for s in derivative.deriv().roots if 0.0 < s.real < width]
        least = min(least, *(derivative(s) for s in [0.0, width, *turns]))
    return least


def test_certifying_many_balls_at_once_gives_each_ball_s_radius():
    numerics = SegmentNumerics(gent_segments(table=True))
    rng = np.random.default_rng(11)
    centres = rng.uniform(numerics.rest_volumes, numerics.max_volumes, (120, 3))
    offsets = np.linspace(-1.0, 1.0, PROBES)

    def radius(centre):
        room = np.min(np.minimum(centre - numerics.rest_volumes,
                                 numerics.max_volumes - centre))
        for share in RADII:
            r = share * numerics.v_scale
            if r >= room:
                continue
            k = []
            for segment, c in zip(numerics.segments, centre):
                k.append(min(np.min(segment.stiffness(c + r * offsets)),
                             least_between_rows(segment, c - r, c + r)))
            k = np.array(k) / numerics.k_scale
            if np.sum(k < 0.0) <= 1 and cofactor_sum(k) > numerics.tolerances.stable_cofactor:
                return r
        return 0.0

    expected = [radius(c) for c in centres]
    assert 0 < sum(r > 0 for r in expected) < len(expected)
    assert certified_radii(numerics, centres).tolist() == expected
