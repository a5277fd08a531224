"""
The paper scene and the Fig. 1 asymmetric pair behind an ideal syringe, behind 1 mL and 10 mL
of trapped air and behind a pressure regulator: sequence type, snap-throughs and speed, in one run.

    python bench/bench_supply.py [--quick] [--out FILE]

Each scene is loaded as shipped and given a ``supply`` block (isothermal air at 101325 Pa, no
line compliance); per case it prints the sequence type (``softseq classify``), the snaps of an
inflation over the whole range and back (injected volume and pressure where each starts) and
the time to assemble the map and its transition graph, as a ratio to the ideal syringe's in the
same run (best of 3). Behind the regulator the segments are independent hysterons
(softseq_ros.quasistatic.regulator): the pressure rises from 0 to just below where a segment
has no stable piece left (or its highest stable pressure) and back, and the flips are its
snaps; its time is that of the graph of hysterons.

Two speed checks follow, as ratios in the same run: the batch run of the paper scene
(``softseq run``, the whole rig into a bag) behind each line and behind an ideal regulator
(as many commands: its ramp takes the syringe programme's time) against the ideal syringe's,
and the map and graph of the three-segment scenes behind each supply (the promise: under 2 s).

The full mode writes the tables to ``bench/supply_results.md`` (or ``--out``); ``--quick``
(the Fig. 1 pair, ideal, 1 mL and the regulator, once each, the batch runs behind the ideal
syringe and the regulator, and the three-segment graphs) prints them and writes nothing.
"""

import argparse
from dataclasses import replace
from pathlib import Path
import sys
import tempfile
import time

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from softseq_ros.quasistatic.equilibrium import (  # noqa: E402
    EquilibriumMap,
    classify,
    inflate_and_deflate,
)
from softseq_ros.quasistatic.graph import transition_graph  # noqa: E402
from softseq_ros.quasistatic.regulator import hysteron_graph, regulated_path  # noqa: E402
from softseq_ros.scene.loader import load_scene, scene_from_dict  # noqa: E402

SCENES = ('paper', 'fig1_asymmetric')
AIR_M3 = (None, 1.0e-6, 1.0e-5)
REGULATOR = 'regulator'
THREE_SEGMENTS = ('three_segments', 'three_nested_loops')
# Pressure samples of the regulator's ramp up and down.
RAMP_SAMPLES = 4001
REPEATS = 3
RESULTS = REPO / 'bench' / 'supply_results.md'


def with_air(name: str, air: float | None):
    """The shipped scene, behind ``air`` m^3 of trapped air (None: the ideal syringe)."""
    scene = load_scene(name)
    if air is None:
        return scene
    # Through the scene's own validation, as a user's block would go.
    from softseq_ros.yaml_text import parse_yaml
    data = parse_yaml(scene.path.read_text(), str(scene.path))
    data['supply'] = {'trapped_gas_m3': air}
    return replace(scene_from_dict(data, scene.path), path=scene.path)


def behind_regulator(name: str):
    """
    The shipped scene behind an ideal regulator, for as long as its syringe programme runs.

    Up to 95 % of the lowest pressure a segment holds on a stable piece and back, at the rate
    that takes the syringe programme's time (so the rig sends as many commands).
    """
    from softseq_ros.scene.regulator import stable_tops
    from softseq_ros.yaml_text import parse_yaml
    scene = load_scene(name)
    data = parse_yaml(scene.path.read_text(), str(scene.path))
    top = 0.95 * min(stable_tops(scene.segments))
    data['supply'] = {'regulator': {}}
    data['pump'] = {'rate_hz': scene.pump.rate_hz,
                    'pressure_rate_pa_per_s': 2.0 * top / scene.pump.profile.duration(),
                    'legs': [{'inflate_to_pa': top}, {'deflate_to_pa': 0.0}]}
    return replace(scene_from_dict(data, scene.path), path=scene.path)


def snaps_text(path) -> str:
    return ', '.join(f'{e.injected * 1e6:.2f} mL at {e.from_pressure / 1e3:.3f} kPa'
                     for e in path.events) or 'none'


