"""The volume-controlled FEM against closed forms and independent references (coarse meshes)."""

import numpy as np
import pytest

from softseq_ros.fem.segment import build_segment
from softseq_ros.fem.sphere import (
    neo_hookean_thick_sphere_pressure,
    sphere_sector,
    thick_sphere_pressure,
    thin_mooney_rivlin_pressure,
)
from softseq_ros.scene.design import load_design, with_changes
from softseq_ros.segments.materials import MooneyRivlin

MU = 1.0e4  # Pa
A, B = 0.010, 0.012  # inner and outer radius of the thick sphere [m]


@pytest.fixture(scope='module')
def thick_sphere_path():
    sphere = sphere_sector(A, B, 'neo_hookean', {'shear_modulus_pa': MU}, radial_cells=4)
    model = sphere.model
    v0 = model.rest_volume
    result = model.ramp_volume(40 * v0, first_step=0.05 * v0, max_step=1.5 * v0,
                               min_step=1e-4 * v0)
    assert result.stop_reason == 'reached the requested volume'
    stretch = np.array([(s.volume / v0) ** (1 / 3) for s in result.states])
    pressure = np.array([s.pressure for s in result.states])
    return sphere, stretch, pressure


def test_thick_neo_hookean_sphere_matches_closed_form_through_peak(thick_sphere_path):
    _, stretch, pressure = thick_sphere_path
    exact = MU * neo_hookean_thick_sphere_pressure(stretch, A, B)
    peak = int(np.argmax(exact))
    # The run goes through the peak and far down the falling branch.
    assert 0 < peak < len(exact) - 5
    assert exact[-1] < 0.6 * exact[peak]
    error = np.abs(pressure[1:] / exact[1:] - 1)
    assert error.max() < 0.005
    assert error[peak - 2:].max() < 0.005  # at and after the peak too


def test_pressure_control_stops_at_the_peak_where_volume_control_goes_on(thick_sphere_path):
    sphere, stretch, pressure = thick_sphere_path
    peak_pressure = pressure.max()
    model = sphere_sector(A, B, 'neo_hookean', {'shear_modulus_pa': MU}, radial_cells=4).model
    loads = np.linspace(0.1, 1.06, 17) * peak_pressure  # 0.94 and 1.0 of the peak among them
    result = model.ramp_pressure(loads)
    reached = max(s.pressure for s in result.states)
    # Load control converges right up to the peak and no further: the first load it fails at
    # lies beyond the largest pressure of the volume-controlled path.
    assert result.stop_reason.startswith('no convergence')
    assert 0.99 * peak_pressure < reached <= peak_pressure * (1 + 1e-9)
    failed_at = loads[len(result.states) - 1]
    assert failed_at > peak_pressure
    # Volume control got past the peak, onto the falling branch, in the same model.
    assert stretch[-1] > 1.5 * stretch[int(np.argmax(pressure))]


def test_thin_mooney_rivlin_balloon_matches_closed_form():
    c1, c2 = 0.45 * MU, 0.05 * MU  # C2/C1 = 0.11 < 0.2145: a limit point exists
    inner, thickness = 0.010, 0.0002
    sphere = sphere_sector(inner, inner + thickness, 'mooney_rivlin',
                           {'c1_pa': c1, 'c2_pa': c2}, radial_cells=1, lateral_cells=2)
    model = sphere.model
    v0 = model.rest_volume
    result = model.ramp_volume(27 * v0, first_step=0.05 * v0, max_step=1.0 * v0,
                               min_step=1e-4 * v0)
    assert result.stop_reason == 'reached the requested volume'
    stretch = np.array([(s.volume / v0) ** (1 / 3) for s in result.states[1:]])
    pressure = np.array([s.pressure for s in result.states[1:]])
    # Thin membrane of mid-surface radius R: stretch of the mid-surface from the volumes.
    radius = inner + thickness / 2
    mid_stretch = np.cbrt(radius**3 + (stretch**3 - 1) * inner**3) / radius
    thin = thin_mooney_rivlin_pressure(mid_stretch, c1, c2, thickness, radius)
    material = MooneyRivlin(c1, c2)
    thick = np.array([thick_sphere_pressure(material.energy_derivative, s, inner,
                                            inner + thickness) for s in stretch])
    # H/R = 0.02: the thin closed form (with the mid-surface radius) and the exact thick-wall
    # integral both agree to well under 0.5 %.
    assert np.max(np.abs(pressure / thin - 1)) < 0.005
    assert np.max(np.abs(pressure / thick - 1)) < 0.005
    peak = int(np.argmax(thin))
    assert 0 < peak < len(thin) - 3  # the run passed the balloon's limit point


