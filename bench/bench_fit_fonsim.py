"""
``softseq fit``'s laws on FONSim's measured latex balloon: each law's fit and its residuals
against the measurement's noise, written into docs/fit.md.

    python bench/bench_fit_fonsim.py [--fonsim-python PATH] [--csv FILE]
    python bench/bench_fit_fonsim.py --quick

The measurement is FONSim's package data ``fonsim/resources/Measurement_60mm_balloon_actuator_01
.csv`` (the curve FONSim's FreeActuator uses when it is given none): one inflation of a latex
balloon actuator, 56 rows of time [s], volume [ml] and pressure [mbar]. It is read by FONSim's
own reader (``fonsim.data.dataseries.DataSeries``) in FONSim's interpreter, never here: FONSim
is never imported by softseq_ros and is not in requirements.txt (bench/README.md says how its
environment is made). Converted to SI: the volume (mL -> m^3) is the volume injected from the
syringe's zero (its first row is 1.00 mL at 22 mbar), the pressure (mbar -> Pa) is gauge, as
FONSim reads it (its ``pressure_reference`` 'relative').

The project's fit (``softseq_ros.segments.fit.fit_law``, as ``softseq fit`` runs it) needs the
balloon's whole volume, and the file has no rest volume, radius or thickness. So no radius is
given: each law fits its rest volume v0 (docs/fit.md, "What p(v) can tell"), and the whole
volume is c + injected, with c the balloon's volume at the syringe's zero, which the file does
not hold either. c is profiled for each law (fits on a grid of c from 0 to 20 mL, refined
between the best grid point's neighbours; its 95 % interval is where the chi-square stays
within t^2 s^2 of its least, s^2 its least per degree of freedom, each end found between grid
points), then the law is fitted at its c with the
Jacobian and bootstrap intervals. Those intervals hold c fixed; AICc counts c as one more
parameter of every law, so the differences between laws are the fit's own. The noise is
estimated from the raw rows as ``softseq fit`` does (it does not depend on c).

The full run writes the results table between the markers of docs/fit.md (reading the file at
write time) and the figure docs/fit_fonsim.png. ``--csv`` also keeps the converted rows.
``--quick``: a check that it runs, coarser grid and 20 bootstrap resamples, printed only; it
uses the measurement when FONSim's environment exists and otherwise (say in CI) a synthetic
balloon sampled as the measurement is (seeded, 1 mbar steps), and says which.
"""

import argparse
import json
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import time

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import numpy as np  # noqa: E402
from scipy.optimize import brentq, minimize_scalar  # noqa: E402
from scipy.stats import t as student_t  # noqa: E402

from softseq_ros.segments.fit import (  # noqa: E402
    FIT_LAWS,
    Inflation,
    akaike_weights,
    estimate_noise_std,
    fit_law,
    information_criteria,
    sphere_pressure,
    sphere_stretch,
)
from softseq_ros.segments.materials import Gent  # noqa: E402

DOC = REPO / 'docs' / 'fit.md'
FIGURE = REPO / 'docs' / 'fit_fonsim.png'
START = '<!-- bench_fit_fonsim: start -->'
END = '<!-- bench_fit_fonsim: end -->'
RESOURCE = 'resources/Measurement_60mm_balloon_actuator_01.csv'
ML, MBAR, KPA = 1e-6, 100.0, 1e-3
# The units FONSim's file gives, and their factor to SI.
UNITS = {'ml': ML, 'mbar': MBAR}
LAW_LABELS = {'neo_hookean': 'neo-Hookean', 'mooney_rivlin': 'Mooney-Rivlin', 'gent': 'Gent',
              'ogden': 'Ogden', 'yeoh': 'Yeoh', 'arruda_boyce': 'Arruda-Boyce'}

# Run in FONSim's interpreter: its package data through its own reader, as JSON to argv[1].
EXTRACT = r"""
import contextlib, importlib.metadata, importlib.resources, io, json, sys
with contextlib.redirect_stdout(io.StringIO()):   # FONSim prints a banner at import
    from fonsim.data import dataseries
path = importlib.resources.files('fonsim').joinpath(sys.argv[2])
series = dataseries.DataSeries(str(path))
with open(sys.argv[1], 'w') as out:
    json.dump({'labels': list(series.labels), 'units': list(series.units),
               'rows': series.array.tolist(), 'path': str(path),
               'title': path.read_text().splitlines()[0],
               'version': importlib.metadata.version('fonsim')}, out)
"""


