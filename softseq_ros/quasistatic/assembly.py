"""
Assembling the equilibrium set: monotone pieces, configurations, stable stretches.

Each segment's PV curve splits into monotone pieces; choosing one piece per segment (a
*configuration*) makes every volume a function of the common pressure p, so the equilibrium set
is a union of curves parametrised by p (the paper's "assembling algorithm"). Each configuration
is sampled at the pressures its pieces contribute; its stable stretches (D > 0) end at folds
(D = 0, solved exactly) or where a piece ends, and become branches (softseq_ros.quasistatic.
branches). How branches end (continue, snap, limit) is decided afterwards
(softseq_ros.quasistatic.branch_ends).

What keeps an eight-segment map affordable (1280 configurations): a segment's volume on a piece
at a pressure does not depend on the configuration, so every piece is inverted once on one
sorted set of all the pressures any configuration samples (:class:`SharedGrid`), and each
configuration reads its volumes from there; the folds of all configurations are solved side by
side (:func:`~softseq_ros.quasistatic.roots.brent_roots`), as are the branches' checks and splits.
"""

from dataclasses import dataclass
import math

import numpy as np
from numpy.typing import NDArray

from softseq_ros.quasistatic.branches import Branch, BranchSamples, fit_branches
from softseq_ros.quasistatic.numerics import FloatArray, SegmentNumerics, cofactor_sum
from softseq_ros.quasistatic.roots import brent_roots
from softseq_ros.segments.models import Piece

# A fold's pressure is found to this share of the pressure scale (and a relative tolerance at
# round-off): the fold is where the branch's volumes turn, located to the last bits.
FOLD_PRESSURE_XTOL = 1e-14
FOLD_PRESSURE_RTOL = 1e-15
# How far inside a configuration's pressure range (a share of the pressure scale) its stability
# is looked at where its end is not stable: a stable stretch shorter than the samples' spacing
# can lie against an end where several segments reach a peak or a valley together
# (Assembly._stable_between_unstable_samples).
BESIDE_END = 1e-10


@dataclass
class EquilibriumCurve:
    """One configuration's equilibria (stable and unstable), for plotting."""

    injected: FloatArray
    volumes: FloatArray
    pressure: FloatArray
    stable: NDArray[np.bool_]


class SharedGrid:
    """
    The pressures every configuration samples, in one sorted set; every piece inverted on it once.

    A configuration samples the pressures its pieces contribute inside the range where all its
    pieces overlap, and the range's ends; all of them are in :attr:`p`. Each piece is inverted
    at the grid's pressures inside its own range, once (elementwise, so the same numbers as
    one inversion per configuration), and a configuration gathers its columns from there.
    """

    def __init__(self, numerics: SegmentNumerics,
                 samples: dict[tuple[int, Piece], FloatArray]) -> None:
        """``samples``: per (segment, piece), the pressures the piece contributes."""
        self.numerics = numerics
        extremes = [np.array([piece.p_min, piece.p_max]) for _, piece in samples]
        self.p = np.unique(np.concatenate([*samples.values(), *extremes]))
        # Per piece: its samples' places in the grid, and its volumes and stiffnesses on the
        # stretch of the grid inside its range (from ``start``).
        self.members = {key: np.unique(np.searchsorted(self.p, values))
                        for key, values in samples.items()}
        self.start: dict[tuple[int, Piece], int] = {}
        self.volumes: dict[tuple[int, Piece], FloatArray] = {}
        self.stiffness: dict[tuple[int, Piece], FloatArray] = {}
        self.curvature_slope: dict[tuple[int, Piece], FloatArray] = {}
        for key in samples:
            index, piece = key
            lo = int(np.searchsorted(self.p, piece.p_min, side='left'))
            hi = int(np.searchsorted(self.p, piece.p_max, side='right'))
            volumes = numerics.invert_piece(index, piece, self.p[lo:hi])
            numerics.remember_inversions(index, piece, self.p[lo:hi], volumes)
            self.start[key] = lo
            self.volumes[key] = volumes
            self.stiffness[key] = numerics.piece_stiffness(index, piece, volumes)
            self.curvature_slope[key] = numerics.segments[index].curvature_slope(volumes)

    def sample(self, config: tuple[Piece, ...]) -> NDArray[np.intp] | None:
        """The grid places ``config`` samples (sorted), or None where its pieces do not overlap."""
        p_lo = max(pc.p_min for pc in config)
        p_hi = min(pc.p_max for pc in config)
        if not p_hi > p_lo:
            return None
        lo = int(np.searchsorted(self.p, p_lo))
        hi = int(np.searchsorted(self.p, p_hi))
        chosen = np.zeros(hi - lo + 1, dtype=bool)
        chosen[0] = chosen[-1] = True
        for key in enumerate(config):
            members = self.members[key]
            inside = members[np.searchsorted(members, lo, side='right'):
                             np.searchsorted(members, hi, side='left')]
            chosen[inside - lo] = True
        return lo + np.flatnonzero(chosen)

    def columns(self, config: tuple[Piece, ...], places: NDArray[np.intp],
                what: tuple[str, ...] = ('volumes', 'stiffness')) -> list[FloatArray]:
        """Volumes, scaled stiffnesses or curvature slopes (n, N) of ``config`` at ``places``."""
        keys = list(enumerate(config))
        return [np.stack([getattr(self, name)[key][places - self.start[key]] for key in keys],
                         axis=1) for name in what]