@pytest.fixture(scope='module')
def coarse_top_cell():
    design = with_changes(load_design('config/designs/paper_top.yaml'),
                          {'mesh.element_size_m': 0.0025, 'mesh.thin_layer_cells': 1})
    return build_segment(design)


def test_volume_derivatives_match_finite_differences(coarse_top_cell):
    model = coarse_top_cell.model
    rng = np.random.default_rng(7)
    q = 2e-4 * rng.normal(size=model.space.size)
    q[model.space.angle_index] = -0.2  # a turned mid-wall cut, as in strong bending
    x = model.positions(q)
    jac = model.space.jacobian(q)
    gradient = jac.T @ model.cavity.gradient(x).ravel()
    for _ in range(3):
        dq = 1e-6 * rng.normal(size=q.size)
        central = (model.cavity.volume(model.positions(q + dq))
                   - model.cavity.volume(model.positions(q - dq))) / 2
        assert gradient @ dq == pytest.approx(central, rel=1e-6)
    dx = 1e-7 * rng.normal(size=x.shape)
    hessian = model.cavity.hessian(x)
    central = (model.cavity.gradient(x + dx) - model.cavity.gradient(x - dx)).ravel() / 2
    assert np.linalg.norm(hessian @ dx.ravel() - central) < 1e-6 * np.linalg.norm(central)


def test_cavity_volume_of_the_unit_cell_is_its_geometry(coarse_top_cell):
    g = coarse_top_cell.design.geometry
    half_pitch, half_cavity = g.pitch_m / 2, g.cavity_width_m / 2
    under_membrane = (g.height_m - g.beam_thickness_m - g.membrane_thickness_m)
    under_wall = (g.height_m - g.beam_thickness_m - g.skin_band_thickness_m)
    expected = half_cavity * (g.membrane_length_m / 2 * under_membrane
                              + (half_pitch - g.membrane_length_m / 2) * under_wall)
    assert coarse_top_cell.model.rest_volume == pytest.approx(expected, rel=1e-12)


def _peak_pressure(design):
    from softseq_ros.fem.table import run_design

    result = run_design(design)
    assert result.stop_reason == 'reached the requested volume'
    return result.peak[0]


@pytest.fixture(scope='module')
def plateau_by_mesh():
    """Largest pressure up to 30 mL of each paper segment's unit cell at three mesh sizes."""
    from concurrent.futures import ProcessPoolExecutor

    sizes = (0.00375, 0.0028, 0.0021)  # each refinement 3/4 of the previous element size
    designs = {}
    for name in ('top', 'bottom'):
        base = load_design(f'config/designs/paper_{name}.yaml')
        designs[name] = [with_changes(base, {'mesh.element_size_m': size,
                                             'mesh.thin_layer_cells': 1,
                                             'volume.max_injected_m3': 3e-5,
                                             'volume.first_step_m3': 1e-6,
                                             'volume.max_step_m3': 4e-6}) for size in sizes]
    # Six independent runs: on two worker processes (the CI machine has two cores).
    with ProcessPoolExecutor(max_workers=2) as pool:
        futures = {name: [pool.submit(_peak_pressure, design) for design in cases]
                   for name, cases in designs.items()}
        plateau = {name: [future.result() for future in runs] for name, runs in futures.items()}
    return sizes, plateau


def test_paper_segments_plateau_converges_with_the_mesh(plateau_by_mesh, record_property):
    sizes, plateau = plateau_by_mesh
    for name, values in plateau.items():
        changes = np.diff(values) / values[:-1]
        record_property(f'{name}_plateau_pa', [round(v, 1) for v in values])
        record_property(f'{name}_change_per_refinement', [f'{c:+.2%}' for c in changes])
        # Coarse linear hexahedra are too stiff in bending: the plateau falls as the mesh is
        # refined, by a few per cent per refinement at these sizes.
        assert np.all(changes < 0) and np.all(np.abs(changes) < 0.05), (name, values)
    # The paper's design rule holds at every mesh: the thin-membrane top levels off lower.
    assert all(t < 0.95 * b for t, b in zip(plateau['top'], plateau['bottom']))


