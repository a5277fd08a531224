"""The ``softseq`` command: one subcommand per job."""

import argparse
from datetime import datetime, timezone
import math
import os
from pathlib import Path
import signal
import sys
from typing import Any, Callable, NoReturn, Sequence

from softseq_ros.errors import UserError, one_line
from softseq_ros.ros_tools.command import add_ros_parser
from softseq_ros.stopping import TerminatedError, raise_terminated

# A user's input that cannot be used, or a file the system cannot read or write: one line.
# Anything else is a bug and keeps its traceback.
USER_ERRORS: tuple[type[BaseException], ...] = (UserError, OSError)


def _solve(args: argparse.Namespace) -> int:
    import softseq_ros
    from softseq_ros.dynamic.path import PathError
    from softseq_ros.quasistatic.equilibrium import DomainError
    from softseq_ros.quasistatic.graph import branch_labels
    from softseq_ros.quasistatic.reach import beyond_domain
    from softseq_ros.quasistatic.solve import read_timed_history, scene_map, write_path

    if args.pressure_path is not None:
        return _solve_regulated(args)
    scene = softseq_ros.load_scene(args.scene)
    if scene.regulator is not None and args.path is None:
        return _solve_regulator_scene(args, scene)
    times, history = (None, None) if args.path is None else read_timed_history(args.path)
    try:
        solved = softseq_ros.solve(scene, history, times=times)
    except PathError as err:
        if history is None:
            raise
        raise PathError(f'{args.path}: {err}' if times is not None
                        else f'{args.path}: injected_m3: {err}') from None
    except DomainError as err:
        if err.row is None or history is None:
            raise
        reason = beyond_domain(float(history[err.row]), err, scene_map(scene),
                               scene.segment_names)
        raise DomainError(f'{args.path}: injected_m3 in data row {err.row + 1}: {reason}') \
            from None
    if scene.network is not None:
        return _write_network_path(args, scene, solved, timed=times is not None)
    write_path(args.out, solved, scene.segment_names)
    emap = scene_map(scene)
    _warn_unconverged('solve', emap)
    snaps = ', '.join(f'{e.injected * 1e6:.3f} mL' for e in solved.events) or 'none'
    print(f'{scene.name}: {solved.injected.size} commanded volumes solved -> {args.out} '
          f'(snap-throughs: {snaps})')
    if solved.branch.size:
        # The numbering of softseq graph: where a history ends, on the map of every branch.
        last = int(solved.branch[-1])
        print(f'  ends at {solved.injected[-1] * 1e6:.4g} mL injected on branch {last} '
              f'({branch_labels(emap)[last]}) of softseq graph')
    if times is not None:
        print(f'  {args.path}: time_s read; a quasi-static path follows the volumes in order, '
              'their times do not change it (a scene with a network follows them in time)')
    return 0


def _solve_regulated(args: argparse.Namespace) -> int:
    """``solve --pressure-path``: the segments behind an ideal regulator, independent hysterons."""
    import softseq_ros
    from softseq_ros.quasistatic.regulator import PressureDomainError, regulated_path
    from softseq_ros.quasistatic.solve import read_pressure_history, write_regulated_path

    if args.path is not None:
        raise UserError('give --path (volumes, a syringe) or --pressure-path (pressures, a '
                        'regulator), not both')
    scene = softseq_ros.load_scene(args.scene)
    for key, block in (('network', scene.network), ('supply', scene.supply)):
        if block is not None:
            raise UserError(f'{args.scene}: {key}: a regulator holds the pressure at the '
                            f"segments, so the syringe's {key} is not on its path: give "
                            f'--pressure-path a scene without a {key}')
    pressures = read_pressure_history(args.pressure_path)
    try:
        solved = regulated_path(scene.segments, pressures)
    except PressureDomainError as err:
        raise PressureDomainError(f'{args.pressure_path}: gauge_pa: {err}') from None
    names = scene.segment_names
    write_regulated_path(args.out, solved, names)
    print(f'{scene.name}: {pressures.size} regulated gauge pressures solved (each segment an '
          f'independent hysteron) -> {args.out} (flips: {len(solved.flips)})')
    _print_flips(solved, names)
    return 0


def _solve_regulator_scene(args: argparse.Namespace, scene: Any) -> int:
    """``solve`` on a scene behind a pressure regulator: its programme, quasi-static or in time."""
    import softseq_ros
    from softseq_ros.quasistatic.solve import write_regulated_path

    solved = softseq_ros.solve(scene)
    if scene.network is not None:
        return _write_network_path(args, scene, solved, timed=False)
    names = scene.segment_names
    write_regulated_path(args.out, solved, names)
    print(f"{scene.name}: the regulator's programme, {solved.pressure.size} gauge pressures "
          f'solved (each segment an independent hysteron) -> {args.out} (flips: '
          f'{len(solved.flips)})')
    _print_flips(solved, names)
    return 0


def _print_flips(solved: Any, names: Sequence[str]) -> None:
    """Each flip of a regulated path, one line each."""
    for flip in solved.flips:
        way = 'up past its peak' if flip.to_volume > flip.from_volume else 'down past its valley'
        print(f'  row {flip.row + 1}: {names[flip.segment]} flips {way} at '
              f'{flip.pressure * 1e-3:.4f} kPa, {flip.from_volume * 1e6:.4f} -> '
              f'{flip.to_volume * 1e6:.4f} mL')


def _write_network_path(args: argparse.Namespace, scene: Any, path: Any, timed: bool) -> int:
    """``solve`` on a scene with a network: the path in time, and its snap-throughs beside it."""
    from softseq_ros.analysis.text import duration_text
    from softseq_ros.dynamic.events import fold_crossing_line
    from softseq_ros.dynamic.network import laminar_range_warning
    from softseq_ros.dynamic.path import (
        folds_file,
        snaps_file,
        write_folds,
        write_path,
        write_snaps,
    )
    from softseq_ros.scene.network import LAMINAR, channel_names

    snaps_out, folds_out = snaps_file(args.out), folds_file(args.out)
    write_path(args.out, path, scene.segment_names)
    write_snaps(snaps_out, path.snaps, scene.segment_names, line=scene.supply is not None)
    write_folds(folds_out, path.folds)
    if scene.regulator is not None:
        pushed = "the regulator's programme of pressures"
    elif timed:
        pushed = f'at the times of {args.path}'
    else:
        pushed = f'pump at {scene.pump.profile.flow_rate * 1e6:g} mL/s'

    print(f'{scene.name}: {path.time_s.size} samples of the network in time, {pushed} -> '
          f'{args.out} (exchanges: {len(path.snaps)}, snap-throughs: '
          f'{sum(s.snap_through for s in path.snaps)} -> {snaps_out}; fold crossings: '
          f'{len(path.folds)} -> {folds_out})')
    for crossing in path.folds:
        print(f'  {fold_crossing_line(crossing)}')
    for snap in path.snaps:
        what = 'snap-through' if snap.snap_through else 'exchange (no instability)'
        print(f'  {what} at {snap.start_s:.6g} s, {snap.injected * 1e6:.3f} mL injected: '
              f'{snap.fluid_moved_m3 * 1e6:.3f} mL moved, peak '
              f'{snap.peak_exchange_m3_per_s * 1e6:.4g} mL/s, 10-90 % in '
              f'{duration_text(snap.duration_s)}'
              + (', still under way at the last sample' if snap.cut_short else ''))
    channels = channel_names(scene.segment_names)
    print('  peak Reynolds number per channel: ' + ', '.join(
        f'{name} {peak:.0f}' for name, peak in zip(channels, path.peak_reynolds)))
    for name, peak, tube in zip(channels, path.peak_reynolds, scene.network.channels):
        line = laminar_range_warning(name, peak, tube.friction != LAMINAR)
        if line is not None:
            print(f'softseq solve: warning: {line}', file=sys.stderr)
    if path.drained is not None:
        print(f'softseq solve: warning: the path ends at {path.time_s[-1]:.6g} s '
              f'({path.injected[-1] * 1e6:.4g} mL injected): {path.drained}', file=sys.stderr)
    return 0


