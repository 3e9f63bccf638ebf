"""Shared helpers of the group kernels: group ids and sizes, small dense 3x3/block algebra, phi(A) and Jr from ad.

Part of :mod:`fgopt.manifolds._kernels` (conventions in its docstring).
"""

from __future__ import annotations

import numpy as np
from ..._jit import njit


SO2_ID, SE2_ID, SO3_ID, SE3_ID, SIM3_ID = 0, 1, 2, 3, 4


GROUP_NAMES = ("SO2", "SE2", "SO3", "SE3", "Sim3")


STORAGE_DIMS = (2, 4, 4, 7, 8)


TANGENT_DIMS = (1, 3, 3, 6, 7)


MAX_STORAGE_DIM = 8


MAX_DIM = 7


@njit(cache=True)
def storage_dim(gid):
    return 2 if gid == SO2_ID else 4 if gid <= SO3_ID else 7 if gid == SE3_ID else 8


@njit(cache=True)
def tangent_dim(gid):
    return 1 if gid == SO2_ID else 3 if gid <= SO3_ID else 6 if gid == SE3_ID else 7


@njit(cache=True)
def _cross(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@njit(cache=True)
def skew_poly_apply(w, c0, c1, c2, v, out):
    """out = (c0 I + c1 hat(w) + c2 hat(w)^2) v, for 3-vectors w, v (out may alias v)."""
    v0, v1, v2 = v[0], v[1], v[2]
    x0, x1, x2 = _cross(w[0], w[1], w[2], v0, v1, v2)
    y0, y1, y2 = _cross(w[0], w[1], w[2], x0, x1, x2)
    out[0] = c0 * v0 + c1 * x0 + c2 * y0
    out[1] = c0 * v1 + c1 * x1 + c2 * y1
    out[2] = c0 * v2 + c1 * x2 + c2 * y2


@njit(cache=True)
def skew_poly3(w, c0, c1, c2, out, r, c):
    """out[r:r+3, c:c+3] = c0 I + c1 hat(w) + c2 hat(w)^2, with hat(w)^2 = w w^T - |w|^2 I.

    Blocks are written through offsets rather than slices: 2-D slices are 'A'-layout arrays,
    each of which costs numba a separate compilation of the callee.
    """
    x, y, z = w[0], w[1], w[2]
    out[r, c] = c0 - c2 * (y * y + z * z)
    out[r + 1, c + 1] = c0 - c2 * (x * x + z * z)
    out[r + 2, c + 2] = c0 - c2 * (x * x + y * y)
    out[r, c + 1] = -c1 * z + c2 * x * y
    out[r + 1, c] = c1 * z + c2 * x * y
    out[r, c + 2] = c1 * y + c2 * x * z
    out[r + 2, c] = -c1 * y + c2 * x * z
    out[r + 1, c + 2] = -c1 * x + c2 * y * z
    out[r + 2, c + 1] = c1 * x + c2 * y * z


@njit(cache=True)
def fill_block(out, r, c, nr, nc, value):
    """out[r:r+nr, c:c+nc] = value."""
    for i in range(r, r + nr):
        for j in range(c, c + nc):
            out[i, j] = value


@njit(cache=True)
def copy_block3(m, rs, cs, rd, cd, scale):
    """m[rd:rd+3, cd:cd+3] = scale * m[rs:rs+3, cs:cs+3] (non-overlapping blocks)."""
    for i in range(3):
        for j in range(3):
            m[rd + i, cd + j] = scale * m[rs + i, cs + j]


@njit(cache=True)
def matmul_block3(m, ra, ca, rb, cb, rd, cd, scale):
    """m[rd:rd+3, cd:cd+3] = scale * A @ B for 3x3 blocks A at (ra, ca), B at (rb, cb) of m.

    The destination must not overlap A or B.
    """
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for k in range(3):
                acc += m[ra + i, ca + k] * m[rb + k, cb + j]
            m[rd + i, cd + j] = scale * acc


@njit(cache=True)
def matmul(a, b, out):
    """out = a @ b for small matrices (out must not alias a or b)."""
    for i in range(a.shape[0]):
        for j in range(b.shape[1]):
            acc = 0.0
            for k in range(a.shape[1]):
                acc += a[i, k] * b[k, j]
            out[i, j] = acc


@njit(cache=True)
def invert(a, out):
    """out = a^-1 by Gauss-Jordan elimination with partial pivoting (small square a)."""
    n = a.shape[0]
    m = a.copy()
    for i in range(n):
        for j in range(n):
            out[i, j] = 1.0 if i == j else 0.0
    for col in range(n):
        piv = col
        for r in range(col + 1, n):
            if abs(m[r, col]) > abs(m[piv, col]):
                piv = r
        if piv != col:
            for j in range(n):
                m[col, j], m[piv, j] = m[piv, j], m[col, j]
                out[col, j], out[piv, j] = out[piv, j], out[col, j]
        inv_p = 1.0 / m[col, col]
        for j in range(n):
            m[col, j] *= inv_p
            out[col, j] *= inv_p
        for r in range(n):
            if r != col and m[r, col] != 0.0:
                f = m[r, col]
                for j in range(n):
                    m[r, j] -= f * m[col, j]
                    out[r, j] -= f * out[col, j]


@njit(cache=True)
def phi_matrix(a, out):
    """out = phi(a) = sum_k a^k / (k+1)! = (e^a - I) a^-1, by Taylor and scaling-and-squaring.

    Squaring uses phi(2a) = phi(a) (e^a + I) / 2. Accurate to rounding error for any a.
    """
    n = a.shape[0]
    nrm = 0.0
    for i in range(n):
        row = 0.0
        for j in range(n):
            row += abs(a[i, j])
        nrm = max(nrm, row)
    s = 0
    while nrm > 0.5 and s < 60:
        nrm *= 0.5
        s += 1
    scale = 0.5 ** s
    b = np.empty((n, n))
    e = np.eye(n)
    term = np.eye(n)
    tmp = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            b[i, j] = a[i, j] * scale
            out[i, j] = 1.0 if i == j else 0.0
    for k in range(1, 18):  # e = exp(b), out = phi(b); |b| <= 1/2, so 18 terms reach 1e-21
        matmul(term, b, tmp)
        for i in range(n):
            for j in range(n):
                term[i, j] = tmp[i, j] / k
                e[i, j] += term[i, j]
                out[i, j] += term[i, j] / (k + 1)
    for _ in range(s):
        for i in range(n):
            e[i, i] += 1.0
        matmul(out, e, tmp)
        for i in range(n):
            e[i, i] -= 1.0
            for j in range(n):
                out[i, j] = 0.5 * tmp[i, j]
        matmul(e, e, tmp)
        for i in range(n):
            for j in range(n):
                e[i, j] = tmp[i, j]


@njit(cache=True)
def jr_from_ad(ad, out):
    """Right Jacobian from the ad matrix: out = phi(-ad) (any matrix Lie group)."""
    phi_matrix(-ad, out)
