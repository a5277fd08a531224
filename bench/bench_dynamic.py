"""
The dynamic model (softseq_ros.dynamic.flow.NetworkFlow) against an independent reference and
against FONSim: run time against error, and the batch rig with the network on.

    python bench/bench_dynamic.py [--out bench/dynamic_results.md] [--fonsim-python PATH]
                                  [--no-fonsim-install] [--skip-rig]
    python bench/bench_dynamic.py --quick
    python bench/bench_dynamic.py --integrators-only [--quick] [--out FILE]

Benchmarks, not tests: nothing is asserted about time. Every ratio is measured in this one run.

Scenes: config/paper.yaml (two tabulated segments, a partial sequence without snap-throughs)
and config/fig1_asymmetric.yaml (two Gent balloons, two snap-throughs on inflation), each with
the network NETWORK below (no supply line; one channel of 10 mm and 0.4 mm radius, laminar: its
Reynolds number stays below 1100, so FONSim's tube stays on its laminar branch too), pumped
from 0 to 65 mL at the scenes' own 0.05 mL/s (1300 s). At that channel the Fig. 1 snaps take
tens of seconds (10-90 % of the fluid moved) and move fluid 6-13 times faster than the pump.

1. Ours: NetworkFlow at rtol 1e-2 ... 1e-10, advanced through outputs at 1 Hz (1300 of them,
   as many as FONSim's outputs at a 1 s step; the snaps last tens of seconds) in one call
   (NetworkFlow.advance_through), timed, best of 5. At the loosest tolerance also asked output
   by output (NetworkFlow.advance, as the rig asks), and with scipy's Radau as it comes
   (integrator 'scipy-radau'), best of 11 each, for the table of what each part costs.
   Error: max over the outputs of |volume - reference| / 65 mL (the range the volumes
   sweep), every segment.
2. Reference (written here, shares no code with NetworkFlow but the segments' pressure
   functions): both volumes as states, dv_0/dt = Q - q, dv_1/dt = q with q = (p_0 - p_1) / R,
   no mass closure, integrated by scipy's DOP853 (explicit, eighth order) at rtol 1e-13, and
   checked against LSODA at rtol 1e-12: their difference is the reference's own error bar.
3. FONSim 0.6.0 (its own interpreter: bench/fonsim_run.py), the same network: a volume-flow
   source, FreeActuators on p(V) CSVs sampled here from our segment models (20,001 points
   each; FONSim interpolates linearly and reads the CSV as 32-bit floats: the floor this
   puts under its error is measured, by the reference integrator on the very same table),
   a CircularTube, backward Euler with a fixed step, three steps. Its error is taken at its
   own steps.
4. Our error at FONSim's run time and our run time at FONSim's error, interpolated (log-log)
   in our tolerance sweep, and the ratio.
5. The batch rig (softseq_ros.run, every topic recorded) on the paper scene with
   the network block added in memory, as a multiple of real time, beside the quasi-static run
   of the same programme.
6. The integrators alone (softseq_ros.dynamic.integrators), against scipy's Radau on the same
   problem at equal tolerances, in this one process: the network's equations written here
   (all volumes but the tip's as states, laminar channels), the paper pair (one state: our
   ScalarRadau) and config/three_segments.yaml (two states: our LeanRadau), each stepped from
   rest to the end of the scene's first inflation, best of 11; the largest difference of the
   two solutions at 1 Hz (from each one's dense output), as a share of the pumped volume.
   ``--integrators-only`` runs this part alone.

FONSim is never imported by softseq_ros and is not in requirements.txt: it is installed into
its own virtual environment from bench/requirements-fonsim.txt, by default
``$XDG_CACHE_HOME/softseq_ros/fonsim-venv`` (~/.cache/...). The full run creates it when it is
missing (``--no-fonsim-install``: it does not); ``--fonsim-python`` names another interpreter.

``--quick``: a check that it runs, in about 15 s: two tolerances, once each, a reference at
rtol 1e-9, FONSim at one 2 s step (only when its environment exists; skipped and
said otherwise), a short rig programme, the integrators at one tolerance once; printed,
nothing written into the repository (unless ``--out``). The test suite runs it
(test/test_bench_quick.py).
"""

import argparse
from dataclasses import dataclass
import json
import math
import os
from pathlib import Path
import platform
import subprocess
import sys
import tempfile
import time

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402
from scipy.integrate import Radau, solve_ivp  # noqa: E402
import yaml  # noqa: E402

import softseq_ros  # noqa: E402
from softseq_ros.dynamic.flow import ATOL_SHARE, NetworkFlow  # noqa: E402
from softseq_ros.dynamic.integrators import new_integrator  # noqa: E402
from softseq_ros.dynamic.network import tube_law  # noqa: E402
from softseq_ros.scene.loader import load_scene, scene_from_dict  # noqa: E402
from softseq_ros.scene.network import (  # noqa: E402
    DEFAULT_NETWORK_RTOL,
    Fluid,
    NetworkSettings,
    Tube,
)
from softseq_ros.scene.validation import YamlLoader  # noqa: E402