def _warn_unconverged(command: str, emap: Any) -> None:
    """Say so when an iterative solve of the map ran out of its budget (never silently)."""
    if not emap.convergence.converged:
        print(f'softseq {command}: warning: {emap.convergence.summary()}; the results may be '
              'off by more than round-off (softseq_ros.tolerances)', file=sys.stderr)


def _classify(args: argparse.Namespace) -> int:
    import softseq_ros
    from softseq_ros.analysis.robustness import robustness_lines, scene_features
    from softseq_ros.quasistatic.solve import scene_map

    scene = softseq_ros.load_scene(args.scene)
    verdict = softseq_ros.classify(scene)
    emap = scene_map(scene)
    _warn_unconverged('classify', emap)
    print(f'{scene.name}: {verdict}')
    lines, warnings = robustness_lines(verdict, *scene_features(scene, emap))
    for line in lines:
        print(line)
    for warning in warnings:
        print(f'softseq classify: warning: {warning}', file=sys.stderr)
    return 0


def _graph(args: argparse.Namespace) -> int:
    import softseq_ros
    from softseq_ros.analysis.graph_figure import check_figure_size, plot_graph
    from softseq_ros.quasistatic.graph import write_graph_json
    from softseq_ros.quasistatic.solve import scene_map

    if args.reversals is not None and args.reversals < 0:
        raise UserError(f'--reversals must be >= 0, got {args.reversals}')
    style = _figure_style(args)
    scene = softseq_ros.load_scene(args.scene)
    if args.regulator or scene.regulator is not None:
        return _regulated_graph(args, scene, style)
    graph = softseq_ros.graph(scene)
    # Before anything is written: a figure of too many branches exhausted the memory after
    # graph.json was written.
    check_figure_size(graph, str(args.scene))
    emap = scene_map(scene)
    out = args.out if args.out is not None else Path('bags') / f'graph_{scene.name}'
    out.mkdir(parents=True, exist_ok=True)
    write_graph_json(out / 'graph.json', graph, args.reversals)
    plot_graph(graph, out / 'graph.png', emap, args.reversals, style=style)
    _warn_unconverged('graph', emap)
    least = graph.min_reversals()
    off_path = [b.index for b in graph.branches if not b.default_path]
    print(f'{scene.name}: {len(graph.branches)} stable branches, {len(graph.snaps())} snaps, '
          f'{sum(b.default_path for b in graph.branches)} on the default path -> '
          f'{out / "graph.json"}, {out / "graph.png"}')
    for index in off_path:
        reach = graph.history_to(index)
        if reach.reversals is None:
            print(f'  branch {index} ({graph.branches[index].label}): no history reaches it')
        else:
            turns = ', '.join(f'{v * 1e6:.4g}' for v in reach.history)
            print(f'  branch {index} ({graph.branches[index].label}): {reach.reversals} '
                  f'reversals, turning volumes [{turns}] mL')
    if args.reversals is not None:
        within = sum(c is not None and c <= args.reversals for c in least.values())
        print(f'  {within} of {len(graph.branches)} branches within {args.reversals} reversals')
    return 0


def _regulated_graph(args: argparse.Namespace, scene: Any, style: Any) -> int:
    """``graph --regulator``: the states and flips of the segments as independent hysterons."""
    import json

    from softseq_ros.analysis.graph_figure import plot_hysteron_graph
    from softseq_ros.quasistatic.regulator import hysteron_graph

    if args.reversals is not None:
        raise UserError('--reversals counts volume reversals of a syringe; with --regulator '
                        'every state is listed with the flips that reach it')
    graph = hysteron_graph(scene.segments)
    out = args.out if args.out is not None else Path('bags') / f'graph_{scene.name}_regulator'
    out.mkdir(parents=True, exist_ok=True)
    (out / 'graph.json').write_text(json.dumps(graph.to_dict(), indent=1) + '\n')
    plot_hysteron_graph(graph, out / 'graph.png', style=style)
    print(f'{scene.name} behind a pressure regulator: {len(graph.states)} stable states, '
          f'{sum(f.target is not None for f in graph.flips)} flips -> {out / "graph.json"}, '
          f'{out / "graph.png"}')
    names = graph.names
    for state in graph.states:
        print(f'  state {state.index} (pieces {state.label}): {state.p_low * 1e-3:.4f} to '
              f'{state.p_high * 1e-3:.4f} kPa')
        for flip in (f for f in graph.flips if f.source == state.index):
            where = ('beyond every stable piece' if flip.target is None
                     else f'to state {flip.target}')
            print(f'    {"up" if flip.up else "down"} at {flip.pressure * 1e-3:.4f} kPa: '
                  f'{" and ".join(names[i] for i in flip.segments)} {where}')
    return 0


class StartTimeError(UserError):
    """A ``--start-time`` that is no time a bag can carry."""


# A bag's times are int64 nanoseconds since 1970: from 1970 to 2262-04-11.
LAST_START_NS = 2**63 - 1


def start_time_ns(text: str) -> int:
    """
    A bag start time: ISO 8601 (``2026-01-01T00:00:00Z``) or seconds since the epoch.

    StartTimeError (one line) for text that is neither, or a time a bag cannot carry: before
    1970, infinite, or beyond int64 nanoseconds (the year 2262).
    """
    try:
        seconds = float(text)
    except ValueError:
        try:
            when = datetime.fromisoformat(text.replace('Z', '+00:00'))
        except ValueError:
            raise StartTimeError(f'--start-time: {text!r} is neither ISO 8601 '
                                 '(2026-01-01T00:00:00Z) nor seconds since 1970') from None
        if when.tzinfo is None:
            when = when.replace(tzinfo=timezone.utc)
        seconds = when.timestamp()
    if not math.isfinite(seconds) or not 0.0 <= seconds * 1e9 <= LAST_START_NS:
        raise StartTimeError(f'--start-time: {text!r} is outside what a bag can carry: from '
                             f'1970 (0 s) to 2262 ({LAST_START_NS // 10**9} s), as int64 ns')
    return min(int(round(seconds * 1e9)), LAST_START_NS)


