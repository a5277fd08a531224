"""The ``softseq`` command: one subcommand per job."""

import argparse
from pathlib import Path
import sys
from typing import Callable, Sequence

USER_ERRORS: tuple[type[BaseException], ...] = (ValueError, OSError)


def _solve(args: argparse.Namespace) -> int:
    from softseq_ros.physics.equilibrium import Tracker
    from softseq_ros.physics.scene import load_scene
    from softseq_ros.physics.solve import build_map, read_history, write_path

    scene = load_scene(args.scene)
    if args.path is not None:
        history = read_history(args.path)
    else:
        _, history = scene.pump.profile.sample(scene.pump.rate_hz)
    emap = build_map(scene.segments, scene.solver.resolution)
    solved = Tracker(emap).sweep(history)
    write_path(args.out, solved, scene.segment_names)
    snaps = ', '.join(f'{e.injected * 1e6:.3f} mL' for e in solved.events) or 'none'
    print(f'{scene.name}: {history.size} commanded volumes solved -> {args.out} '
          f'(snap-throughs: {snaps})')
    return 0


def _classify(args: argparse.Namespace) -> int:
    from softseq_ros.physics.equilibrium import classify
    from softseq_ros.physics.scene import load_scene
    from softseq_ros.physics.solve import build_map

    scene = load_scene(args.scene)
    print(f'{scene.name}: {classify(build_map(scene.segments, scene.solver.resolution))}')
    return 0


def _run(args: argparse.Namespace) -> int:
    from softseq_ros.batch import run_scene

    result = run_scene(args.scene, args.out, show_progress=not args.quiet)
    print(f'{args.out}: {result.sim_duration_s:.1f} s of rig time in {result.wall_s:.1f} s '
          f'({result.speedup:.0f}x real time), {sum(result.message_counts.values())} messages, '
          f'pump {result.pump_state}')
    if not args.no_report:
        _write_report(args.out, args.scene, None, args.out / 'report')
    return 0


def _report(args: argparse.Namespace) -> int:
    _write_report(args.bag, args.scene, args.experiment, args.out or args.bag / 'report')
    return 0


def _write_report(bag: Path, scene_name: str | None, experiment_csv: Path | None,
                  out: Path) -> None:
    from softseq_ros.analysis.figures import summary, write_figures
    from softseq_ros.analysis.recording import load_recording, read_experiment
    from softseq_ros.bag.reader import bag_summary
    from softseq_ros.physics.scene import load_scene
    from softseq_ros.physics.solve import build_map

    recording = load_recording(bag)
    emap = None
    if scene_name is not None:
        scene = load_scene(scene_name)
        emap = build_map(scene.segments, scene.solver.resolution)
    experiment = read_experiment(experiment_csv) if experiment_csv is not None else None
    counts = {name: topic.message_count for name, topic in bag_summary(bag).topics.items()}
    text = summary(recording, emap, counts)
    figures = write_figures(recording, emap, out, experiment)
    (out / 'summary.txt').write_text(text + '\n')
    print(text)
    print(f'figures: {", ".join(str(f) for f in figures)}')


def _recover(args: argparse.Namespace) -> int:
    from softseq_ros.bag.writer import recover

    result = recover(args.bag)
    if result.was_complete:
        print(f'{args.bag}: complete, {result.message_count} messages; metadata.yaml rewritten')
    else:
        print(f'{args.bag}: recovered {result.message_count} messages into {result.mcap_path}'
              f' (damaged original kept as {result.damaged_copy})')
    return 0


def _fem(args: argparse.Namespace) -> int:
    from softseq_ros.fem.command import run_fem_command

    return run_fem_command(args)


