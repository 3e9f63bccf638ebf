"""numba pieces every small-problem driver calls (compiled once, shared by all drivers).

Storage and tangent layout: the problem's variables in its order, variable ``v``'s storage at
``x[soff[v]:soff[v] + s_v]`` and its tangent at ``delta[toff[v]:toff[v] + d_v]``; H is dense
``(N, N)`` with both triangles filled.
"""

from __future__ import annotations

import numpy as np

from ..._jit import njit
from ...manifolds._kernels import lie_retract


@njit(cache=True, error_model="numpy", nogil=True)
def gather(x, soff, arg, out):
    """``out[i] = x[soff[i, arg]:soff[i, arg] + out.shape[1]]``: argument ``arg``'s storage rows."""
    s = out.shape[1]
    for i in range(out.shape[0]):
        o = soff[i, arg]
        for k in range(s):
            out[i, k] = x[o + k]


@njit(cache=True, error_model="numpy", nogil=True)
def accumulate(res, jac, toff, R, dims, offs, H, g):
    """Add one batch's whitened ``J^T J`` to ``H`` and ``J^T r`` to ``g``; return its cost
    ``0.5 sum |R_i r_i|^2``.

    ``res (n, r)`` and ``jac (n, r, D)``: the kernel's unwhitened residuals and Jacobians;
    ``toff (n, k)``: each argument's tangent offset in H; ``R``: ``(0, r, r)`` for unit noise,
    ``(1, r, r)`` one square-root information for all rows, or ``(n, r, r)``; ``dims`` /
    ``offs``: each argument's tangent dimension and first Jacobian column.
    """
    n, r = res.shape
    D = jac.shape[2]
    k = dims.shape[0]
    wr = res[0].copy()
    wJ = jac[0].copy()
    cost = 0.0
    for i in range(n):
        if R.shape[0] == 0:
            for a in range(r):
                wr[a] = res[i, a]
                for c in range(D):
                    wJ[a, c] = jac[i, a, c]
        else:
            Ri = R[i] if R.shape[0] > 1 else R[0]
            for a in range(r):
                s = 0.0
                for b in range(r):
                    s += Ri[a, b] * res[i, b]
                wr[a] = s
                for c in range(D):
                    s = 0.0
                    for b in range(r):
                        s += Ri[a, b] * jac[i, b, c]
                    wJ[a, c] = s
        for a in range(r):
            cost += 0.5 * wr[a] * wr[a]
        for p in range(k):
            tp, op = toff[i, p], offs[p]
            for u in range(dims[p]):
                s = 0.0
                for a in range(r):
                    s += wJ[a, op + u] * wr[a]
                g[tp + u] += s
                for q in range(k):
                    tq, oq = toff[i, q], offs[q]
                    for v in range(dims[q]):
                        s = 0.0
                        for a in range(r):
                            s += wJ[a, op + u] * wJ[a, oq + v]
                        H[tp + u, tq + v] += s
    return cost


@njit(cache=True, error_model="numpy", nogil=True)
def retract(x, delta, out, tmp, layout):
    """``out = x (+) delta`` per variable; ``layout (V, 5)``: storage offset, tangent offset,
    Lie group id (-1: a vector, added), storage dim, tangent dim."""
    xs = np.empty(8)
    ds = np.empty(8)
    os_ = np.empty(8)
    for v in range(layout.shape[0]):
        so, to, gid, s, d = layout[v, 0], layout[v, 1], layout[v, 2], layout[v, 3], layout[v, 4]
        if gid < 0:
            for k in range(s):
                out[so + k] = x[so + k] + delta[to + k]
            continue
        for k in range(s):
            xs[k] = x[so + k]
        for k in range(d):
            ds[k] = delta[to + k]
        lie_retract(gid, xs, ds, os_, tmp)
        for k in range(s):
            out[so + k] = os_[k]


@njit(cache=True, error_model="numpy", nogil=True)
def clear(H, g):
    for i in range(H.shape[0]):
        g[i] = 0.0
        for j in range(H.shape[1]):
            H[i, j] = 0.0


@njit(cache=True, error_model="numpy", nogil=True)
def stacked(x, soff, s):
    """A ``hessian`` call's storage and rows (:class:`~fgopt.factors.kernel.CompiledCall`): the
    batch's argument storages (all of dimension ``s``) stacked ``(n k, s)``, and ``rows (n, k)``
    into them."""
    n, k = soff.shape
    P = np.empty((n * k, s))
    rows = np.empty((n, k), dtype=np.int64)
    for i in range(n):
        for p in range(k):
            rows[i, p] = i * k + p
            o = soff[i, p]
            for c in range(s):
                P[i * k + p, c] = x[o + c]
    return P, rows
