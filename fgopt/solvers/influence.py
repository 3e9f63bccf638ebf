"""Leave-one-out (deleted) residuals of factors, from one factorization of H.

For a least-squares problem linearized at its solution, with whitened Jacobian ``J_e`` and
residual ``r_e`` of factor ``e`` and ``H = J^T W J``, the residual factor ``e`` would have if it
were removed and the problem re-solved is, to first order (the geodesists' "studentized" or
deleted residual, Baarda's data snooping)::

    r_loo = (I - h_e)^-1 r_e,   h_e = sqrt(w_e) J_e H^-1 J_e^T sqrt(w_e)   (the leverage)

A factor whose measurement the rest of the graph contradicts but which bent the estimate to fit
itself (an outlier accepted in a weakly constrained region) has a small ``r_e`` and a leverage
near the identity, so a large ``r_loo``: that is how GNC's result is checked (see
:mod:`fgopt.solvers.gnc`). For factors in the problem the leverages come from the selected
inverse of one factorization (every factor's variables are coupled in H, so their block of
``H^-1`` is on L's pattern); for factors left out (:func:`prediction_sq_norms`), whose variables
need not be coupled, from multi-right-hand-side solves with ``dim(r_e)`` columns per factor.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp

from ..errors import NotPositiveDefiniteError, have_extra
from ..problem import Problem, State
from .linear.base import make_linear_solver

#: Factors per multi-right-hand-side solve without CHOLMOD (dense right-hand sides: N x 3 x 256).
_DENSE_CHUNK = 256


def _sparse_leverages(F):
    """``h = Z^T Z`` blocks with ``Z = L^-1 P B`` from CHOLMOD's factor (a sparse forward solve)."""
    def leverages(B, c, m):
        Z = sp.csc_matrix(F.solve_L(F.apply_P(B), use_LDLt_decomposition=False))
        h = np.empty((c, m, m))
        for k1 in range(m):
            for k2 in range(k1, m):
                v = np.asarray(Z[:, k1::m].multiply(Z[:, k2::m]).sum(axis=0)).ravel()
                h[:, k1, k2] = v
                h[:, k2, k1] = v
        return h

    return leverages


def _solve_leverages(problem: Problem):
    """``h = B^T H^-1 B`` blocks by a multi-right-hand-side solve with fgopt's own solver (no
    CHOLMOD): the same leverages as ``Z^T Z``, with dense right-hand sides."""
    solver = _factorized(problem, make_linear_solver("auto", pattern=problem.pattern))

    def leverages(B, c, m):
        X = np.asarray(solver.solve(np.asarray(B.todense()))).reshape(B.shape)
        h = np.empty((c, m, m))
        for k1 in range(m):
            for k2 in range(k1, m):
                v = np.asarray(B[:, k1::m].multiply(X[:, k2::m]).sum(axis=0)).ravel()
                h[:, k1, k2] = v
                h[:, k2, k1] = v
        return h

    return leverages


def leave_one_out_sq_norms(problem: Problem, state: State, masks: list[np.ndarray],
                           chunk: int = 4000, cost_decrease: bool = False,
                           both: bool = False) -> Any:
    """``|r_loo|^2`` (whitened by each factor's own noise) of the factors selected by ``masks``
    (one boolean array per batch, as :meth:`Problem.set_weights` takes; Python factors are not
    examined); 0 elsewhere.

    With ``cost_decrease=True``, return instead how much the optimal cost ``0.5 sum |r|^2``
    would drop if the factor were removed: ``0.5 r^T (I - h)^-1 r = 0.5 r . r_loo`` (exact for
    linear problems; first order otherwise). Rejecting a factor lowers a truncated-least-squares
    objective ``0.5 sum min(r_i^2, c_i^2)`` when this exceeds ``c^2 / 2``.

    ``both=True`` returns ``(|r_loo|^2 arrays, cost-decrease arrays)`` from one factorization.

    Linearizes at ``state`` with the problem's current weights (a factor with weight ``w_e``
    enters H as ``w_e J^T J``, so its leverage uses ``sqrt(w_e) J``), factorizes H once (fgopt's
    block Cholesky) and takes the leverage ``h_e = (sqrt(w_e) R_e J_e) Sigma_e (...)^T`` from the
    block ``Sigma_e`` of ``H^-1`` over the factor's variables, which the selected inverse of the
    factor holds (:func:`_covariance_fn`): the cost is that of a factorization, whatever the
    number of factors examined. ``chunk``: factors per vectorized step.
    """
    covariance = _covariance_fn(problem, state)
    out, drops = [], []
    for b, mask in zip(problem.batches, masks):
        n = len(b.source)
        sq = np.zeros(n)
        drop = np.zeros(n)
        rows = np.nonzero(mask[:n])[0]
        out.append(drop if cost_decrease and not both else sq)
        drops.append(drop)
        if rows.size == 0:
            continue
        res, jac = b.kernel.linearize(b.gather(state), b.source.constants)
        R0 = np.broadcast_to(b.sqrt_info0, (n,) + b.sqrt_info0.shape[1:])
        R = np.broadcast_to(b.sqrt_info, (n,) + b.sqrt_info.shape[1:])  # includes sqrt(w)
        for start in range(0, rows.size, chunk):
            es = rows[start:start + chunk]
            Jw = np.einsum("nab,nbc->nac", R[es], jac[es])        # sqrt(w) R J, (c, m, D)
            sigma = covariance(b.var_idx[es], b.arg_dims, b.arg_local_off)  # (c, D, D)
            h = Jw @ sigma @ Jw.transpose(0, 2, 1)
            r0 = np.einsum("nab,nb->na", R0[es], res[es])                # own noise, no weight
            m = res.shape[1]
            A = np.eye(m)[None] - h
            # a bridge (h = I in some direction: nothing else predicts the factor) is not an
            # outlier: drop the unpredictable directions (least squares) instead of dividing
            bridge = np.linalg.cond(A) > 1e10
            r_loo = np.empty_like(r0)
            ok = ~bridge
            if np.any(ok):
                r_loo[ok] = np.linalg.solve(A[ok], r0[ok][:, :, None])[:, :, 0]
            for i in np.nonzero(bridge)[0]:
                r_loo[i] = np.linalg.lstsq(A[i], r0[i], rcond=1e-10)[0]
            drop[es] = 0.5 * np.sum(r0 * r_loo, axis=1)
            sq[es] = np.sum(r_loo * r_loo, axis=1)
    return (out, drops) if both else out


