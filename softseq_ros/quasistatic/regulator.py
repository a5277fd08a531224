"""
Segments under pressure control: each one an independent hysteron.

A pressure regulator holds the common pressure p wherever the fluid goes, so the segments no
longer share a fixed volume: each one sits at p on a rising piece of its own curve (a falling
piece is unstable alone at a held pressure), whatever the others do. Raised past the top of
its piece (a peak), a segment jumps at that pressure to the next rising piece that reaches p;
lowered past the bottom of its piece (a valley), it jumps back to the rising piece below. This
is the model hysteron theory starts from (each segment flips at its peak pressure and back at
its valley); the coupling through the shared volume that encodes the paper's sequence is gone.
:func:`regulated_path` follows a history of gauge pressures so, from rest.
"""

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from softseq_ros.errors import UserError
from softseq_ros.segments.models import Segment, piece_holding, rising_pieces

FloatArray = NDArray[np.float64]


class PressureDomainError(UserError):
    """A commanded pressure that some segment's curve does not reach on any rising piece."""


@dataclass(frozen=True)
class Flip:
    """
    One segment's jump, on the way to command ``row``.

    At ``pressure`` [Pa], the peak (rising) or valley (falling) it passed, from
    ``from_volume`` (that end of its piece) to ``to_volume`` [m^3] (the piece it lands on, at
    the same pressure).
    """

    row: int
    segment: int
    pressure: float
    from_volume: float
    to_volume: float


@dataclass
class RegulatedPath:
    """Per commanded pressure: each segment's volume [m^3] and curvature [1/m], and the flips."""

    pressure: FloatArray
    volumes: FloatArray
    curvatures: FloatArray
    flips: list[Flip] = field(default_factory=list)
    rest_volume: float = 0.0    # the segments' rest volumes together [m^3]
    time_s: FloatArray | None = None    # a programme's times [s], when it had any

    @property
    def injected(self) -> FloatArray:
        """What the regulator has let in since rest [m^3]."""
        return self.volumes.sum(axis=1) - self.rest_volume


class HysteronTracker:
    """
    The segments under a held pressure, one command after another: each on its rising pieces.

    Every segment starts on its first rising piece (at rest), or on the piece that holds the
    volume :meth:`place` gives it. :meth:`move` takes the next gauge pressure.
    """

    def __init__(self, segments: Sequence[Segment]) -> None:
        self.segments = tuple(segments)
        self.pieces = [rising_pieces(segment) for segment in self.segments]
        for segment, rising in zip(self.segments, self.pieces):
            if not rising:
                raise PressureDomainError(f'segment {segment.name!r} never rises: no state of '
                                          'it is stable at a held pressure')
        self.current = [0] * len(self.segments)

    def place(self, volumes: Sequence[float]) -> None:
        """Each segment on the rising piece nearest its volume [m^3] (a resumed state)."""
        for i, (rising, volume) in enumerate(zip(self.pieces, volumes)):
            self.current[i] = min(range(len(rising)), key=lambda k: max(
                rising[k].v_lo - volume, volume - rising[k].v_hi, 0.0))

    def move(self, target: float, row: int = 0) -> tuple[list[float], list[Flip]]:
        """
        Each segment's volume [m^3] at the gauge pressure ``target`` [Pa], and its flips.

        A pressure above the top of a segment's piece moves it up to the first rising piece
        above that reaches the pressure, one below the bottom of its piece down to the last
        rising piece below that does (a :class:`Flip` each, at ``row``); a pressure no rising
        piece of a segment reaches raises :class:`PressureDomainError` (naming ``row`` and the
        segment) and leaves every segment where it was.
        """
        if not np.isfinite(target):
            raise PressureDomainError(f'row {row}: a commanded pressure must be finite')
        places = list(self.current)
        for i, (segment, rising) in enumerate(zip(self.segments, self.pieces)):
            at: int | None = places[i]
            if target > rising[at].p_max:
                at = piece_holding(rising, target, range(at + 1, len(rising)))
            elif target < rising[at].p_min:
                at = piece_holding(rising, target, range(at - 1, -1, -1))
            if at is None:
                raise PressureDomainError(
                    f'row {row}: {target:.6g} Pa is beyond what segment {segment.name!r} '
                    f'holds on a stable piece ({rising[0].p_min:.6g} to '
                    f'{max(r.p_max for r in rising):.6g} Pa)')
            places[i] = at
        volumes, flips = [], []
        for i, (segment, rising) in enumerate(zip(self.segments, self.pieces)):
            at = places[i]
            volumes.append(float(segment.invert(rising[at], np.array([target]))[0]))
            if at != self.current[i]:
                before = rising[self.current[i]]
                # A pressure raised or lowered steadily jumps where it passes the piece's end.
                up = target > before.p_max
                edge_p, edge_v = (before.p_max, before.v_hi) if up else (before.p_min,
                                                                         before.v_lo)
                landed = float(segment.invert(rising[at], np.array([edge_p]))[0])
                flips.append(Flip(row, i, edge_p, edge_v, landed))
        self.current = places
        return volumes, flips


