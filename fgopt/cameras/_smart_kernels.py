"""numba kernel of the smart projection factor: triangulate, then eliminate the landmark.

For a track seen by ``m`` poses, with the landmark ``X`` triangulated from the current poses
(DLT, optionally refined), the whitened reprojection errors and Jacobians are stacked as
``b (2m)``, ``F = blockdiag(F_i) (2m x 6m)`` (poses) and ``E (2m x 3)`` (landmark). Eliminating
the landmark from ``|F dx + E dX + b|^2`` leaves ``|Q (F dx + b)|^2`` with the projector
``Q = I - E (E^T E)^-1 E^T`` (the Schur complement of GTSAM's smart factors). With the
Householder QR ``E = U [R; 0]``, ``U = [U1 (2m x 3), U2 (2m x (2m - 3))]`` orthogonal, the
factor returns

    r = U^T b,    J = U^T F with its first three rows zeroed,

so ``0.5 |r|^2 = 0.5 |b|^2`` is the factor's error at the triangulated point (GTSAM's
``totalReprojectionError``), ``J^T J = F^T Q F`` and ``J^T r = F^T Q b`` (GTSAM's Hessian
factor). The core's Gauss-Newton / LM machinery then sees an ordinary residual and Jacobian;
the compiled problem's H and g take the same sums from :func:`smart_hessian_batch`, which uses
``F``'s block diagonal instead of the dense ``J``.

Degenerate tracks (a pixel that cannot be undistorted, DLT rank < 3, the point behind a view,
``E`` rank-deficient) give NaN (the step is rejected; at the initial estimate the optimizer names
the factor) or, when the track's last constant (its policy, :func:`zero_on_degenerate`) is
nonzero, a zero residual and Jacobian (GTSAM's ``ZERO_ON_DEGENERACY``). The policy is data, not
a compile-time flag: tracks of both policies share one kernel, one compile and one small-problem
driver.
"""

from __future__ import annotations

import numpy as np
from .._jit import njit

from . import _projection_kernels as PK
from . import _triangulation_kernels as TK
# bare names: _jit.specialize swaps them for their per-model copies
from ._projection_kernels import project_core
from ._triangulation_kernels import dlt
from ._triangulation_kernels import refine as refine_point  # (a parameter is named refine)


@njit(cache=True)
def zero_on_degenerate(consts, i, m, s):
    """Whether track ``i`` (constants ``consts[i]``: pixels ``2m``, calibration ``s``, square-root
    information 4, rank tolerance, policy) contributes nothing where it is degenerate."""
    return consts[i, 2 * m + s + 5] != 0.0


@njit(cache=True)
def unpack(pose_rows, Rs, ts):
    for j in range(pose_rows.shape[0]):
        PK.quat_to_rotation(pose_rows[j, :4], Rs[j])
        ts[j, 0], ts[j, 1], ts[j, 2] = pose_rows[j, 4], pose_rows[j, 5], pose_rows[j, 6]


@njit(cache=True)
def triangulate_track(model, Rs, ts, ks, z, rank_tol, refine, X):
    """DLT (+ refinement) of one track into ``X``; True when non-degenerate and in front."""
    rank = dlt(model, Rs, ts, ks, z, rank_tol, X)
    if rank < 3 or TK.in_front(Rs, ts, X) >= 0:
        return False
    if refine:
        refine_point(model, Rs, ts, ks, z, X, 50)
        if TK.in_front(Rs, ts, X) >= 0:
            return False
    return True


@njit(cache=True)
def _reflect_column(E, k, r2, r00, v):
    """Householder step ``k`` of the QR of ``E (r2 x 3)``, in place: ``v[k:]`` gets the vector
    of the reflection ``I - s v v^T`` that maps ``E[k:, k]`` to ``alpha e_k``, applied to columns
    ``k..2``. Returns ``s`` (0: nothing to reflect), or -1 when ``E`` is rank-deficient
    (``|R_kk| <= 1e-12 |R_00|``; ``r00 = |R_00|``, ignored for ``k = 0``)."""
    norm = 0.0
    for r in range(k, r2):
        norm += E[r, k] * E[r, k]
    norm = np.sqrt(norm)
    if k == 0:
        r00 = norm
    if not norm > 1e-12 * r00 or norm == 0.0:
        return -1.0
    alpha = -norm if E[k, k] >= 0.0 else norm
    vnorm2 = 0.0
    for r in range(k, r2):
        v[r] = E[r, k]
    v[k] -= alpha
    for r in range(k, r2):
        vnorm2 += v[r] * v[r]
    if vnorm2 == 0.0:
        return 0.0
    scale = 2.0 / vnorm2
    for c in range(k, 3):
        _reflect(v, scale, k, r2, E[:, c])
    return scale


