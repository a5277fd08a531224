"""
Regenerate config/segments/paper_{bottom,top}.csv: calibrated stand-ins for the paper's segments.

    python tools/make_paper_segments.py            write both tables
    python tools/make_paper_segments.py --check    exit 1 if the committed tables differ

The model is softseq_ros.segments.bulge (membranes bulging as spherical caps + linear side walls).
Two factors are calibrated by root finding and rounded, so the output is deterministic.
"""

import argparse
import math
from pathlib import Path
import sys

import numpy as np
from scipy.optimize import brentq

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from softseq_ros.segments.bulge import BulgeSegment, SegmentGeometry  # noqa: E402
from softseq_ros.segments.materials import Ogden  # noqa: E402

MM = 1e-3
ML = 1e-6

# Table I of the paper; each segment is half of the 222 mm actuator.
SEGMENT_LENGTH = 111 * MM
COMMON = {'segment_length': SEGMENT_LENGTH, 'height': 15 * MM, 'beam_thickness': 5 * MM,
          'cavity_width': 11 * MM, 'wall_length': 4 * MM, 'membrane_length': 6 * MM}
GEOMETRY = {
    'bottom': SegmentGeometry(**COMMON, membrane_thickness=1.0 * MM, wall_thickness=1.0 * MM),
    'top': SegmentGeometry(**COMMON, membrane_thickness=0.5 * MM, wall_thickness=2.0 * MM),
}

# Ecoflex 00-30: initial shear modulus 2 C1 of the published Yeoh fit (C1 = 17 kPa).
SHEAR_MODULUS = 34e3
# One-term Ogden exponent. With alpha = 3 the tension of a large cap grows like its radius, so
# its Laplace pressure levels off at 4 H mu1 / a: the level plateau the paper's top segment shows.
OGDEN_ALPHA = 3.0

# Calibration targets (paper, Section IV and Fig. 7).
PLATEAU_INJECTED = 40 * ML       # simulated plateau reached at 40 mL ...
PLATEAU_REFERENCE = 65 * ML      # ... measured against the pressure at the end of the run
PLATEAU_FRACTION = 0.95          # 'reached' = 95 % of that pressure
STEP5_INJECTED = 60 * ML         # step 5 in the simulation
STEP5_TOP_BEND = 2.0 * math.pi   # assumed ('curling over itself'): one full turn at step 5

# Table ranges (injected volume per segment) and size.
MAX_INJECTED = {'bottom': 35 * ML, 'top': 85 * ML}
ROWS = 320
HEADER = 'volume_m3,pressure_pa,curvature_per_m'


def material() -> Ogden:
    return Ogden((2.0 * SHEAR_MODULUS / OGDEN_ALPHA,), (OGDEN_ALPHA,))


def segments(wall_factor: float, curvature_transfer: float) -> dict[str, BulgeSegment]:
    return {name: BulgeSegment(geo, material(), curvature_transfer, wall_factor)
            for name, geo in GEOMETRY.items()}


def combined_path(segs: dict[str, BulgeSegment]) -> dict[str, np.ndarray]:
    """Equilibrium of the two segments parametrised by the top caps' stretch."""
    lam = np.linspace(1.0, 8.0, 70001)
    top, bottom = segs['top'], segs['bottom']
    p_top = top.pressure(lam)
    p_bottom = bottom.pressure(lam)
    if np.any(np.diff(p_bottom) <= 0.0) or np.any(np.diff(p_top) <= 0.0):
        raise RuntimeError('cap pressure is not monotone; the path below assumes it is')
    lam_bottom = np.interp(p_top, p_bottom, lam)
    v_top = top.volume(lam) - top.rest_volume
    v_bottom = bottom.volume(lam_bottom) - bottom.rest_volume
    return {'injected': v_top + v_bottom, 'pressure': p_top, 'top_volume': v_top,
            'top_curvature': top.curvature(lam), 'bottom_curvature': bottom.curvature(lam_bottom)}


def plateau_miss(wall_factor: float) -> float:
    path = combined_path(segments(wall_factor, 1.0))
    p_ref = np.interp(PLATEAU_REFERENCE, path['injected'], path['pressure'])
    reached = np.interp(PLATEAU_FRACTION * p_ref, path['pressure'], path['injected'])
    return reached - PLATEAU_INJECTED


def calibrate() -> tuple[float, float]:
    wall_factor = round(brentq(plateau_miss, 0.5, 5.0, xtol=1e-7), 3)
    path = combined_path(segments(wall_factor, 1.0))
    kappa = np.interp(STEP5_INJECTED, path['injected'], path['top_curvature'])
    curvature_transfer = round(STEP5_TOP_BEND / (kappa * SEGMENT_LENGTH), 4)
    return wall_factor, curvature_transfer


def table_stretches(seg: BulgeSegment, max_injected: float) -> np.ndarray:
    """Stretches spread evenly along the (volume, pressure, curvature) curve."""
    lam_max = brentq(lambda x: seg.volume(x) - seg.rest_volume - max_injected, 1.0, 20.0,
                     xtol=1e-12)
    lam = np.linspace(1.0, lam_max, 20001)
    cols = [seg.volume(lam), seg.pressure(lam), seg.curvature(lam)]
    steps = sum((np.diff(c) / (c[-1] - c[0])) ** 2 for c in cols)
    arc = np.concatenate([[0.0], np.cumsum(np.sqrt(steps))])
    return np.interp(np.linspace(0.0, arc[-1], ROWS), arc, lam)