@dataclass
class _Sampled:
    """A configuration sampled on the shared grid: where, and which samples are stable."""

    config: tuple[Piece, ...]
    places: NDArray[np.intp]
    stable: NDArray[np.bool_]


class Assembly:
    """The stable branches and the whole equilibrium set (for plots) of some segments."""

    def __init__(self, numerics: SegmentNumerics, resolution: int) -> None:
        """
        Assemble every configuration's branches at ``resolution`` samples per segment.

        Where the samples step over a stable stretch (:meth:`_stable_between_unstable_samples`),
        every piece also samples the pressures that find it (:attr:`also_sampled`).
        """
        self.numerics = numerics
        self.resolution = int(resolution)
        self.configurations = self._configurations()
        self.also_sampled = np.empty(0)
        self.grid = self._sample_grid()
        missed = self._stable_between_unstable_samples()
        if missed.size:
            self.also_sampled = np.unique(missed)
            self.grid = self._sample_grid()
        # Per configuration, in order: where it is sampled and which samples are stable.
        self._sampled: list[_Sampled] = []
        stretches = self._stretches()
        self.branches: list[Branch] = [b for b in fit_branches(numerics, stretches)
                                       if b is not None]

    def _configurations(self) -> list[tuple[Piece, ...]]:
        """Piece tuples that can hold a stable equilibrium: at most one falling piece."""
        found = []

        def extend(prefix: tuple[Piece, ...], p_lo: float, p_hi: float, falling: int) -> None:
            if len(prefix) == len(self.numerics.pieces):
                found.append(prefix)
                return
            for piece in self.numerics.pieces[len(prefix)]:
                lo, hi = max(p_lo, piece.p_min), min(p_hi, piece.p_max)
                fall = falling + (piece.direction < 0)
                if lo <= hi and fall <= 1:
                    extend(prefix + (piece,), lo, hi, fall)

        extend((), -math.inf, math.inf, 0)
        return found

    def _sample_grid(self) -> SharedGrid:
        self._samples: dict[tuple[int, Piece], FloatArray] = {}
        return SharedGrid(self.numerics, {
            (i, pc): self._piece_samples(i, pc) for config in self.configurations
            for i, pc in enumerate(config)})

    def _stable_between_unstable_samples(self) -> FloatArray:
        """
        Pressures where a configuration is stable between two of its unstable samples.

        The samples can step over a stable stretch shorter than their spacing, in two places:

        - against an end where two or more segments reach a peak or a valley together
          (identical tables), which is unstable (every stiffness there 0, or two falling),
          while the stretch next to it can be stable for less than 1 Pa: looked at
          :data:`BESIDE_END` inside such an end;
        - where a rising and a falling segment's stiffnesses nearly cancel (D about 0 over
          several pascals) and a table's stiffness, a quadratic between two of its rows, turns
          between two samples: looked at every volume where a segment's stiffness is extreme
          (:meth:`SegmentNumerics.stiffness_extremes`) between two unstable samples.

        Those that are stable are sampled too: the stretch is then found like any other, its
        folds solved on both sides. Nothing is added where no stretch was missed, so every
        other map keeps its samples.
        """
        numerics = self.numerics
        extremes = [np.sort(seg.pressure(numerics.stiffness_extremes(i)))
                    for i, seg in enumerate(numerics.segments)]
        rows, pressures = [], []
        for config in self.configurations:
            places = self.grid.sample(config)
            if places is None or places.size < 2:
                continue
            stiffness, = self.grid.columns(config, places, ('stiffness',))
            unstable = cofactor_sum(stiffness) <= 0.0
            p = self.grid.p[places]
            probes = []
            step = min(BESIDE_END * numerics.p_scale, 0.25 * (p[-1] - p[0]))
            if unstable[0] and unstable[1]:
                probes.append(p[0] + step)
            if unstable[-1] and unstable[-2]:
                probes.append(p[-1] - step)
            gaps = unstable[:-1] & unstable[1:]
            if gaps.any():
                for i, piece in enumerate(config):
                    found = extremes[i][(extremes[i] > max(p[0], piece.p_min))
                                        & (extremes[i] < min(p[-1], piece.p_max))]
                    probes.extend(found[gaps[np.searchsorted(p, found) - 1]].tolist())
            rows.extend([numerics.piece_indices(config)] * len(probes))
            pressures.extend(probes)
        if not rows:
            return np.empty(0)
        pressures = np.array(pressures)
        _, stiffness = numerics.states_at(np.array(rows, dtype=np.intp), pressures)
        return pressures[cofactor_sum(stiffness) > 0.0]

    def curves(self) -> list[EquilibriumCurve]:
        """Every configuration's equilibria, stable and unstable, in configuration order."""
        found: list[EquilibriumCurve] = []
        for entry in self._sampled:
            volumes, = self.grid.columns(entry.config, entry.places, ('volumes',))
            total = volumes.sum(axis=1)
            found.append(EquilibriumCurve(total - self.numerics.total_rest_volume, volumes,
                                          self.grid.p[entry.places], entry.stable))
        return found

    def _stretches(self) -> list[BranchSamples]:
        """Every configuration's stable stretches, their folds solved side by side."""
        # A stretch is (config, its grid places, the fold pressures at its ends) until the
        # folds are known.
        pending: list[tuple[tuple[Piece, ...], NDArray[np.intp], list[int]]] = []
        # (configuration, grid places, the folds below and above it: -1 for none)
        folds: list[tuple[tuple[Piece, ...], float, float, float, float]] = []
        for config in self.configurations:
            places = self.grid.sample(config)
            if places is None:
                continue
            stiffness, = self.grid.columns(config, places, ('stiffness',))
            d = cofactor_sum(stiffness)
            stable = d > 0.0
            self._sampled.append(_Sampled(config, places, stable))
            p = self.grid.p[places]
            edges = np.flatnonzero(np.diff(stable.astype(np.int8)))
            starts = [0] + list(edges + 1)
            stops = list(edges + 1) + [p.size]
            for start, stop in zip(starts, stops):
                if not stable[start]:
                    continue
                ends = [-1, -1]
                # The fold between the last unstable and the first stable sample, and back.
                for side, (a, b) in enumerate(((start - 1, start), (stop - 1, stop))):
                    if 0 <= a and b < p.size:
                        ends[side] = len(folds)
                        folds.append((config, float(p[a]), float(p[b]), float(d[a]),
                                      float(d[b])))
                pending.append((config, places[start:stop], ends))
        fold_p = self._folds(folds)
        # The states at the folds, all inverted at once.
        at_volumes, at_stiffness = self.numerics.states_at(
            np.array([self.numerics.piece_indices(f[0]) for f in folds],
                     dtype=np.intp).reshape(-1, len(self.numerics.segments)), fold_p)
        at_curvature = self.numerics.curvature_slopes(at_volumes)
        stretches = []
        for config, places, (lower, upper) in pending:
            pressure = self.grid.p[places]
            # A fold lies between its two samples: before the stretch's first sample or
            # after its last; at a sample's own pressure, the sample stands for it.
            before = [lower] if lower >= 0 and fold_p[lower] < pressure[0] else []
            after = [upper] if upper >= 0 and fold_p[upper] > pressure[-1] else []
            columns = self.grid.columns(config, places,
                                        ('volumes', 'stiffness', 'curvature_slope'))
            if before or after:
                pressure = np.concatenate([fold_p[before], pressure, fold_p[after]])
                columns = [np.concatenate([at[before], column, at[after]]) for column, at in
                           zip(columns, (at_volumes, at_stiffness, at_curvature))]
            stretches.append(BranchSamples(pressure, *columns, config))
        return stretches

    def _folds(self, folds: list[tuple[tuple[Piece, ...], float, float, float, float]]
               ) -> FloatArray:
        """
        Pressures where D = 0 between two samples of opposite stability, all at once.

        Brent's method on D(p), each step inverting every configuration's pieces at once
        (:func:`brent_roots`: the roots scipy's ``brentq`` gives, to the bit). An end where D
        is exactly 0 is the fold itself.
        """
        if not folds:
            return np.empty(0)
        pieces = np.array([self.numerics.piece_indices(f[0]) for f in folds], dtype=np.intp)
        p_a, p_b, d_a, d_b = (np.array(column) for column in list(zip(*folds))[1:])

        def cofactor_sums(indices: NDArray[np.intp], p: FloatArray) -> FloatArray:
            return cofactor_sum(self.numerics.states_at(pieces[indices], p)[1])

        roots = np.where(d_a == 0.0, p_a, p_b)
        solve = np.flatnonzero((d_a != 0.0) & ~((d_b == 0.0) | (d_a * d_b > 0.0)))
        if solve.size:
            roots[solve] = brent_roots(
                lambda rows, p: cofactor_sums(solve[rows], p), p_a[solve], p_b[solve],
                d_a[solve], d_b[solve], xtol=FOLD_PRESSURE_XTOL * self.numerics.p_scale,
                rtol=FOLD_PRESSURE_RTOL)
        return roots

    def _piece_samples(self, index: int, piece: Piece) -> FloatArray:
        """
        The pressures segment ``index`` contributes on ``piece``, computed once.

        They are the same in every configuration: samples evenly spaced along its curve, the
        model's own knots, so the cubics never straddle a kink, and the pressures
        ``also_sampled`` inside its range.
        """
        key = (index, piece)
        if key not in self._samples:
            seg = self.numerics.segments[index]
            count = max(32, int(math.ceil(self.resolution * seg.arclength_share(piece))))
            knots = seg.knots()
            knots = knots[(knots > piece.v_lo) & (knots < piece.v_hi)]
            volumes = np.concatenate([seg.arclength_samples(piece, count), knots])
            extra = self.also_sampled[(self.also_sampled > piece.p_min)
                                      & (self.also_sampled < piece.p_max)]
            if extra.size:
                volumes = np.concatenate([volumes, self.numerics.invert_piece(index, piece,
                                                                              extra)])
            self._samples[key] = seg.pressure(volumes)
            # Each sample is a volume and its pressure: a bracket for every later inversion.
            order = np.argsort(self._samples[key], kind='stable')
            self.numerics.remember_inversions(index, piece, self._samples[key][order],
                                              volumes[order])
        return self._samples[key]
