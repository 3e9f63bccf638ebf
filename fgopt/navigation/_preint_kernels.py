"""Numba loops of on-manifold IMU preintegration (Forster et al. 2017; GTSAM's
``ManifoldPreintegration``) and the prediction ``predict(state_i, bias_i)``.

Preintegrated state: ``dR`` (3x3), ``dp``, ``dv``, ``dt`` and the bias Jacobians
``JRw = d dR/d b_w`` (tangent of dR), ``Jpa, Jpw, Jva, Jvw``. With the bias-corrected (and
sensor-pose-corrected) sample ``a, w`` and ``E = Exp(w dt)``, one step is::

    dp += dv dt + dR a dt^2/2      dv += dR a dt      dR <- dR E
    JRw <- E^T JRw - Jr(w dt) dt
    Jpa += Jva dt - dR dt^2/2      Jpw += Jvw dt - dR hat(a) JRw dt^2/2   (old dR, old JRw)
    Jva -= dR dt                   Jvw -= dR hat(a) JRw dt

and the covariance of ``[theta, p, v]`` (GTSAM's ``preintMeasCov`` order, in the NavState chart)
propagates with ``A = d new/d old``, ``B = d new/d a``, ``C = d new/d w``::

    A = [[E^T, 0, 0], [-E^T hat(a) dt^2/2, E^T, E^T dt], [-E^T hat(a) dt, 0, E^T]]
    B = [0; E^T dt^2/2; E^T dt]        C = [Jr(w dt) dt; 0; 0]
    P <- A P A^T + B (Sa/dt) B^T + C (Sw/dt) C^T,   P_pp += Si dt

With a sensor pose ``body_P_sensor = (bRs, arm)`` the sample is rotated into the body frame and
the centrifugal term ``w x (w x arm)`` removed, and ``B``, ``C`` get the chain rule of that
correction (as GTSAM; GTSAM's bias Jacobians ignore ``bRs``, and so do these, to stay equal).
The combined (15-state) covariance adds the bias random walk:
``F = [[A, B, C], [0, I]]``, ``P <- F P F^T + ...``, ``P_bb += S_bias dt`` -- ``B`` and ``C``
with GTSAM's sign (the derivative with respect to the measurement, not the bias).
"""

from __future__ import annotations

import math

import numpy as np
from .._jit import njit

from ..manifolds._kernels import skew_poly3
from ._so3_matrix import exp_matrix, jr_matrix, mm3, mv3

# layout of the packed preintegrated state ``x`` (float64, length STATE_DIM)
R_, P_, V_, T_ = 0, 9, 12, 15
JRW, JPA, JPW, JVA, JVW = 16, 25, 34, 43, 52
STATE_DIM = 61


@njit(cache=True)
def initial_state():
    x = np.zeros(STATE_DIM)
    x[R_ + 0] = x[R_ + 4] = x[R_ + 8] = 1.0
    return x


@njit(cache=True)
def _get3(x, off, m):
    for i in range(3):
        for j in range(3):
            m[i, j] = x[off + 3 * i + j]


@njit(cache=True)
def _put3(x, off, m):
    for i in range(3):
        for j in range(3):
            x[off + 3 * i + j] = m[i, j]


@njit(cache=True)
def _l_cols(P, a, dt, c1, out, ncol):
    """out[:9, :ncol] = L P[:9, :ncol] with ``L = [[I, 0, 0], [-c1 H, I, dt I], [-dt H, 0, I]]``,
    ``H = hat(a)`` (``H x = a x x``)."""
    for j in range(ncol):
        p0, p1, p2 = P[0, j], P[1, j], P[2, j]
        h0 = a[1] * p2 - a[2] * p1
        h1 = a[2] * p0 - a[0] * p2
        h2 = a[0] * p1 - a[1] * p0
        out[0, j], out[1, j], out[2, j] = p0, p1, p2
        out[3, j] = P[3, j] + dt * P[6, j] - c1 * h0
        out[4, j] = P[4, j] + dt * P[7, j] - c1 * h1
        out[5, j] = P[5, j] + dt * P[8, j] - c1 * h2
        out[6, j] = P[6, j] - dt * h0
        out[7, j] = P[7, j] - dt * h1
        out[8, j] = P[8, j] - dt * h2


