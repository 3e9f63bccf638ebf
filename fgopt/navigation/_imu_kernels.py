"""Batched numba kernels of ``ImuFactor``, ``CombinedImuFactor`` and ``GpsFactor`` (hand-written
residuals and tangent-space Jacobians).

**Prediction** (GTSAM's ``PreintegrationBase::predict`` with exact rotating-frame dynamics).
With ``db = b_i - b_hat`` and the first-order bias correction of the preintegrated deltas::

    dRc = dR Exp(JRw db_w)     dpc = dp + Jpa db_a + Jpw db_w     dvc = dv + Jva db_a + Jvw db_w

a navigation frame turning at ``omega`` (Coriolis; 0 by default), ``E = Exp(-omega T)``,
``G1 = int_0^T Exp(omega u) du``, ``G2 = int_0^T int_0^s Exp(omega u) du ds`` and gravity ``g``::

    R^ = E Ri dRc
    p^ = E (pi + T vi + T omega x pi + Ri dpc + G2 g)
    v^ = E (vi + omega x pi + Ri dvc + G1 g) - omega x p^

(at omega = 0: ``p^ = pi + T vi + g T^2/2 + Ri dpc``, ``v^ = vi + g T + Ri dvc``).

**Residual** against state j, component-wise (GTSAM's ``localCoordinates``)::

    phi = Log(Rj^T R^),  rp = Rj^T (p^ - pj),  rv = Rj^T (v^ - vj)

and in GTSAM 4.3's default ``Logmap`` mode the SE_2(3) logarithm of ``X_j^-1 X^``:
``[phi, Jl^-1(phi) rp, Jl^-1(phi) rv]``. ``CombinedImuFactor`` appends ``b_i - b_j`` (GTSAM's sign).

**Jacobians** (right perturbations ``R Exp(d)``, ``p + R dt`` of the SE(3) poses, additive
velocities and biases). A perturbation enters ``R^`` as ``R^ Exp(eta)`` and moves ``p^``, ``v^``
by ``dp^``, ``dv^``; then ``d phi = Jr^-1(phi) eta``, ``d rp = Rj^T dp^``, ``d rv = Rj^T dv^``:

    pose_i rotation:   eta = dRc^T          dp^ = -E Ri hat(dpc)        dv^ = -E Ri hat(dvc) - W dp^
    pose_i position:   eta = 0              dp^ = E (I + T W) Ri        dv^ = E W Ri - W dp^
    vel_i:             eta = 0              dp^ = T E                   dv^ = E - W dp^
    bias_a:            eta = 0              dp^ = E Ri Jpa              dv^ = E Ri Jva - W dp^
    bias_w:            eta = Jr(JRw db_w) JRw, dp^ = E Ri Jpw           dv^ = E Ri Jvw - W dp^

with ``W = hat(omega)``; for state j: ``d phi/d rot_j = -Jl^-1(phi)``, ``d rp/d rot_j =
hat(rp)``, ``d rp/d pos_j = -I``, ``d rv/d rot_j = hat(rv)``, ``d rv/d vel_j = -Rj^T``. The
Logmap rows are ``d(Jl^-1(phi) r) = Jl^-1(phi) dr + [d/dphi Jl^-1(phi) r] dphi``.

The batch entries release the GIL (``threads=N`` linearizes chunks in parallel). The helpers
are plain calls, not numba IR inlining (``inline='always'``): inlined, ``imu_batch`` took 54 s of
CPU to compile on a fresh install, called ~4 s (the IMU example's first use 124 -> 74 s CPU), at
~0.4 us more per factor warm.

Constants row of an IMU factor (``PIM_CONSTANTS`` floats, :func:`pack_constants`):
``dR (9, row-major), dp, dv, T, JRw, Jpa, Jpw, Jva, Jvw (9 each), b_hat (6), g (3), omega (3),
logmap flag``. ``GpsFactor``: ``e = t + R arm - m``, constants ``[m, arm]``.
"""

from __future__ import annotations

import numpy as np
from .._jit import njit

