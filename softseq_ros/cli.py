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
