"""
Playback analysis: our array reader against rosbags and mcap-ros2-support, report time, memory.

    python bench/bench_analysis.py [--big] [--repeat 3] [--commands 9] [--out FILE]
    python bench/bench_analysis.py --quick

Makes the paper bag (`softseq run paper`) in bags/bench_paper and, with --big, an 18-cycle
paper bag (10.3 million messages) in bags/bench_paper18, anew each run (so they have the current
writer's layout). In one run it measures:

- reading the columns the analysis uses (pump command, actuator volumes, curvatures: stamps and
  values) with our reader, with rosbags and with mcap-ros2-support; the three results are
  checked to be identical before any time is reported;
- our reader on a copy of the bag in one sequence of chunks, as mcap's writer (and rosbag2)
  lay it out, against the bag itself, whose camera frames fill chunks of their own;
- the whole report (read, metrics, five figures), in-process and as the `softseq report`
  command (Python start-up included): the paper style (the default, PNG only), the screen
  style, with SVG and with the scene, the commands taken in turn so that a slower minute of the
  machine falls on all, each against the screen style run by run;
- the peak memory (max RSS) of `softseq report` on the paper bag and on the big bag.

Writes bench/analysis_results.md. In-process times are the best of --repeat runs (the run least
disturbed by others on a shared machine); command times are the median, minimum and maximum of
--commands runs of each.

``--quick`` checks that the benchmark runs, in under 30 s: the paper scene shortened to
0 -> 6 -> 0 mL (about 50,000 messages), every measurement once, the bags in a temporary folder
(not bags/); the tables are printed, not written (unless ``--out`` is given). The test suite
runs it (test/test_bench_quick.py).
"""

import argparse
import os
from pathlib import Path
import platform
import resource
import subprocess
import sys
import tempfile
import time

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from softseq_ros.bag.arrays import JointStateDecoder, open_bag  # noqa: E402
from softseq_ros.wire import contract  # noqa: E402

TOPICS = {contract.PUMP_COMMAND: ('position', 'velocity'),
          contract.VOLUMES: ('position', 'effort'),
          contract.CURVATURES: ('position',)}
# --quick: the paper programme shortened to 0 -> 6 -> 0 mL (240 s of rig time).
QUICK_LEGS = [{'inflate_to_m3': 6.0e-6}, {'deflate_to_m3': 0.0}]


def make_bag(path: Path, cycles: int, legs: list | None = None) -> Path:
    """The paper scene run into ``path``: ``cycles`` cycles of its programme (or of ``legs``)."""
    import shutil

    shutil.rmtree(path, ignore_errors=True)
    scene = REPO / 'config' / 'paper.yaml'
    if cycles != 1 or legs is not None:
        import yaml
        document = yaml.safe_load(scene.read_text())
        document['name'] = f'paper_{cycles}_cycles' if legs is None else 'paper_quick'
        document['pump']['cycles'] = cycles
        if legs is not None:
            document['pump']['legs'] = legs
            top = max(leg.get('inflate_to_m3', 0.0) for leg in legs)
            camera = document['camera']
            camera['trigger_injected_m3'] = [v for v in camera['trigger_injected_m3']
                                             if v <= top]
        for segment in document['segments']:
            segment['table'] = str(REPO / 'config' / segment['table'])
        scene = path.parent / f'{document["name"]}.yaml'
        scene.write_text(yaml.safe_dump(document))
    subprocess.run([sys.executable, '-m', 'softseq_ros.cli', 'run', str(scene), '--out',
                    str(path), '--no-report', '--quiet'], check=True)
    return path


def names() -> dict:
    return {spec: contract.resolve(spec.name, '/') for spec in TOPICS}


def read_ours(bag: Path) -> dict:
    decoders = {spec: JointStateDecoder(topic, TOPICS[spec], log_times=False)
                for spec, topic in names().items()}
    open_bag(bag).read(decoders.values())
    return {spec.name: decoders[spec].result() for spec in TOPICS}


def _columns(rows: dict) -> dict:
    return {name: {key: np.asarray(values) for key, values in columns.items()}
            for name, columns in rows.items()}


def _empty() -> dict:
    return {spec.name: {'stamp_ns': [], **{f: [] for f in TOPICS[spec]}} for spec in TOPICS}


