"""
Hexahedral models of one bending segment (Table I of Milana et al. 2018) and their outputs.

Coordinates: x along the segment, y across its width (y = 0 is the mid-width symmetry plane),
z through its height from the beam (z = 0, the concave side) to the membrane skin (z = h). The
cross-section is the beam (0 <= z <= e), two side walls (g/2 <= |y| <= w/2) and the skin on top.
Along x the skin alternates membranes (length b, thickness t) and walls (length a, a thicker band
of the skin reaching down into the cavity: thickness d from the outer surface, which stays flat).

Two models:

- ``unit_cell``: half a pitch (mid-membrane x = 0 to mid-wall x = (a + b)/2) and half the width.
  x = 0 is a mirror plane; the mid-wall cut stays plane but turns about y as the segment bends
  (every pitch bends alike). The segment's volume is 4 n times the cell's (n membranes).
- ``whole_segment``: all n membranes between two end caps, half the width; the base end is
  clamped, the tip end free: end effects and non-uniform bulging show.

The grid has lines at every interface, so each hexahedron is solid or fluid; only the solid
cells are meshed and the faces between solid and fluid cells bound the cavity.
"""

from dataclasses import dataclass
import math

import felupe as fem
import numpy as np
from numpy.typing import NDArray

from softseq_ros.fem.cavity import Cavity
from softseq_ros.fem.constraints import ReducedSpace
from softseq_ros.fem.materials import initial_shear_modulus, make_umat
from softseq_ros.fem.solver import InflationModel
from softseq_ros.scene.design import Design


def _subdivide(lines: list[float], size: float, thin_cells: int, thin_below: float) -> NDArray:
    """Grid coordinates through the given interface lines, about ``size`` apart."""
    lines = sorted({round(v, 12) for v in lines})
    out = [lines[0]]
    for lo, hi in zip(lines[:-1], lines[1:]):
        count = max(1, math.ceil((hi - lo) / size - 1e-9))
        if hi - lo < thin_below:
            count = max(count, thin_cells)
        out.extend(np.linspace(lo, hi, count + 1)[1:])
    return np.asarray(out)


