"""
Rig benchmarks: batch speed, hand-started processes on sim time, real-time latency.

    python bench/bench_rig.py [--part batch|processes|latency|baseline|former|all]
                              [--repeats N] [--baseline-ref REF] [--former-ref REF]
                              [--out bench/rig_results.md] [--quick]

Benchmarks, not tests: nothing is asserted about time. Each part prints a markdown section and
replaces its own section of the results file (the other parts' sections stay), so one part can
be re-run alone. Every ratio is measured within one run of this script; times are the best of
``--repeats`` where a run is repeated. The machine facts (cores, load average before and after
each part, Python, rclpy) go into the file: on a shared machine the wall times move with the
load, the CPU times (this process only) much less.

Parts:
  batch      softseq_ros.run on the paper scene (0 -> 65 -> 0 mL, pump 50 Hz, camera
             10 Hz, everything recorded); where the time goes (exclusive timers around each
             stage of the run, through the run's public ``wrap`` hook: the stages of a block
             of instants, and those of one message at a time with ``by_blocks=False``; and
             cProfile's top functions); the saving from skipping work (reduced outputs, a 1 Hz
             camera, a pump hold answered from the actuator's cache).
  processes  the console-script nodes as processes on sim time (sim_clock at several speed-ups,
             recorder writing a bag): the highest speed-up at which no message is lost.
  latency    real time, pump and camera at 100 Hz, nodes as processes, a probe node in this
             process: latency from a pump command to its /actuator/volumes and to the first
             /camera/backbone frame that shows it.
  baseline   before and after: the batch run of the paper scene and the rig's latency of the
             code at --baseline-ref (checked out into a temporary git worktree) against this
             checkout, alternated A B A B in this one run; and what a line logged through
             rclpy's public logger costs.
  former     the batch run of the paper scene (as ``softseq run paper --no-report`` runs it:
             ``softseq_ros.run`` in a fresh interpreter) of the code at --former-ref (the
             code before the batch ran by blocks, checked out into a temporary git worktree)
             against this checkout, alternated A B A B, 5 pairs: medians and pair ratios of
             the run's wall time (its real-time factor) and of the whole process.

``--quick``: the batch part only (no DDS, no processes), every run on a 100 s programme and
once, the actuator alone on 1000 commands; a few seconds. Printed, not written into the results
file unless ``--out`` is given. The test suite runs it (test/test_bench_quick.py), so a
benchmark that no longer runs fails a test.
"""

import argparse
import atexit
from collections import defaultdict
from contextlib import contextmanager
import cProfile
from dataclasses import dataclass
import json
import math
import os
from pathlib import Path
import pstats
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from types import SimpleNamespace

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