def read_rosbags(bag: Path) -> dict:
    from rosbags.highlevel import AnyReader

    topics = {topic: spec for spec, topic in names().items()}
    rows = _empty()
    with AnyReader([bag]) as reader:
        connections = [c for c in reader.connections if c.topic in topics]
        for connection, _, raw in reader.messages(connections=connections):
            msg = reader.deserialize(raw, connection.msgtype)
            spec = topics[connection.topic]
            out = rows[spec.name]
            out['stamp_ns'].append(msg.header.stamp.sec * 1_000_000_000
                                   + msg.header.stamp.nanosec)
            for name in TOPICS[spec]:
                out[name].append(getattr(msg, name))
    return _columns(rows)


def read_mcap_ros2(bag: Path) -> dict:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    topics = {topic: spec for spec, topic in names().items()}
    rows = _empty()
    with open(next(bag.glob('*.mcap')), 'rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, channel, _, msg in reader.iter_decoded_messages(topics=list(topics)):
            spec = topics[channel.topic]
            out = rows[spec.name]
            out['stamp_ns'].append(msg.header.stamp.sec * 1_000_000_000
                                   + msg.header.stamp.nanosec)
            for name in TOPICS[spec]:
                out[name].append(getattr(msg, name))
    return _columns(rows)


def one_chunk_sequence_copy(bag: Path, copy: Path) -> Path:
    """The bag rewritten by mcap's own writer: one sequence of chunks, every topic mixed."""
    import shutil

    from mcap.reader import make_reader
    from mcap.writer import Writer

    shutil.rmtree(copy, ignore_errors=True)
    copy.mkdir(parents=True)
    source_file = next(bag.glob('*.mcap'))
    with open(source_file, 'rb') as source, open(copy / source_file.name, 'wb') as target:
        reader = make_reader(source)
        writer = Writer(target, chunk_size=768 * 1024)
        writer.start(profile='ros2', library='bench')
        summary = reader.get_summary()
        schemas = {s.id: writer.register_schema(s.name, s.encoding, s.data)
                   for s in summary.schemas.values()}
        channels = {c.id: writer.register_channel(c.topic, c.message_encoding,
                                                  schemas[c.schema_id], c.metadata)
                    for c in summary.channels.values()}
        for _, channel, message in reader.iter_messages(log_time_order=True):
            writer.add_message(channels[channel.id], message.log_time, message.data,
                               message.publish_time, message.sequence)
        writer.finish()
    return copy


def check_same(a: dict, b: dict, what: str) -> None:
    for topic, columns in a.items():
        for key, values in columns.items():
            other = np.asarray(b[topic][key]).reshape(values.shape)
            if not np.array_equal(values, other):
                raise SystemExit(f'{what}: {topic}.{key} differs')


def cpu_seconds() -> float:
    """CPU time of this process so far, every thread (the reader decompresses on a second)."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def best_with_cpu(function, repeat: int) -> tuple[float, float, object]:
    """Best wall time [s], the CPU time [s] of that run, and the result."""
    runs, result = [], None
    for _ in range(repeat):
        cpu, start = cpu_seconds(), time.perf_counter()
        result = function()
        runs.append((time.perf_counter() - start, cpu_seconds() - cpu))
    wall, cpu = min(runs)
    return wall, cpu, result


def best(function, repeat: int) -> tuple[float, object]:
    times, result = [], None
    for _ in range(repeat):
        start = time.perf_counter()
        result = function()
        times.append(time.perf_counter() - start)
    return min(times), result


def commands_in_turn(commands: dict[str, list[str]], runs: int) -> dict[str, list[tuple]]:
    """Each command ``runs`` times, taken in turn: (wall s, CPU s, max RSS kB) of every run."""
    results: dict[str, list[tuple]] = {name: [] for name in commands}
    for _ in range(runs):
        for name, args in commands.items():
            results[name].append(command(args))
    return results


def spread(values: list[float]) -> str:
    return (f'{float(np.median(values)):.2f} s ({min(values):.2f} to {max(values):.2f}, '
            f'{len(values)} runs)')


def against(runs: list[tuple], baseline: list[tuple], field: int) -> str:
    """The median of the run-by-run ratios of ``field`` (0 wall, 1 CPU) to the baseline's."""
    ratios = [a[field] / b[field] for a, b in zip(runs, baseline)]
    return f'{float(np.median(ratios)):.2f}x'


def command(args: list[str]) -> tuple[float, float, int]:
    """Wall time [s], CPU time [s] (user and system, its children's too) and max RSS [kB]."""
    result = subprocess.run(['/usr/bin/time', '-f', '%e %U %S %M', *args], capture_output=True,
                            text=True, check=True)
    wall, user, system, rss = result.stderr.strip().splitlines()[-1].split()
    return float(wall), float(user) + float(system), int(rss)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--repeat', type=int, default=3)
    parser.add_argument('--commands', type=int, default=9, help='runs of each command')
    parser.add_argument('--big', action='store_true', help='also the 18-cycle bag (10^7 msgs)')
    parser.add_argument('--out', type=Path, default=None,
                        help='results file (default bench/analysis_results.md; with --quick '
                        'none: printed only)')
    parser.add_argument('--quick', action='store_true',
                        help='a check that the benchmark runs: a short bag in a temporary '
                        'folder, every measurement once, about 30 s')
    args = parser.parse_args()
    if args.quick:
        if args.big:
            parser.error('--quick and --big: choose one')
        args.repeat = args.commands = 1
        with tempfile.TemporaryDirectory(prefix='bench_analysis_') as folder:
            lines = measure(args, Path(folder))
    else:
        bags = REPO / 'bags'
        bags.mkdir(exist_ok=True)
        lines = measure(args, bags)
    out = args.out or (None if args.quick else REPO / 'bench' / 'analysis_results.md')
    if out is not None:
        out.write_text('\n'.join(lines))
    print('\n'.join(lines))


def measure(args: argparse.Namespace, bags: Path) -> list[str]:
    """Every measurement, the bags in ``bags``; the results as markdown lines."""
    load_before = os.getloadavg()[0]
    paper = make_bag(bags / 'bench_paper', 1, QUICK_LEGS if args.quick else None)
    count = open_bag(paper).channels
    messages = sum(c.message_count for c in count.values())
    read = sum(count[t].message_count for t in names().values())

    ours_s, ours_cpu, ours = best_with_cpu(lambda: read_ours(paper), args.repeat)
    rosbags_s, theirs = best(lambda: read_rosbags(paper), 1)
    check_same(ours, theirs, 'rosbags')
    mcap_s, theirs = best(lambda: read_mcap_ros2(paper), 1)
    check_same(ours, theirs, 'mcap-ros2-support')
    mixed = one_chunk_sequence_copy(paper, bags / 'bench_paper_mixed')
    mixed_s, mixed_cpu, theirs = best_with_cpu(lambda: read_ours(mixed), args.repeat)
    check_same(ours, theirs, 'the one-chunk-sequence copy')
    del theirs
    # As in a report, where the figure worker holds the second core while the bag is read.
    busy = subprocess.Popen([sys.executable, '-c', 'while True: pass'])
    try:
        busy_s, _, _ = best_with_cpu(lambda: read_ours(paper), args.repeat)
        busy_mixed_s, _, _ = best_with_cpu(lambda: read_ours(mixed), args.repeat)
    finally:
        busy.kill()
        busy.wait()

    from softseq_ros.analysis.report import write_report

    out = bags / 'bench_report'
    png_s, _ = best(lambda: write_report(paper, out), args.repeat)
    svg_s, _ = best(lambda: write_report(paper, out, svg=True), args.repeat)
    scene_s, _ = best(lambda: write_report(paper, out, scene_name='paper'), args.repeat)
    softseq = [sys.executable, '-m', 'softseq_ros.cli', 'report', str(paper), '--out', str(out)]
    # The screen style in the same run: the baseline each other command's ratio is taken to,
    # run by run, so a busier minute of the machine falls on both.
    # What the command imports before it works (its own modules, and matplotlib in the figure
    # worker), alone: the report's CPU after import is its CPU less this, run by run.
    imports = [sys.executable, '-c', 'import softseq_ros.cli, softseq_ros.analysis.report; '
               "import matplotlib; matplotlib.use('Agg'); import matplotlib.pyplot"]
    cli = commands_in_turn({'screen': [*softseq, '--style', 'screen'], 'png': softseq,
                            'svg': [*softseq, '--svg'],
                            'scene': [*softseq, '--scene', 'paper'], 'imports': imports},
                           args.commands)
    after_import = [run[1] - alone[1] for run, alone in zip(cli['png'], cli['imports'])]
    cli_rss = max(rss for _, _, rss in cli['png'])
    rows = [('paper bag', messages, cli_rss)]
    big_line = ''
    if args.big:
        big = make_bag(bags / 'bench_paper18', 18)
        big_messages = sum(c.message_count for c in open_bag(big).channels.values())
        wall, _, rss = command([sys.executable, '-m', 'softseq_ros.cli', 'report', str(big),
                                '--out', str(bags / 'bench_report18')])
        rows.append(('18-cycle paper bag', big_messages, rss))
        big_line = f'`softseq report` of the 18-cycle bag: {wall:.1f} s'

    source = ('`softseq run paper`' if not args.quick else
              '**quick check**: the paper scene shortened to 0 -> 6 -> 0 mL')
    flag = ' --big' if args.big else ' --quick' if args.quick else ''
    lines = [
        '# Playback analysis benchmark', '',
        f'`python bench/bench_analysis.py{flag}` on '
        f'{platform.machine()}, Python {platform.python_version()}; the paper bag '
        f'({source}: {messages:,} messages, {read:,} of them on the three topics '
        'read). Best of '
        f'{args.repeat} runs unless one. All three readers return identical arrays (checked). '
        f'Load average (1 min) on the {os.cpu_count()} cores: {load_before:.1f} when the run '
        f'began, {os.getloadavg()[0]:.1f} when it ended (other work on a shared machine '
        'slows the wall times; the ratios of commands taken in turn hold better).',
        '',
        '| reading pump command, volumes, curvatures (stamps, values) | time | vs ours |',
        '|---|---:|---:|',
        f'| ours (`softseq_ros.bag.arrays`) | {ours_s:.2f} s (CPU {ours_cpu:.2f} s) | 1x |',
        f'| rosbags 0.11 (`AnyReader.deserialize`) | {rosbags_s:.2f} s | '
        f'{rosbags_s / ours_s:.0f}x |',
        f'| mcap-ros2-support 0.6 (`iter_decoded_messages`) | {mcap_s:.2f} s | '
        f'{mcap_s / ours_s:.0f}x |',
        f"| ours, on a copy in one sequence of chunks (mcap's writer) | {mixed_s:.2f} s (CPU "
        f'{mixed_cpu:.2f} s) | {mixed_s / ours_s:.1f}x |',
        f'| ours, the other core busy | {busy_s:.2f} s | {busy_s / ours_s:.1f}x |',
        f'| ours on the copy, the other core busy | {busy_mixed_s:.2f} s | '
        f'{busy_mixed_s / ours_s:.1f}x |',
        '',
        '| whole report of the paper bag | time |', '|---|---:|',
        f'| in-process: read, metrics, 5 figures as PNG | {png_s:.2f} s |',
        f'| in-process, PNG and SVG | {svg_s:.2f} s |',
        f'| in-process, with `--scene paper` (equilibrium set) | {scene_s:.2f} s |',
        '',
        '| the `softseq report BAG` command (Python and ROS wheel start-up included; the '
        'commands taken in turn) | wall, median (range) | CPU, median | vs `--style screen`: '
        'CPU, wall (median of run-by-run ratios) |',
        '|---|---:|---:|---:|',
        *[f'| {label} | {spread([w for w, _, _ in cli[name]])} | '
          f'{float(np.median([c for _, c, _ in cli[name]])):.2f} s | '
          f'{against(cli[name], cli["screen"], 1)}, {against(cli[name], cli["screen"], 0)} |'
          for name, label in (('png', 'paper style (the default), PNG'),
                              ('screen', '`--style screen`'), ('svg', 'with `--svg`'),
                              ('scene', 'with `--scene paper`'))],
        f"| its imports alone (the command's modules, matplotlib) | "
        f'{spread([w for w, _, _ in cli["imports"]])} | '
        f'{float(np.median([c for _, c, _ in cli["imports"]])):.2f} s | |',
        '',
        f"CPU of `softseq report` on the paper bag after its imports (the default style's CPU "
        f"less its imports' alone, run by run): median {float(np.median(after_import)):.2f} s "
        f'({min(after_import):.2f} to {max(after_import):.2f}); the target is under 1 s.',
        '',
        '| peak memory of `softseq report` (max RSS) | messages | MB |', '|---|---:|---:|',
        *[f'| {name} | {n:,} | {rss / 1024:.0f} |' for name, n, rss in rows],
        '', big_line, '']
    return lines


if __name__ == '__main__':
    main()