def _run(args: argparse.Namespace) -> int:
    from softseq_ros.batch import run

    # Parsed here, not by argparse: a refusal is one line, without the usage text.
    start = None if args.start_time is None else start_time_ns(args.start_time)
    held = {}
    if args.hold_gauge_pa is not None:
        from softseq_ros.rig.controller import PressureHold

        if args.hold_for_s is None:
            raise UserError('--hold-gauge-pa needs --hold-for-s: how long the controller '
                            'drives the pump [s of rig time]')
        for option, value in (('--hold-gauge-pa', args.hold_gauge_pa),
                              ('--hold-for-s', args.hold_for_s)):
            if not math.isfinite(value) or (option == '--hold-for-s' and value <= 0.0):
                raise UserError(f'{option}: must be a finite number'
                                + (' of seconds > 0' if option == '--hold-for-s' else '')
                                + f', got {value}')
        held = {'controller': PressureHold(args.hold_gauge_pa), 'controlled_s': args.hold_for_s}
    elif args.hold_for_s is not None:
        raise UserError('--hold-for-s goes with --hold-gauge-pa')
    result = run(args.scene, args.out, progress=None if args.quiet else sys.stderr,
                 log=sys.stderr, start_time_ns=start, allow_long=args.allow_long, **held)
    print(f'{args.out}: {result.sim_duration_s:.1f} s of rig time in {result.wall_s:.1f} s '
          f'({result.speedup:.0f}x real time), {sum(result.message_counts.values())} messages, '
          f'pump {result.pump_state}')
    if not args.no_report:
        _write_report(args.out, args.scene, None, args.out / 'report')
    return 0


def _report(args: argparse.Namespace) -> int:
    from softseq_ros.analysis.figure_workers import start_workers, stop_workers

    # Before anything else is imported: the worker loads matplotlib while the bag is read.
    workers = start_workers(args.svg)
    try:
        _write_report(args.bag, args.scene, args.experiment, args.out or args.bag / 'report',
                      reference=args.reference, namespace=args.namespace, svg=args.svg,
                      workers=workers, style=_figure_style(args))
    finally:
        stop_workers(workers)
    return 0


def _figure_style(args: argparse.Namespace) -> Any:
    """The figures' look from --style, --width and --dpi (refused in one line if unusable)."""
    from softseq_ros.analysis.figures import FigureStyle

    return FigureStyle(args.style, args.width, args.dpi)


def _write_report(bag: Path, scene_name: str | None, experiment_csv: Path | None,
                  out: Path, reference: Path | None = None, namespace: str | None = None,
                  svg: bool = False, workers: object | None = None,
                  style: Any = None) -> None:
    import softseq_ros

    _, text = softseq_ros.report(bag, out, scene=scene_name, experiment=experiment_csv,
                                 reference=reference, namespace=namespace, svg=svg,
                                 workers=workers, style=style)
    print(text)
    print(f'report: {out / "report.md"}, {out / "metrics.json"}, figures in {out}')


def _compare(args: argparse.Namespace) -> int:
    import json

    from softseq_ros.analysis.compare import compare_bags

    _figure_style(args)   # an unusable --style, --width or --dpi is refused before reading
    scene = None
    if args.scene is not None:
        from softseq_ros import load_scene
        from softseq_ros.scene.loader import require_syringe

        scene = load_scene(args.scene)
        require_syringe(scene, 'softseq compare --scene (the volume-controlled equilibrium '
                               'beside the recordings)')
    metrics_a, metrics_b, table = compare_bags(args.a, args.b, args.namespace_a,
                                               args.namespace_b, scene=scene)
    print(table, end='')
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / 'compare.md').write_text(table)
        (args.out / 'compare.json').write_text(json.dumps({'a': metrics_a, 'b': metrics_b},
                                                          indent=2) + '\n')
        figure = _compare_figure(args)
        print(f'written: {args.out / "compare.md"}, {args.out / "compare.json"}, '
              + ', '.join(str(path) for path in figure))
    return 0


def _figure_options(parser: argparse.ArgumentParser) -> None:
    """--style, --width and --dpi: how a command's figures look."""
    parser.add_argument('--style', choices=('paper', 'screen'), default='paper',
                        help='paper (default): no titles, 8 pt type, sized for a journal '
                        'column or page, 300 dpi, cropped to what is drawn; screen: short '
                        'titles, larger, 110 dpi')
    parser.add_argument('--width', type=float, metavar='INCHES',
                        help="every figure's width in inches, its height in proportion (3.5: "
                        'a journal column, 7.2: a page; default: each figure its own)')
    parser.add_argument('--dpi', type=float, help='PNG resolution in dots per inch (default '
                        '300 for paper, 110 for screen)')


def _compare_figure(args: argparse.Namespace) -> list[Path]:
    """compare.png: both bags' curves over each other, in the figure style asked for."""
    from softseq_ros.analysis.compare import write_overlay, write_transients_overlay

    style = _figure_style(args)
    return (write_overlay(args.a, args.b, args.out, args.namespace_a, args.namespace_b, style)
            # and around each snap-through in time, when either bag has one
            + write_transients_overlay(args.a, args.b, args.out, args.namespace_a,
                                       args.namespace_b, style))


def _library(args: argparse.Namespace) -> int:
    from softseq_ros.analysis.library import write_library
    from softseq_ros.parallel import worker_option

    jobs = worker_option('--jobs', args.jobs)
    style = _figure_style(args)
    out = args.out or Path('bags') / f'library_{Path(args.source).stem}'
    _, table = write_library(args.source, out, args.triples, args.length_m, jobs, style=style)
    print(table, end='')
    print(f'written: {out / "library.md"}, {out / "library.json"}, {out / "library.png"}')
    return 0


def _rates(args: argparse.Namespace) -> int:
    from softseq_ros import load_scene
    from softseq_ros.analysis.rates import (
        MAX_SAMPLES_PER_LEG,
        RatesError,
        check_grid,
        quasistatic_reference,
        rates_figure,
        rates_markdown,
        reference_line,
        run_rates,
        write_rates_csv,
    )
    from softseq_ros.errors import check_output_folder
    from softseq_ros.parallel import scheduler_option
    from softseq_ros.scene.loader import require_syringe

    def numbers(option: str, text: str) -> list[float]:
        try:
            return [float(item) for item in text.split(',')]
        except ValueError:
            raise RatesError(f'{option}: {text!r} is not a comma-separated list of numbers') \
                from None

    def count(option: str, text: str | None, least: int) -> int | None:
        if text is None:
            return None
        try:
            value = int(text)
        except ValueError:
            raise RatesError(f'{option}: {text!r} is not a whole number') from None
        if value < least:
            raise RatesError(f'{option}: must be >= {least}, got {value}')
        return value

    flows, radii = numbers('--flows', args.flows), numbers('--radii', args.radii)
    samples = count('--samples', args.samples, 50)
    if samples is not None and samples > MAX_SAMPLES_PER_LEG:
        raise RatesError(f'--samples: must be <= {MAX_SAMPLES_PER_LEG} (samples of the path '
                         f'per leg, held in memory by every worker: 1e6 take 0.5 GB and the '
                         f'default is 600), got {samples}')
    workers = count('--workers', args.workers, 1)
    scheduler = scheduler_option('--scheduler', args.scheduler)
    if scheduler is not None and workers is not None:
        raise RatesError('--workers: not with --scheduler (the cluster has its own workers)')
    style = _figure_style(args)
    scene = load_scene(args.scene)
    require_syringe(scene, 'softseq rates')
    check_grid(scene, flows, radii)
    out = args.out or Path('bags') / f'rates_{scene.name}'
    check_output_folder(out, '--out' if args.out is not None else 'the output folder')
    reference = quasistatic_reference(scene, samples)
    rows = run_rates(scene, flows, radii, workers=workers, scheduler=scheduler,
                     samples_per_leg=samples)
    table = write_rates_csv(out / 'rates.csv', rows, scene.name, reference)
    figure = rates_figure(rows, scene.segment_names, reference, scene.name, out / 'rates.png',
                          style)
    print(reference_line(reference))
    print(rates_markdown(rows), end='')
    print(f'written: {table}, {figure}')
    return 0