def render(name: str, seg: BulgeSegment, wall_factor: float, curvature_transfer: float,
           summary: dict[str, float]) -> str:
    geo = seg.geometry
    mat = seg.material
    lam = table_stretches(seg, MAX_INJECTED[name])
    v, p, k = seg.volume(lam), seg.pressure(lam), seg.curvature(lam)
    v[0], p[0], k[0] = seg.rest_volume, 0.0, 0.0
    plateau = 4.0 * geo.membrane_thickness * mat.mus[0] / geo.cap_base_radius
    lines = [
        f'# paper_{name}.csv: CALIBRATED STAND-IN for the {name} segment of Milana et al. 2018',
        "# (bi-segmented soft actuator). NOT the paper's Abaqus curves, which are unavailable.",
        '# Regenerate: python tools/make_paper_segments.py (model: softseq_ros.segments.bulge)',
        '# Model: each membrane bulges as a clamped spherical cap (bulge test), uniform',
        '#   equibiaxial stretch lam = sqrt(1 + (h/a)^2), tension N = H/(2 lam) dW/dlam,',
        '#   p = 2N/R_cap; volume = cavity + n caps + linear side-wall swelling C_w p;',
        '#   curvature = n * eta * b * (s/2a - 1) / (L * arm), s = cap meridian arc.',
        '# Geometry (Table I): segment length L = 111 mm (222/2), height 15 mm, beam 5 mm,',
        f'#   cavity width 11 mm, wall 4 mm + membrane 6 mm pitch -> n = {geo.membrane_count}'
        ' membranes,',
        f'#   membrane thickness H = {geo.membrane_thickness / MM:g} mm, side-wall thickness'
        f' d = {geo.wall_thickness / MM:g} mm.',
        f"# Assumed: round cap of the membrane's area (6 x 11 mm), base radius a ="
        f' {geo.cap_base_radius / MM:.4f} mm;',
        f'#   cavity 11 mm x {geo.cavity_depth / MM:g} mm (15 - 5 - H) x 111 mm ='
        f' {geo.cavity_volume / ML:.4f} mL; arm = 15 - H/2 - 2.5 = {geo.bending_arm / MM:g} mm;',
        '#   caps independent (contact between neighbouring bulges neglected), beam inextensible,',
        '#   all membranes of a segment equal (no localisation), side walls linear.',
        f'# Material: Ecoflex 00-30 as one-term Ogden, mu1 = {mat.mus[0]:.2f} Pa, alpha ='
        f' {OGDEN_ALPHA:g};',
        f'#   initial shear modulus {SHEAR_MODULUS:g} Pa = 2 C1 of the published Yeoh fit',
        '#   (C1 = 17 kPa, C2 = -0.2 kPa, C3 = 0.023 kPa, Sorotoki toolkit). alpha = 3 (chosen)',
        f'#   makes large caps level off at p = 4 H mu1 / a = {plateau:.1f} Pa (the plateau).',
        '#   The Arruda-Boyce values of Martinez et al. 2013 used by the paper were not found.',
        f'# Calibrated: wall_compliance_factor = {wall_factor:g} (x thin-tube closed form'
        ' g V0/(4 mu d)):',
        f'#   C_w = {seg.cavity_compliance:.6e} m^3/Pa; target: combined pressure reaches'
        ' 95 % of its',
        '#   65 mL value at 40 mL injected (paper: plateau reached at 40 mL).',
        f'# Calibrated: curvature_transfer eta = {curvature_transfer:g}; target (assumed: the',
        '#   top "curls over itself"): top segment bent one full turn (2 pi rad) at step 5,',
        '#   60 mL injected. Bending from side-wall swelling is neglected.',
        '# Resulting combined path (bottom + top on one syringe): top takes'
        f' {summary["share"]:.0%} of the flow',
        f'#   from 40 to 70 mL; pressure {summary["p25"]:.0f} / {summary["p40"]:.0f} /'
        f' {summary["p65"]:.0f} Pa at 25 / 40 / 65 mL.',
        f'# Range: unpressurised to {MAX_INJECTED[name] / ML:g} mL injected into this segment;'
        ' SI units.',
        HEADER,
    ]
    for row in zip(v, p, k):
        lines.append(','.join(f'{x:.9e}' for x in row))
    return '\n'.join(lines) + '\n'


def build() -> dict[str, str]:
    wall_factor, curvature_transfer = calibrate()
    segs = segments(wall_factor, curvature_transfer)
    path = combined_path(segs)
    u = path['injected']
    at = {x: np.interp(x * ML, u, path['pressure']) for x in (25, 40, 65)}
    v40, v70 = np.interp([40 * ML, 70 * ML], u, path['top_volume'])
    summary = {'share': (v70 - v40) / (30 * ML), 'p25': at[25], 'p40': at[40], 'p65': at[65]}
    return {name: render(name, seg, wall_factor, curvature_transfer, summary)
            for name, seg in segs.items()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--check', action='store_true',
                        help='compare with the committed tables instead of writing them')
    parser.add_argument('--out-dir', type=Path, default=REPO / 'config' / 'segments',
                        help='folder of the tables (default: config/segments)')
    args = parser.parse_args(argv)
    tables = build()
    stale = []
    for name, text in tables.items():
        path = args.out_dir / f'paper_{name}.csv'
        if args.check:
            if not path.is_file() or path.read_text() != text:
                stale.append(str(path))
        else:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(text)
            print(f'wrote {path}')
    if stale:
        print(f'out of date (run tools/make_paper_segments.py): {", ".join(stale)}',
              file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