@njit(cache=True)
def _reflect(v, scale, k, r2, x):
    """``x <- (I - scale v v^T) x`` on entries ``k..r2-1``."""
    dot = 0.0
    for r in range(k, r2):
        dot += v[r] * x[r]
    dot *= scale
    if dot != 0.0:
        for r in range(k, r2):
            x[r] -= dot * v[r]


@njit(cache=True)
def _householder_eliminate(E, b, F, m, Fd):
    """Apply ``Q^T`` of the Householder QR of ``E (2m x 3)`` to ``b`` (in place) and to the
    block-diagonal ``F`` (rows ``2j, 2j+1`` of view ``j`` in ``F[:, :6]``), written densely into
    ``Fd (2m x 6m)``. Rows 3.. of the results span ``E``'s left null space. Returns False when
    ``E`` is rank-deficient (``|R_kk| <= 1e-12 |R_00|``)."""
    r2 = 2 * m
    for r in range(r2):
        for col in range(6 * m):
            Fd[r, col] = 0.0
    for j in range(m):
        for col in range(6):
            Fd[2 * j, 6 * j + col] = F[2 * j, col]
            Fd[2 * j + 1, 6 * j + col] = F[2 * j + 1, col]
    r00 = 0.0
    v = np.empty(r2)
    for k in range(3):
        scale = _reflect_column(E, k, r2, r00, v)
        if scale < 0.0:
            return False
        if k == 0:
            r00 = abs(E[0, 0])
        if scale == 0.0:
            continue
        _reflect(v, scale, k, r2, b)
        for c in range(6 * m):
            _reflect(v, scale, k, r2, Fd[:, c])
    return True


@njit(cache=True)
def _track_workspace(m, s):
    """Work arrays of :func:`_track_system` for ``m`` views and ``s`` calibration parameters:
    ``Rs, ts, ks, z, X, b, E, F``."""
    r2 = 2 * m
    return (np.empty((m, 3, 3)), np.empty((m, 3)), np.empty((m, s)), np.empty((m, 2)),
            np.empty(3), np.empty(r2), np.empty((r2, 3)), np.empty((r2, 6)))


@njit(cache=True)
def _track_system(model, Rs, ts, ks, z, c, m, s, refine, b, F, E, X):
    """Triangulate one track and fill its whitened system: ``b (2m)`` reprojection errors,
    ``F (2m x 6)`` (view ``j``'s pose Jacobian in rows ``2j, 2j+1``) and ``E (2m x 3)``
    (landmark). False when the track is degenerate at these poses."""
    r2 = 2 * m
    uv = np.empty(2)
    p, Dk, Dp, A = PK.scratch()
    J9 = np.empty((2, 9))
    for j in range(m):
        z[j, 0], z[j, 1] = c[2 * j], c[2 * j + 1]
        for q in range(s):
            ks[j, q] = c[r2 + q]
    w00, w01, w10, w11 = c[r2 + s], c[r2 + s + 1], c[r2 + s + 2], c[r2 + s + 3]
    if not triangulate_track(model, Rs, ts, ks, z, c[r2 + s + 4], refine, X):
        return False
    for j in range(m):
        if project_core(model, Rs[j], ts[j], ks[j], X, True, True, uv, p, Dk, Dp,
                           A) != PK.OK:
            return False
        PK._chain(A, p, Rs[j], J9, 0, 6, 2)
        e0, e1 = uv[0] - z[j, 0], uv[1] - z[j, 1]
        b[2 * j] = w00 * e0 + w01 * e1
        b[2 * j + 1] = w10 * e0 + w11 * e1
        for col in range(6):
            F[2 * j, col] = w00 * J9[0, col] + w01 * J9[1, col]
            F[2 * j + 1, col] = w10 * J9[0, col] + w11 * J9[1, col]
        for col in range(3):
            E[2 * j, col] = w00 * J9[0, 6 + col] + w01 * J9[1, 6 + col]
            E[2 * j + 1, col] = w10 * J9[0, 6 + col] + w11 * J9[1, 6 + col]
    return True


@njit(cache=True, nogil=True)  # threads=N runs chunks in parallel
def smart_batch(model, P, consts, m, s, refine, with_jac):
    """``P (n, m, 7)`` pose storages, ``consts (n, 2m + s + 6)`` = pixels, calibration,
    the 2x2 square-root information (row major), rank tolerance, degenerate policy (1: zero,
    0: NaN; :func:`zero_on_degenerate`) -> res ``(n, 2m)``, jac ``(n, 2m, 6m)``."""
    n = P.shape[0]
    r2 = 2 * m
    res = np.zeros((n, r2))
    jac = np.zeros((n if with_jac else 0, r2, 6 * m))
    Rs, ts, ks, z, X, b, E, F = _track_workspace(m, s)
    Fd = np.empty((r2, 6 * m))
    for i in range(n):
        unpack(P[i], Rs, ts)
        ok = _track_system(model, Rs, ts, ks, z, consts[i], m, s, refine, b, F, E, X)
        if not ok or not _householder_eliminate(E, b, F, m, Fd):
            if not zero_on_degenerate(consts, i, m, s):
                for r in range(r2):
                    res[i, r] = np.nan
            continue
        for r in range(r2):
            res[i, r] = b[r]
        if with_jac:
            Ji = jac[i]
            for r in range(3, r2):
                for col in range(6 * m):
                    Ji[r, col] = Fd[r, col]
    return res, jac