RESULTS = ROOT / 'bench' / 'dynamic_results.md'
REQUIREMENTS = ROOT / 'bench' / 'requirements-fonsim.txt'
WORKER = ROOT / 'bench' / 'fonsim_run.py'
ML = 1e-6
SCENES = ('paper', 'fig1_asymmetric')
# The integrators alone: one scene whose network has one state, one whose has two.
INTEGRATOR_SCENES = ('paper', 'three_segments')
CHANNEL = Tube(length_m=0.01, radius_m=0.4e-3)
FLUID = Fluid()
NETWORK = {'channels': [{'length_m': CHANNEL.length_m, 'radius_m': CHANNEL.radius_m}]}
CURVE_POINTS = 20001


@dataclass(frozen=True)
class Sizes:
    """What a run covers: the benchmark, or a check that it runs (``--quick``)."""

    output_hz: float
    rtols: tuple[float, ...]
    repeats: int
    reference_rtol: float
    check_rtol: float
    fonsim_steps: tuple[float, ...]
    rig_legs: list
    rig_triggers: list
    rig_rates_hz: tuple[float, ...]
    integrator_rtols: tuple[float, ...]
    integrator_repeats: int


FULL = Sizes(1.0, (1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10), 5, 1e-13, 1e-12,
             (0.5, 0.1, 0.02),
             [{'inflate_to_m3': 6.5e-5}, {'hold_s': 10}, {'deflate_to_m3': 0.0}],
             [5.0e-6, 1.5e-5, 2.5e-5, 4.5e-5, 6.0e-5], (200.0, 50.0), (1e-3, 1e-6), 11)
QUICK = Sizes(1.0, (1e-3, 1e-5), 1, 1e-9, 1e-8, (2.0,),
              [{'inflate_to_m3': 3.0e-6}, {'deflate_to_m3': 0.0}], [2.0e-6], (200.0,),
              (1e-3,), 1)


def best_of(fn, repeats):
    """The shortest of ``repeats`` wall times of ``fn()``, the shortest CPU time, the result."""
    best, best_cpu, result = math.inf, math.inf, None
    for _ in range(repeats):
        start, cpu_start = time.perf_counter(), time.process_time()
        result = fn()
        best = min(best, time.perf_counter() - start)
        best_cpu = min(best_cpu, time.process_time() - cpu_start)
    return best, best_cpu, result


# ---------------------------------------------------------------------------------- the case

class Case:
    """One scene with the network: segments, pump flow, duration, output times."""

    def __init__(self, name, sizes):
        scene = load_scene(name)
        self.name = name
        self.segments = scene.segments
        self.flow, self.end = pump_of(name)
        self.duration = self.end / self.flow
        self.range = self.end
        count = int(round(self.duration * sizes.output_hz))
        self.outputs = np.linspace(0.0, self.duration, count + 1)[1:]
        self.rest = np.array([s.rest_volume for s in self.segments])

    def settings(self, rtol):
        return NetworkSettings(FLUID, None, (CHANNEL,), rtol=rtol)


def pump_of(name):
    """The scene's pump flow [m^3/s] and its first inflation's end [m^3] (the benchmark's)."""
    pump = yaml.load((ROOT / 'config' / f'{name}.yaml').read_text(), Loader=YamlLoader)['pump']
    return pump['flow_rate_m3_per_s'], next(leg['inflate_to_m3'] for leg in pump['legs']
                                            if 'inflate_to_m3' in leg)


def ours(case, rtol):
    """
    NetworkFlow through every output: (volumes at the outputs, steps, peak Reynolds, snaps).

    All outputs in one call (NetworkFlow.advance_through: the same steps and states as one
    advance per output, each step's outputs read from its interpolant at once).
    """
    flow = NetworkFlow(case.segments, case.settings(rtol))
    flow.set_flow(case.flow)
    states = flow.advance_through(case.outputs)
    volumes = flow.states_volumes(states, case.flow * case.outputs)
    return volumes, flow.steps, max(flow.peak_reynolds), flow.snaps.found


def ours_per_output(case, rtol, integrator):
    """The same outputs asked for one at a time (as the rig asks), with ``integrator``."""
    flow = NetworkFlow(case.segments, case.settings(rtol), integrator=integrator)
    flow.set_flow(case.flow)
    volumes = np.empty((case.outputs.size, len(case.segments)))
    for k, t in enumerate(case.outputs):
        flow.advance(float(t))
        volumes[k] = flow.volumes()
    return volumes, flow.steps, max(flow.peak_reynolds), flow.snaps.found