# Before the first rclpy import: DDS reads these when the first participant is created. Each
# part passes its own domain id to rclpy.init and to its children, so runs never mix.
BASE_DOMAIN_ID = 1 + os.getpid() % 80
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.pop('ROS_LOCALHOST_ONLY', None)
_prefixes = [p for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
if sys.prefix not in _prefixes:
    os.environ['AMENT_PREFIX_PATH'] = os.pathsep.join([sys.prefix, *_prefixes])

from machine import latency_row, load_text, machine_facts  # noqa: E402
import numpy as np  # noqa: E402
import rclpy  # noqa: E402
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

import softseq_ros  # noqa: E402
from softseq_ros.bag.reader import read_bag  # noqa: E402
from softseq_ros.batch import BLOCK_STAGES, STAGES, STEP_STAGES  # noqa: E402
from softseq_ros.nodes.core_node import message_class, qos_profile  # noqa: E402
from softseq_ros.rig.build import actuator_core  # noqa: E402
from softseq_ros.scene.loader import load_scene  # noqa: E402
from softseq_ros.scene.programme import Leg, PumpProfile  # noqa: E402
from softseq_ros.segments.kinematics import backbone_batch  # noqa: E402
from softseq_ros.wire import contract  # noqa: E402
from softseq_ros.wire.values import PumpCommand  # noqa: E402

RESULTS = ROOT / 'bench' / 'rig_results.md'
PARTS = ('batch', 'processes', 'latency', 'baseline', 'former')
# The last commit whose batch runner stepped rclpy nodes (before the ROS-free cores).
BASELINE_REF = '7a1bb18'
# The code before the batch runner ran its plain instants by blocks.
FORMER_REF = 'c888a0c'
FORMER_PAIRS = 5
ML = 1.0e-6

# A shortened paper programme (same scene, flow and rates): 0 -> 10 mL -> 0, 400 s of sim time.
SHORT_LEGS = (Leg.inflate(1.0e-5), Leg.deflate(0.0))
SHORT_LEGS_YAML = '[{inflate_to_m3: 1.0e-5}, {deflate_to_m3: 0.0}]'
# Same 400 s and command count, but half of it a hold: 0 -> 5 mL, hold 200 s, -> 0.
HOLD_LEGS = (Leg.inflate(5.0e-6), Leg.hold(200.0), Leg.deflate(0.0))
# For cProfile (about 4x slower under the profiler): 0 -> 2.5 mL -> 0, 100 s.
# Under cProfile: the scene's own programme (None); by blocks a short one is mostly the bag's
# closing.
PROFILE_LEGS = None
# --quick: the batch part only, every run 0 -> 2.5 -> 0 mL (100 s sim; cProfile 40 s).
QUICK_LEGS = (Leg.inflate(2.5e-6), Leg.deflate(0.0))
QUICK_HOLD_LEGS = (Leg.inflate(1.25e-6), Leg.hold(50.0), Leg.deflate(0.0))
QUICK_PROFILE_LEGS = (Leg.inflate(1.0e-6), Leg.deflate(0.0))

SPEEDUPS = (10, 30, 100, 300, 1000)
RECORDED_TOPICS = tuple(contract.resolve(topic.name) for topic in contract.RIG_TOPICS
                        if topic is not contract.IMAGE)
STARTUP_TIMEOUT_S = 90.0
LATENCY_RUN_S = 20.0
LATENCY_WARMUP_S = 1.0
QUIET_S = 2.0
# Commands and their answers agree to round-off; consecutive commands are >= 1e-10 m^3 apart.
MATCH_TOLERANCE_M3 = 1.0e-12


# ------------------------------------------------------------------------------ machine facts

def under_load_note(before: str, after: str) -> str:
    peak = max(float(before.split('/')[0]), float(after.split('/')[0]))
    cores = len(os.sched_getaffinity(0))
    text = f'Load average (1/5/15 min) before: {before}; after: {after} ({cores} cores).'
    if peak > 0.5 * cores:
        text += (' **Measured under load from other work on this machine**: wall times and '
                 'latencies are worse than on an idle machine; the CPU times of this process '
                 'move much less.')
    return text


# ------------------------------------------------------------------------------ part 1: batch

@dataclass(frozen=True)
class BatchSizes:
    """The programmes and counts of the batch part: the measurement, or a quick check of it."""

    full_legs: tuple[Leg, ...] | None   # the headline run; None: the scene's own programme
    short_legs: tuple[Leg, ...]         # where the time goes, and the skipping-work variants
    hold_legs: tuple[Leg, ...]          # as long as short_legs, as many commands, half a hold
    profile_legs: tuple[Leg, ...] | None  # under cProfile; None: the scene's own programme
    micro_commands: int                 # the actuator alone


FULL = BatchSizes(None, SHORT_LEGS, HOLD_LEGS, PROFILE_LEGS, 5000)
QUICK = BatchSizes(QUICK_LEGS, QUICK_LEGS, QUICK_HOLD_LEGS, QUICK_PROFILE_LEGS, 1000)

# What each stage of STAGES is, for the table (a stage not named here shows its label).
STAGE_NAMES = {
    'pump.tick': 'pump: tick (programme, state)',
    'pump.handle': 'pump: pressure check (volumes feedback)',
    'actuator.tick': 'actuator: model advance between commands',
    'actuator.handle': 'actuator: command handling (no solve)',
    'actuator.model.command': 'actuator: equilibrium solve (QuasiStaticModel.command)',
    'camera.tick': 'camera: frame (backbone kinematics, poses, markers)',
    'camera.handle': 'camera: input handlers (snapshots, with their backbone kinematics)',
    'encode': 'serialisation (CDR encode)',
    'append': 'bag writing (MCAP, zstd chunks)',
    'block.pump': 'pump: plain ticks of a block (programme, limits)',
    'block.actuator': 'actuator: states of a block of commands (walk, branch cubics)',
    'block.camera': 'camera: states taken, frames (backbone kinematics)',
    'block.encode': 'serialisation of a block (CDR rows per topic)',
    'block.append': 'bag writing of a block (MCAP rows, chunks, zstd)',
}


class StageTimer:
    """
    A ``wrap`` hook for a batch run: the exclusive time of every stage and its calls.

    Exclusive: each wrapped call's time minus the time of the wrapped calls inside it (the
    actuator's command handling does not count the equilibrium solve it asks for).
    """

    def __init__(self, labels: tuple[str, ...] = STAGES) -> None:
        """Time the stages ``labels`` (those of a block alone leave the run by blocks)."""
        self.labels = labels
        self.exclusive: dict[str, float] = defaultdict(float)
        self.calls: dict[str, int] = defaultdict(int)
        self.stack: list[float] = []

    def __call__(self, label: str, function):
        if label not in self.labels:
            return function
        stack, exclusive, calls, clock = self.stack, self.exclusive, self.calls, \
            time.perf_counter

        def timed(*args):
            stack.append(0.0)
            start = clock()
            try:
                return function(*args)
            finally:
                elapsed = clock() - start
                inner = stack.pop()
                exclusive[label] += elapsed - inner
                calls[label] += 1
                if stack:
                    stack[-1] += elapsed
        return timed


def describe_legs(legs: tuple[Leg, ...]) -> str:
    """A programme from 0 mL as text: '0 -> 10 -> 0 mL', '0 -> 5 -> (hold 200 s) -> 0 mL'."""
    steps = [f'(hold {leg.duration_s:g} s)' if leg.action == 'hold' else f'{leg.to_m3 / ML:g}'
             for leg in legs]
    return ' -> '.join(['0', *steps]) + ' mL'


def _batch_overrides(legs=None, camera_rate=None, outputs=None):
    overrides = defaultdict(dict)
    if legs is not None:
        overrides['pump']['legs'] = legs
    if camera_rate is not None:
        overrides['camera']['rate_hz'] = float(camera_rate)
    if outputs is not None:
        for role in ('actuator', 'camera'):
            overrides[role]['outputs'] = frozenset(outputs)
    return dict(overrides)


def _seeing(cores: dict, started: list, wrap=None):
    """A ``wrap`` hook that keeps each core by role and the CPU time the run started at."""
    def seen(stage: str, function):
        # Called once per stage after the cores are built and before the run starts.
        if not started:
            started.append(time.process_time())
        if stage.endswith('.tick'):
            cores[stage.split('.')[0]] = function.__self__
        return function if wrap is None else wrap(stage, function)
    return seen


def run_batch(workdir: Path, label: str, repeats: int, wrap=None, by_blocks=True, **options):
    """
    Best of ``repeats`` (by wall time) of one batch configuration: (run, result, CPU [s]).

    The CPU time is this process's from the run's cores being built to its end (all its
    threads). ``wrap`` goes to every repeat (the run's public hook); a timer there adds up over
    the repeats. ``run`` holds the run's cores by role, seen through the same hook.
    """
    best = None
    for index in range(repeats):
        out = workdir / f'{re.sub(r"[^a-z0-9]+", "_", label.lower())}_{index}'
        cores, started = {}, []
        seen = _seeing(cores, started, wrap)
        result = softseq_ros.run('paper', out, overrides=_batch_overrides(**options), wrap=seen,
                                 by_blocks=by_blocks)
        cpu = time.process_time() - started[0]
        if best is None or result.wall_s < best[1].wall_s:
            best = (SimpleNamespace(**cores), result, cpu)
        shutil.rmtree(out, ignore_errors=True)
    return best


def _messages(result) -> int:
    return sum(result.message_counts.values())


def actuator_micro(repeats: int, count: int = 5000) -> dict[str, float]:
    """Microseconds per command: a moving volume (solve) against a repeated one (cache)."""
    core = actuator_core(load_scene('paper'))
    model = core.model
    volumes = np.linspace(0.0, 10.0 * ML, count).tolist()

    def feed(values) -> float:
        commands = [PumpCommand(0, value, 0.0) for value in values]
        start = time.perf_counter()
        for command in commands:
            core.handle(command, 0)
        return (time.perf_counter() - start) / len(values) * 1e6

    moving = held = math.inf
    for _ in range(repeats):
        # Back to rest, so every repeat walks the same path.
        model.resume(0.0, [s.rest_volume for s in model.segments])
        solves = model.solves
        moving = min(moving, feed(volumes))
        moving_solves = model.solves - solves
        solves = model.solves
        held = min(held, feed([volumes[-1]] * count))
        held_solves = model.solves - solves
    return {'moving_us': moving, 'held_us': held, 'moving_solves': moving_solves,
            'held_solves': held_solves, 'count': count}


def cprofile_top(workdir: Path, legs: tuple[Leg, ...] | None = PROFILE_LEGS,
                 rows: int = 14) -> str:
    out = workdir / 'profiled'
    profile = cProfile.Profile()

    def profiled(stage: str, function):
        # The first stage handed over: the cores are built, the run is about to start.
        if stage == STAGES[0]:
            profile.enable()
        return function

    softseq_ros.run('paper', out, overrides=_batch_overrides(legs=legs), wrap=profiled)
    profile.disable()
    shutil.rmtree(out, ignore_errors=True)
    stats = pstats.Stats(profile)
    total = stats.total_tt
    entries = sorted(stats.stats.items(), key=lambda item: item[1][2], reverse=True)[:rows]
    lines = ['| function | calls | own time [s] | share of profiled time |',
             '|---|---:|---:|---:|']
    for (file_name, line, function), (_, calls, own, _cumulative, _) in entries:
        where = file_name
        for marker in ('site-packages/', 'softseq_ros/'):
            if marker in file_name:
                where = file_name.split(marker, 1)[1]
                where = ('softseq_ros/' + where) if marker == 'softseq_ros/' else where
        name = f'`{where}:{line}({function})`' if line else f'`{function}`'
        lines.append(f'| {name} | {calls} | {own:.2f} | {100.0 * own / total:.1f} % |')
    return '\n'.join(lines) + f'\n\nProfiled total: {total:.1f} s (cProfile slows most what ' \
        'makes many Python calls: the instants run one at a time more than the blocks).'


def stage_table(title: str, timer: StageTimer, result, stages: tuple[str, ...]) -> list[str]:
    """The timer's stages by own time, as a table, and the stages never called."""
    total = result.wall_s
    called = [label for label in timer.exclusive if timer.calls[label]]
    rows = sorted(called, key=lambda label: -timer.exclusive[label])
    accounted = sum(timer.exclusive.values())
    lines = [f'**{title}**: run wall {total:.2f} s ({result.speedup:.0f}x).', '',
             '| component (stage) | calls | own time [s] | share | per call [us] |',
             '|---|---:|---:|---:|---:|']
    for label in rows:
        seconds, calls = timer.exclusive[label], timer.calls[label]
        lines.append(f'| {STAGE_NAMES.get(label, label)} (`{label}`) | {calls} | '
                     f'{seconds:.2f} | {100 * seconds / total:.0f} % | '
                     f'{1e6 * seconds / max(calls, 1):.1f} |')
    rest = total - accounted
    lines += [f'| runner: routing, queue, loop, setup (the rest) | | {rest:.2f} | '
              f'{100 * rest / total:.0f} % | |', '']
    idle = [label for label in stages if not timer.calls.get(label)]
    if idle:
        lines += ['Stages never called in this run: '
                  + ', '.join(f'`{label}`' for label in idle)
                  + (' (the quasi-static model changes only on commands: it has no rate, '
                     'so the runner never ticks the actuator)'
                     if 'actuator.tick' in idle else '') + '.', '']
    return lines


def part_batch(repeats: int, sizes: BatchSizes = FULL) -> str:
    load_before = load_text()
    scene = load_scene('paper')
    short = describe_legs(sizes.short_legs)
    lines = ['## 1. Batch run (`softseq_ros.run`, one process, no DDS)', '']
    if sizes is not FULL:
        lines += ['**Quick check** (`--quick`): short programmes, too short for the numbers '
                  'to mean much; they show that the benchmark runs.', '']
    with tempfile.TemporaryDirectory(prefix='bench_rig_') as tmp:
        workdir = Path(tmp)
        if sizes.full_legs is None:
            print('batch: full paper scene, everything recorded ...', flush=True)
            programme = '0 -> 65 -> 0 mL at 0.05 mL/s'
        else:
            print(f'batch: paper scene, {describe_legs(sizes.full_legs)}, everything recorded '
                  '...', flush=True)
            programme = f'programme shortened to {describe_legs(sizes.full_legs)} at 0.05 mL/s'
        run, full, full_cpu = run_batch(workdir, 'full', repeats, legs=sizes.full_legs)
        cpu_speedup = full.sim_duration_s / full_cpu
        lines += [
            f'Paper scene `config/paper.yaml`: {programme} '
            f'({full.sim_duration_s:.0f} s sim), pump {scene.pump.rate_hz:g} Hz, camera '
            f'{scene.camera.rate_hz:g} Hz, outputs {", ".join(scene.outputs)}; every message '
            'serialised and written to an MCAP bag (zstd chunks, compressed on a worker thread). '
            f'Best of {repeats} runs by wall time: on this shared machine the same run varies '
            'by up to a third from minute to minute.',
            '',
            '| wall [s] | CPU of this process [s] | speed-up (sim / wall) | speed-up (sim / CPU) '
            '| messages | messages / wall s |',
            '|---:|---:|---:|---:|---:|---:|',
            f'| {full.wall_s:.1f} | {full_cpu:.1f} | **{full.speedup:.0f}x** | '
            f'{cpu_speedup:.0f}x | {_messages(full)} | {_messages(full) / full.wall_s:,.0f} |',
            '',
            'Messages: ' + ', '.join(f'{t} {n}' for t, n in sorted(full.message_counts.items()))
            + '.', '',
            'Target in the issue: past 1000x with every output (at first 300x). CPU-bound: the '
            'cores run on one core (one process, lock-step), most instants by blocks of '
            'up to 4096 pump ticks; the second core compresses the finished chunks and keeps '
            'other work off the first.', '']

        print('batch: where the time goes ...', flush=True)
        lines += [
            '### Where the time goes', '',
            f'Shortened programme {short} (same scene and rates). The stages of the run '
            "(`STAGES`) are wrapped, through the run's public `wrap` hook, in a timer that "
            'counts its own time without the wrapped calls inside it. Twice: by blocks (the '
            'default: only the block stages `BLOCK_STAGES` are wrapped, which leaves the run '
            'by blocks), and one message at a time (`by_blocks=False`, every per-message '
            "stage wrapped: the actuator's command handling does not count the equilibrium "
            'solve it asks for; the serialisation and bag write of what a core produces are '
            "stages of their own; the backbone kinematics are in the camera's frame "
            '(`camera.tick`) and snapshots (`camera.handle`)). The instants that are not plain '
            '(start, snapshots, the end) go one message at a time in a run by blocks too; '
            'their stages are not timed there. The timers themselves add a few %.', '']
        for title, labels, by_blocks in (('By blocks', BLOCK_STAGES, True),
                                         ('One message at a time', STAGES, False)):
            timer = StageTimer(labels)
            _, result, _ = run_batch(workdir, f'instrumented {by_blocks}', 1, wrap=timer,
                                     legs=sizes.short_legs, by_blocks=by_blocks)
            lines += stage_table(title, timer, result,
                                 BLOCK_STAGES if by_blocks else STEP_STAGES)

        print('batch: cProfile ...', flush=True)
        profiled = ('the paper programme (0 -> 65 -> 0 mL)' if sizes.profile_legs is None
                    else f'a {describe_legs(sizes.profile_legs)} programme')
        lines += [f'cProfile of a run of {profiled}, by blocks, functions by own time:', '',
                  cprofile_top(workdir, sizes.profile_legs), '']

        print('batch: skipping work ...', flush=True)
        hold_s = PumpProfile(sizes.hold_legs, scene.pump.profile.flow_rate).duration()
        variants = [
            ('everything recorded (scene outputs)', {}),
            ('outputs [pressure, volumes] only (no curvature, poses, markers, events)',
             {'outputs': ['pressure', 'volumes']}),
            ('camera at 1 Hz (instead of 10 Hz)', {'camera_rate': 1.0}),
            (f'pump hold: {describe_legs(sizes.hold_legs)} (same {hold_s:.0f} s, same command '
             'count)', {'legs': sizes.hold_legs}),
        ]
        lines += [
            '### Skipping what a scene does not need', '',
            f'Shortened programme {short} unless said otherwise, best of {repeats} '
            'runs each (by wall time).', '',
            '| variant | wall [s] | CPU [s] | speed-up | CPU vs everything | messages | '
            'actuator solves / commands |', '|---|---:|---:|---:|---:|---:|---:|']
        reference_cpu = None
        for label, options in variants:
            print(f'  {label}', flush=True)
            options.setdefault('legs', sizes.short_legs)
            run, result, cpu = run_batch(workdir, label, repeats, **options)
            actuator = run.actuator
            reference_cpu = reference_cpu or cpu
            commands = result.message_counts.get('/pump/command', 0)
            lines.append(
                f'| {label} | {result.wall_s:.2f} | {cpu:.2f} | {result.speedup:.0f}x | '
                f'{100 * cpu / reference_cpu:.0f} % | {_messages(result)} | '
                f'{actuator.model.solves} / {commands} (rejected '
                f'{actuator.rejected_commands}) |')
        micro = actuator_micro(repeats, sizes.micro_commands)
        lines += [
            '', f'Actuator alone (batch mode, emit discarded), {micro["count"]} commands, best '
            f'of {repeats}: a moving volume costs {micro["moving_us"]:.1f} us per command '
            f'({micro["moving_solves"]} solves); the same volume repeated (a hold) '
            f'{micro["held_us"]:.1f} us ({micro["held_solves"]} solves: the cached messages '
            'go out with the new stamp).', '']
    lines.append(under_load_note(load_before, load_text()))
    return '\n'.join(lines)


# ------------------------------------------------------------------------------ ROS plumbing

_ROS_HOME = tempfile.mkdtemp(prefix='softseq_bench_ros_home_')
atexit.register(shutil.rmtree, _ROS_HOME, True)


def child_environment(domain_id: int) -> dict[str, str]:
    """
    The whole environment (the ROS wheels need it) with this run's domain.

    The ROS home is a fresh folder: an actuator never resumes from a state file that an
    earlier run, or the user's rig, left behind.
    """
    env = dict(os.environ)
    env['ROS_DOMAIN_ID'] = str(domain_id)
    env['ROS_HOME'] = _ROS_HOME
    env['PYTHONUNBUFFERED'] = '1'
    return env


@contextmanager
def node_processes(env: dict[str, str], log_dir: Path, code_root: Path | None = None):
    """
    start(name, script, **params) starts a console script; all are stopped at the end.

    With ``code_root``, the node's module runs from that source tree instead (a baseline).
    """
    started: dict[str, subprocess.Popen] = {}
    if code_root is not None:
        env = dict(env, PYTHONPATH=str(code_root))

    def start(name: str, script: str, **params) -> subprocess.Popen:
        if code_root is None:
            args = [os.path.join(sys.prefix, 'bin', script), '--ros-args']
        else:
            module = 'syringe_pump' if script == 'syringe_pump' else script
            args = [sys.executable, '-m', f'softseq_ros.nodes.{module}', '--ros-args']
        for key, value in params.items():
            args += ['-p', f'{key}:={value}']
        with open(log_dir / f'{name}.log', 'ab') as log:
            started[name] = subprocess.Popen(args, env=env, stdout=log, cwd=code_root,
                                             stderr=subprocess.STDOUT)
        return started[name]

    start.processes = started
    try:
        yield start
    finally:
        for process in started.values():
            if process.poll() is None:
                process.send_signal(signal.SIGINT)
        for process in started.values():
            try:
                process.wait(timeout=15)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()


def stop_process(process: subprocess.Popen, timeout: float = 20.0) -> None:
    if process.poll() is None:
        process.send_signal(signal.SIGINT)
    try:
        process.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()


@contextmanager
def spinning(context, node):
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)

    def spin() -> None:
        try:
            executor.spin()
        except ExternalShutdownException:
            pass

    thread = threading.Thread(target=spin, daemon=True)
    thread.start()
    try:
        yield executor
    finally:
        executor.shutdown(timeout_sec=10.0)
        thread.join(timeout=10.0)
        node.destroy_node()


