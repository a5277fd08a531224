"""
Adversarial suite: generated bad inputs for every subcommand, node parameter, topic and signal.

    python bench/bench_adversarial.py [--quick] [--classes A,B,...] [--seed N] [--out FILE]
                                      [--no-docs] [--list]

Each case feeds one bad input to the rig as a user would meet it and judges what comes back
against the project's promise (docs/faults.md):

- a command (``softseq SUBCOMMAND``): exit 2 and exactly one line on stderr,
  ``softseq SUBCOMMAND: error: ...``, naming the file, key or option at fault; no traceback, no
  Python warning; what it would have written is not there (it refuses before it starts). A
  case whose input may be acceptable (an optional key deleted, a value of 0) holds when the
  command either succeeds cleanly or refuses so;
- a node given a bad parameter at start: refused in one line that names the node and the
  parameter (ParameterValueError, NodeConfigError, SceneError), nothing else raised; at run
  time (``set_parameters``): refused with a reason that starts with the parameter's name;
- garbage on a topic a node subscribes to: no exception escapes, the node says so (a warning
  or a refusal counted), and it still answers right afterwards (the pump: an untrustworthy
  answer holds it, naming the topic);
- a signal: ``softseq run``/``play`` exit 130 on SIGINT and 143 on SIGTERM with their bag
  complete; nodes and the recorder exit 0 with their files closed; a recording killed with
  SIGKILL is restored by ``softseq recover``;
- a damaged or foreign bag: ``info``, ``report``, ``compare`` succeed or refuse in one line;
  ``recover`` either writes a bag every reader opens or refuses in one line.

Classes: scene, table, design, experiment, reference, history, bag, cli, option, file,
node_parameter, service, topic, signal. Commands run in forked children of one process that has
imported the package (a fresh interpreter per case costs a second of CPU on imports alone): the
child is a real process with its own stdout, stderr and exit status, as the command line gives
them.

The summary (tried, held, broken, by class, and every broken case with why) goes to
bench/adversarial_results.md and between the markers of docs/faults.md. ``--quick`` tries a
small sample (a few cases per class, no signals; seconds), prints it and writes nothing unless
``--out`` is given; test/test_bench_quick.py runs it.
"""

import argparse
from contextlib import contextmanager, redirect_stderr
from dataclasses import dataclass, field
import io
import json
import math
import os
from pathlib import Path
import random
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from typing import Any, Callable, Iterator

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

RESULTS = ROOT / 'bench' / 'adversarial_results.md'
FAULTS = ROOT / 'docs' / 'faults.md'
BEGIN, END = '<!-- adversarial summary: begin -->', '<!-- adversarial summary: end -->'
CLASSES = ('scene', 'table', 'design', 'experiment', 'reference', 'history', 'bag', 'cli',
           'option', 'file', 'node_parameter', 'service', 'topic', 'signal')
QUICK_PER_CLASS = 1
COMMAND_TIMEOUT_S = 120.0
# A refusal comes before any work: a FEM run or a playback still going after this did not.
REFUSE_TIMEOUT_S = 60.0
HUGE = 10 ** 400          # an integer beyond a double
WARNING_LINE = re.compile(r'\b\w*Warning: ')


# ------------------------------------------------------------------------------ verdicts

@dataclass(frozen=True)
class Verdict:
    """Whether a case held the promise; why not when it did not."""

    held: bool
    why: str = ''
    tried: bool = True


HELD = Verdict(True)


def broken(why: str) -> Verdict:
    return Verdict(False, why)


def not_tried(why: str) -> Verdict:
    """A case this machine cannot try (counted apart, never as held)."""
    return Verdict(False, why, tried=False)


@dataclass
class Case:
    """One bad input: its class, a name that says what it is, and how to try it."""

    cls: str
    name: str
    run: Callable[['Workbench'], Verdict]
    # Whether this machine can try it (a file of mode 000 cannot stop root): --quick samples
    # only cases it can; the full run says the others were not tried.
    can_try: Callable[[], bool] = lambda: True


@dataclass
class Outcome:
    """What a command did: exit status (None: still running at its time-out), its output."""

    code: int | None
    stdout: str
    stderr: str
    seconds: float


# ------------------------------------------------------------------------------ commands

class Zygote:
    """
    A process that has imported the package and forks one child per command.

    The child is a real process (its own stdout, stderr, exit status, signal handlers), without
    the second of imports a fresh interpreter costs. BLAS threads are kept to one, so that a
    fork never inherits a thread pool.
    """

    def __init__(self) -> None:
        env = dict(os.environ, OPENBLAS_NUM_THREADS='1', OMP_NUM_THREADS='1',
                   MKL_NUM_THREADS='1', MPLBACKEND='Agg', PYTHONUNBUFFERED='1')
        self.process = subprocess.Popen([sys.executable, __file__, '--zygote'], env=env,
                                        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)

    def command(self, argv: list[str], cwd: Path, timeout: float = COMMAND_TIMEOUT_S,
                signum: int = 0, after: float = 0.0) -> Outcome:
        """Run ``softseq ARGV`` in a child; with ``signum``, send it that signal ``after`` s."""
        self.process.stdin.write(json.dumps({'argv': argv, 'cwd': str(cwd), 'timeout': timeout,
                                             'signal': signum, 'after': after}) + '\n')
        self.process.stdin.flush()
        line = self.process.stdout.readline()
        if not line:
            raise RuntimeError('the command zygote died')
        answer = json.loads(line)
        return Outcome(answer['code'], answer['stdout'], answer['stderr'], answer['seconds'])

    def close(self) -> None:
        if self.process.poll() is None:
            self.process.stdin.close()
            self.process.wait(timeout=30)


def zygote_main() -> None:
    """Serve commands: one JSON request a line on stdin, one JSON answer a line on stdout."""
    # What most commands load anyway, imported once here, before any fork.
    import numpy  # noqa: F401
    import scipy.interpolate  # noqa: F401
    import scipy.optimize  # noqa: F401

    import softseq_ros.cli as cli

    for line in sys.stdin:
        request = json.loads(line)
        with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
            start = time.monotonic()
            pid = os.fork()
            if pid == 0:
                _child(cli, request, out.fileno(), err.fileno())
            code = _wait(pid, request['timeout'], request.get('signal', 0),
                         request.get('after', 0.0))
            seconds = time.monotonic() - start
            out.seek(0)
            err.seek(0)
            answer = {'code': code, 'seconds': seconds,
                      'stdout': out.read().decode('utf-8', 'replace')[-20000:],
                      'stderr': err.read().decode('utf-8', 'replace')[-20000:]}
        sys.stdout.write(json.dumps(answer) + '\n')
        sys.stdout.flush()


def _child(cli: Any, request: dict, out_fd: int, err_fd: int) -> None:
    code = 1
    try:
        os.setsid()   # a time-out kills the command and whatever it started
        os.dup2(out_fd, 1)
        os.dup2(err_fd, 2)
        devnull = os.open(os.devnull, os.O_RDONLY)
        os.dup2(devnull, 0)
        sys.stdout = io.TextIOWrapper(os.fdopen(1, 'wb', buffering=0), write_through=True)
        sys.stderr = io.TextIOWrapper(os.fdopen(2, 'wb', buffering=0), write_through=True)
        os.chdir(request['cwd'])
        signal.signal(signal.SIGINT, signal.default_int_handler)
        # The child is the command's own process: its SIGTERM handler must take it for the
        # main process (it kills a forked worker, which the zygote's children are not).
        import softseq_ros.stopping as stopping
        stopping._MAIN_PID = os.getpid()
        code = cli.main(request['argv'])
    except SystemExit as exit_:
        code = exit_.code if isinstance(exit_.code, int) else (0 if exit_.code is None else 1)
    except BaseException:  # noqa: BLE001 - the judge reads it: a traceback breaks the promise
        import traceback
        traceback.print_exc()
        code = 1
    finally:
        try:
            sys.stdout.flush()
            sys.stderr.flush()
        finally:
            os._exit(code if isinstance(code, int) else 1)


def _wait(pid: int, timeout: float, signum: int = 0, after: float = 0.0) -> int | None:
    start = time.monotonic()
    deadline = start + timeout
    while True:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            return os.waitstatus_to_exitcode(status)
        if signum and time.monotonic() - start > after:
            os.kill(pid, signum)
            signum = 0
        if time.monotonic() > deadline:
            try:
                os.killpg(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            os.waitpid(pid, 0)
            return None
        time.sleep(0.005)


def _lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.strip()]


def judge_refusal(outcome: Outcome, command: str, names: tuple[str, ...],
                  unwritten: tuple[Path, ...] = ()) -> Verdict:
    """Exit 2, one line 'softseq COMMAND: error: ...' naming one of ``names``, nothing written."""
    if outcome.code is None:
        return broken(f'still running after {outcome.seconds:.0f} s: not refused before it '
                      'started')
    problems = []
    lines = _lines(outcome.stderr)
    if 'Traceback' in outcome.stderr:
        problems.append('a traceback: ' + lines[-1][:160] if lines else 'a traceback')
    elif outcome.code != 2:
        problems.append(f'exit {outcome.code}, not 2')
    if len(lines) != 1:
        problems.append(f'{len(lines)} lines on stderr' + (f' (first: {lines[0][:120]!r})'
                                                           if lines else ''))
    elif not lines[0].startswith(f'softseq {command}: error: ' if command else 'softseq'):
        problems.append(f'not "softseq {command}: error: ...": {lines[0][:160]!r}')
    elif names and not any(name in lines[0] for name in names):
        problems.append(f'names none of {list(names)}: {lines[0][:200]!r}')
    for path in unwritten:
        if path.exists():
            problems.append(f'{path.name} was written')
    return broken('; '.join(problems)) if problems else HELD


def judge_clean(outcome: Outcome, command: str, names: tuple[str, ...],
                unwritten: tuple[Path, ...] = ()) -> Verdict:
    """Either success without a traceback or a warning, or a refusal as judge_refusal wants."""
    if outcome.code == 0:
        if 'Traceback' in outcome.stderr:
            return broken('exit 0 with a traceback on stderr')
        warned = [line for line in _lines(outcome.stderr) if WARNING_LINE.search(line)]
        if warned:
            return broken(f'a Python warning: {warned[0][:160]!r}')
        return HELD
    return judge_refusal(outcome, command, names, unwritten)


# ------------------------------------------------------------------------------ the workbench

@dataclass
class Workbench:
    """What every case may use: a scratch folder, the zygote, good inputs made once."""

    root: Path
    zygote: Zygote
    rng: random.Random
    made: dict[str, Any] = field(default_factory=dict)
    ros: Any = None
    domain_id: int = 0

    def folder(self, name: str) -> Path:
        path = Path(tempfile.mkdtemp(prefix=re.sub(r'\W+', '_', name)[:40] + '_',
                                     dir=self.root))
        return path

    def softseq(self, argv: list[str], cwd: Path, timeout: float = COMMAND_TIMEOUT_S,
                signum: int = 0, after: float = 0.0) -> Outcome:
        return self.zygote.command(argv, cwd, timeout, signum, after)

    def good(self, what: str) -> Path:
        """A good input made once: 'bag' (a short rig bag), 'scene', 'table_scene', 'design'."""
        if what not in self.made:
            self.made[what] = GOOD[what](self)
        return self.made[what]


def _yaml(data: Any) -> str:
    import yaml
    return yaml.safe_dump(data, sort_keys=False, allow_unicode=True)


def _read_yaml(path: Path) -> Any:
    import yaml
    return yaml.safe_load(path.read_text(encoding='utf-8'))


def _config(name: str) -> Path:
    return ROOT / 'config' / name


def _good_scene(bench: Workbench) -> Path:
    """fig1_none with a short, fast programme (0 -> 5 mL -> 0 at 1 mL/s): a 10 s bag."""
    data = _read_yaml(_config('fig1_none.yaml'))
    data['pump'].update(flow_rate_m3_per_s=1.0e-6, rate_hz=50,
                        legs=[{'inflate_to_m3': 5.0e-6}, {'deflate_to_m3': 0.0}])
    data['camera']['trigger_injected_m3'] = [1.0e-6, 4.0e-6]
    path = bench.folder('good') / 'good.yaml'
    path.write_text(_yaml(data), encoding='utf-8')
    return path


def _good_bag(bench: Workbench) -> Path:
    scene = bench.good('scene')
    out = scene.parent / 'bag'
    outcome = bench.softseq(['run', str(scene), '--out', str(out), '--quiet', '--no-report',
                             '--start-time', '0'], scene.parent)
    if outcome.code != 0:
        raise RuntimeError(f'the good bag could not be made: {outcome.stderr[-2000:]}')
    return out


def _table_scene(bench: Workbench) -> Path:
    """The paper scene with its tables copied beside it (a case replaces the top one)."""
    folder = bench.folder('tables')
    for name in ('paper_bottom.csv', 'paper_top.csv'):
        shutil.copy(_config('segments') / name, folder / name)
    data = _read_yaml(_config('paper.yaml'))
    data['segments'][0]['table'] = 'paper_bottom.csv'
    data['segments'][1]['table'] = 'top.csv'
    path = folder / 'scene.yaml'
    path.write_text(_yaml(data), encoding='utf-8')
    return path


GOOD: dict[str, Callable[[Workbench], Path]] = {
    'scene': _good_scene,
    'bag': _good_bag,
    'table_scene': _table_scene,
}


# ------------------------------------------------------------------------------ mutations

def key_path(path: tuple) -> str:
    """A key path as the loaders name it: ``segments[0].linear.max_volume_m3``."""
    text = ''
    for part in path:
        text += f'[{part}]' if isinstance(part, int) else (f'.{part}' if text else str(part))
    return text


def _walk(data: Any, path: tuple = ()) -> Iterator[tuple[str, tuple, Any]]:
    """Every node of a YAML document: ('mapping' | 'sequence' | 'leaf', its path, its value)."""
    if isinstance(data, dict):
        yield 'mapping', path, data
        for key, value in data.items():
            yield from _walk(value, path + (key,))
    elif isinstance(data, list):
        yield 'sequence', path, data
        for index, value in enumerate(data):
            yield from _walk(value, path + (index,))
    else:
        yield 'leaf', path, data


def _set(data: Any, path: tuple, value: Any) -> None:
    for part in path[:-1]:
        data = data[part]
    data[path[-1]] = value


def _delete(data: Any, path: tuple) -> None:
    for part in path[:-1]:
        data = data[part]
    del data[path[-1]]


# Values no number can be (refused), and values a number may or may not be (either is fine).
NOT_A_NUMBER = (('text', 'abc'), ('list', [1]), ('mapping', {'a': 1}), ('null', None),
                ('bool', True), ('nan', math.nan), ('inf', math.inf), ('-inf', -math.inf),
                ('1e400', HUGE))