class Reference:
    """
    The same equations, written again: both volumes as states, no mass closure.

    q = (p_0(v_0) - p_1(v_1)) / R (Hagen-Poiseuille, the channel has no inertance or minor
    loss here); the pressures are the segments' own (the curves are what is compared, not
    re-derived). DOP853 at ``rtol``; LSODA at ``check_rtol`` for the error bar.
    """

    def __init__(self, case, rtol, check_rtol, pressure_of=None):
        self.case = case
        resistance = 8.0 * FLUID.viscosity_pa_s * CHANNEL.length_m / (math.pi
                                                                      * CHANNEL.radius_m ** 4)
        pressures = pressure_of or [s.pressure for s in case.segments]
        q_pump = case.flow

        def rates(t, v):
            q = (float(pressures[0](v[0])) - float(pressures[1](v[1]))) / resistance
            return [q_pump - q, q]

        atol = 1e-3 * rtol * case.range
        start = time.perf_counter()
        self.solution = solve_ivp(rates, (0.0, case.duration), case.rest, method='DOP853',
                                  rtol=rtol, atol=atol, dense_output=True)
        self.seconds = time.perf_counter() - start
        if self.solution.status != 0:
            raise RuntimeError(f'reference failed: {self.solution.message}')
        self.steps = self.solution.t.size - 1
        self.check = None
        if check_rtol is not None:
            other = solve_ivp(rates, (0.0, case.duration), case.rest, method='LSODA',
                              rtol=check_rtol, atol=1e-3 * check_rtol * case.range,
                              dense_output=True)
            grid = np.linspace(0.0, case.duration, 20001)
            self.check = float(np.max(np.abs(other.sol(grid) - self.solution.sol(grid)))
                               / case.range)
        # Mass, which this formulation does not enforce: another measure of its accuracy.
        grid = np.linspace(0.0, case.duration, 20001)
        self.mass = float(np.max(np.abs(self.solution.sol(grid).sum(axis=0) - case.rest.sum()
                                        - case.flow * grid)) / case.range)

    def volumes(self, times):
        return self.solution.sol(np.asarray(times)).T

    def error(self, times, volumes):
        return float(np.max(np.abs(volumes - self.volumes(times))) / self.case.range)


# ---------------------------------------------------------------------------------- FONSim

def cache_folder():
    return Path(os.environ.get('XDG_CACHE_HOME') or Path.home() / '.cache') / 'softseq_ros'


def fonsim_python(args, install):
    """FONSim's interpreter, or (None, why not)."""
    python = Path(args.fonsim_python) if args.fonsim_python else \
        cache_folder() / 'fonsim-venv' / 'bin' / 'python'
    if not python.exists() and install and not args.fonsim_python:
        venv = python.parent.parent
        print(f"creating FONSim's environment in {venv} (python -m venv; pip install -r "
              f'{REQUIREMENTS.relative_to(ROOT)})', flush=True)
        try:
            subprocess.run([sys.executable, '-m', 'venv', '--without-pip', str(venv)], check=True)
            # The project's interpreter may itself live in a venv without ensurepip.
            subprocess.run([str(python), '-m', 'ensurepip', '--upgrade'], check=False,
                           capture_output=True)
            pip = [str(python), '-m', 'pip'] if subprocess.run(
                [str(python), '-m', 'pip', '--version'], capture_output=True).returncode == 0 \
                else [sys.executable, '-m', 'pip', '--python', str(python)]
            subprocess.run([*pip, 'install', '-q', '-r', str(REQUIREMENTS)], check=True,
                           capture_output=True, text=True)
        except (subprocess.CalledProcessError, OSError) as error:
            detail = getattr(error, 'stderr', '') or ''
            return None, f'installing FONSim failed: {error} {detail.strip()[-500:]}'
    if not python.exists():
        return None, (f"FONSim's environment is not installed ({python} missing; the full run "
                      f'creates it, or: python -m venv {python.parent.parent} && '
                      f'{python} -m pip install -r bench/requirements-fonsim.txt)')
    probe = subprocess.run([str(python), '-c', 'import importlib.metadata as m; '
                            'print(m.version("fonsim"))'], capture_output=True, text=True)
    if probe.returncode != 0:
        return None, f'FONSim does not import in {python}: {probe.stderr.strip()[-300:]}'
    return python, probe.stdout.strip()


def write_curves(case, folder):
    """Each segment's p(V) as FONSim reads it: volume from rest [m^3], gauge pressure [Pa]."""
    paths, tables = [], []
    for segment in case.segments:
        volume = np.linspace(segment.rest_volume, segment.max_volume, CURVE_POINTS)
        pressure = np.asarray(segment.pressure(volume), dtype=float)
        path = folder / f'{case.name}_{segment.name}.csv'
        np.savetxt(path, np.column_stack([volume - segment.rest_volume, pressure]),
                   delimiter=',', header='volume,pressure\nm^3,Pa', comments='', fmt='%.10e')
        paths.append(str(path))
        # What FONSim will hold: the rows as 32-bit floats, interpolated linearly.
        tables.append((np.float32(volume - segment.rest_volume).astype(float),
                       np.float32(pressure).astype(float), segment.rest_volume))
    return paths, tables


