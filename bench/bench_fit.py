"""
``softseq fit`` on synthetic inflations: do its intervals hold what they claim, does its noise
estimate see the noise, does its criterion name the law, and what a fit costs.

    python bench/bench_fit.py [--quick] [--out FILE]

Synthetic measurements come from a known law on a thin sphere (R = 10 mm, H = 1 mm; Gent
mu = 300 kPa, Jm = 20 to a stretch of 2.6; Ogden mu = 300 kPa, alpha = 5 to 3.0; Mooney-Rivlin
C1 = 150 kPa, C2 = 15 kPa to 4.0), rows evenly spaced in volume from rest, with seeded Gaussian
noise of a share of the largest pressure. Per case:

1. Coverage: in how many of the trials the Jacobian 95 % interval and the parametric
   bootstrap's percentile interval hold each true parameter, with R given and with the rest
   volume fitted, on 80 rows at 1 % noise and on 30 rows at 5 % (where the linearisation is
   tested harder), and the median width of the bootstrap interval over the Jacobian one.
2. The noise estimate (third divided differences, trimmed) against the median absolute
   deviation of chord residuals that table smoothing uses, over row counts: mean and spread of
   estimate / truth and how often it leaves +-20 %.
3. The criterion: how often AICc and BIC name the true law, each law in turn the truth
   (neo-Hookean is a special case of the three others: there they must decline a parameter).
4. Time per fit, with R given and fitted, and with 200 bootstrap resamples.

The full mode (100 trials, 200 bootstrap resamples each) writes ``bench/fit_results.md`` (or
``--out``); ``--quick`` (10 trials, 20 resamples, fewer seeds) prints the tables and writes
nothing.
"""

import argparse
from pathlib import Path
import sys
import time

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from softseq_ros.segments.fit import (  # noqa: E402
    BOOTSTRAP_RESAMPLES,
    FIT_LAWS,
    Inflation,
    estimate_noise_std,
    fit_law,
    fit_sphere,
    rest_volume_of,
    sphere_pressure,
    sphere_stretch,
)
from softseq_ros.segments.materials import (  # noqa: E402
    ArrudaBoyce,
    Gent,
    MooneyRivlin,
    NeoHookean,
    Ogden,
    Yeoh,
)
from softseq_ros.segments.smoothing import estimate_noise  # noqa: E402

RADIUS, THICKNESS = 0.01, 1e-3
REST = rest_volume_of(RADIUS)
RESULTS = REPO / 'bench' / 'fit_results.md'
# law -> (material, largest stretch measured, true fitted groups)
TRUTHS = {
    'gent': (Gent(300e3, 20.0), 2.6, {'shear_modulus_h_over_r_pa': 30e3, 'jm': 20.0}),
    'ogden': (Ogden((300e3,), (5.0,)), 3.0, {'mu_h_over_r_pa': 30e3, 'alpha': 5.0}),
    'mooney_rivlin': (MooneyRivlin(150e3, 15e3), 4.0,
                      {'c1_h_over_r_pa': 15e3, 'c2_h_over_r_pa': 1.5e3}),
    'yeoh': (Yeoh(150e3, -3e3, 300.0), 3.5,
             {'c1_h_over_r_pa': 15e3, 'c2_h_over_r_pa': -300.0, 'c3_h_over_r_pa': 30.0}),
    'arruda_boyce': (ArrudaBoyce(150e3, 3.0), 2.8,
                     {'shear_modulus_h_over_r_pa': 15e3, 'lambda_m': 3.0}),
}
CRITERION_TRUTHS = {
    'neo_hookean': (NeoHookean(300e3), 3.0),
    'gent': (Gent(300e3, 20.0), 2.6),
    'ogden': (Ogden((300e3,), (5.0,)), 3.0),
    'mooney_rivlin': (MooneyRivlin(150e3, 15e3), 4.0),
    'yeoh': (Yeoh(150e3, -3e3, 300.0), 3.5),
    'arruda_boyce': (ArrudaBoyce(100e3, 3.0), 3.8),
}
# (rows, noise as a share of the largest pressure)
SETTINGS = ((80, 0.01), (30, 0.05))


def inflation(material, stretch, rows, share, seed):
    volume = REST * np.linspace(1.0, stretch**3, rows)
    pressure = sphere_pressure(material, sphere_stretch(volume, REST), THICKNESS / RADIUS)
    sigma = share * float(np.max(pressure))
    noisy = pressure + np.random.default_rng(seed).normal(0.0, sigma, rows)
    return Inflation(volume, noisy), sigma


def coverage_rows(trials: int, resamples: int) -> list[str]:
    lines = ['## Coverage of the 95 % intervals', '',
             f'{trials} seeded trials per case, {resamples} bootstrap resamples per trial; '
             'a correct 95 % interval holds the truth in 95 of 100 (90 or fewer: 1.1 %).', '',
             '| law | radius | rows | noise | parameter | Jacobian held | bootstrap held | '
             'bootstrap / Jacobian width |', '|---|---|---:|---:|---|---:|---:|---:|']
    print('\n'.join(lines), flush=True)
    for law, (material, stretch, truth) in TRUTHS.items():
        for radius in (RADIUS, None):
            for rows, share in SETTINGS:
                names = {**truth, **({} if radius else {'rest_volume_m3': REST})}
                jacobian = dict.fromkeys(names, 0)
                bootstrap = dict.fromkeys(names, 0)
                widths = {name: [] for name in names}
                for seed in range(trials):
                    measured, _ = inflation(material, stretch, rows, share, seed)
                    fit = fit_law(law, [measured], radius=radius, bootstrap=resamples,
                                  seed=seed)
                    for name, value in names.items():
                        estimate = fit.estimates[name]
                        jacobian[name] += estimate.holds(value)
                        low, high = estimate.bootstrap
                        bootstrap[name] += low <= value <= high
                        widths[name].append((high - low)
                                            / (estimate.interval[1] - estimate.interval[0]))
                for name in names:
                    lines.append(f'| {law} | {"given" if radius else "fitted"} | {rows} | '
                                 f'{share * 100:g} % | {name} | {jacobian[name]} / {trials} | '
                                 f'{bootstrap[name]} / {trials} | '
                                 f'{np.median(widths[name]):.2f} |')
                    print(lines[-1], flush=True)
    return lines + ['']