MAYBE_A_NUMBER = (('-1', -1), ('0', 0))
NOT_A_TEXT = (('list', ['a']), ('mapping', {'a': 1}), ('null', None))
# Keys whose value is free text: any text goes.
FREE_TEXT = {'description', 'source'}
# Keys where null is documented as "the default" (docs/scene_reference.md): null is taken.
NULL_MEANS_DEFAULT = {'solver.resolution', 'segments[].smoothing.noise_std_pa',
                      'segments[].smoothing.prominence_pa'}


@dataclass(frozen=True)
class Mutation:
    """One change of a good document: what it is, the key it touches, whether it must fail."""

    name: str
    path: tuple
    change: Callable[[Any], None]
    must_refuse: bool


def mutations(document: Any) -> list[Mutation]:
    """Changes of every key of ``document``: wrong types, non-finite, deleted, unknown keys."""
    found = []
    for kind, path, value in _walk(document):
        where = key_path(path)
        if kind == 'mapping':
            found.append(Mutation(f'{where or "top"}: an unknown key', path + ('bogus_key',),
                                  lambda d, p=path: _set(d, p + ('bogus_key',), 1) if p
                                  else d.__setitem__('bogus_key', 1), True))
            for key in value:
                found.append(Mutation(f'{key_path(path + (key,))}: deleted', path + (key,),
                                      lambda d, p=path + (key,): _delete(d, p), False))
        elif kind == 'sequence':
            found.append(Mutation(f'{where}: empty', path, lambda d, p=path: _set(d, p, []),
                                  False))
            found.append(Mutation(f'{where}: a number, not a list', path,
                                  lambda d, p=path: _set(d, p, 5), True))
        elif isinstance(value, bool):
            found.append(Mutation(f'{where}: text', path,
                                  lambda d, p=path: _set(d, p, 'maybe'), True))
        elif isinstance(value, (int, float)):
            documented = re.sub(r'\[\d+\]', '[]', where)
            for label, bad in NOT_A_NUMBER:
                refuse = not (bad is None and documented in NULL_MEANS_DEFAULT)
                found.append(Mutation(f'{where}: {label}', path,
                                      lambda d, p=path, b=bad: _set(d, p, b), refuse))
            for label, odd in MAYBE_A_NUMBER:
                found.append(Mutation(f'{where}: {label}', path,
                                      lambda d, p=path, b=odd: _set(d, p, b), False))
        elif isinstance(value, str) and path and path[-1] not in FREE_TEXT:
            for label, bad in NOT_A_TEXT:
                found.append(Mutation(f'{where}: {label}', path,
                                      lambda d, p=path, b=bad: _set(d, p, b), True))
    return found


def _line_names_file_and_key(line: str, file_name: str, path: tuple) -> bool:
    if file_name not in line:
        return False
    if not path:
        return True
    last = next((part for part in reversed(path) if isinstance(part, str)), None)
    return key_path(path) in line or (last is not None and last in line)


def judge_names(outcome: Outcome, command: str, file_name: str, path: tuple,
                must_refuse: bool, unwritten: tuple[Path, ...] = ()) -> Verdict:
    """A refusal naming the file and the key; or, when it need not refuse, a clean success."""
    if not must_refuse and outcome.code == 0:
        return judge_clean(outcome, command, ())
    verdict = judge_refusal(outcome, command, (), unwritten)
    if not verdict.held:
        return verdict
    line = _lines(outcome.stderr)[0]
    if not _line_names_file_and_key(line, file_name, path):
        return broken(f'does not name {file_name} and {key_path(path)}: {line[:200]!r}')
    return HELD


# ------------------------------------------------------------------------------ case makers

SHIPPED_SCENE_BASES = ('fig1_none.yaml', 'fig1_asymmetric.yaml', 'rate_inversion.yaml',
                       'paper.yaml')
# Scenes written here so that, with the shipped ones, every key of the scene reference
# (softseq_ros/scene/reference.py) is in some base and so made wrong in every way:
# test/test_adversarial_registry.py fails on a documented key no base holds.
MAXIMAL_SCENE_BASES = ('every_block', 'every_law', 'every_leg', 'every_regulator_leg')
SCENE_BASES = SHIPPED_SCENE_BASES + MAXIMAL_SCENE_BASES
# The profile leg's file of the base every_leg (time_s, injected_m3: 3 mL to 5 mL), written
# beside each scene made of it; and of every_regulator_leg (time_s, gauge_pa: 3 to 8 kPa).
PROFILE_CSV = ('fill.csv', 'time_s,injected_m3\n0,3.0e-6\n2,4.0e-6\n4,5.0e-6\n')
PRESSURE_PROFILE_CSV = ('press.csv', 'time_s,gauge_pa\n0,3000\n2,5000\n4,8000\n')


def write_companions(folder: Path, base: str) -> None:
    """The files a base scene names relative to itself, into the scene's ``folder``."""
    if base == 'every_leg':
        (folder / PROFILE_CSV[0]).write_text(PROFILE_CSV[1], encoding='utf-8')
    if base == 'every_regulator_leg':
        (folder / PRESSURE_PROFILE_CSV[0]).write_text(PRESSURE_PROFILE_CSV[1], encoding='utf-8')


def scene_job(base: str, scene: Path, folder: Path) -> list[str]:
    """What a scene made of ``base`` is tried with: classify, or behind a regulator solve."""
    if base == 'every_regulator_leg':
        return ['solve', str(scene), '--out', str(folder / 'path.csv')]
    return ['classify', str(scene)]


def _maximal_document(name: str) -> Any:
    """One of MAXIMAL_SCENE_BASES: a valid scene holding keys no shipped scene holds."""
    gent = {'law': 'gent', 'shear_modulus_pa': 60.0e3, 'jm': 40.0}

    def balloon(segment: str, material: dict, stretch: float = 3.0) -> dict:
        return {'name': segment, 'length_m': 0.111,
                'balloon': {'material': material, 'radius_m': 0.006, 'thickness_m': 0.6e-3,
                            'max_stretch': stretch, 'curvature_per_m_per_m3': 5.0e5}}
    if name == 'every_block':
        return {
            'name': 'every_block', 'description': 'every block the scene file has',
            'segments': [
                {'name': 'bottom', 'length_m': 0.111, 'smoothing': {
                    'noise_std_pa': 5.0, 'prominence_pa': 50.0},
                 'table': str(_config('segments') / 'paper_bottom.csv')},
                {'name': 'top', 'length_m': 0.111,
                 'linear': {'rest_volume_m3': 2.0e-6, 'stiffness_pa_per_m3': 2.0e8,
                            'max_volume_m3': 6.0e-5, 'curvature_per_m_per_m3': 1.0e5}}],
            'pump': {'flow_rate_m3_per_s': 1.0e-6, 'rate_hz': 20.0, 'cycles': 1,
                     'start_history_m3': [2.0e-6, 1.0e-6],
                     'legs': [{'inflate_to_m3': 5.0e-6}, {'deflate_to_m3': 0.0}]},
            'camera': {'rate_hz': 2.0, 'noise_std_m': 1.0e-4, 'seed': 3,
                       'trigger_injected_m3': [2.0e-6], 'points_per_segment': 10,
                       'image_width_px': 64, 'image_height_px': 48},
            'outputs': ['pressure', 'volumes', 'curvature', 'events'],
            'solver': {'resolution': 400},
            'network': {'fluid': {'viscosity_pa_s': 1.0e-3, 'density_kg_per_m3': 998.0},
                        'supply': {'length_m': 0.3, 'radius_m': 0.8e-3, 'inertance': False,
                                   'minor_loss': 0.5, 'friction': 'laminar'},
                        'feeds': 'bottom',
                        'channels': [{'length_m': 0.01, 'radius_m': 0.5e-3,
                                      'inertance': False, 'minor_loss': 0.5,
                                      'friction': 'blasius'}],
                        'rate_hz': 20.0, 'rtol': 1.0e-6},
            'supply': {'trapped_gas_m3': 1.0e-6, 'line_compliance_m3_per_pa': 1.0e-12,
                       'ambient_pa': 101325.0, 'polytropic_exponent': 1.0}}
    if name == 'every_law':
        return {
            'name': 'every_law',
            'segments': [
                balloon('neo', {'law': 'neo_hookean', 'shear_modulus_pa': 60.0e3}),
                balloon('mooney', {'law': 'mooney_rivlin', 'c1_pa': 25.0e3, 'c2_pa': 5.0e3}),
                balloon('ogden', {'law': 'ogden', 'mu_pa': [60.0e3], 'alpha': [2.0]}),
                balloon('arruda', {'law': 'arruda_boyce', 'shear_modulus_pa': 60.0e3,
                                   'lambda_m': 5.0}),
                balloon('yeoh', {'law': 'yeoh', 'c1_pa': 30.0e3, 'c2_pa': -300.0,
                                 'c3_pa': 10.0}),
                balloon('gent', gent)],
            'pump': {'start_injected_m3': 0.0,
                     'legs': [{'inflate_to_m3': 2.0e-6}, {'deflate_to_m3': 0.0}]}}
    if name == 'every_leg':
        return {
            'name': 'every_leg',
            'segments': [balloon('bottom', gent, 4.0),
                         balloon('top', {**gent, 'jm': 30.0}, 3.6)],
            'pump': {'start_branch': 0, 'flow_rate_m3_per_s': 1.0e-6,
                     'legs': [{'inflate_to_m3': 3.0e-6, 'flow_rate_m3_per_s': 2.0e-6},
                              {'profile': PROFILE_CSV[0]}, {'hold_s': 1.0},
                              {'deflate_to_m3': 0.0}]}}
    if name == 'every_regulator_leg':
        return {
            'name': 'every_regulator_leg',
            'segments': [balloon('bottom', gent, 4.0),
                         balloon('top', {**gent, 'jm': 30.0}, 3.6)],
            'supply': {'regulator': {'time_constant_s': 0.5, 'max_flow_m3_per_s': 2.0e-6,
                                     'max_pressure_pa': 12000.0}},
            'pump': {'pressure_rate_pa_per_s': 500.0, 'rate_hz': 5.0, 'cycles': 1,
                     'legs': [{'inflate_to_pa': 3000.0, 'rate_pa_per_s': 1000.0},
                              {'profile': PRESSURE_PROFILE_CSV[0]}, {'hold_s': 1.0},
                              {'deflate_to_pa': 0.0}]}}
    raise ValueError(f'no maximal scene base {name!r}')


def _scene_document(base: str) -> Any:
    if base in MAXIMAL_SCENE_BASES:
        return _maximal_document(base)
    data = _read_yaml(_config(base))
    for segment in data.get('segments', []):
        if 'table' in segment:
            segment['table'] = str(_config(segment['table']))
    return data


def scene_key_paths(document: Any) -> set[str]:
    """Every key a scene document holds, by path, list items as ``[]``."""
    return {re.sub(r'\[\d+\]', '[]', key_path(path)) for kind, path, _ in _walk(document)
            if path and isinstance(path[-1], str)}


def scene_cases() -> list[Case]:
    """Every key of four shipped scenes (linear, balloon, network, tables) made wrong."""
    cases = []
    seen = set()
    for base in SCENE_BASES:
        for mutation in mutations(_scene_document(base)):
            # A key the bases share (pump.rate_hz, camera.seed) is tried once.
            if mutation.name in seen:
                continue
            seen.add(mutation.name)

            def run(bench: Workbench, base=base, mutation=mutation) -> Verdict:
                data = _scene_document(base)
                mutation.change(data)
                folder = bench.folder('scene')
                scene = folder / 'scene.yaml'
                scene.write_text(_yaml(data), encoding='utf-8')
                write_companions(folder, base)
                job = scene_job(base, scene, folder)
                outcome = bench.softseq(job, folder)
                return judge_names(outcome, job[0], 'scene.yaml', mutation.path,
                                   mutation.must_refuse)
            cases.append(Case('scene', f'{base}: {mutation.name}', run))
    # Not a scene at all, and what `run` must not start on.
    whole = [('empty file', ''), ('a list', '- 1\n- 2\n'), ('a number', '42\n'),
             ('binary', '\x00\x01\x02'), ('deep nesting', '[' * 50_000 + ']' * 50_000),
             ('tabs', 'name:\tx\n'), ('duplicate key', 'name: a\nname: b\n'),
             ('a YAML anchor bomb', 'a: &a [' + ', '.join(['x'] * 10) + ']\n'
              + ''.join(f'{c}: &{c} [' + ', '.join([f'*{p}'] * 10) + ']\n'
                        for p, c in zip('abcdefgh', 'bcdefghi')))]
    for label, text in whole:
        def run_whole(bench: Workbench, text=text) -> Verdict:
            folder = bench.folder('scene')
            scene = folder / 'scene.yaml'
            scene.write_text(text, encoding='utf-8', errors='surrogateescape')
            out = folder / 'bag'
            outcome = bench.softseq(['run', str(scene), '--out', str(out), '--quiet',
                                     '--no-report'], folder, REFUSE_TIMEOUT_S)
            return judge_refusal(outcome, 'run', ('scene.yaml',), (out,))
        cases.append(Case('scene', f'whole file: {label}', run_whole))
    return cases


def _top_table_text() -> str:
    return (_config('segments') / 'paper_top.csv').read_text(encoding='utf-8')


def _data_rows(text: str) -> tuple[list[str], str, list[str]]:
    lines = text.splitlines()
    comments = [line for line in lines if line.startswith('#')]
    body = [line for line in lines if line.strip() and not line.startswith('#')]
    return comments, body[0], body[1:]


def _scaled(text: str, column: int, factor: float) -> str:
    comments, header, rows = _data_rows(text)
    out = []
    for row in rows:
        cells = row.split(',')
        cells[column] = repr(float(cells[column]) * factor)
        out.append(','.join(cells))
    return '\n'.join(comments + [header] + out) + '\n'


def _edited_rows(text: str, edit: Callable[[list[str]], list[str]]) -> str:
    comments, header, rows = _data_rows(text)
    return '\n'.join(comments + [header] + edit(list(rows))) + '\n'


def _cell(rows: list[str], row: int, column: int, value: str) -> list[str]:
    cells = rows[row].split(',')
    cells[column] = value
    rows[row] = ','.join(cells)
    return rows


