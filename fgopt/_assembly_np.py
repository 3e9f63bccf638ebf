"""NumPy twins of the assembly kernels (:mod:`fgopt._assembly`) for small batches.

The same sums, vectorized over a batch's instances instead of a numba loop: whiten, robust
weight, ``w J^T r`` into g and ``w J^T J`` into H's data at the scatter positions (lower
triangle only), the batch cost. Used for batches of at most
``fgopt.symbolic.runtime.NUMPY_MAX_BATCH`` instances, where numba's per-process import,
initialization and cache loads (about 0.5 s) would cost more than the arithmetic.
"""

from __future__ import annotations

import numpy as np

from .noise.robust import rho_and_weight_np


def _whitened(res, jac, sqrt_info, unit):
    if unit:
        return res, jac
    R = np.triu(sqrt_info)  # the kernels read only the upper triangle
    r = np.einsum("nab,nb->na", R, res)
    J = None if jac is None else np.einsum("nab,nbc->nac", R, jac)
    return r, J


def batch_cost(res, sqrt_info, unit, loss_code, loss_param, loss_shape, cost=0.0) -> float:
    """``cost + sum rho(|R e|)`` over a batch (as :func:`fgopt._assembly.batch_cost`)."""
    r, _ = _whitened(res, None, sqrt_info, unit)
    rho, _ = rho_and_weight_np(loss_code, loss_param, loss_shape, np.einsum("na,na->n", r, r))
    return float(cost) + float(rho.sum())


def scatter_batch(res, jac, sqrt_info, unit, loss_code, loss_param, loss_shape, arg_dims,
                  arg_local_off, toff, pos, col_shift, H_data, g, weights, cost=0.0) -> float:
    """Accumulate a batch into ``H_data`` / ``g``; return ``cost`` plus its cost (as
    :func:`fgopt._assembly.scatter_batch`: entry ``(a, b)`` of block ``(p, q)`` goes to
    ``pos[i, p, q] + col_shift[toff[i, q] + b] + a``)."""
    r, J = _whitened(res, jac, sqrt_info, unit)
    rho, w = rho_and_weight_np(loss_code, loss_param, loss_shape, np.einsum("na,na->n", r, r))
    weights[:] = w
    gl = w[:, None] * np.einsum("nad,na->nd", J, r)             # (n, D)
    Hl = w[:, None, None] * np.einsum("nac,nad->ncd", J, J)     # (n, D, D)
    idx, val = [], []
    k = arg_dims.shape[0]
    for p in range(k):
        op, dp = int(arg_local_off[p]), int(arg_dims[p])
        idx.append((toff[:, p][:, None] + np.arange(dp)[None]).ravel())
        val.append(gl[:, op:op + dp].ravel())
    np.add.at(g, np.concatenate(idx), np.concatenate(val))
    idx, val = [], []
    for p in range(k):
        op, dp = int(arg_local_off[p]), int(arg_dims[p])
        for q in range(k):
            oq, dq = int(arg_local_off[q]), int(arg_dims[q])
            ok = pos[:, p, q] >= 0
            if not np.any(ok):
                continue
            a = np.arange(dp)[:, None]
            b = np.arange(dq)[None, :]
            keep = a >= b if p == q else np.ones((dp, dq), bool)     # diagonal: lower triangle
            cols = col_shift[toff[ok, q][:, None] + np.arange(dq)[None]]  # (n_ok, dq)
            where = pos[ok, p, q][:, None, None] + cols[:, None, :] + a[None]  # (n_ok, dp, dq)
            block = Hl[ok][:, op:op + dp, oq:oq + dq]
            idx.append(where[:, keep].ravel())
            val.append(block[:, keep].ravel())
    if idx:
        np.add.at(H_data, np.concatenate(idx), np.concatenate(val))
    return float(cost) + float(rho.sum())