def _scenes(args: argparse.Namespace) -> int:
    from softseq_ros.physics.scene import config_dir, shipped_scenes

    print(f'shipped scenes in {config_dir()}:')
    for name in shipped_scenes():
        print(f'  {name}')
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every subcommand."""
    parser = argparse.ArgumentParser(
        prog='softseq',
        description='Emulated rig of a soft actuator with a hardware-encoded inflation sequence.')
    sub = parser.add_subparsers(dest='command', required=True, metavar='COMMAND')

    solve = sub.add_parser('solve', help='quasi-static inflation sequence along a volume history',
                           description='Solve the hardware-encoded equilibrium along a history '
                           'of commanded injected volumes (the history matters).')
    solve.add_argument('scene', help='scene YAML file, or the name of a shipped scene')
    solve.add_argument('--path', type=Path, help='CSV with a column injected_m3, in order '
                       "(default: the scene's pump profile at the pump rate)")
    solve.add_argument('--out', type=Path, required=True, help='output CSV file')
    solve.set_defaults(handler=_solve)

    classify = sub.add_parser('classify', help="the paper's sequence type of a scene",
                              description='Print none, partial, symmetric or asymmetric.')
    classify.add_argument('scene', help='scene YAML file, or the name of a shipped scene')
    classify.set_defaults(handler=_classify)

    run = sub.add_parser('run', help='run the rig in batch mode and record it to a bag',
                         description='Run the pump, actuator and camera nodes in one process '
                         'in lock-step simulated time, as fast as the machine allows, record '
                         'every topic to an MCAP bag and write a summary with figures.')
    run.add_argument('scene', help='scene YAML file, or the name of a shipped scene')
    run.add_argument('--out', type=Path, required=True,
                     help='bag directory to create (for example bags/paper)')
    run.add_argument('--quiet', action='store_true', help='no progress line')
    run.add_argument('--no-report', action='store_true', help='skip the summary and figures')
    run.set_defaults(handler=_run)

    report = sub.add_parser('report', help='summary and figures of a recorded bag',
                            description='Summarise a rig bag and draw the paper-style figures, '
                            'optionally beside a measured PV curve.')
    report.add_argument('bag', type=Path, help='bag directory (metadata.yaml and .mcap)')
    report.add_argument('--scene', help='scene of the run: adds the segment curves and the '
                        'equilibrium set to the figures')
    report.add_argument('--experiment', type=Path, help='CSV with columns injected_m3 and '
                        'pressure_pa measured on the rig')
    report.add_argument('--out', type=Path, help='folder for the figures (default BAG/report)')
    report.set_defaults(handler=_report)

    recover = sub.add_parser('recover', help='make a killed recording readable again',
                             description='Rebuild the index and metadata.yaml of a bag whose '
                             'recorder was killed: every message written before the last '
                             'flush (at most 0.5 s before the kill) is kept.')
    recover.add_argument('bag', type=Path, help='bag directory')
    recover.set_defaults(handler=_recover)

    fem = sub.add_parser('fem', help='segment table from a segment design (volume-controlled FEM)',
                         description="Compute a segment's pressure-volume and curvature table "
                         'from its geometry and material by hyperelastic FEM with the cavity '
                         "volume prescribed (felupe); tables are cached by the design's hash. "
                         'With --sweep, every combination of the given values, in parallel.')
    fem.add_argument('design', help='design YAML file, or the name of a shipped design '
                     '(paper_top, paper_bottom)')
    fem.add_argument('--out', type=Path, help='CSV table to write (default: the cache file)')
    fem.add_argument('--model', choices=('unit_cell', 'whole_segment'),
                     help="override the design's mesh.model")
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

    scenes = sub.add_parser('scenes', help='list the shipped scenes')
    scenes.set_defaults(handler=_scenes)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run one subcommand; a user's mistake is one line on stderr and exit code 2."""
    parser = build_parser()
    args = parser.parse_args(argv)
    handler: Callable[[argparse.Namespace], int] = args.handler
    try:
        return handler(args)
    except USER_ERRORS as err:
        print(f'softseq {args.command}: error: {err}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f'softseq {args.command}: interrupted', file=sys.stderr)
        return 130


if __name__ == '__main__':
    sys.exit(main())