# (name, the table's bytes made from the good one, must it be refused)
TABLES: list[tuple[str, Callable[[str], bytes], bool]] = [
    ('empty file', lambda t: b'', True),
    ('header only', lambda t: b'volume_m3,pressure_pa,curvature_per_m\n', True),
    ('one row', lambda t: _edited_rows(t, lambda r: r[:1]).encode(), True),
    ('no pressure column', lambda t: t.replace('pressure_pa', 'pressure_kpa').encode(), True),
    ('columns renamed', lambda t: t.replace('volume_m3', 'volume').encode(), True),
    ('volumes in mL', lambda t: _scaled(t, 0, 1e6).encode(), True),
    ('volumes in mm^3', lambda t: _scaled(t, 0, 1e9).encode(), True),
    ('pressures in kPa', lambda t: _scaled(t, 1, 1e-3).encode(), True),
    ('pressures in MPa', lambda t: _scaled(t, 1, 1e-6).encode(), True),
    ('pressures x1e304', lambda t: _scaled(t, 1, 1e304).encode(), True),
    ('pressures of 1e12 Pa', lambda t: _scaled(t, 1, 1e8).encode(), True),
    ('rows reversed', lambda t: _edited_rows(t, lambda r: r[::-1]).encode(), True),
    ('a repeated row', lambda t: _edited_rows(t, lambda r: r[:3] + r[2:]).encode(), True),
    ('NaN pressure', lambda t: _edited_rows(t, lambda r: _cell(r, 3, 1, 'nan')).encode(), True),
    ('inf volume', lambda t: _edited_rows(t, lambda r: _cell(r, 3, 0, 'inf')).encode(), True),
    ('text in a cell', lambda t: _edited_rows(t, lambda r: _cell(r, 3, 1, '1,2kPa')).encode(),
     True),
    ('a negative volume', lambda t: _edited_rows(t, lambda r: _cell(r, 0, 0, '-1e-5')).encode(),
     True),
    ('decimal commas', lambda t: t.replace('.', ',').encode(), True),
    ('semicolons', lambda t: t.replace(',', ';').encode(), True),
    ('a missing cell', lambda t: _edited_rows(t, lambda r: _cell(r, 3, 2, '')).encode(), True),
    ('latin-1 comment', lambda t: ('# Messung am Pr\u00fcfstand\n' + t).encode('latin-1'), True),
    ('binary', lambda t: bytes(range(256)) * 16, True),
    ('NUL bytes in a row', lambda t: _edited_rows(t, lambda r: _cell(r, 3, 1, '1\x002')).encode(),
     True),
    ('a field beyond the csv limit', lambda t: t.encode() + b'"' + b'9' * 140_000 + b'",0,0\n',
     True),
    ('an integer of 5000 digits',
     lambda t: _edited_rows(t, lambda r: _cell(r, 3, 1, '9' * 5000)).encode(), True),
    # Good tables written otherwise: each must be read.
    ('byte-order mark', lambda t: b'\xef\xbb\xbf' + t.encode(), False),
    ('CRLF line ends', lambda t: t.replace('\n', '\r\n').encode(), False),
    ('extra columns', lambda t: _edited_rows(
        t.replace('curvature_per_m', 'curvature_per_m,note'),
        lambda r: [row + ',x' for row in r]).encode(), False),
]


def table_cases() -> list[Case]:
    """The paper scene's top table damaged or in other units, loaded by `softseq classify`."""
    cases = []
    for name, make, must_refuse in TABLES:
        def run(bench: Workbench, make=make, must_refuse=must_refuse) -> Verdict:
            scene = bench.good('table_scene')
            folder = bench.folder('table')
            shutil.copy(scene, folder / 'scene.yaml')
            shutil.copy(scene.parent / 'paper_bottom.csv', folder / 'paper_bottom.csv')
            (folder / 'top.csv').write_bytes(make(_top_table_text()))
            outcome = bench.softseq(['classify', str(folder / 'scene.yaml')], folder)
            if must_refuse:
                return judge_refusal(outcome, 'classify', ('top.csv',))
            if outcome.code != 0:
                return broken(f'a good table refused: {_lines(outcome.stderr)[-1:]}')
            return judge_clean(outcome, 'classify', ())
        cases.append(Case('table', name, run))
    # The same damage seen by `softseq library`, which reads a folder of tables.
    for name, make, must_refuse in TABLES[:8]:
        def run_library(bench: Workbench, make=make) -> Verdict:
            folder = bench.folder('library')
            tables = folder / 'tables'
            tables.mkdir()
            (tables / 'bad.csv').write_bytes(make(_top_table_text()))
            out = folder / 'out'
            outcome = bench.softseq(['library', str(tables), '--length-m', '0.111', '--out',
                                     str(out), '--jobs', '1'], folder)
            return judge_refusal(outcome, 'library', ('bad.csv',), (out,))
        if must_refuse:
            cases.append(Case('table', f'library: {name}', run_library))
    return cases


def design_cases() -> list[Case]:
    """Every key of a shipped FEM design made wrong: refused before any meshing."""
    base = _config('designs') / 'paper_top.yaml'
    cases = []
    for mutation in mutations(_read_yaml(base)):
        # A deleted key or a 0 may be a design the FEM runs for minutes: only what no design
        # can be is tried here (every number of a design is positive).
        if mutation.name.endswith(': deleted') or mutation.name.endswith(': 0') \
                or mutation.name.endswith(': empty'):
            continue

        def run(bench: Workbench, mutation=mutation) -> Verdict:
            data = _read_yaml(base)
            mutation.change(data)
            folder = bench.folder('design')
            design = folder / 'design.yaml'
            design.write_text(_yaml(data), encoding='utf-8')
            out = folder / 'table.csv'
            outcome = bench.softseq(['fem', str(design), '--out', str(out), '--quiet',
                                     '--cache-dir', str(folder / 'cache')], folder,
                                    REFUSE_TIMEOUT_S)
            return judge_names(outcome, 'fem', 'design.yaml', mutation.path, True, (out,))
        cases.append(Case('design', mutation.name, run))
    for setting in ('mesh.element_size_m=abc', 'mesh.element_size_m=-1',
                    'mesh.element_size_m=nan', 'mesh.element_size_m=1e-9',
                    'geometry.length_m=inf', 'material.shear_modulus_pa=1e306',
                    'no.such.key=1', 'geometry=5', 'mesh.thin_layer_cells=1e9'):
        def run_set(bench: Workbench, setting=setting) -> Verdict:
            folder = bench.folder('design_set')
            out = folder / 'table.csv'
            outcome = bench.softseq(['fem', 'paper_top', '--set', setting, '--out', str(out),
                                     '--quiet', '--cache-dir', str(folder / 'cache')], folder,
                                    REFUSE_TIMEOUT_S)
            return judge_refusal(outcome, 'fem', (setting.split('=')[0].split('.')[-1],),
                                 (out,))
        cases.append(Case('design', f'--set {setting}', run_set))
    return cases


def _experiment_text() -> str:
    rows = '\n'.join(f'{1.0e-6 * k:.6e},{101325.0 + 1000.0 * k:.1f},inflation'
                     for k in range(1, 5))
    return ('# pressure_kind: absolute\n# ambient_pressure_pa: 101325\n'
            f'injected_m3,pressure_pa,direction\n{rows}\n')


EXPERIMENTS: list[tuple[str, Callable[[str], bytes]]] = [
    ('empty', lambda t: b''),
    ('header only', lambda t: b'injected_m3,pressure_pa\n'),
    ('no pressure column', lambda t: t.replace('pressure_pa', 'p').encode()),
    ('absolute in kPa', lambda t: re.sub(r',1(\d{2})(\d{3})\.0,', r',1\1.\2,', t).encode()),
    ('ambient in kPa', lambda t: t.replace('101325\n', '101.325\n').encode()),
    ('ambient NaN', lambda t: t.replace('101325\n', 'nan\n').encode()),
    ('pressure kind unknown', lambda t: t.replace('absolute', 'relative').encode()),
    ('gauge in kPa', lambda t: re.sub(r',1(\d{2})(\d{3})\.0,', lambda m: f',{int(m[1]) - 1}.'
                                      f'{m[2]},', t.replace('absolute', 'gauge')).encode()),
    ('gauge far from the model', lambda t: re.sub(r',1(\d{2})(\d{3})\.0,', r',\2,',
                                                  t.replace('absolute', 'gauge')).encode()),
    ('volumes in mL', lambda t: re.sub(r'^(\d\.\d+)e-06', r'\1', t, flags=re.M).encode()),
    ('negative volume', lambda t: t.replace('1.000000e-06', '-1.000000e-06').encode()),
    ('NaN pressure', lambda t: t.replace('102325.0', 'nan').encode()),
    ('direction garbage', lambda t: t.replace('inflation', 'upwards', 1).encode()),
    ('one tip column', lambda t: t.replace('direction', 'direction,tip_x_m').replace(
        'inflation', 'inflation,0.1').encode()),
    ('binary', lambda t: bytes(range(256)) * 8),
    ('latin-1', lambda t: ('# Pr\u00fcfstand\n' + t).encode('latin-1')),
    ('a field beyond the csv limit', lambda t: t.encode() + b'"' + b'1' * 140_000 + b'",1\n'),
]


# Plausible files that only disagree with the model: a report, not a refusal.
FAIR_EXPERIMENTS = {'gauge far from the model'}


def experiment_cases() -> list[Case]:
    """`softseq report BAG --experiment FILE` with a damaged or mis-unit experiment file."""
    cases = []
    for name, make in EXPERIMENTS:
        def run(bench: Workbench, make=make, name=name) -> Verdict:
            bag = bench.good('bag')
            folder = bench.folder('experiment')
            experiment = folder / 'rig.csv'
            experiment.write_bytes(make(_experiment_text()))
            out = folder / 'report'
            outcome = bench.softseq(['report', str(bag), '--experiment', str(experiment),
                                     '--out', str(out)], folder)
            if name in FAIR_EXPERIMENTS:
                return judge_clean(outcome, 'report', ('rig.csv',), (out,))
            return judge_refusal(outcome, 'report', ('rig.csv',), (out,))
        cases.append(Case('experiment', name, run))
    return cases


REFERENCE_TEXTS = [
    ('not a mapping', 'reported: [partial]\n'),
    ('a list', '- reported\n'),
    ('type a number', 'reported:\n  sequence_type: 3\n'),
    ('type unknown', 'reported:\n  sequence_type: sideways\n'),
    ('NaN plateau', 'reported:\n  plateau_onset_injected_m3: .nan\n'),
    ('negative plateau', 'reported:\n  plateau_onset_injected_m3: -1.0e-5\n'),
    ('tolerance a list', 'reported:\n  plateau_onset_tolerance_m3: [1]\n'),
    ('steps a mapping', 'reported:\n  steps: {step: 3}\n'),
    ('steps numbers', 'reported:\n  steps: [1, 2]\n'),
    ('step a word', 'reported:\n  steps:\n    - {step: three}\n'),
    ('step volume negative',
     'reported:\n  steps:\n    - {step: 3, experiment_injected_m3: -1.0e-5}\n'),
    ('segment unknown', 'reported:\n  segment_plateau_lower: middle\n'),
    ('deep nesting', 'reported: ' + '[' * 100_000 + '\n'),
    ('binary', '\x00\xff\x00'),
    ('empty', ''),
]


def reference_cases() -> list[Case]:
    """`softseq report BAG --reference FILE` with a malformed reference."""
    cases = []
    for name, text in REFERENCE_TEXTS:
        def run(bench: Workbench, text=text) -> Verdict:
            bag = bench.good('bag')
            folder = bench.folder('reference')
            reference = folder / 'reference.yaml'
            reference.write_bytes(text.encode('utf-8', 'surrogateescape')
                                  if text != '\x00\xff\x00' else b'\x00\xff\x00')
            out = folder / 'report'
            outcome = bench.softseq(['report', str(bag), '--reference', str(reference),
                                     '--out', str(out)], folder)
            return judge_refusal(outcome, 'report', ('reference.yaml',), (out,))
        cases.append(Case('reference', name, run))
    return cases


HISTORIES = [
    ('empty', b''),
    ('header only', b'injected_m3\n'),
    ('no column', b'volume\n1e-6\n'),
    ('text', b'injected_m3\n1e-6\nabc\n'),
    ('NaN', b'injected_m3\n1e-6\nnan\n'),
    ('inf', b'injected_m3\n1e-6\ninf\n'),
    ('negative', b'injected_m3\n1e-6\n-1e-6\n'),
    ('beyond the domain', b'injected_m3\n1e-6\n1.0\n'),
    ('in mL', b'injected_m3\n1\n5\n10\n'),
    ('binary', bytes(range(256)) * 4),
    ('a field beyond the csv limit', b'injected_m3\n"' + b'1' * 140_000 + b'"\n'),
    ('an integer of 5000 digits', b'injected_m3\n' + b'9' * 5000 + b'\n'),
]


def history_cases() -> list[Case]:
    """`softseq solve SCENE --path FILE` with a bad volume history."""
    cases = []
    for name, data in HISTORIES:
        def run(bench: Workbench, data=data) -> Verdict:
            folder = bench.folder('history')
            history = folder / 'history.csv'
            history.write_bytes(data)
            out = folder / 'path.csv'
            outcome = bench.softseq(['solve', 'fig1_none', '--path', str(history), '--out',
                                     str(out)], folder)
            return judge_refusal(outcome, 'solve', ('history.csv',), (out,))
        cases.append(Case('history', name, run))
    return cases


def _mcap(bag: Path) -> Path:
    return next(bag.glob('*.mcap'))


def _copy_bag(bench: Workbench, folder: Path) -> Path:
    bag = folder / 'damaged_bag'
    shutil.copytree(bench.good('bag'), bag)
    return bag


def _flip(bag: Path, fraction: float) -> None:
    path = _mcap(bag)
    data = bytearray(path.read_bytes())
    index = int(fraction * (len(data) - 1))
    data[index] ^= 0x10
    path.write_bytes(bytes(data))


def _truncate(bag: Path, fraction: float) -> None:
    path = _mcap(bag)
    data = path.read_bytes()
    path.write_bytes(data[:int(fraction * len(data))])


def _zero(bag: Path, fraction: float) -> None:
    path = _mcap(bag)
    data = bytearray(path.read_bytes())
    start = int(fraction * len(data))
    data[start:start + 4096] = bytes(min(4096, len(data) - start))
    path.write_bytes(bytes(data))


def _foreign(bag: Path, kind: str) -> None:
    """A bag of other topics, or a rig topic of another type, written by our bag writer."""
    from softseq_ros.bag.writer import BagWriter
    shutil.rmtree(bag)
    writer = BagWriter(bag)
    topic, type_name = (('/chatter', 'std_msgs/msg/String') if kind == 'other topics'
                        else ('/pump/command', 'std_msgs/msg/String'))
    writer.add_topic(topic, type_name, '')
    payload = b'\x00\x01\x00\x00' + (6).to_bytes(4, 'little') + b'hello\x00'
    for k in range(10):
        writer.write(topic, payload, 1_000_000_000 + k)
    writer.close()


