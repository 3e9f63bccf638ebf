"""Chordal initialization of pose graphs (Carlone et al., "Initialization techniques for 3D SLAM",
ICRA 2015; GTSAM's ``InitializePose3`` / ``lago`` do the same job).

A pose graph (SE(2) or SE(3) poses, between factors, priors) is solved in two linear steps that
need no initial guess:

1. rotations: relax ``R_j = R_i R_ij`` to the linear residual ``R_j^T - R_ij^T R_i^T`` over
   unconstrained d x d matrices (the chordal distance), solve the weighted linear least squares
   (the d columns of ``R^T`` are independent right-hand sides of one sparse system) and project
   each block onto SO(d) with an SVD;
2. translations: with the rotations fixed, ``t_j - t_i - R_i t_ij`` is linear in the positions
   (one weighted graph Laplacian, d right-hand sides).

Each edge's weights come from its information matrix ``Omega = R^T R`` (rotation-first tangent
order): ``kappa = tr(Omega_rot) / dim_rot`` for the rotation and ``tau = tr(Omega_trans) / d`` for
the translation, times an optional per-factor weight (GNC uses this). Priors anchor the gauge; a
graph without priors is anchored at its first pose's current value.

The result is close to the global optimum on typical SLAM graphs whatever the initial values, so
Levenberg-Marquardt started from it reaches the right basin: that is what lets GNC reject outlier
loop closures on real graphs (the weighted least squares of each GNC round needs a near-global
solver; local LM from a distorted estimate falls into wrong minima).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp
from .._jit import njit

from ..errors import FgoptError, have_extra
from ..manifolds import _kernels as K
from ..problem import Problem, State
from ..variables import Variables

_BETWEEN = {"between_pose2": 2, "between_pose3": 3}
_PRIOR = {"prior_pose2": 2, "prior_pose3": 3}


@njit(cache=True)
def _quaternions_to_matrices(q, out):
    for i in range(q.shape[0]):
        K.quat_to_matrix(q[i], out[i])


@njit(cache=True)
def _matrices_to_quaternions(R, out):
    for i in range(R.shape[0]):
        K.quat_from_matrix(R[i], out[i])


def _rotations_from_storage(storage: np.ndarray, d: int) -> np.ndarray:
    """(n, d, d) rotation matrices of SE(2) [c, s, x, y] / SE(3) [qx, qy, qz, qw, t] storage."""
    if d == 2:
        c, s = storage[:, 0], storage[:, 1]
        return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)
    out = np.empty((storage.shape[0], 3, 3))
    _quaternions_to_matrices(np.ascontiguousarray(storage[:, :4]), out)
    return out


def _storage_from_rotations(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    if R.shape[1] == 2:
        return np.concatenate([R[:, :, 0], t], axis=1)
    q = np.empty((R.shape[0], 4))  # x, y, z, w (the SO3 kernels' Shepperd conversion)
    _matrices_to_quaternions(np.ascontiguousarray(R), q)
    return np.concatenate([q, t], axis=1)


def _project_to_rotations(M: np.ndarray) -> np.ndarray:
    """Nearest rotation (Frobenius) of each d x d block: U diag(1, .., det(U V^T)) V^T; in 2D
    directly, the angle maximizing tr(R^T M): atan2(M10 - M01, M00 + M11) (a 3500-pose graph:
    0.1 ms instead of the SVD's 10)."""
    if M.shape[1] == 2:
        c, s = M[:, 0, 0] + M[:, 1, 1], M[:, 1, 0] - M[:, 0, 1]
        norm = np.hypot(c, s)
        tie = norm == 0  # every angle is as near (M = [[a, b], [b, -a]]): the identity
        norm[tie] = 1.0
        c, s = np.where(tie, 1.0, c / norm), s / norm
        return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)
    U, _, Vt = np.linalg.svd(M)
    det = np.linalg.det(U @ Vt)
    U[:, :, -1] *= det[:, None]
    return U @ Vt


