"""
Playback analysis: our array reader against rosbags and mcap-ros2-support, report time, memory.

    python bench/bench_analysis.py [--big BAG_OR_NOTHING] [--repeat 3]

Makes the paper bag (`softseq run paper`) in bags/bench_paper if missing and, with --big, an
18-cycle paper bag (10.3 million messages) in bags/bench_paper18. In one run it measures:

- reading the columns the analysis uses (pump command, actuator volumes, curvatures: stamps and
  values) with our reader, with rosbags and with mcap-ros2-support; the three results are
  checked to be identical before any time is reported;
- the whole report (read, metrics, five figures as PNG and SVG), in-process and as the
  `softseq report` command (Python start-up included);
- the peak memory (max RSS) of `softseq report` on the paper bag and on the big bag.

Writes bench/analysis_results.md. Times are the best of --repeat runs: on a shared machine the
best run is the one least disturbed by others.
"""

import argparse
from pathlib import Path
import platform
import subprocess
import sys
import time

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from softseq_ros.bag.arrays import JointStateDecoder, open_bag  # noqa: E402
from softseq_ros.rig import contract  # noqa: E402

TOPICS = {contract.PUMP_COMMAND: ('position', 'velocity'),
          contract.VOLUMES: ('position', 'effort'),
          contract.CURVATURES: ('position',)}


def ensure_bag(path: Path, cycles: int) -> Path:
    if (path / 'metadata.yaml').is_file():
        return path
    scene = REPO / 'config' / 'paper.yaml'
    if cycles != 1:
        import yaml
        document = yaml.safe_load(scene.read_text())
        document['name'] = f'paper_{cycles}_cycles'
        document['pump']['cycles'] = cycles
        for segment in document['segments']:
            segment['table'] = str(REPO / 'config' / segment['table'])
        scene = path.parent / f'paper_{cycles}_cycles.yaml'
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


def check_same(a: dict, b: dict, what: str) -> None:
    for topic, columns in a.items():
        for key, values in columns.items():
            other = np.asarray(b[topic][key]).reshape(values.shape)
            if not np.array_equal(values, other):
                raise SystemExit(f'{what}: {topic}.{key} differs')


def best(function, repeat: int) -> tuple[float, object]:
    times, result = [], None
    for _ in range(repeat):
        start = time.perf_counter()
        result = function()
        times.append(time.perf_counter() - start)
    return min(times), result


def command(args: list[str]) -> tuple[float, int]:
    """Wall time [s] and max RSS [kB] of a command, from GNU time."""
    result = subprocess.run(['/usr/bin/time', '-f', '%e %M', *args], capture_output=True,
                            text=True, check=True)
    wall, rss = result.stderr.strip().splitlines()[-1].split()
    return float(wall), int(rss)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--repeat', type=int, default=3)
    parser.add_argument('--big', action='store_true', help='also the 18-cycle bag (10^7 msgs)')
    parser.add_argument('--out', type=Path, default=REPO / 'bench' / 'analysis_results.md')
    args = parser.parse_args()
    bags = REPO / 'bags'
    bags.mkdir(exist_ok=True)
    paper = ensure_bag(bags / 'bench_paper', 1)
    count = open_bag(paper).channels
    messages = sum(c.message_count for c in count.values())
    read = sum(count[t].message_count for t in names().values())

    ours_s, ours = best(lambda: read_ours(paper), args.repeat)
    rosbags_s, theirs = best(lambda: read_rosbags(paper), 1)
    check_same(ours, theirs, 'rosbags')
    mcap_s, theirs = best(lambda: read_mcap_ros2(paper), 1)
    check_same(ours, theirs, 'mcap-ros2-support')
    del theirs

    from softseq_ros.analysis.report import write_report

    out = bags / 'bench_report'
    report_s, _ = best(lambda: write_report(paper, out, svg=True), args.repeat)
    png_s, _ = best(lambda: write_report(paper, out, svg=False), args.repeat)
    scene_s, _ = best(lambda: write_report(paper, out, scene_name='paper', svg=True), 1)
    softseq = [sys.executable, '-m', 'softseq_ros.cli', 'report']
    cli = [command([*softseq, str(paper), '--out', str(out)]) for _ in range(args.repeat)]
    cli_s = min(c[0] for c in cli)
    cli_rss = max(c[1] for c in cli)
    rows = [('paper bag', messages, cli_rss)]
    big_line = ''
    if args.big:
        big = ensure_bag(bags / 'bench_paper18', 18)
        big_messages = sum(c.message_count for c in open_bag(big).channels.values())
        wall, rss = command([*softseq, str(big), '--out', str(bags / 'bench_report18'),
                             '--no-svg'])
        rows.append(('18-cycle paper bag', big_messages, rss))
        big_line = f'`softseq report` of the 18-cycle bag: {wall:.1f} s'

    lines = [
        '# Playback analysis benchmark', '',
        f'`python bench/bench_analysis.py{" --big" if args.big else ""}` on '
        f'{platform.machine()}, Python {platform.python_version()}; the paper bag '
        f'(`softseq run paper`: {messages:,} messages, {read:,} of them on the three topics '
        'read). Best of '
        f'{args.repeat} runs unless one. All three readers return identical arrays (checked).',
        '',
        '| reading pump command, volumes, curvatures (stamps, values) | time | vs ours |',
        '|---|---:|---:|',
        f'| ours (`softseq_ros.bag.arrays`) | {ours_s:.2f} s | 1x |',
        f'| rosbags 0.11 (`AnyReader.deserialize`) | {rosbags_s:.2f} s | '
        f'{rosbags_s / ours_s:.0f}x |',
        f'| mcap-ros2-support 0.6 (`iter_decoded_messages`) | {mcap_s:.2f} s | '
        f'{mcap_s / ours_s:.0f}x |',
        '',
        '| whole report of the paper bag | time |', '|---|---:|',
        f'| in-process: read, metrics, 5 figures as PNG and SVG | {report_s:.2f} s |',
        f'| in-process, PNG only | {png_s:.2f} s |',
        f'| in-process, with `--scene paper` (equilibrium set, PNG and SVG) | {scene_s:.2f} s |',
        f'| `softseq report BAG` command (Python and ROS wheel start-up included) | '
        f'{cli_s:.2f} s |',
        '',
        '| peak memory of `softseq report` (max RSS) | messages | MB |', '|---|---:|---:|',
        *[f'| {name} | {n:,} | {rss / 1024:.0f} |' for name, n, rss in rows],
        '', big_line, '']
    args.out.write_text('\n'.join(lines))
    print('\n'.join(lines))


if __name__ == '__main__':
    main()