DAMAGE: list[tuple[str, Callable[[Path], None]]] = (
    [(f'a bit flipped at {f:.0%}', lambda b, f=f: _flip(b, f)) for f in (0.02, 0.3, 0.6, 0.97)]
    + [(f'truncated at {f:.0%}', lambda b, f=f: _truncate(b, f)) for f in (0.0, 0.01, 0.5, 0.99)]
    + [(f'4 KB zeroed at {f:.0%}', lambda b, f=f: _zero(b, f)) for f in (0.2, 0.7)]
    + [('no metadata.yaml', lambda b: (b / 'metadata.yaml').unlink()),
       ('metadata.yaml not YAML', lambda b: (b / 'metadata.yaml').write_text('a: [\n')),
       ('metadata.yaml a list', lambda b: (b / 'metadata.yaml').write_text('- 1\n')),
       ('metadata.yaml counts wrong', lambda b: (b / 'metadata.yaml').write_text(re.sub(
           r'message_count: \d+', 'message_count: 99999999',
           (b / 'metadata.yaml').read_text()))),
       ('no .mcap', lambda b: _mcap(b).unlink()),
       ('.mcap random bytes', lambda b: _mcap(b).write_bytes(os.urandom(5000))),
       ('.mcap text', lambda b: _mcap(b).write_text('not a bag\n' * 100)),
       ('sqlite3 bag', lambda b: (_mcap(b).unlink(), (b / 'bag_0.db3').write_bytes(
           b'SQLite format 3\x00' + bytes(1000)), (b / 'metadata.yaml').write_text(
           (b / 'metadata.yaml').read_text().replace('storage_identifier: mcap',
                                                     'storage_identifier: sqlite3')))),
       ('other topics only', lambda b: _foreign(b, 'other topics')),
       ('a rig topic of another type', lambda b: _foreign(b, 'another type'))])


def _readable(bag: Path) -> str | None:
    """Why a recovered bag is not readable by our reader and by rosbags, or None."""
    from softseq_ros.bag.reader import bag_summary, read_bag
    try:
        summary = bag_summary(bag)
        count = sum(1 for _ in read_bag(bag))
    except Exception as err:  # noqa: BLE001 - any failure to read is the finding
        return f'{type(err).__name__}: {err}'[:200]
    if not summary.complete:
        return 'the recovered bag is not complete'
    if count != summary.message_count:
        return f'{count} messages read, metadata says {summary.message_count}'
    return None


def bag_cases() -> list[Case]:
    """Damaged and foreign bags given to info, report, compare and recover."""
    cases = []
    for name, damage in DAMAGE:
        for command in ('info', 'report', 'compare', 'recover'):
            def run(bench: Workbench, damage=damage, command=command) -> Verdict:
                folder = bench.folder('bag')
                bag = _copy_bag(bench, folder)
                damage(bag)
                out = folder / 'out'
                argv = {'info': ['info', str(bag)],
                        'report': ['report', str(bag), '--out', str(out)],
                        'compare': ['compare', str(bench.good('bag')), str(bag), '--out',
                                    str(out)],
                        'recover': ['recover', str(bag)]}[command]
                outcome = bench.softseq(argv, folder)
                verdict = judge_clean(outcome, command, ('damaged_bag',))
                if verdict.held and command == 'recover' and outcome.code == 0:
                    why = _readable(bag)
                    if why is not None:
                        return broken(f'recover said it wrote a bag, but {why}')
                return verdict
            cases.append(Case('bag', f'{command}: {name}', run))
    for name, setup in (('no such folder', lambda f: f / 'nowhere'),
                        ('an empty folder', lambda f: (f / 'empty').mkdir() or f / 'empty'),
                        ('a file, not a folder', lambda f: (f / 'file').write_text('x')
                         and f / 'file')):
        for command in ('info', 'report', 'recover', 'play'):
            def run_path(bench: Workbench, setup=setup, command=command) -> Verdict:
                folder = bench.folder('bag_path')
                path = setup(folder)
                outcome = bench.softseq([command, str(path)], folder, REFUSE_TIMEOUT_S)
                return judge_refusal(outcome, command, (path.name,))
            cases.append(Case('bag', f'{command}: {name}', run_path))
    return cases


# (command, arguments with {bag}, {scene}, {folder}, {missing}; what the line must name)
CLI = [
    ('', [], ''), ('', ['bogus'], 'bogus'), ('', ['--bogus'], 'COMMAND'),
    ('solve', [], 'scene'), ('solve', ['{scene}'], '--out'),
    ('solve', ['{missing}', '--out', '{folder}/p.csv'], 'missing.yaml'),
    ('solve', ['{scene}', '--out', '{folder}/p.csv', '--bogus'], '--bogus'),
    ('solve', ['{scene}', '--path', '{missing}', '--out', '{folder}/p.csv'], 'missing'),
    ('solve', ['{scene}', '--out', '/proc/no/such/p.csv'], '/proc/no'),
    ('solve', ['{folder}', '--out', '{folder}/p.csv'], '{folder}'),
    ('classify', [], 'scene'), ('classify', ['{missing}'], 'missing.yaml'),
    ('classify', ['{folder}'], '{folder}'), ('classify', ['no_such_scene'], 'no_such_scene'),
    ('run', [], 'scene'), ('run', ['{scene}'], '--out'),
    ('run', ['{scene}', '--out', '{folder}/b', '--start-time', 'yesterday'], '--start-time'),
    ('run', ['{scene}', '--out', '{folder}/b', '--start-time', '-5'], '--start-time'),
    ('run', ['{scene}', '--out', '{folder}/b', '--start-time', 'nan'], '--start-time'),
    ('run', ['{scene}', '--out', '{bag}'], 'bag'),
    ('run', ['{scene}', '--out', '/proc/no/such/b'], '/proc/no'),
    ('report', [], 'bag'), ('report', ['{missing}'], 'missing'),
    ('report', ['{bag}', '--scene', 'no_such_scene'], 'no_such_scene'),
    ('report', ['{bag}', '--experiment', '{missing}'], 'missing'),
    ('report', ['{bag}', '--reference', '{missing}'], 'missing'),
    ('report', ['{bag}', '--namespace', '/nope'], '/nope'),
    ('report', ['{bag}', '--width', 'abc'], '--width'),
    ('report', ['{bag}', '--width', '-3'], '--width'),
    ('report', ['{bag}', '--width', 'nan'], '--width'),
    ('report', ['{bag}', '--width', '1e9'], '--width'),
    ('report', ['{bag}', '--dpi', '0'], '--dpi'),
    ('report', ['{bag}', '--dpi', 'inf'], '--dpi'),
    ('report', ['{bag}', '--dpi', '1e9'], '--dpi'),
    ('report', ['{bag}', '--style', 'ugly'], '--style'),
    ('report', ['{bag}', '--out', '/proc/no/such/r'], '/proc/no'),
    ('compare', [], 'a'), ('compare', ['{bag}'], 'b'),
    ('compare', ['{bag}', '{missing}'], 'missing'),
    ('compare', ['{bag}', '{bag}', '--namespace-a', '/nope'], '/nope'),
    ('compare', ['{bag}', '{bag}', '--scene', 'no_such_scene'], 'no_such_scene'),
    ('compare', ['{bag}', '{bag}', '--dpi', '-1', '--out', '{folder}/c'], '--dpi'),
    ('library', [], 'source'), ('library', ['{missing}'], 'missing'),
    ('library', ['{tables}', '--jobs', '0'], '--jobs'),
    ('library', ['{tables}', '--jobs', 'many'], '--jobs'),
    ('library', ['{tables}', '--length-m', 'abc'], '--length-m'),
    ('library', ['{tables}', '--length-m', '-1'], '--length-m'),
    ('library', ['{tables}', '--length-m', 'nan'], '--length-m'),
    ('library', ['{folder}'], '{folder}'),
    ('rates', [], 'scene'), ('rates', ['rate_inversion'], '--flows'),
    ('rates', ['rate_inversion', '--flows', 'a,b', '--radii', '2e-4'], '--flows'),
    ('rates', ['rate_inversion', '--flows', '1e-8', '--radii', '-2e-4'], '--radii'),
    ('rates', ['rate_inversion', '--flows', 'nan', '--radii', '2e-4'], '--flows'),
    ('rates', ['rate_inversion', '--flows', '1e-8', '--radii', '2e-4', '--samples', '0'],
     '--samples'),
    ('rates', ['rate_inversion', '--flows', '1e-8', '--radii', '2e-4', '--samples', '1e12'],
     '--samples'),
    ('rates', ['rate_inversion', '--flows', '1e-8', '--radii', '2e-4', '--workers', '0'],
     '--workers'),
    ('rates', ['fig1_none', '--flows', '1e-8', '--radii', '2e-4'], 'network'),
    ('play', [], 'bag'), ('play', ['{missing}'], 'missing'),
    ('play', ['{bag}', '--rate', '0'], '--rate'), ('play', ['{bag}', '--rate', '-1'], '--rate'),
    ('play', ['{bag}', '--rate', 'nan'], '--rate'), ('play', ['{bag}', '--rate', 'inf'], '--rate'),
    ('play', ['{bag}', '--start-offset', '-1'], '--start-offset'),
    ('play', ['{bag}', '--start-offset', 'nan'], '--start-offset'),
    ('play', ['{bag}', '--wait-for-subscribers', '-1'], '--wait-for-subscribers'),
    ('play', ['{bag}', '--remap', 'nonsense'], 'nonsense'),
    ('play', ['{bag}', '--topics', '/no/such/topic'], '/no/such/topic'),
    ('play', ['{bag}', '--qos-profile-overrides-path', '{missing}'], 'missing'),
    ('recover', [], 'bag'), ('info', [], 'bag'),
    ('fem', [], 'design'), ('fem', ['{missing}'], 'missing'),
    ('fem', ['no_such_design'], 'no_such_design'),
    ('fem', ['paper_top', '--model', 'sphere'], '--model'),
    ('fem', ['paper_top', '--workers', '0', '--sweep', 'mesh.element_size_m=1e-3,2e-3',
             '--out-dir', '{folder}/s'], '--workers'),
    ('fem', ['paper_top', '--sweep', 'no.such=1,2', '--out-dir', '{folder}/s'], 'no.such'),
    ('fem', ['paper_top', '--set', 'nonsense'], 'nonsense'),
    ('graph', [], 'scene'), ('graph', ['{missing}'], 'missing'),
    ('graph', ['fig1_none', '--reversals', '-1'], '--reversals'),
    ('graph', ['fig1_none', '--reversals', 'many'], '--reversals'),
    ('graph', ['fig1_none', '--out', '/proc/no/such/g'], '/proc/no'),
    ('scenes', ['--bogus'], '--bogus'),
    ('scatter', [], 'scene'), ('scatter', ['fig1_symmetric'], '--vary'),
    ('scatter', ['fig1_symmetric', '--vary', 'top.thickness_m=normal:2e-3,-1e-4'],
     'top.thickness_m'),
    ('scatter', ['fig1_symmetric', '--vary', 'top.thickness_m=normal:nan,1e-4'],
     'top.thickness_m'),
    ('scatter', ['fig1_symmetric', '--vary', 'top.no_such_m=normal:5%'], 'no_such_m'),
    ('scatter', ['fig1_symmetric', '--vary', 'middle.thickness_m=normal:5%'], 'middle'),
    ('scatter', ['fig1_symmetric', '--vary', 'top.thickness_m=uniform:-1e-3,3e-3'],
     'top.thickness_m'),
    ('scatter', ['fig1_symmetric', '--vary', 'top.thickness_m=normal:5%', '--spec',
                 '{missing}'], 'missing'),
    ('scatter', ['fig1_symmetric', '--vary', 'top.thickness_m=normal:5%', '--sobol', '3'],
     '--sobol'),
]


# What every option that takes a value is given, whatever it means: each must be taken or
# refused in one line, never a traceback, and never a wait without end.
BAD_OPTION_VALUES = (('nan', 'nan'), ('inf', 'inf'), ('-1', '-1'), ('0', '0'),
                     ('1e300', '1e300'), ('text', 'abc'), ('empty', ''), ('Latin-1', 'caf\xe9'))
# Words a command is given beside the option under test, so that it refuses before any work:
# a file that is not there, and for the commands that would otherwise run until stopped, a
# bound of their own (an option under test replaces its own default here).
OPTION_FILL: dict[tuple[str, ...], list[str]] = {
    ('ros', 'echo'): ['/no/such/topic', '--count', '1', '--timeout', '1'],
    ('ros', 'rig'): ['--scene', '{missing}'],
    ('ros', 'call'): ['/no/such/service', '--timeout', '1'],
    ('ros', 'param'): ['get', '/no_such_node', 'rate_hz', '--timeout', '1'],
    ('ros', 'lifecycle'): ['get', '/no_such_node', '--timeout', '1'],
}


def parser_commands() -> list[tuple[tuple[str, ...], argparse.ArgumentParser]]:
    """Every command of softseq's own parser, nested ones (``ros call``) too: (words, parser)."""
    from softseq_ros.cli import build_parser

    found = []

    def walk(words: tuple[str, ...], parser: argparse.ArgumentParser) -> None:
        commands = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        if not commands:
            found.append((words, parser))
        for action in commands:
            for name, command in action.choices.items():
                walk(words + (name,), command)
    walk((), build_parser())
    return found


def valued_options(parser: argparse.ArgumentParser) -> list[str]:
    """The options of a command that take a value, each by its long name."""
    return [max(action.option_strings, key=len) for action in parser._actions
            if action.option_strings and action.nargs != 0
            and not isinstance(action, argparse._HelpAction)]


def required_options(parser: argparse.ArgumentParser) -> list[list[str]]:
    """A command's required options, each with a value of the right form: [option, value]."""
    return [[max(action.option_strings, key=len),
             '{folder}/out' if 'out' in action.dest else '1e-8']
            for action in parser._actions if action.option_strings and action.required]


def option_cases() -> list[Case]:
    """Every option of every command that takes a value, given each of BAD_OPTION_VALUES."""
    cases = []
    for words, parser in parser_commands():
        fill = OPTION_FILL.get(words)
        if fill is None:
            fill = ['{missing}' for action in parser._actions
                    if not action.option_strings and action.nargs not in ('?', '*')]
            fill += [word for pair in required_options(parser) for word in pair]
        for option in valued_options(parser):
            for label, value in BAD_OPTION_VALUES:
                def run(bench: Workbench, words=words, fill=fill, option=option,
                        value=value) -> Verdict:
                    folder = bench.folder('option')
                    missing = str(folder / 'missing.yaml')
                    words_given = [w.format(missing=missing, folder=folder) for w in fill]
                    if option in words_given:
                        # The option under test replaces the fill's own bound.
                        at = words_given.index(option)
                        del words_given[at:at + 2]
                    outcome = bench.softseq([*words, *words_given, option, value], folder,
                                            REFUSE_TIMEOUT_S)
                    # The line names the option, the value given or the file not there.
                    names = (option, 'missing', 'no_such', '/no/such') + \
                        ((value,) if value else ())
                    return judge_refusal(outcome, ' '.join(words), names)
                cases.append(Case('option', f'{" ".join(words)} {option} {label}', run))
    return cases