def _fit(args: argparse.Namespace) -> int:
    from softseq_ros.analysis.fit_inputs import read_fit_inputs
    from softseq_ros.analysis.fit_outputs import summary_lines, write_fit_outputs
    from softseq_ros.errors import check_output_folder
    from softseq_ros.segments.fit import FIT_LAWS, Bulge, FitError, fit_cycles, rest_volume_of

    # Every option before any file is read: a mistake costs no fit.
    for option, value in (('--radius-m', args.radius_m), ('--thickness-m', args.thickness_m),
                          ('--length-m', args.length_m), ('--hole-radius-m', args.hole_radius_m)):
        if value is not None and not (math.isfinite(value) and value > 0.0):
            raise FitError(f'{option}: must be a finite length > 0 (m), got {value}')
    bulge_options = (('--hole-radius-m', args.hole_radius_m),
                     ('--membrane-count', args.membrane_count),
                     ('--rest-volume-m3', args.rest_volume_m3),
                     ('--wall-compliance-m3-per-pa', args.wall_compliance_m3_per_pa))
    if args.geometry == 'sphere':
        for option, value in bulge_options:
            if value is not None:
                raise FitError(f"{option}: a bulge's (--geometry bulge); a sphere's size is "
                               '--radius-m')
    else:
        if args.radius_m is not None:
            raise FitError("--radius-m: a sphere's; a bulge's holes are --hole-radius-m")
        if args.hole_radius_m is None:
            raise FitError('--geometry bulge needs --hole-radius-m: the radius of the holes the '
                           'membranes bulge out of [m]')
        if args.membrane_count is not None and args.membrane_count < 1:
            raise FitError(f'--membrane-count: a number of membranes >= 1, got '
                           f'{args.membrane_count}')
        if args.rest_volume_m3 is not None and not (math.isfinite(args.rest_volume_m3)
                                                    and args.rest_volume_m3 > 0.0):
            raise FitError(f'--rest-volume-m3: must be a finite volume > 0 (m^3), got '
                           f'{args.rest_volume_m3}')
        compliance = args.wall_compliance_m3_per_pa
        if compliance is not None and not (math.isfinite(compliance) and compliance >= 0.0):
            raise FitError(f'--wall-compliance-m3-per-pa: must be a finite compliance >= 0 '
                           f'(m^3/Pa), got {compliance}')
    if args.bootstrap < 0:
        raise FitError(f'--bootstrap: a number of resamples >= 0, got {args.bootstrap}')
    laws = [name.strip() for name in args.laws.split(',')] if args.laws else list(FIT_LAWS)
    unknown = [name for name in laws if name not in FIT_LAWS]
    if unknown or not laws:
        raise FitError(f'--laws: unknown law {", ".join(unknown) or "(none)"}; known: '
                       f'{", ".join(FIT_LAWS)}')
    style = _figure_style(args)
    check_output_folder(args.out, '--out')
    geometry = None
    if args.geometry == 'bulge':
        geometry = Bulge(args.hole_radius_m, args.membrane_count or 1, args.rest_volume_m3,
                         args.wall_compliance_m3_per_pa or 0.0)
    # The volumes' unit is checked against the segment's size where it is known.
    size = args.length_m if args.length_m is not None else (
        None if args.radius_m is None else 2.0 * args.radius_m)
    if size is None and geometry is not None:
        size = 2.0 * geometry.hole_radius * geometry.membrane_count
    # An experiment's injected volume is added to the rest volume: the sphere's at R, or the
    # bulge's cavity.
    try:
        rest_volume = args.rest_volume_m3 if geometry is not None else (
            None if args.radius_m is None else rest_volume_of(args.radius_m))
    except OverflowError:
        raise FitError(f'--radius-m: {args.radius_m} m: its sphere holds more than any number '
                       'can say (4/3 pi R^3 overflows); radii are in m') from None
    inputs = read_fit_inputs(args.inputs, args.segment, rest_volume, size)
    fit = fit_cycles(inputs.cycles, radius=args.radius_m, thickness=args.thickness_m, laws=laws,
                     bootstrap=args.bootstrap, seed=args.seed, geometry=geometry)
    written = write_fit_outputs(fit, args.out, args.length_m, style)
    for line in summary_lines(fit, written):
        print(line)
    for note in inputs.notes + fit.notes:
        print(f'softseq fit: warning: {note}', file=sys.stderr)
    return 0


def _scatter(args: argparse.Namespace) -> int:
    from softseq_ros import load_scene
    from softseq_ros.analysis.scatter import (
        ScatterError,
        check_settings,
        correlation_of,
        parameters_of,
        read_correlate,
        read_vary,
        run_scatter,
    )
    from softseq_ros.analysis.scatter_outputs import summary_lines, write_scatter_outputs
    from softseq_ros.errors import check_output_folder
    from softseq_ros.parallel import scheduler_option, worker_option
    from softseq_ros.progress import end_progress, write_progress

    # Every option before the scene is loaded: a mistake costs no run.
    for option, value in (('--until-width', args.until_width),
                          ('--confidence', args.confidence)):
        if value is not None and not math.isfinite(value):
            raise ScatterError(f'{option}: must be a finite number, got {value}')
    if args.seed < 0:
        raise ScatterError(f'--seed: a whole number >= 0, got {args.seed}')
    vary = read_vary(args.vary, args.spec)
    correlate = read_correlate(args.correlate, args.spec)
    check_settings(args.samples, args.until_width, args.confidence, args.sobol,
                   max(len(vary), 1), args.fem_points)
    workers = worker_option('--workers', args.workers)
    scheduler = scheduler_option('--scheduler', args.scheduler)
    if scheduler is not None and workers is not None:
        raise ScatterError('--workers: not with --scheduler (the cluster has its own workers)')
    style = _figure_style(args)
    scene = load_scene(args.scene)
    parameters = parameters_of(scene, vary)
    correlation = correlation_of(parameters, correlate)
    out = args.out or Path('bags') / f'scatter_{scene.name}'
    check_output_folder(out, '--out' if args.out is not None else 'the output folder')
    stream = None if args.quiet else sys.stderr
    result = run_scatter(scene, parameters, samples=args.samples, until_width=args.until_width,
                         confidence=args.confidence, seed=args.seed, sobol=args.sobol,
                         workers=workers, scheduler=scheduler,
                         backend='dask' if scheduler is not None else 'processes',
                         progress=None if stream is None else
                         (lambda line: write_progress(stream, line)),
                         fem_points=args.fem_points, correlation=correlation)
    end_progress(stream)
    written = write_scatter_outputs(result, out, style)
    for line in summary_lines(result, written):
        print(line)
    stop = result.stop
    if stop['reached'] is False:
        print(f'softseq scatter: warning: the widest interval is {stop["widest_interval"]:.3g}, '
              f'not {stop["until_width"]:g}, after {stop["samples"]} samples: give more '
              '--samples', file=sys.stderr)
    if result.summary['unconverged_samples']:
        print(f'softseq scatter: warning: {result.summary["unconverged_samples"]} samples ran '
              "out of the solver's budget (softseq_ros.tolerances)", file=sys.stderr)
    return 0


