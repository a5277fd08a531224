"""What ``softseq design`` reports: lines for people, the designs found and results.yaml."""

from dataclasses import replace
from pathlib import Path
from typing import Any

from softseq_ros.fem.design_evaluation import plain_metrics
from softseq_ros.fem.design_problem import Target
from softseq_ros.fem.design_search import SearchResult
from softseq_ros.scene.design import with_changes


def values_text(values: dict[str, float]) -> str:
    """Parameter values for people: millimetres."""
    return ', '.join(f'{k.removesuffix("_m")} {v * 1e3:.3f} mm' for k, v in values.items()) \
        or 'as designed'


def numbers_text(metrics: dict[str, Any], target: Target) -> str:
    """A pair's sequence, leader, switch, plateau and tip in one line."""
    switch = metrics.get('switch_injected_m3')
    parts = [f'{metrics.get("sequence")}', f'{metrics.get("leader")} leads',
             f'switch {switch * 1e6:.1f} mL' if switch is not None else 'no switch',
             f'plateau {metrics.get("plateau_pressure_pa", float("nan")):.0f} Pa from '
             f'{metrics.get("plateau_from_m3", float("nan")) * 1e6:.1f} mL']
    if target.tip_at_m3 is not None and 'tip_distance_m' in metrics:
        parts.append(f'tip {metrics["tip_distance_m"] * 1e3:.0f} mm from the base at '
                     f'{target.tip_at_m3 * 1e6:g} mL')
    return ', '.join(parts)


def write_result_files(result: SearchResult, out: Path) -> list[Path]:
    """Design files of the ranked pairs and results.yaml (SI) into ``out``."""
    import yaml

    out.mkdir(parents=True, exist_ok=True)
    problem = result.problem
    written = []
    rows = []
    for rank, evaluation in enumerate(result.ranked, start=1):
        material = problem.materials[evaluation.material]
        files = {}
        for segment, values in zip(problem.segments, evaluation.values):
            design = replace(segment.design, material=material)
            if values:
                design = with_changes(design, {f'geometry.{k}': v for k, v in values.items()})
            data = {'name': f'{problem.name}_{rank}_{segment.name}',
                    'description': f'found by softseq design for {problem.name} (rank {rank}): '
                                   f'{numbers_text(evaluation.metrics, problem.target)}',
                    'geometry': {k: v for k, v in design.geometry.__dict__.items()
                                 if v is not None and not (k == 'skin_band_thickness_m'
                                                           and design.geometry.wall_reading
                                                           == 'skin_bands')},
                    'material': {'law': material.law, **material.params},
                    'mesh': dict(design.mesh.__dict__), 'volume': dict(design.volume.__dict__)}
            path = out / f'{data["name"]}.yaml'
            path.write_text(yaml.safe_dump(data, sort_keys=False))
            written.append(path)
            files[segment.name] = path.name
        rows.append({'rank': rank, 'score': float(evaluation.score), 'designs': files,
                     'parameters': {s.name: v for s, v in zip(problem.segments,
                                                              evaluation.values)},
                     'predicted': plain_metrics(evaluation.metrics)})
    summary = {'problem': str(problem.path) if problem.path else problem.name,
               'ranked': rows, 'assembled_pairs': result.evaluations,
               'fem_runs': result.fem_runs, 'grid_tables': result.grid_tables,
               'timings_s': {k: round(v, 2) for k, v in result.timings.items()},
               'reach': {k: list(v) for k, v in result.reach.bounds.items()},
               'reach_notes': result.reach.notes,
               'corner_pairs': result.reach.corner_pairs,
               'verified': result.verified,
               'verification': (plain_metrics(result.verification.metrics)
                                if result.verification else None)}
    path = out / 'results.yaml'
    path.write_text('# softseq design: ranked designs (SI units, gauge pressures)\n'
                    + yaml.safe_dump(summary, sort_keys=False))
    written.append(path)
    return written


def write_best_scene(result: SearchResult, out: Path,
                     flow_rate_m3_per_s: float = 5.0e-8) -> Path | None:
    """
    A runnable scene of the best design into ``out`` (None when nothing was ranked).

    Its segments name the design files written beside it (``design:``), so their tables are
    `softseq fem`'s of those files, at their own mesh; the pump inflates to the target's
    ``max_injected_m3`` at 0.05 mL/s (the paper's rig), holds 10 s and deflates to 0.
    """
    import yaml

    if not result.ranked:
        return None
    problem = result.problem
    best = result.ranked[0]
    designs = [f'{problem.name}_1_{segment.name}.yaml' for segment in problem.segments]
    # A varied length is the design file's too: the scene must give the same.
    lengths = [values.get('length_m', segment.design.geometry.length_m)
               for segment, values in zip(problem.segments, best.values)]
    name = f'{problem.name}_best'
    commands = ' && '.join(f'softseq fem {out / design}' for design in designs)
    data = {
        'name': name,
        'description': f'the best design softseq design found for {problem.name}: predicted '
                       f'{numbers_text(best.metrics, problem.target)}',
        'segments': [{'name': segment.name, 'length_m': length, 'design': design}
                     for segment, length, design in zip(problem.segments, lengths, designs)],
        'pump': {'flow_rate_m3_per_s': flow_rate_m3_per_s, 'rate_hz': 50.0,
                 'legs': [{'inflate_to_m3': problem.target.max_injected_m3}, {'hold_s': 10.0},
                          {'deflate_to_m3': 0.0}]},
    }
    path = out / f'{name}.yaml'
    path.write_text(f'# Written by softseq design: the best design of {problem.name} as a scene.\n'
                    f'# Its tables come from the design files beside it, at their own mesh:\n'
                    f'#   {commands}\n#   softseq run {path}\n'
                    + yaml.safe_dump(data, sort_keys=False))
    return path