def cli_cases() -> list[Case]:
    """Every subcommand with missing, unknown or bad arguments."""
    cases = []
    for command, arguments, names in CLI:
        def run(bench: Workbench, command=command, arguments=arguments,
                names=names) -> Verdict:
            folder = bench.folder('cli')
            tables = folder / 'tables'
            tables.mkdir()
            shutil.copy(_config('segments') / 'paper_top.csv', tables / 'top.csv')
            fill = {'bag': str(bench.good('bag')), 'scene': str(bench.good('scene')),
                    'folder': str(folder), 'missing': str(folder / 'missing.yaml'),
                    'tables': str(tables)}
            argv = ([command] if command else []) + [a.format(**fill) for a in arguments]
            outcome = bench.softseq(argv, folder, REFUSE_TIMEOUT_S)
            return judge_refusal(outcome, command, (names.format(**fill),))
        label = ' '.join([command or 'softseq'] + arguments) or 'softseq'
        cases.append(Case('cli', label, run))
    return cases


# ------------------------------------------------------------------------------ file inputs

# Every file a command reads, as its parser names it: (command words, argument) -> (kind, the
# command line with {file} where the file goes). A kind says what a good file of it holds and
# which damages apply: 'scene' (a scene file or a shipped name), 'yaml', 'csv', 'bag' (a bag
# folder: the folder itself, its metadata.yaml and its .mcap each get the battery).
FILE_INPUTS: dict[tuple[str, str], tuple[str, list[str]]] = {
    ('solve', 'scene'): ('scene', ['solve', '{file}', '--out', '{folder}/p.csv']),
    ('solve', '--path'): ('csv', ['solve', '{scene}', '--path', '{file}',
                                  '--out', '{folder}/p.csv']),
    ('solve', '--pressure-path'): ('csv', ['solve', '{scene}', '--pressure-path', '{file}',
                                           '--out', '{folder}/p.csv']),
    ('classify', 'scene'): ('scene', ['classify', '{file}']),
    ('run', 'scene'): ('scene', ['run', '{file}', '--out', '{folder}/b', '--quiet',
                                 '--no-report', '--start-time', '0']),
    ('report', 'bag'): ('bag', ['report', '{file}', '--out', '{folder}/r']),
    ('report', '--scene'): ('scene', ['report', '{bag}', '--scene', '{file}',
                                      '--out', '{folder}/r']),
    ('report', '--experiment'): ('csv', ['report', '{bag}', '--experiment', '{file}',
                                         '--out', '{folder}/r']),
    ('report', '--reference'): ('yaml', ['report', '{bag}', '--reference', '{file}',
                                         '--out', '{folder}/r']),
    ('compare', 'a'): ('bag', ['compare', '{file}', '{bag}', '--out', '{folder}/c']),
    ('compare', 'b'): ('bag', ['compare', '{bag}', '{file}', '--out', '{folder}/c']),
    ('compare', '--scene'): ('scene', ['compare', '{bag}', '{bag}', '--scene', '{file}',
                                       '--out', '{folder}/c']),
    ('library', 'source'): ('scene', ['library', '{file}', '--out', '{folder}/l']),
    ('rates', 'scene'): ('scene', ['rates', '{file}', '--flows', '1e-8', '--radii', '2e-4',
                                   '--samples', '50', '--workers', '1', '--out', '{folder}/r']),
    ('fit', 'inputs'): ('csv', ['fit', '{file}', '--bootstrap', '0', '--out', '{folder}/f']),
    ('scatter', 'scene'): ('scene', ['scatter', '{file}', '--vary', 'top.thickness_m=normal:5%',
                                     '--samples', '10', '--sobol', '0', '--workers', '1',
                                     '--quiet', '--out', '{folder}/s']),
    ('scatter', '--spec'): ('yaml', ['scatter', 'fig1_symmetric', '--spec', '{file}',
                                     '--samples', '10', '--sobol', '0', '--workers', '1',
                                     '--quiet', '--out', '{folder}/s']),
    ('play', 'bag'): ('bag', ['play', '{file}', '--rate', '100']),
    ('play', '--qos-profile-overrides-path'): ('yaml', ['play', '{bag}', '--rate', '100',
                                                        '--qos-profile-overrides-path',
                                                        '{file}']),
    ('recover', 'bag'): ('bag', ['recover', '{file}']),
    ('info', 'bag'): ('bag', ['info', '{file}']),
    ('fem', 'design'): ('yaml', ['fem', '{file}', '--out', '{folder}/t.csv', '--quiet',
                                 '--cache-dir', '{folder}/cache']),
    ('design', 'problem'): ('yaml', ['design', '{file}', '--out', '{folder}/d', '--quiet',
                                     '--workers', '1', '--cache-dir', '{folder}/cache']),
    ('graph', 'scene'): ('scene', ['graph', '{file}', '--out', '{folder}/g']),
    ('ros rig', '--params-file'): ('yaml', ['ros', 'rig', '--namespace', '/adversarial_file',
                                            '--scene', '{scene}', '--params-file', '{file}',
                                            '--record', '{folder}/b']),
    ('ros rig', '--scene'): ('scene', ['ros', 'rig', '--namespace', '/adversarial_file',
                                       '--scene', '{file}', '--record', '{folder}/b']),
}
# Arguments the parser's words make look like files that no command reads, and why.
NOT_FILE_INPUTS: dict[tuple[str, str], str] = {
    **{(command, '--out'): 'written, not read' for command in (
        'solve', 'run', 'report', 'compare', 'library', 'rates', 'fit', 'scatter', 'fem',
        'design', 'graph')},
    ('fem', '--out-dir'): 'a folder written, not read',
    ('fem', '--cache-dir'): 'a folder of tables it writes, read back only by their hashes',
    ('design', '--cache-dir'): 'a folder of tables it writes, read back only by their hashes',
    ('ros rig', '--record'): 'a bag folder written, not read',
    ('ros rig', '--namespace'): 'a ROS namespace (its help names the launch file)',
}
FILE_TIMEOUT_S = 20.0
SIGNAL_AFTER_S = 2.5        # the command has parsed its arguments and reached the file by then
HUGE_LINE_BYTES = 8 << 20
DEEP = 100_000


def file_arguments(parser: argparse.ArgumentParser) -> list[str]:
    """The arguments of a command that name a file or a folder: Path-typed, or said so."""
    found = []
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        kind = getattr(action.type, '__qualname__', '')
        if (action.type is Path or kind.startswith('_given') or action.dest == 'scene'
                or re.search(r'\b(file|folder|directory)\b', action.help or '', re.I)):
            found.append(max(action.option_strings, key=len) if action.option_strings
                         else action.dest)
    return found


GOOD_FILES = {'--reference': ('reference', 'milana2018.yaml'),
              'design': ('designs', 'paper_top.yaml'),
              'problem': ('design_targets', 'tiny.yaml'),
              '--params-file': ('params', 'params_example.yaml')}
GOOD_TEXTS = {'--path': 'injected_m3\n0\n1.0e-6\n2.0e-6\n',
              '--pressure-path': 'gauge_pa\n0\n1000\n2000\n',
              '--spec': 'vary:\n  top.thickness_m: normal:5%\n',
              '--qos-profile-overrides-path': '/pump/status:\n  depth: 10\n'}


def _good_text(kind: str, argument: str) -> str:
    """A good file of ``kind`` for ``argument``: the base a damage starts from."""
    if kind == 'scene':
        return _yaml(_read_yaml(_config('fig1_none.yaml')))
    if argument == '--experiment':
        return _experiment_text()
    if argument == 'inputs':
        return _top_table_text()
    if argument in GOOD_FILES:
        folder, name = GOOD_FILES[argument]
        return (_config(folder) / name).read_text(encoding='utf-8')
    return GOOD_TEXTS[argument]


def _fifo(path: Path) -> None:
    os.mkfifo(path)


# The battery: (label, what it makes at a path from a good text, whether it must be refused).
# 'must' damages leave nothing a command can read; the others may be taken if taken cleanly.
FILE_DAMAGES: list[tuple[str, Callable[[Path, bytes], None], bool]] = [
    ('a FIFO nobody writes', lambda p, good: _fifo(p), True),
    ('unreadable (mode 000)', lambda p, good: (p.write_bytes(good), p.chmod(0)), True),
    ('a folder', lambda p, good: p.mkdir(), True),
    ('Latin-1', lambda p, good: p.write_bytes(b'# Pr\xfcfstand caf\xe9\n' + good), False),
    ('empty', lambda p, good: p.write_bytes(b''), False),
    ('nested 100000 deep', lambda p, good: p.write_bytes(b'[' * DEEP + b']' * DEEP), False),
    ('one huge line', lambda p, good: p.write_bytes(b'a' * HUGE_LINE_BYTES), False),
]
TEXT_ONLY = {'Latin-1', 'nested 100000 deep'}
YAML_ONLY = {'nested 100000 deep'}
FILE_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def _is_root() -> bool:
    return hasattr(os, 'geteuid') and os.geteuid() == 0


def _targets(kind: str) -> list[tuple[str, str]]:
    """What of an input of ``kind`` gets the battery: (where, its text kind)."""
    if kind == 'bag':
        return [('the bag folder', 'folder'), ('metadata.yaml', 'metadata'),
                ('the .mcap', 'mcap')]
    return [('', 'csv' if kind == 'csv' else 'yaml')]


def _damages_for(text_kind: str) -> list[tuple[str, Callable[[Path, bytes], None], bool]]:
    found = []
    for label, make, must in FILE_DAMAGES:
        if label in YAML_ONLY and text_kind not in ('yaml', 'metadata'):
            continue
        if label in TEXT_ONLY and text_kind not in ('yaml', 'csv', 'metadata'):
            continue
        if text_kind == 'metadata':
            # A bag whose metadata.yaml is no file is read from its .mcap, as a recording
            # killed before it wrote one: taken cleanly, or refused in one line.
            must = False
        if text_kind == 'folder' and label == 'a folder':
            label, make = 'a file', lambda p, good: p.write_bytes(b'not a bag\n')
        if text_kind == 'folder' and label not in ('a FIFO nobody writes',
                                                   'unreadable (mode 000)', 'a file'):
            continue
        found.append((label, make, must))
    return found


def file_case_names(words: tuple[str, ...], argument: str) -> list[str]:
    """The names of the cases of one file argument (the registry test checks them)."""
    kind, _ = FILE_INPUTS[(' '.join(words), argument)]
    names = []
    for where, text_kind in _targets(kind):
        head = f'{" ".join(words)} {argument}' + (f' ({where})' if where else '')
        names += [f'{head}: {label}' for label, _, _ in _damages_for(text_kind)]
        names += [f'{head}: {signal.Signals(s).name} while it waits on a FIFO'
                  for s in FILE_SIGNALS]
    return names


def _place(bench: Workbench, folder: Path, kind: str, where: str, argument: str
           ) -> tuple[Path, Path, bytes]:
    """Where the damaged file goes, the path given to the command, the good bytes there."""
    if kind != 'bag':
        suffix = '.csv' if kind == 'csv' else '.yaml'
        path = folder / f'input_file{suffix}'
        return path, path, _good_text(kind, argument).encode()
    bag = folder / 'input_bag'
    shutil.copytree(bench.good('bag'), bag)
    if where == 'the bag folder':
        shutil.rmtree(bag)
        return bag, bag, b''
    target = bag / 'metadata.yaml' if where == 'metadata.yaml' else _mcap(bag)
    good = target.read_bytes()
    target.unlink()
    return target, bag, good


def _judge_signal(outcome: Outcome, command: str, names: tuple[str, ...],
                  signum: int, must: bool) -> Verdict:
    """Refused before the signal came, or ended by it with 128 + signal, quietly."""
    if outcome.code == 0 and not must:
        return judge_clean(outcome, command, names)
    if outcome.code == 2:
        return judge_refusal(outcome, command, names)
    expected = 128 + signum
    if outcome.code != expected:
        return broken(f'exit {outcome.code}, not 2 (refused) or {expected} (the signal)'
                      + (f': {_lines(outcome.stderr)[-1][:160]!r}' if outcome.stderr.strip()
                         else ''))
    if 'Traceback' in outcome.stderr:
        return broken('a traceback')
    if len(_lines(outcome.stderr)) > 1:
        return broken(f'{len(_lines(outcome.stderr))} lines on stderr')
    return HELD


def file_cases() -> list[Case]:
    """Every file every command reads: a FIFO, unreadable, a folder, Latin-1, empty, ..."""
    cases = []
    for words, parser in parser_commands():
        command = ' '.join(words)
        for argument in file_arguments(parser):
            if (command, argument) not in FILE_INPUTS:
                continue
            kind, template = FILE_INPUTS[(command, argument)]
            for where, text_kind in _targets(kind):
                head = f'{command} {argument}' + (f' ({where})' if where else '')
                tries: list[tuple[str, Callable[[Path, bytes], None], bool, int]] = [
                    (label, make, must, 0) for label, make, must in _damages_for(text_kind)]
                tries += [(f'{signal.Signals(s).name} while it waits on a FIFO',
                           lambda p, good: _fifo(p), text_kind != 'metadata', s)
                          for s in FILE_SIGNALS]
                for label, make, must, signum in tries:
                    def run(bench: Workbench, kind=kind, template=template, where=where,
                            argument=argument, command=command, label=label, make=make,
                            must=must, signum=signum) -> Verdict:
                        if label.startswith('unreadable') and _is_root():
                            # Not counted as held: nothing was tried.
                            return not_tried('running as root, who reads a file of mode 000 '
                                             'all the same')
                        folder = bench.folder('file')
                        target, given, good = _place(bench, folder, kind, where, argument)
                        make(target, good)
                        fill = {'file': str(given), 'folder': str(folder),
                                'scene': str(bench.good('scene')), 'bag': '{bag}'}
                        argv = [w.format(**fill) for w in template]
                        if '{bag}' in argv:
                            argv = [str(bench.good('bag')) if w == '{bag}' else w
                                    for w in argv]
                        names = (target.name, given.name, argument)
                        try:
                            outcome = bench.softseq(argv, folder, FILE_TIMEOUT_S,
                                                    signum=signum, after=SIGNAL_AFTER_S)
                        finally:
                            if target.exists() and not target.is_symlink():
                                target.chmod(0o700 if target.is_dir() else 0o600)
                        if signum:
                            return _judge_signal(outcome, command, names, signum, must)
                        if must:
                            return judge_refusal(outcome, command, names)
                        return judge_clean(outcome, command, names)
                    unreadable = label.startswith('unreadable')
                    cases.append(Case('file', f'{head}: {label}', run,
                                      (lambda: not _is_root()) if unreadable
                                      else (lambda: True)))
    return cases


# ------------------------------------------------------------------------------ nodes in-process

class Ros:
    """One rclpy context for the in-process node cases (rclpy is imported only here)."""

    def __init__(self, domain_id: int) -> None:
        os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
        prefixes = [p for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
        if sys.prefix not in prefixes:
            os.environ['AMENT_PREFIX_PATH'] = os.pathsep.join([sys.prefix, *prefixes])
        import rclpy
        self.rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context, args=[], domain_id=domain_id)

    def close(self) -> None:
        self.rclpy.try_shutdown(context=self.context)