def run_fonsim(python, case, steps, folder):
    """
    FONSim at each step: {step: (times, volumes, run seconds, CPU seconds)}, or raises with
    its stderr.
    """
    paths, _ = write_curves(case, folder)
    out = folder / f'fonsim_{case.name}.npz'
    job = {'curves': paths, 'channel_length_m': CHANNEL.length_m,
           'channel_radius_m': CHANNEL.radius_m, 'density_kg_per_m3': FLUID.density_kg_per_m3,
           'viscosity_pa_s': FLUID.viscosity_pa_s, 'flow_m3_per_s': case.flow,
           'duration_s': case.duration, 'steps_s': list(steps), 'out': str(out)}
    job_path = folder / f'fonsim_{case.name}.json'
    job_path.write_text(json.dumps(job))
    # Its matplotlib wants a writable config folder; one beside its environment persists.
    env = dict(os.environ, MPLCONFIGDIR=str(Path(python).parent.parent / 'mplconfig'),
               MPLBACKEND='Agg', PYTHONDONTWRITEBYTECODE='1')
    done = subprocess.run([str(python), str(WORKER), str(job_path)], capture_output=True,
                          text=True, env=env)
    if done.returncode != 0:
        raise RuntimeError(done.stderr.strip()[-800:])
    data = np.load(out)
    timing = json.loads(out.with_suffix('.json').read_text())
    return {step: (data[f't{k}'], data[f'v{k}'] + case.rest, timing['run_s'][str(step)],
                   timing['cpu_s'][str(step)])
            for k, step in enumerate(steps)}


def curve_floor(case, folder, reference, rtol):
    """What FONSim's table alone costs: the reference integrator on that table, against ours."""
    _, tables = write_curves(case, folder)
    functions = [lambda v, x=x, p=p, rest=rest: np.interp(v - rest, x, p)
                 for x, p, rest in tables]
    on_table = Reference(case, max(rtol, 1e-11), None, functions)
    grid = np.linspace(0.0, case.duration, 20001)
    return on_table.error(grid, reference.volumes(grid))


# ---------------------------------------------------------------------------------- compare

def interpolate_loglog(x, y, at):
    """y at ``at`` on the log-log polyline through (x, y) sorted by x; None outside."""
    order = np.argsort(x)
    lx, ly = np.log(np.asarray(x)[order]), np.log(np.asarray(y)[order])
    if not lx[0] <= math.log(at) <= lx[-1]:
        return None
    return float(math.exp(np.interp(math.log(at), lx, ly)))


def monotone_front(points):
    """(time, error) points where no faster run has a smaller error: the usable trade-off."""
    front, best = [], math.inf
    for t, e in sorted(points):
        if e < best:
            front.append((t, e))
            best = e
    return front


def equal_error(front, error):
    """Our run time at ``error`` (interpolated on the front); (time, qualifier)."""
    times, errors = zip(*front)
    if error >= max(errors):
        return min(times), '<='     # even our loosest run is at least as accurate
    if error < min(errors):
        return None, 'beyond'
    value = interpolate_loglog(errors, times, error)
    return value, '='


def at_equal(value, how):
    """Our time at equal error, as a cell."""
    return f'{"<= " if how == "<=" else ""}{"-" if value is None else f"{value:.3f}"}'


def ratio_cell(theirs, ours_at_error, how):
    """FONSim's time over ours at equal error, as a cell (a lower bound where marked)."""
    if ours_at_error is None:
        return 'ours never that accurate'
    return f'{"**>= " if how == "<=" else "**"}{theirs / ours_at_error:.0f}x**'


def equal_time(front, seconds):
    """Our error at a run time of ``seconds``; (error, qualifier)."""
    times, errors = zip(*front)
    if seconds >= max(times):
        return min(errors), '<='    # our tightest run is still faster
    if seconds < min(times):
        return None, 'beyond'
    return interpolate_loglog(times, errors, seconds), '='


# ---------------------------------------------------------------------------------- the rig

def rig_scene(folder, legs, triggers, rate_hz, network):
    data = yaml.load((ROOT / 'config' / 'paper.yaml').read_text(), Loader=YamlLoader)
    data['pump']['legs'] = legs
    data['camera']['trigger_injected_m3'] = triggers
    if network:
        data['network'] = dict(NETWORK, rate_hz=rate_hz)
    # The scene's own folder, for its table paths; no file is written there.
    return scene_from_dict(data, ROOT / 'config' / 'paper_network.yaml')


def rig_run(folder, legs, triggers, rate_hz, network):
    scene = rig_scene(folder, legs, triggers, rate_hz, network)
    bag = folder / f'bag_{"net" if network else "qs"}_{int(rate_hz)}'
    start, cpu_start = time.perf_counter(), time.process_time()
    result = softseq_ros.run(scene, bag, start_time_ns=0)
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu_start
    messages = sum(result.message_counts.values())
    for path in sorted(bag.rglob('*'), reverse=True):
        path.unlink() if path.is_file() else path.rmdir()
    bag.rmdir()
    return result.sim_duration_s, wall, cpu, messages, result.pump_state


# ---------------------------------------------------------------------------------- integrators

