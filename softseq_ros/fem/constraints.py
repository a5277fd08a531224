"""
The unknowns of a model with symmetry: nodal positions as a function of reduced coordinates q.

Most points move freely or slide on fixed planes (a linear map ``x = X + B q``). The points of a
cut through a repeating pattern (the mid-plane of a wall in a unit cell) must stay on one plane
that contains the y direction and may turn about it as the segment bends: their positions are
``x = o + c n(theta) + s t(theta) + y e_y`` with ``n = (cos, 0, sin)``, ``t = (-sin, 0, cos)``,
two global unknowns (offset c, angle theta) and, per point, its coordinates s and y in the plane.
The map is non-linear in theta; :meth:`ReducedSpace.second_order` gives the term that makes the
Newton tangent exact.
"""

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
import scipy.sparse as sp


def _complement(normals: list[NDArray]) -> NDArray[np.float64]:
    """Orthonormal basis (3, k) of the directions perpendicular to every given normal."""
    if not normals:
        return np.eye(3)
    _, singular, vt = np.linalg.svd(np.array(normals, dtype=float))
    rank = int((singular > 1e-12).sum())
    return vt[rank:].T.copy()


@dataclass
class ReducedSpace:
    """
    Reduced coordinates of a mesh's points under symmetry and support constraints.

    Build it with the reference points, then call :meth:`fix` for points that stay on planes (or
    are held), optionally :meth:`rotating_plane`, and finally :meth:`finish`.
    """

    reference: NDArray[np.float64]
    _normals: dict[int, list[NDArray]] = field(default_factory=dict)
    _plane_points: NDArray[np.int64] | None = None
    _plane_origin: NDArray[np.float64] | None = None

    def fix(self, points: NDArray[np.int64], normal: tuple[float, float, float]) -> None:
        """Keep ``points`` from moving along ``normal`` (a plane of symmetry or a support)."""
        direction = np.asarray(normal, dtype=float)
        direction = direction / np.linalg.norm(direction)
        for point in np.asarray(points).ravel():
            self._normals.setdefault(int(point), []).append(direction)

    def rotating_plane(self, points: NDArray[np.int64],
                       origin: tuple[float, float, float]) -> None:
        """Keep ``points`` (all at x = origin[0]) on one plane that may shift and turn about y."""
        self._plane_points = np.asarray(points, dtype=np.int64).ravel()
        self._plane_origin = np.asarray(origin, dtype=float)
        if not np.allclose(self.reference[self._plane_points, 0], self._plane_origin[0]):
            raise ValueError("rotating plane points must lie at the origin's x")

    def finish(self) -> 'ReducedSpace':
        """Number the reduced coordinates; returns self."""
        npoints = self.reference.shape[0]
        in_plane = np.zeros(npoints, dtype=bool)
        if self._plane_points is not None:
            in_plane[self._plane_points] = True
        rows, cols, vals = [], [], []
        count = 0
        for point in range(npoints):
            if in_plane[point]:
                continue
            basis = _complement(self._normals.get(point, []))
            for k in range(basis.shape[1]):
                for i in range(3):
                    if abs(basis[i, k]) > 0.0:
                        rows.append(3 * point + i)
                        cols.append(count)
                        vals.append(basis[i, k])
                count += 1
        self.linear_count = count
        self._linear = sp.csr_matrix((vals, (rows, cols)), shape=(3 * npoints, count))
        # Plane points: s always free; y free unless the point is held in y (on y = 0).
        self._plane_s_index = np.zeros(0, dtype=np.int64)
        self._plane_y_index = np.full(0, -1, dtype=np.int64)
        if self._plane_points is not None:
            s_index, y_index = [], []
            for point in self._plane_points:
                normals = self._normals.get(int(point), [])
                held_y = any(abs(n[1]) > 0.5 for n in normals)
                others = [n for n in normals if abs(n[1]) <= 0.5]
                if others:
                    raise ValueError('a rotating plane point may only be held in y')
                s_index.append(count)
                count += 1
                if held_y:
                    y_index.append(-1)
                else:
                    y_index.append(count)
                    count += 1
            self._plane_s_index = np.array(s_index, dtype=np.int64)
            self._plane_y_index = np.array(y_index, dtype=np.int64)
            self.offset_index = count
            self.angle_index = count + 1
            count += 2
        self.size = count
        return self

    @property
    def has_plane(self) -> bool:
        """Whether the model has a rotating cut plane."""
        return self._plane_points is not None

    def plane_angle(self, q: NDArray[np.float64]) -> float:
        """Rotation of the cut plane about y [rad] (0 without one)."""
        return float(q[self.angle_index]) if self.has_plane else 0.0

    def _plane_frame(self, q: NDArray) -> tuple[NDArray, NDArray, float, NDArray]:
        theta = q[self.angle_index]
        normal = np.array([np.cos(theta), 0.0, np.sin(theta)])
        tangent = np.array([-np.sin(theta), 0.0, np.cos(theta)])
        along = (self.reference[self._plane_points, 2] - self._plane_origin[2]
                 + q[self._plane_s_index])
        return normal, tangent, float(q[self.offset_index]), along

    def positions(self, q: NDArray[np.float64]) -> NDArray[np.float64]:
        """Point positions (npoints, 3) [m] for reduced coordinates q."""
        x = self.reference + (self._linear @ q[:self.linear_count]).reshape(-1, 3)
        if self.has_plane:
            normal, tangent, offset, along = self._plane_frame(q)
            y = self.reference[self._plane_points, 1].copy()
            free = self._plane_y_index >= 0
            y[free] += q[self._plane_y_index[free]]
            x[self._plane_points] = (self._plane_origin + offset * normal
                                     + along[:, None] * tangent + y[:, None] * [0.0, 1.0, 0.0])
        return x

    def jacobian(self, q: NDArray[np.float64]) -> sp.csr_matrix:
        """dx/dq as a sparse matrix (3 npoints, size)."""
        npoints = self.reference.shape[0]
        linear = sp.hstack([self._linear,
                            sp.csr_matrix((3 * npoints, self.size - self.linear_count))])
        if not self.has_plane:
            return linear.tocsr()
        normal, tangent, offset, along = self._plane_frame(q)
        rows, cols, vals = [], [], []
        for k, point in enumerate(self._plane_points):
            d_theta = offset * tangent - along[k] * normal
            for i in range(3):
                base = 3 * int(point) + i
                rows += [base, base, base]
                cols += [int(self._plane_s_index[k]), self.offset_index, self.angle_index]
                vals += [tangent[i], normal[i], d_theta[i]]
            if self._plane_y_index[k] >= 0:
                rows.append(3 * int(point) + 1)
                cols.append(int(self._plane_y_index[k]))
                vals.append(1.0)
        plane = sp.csr_matrix((vals, (rows, cols)), shape=(3 * npoints, self.size))
        return (linear + plane).tocsr()

    def second_order(self, q: NDArray[np.float64],
                     force: NDArray[np.float64]) -> sp.csr_matrix:
        """Sum over points of force . d2x/dq2: the tangent term of the turning plane."""
        if not self.has_plane:
            return sp.csr_matrix((self.size, self.size))
        normal, tangent, offset, along = self._plane_frame(q)
        f = force.reshape(-1, 3)[self._plane_points]
        f_t = f @ tangent
        f_n = f @ normal
        a, c = self.angle_index, self.offset_index
        rows = [a, c, a]
        cols = [c, a, a]
        vals = [f_t.sum(), f_t.sum(), float((-offset * f_n - along * f_t).sum())]
        s = self._plane_s_index
        rows += list(s) + [a] * len(s)
        cols += [a] * len(s) + list(s)
        vals += list(-f_n) + list(-f_n)
        return sp.csr_matrix((vals, (rows, cols)), shape=(self.size, self.size))
