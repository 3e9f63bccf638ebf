"""Selected inverse of H from its block supernodal Cholesky factor (numba).

The entries of ``Sigma = H^-1`` on the pattern of ``L`` (``H = L L^T``) follow from ``L`` alone
(Takahashi, Fagan and Chen, 1973), without the rest of the inverse. For a supernode with
diagonal block ``L11``, the block ``L21`` below it (rows: its row variables ``S``) and the
already computed ``Sigma_SS`` of those ancestors (a clique of L's pattern, so stored)::

    X        = L21 L11^-1
    Sigma_21 = -Sigma_SS X
    Sigma_11 = L11^-T L11^-1 - X^T Sigma_21

processed from the root down. The cost is of the order of the factorization's. Every pair of
variables a factor couples is in H's pattern, hence in L's: a factor's covariance block
``Sigma_ee`` (what its leverage needs, :mod:`fgopt.solvers.influence`) is read from here.

Storage is the factor's (:mod:`fgopt.solvers.linear.block_cholesky`): supernode ``s`` owns a
column-major ``rows[s] x width[s]`` panel at ``pstart[s]``; the selected inverse fills a panel
of the same layout, with the full symmetric diagonal block.
"""

from __future__ import annotations

import numpy as np
from ..._jit import njit
from ..._structure_kernels import lower_bound


@njit(cache=True)
def _row_of(rvi, lo, hi, v):
    """Position of variable ``v`` in the sorted ``rvi[lo:hi]``, -1 if absent."""
    lo = lower_bound(rvi, lo, hi, v)
    return lo if lo < rvi.shape[0] and rvi[lo] == v else -1


@njit(cache=True)
def _block(pstart, rows, sn, sn_of, off, rvp, rvi, rpos, a, b):
    """``(start, stride)`` of block ``Sigma[b, a]`` (postorder variables, ``a <= b``): entry
    ``(i, j)`` (row of ``b``, column of ``a``) is at ``start + j * stride + i``; -1 if absent."""
    t = sn_of[a]
    k = _row_of(rvi, rvp[t], rvp[t + 1], b)
    if k < 0:
        return -1, 0
    col = off[a] - off[sn[t]]
    return pstart[t] + col * rows[t] + rpos[k], rows[t]


@njit(cache=True)
def selected_inverse(L, pstart, width, rows, sn, rvp, rvi, rpos, dim, off, sn_of, Sig):
    """Fill ``Sig`` (the factor's layout) with ``H^-1`` on L's pattern; return -1, or the
    supernode whose ancestor block was missing (cannot happen for a valid factor)."""
    S = width.shape[0]
    for s in range(S - 1, -1, -1):
        w, r, p0 = width[s], rows[s], pstart[s]
        m = r - w
        L11inv = np.zeros((w, w))
        for j in range(w):  # L11^-1 by forward substitution on the identity's columns
            L11inv[j, j] = 1.0 / L[p0 + j * r + j]
            for i in range(j + 1, w):
                acc = 0.0
                for k in range(j, i):
                    acc += L[p0 + k * r + i] * L11inv[k, j]
                L11inv[i, j] = -acc / L[p0 + i * r + i]
        Sig11 = L11inv.T @ L11inv
        if m > 0:
            L21 = np.empty((m, w))
            for j in range(w):
                for i in range(m):
                    L21[i, j] = L[p0 + j * r + w + i]
            X = L21 @ L11inv
            G = np.empty((m, m))  # Sigma_SS of the row variables below the supernode
            first = rvp[s] + (sn[s + 1] - sn[s])
            for ka in range(first, rvp[s + 1]):
                a = rvi[ka]
                ga = rpos[ka] - w
                for kb in range(ka, rvp[s + 1]):
                    b = rvi[kb]
                    gb = rpos[kb] - w
                    start, stride = _block(pstart, rows, sn, sn_of, off, rvp, rvi, rpos, a, b)
                    if start < 0:
                        return s
                    for j in range(dim[a]):
                        for i in range(dim[b]):
                            v = Sig[start + j * stride + i]
                            G[gb + i, ga + j] = v
                            G[ga + j, gb + i] = v
            Sig21 = -(G @ X)
            Sig11 -= X.T @ Sig21
            for j in range(w):
                for i in range(m):
                    Sig[p0 + j * r + w + i] = Sig21[i, j]
        for j in range(w):
            for i in range(w):
                Sig[p0 + j * r + i] = Sig11[i, j]
    return -1


@njit(cache=True)
def factor_covariances(Sig, pstart, rows, sn, sn_of, off, rvp, rvi, rpos, dim, var_p, loc,
                       out):
    """``out[e]`` = the ``D x D`` block of ``H^-1`` over factor ``e``'s variables ``var_p[e]``
    (postorder), variable ``p`` at rows/columns ``loc[p]:loc[p] + dim``; returns -1, or the
    first factor with a pair outside L's pattern."""
    for e in range(var_p.shape[0]):
        k = var_p.shape[1]
        for p in range(k):
            for q in range(k):
                a, b = var_p[e, p], var_p[e, q]
                swap = a > b
                lo, hi = (b, a) if swap else (a, b)
                start, stride = _block(pstart, rows, sn, sn_of, off, rvp, rvi, rpos, lo, hi)
                if start < 0:
                    return e
                # Sigma[hi, lo] is stored; out[var_p=a rows, var_p=b cols] = Sigma[a, b]
                for j in range(dim[lo]):
                    for i in range(dim[hi]):
                        v = Sig[start + j * stride + i]
                        if swap:  # a = hi, b = lo: Sigma[a, b] = stored (i, j)
                            out[e, loc[p] + i, loc[q] + j] = v
                        else:  # a = lo, b = hi: Sigma[a, b] = stored^T
                            out[e, loc[p] + j, loc[q] + i] = v
    return -1
