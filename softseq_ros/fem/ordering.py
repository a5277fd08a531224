"""
Sparse direct solves of the FEM systems with a fill-reducing nested-dissection ordering.

SuperLU's own column orderings fill a 3D stiffness matrix badly (about 5 million factor entries
for 10,000 unknowns). METIS' nested dissection of the matrix graph, applied symmetrically, cuts
that by half and, without partial pivoting (the matrices are symmetric and the border row of the
volume constraint comes last), the factorization by a factor of five. Every solution is refined
once and checked by its backward error; a poor one is redone with SuperLU's pivoting LU.

An unpivoted LU of a symmetric matrix is its L D L^T factorization (U = D L^T), so it also gives
the matrix's inertia (Sylvester: as many negative eigenvalues as negative pivots) for
the price of the solve: whether an equilibrium is stable.
"""

import numpy as np
from numpy.typing import NDArray
import pymetis
import scipy.sparse as sp
from scipy.sparse.linalg import splu

# Backward error |A x - b| / (|A| |x| + |b|) (infinity norms) above which an unpivoted
# factorization is not trusted; a stable LU gives about 1e-16. The relative residual alone would
# not do: the first Newton system of each volume step has a right-hand side that is only the
# small volume mismatch, and round-off in the force rows then looks large beside it.
_BACKWARD_ERROR_LIMIT = 1e-10


def nested_dissection(matrix: sp.spmatrix) -> NDArray[np.int64]:
    """Symmetric fill-reducing permutation of a square sparse matrix (METIS)."""
    pattern = (abs(matrix) + abs(matrix).T).tocsr()
    pattern.setdiag(0)
    pattern.eliminate_zeros()
    adjacency = pymetis.CSRAdjacency(pattern.indptr, pattern.indices)
    permutation, _ = pymetis.nested_dissection(adjacency)
    return np.asarray(permutation, dtype=np.int64)


class SparseSolver:
    """Solves systems that share one sparsity pattern, reusing its ordering."""

    def __init__(self, border: int = 1) -> None:
        """``border``: the last unknowns (multipliers, path parameters) kept last, in order."""
        self._permutation: NDArray[np.int64] | None = None
        self._size = -1
        self._border = border
        self._factor = None  # the last solve's unpivoted factorization, when it was trusted

    def solve(self, matrix: sp.spmatrix, rhs: NDArray[np.float64]) -> NDArray[np.float64]:
        """Solution of ``matrix @ x = rhs``; raises RuntimeError on an exactly singular matrix."""
        matrix = matrix.tocsr()
        size = matrix.shape[0]
        if self._permutation is None or self._size != size:
            # The border unknowns stay last.
            inner = size - self._border
            head = nested_dissection(matrix[:inner, :inner])
            self._permutation = np.concatenate([head, np.arange(inner, size)])
            self._size = size
        perm = self._permutation
        permuted = matrix[perm][:, perm].tocsc()
        solution = np.empty(size)
        self._factor = None
        try:
            lu = splu(permuted, permc_spec='NATURAL', diag_pivot_thresh=0.0,
                      options={'SymmetricMode': True})
            solution[perm] = lu.solve(rhs[perm])
            correction = np.empty(size)
            correction[perm] = lu.solve((rhs - matrix @ solution)[perm])
            solution += correction
            residual = np.abs(matrix @ solution - rhs).max()
            scale = (abs(matrix).sum(axis=1).max() * np.abs(solution).max()
                     + np.abs(rhs).max())
            if np.isfinite(residual) and residual <= _BACKWARD_ERROR_LIMIT * scale:
                if np.array_equal(lu.perm_r, np.arange(size)):
                    self._factor = lu
                return solution
        except RuntimeError:
            pass
        return splu(matrix.tocsc()).solve(rhs)

    def negative_pivots(self) -> int | None:
        """
        Negative eigenvalues of the last matrix solved, if symmetric (None: not known).

        Known when the last solve kept its unpivoted factorization (no row was exchanged).
        """
        if self._factor is None:
            return None
        return int(np.count_nonzero(self._factor.U.diagonal() < 0))

    def solve_again(self, rhs: NDArray[np.float64]) -> NDArray[np.float64] | None:
        """Solution with the last trusted factorization, unrefined (None: there is none)."""
        if self._factor is None:
            return None
        perm = self._permutation
        solution = np.empty(rhs.size)
        solution[perm] = self._factor.solve(rhs[perm])
        return solution