def cache_folder() -> Path:
    return Path(os.environ.get('XDG_CACHE_HOME') or Path.home() / '.cache') / 'softseq_ros'


def fonsim_python(named: str | None) -> tuple[Path | None, str]:
    """FONSim's interpreter, or (None, why not). Nothing is installed here (bench/README.md)."""
    python = Path(named) if named else cache_folder() / 'fonsim-venv' / 'bin' / 'python'
    if not python.exists():
        return None, (f"FONSim's environment is not installed ({python} missing; "
                      'bench/README.md, "Dynamic model against FONSim", says how)')
    return python, ''


def extract(python: Path, folder: Path) -> dict:
    """The measurement as FONSim reads it: labels, units, rows, its file and FONSim's version."""
    out = folder / 'fonsim_balloon.json'
    done = subprocess.run([str(python), '-c', EXTRACT, str(out), RESOURCE],
                          capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f'reading the balloon in FONSim failed: {done.stderr.strip()[-800:]}')
    return json.loads(out.read_text())


def to_si(data: dict) -> tuple[np.ndarray, np.ndarray]:
    """Injected volume [m^3] and gauge pressure [Pa], after checking the file's units."""
    labels = [label.lower() for label in data['labels']]
    units = [unit.lower() for unit in data['units']]
    columns = {}
    for name in ('volume', 'pressure'):
        index = labels.index(name)
        if units[index] not in UNITS:
            raise SystemExit(f"FONSim's balloon: column {name} in {units[index]!r}, not one of "
                             f'{sorted(UNITS)}')
        columns[name] = np.asarray([row[index] for row in data['rows']]) * UNITS[units[index]]
    return columns['volume'], columns['pressure']


def synthetic() -> tuple[dict, np.ndarray, np.ndarray]:
    """A Gent balloon sampled as the measurement is: 56 rows of 1 mL, 1 mbar steps, seeded."""
    injected = np.arange(1, 57) * 1.003 * ML
    rest, offset = 2.0 * ML, 1.0 * ML
    pressure = sphere_pressure(Gent(450e3, 25.0), sphere_stretch(injected + offset, rest), 0.1)
    noisy = pressure + np.random.default_rng(0).normal(0.0, 150.0, injected.size)
    measured = np.round(noisy / MBAR) * MBAR
    data = {'title': 'synthetic Gent balloon (FONSim not installed)', 'version': None,
            'path': 'synthetic', 'labels': ['Volume', 'Pressure'], 'units': ['ml', 'mbar']}
    return data, injected, measured


def profile(law: str, injected: np.ndarray, pressure: np.ndarray, noise: float,
            grid: np.ndarray) -> dict:
    """c (the volume at the syringe's zero) that serves ``law`` best, and its 95 % interval."""
    def chi_square(c: float) -> float:
        return fit_law(law, [Inflation(injected + c, pressure, 'balloon')], [noise]).chi_square

    values = np.array([chi_square(c) for c in grid])
    best = int(np.argmin(values))
    low, high = grid[max(best - 1, 0)], grid[min(best + 1, grid.size - 1)]
    found = minimize_scalar(chi_square, bounds=(low, high), method='bounded',
                            options={'xatol': 1e-3 * ML})
    c = float(found.x) if found.fun <= values[best] else float(grid[best])
    least = min(float(found.fun), float(values[best]))
    fit = fit_law(law, [Inflation(injected + c, pressure, 'balloon')], [noise])
    dof = fit.rows - fit.parameters - 1
    allowed = least + float(student_t.ppf(0.975, dof))**2 * least / dof
    inside = values <= allowed
    # The contiguous run of grid points around the least (a second valley is not its
    # interval), each end then found between its grid point and the next one out.
    lo = hi = best
    while lo > 0 and inside[lo - 1]:
        lo -= 1
    while hi < grid.size - 1 and inside[hi + 1]:
        hi += 1
    ends = []
    for end, outer in ((lo, lo - 1), (hi, hi + 1)):
        if 0 <= outer < grid.size:
            inner = c if end == best else float(grid[end])
            ends.append(brentq(lambda x: chi_square(x) - allowed, inner, float(grid[outer]),
                               xtol=1e-3 * ML))
        else:
            ends.append(float(grid[end]))   # the range searched ends first
    edge = min(c - grid[0], grid[-1] - c) < 1e-2 * ML
    return {'c': c, 'interval': (min(ends[0], c), max(ends[1], c)), 'edge': edge,
            'grid': grid, 'chi_square': values}


