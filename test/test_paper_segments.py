"""Stand-in tables for the paper's segments: cap closed forms and the calibrated facts."""

import math
from pathlib import Path
import subprocess
import sys

import numpy as np
import pytest

from softseq_ros.segments.bulge import (
    BulgeModelError,
    SegmentGeometry,
    cap_energy,
    cap_height,
    cap_meridian_length,
    cap_pressure,
    cap_sphere_radius,
    cap_stretch,
    cap_volume,
)
from softseq_ros.segments.materials import NeoHookean, Ogden

REPO = Path(__file__).resolve().parents[1]
TABLES = REPO / 'config' / 'segments'
ML = 1e-6
MM = 1e-3
A = 4.5e-3  # an arbitrary cap base radius for the closed-form checks


# --- cap geometry and mechanics against closed forms -------------------------------------------

def test_hemisphere():
    lam = math.sqrt(2.0)  # cap area 2 pi a^2 = twice the base: a hemisphere
    h = cap_height(lam, A)
    assert h == pytest.approx(A, rel=1e-12)
    assert cap_volume(h, A) == pytest.approx(2.0 / 3.0 * math.pi * A**3, rel=1e-12)
    assert cap_sphere_radius(h, A) == pytest.approx(A, rel=1e-12)
    assert cap_meridian_length(h, A) == pytest.approx(math.pi * A, rel=1e-12)
    assert cap_stretch(A, A) == pytest.approx(lam, rel=1e-12)


def test_flat_and_tall_caps():
    assert cap_volume(0.0, A) == 0.0
    assert cap_meridian_length(0.0, A) == pytest.approx(2.0 * A)
    # Past the hemisphere the cap is a sphere of radius R less the small cap of height 2R - h
    # cut off below the base plane (volume pi c^2 (3R - c) / 3 with c = 2R - h).
    h = 3.0 * A
    r = (A**2 + h**2) / (2.0 * h)
    sphere_minus_cap = 4.0 / 3.0 * math.pi * r**3 - math.pi * (2 * r - h)**2 * (r + h) / 3.0
    assert cap_volume(h, A) == pytest.approx(sphere_minus_cap, rel=1e-12)
    # Meridian = full circumference minus the missing arc below the base.
    missing = 2.0 * r * math.asin(A / r)
    assert cap_meridian_length(h, A) == pytest.approx(2.0 * math.pi * r - missing, rel=1e-12)


def test_small_deflection_bulge_law():
    # Neo-Hookean, equibiaxial: W'(lam) = 2 mu (lam - lam^-5) ~ 12 mu (lam - 1) for small strain;
    # lam - 1 ~ h^2 / (2 a^2), so N = H W' / (2 lam) ~ 3 H mu h^2 / a^2; with R ~ a^2 / (2 h),
    # p = 2 N / R ~ 12 H mu h^3 / a^4 (no linear term: the membrane is not pre-stressed).
    mu, thickness = 34e3, 0.5e-3
    h = np.array([1e-3, 3e-3, 1e-2]) * A
    p = cap_pressure(cap_stretch(h, A), A, thickness, NeoHookean(mu))
    closed = 12.0 * thickness * mu * h**3 / A**4
    # The next term is O((h / a)^2) relative: the error must shrink like it.
    relative = np.abs(p / closed - 1.0)
    assert np.all(relative < 5.0 * (h / A) ** 2)
    assert relative[0] < 1e-5


def test_ogden_alpha_three_levels_off():
    # W' = 2 mu1 (lam^2 - lam^-7) -> p = 2 H W' sqrt(lam^2 - 1) / (a lam^3) -> 4 H mu1 / a.
    mu1, thickness = 2.0 * 34e3 / 3.0, 0.5e-3
    p = cap_pressure(np.array([300.0]), A, thickness, Ogden((mu1,), (3.0,)))
    assert p[0] == pytest.approx(4.0 * thickness * mu1 / A, rel=1e-4)


def test_laplace_pressure_is_the_energy_derivative():
    material = NeoHookean(34e3)
    lam = np.linspace(1.0, 3.0, 20001)
    h = cap_height(lam, A)
    p = cap_pressure(lam, A, 1e-3, material)
    work = np.trapezoid(p, cap_volume(h, A))
    assert work == pytest.approx(cap_energy(3.0, A, 1e-3, material), rel=1e-6)


def test_bad_inputs_name_the_field():
    with pytest.raises(BulgeModelError, match='stretch'):
        cap_pressure(0.9, A, 1e-3, NeoHookean(1.0))
    with pytest.raises(BulgeModelError, match='base_radius'):
        cap_volume(1e-3, -1.0)
    with pytest.raises(BulgeModelError, match='height must exceed'):
        SegmentGeometry(0.1, 0.005, 0.005, 0.011, 0.004, 0.006, 1e-3, 1e-3)
    with pytest.raises(BulgeModelError, match='wall_thickness'):
        SegmentGeometry(0.1, 0.015, 0.005, 0.011, 0.004, 0.006, 1e-3, 0.0)


# --- the committed tables -----------------------------------------------------------------------

def load(name: str) -> np.ndarray:
    path = TABLES / f'paper_{name}.csv'
    lines = [ln for ln in path.read_text().splitlines() if not ln.startswith('#')]
    assert lines[0] == 'volume_m3,pressure_pa,curvature_per_m'
    return np.array([[float(x) for x in ln.split(',')] for ln in lines[1:]])


