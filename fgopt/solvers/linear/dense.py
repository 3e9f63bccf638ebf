"""Dense Cholesky (LAPACK) for small problems."""

from __future__ import annotations

import numpy as np
import scipy.linalg

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
            self._cho = scipy.linalg.cho_factor(H, lower=True, check_finite=False)
        except np.linalg.LinAlgError:
            raise NotPositiveDefiniteError("dense Cholesky: H is not positive definite") from None
        if not np.all(np.diag(self._cho[0]) > 0):
            raise NotPositiveDefiniteError("dense Cholesky: H is not positive definite")

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        return scipy.linalg.cho_solve(self._cho, rhs, check_finite=False)
