"""Information matrices in files: upper-triangle packing, tangent-order permutation, batched
Cholesky with per-row positive-definiteness checks, and the optional eigenvalue repair.

Files store the upper triangle of each information matrix row by row. g2o orders a pose's
tangent translation first ``(x, y, theta)`` / ``(x, y, z, rx, ry, rz)``; fgopt's SE2 / SE3 tangents
are rotation first ``[theta, vx, vy]`` / ``[wx, wy, wz, vx, vy, vz]``, so matrices are permuted
(``I_fgopt[a, b] = I_file[perm[a], perm[b]]``) on reading and back on writing. The
square-root information is the upper-triangular ``R = L^T`` of the Cholesky ``I = L L^T``.
"""

from __future__ import annotations

import logging

import numpy as np

log = logging.getLogger("fgopt.io")

#: fgopt tangent index -> file tangent index, per pose dimension.
PERM_SE2 = np.array([2, 0, 1])
PERM_SE3 = np.array([3, 4, 5, 0, 1, 2])
#: TORO EDGE2 stores ``xx xy yy tt xt yt``: positions of these in the (x, y, t) upper triangle.
TORO_TO_G2O_SE2 = np.array([0, 1, 3, 5, 2, 4])

REPAIR_CHOICES = (None, "clip")


def unpack_upper(packed: np.ndarray, dim: int, perm: np.ndarray | None = None) -> np.ndarray:
    """``(n, dim*(dim+1)/2)`` upper triangles, row by row -> ``(n, dim, dim)`` symmetric, then
    permuted (``out[:, a, b] = full[:, perm[a], perm[b]]``) when ``perm`` is given."""
    n = packed.shape[0]
    iu, ju = np.triu_indices(dim)
    if n > 1 and (packed == packed[0]).all():
        # one matrix for every edge (most files): unpack it once (a 122k-edge grid: 41 -> 10 ms)
        out = np.empty((n, dim, dim))
        out[:] = unpack_upper(packed[:1], dim, perm)[0]
        return out
    out = np.zeros((n, dim, dim))
    out[:, iu, ju] = packed
    out[:, ju, iu] = packed
    return out if perm is None else permute(out, perm)


def pack_upper(mats: np.ndarray) -> np.ndarray:
    """``(n, dim, dim)`` -> ``(n, dim*(dim+1)/2)`` upper triangles, row by row."""
    iu, ju = np.triu_indices(mats.shape[-1])
    return mats[:, iu, ju]


def permute(mats: np.ndarray, perm: np.ndarray) -> np.ndarray:
    """``out[:, a, b] = mats[:, perm[a], perm[b]]``."""
    return mats[:, perm[:, None], perm[None, :]]


def inverse_permutation(perm: np.ndarray) -> np.ndarray:
    inv = np.empty_like(perm)
    inv[perm] = np.arange(perm.shape[0])
    return inv


def not_positive_definite(info: np.ndarray) -> np.ndarray:
    """Boolean ``(n,)``: rows whose symmetric matrix is not (numerically) positive definite."""
    n = info.shape[0]
    if n == 0:
        return np.zeros(0, dtype=bool)
    try:
        np.linalg.cholesky(info)
        return np.zeros(n, dtype=bool)
    except np.linalg.LinAlgError:
        pass
    w = np.linalg.eigvalsh(info)
    bad = w[:, 0] <= 1e-14 * np.maximum(np.abs(w[:, -1]), 1e-300)
    good = np.nonzero(~bad)[0]
    try:
        np.linalg.cholesky(info[good])
    except np.linalg.LinAlgError:  # borderline rows: decide one by one
        for i in good.tolist():
            try:
                np.linalg.cholesky(info[i])
            except np.linalg.LinAlgError:
                bad[i] = True
    return bad


def clip_eigenvalues(info: np.ndarray, rows: np.ndarray, floor: float) -> tuple[np.ndarray, float]:
    """Clip the eigenvalues of ``info[rows]`` to ``floor * max(|eigenvalue|)`` (per matrix).

    Returns the repaired copy and the largest relative change ``|I' - I|_F / |I|_F``.
    """
    out = info.copy()
    if rows.shape[0] == 0:
        return out, 0.0
    sub = info[rows]
    w, V = np.linalg.eigh(sub)
    lo = floor * np.maximum(np.abs(w).max(axis=1), 1e-300)
    w2 = np.maximum(w, lo[:, None])
    fixed = np.einsum("nij,nj,nkj->nik", V, w2, V)
    fixed = 0.5 * (fixed + fixed.transpose(0, 2, 1))
    out[rows] = fixed
    change = np.linalg.norm(fixed - sub, axis=(1, 2)) / np.maximum(
        np.linalg.norm(sub, axis=(1, 2)), 1e-300)
    return out, float(change.max())


def sqrt_information(info: np.ndarray) -> np.ndarray:
    """Upper-triangular ``R`` with ``R^T R = info`` for a stack of PD matrices."""
    L = np.linalg.cholesky(info)
    return np.ascontiguousarray(L.transpose(0, 2, 1))


def checked_sqrt_information(info: np.ndarray) -> tuple[np.ndarray | None, np.ndarray]:
    """``(R, bad)``: :func:`sqrt_information` of ``info`` and the rows that are not positive
    definite (:func:`not_positive_definite`); ``R`` is None when any row is bad.

    One factorization when every matrix is the same (most files; LAPACK factors each matrix of a
    stack alone, so the result is the same bits), else one of the stack.
    """
    n = info.shape[0]
    if n > 1 and (info == info[0]).all():
        try:
            R1 = np.linalg.cholesky(info[0]).T
        except np.linalg.LinAlgError:
            return None, not_positive_definite(info[:1]).repeat(n)
        R = np.empty_like(info)
        R[:] = R1
        return R, np.zeros(n, dtype=bool)
    try:
        return sqrt_information(info), np.zeros(n, dtype=bool)
    except np.linalg.LinAlgError:
        return None, not_positive_definite(info)


def information_of(R: np.ndarray) -> np.ndarray:
    """``R^T R`` for a stack of square-root information matrices."""
    return np.einsum("nki,nkj->nij", R, R)