def _play(args: argparse.Namespace) -> int:
    from softseq_ros.stopping import HeldSignals

    # Held from before rclpy loads: a signal inside its import would end in an ImportError.
    with HeldSignals() as held:
        from softseq_ros.nodes.player import PlayError, parse_remaps, play, rate_reason

        reason = rate_reason(args.rate)
        if reason is not None:
            raise PlayError(f'--{reason}')
        for option, seconds in (('--start-offset', args.start_offset),
                                ('--wait-for-subscribers', args.wait_for_subscribers)):
            if not (math.isfinite(seconds) and seconds >= 0.0):
                raise PlayError(f'{option}: must be a finite number of seconds >= 0, got '
                                f'{seconds}')

        result = play(str(args.bag), rate=args.rate, loop=args.loop, clock=args.clock,
                      topics=args.topics, wait_s=args.wait_for_subscribers, held=held,
                      start_offset_s=args.start_offset, remap=parse_remaps(args.remap),
                      qos_overrides_path=args.qos_profile_overrides_path)
    print(f'{args.bag}: {result.messages} messages replayed in {result.loops} pass(es)')
    return 0


def _recover(args: argparse.Namespace) -> int:
    from softseq_ros.bag.recovery import recover

    result = recover(args.bag)
    if result.was_complete:
        print(f'{args.bag}: complete, {result.message_count} messages, every chunk passes its '
              'CRC; metadata.yaml rewritten')
        return 0
    lost = result.dropped_messages
    dropped = (f'dropped: {len(result.dropped)} part(s), '
               f'{"an unknown number of" if lost is None else lost} messages'
               if result.dropped or lost else 'nothing in the file dropped')
    print(f'{args.bag}: recovered {result.message_count} messages into {result.mcap_path}'
          f' (damaged original kept as {result.damaged_copy}); {dropped}; '
          f'{result.stop_reason}')
    for part in result.dropped:
        print(f'  dropped {part.describe()}')
    return 0


def _info(args: argparse.Namespace) -> int:
    from softseq_ros.bag.info import bag_info, format_info

    print(format_info(bag_info(args.bag)))
    return 0


def _design(args: argparse.Namespace) -> int:
    from softseq_ros.fem.design_command import run_design_command

    return run_design_command(args)


def _fem(args: argparse.Namespace) -> int:
    from softseq_ros.fem.command import run_fem_command

    return run_fem_command(args)


