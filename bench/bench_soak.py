"""
Soak benchmarks: memory and latency at the start and at the end of long runs.

    python bench/bench_soak.py [--part batch|realtime|all] [--cycles N] [--seconds S]
                               [--camera-hz HZ] [--quick] [--keep-bag] [--out FILE]

Benchmarks, not tests: nothing is asserted. Each part prints a markdown section and replaces
its own section of the results file (bench/soak_results.md; the other part's section stays).
Every ratio compares the end of a run with its own start, so a busy machine moves both ends
alike; the load average and the share of the machine other work took go into the file.

Parts:
  batch     `softseq run` of the paper scene repeated ``--cycles`` times (18 by default:
            10.3 M messages), in a fresh interpreter that imports no rclpy: a temporary scene
            file beside the shipped ones (config/, the public scene format, removed
            afterwards), run by softseq_ros.run. Its progress stream (a line every
            0.25 s of wall time) is the sampling hook: resident memory (VmRSS), Python's
            allocated blocks, CPU time and messages written so far. Reported per pump cycle
            (equal work) and at the start, at 10 % and at the end; the bag is checked with
            bag_summary and removed unless ``--keep-bag``.
  realtime  the rclpy nodes as processes over DDS in real time: `syringe_pump` at 100 Hz
            (paper scene, autostart off), `actuator`, `camera` (``--camera-hz``, 100 by
            default) and `recorder` (every rig topic), for ``--seconds`` (600 by default), with
            a probe node in this process. Command -> /actuator/volumes latency (the actuator
            stamps its outputs with the command's stamp; receipt wall clock at the probe, as
            bench_rig.py's latency part measures it) per minute, first against last minute;
            losses against the probe and against the recorder's bag; resident memory and CPU
            of every node process from /proc/<pid>/ at the start and at the end.

``--quick``: the batch part only, 2 cycles of a 0 -> 10 -> 0 mL programme (about 10 s; the
scene file in a temporary folder, not in config/); ``--quick --part realtime`` runs the
real-time part for 20 s. Printed but not written into the results file unless ``--out`` is
given. The test suite runs ``--quick`` (test/test_bench_quick.py).

Run the batch child alone: ``python bench/bench_soak.py --batch-child SCENE OUT`` (prints one
JSON object).
"""

import argparse
import json
import math
import os
from pathlib import Path
import re
import shutil
import struct
import subprocess
import sys
import tempfile
import time

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from machine import latency_row, load_text, machine_facts  # noqa: E402
from mcap.reader import make_reader  # noqa: E402
import numpy as np  # noqa: E402
import yaml  # noqa: E402

import softseq_ros  # noqa: E402
from softseq_ros.bag.reader import bag_summary, read_bag  # noqa: E402
from softseq_ros.scene.loader import load_scene  # noqa: E402
from softseq_ros.scene.paths import config_dir  # noqa: E402

# rclpy (and bench_rig, which imports it) are imported in the real-time part only: the batch
# child runs this file and must carry no more than `softseq run` does.

RESULTS = ROOT / 'bench' / 'soak_results.md'
PARTS = ('batch', 'realtime')
MB = 1024.0 * 1024.0
CLOCK_TICKS = os.sysconf('SC_CLK_TCK')

BATCH_CYCLES = 18             # 18 x 574,229 messages of the paper programme = 10.3 M
BATCH_TARGET_MESSAGES = 10_000_000
REALTIME_S = 600.0
QUICK_S = 20.0
QUICK_CYCLES = 2
QUICK_LEGS = [{'inflate_to_m3': 1.0e-5}, {'deflate_to_m3': 0.0}]   # 0 -> 10 -> 0 mL, 400 s
PUMP_HZ = 100
CAMERA_HZ = 100
SAMPLE_PERIOD_S = 5.0
WINDOW_S = 60.0               # "first minute" and "last minute"
STARTUP_TIMEOUT_S = 90.0
QUIET_S = 2.0
MATCH_TOLERANCE_M3 = 1.0e-12  # a command and its answer agree to round-off


# ------------------------------------------------------------------------------ /proc readers

def proc_memory(pid: int | str = 'self') -> tuple[int, int]:
    """VmRSS and VmHWM [bytes] of a process, from /proc/<pid>/status."""
    values = {}
    with open(f'/proc/{pid}/status', encoding='ascii') as status:
        for line in status:
            if line.startswith(('VmRSS:', 'VmHWM:')):
                key, amount, _unit = line.split()
                values[key] = int(amount) * 1024
    return values.get('VmRSS:', 0), values.get('VmHWM:', 0)


def proc_cpu_s(pid: int | str = 'self') -> float:
    """User + system CPU time [s] of a process (all its threads), from /proc/<pid>/stat."""
    with open(f'/proc/{pid}/stat', encoding='ascii') as stat:
        fields = stat.read().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS


def machine_cpu_s() -> tuple[float, float]:
    """Busy and total CPU time [s] of the whole machine (all cores), from /proc/stat."""
    with open('/proc/stat', encoding='ascii') as stat:
        numbers = [int(x) for x in stat.readline().split()[1:9]]
    total = sum(numbers)
    idle = numbers[3] + numbers[4]  # idle + iowait
    return (total - idle) / CLOCK_TICKS, total / CLOCK_TICKS


def shared_machine_note(load_before: str, load_after: str, other_share: float | None) -> str:
    cores = len(os.sched_getaffinity(0))
    text = (f'Load average (1/5/15 min) before: {load_before}; after: {load_after} '
            f'({cores} cores).')
    if other_share is not None:
        text += (f' Other work on the machine took {100.0 * other_share:.0f} % of its CPU '
                 'time during the run (whole machine busy time from /proc/stat minus the '
                 "benchmark's own processes).")
    text += (' The machine is shared: test runs of other work may have run at the same time, '
             'so absolute rates and latencies are those of a busy 2-core machine; the start '
             'and end of a run saw the same kind of load.')
    return text


def mb(value: float) -> str:
    return f'{value / MB:.1f}'


