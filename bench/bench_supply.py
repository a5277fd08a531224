"""
The paper scene and the Fig. 1 asymmetric pair behind an ideal syringe and behind 1 mL and 10 mL
of trapped air: sequence type, snap-throughs and the map's speed, in one run.

    python bench/bench_supply.py [--quick] [--out FILE]

Each scene is loaded as shipped and given a ``supply`` block (isothermal air at 101325 Pa, no
line compliance); per case it prints the sequence type (``softseq classify``), the snaps of an
inflation over the whole range and back (injected volume and pressure where each starts) and
the time to assemble the map and its transition graph, as a ratio to the ideal syringe's in the
same run (best of 3). The full mode writes the table to ``bench/supply_results.md`` (or
``--out``); ``--quick`` (the Fig. 1 pair, ideal and 1 mL, once each) prints it and writes
nothing.
"""

import argparse
from dataclasses import replace
from pathlib import Path
import sys
import time

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from softseq_ros.quasistatic.equilibrium import (  # noqa: E402
    EquilibriumMap,
    classify,
    inflate_and_deflate,
)
from softseq_ros.quasistatic.graph import transition_graph  # noqa: E402
from softseq_ros.scene.loader import load_scene, scene_from_dict  # noqa: E402

SCENES = ('paper', 'fig1_asymmetric')
AIR_M3 = (None, 1.0e-6, 1.0e-5)
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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--quick', action='store_true', help='two cases once; write nothing')
    parser.add_argument('--out', type=Path, default=None, help='Markdown file to write')
    args = parser.parse_args(argv)
    lines = ['| scene | supply | sequence type | inflation snaps | deflation snaps | '
             'map and graph (ratio to the ideal syringe) |', '|---|---|---|---|---|---|']
    print('\n'.join(lines), flush=True)
    scenes, airs = (('fig1_asymmetric',), AIR_M3[:2]) if args.quick else (SCENES, AIR_M3)
    for name in scenes:
        baseline = None
        for air in airs:
            text, seconds = row(name, air, baseline, 1 if args.quick else REPEATS)
            baseline = seconds if baseline is None else baseline
            lines.append(text)
            print(text, flush=True)
    out = args.out or (None if args.quick else RESULTS)
    if out is not None:
        out.write_text('\n'.join(lines) + '\n', encoding='utf-8')
        print(f'wrote {out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