from ..manifolds._kernels import rotation_block
from ._preint_kernels import JPA, JPW, JRW, JVA, JVW, P_, R_, T_, V_, coriolis_terms
from ._so3_matrix import (
    dlinv_apply,
    exp_matrix,
    jlinv_matrix,
    jr_matrix,
    jrinv_matrix,
    log_matrix,
    mm3,
    mtm3,
    mtv3,
    mv3,
)

# constants layout: the preintegrated state (same offsets as the packed state), then these
C_BHAT, C_G, C_OMEGA, C_MODE = 61, 67, 70, 73
PIM_CONSTANTS = 74

# scratch 3x3 matrices / 3-vectors of one evaluation (indices into S / s)
(S_RI, S_RJ, S_DR, S_E, S_G1, S_G2, S_W, S_ERI, S_RHAT, S_RE, S_JRINV, S_JLINV, S_T1, S_T2,
 S_T3, S_JRU, S_JRW, S_DRC, S_DP, S_DV, S_ETA, S_D1, S_D2, S_M) = range(24)
N_S = 24
(v_DPC, v_DVC, v_U, v_SP, v_SV, v_PH, v_VH, v_PHI, v_RP, v_RV, v_T1, v_T2, v_Q) = range(13)
N_V = 13


def pack_constants(state: np.ndarray, bias_hat: np.ndarray, gravity: np.ndarray,
                   omega: np.ndarray, logmap: bool) -> np.ndarray:
    """The constants row of an IMU factor from a packed preintegrated state (61 floats)."""
    c = np.empty(PIM_CONSTANTS)
    c[:61] = state
    c[C_BHAT:C_BHAT + 6] = bias_hat
    c[C_G:C_G + 3] = gravity
    c[C_OMEGA:C_OMEGA + 3] = omega
    c[C_MODE] = 1.0 if logmap else 0.0
    return c


@njit(cache=True)
def _get3(c, off, m):
    for i in range(3):
        for j in range(3):
            m[i, j] = c[off + 3 * i + j]


@njit(cache=True)
def _hat(v, m):
    m[0, 0] = m[1, 1] = m[2, 2] = 0.0
    m[0, 1], m[0, 2], m[1, 0] = -v[2], v[1], v[2]
    m[1, 2], m[2, 0], m[2, 1] = -v[0], -v[1], v[0]


@njit(cache=True)
def predict(Ri, pi, vi, b, c, S, s):
    """The prediction of the module docstring into ``S[S_RHAT]``, ``s[v_PH]``, ``s[v_VH]``
    (intermediates stay in ``S`` / ``s`` for the Jacobians)."""
    T = c[T_]
    _get3(c, R_, S[S_DR])
    _get3(c, JRW, S[S_T1])
    for k in range(3):
        s[v_T1][k] = b[3 + k] - c[C_BHAT + 3 + k]  # db_w
        s[v_T2][k] = b[k] - c[C_BHAT + k]  # db_a
    mv3(S[S_T1], s[v_T1], s[v_U])  # u = JRw db_w
    exp_matrix(s[v_U], S[S_T2])
    mm3(S[S_DR], S[S_T2], S[S_DRC])
    for k in range(3):
        dpc = c[P_ + k]
        dvc = c[V_ + k]
        for m in range(3):
            dpc += c[JPA + 3 * k + m] * s[v_T2][m] + c[JPW + 3 * k + m] * s[v_T1][m]
            dvc += c[JVA + 3 * k + m] * s[v_T2][m] + c[JVW + 3 * k + m] * s[v_T1][m]
        s[v_DPC][k] = dpc
        s[v_DVC][k] = dvc
    om = c[C_OMEGA:C_OMEGA + 3]
    coriolis_terms(om, T, S[S_E], S[S_G1], S[S_G2])
    _hat(om, S[S_W])
    mm3(S[S_E], Ri, S[S_ERI])
    mm3(S[S_ERI], S[S_DRC], S[S_RHAT])
    g = c[C_G:C_G + 3]
    mv3(Ri, s[v_DPC], s[v_T1])
    mv3(S[S_G2], g, s[v_T2])
    wp0 = om[1] * pi[2] - om[2] * pi[1]
    wp1 = om[2] * pi[0] - om[0] * pi[2]
    wp2 = om[0] * pi[1] - om[1] * pi[0]
    s[v_SP][0] = pi[0] + T * vi[0] + T * wp0 + s[v_T1][0] + s[v_T2][0]
    s[v_SP][1] = pi[1] + T * vi[1] + T * wp1 + s[v_T1][1] + s[v_T2][1]
    s[v_SP][2] = pi[2] + T * vi[2] + T * wp2 + s[v_T1][2] + s[v_T2][2]
    mv3(S[S_E], s[v_SP], s[v_PH])
    mv3(Ri, s[v_DVC], s[v_T1])
    mv3(S[S_G1], g, s[v_T2])
    s[v_SV][0] = vi[0] + wp0 + s[v_T1][0] + s[v_T2][0]
    s[v_SV][1] = vi[1] + wp1 + s[v_T1][1] + s[v_T2][1]
    s[v_SV][2] = vi[2] + wp2 + s[v_T1][2] + s[v_T2][2]
    mv3(S[S_E], s[v_SV], s[v_VH])
    ph = s[v_PH]
    s[v_VH][0] -= om[1] * ph[2] - om[2] * ph[1]
    s[v_VH][1] -= om[2] * ph[0] - om[0] * ph[2]
    s[v_VH][2] -= om[0] * ph[1] - om[1] * ph[0]