@njit(cache=True)
def _landmark_r(E, m, R):
    """``R (3 x 3)`` upper triangular with ``R^T R = E^T E`` (Householder QR of ``E``, which
    it overwrites); False when ``E`` is rank-deficient, by the test of
    :func:`_householder_eliminate`."""
    r2 = 2 * m
    v = np.empty(r2)
    r00 = 0.0
    for k in range(3):
        if _reflect_column(E, k, r2, r00, v) < 0.0:
            return False
        if k == 0:
            r00 = abs(E[0, 0])
    for k in range(3):
        for c in range(3):
            R[k, c] = E[k, c] if c >= k else 0.0
    return True


@njit(cache=True)
def _track_schur(model, storage, rows, i, consts, m, s, refine, ws):
    """Track ``i``'s triangulated system and landmark elimination into the workspace ``ws`` of
    :func:`_schur_workspace`: ``b``, ``F`` (:func:`_track_system`), ``V_j = F_j^T E_j R^-1``
    and ``y = R^-T E^T b`` with ``R^T R = E^T E``. False when the track is degenerate."""
    Rs, ts, ks, z, X, b, E, F, R, V, y, pose = ws
    r2 = 2 * m
    for j in range(m):
        row = rows[i, j]
        for q in range(7):
            pose[j, q] = storage[row, q]
    unpack(pose, Rs, ts)
    if not _track_system(model, Rs, ts, ks, z, consts[i], m, s, refine, b, F, E, X):
        return False
    # c = E^T b and W_j = F_j^T E_j before the QR overwrites E
    c0 = c1 = c2 = 0.0
    for r in range(r2):
        c0 += E[r, 0] * b[r]
        c1 += E[r, 1] * b[r]
        c2 += E[r, 2] * b[r]
    for j in range(m):
        for a in range(6):
            for q in range(3):
                V[j, a, q] = F[2 * j, a] * E[2 * j, q] + F[2 * j + 1, a] * E[2 * j + 1, q]
    if not _landmark_r(E, m, R):
        return False
    # V_j <- W_j R^-1 (row by row: v R = w), y = R^-T c
    for j in range(m):
        for a in range(6):
            v0 = V[j, a, 0] / R[0, 0]
            v1 = (V[j, a, 1] - v0 * R[0, 1]) / R[1, 1]
            V[j, a, 0], V[j, a, 1] = v0, v1
            V[j, a, 2] = (V[j, a, 2] - v0 * R[0, 2] - v1 * R[1, 2]) / R[2, 2]
    y[0] = c0 / R[0, 0]
    y[1] = (c1 - R[0, 1] * y[0]) / R[1, 1]
    y[2] = (c2 - R[0, 2] * y[0] - R[1, 2] * y[1]) / R[2, 2]
    return True


@njit(cache=True)
def _schur_workspace(m, s):
    Rs, ts, ks, z, X, b, E, F = _track_workspace(m, s)
    return (Rs, ts, ks, z, X, b, E, F, np.empty((3, 3)), np.empty((m, 6, 3)), np.empty(3),
            np.empty((m, 7)))


@njit(cache=True)
def _track_step(model, storage, rows, i, consts, m, s, refine, ws, toff, g):
    """Track ``i``'s :func:`_track_schur`, its gradient ``g_j += F_j^T b_j - V_j y`` for each
    view ``j`` and its cost: ``(True, 0.5 |b|^2)``, or for a degenerate track ``(False, NaN)``
    (``(False, 0)`` where its policy is :func:`zero_on_degenerate`); the caller adds the
    Hessian blocks."""
    if not _track_schur(model, storage, rows, i, consts, m, s, refine, ws):
        return False, (0.0 if zero_on_degenerate(consts, i, m, s) else np.nan)
    b, F, V, y = ws[5], ws[7], ws[9], ws[10]
    e2 = 0.0
    for r in range(2 * m):
        e2 += b[r] * b[r]
    for p in range(m):
        gbase = toff[i, p]
        for a in range(6):
            g[gbase + a] += (F[2 * p, a] * b[2 * p] + F[2 * p + 1, a] * b[2 * p + 1]
                             - V[p, a, 0] * y[0] - V[p, a, 1] * y[1] - V[p, a, 2] * y[2])
    return True, 0.5 * e2