def _node_classes() -> dict[str, Any]:
    from softseq_ros.nodes.actuator import ActuatorNode
    from softseq_ros.nodes.camera import CameraNode
    from softseq_ros.nodes.pressure_hold import PressureHoldNode
    from softseq_ros.nodes.recorder import Recorder
    from softseq_ros.nodes.sim_clock import SimClockNode
    from softseq_ros.nodes.syringe_pump import SyringePumpNode
    return {'syringe_pump': SyringePumpNode, 'actuator': ActuatorNode, 'camera': CameraNode,
            'sim_clock': SimClockNode, 'recorder': Recorder, 'pressure_hold': PressureHoldNode,
            # The pump node driving a regulator: its parameters follow from its scene.
            REGULATOR_PUMP: SyringePumpNode}


# The pump node on a scene behind a pressure regulator (docs/supply.md), by this name here.
REGULATOR_PUMP = 'syringe_pump (regulator)'
# Parameters a node class is declared with before its own, for the nodes whose parameters
# depend on them.
DECLARED_WITH = {REGULATOR_PUMP: {'scene': 'fig1_regulator_quasistatic'}}


# Executables whose nodes the node_parameter class does not build, and why (a test holds
# every executable of setup.py to a node class above or a reason here).
NODES_TRIED_ELSEWHERE = {
    'managed_syringe_pump': 'the syringe pump class declares its parameters (tried above); its '
                            "lifecycle and services are the service class's",
    'rig': 'the pump, actuator and camera in one process: each node class is tried above',
}


def _base_overrides(node: str, folder: Path) -> dict[str, Any]:
    return {'syringe_pump': {'scene': 'fig1_none', 'autostart': False},
            REGULATOR_PUMP: {'scene': 'fig1_regulator_quasistatic', 'autostart': False},
            'actuator': {'scene': 'fig1_none', 'state_file': '', 'resume_timeout_s': 0.0},
            'camera': {'scene': 'fig1_none'},
            'sim_clock': {},
            'recorder': {'output': str(folder / 'bag')},
            'pressure_hold': {'take_over': False}}[node]


# Bad values by the kind of a parameter's default: (label, value, must it be refused).
NUMBER_VALUES = [('text', 'abc', True), ('nan', math.nan, True), ('inf', math.inf, True),
                 ('-inf', -math.inf, True), ('bool', True, True), ('list', [1.0], True),
                 ('1e300', 1.0e300, False), ('-1e300', -1.0e300, False)]
INTEGER_VALUES = [('text', 'abc', True), ('1.5', 1.5, True), ('bool', True, True),
                  ('-1e9', -10 ** 9, False), ('2^62', 2 ** 62, False)]
TEXT_VALUES = [('number', 5, True), ('list', ['a'], True), ('empty', '', False),
               ('100 kB', 'x' * 100_000, False)]
FLAG_VALUES = [('text', 'maybe', True), ('number', 5, True)]
TEXTS_VALUES = [('numbers', [1, 2], True), ('text', 'a', True), ('empty', [], False)]
NUMBERS_VALUES = [('texts', ['a'], True), ('nan', [math.nan], True), ('text', 'x', True),
                  ('1e300', [1.0e300], False)]


def _values_for(default: Any) -> list[tuple[str, Any, bool]]:
    if isinstance(default, bool):
        return FLAG_VALUES
    if isinstance(default, int):
        return INTEGER_VALUES
    if isinstance(default, float):
        return NUMBER_VALUES
    if isinstance(default, str):
        return TEXT_VALUES
    if isinstance(default, (list, tuple)):
        return NUMBERS_VALUES if default and isinstance(default[0], (int, float)) \
            else TEXTS_VALUES
    return TEXT_VALUES


def _parameters_of(node: str) -> list[tuple[str, Any, bool]]:
    from softseq_ros.nodes.runner import declared_parameters
    found = [(name, default, descriptor.read_only)
             for name, default, descriptor in declared_parameters(
                 _node_classes()[node], DECLARED_WITH.get(node))]
    return found + [('use_sim_time', False, False)]


def _build(bench: Workbench, node: str, folder: Path, **overrides: Any) -> Any:
    from rclpy.parameter import Parameter
    values = {**_base_overrides(node, folder), **overrides}
    return _node_classes()[node](context=bench.ros.context, parameter_overrides=[
        Parameter(name, value=value) for name, value in values.items()])


def node_parameter_cases() -> list[Case]:
    """Every parameter of every node, at start and at run time, given values it cannot take."""
    cases = []
    for node in _node_classes():
        for name, default, read_only in _parameters_of(node):
            for label, value, must_refuse in _values_for(default):
                def at_start(bench: Workbench, node=node, name=name, value=value,
                             must_refuse=must_refuse) -> Verdict:
                    return _judge_start(bench, node, name, value, must_refuse)
                cases.append(Case('node_parameter', f'{node} {name}: {label} at start',
                                  at_start))
                if read_only or name == 'scene':
                    continue

                def at_run_time(bench: Workbench, node=node, name=name, value=value,
                                must_refuse=must_refuse) -> Verdict:
                    return _judge_run_time(bench, node, name, value, must_refuse)
                cases.append(Case('node_parameter', f'{node} {name}: {label} at run time',
                                  at_run_time))
    return cases


def _judge_start(bench: Workbench, node: str, name: str, value: Any,
                 must_refuse: bool) -> Verdict:
    from softseq_ros.bag.writer import BagWriterError
    from softseq_ros.nodes.parameters import NodeConfigError
    from softseq_ros.rig.build import SettingError
    from softseq_ros.scene.loader import SceneError
    folder = bench.folder('node')
    try:
        built = _build(bench, node, folder, **{name: value})
    except (NodeConfigError, SceneError, SettingError, BagWriterError) as err:
        text = str(err)
        if '\n' in text.strip():
            return broken(f'{len(text.splitlines())} lines: {text[:160]!r}')
        if name not in text:
            return broken(f'does not name {name}: {text[:200]!r}')
        return HELD
    except Exception as err:  # noqa: BLE001 - anything else escapes as a traceback
        return broken(f'{type(err).__name__}: {str(err)[:200]}')
    _destroy(built)
    return broken('accepted') if must_refuse else HELD


def _judge_run_time(bench: Workbench, node: str, name: str, value: Any,
                    must_refuse: bool) -> Verdict:
    from rclpy.parameter import Parameter
    built = _build(bench, node, bench.folder('node'))
    try:
        before = built.get_parameter(name).value
        try:
            (result,) = built.set_parameters([Parameter(name, value=value)])
        except Exception as err:  # noqa: BLE001 - a set_parameters that raises breaks it
            return broken(f'{type(err).__name__}: {str(err)[:200]}')
        if result.successful:
            return broken('accepted') if must_refuse else HELD
        if not result.reason.startswith(f'{name}: '):
            return broken(f'reason not ours: {result.reason[:200]!r}')
        if built.get_parameter(name).value != before and not (
                isinstance(before, float) and math.isnan(before)):
            return broken('refused, but the value changed')
        return HELD
    finally:
        _destroy(built)


def _destroy(node: Any) -> None:
    close = getattr(node, 'close_bag', None)
    if close is not None:
        close(log=False)
    node.destroy_node()


# ------------------------------------------------------------------------------ services

# rclpy's own parameter services: the node_parameter class tries what they carry.
PARAMETER_SERVICES = ('describe_parameters', 'get_parameter_types', 'get_parameters',
                      'get_type_description', 'list_parameters', 'set_parameters',
                      'set_parameters_atomically')
# States of the syringe pump a service may find it in: reached from a fresh, idle pump by these
# service calls (the answers need not succeed: a state is what the calls leave).
PUMP_STATES = {'idle': (), 'running': ('start',), 'held': ('start', 'hold'),
               'stopped': ('start', 'stop'), 'setpoint': ('start', ('setpoint_mode', True)),
               'reset': ('start', 'stop', 'reset')}
# The transitions each primary state of a managed node has (the ROS 2 managed-node design);
# every other id, 0 to 11 and two beyond, must be refused with the node living on.
LIFECYCLE_PATH = (('unconfigured', 1), ('inactive', 3), ('active', 7), ('finalized', None))
LIFECYCLE_ALLOWED = {'unconfigured': {1, 5}, 'inactive': {2, 3, 6}, 'active': {4, 7},
                     'finalized': set()}
LIFECYCLE_IDS = tuple(range(12)) + (99, 255)
SERVICE_TIMEOUT_S = 20.0


def node_services(node: str, bench: Workbench) -> list[tuple[str, Any]]:
    """A node's own services (name after the node's, type), read from a node built here."""
    built = _build(bench, node, bench.folder('services'))
    try:
        found = []
        for service in built.services:
            name = service.srv_name.rsplit('/', 1)[-1]
            if name not in PARAMETER_SERVICES:
                found.append((name, service.srv_type))
        return sorted(found, key=lambda item: item[0])
    finally:
        _destroy(built)


def _requests(srv_type: Any) -> list[tuple[str, Any]]:
    """The requests a service is given: its default, then each bool field both ways."""
    made = [('default request', srv_type.Request())]
    for field_name, kind in srv_type.Request.get_fields_and_field_types().items():
        if kind == 'boolean':
            for value in (True, False):
                request = srv_type.Request()
                setattr(request, field_name, value)
                made.append((f'{field_name}={value}', request))
    return made


def _call(client_node: Any, srv_type: Any, service: str, request: Any) -> Any:
    from softseq_ros.testing import wait_for
    client = client_node.create_client(srv_type, service)
    if not client.wait_for_service(timeout_sec=SERVICE_TIMEOUT_S):
        raise TimeoutError(f'{service} never came up')
    future = client.call_async(request)
    wait_for(future.done, f'the answer of {service}', SERVICE_TIMEOUT_S)
    return future.result()


def _trigger_path(client_node: Any, target: str, steps: tuple) -> None:
    from std_srvs.srv import SetBool, Trigger
    for step in steps:
        if isinstance(step, tuple):
            _call(client_node, SetBool, f'{target}/{step[0]}', SetBool.Request(data=step[1]))
        else:
            _call(client_node, Trigger, f'{target}/{step}', Trigger.Request())


def service_cases() -> list[Case]:
    """
    Every service of every node, in every state the node can be in, and every lifecycle
    transition from every state of the managed pump: an answer, and the node lives on.
    """
    cases = []
    for node, pump_states in (('syringe_pump', PUMP_STATES),):
        for state, path in pump_states.items():
            def run(bench: Workbench, node=node, state=state, path=path) -> Verdict:
                return _judge_services(bench, node, path)
            cases.append(Case('service', f'{node} in state {state}: every service, every '
                                         'request', run))
    for state, transitions in (('inactive', (1,)), ('active', (1, 3))):
        for pump_state, path in PUMP_STATES.items():
            def run_managed(bench: Workbench, transitions=transitions, path=path) -> Verdict:
                return _judge_services(bench, 'syringe_pump', path, transitions)
            cases.append(Case('service', f'managed_syringe_pump {state}, pump {pump_state}: '
                                         'every service, every request', run_managed))
    for node in _node_classes():
        if node == 'syringe_pump':
            continue

        def run_other(bench: Workbench, node=node) -> Verdict:
            return _judge_services(bench, node, ())
        cases.append(Case('service', f'{node}: every service, every request', run_other))
    for state, _ in LIFECYCLE_PATH:
        for transition in LIFECYCLE_IDS:
            def run_transition(bench: Workbench, state=state,
                               transition=transition) -> Verdict:
                return _judge_transition(bench, state, transition)
            cases.append(Case('service', f'managed_syringe_pump in state {state}: transition '
                                         f'{transition}', run_transition))
    return cases


def _judge_services(bench: Workbench, node: str, path: tuple,
                    transitions: tuple[int, ...] | None = None) -> Verdict:
    """
    Each service of a fresh ``node`` (brought along ``path`` first) called with each request.

    ``transitions``: the node is the managed pump instead, taken through these lifecycle
    transitions before the path.
    """
    from lifecycle_msgs.srv import ChangeState
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from softseq_ros.nodes.managed_syringe_pump import ManagedSyringePumpNode
    from softseq_ros.testing import spinning
    services = node_services(node, bench)
    for name, srv_type in services:
        for label, request in _requests(srv_type):
            if transitions is None:
                built = _build(bench, node, bench.folder('services'))
            else:
                built = ManagedSyringePumpNode(context=bench.ros.context, parameter_overrides=[
                    Parameter(key, value=value) for key, value in
                    _base_overrides(node, bench.folder('services')).items()])
            target = built.get_fully_qualified_name()
            client = Node('service_client', context=bench.ros.context)
            try:
                with spinning(bench.ros.context, built, client):
                    for transition in transitions or ():
                        change = ChangeState.Request()
                        change.transition.id = transition
                        if not _call(client, ChangeState, f'{target}/change_state',
                                     change).success:
                            return broken(f'lifecycle transition {transition} refused')
                    _trigger_path(client, target, path)
                    answer = _call(client, srv_type, f'{target}/{name}', request)
                    if hasattr(answer, 'success') and not answer.success \
                            and not getattr(answer, 'message', 'x'):
                        return broken(f'{name} ({label}): refused without saying why')
                    # The node lives on: it answers the same call again.
                    _call(client, srv_type, f'{target}/{name}', request)
            except Exception as err:  # noqa: BLE001 - a dead executor or no answer breaks it
                return broken(f'{name} ({label}): {type(err).__name__}: {str(err)[:160]}')
    return HELD


def _judge_transition(bench: Workbench, state: str, transition: int) -> Verdict:
    """A fresh managed pump brought to ``state``, then sent ``transition``."""
    from lifecycle_msgs.srv import ChangeState, GetState
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from softseq_ros.nodes.managed_syringe_pump import ManagedSyringePumpNode
    from softseq_ros.testing import spinning
    pump = ManagedSyringePumpNode(context=bench.ros.context, parameter_overrides=[
        Parameter('scene', value='fig1_none'), Parameter('autostart', value=False),
        Parameter('open_loop', value=True)])
    client = Node('lifecycle_client', context=bench.ros.context)
    target = pump.get_fully_qualified_name()

    def change(transition_id: int) -> bool:
        request = ChangeState.Request()
        request.transition.id = transition_id
        return _call(client, ChangeState, f'{target}/change_state', request).success

    def current() -> str:
        return _call(client, GetState, f'{target}/get_state',
                     GetState.Request()).current_state.label
    try:
        with spinning(bench.ros.context, pump, client):
            for reached, onwards in LIFECYCLE_PATH:
                if reached == state:
                    break
                if not change(onwards):
                    return broken(f'could not reach {state}: {reached} refused {onwards}')
            if current() != state:
                return broken(f'expected state {state}, the node says {current()}')
            allowed = transition in LIFECYCLE_ALLOWED[state]
            done = change(transition)
            after = current()
            if done != allowed:
                return broken(f'transition {transition} from {state}: '
                              f'{"taken" if done else "refused"}, the design says otherwise')
            if not allowed and after != state:
                return broken(f'refused, but the state went from {state} to {after}')
    except Exception as err:  # noqa: BLE001 - a dead executor or no answer breaks it
        return broken(f'{type(err).__name__}: {str(err)[:200]}')
    return HELD


