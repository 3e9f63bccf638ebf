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
    r = np.matmul(R, res[:, :, None])[:, :, 0]  # batched matmul: ~5x einsum's speed here
    J = None if jac is None else np.matmul(R, jac)
    return r, J


def batch_cost(res, sqrt_info, unit, loss_code, loss_param, loss_shape, cost=0.0) -> float:
    """``cost + sum rho(|R e|)`` over a batch (as :func:`fgopt._assembly.batch_cost`)."""
    r, _ = _whitened(res, None, sqrt_info, unit)
    rho, _ = rho_and_weight_np(loss_code, loss_param, loss_shape, np.einsum("na,na->n", r, r))
    return float(cost) + float(rho.sum())


def row_squared_norms(res, sqrt_info, unit) -> np.ndarray:
    """``|R_i e_i|^2`` per row, no robust loss (as :func:`fgopt._assembly.row_squared_norms`)."""
    r, _ = _whitened(res, None, sqrt_info, unit)
    return np.einsum("na,na->n", r, r)


def scatter_plan(arg_dims, arg_local_off, toff, pos, col_shift, H_size: int):
    """Where each entry of a batch's ``w J^T r`` / ``w J^T J`` goes, computed once per problem:
    ``(g_idx, g_sel, H_idx, H_sel)``, flat targets in g / H's data and the flat positions of
    their values in ``gl (n, D)`` / ``Hl (n, D, D)`` (lower triangle of each stored block).
    Entry ``(a, b)`` of block ``(p, q)`` is at ``pos[i, p, q] + col_shift[toff[i, q] + b] + a``
    (:func:`fgopt.structure.scatter_positions`)."""
    n, k = toff.shape
    D = int(arg_dims.sum())
    inst = np.arange(n, dtype=np.int64)
    g_idx, g_sel, H_idx, H_sel = [], [], [], []
    for p in range(k):
        op, dp = int(arg_local_off[p]), int(arg_dims[p])
        g_idx.append((toff[:, p][:, None] + np.arange(dp)[None]).ravel())
        g_sel.append((inst[:, None] * D + op + np.arange(dp)[None]).ravel())
    for p in range(k):
        op, dp = int(arg_local_off[p]), int(arg_dims[p])
        for q in range(k):
            oq, dq = int(arg_local_off[q]), int(arg_dims[q])
            ok = np.nonzero(pos[:, p, q] >= 0)[0]
            if ok.shape[0] == 0:
                continue
            a = np.arange(dp)[:, None]
            b = np.arange(dq)[None, :]
            keep = a >= b if p == q else np.ones((dp, dq), bool)     # diagonal: lower triangle
            cols = col_shift[toff[ok, q][:, None] + np.arange(dq)[None]]      # (n_ok, dq)
            where = (pos[ok, p, q].astype(np.int64)[:, None, None] + cols[:, None, :]
                     + a[None])                                        # (n_ok, dp, dq)
            sel = (ok[:, None, None] * (D * D) + (op + a)[None] * D + (oq + b)[None])
            H_idx.append(where[:, keep].ravel())
            H_sel.append(np.broadcast_to(sel, where.shape)[:, keep].ravel())
    cat = (lambda xs: np.concatenate(xs).astype(np.int64, copy=False) if xs
           else np.zeros(0, np.int64))
    return cat(g_idx), cat(g_sel), cat(H_idx), cat(H_sel)


def scatter_batch(res, jac, sqrt_info, unit, loss_code, loss_param, loss_shape, arg_dims,
                  arg_local_off, toff, pos, col_shift, H_data, g, weights, cost=0.0,
                  plan=None) -> float:
    """Accumulate a batch into ``H_data`` / ``g``; return ``cost`` plus its cost (as
    :func:`fgopt._assembly.scatter_batch`: entry ``(a, b)`` of block ``(p, q)`` goes to
    ``pos[i, p, q] + col_shift[toff[i, q] + b] + a``). ``plan``: :func:`scatter_plan` of these
    rows (made here when not given)."""
    r, J = _whitened(res, jac, sqrt_info, unit)
    rho, w = rho_and_weight_np(loss_code, loss_param, loss_shape, np.einsum("na,na->n", r, r))
    weights[:] = w
    if plan is None:
        plan = scatter_plan(arg_dims, arg_local_off, toff, pos, col_shift, H_data.shape[0])
    g_idx, g_sel, H_idx, H_sel = plan
    Jt = np.swapaxes(J, 1, 2)                                        # (n, D, r)
    gl = np.matmul(Jt, r[:, :, None])[:, :, 0]                       # (n, D)
    Hl = np.matmul(Jt, J)                                            # (n, D, D)
    if loss_code != 0:  # (without a robust loss every weight is 1)
        gl *= w[:, None]
        Hl *= w[:, None, None]
    g += np.bincount(g_idx, gl.reshape(-1)[g_sel], minlength=g.shape[0])
    if H_idx.shape[0]:
        H_data += np.bincount(H_idx, Hl.reshape(-1)[H_sel], minlength=H_data.shape[0])
    return float(cost) + float(rho.sum())
