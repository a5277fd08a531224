"""The ``softseq fem`` command: a segment table from a design, or a sweep of designs."""

import argparse
import sys
import time
from typing import Any

import yaml

from softseq_ros.scene.design import (
    Design,
    DesignError,
    design_path,
    load_design,
    with_changes,
)
from softseq_ros.scene.validation import YamlLoader


def _value(text: str) -> Any:
    try:
        # The scene files' reading of numbers, so 3e-6 is a number here too.
        return yaml.load(text, Loader=YamlLoader)  # noqa: S506 (a SafeLoader subclass)
    except yaml.YAMLError:
        return text


def _assignments(items: list[str], option: str, many: bool) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition('=')
        if not sep or not key or not value:
            example = 'KEY=V1,V2,...' if many else 'KEY=VALUE'
            raise DesignError(f'{option} {item!r}: expected {example}, e.g. '
                              'geometry.membrane_thickness_m=0.0005')
        if key in out:
            raise DesignError(f'{option} {key}: given twice')
        out[key] = [_value(v) for v in value.split(',')] if many else _value(value)
    return out


def _actuator(args: argparse.Namespace, changes: dict[str, Any]) -> int:
    """``softseq fem BOTTOM TOP --model actuator``: the whole actuator on one cavity."""
    from softseq_ros.fem.actuator import actuator_table_for, check_actuator
    from softseq_ros.progress import end_progress, write_progress

    for option, value in (('--sweep', args.sweep), ('--out-dir', args.out_dir),
                          ('--workers', args.workers), ('--scheduler', args.scheduler)):
        if value:
            raise DesignError(f'{option}: not with --model actuator')
    designs = [load_design(design_path(name)) for name in args.design]
    changes = {**changes, 'mesh.model': 'whole_segment'}
    designs = [with_changes(design, changes) for design in designs]
    check_actuator(designs)
    start = time.perf_counter()
    stream = None if args.quiet else sys.stderr
    path, computed, _ = actuator_table_for(
        designs, out=args.out, cache_dir=args.cache_dir, use_cache=not args.no_cache,
        progress=None if stream is None else (lambda line: write_progress(stream, line)))
    end_progress(stream)
    how = (f'computed in {time.perf_counter() - start:.1f} s' if computed
           else 'from the cache')
    print(f'actuator {" + ".join(d.name for d in designs)}: table {path} ({how})')
    return 0


def run_fem_command(args: argparse.Namespace) -> int:
    """Run ``softseq fem`` with parsed arguments; a bad input raises before any work."""
    changes = _assignments(args.set, '--set', many=False)
    if args.model == 'actuator':
        return _actuator(args, changes)
    if len(args.design) != 1:
        raise DesignError(f'{" ".join(args.design)}: one design, or several (base to tip) with '
                          '--model actuator')
    design: Design = load_design(design_path(args.design[0]))
    if args.model is not None:
        changes['mesh.model'] = args.model
    if changes:
        design = with_changes(design, changes)
    show = None if args.quiet else (lambda line: print(line, file=sys.stderr, flush=True))
    if not args.sweep:
        for option, value in (('--out-dir', args.out_dir), ('--workers', args.workers),
                              ('--scheduler', args.scheduler)):
            if value is not None:
                raise DesignError(f'{option}: only with --sweep')
        from softseq_ros.fem.table import table_for

        start = time.perf_counter()
        path, computed = table_for(design, out=args.out, cache_dir=args.cache_dir,
                                   use_cache=not args.no_cache,
                                   stream=None if args.quiet else sys.stderr)
        how = (f'computed in {time.perf_counter() - start:.1f} s' if computed
               else 'from the cache')
        print(f'{design.name}: table {path} ({how}; design hash {design.digest()})')
        return 0

    from softseq_ros.fem.sweep import run_sweep, sweep_cases
    from softseq_ros.parallel import workers_or_scheduler

    grid = _assignments(args.sweep, '--sweep', many=True)
    if args.out_dir is None:
        raise DesignError('--sweep: needs --out-dir for the tables and summary.csv')
    if args.out is not None:
        raise DesignError('--out: not with --sweep (tables go to --out-dir)')
    workers = workers_or_scheduler(args.workers, args.scheduler, DesignError)
    cases = sweep_cases(design, grid)
    start = time.perf_counter()
    summary = run_sweep(cases, args.out_dir, workers=workers, scheduler=args.scheduler,
                        progress=show)
    where = f'Dask scheduler {args.scheduler}' if args.scheduler else f'{workers} local workers'
    print(f'{design.name}: {len(cases)} designs on {where} in '
          f'{time.perf_counter() - start:.1f} s -> {summary}')
    return 0