def prediction_sq_norms(problem: Problem, state: State, batch: Any,
                        rows: np.ndarray, bound: np.ndarray | None = None) -> np.ndarray:
    """For factors *not* in ``problem`` (rows ``rows`` of the :class:`~fgopt.batch.FactorBatch`
    ``batch``, over variables of ``problem``): the squared prediction error normalized by its
    covariance, ``r^T (I + h')^-1 r`` with ``r`` the whitened residual at ``state`` (which is
    then the leave-one-out residual) and ``h' = R J H^-1 J^T R^T`` (how uncertain ``problem``'s
    estimate of the factor's relative pose is, in the factor's own units). Under the factor's
    noise model (times a scale ``s^2``) it is ``s^2 chi2(dim)`` distributed: Baarda's test of a
    left-out measurement, as ``r^T (I - h)^-1 r`` is for one that is in.

    ``bound`` (one value per row), for callers that only test ``value <= bound``: a row whose
    cheap lower bound already exceeds its bound gets that lower bound (above the bound, so the
    test fails as it would on the exact value), the others the exact value. The lower bound
    replaces the cross blocks of ``H^-1`` over the factor's ``k`` variables by ``k`` times its
    diagonal blocks (``Sigma <= k blockdiag(Sigma_pp)`` for positive semidefinite ``Sigma``, so
    ``h' <= h'_up`` and ``r^T (I + h'_up)^-1 r <= r^T (I + h')^-1 r``); the diagonal blocks come
    from the selected inverse of one block Cholesky factorization. Gross outliers then need no
    forward solves, which for hundreds of left-out loop closures in 3D (nearly dense columns of
    ``L^-1``) took ~6 s per call on sphere2500.
    """
    rows = np.asarray(rows, dtype=np.int64)
    out = np.zeros(rows.shape[0])
    if rows.size == 0:
        return out
    kernel = batch.kernel
    var_idx = problem._vars_of(batch.keys[rows])
    args = tuple(state.storages[problem._kind_id[id(kind)]][problem.var_row[var_idx[:, j]]]
                 for j, kind in enumerate(kernel.arg_kinds))
    res, jac = kernel.linearize(args, batch.constants[rows])
    m = res.shape[1]
    R = (np.broadcast_to(np.eye(m), (rows.size, m, m)) if batch.sqrt_information is None
         else batch.sqrt_information[rows])
    r = np.einsum("nab,nb->na", R, res)
    Jw = np.einsum("nab,nbc->nac", R, jac)
    dims = np.array([k.dim for k in kernel.arg_kinds], dtype=np.int64)
    offs = np.concatenate([[0], np.cumsum(dims)[:-1]]).astype(np.int64)
    todo = np.arange(rows.size)
    if bound is not None:
        out[:] = _prediction_lower_bounds(problem, state, r, Jw, var_idx, dims, offs)
        # a relative margin: the bound and the exact value come from two factorizations
        todo = np.nonzero(out <= np.asarray(bound, dtype=float) * (1.0 + 1e-6))[0]
        if todo.size == 0:
            return out
    leverages, cap = _leverage_fn(problem, state)
    toff = problem.var_offset[var_idx[todo]]
    Jt = Jw[todo]
    h = np.empty((todo.size, m, m))
    step = min(cap, 4000)
    for a in range(0, todo.size, step):
        sl = slice(a, a + step)
        h[sl] = leverages(_whitened_columns(problem.pattern.size, Jt[sl], toff[sl], dims, offs),
                          Jt[sl].shape[0], m)
    A = np.eye(m)[None] + h
    rt = r[todo]
    out[todo] = np.einsum("na,na->n", rt, np.linalg.solve(A, rt[:, :, None])[:, :, 0])
    return out


