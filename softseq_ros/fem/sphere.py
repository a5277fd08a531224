"""
A thick-walled sphere as a test of the FEM against closed forms.

The model is a sector of the shell: directions (xi, eta, 1)/|.| with 0 <= xi, eta <= ``spread``,
radii from A to B. Its four side faces are planes through the centre, which a radially symmetric
inflation maps onto themselves, so the sector with its points sliding on those planes is the
whole sphere. The cavity's other boundaries are those planes, where x . n = 0: the volume is
(1/3) of the integral of x . n over the inner surface (a cone's volume).
"""

from dataclasses import dataclass

import felupe as fem
import numpy as np
from numpy.typing import NDArray
from scipy.integrate import quad

from softseq_ros.fem.cavity import Cavity
from softseq_ros.fem.constraints import ReducedSpace
from softseq_ros.fem.materials import initial_shear_modulus, make_umat
from softseq_ros.fem.solver import InflationModel


def neo_hookean_thick_sphere_pressure(inner_stretch: NDArray[np.float64], inner_radius: float,
                                      outer_radius: float) -> NDArray[np.float64]:
    """
    P / mu of an incompressible neo-Hookean thick sphere at inner stretch la = a / A.

    p / mu = (2 / lb + 1 / (2 lb^4)) - (2 / la + 1 / (2 la^4)) with lb = b / B and
    b^3 = B^3 + a^3 - A^3 (incompressibility).
    """
    la = np.asarray(inner_stretch, dtype=float)
    a = la * inner_radius
    b = np.cbrt(outer_radius**3 + a**3 - inner_radius**3)
    lb = b / outer_radius
    return (2 / lb + 1 / (2 * lb**4)) - (2 / la + 1 / (2 * la**4))


def thick_sphere_pressure(energy_derivative: object, inner_stretch: float, inner_radius: float,
                          outer_radius: float) -> float:
    """
    Gauge pressure [Pa] of any incompressible isotropic thick sphere, by quadrature.

    p = integral from lb to la of W'(l) / (l^3 - 1) dl, with W(l) the strain energy of the
    equibiaxial stretch l (``energy_derivative`` is dW/dl, e.g. a physics material's).
    """
    a = inner_stretch * inner_radius
    b = np.cbrt(outer_radius**3 + a**3 - inner_radius**3)
    lb = b / outer_radius
    value, _ = quad(lambda lam: float(energy_derivative(lam)) / (lam**3 - 1), lb, inner_stretch,
                    epsabs=0.0, epsrel=1e-12, limit=200)
    return value


def thin_mooney_rivlin_pressure(stretch: NDArray[np.float64], c1: float, c2: float,
                                thickness: float, radius: float) -> NDArray[np.float64]:
    """Thin Mooney-Rivlin balloon: p = 4 H / R (1/l - 1/l^7) (C1 + C2 l^2) [Pa]."""
    lam = np.asarray(stretch, dtype=float)
    return 4 * thickness / radius * (1 / lam - 1 / lam**7) * (c1 + c2 * lam**2)


@dataclass(frozen=True)
class SphereSector:
    """The FEM model of a thick sphere and its mesh."""

    model: InflationModel
    mesh: fem.Mesh
    inner_radius: float
    outer_radius: float


def _sector(inner_radius: float, outer_radius: float, radial_cells: int, lateral_cells: int,
            spread: float, side: float, first: int) -> tuple:
    """
    Points, hexahedra, inner faces and sliding planes of one sector, numbered from ``first``.

    The sector's directions are (xi, eta, side)/|.|: ``side`` -1 is the mirror image of +1
    through z = 0, with its cells and faces reordered to keep their orientation.
    """
    xi = np.linspace(0.0, spread, lateral_cells + 1)
    radii = np.linspace(inner_radius, outer_radius, radial_cells + 1)
    grid_r, grid_eta, grid_xi = np.meshgrid(radii, xi, xi, indexing='ij')
    direction = np.stack([grid_xi, grid_eta, side * np.ones_like(grid_xi)], axis=-1)
    direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
    points = (grid_r[..., None] * direction).reshape(-1, 3)
    nr, nl = radial_cells + 1, lateral_cells + 1

    def index(i: NDArray, j: NDArray, k: NDArray) -> NDArray:
        return first + (i * nl + j) * nl + k

    i, j, k = np.meshgrid(np.arange(radial_cells), np.arange(lateral_cells),
                          np.arange(lateral_cells), indexing='ij')
    i, j, k = i.ravel(), j.ravel(), k.ravel()
    # Hexahedron node order (felupe/VTK): bottom face counter-clockwise, then top face; here the
    # local axes (k: xi, j: eta, i: r) are right-handed, so the volume is positive.
    cells = np.stack([index(i, j, k), index(i, j, k + 1), index(i, j + 1, k + 1),
                      index(i, j + 1, k), index(i + 1, j, k), index(i + 1, j, k + 1),
                      index(i + 1, j + 1, k + 1), index(i + 1, j + 1, k)], axis=1)
    # Inner surface faces (i = 0), ordered so that the normal points away from the centre,
    # out of the fluid.
    j2, k2 = (a.ravel() for a in np.meshgrid(np.arange(lateral_cells), np.arange(lateral_cells),
                                             indexing='ij'))
    zero = np.zeros_like(j2)
    faces = np.stack([index(zero, j2, k2), index(zero, j2, k2 + 1),
                      index(zero, j2 + 1, k2 + 1), index(zero, j2 + 1, k2)], axis=1)
    if side < 0:
        cells = cells[:, [0, 3, 2, 1, 4, 7, 6, 5]]
        faces = faces[:, ::-1]
    ii, ll = np.meshgrid(np.arange(nr), np.arange(nl), indexing='ij')
    planes = [(index(ii, ll, 0), (1.0, 0.0, 0.0)), (index(ii, 0, ll), (0.0, 1.0, 0.0)),
              (index(ii, ll, lateral_cells), (1.0, 0.0, -spread * side)),
              (index(ii, lateral_cells, ll), (0.0, 1.0, -spread * side))]
    return points, cells, faces, planes