class IntegratorProblem:
    """
    A scene's network written as the integrators see it, without NetworkFlow around it.

    The states are the volumes but the tip's (mass gives it), the syringe feeds the base at the
    scene's flow, laminar channels (CHANNEL) join the segments; a volume outside a segment's
    curve reads the pressure at its end. ``rates`` takes and gives arrays (scipy's Radau,
    LeanRadau), ``rate_of_one`` floats (ScalarRadau, one state); the same arithmetic.
    """

    def __init__(self, name):
        segments = load_scene(name).segments
        self.name = name
        self.flow, self.pumped = pump_of(name)
        self.duration = self.pumped / self.flow
        self.count = len(segments)
        self.bounds = [(s.rest_volume, s.max_volume) for s in segments]
        self.y0 = np.array([lo for lo, _ in self.bounds[:-1]])
        rest_total = sum(lo for lo, _ in self.bounds)
        self.atol_per_rtol = np.full(self.count - 1,
                                     ATOL_SHARE * sum(hi - lo for lo, hi in self.bounds))
        resistance = tube_law(CHANNEL, FLUID).resistance
        pressure_of = [s.pressure for s in segments]
        last = self.count - 1

        def pressures(t, others):
            volumes = others + [rest_total + self.flow * t - sum(others)]
            return [float(p(min(max(v, lo), hi)))
                    for p, v, (lo, hi) in zip(pressure_of, volumes, self.bounds)]

        def rates(t, y):
            p = pressures(t, y.tolist())
            q = [(p[j] - p[j + 1]) / resistance for j in range(last)]
            return np.array([self.flow - q[0]] + [q[i - 1] - q[i] for i in range(1, last)])

        def rate_of_one(t, v):
            p = pressures(t, [v])
            return self.flow - (p[0] - p[1]) / resistance

        self.rates, self.rate_of_one = rates, rate_of_one

    def ours(self, rtol):
        """Our default for this state (new_integrator: ScalarRadau or LeanRadau)."""
        return new_integrator('radau', self.rates, self.rate_of_one, 0.0, self.y0,
                              self.duration, rtol, self.atol_per_rtol * rtol)

    def scipys(self, rtol):
        """scipy's Radau as it comes, on the same rates and tolerances."""
        return Radau(self.rates, 0.0, self.y0, self.duration, rtol=rtol,
                     atol=self.atol_per_rtol * rtol)


def step_through(solver, times=None):
    """Step ``solver`` to its end: its steps, and its state at ``times`` (dense output)."""
    rows = None if times is None else np.empty((times.size, solver.y.size))
    k, steps = 0, 0
    while solver.status == 'running':
        message = solver.step()
        steps += 1
        if solver.status == 'failed':
            raise RuntimeError(f'{type(solver).__name__} failed at {solver.t:g} s: {message}')
        if rows is not None:
            inside = int(np.searchsorted(times, solver.t, side='right'))
            if inside > k:
                rows[k:inside] = np.asarray(solver.dense_output()(times[k:inside])).T
                k = inside
    return steps, rows


def integrator_section(sizes):
    """Our integrators against scipy's Radau, each problem and tolerance in turn."""
    load = os.getloadavg()[0]
    rows = []
    for name in INTEGRATOR_SCENES:
        problem = IntegratorProblem(name)
        times = np.arange(1.0, problem.duration, 1.0)
        for rtol in sizes.integrator_rtols:
            kind = type(problem.ours(rtol)).__name__
            ours_s, _, (ours_steps, _) = best_of(
                lambda p=problem, r=rtol: step_through(p.ours(r)), sizes.integrator_repeats)
            scipy_s, _, (scipy_steps, _) = best_of(
                lambda p=problem, r=rtol: step_through(p.scipys(r)), sizes.integrator_repeats)
            _, ours_rows = step_through(problem.ours(rtol), times)
            _, scipy_rows = step_through(problem.scipys(rtol), times)
            difference = float(np.max(np.abs(ours_rows - scipy_rows))) / problem.pumped
            rows.append((name, problem.count - 1, kind, rtol, ours_s, ours_steps, scipy_s,
                         scipy_steps, difference))
            print(f'  integrators {name} rtol={rtol:g}: {kind} {ours_s * 1e3:.2f} ms, scipy '
                  f'{scipy_s * 1e3:.2f} ms ({ours_s / scipy_s:.2f}), difference '
                  f'{difference:.1e}', flush=True)
    lines = ["## The integrators alone, against scipy's Radau", '',
             "softseq_ros.dynamic.integrators on the network's equations written in the bench "
             "(all volumes but the tip's as states; channels of "
             f'{CHANNEL.length_m * 1e3:g} mm, radius {CHANNEL.radius_m * 1e3:g} mm), pumped '
             "from rest to the end of the scene's first inflation at its flow; ours (what "
             "`new_integrator` picks for the state) and scipy's `Radau` at the same rtol and "
             'atol (1e-3 rtol of the volume scale), stepped to the end in turn in one process, '
             f'best of {sizes.integrator_repeats} each (load average {load:.2f} at the start). '
             "ScalarRadau gets the rate as a float function, scipy's Radau and LeanRadau the "
             'same rates as an array function. Difference: max over 1 Hz outputs (each '
             "solution's dense output) of |ours - scipy's|, over the pumped volume.", '',
             '| scene | states | ours | rtol | ours [ms] | steps | scipy Radau [ms] | steps '
             '| ours / scipy | difference / pumped |',
             '|---|---:|---|---:|---:|---:|---:|---:|---:|---:|']
    lines += [f'| {name} | {states} | {kind} | {rtol:.0e} | {ours_s * 1e3:.2f} | {ours_steps} | '
              f'{scipy_s * 1e3:.2f} | {scipy_steps} | **{ours_s / scipy_s:.2f}** | '
              f'{difference:.1e} |'
              for name, states, kind, rtol, ours_s, ours_steps, scipy_s, scipy_steps, difference
              in rows]
    return lines + ['']


