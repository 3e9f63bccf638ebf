"""Preconditioned conjugate gradients (scipy ``cg``) with a block-Jacobi preconditioner.

The preconditioner inverts each variable's diagonal block of H (batched per block size).
H is applied from its lower triangle by a numba product, so no full matrix is built.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse.linalg as spla

from ...errors import NotPositiveDefiniteError
from ...structure import HessianPattern


class PCGSolver:
    name = "pcg"

    def __init__(self, rtol: float = 1e-10, max_iterations: int | None = None):
        self.rtol = rtol
        self.max_iterations = max_iterations
        self.last_iterations = 0

    def analyze(self, pattern: HessianPattern) -> None:
        self._pattern = pattern
        # data indices of every variable's diagonal block (lower part), grouped by block size
        self._groups = []
        for d in np.unique(pattern.var_dim):
            vars_ = np.nonzero(pattern.var_dim == d)[0]
            off = pattern.var_offset[vars_]
            # positions of (off+a, off+b) for a >= b, found from the CSC column of off+b
            idx = np.full((vars_.shape[0], d, d), -1, dtype=np.int64)
            for b in range(d):
                col = off + b
                start = pattern.indptr[col]
                for a in range(b, d):
                    idx[:, a, b] = start + (a - b)  # diagonal block rows come first, contiguous
            tangent = off[:, None] + np.arange(d)[None, :]
            self._groups.append((d, idx, tangent))

    def factorize(self, H_data: np.ndarray) -> None:
        self._H = H_data.copy()
        self._inv = []
        for d, idx, tangent in self._groups:
            blocks = H_data[idx]                       # lower entries; upper positions hold junk
            tril = np.tril(np.ones((d, d), dtype=bool))
            blocks = np.where(tril, blocks, 0.0)
            blocks = blocks + np.transpose(blocks, (0, 2, 1)) - blocks * np.eye(d)
            try:
                L = np.linalg.cholesky(blocks)
            except np.linalg.LinAlgError:
                raise NotPositiveDefiniteError(
                    "PCG: a diagonal block of H is not positive definite") from None
            eye = np.broadcast_to(np.eye(d), blocks.shape)
            Linv = np.linalg.solve(L, eye)
            self._inv.append((tangent, np.transpose(Linv, (0, 2, 1)) @ Linv))

    def _precondition(self, r: np.ndarray) -> np.ndarray:
        z = np.empty_like(r)
        for tangent, inv in self._inv:
            z[tangent] = np.einsum("nij,nj->ni", inv, r[tangent])
        return z

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """``H^-1 rhs`` for one right-hand side or the columns of a 2-D ``rhs``. Raises
        :class:`NotPositiveDefiniteError` when CG does not reach ``rtol`` (H singular, or too
        ill-conditioned for ``max_iterations``): its iterate is no solution."""
        rhs = np.asarray(rhs, dtype=float)
        if rhs.ndim == 2:
            return np.column_stack([self._solve1(rhs[:, j]) for j in range(rhs.shape[1])])
        return self._solve1(rhs)

    def _solve1(self, rhs: np.ndarray) -> np.ndarray:
        n = self._pattern.size
        H_data, pattern = self._H, self._pattern
        A = spla.LinearOperator((n, n), matvec=lambda x: pattern.matvec(H_data, x), dtype=float)
        M = spla.LinearOperator((n, n), matvec=self._precondition, dtype=float)
        iters = [0]

        def count(_):
            iters[0] += 1

        maxiter = self.max_iterations or 10 * n
        x, info = spla.cg(A, rhs, rtol=self.rtol, atol=0.0, M=M, maxiter=maxiter,
                          callback=count)
        self.last_iterations = iters[0]
        if info < 0:
            raise NotPositiveDefiniteError("PCG broke down (H not positive definite?)")
        if info > 0 or not np.all(np.isfinite(x)):
            raise NotPositiveDefiniteError(
                f"PCG: no solution to rtol={self.rtol:g} in {maxiter} iterations (H singular "
                "or too ill-conditioned)")
        return x
