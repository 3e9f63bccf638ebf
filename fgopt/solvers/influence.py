"""Leave-one-out (deleted) residuals of factors, from one factorization of H.

For a least-squares problem linearized at its solution, with whitened Jacobian ``J_e`` and
residual ``r_e`` of factor ``e`` and ``H = J^T W J``, the residual factor ``e`` would have if it
were removed and the problem re-solved is, to first order (the geodesists' "studentized" or
deleted residual, Baarda's data snooping)::

    r_loo = (I - h_e)^-1 r_e,   h_e = sqrt(w_e) J_e H^-1 J_e^T sqrt(w_e)   (the leverage)

A factor whose measurement the rest of the graph contradicts but which bent the estimate to fit
itself (an outlier accepted in a weakly constrained region) has a small ``r_e`` and a leverage
near the identity, so a large ``r_loo``: that is how GNC's result is checked (see
:mod:`fgopt.solvers.gnc`). The cost is one multi-right-hand-side solve with ``dim(r_e)`` columns
per factor examined.
"""

from __future__ import annotations

import numpy as np

from ..problem import Problem, State


def leave_one_out_sq_norms(problem: Problem, state: State, solver, masks: list[np.ndarray],
                           chunk: int = 600) -> list[np.ndarray]:
    """``|r_loo|^2`` (whitened by each factor's own noise) of the factors selected by ``masks``
    (one boolean array per batch, as :meth:`Problem.set_weights` takes; Python factors are not
    examined); 0 elsewhere.

    ``solver`` must hold a factorization of the (weighted, undamped) H at ``state``. A factor
    with weight ``w_e`` enters H as ``w_e J^T J``, so its leverage uses ``sqrt(w_e) J``.
    """
    N = problem.pattern.size
    out = []
    for b, mask in zip(problem.batches, masks):
        n = len(b.source)
        sq = np.zeros(n)
        rows = np.nonzero(mask[:n])[0]
        out.append(sq)
        if rows.size == 0:
            continue
        res, jac = b.kernel.linearize(b.gather(state), b.source.constants)
        R0 = np.broadcast_to(b.sqrt_info0, (n,) + b.sqrt_info0.shape[1:])
        R = np.broadcast_to(b.sqrt_info, (n,) + b.sqrt_info.shape[1:])  # includes sqrt(w)
        m = res.shape[1]
        dims, offs = b.arg_dims, b.arg_local_off
        for start in range(0, rows.size, chunk):
            es = rows[start:start + chunk]
            Jw = np.einsum("nab,nbc->nac", R[es], jac[es])        # sqrt(w) R J
            c = len(es)
            B = np.zeros((N, c * m))
            X_cols = np.arange(c)[:, None] * m + np.arange(m)[None]  # (c, m) column ids
            for p in range(len(dims)):
                d, o = int(dims[p]), int(offs[p])
                Hrows = b.toff[es, p][:, None] + np.arange(d)[None]  # (c, d)
                # B[Hrows[e, a], X_cols[e, k]] += Jw[e, k, o + a]
                np.add.at(B, (np.repeat(Hrows, m, axis=1).reshape(-1),
                              np.tile(X_cols, (1, d)).reshape(-1)),
                          Jw[:, :, o:o + d].transpose(0, 2, 1).reshape(-1))
            X = np.asarray(solver.solve(B)).reshape(N, c * m)
            h = np.zeros((c, m, m))
            for p in range(len(dims)):
                d, o = int(dims[p]), int(offs[p])
                Hrows = b.toff[es, p][:, None] + np.arange(d)[None]
                Xp = X[Hrows[:, :, None], X_cols[:, None, :]]            # (c, d, m)
                h += np.einsum("nkd,ndm->nkm", Jw[:, :, o:o + d], Xp)
            r0 = np.einsum("nab,nb->na", R0[es], res[es])                # own noise, no weight
            eye = np.eye(m)[None]
            try:
                r_loo = np.linalg.solve(eye - h, r0[:, :, None])[:, :, 0]
            except np.linalg.LinAlgError:  # a factor the rest of the graph cannot predict (a
                # bridge): drop the unpredictable directions instead of calling it an outlier
                r_loo = np.stack([np.linalg.lstsq(eye[0] - hi, ri, rcond=None)[0]
                                  for hi, ri in zip(h, r0)])
            sq[es] = np.sum(r_loo * r_loo, axis=1)
    return out