def fit_all(injected: np.ndarray, pressure: np.ndarray, grid: np.ndarray,
            resamples: int) -> tuple[float, dict]:
    noise = estimate_noise_std(injected, pressure)
    results = {}
    for law in FIT_LAWS:
        start = time.perf_counter()
        found = profile(law, injected, pressure, noise, grid)
        fit = fit_law(law, [Inflation(injected + found['c'], pressure, 'balloon')], [noise],
                      bootstrap=resamples, seed=0)
        residuals = pressure - fit.pressure(injected + found['c'])
        # c is one more fitted parameter of every law.
        aicc, _ = information_criteria(fit.chi_square, fit.rows, fit.parameters + 1)
        results[law] = {'fit': fit, 'profile': found, 'aicc': aicc, 'residuals': residuals,
                        'reduced': fit.chi_square / (fit.rows - fit.parameters - 1),
                        'seconds': time.perf_counter() - start}
        print(f'{law}: c {found["c"] / ML:.3f} mL, reduced chi-square '
              f'{results[law]["reduced"]:.4g} ({results[law]["seconds"]:.1f} s)', flush=True)
    least = min(r['aicc'] for r in results.values())
    weights = akaike_weights([r['aicc'] for r in results.values()])
    for result, weight in zip(results.values(), weights):
        result['delta'] = result['aicc'] - least
        result['weight'] = weight
    return noise, results


def _number(name: str, value: float) -> tuple[float, str]:
    if name.endswith('_pa'):
        return value * KPA, ' kPa'
    if name.endswith('_m3'):
        return value / ML, ' mL'
    return value, ''


def parameter_text(fit) -> str:
    parts = []
    for name, estimate in fit.estimates.items():
        if not estimate.fitted:
            continue
        value, unit = _number(name, estimate.value)
        low, high = (_number(name, x)[0] for x in estimate.interval)
        text = f'{name} {value:.4g}{unit} ({low:.4g} to {high:.4g}'
        if estimate.bootstrap is not None:
            b_low, b_high = (_number(name, x)[0] for x in estimate.bootstrap)
            text += f'; bootstrap {b_low:.4g} to {b_high:.4g}'
        parts.append(text + ')')
    return '; '.join(parts)


def table(noise: float, results: dict, resamples: int) -> list[str]:
    chosen = min(results, key=lambda law: results[law]['aicc'])
    lines = [
        "| law | c: volume at the syringe's zero [mL] (95 % profile) | fitted parameters "
        f'(95 % CI; bootstrap, {resamples} resamples) | reduced chi-square | delta AICc '
        '(weight) | residuals: RMS / noise, largest / noise, within 2 noise |',
        '|---|---|---|---:|---:|---|']
    for law, result in results.items():
        found, residuals = result['profile'], result['residuals']
        low, high = found['interval']
        where = f'{found["c"] / ML:.2f} ({low / ML:.2f} to {high / ML:.2f}'
        where += ', at the edge searched)' if found['edge'] else ')'
        rms = float(np.sqrt(np.mean(residuals**2)))
        within = int(np.sum(np.abs(residuals) <= 2.0 * noise))
        name = f'**{LAW_LABELS[law]}**' if law == chosen else LAW_LABELS[law]
        lines.append(f'| {name} | {where} | {parameter_text(result["fit"])} | '
                     f'{result["reduced"]:.4g} | {result["delta"]:.1f} ({result["weight"]:.2g}) '
                     f'| {rms / noise:.3g}, {np.max(np.abs(residuals)) / noise:.3g}, '
                     f'{within} / {residuals.size} |')
    return lines


def plot(injected: np.ndarray, pressure: np.ndarray, noise: float, results: dict,
         out: Path) -> None:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    chosen = min(results, key=lambda law: results[law]['aicc'])
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(6.4, 5.6), sharex=True,
                                      gridspec_kw={'height_ratios': (2.2, 1.0)})
    top.plot(injected / ML, pressure * KPA, 'o', ms=3, mfc='none', color='0.35',
             label='measured (FONSim package data)')
    grid = np.linspace(injected[0], injected[-1], 400)
    for k, (law, result) in enumerate(results.items()):
        colour = f'C{k}'
        c = result['profile']['c']
        style = {'lw': 1.8 if law == chosen else 0.9, 'ls': '-' if law == chosen else '--'}
        top.plot(grid / ML, result['fit'].pressure(grid + c) * KPA, color=colour,
                 label=f'{LAW_LABELS[law]}: $\\Delta$AICc {result["delta"]:.0f}, '
                       f'$\\chi^2_\\nu$ {result["reduced"]:.3g}', **style)
        bottom.plot(injected / ML, result['residuals'] * KPA, '.', ms=3, color=colour)
    bottom.axhspan(-2 * noise * KPA, 2 * noise * KPA, color='0.85', lw=0)
    bottom.axhline(0.0, color='0.5', lw=0.5)
    top.set_ylabel('gauge pressure [kPa]')
    bottom.set_ylabel('residual [kPa]')
    bottom.set_xlabel('volume injected [mL]')
    top.legend(fontsize=7, frameon=False)
    fig.tight_layout()
    fig.savefig(out, dpi=150)
    plt.close(fig)