@njit(cache=True)
def _put(J, r0, c0, m, scale):
    for i in range(3):
        for j in range(3):
            J[r0 + i, c0 + j] = scale * m[i, j]


@njit(cache=True)
def _columns(J, col, eta_zero, S, Rj):
    """Fill the 9 rows of one 3-column block from ``S[S_ETA]`` (unless ``eta_zero``),
    ``S[S_DP]`` = dp^ and ``S[S_DV]`` = dv^ (``dv^`` gets ``- W dp^`` here)."""
    mm3(S[S_W], S[S_DP], S[S_T1])
    for i in range(3):
        for j in range(3):
            S[S_DV][i, j] -= S[S_T1][i, j]
    if eta_zero:
        for i in range(3):
            for j in range(3):
                J[i, col + j] = 0.0
    else:
        mm3(S[S_JRINV], S[S_ETA], S[S_T1])
        _put(J, 0, col, S[S_T1], 1.0)
    mtm3(Rj, S[S_DP], S[S_T1])
    _put(J, 3, col, S[S_T1], 1.0)
    mtm3(Rj, S[S_DV], S[S_T1])
    _put(J, 6, col, S[S_T1], 1.0)


@njit(cache=True)
def imu_rows(pose_i, vi, pose_j, vj, b, c, res, J, with_jac, S, s, Ri, Rj):
    """Residual ``res[:9]`` and, if ``with_jac``, Jacobian columns 0..23 of ``J`` (pose_i,
    vel_i, pose_j, vel_j, bias_i) of one IMU factor."""
    rotation_block(pose_i, Ri, 0, 0, 1.0)
    rotation_block(pose_j, Rj, 0, 0, 1.0)
    pi = pose_i[4:7]
    pj = pose_j[4:7]
    predict(Ri, pi, vi, b, c, S, s)
    mtm3(Rj, S[S_RHAT], S[S_RE])
    log_matrix(S[S_RE], s[v_Q], s[v_PHI])
    for k in range(3):
        s[v_T1][k] = s[v_PH][k] - pj[k]
        s[v_T2][k] = s[v_VH][k] - vj[k]
    mtv3(Rj, s[v_T1], s[v_RP])
    mtv3(Rj, s[v_T2], s[v_RV])
    logmap = c[C_MODE] != 0.0
    phi = s[v_PHI]
    for k in range(3):
        res[k] = phi[k]
    if logmap:
        jlinv_matrix(phi, S[S_JLINV])
        mv3(S[S_JLINV], s[v_RP], s[v_T1])
        mv3(S[S_JLINV], s[v_RV], s[v_T2])
        for k in range(3):
            res[3 + k] = s[v_T1][k]
            res[6 + k] = s[v_T2][k]
    else:
        for k in range(3):
            res[3 + k] = s[v_RP][k]
            res[6 + k] = s[v_RV][k]
    if not with_jac:
        return
    T = c[T_]
    jrinv_matrix(phi, S[S_JRINV])
    if not logmap:
        jlinv_matrix(phi, S[S_JLINV])
    # pose_i rotation
    for i in range(3):
        for j in range(3):
            S[S_ETA][i, j] = S[S_DRC][j, i]
    _hat(s[v_DPC], S[S_T2])
    mm3(S[S_ERI], S[S_T2], S[S_DP])
    _hat(s[v_DVC], S[S_T2])
    mm3(S[S_ERI], S[S_T2], S[S_DV])
    for i in range(3):
        for j in range(3):
            S[S_DP][i, j] = -S[S_DP][i, j]
            S[S_DV][i, j] = -S[S_DV][i, j]
    _columns(J, 0, False, S, Rj)
    # pose_i position: dp^ = E (I + T W) Ri, dv^ = E W Ri
    mm3(S[S_W], Ri, S[S_T2])
    mm3(S[S_E], S[S_T2], S[S_DV])
    for i in range(3):
        for j in range(3):
            S[S_DP][i, j] = S[S_ERI][i, j] + T * S[S_DV][i, j]
    _columns(J, 3, True, S, Rj)
    # vel_i: dp^ = T E, dv^ = E
    for i in range(3):
        for j in range(3):
            S[S_DP][i, j] = T * S[S_E][i, j]
            S[S_DV][i, j] = S[S_E][i, j]
    _columns(J, 6, True, S, Rj)
    # bias_a
    _get3(c, JPA, S[S_T2])
    mm3(S[S_ERI], S[S_T2], S[S_DP])
    _get3(c, JVA, S[S_T2])
    mm3(S[S_ERI], S[S_T2], S[S_DV])
    _columns(J, 18, True, S, Rj)
    # bias_w
    jr_matrix(s[v_U], S[S_JRU])
    _get3(c, JRW, S[S_T2])
    mm3(S[S_JRU], S[S_T2], S[S_ETA])
    _get3(c, JPW, S[S_T2])
    mm3(S[S_ERI], S[S_T2], S[S_DP])
    _get3(c, JVW, S[S_T2])
    mm3(S[S_ERI], S[S_T2], S[S_DV])
    _columns(J, 21, False, S, Rj)
    # state j
    rp, rv = s[v_RP], s[v_RV]
    for i in range(9):
        for j in range(9, 18):
            J[i, j] = 0.0
    _put(J, 0, 9, S[S_JLINV], -1.0)
    J[3, 10], J[3, 11], J[4, 9] = -rp[2], rp[1], rp[2]
    J[4, 11], J[5, 9], J[5, 10] = -rp[0], -rp[1], rp[0]
    J[6, 10], J[6, 11], J[7, 9] = -rv[2], rv[1], rv[2]
    J[7, 11], J[8, 9], J[8, 10] = -rv[0], -rv[1], rv[0]
    J[3, 12] = J[4, 13] = J[5, 14] = -1.0
    for i in range(3):
        for j in range(3):
            J[6 + i, 15 + j] = -Rj[j, i]
    if logmap:
        _logmap_rows(J, 1, phi, rp, S)
        _logmap_rows(J, 2, phi, rv, S)