# ------------------------------------------------------------------------------ topics

@dataclass
class TopicRig:
    """An actuator, a pump and a camera, each in its own namespace, and a node feeding them."""

    actuator: Any
    pump: Any
    camera: Any
    feeder: Any
    publishers: dict[str, Any]
    answers: list
    pump_commands: list
    spinning: Any
    tracker: Any
    good_volume: list


def _topic_rig(bench: Workbench) -> TopicRig:
    if 'topic_rig' in bench.made:
        return bench.made['topic_rig']
    from rclpy.node import Node
    from sensor_msgs.msg import JointState

    from softseq_ros.nodes.core_node import qos_profile
    from softseq_ros.quasistatic.equilibrium import EquilibriumMap, Tracker
    from softseq_ros.scene.loader import load_scene
    from softseq_ros.testing import Collector, call_trigger, spinning, wait_for
    from softseq_ros.wire import contract
    context = bench.ros.context
    folder = bench.folder('topics')

    def node(kind: str, namespace: str, **overrides: Any) -> Any:
        from rclpy.parameter import Parameter
        values = {**_base_overrides(kind, folder), **overrides}
        return _node_classes()[kind](
            context=context, cli_args=['--ros-args', '-r', f'__ns:={namespace}'],
            parameter_overrides=[Parameter(n, value=v) for n, v in values.items()])
    actuator = node('actuator', '/a')
    pump = node('syringe_pump', '/p', feedback_timeout_s=3600.0)
    camera = node('camera', '/c', frame_trigger='state')
    feeder = Node('feeder', context=context)
    publishers = {
        '/a/pump/command': feeder.create_publisher(
            JointState, '/a/pump/command', qos_profile(contract.PUMP_COMMAND.qos)),
        '/p/actuator/volumes': feeder.create_publisher(
            JointState, '/p/actuator/volumes', qos_profile(contract.VOLUMES.qos)),
        '/c/actuator/volumes': feeder.create_publisher(
            JointState, '/c/actuator/volumes', qos_profile(contract.VOLUMES.qos)),
        '/c/actuator/curvatures': feeder.create_publisher(
            JointState, '/c/actuator/curvatures', qos_profile(contract.CURVATURES.qos))}
    collector = Collector(['actuator/volumes'], context, namespace='/a', name='answers')
    pump_commands = collector.add('/p/pump/command', JointState,
                                  qos_profile(contract.PUMP_COMMAND.qos))
    block = spinning(context, actuator, pump, camera, feeder, collector)
    block.__enter__()
    wait_for(lambda: all(p.get_subscription_count() > 0 for p in publishers.values())
             and collector.matched('/a/actuator/volumes'), 'the nodes under test', 60.0)
    assert call_trigger(feeder, '/p/syringe_pump/start').success
    scene = load_scene('fig1_none')
    rig = TopicRig(actuator, pump, camera, feeder, publishers,
                   collector.messages('/a/actuator/volumes'), pump_commands, block,
                   Tracker(EquilibriumMap(scene.segments)), [0.0])
    bench.made['topic_rig'] = rig
    return rig


def _joint_state(stamp_ns: int, names: list[str], position: list[float],
                 effort: list[float] | None = None, velocity: list[float] | None = None) -> Any:
    from sensor_msgs.msg import JointState
    msg = JointState(name=names, position=position, effort=effort or [],
                     velocity=velocity or [])
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
    return msg


SEGMENTS = ['bottom', 'top']
# Garbage commands for the actuator: (label, names, positions, velocity).
COMMANDS = [('NaN volume', ['syringe'], [math.nan], []),
            ('inf volume', ['syringe'], [math.inf], []),
            ('negative volume', ['syringe'], [-1.0e-6], []),
            ('beyond the segments', ['syringe'], [1.0], []),
            ('1e300', ['syringe'], [1.0e300], []),
            ('no joint', [], [], []),
            ('two joints', ['syringe', 'syringe'], [1e-6, 2e-6], []),
            ('other joint', ['plunger'], [1.0e-6], []),
            ('no position', ['syringe'], [], []),
            ('100000 joints', ['syringe'] * 100_000, [1.0e-6] * 100_000, [])]
# Garbage answers for the pump and states for the camera: (label, names, volumes, pressures).
STATES = [('NaN volume', SEGMENTS, [math.nan, 1e-5], [100.0, 100.0]),
          ('inf volume', SEGMENTS, [math.inf, 1e-5], [100.0, 100.0]),
          ('negative volume', SEGMENTS, [-1e-6, 1e-5], [100.0, 100.0]),
          ('NaN pressure', SEGMENTS, [1e-5, 1e-5], [math.nan, math.nan]),
          ('pressure below vacuum', SEGMENTS, [1e-5, 1e-5], [-2e5, -2e5]),
          ('+inf pressure', SEGMENTS, [1e-5, 1e-5], [math.inf, math.inf]),
          ('other joint names', ['a', 'b'], [1e-5, 1e-5], [100.0, 100.0]),
          ('one joint of two', ['bottom'], [1e-5], [100.0]),
          ('volumes of the wrong length', SEGMENTS, [1e-5], [100.0, 100.0]),
          ('no pressure', SEGMENTS, [1e-5, 1e-5], []),
          ('100000 joints', SEGMENTS * 50_000, [1e-5] * 100_000, [1.0] * 100_000)]
CURVATURES = [('NaN curvature', SEGMENTS, [math.nan, 1.0]),
              ('inf curvature', SEGMENTS, [math.inf, 1.0]),
              ('wrong length', SEGMENTS, [1.0]),
              ('other joint names', ['a', 'b'], [1.0, 1.0]),
              ('none', [], [])]


def topic_cases() -> list[Case]:
    """Garbage on every topic a node subscribes to, while it runs."""
    cases = []
    for label, names, positions, velocity in COMMANDS:
        def run(bench: Workbench, names=names, positions=positions,
                velocity=velocity) -> Verdict:
            return _judge_actuator(bench, _joint_state(time.time_ns(), names, positions,
                                                       velocity=velocity))
        cases.append(Case('topic', f'actuator pump/command: {label}', run))
    for label, names, volumes, pressures in STATES:
        def run_pump(bench: Workbench, names=names, volumes=volumes, pressures=pressures,
                     label=label) -> Verdict:
            return _judge_pump(bench, names, volumes, pressures, label.startswith('+inf'))
        cases.append(Case('topic', f'pump actuator/volumes: {label}', run_pump))

        # The camera reads the volumes only (for its trigger crossings): a pressure it does
        # not use may be anything, a volume it uses may not.
        uses = 'pressure' not in label

        def run_camera(bench: Workbench, names=names, volumes=volumes,
                       pressures=pressures, uses=uses) -> Verdict:
            return _judge_camera(bench, '/c/actuator/volumes',
                                 _joint_state(time.time_ns(), names, volumes, pressures), uses)
        cases.append(Case('topic', f'camera actuator/volumes: {label}', run_camera))
    for label, names, values in CURVATURES:
        def run_curvatures(bench: Workbench, names=names, values=values) -> Verdict:
            return _judge_camera(bench, '/c/actuator/curvatures',
                                 _joint_state(time.time_ns(), names, values))
        cases.append(Case('topic', f'camera actuator/curvatures: {label}', run_curvatures))
    return cases


def _spin_failure(rig: TopicRig) -> str | None:
    """An exception the executor thread met (a callback that raised), if any."""
    thread_alive = any(t.name == 'softseq-testing-spin' and t.is_alive()
                       for t in __import__('threading').enumerate())
    return None if thread_alive else 'the executor thread died (a callback raised)'


def _judge_actuator(bench: Workbench, garbage: Any) -> Verdict:
    from softseq_ros.testing import stamp_ns, wait_for
    rig = _topic_rig(bench)
    node = rig.actuator
    before = node.core.rejected_commands + node.refusals
    rig.publishers['/a/pump/command'].publish(garbage)
    try:
        wait_for(lambda: node.core.rejected_commands + node.refusals > before,
                 'the actuator to refuse it', 10.0)
    except AssertionError:
        return broken('not refused (no refusal counted)')
    # Still answering, and right: a good command after it.
    rig.good_volume[0] += 1.0e-7
    volume = rig.good_volume[0]
    stamp = time.time_ns()
    rig.publishers['/a/pump/command'].publish(_joint_state(stamp, ['syringe'], [volume]))
    try:
        wait_for(lambda: any(stamp_ns(m.header) == stamp for m in rig.answers),
                 'the answer to a good command', 10.0)
    except AssertionError:
        return broken(_spin_failure(rig) or 'no answer to a good command afterwards')
    answer = next(m for m in rig.answers if stamp_ns(m.header) == stamp)
    expected = rig.tracker.step(volume).volumes
    if not all(math.isclose(a, b, rel_tol=1e-9) for a, b in zip(answer.position, expected)):
        return broken(f'a wrong state afterwards: {list(answer.position)} != {list(expected)}')
    return HELD


def _judge_pump(bench: Workbench, names: list[str], volumes: list[float],
                pressures: list[float], stops: bool) -> Verdict:
    from softseq_ros.testing import call_trigger, stamp_ns, wait_for
    rig = _topic_rig(bench)
    pump = rig.pump
    if pump.state != 'running':
        return broken(f'the pump was {pump.state} before the case')
    count = len(rig.pump_commands)
    wait_for(lambda: len(rig.pump_commands) > count, 'a pump command', 10.0)
    # An answer to its newest command, that cannot be trusted.
    stamp = stamp_ns(rig.pump_commands[-1].header)
    rig.publishers['/p/actuator/volumes'].publish(_joint_state(stamp, names, volumes,
                                                               pressures))
    expected = 'stopped' if stops else 'held'
    try:
        wait_for(lambda: pump.state == expected, f'the pump to be {expected}', 10.0)
    except AssertionError:
        return broken(_spin_failure(rig) or f'the pump is {pump.state}, not {expected}')
    reason = pump.core.reason
    verdict = HELD
    if not stops and 'actuator/volumes' not in reason:
        verdict = broken(f'the reason does not name the topic: {reason!r}')
    if stops:
        call_trigger(rig.feeder, '/p/syringe_pump/reset')
    if not call_trigger(rig.feeder, '/p/syringe_pump/start').success:
        return broken('the pump does not start again')
    return verdict


def _judge_camera(bench: Workbench, topic: str, garbage: Any,
                  must_refuse: bool = True) -> Verdict:
    from softseq_ros.testing import wait_for
    rig = _topic_rig(bench)
    core = rig.camera.core
    before = core.refused_states
    rig.publishers[topic].publish(garbage)
    if must_refuse:
        try:
            wait_for(lambda: core.refused_states > before, 'the camera to refuse it', 10.0)
        except AssertionError:
            return broken(_spin_failure(rig) or 'taken (no refusal counted)')
    # Still drawing: good states after it give a frame (a state-triggered camera draws at
    # most at its rate, so they come until one is drawn).
    frames = rig.camera.published.get('camera/backbone', 0)

    def drawn() -> bool:
        rig.good_volume[0] += 1.0e-7
        rig.publishers['/c/actuator/curvatures'].publish(
            _joint_state(time.time_ns(), SEGMENTS, [1.0 + 1e6 * rig.good_volume[0], 2.0]))
        time.sleep(0.05)
        return rig.camera.published.get('camera/backbone', 0) > frames
    try:
        wait_for(drawn, 'a frame afterwards', 10.0)
    except AssertionError:
        return broken(_spin_failure(rig) or 'no frame after good states')
    if not must_refuse and core.refused_states > before:
        return broken('refused a state whose only fault is in what the camera does not use')
    return HELD


# ------------------------------------------------------------------------------ signals

def _process(argv: list[str], cwd: Path, env: dict[str, str], log: Path) -> subprocess.Popen:
    with open(log, 'wb') as out:
        return subprocess.Popen(argv, cwd=cwd, env=env, stdout=out, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL)


