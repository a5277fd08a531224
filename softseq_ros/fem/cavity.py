"""
Fluid volume of a cavity bounded by bilinear faces, with its exact first and second derivatives.

The fluid region is closed by the solid's inner faces and by symmetry planes. By the divergence
theorem, for a constant diagonal weight ``A`` with trace 1,

    V = integral over the closed boundary of  x . (A n) dA      (n: outward from the fluid)

and a plane contributes nothing where ``x . (A n)`` vanishes on it. Two weights cover every model
here: ``(1/3, 1/3, 1/3)`` (planes through the origin: a sector of a sphere) and ``(0, 1, 0)``
(planes ``y = 0`` and planes that contain the y axis direction: a segment cut at its mid-width and
at rotating cross-sections). Only the solid faces are then integrated, and the derivative of V is
exact for every motion the symmetry constraints allow, including the rotation of a cut plane
(the pressure on the fluid's cut face, which a follower load on the solid faces alone misses).
"""

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
import scipy.sparse as sp

# The integrand x . (A n) of a bilinear face has degree 2 in each of xi, eta: 3 x 3 Gauss points
# integrate it exactly.
_G3 = np.array([-np.sqrt(0.6), 0.0, np.sqrt(0.6)])
_W3 = np.array([5.0, 8.0, 5.0]) / 9.0
_XI3, _ETA3 = (grid.ravel() for grid in np.meshgrid(_G3, _G3, indexing='ij'))
_WEIGHTS3 = np.outer(_W3, _W3).ravel()
_CORNERS = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])


def _shape(xi: NDArray, eta: NDArray) -> tuple[NDArray, NDArray, NDArray]:
    """Bilinear shape functions and their xi, eta derivatives: arrays (points, 4)."""
    cx, cy = _CORNERS[:, 0], _CORNERS[:, 1]
    n = 0.25 * (1 + np.outer(xi, cx)) * (1 + np.outer(eta, cy))
    dn_dxi = 0.25 * cx[None, :] * (1 + np.outer(eta, cy))
    dn_deta = 0.25 * (1 + np.outer(xi, cx)) * cy[None, :]
    return n, dn_dxi, dn_deta


_N, _DXI, _DETA = _shape(_XI3, _ETA3)


@dataclass(frozen=True)
class Cavity:
    """
    Faces of the solid that bound a fluid cavity.

    ``faces`` holds four point indices per face, ordered so that ``dx/dxi x dx/deta`` points out
    of the fluid (into the solid); ``weights`` is the diagonal of ``A`` (see the module notes).
    """

    faces: NDArray[np.int64]
    weights: tuple[float, float, float]

    def volume(self, points: NDArray[np.float64]) -> float:
        """Fluid volume [m^3] for the current point positions (npoints, 3)."""
        return float(self._integrand_terms(points)[0].sum())

    def _integrand_terms(self, points: NDArray[np.float64]) -> tuple:
        x = points[self.faces]                                   # (faces, 4, 3)
        pos = np.einsum('qa,fai->fqi', _N, x)                   # (faces, q, 3)
        t1 = np.einsum('qa,fai->fqi', _DXI, x)
        t2 = np.einsum('qa,fai->fqi', _DETA, x)
        normal = np.cross(t1, t2)                                # n dA / (dxi deta)
        a = np.asarray(self.weights)
        values = np.einsum('fqi,i,fqi,q->f', pos, a, normal, _WEIGHTS3)
        return values, pos, t1, t2, normal

    def gradient(self, points: NDArray[np.float64]) -> NDArray[np.float64]:
        """dV/dx as an array (npoints, 3) [m^2]: the pressure load per unit pressure."""
        _, pos, t1, t2, normal = self._integrand_terms(points)
        a = np.asarray(self.weights)
        apos = pos * a                                           # A x at each point
        # d/dx_b of (A x) . (t1 x t2) = N_b A n + dN_b/dxi (t2 x A x) + dN_b/deta (A x x t1)
        term_n = np.einsum('qb,fqi,q->fbi', _N, normal * a, _WEIGHTS3)
        term_1 = np.einsum('qb,fqi,q->fbi', _DXI, np.cross(t2, apos), _WEIGHTS3)
        term_2 = np.einsum('qb,fqi,q->fbi', _DETA, np.cross(apos, t1), _WEIGHTS3)
        local = term_n + term_1 + term_2
        grad = np.zeros_like(points)
        np.add.at(grad, self.faces, local)
        return grad

    def hessian(self, points: NDArray[np.float64]) -> sp.csr_matrix:
        """d2V/dx2 as a sparse matrix over the dofs ``3 * point + component`` [m]."""
        _, pos, t1, t2, _ = self._integrand_terms(points)
        a = np.asarray(self.weights)
        eps = np.zeros((3, 3, 3))
        eps[0, 1, 2] = eps[1, 2, 0] = eps[2, 0, 1] = 1.0
        eps[0, 2, 1] = eps[2, 1, 0] = eps[1, 0, 2] = -1.0
        # f = a_i x_i eps_ijk t1_j t2_k is linear in each of x, t1, t2: only the mixed second
        # derivatives are non-zero; one order of each pair is built, then its transpose added.
        w = _WEIGHTS3
        e_t2 = np.einsum('imk,fqk->fqim', eps, t2)               # d(n_i)/d(t1_m)
        e_t1 = np.einsum('ijm,fqj->fqim', eps, t1)               # d(n_i)/d(t2_m)
        apos_eps = np.einsum('i,fqi,ijk->fqjk', a, pos, eps)     # d2 f / dt1_j dt2_k
        h_x_t1 = np.einsum('qb,qc,i,fqim,q->fbicm', _N, _DXI, a, e_t2, w)
        h_x_t2 = np.einsum('qb,qc,i,fqim,q->fbicm', _N, _DETA, a, e_t1, w)
        h_t1_t2 = np.einsum('qb,qc,fqjk,q->fbjck', _DXI, _DETA, apos_eps, w)
        local = h_x_t1 + h_x_t2 + h_t1_t2
        local = local + local.transpose(0, 3, 4, 1, 2)
        nf = self.faces.shape[0]
        dofs = (3 * self.faces[:, :, None] + np.arange(3)[None, None, :]).reshape(nf, 12)
        rows = np.repeat(dofs, 12, axis=1).ravel()
        cols = np.tile(dofs, (1, 12)).ravel()
        size = 3 * points.shape[0]
        return sp.csr_matrix((local.reshape(nf, 144).ravel(), (rows, cols)),
                             shape=(size, size))