def _sectors_model(sectors: list[tuple], law: str, params: dict, bulk_ratio: float,
                   force_length: float, length_scale: float) -> tuple:
    points = np.vstack([sector[0] for sector in sectors])
    mesh = fem.Mesh(points, np.vstack([sector[1] for sector in sectors]), 'hexahedron')
    region = fem.RegionHexahedron(mesh)
    displacement = fem.FieldContainer([fem.Field(region, dim=3)])
    mu = initial_shear_modulus(law, params)
    solid = fem.SolidBodyNearlyIncompressible(make_umat(law, params), displacement,
                                              bulk=bulk_ratio * mu)
    space = ReducedSpace(points)
    for sector in sectors:
        for nodes, normal in sector[3]:
            space.fix(nodes, normal)
    space.finish()
    cavity = Cavity(faces=np.vstack([sector[2] for sector in sectors]),
                    weights=(1 / 3, 1 / 3, 1 / 3))
    if cavity.volume(points) <= 0:
        raise AssertionError('inner face orientation')
    model = InflationModel(solid, displacement, space, cavity,
                           force_scale=mu * force_length**2, length_scale=length_scale)
    return model, mesh


def sphere_sector(inner_radius: float, outer_radius: float, law: str, params: dict,
                  radial_cells: int = 4, lateral_cells: int = 2, spread: float = 0.2,
                  bulk_ratio: float = 5000.0) -> SphereSector:
    """Build the sector model of a sphere (radii in m, a material block's law and params)."""
    sector = _sector(inner_radius, outer_radius, radial_cells, lateral_cells, spread, 1.0, 0)
    model, mesh = _sectors_model([sector], law, params, bulk_ratio, inner_radius, outer_radius)
    return SphereSector(model=model, mesh=mesh, inner_radius=inner_radius,
                        outer_radius=outer_radius)


@dataclass(frozen=True)
class SpherePair:
    """Two thick spheres on one fluid volume (a sector of each, the same solid angle)."""

    model: InflationModel
    mesh: fem.Mesh
    radii: tuple[tuple[float, float], tuple[float, float]]  # (inner, outer) of each [m]
    cavities: tuple[Cavity, Cavity]                          # each sphere's own cavity

    def stretches(self, q: NDArray[np.float64]) -> tuple[float, float]:
        """Each sphere's inner stretch a / A, from its own cavity's volume."""
        x = self.model.positions(q)
        reference = self.model.reference
        return tuple(float((c.volume(x) / c.volume(reference)) ** (1 / 3))
                     for c in self.cavities)


def sphere_pair(first: tuple[float, float], second: tuple[float, float], law: str,
                params: dict, radial_cells: int = 4, lateral_cells: int = 2,
                spread: float = 0.2, bulk_ratio: float = 5000.0) -> SpherePair:
    """
    Two spheres (inner, outer radius [m]) on one syringe: a path with a snap-back.

    A small thin sphere and a large thick one, as two membranes of one segment: past the small
    one's pressure peak it takes fluid from the large one, and where the large one gives up
    more than the small one takes, the total volume turns back. The two sectors point in +z and
    -z from one centre, so their cavities' volume stays one closed-form integral.
    """
    one = _sector(*first, radial_cells, lateral_cells, spread, 1.0, 0)
    two = _sector(*second, radial_cells, lateral_cells, spread, -1.0, one[0].shape[0])
    model, mesh = _sectors_model([one, two], law, params, bulk_ratio, first[0], second[1])
    cavities = (Cavity(faces=one[2], weights=(1 / 3, 1 / 3, 1 / 3)),
                Cavity(faces=two[2], weights=(1 / 3, 1 / 3, 1 / 3)))
    return SpherePair(model=model, mesh=mesh, radii=(first, second), cavities=cavities)