@njit(cache=True)
def _logmap_rows(J, blk, phi, r, S):
    """Rows ``3 blk .. 3 blk + 2`` of J <- Jl^-1(phi) (those rows) + d/dphi[Jl^-1(phi) r] J[0:3]."""
    L = S[S_JLINV]
    D = S[S_D1]
    dlinv_apply(phi, r, D)
    for j in range(J.shape[1]):
        x0, x1, x2 = J[3 * blk, j], J[3 * blk + 1, j], J[3 * blk + 2, j]
        p0, p1, p2 = J[0, j], J[1, j], J[2, j]
        for i in range(3):
            J[3 * blk + i, j] = (L[i, 0] * x0 + L[i, 1] * x1 + L[i, 2] * x2
                                 + D[i, 0] * p0 + D[i, 1] * p1 + D[i, 2] * p2)


@njit(cache=True, nogil=True)
def imu_batch(pose_i, vel_i, pose_j, vel_j, bias_i, consts, with_jac):
    """``ImuFactor`` residuals ``(n, 9)`` and Jacobians ``(n, 9, 24)``."""
    n = pose_i.shape[0]
    res = np.empty((n, 9))
    jac = np.empty((n if with_jac else 0, 9, 24))
    S = np.empty((N_S, 3, 3))
    s = np.empty((N_V, 4))
    Ri = np.empty((3, 3))
    Rj = np.empty((3, 3))
    Jd = np.empty((9, 24))
    for f in range(n):
        imu_rows(pose_i[f], vel_i[f], pose_j[f], vel_j[f], bias_i[f], consts[f], res[f],
                 jac[f] if with_jac else Jd, with_jac, S, s, Ri, Rj)
    return res, jac