# ---------------------------------------------------------------------------------- report

def fmt(x, digits=2):
    if x is None:
        return '-'
    return f'{x:.{digits}e}'


def run(args, sizes, folder):
    lines = ['# Dynamic model: run time against error, against FONSim, and on the rig', '',
             'Written by `python bench/bench_dynamic.py` (bench/README.md has the method).', '',
             f'Machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f} at the '
             f'start; Python {platform.python_version()}.', '',
             f'Network: no supply line; one channel of {CHANNEL.length_m * 1e3:g} mm, radius '
             f'{CHANNEL.radius_m * 1e3:g} mm, water (viscosity {FLUID.viscosity_pa_s:g} Pa s, '
             f'density {FLUID.density_kg_per_m3:g} kg/m^3), laminar, no inertance; resistance '
             f"{tube_law(CHANNEL, FLUID).resistance:.3e} Pa s/m^3. Pump: the scenes' own "
             f'0.05 mL/s from 0 to 65 mL (1300 s). Our outputs at {sizes.output_hz:g} Hz. '
             'Error: max over time of |volume - reference| / 65 mL, every segment.', '']
    install = not args.quick and not args.no_fonsim_install
    python, fonsim_note = fonsim_python(args, install)
    if python is None:
        print(f'FONSim skipped: {fonsim_note}', flush=True)
        lines += [f'**FONSim skipped**: {fonsim_note}', '']
    else:
        lines += [f'FONSim {fonsim_note} from `{python}` (bench/requirements-fonsim.txt); '
                  f'fixed backward-Euler steps {", ".join(f"{s:g} s" for s in sizes.fonsim_steps)}'
                  '; its other settings at their defaults.', '']
    summary = []
    for name in SCENES:
        case = Case(name, sizes)
        print(f'== {name}', flush=True)
        reference = Reference(case, sizes.reference_rtol, sizes.check_rtol)
        rows, points, cpu_points = [], [], []
        snaps_at = {}
        for rtol in sizes.rtols:
            seconds, cpu, (volumes, steps, reynolds, snaps) = best_of(
                lambda c=case, r=rtol: ours(c, r), sizes.repeats)
            error = reference.error(case.outputs, volumes)
            rows.append((rtol, seconds, steps, error, cpu))
            points.append((seconds, error))
            cpu_points.append((cpu, error))
            snaps_at[rtol] = (reynolds, snaps)
            print(f'  ours rtol={rtol:g}: {seconds:.3f} s, {steps} steps, error {error:.2e}',
                  flush=True)
        shown = DEFAULT_NETWORK_RTOL if DEFAULT_NETWORK_RTOL in snaps_at else sizes.rtols[0]
        reynolds, snaps = snaps_at[shown]

        def said(exchanges: list, flow: float = case.flow) -> str:
            return '; '.join(f'at {s.injected / ML:.2f} mL, {s.fluid_moved_m3 / ML:.3f} mL '
                             f'moved in {s.duration_s:.3f} s (10-90 %), peak '
                             f'{s.peak_exchange_m3_per_s / flow:.1f}x the pump'
                             for s in exchanges) or 'none'
        which = 'the default tolerance ' if shown == DEFAULT_NETWORK_RTOL else 'rtol '
        # Every exchange of fluid is an event; those that pass an unstable state are the
        # snap-throughs (docs/dynamic.md), the others exchanges as a slow pump's lag evens out.
        others = [s for s in snaps if not s.snap_through]
        snap_text = (f'Snap-throughs (ours, at {which}{shown:g}): '
                     f'{said([s for s in snaps if s.snap_through])}'
                     + snap_spread(snaps_at) + '.'
                     + (f' Other exchanges of fluid: {said(others)}.' if others else ''))
        lines += [f'## {name}', '',
                  f'Reference: DOP853 at rtol {sizes.reference_rtol:g}, {reference.steps} steps, '
                  f'{reference.seconds:.1f} s; against LSODA at rtol {sizes.check_rtol:g}: '
                  f'{reference.check:.1e} of the range; mass (not enforced by it) kept to '
                  f'{reference.mass:.1e} of the range. Peak Reynolds number {reynolds:.0f}. '
                  f'{snap_text}', '',
                  '| ours: rtol | run time [s] | steps | error / range | CPU [s] |',
                  '|---:|---:|---:|---:|---:|']
        lines += [f'| {rtol:.0e} | {seconds:.3f} | {steps} | {error:.2e} | {cpu:.3f} |'
                  for rtol, seconds, steps, error, cpu in rows]
        lines.append('')
        # How the two integrators and the two ways of asking compare, at the loosest tolerance:
        # scipy's Radau as it comes, asked output by output, was the model's way before.
        loosest = sizes.rtols[0]
        variants = [('radau', 'all at once', lambda c=case, r=loosest: ours(c, r)),
                    ('radau', 'one by one',
                     lambda c=case, r=loosest: ours_per_output(c, r, 'radau')),
                    ('scipy-radau', 'one by one',
                     lambda c=case, r=loosest: ours_per_output(c, r, 'scipy-radau'))]
        timed = []
        for integrator, asked, fn in variants:
            seconds, _, (volumes, steps, _, _) = best_of(fn, 2 * sizes.repeats + 1)
            timed.append((integrator, asked, seconds, steps,
                          reference.error(case.outputs, volumes)))
        lines += [f'Integrators and outputs at rtol {loosest:.0e} (best of '
                  f"{2 * sizes.repeats + 1} each, in turn): `radau` is the default (scipy's "
                  "Radau IIA without scipy's wrappers; for this one-state network its port to "
                  "plain floats, docs/dynamic.md), `scipy-radau` scipy's Radau as it comes; "
                  "'one by one' asks NetworkFlow.advance per output, as the rig does.", '',
                  '| integrator | outputs asked | run time [s] | steps | error / range '
                  '| time / the default |', '|---|---|---:|---:|---:|---:|']
        lines += [f'| {integrator} | {asked} | {seconds:.4f} | {steps} | {error:.2e} | '
                  f'{seconds / timed[0][2]:.2f} |'
                  for integrator, asked, seconds, steps, error in timed]
        lines.append('')
        for integrator, asked, seconds, steps, error in timed:
            print(f'  {integrator}, {asked}: {seconds:.4f} s, {steps} steps, error {error:.2e}',
                  flush=True)
        front, cpu_front = monotone_front(points), monotone_front(cpu_points)
        if python is not None:
            try:
                results = run_fonsim(python, case, sizes.fonsim_steps, folder)
            except RuntimeError as error:
                lines += [f'FONSim failed on {name}: {error}', '']
                results = {}
            floor = curve_floor(case, folder, reference, sizes.reference_rtol) \
                if results else None
            if results:
                lines += [f'FONSim on the same network; its table (linear, 32-bit) alone puts '
                          f'{floor:.1e} of the range under its error (the reference integrator '
                          'on that table).', '',
                          '| FONSim step [s] | run time [s] | steps | error / range '
                          '| ours at equal run time: error | ours at equal error: run time [s] '
                          '| FONSim time / ours at equal error | FONSim CPU [s] '
                          '| ours at equal error: CPU [s] | FONSim CPU / ours at equal error |',
                          '|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|']
            for step, (times, volumes, seconds, cpu) in results.items():
                error = reference.error(times, volumes)
                at_time, how_t = equal_time(front, seconds)
                at_error, how_e = equal_error(front, error)
                cpu_at_error, how_c = equal_error(cpu_front, error)
                lines.append(
                    f'| {step:g} | {seconds:.2f} | {times.size - 1} | {error:.2e} | '
                    f'{"<= " if how_t == "<=" else ""}{fmt(at_time)} | '
                    f'{at_equal(at_error, how_e)} | {ratio_cell(seconds, at_error, how_e)} | '
                    f'{cpu:.2f} | {at_equal(cpu_at_error, how_c)} | '
                    f'{ratio_cell(cpu, cpu_at_error, how_c)} |')
                summary.append((seconds / at_error if at_error else None,
                                cpu / cpu_at_error if cpu_at_error else None))
                print(f'  FONSim step {step:g}: {seconds:.2f} s (CPU {cpu:.2f} s), error '
                      f'{error:.2e}', flush=True)
            lines.append('')
    if summary:
        worst = min(wall for wall, _ in summary if wall)
        worst_cpu = min(cpu for _, cpu in summary if cpu)
        lines += ['## Target: 100x less run time than FONSim at equal error', '',
                  f"Smallest ratio over both scenes and FONSim's steps: **{worst:.0f}x** in run "
                  f'time ({"met" if worst >= 100 else "not met"}), **{worst_cpu:.0f}x** in CPU '
                  f'time ({"met" if worst_cpu >= 100 else "not met"}). "<=" marks where even our '
                  'loosest tolerance is more accurate than FONSim (the ratio is then a lower '
                  "bound), or where our tightest tolerance is still faster than FONSim's run. "
                  'Both run on one thread: on a quiet machine run time and CPU time agree; on '
                  'a loaded one (the load average above) the run times stretch, our runs of a '
                  "few milliseconds more than FONSim's of seconds, and the CPU times less "
                  '(shared caches slow both).', '']
    if not args.skip_rig:
        lines += rig_section(sizes, folder)
    lines += integrator_section(sizes)
    return '\n'.join(lines) + '\n'