def write_doc(block: list[str]) -> None:
    """The block between the markers of docs/fit.md, read now (others may have edited it)."""
    text = DOC.read_text(encoding='utf-8')
    if START not in text or END not in text:
        raise SystemExit(f'{DOC}: the markers {START} and {END} are missing')
    head, rest = text.split(START, 1)
    _, tail = rest.split(END, 1)
    DOC.write_text(head + START + '\n' + '\n'.join(block) + '\n' + END + tail, encoding='utf-8')


def write_csv(path: Path, data: dict, injected: np.ndarray, pressure: np.ndarray,
              chosen: str, c: float) -> None:
    lines = [f'# {data["title"]}: FONSim {data["version"]} package data ({RESOURCE})',
             "# source columns: Time [s], Volume [ml] (injected from the syringe's zero), "
             'Pressure [mbar] (gauge); converted: mL x 1e-6 = m^3, mbar x 100 = Pa',
             f'# volume_m3: the whole volume, c + injected, with c = {c!r} m^3 (the {chosen} '
             "law's profiled volume at the syringe's zero; bench/bench_fit_fonsim.py)",
             'injected_m3,volume_m3,pressure_pa']
    lines += [f'{u!r},{u + c!r},{p!r}' for u, p in zip(injected.tolist(), pressure.tolist())]
    path.write_text('\n'.join(lines) + '\n', encoding='utf-8')


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--quick', action='store_true',
                        help='a coarse check that it runs; prints, writes nothing')
    parser.add_argument('--fonsim-python', default=None,
                        help='the interpreter of an environment with FONSim installed')
    parser.add_argument('--csv', type=Path, default=None,
                        help='also keep the measurement, converted to SI, in this file')
    args = parser.parse_args(argv)
    python, why = fonsim_python(args.fonsim_python)
    with tempfile.TemporaryDirectory(prefix='bench_fit_fonsim_') as folder:
        if python is not None:
            data = extract(python, Path(folder))
            injected, pressure = to_si(data)
            print(f'{data["title"]}: {injected.size} rows from FONSim {data["version"]} '
                  f'({data["path"]})', flush=True)
        elif args.quick:
            print(f'FONSim skipped: {why}; a synthetic balloon instead', flush=True)
            data, injected, pressure = synthetic()
        else:
            raise SystemExit(why)
    step, resamples = (1.0 * ML, 20) if args.quick else (0.25 * ML, 200)
    grid = np.arange(0.0, 20.0 * ML + 0.5 * step, step)
    noise, results = fit_all(injected, pressure, grid, resamples)
    chosen = min(results, key=lambda law: results[law]['aicc'])
    peak = int(np.flatnonzero(np.diff(pressure) < 0)[0]) if np.any(np.diff(pressure) < 0) \
        else int(np.argmax(pressure))
    source = (f'{data["title"]} (FONSim {data["version"]}, `fonsim/{RESOURCE}`)'
              if data['version'] else data['title'])
    block = [
        f'{source}: {injected.size} rows from {injected[0] / ML:.2f} to '
        f'{injected[-1] / ML:.2f} mL injected, a peak of {pressure[peak] * KPA:.1f} kPa at '
        f'{injected[peak] / ML:.2f} mL, {np.max(pressure) * KPA:.1f} kPa at the last; noise '
        f'estimated from the raw rows **{noise:.0f} Pa** (the pressures are whole mbar, 100 Pa). '
        'Written by `python bench/bench_fit_fonsim.py`; the law AICc chooses in bold.', '',
        *table(noise, results, resamples), '']
    print('\n' + '\n'.join(block), flush=True)
    if args.csv is not None:
        write_csv(args.csv, data, injected, pressure, chosen, results[chosen]['profile']['c'])
        print(f'wrote {args.csv}')
    if not args.quick:
        write_doc(block)
        plot(injected, pressure, noise, results, FIGURE)
        print(f'wrote {DOC} (between its markers) and {FIGURE}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