def row(name: str, air: float | None, baseline: float | None,
        repeats: int = REPEATS) -> tuple[str, float]:
    scene = with_air(name, air)
    best = float('inf')
    for _ in range(repeats):
        start = time.perf_counter()
        emap = EquilibriumMap(scene.segments, supply=scene.supply)
        transition_graph(emap)
        best = min(best, time.perf_counter() - start)
    inflation, deflation = inflate_and_deflate(emap, 4001)
    ratio = '1' if baseline is None else f'{best / baseline:.2f}'
    supply = 'ideal syringe' if air is None else f'{air * 1e6:g} mL of air'
    return (f'| {name} | {supply} | {classify(emap)} | {snaps_text(inflation)} | '
            f'{snaps_text(deflation)} | {best:.3f} s ({ratio}) |', best)


def regulator_row(name: str, baseline: float, repeats: int = REPEATS) -> str:
    """The scene's segments behind a regulator: the flips of a pressure ramp up and down."""
    scene = load_scene(name)
    best = float('inf')
    for _ in range(repeats):
        start = time.perf_counter()
        graph = hysteron_graph(scene.segments)
        best = min(best, time.perf_counter() - start)
    ends = [f.pressure for f in graph.flips if f.up and f.target is None]
    top = (1.0 - 1e-9) * min(ends) if ends else max(s.p_high for s in graph.states)
    ramp = np.linspace(0.0, top, RAMP_SAMPLES)
    path = regulated_path(scene.segments, np.concatenate([ramp, ramp[::-1]]))
    names = scene.segment_names

    def flips(up: bool) -> str:
        return ', '.join(f'{names[f.segment]} at {f.pressure / 1e3:.3f} kPa'
                         for f in path.flips if (f.to_volume > f.from_volume) == up) or 'none'
    kind = 'independent hysterons' if path.flips else 'none'
    return (f'| {name} | pressure regulator | {kind} | {flips(True)} | {flips(False)} | '
            f'{best:.4f} s ({best / baseline:.2f}) |')


def batch_rows(repeats: int, supplies: tuple = AIR_M3 + (REGULATOR,)) -> list[str]:
    """
    The paper scene's batch run behind each supply, as a ratio to the ideal syringe's.

    Behind the regulator the programme is :func:`behind_regulator`'s: as many commands.
    """
    import softseq_ros

    lines = ['| supply | batch run of the paper scene | ratio to the ideal syringe |',
             '|---|---|---|']
    print('\n'.join(lines), flush=True)
    baseline = None
    with tempfile.TemporaryDirectory() as folder:
        for air in supplies:
            scene = behind_regulator('paper') if air == REGULATOR else with_air('paper', air)
            best = float('inf')
            for attempt in range(repeats):
                start = time.perf_counter()
                softseq_ros.run(scene, Path(folder) / f'{air}_{attempt}', start_time_ns=0)
                best = min(best, time.perf_counter() - start)
            baseline = best if baseline is None else baseline
            supply = 'ideal syringe' if air is None else 'ideal regulator' \
                if air == REGULATOR else f'{air * 1e6:g} mL of air'
            lines.append(f'| {supply} | {best:.3f} s | {best / baseline:.2f} |')
            print(lines[-1], flush=True)
    return lines


