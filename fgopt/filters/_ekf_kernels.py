"""Numba kernels of :class:`~fgopt.filters.ekf.ManifoldEKF`: checks, covariance propagation,
the Joseph-form update and the commit, each one call per filter step.

Every kernel validates its inputs first and writes the filter's state (``x`` inside the process
input buffer, ``P``) only as its last act, after every check passed: a step either happens
completely or not at all. Kernels return a status code (``OK`` or one of the codes below) and
an index (the offending entry) that :mod:`fgopt.filters.ekf` turns into an ``FgoptError``.

Kernels are :func:`fgopt._jit.njit` proxies: numba is imported and they are compiled (or loaded
from numba's cache) on first use, not when ``fgopt.filters`` is imported.

Products skip the structural zeros of the generated Jacobians (``F``, ``G``, ``H`` are mostly
zeros for navigation models), which keeps a 15-state predict + update in a few microseconds.
"""

from __future__ import annotations

import numpy as np

from .._jit import njit

OK = 0
U_NONFINITE = 1
DT_INVALID = 2
Q_NONFINITE = 3
Q_ASYMMETRIC = 4
Q_NOT_PSD = 5
QS_NONFINITE = 6
QS_ASYMMETRIC = 7
QS_NOT_PSD = 8
PROCESS_NONFINITE = 9
JACOBIAN_NONFINITE = 10
COVARIANCE_NONFINITE = 11
R_NONFINITE = 12
R_ASYMMETRIC = 13
R_NOT_PD = 14
INNOVATION_NONFINITE = 15
S_NOT_PD = 16
RETRACT_NONFINITE = 17
Z_NONFINITE = 18

#: Relative tolerances: symmetry of noise matrices, and the eigenvalue shift accepted as PSD.
SYMMETRY_TOL = 1e-9
PSD_TOL = 1e-12

_JIT = {"cache": True, "fastmath": False, "error_model": "numpy", "nogil": True}


@njit(**_JIT)
def _first_nonfinite(a):
    flat = a.reshape(-1)
    for i in range(flat.shape[0]):
        if not np.isfinite(flat[i]):
            return i
    return -1


@njit(**_JIT)
def _cholesky(A, L, shift):
    """Lower Cholesky factor of ``A + shift I`` into ``L``; False if a pivot is not positive."""
    n = A.shape[0]
    scale = 0.0
    for i in range(n):
        scale = max(scale, abs(A[i, i]))
    floor = 1e-14 * scale
    for j in range(n):
        s = A[j, j] + shift
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if not s > floor:
            if shift > 0.0 and s > -shift:  # PSD mode: a zero pivot with a zero column is fine
                s = shift
            else:
                return False
        d = np.sqrt(s)
        L[j, j] = d
        for i in range(j + 1, n):
            t = A[i, j]
            for k in range(j):
                t -= L[i, k] * L[j, k]
            L[i, j] = t / d
        for i in range(j):
            L[i, j] = 0.0
    return True


@njit(**_JIT)
def _check_noise(A, L, psd):
    """0 fine, 1 non-finite, 2 asymmetric, 3 not PSD / PD; and the offending index."""
    n = A.shape[0]
    i = _first_nonfinite(A)
    if i >= 0:
        return 1, i
    amax = 0.0
    for i in range(n):
        for j in range(n):
            amax = max(amax, abs(A[i, j]))
    for i in range(n):
        for j in range(i + 1, n):
            if abs(A[i, j] - A[j, i]) > SYMMETRY_TOL * amax:
                return 2, i * n + j
    if n == 0:
        return 0, -1
    shift = PSD_TOL * amax + 1e-300 if psd else 0.0
    if not _cholesky(A, L, shift):
        return 3, -1
    return 0, -1


@njit(**_JIT)
def _symmetrize(A):
    n = A.shape[0]
    for i in range(n):
        for j in range(i + 1, n):
            v = 0.5 * (A[i, j] + A[j, i])
            A[i, j] = v
            A[j, i] = v


@njit(**_JIT)
def _normalize(x, unit):
    for r in range(unit.shape[0]):
        a, n = unit[r, 0], unit[r, 1]
        s = 0.0
        for k in range(a, a + n):
            s += x[k] * x[k]
        s = np.sqrt(s)
        for k in range(a, a + n):
            x[k] /= s