@njit(cache=True)
def _l_rows(P, a, dt, c1, out):
    """out[:9, :9] = P[:9, :9] L^T (L of :func:`_l_cols`; a row x times H^T is ``a x x``)."""
    for i in range(9):
        p0, p1, p2 = P[i, 0], P[i, 1], P[i, 2]
        h0 = a[1] * p2 - a[2] * p1
        h1 = a[2] * p0 - a[0] * p2
        h2 = a[0] * p1 - a[1] * p0
        out[i, 0], out[i, 1], out[i, 2] = p0, p1, p2
        out[i, 3] = P[i, 3] + dt * P[i, 6] - c1 * h0
        out[i, 4] = P[i, 4] + dt * P[i, 7] - c1 * h1
        out[i, 5] = P[i, 5] + dt * P[i, 8] - c1 * h2
        out[i, 6] = P[i, 6] - dt * h0
        out[i, 7] = P[i, 7] - dt * h1
        out[i, 8] = P[i, 8] - dt * h2


@njit(cache=True)
def _et_rows(X, Et, out, ncol):
    """out[:9, :ncol] = blockdiag(Et, Et, Et) X[:9, :ncol]."""
    for b in range(3):
        r0 = 3 * b
        for j in range(ncol):
            x0, x1, x2 = X[r0, j], X[r0 + 1, j], X[r0 + 2, j]
            for i in range(3):
                out[r0 + i, j] = Et[i, 0] * x0 + Et[i, 1] * x1 + Et[i, 2] * x2


@njit(cache=True)
def _propagate_nav(P, a, dt, Et, Q, S1, S2):
    """P[:9, :9] <- A P A^T + Q[:9, :9] with ``A = blockdiag(Et) L`` (module docstring's A:
    ``-E^T hat(a)`` blocks are ``Et`` times L's ``-hat(a)``); S1, S2: 9x9 scratch."""
    c1 = 0.5 * dt * dt
    _l_cols(P, a, dt, c1, S1, 9)
    _l_rows(S1, a, dt, c1, S2)
    _et_rows(S2, Et, S1, 9)
    # P = S1 blockdiag(E) = (blockdiag(Et) S1^T)^T, written straight into P (symmetric)
    for b in range(3):
        c0 = 3 * b
        for i in range(9):
            x0, x1, x2 = S1[i, c0], S1[i, c0 + 1], S1[i, c0 + 2]
            for k in range(3):
                P[i, c0 + k] = Et[k, 0] * x0 + Et[k, 1] * x1 + Et[k, 2] * x2 + Q[i, c0 + k]


@njit(cache=True)
def _propagate_combined(P, a, dt, Et, G, Q, S1, S2, Z, Y):
    """P (15x15) <- F P F^T + Q with ``F = [[A, G], [0, I]]``: with ``N, X, Bb`` the blocks of P,
    ``Z = A X``, ``Y = Z + G Bb``: ``N <- A N A^T + Y G^T + G Z^T + Qn``, ``X <- Y``,
    ``Bb <- Bb + Qb``."""
    c1 = 0.5 * dt * dt
    # Z = A X: X is P[:9, 9:15]; L then blockdiag(Et), on its 6 columns
    for j in range(6):
        for i in range(9):
            S2[i, j] = P[i, 9 + j]
    _l_cols(S2, a, dt, c1, S1, 6)
    _et_rows(S1, Et, Z, 6)
    for i in range(9):
        for j in range(6):
            acc = Z[i, j]
            for k in range(6):
                acc += G[i, k] * P[9 + k, 9 + j]
            Y[i, j] = acc
    # the navigation block: A N A^T + Q first, then the cross terms
    for i in range(9):
        for j in range(9):
            acc = 0.0
            for k in range(6):
                acc += Y[i, k] * G[j, k] + G[i, k] * Z[j, k]
            Q[i, j] += acc
    _propagate_nav(P, a, dt, Et, Q, S1, S2)
    for i in range(9):
        for j in range(6):
            P[i, 9 + j] = Y[i, j]
            P[9 + j, i] = Y[i, j]
    for i in range(6):
        for j in range(6):
            P[9 + i, 9 + j] += Q[9 + i, 9 + j]