def mcap_chunks(bag: Path) -> tuple[int, int]:
    """Chunks of a bag's MCAP files and their uncompressed bytes, from the summary."""
    count = size = 0
    for file in sorted(bag.glob('*.mcap')):
        with open(file, 'rb') as stream:
            indexes = make_reader(stream).get_summary().chunk_indexes
        count += len(indexes)
        size += sum(index.uncompressed_size for index in indexes)
    return count, size


# ------------------------------------------------------------------------------ part 1: batch

class _Sampler:
    """
    Samples of a batch run as it goes, through its public hooks only.

    The run's progress stream (a line every 0.25 s of wall time) takes a sample at every line.
    Its ``wrap`` hook counts the messages written by blocks (``block.append``: how many, and
    the log time of the last, the run's simulated clock) and sees the programme's last instant
    coming (``block.pump``: no plain tick left, the programme over), where it takes the last
    sample, before the bag is closed. It wraps no per-message stage, so the run goes by blocks
    as ``softseq run`` does; the few instants that go one message at a time (the start,
    snapshots, the last instant) are not counted in the samples, only in the run's totals.
    """

    def __init__(self, start_time_ns: int) -> None:
        self.start_time_ns = start_time_ns
        self.pump = None
        # What was measured once the run's cores were built, just before it started.
        self.built: dict[str, float] = {}
        self.origin = time.perf_counter()
        self.samples: list[tuple[float, float, int, int, int, float]] = []
        # Messages written, log time of the last [ns], whether the programme has ended.
        self.written = [0, 0, False]

    def _sample(self) -> tuple[float, float, int, int, int, float]:
        count, last_ns, _ = self.written
        sim = (last_ns - self.start_time_ns) * 1e-9 if count else 0.0
        rss, _ = proc_memory()
        return (time.perf_counter() - self.origin, sim, count, rss, sys.getallocatedblocks(),
                time.process_time())

    def sample(self) -> None:
        self.samples.append(self._sample())

    def renew(self) -> None:
        self.samples[-1] = self._sample()

    def wrap(self, label: str, function):
        """The run's ``wrap`` hook: count what is written, see the programme end."""
        if not self.built:
            # The first stage handed over: the cores are built, the run is about to start.
            self.built['rss'] = proc_memory()[0]
            self.origin = time.perf_counter()
            self.sample()
            self.built['machine_busy_s'] = machine_cpu_s()[0]
        if label == 'block.append':
            written = self.written

            def counted(blocks) -> None:
                function(blocks)
                for block in blocks:
                    written[0] += block.rows.size * len(block.channels)
                    if block.log_times.size:
                        written[1] = max(written[1], int(block.log_times[-1]))
            return counted
        if label == 'pump.tick':
            self.pump = function.__self__   # seen, not wrapped: the run stays by blocks
        if label == 'block.pump':
            def planned(times, *options):
                plan = function(times, *options)
                pump = self.pump
                if not plan[0] and not self.written[2] and pump.state == 'running' \
                        and pump.run_time_s(int(times[0])) >= pump.duration_s:
                    # The programme's last instant is next: the last sample, before it.
                    self.sample()
                    self.written[2] = True
                return plan
            return planned
        return function

    def write(self, text: str) -> None:
        if text.strip():
            self.sample()

    def flush(self) -> None:
        pass

    def isatty(self) -> bool:
        return False


def batch_child(scene: Path, out: Path) -> None:
    """Run the soak scene into ``out`` sampling as it goes; print one JSON object."""
    rss_imported, _ = proc_memory()
    sampler = _Sampler(time.time_ns())
    result = softseq_ros.run(scene, out, progress=sampler, wrap=sampler.wrap,
                             start_time_ns=sampler.start_time_ns)
    machine_after = machine_cpu_s()[0]
    rss_built, machine_before = sampler.built['rss'], sampler.built['machine_busy_s']
    closing_s = time.perf_counter() - sampler.origin - sampler.samples[-1][0]
    cpu_end = time.process_time()
    rss_end, hwm = proc_memory()
    profile = sampler.pump.profile
    print(json.dumps({
        'rss_imported': rss_imported, 'rss_built': rss_built, 'rss_end': rss_end, 'hwm': hwm,
        'samples': sampler.samples, 'wall_s': result.wall_s,
        'sim_s': result.sim_duration_s, 'counts': result.message_counts,
        'pump_state': result.pump_state, 'closing_s': closing_s,
        'machine_busy_s': machine_after - machine_before, 'cpu_end': cpu_end,
        'cycles': profile.cycles,
        'cycle_s': sampler.pump.duration_s / profile.cycles, 'warnings': result.warnings[:20]}))


def write_soak_scene(cycles: int, folder: Path | None = None, legs: list | None = None) -> Path:
    """
    The paper scene with ``cycles`` pump cycles (of ``legs``, if given, instead of its own).

    Written beside the shipped scenes (its tables resolve as theirs do), or into ``folder``
    with its tables by absolute path.
    """
    raw = yaml.safe_load((config_dir() / 'paper.yaml').read_text(encoding='utf-8'))
    raw['name'] = f'soak_paper_{cycles}'
    raw['description'] = (f'The paper scene, its pump programme repeated {cycles} times '
                          '(bench/bench_soak.py, temporary).')
    raw['pump']['cycles'] = int(cycles)
    if legs is not None:
        raw['pump']['legs'] = legs
        # The camera's snapshots at volumes the programme reaches.
        top = max(leg.get('inflate_to_m3', 0.0) for leg in legs)
        camera = raw.get('camera', {})
        camera['trigger_injected_m3'] = [v for v in camera.get('trigger_injected_m3', [])
                                         if v <= top]
    if folder is None:
        path = config_dir() / f'soak_{os.getpid()}.yaml'
    else:
        for segment in raw['segments']:
            if 'table' in segment:
                segment['table'] = str(config_dir() / segment['table'])
        path = folder / f'soak_{os.getpid()}.yaml'
    path.write_text('# Temporary: written and removed by bench/bench_soak.py.\n'
                    + yaml.safe_dump(raw, sort_keys=False), encoding='utf-8')
    load_scene(path)  # refused here, in one line, rather than in the child
    return path


def _at_fraction(samples: list, fraction: float, total: int) -> tuple:
    """The first sample at or past ``fraction`` of the messages."""
    return next(s for s in samples if s[2] >= fraction * total)