def in_time_rows(repeats: int) -> list[str]:
    """
    The Fig. 1 pair in time behind the syringe and behind a regulator, over the same span.

    The syringe runs fig1_asymmetric_dynamic's programme (to 65 mL and back); the regulator,
    on the same network, ramps to 8 kPa (past both peaks) and back over the same duration, and
    then follows the syringe run's own pressure, sampled every 10 s, as a profile (a leg of
    262 rows, no step passing a row's corner). Best of ``repeats``, ratios to the syringe's.
    """
    import softseq_ros
    from softseq_ros.dynamic.regulated import regulated_network_path
    from softseq_ros.scene.regulator import PressureProgramme, Regulator

    scene = load_scene('fig1_asymmetric_dynamic')
    span = scene.pump.profile.duration()
    syringe_path = softseq_ros.solve(scene)
    rows = np.append(np.arange(0.0, span, 10.0), span)
    measured = np.clip(np.interp(rows, syringe_path.time_s, syringe_path.pressure), 0.0, None)
    ramp = PressureProgramme((0.0, span / 2.0, span), (0.0, 8000.0, 0.0))
    profile = PressureProgramme(tuple(rows.tolist()), tuple(measured.tolist()), (0.0, span))
    cases = [('syringe: to 65 mL and back', lambda: softseq_ros.solve(scene))]
    for label, programme in (('regulator: to 8 kPa and back', ramp),
                             ("regulator: the syringe run's pressure every 10 s", profile)):
        regulator = Regulator(programme, rate_hz=scene.network.rate_hz)
        cases.append((label, lambda regulator=regulator: regulated_network_path(
            scene.segments, scene.network, regulator)))
    lines = [f'| fig1_asymmetric_dynamic, {span:g} s | solve in time | steps | ratio to the '
             'syringe |', '|---|---|---|---|']
    print('\n'.join(lines), flush=True)
    baseline = None
    for label, job in cases:
        best = float('inf')
        for _ in range(repeats):
            start = time.perf_counter()
            path = job()
            best = min(best, time.perf_counter() - start)
        baseline = best if baseline is None else baseline
        lines.append(f'| {label} | {best:.3f} s | {path.steps} | {best / baseline:.2f} |')
        print(lines[-1], flush=True)
    return lines


def three_segment_rows(repeats: int) -> list[str]:
    """The map and graph of three segments behind each supply (the promise: under 2 s)."""
    lines = ['| scene | supply | map and graph | under 2 s |', '|---|---|---|---|']
    print('\n'.join(lines), flush=True)
    for name in THREE_SEGMENTS:
        for air in (*AIR_M3, REGULATOR):
            best = float('inf')
            for _ in range(repeats):
                start = time.perf_counter()
                if air == REGULATOR:
                    hysteron_graph(load_scene(name).segments)
                else:
                    scene = with_air(name, air)
                    transition_graph(EquilibriumMap(scene.segments, supply=scene.supply))
                best = min(best, time.perf_counter() - start)
            supply = ('pressure regulator' if air == REGULATOR else 'ideal syringe'
                      if air is None else f'{air * 1e6:g} mL of air')
            lines.append(f'| {name} | {supply} | {best:.3f} s | {"yes" if best < 2.0 else "no"} |')
            print(lines[-1], flush=True)
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--quick', action='store_true', help='two cases once; write nothing')
    parser.add_argument('--out', type=Path, default=None, help='Markdown file to write')
    args = parser.parse_args(argv)
    lines = ['| scene | supply | sequence type | inflation snaps | deflation snaps | '
             'map and graph (ratio to the ideal syringe) |', '|---|---|---|---|---|---|']
    print('\n'.join(lines), flush=True)
    scenes, airs = (('fig1_asymmetric',), AIR_M3[:2]) if args.quick else (SCENES, AIR_M3)
    repeats = 1 if args.quick else REPEATS
    for name in scenes:
        baseline = None
        for air in airs:
            text, seconds = row(name, air, baseline, repeats)
            baseline = seconds if baseline is None else baseline
            lines.append(text)
            print(text, flush=True)
        lines.append(regulator_row(name, baseline, repeats))
        print(lines[-1], flush=True)
    lines.append('')
    print(flush=True)
    lines += batch_rows(repeats, (None, REGULATOR) if args.quick else AIR_M3 + (REGULATOR,))
    lines.append('')
    print(flush=True)
    lines += in_time_rows(repeats) + ['']
    print(flush=True)
    lines += three_segment_rows(repeats)
    out = args.out or (None if args.quick else RESULTS)
    if out is not None:
        out.write_text('\n'.join(lines) + '\n', encoding='utf-8')
        print(f'wrote {out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