def regulated_path(segments: Sequence[Segment], pressures: ArrayLike) -> RegulatedPath:
    """
    Follow gauge pressures [Pa] from rest, each segment on its own rising pieces.

    Every segment starts on its first rising piece (:class:`HysteronTracker`); a pressure no
    rising piece of a segment reaches raises :class:`PressureDomainError`, naming the row and
    the segment.
    """
    p = np.asarray(pressures, dtype=float).ravel()
    if not np.all(np.isfinite(p)):
        raise PressureDomainError(f'row {int(np.argmax(~np.isfinite(p)))}: a commanded '
                                  'pressure must be finite')
    tracker = HysteronTracker(segments)
    volumes = np.empty((p.size, len(tracker.segments)))
    flips: list[Flip] = []
    for row, target in enumerate(p.tolist()):
        volumes[row], found = tracker.move(target, row)
        flips += found
    curvatures = np.column_stack([np.asarray(s.curvature(volumes[:, i]), dtype=float)
                                  for i, s in enumerate(tracker.segments)]) if p.size else \
        np.empty((0, len(tracker.segments)))
    return RegulatedPath(p, volumes, curvatures, flips,
                         float(sum(segment.rest_volume for segment in tracker.segments)))


@dataclass(frozen=True)
class HysteronState:
    """
    One stable state under a regulator: each segment's rising piece (``pieces``, indices).

    It holds for every pressure from ``p_low`` to ``p_high`` [Pa] (the highest valley and the
    lowest peak of its pieces); ``label`` names each segment's piece, e.g. ``0/1``.
    """

    index: int
    pieces: tuple[int, ...]
    p_low: float
    p_high: float

    @property
    def label(self) -> str:
        """Each segment's rising piece, base to tip, as ``0/1/0``."""
        return '/'.join(str(k) for k in self.pieces)


@dataclass(frozen=True)
class HysteronFlip:
    """
    Leaving state ``source`` at ``pressure`` [Pa]: the ``segments`` that jump.

    Raised past a peak (``up``) or lowered past a valley, they land in ``target`` (None: a
    pressure no rising piece of some segment reaches, the end of the domain).
    """

    source: int
    up: bool
    pressure: float
    segments: tuple[int, ...]
    target: int | None


@dataclass
class HysteronGraph:
    """The states and flips of segments under pressure control, from rest (state 0)."""

    names: tuple[str, ...]
    states: list[HysteronState]
    flips: list[HysteronFlip]

    def to_dict(self) -> dict:
        """The graph as graph.json holds it (SI: gauge pressures in Pa)."""
        return {
            'supply': 'pressure regulator (independent hysterons)',
            'segments': list(self.names),
            'states': [{'index': s.index, 'label': s.label, 'pieces': list(s.pieces),
                        'gauge_pa_low': s.p_low, 'gauge_pa_high': s.p_high}
                       for s in self.states],
            'flips': [{'from': f.source, 'to': f.target,
                       'direction': 'up' if f.up else 'down', 'gauge_pa': f.pressure,
                       'segments': [self.names[i] for i in f.segments]}
                      for f in self.flips]}


def hysteron_graph(segments: Sequence[Segment]) -> HysteronGraph:
    """
    Every state a pressure history from rest reaches, and the flips between them.

    From a state, raising the pressure flips the segments whose piece peaks lowest, at that
    peak, each onto its first rising piece above that reaches it; lowering flips those whose
    piece bottoms highest, at that valley, each onto its last rising piece below that reaches
    it (what :func:`regulated_path` does row by row). Segments peaking at the same pressure
    flip together. The states are numbered in the order they are first reached.
    """
    pieces = [rising_pieces(segment) for segment in segments]
    for segment, rising in zip(segments, pieces):
        if not rising:
            raise PressureDomainError(f'segment {segment.name!r} never rises: no state of it is '
                                      'stable at a held pressure')

    def bounds(state: tuple[int, ...]) -> tuple[float, float]:
        return (max(rising[k].p_min for rising, k in zip(pieces, state)),
                min(rising[k].p_max for rising, k in zip(pieces, state)))

    def landing(i: int, at: int, pressure: float, up: bool) -> int | None:
        rising = pieces[i]
        order = range(at + 1, len(rising)) if up else range(at - 1, -1, -1)
        return next((k for k in order if rising[k].p_min <= pressure <= rising[k].p_max), None)

    rest = tuple(0 for _ in segments)
    index = {rest: 0}
    states = [HysteronState(0, rest, *bounds(rest))]
    flips: list[HysteronFlip] = []
    queue = [rest]
    while queue:
        state = queue.pop(0)
        low, high = bounds(state)
        for up in (True, False):
            edge = high if up else low
            ends = [rising[k].p_max if up else rising[k].p_min
                    for rising, k in zip(pieces, state)]
            jumping = tuple(i for i, end in enumerate(ends) if end == edge)
            landed = [landing(i, state[i], edge, up) for i in jumping]
            if not up and all(k is None for k in landed) and edge <= bounds(rest)[0]:
                continue    # below the rest state's valley: nothing to lower into
            target: int | None = None
            if all(k is not None for k in landed):
                moved = list(state)
                for i, k in zip(jumping, landed):
                    moved[i] = k
                new = tuple(moved)
                if new not in index:
                    index[new] = len(states)
                    states.append(HysteronState(len(states), new, *bounds(new)))
                    queue.append(new)
                target = index[new]
            flips.append(HysteronFlip(index[state], up, float(edge), jumping, target))
    return HysteronGraph(tuple(s.name for s in segments), states, flips)