@njit(cache=True, nogil=True)
def integrate(x, P, acc, gyro, dts, bias_hat, acc_cov, gyro_cov, int_cov, bias_acc_cov,
              bias_gyro_cov, bRs, arm, has_sensor, has_arm, combined):
    """Integrate samples ``acc (n, 3)``, ``gyro (n, 3)``, ``dts (n,)`` into ``x`` and ``P`` in
    place (``P`` is 9x9, or 15x15 when ``combined``)."""
    n_state = 15 if combined else 9
    dR = np.empty((3, 3))
    E = np.empty((3, 3))
    Et = np.empty((3, 3))
    Jrw = np.empty((3, 3))
    H = np.empty((3, 3))
    DaW = np.zeros((3, 3))
    DaR = np.empty((3, 3))
    JRw = np.empty((3, 3))
    tmp = np.empty((3, 3))
    tmp2 = np.empty((3, 3))
    Q = np.zeros((n_state, n_state))
    G = np.zeros((9, 6))
    GS = np.empty((9, 6))
    S1 = np.empty((9, 9))
    S2 = np.empty((9, 9))
    Z = np.empty((9, 6))
    Y = np.empty((9, 6))
    a = np.empty(3)
    w = np.empty(3)
    ws = np.empty(3)
    wdt = np.empty(3)
    Ra = np.empty(3)
    for s in range(acc.shape[0]):
        dt = dts[s]
        for k in range(3):
            a[k] = acc[s, k] - bias_hat[k]
            ws[k] = gyro[s, k] - bias_hat[3 + k]
        if has_sensor:
            mv3(bRs, ws, w)
            mv3(bRs, a, Ra)
            for k in range(3):
                a[k] = Ra[k]
            if has_arm:
                # centrifugal acceleration of the lever arm: a -= w x (w x arm)
                wa = w[0] * arm[0] + w[1] * arm[1] + w[2] * arm[2]
                ww = w[0] * w[0] + w[1] * w[1] + w[2] * w[2]
                for k in range(3):
                    a[k] -= w[k] * wa - arm[k] * ww
                # d a / d w_sensor = -((w.arm) I + w arm^T) bRs + 2 arm ws^T
                for r in range(3):
                    for c in range(3):
                        tmp[r, c] = w[r] * arm[c]
                    tmp[r, r] += wa
                mm3(tmp, bRs, DaW)
                for r in range(3):
                    for c in range(3):
                        DaW[r, c] = -DaW[r, c] + 2.0 * arm[r] * ws[c]
        else:
            for k in range(3):
                w[k] = ws[k]
        for k in range(3):
            wdt[k] = w[k] * dt
        exp_matrix(wdt, E)
        jr_matrix(wdt, Jrw)
        for r in range(3):
            for c in range(3):
                Et[r, c] = E[c, r]
        # H = hat(a)
        H[0, 0] = H[1, 1] = H[2, 2] = 0.0
        H[0, 1], H[0, 2], H[1, 0] = -a[2], a[1], a[2]
        H[1, 2], H[2, 0], H[2, 1] = -a[0], -a[1], a[0]
        dt22 = 0.5 * dt * dt

        # ---- covariance: G = [B, C] (A is applied in factored form, _propagate_nav)
        for r in range(3):
            for c in range(3):
                e = Et[r, c]
                G[r, c] = 0.0  # B
                G[3 + r, c] = dt22 * e
                G[6 + r, c] = dt * e
                G[r, 3 + c] = Jrw[r, c] * dt  # C
                G[3 + r, 3 + c] = 0.0
                G[6 + r, 3 + c] = 0.0
        if has_sensor:
            for blk in range(3):
                for r in range(3):
                    for c in range(3):
                        tmp[r, c] = G[3 * blk + r, 3 + c]
                        tmp2[r, c] = G[3 * blk + r, c]
                mm3(tmp, bRs, JRw)  # C bRs
                for r in range(3):
                    for c in range(3):
                        G[3 * blk + r, 3 + c] = JRw[r, c]
                if has_arm:
                    mm3(tmp2, DaW, JRw)  # + B DaW
                    for r in range(3):
                        for c in range(3):
                            G[3 * blk + r, 3 + c] += JRw[r, c]
                mm3(tmp2, bRs, JRw)  # B bRs
                for r in range(3):
                    for c in range(3):
                        G[3 * blk + r, c] = JRw[r, c]
        # Q = B (Sa/dt) B^T + C (Sw/dt) C^T (+ integration and bias random walk)
        inv_dt = 1.0 / dt
        for r in range(9):
            for k in range(3):
                ga = 0.0
                gw = 0.0
                for m in range(3):
                    ga += G[r, m] * acc_cov[m, k]
                    gw += G[r, 3 + m] * gyro_cov[m, k]
                GS[r, k] = ga * inv_dt
                GS[r, 3 + k] = gw * inv_dt
        for r in range(9):
            for c in range(9):
                acc_rc = 0.0
                for k in range(6):
                    acc_rc += GS[r, k] * G[c, k]
                Q[r, c] = acc_rc
        for r in range(3):
            for c in range(3):
                Q[3 + r, 3 + c] += int_cov[r, c] * dt
        if combined:
            for r in range(3):
                for c in range(3):
                    Q[9 + r, 9 + c] = bias_acc_cov[r, c] * dt
                    Q[12 + r, 12 + c] = bias_gyro_cov[r, c] * dt
            _propagate_combined(P, a, dt, Et, G, Q, S1, S2, Z, Y)
        else:
            _propagate_nav(P, a, dt, Et, Q, S1, S2)

        # ---- bias Jacobians (with the old dR and JRw)
        _get3(x, R_, dR)
        _get3(x, JRW, JRw)
        mm3(dR, H, tmp)
        mm3(tmp, JRw, DaR)  # -d(dR a)/d b_w = dR hat(a) JRw; DaR below is its negative
        mm3(Et, JRw, tmp)
        for r in range(3):
            for c in range(3):
                idx = 3 * r + c
                x[JRW + idx] = tmp[r, c] - Jrw[r, c] * dt
                x[JPA + idx] += x[JVA + idx] * dt - dt22 * dR[r, c]
                x[JPW + idx] += x[JVW + idx] * dt - dt22 * DaR[r, c]
                x[JVA + idx] -= dR[r, c] * dt
                x[JVW + idx] -= DaR[r, c] * dt

        # ---- deltas
        mv3(dR, a, Ra)
        for k in range(3):
            x[P_ + k] += x[V_ + k] * dt + dt22 * Ra[k]
            x[V_ + k] += Ra[k] * dt
        mm3(dR, E, tmp)
        _put3(x, R_, tmp)
        x[T_] += dt


