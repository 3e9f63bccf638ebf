"""Dense Cholesky (LAPACK through numpy) for small problems."""

from __future__ import annotations

import numpy as np

from ...structure import HessianPattern
from .base import PIVOT_TOLERANCE, pivot_failure


class DenseCholeskySolver:
    """Dense Cholesky of H. ``numba=True`` (what ``"auto"`` picks on the numba backend): the
    block solver's kernels on one supernode (:func:`~.block_cholesky.analyze_dense`), one
    compiled call per factorization and per solve; measured 13 us instead of 99 us per
    factorization and solve at 72 unknowns (SFMExample). Otherwise NumPy's LAPACK (no numba)."""

    name = "dense"

    def __init__(self, numba: bool = False, pivot_tolerance: float = PIVOT_TOLERANCE):
        self._block = None
        #: A pivot must exceed this times its diagonal entry of H (:data:`.base.PIVOT_TOLERANCE`).
        self.pivot_tolerance = float(pivot_tolerance)
        if numba:
            from .block_cholesky import BlockCholeskySolver

            self._block = BlockCholeskySolver(dense=True, pivot_tolerance=pivot_tolerance)

    def analyze(self, pattern: HessianPattern) -> None:
        if self._block is not None:
            self._block.analyze(pattern)
            return
        self._pattern = pattern
        n = pattern.size
        cols = np.repeat(np.arange(n), np.diff(pattern.indptr))
        self._rows, self._cols = pattern.indices, cols

    def factorize(self, H_data: np.ndarray) -> None:
        if self._block is not None:
            self._block.factorize(H_data)
            return
        n = self._pattern.size
        H = np.zeros((n, n))
        H[self._rows, self._cols] = H_data
        try:
            L = np.linalg.cholesky(H)  # reads the lower triangle (numpy: no scipy import)
        except np.linalg.LinAlgError:
            # which pivot failed (LAPACK's info; scipy only on this path)
            from scipy.linalg import lapack

            _, info = lapack.dpotrf(H, lower=1)
            raise pivot_failure("dense Cholesky", self._pattern.var_offset,
                                self._pattern.var_dim, max(int(info) - 1, 0),
                                self.pivot_tolerance) from None
        d = np.diag(L)
        ok = d * d > self.pivot_tolerance * np.diag(H)   # (NaN fails)
        if not np.all(ok):
            raise pivot_failure("dense Cholesky", self._pattern.var_offset,
                                self._pattern.var_dim, int(np.argmin(ok)), self.pivot_tolerance)
        self._L = L

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        if self._block is not None:
            return self._block.solve(rhs)
        # L L^T x = rhs; numpy has no triangular solver, and its general solve (LU; no pivoting
        # happens on a triangular matrix with a positive diagonal) costs little at <= 300 unknowns
        return np.linalg.solve(self._L.T, np.linalg.solve(self._L, rhs))