@njit(cache=True, nogil=True)
def combined_batch(pose_i, vel_i, pose_j, vel_j, bias_i, bias_j, consts, with_jac):
    """``CombinedImuFactor`` residuals ``(n, 15)`` and Jacobians ``(n, 15, 30)``: the IMU rows
    from :func:`imu_batch` (one compiled copy of the rows), then the bias rows."""
    n = pose_i.shape[0]
    r9, j9 = imu_batch(pose_i, vel_i, pose_j, vel_j, bias_i, consts, with_jac)
    res = np.empty((n, 15))
    jac = np.zeros((n if with_jac else 0, 15, 30))
    for f in range(n):
        for k in range(9):
            res[f, k] = r9[f, k]
        for k in range(6):
            res[f, 9 + k] = bias_i[f, k] - bias_j[f, k]  # GTSAM's Between(bias_j, bias_i)
        if with_jac:
            for i in range(9):
                for j in range(24):
                    jac[f, i, j] = j9[f, i, j]
            for k in range(6):
                jac[f, 9 + k, 18 + k] = 1.0
                jac[f, 9 + k, 24 + k] = -1.0
    return res, jac


@njit(cache=True)
def predict_state(pose_i, vi, b, c):
    """``(R^ (3, 3), p^, v^)`` for state ``pose_i`` (SE3 storage), ``vi`` and bias ``b``."""
    S = np.empty((N_S, 3, 3))
    s = np.empty((N_V, 4))
    Ri = np.empty((3, 3))
    rotation_block(pose_i, Ri, 0, 0, 1.0)
    predict(Ri, pose_i[4:7], vi, b, c, S, s)
    return S[S_RHAT].copy(), s[v_PH][:3].copy(), s[v_VH][:3].copy()


@njit(cache=True, nogil=True)
def gps_batch(pose, consts, with_jac):
    """``GpsFactor`` residuals ``t + R arm - m`` ``(n, 3)`` and Jacobians ``(n, 3, 6)``
    (``[-R hat(arm), R]``)."""
    n = pose.shape[0]
    res = np.empty((n, 3))
    jac = np.empty((n if with_jac else 0, 3, 6))
    R = np.empty((3, 3))
    for f in range(n):
        rotation_block(pose[f], R, 0, 0, 1.0)
        a0, a1, a2 = consts[f, 3], consts[f, 4], consts[f, 5]
        for i in range(3):
            res[f, i] = (pose[f, 4 + i] + R[i, 0] * a0 + R[i, 1] * a1 + R[i, 2] * a2
                         - consts[f, i])
        if with_jac:
            J = jac[f]
            for i in range(3):
                # -R hat(arm): column k of hat(arm) is arm x e_k
                J[i, 0] = -(R[i, 1] * a2 - R[i, 2] * a1)
                J[i, 1] = -(R[i, 2] * a0 - R[i, 0] * a2)
                J[i, 2] = -(R[i, 0] * a1 - R[i, 1] * a0)
                for k in range(3):
                    J[i, 3 + k] = R[i, k]
    return res, jac