@dataclass(frozen=True)
class SegmentModel:
    """A meshed segment: the solver model and what is needed to read its results."""

    model: InflationModel
    mesh: fem.Mesh
    design: Design
    volume_factor: float            # segment volume / modelled cavity volume
    neutral_line: NDArray[np.int64]  # beam mid-line points, in order along x
    top_points: NDArray[np.int64]    # outer skin points over the membranes
    membrane_of_top: NDArray[np.int64]  # index of the membrane each of those belongs to
    wall_cuts: list[NDArray[np.int64]]  # points at each wall's mid-plane (whole segment)
    dofs: int
    bounds: tuple[float, ...] = ()   # where each segment starts and ends along x [m]
    membrane_owner: NDArray[np.int64] | None = None  # the segment of each membrane

    @property
    def is_unit_cell(self) -> bool:
        """Whether this is a unit cell (a mirror plane and a turning cut) or a whole model."""
        return bool(self.model.space.has_plane)

    def segment_volume(self, model_volume: float) -> float:
        """Fluid volume of the whole segment [m^3] for a modelled cavity volume."""
        return self.volume_factor * model_volume

    def curvature(self, x: NDArray[np.float64]) -> float:
        """
        Curvature of the deformed beam [1/m], positive toward the beam side.

        The tangent angle of the beam's mid-line (y = 0, z = e/2) is fitted by least squares as
        a linear function of the undeformed arc length: a mean curvature over the modelled
        length that assumes no constant radius (the angles come from the deformed points).
        """
        ref = self.model.reference[self.neutral_line]
        cur = x[self.neutral_line]
        dx = np.diff(cur, axis=0)
        angle = np.unwrap(np.arctan2(dx[:, 2], dx[:, 0]))
        s_ref = 0.5 * (ref[1:, 0] + ref[:-1, 0])
        slope = np.polyfit(s_ref, angle, 1)[0]
        return float(-slope)

    def membrane_heights(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """
        Each membrane's bulge [m], base to tip.

        The farthest its outer skin stands from the beam's mid-line, in the bending plane: a
        measure that bending alone leaves alone.
        """
        line = x[self.neutral_line][:, [0, 2]]
        top = x[self.top_points][:, [0, 2]]
        distance = np.min(np.linalg.norm(top[:, None, :] - line[None, :, :], axis=-1), axis=1)
        heights = np.zeros(int(self.membrane_of_top.max()) + 1)
        np.maximum.at(heights, self.membrane_of_top, distance)
        return heights

    def contact(self, x: NDArray[np.float64], q: NDArray[np.float64]) -> bool:
        """Whether a membrane has reached the mid-plane between it and its neighbour."""
        if self.is_unit_cell:
            theta = self.model.space.plane_angle(q)
            normal = np.array([np.cos(theta), 0.0, np.sin(theta)])
            cut = x[self.wall_cuts[0]]
            offset = float(np.mean(cut @ normal))
            return bool(np.any(x[self.top_points] @ normal >= offset))
        ref_line = self.model.reference[self.neutral_line, 0]
        line = x[self.neutral_line][:, [0, 2]]
        top = x[self.top_points][:, [0, 2]]
        for wall, cut_points in enumerate(self.wall_cuts):
            # The deformed mid-wall section, seen in the bending plane, as a straight line
            # (principal direction of its points: valid at any angle the segment has turned).
            cut = x[cut_points][:, [0, 2]]
            centre = cut.mean(axis=0)
            direction = np.linalg.svd(cut - centre, full_matrices=False)[2][0]
            normal = np.array([direction[1], -direction[0]])
            # Oriented along the beam, from this wall's left membrane to its right one.
            x_wall = self.model.reference[cut_points[0], 0]
            after = int(np.searchsorted(ref_line, x_wall + 1e-12))
            tangent = line[min(after, len(line) - 1)] - line[max(after - 1, 0)]
            if normal @ tangent < 0:
                normal = -normal
            side = (top - centre) @ normal
            left = self.membrane_of_top == wall
            right = self.membrane_of_top == wall + 1
            if np.any(side[left] >= 0) or np.any(side[right] <= 0):
                return True
        return False


def mesh_grid(xs: NDArray, ys: NDArray, zs: NDArray, fluid: NDArray
              ) -> tuple[fem.Mesh, NDArray, NDArray, NDArray]:
    """
    The solid cells of a grid as a hexahedral mesh, and the faces that bound its fluid cells.

    ``fluid`` (cells along x, y, z) marks the cavity. Returns the mesh, its points, the cavity
    faces (four point indices each, ordered so that their normal points into the solid) and
    the map from grid points to mesh points (-1: not in the mesh).
    """
    nx, ny, nz = len(xs), len(ys), len(zs)

    def node(i: NDArray, j: NDArray, k: NDArray) -> NDArray:
        return (i * ny + j) * nz + k

    ci, cj, ck = (a.ravel() for a in np.meshgrid(np.arange(nx - 1), np.arange(ny - 1),
                                                 np.arange(nz - 1), indexing='ij'))
    solid = ~fluid[ci, cj, ck]
    ci, cj, ck = ci[solid], cj[solid], ck[solid]
    cells = np.stack([node(ci, cj, ck), node(ci + 1, cj, ck), node(ci + 1, cj + 1, ck),
                      node(ci, cj + 1, ck), node(ci, cj, ck + 1), node(ci + 1, cj, ck + 1),
                      node(ci + 1, cj + 1, ck + 1), node(ci, cj + 1, ck + 1)], axis=1)
    gx, gy, gz = np.meshgrid(xs, ys, zs, indexing='ij')
    grid_points = np.stack([gx.ravel(), gy.ravel(), gz.ravel()], axis=1)
    used = np.unique(cells)
    renumber = np.full(grid_points.shape[0], -1, dtype=np.int64)
    renumber[used] = np.arange(used.size)
    points = grid_points[used]
    mesh = fem.Mesh(points, renumber[cells], 'hexahedron')

    # Cavity faces: between a fluid cell and a solid neighbour, normal toward the solid.
    faces = []
    fi, fj, fk = np.nonzero(fluid)
    for axis, sign in ((0, 1), (0, -1), (1, 1), (1, -1), (2, 1), (2, -1)):
        ni, nj, nk = fi.copy(), fj.copy(), fk.copy()
        (ni, nj, nk)[axis][:] += sign
        inside = ((ni >= 0) & (ni < nx - 1) & (nj >= 0) & (nj < ny - 1)
                  & (nk >= 0) & (nk < nz - 1))
        neighbour_fluid = np.zeros_like(inside)
        neighbour_fluid[inside] = fluid[ni[inside], nj[inside], nk[inside]]
        wall = inside & ~neighbour_fluid
        i, j, k = fi[wall], fj[wall], fk[wall]
        plane = (i, j, k)[axis] + (1 if sign > 0 else 0)
        # In-face axes (xi, eta) chosen so that xi x eta = +axis direction.
        a1, a2 = (axis + 1) % 3, (axis + 2) % 3

        def corner(d1: int, d2: int, a1: int = a1, a2: int = a2, axis: int = axis,
                   i: NDArray = i, j: NDArray = j, k: NDArray = k,
                   plane: NDArray = plane) -> NDArray:
            index = [i.copy(), j.copy(), k.copy()]
            index[axis] = plane
            index[a1] = index[a1] + d1
            index[a2] = index[a2] + d2
            return node(*index)

        quad = np.stack([corner(0, 0), corner(1, 0), corner(1, 1), corner(0, 1)], axis=1)
        faces.append(quad if sign > 0 else quad[:, ::-1])
    return mesh, points, renumber[np.concatenate(faces)], renumber


def build_segment(design: Design) -> SegmentModel:
    """Mesh a segment design and set up its volume-controlled model."""
    return build_chain([design], design.mesh.model)


# Dimensions that segments on one cavity must share (their cross-section).
SHARED_SECTION = ('height_m', 'width_m', 'beam_thickness_m', 'cavity_width_m')


def _layout(designs: list[Design]) -> tuple[list, list, list, list, float]:
    """
    Along x, base to tip: membranes (lo, hi), their segment, mid-wall planes, segment bounds.

    Each segment is its membranes between end caps; where two segments meet, their end caps
    are one wall band over the shared cavity (each half its own segment's skin thickness).
    """
    membranes, owner, wall_centres, bounds = [], [], [], [0.0]
    start = 0.0
    for index, design in enumerate(designs):
        g = design.geometry
        x = start + g.end_cap_length_m
        if index > 0:
            wall_centres.append(start)  # the junction's band, as a wall between membranes
        for k in range(g.membranes):
            membranes.append((x, x + g.membrane_length_m))
            owner.append(index)
            x += g.membrane_length_m
            if k < g.membranes - 1:
                wall_centres.append(x + g.wall_length_m / 2)
                x += g.wall_length_m
        start += g.length_m
        bounds.append(start)
    return membranes, owner, wall_centres, bounds, start


def build_chain(designs: list[Design], model: str) -> SegmentModel:
    """
    Mesh segments in a row, base to tip, on one cavity, and set up its volume-controlled model.

    One design and ``unit_cell`` or ``whole_segment``: the segment models. Several designs
    (``whole_segment``): the whole actuator, base clamped; the designs share their
    cross-section (:data:`SHARED_SECTION`), their material and the first one's mesh settings.
    """
    design = designs[0]
    g = design.geometry
    size = design.mesh.element_size_m
    thin = design.mesh.thin_layer_cells
    pitch = g.wall_length_m + g.membrane_length_m
    half_cavity = g.cavity_width_m / 2
    roofs = [(g_i.height_m - g_i.membrane_thickness_m, g_i.height_m - g_i.skin_band_thickness_m)
             for g_i in (d.geometry for d in designs)]
    top_membrane, top_wall = roofs[0]

    if model == 'unit_cell':
        x_lines = [0.0, g.membrane_length_m / 2, pitch / 2]
        membranes = [(-g.membrane_length_m / 2, g.membrane_length_m / 2)]
        owner = [0]
        wall_centres = [pitch / 2]
        x_end = pitch / 2
        bounds = [0.0, x_end]
    else:
        membranes, owner, wall_centres, bounds, x_end = _layout(designs)
        x_lines = [0.0, x_end] + [v for m in membranes for v in m] + wall_centres
    thin_below = 2.0 * max(max(d.geometry.membrane_thickness_m, d.geometry.skin_band_thickness_m)
                           for d in designs) + 1e-9
    xs = _subdivide(x_lines, size, 1, 0.0)
    ys = _subdivide([0.0, half_cavity, g.width_m / 2], size, thin, thin_below)
    zs = _subdivide([0.0, g.beam_thickness_m / 2, g.beam_thickness_m,
                     *(z for roof in roofs for z in roof), g.height_m], size, thin, thin_below)
    nx = len(xs)

    xc, yc, zc = (0.5 * (v[1:] + v[:-1]) for v in (xs, ys, zs))
    in_membrane = np.zeros(nx - 1, dtype=bool)
    for lo, hi in membranes:
        in_membrane |= (xc > lo) & (xc < hi)
    if model == 'unit_cell':
        in_cavity_x = np.ones(nx - 1, dtype=bool)
    else:
        in_cavity_x = (xc > membranes[0][0]) & (xc < membranes[-1][1])
    segment_of = np.clip(np.searchsorted(bounds, xc) - 1, 0, len(designs) - 1)
    membrane_roof = np.array([r[0] for r in roofs])[segment_of]
    wall_roof = np.array([r[1] for r in roofs])[segment_of]
    roof = np.where(in_membrane, membrane_roof, wall_roof)
    fluid = (in_cavity_x[:, None, None] & (yc[None, :, None] < half_cavity)
             & (zc[None, None, :] > g.beam_thickness_m)
             & (zc[None, None, :] < roof[:, None, None]))

    mesh, points, faces, _ = mesh_grid(xs, ys, zs, fluid)
    if g.membrane_thickness_factors is not None:
        # Each membrane's skin scaled through its thickness (the outer surface stays flat).
        skin = points[:, 2] >= top_membrane - 1e-9
        for (lo, hi), factor in zip(membranes, g.membrane_thickness_factors):
            over = skin & (points[:, 0] >= lo - 1e-9) & (points[:, 0] <= hi + 1e-9)
            points[over, 2] = g.height_m - (g.height_m - points[over, 2]) * factor
        mesh = fem.Mesh(points, mesh.cells, 'hexahedron')
    cavity = Cavity(faces=faces, weights=(0.0, 1.0, 0.0))

    mu = initial_shear_modulus(design.material.law, design.material.params)
    region = fem.RegionHexahedron(mesh)
    displacement = fem.FieldContainer([fem.Field(region, dim=3)])
    body = fem.SolidBodyNearlyIncompressible(
        make_umat(design.material.law, design.material.params), displacement,
        bulk=design.mesh.bulk_ratio * mu)

    tol = 1e-9
    space = ReducedSpace(points)
    space.fix(np.nonzero(points[:, 1] < tol)[0], (0.0, 1.0, 0.0))
    if model == 'unit_cell':
        start_face = np.nonzero(points[:, 0] < tol)[0]
        space.fix(start_face, (1.0, 0.0, 0.0))
        anchor = np.nonzero((points[:, 0] < tol) & (points[:, 1] < tol) & (points[:, 2] < tol))[0]
        space.fix(anchor, (0.0, 0.0, 1.0))
        end_face = np.nonzero(points[:, 0] > x_end - tol)[0]
        space.rotating_plane(end_face, (x_end, 0.0, g.beam_thickness_m / 2))
        volume_factor = 4.0 * g.membranes
        wall_cuts = [end_face]
    else:
        base = np.nonzero(points[:, 0] < tol)[0]
        for direction in np.eye(3):
            space.fix(base, tuple(direction))
        volume_factor = 2.0
        wall_cuts = [np.nonzero(np.abs(points[:, 0] - xw) < tol)[0] for xw in wall_centres]
    space.finish()

    line = np.nonzero((points[:, 1] < tol)
                      & (np.abs(points[:, 2] - g.beam_thickness_m / 2) < tol))[0]
    line = line[np.argsort(points[line, 0])]
    top = np.nonzero((points[:, 2] > g.height_m - tol) & (points[:, 1] < half_cavity + tol))[0]
    membrane_of_top = np.full(top.size, -1, dtype=np.int64)
    for index, (lo, hi) in enumerate(membranes):
        inside = (points[top, 0] >= lo - tol) & (points[top, 0] <= hi + tol)
        membrane_of_top[inside] = index
    keep = membrane_of_top >= 0
    if model == 'unit_cell':
        # Points on the cut itself are its own mirror images; they cannot signal contact.
        keep &= points[top, 0] < x_end - tol
    top, membrane_of_top = top[keep], membrane_of_top[keep]

    solver = InflationModel(body, displacement, space, cavity,
                           force_scale=mu * g.height_m**2, length_scale=g.height_m)
    return SegmentModel(model=solver, mesh=mesh, design=design, volume_factor=volume_factor,
                        neutral_line=line, top_points=top, membrane_of_top=membrane_of_top,
                        wall_cuts=wall_cuts, dofs=space.size, bounds=tuple(bounds),
                        membrane_owner=np.asarray(owner, dtype=np.int64))