def noise_rows(seeds: int) -> list[str]:
    lines = ['## Noise estimate', '',
             f'Gent curve, 1 % noise, {seeds} seeds per row count: estimate / true deviation.',
             '', '| rows | estimator | mean | spread | outside +-20 % |',
             '|---:|---|---:|---:|---:|']
    print('\n'.join(lines), flush=True)
    material, stretch, _ = TRUTHS['gent']
    for rows in (30, 60, 100, 200):
        ratios = {'third differences, trimmed (fit)': [],
                  'MAD of chord residuals (smoothing)': []}
        for seed in range(seeds):
            measured, sigma = inflation(material, stretch, rows, 0.01, seed)
            ratios['third differences, trimmed (fit)'].append(
                estimate_noise_std(measured.volume, measured.pressure) / sigma)
            ratios['MAD of chord residuals (smoothing)'].append(
                estimate_noise(measured.volume, measured.pressure) / sigma)
        for name, values in ratios.items():
            values = np.asarray(values)
            lines.append(f'| {rows} | {name} | {values.mean():.3f} | {values.std():.3f} | '
                         f'{np.mean(np.abs(values - 1.0) > 0.2) * 100:.0f} % |')
            print(lines[-1], flush=True)
    return lines + ['']


def criterion_rows(trials: int) -> list[str]:
    lines = ['## The criterion names the law', '',
             f'{trials} seeded trials per true law, 80 rows, 1 % noise, R given, every law '
             'fitted.', '', '| true law | AICc names it | BIC names it | AICc chose instead |',
             '|---|---:|---:|---|']
    print('\n'.join(lines), flush=True)
    for law, (material, stretch) in CRITERION_TRUTHS.items():
        by_aicc = by_bic = 0
        others: dict[str, int] = {}
        for seed in range(trials):
            measured, _ = inflation(material, stretch, 80, 0.01, 500 + seed)
            fit = fit_sphere([measured], radius=RADIUS, bootstrap=0)
            by_aicc += fit.chosen == law
            by_bic += fit.by_bic() == law
            if fit.chosen != law:
                others[fit.chosen] = others.get(fit.chosen, 0) + 1
        instead = ', '.join(f'{name} {count}' for name, count in sorted(others.items())) or '-'
        lines.append(f'| {law} | {by_aicc} / {trials} | {by_bic} / {trials} | {instead} |')
        print(lines[-1], flush=True)
    return lines + ['']


def timing_rows(repeats: int) -> list[str]:
    lines = ['## Time per fit', '', f'80 rows, best of {repeats}.', '',
             '| law | radius given | radius fitted | given, 200 bootstrap resamples |',
             '|---|---:|---:|---:|']
    print('\n'.join(lines), flush=True)
    # A first fit imports scipy.stats: not the fit's time.
    fit_law('neo_hookean', [inflation(NeoHookean(1e5), 2.0, 20, 0.01, 0)[0]], radius=RADIUS)
    for law in FIT_LAWS:
        material, stretch = CRITERION_TRUTHS[law]
        measured, _ = inflation(material, stretch, 80, 0.01, 0)
        times = []
        for radius, resamples in ((RADIUS, 0), (None, 0), (RADIUS, 200)):
            best = np.inf
            for _ in range(repeats):
                start = time.perf_counter()
                fit_law(law, [measured], radius=radius, bootstrap=resamples)
                best = min(best, time.perf_counter() - start)
            times.append(best)
        lines.append(f'| {law} | {times[0] * 1e3:.1f} ms | {times[1] * 1e3:.1f} ms | '
                     f'{times[2]:.2f} s |')
        print(lines[-1], flush=True)
    # The promise: a 600-row measurement with every law, as softseq fit runs it (the
    # radius fitted, the default bootstrap), under 5 s.
    measured, _ = inflation(*CRITERION_TRUTHS['gent'], 600, 0.01, 0)
    best = np.inf
    for _ in range(repeats):
        start = time.perf_counter()
        fit_sphere([measured])
        best = min(best, time.perf_counter() - start)
    lines += ['', f'600 rows, every law ({len(FIT_LAWS)}), radius fitted, the default '
              f'{BOOTSTRAP_RESAMPLES} bootstrap resamples each: {best:.2f} s (best of '
              f'{repeats}; the promise: under 5 s).']
    print(lines[-1], flush=True)
    return lines + ['']


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--quick', action='store_true', help='10 trials; write nothing')
    parser.add_argument('--out', type=Path, default=None, help='Markdown file to write')
    args = parser.parse_args(argv)
    trials, resamples, seeds = (10, 20, 50) if args.quick else (100, 200, 400)
    lines = ['# softseq fit on synthetic inflations', '']
    lines += coverage_rows(trials, resamples)
    lines += noise_rows(seeds)
    lines += criterion_rows(trials)
    lines += timing_rows(1 if args.quick else 3)
    out = args.out or (None if args.quick else RESULTS)
    if out is not None:
        out.write_text('\n'.join(lines).rstrip('\n') + '\n', encoding='utf-8')
        print(f'wrote {out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