@njit(**_JIT)
def _sandwich_add(B, c0, M, out, T):
    """``out += B M B^T`` for ``B = J[:, c0:c0 + M.shape[0]]`` (M symmetric; zeros of B
    skipped: generated Jacobians are sparse). ``T`` (at least ``n x k``) receives ``B M``.

    Measured against a dense loop, index lists of the non-zeros and BLAS for a 15-state INS
    ``F`` (45 of 225 entries non-zero): this plain skip is the fastest (0.7 us vs 1.0-1.9 us).
    """
    n, k = B.shape[0], M.shape[0]
    for i in range(n):
        for j in range(k):
            T[i, j] = 0.0
        for a in range(k):
            b = B[i, c0 + a]
            if b != 0.0:
                for j in range(k):
                    T[i, j] += b * M[a, j]
    for i in range(n):
        for a in range(k):
            b = B[i, c0 + a]
            if b != 0.0:
                for j in range(n):
                    out[i, j] += b * T[j, a]


@njit(**_JIT)
def _validated(A, last, L, psd):
    """``_check_noise(A)``, skipped when ``A`` equals ``last`` (the last matrix that passed);
    a matrix that passes is copied into ``last``."""
    n = A.shape[0]
    same = True
    for i in range(n):
        for j in range(n):
            if A[i, j] != last[i, j]:  # NaN never equals: checked
                same = False
                break
        if not same:
            break
    if same:
        return 0, -1
    code, idx = _check_noise(A, L, psd)
    if code == 0:
        for i in range(n):
            for j in range(n):
                last[i, j] = A[i, j]
    return code, idx


@njit(**_JIT)
def predict(pin, nx, nu, xnext, FG, P, Q, Qs, use_qs, Pn, L, T, unit, Qlast, Qslast):
    """Checks, then ``P <- F P F^T + G Q G^T (+ Qs)`` and ``x <- f(x, u, dt)`` (committed).

    ``pin`` = ``[x storage | u storage | dt]`` (``x`` is the filter's state), ``xnext`` the
    process output, ``FG = [F | G]`` its Jacobian (``n x (n + m)``).
    """
    n = P.shape[0]
    for i in range(nx, nx + nu):
        if not np.isfinite(pin[i]):
            return U_NONFINITE, i - nx
    dt = pin[nx + nu]
    if not (np.isfinite(dt) and dt > 0.0):
        return DT_INVALID, -1
    code, idx = _validated(Q, Qlast, L, True)
    if code != 0:
        return Q_NONFINITE + code - 1, idx
    if use_qs:
        code, idx = _validated(Qs, Qslast, L, True)
        if code != 0:
            return QS_NONFINITE + code - 1, idx
    i = _first_nonfinite(xnext)
    if i >= 0:
        return PROCESS_NONFINITE, i
    i = _first_nonfinite(FG)
    if i >= 0:
        return JACOBIAN_NONFINITE, i
    for i in range(n):
        for j in range(n):
            Pn[i, j] = Qs[i, j] if use_qs else 0.0
    _sandwich_add(FG, 0, P, Pn, T)
    if Q.shape[0] > 0:
        _sandwich_add(FG, n, Q, Pn, T)
    _symmetrize(Pn)
    i = _first_nonfinite(Pn)
    if i >= 0:
        return COVARIANCE_NONFINITE, i
    _normalize(xnext, unit)
    for i in range(n):
        for j in range(n):
            P[i, j] = Pn[i, j]
    for i in range(nx):
        pin[i] = xnext[i]
    return OK, -1