# ----------------------------------------------------------------------------- prediction


@njit(cache=True)
def coriolis_terms(omega, T, E, G1, G2):
    """Exact rotating-frame integrals for a nav frame turning at ``omega`` (rad/s):
    ``E = Exp(-omega T)``, ``G1 = int_0^T Exp(omega u) du``,
    ``G2 = int_0^T int_0^s Exp(omega u) du ds`` (3x3 each; no allocation). With ``W = hat(omega)``
    and ``t = |omega| T``: ``E = I - T s W + T^2 a W^2`` (``s = sin t / t``,
    ``a = (1 - cos t)/t^2``), ``G1 = T I + T^2 a W + T^3 b W^2`` (``b = (t - sin t)/t^3``),
    ``G2 = T^2/2 I + T^3 b W + T^4 c W^2`` (``c = (t^2/2 - 1 + cos t)/t^4``)."""
    t2 = (omega[0] * omega[0] + omega[1] * omega[1] + omega[2] * omega[2]) * T * T
    if t2 < 1e-4:  # t < 0.01: series to t^6, truncation below 1e-18
        a = 0.5 - t2 * (1.0 / 24.0 - t2 * (1.0 / 720.0 - t2 / 40320.0))
        b = 1.0 / 6.0 - t2 * (1.0 / 120.0 - t2 * (1.0 / 5040.0 - t2 / 362880.0))
        c = 1.0 / 24.0 - t2 * (1.0 / 720.0 - t2 * (1.0 / 40320.0 - t2 / 3628800.0))
    else:
        t = math.sqrt(t2)
        a = (1.0 - math.cos(t)) / t2
        b = (t - math.sin(t)) / (t2 * t)
        c = (0.5 * t2 - 1.0 + math.cos(t)) / (t2 * t2)
    sinc = 1.0 - t2 * b  # sin t / t
    T2 = T * T
    skew_poly3(omega, 1.0, -T * sinc, T2 * a, E, 0, 0)
    skew_poly3(omega, T, T2 * a, T2 * T * b, G1, 0, 0)
    skew_poly3(omega, 0.5 * T2, T2 * T * b, T2 * T2 * c, G2, 0, 0)
