"""numba kernels of landmark triangulation: the DLT and a Levenberg-Marquardt refinement.

DLT (Hartley & Zisserman, as GTSAM's ``triangulateDLT``): with ``P_i = K_i [R_i^T | -R_i^T t_i]``
(the linear part ``K_i`` of view ``i``'s calibration) and the *undistorted* pixel ``(u_i, v_i)``
(``K_i calibrate_i(uv_i)``), each view gives two rows ``u_i P_i3 - P_i1`` and
``v_i P_i3 - P_i2`` of ``A X = 0``; ``X`` is the right singular vector of the smallest singular
value (Householder QR then one-sided Jacobi, :func:`svd_n4`), de-homogenized. The rank is the
number of singular values above ``rank_tol`` (GTSAM's
rule; it depends on pixel units).

Refinement minimizes the reprojection error ``sum_i |uv_i(X) - z_i|^2`` over ``X`` by damped
Gauss-Newton with the analytic Jacobians of :mod:`fgopt.cameras._projection_kernels`.
"""

from __future__ import annotations

import math

import numpy as np
from .._jit import njit

from . import _calib_kernels as CK
# bare names: numba prunes on constants, _jit.specialize swaps kernels for per-model copies
from ._calib_kernels import CAL3_S2, CAL3_S2STEREO, pinhole_part
from ._projection_kernels import project_core
from . import _projection_kernels as PK


@njit(cache=True, inline="always")
def undistort(model, k, u, v, tol, max_iterations, out):
    """``out = K calibrate(u, v)`` (the pixel a distortion-free camera would see); False if
    calibrate fails: the pixel is outside the model's image, Newton's root lies past a fold of
    the distortion, or it did not converge."""
    if model == CAL3_S2 or model == CAL3_S2STEREO:
        out[0], out[1] = u, v
        return True
    xy = np.empty(2)
    if CK.calibrate(model, k, u, v, tol, max_iterations, xy) != CK.OK:
        return False
    K5 = np.empty(5)
    CK.pinhole_part(model, k, K5)
    out[0] = K5[0] * xy[0] + K5[2] * xy[1] + K5[3]
    out[1] = K5[1] * xy[1] + K5[4]
    return True


@njit(cache=True)
def dlt(model, Rs, ts, ks, uv, rank_tol, X):
    """DLT of ``m`` views (``Rs (m, 3, 3)``, ``ts (m, 3)``, calibrations ``ks (m, s)`` of one
    model, pixels ``uv (m, 2)``) into ``X (3,)``. Returns the rank of ``A`` (``-1`` when a pixel
    cannot be undistorted, ``-2`` for a point at infinity)."""
    m = Rs.shape[0]
    A = np.empty((2 * m, 4))
    K5 = np.empty(5)
    und = np.empty(2)
    P = np.empty((3, 4))
    M = np.empty((3, 4))
    for i in range(m):
        if not undistort(model, ks[i], uv[i, 0], uv[i, 1], 1e-10, 20, und):
            return -1
        pinhole_part(model, ks[i], K5)
        R = Rs[i]
        # M = [R^T | -R^T t], then P = K M with K = [[fx, s, u0], [0, fy, v0], [0, 0, 1]]
        for r in range(3):
            for c in range(3):
                M[r, c] = R[c, r]
            M[r, 3] = -(R[0, r] * ts[i, 0] + R[1, r] * ts[i, 1] + R[2, r] * ts[i, 2])
        for c in range(4):
            P[0, c] = K5[0] * M[0, c] + K5[2] * M[1, c] + K5[3] * M[2, c]
            P[1, c] = K5[1] * M[1, c] + K5[4] * M[2, c]
            P[2, c] = M[2, c]
            A[2 * i, c] = und[0] * P[2, c] - P[0, c]
            A[2 * i + 1, c] = und[1] * P[2, c] - P[1, c]
    sv = np.empty(4)
    V = np.empty((4, 4))
    small = svd_n4(A, sv, V)
    rank = 0
    for j in range(min(4, 2 * m)):
        if sv[j] > rank_tol:
            rank += 1
    w = V[3, small]
    if w == 0.0:
        return -2
    X[0], X[1], X[2] = V[0, small] / w, V[1, small] / w, V[2, small] / w
    return rank


