"""LDL^T with qdldl: the pattern (upper triangle, the transpose of fgopt's lower CSC) is fixed
once; each step only permutes the numbers into it and calls ``update``."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ...errors import BackendUnavailableError, NotPositiveDefiniteError
from ...structure import HessianPattern
from .base import PIVOT_TOLERANCE, pivot_failure


class LDLTSolver:
    name = "ldlt"

    def __init__(self, pivot_tolerance: float = PIVOT_TOLERANCE):
        #: A pivot must exceed this times its diagonal entry of H (:data:`.base.PIVOT_TOLERANCE`).
        self.pivot_tolerance = float(pivot_tolerance)
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
        self._diag, self._var_offset, self._var_dim = (pattern.diag_pos, pattern.var_offset,
                                                       pattern.var_dim)

    def factorize(self, H_data: np.ndarray) -> None:
        diag = H_data[self._diag]
        try:
            self._factor(H_data)
        except NotPositiveDefiniteError:
            # qdldl stops at an exact zero pivot without saying where: locate it on H plus half
            # the tolerated pivot, where it is the first pivot to fail the relative test
            damped = H_data.copy()
            damped[self._diag] += 0.5 * self.pivot_tolerance * np.abs(diag)
            try:
                self._factor(damped)
            except NotPositiveDefiniteError:
                raise NotPositiveDefiniteError("qdldl: H is not positive definite") from None
            self._check(diag)
            raise NotPositiveDefiniteError("qdldl: H is not positive definite") from None
        self._check(diag)

    def _factor(self, H_data: np.ndarray) -> None:
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

    def _check(self, diag: np.ndarray) -> None:
        """Each pivot against its diagonal entry of H (:data:`.base.PIVOT_TOLERANCE`)."""
        _, D, P = self._solver.factors()   # A[P][:, P] = L D L^T
        ok = D > self.pivot_tolerance * diag[P]   # (NaN fails)
        if not np.all(ok):
            raise pivot_failure("qdldl", self._var_offset, self._var_dim, int(P[np.argmin(ok)]),
                                self.pivot_tolerance)

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """``H^-1 rhs`` for one right-hand side or the columns of a 2-D ``rhs`` (qdldl solves
        one at a time)."""
        rhs = np.asarray(rhs, dtype=float)
        if rhs.ndim == 2:
            return np.column_stack([self._solver.solve(rhs[:, j]) for j in range(rhs.shape[1])])
        return self._solver.solve(rhs)