def _scenes(args: argparse.Namespace) -> int:
    import yaml

    from softseq_ros.scene.paths import config_dir, shipped_scenes

    print(f'shipped scenes in {config_dir()}:')
    names = shipped_scenes()
    width = max(map(len, names), default=0)
    for name in names:
        # The description as the file gives it, read without building the scene's segments.
        try:
            text = yaml.safe_load((config_dir() / f'{name}.yaml').read_text(encoding='utf-8'))
            described = ' '.join(str(text.get('description', '')).split())
            # A network puts time into the physics: its sequence depends on the pump's rate.
            kind = 'in time, a network' if text.get('network') is not None else 'quasi-static'
            if isinstance(text.get('supply'), dict) and 'regulator' in text['supply']:
                # Not on the rig: softseq run refuses it, solve and graph take it.
                kind += ', a pressure regulator'
        except (OSError, ValueError, AttributeError, yaml.YAMLError):
            described, kind = '', '?'
        print(f'  {name:<{width}}  [{kind}] {described}'.rstrip())
    return 0


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose mistakes are one line, as every other refusal of softseq."""

    def error(self, message: str) -> NoReturn:
        """Missing, unknown or malformed arguments: one line, exit 2 (usage: --help)."""
        self.exit(2, f'{self.prog}: error: {one_line(message)} (see {self.prog} --help)\n')


def _given(what: str) -> Any:
    """An argparse type: the text as given, refusing an empty word (it would name no file)."""
    def given(text: str) -> str:
        if not text.strip():
            raise argparse.ArgumentTypeError(f'empty; give {what}')
        return text
    return given


def _given_path(what: str) -> Any:
    """As :func:`_given`, as a Path."""
    return lambda text: Path(_given(what)(text))


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every subcommand."""
    parser = OneLineParser(
        prog='softseq',
        description='Emulated rig of a soft actuator with a hardware-encoded inflation sequence.')
    sub = parser.add_subparsers(dest='command', required=True, metavar='COMMAND')

    solve = sub.add_parser('solve', help='quasi-static inflation sequence along a volume history',
                           description='Solve the hardware-encoded equilibrium along a history '
                           'of commanded injected volumes (the history matters).')
    solve.add_argument('scene', help='scene YAML file, or the name of a shipped scene')
    solve.add_argument('--path', type=Path, help='CSV with a column injected_m3, in order, '
                       "and optionally time_s (default: the scene's pump profile at the pump "
                       "rate; with a network, pushed from row to row at the pump's flow rate, "
                       "or at each row's time_s, holds included)")
    solve.add_argument('--pressure-path', type=Path, help='CSV with a column gauge_pa [Pa], in '
                       'order: the segments behind an ideal pressure regulator instead of the '
                       'syringe, each an independent hysteron (docs/supply.md); writes each '
                       "row's volumes and what the regulator let in, and the flips")
    solve.add_argument('--out', type=Path, required=True, help='output CSV file; with a '
                       'network (docs/dynamic.md) the path in time (time_s first, each '
                       "segment's pressure and the channel flows added) and its snap-throughs "
                       '(start, duration, fluid moved, peak flow) in OUT_snaps.csv beside it')
    solve.set_defaults(handler=_solve)

    classify = sub.add_parser('classify', help="the paper's sequence type of a scene",
                              description='Print none, partial, symmetric or asymmetric.')
    classify.add_argument('scene', help='scene YAML file, or the name of a shipped scene')
    classify.set_defaults(handler=_classify)

    run = sub.add_parser('run', help='run the rig in batch mode and record it to a bag',
                         description='Run the pump, actuator and camera cores in one process '
                         'in lock-step simulated time, as fast as the machine allows, record '
                         'every topic to an MCAP bag and write a summary with figures.')
    run.add_argument('scene', help='scene YAML file, or the name of a shipped scene')
    run.add_argument('--out', type=Path, required=True,
                     help='bag directory to create (for example bags/paper)')
    run.add_argument('--quiet', action='store_true', help='no progress line')
    run.add_argument('--start-time', metavar='TIME',
                     help='the simulated clock at the start, as ISO 8601 or seconds since '
                     '1970 (default: now); the same scene and start time give the same bag')
    run.add_argument('--allow-long', action='store_true',
                     help='run a programme beyond the limits of a batch run (1e6 s of rig '
                     'time, 1e8 messages, 10 GB of bag; docs/faults.md) all the same')
    run.add_argument('--no-report', action='store_true', help='skip the summary and figures')
    run.add_argument('--hold-gauge-pa', type=float, metavar='PA',
                     help="instead of the scene's programme, the example PI controller holds "
                     "this gauge pressure [Pa] through the pump's setpoints "
                     '(docs/controllers.md); with --hold-for-s')
    run.add_argument('--hold-for-s', type=float, metavar='S',
                     help='how long the controller drives the pump [s of rig time]')
    run.set_defaults(handler=_run)

    report = sub.add_parser('report', help='summary and figures of a recorded bag',
                            description='Summarise a rig bag and draw the paper-style figures, '
                            'optionally beside a measured PV curve.')
    report.add_argument('bag', type=Path, help='bag directory (metadata.yaml and .mcap)')
    report.add_argument('--scene', type=_given('a scene file or a shipped scene name'),
                        help='scene of the run: adds the segment curves and the '
                        'equilibrium set to the figures')
    report.add_argument('--experiment', type=_given_path('an experiment file'),
                        help='experiment CSV (injected_m3, '
                        'pressure_pa, optional direction, tip_x_m, tip_z_m; "# pressure_kind: '
                        'gauge|absolute"; see docs/analysis.md)')
    report.add_argument('--reference', type=_given_path('a reference file'),
                        help='YAML of what a paper reports (e.g. '
                        'config/reference/milana2018.yaml): each fact beside the recording')
    report.add_argument('--namespace', help='rig namespace when the bag holds several rigs')
    svg = report.add_mutually_exclusive_group()
    # SVG takes as long again as PNG to draw: asked for, not the default.
    svg.add_argument('--svg', action='store_true', help='SVG figures too (for print), beside '
                     'the PNGs')
    svg.add_argument('--no-svg', action='store_false', dest='svg',
                     help='PNG figures only (the default)')
    report.add_argument('--out', type=Path, help='folder for the report (default BAG/report)')
    _figure_options(report)
    report.set_defaults(handler=_report)

    compare = sub.add_parser('compare', help='two bags side by side, the same metrics',
                             description='Read two rig bags (two resolutions, two scenes, a '
                             'quasi-static against a dynamic run) and print their metrics side '
                             'by side with the difference B - A.')
    compare.add_argument('a', type=Path, help='first bag directory')
    compare.add_argument('b', type=Path, help='second bag directory')
    compare.add_argument('--namespace-a', help='rig namespace in A when it holds several')
    compare.add_argument('--namespace-b', help='rig namespace in B when it holds several')
    compare.add_argument('--scene', type=_given('a scene file or a shipped scene name'),
                         help='the scene (file or shipped name) whose segments made '
                         'both bags: with it a dynamic bag also shows its lag behind the '
                         'quasi-static path')
    compare.add_argument('--out', type=Path, help='folder for compare.md, compare.json, '
                         'compare.png (both PV curves and volume planes over each other) and, '
                         'when a bag has snap-throughs in time, compare_transients.png (both '
                         'around each snap)')
    _figure_options(compare)
    compare.set_defaults(handler=_compare)

    library = sub.add_parser('library', help='assemble every pair (and triple) of segments',
                             description='Take a folder of segment tables (or a scene listing '
                             'segments), assemble every ordered pair (base, tip) on one supply, '
                             'optionally every ordered triple, and tabulate sequence type, '
                             'switch and snap volumes, pressure range, hysteresis and tip reach.')
    library.add_argument('source', help='folder of segment tables (*.csv) or a scene file')
    library.add_argument('--triples', action='store_true', help='also every ordered triple')
    library.add_argument('--length-m', type=float, help='segment length [m] for tables '
                         'without a "# length_m:" line')
    library.add_argument('--jobs', metavar='N', help='worker processes, at least 1 (default: '
                         'one per core)')
    library.add_argument('--out', type=Path, help='output folder (default bags/library_NAME)')
    _figure_options(library)
    library.set_defaults(handler=_library)

    rates = sub.add_parser('rates', help='rate map: the sequence over pump flows and radii',
                           description='Run a scene with a network (docs/dynamic.md) along its '
                           'pump programme at every pump flow rate and channel radius of a grid '
                           '(every channel set to the radius), in parallel, and write rates.csv '
                           '(one row per grid point: sequence type, leading segment, switch, '
                           'snap-throughs with durations, peak Reynolds number; SI) and '
                           'rates.png.')
    rates.add_argument('scene', help='scene YAML file with a network block, or the name of a '
                       'shipped scene')
    rates.add_argument('--flows', required=True, metavar='Q1,Q2,...',
                       help='pump flow rates [m^3/s], comma-separated, e.g. 1e-8,1e-7')
    rates.add_argument('--radii', required=True, metavar='R1,R2,...',
                       help='channel radii [m], comma-separated, e.g. 0.2e-3,0.5e-3')
    rates.add_argument('--samples', default='600', metavar='N', help='samples of the path per '
                       'leg of the programme (default 600, at least 50, at most 100000)')
    rates.add_argument('--workers', help='local worker processes (default: one per core)')
    rates.add_argument('--scheduler', help='Dask scheduler address, e.g. tcp://10.0.0.5:8786')
    rates.add_argument('--out', type=Path, help='output folder (default bags/rates_NAME)')
    _figure_options(rates)
    rates.set_defaults(handler=_rates)

    fit = sub.add_parser('fit', help='membrane laws fitted to measured inflations of a '
                         'segment, with intervals, and the best as a segment table',
                         description='Fit neo-Hookean, Mooney-Rivlin, Gent, one-term Ogden, '
                         'Yeoh and Arruda-Boyce membrane laws on a thin sphere, or on membranes '
                         'bulging out of circular holes, to measured inflations of one segment '
                         '(each CSV: volume_m3 = the whole segment volume, pressure_pa = gauge, '
                         'in rising volume; a file whose volume then falls holds a deflation '
                         'too, and both branches and the hysteresis between them are fitted), '
                         'or experiment files (injected_m3, pressure_pa: the rest volume is '
                         "added), or rig bags (one --segment's volume against the recorded "
                         'pressure), '
                         'by weighted least squares with the noise '
                         'estimated from the raw rows; 95 % intervals from the Jacobian and a '
                         'seeded parametric bootstrap; the law chosen by AICc. Writes fit.json, '
                         'segment.csv (the chosen curve as a segment table; with deflations also '
                         'segment_unloading.csv), cleaned.csv (the measured rows smoothed, '
                         'peaks kept, with a band) and fit.png (docs/fit.md).')
    fit.add_argument('inputs', nargs='+', type=Path, metavar='INPUT',
                     help='measured inflations of one segment, all of one kind: tables '
                     '(volume_m3, pressure_pa), experiment files (injected_m3, pressure_pa) or '
                     'bag folders (metadata.yaml and .mcap), each optionally with its deflation')
    fit.add_argument('--segment', metavar='NAME', help="a bag's segment to fit (a bag holds "
                     'every segment of its scene)')
    fit.add_argument('--geometry', choices=('sphere', 'bulge'), default='sphere',
                     help="the segment's shape: a thin sphere (the balloon; default), or a "
                     'cavity whose membranes bulge out of circular holes as spherical caps '
                     '(bulge: needs --hole-radius-m)')
    fit.add_argument('--radius-m', type=float, metavar='R', help="the sphere's reference "
                     'radius [m]; without it the rest volume is fitted')
    fit.add_argument('--hole-radius-m', type=float, metavar='A', help='bulge: the radius of the '
                     'holes the membranes bulge out of [m] (a rectangular membrane of '
                     'membrane_length_m b and cavity_width_m g: sqrt(b g / pi))')
    fit.add_argument('--membrane-count', type=int, metavar='N', help='bulge: how many '
                     'membranes bulge out of the one cavity (default 1)')
    fit.add_argument('--rest-volume-m3', type=float, metavar='V0', help="bulge: the cavity's "
                     'volume at rest [m^3]; without it the rest volume is fitted (what an '
                     "experiment's injected volume is added to; a sphere's is that of "
                     '--radius-m)')
    fit.add_argument('--wall-compliance-m3-per-pa', type=float, metavar='C', help="bulge: the "
                     "side walls' compliance dV/dp [m^3/Pa] (default 0: rigid walls)")
    fit.add_argument('--thickness-m', type=float, metavar='H', help="the membrane's thickness "
                     "[m]: with it the law's own moduli are reported (p(v) fixes only moduli "
                     'times H / R, or H / A for a bulge)')
    fit.add_argument('--length-m', type=float, metavar='L', help='segment length [m] written '
                     "into segment.csv's # length_m: line (default: the sphere's diameter; "
                     "a bulge's holes side by side, 2 A N)")
    fit.add_argument('--laws', metavar='LAW,...', help='laws to fit, comma-separated (default: '
                     'neo_hookean,mooney_rivlin,gent,ogden,yeoh,arruda_boyce)')
    fit.add_argument('--bootstrap', type=int, default=200, metavar='N', help='parametric '
                     'bootstrap resamples per law (default 200; 0: none)')
    fit.add_argument('--seed', type=int, default=0, help="the bootstrap's random seed "
                     '(default 0): the same files and seed give the same numbers')
    fit.add_argument('--out', type=Path, required=True, help='folder for fit.json, segment.csv, '
                     'cleaned.csv and fit.png')
    _figure_options(fit)
    fit.set_defaults(handler=_fit)

    scatter = sub.add_parser('scatter', help='the sequence under manufacturing scatter: '
                             'Monte Carlo probabilities and Sobol indices',
                             description='Draw the varied parameters of a scene (a law '
                             "segment's numbers, a table's pressure scale or noise, a FEM "
                             "design's membrane thickness or modulus) from "
                             'their distributions, classify every sample as classify does and '
                             'measure its switch, snap-throughs and plateau; every probability '
                             'with its Wilson interval; Sobol first-order and total indices '
                             '(SALib) of each number; on local processes or a Dask scheduler. '
                             'Writes scatter.json, scatter.png and summary.txt '
                             '(docs/scatter.md).')
    scatter.add_argument('scene', help='scene YAML file, or the name of a shipped scene')
    scatter.add_argument('--vary', action='append', metavar='NAME=DIST',
                         help='a parameter and its distribution, repeatable: '
                         'top.thickness_m=normal:5%%, top.material.shear_modulus_pa='
                         'uniform:30e3,38e3, top.pressure_scale=normal:1,0.05 (a table), '
                         'top.noise_std_pa=20 (a table: Pa of noise, drawn afresh per sample)')
    scatter.add_argument('--spec', type=_given_path('a spec file'), metavar='FILE.yaml',
                         help='YAML with one key, vary: a mapping of NAME: DIST as --vary '
                         'takes them')
    scatter.add_argument('--correlate', action='append', metavar='A,B=RHO',
                         help='correlate the draws of two varied parameters, repeatable: '
                         'top.modulus_scale,bottom.modulus_scale=0.8 (one batch of rubber); '
                         'rho is the correlation of their normal scores (docs/scatter.md)')
    scatter.add_argument('--samples', type=int, default=1000, metavar='N',
                         help='Monte Carlo samples, at most (default 1000)')
    scatter.add_argument('--until-width', type=float, metavar='W',
                         help="stop once every probability's interval is at most W wide "
                         '(checked every 50 samples, in order)')
    scatter.add_argument('--confidence', type=float, default=0.95,
                         help='confidence level of the intervals (default 0.95)')
    scatter.add_argument('--seed', type=int, default=0, help='random seed (default 0): the '
                         'same seed gives the same samples, whatever the workers')
    scatter.add_argument('--sobol', type=int, default=64, metavar='N',
                         help='base samples of the Sobol design, a power of 2 (default 64: '
                         '64 x (parameters + 2) samples more); 0: no indices')
    scatter.add_argument('--fem-points', type=int, default=3, metavar='N',
                         help="a design segment's drawn geometry (top.geometry."
                         'membrane_thickness_m) is read from N unit-cell FEM tables per key, '
                         'from the lowest draw to the highest, interpolated (default 3; '
                         'computed once, then cached)')
    scatter.add_argument('--workers', help='local worker processes (default: one per core)')
    scatter.add_argument('--scheduler', help='Dask scheduler address, e.g. '
                         'tcp://10.0.0.5:8786')
    scatter.add_argument('--out', type=Path, help='output folder (default bags/scatter_NAME)')
    scatter.add_argument('--quiet', action='store_true', help='no progress lines')
    _figure_options(scatter)
    scatter.set_defaults(handler=_scatter)

    play = sub.add_parser('play', help='republish a bag on its topics (like ros2 bag play)',
                          description='Publish every recorded message on its topic with its '
                          'recorded timing and QoS, as recorded CDR. While it plays, the '
                          'node softseq_player serves ~/pause, ~/resume, ~/toggle_paused and '
                          '~/is_paused (std_srvs/Trigger) and takes its speed factor from '
                          'its rate parameter (ros2 param set /softseq_player rate 2.0, or '
                          'without ros2: softseq ros param set /softseq_player rate 2.0).')
    play.add_argument('bag', type=Path, help='bag directory')
    play.add_argument('--rate', type=float, default=1.0, help='speed factor (default 1)')
    play.add_argument('--loop', action='store_true', help='start again at the end, until Ctrl-C')
    play.add_argument('--clock', action='store_true', help='publish the bag time on /clock')
    play.add_argument('--topics', nargs='+', help='only these topics (absolute names)')
    play.add_argument('--wait-for-subscribers', type=float, default=0.0, metavar='S',
                      help='wait up to S seconds for a subscriber on every topic first')
    play.add_argument('--start-offset', type=float, default=0.0, metavar='S',
                      help='start S seconds into the bag (each --loop pass too)')
    play.add_argument('--remap', '-m', action='append', metavar='FROM:=TO',
                      help='publish the recorded topic FROM as TO (repeatable)')
    play.add_argument('--qos-profile-overrides-path', type=Path, metavar='FILE',
                      help="QoS per recorded topic, in ros2 bag play's YAML form, instead of "
                      'what the bag says was offered')
    play.set_defaults(handler=_play)

    recover = sub.add_parser('recover', help='make a killed recording readable again',
                             description='Rebuild the index and metadata.yaml of a bag whose '
                             'recorder was killed: every message written before the last '
                             'flush (at most 0.5 s before the kill) is kept.')
    recover.add_argument('bag', type=Path, help='bag directory')
    recover.set_defaults(handler=_recover)

    info = sub.add_parser('info', help='what a bag holds (like ros2 bag info) and the scene '
                          'that made it',
                          description='Files, size, storage, compression, duration, start and '
                          'end, message counts per topic and type, whether the recording '
                          'finished, the rig namespaces and, from actuator/scene, the scene '
                          'that made it (name, segments, SHA-256). Needs no ROS.')
    info.add_argument('bag', type=Path, help='bag directory (or its .mcap file)')
    info.set_defaults(handler=_info)

    fem = sub.add_parser('fem', help='segment table from a segment design (volume-controlled FEM)',
                         description="Compute a segment's pressure-volume and curvature table "
                         'from its geometry and material by hyperelastic FEM with the cavity '
                         "volume prescribed (felupe); tables are cached by the design's hash. "
                         'With --sweep, every combination of the given values, in parallel.')
    fem.add_argument('design', nargs='+', help='design YAML file, or the name of a shipped '
                     "design (paper_top, paper_bottom); with --model actuator, the segments' "
                     'designs base to tip')
    fem.add_argument('--out', type=Path, help='CSV table to write (default: the cache file)')
    fem.add_argument('--model', choices=('unit_cell', 'whole_segment', 'actuator'),
                     help="override the design's mesh.model; actuator: the whole actuator of "
                     'the designs given, on one cavity, base clamped (docs/fem.md)')
    fem.add_argument('--set', action='append', default=[], metavar='KEY=VALUE',
                     help='override a design value, e.g. mesh.element_size_m=0.001')
    fem.add_argument('--sweep', action='append', default=[], metavar='KEY=V1,V2,...',
                     help='sweep a design value (repeat for a grid of several)')
    fem.add_argument('--out-dir', type=Path, help='folder for the sweep tables and summary.csv')
    fem.add_argument('--workers', type=int, help='local worker processes for a sweep '
                     '(default: one per core)')
    fem.add_argument('--scheduler', help='Dask scheduler address for a sweep, e.g. '
                     'tcp://10.0.0.5:8786')
    fem.add_argument('--no-cache', action='store_true', help='recompute even when cached')
    fem.add_argument('--cache-dir', type=Path, help='table cache (default: $SOFTSEQ_FEM_CACHE '
                     'or ~/.cache/softseq/fem)')
    fem.add_argument('--quiet', action='store_true', help='no progress lines')
    fem.set_defaults(handler=_fem)

    design = sub.add_parser('design', help='segment designs for a target sequence (FEM library '
                            'search)',
                            description='Find segment designs (membrane and wall thicknesses, '
                            'membrane length, material fit within the ranges given) whose '
                            'assembled sequence meets a target: unit-cell FEM tables on a '
                            'coarse grid (cached, in parallel), interpolated, searched by '
                            "scipy's differential evolution, the best verified by direct FEM. "
                            'Exit 0 when verified, 1 when not, 2 on bad input or an '
                            'unreachable target (docs/fem.md).')
    design.add_argument('problem', type=Path, help='problem YAML: segments, ranges, target')
    design.add_argument('--out', type=Path, help='folder for the designs found and '
                        'results.yaml (default bags/design_NAME)')
    design.add_argument('--workers', type=int, help='local worker processes for the FEM '
                        '(default: one per core)')
    design.add_argument('--scheduler', help='Dask scheduler address for the FEM, e.g. '
                        'tcp://10.0.0.5:8786')
    design.add_argument('--cache-dir', type=Path, help='table cache (default: '
                        '$SOFTSEQ_FEM_CACHE or ~/.cache/softseq/fem)')
    design.add_argument('--quiet', action='store_true', help='no progress lines')
    design.set_defaults(handler=_design)

    graph = sub.add_parser('graph', help='transition graph: every stable branch and snap',
                           description='Write graph.json (every stable branch with its state '
                           'label and injected-volume interval, every transition with its '
                           'volume, fluid moved and energy released, SI; how a history from '
                           'rest reaches each branch) and graph.png (docs/graph.md).')
    graph.add_argument('scene', help='scene YAML file, or the name of a shipped scene')
    graph.add_argument('--out', type=Path, help='output folder (default bags/graph_NAME)')
    graph.add_argument('--reversals', type=int, metavar='K', help='mark the branches a '
                       'history from rest with at most K reversals reaches (default: any '
                       'number)')
    graph.add_argument('--regulator', action='store_true', help='the segments behind an '
                       'ideal pressure regulator instead of the syringe: each an independent '
                       'hysteron; every stable state (each segment on a rising piece) and the '
                       'pressures where they flip')
    _figure_options(graph)
    graph.set_defaults(handler=_graph)

    scenes = sub.add_parser('scenes', help='list the shipped scenes')
    scenes.set_defaults(handler=_scenes)

    add_ros_parser(sub)
    parser.commands = dict(sub.choices)
    return parser