def test_contact_is_seen_where_a_membrane_reaches_its_neighbours_mid_plane(coarse_top_cell):
    for segment in (coarse_top_cell,
                    build_segment(with_changes(coarse_top_cell.design,
                                               {'mesh.model': 'whole_segment'}))):
        model = segment.model
        q = np.zeros(model.space.size)
        x = model.positions(q).copy()
        assert not segment.contact(x, q)
        if segment.design.mesh.model == 'whole_segment':
            # A segment turned far about y (as when it curls) is no contact either.
            for angle in (0.5 * np.pi, 0.75 * np.pi, 1.2 * np.pi):
                c, s = np.cos(angle), np.sin(angle)
                turned = x @ np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])
                assert not segment.contact(turned, q)
        # Push one membrane point of the outer skin over the mid-plane of the wall beside it.
        first = segment.top_points[segment.membrane_of_top == 0]
        point = first[np.argmax(x[first, 0])]
        wall_x = x[segment.wall_cuts[0], 0].mean()
        x[point, 0] = wall_x + 1e-4
        assert segment.contact(x, q)


def test_membrane_heights_see_one_membrane_bulge_however_the_segment_bends(coarse_top_cell):
    segment = build_segment(with_changes(coarse_top_cell.design,
                                         {'mesh.model': 'whole_segment'}))
    g = segment.design.geometry
    x = segment.model.reference.copy()
    # At rest every membrane's outer skin stands h - e/2 from the beam's mid-line.
    rest = segment.membrane_heights(x)
    assert rest.shape == (g.membranes,)
    assert rest == pytest.approx(g.height_m - g.beam_thickness_m / 2, rel=1e-12)
    # Push the fourth membrane's skin out by a bump; then bend the whole segment far.
    skin = segment.top_points[segment.membrane_of_top == 3]
    centre = x[skin, 0].mean()
    bump = 2e-3 * np.cos(np.pi * (x[skin, 0] - centre) / g.membrane_length_m)
    x[skin, 2] += bump
    for angle in (0.0, 0.6 * np.pi):
        c, s = np.cos(angle), np.sin(angle)
        turned = x @ np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])
        heights = segment.membrane_heights(turned)
        assert heights[3] - rest[3] == pytest.approx(bump.max(), rel=1e-9)
        assert np.delete(heights, 3) == pytest.approx(np.delete(rest, 3), rel=1e-9)


SMALL_THIN, LARGE_THICK = (0.010, 0.011), (0.060, 0.072)  # spheres' (inner, outer) radii [m]


def _snapping_pair():
    # A thin small sphere and a thick large one on one fluid volume: past the small one's
    # peak the large one gives up more fluid than the small one takes, so the total volume
    # turns back (the path a segment's membranes take when one of them runs away).
    from softseq_ros.fem.sphere import sphere_pair

    pair = sphere_pair(SMALL_THIN, LARGE_THICK, 'neo_hookean', {'shear_modulus_pa': MU})
    return pair, pair.model, pair.model.rest_volume


def test_arc_length_follows_two_spheres_on_one_syringe_through_their_snap_back():
    pair, model, v0 = _snapping_pair()
    small, large = SMALL_THIN, LARGE_THICK
    result = model.trace_path(1.5 * v0, first_step=0.004 * v0, max_step=0.04 * v0,
                              min_step=1e-6 * v0)
    assert result.stop_reason == 'reached the requested volume'
    assert result.states[-1].volume == pytest.approx(1.5 * v0, rel=1e-12)
    volumes = np.array([s.volume for s in result.states]) / v0
    (turn,) = result.volume_turns
    # The volume falls well back before it grows again: a snap-back, not a wiggle.
    assert volumes[turn:].min() < volumes[turn] - 0.05
    # Every state, before, in and after the snap-back, is an equilibrium of both spheres.
    for state in result.states[1:]:
        first, second = pair.stretches(state.q)
        for stretch, (inner, outer) in ((first, small), (second, large)):
            exact = MU * neo_hookean_thick_sphere_pressure(stretch, inner, outer)
            assert state.pressure == pytest.approx(exact, rel=0.005)
    # The small sphere went over its peak and far down its falling branch.
    assert pair.stretches(result.states[-1].q)[0] > 2.0


def _pair_closed_form(pair, state):
    """Each sphere's stretch, closed-form pressure [Pa] and stiffness dp/dv [Pa/m^3]."""
    reference = pair.model.reference
    out = []
    for stretch, (inner, outer), cavity in zip(pair.stretches(state.q), pair.radii,
                                               pair.cavities):
        rest = cavity.volume(reference)
        h = 1e-6 * stretch
        slope = MU * (neo_hookean_thick_sphere_pressure(stretch + h, inner, outer)
                      - neo_hookean_thick_sphere_pressure(stretch - h, inner, outer)) / (2 * h)
        out.append((stretch, MU * neo_hookean_thick_sphere_pressure(stretch, inner, outer),
                    slope / (3 * rest * stretch**2)))
    return out