@contextmanager
def ros_context(domain_id: int):
    context = rclpy.Context()
    rclpy.init(context=context, args=[], domain_id=domain_id)
    try:
        yield context
    finally:
        rclpy.try_shutdown(context=context)


def wait_for(condition, what: str, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise TimeoutError(f'timed out after {timeout:.0f} s waiting for {what}')
        time.sleep(0.02)


def call_start(node: Node) -> None:
    client = node.create_client(Trigger, '/syringe_pump/start')
    wait_for(client.service_is_ready, 'the pump service /syringe_pump/start', 30.0)
    future = client.call_async(Trigger.Request())
    wait_for(future.done, 'the answer of /syringe_pump/start', 30.0)
    if not future.result().success:
        raise RuntimeError(f'/syringe_pump/start refused: {future.result().message}')


def rest_volume(scene_name: str) -> float:
    return float(sum(segment.rest_volume for segment in load_scene(scene_name).segments))


def volume_key(injected_m3: float) -> int:
    # Commands 5e-10 m^3 apart (0.05 mL/s at 100 Hz) stay apart.
    return round(injected_m3 / MATCH_TOLERANCE_M3)


def match_volumes(asked: list[float], answered: list[float]) -> tuple[int, int, float]:
    """Pair volumes within the tolerance: unpaired asked, unpaired answered, worst gap."""
    asked, answered = sorted(asked), sorted(answered)
    i = j = unanswered = unasked = 0
    worst = 0.0
    while i < len(asked) and j < len(answered):
        gap = answered[j] - asked[i]
        if abs(gap) <= MATCH_TOLERANCE_M3:
            worst = max(worst, abs(gap))
            i += 1
            j += 1
        elif gap > 0.0:
            unanswered += 1
            i += 1
        else:
            unasked += 1
            j += 1
    return unanswered + len(asked) - i, unasked + len(answered) - j, worst


def _stamp(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


# ------------------------------------------------------------------------------ part 2: processes

class Monitor(Node):
    """Watches the pump status and sees the first command (the pump has the clock)."""

    def __init__(self, context) -> None:
        super().__init__('bench_monitor', context=context)
        self.statuses: list[str] = []
        self.create_subscription(
            message_class(contract.PUMP_STATUS.type_name), contract.PUMP_STATUS.name,
            lambda msg: self.statuses.append(json.loads(msg.data)['state']),
            qos_profile(contract.PUMP_STATUS.qos))
        self.commands_seen = 0
        self._command_subscription = self.create_subscription(
            message_class(contract.PUMP_COMMAND.type_name), contract.PUMP_COMMAND.name,
            self._on_command, qos_profile(contract.PUMP_COMMAND.qos))

    def _on_command(self, _msg) -> None:
        self.commands_seen += 1

    def stop_watching_commands(self) -> None:
        # One reader less for the pump while the benchmark runs.
        self.destroy_subscription(self._command_subscription)

    def watch_answers(self) -> None:
        self.last_answer = time.monotonic()
        qos = qos_profile(contract.VOLUMES.qos)
        qos.depth = 1000
        self.create_subscription(message_class(contract.VOLUMES.type_name),
                                 contract.VOLUMES.name, self._on_answer, qos)

    def _on_answer(self, _msg) -> None:
        self.last_answer = time.monotonic()

    def recorder_on(self, topic: str) -> bool:
        return any(info.node_name == 'recorder'
                   for info in self.get_subscriptions_info_by_topic(topic))


def run_sim_level(speedup: float, domain_id: int, workdir: Path) -> dict:
    """One speed-up: start the nodes, run the short programme, read the bag back."""
    env = child_environment(domain_id)
    bag = workdir / f'bag_{speedup:g}x'
    sim_params = {'scene': 'paper', 'use_sim_time': 'true'}
    topics = '[' + ', '.join(f"'{t}'" for t in RECORDED_TOPICS) + ']'
    outcome: dict = {'speedup': speedup}
    with ros_context(domain_id) as context, node_processes(env, workdir) as start:
        monitor = Monitor(context)
        with spinning(context, monitor):
            # The recorder stays on wall time: its discovery timer runs on the node clock, so
            # with use_sim_time it would find no topic before /clock runs, and the clock starts
            # only once everything is recorded (log times in the bag are wall times here).
            recorder = start('recorder', 'recorder', output=str(bag), topics=topics)
            start('actuator', 'actuator', resume_timeout_s=0.0, **sim_params)
            start('camera', 'camera', **sim_params)
            start('pump', 'syringe_pump', legs=f'"{SHORT_LEGS_YAML}"', autostart='false',
                  **sim_params)
            wait_for(lambda: all(monitor.recorder_on(t) for t in RECORDED_TOPICS),
                     'the recorder on every topic', STARTUP_TIMEOUT_S)
            wait_for(lambda: monitor.count_subscribers('/pump/command') >= 3
                     and monitor.count_subscribers('/actuator/curvatures') >= 2,
                     'the actuator and camera subscriptions', STARTUP_TIMEOUT_S)
            # Time starts only now, so every command goes to a ready recorder.
            clock = start('sim_clock', 'sim_clock', speedup=float(speedup))
            wait_for(lambda: monitor.commands_seen > 0, 'the first command on sim time',
                     STARTUP_TIMEOUT_S)
            monitor.stop_watching_commands()
            wall_start = time.monotonic()
            call_start(monitor)
            expected_wall = 400.0 / speedup
            wait_for(lambda: any(s == 'finished' or s.startswith('stopped')
                                 for s in monitor.statuses),
                     'the programme to finish', 3.0 * expected_wall + 60.0)
            outcome['wall_s'] = time.monotonic() - wall_start
            outcome['final_status'] = monitor.statuses[-1]
            # Stop time first: no new command; then wait until the actuator has answered its
            # backlog (no /actuator/volumes for QUIET_S) and give the recorder as long again.
            stop_process(clock)
            monitor.watch_answers()
            wait_for(lambda: time.monotonic() - monitor.last_answer > QUIET_S,
                     'the actuator to go quiet', 120.0)
            time.sleep(QUIET_S)
            stop_process(recorder, timeout=60.0)
            outcome['load'] = load_text()
    # A command and its answer are paired by content, independent of stamps: the injected
    # volume the command asks for equals the segments' volumes minus their rest volumes.
    rest = rest_volume('paper')
    counts: dict[str, int] = defaultdict(int)
    asked: list[float] = []
    answered: list[float] = []
    command_stamps = []
    for item in read_bag(bag):
        counts[item.topic] += 1
        if item.topic == '/pump/command':
            asked.append(float(item.msg.position[0]))
            command_stamps.append(_stamp(item.msg))
        elif item.topic == '/actuator/volumes':
            answered.append(float(sum(item.msg.position)) - rest)
    unanswered, unasked, worst = match_volumes(asked, answered)
    outcome.update(counts=dict(counts), unanswered=unanswered, unasked=unasked,
                   worst_match_m3=worst,
                   lossless=(counts['/pump/command'] == counts['/actuator/volumes']
                             == counts['/actuator/pressure'] == counts['/actuator/curvatures']
                             and unanswered == 0 and unasked == 0),
                   sim_span_s=((max(command_stamps) - min(command_stamps)) * 1e-9
                               if command_stamps else 0.0))
    shutil.rmtree(bag, ignore_errors=True)
    return outcome


def part_processes(repeats: int) -> str:
    del repeats  # one run per speed-up: a loss at any run is a loss
    load_before = load_text()
    lines = ['## 2. Hand-started processes on sim time', '',
             'Console scripts started as a user starts them (`--ros-args -p ...`, '
             '`use_sim_time:=true`), one process each: `syringe_pump` (paper scene, 50 Hz, '
             'programme shortened with `legs` to 0 -> 10 -> 0 mL = 400 s sim), `actuator`, '
             '`camera` (10 Hz), `recorder` (every rig topic except /clock; on wall time, see '
             'below) and `sim_clock` '
             '(1000 ticks per wall second, the default). The recorder is subscribed to every '
             'topic before `sim_clock` starts, and `sim_clock` is stopped before the recorder '
             'when the programme ends, so every command the pump sent should be in the bag '
             'with its answers. Lossless = the bag holds as many /actuator/volumes, '
             '/actuator/pressure and /actuator/curvatures as /pump/command messages, and every '
             'command has its /actuator/volumes: paired by content, independent of stamps: the '
             'volumes minus the rest volumes equal the commanded injected volume (to 1e-12 '
             'm^3), as a multiset. After the programme the clock is stopped and the recorder '
             'is stopped '
             f'only when no /actuator/volumes came for {QUIET_S:g} s and {QUIET_S:g} s more '
             'have passed. Fresh processes and a fresh ROS domain per speed-up.', '',
             '| speed-up | wall [s] | commands | commands / sim s | volumes | pressure | '
             'curvatures | backbone | commands without volumes | lossless | load (1 min) |',
             '|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|']
    best = None
    lost = []
    with tempfile.TemporaryDirectory(prefix='bench_rig_sim_') as tmp:
        for index, speedup in enumerate(SPEEDUPS):
            print(f'processes: {speedup}x ...', flush=True)
            domain = BASE_DOMAIN_ID + 1 + index
            try:
                outcome = run_sim_level(speedup, domain, Path(tmp))
            except (TimeoutError, RuntimeError) as err:
                lines.append(f'| {speedup}x | | | | | | | | | failed: {err} | '
                             f'{load_text().split()[0]} |')
                lost.append(speedup)
                continue
            counts = outcome['counts']
            commands = counts.get('/pump/command', 0)
            per_sim_s = commands / outcome['sim_span_s'] if outcome['sim_span_s'] else 0.0
            lines.append(
                f'| {speedup}x | {outcome["wall_s"]:.1f} | {commands} | {per_sim_s:.1f} | '
                f'{counts.get("/actuator/volumes", 0)} | {counts.get("/actuator/pressure", 0)} '
                f'| {counts.get("/actuator/curvatures", 0)} | '
                f'{counts.get("/camera/backbone", 0)} | '
                f'{outcome["unanswered"]} | '
                f'{"yes" if outcome["lossless"] else "**no**"} | {outcome["load"].split()[0]} |')
            print('  ' + json.dumps({k: v for k, v in outcome.items() if k != 'load'}),
                  flush=True)
            if outcome['lossless']:
                best = speedup
            else:
                lost.append(speedup)
    lines.append('')
    if best is None:
        lines.append('No speed-up ran without loss.')
    else:
        lines.append(f'**Highest speed-up without a lost message: {best}x.**')
        below = [s for s in lost if s < best]
        if below:
            lines.append(f'(Losses at a lower speed-up too: {", ".join(map(str, below))}x.)')
    lines += ['', "Commands per sim second below the pump's 50 Hz are not losses: a timer on "
              'sim time fires at most once per /clock tick, so at speed-up S with 1000 clock '
              'ticks per wall second the pump can tick at most 1000 / S times per sim second '
              '(and less when a process falls behind: every node on sim time handles every '
              '/clock message, 1000 per wall second, in Python).', '',
              'The recorder runs without use_sim_time: its topic discovery timer is on the '
              'node clock, so on sim time it subscribes to nothing until /clock runs.', '',
              under_load_note(load_before, load_text())]
    return '\n'.join(lines)


# ------------------------------------------------------------------------------ part 3: latency

class Probe(Node):
    """Receipt wall time of every command, volumes, curvatures and backbone message."""

    def __init__(self, context) -> None:
        super().__init__('bench_probe', context=context)
        self.received: dict[str, list] = {t: [] for t in (
            '/pump/command', '/actuator/volumes', '/actuator/curvatures', '/camera/backbone')}
        for topic, store in self.received.items():
            spec = contract.TOPICS_BY_NAME[topic.lstrip('/')]
            qos = qos_profile(spec.qos)
            qos.depth = 1000
            self.create_subscription(
                message_class(spec.type_name), topic,
                lambda msg, store=store: store.append((time.time_ns(), msg)), qos)

    def matched(self) -> bool:
        return all(self.count_publishers(t) > 0 for t in self.received)


def latency_run(layout: str, domain: int, code_root: Path | None = None) -> dict:
    """
    One real-time run at 100 Hz; ``layout`` 'processes' (one process per node, camera on its
    timer) or 'rig' (the ``rig`` executable: all three nodes in one process, camera triggered
    by the actuator's state). Returns the latency samples [ms] and counts.
    """
    scene = load_scene('paper')
    lengths = np.array(scene.lengths)
    points_per_segment = scene.camera.points_per_segment
    with tempfile.TemporaryDirectory(prefix='bench_rig_latency_') as tmp, \
            ros_context(domain) as context, \
            node_processes(child_environment(domain), Path(tmp), code_root) as start:
        probe = Probe(context)
        with spinning(context, probe):
            if layout == 'rig':
                start('rig', 'rig', scene='paper', rate_hz=100, autostart='false',
                      resume_timeout_s=0.0, frame_trigger='state')
            else:
                start('actuator', 'actuator', scene='paper', resume_timeout_s=0.0)
                start('camera', 'camera', scene='paper', rate_hz=100)
                start('pump', 'syringe_pump', scene='paper', rate_hz=100, autostart='false')
            wait_for(probe.matched, 'the nodes', STARTUP_TIMEOUT_S)
            if layout != 'rig':  # inside the rig the nodes hand messages over directly
                wait_for(lambda: probe.count_subscribers('/pump/command') >= 1
                         and probe.count_subscribers('/actuator/curvatures') >= 2,
                         'the actuator and camera subscriptions', STARTUP_TIMEOUT_S)
            call_start(probe)
            started_ns = time.time_ns()
            time.sleep(LATENCY_RUN_S)
            load_during = load_text()
        received = {topic: list(items) for topic, items in probe.received.items()}

    warm = started_ns + int(LATENCY_WARMUP_S * 1e9)
    rest = rest_volume('paper')
    # Paired by content, so the result does not rest on how the actuator stamps its outputs:
    # volumes -> command by the injected volume (distinct at every tick while the pump
    # inflates), curvatures -> volumes by their common stamp (one command's outputs share it),
    # frame -> curvatures by the backbone's tip point.
    command_stamp_of: dict[int, int] = {}
    for _, msg in received['/pump/command']:
        if _stamp(msg) >= warm:
            command_stamp_of.setdefault(volume_key(msg.position[0]), _stamp(msg))
    total_ms = []
    hop_ms = [(t - _stamp(m)) * 1e-6 for t, m in received['/pump/command'] if _stamp(m) >= warm]
    command_of_actuator_stamp: dict[int, int] = {}
    for received_ns, msg in received['/actuator/volumes']:
        command = command_stamp_of.get(volume_key(sum(msg.position) - rest))
        if command is None:
            continue
        answered = _stamp(msg)
        command_of_actuator_stamp.setdefault(answered, command)
        total_ms.append((received_ns - command) * 1e-6)
    curvatures = [(_stamp(m), list(m.position)) for _, m in received['/actuator/curvatures']
                  if _stamp(m) in command_of_actuator_stamp]
    # The camera draws the latest curvatures with the same kinematics, so a frame's tip point
    # equals the tip computed here from the curvatures it shows, bit for bit.
    tips: dict[tuple[float, float], int] = {}
    if curvatures:
        points, _ = backbone_batch(np.array([c for _, c in curvatures]), lengths,
                                   points_per_segment)
        for (stamp, _), tip in zip(curvatures, points[:, -1, :].tolist()):
            tips.setdefault((tip[0], tip[1]), command_of_actuator_stamp[stamp])
    shown: dict[int, tuple[int, int]] = {}
    unmatched = frames = 0
    for received_ns, msg in received['/camera/backbone']:
        frame_stamp = _stamp(msg)
        if frame_stamp < warm:
            continue
        frames += 1
        tip = msg.poses[-1].position
        command = tips.get((tip.x, tip.z))
        if command is None:
            unmatched += 1
        elif command not in shown:
            shown[command] = (received_ns, frame_stamp)
    return {
        'total': total_ms, 'hop': hop_ms,
        'pose': [(r - c) * 1e-6 for c, (r, _) in shown.items()],
        'taken': [(f - c) * 1e-6 for c, (_, f) in shown.items()],
        'delivery': [(r - f) * 1e-6 for _, (r, f) in shown.items()],
        'commands': len(command_stamp_of), 'frames': frames, 'shown': len(shown),
        'unmatched': unmatched, 'load': load_during}


def part_latency(repeats: int) -> str:
    del repeats
    load_before = load_text()
    base = BASE_DOMAIN_ID + 1 + len(SPEEDUPS)
    runs = {}
    for offset, layout in enumerate(('rig', 'processes')):
        print(f'latency ({layout}): {LATENCY_RUN_S:.0f} s at 100 Hz in real time ...',
              flush=True)
        runs[layout] = latency_run(layout, base + offset)
    rig, processes = runs['rig'], runs['processes']
    lines = [
        '## 3. Real-time latency (pump and camera at 100 Hz)', '',
        'Paper scene in real time, pump at 100 Hz, in two layouts:', '',
        '- **rig**: `rig --ros-args -p rate_hz:=100 -p frame_trigger:=state` (pump, actuator '
        'and camera in one process on one executor; messages between them go straight to '
        'the consumer, every topic is also published over DDS; the camera takes a frame as '
        'soon as new curvatures arrive, at most about 100 per second).',
        '- **processes**: `syringe_pump` (`rate_hz:=100`), `actuator` and `camera` '
        '(`rate_hz:=100`, free-running frame timer) as three processes.', '',
        f'A probe node in the benchmark process (SingleThreadedExecutor in a thread) '
        f'subscribes to /pump/command, /actuator/volumes, /actuator/curvatures and '
        f'/camera/backbone and notes the wall clock (`time.time_ns()`) when each callback '
        f'runs. {LATENCY_RUN_S:.0f} s per run, the first {LATENCY_WARMUP_S:.0f} s dropped. '
        "A command's time is its header stamp: the pump's ROS clock (system time) read in its "
        "tick just before publishing. A frame's stamp is the camera's clock when it takes the "
        'frame. Answers are paired with commands by content, independent of stamps: the '
        "volumes' sum minus the rest volumes is the commanded injected volume, and a frame "
        'shows the command whose curvatures give the same tip point (same kinematics, exact '
        'match); commands superseded before any frame are not counted.', '',
        '| latency [ms] | layout | median | p90 | p99 | max | samples |',
        '|---|---|---:|---:|---:|---:|---:|']
    rows = [
        ('**command -> pose taken** (frame stamp - command stamp)', 'taken'),
        ('command -> pose received by the probe (one more process hop)', 'pose'),
        ('of which: frame delivery to the probe (receipt - frame stamp)', 'delivery'),
        ('command -> /actuator/volumes received by the probe', 'total'),
        ('for scale: command -> /pump/command received by the probe (one hop)', 'hop')]
    for label, key in rows:
        for layout, run in (('rig', rig), ('processes', processes)):
            lines.append(f'| {label} | {layout} | {latency_row(run[key])} |')
    lines.append('')
    for layout, run in (('rig', rig), ('processes', processes)):
        lines.append(
            f'- {layout}: after warm-up {run["commands"]} commands, {len(run["total"])} '
            f'answered; {run["frames"]} frames, {run["shown"]} distinct commands shown, '
            f'{run["unmatched"]} frames not matched to a command; load average during the '
            f'run {run["load"]}.')
    lines += ['', under_load_note(load_before, load_text())]
    return '\n'.join(lines)


# ------------------------------------------------------------------------------ part 4: baseline

@contextmanager
def baseline_tree(ref: str):
    """The code at git ``ref``, checked out into a temporary worktree (removed afterwards)."""
    folder = Path(tempfile.mkdtemp(prefix='bench_rig_baseline_'))
    tree = folder / 'tree'
    subprocess.run(['git', 'worktree', 'add', '--detach', '--quiet', str(tree), ref], cwd=ROOT,
                   check=True, capture_output=True)
    try:
        yield tree
    finally:
        subprocess.run(['git', 'worktree', 'remove', '--force', str(tree)], cwd=ROOT,
                       capture_output=True)
        shutil.rmtree(folder, ignore_errors=True)


_BATCH_CHILD = """
import json, sys
try:
    from softseq_ros.batch import run
except ImportError:  # the code before one way to run a batch
    from softseq_ros.batch import run_scene as run
result = run('paper', sys.argv[1])
print(json.dumps({'wall': result.wall_s, 'sim': result.sim_duration_s,
                  'messages': sum(result.message_counts.values()),
                  'module': __import__('softseq_ros').__file__}))
"""


def batch_in_child(code_root: Path, out: Path) -> dict:
    """One batch run of the paper scene in a fresh interpreter running ``code_root``."""
    env = dict(os.environ, PYTHONPATH=str(code_root))
    # Run from the tree itself: 'python -c' puts the working directory first on sys.path.
    result = subprocess.run([sys.executable, '-c', _BATCH_CHILD, str(out)], env=env,
                            cwd=code_root, capture_output=True, text=True, timeout=1800)
    shutil.rmtree(out, ignore_errors=True)
    if result.returncode != 0:
        raise RuntimeError(f'batch run of {code_root} failed: {result.stderr[-2000:]}')
    info = json.loads(result.stdout.strip().splitlines()[-1])
    assert info['module'].startswith(str(code_root)), info['module']
    return info


_LOGGING_CHILD = """
import os, sys, time
import rclpy
from rclpy.node import Node
os.dup2(os.open(os.devnull, os.O_WRONLY), 2)   # the console lines go nowhere
rclpy.init()
node = Node('logging_cost', enable_rosout=True)
logger = node.get_logger()
count = 2000
start = time.perf_counter()
for i in range(count):
    logger.info('snap-through at 26.3872 mL injected')
public = (time.perf_counter() - start) / count
start = time.perf_counter()
for i in range(count):
    logger.debug('below the threshold: not formatted, not written')
filtered = (time.perf_counter() - start) / count
print(public * 1e6, filtered * 1e6)
node.destroy_node()
rclpy.shutdown()
"""


def logging_cost() -> tuple[float, float]:
    """Microseconds per line through rclpy's public logger: written (INFO) and filtered."""
    env = child_environment(BASE_DOMAIN_ID + 40)
    result = subprocess.run([sys.executable, '-c', _LOGGING_CHILD], env=env,
                            capture_output=True, text=True, timeout=300)
    if result.returncode != 0:
        raise RuntimeError(f'logging benchmark failed: {result.stderr[-2000:]}')
    written, filtered = (float(x) for x in result.stdout.split())
    return written, filtered


def part_baseline(repeats: int) -> str:
    load_before = load_text()
    ref = BASELINE_REF
    described = subprocess.run(['git', 'log', '-1', '--format=%h %s', ref], cwd=ROOT,
                               capture_output=True, text=True).stdout.strip()
    lines = ['## 4. Before and after (the same run)', '',
             f'Baseline: `{described[:110]}`, checked out into a temporary git worktree and run '
             'from its source; "now" is this checkout. Runs alternate baseline, now, baseline, '
             'now, ... in fresh interpreters, so both see the same machine load.', '']
    with baseline_tree(ref) as tree, tempfile.TemporaryDirectory(prefix='bench_rig_') as tmp:
        walls: dict[str, list[float]] = {'baseline': [], 'now': []}
        sim = messages = 0.0
        for index in range(repeats):
            for label, root in (('baseline', tree), ('now', ROOT)):
                print(f'baseline: batch {label} {index + 1}/{repeats} ...', flush=True)
                info = batch_in_child(root, Path(tmp) / f'{label}_{index}')
                walls[label].append(info['wall'])
                sim, messages = info['sim'], info['messages']
        best = {label: min(values) for label, values in walls.items()}
        median = {label: float(np.median(values)) for label, values in walls.items()}
        lines += [
            f'**Batch run** of the paper scene ({sim:.0f} s of rig time, {messages:.0f} '
            f'messages, every topic recorded), {repeats} alternated pairs:', '',
            '| code | wall, best [s] | wall, median [s] | speed-up, best | speed-up, median |',
            '|---|---:|---:|---:|---:|']
        for label in ('baseline', 'now'):
            lines.append(f'| {label} | {best[label]:.2f} | {median[label]:.2f} | '
                         f'{sim / best[label]:.0f}x | {sim / median[label]:.0f}x |')
        lines += ['', f'Now against the baseline: **{median["baseline"] / median["now"]:.2f}x** '
                  f'faster (ratio of medians; {best["baseline"] / best["now"]:.2f}x by best).',
                  '']
        latency = {}
        for offset, (label, root) in enumerate((('baseline', tree), ('now', None))):
            print(f'baseline: rig latency {label} ...', flush=True)
            latency[label] = latency_run('rig', BASE_DOMAIN_ID + 30 + offset, root)
        lines += [
            f'**Rig latency**: the `rig` executable at 100 Hz with state-triggered frames, '
            f'{LATENCY_RUN_S:.0f} s each, real time (as part 3):', '',
            '| latency [ms] | code | median | p90 | p99 | max | samples |',
            '|---|---|---:|---:|---:|---:|---:|']
        for key, label in (('taken', 'command -> pose taken'),
                           ('total', 'command -> actuator/volumes at the probe')):
            for code in ('baseline', 'now'):
                lines.append(f'| {label} | {code} | {latency_row(latency[code][key])} |')
    written, filtered = logging_cost()
    lines += [
        '', f"**Logging**: one line through rclpy's public logger (`node.get_logger().info`, "
        f'console and /rosout) costs {written:.0f} us, a filtered one (DEBUG below the '
        f'threshold) {filtered:.1f} us. The nodes log only what is rare (state changes, '
        'snap-throughs, refusals throttled to one line per kind every 2 s), never per '
        'command or frame, so the public API costs nothing measurable on the hot path.', '',
        under_load_note(load_before, load_text())]
    return '\n'.join(lines)


# ------------------------------------------------------------------------------ part 5: former

def timed_batch_in_child(code_root: Path, out: Path) -> dict:
    """:func:`batch_in_child`, with the whole process's wall and CPU time (its start-up too)."""
    before = os.times()
    start = time.perf_counter()
    info = batch_in_child(code_root, out)
    info['process_wall'] = time.perf_counter() - start
    after = os.times()
    info['process_cpu'] = (after.children_user - before.children_user
                           + after.children_system - before.children_system)
    return info


def part_former(repeats: int) -> str:
    load_before = load_text()
    ref = FORMER_REF
    described = subprocess.run(['git', 'log', '-1', '--format=%h %s', ref], cwd=ROOT,
                               capture_output=True, text=True).stdout.strip()
    pairs = FORMER_PAIRS
    lines = ['## 5. The batch run by blocks against the former code (the same run)', '',
             f'Former code: `{described[:110]}` (before the batch ran by blocks), checked out '
             'into a temporary git worktree; "now" is this checkout. Each run is the paper '
             'scene as `softseq run paper --no-report` runs it (`softseq_ros.run`, every topic '
             'recorded) in a fresh interpreter, former and now in turn (A B A B ...), '
             f'{pairs} pairs. "Run" is the wall time the run reports (the lock-step loop and '
             'the bag, what the real-time factor divides); "process" is the whole command '
             'timed from outside (interpreter start, imports, the scene and its equilibrium '
             'map, the run). Ratios are taken pair by pair and their median quoted.', '']
    with baseline_tree(ref) as tree, tempfile.TemporaryDirectory(prefix='bench_rig_') as tmp:
        runs: dict[str, list[dict]] = {'former': [], 'now': []}
        for index in range(pairs):
            for label, root in (('former', tree), ('now', ROOT)):
                print(f'former: batch {label} {index + 1}/{pairs} ...', flush=True)
                runs[label].append(timed_batch_in_child(root, Path(tmp) / f'{label}_{index}'))
    sim = runs['now'][0]['sim']
    messages = runs['now'][0]['messages']
    lines += [f'Paper scene: {sim:.0f} s of rig time, {messages:.0f} messages.', '',
              '| code | run wall, median [s] | min | max | real time, median | process wall, '
              'median [s] | process CPU, median [s] |',
              '|---|---:|---:|---:|---:|---:|---:|']
    for label in ('former', 'now'):
        walls = [run['wall'] for run in runs[label]]
        median = float(np.median(walls))
        lines.append(
            f'| {label} | {median:.2f} | {min(walls):.2f} | {max(walls):.2f} | '
            f'**{sim / median:.0f}x** | '
            f'{np.median([run["process_wall"] for run in runs[label]]):.2f} | '
            f'{np.median([run["process_cpu"] for run in runs[label]]):.2f} |')
    ratios = {key: [old[key] / new[key] for old, new in zip(runs['former'], runs['now'])]
              for key in ('wall', 'process_wall', 'process_cpu')}
    spread = {key: f'{min(values):.2f} to {max(values):.2f}' for key, values in ratios.items()}
    lines += ['', f'Now against the former code, median of the {pairs} pair ratios former / '
              f'now: the run **{np.median(ratios["wall"]):.2f}x** faster (pairs '
              f'{spread["wall"]}), the whole process {np.median(ratios["process_wall"]):.2f}x '
              f'by wall time ({spread["process_wall"]}) and '
              f'{np.median(ratios["process_cpu"]):.2f}x by CPU time ({spread["process_cpu"]}).',
              '', under_load_note(load_before, load_text())]
    return '\n'.join(lines)


# ------------------------------------------------------------------------------ results file

def write_results(path: Path, sections: dict[str, str]) -> None:
    """Replace this run's sections in the results file and keep the others."""
    existing = path.read_text(encoding='utf-8') if path.is_file() else ''
    kept = {}
    for part in PARTS:
        match = re.search(rf'<!-- part:{part} -->\n(.*?)<!-- /part:{part} -->', existing,
                          re.S)
        if match:
            kept[part] = match.group(1).rstrip('\n')
    kept.update(sections)
    facts = machine_facts()
    header = [
        '# Rig benchmarks', '',
        'Generated by `python bench/bench_rig.py` (see its docstring); a part re-run alone '
        'replaces only its section. Benchmarks, not tests: no time is asserted.', '',
        '| machine | |', '|---|---|', *[f'| {k} | {v} |' for k, v in facts.items()], '']
    body = []
    for part in PARTS:
        if part in kept:
            stamp = time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime()) \
                if part in sections else None
            text = kept[part]
            if stamp:
                text = f'_Measured {stamp}._\n\n' + re.sub(r'^_Measured [^\n]*_\n\n', '', text)
            body += [f'<!-- part:{part} -->', text, f'<!-- /part:{part} -->', '']
    path.write_text('\n'.join(header + body), encoding='utf-8')


def main() -> None:
    global LATENCY_RUN_S, BASELINE_REF, FORMER_REF
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--part', choices=(*PARTS, 'all'), default='all')
    parser.add_argument('--repeats', type=int, default=None,
                        help='repeats of the shortened batch runs (best is kept; default 3, '
                        '1 with --quick)')
    parser.add_argument('--latency-seconds', type=float, default=LATENCY_RUN_S,
                        help='length of the real-time latency run [s]')
    parser.add_argument('--out', type=Path, default=None,
                        help=f'results file (default {RESULTS.relative_to(ROOT)}; with --quick '
                        'none: printed only)')
    parser.add_argument('--quick', action='store_true',
                        help='the batch part only, on short programmes, once: a check that the '
                        'benchmark runs, in a few seconds')
    parser.add_argument('--baseline-ref', default=BASELINE_REF,
                        help='git revision the baseline part compares against')
    parser.add_argument('--former-ref', default=FORMER_REF,
                        help='git revision the former part compares against (the code before '
                        'the batch ran by blocks)')
    options = parser.parse_args()
    if options.latency_seconds <= LATENCY_WARMUP_S:
        parser.error(f'--latency-seconds: must be more than the {LATENCY_WARMUP_S:g} s warm-up')
    LATENCY_RUN_S = options.latency_seconds
    BASELINE_REF = options.baseline_ref
    FORMER_REF = options.former_ref
    if options.quick and options.part not in ('batch', 'all'):
        parser.error(f'--quick runs the batch part only, not {options.part} (DDS, processes)')
    repeats = options.repeats if options.repeats is not None else (1 if options.quick else 3)
    if repeats < 1:
        parser.error('--repeats: must be at least 1')
    out = options.out or (None if options.quick else RESULTS)
    sizes = QUICK if options.quick else FULL
    runners = {'batch': lambda repeats: part_batch(repeats, sizes), 'processes': part_processes,
               'latency': part_latency, 'baseline': part_baseline, 'former': part_former}
    chosen = ('batch',) if options.quick else PARTS if options.part == 'all' \
        else (options.part,)
    sections = {}
    for part in chosen:
        start = time.monotonic()
        sections[part] = runners[part](repeats)
        print(f'\n{sections[part]}\n\n({part}: {time.monotonic() - start:.0f} s)\n',
              flush=True)
        if out is not None:
            write_results(out, sections)
    if out is not None:
        print(f'written {out}')


def _interrupted(_signum, _frame) -> None:
    raise KeyboardInterrupt


if __name__ == '__main__':
    signal.signal(signal.SIGTERM, _interrupted)
    try:
        main()
    except KeyboardInterrupt:
        sys.exit('bench_rig: interrupted')