def _solve_spd(A: sp.spmatrix, B: np.ndarray) -> np.ndarray:
    """``A^-1 B``: CHOLMOD when the ``fgopt[cholmod]`` extra is installed, else SuperLU (scipy)
    in a minimum-degree order with diagonal pivots (A is SPD)."""
    if have_extra("sksparse"):
        from sksparse.cholmod import cholesky

        from .linear.cholmod import serial_openmp

        with serial_openmp():
            return cholesky(A.tocsc()).solve_A(B)
    from scipy.sparse.linalg import splu

    lu = splu(A.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
              options={"SymmetricMode": True})
    return lu.solve(np.asarray(B, dtype=float))


def _block_weights(sqrt_info: np.ndarray, n: int, rot_dim: int) -> tuple[np.ndarray, np.ndarray]:
    R = np.broadcast_to(sqrt_info, (n,) + sqrt_info.shape[1:])
    omega = np.einsum("nki,nkj->nij", R, R)
    diag = np.diagonal(omega, axis1=1, axis2=2)
    return diag[:, :rot_dim].mean(axis=1), diag[:, rot_dim:].mean(axis=1)


class _PoseGraph:
    """The between / prior factors of a compiled problem, as arrays (``None`` if it is not a pose
    graph of one SE(2) or SE(3) kind)."""

    def __init__(self, problem: Problem):
        self.ok = False
        if problem._slow or len(problem.kinds) != 1 or not problem.batches:
            return
        names = {b.kernel.name for b in problem.batches}
        dims = {(_BETWEEN | _PRIOR).get(n) for n in names}
        if None in dims or len(dims) != 1 or not any(n in _BETWEEN for n in names):
            return
        self.d = dims.pop()
        self.kind = problem.kinds[0]
        self.num_poses = int(problem._initial_storages[0].shape[0])
        self.ok = True

    def systems(self, problem: Problem, weights: list[np.ndarray] | None):
        d = self.d
        rot_dim = 1 if d == 2 else 3
        N = self.num_poses
        rows, cols, vals = [], [], []       # rotation system (N d x N d)
        lrows, lcols, lvals = [], [], []    # translation Laplacian (N x N)
        b_rot = np.zeros((N * d, d))
        priors = []                          # (rows, kappa, tau, R, t) anchored poses
        edges = []                           # (i, j, tau, R_ij, t_ij)
        eye = np.eye(d)
        for bi, b in enumerate(problem.batches):
            n = len(b.source)
            w = np.ones(n) if weights is None else np.asarray(weights[bi], dtype=float)
            kappa, tau = _block_weights(b.sqrt_info0, n, rot_dim)
            kappa, tau = 0.5 * kappa * w, tau * w  # |R - I|_F^2 ~ 2 theta^2
            meas = b.source.constants
            Rm = _rotations_from_storage(meas, d)
            tm = meas[:, -d:]
            if b.kernel.name in _PRIOR:
                priors.append((b.rows[0], kappa, tau, Rm, tm))
                continue
            i, j = b.rows[0], b.rows[1]
            edges.append((i, j, tau, Rm, tm))
            # residual y_j - M y_i with M = R_ij^T (y = a column of R^T)
            bi_idx = i[:, None] * d + np.arange(d)[None]
            bj_idx = j[:, None] * d + np.arange(d)[None]
            K = kappa[:, None, None]
            for (ri, ci, blk) in ((bi_idx, bi_idx, K * eye), (bj_idx, bj_idx, K * eye),
                                  (bi_idx, bj_idx, -K * Rm), (bj_idx, bi_idx, -K * Rm.transpose(0, 2, 1))):
                rows.append(np.repeat(ri, d, axis=1).reshape(-1))
                cols.append(np.tile(ci, (1, d)).reshape(-1))
                vals.append(blk.reshape(-1))
            lrows += [i, j, i, j]
            lcols += [i, j, j, i]
            lvals += [tau, tau, -tau, -tau]
        b_t = np.zeros((N, d))
        for (a, kappa, tau, Rp, tp) in priors:
            ai = a[:, None] * d + np.arange(d)[None]
            rows.append(np.repeat(ai, d, axis=1).reshape(-1))
            cols.append(np.tile(ai, (1, d)).reshape(-1))
            vals.append((kappa[:, None, None] * eye).reshape(-1))
            np.add.at(b_rot, ai.reshape(-1), (kappa[:, None, None] * Rp.transpose(0, 2, 1)).reshape(-1, d))
            lrows.append(a)
            lcols.append(a)
            lvals.append(tau)
            np.add.at(b_t, a, tau[:, None] * tp)
        A_rot = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                              shape=(N * d, N * d)).tocsc()
        L = sp.coo_matrix((np.concatenate(lvals), (np.concatenate(lrows), np.concatenate(lcols))),
                          shape=(N, N)).tocsc()
        return A_rot, b_rot, L, b_t, edges, bool(priors)