def _stable_pair_states(pair, volume):
    """Closed-form stable equilibria (stretches) of the two spheres sharing ``volume``."""
    from scipy.optimize import brentq

    (a1, b1), (a2, b2) = pair.radii
    rest1, rest2 = (c.volume(pair.model.reference) for c in pair.cavities)

    def second(l1):
        return np.cbrt((volume - rest1 * l1**3) / rest2)

    def mismatch(l1):
        return (neo_hookean_thick_sphere_pressure(l1, a1, b1)
                - neo_hookean_thick_sphere_pressure(second(l1), a2, b2))

    top = np.cbrt((volume - rest2) / rest1)  # the second sphere back at rest
    grid = np.linspace(1.0 + 1e-9, top - 1e-9, 4000)
    values = mismatch(grid)
    stable = []
    for lo, hi, f_lo, f_hi in zip(grid[:-1], grid[1:], values[:-1], values[1:]):
        if f_lo * f_hi < 0:
            l1 = brentq(mismatch, lo, hi, xtol=1e-13)
            l2 = second(l1)
            h = 1e-6
            k = [(neo_hookean_thick_sphere_pressure(lam + h, a, b)
                  - neo_hookean_thick_sphere_pressure(lam - h, a, b)) / (2 * h)
                 / (3 * rest * lam**2)
                 for lam, a, b, rest in ((l1, a1, b1, rest1), (l2, a2, b2, rest2))]
            # Fluid moved from one to the other at a fixed total: stable if k1 + k2 > 0.
            if k[0] + k[1] > 0:
                stable.append((l1, l2))
    return stable


def _check_volume_controlled_pair(pair, result):
    states = result.states
    volumes = np.array([s.volume for s in states])
    assert np.all(np.diff(volumes) > 0)
    for state in states[1:]:
        spheres = _pair_closed_form(pair, state)
        for _, exact, _ in spheres:
            assert state.pressure == pytest.approx(exact, rel=0.005)
        # Every state the syringe passes through is stable, by the FEM's own count and by
        # the closed forms' stiffnesses.
        assert state.stable is True
        assert spheres[0][2] + spheres[1][2] > 0


def test_volume_control_snaps_through_where_two_spheres_volume_turns_back():
    # The path of the arc-length test above, under volume control: a syringe cannot follow the
    # snap-back, so at the turning volume the spheres snap at constant volume onto the far
    # branch, where the small one holds most of the fluid.
    pair, model, v0 = _snapping_pair()
    result = model.ramp_volume(1.5 * v0, first_step=0.004 * v0, max_step=0.04 * v0,
                               min_step=1e-6 * v0)
    assert result.stop_reason == 'reached the requested volume'
    assert result.states[-1].volume == pytest.approx(1.5 * v0, rel=1e-12)
    _check_volume_controlled_pair(pair, result)
    (snap,) = result.snaps
    before, after = result.states[snap.index - 1], result.states[snap.index]
    assert after.volume - before.volume <= 2e-6 * v0
    assert snap.pressure_after < 0.6 * snap.pressure_before
    # It landed where the closed forms have their stable state of largest small sphere.
    l1, l2 = max(_stable_pair_states(pair, after.volume))
    assert pair.stretches(after.q) == pytest.approx((l1, l2), rel=0.01)
    assert pair.stretches(before.q)[0] < 0.5 * l1


def test_volume_control_leaves_the_unstable_uniform_inflation_of_two_equal_spheres():
    # Two equal spheres on one syringe: past their common peak inflating both alike is an
    # equilibrium, but unstable (a perfect bifurcation, like equal membranes of a segment).
    # Volume control finds it, sees it unstable, and settles on the stable unequal state.
    from softseq_ros.fem.sphere import sphere_pair

    pair = sphere_pair((A, B), (A, B), 'neo_hookean', {'shear_modulus_pa': MU})
    model = pair.model
    v0 = model.rest_volume
    result = model.ramp_volume(6 * v0, first_step=0.05 * v0, max_step=0.5 * v0,
                               min_step=1e-4 * v0)
    assert result.stop_reason == 'reached the requested volume'
    _check_volume_controlled_pair(pair, result)
    (snap,) = result.snaps
    assert snap.cause == 'the equilibrium at the next volume is unstable'
    for state in result.states[:snap.index]:
        first, second = pair.stretches(state.q)
        assert first == pytest.approx(second, rel=1e-6)
    for state in result.states[snap.index:]:
        stretches = sorted(pair.stretches(state.q))
        closed = [sorted(s) for s in _stable_pair_states(pair, state.volume)]
        assert any(np.allclose(stretches, c, rtol=0.01) for c in closed)
        assert stretches[1] - stretches[0] > 0.2