def rig_section(sizes, folder):
    legs = sizes.rig_legs
    lines = ['## Batch rig: the paper scene with the network on', '',
             '`softseq_ros.run` of config/paper.yaml with the network block above added in '
             f'memory (pump at 50 Hz, camera at 10 Hz, every topic recorded to a bag), programme '
             f'{" -> ".join(describe(leg) for leg in legs)} (at the end of the withdrawal the '
             "base segment collapses below its rest volume and pulls the tip's fluid through "
             "the channel). Between the pump's commands the actuator speaks at its rate while "
             'fluid moves between the segments. The quasi-static run '
             'is the same programme without the network. The batch runner computes on one '
             'thread (another only flushes the bag now and then). On a loaded machine (the '
             'load average above) its wall time stretches with the load and its CPU time less '
             '(shared caches slow it too): rig time / wall is what this machine gave, and the '
             "network's CPU time as a multiple of the quasi-static run's in the same run is "
             'what the network costs.', '',
             '| model | actuator rate [Hz] | rig time [s] | wall [s] | CPU [s] | messages '
             '| rig time / wall | rig time / CPU | CPU / quasi-static |',
             '|---|---:|---:|---:|---:|---:|---:|---:|---:|']
    runs = [('quasi-static', '(pump 50)', False, 200.0)] + \
        [('network', f'{rate:g}', True, rate) for rate in sizes.rig_rates_hz]
    baseline = None
    for model, shown, network, rate in runs:
        sim, wall, cpu, messages, state = rig_run(folder, legs, sizes.rig_triggers, rate,
                                                  network)
        baseline = baseline or cpu
        lines.append(f'| {model} | {shown} | {sim:.0f} | {wall:.1f} | {cpu:.1f} | '
                     f'{messages:,} | **{sim / wall:.0f}x** | {sim / cpu:.0f}x | '
                     f'{cpu / baseline:.2f} |')
        print(f'  rig {model} {shown} Hz: {sim / wall:.0f}x real time, {sim / cpu:.0f}x per '
              f'CPU second ({state})', flush=True)
    return lines + ['']