def _ros_env(bench: Workbench, folder: Path) -> dict[str, str]:
    env = dict(os.environ, PYTHONUNBUFFERED='1', ROS_HOME=str(folder / 'ros_home'),
               ROS_DOMAIN_ID=str(bench.domain_id + 1),
               ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    return env


def _wait_exit(process: subprocess.Popen, timeout: float = 60.0) -> int | None:
    try:
        return process.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()
        return None


def _wait_until(condition: Callable[[], bool], timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.05)
    return False


def _complete_bag(bag: Path) -> str | None:
    why = _readable(bag)
    return None if why is None else f'the bag: {why}'


def _softseq_signal(bench: Workbench, command: str, signum: int, delay_s: float) -> Verdict:
    folder = bench.folder('signal')
    env = dict(os.environ, PYTHONUNBUFFERED='1')
    if command == 'run':
        out = folder / 'bag'
        # 20 cycles of 2610 s of rig time: the batch runner takes tens of seconds over them,
        # so every signal of the battery finds it running (one cycle ends within a second).
        scene = _read_yaml(_config('fig1_none.yaml'))
        scene['pump']['cycles'] = 20
        (folder / 'scene.yaml').write_text(_yaml(scene), encoding='utf-8')
        argv = [sys.executable, '-m', 'softseq_ros.cli', 'run', str(folder / 'scene.yaml'),
                '--out', str(out), '--no-report', '--start-time', '0']
        started = lambda: out.exists() and any(out.glob('*.mcap'))  # noqa: E731
    else:
        env = _ros_env(bench, folder)
        argv = [sys.executable, '-m', 'softseq_ros.cli', 'play', str(bench.good('bag')),
                '--rate', '0.5']
        # It prints nothing before it ends: a few seconds in, it has loaded and plays.
        begun = time.monotonic() + 4.0
        started = lambda: time.monotonic() > begun  # noqa: E731
    process = _process(argv, folder, env, folder / 'log')
    if not _wait_until(lambda: started() or process.poll() is not None, 60.0):
        process.kill()
        return broken('did not start within 60 s')
    time.sleep(delay_s)
    if process.poll() is not None:
        return broken(f'ended before the signal (exit {process.returncode})')
    process.send_signal(signum)
    code = _wait_exit(process)
    expected = 130 if signum == signal.SIGINT else 143
    log = (folder / 'log').read_text(errors='replace')
    if code != expected:
        return broken(f'exit {code}, not {expected}: {_lines(log)[-1:]}')
    if 'Traceback' in log:
        return broken('a traceback')
    if command == 'run':
        why = _complete_bag(folder / 'bag')
        if why is not None:
            return broken(why)
    return HELD


# What shows that a node executable is up: a topic its node (at the root) publishes.
UP_TOPIC = {'actuator': ('/actuator/scene', 'actuator'),
            'syringe_pump': ('/pump/status', 'syringe_pump'),
            'camera': ('/camera/backbone', 'camera'), 'rig': ('/pump/status', 'syringe_pump'),
            'recorder': ('/diagnostics', 'recorder'), 'sim_clock': ('/clock', 'sim_clock')}


def _node_signal(bench: Workbench, executable: str, signum: int, delay_s: float,
                 loading: bool = False) -> Verdict:
    """
    Signal a node executable while it loads (``loading``) or once it is up.

    While it loads, it ends at once, quietly, with 128 + the signal; once up, it stops cleanly
    with 0 and its files closed (the recorder's bag, the actuator's state file). SIGKILL of a
    recorder that recorded a pump leaves a bag that `softseq recover` restores.
    """
    from rclpy.node import Node
    folder = bench.folder('signal_node')
    env = _ros_env(bench, folder)
    env['ROS_DOMAIN_ID'] = str(bench.domain_id)
    params = {'actuator': ['-p', 'scene:=fig1_none', '-p', 'resume_timeout_s:=0.0'],
              'syringe_pump': ['-p', 'scene:=fig1_none'],
              'camera': ['-p', 'scene:=fig1_none'],
              'rig': ['-p', 'scene:=fig1_none', '-p', 'resume_timeout_s:=0.0'],
              'recorder': ['-p', f'output:={folder / "bag"}'],
              'sim_clock': []}[executable]
    helpers = []
    if executable == 'recorder' and signum == signal.SIGKILL:
        # Something to record: a pump commands 50 times a second from its start.
        helpers.append(_process([os.path.join(sys.prefix, 'bin', 'syringe_pump'), '--ros-args',
                                 '-p', 'scene:=fig1_none', '-p', 'autostart:=false'],
                                folder, env, folder / 'pump.log'))
    process = _process([os.path.join(sys.prefix, 'bin', executable), '--ros-args', *params],
                       folder, env, folder / 'log')
    watcher = Node('signal_watcher', context=bench.ros.context)
    try:
        if loading:
            time.sleep(delay_s)
        else:
            topic, name = UP_TOPIC[executable]

            def up() -> bool:
                return any(info.node_name == name and info.node_namespace == '/'
                           for info in watcher.get_publishers_info_by_topic(topic))
            if not _wait_until(lambda: up() or process.poll() is not None, 120.0):
                process.kill()
                return broken(f'not up within 120 s (no publisher of {topic})')
            if signum == signal.SIGKILL:
                mcap = folder / 'bag' / 'bag_0.mcap'
                _wait_until(lambda: mcap.is_file() and mcap.stat().st_size > 4096, 60.0)
            time.sleep(delay_s)
        if process.poll() is not None:
            return broken(f'ended before the signal (exit {process.returncode})')
        process.send_signal(signum)
        code = _wait_exit(process)
    finally:
        watcher.destroy_node()
        for helper in helpers:
            helper.send_signal(signal.SIGINT)
            _wait_exit(helper, 30.0)
    log = (folder / 'log').read_text(errors='replace')
    if 'Traceback' in log or 'terminate called' in log:
        return broken(f'a traceback or a crash: {_lines(log)[-2:]}')
    if signum == signal.SIGKILL:
        outcome = bench.softseq(['recover', str(folder / 'bag')], folder)
        if outcome.code != 0:
            return broken(f'recover after SIGKILL: exit {outcome.code}: '
                          f'{_lines(outcome.stderr)[-1:]}')
        why = _complete_bag(folder / 'bag')
        return broken(why) if why else HELD
    if code != 0:
        if loading and code == 128 + signum:
            return HELD   # ended quietly while it loaded
        return broken(f'exit {code}, not 0: {_lines(log)[-2:]}')
    if executable == 'recorder':
        why = _complete_bag(folder / 'bag')
        if why is not None:
            return broken(why)
    state_file = folder / 'ros_home' / 'softseq' / 'actuator.json'
    if executable in ('actuator', 'rig') and not loading:
        saved = json.loads(state_file.read_text(encoding='utf-8'))
        if saved.get('closed') is not True:
            return broken('the state file is not marked closed after a clean stop')
    return HELD


def signal_cases() -> list[Case]:
    """SIGINT, SIGTERM (and SIGKILL for the recorder) at random moments of running commands."""
    cases = []
    for command in ('run', 'play'):
        for signum in (signal.SIGINT, signal.SIGTERM):
            for delay in (0.0, 0.7, 1.9):
                def run(bench: Workbench, command=command, signum=signum,
                        delay=delay) -> Verdict:
                    return _softseq_signal(bench, command, signum, delay)
                cases.append(Case('signal', f'softseq {command}: {signal.Signals(signum).name} '
                                            f'after {delay:g} s', run))
    for executable in ('actuator', 'syringe_pump', 'camera', 'rig', 'recorder', 'sim_clock'):
        for signum in (signal.SIGINT, signal.SIGTERM):
            for loading in (True, False):
                def run_node(bench: Workbench, executable=executable, signum=signum,
                             loading=loading) -> Verdict:
                    return _node_signal(bench, executable, signum,
                                        bench.rng.uniform(0.1, 0.6 if loading else 1.5),
                                        loading)
                when = 'while it loads' if loading else 'once up'
                cases.append(Case('signal', f'{executable}: {signal.Signals(signum).name} '
                                            f'{when}', run_node))
    cases.append(Case('signal', 'recorder: SIGKILL, then softseq recover',
                      lambda bench: _node_signal(bench, 'recorder', signal.SIGKILL, 1.2)))
    return cases


# ------------------------------------------------------------------------------ the run

MAKERS: dict[str, Callable[[], list[Case]]] = {
    'scene': scene_cases, 'table': table_cases, 'design': design_cases,
    'experiment': experiment_cases, 'reference': reference_cases, 'history': history_cases,
    'bag': bag_cases, 'cli': cli_cases, 'option': option_cases, 'file': file_cases,
    'node_parameter': node_parameter_cases, 'service': service_cases,
    'topic': topic_cases, 'signal': signal_cases,
}
WHAT = {
    'option': 'every option of every command that takes a value (read from the parser itself, '
              'nested commands too) given NaN, infinity, -1, 0, 1e300, text, nothing and '
              'Latin-1, beside a file that is not there: refused in one line, never a '
              'traceback or a wait without end',
    'file': 'every file and folder every command reads (read from the parser, checked against '
            "bench_adversarial.FILE_INPUTS; a bag's folder, metadata.yaml and .mcap each) as a "
            'FIFO nobody writes, unreadable (mode 000), a folder, Latin-1, empty, YAML nested '
            '100,000 deep, one line of 8 MB, and SIGINT or SIGTERM while it would wait on a '
            'FIFO: refused in one line naming the file, or ended by the signal with 130 or 143',
    'scene': 'every key of four shipped scenes (linear, balloon, network, tables) given a '
             'wrong type, NaN, infinity, an integer beyond a double, deleted or unknown; whole '
             'files that are no scene (`softseq classify`, `softseq run`)',
    'table': 'segment tables damaged, in mL, mm^3, kPa, MPa, scaled by 1e304, with NaN, text, '
             'binary, Latin-1 or over-long fields (`classify`, `library`)',
    'design': 'every key of a FEM design made wrong, and `--set` values (`softseq fem`: '
              'refused before meshing)',
    'experiment': 'experiment files damaged or in other units (`report --experiment`)',
    'reference': 'malformed reference files (`report --reference`)',
    'history': 'volume histories damaged or out of the domain (`solve --path`)',
    'bag': 'bags with flipped bits, truncated, zeroed, without or with broken metadata, '
           'foreign (sqlite3, other topics, a rig topic of another type), or no bag at all '
           '(`info`, `report`, `compare`, `recover`, `play`)',
    'cli': 'every subcommand without its arguments, with unknown options or bad values',
    'node_parameter': 'every parameter of the pump, actuator, camera, sim clock and recorder '
                      'given values it cannot take, at start and at run time (`set_parameters`)',
    'service': 'every service of every node called in every state the node can be in (the '
               'pump idle, running, held, stopped, following setpoints, reset), each bool '
               'field both ways; every lifecycle transition (0 to 11, 99, 255) from every '
               'state of the managed pump: an answer, a refusal that says why, the node lives '
               'on',
    'topic': 'garbage on every topic a node subscribes to, while it runs',
    'signal': 'SIGINT and SIGTERM at random moments of `softseq run`, `softseq play` and '
              'every node executable; SIGKILL of the recorder, then `softseq recover`',
}


@dataclass
class Tally:
    """What one class gave."""

    tried: int = 0
    held: int = 0
    broken: list[tuple[str, str]] = field(default_factory=list)
    seconds: float = 0.0
    not_tried: list[tuple[str, str]] = field(default_factory=list)


def select(classes: list[str], quick: bool, rng: random.Random) -> list[Case]:
    cases = []
    for cls in classes:
        made = MAKERS[cls]()
        if quick:
            made = [case for case in made if case.can_try()]
            made = rng.sample(made, min(QUICK_PER_CLASS, len(made)))
        cases += made
    return cases


def run_cases(cases: list[Case], bench: Workbench, verbose: bool = True) -> dict[str, Tally]:
    tallies: dict[str, Tally] = {}
    for number, case in enumerate(cases, start=1):
        tally = tallies.setdefault(case.cls, Tally())
        start = time.monotonic()
        try:
            with _quiet():
                verdict = case.run(bench)
        except Exception as err:  # noqa: BLE001 - a case that cannot even run is broken
            verdict = broken(f'the case itself failed: {type(err).__name__}: {str(err)[:200]}')
        tally.seconds += time.monotonic() - start
        if not verdict.tried:
            tally.not_tried.append((case.name, verdict.why))
            if verbose:
                print(f'[{number}/{len(cases)}] {case.cls}: {case.name}: not tried: '
                      f'{verdict.why}', flush=True)
            continue
        tally.tried += 1
        if verdict.held:
            tally.held += 1
        else:
            tally.broken.append((case.name, verdict.why))
        if verbose:
            mark = 'held' if verdict.held else f'BROKEN: {verdict.why}'
            print(f'[{number}/{len(cases)}] {case.cls}: {case.name}: {mark}', flush=True)
    return tallies


@contextmanager
def _quiet() -> Iterator[None]:
    """Node logs and warnings of in-process cases stay out of the bench's own output."""
    buffer = io.StringIO()
    with redirect_stderr(buffer):
        yield


def summary(tallies: dict[str, Tally], quick: bool, seed: int, wall_s: float) -> str:
    tried = sum(t.tried for t in tallies.values())
    held = sum(t.held for t in tallies.values())
    broken_count = sum(len(t.broken) for t in tallies.values())
    lines = [
        f'**{tried} bad inputs tried, {held} held, {broken_count} broken**'
        + (' (quick sample)' if quick else '') + f' (seed {seed}, {wall_s:.0f} s on '
        f'{len(os.sched_getaffinity(0))} cores; `python bench/bench_adversarial.py`).', '',
        '| class | what is tried | tried | held | broken |', '|---|---|---:|---:|---:|']
    for cls in CLASSES:
        if cls in tallies:
            tally = tallies[cls]
            lines.append(f'| {cls} | {WHAT[cls]} | {tally.tried} | {tally.held} | '
                         f'{len(tally.broken)} |')
    lines.append(f'| all | | {tried} | {held} | {broken_count} |')
    if broken_count:
        lines += ['', 'Broken:', '']
        for cls, tally in tallies.items():
            lines += [f'- {cls}: {name}: {why}' for name, why in tally.broken]
    skipped = [(cls, name, why) for cls, tally in tallies.items()
               for name, why in tally.not_tried]
    if skipped:
        reasons = sorted({why for _, _, why in skipped})
        lines += ['', f'Not tried here ({len(skipped)} cases, not counted above): '
                  + '; '.join(reasons) + '.']
    return '\n'.join(lines) + '\n'


def write_results(text: str, path: Path) -> None:
    head = ('# Adversarial suite: results\n\nWritten by `python bench/bench_adversarial.py` '
            '(docs/faults.md keeps the summary). Each case feeds one bad input to the rig as a '
            'user would and judges what comes back against the promise of docs/faults.md: a '
            'command exits 2 with one line naming the file, key or option and writes nothing; '
            'a node refuses a parameter in one line naming itself and the parameter; garbage '
            'on a topic is said and the node answers right afterwards; a signal ends a command '
            'with 130 or 143 and nodes with 0, every bag and state file complete.\n\n')
    path.write_text(head + text, encoding='utf-8')


def write_docs(text: str) -> None:
    doc = FAULTS.read_text(encoding='utf-8')
    if BEGIN not in doc or END not in doc:
        raise RuntimeError(f'{FAULTS}: the markers {BEGIN} / {END} are missing')
    before, rest = doc.split(BEGIN, 1)
    _, after = rest.split(END, 1)
    FAULTS.write_text(before + BEGIN + '\n' + text + END + after, encoding='utf-8')


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--quick', action='store_true',
                        help=f'{QUICK_PER_CLASS} cases per class, no signals; writes nothing')
    parser.add_argument('--classes', help='comma-separated classes (default: all)')
    parser.add_argument('--seed', type=int, default=2024)
    parser.add_argument('--out', type=Path, help=f'results file (default {RESULTS} unless '
                        '--quick)')
    parser.add_argument('--no-docs', action='store_true', help='leave docs/faults.md alone')
    parser.add_argument('--list', action='store_true', help='list the cases and exit')
    parser.add_argument('--zygote', action='store_true', help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.zygote:
        zygote_main()
        return 0
    classes = args.classes.split(',') if args.classes else list(CLASSES)
    unknown = [c for c in classes if c not in MAKERS]
    if unknown:
        parser.error(f'unknown class(es) {", ".join(unknown)}; known: {", ".join(CLASSES)}')
    if args.quick and not args.classes:
        classes = [c for c in classes if c != 'signal']
    rng = random.Random(args.seed)
    cases = select(classes, args.quick, rng)
    if args.list:
        for case in cases:
            print(f'{case.cls}: {case.name}')
        return 0
    start = time.monotonic()
    with tempfile.TemporaryDirectory(prefix='adversarial_') as tmp:
        bench = Workbench(Path(tmp), Zygote(), rng, domain_id=1 + os.getpid() % 90)
        try:
            if any(c.cls in ('node_parameter', 'service', 'topic', 'signal') for c in cases):
                bench.ros = Ros(bench.domain_id)
            tallies = run_cases(cases, bench)
        finally:
            rig = bench.made.get('topic_rig')
            if rig is not None:
                rig.spinning.__exit__(None, None, None)
            if bench.ros is not None:
                bench.ros.close()
            bench.zygote.close()
    text = summary(tallies, args.quick, args.seed, time.monotonic() - start)
    print()
    print(text)
    out = args.out or (None if args.quick else RESULTS)
    if out is not None:
        write_results(text, out)
    if not args.quick and not args.no_docs and not args.classes:
        write_docs(text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