def _solve_anchored(A: sp.csc_matrix, B: np.ndarray, block: int,
                    anchor: np.ndarray | None) -> np.ndarray:
    """Solve ``A X = B`` (SPD up to the gauge), with unknown block 0 fixed to ``anchor`` when
    given (moved to the right-hand side and removed: the gauge of a graph without priors)."""
    n = A.shape[0]
    ridge = 1e-10 * max(1.0, float(np.abs(A.diagonal()).max()))
    if anchor is None:
        # the ridge keeps poses cut off by zero (GNC) weights from making A singular
        return _solve_spd(A + ridge * sp.identity(n, format="csc"), B)
    free = np.arange(block, n)
    A = A.tocsc()
    rhs = B[free] - A[free][:, :block] @ anchor
    Aff = A[free][:, free]
    X = np.empty_like(B)
    X[:block] = anchor
    X[free] = _solve_spd(Aff + ridge * sp.identity(n - block, format="csc"), rhs)
    return X


def chordal_state(problem: Problem, state: State | None = None,
                  weights: list[np.ndarray] | None = None) -> State | None:
    """The chordal estimate of a compiled pose-graph problem as a new :class:`State`, or ``None``
    when the problem is not a pose graph (one SE(2)/SE(3) kind, between factors and priors only).

    ``weights`` (one array per batch, as :meth:`Problem.set_weights` takes) scale each factor.
    """
    pg = _PoseGraph(problem)
    if not pg.ok:
        return None
    state = state or problem.initial_state()
    d, N = pg.d, pg.num_poses
    A_rot, b_rot, L, b_t, edges, has_prior = pg.systems(problem, weights)
    first = state.storages[0][:1]
    R0 = _rotations_from_storage(first, d)[0]
    Y = _solve_anchored(A_rot, b_rot, d, None if has_prior else R0.T)
    Rs = _project_to_rotations(Y.reshape(N, d, d).transpose(0, 2, 1))
    b = b_t.copy()
    for (i, j, tau, Rm, tm) in edges:
        rt = tau[:, None] * np.einsum("nab,nb->na", Rs[i], tm)
        np.add.at(b, j, rt)
        np.add.at(b, i, -rt)
    t = _solve_anchored(L, b, 1, None if has_prior else first[:, -d:])
    storages = [_storage_from_rotations(Rs, t)]
    if not np.all(np.isfinite(storages[0])):
        return None
    return State(storages, dict(state.objects))


def chordal_initialization(graph: Any, initial: Variables) -> Variables:
    """Initial values for a pose graph (SE(2) or SE(3) poses with between factors and priors)
    by chordal relaxation: no dependence on ``initial`` beyond which keys exist (and, without a
    prior, where the first pose is).

    >>> graph, initial = fgopt.io.read("sphere2500.g2o")          # doctest: +SKIP
    >>> result = fgopt.optimize(graph, fgopt.chordal_initialization(graph, initial))  # doctest: +SKIP
    """
    problem = Problem(graph, initial, build_structure=False)
    state = chordal_state(problem)
    if state is None:
        raise FgoptError("chordal initialization needs a pose graph: SE2 or SE3 poses (one kind) "
                         "with only between factors and priors")
    return problem.values(state)