def _output_gone() -> bool:
    """Whether the standard output's reader has closed its end of the pipe."""
    import select
    try:
        poller = select.poll()
        poller.register(sys.stdout.fileno(), select.POLLOUT)
        return any(events & select.POLLERR for _, events in poller.poll(0))
    except (OSError, ValueError):
        return False


def main(argv: Sequence[str] | None = None) -> int:
    """
    Run one subcommand; a user's mistake is one line on stderr and exit code 2.

    SIGINT and SIGTERM stop a job as a user expects of a command line tool: whatever it was
    writing is closed completely (a bag gets its index and metadata.yaml), and the exit code
    is 130 or 143.
    """
    parser = build_parser()
    args, unknown = parser.parse_known_args(argv)
    command = parser.commands[args.command]
    # softseq ros has subcommands of its own: each says its own mistakes.
    command = getattr(command, 'commands', {}).get(getattr(args, 'ros_command', None), command)
    if unknown:
        # Said by the subcommand's parser, as its other mistakes are.
        command.error(f'unrecognized arguments: {" ".join(unknown)}')
    name = getattr(args, 'command_path', args.command)
    handler: Callable[[argparse.Namespace], int] = args.handler
    previous = signal.signal(signal.SIGTERM, raise_terminated)
    try:
        return handler(args)
    except BrokenPipeError as err:
        if not _output_gone():
            print(f'softseq {name}: error: {one_line(str(err))}', file=sys.stderr)
            return 2
        # The reader of the output left (``softseq info BAG | head``): stop as a filter does,
        # quietly, with 128 + SIGPIPE, and nothing more written to the closed pipe at exit.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 128 + signal.SIGPIPE
    except USER_ERRORS as err:
        # One line, also where the reason quotes a library's message of several lines; a
        # file the system refused is named first, as every other refusal names its input.
        reason = f'{err.filename}: {err.strerror}' if isinstance(err, OSError) \
            and err.filename and err.strerror else str(err)
        print(f'softseq {name}: error: {one_line(reason)}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f'softseq {name}: interrupted', file=sys.stderr)
        return 130
    except TerminatedError:
        print(f'softseq {name}: terminated', file=sys.stderr)
        return 143
    finally:
        signal.signal(signal.SIGTERM, previous)


if __name__ == '__main__':
    sys.exit(main())