@pytest.fixture(scope='module')
def tables():
    return {name: load(name) for name in ('bottom', 'top')}


def test_generator_reproduces_committed_tables():
    result = subprocess.run([sys.executable, str(REPO / 'tools' / 'make_paper_segments.py'),
                             '--check'], capture_output=True, text=True, check=False)
    assert result.returncode == 0, result.stderr


def test_check_flags_a_stale_table(tmp_path):
    for name in ('bottom', 'top'):
        (tmp_path / f'paper_{name}.csv').write_text((TABLES / f'paper_{name}.csv').read_text())
    (tmp_path / 'paper_top.csv').write_text('stale\n')
    result = subprocess.run([sys.executable, str(REPO / 'tools' / 'make_paper_segments.py'),
                             '--check', '--out-dir', str(tmp_path)],
                            capture_output=True, text=True, check=False)
    assert result.returncode == 1
    assert 'paper_top.csv' in result.stderr and 'Traceback' not in result.stderr


@pytest.mark.parametrize('name', ['bottom', 'top'])
def test_table_shape(tables, name):
    t = tables[name]
    assert 200 <= len(t) <= 400
    assert t[0, 1] == 0.0 and t[0, 2] == 0.0
    assert np.all(np.diff(t[:, 0]) > 0.0)
    # Monotone PV curves: the partial sequence needs no peak (no snap-through).
    assert np.all(np.diff(t[:, 1]) > 0.0)
    assert np.all(np.diff(t[:, 2]) > 0.0)
    # Rest volume = cavity 11 mm x (15 - 5 - H) mm x 111 mm (Table I).
    membrane = {'bottom': 1.0, 'top': 0.5}[name]
    assert t[0, 0] == pytest.approx(11 * (10 - membrane) * 111 * MM**3, rel=1e-9)
    text = (TABLES / f'paper_{name}.csv').read_text()
    assert 'STAND-IN' in text and 'NOT the paper' in text


def combined(tables):
    """Equilibrium on one syringe, built here from the two CSVs only.

    Both pressure columns increase, so every common pressure p fixes v_i = p_i^-1(p); walking
    the top table's rows gives the path, and the injected volume must grow along it (then the
    equilibrium is unique and stable: du/dv_top = 1 + p_top' / p_bottom' > 0).
    """
    top, bottom = tables['top'], tables['bottom']
    p = top[:, 1]
    assert p[-1] < bottom[-1, 1], 'bottom table must reach every top pressure'
    v_bottom = np.interp(p, bottom[:, 1], bottom[:, 0])
    k_bottom = np.interp(p, bottom[:, 1], bottom[:, 2])
    injected = (top[:, 0] - top[0, 0]) + (v_bottom - bottom[0, 0])
    assert np.all(np.diff(injected) > 0.0)
    return {'injected': injected, 'pressure': p, 'v_top': top[:, 0] - top[0, 0],
            'v_bottom': v_bottom - bottom[0, 0], 'k_top': top[:, 2], 'k_bottom': k_bottom}


def at(path, key, volume_ml):
    return np.interp(volume_ml * ML, path['injected'], path[key])


def test_ranges_cover_a_70_ml_run(tables):
    reach = {n: t[-1, 0] - t[0, 0] for n, t in tables.items()}
    assert sum(reach.values()) > 100 * ML
    path = combined(tables)
    assert path['injected'][-1] > 75 * ML
    assert at(path, 'v_bottom', 70) < reach['bottom']


def test_top_plateau_below_bottom(tables):
    # Closed-form plateau of a large alpha = 3 Ogden cap: 4 H mu1 / a, a = sqrt(6 x 11 mm^2 / pi).
    mu1, a = 2.0 * 34e3 / 3.0, math.sqrt(6 * 11 / math.pi) * MM
    plateau = {'top': 4 * 0.5 * MM * mu1 / a, 'bottom': 4 * 1.0 * MM * mu1 / a}
    assert tables['top'][-1, 1] < plateau['top']
    assert tables['top'][-1, 1] > 0.95 * plateau['top']
    # Along the whole run the bottom stays far below its own plateau.
    path = combined(tables)
    assert at(path, 'pressure', 70) < 0.55 * plateau['bottom']


def test_partial_sequence_facts(tables):
    path = combined(tables)
    p = {v: at(path, 'pressure', v) for v in (25, 40, 65, 70)}
    # Plateau reached near 40 mL: within 6 % of the final pressure from there on, not before.
    assert p[40] > 0.94 * p[65]
    assert p[25] < 0.85 * p[65]
    assert p[70] < 1.07 * p[40]
    # After ~40 mL the top takes most of the flow.
    share = (at(path, 'v_top', 70) - at(path, 'v_top', 40)) / (30 * ML)
    assert share > 0.8
    # Both bend before step 3 (25 mL); afterwards only the top keeps curling.
    length = 0.111
    bend = {s: {v: at(path, f'k_{s}', v) * length for v in (25, 60)} for s in ('top', 'bottom')}
    assert bend['bottom'][25] > math.radians(10) and bend['top'][25] > math.radians(10)
    top_gain = bend['top'][60] - bend['top'][25]
    bottom_gain = bend['bottom'][60] - bend['bottom'][25]
    assert bottom_gain < 0.1 * top_gain
    # Calibration of the curvature: one full turn of the top at step 5 (60 mL).
    assert bend['top'][60] == pytest.approx(2 * math.pi, rel=0.02)