def _ratio(value: float, baseline: float) -> str:
    """``value / baseline`` to two places; '-' where a run too short to sample has none."""
    return f'{value / baseline:.2f}' if baseline > 0 else '-'


def _window_rate(samples: list, start: int, end: int) -> float:
    """
    Messages per wall second between the samples nearest two message counts.

    At least one sample apart: a short run (``--quick``) may have no sample between them.
    """
    index = next(i for i, s in enumerate(samples) if s[2] >= start)
    if index == len(samples) - 1 and index > 0:
        index -= 1   # the window lies past the last sample but one: from that one on
    first = samples[index]
    last = next((s for s in samples[index + 1:] if s[2] >= end), samples[-1])
    return (last[2] - first[2]) / max(last[0] - first[0], 1e-9)


def part_batch(cycles: int, keep_bag: bool, quick: bool = False) -> str:
    load_before = load_text()
    with tempfile.TemporaryDirectory(prefix='bench_soak_batch_') as tmp:
        # Quick: a shorter programme, and the scene file in the temporary folder, not config/.
        scene = write_soak_scene(cycles, Path(tmp), QUICK_LEGS) if quick \
            else write_soak_scene(cycles)
        try:
            out = Path(tmp) / 'bag'
            print(f'batch: {cycles} cycles of the paper programme -> {out} ...', flush=True)
            child = subprocess.run(
                [sys.executable, __file__, '--batch-child', str(scene), str(out)],
                capture_output=True, text=True, timeout=4 * 3600)
            if child.returncode != 0:
                raise RuntimeError(f'batch child failed ({child.returncode}): '
                                   f'{child.stderr[-3000:]}')
            info = json.loads(child.stdout.strip().splitlines()[-1])
            summary = bag_summary(out)
            bag_bytes = sum(f.stat().st_size for f in out.iterdir() if f.is_file())
            chunks, raw_bytes = mcap_chunks(out)
            kept = _keep_bag(out, 'batch') if keep_bag else None
        finally:
            scene.unlink(missing_ok=True)
    samples = info['samples']
    total = sum(info['counts'].values())
    child_cpu = info['cpu_end'] - samples[0][5]
    other = max(0.0, info['machine_busy_s'] - child_cpu) / (
        info['wall_s'] * len(os.sched_getaffinity(0)))

    counts_agree = all(summary.topics[t].message_count == n for t, n in info['counts'].items()
                       if t in summary.topics) and summary.message_count == total
    start, tenth, end = samples[0], _at_fraction(samples, 0.1, total), samples[-1]
    # After the first progress line: the equilibrium map and the writer exist, messages flow.
    first = samples[1] if len(samples) > 2 else start
    cycle_s = info['cycle_s']
    sims = np.array([s[1] for s in samples])
    walls = np.array([s[0] for s in samples])
    messages = np.array([s[2] for s in samples], dtype=float)
    cpus = np.array([s[5] for s in samples])
    rows = []
    for k in range(info['cycles']):
        lo, hi = k * cycle_s, min((k + 1) * cycle_s, info['sim_s'])
        wall = np.interp(hi, sims, walls) - np.interp(lo, sims, walls)
        count = np.interp(hi, sims, messages) - np.interp(lo, sims, messages)
        cpu = np.interp(hi, sims, cpus) - np.interp(lo, sims, cpus)
        at_end = samples[min(int(np.searchsorted(sims, hi)), len(samples) - 1)]
        rows.append((k + 1, count, wall, cpu, at_end[3], at_end[4]))
    # A cycle the samples do not resolve (a --quick run is over in a fraction of a second)
    # has no rate: 0, and its ratios show '-'.
    rate_first, rate_last = (row[1] / row[2] if row[2] > 0 else 0.0 for row in (rows[0], rows[-1]))
    cpu_first, cpu_last = (row[3] / row[1] * 1e6 if row[1] > 0 else 0.0
                           for row in (rows[0], rows[-1]))
    window = max(1, total // 10)
    early = _window_rate(samples, first[2], first[2] + window)
    late = _window_rate(samples, total - window, total)
    rss_values = [s[3] for s in samples[1:]] or [start[3]]
    later = ''
    if len(rows) > 1:
        growth = rows[-1][4] - rows[0][4]
        chunks_later = chunks * (len(rows) - 1) / len(rows)
        later = (f' After the first cycle: {growth / MB:+.1f} MB over {len(rows) - 1} cycles '
                 f'({growth / (len(rows) - 1) / 1024:+.0f} KB per cycle, '
                 f'{growth / max(chunks_later, 1):+.0f} bytes per chunk written then), Python '
                 f'blocks {rows[-1][5] - rows[0][5]:+,} '
                 f'({(rows[-1][5] - rows[0][5]) / max(chunks_later, 1):+.1f} per chunk).')

    programme, where = ('0 -> 65 -> 0 mL', 'in `config/`') if not quick else (
        '**quick check**: programme shortened to 0 -> 10 -> 0 mL', 'in a temporary folder')
    lines = [
        '## 1. Batch soak (`softseq_ros.run`, one process, no rclpy)', '',
        f'The paper scene (`config/paper.yaml`: {programme} at 0.05 mL/s, pump 50 Hz, '
        f'camera 10 Hz, every output recorded) with its pump programme repeated '
        f'{info["cycles"]} times, {info["sim_s"]:,.0f} s of rig time, from a temporary scene '
        f'file {where} (the public scene format; removed afterwards), run in a fresh '
        "interpreter that imports what `softseq run` imports and no rclpy. The run's "
        'progress stream is the sampling hook (a line every 0.25 s of wall time): VmRSS from '
        '/proc/self/status, `sys.getallocatedblocks()` (Python objects alive), CPU time and '
        "the messages written so far (counted through the run's public `wrap` hook around "
        'the bag write of each block of instants; the few instants written one message at a '
        'time, the start, snapshots and the last instant, count in the totals only; the last '
        f'sample is taken just before the last instant); {len(samples)} samples.', '',
        f'**{total:,} messages** in {info["wall_s"]:.0f} s wall '
        f'({info["sim_s"] / info["wall_s"]:.0f}x real time; target >= '
        f'{BATCH_TARGET_MESSAGES:,}: {"met" if total >= BATCH_TARGET_MESSAGES else "**not met**"}'
        f'). Bag: {bag_bytes / 1e9:.2f} GB in {chunks:,} chunks ({raw_bytes / 1e9:.2f} GB '
        f'uncompressed), `bag_summary`: complete = {summary.complete}, '
        f'{summary.message_count:,} messages, per-topic counts '
        f'{"equal to" if counts_agree else "**differ from**"} the run\'s; pump state at the end '
        f'`{info["pump_state"]}`. '
        + (f'Kept at `{kept.relative_to(ROOT)}`.' if kept else 'The bag was removed.'), '',
        '| resident memory (VmRSS) | messages written | MB | Python blocks |',
        '|---|---:|---:|---:|',
        f'| after the imports | - | {mb(info["rss_imported"])} | - |',
        f'| run built (scene, equilibrium map, cores) | 0 | {mb(info["rss_built"])} | '
        f'{start[4]:,} |',
        f'| start (first progress line) | {first[2]:,} | {mb(first[3])} | {first[4]:,} |',
        f'| at 10 % | {tenth[2]:,} | {mb(tenth[3])} | {tenth[4]:,} |',
        f'| end (before the last instant) | {end[2]:,} | {mb(end[3])} | {end[4]:,} |',
        f'| bag closed ({info["closing_s"]:.1f} s: last chunk, summary, metadata) | '
        f'{end[2]:,} | {mb(info["rss_end"])} | - |',
        f'| lowest / highest sample after the start | | {mb(min(rss_values))} / '
        f'{mb(max(rss_values))} | |',
        f'| peak (VmHWM) | | {mb(info["hwm"])} | |', '',
        f'**End / start: RSS {end[3] / first[3]:.3f}** (end / 10 %: {end[3] / tenth[3]:.3f}); '
        f'Python blocks {end[4] / max(first[4], 1):.3f} (end / 10 %: '
        f'{end[4] / max(tenth[4], 1):.3f}).' + later, '',
        f'**Messages per wall second**: first cycle {rate_first:,.0f}, last cycle '
        f'{rate_last:,.0f}, **last / first {_ratio(rate_last, rate_first)}**; first 10 % of '
        f'the messages {early:,.0f}, last 10 % {late:,.0f} ({_ratio(late, early)}). CPU per '
        f'message (this process, all threads): {cpu_first:.1f} us in the first cycle, '
        f'{cpu_last:.1f} us in the last ({_ratio(cpu_last, cpu_first)}): CPU time moves less '
        'with the load than wall time.', '',
        '| cycle | messages | wall [s] | messages / wall s | CPU [us / message] | RSS at its '
        'end [MB] | Python blocks at its end |',
        '|---:|---:|---:|---:|---:|---:|---:|']
    for number, count, wall, cpu, rss, blocks in rows:
        rate = f'{count / wall:,.0f}' if wall > 0 else '-'
        per_message = f'{cpu / count * 1e6:.1f}' if count > 0 else '-'
        lines.append(f'| {number} | {count:,.0f} | {wall:.1f} | {rate} | {per_message} | '
                     f'{mb(rss)} | {blocks:,} |')
    lines += ['', 'Messages: ' + ', '.join(f'{t} {n:,}' for t, n in sorted(info['counts'].items()))
              + '.', '']
    if info['warnings']:
        lines += ['Warnings of the run: ' + '; '.join(info['warnings']), '']
    lines.append(shared_machine_note(load_before, load_text(), other))
    return '\n'.join(lines)


# ------------------------------------------------------------------------------ part 2: realtime

def _cdr_stamp(data: bytes) -> int:
    """The header stamp [ns] of a CDR message whose first field is std_msgs/Header."""
    order = '<' if data[1] & 1 else '>'
    sec, nanosec = struct.unpack_from(order + 'iI', data, 4)
    return sec * 1_000_000_000 + nanosec


class SoakProbe:
    """
    What this benchmark hears of the rig, kept small: receipt time and stamp per message.

    Commands and volumes are decoded (their volumes are compared); pressure, curvatures and
    frames arrive raw and only their header stamp is read, so ten minutes at 100 Hz stay a few
    MB and the probe's callbacks stay cheap.
    """

    def __init__(self, node, rest_m3: float) -> None:  # noqa: ANN001
        from softseq_ros.nodes.core_node import message_class, qos_profile
        from softseq_ros.wire import contract
        self.node = node
        self.rest_m3 = rest_m3
        self.commands: list[tuple[int, int, float]] = []  # received, stamp, injected
        self.volumes: list[tuple[int, int, float]] = []   # received, stamp, injected
        self.pressure: list[tuple[int, int]] = []
        self.curvatures: list[tuple[int, int]] = []
        self.frames: list[tuple[int, int]] = []
        self.statuses: list[tuple[int, str, str]] = []
        self.last_volumes = time.monotonic()

        def subscribe(topic, callback, raw=False) -> None:  # noqa: ANN001
            qos = qos_profile(topic.qos)
            qos.depth = max(qos.depth, 1000)
            node.create_subscription(message_class(topic.type_name),
                                     contract.resolve(topic.name), callback, qos, raw=raw)

        subscribe(contract.PUMP_COMMAND, self._on_command)
        subscribe(contract.VOLUMES, self._on_volumes)
        subscribe(contract.PRESSURE, lambda data: self.pressure.append(
            (time.time_ns(), _cdr_stamp(data))), raw=True)
        subscribe(contract.CURVATURES, lambda data: self.curvatures.append(
            (time.time_ns(), _cdr_stamp(data))), raw=True)
        subscribe(contract.BACKBONE, lambda data: self.frames.append(
            (time.time_ns(), _cdr_stamp(data))), raw=True)
        subscribe(contract.PUMP_STATUS, self._on_status)
        self.topics = [contract.resolve(t.name) for t in (
            contract.PUMP_COMMAND, contract.VOLUMES, contract.PRESSURE, contract.CURVATURES,
            contract.BACKBONE)]

    def _on_command(self, msg) -> None:  # noqa: ANN001
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        self.commands.append((time.time_ns(), stamp, msg.position[0]))

    def _on_volumes(self, msg) -> None:  # noqa: ANN001
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        self.volumes.append((time.time_ns(), stamp, sum(msg.position) - self.rest_m3))
        self.last_volumes = time.monotonic()

    def _on_status(self, msg) -> None:  # noqa: ANN001
        status = json.loads(msg.data)
        self.statuses.append((time.time_ns(), status['state'], status.get('reason', '')))

    def matched(self) -> bool:
        return all(self.node.count_publishers(t) > 0 for t in self.topics)

    def recorder_on_every_topic(self) -> bool:
        return all(any(info.node_name == 'recorder'
                       for info in self.node.get_subscriptions_info_by_topic(t))
                   for t in self.topics)


class ProcessSamples:
    """RSS, peak RSS and CPU time of processes, sampled on demand."""

    def __init__(self, processes: dict[str, int]) -> None:
        self.pids = processes
        self.rows: dict[str, list[tuple[float, int, int, float]]] = {n: [] for n in processes}
        self.machine: list[tuple[float, float, float, float]] = []

    def take(self, t_s: float) -> None:
        for name, pid in self.pids.items():
            try:
                rss, hwm = proc_memory(pid)
                self.rows[name].append((t_s, rss, hwm, proc_cpu_s(pid)))
            except (FileNotFoundError, ProcessLookupError):
                pass
        busy, total = machine_cpu_s()
        self.machine.append((t_s, busy, total, os.getloadavg()[0]))

    def at(self, name: str, t_s: float) -> tuple[float, int, int, float]:
        """The sample nearest to ``t_s``."""
        return min(self.rows[name], key=lambda row: abs(row[0] - t_s))

    def cpu_share(self, name: str, lo: float, hi: float) -> float:
        """CPU time per wall time (1.0 = one core) between the samples nearest lo and hi."""
        a, b = self.at(name, lo), self.at(name, hi)
        return (b[3] - a[3]) / max(b[0] - a[0], 1e-9)


def pick_domain(context_of) -> tuple[int, object]:  # noqa: ANN001
    """A ROS domain with nobody else on it (a test run may be using its own)."""
    import rclpy
    first = 1 + os.getpid() % 100
    for attempt in range(8):
        domain = 1 + (first - 1 + 13 * attempt) % 100
        context = context_of(domain)
        node = rclpy.create_node('soak_domain_check', context=context)
        time.sleep(3.0)
        others = [n for n, _ in node.get_node_names_and_namespaces()
                  if n != 'soak_domain_check']
        node.destroy_node()
        if not others:
            return domain, context
        rclpy.try_shutdown(context=context)
        print(f'realtime: domain {domain} in use ({", ".join(sorted(set(others)))}); next',
              flush=True)
    raise RuntimeError('no free ROS domain found')


def _keep_bag(bag: Path, kind: str) -> Path:
    """Move a soak's bag into bags/, named by its kind and the time."""
    kept = ROOT / 'bags' / f'soak_{kind}_{time.strftime("%Y%m%d_%H%M%S")}'
    kept.parent.mkdir(exist_ok=True)
    shutil.move(str(bag), kept)
    return kept


def _window(items: list, start_ns: int, lo_s: float, hi_s: float, index: int = 1) -> list:
    lo, hi = start_ns + int(lo_s * 1e9), start_ns + int(hi_s * 1e9)
    return [item for item in items if lo <= item[index] < hi]


def realtime_run(seconds: float, camera_hz: float, workdir: Path) -> dict:
    """Start the nodes, run the pump for ``seconds``, stop; everything the report needs."""
    import bench_rig as rig  # rclpy from here on
    import rclpy

    rest = rig.rest_volume('paper')
    profile = load_scene('paper').pump.profile
    cycle_s = profile.duration() / profile.cycles
    cycles = max(1, math.ceil((seconds + 120.0) / cycle_s))
    bag = workdir / 'bag'
    logs = workdir / 'logs'
    logs.mkdir()
    (workdir / 'ros_home').mkdir()

    def context_of(domain: int):  # noqa: ANN202
        context = rclpy.Context()
        rclpy.init(context=context, args=[], domain_id=domain)
        return context

    domain, context = pick_domain(context_of)
    print(f'realtime: ROS domain {domain}', flush=True)
    env = rig.child_environment(domain)
    env['ROS_HOME'] = str(workdir / 'ros_home')
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    outcome: dict = {'domain': domain, 'cycles': cycles, 'rest': rest, 'holds': 0,
                     'seconds': seconds, 'camera_hz': camera_hz}
    try:
        with rig.node_processes(env, logs) as start:
            node = rclpy.create_node('soak_probe', context=context)
            probe = SoakProbe(node, rest)
            with rig.spinning(context, node):
                # The recorder subscribes to a topic once it has a publisher: it is waited
                # for below, before the pump starts.
                procs = {'recorder': start('recorder', 'recorder', output=str(bag))}
                procs['actuator'] = start('actuator', 'actuator', scene='paper',
                                          resume_timeout_s=0.0)
                procs['camera'] = start('camera', 'camera', scene='paper',
                                        rate_hz=float(camera_hz))
                procs['syringe_pump'] = start('pump', 'syringe_pump', scene='paper',
                                              rate_hz=PUMP_HZ, autostart='false',
                                              cycles=cycles)
                rig.wait_for(probe.matched, 'the nodes', STARTUP_TIMEOUT_S)
                rig.wait_for(lambda: node.count_subscribers('/pump/command') >= 3
                             and node.count_subscribers('/actuator/curvatures') >= 3,
                             'the actuator, camera and recorder subscriptions',
                             STARTUP_TIMEOUT_S)
                rig.wait_for(probe.recorder_on_every_topic, 'the recorder on every topic',
                             STARTUP_TIMEOUT_S)
                time.sleep(2.0)  # the nodes settle (first timers, discovery of the rest)
                pids = {name: procs[name].pid
                        for name in ('syringe_pump', 'actuator', 'camera', 'recorder')}
                pids['benchmark (probe)'] = os.getpid()
                samples = ProcessSamples(pids)
                outcome['load_before'] = load_text()
                origin = time.monotonic()
                samples.take(0.0)
                start_ns = time.time_ns()
                rig.call_start(node)
                handled = 0
                next_sample = SAMPLE_PERIOD_S
                print(f'realtime: running {seconds:.0f} s ...', flush=True)
                while True:
                    elapsed = time.monotonic() - origin
                    if elapsed >= seconds:
                        break
                    dead = [n for n, p in procs.items() if p.poll() is not None]
                    if dead:
                        tail = (logs / f'{"pump" if dead[0] == "syringe_pump" else dead[0]}'
                                '.log').read_text(errors='replace')[-2000:]
                        raise RuntimeError(f'{", ".join(dead)} exited during the run:\n{tail}')
                    statuses = probe.statuses[handled:]
                    handled += len(statuses)
                    if any(state == 'held' for _, state, _ in statuses):
                        # The pump held (no pressure feedback for feedback_timeout_s): go on,
                        # and count it.
                        outcome['holds'] += 1
                        rig.call_start(node)
                    if elapsed >= next_sample:
                        samples.take(elapsed)
                        next_sample += SAMPLE_PERIOD_S
                        if int(elapsed) % 60 < SAMPLE_PERIOD_S:
                            print(f'  {elapsed:5.0f} s: {len(probe.commands)} commands, '
                                  f'load {load_text()}', flush=True)
                    time.sleep(min(0.2, max(0.0, next_sample - elapsed)))
                end_ns = time.time_ns()
                samples.take(time.monotonic() - origin)
                outcome['load_after'] = load_text()
                # Stop the pump, let the answers to its last commands arrive, then close the bag.
                rig.stop_process(procs['syringe_pump'])
                rig.wait_for(lambda: time.monotonic() - probe.last_volumes > QUIET_S,
                             'the actuator to go quiet', 60.0)
                rig.stop_process(procs['recorder'], timeout=120.0)
            received = {'commands': list(probe.commands), 'volumes': list(probe.volumes),
                        'pressure': list(probe.pressure), 'curvatures': list(probe.curvatures),
                        'frames': list(probe.frames), 'statuses': list(probe.statuses)}
    finally:
        rclpy.try_shutdown(context=context)
    outcome.update(received=received, samples=samples, start_ns=start_ns, end_ns=end_ns,
                   bag=bag)
    return outcome


def _bag_stamps(bag: Path, topics: list[str]) -> dict[str, list[int]]:
    stamps: dict[str, list[int]] = {t: [] for t in topics}
    for item in read_bag(bag, topics=topics):
        stamp = item.msg.header.stamp
        stamps[item.topic].append(stamp.sec * 1_000_000_000 + stamp.nanosec)
    return stamps


def part_realtime(seconds: float, camera_hz: float, keep_bag: bool) -> str:
    with tempfile.TemporaryDirectory(prefix='bench_soak_rt_') as tmp:
        workdir = Path(tmp)
        run = realtime_run(seconds, camera_hz, workdir)
        bag = run['bag']
        print('realtime: reading the bag back ...', flush=True)
        summary = bag_summary(bag)
        answer_topics = ['/actuator/volumes', '/actuator/pressure', '/actuator/curvatures']
        in_bag = _bag_stamps(bag, ['/pump/command', *answer_topics])
        bag_bytes = sum(f.stat().st_size for f in bag.iterdir() if f.is_file())
        chunks, _ = mcap_chunks(bag)
        kept = _keep_bag(bag, 'realtime') if keep_bag else None
    received, samples = run['received'], run['samples']
    start_ns, end_ns = run['start_ns'], run['end_ns']
    duration = (end_ns - start_ns) * 1e-9
    window = min(WINDOW_S, duration / 3.0)
    period_ns = 1_000_000_000 // PUMP_HZ

    # Commands of the measured span (from the start call to the end of the loop), by stamp.
    commands = [c for c in received['commands'] if start_ns <= c[1] < end_ns]
    command_of = {stamp: (recv, injected) for recv, stamp, injected in commands}
    volumes_of: dict[int, tuple[int, float]] = {}
    for recv, stamp, injected in received['volumes']:
        volumes_of.setdefault(stamp, (recv, injected))
    mismatched = sum(1 for stamp, (_, injected) in command_of.items()
                     if stamp in volumes_of
                     and abs(volumes_of[stamp][1] - injected) > MATCH_TOLERANCE_M3)
    stamps = sorted(command_of)
    gaps = np.diff(np.array(stamps, dtype=np.int64)) if len(stamps) > 1 else np.array([])
    late = int(np.count_nonzero(gaps > 1.5 * period_ns)) if gaps.size else 0
    widest_ms = float(gaps.max()) * 1e-6 if gaps.size else 0.0
    probe_answers = {'/actuator/volumes': set(volumes_of),
                     '/actuator/pressure': {s for _, s in received['pressure']},
                     '/actuator/curvatures': {s for _, s in received['curvatures']}}
    span = set(stamps)
    bag_commands = {s for s in in_bag['/pump/command'] if start_ns <= s < end_ns}
    bag_answers = {t: set(in_bag[t]) for t in answer_topics}

    def latency_ms(items: list) -> list[float]:
        return [(volumes_of[stamp][0] - stamp) * 1e-6 for _, stamp, _ in items
                if stamp in volumes_of]

    def hop_ms(items: list) -> list[float]:
        return [(recv - stamp) * 1e-6 for recv, stamp, _ in items]

    def frames_in(lo: float, hi: float) -> list:
        return _window(received['frames'], start_ns, lo, hi)

    first_cmds = _window(commands, start_ns, 0.0, window)
    last_cmds = _window(commands, start_ns, duration - window, duration)
    first_lat, last_lat = latency_ms(first_cmds), latency_ms(last_cmds)

    lines = [
        f'## 2. Real-time soak (nodes as processes over DDS, pump at {PUMP_HZ} Hz, '
        f'{duration:.0f} s)', '',
        f'`recorder` (every rig topic, into a temporary bag), `actuator` (`scene:=paper`), '
        f'`camera` (`rate_hz:={camera_hz:g}`, free-running frame timer) and `syringe_pump` '
        f'(`rate_hz:={PUMP_HZ}`, `autostart:=false`, `cycles:={run["cycles"]}`, the paper '
        'programme: 0.05 mL/s from 0 mL), each a console script in its own process, on a ROS '
        f'domain of their own (checked empty first; `ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`, '
        '`ROS_HOME` a temporary directory). A probe node in the benchmark process '
        '(SingleThreadedExecutor in a thread) notes the wall clock at every /pump/command, '
        '/actuator/volumes, /actuator/pressure, /actuator/curvatures and /camera/backbone '
        'message (only the stamp and, for commands and volumes, the injected volume are kept). '
        "Latency = the probe's receipt of /actuator/volumes minus the stamp of the command it "
        "answers (the pump's system clock just before publishing; the actuator stamps its "
        'outputs with it), as `bench_rig.py --part latency` measures it, here paired by stamp '
        'and checked by content (the volumes minus the rest volumes equal the commanded '
        f'injected volume to 1e-12 m^3). Process memory and CPU from /proc/<pid>/ every '
        f'{SAMPLE_PERIOD_S:g} s. "First" and "last" are the first and last {window:.0f} s of '
        'the run, by command stamp. At the end the pump is stopped first, the answers to its '
        f'last commands are waited for ({QUIET_S:g} s without /actuator/volumes), then the '
        'recorder closes its bag.', '',
        '**Latency, command -> /actuator/volumes at the probe [ms]**:', '',
        '| window | median | p99 | max | samples |', '|---|---:|---:|---:|---:|',
        f'| first {window:.0f} s | {latency_row(first_lat, (50, 99))} |',
        f'| last {window:.0f} s | {latency_row(last_lat, (50, 99))} |',
        f'| for scale, command -> /pump/command at the probe (one hop), first | '
        f'{latency_row(hop_ms(first_cmds), (50, 99))} |',
        f'| for scale, command -> /pump/command at the probe (one hop), last | '
        f'{latency_row(hop_ms(last_cmds), (50, 99))} |', '']
    if first_lat and last_lat:
        lines += [f'Last / first: median **{np.median(last_lat) / np.median(first_lat):.2f}**, '
                  f'p99 {np.percentile(last_lat, 99) / np.percentile(first_lat, 99):.2f}, '
                  f'max {max(last_lat) / max(first_lat):.2f}.', '']

    lines += ['Per minute (by command stamp; frames by frame stamp; load = 1-minute load '
              "average at the minute's end):", '',
              '| minute | commands | answered (volumes) | median [ms] | p99 [ms] | max [ms] | '
              'hop median [ms] | frames / s | frame delivery median [ms] | load |',
              '|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|']
    minutes = max(1, math.ceil(duration / 60.0 - 1e-6))
    for minute in range(minutes):
        lo, hi = 60.0 * minute, min(60.0 * (minute + 1), duration)
        items = _window(commands, start_ns, lo, hi)
        lat = latency_ms(items)
        frames = frames_in(lo, hi)
        delivery = [(recv - stamp) * 1e-6 for recv, stamp in frames]
        load = min(samples.machine, key=lambda row: abs(row[0] - hi))[3]
        lines.append(
            f'| {minute + 1} | {len(items)} | {len(lat)} | '
            f'{np.median(lat) if lat else float("nan"):.2f} | '
            f'{np.percentile(lat, 99) if lat else float("nan"):.2f} | '
            f'{max(lat) if lat else float("nan"):.2f} | '
            f'{np.median(hop_ms(items)) if items else float("nan"):.2f} | '
            f'{len(frames) / max(hi - lo, 1e-9):.1f} | '
            f'{np.median(delivery) if delivery else float("nan"):.2f} | {load:.2f} |')

    expected = duration * PUMP_HZ
    lines += [
        '', '**Losses** (commands of the measured span, by stamp):', '',
        f'- /pump/command: {len(stamps):,} at the probe for {expected:,.0f} timer periods '
        f'({expected - len(stamps):,.0f} fewer); {late} stamp gaps over 1.5 periods (a late '
        f'pump timer, which then catches up, or a lost message), the widest {widest_ms:.0f} '
        'ms; in the bag '
        f'{len(bag_commands):,}: {len(bag_commands - span)} in the bag but not at the probe, '
        f'{len(span - bag_commands)} at the probe but not in the bag.']
    for topic in answer_topics:
        lines.append(
            f'- {topic}: commands without an answer at the probe '
            f'{len(span - probe_answers[topic])}, in the bag '
            f'{len(bag_commands - bag_answers[topic])}.')
    lines += [
        f'- Answers whose volumes differ from their command: {mismatched}. Pump holds '
        f'(no pressure feedback for 2 s, restarted by the benchmark): {run["holds"]}.',
        f'- Bag: {bag_bytes / 1e6:.0f} MB in {chunks:,} chunks (the recorder closes a chunk '
        f'at every flush, at least every 0.5 s), complete = {summary.complete}, '
        f'{summary.message_count:,} messages ('
        + ', '.join(f'{t} {s.message_count:,}' for t, s in sorted(summary.topics.items()))
        + ')' + (f'; kept at `{kept.relative_to(ROOT)}`.' if kept else '; removed.'), '']

    lines += ['**Node processes** (VmRSS and VmHWM from /proc/<pid>/status, CPU from '
              f'/proc/<pid>/stat; start = just before the pump starts, "at {window:.0f} s" the '
              'sample nearest to it; slope = least-squares line through the samples after '
              f'{window:.0f} s):', '',
              f'| process | RSS start [MB] | RSS at {window:.0f} s [MB] | RSS end [MB] | '
              f'**end / start** | end / {window:.0f} s | slope after {window:.0f} s [MB/h] | '
              'peak [MB] | CPU first / last window [% of a core] |',
              '|---|---:|---:|---:|---:|---:|---:|---:|---:|']
    for name, rows in samples.rows.items():
        if not rows:
            continue
        first, settled, last = rows[0], samples.at(name, window), rows[-1]
        later = [r for r in rows if r[0] >= window]
        slope = (np.polyfit([r[0] for r in later], [r[1] for r in later], 1)[0] * 3600 / MB
                 if len(later) >= 3 else float('nan'))
        cpu_first = samples.cpu_share(name, 0.0, window)
        cpu_last = samples.cpu_share(name, duration - window, duration)
        lines.append(
            f'| {name} | {mb(first[1])} | {mb(settled[1])} | {mb(last[1])} | '
            f'**{last[1] / first[1]:.3f}** | {last[1] / settled[1]:.3f} | {slope:+.1f} | '
            f'{mb(last[2])} | {100 * cpu_first:.0f} / {100 * cpu_last:.0f} |')
    recorder = samples.rows['recorder']
    if recorder:
        growth = recorder[-1][1] - samples.at('recorder', window)[1]
        chunks_later = chunks * (duration - window) / duration
        per_chunk = growth / max(chunks_later, 1)
        lines += ['', f'Recorder after {window:.0f} s: {growth / MB:+.1f} MB for about '
                  f'{chunks_later:,.0f} chunks written then ({per_chunk:+,.0f} bytes per '
                  'chunk).']
    names = [name for name, rows in samples.rows.items() if rows]
    lines += ['', 'Resident memory [MB] at the end of each minute (the sample nearest to it):',
              '', '| minute | ' + ' | '.join(names) + ' |',
              '|---:|' + '---:|' * len(names)]
    for minute in range(minutes):
        at = min(60.0 * (minute + 1), duration)
        lines.append(f'| {minute + 1} | '
                     + ' | '.join(mb(samples.at(name, at)[1]) for name in names) + ' |')
    machine = samples.machine
    cores = len(os.sched_getaffinity(0))
    ours = sum(rows[-1][3] - rows[0][3] for rows in samples.rows.values() if rows)
    busy = machine[-1][1] - machine[0][1]
    other = max(0.0, busy - ours) / max((machine[-1][0] - machine[0][0]) * cores, 1e-9)
    lines += ['', 'The benchmark process keeps every sample it takes (a few tuples per '
              'message), so its own growth is the measurement, not a leak.', '',
              shared_machine_note(run['load_before'], run['load_after'], other)]
    return '\n'.join(lines)


# ------------------------------------------------------------------------------ results file

def write_results(path: Path, sections: dict[str, str]) -> None:
    """Replace this run's sections in the results file and keep the others."""
    existing = path.read_text(encoding='utf-8') if path.is_file() else ''
    # What the numbers mean is written by hand between these markers and kept as it is.
    notes = re.search(r'<!-- notes -->\n.*?<!-- /notes -->\n', existing, re.S)
    kept = {}
    for part in PARTS:
        match = re.search(rf'<!-- part:{part} -->\n(.*?)<!-- /part:{part} -->', existing,
                          re.S)
        if match:
            kept[part] = match.group(1).rstrip('\n')
    for part, (command, started, minutes, text) in sections.items():
        kept[part] = (f'_Measured {started} ({minutes:.0f} min): `{command}`._\n\n{text}')
    header = [
        '# Soak benchmarks', '',
        'Generated by `python bench/bench_soak.py` (see its docstring); a part re-run alone '
        'replaces only its section; the notes between `<!-- notes -->` markers are written by '
        'hand and kept. Benchmarks, not tests: nothing is asserted.', '',
        '| machine | |', '|---|---|', *[f'| {k} | {v} |' for k, v in machine_facts().items()],
        '', *([notes.group(0)] if notes else [])]
    body = []
    for part in PARTS:
        if part in kept:
            body += [f'<!-- part:{part} -->', kept[part], f'<!-- /part:{part} -->', '']
    path.write_text('\n'.join(header + body), encoding='utf-8')


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--part', choices=(*PARTS, 'all'), default='all')
    parser.add_argument('--cycles', type=int, default=None,
                        help=f'pump cycles of the batch soak (default {BATCH_CYCLES})')
    parser.add_argument('--seconds', type=float, default=None,
                        help=f'length of the real-time soak [s] (default {REALTIME_S:g})')
    parser.add_argument('--camera-hz', type=float, default=CAMERA_HZ,
                        help=f'camera frame rate in the real-time soak (default {CAMERA_HZ})')
    parser.add_argument('--quick', action='store_true',
                        help=f'the batch part only, {QUICK_CYCLES} short cycles (with --part '
                        f'realtime: {QUICK_S:g} s); nothing written unless --out is given')
    parser.add_argument('--keep-bag', action='store_true',
                        help='keep the bags (in bags/) instead of removing them')
    parser.add_argument('--out', type=Path, default=None,
                        help=f'results file (default {RESULTS.relative_to(ROOT)})')
    parser.add_argument('--batch-child', nargs=2, metavar=('SCENE', 'OUT'),
                        help=argparse.SUPPRESS)
    options = parser.parse_args()
    if options.batch_child:
        batch_child(Path(options.batch_child[0]), Path(options.batch_child[1]))
        return
    cycles = options.cycles or (QUICK_CYCLES if options.quick else BATCH_CYCLES)
    seconds = options.seconds or (QUICK_S if options.quick else REALTIME_S)
    if cycles < 1:
        parser.error('--cycles: must be at least 1')
    if seconds < 3 * SAMPLE_PERIOD_S:
        parser.error(f'--seconds: must be at least {3 * SAMPLE_PERIOD_S:g}')
    out = options.out or (None if options.quick else RESULTS)
    command = 'python bench/bench_soak.py ' + ' '.join(sys.argv[1:])
    if options.part == 'all':
        chosen = ('batch',) if options.quick else PARTS   # --quick: no DDS unless asked for
    else:
        chosen = (options.part,)
    sections = {}
    for part in chosen:
        started = time.monotonic()
        stamp = time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())
        if part == 'batch':
            text = part_batch(cycles, options.keep_bag, options.quick)
        else:
            text = part_realtime(seconds, options.camera_hz, options.keep_bag)
        elapsed = time.monotonic() - started
        print(f'\n{text}\n\n({part}: {elapsed:.0f} s)\n', flush=True)
        sections[part] = (command.strip(), stamp, elapsed / 60.0, text)
        if out is not None:
            write_results(out, sections)
    if out is not None:
        print(f'written {out}')


if __name__ == '__main__':
    main()
