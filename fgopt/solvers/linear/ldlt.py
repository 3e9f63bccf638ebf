"""LDL^T with qdldl: the pattern (upper triangle, the transpose of fgopt's lower CSC) is fixed
once; each step only permutes the numbers into it and calls ``update``."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ...errors import BackendUnavailableError, NotPositiveDefiniteError
from ...structure import HessianPattern


class LDLTSolver:
    name = "ldlt"

    def __init__(self):
        try:
            import qdldl  # noqa: F401
        except ImportError as e:  # pragma: no cover
            raise BackendUnavailableError("linear_solver='ldlt' needs qdldl (pip install qdldl)") from e
        self._solver = None

    def analyze(self, pattern: HessianPattern) -> None:
        L = pattern.matrix(np.arange(1, pattern.nnz + 1, dtype=float))
        U = L.T.tocsc()
        U.sort_indices()
        self._perm = U.data.astype(np.int64) - 1  # upper data = lower data[perm]
        self._U = sp.csc_matrix((np.zeros(pattern.nnz), U.indices, U.indptr), shape=U.shape)
        self._solver = None

    def factorize(self, H_data: np.ndarray) -> None:
        import qdldl

        self._U.data[:] = H_data[self._perm]
        try:
            if self._solver is None:
                self._solver = qdldl.Solver(self._U, upper=True)
            else:
                self._solver.update(self._U, upper=True)
        except Exception as e:
            self._solver = None
            raise NotPositiveDefiniteError(f"qdldl: factorization failed ({e})") from None
        _, D, _ = self._solver.factors()
        if not np.all(D > 0):
            raise NotPositiveDefiniteError("qdldl: H is not positive definite (non-positive pivot)")

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        return self._solver.solve(rhs)
