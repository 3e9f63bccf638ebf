"""Dense Cholesky (LAPACK through numpy) for small problems."""

from __future__ import annotations

import numpy as np

from ...errors import NotPositiveDefiniteError
from ...structure import HessianPattern


class DenseCholeskySolver:
    name = "dense"

    def analyze(self, pattern: HessianPattern) -> None:
        self._pattern = pattern
        n = pattern.size
        cols = np.repeat(np.arange(n), np.diff(pattern.indptr))
        self._rows, self._cols = pattern.indices, cols

    def factorize(self, H_data: np.ndarray) -> None:
        n = self._pattern.size
        H = np.zeros((n, n))
        H[self._rows, self._cols] = H_data
        try:
            L = np.linalg.cholesky(H)  # reads the lower triangle (numpy: no scipy import)
        except np.linalg.LinAlgError:
            raise NotPositiveDefiniteError("dense Cholesky: H is not positive definite") from None
        if not np.all(np.diag(L) > 0):
            raise NotPositiveDefiniteError("dense Cholesky: H is not positive definite")
        self._L = L

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        # L L^T x = rhs; numpy has no triangular solver, and its general solve (LU; no pivoting
        # happens on a triangular matrix with a positive diagonal) costs little at <= 300 unknowns
        return np.linalg.solve(self._L.T, np.linalg.solve(self._L, rhs))