@njit(cache=True)
def smart_hessian_batch(model, storage, rows, consts, m, s, refine, toff, pos, col_shift,
                        H_data, g, weights, cost):
    """Add the batch's Schur complements straight into ``H_data`` / ``g`` (the scatter map of
    :func:`fgopt._assembly.scatter_batch`); return ``cost`` plus the batch's cost.

    Same sums as :func:`smart_batch`'s ``J^T J``, ``J^T r``, ``0.5 |r|^2`` (unit noise, no
    robust loss), using ``F``'s block diagonal: with ``E = Q [R; 0]``, ``V_j = F_j^T E_j R^-1``
    and ``y = R^-T E^T b``, block ``(i, j)`` of ``F^T (I - E (E^T E)^-1 E^T) F`` is
    ``delta_ij F_i^T F_i - V_i V_j^T`` and ``g_j = F_j^T b_j - V_j y``: ~100 multiply-adds per
    6 x 6 block instead of the scatter's dense ``(2m - 3) x 6m`` product, and no dense ``Q^T F``
    (measured on SFMExample's eight 8-view tracks: 42 us kernel + 44 us scatter -> 41 us, of which
    the DLTs take ~12). ``storage[rows[i, j]]``: the pose of track ``i``'s view ``j``.
    """
    n = consts.shape[0]
    ws = _schur_workspace(m, s)
    F, V = ws[7], ws[9]
    for i in range(n):
        weights[i] = 1.0
        ok, c = _track_step(model, storage, rows, i, consts, m, s, refine, ws, toff, g)
        cost += c
        if not ok:
            continue
        for p in range(m):
            for q in range(m):
                p00 = pos[i, p, q]
                if p00 < 0:
                    continue
                tq = toff[i, q]
                for bb in range(6):
                    base = p00 + col_shift[tq + bb]
                    u0, u1, u2 = V[q, bb, 0], V[q, bb, 1], V[q, bb, 2]
                    if p == q:  # diagonal block: lower triangle, plus F_p^T F_p
                        f0, f1 = F[2 * p, bb], F[2 * p + 1, bb]
                        for a in range(bb, 6):
                            H_data[base + a] += (F[2 * p, a] * f0 + F[2 * p + 1, a] * f1
                                                 - V[p, a, 0] * u0 - V[p, a, 1] * u1
                                                 - V[p, a, 2] * u2)
                    else:
                        for a in range(6):
                            H_data[base + a] -= (V[p, a, 0] * u0 + V[p, a, 1] * u1
                                                 + V[p, a, 2] * u2)
    return cost


@njit(cache=True)
def smart_dense_batch(model, storage, rows, consts, m, s, refine, toff, H, g, cost):
    """:func:`smart_hessian_batch`'s sums into a dense ``H (N, N)`` (both triangles) and ``g``,
    for the small-problem driver (:mod:`fgopt.solvers.small`): the ``F_j^T F_j`` blocks by
    hand, every track's ``-V V^T`` as one product ``-B B^T`` of the ``(N, 3 n)`` matrix ``B``
    whose column block ``i`` holds track ``i``'s ``V`` at its poses' rows (one BLAS call instead
    of ``m^2`` scattered 6 x 6 blocks per track; SFMExample's eight 8-view tracks: a whole
    linearization 59 -> 48 us, of which the triangulations ~13)."""
    n = consts.shape[0]
    ws = _schur_workspace(m, s)
    F, V = ws[7], ws[9]
    B = np.zeros((H.shape[0], 3 * n))
    for i in range(n):
        ok, c = _track_step(model, storage, rows, i, consts, m, s, refine, ws, toff, g)
        cost += c
        if not ok:
            continue
        for p in range(m):
            t = toff[i, p]
            for a in range(6):
                for q in range(3):
                    B[t + a, 3 * i + q] = V[p, a, q]
                fa0, fa1 = F[2 * p, a], F[2 * p + 1, a]
                for c in range(6):
                    H[t + a, t + c] += fa0 * F[2 * p, c] + fa1 * F[2 * p + 1, c]
    H -= np.dot(B, B.T)
    return cost


@njit(cache=True)
def smart_point(model, pose_rows, k, z, rank_tol, refine):
    """The landmark of one track (``pose_rows (m, 7)``, ``z (m, 2)``): ``(X, ok)``."""
    m = pose_rows.shape[0]
    Rs = np.empty((m, 3, 3))
    ts = np.empty((m, 3))
    unpack(pose_rows, Rs, ts)
    ks = np.empty((m, k.shape[0]))
    for j in range(m):
        ks[j] = k
    X = np.empty(3)
    ok = triangulate_track(model, Rs, ts, ks, z, rank_tol, refine, X)
    return X, ok