def _prediction_lower_bounds(problem: Problem, state: State, r: np.ndarray, Jw: np.ndarray,
                             var_idx: np.ndarray, dims: np.ndarray,
                             offs: np.ndarray) -> np.ndarray:
    """``r^T (I + h'_up)^-1 r`` with ``h'_up = k sum_p Jw_p Sigma_pp Jw_p^T`` (the bound of
    :func:`prediction_sq_norms`): only diagonal blocks of ``H^-1``, always on L's pattern."""
    covariance = _covariance_fn(problem, state)
    k = dims.shape[0]
    m = r.shape[1]
    h = np.zeros((r.shape[0], m, m))
    for p in range(k):
        d, o = int(dims[p]), int(offs[p])
        sigma = covariance(var_idx[:, p:p + 1], dims[p:p + 1], np.zeros(1, dtype=np.int64))
        Jp = Jw[:, :, o:o + d]
        h += Jp @ sigma @ Jp.transpose(0, 2, 1)
    A = np.eye(m)[None] + k * h
    return np.einsum("na,na->n", r, np.linalg.solve(A, r[:, :, None])[:, :, 0])


def _covariance_fn(problem: Problem, state: State):
    """``covariance(var_idx, dims, loc)``: blocks of ``H^-1`` (H at ``state``, current weights)
    over the factors' variables, read from the selected inverse of fgopt's block Cholesky
    (:meth:`BlockCholeskySolver.covariance_blocks`: sphere2500's 4,949 factors in 0.1 s, where
    CHOLMOD's sparse forward solves ``L^-1 P B`` took 15-29 s, their columns nearly dense in 3D).
    A tiny ridge fixes a free gauge."""
    from .linear.block_cholesky import BlockCholeskySolver

    problem.linearize(state)
    return _factorized(problem, BlockCholeskySolver()).covariance_blocks


def _factorized(problem: Problem, solver: Any) -> Any:
    """``solver`` analyzed and factorized on the problem's current H; a tiny ridge fixes a free
    gauge (no prior)."""
    pattern = problem.pattern
    solver.analyze(pattern)
    H_data = problem.H_data.copy()
    try:
        solver.factorize(H_data)
    except NotPositiveDefiniteError:
        H_data[pattern.diag_pos] += 1e-9 * max(1.0, float(np.abs(H_data[pattern.diag_pos]).max()))
        solver.factorize(H_data)
    return solver


def _leverage_fn(problem: Problem, state: State):
    """``(leverages(B, c, m), max chunk)`` for ``problem``'s H at ``state``: CHOLMOD's sparse
    forward solve with the ``fgopt[cholmod]`` extra, else fgopt's own solver (dense right-hand
    sides, so smaller chunks). A tiny ridge fixes a free gauge."""
    problem.linearize(state)
    if have_extra("sksparse"):
        from .linear.cholmod import CholmodSolver

        # through the solver's pivot test: with no prior, CHOLMOD's L D L^T of H could hold a
        # rounding-negative pivot that only the conversion to L L^T in solve_L reported
        solver = _factorized(problem, CholmodSolver(ordering_method="default"))
        return _sparse_leverages(solver._factor), 1 << 30
    return _solve_leverages(problem), _DENSE_CHUNK


def _whitened_columns(N: int, Jw: np.ndarray, toff: np.ndarray, dims: np.ndarray,
                      offs: np.ndarray) -> sp.csc_matrix:
    """``B`` (N x c m): column ``(e, k)`` is row ``k`` of factor ``e``'s whitened Jacobian
    ``Jw (c, m, D)`` placed at its variables' tangent offsets ``toff (c, k)`` in H."""
    c, m = Jw.shape[0], Jw.shape[1]
    cols = np.arange(c)[:, None] * m + np.arange(m)[None]  # (c, m) column of (e, k)
    ri, ci, vals = [], [], []
    for p in range(len(dims)):
        d, o = int(dims[p]), int(offs[p])
        Hrows = toff[:, p][:, None] + np.arange(d)[None]  # (c, d)
        # B[Hrows[e, a], cols[e, k]] = Jw[e, k, o + a]
        ri.append(np.repeat(Hrows, m, axis=1).reshape(-1))
        ci.append(np.tile(cols, (1, d)).reshape(-1))
        vals.append(Jw[:, :, o:o + d].transpose(0, 2, 1).reshape(-1))
    return sp.csc_matrix((np.concatenate(vals), (np.concatenate(ri), np.concatenate(ci))),
                         shape=(N, c * m))
