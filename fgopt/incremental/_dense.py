"""Dense kernels on one clique's frontal matrix (numba; column-major, lower triangle).

A front is the ``m x m`` information matrix of a clique's ``fd`` frontal and ``sd`` separator
scalars (``m = fd + sd``) with its right-hand side ``b = -g``. ``partial_factor`` eliminates the
frontal block::

    [F11 F21^T]   [L11  0] [L11^T L21^T]   [0 0]
    [F21 F22  ] = [L21  I] [ 0     I   ] + [0 C],   C = F22 - L21 L21^T

leaving ``[L11; L21]`` in the first ``fd`` columns and the Schur complement ``C`` (the
clique's marginal on its separator, passed to the parent) in the trailing block. Narrow fronts
use numba loops; wide ones LAPACK ``dpotrf`` + BLAS ``dtrsm`` / ``dsyrk`` through the symbols
fgopt's block Cholesky binds (:mod:`fgopt.solvers.linear._block_kernels`).

A pivot ``d_j`` is accepted when ``d_j > tol * F_jj`` (``F_jj`` the assembled diagonal before
elimination): a direction the factors do not constrain leaves only rounding noise there.
"""

from __future__ import annotations

import math

import numpy as np

from .._jit import njit
from ..solvers.linear._block_kernels import (_CL, _CN, _CR, _CT, _I0, _dpotrf, _dsyrk,
                                             _dtrsm)

#: Fronts with more frontal columns than this go to LAPACK / BLAS.
BLAS_MIN_WIDTH = 24


_u = np.uint64


@njit(cache=True)
def _factor_narrow(W, m, fd, diag0, tol):
    """``partial_factor`` for narrow fronts: the panel left-looking, then the trailing update
    one column at a time (the column stays in cache while the ``fd`` panel columns are
    subtracted from it). Unsigned indices: no wraparound checks, so LLVM vectorizes."""
    mu = _u(m)
    for j in range(fd):
        ju = _u(j)
        cj = ju * mu
        for k in range(j):
            ck = _u(k) * mu
            f = W[ck + ju]
            for i in range(ju, mu):
                W[cj + i] -= W[ck + i] * f
        d = W[cj + ju]
        if not (d > tol * diag0[j]) or not (d > 0.0):
            return j
        d = math.sqrt(d)
        W[cj + ju] = d
        inv = 1.0 / d
        for i in range(ju + _u(1), mu):
            W[cj + i] *= inv
    for c in range(fd, m):
        cu = _u(c)
        cc = cu * mu
        j = 0
        while j + 3 <= fd:             # three panel columns per pass over column c
            a0 = _u(j) * mu
            a1 = a0 + mu
            a2 = a1 + mu
            f0, f1, f2 = W[a0 + cu], W[a1 + cu], W[a2 + cu]
            for i in range(cu, mu):
                W[cc + i] -= W[a0 + i] * f0 + W[a1 + i] * f1 + W[a2 + i] * f2
            j += 3
        while j < fd:
            a0 = _u(j) * mu
            f0 = W[a0 + cu]
            for i in range(cu, mu):
                W[cc + i] -= W[a0 + i] * f0
            j += 1
    return -1


@njit(cache=True)
def partial_factor(W, m, fd, diag0, tol, iw, fw):
    """Eliminate the first ``fd`` columns of the ``m x m`` front ``W`` in place.

    Returns -1, or the frontal column whose pivot failed the test in the module docstring.
    """
    for j in range(fd):
        diag0[j] = W[j + j * m]
    if fd <= BLAS_MIN_WIDTH:
        return _factor_narrow(W, m, fd, diag0, tol)
    sd = m - fd
    ip = iw.ctypes.data
    fp = fw.ctypes.data
    base = W.ctypes.data
    iw[_I0] = fd
    iw[_I0 + 1] = m
    iw[_I0 + 2] = 0
    iw[_I0 + 3] = sd
    _dpotrf(ip + 4 * _CL, ip + 4 * _I0, base, ip + 4 * (_I0 + 1), ip + 4 * (_I0 + 2))
    if iw[_I0 + 2] != 0:
        return iw[_I0 + 2] - 1
    for j in range(fd):
        d = W[j + j * m]
        if not (d * d > tol * diag0[j]) or not (d > 0.0):
            return j
    if sd > 0:
        # B <- B L11^-T (B: sd x fd below the diagonal block), then C <- C - B B^T
        _dtrsm(ip + 4 * _CR, ip + 4 * _CL, ip + 4 * _CT, ip + 4 * _CN, ip + 4 * (_I0 + 3),
               ip + 4 * _I0, fp, base, ip + 4 * (_I0 + 1), base + 8 * fd, ip + 4 * (_I0 + 1))
        _dsyrk(ip + 4 * _CL, ip + 4 * _CN, ip + 4 * (_I0 + 3), ip + 4 * _I0, fp + 8,
               base + 8 * fd, ip + 4 * (_I0 + 1), fp, base + 8 * (fd + fd * m),
               ip + 4 * (_I0 + 1))
    return -1


@njit(cache=True)
def forward_rhs(W, m, fd, b):
    """``y = L11^-1 b_F`` in place, then ``b_S -= L21 y`` (the separator's rhs)."""
    for j in range(fd):
        jm = j * m
        yj = b[j] / W[j + jm]
        b[j] = yj
        if yj != 0.0:
            for i in range(j + 1, m):
                b[i] -= W[i + jm] * yj


@njit(cache=True)
def add_local_system(W, m, b, H, g, P, D):
    """Add a factor's ``D x D`` Hessian ``H`` (row-major, full) and gradient ``g`` at front
    positions ``P`` (lower triangle of ``W``; ``b -= g``)."""
    for i in range(D):
        pi = P[i]
        b[pi] -= g[i]
        row = i * D
        for j in range(i + 1):
            pj = P[j]
            v = H[row + j]
            if pi >= pj:
                W[pi + pj * m] += v
            else:
                W[pj + pi * m] += v


@njit(cache=True)
def add_cached(W, m, b, C, c, P, sd):
    """Add a child's cached marginal ``C`` (``sd x sd`` lower, column-major) and rhs ``c`` at
    front positions ``P``."""
    for j in range(sd):
        pj = P[j]
        b[pj] += c[j]
        col = j * sd
        for i in range(j, sd):
            pi = P[i]
            v = C[i + col]
            if pi >= pj:
                W[pi + pj * m] += v
            else:
                W[pj + pi * m] += v


@njit(cache=True)
def back_substitute(panel, y, m, fd, xs, xf):
    """``x_F = L11^-T (y - L21^T x_S)`` from a stored panel ``[L11; L21]`` (``m x fd``)."""
    for j in range(fd - 1, -1, -1):
        jm = j * m
        acc = y[j]
        for i in range(fd, m):
            acc -= panel[i + jm] * xs[i - fd]
        for i in range(j + 1, fd):
            acc -= panel[i + jm] * xf[i]
        xf[j] = acc / panel[j + jm]