@njit(**_JIT)
def gain(y, J, P, R, S, L, K, Pn, HP, AP, W, rin, pin, nx, stats, Rlast):
    """Joseph-form update in the tangent space: ``delta = K y`` (into ``rin[nx:]``), ``Pn``.

    ``y`` is the innovation ``local(h(x), z)`` and ``J = d y / d x`` (so ``H = -J``);
    ``S = H P H^T + R``, ``K = P H^T S^-1``, ``Pn = (I - K H) P (I - K H)^T + K R K^T``
    (computed as ``A = P - K (H P)``, ``Pn = A - (A H^T) K^T + K R K^T``). ``stats`` receives
    the normalized innovation squared ``y^T S^-1 y``. Nothing of the filter is written.
    """
    n, m = P.shape[0], y.shape[0]
    i = _first_nonfinite(y)
    if i >= 0:
        return INNOVATION_NONFINITE, i
    i = _first_nonfinite(J)
    if i >= 0:
        return JACOBIAN_NONFINITE, i
    code, idx = _validated(R, Rlast, L, False)
    if code != 0:
        return R_NONFINITE + code - 1, idx
    # HP = H P = -J P (m x n), skipping zeros of J
    for a in range(m):
        for j in range(n):
            HP[a, j] = 0.0
        for k in range(n):
            h = -J[a, k]
            if h != 0.0:
                for j in range(n):
                    HP[a, j] += h * P[k, j]
    # S = H P H^T + R
    for a in range(m):
        for b in range(m):
            s = R[a, b]
            for k in range(n):
                h = -J[b, k]
                if h != 0.0:
                    s += HP[a, k] * h
            S[a, b] = s
    _symmetrize(S)
    if not _cholesky(S, L, 0.0):
        return S_NOT_PD, -1
    # K^T = S^-1 H P (S symmetric, H P = (P H^T)^T): solve L L^T X = HP column by column
    for j in range(n):
        for a in range(m):
            t = HP[a, j]
            for b in range(a):
                t -= L[a, b] * K[j, b]
            K[j, a] = t / L[a, a]
        for a in range(m - 1, -1, -1):
            t = K[j, a]
            for b in range(a + 1, m):
                t -= L[b, a] * K[j, b]
            K[j, a] = t / L[a, a]
    # normalized innovation squared: |L^-1 y|^2
    nis = 0.0
    for a in range(m):
        t = y[a]
        for b in range(a):
            t -= L[a, b] * stats[1 + b]
        t /= L[a, a]
        stats[1 + a] = t
        nis += t * t
    stats[0] = nis
    # delta = K y, written after the state in the retraction input
    for i in range(nx):
        rin[i] = pin[i]
    for j in range(n):
        d = 0.0
        for a in range(m):
            d += K[j, a] * y[a]
        rin[nx + j] = d
    # A = P - K (H P)
    for i in range(n):
        for j in range(n):
            s = P[i, j]
            for a in range(m):
                s -= K[i, a] * HP[a, j]
            AP[i, j] = s
    # Pn = A - W K^T + V K^T with W = A H^T, V = K R (both n x m)
    for i in range(n):
        for a in range(m):
            w = 0.0
            for k in range(n):
                h = -J[a, k]
                if h != 0.0:
                    w += AP[i, k] * h
            v = 0.0
            for b in range(m):
                v += K[i, b] * R[b, a]
            W[i, a] = v - w
    for i in range(n):
        for j in range(n):
            s = AP[i, j]
            for a in range(m):
                s += W[i, a] * K[j, a]
            Pn[i, j] = s
    _symmetrize(Pn)
    i = _first_nonfinite(Pn)
    if i >= 0:
        return COVARIANCE_NONFINITE, i
    return OK, -1


@njit(**_JIT)
def commit_update(xnew, G, Pn, reset, P, pin, nx, unit, T):
    """``P <- G Pn G^T`` (if ``reset``) or ``Pn``, and ``x <- xnew`` (normalized), committed.

    ``T`` is an ``n x n`` scratch array.
    """
    n = P.shape[0]
    i = _first_nonfinite(xnew)
    if i >= 0:
        return RETRACT_NONFINITE, i
    i = _first_nonfinite(G)
    if i >= 0:
        return JACOBIAN_NONFINITE, i
    if reset:  # Pn <- G Pn G^T, through T = G Pn and then (G T^T)
        for i in range(n):
            for j in range(n):
                T[i, j] = 0.0
            for a in range(n):
                g = G[i, a]
                if g != 0.0:
                    for j in range(n):
                        T[i, j] += g * Pn[a, j]
        for i in range(n):
            for j in range(n):
                Pn[i, j] = 0.0
            for a in range(n):
                g = G[i, a]
                if g != 0.0:
                    for j in range(n):
                        Pn[i, j] += g * T[j, a]
        _symmetrize(Pn)
    i = _first_nonfinite(Pn)
    if i >= 0:
        return COVARIANCE_NONFINITE, i
    _normalize(xnew, unit)
    for i in range(n):
        for j in range(n):
            P[i, j] = Pn[i, j]
    for i in range(nx):
        pin[i] = xnew[i]
    return OK, -1
