"""
The quasi-static solver's tolerances and iteration budgets, and whether its solves converged.

Two loops iterate: the inversion of a segment's curve on one monotone piece (pressure to
volume, :meth:`softseq_ros.segments.models.Segment.invert`) and the exact states next to a fold
(:class:`softseq_ros.quasistatic.states.StateReader`). Both are safeguarded Newton iterations
inside a bracket: a step that would leave the bracket halves it instead, so they cannot
diverge, and they stop at round-off. Their budgets exceed what a double needs (a bracket
halves to round-off in about 64 steps), so a solve that runs out of its budget is a sign of a
curve the models did not foresee (a NaN, a discontinuity): it is logged, never silent.

``EquilibriumMap(segments, tolerances=Tolerances(...))`` sets them; ``emap.convergence`` holds
the log, and ``softseq solve`` and ``softseq classify`` print it when anything did not
converge.
"""

from dataclasses import dataclass, field


@dataclass(frozen=True)
class Tolerances:
    """Iteration budgets and what counts as round-off, for the quasi-static solver."""

    # Safeguarded Newton steps inverting one monotone piece of a segment's curve.
    inversion_steps: int = 96
    # Safeguarded Newton steps on the common pressure of a state next to a fold.
    polish_steps: int = 64
    # Round-off: this many units in the last place of the quantity (or machine epsilons of its
    # scale) count as zero.
    round_off_ulps: float = 4.0
    # Volumes closer than this share of the volume scale are the same (branch ends, joins).
    same_volume: float = 1e-9
    # A snap-through's redistribution flow starts this share of the volume scale off the fold
    # and is integrated to these tolerances in scaled units: relative to the state, or, where
    # that is looser, to how far the state has moved from the fold (the escape from the fold,
    # at a millionth of the range at first, is followed to flow_rtol of the state, the way
    # across to flow_rtol_moved of the way; softseq_ros.quasistatic.landing). It is at rest
    # when the scaled pressures balance to flow_rest; a state is stable when the cofactor sum
    # of its scaled stiffnesses exceeds stable_cofactor; the branch it lands on lies within
    # landing_distance (a share of the volume scale) of where the flow came to rest.
    fold_offset: float = 1e-6
    flow_rtol: float = 1e-6
    flow_rtol_moved: float = 1e-4
    flow_atol: float = 1e-12
    flow_rest: float = 1e-9
    stable_cofactor: float = 1e-6
    landing_distance: float = 1e-3

    def __post_init__(self) -> None:
        """Refuse budgets that cannot work."""
        for name in ('inversion_steps', 'polish_steps'):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f'tolerances: {name} must be an integer >= 1, got {value!r}')
        if not self.round_off_ulps >= 1.0:
            raise ValueError(f'tolerances: round_off_ulps must be >= 1, got '
                             f'{self.round_off_ulps!r}')


DEFAULT_TOLERANCES = Tolerances()


@dataclass
class ConvergenceLog:
    """Per kind of iterative solve: how many ran, and how many ended without converging."""

    runs: dict[str, int] = field(default_factory=dict)
    unconverged: dict[str, int] = field(default_factory=dict)

    def record(self, kind: str, converged: bool) -> None:
        """Count one vectorised solve of ``kind`` (all its points converged, or not)."""
        self.runs[kind] = self.runs.get(kind, 0) + 1
        if not converged:
            self.unconverged[kind] = self.unconverged.get(kind, 0) + 1

    @property
    def converged(self) -> bool:
        """Whether every solve so far reached round-off within its budget."""
        return not self.unconverged

    def summary(self) -> str:
        """One line: the solves and whether they converged."""
        parts = [f'{kind} {self.runs[kind] - self.unconverged.get(kind, 0)}/{self.runs[kind]}'
                 for kind in sorted(self.runs)]
        state = 'all converged' if self.converged else 'NOT all converged'
        return f'iterative solves {state} ({", ".join(parts) or "none ran"})'