@njit(cache=True)
def svd_n4(A, sv, V):
    """Singular values ``sv`` and right singular vectors ``V`` (columns) of ``A (r x 4)``:
    Householder QR to ``R (4 x 4)``, then one-sided Jacobi (Hestenes) on ``R``, accurate to
    rounding like Eigen's JacobiSVD that GTSAM uses, without a LAPACK call per track. ``sv`` is
    unsorted; returns the index of the smallest singular value."""
    rows = A.shape[0]
    W = A.copy()
    k_max = min(4, rows)
    for k in range(k_max):
        norm = 0.0
        for r in range(k, rows):
            norm += W[r, k] * W[r, k]
        norm = np.sqrt(norm)
        if norm == 0.0:
            continue
        alpha = -norm if W[k, k] >= 0.0 else norm
        W[k, k] -= alpha
        vn2 = 0.0
        for r in range(k, rows):
            vn2 += W[r, k] * W[r, k]
        for c in range(k + 1, 4):
            dot = 0.0
            for r in range(k, rows):
                dot += W[r, k] * W[r, c]
            dot *= 2.0 / vn2
            for r in range(k, rows):
                W[r, c] -= dot * W[r, k]
        W[k, k] = alpha
        for r in range(k + 1, rows):
            W[r, k] = 0.0
    R = np.zeros((4, 4))
    for r in range(k_max):
        for c in range(r, 4):
            R[r, c] = W[r, c]
    for r in range(4):
        for c in range(4):
            V[r, c] = 1.0 if r == c else 0.0
    for _ in range(60):
        rotated = False
        for p in range(3):
            for q in range(p + 1, 4):
                a = b = g = 0.0
                for r in range(4):
                    a += R[r, p] * R[r, p]
                    b += R[r, q] * R[r, q]
                    g += R[r, p] * R[r, q]
                if abs(g) <= 1e-15 * np.sqrt(a * b) or g == 0.0:
                    continue
                rotated = True
                zeta = (b - a) / (2.0 * g)
                t = (1.0 if zeta >= 0.0 else -1.0) / (abs(zeta) + np.sqrt(1.0 + zeta * zeta))
                c = 1.0 / np.sqrt(1.0 + t * t)
                sn = c * t
                for r in range(4):
                    rp, rq = R[r, p], R[r, q]
                    R[r, p] = c * rp - sn * rq
                    R[r, q] = sn * rp + c * rq
                    vp, vq = V[r, p], V[r, q]
                    V[r, p] = c * vp - sn * vq
                    V[r, q] = sn * vp + c * vq
        if not rotated:
            break
    small = 0
    for c in range(4):
        acc = 0.0
        for r in range(4):
            acc += R[r, c] * R[r, c]
        sv[c] = np.sqrt(acc)
        if sv[c] < sv[small]:
            small = c
    return small


@njit(cache=True)
def reprojection_cost(model, Rs, ts, ks, uv, X):
    """``0.5 sum |uv_i(X) - z_i|^2`` (NaN if a view cannot see ``X``)."""
    m = Rs.shape[0]
    total = 0.0
    out = np.empty(2)
    p, Dk, Dp, A = PK.scratch()
    for i in range(m):
        if project_core(model, Rs[i], ts[i], ks[i], X, True, False, out, p, Dk, Dp, A) != 0:
            return np.nan
        e0, e1 = out[0] - uv[i, 0], out[1] - uv[i, 1]
        total += 0.5 * (e0 * e0 + e1 * e1)
    return total


@njit(cache=True)
def refine(model, Rs, ts, ks, uv, X, max_iterations):
    """Levenberg-Marquardt on ``X`` (in place) from its current value; returns the iterations
    used, or -1 when the start is not visible from every view."""
    m = Rs.shape[0]
    cost = reprojection_cost(model, Rs, ts, ks, uv, X)
    if not math.isfinite(cost):
        return -1
    lam = 1e-6
    out = np.empty(2)
    p, Dk, Dp, A = PK.scratch()
    Hm = np.empty((3, 3))
    g = np.empty(3)
    trial = np.empty(3)
    J = np.empty((2, 3))
    it = 0
    while it < max_iterations:
        it += 1
        Hm[:, :] = 0.0
        g[:] = 0.0
        for i in range(m):
            project_core(model, Rs[i], ts[i], ks[i], X, True, True, out, p, Dk, Dp, A)
            e0, e1 = out[0] - uv[i, 0], out[1] - uv[i, 1]
            # d uv / d X = A R^T
            for r in range(2):
                for c in range(3):
                    J[r, c] = A[r, 0] * Rs[i, c, 0] + A[r, 1] * Rs[i, c, 1] + A[r, 2] * Rs[i, c, 2]
            for a in range(3):
                g[a] += J[0, a] * e0 + J[1, a] * e1
                for b in range(3):
                    Hm[a, b] += J[0, a] * J[0, b] + J[1, a] * J[1, b]
        gmax = max(abs(g[0]), abs(g[1]), abs(g[2]))
        if gmax <= 1e-14 * max(1.0, cost):
            break
        accepted = False
        while lam < 1e12:
            D = Hm.copy()
            for a in range(3):
                D[a, a] += lam * max(Hm[a, a], 1e-12)
            step = np.linalg.solve(D, -g)
            for a in range(3):
                trial[a] = X[a] + step[a]
            new = reprojection_cost(model, Rs, ts, ks, uv, trial)
            if math.isfinite(new) and new <= cost:
                X[:] = trial
                small = (cost - new) <= 1e-15 * cost or \
                    math.sqrt(step[0] ** 2 + step[1] ** 2 + step[2] ** 2) <= \
                    1e-14 * (1.0 + math.sqrt(X[0] ** 2 + X[1] ** 2 + X[2] ** 2))
                cost = new
                lam = max(lam / 10.0, 1e-12)
                accepted = True
                if small:
                    return it
                break
            lam *= 10.0
        if not accepted:
            break
    return it


@njit(cache=True)
def in_front(Rs, ts, X):
    """Index of the first view with ``X`` at or behind it, or -1."""
    p = np.empty(3)
    for i in range(Rs.shape[0]):
        PK.to_camera(Rs[i], ts[i], X, p)
        if not p[2] > 0.0:
            return i
    return -1