def snap_spread(snaps_at):
    """How far the snap-throughs' numbers move over the tolerance sweep (on the polynomials)."""
    throughs = {rtol: [s for s in snaps if s.snap_through]
                for rtol, (_, snaps) in snaps_at.items()}
    counts = {len(snaps) for snaps in throughs.values()}
    if len(counts) != 1:
        return ' (the sweep finds different numbers of snap-throughs)'
    if not counts.pop() or len(snaps_at) < 2:
        return ''
    numbers = np.array([[[s.duration_s, s.fluid_moved_m3, s.peak_exchange_m3_per_s]
                         for s in snaps] for snaps in throughs.values()])
    spread = float(np.max(np.ptp(numbers, axis=0) / np.abs(numbers).max(axis=0)))
    tolerances = sorted(snap_at for snap_at in snaps_at)
    return (f'; over rtol {tolerances[-1]:g} to {tolerances[0]:g} each duration, fluid moved '
            f'and peak exchange stays within {spread:.1e} of itself (relative)')


def describe(leg):
    key, value = next(iter(leg.items()))
    return {'inflate_to_m3': f'{value / ML:g} mL', 'deflate_to_m3': f'{value / ML:g} mL',
            'hold_s': f'hold {value:g} s'}[key]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--quick', action='store_true',
                        help='a check that the benchmark runs (about 30 s), printed only')
    parser.add_argument('--out', default=None, help=f'results file (default {RESULTS})')
    parser.add_argument('--fonsim-python', default=None,
                        help='the interpreter of an environment with FONSim installed')
    parser.add_argument('--no-fonsim-install', action='store_true',
                        help="do not create FONSim's environment when it is missing")
    parser.add_argument('--skip-rig', action='store_true')
    parser.add_argument('--integrators-only', action='store_true',
                        help="only our integrators against scipy's Radau, printed (part 6)")
    args = parser.parse_args()
    sizes = QUICK if args.quick else FULL
    if args.integrators_only:
        report = '\n'.join(integrator_section(sizes)) + '\n'
        if args.out:
            Path(args.out).write_text(report)
        print('\n' + report)
        return
    with tempfile.TemporaryDirectory(prefix='bench_dynamic_') as folder:
        report = run(args, sizes, Path(folder))
    out = Path(args.out) if args.out else (None if args.quick else RESULTS)
    if out is not None:
        out.write_text(report)
        print(f'wrote {out}')
    if args.quick or out is None:
        print('\n' + report)


if __name__ == '__main__':
    main()
