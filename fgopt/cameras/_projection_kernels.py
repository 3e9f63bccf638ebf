"""numba kernels of monocular and stereo projection, with tangent-space Jacobians.

A camera pose is ``world_T_camera`` stored as SE(3) ``[qx, qy, qz, qw, tx, ty, tz]``; the camera
looks along its +z axis (x right, y down: GTSAM's convention). A world point ``X`` is seen at
``p = R^T (X - t)`` and projects to the intrinsic point ``(p_x / p_z, p_y / p_z)``, then through
the calibration (:mod:`fgopt.cameras._calib_kernels`). The kernels that take a ``model`` id are
inlined into per-model entries (:func:`fgopt._jit.specialize`), as the calibration's are.

Jacobians, for the pose's right perturbation ``world_T_camera * Exp([w, v])`` (fgopt's SE3
retract; rotation first) and ``X + dX``: to first order ``p -> Exp(w)^T (p - v) = p + p x w - v``,
so ``p_D_w = hat(p)``, ``p_D_v = -I``, ``p_D_X = R^T``; then
``xy_D_p = [[1/z, 0, -x/z], [0, 1/z, -y/z]] / 1`` (with ``x, y`` already divided by ``z``) and
``uv_D_p = uv_D_xy xy_D_p``. Calibration columns are the model's ``uv_D_k``.

Cheirality: where ``p_z <= 0`` (with ``reject``) or the lens model is undefined, the status is
non-zero and the factor kernels write NaN residuals, so a trial step that moves a point behind a
camera is rejected by the optimizer and a bad initial estimate is reported by name. With
``reject=False`` (the BAL convention) only ``p_z == 0`` is undefined. A pixel that is not finite
(a depth so small that it overflows) is undefined too, and so is a calibration variable that an
optimizer step has moved outside its class's invariant (``fx <= 0``, stereo ``b <= 0``, ...:
:func:`fgopt.cameras._calib_kernels.parameters_valid`), so that step is rejected.
"""

from __future__ import annotations

import math

import numpy as np
from .._jit import njit

from . import _calib_kernels as CK
from ._calib_kernels import CAL3BUNDLER  # a bare name: numba prunes on constants

OK, BEHIND, INVALID_MODEL = 0, 1, 2


@njit(cache=True)
def quat_to_rotation(q, R):
    """Rotation matrix of the unit quaternion ``q = (x, y, z, w)``."""
    x, y, z, w = q[0], q[1], q[2], q[3]
    R[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    R[0, 1] = 2.0 * (x * y - z * w)
    R[0, 2] = 2.0 * (x * z + y * w)
    R[1, 0] = 2.0 * (x * y + z * w)
    R[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    R[1, 2] = 2.0 * (y * z - x * w)
    R[2, 0] = 2.0 * (x * z - y * w)
    R[2, 1] = 2.0 * (y * z + x * w)
    R[2, 2] = 1.0 - 2.0 * (x * x + y * y)


@njit(cache=True)
def to_camera(R, t, X, p):
    """``p = R^T (X - t)``."""
    d0, d1, d2 = X[0] - t[0], X[1] - t[1], X[2] - t[2]
    for r in range(3):
        p[r] = R[0, r] * d0 + R[1, r] * d1 + R[2, r] * d2


@njit(cache=True)
def _chain(A, p, R, J, col_pose, col_point, rows):
    """``J[:, pose] = [A hat(p), -A]`` and ``J[:, point] = A R^T`` for ``A = uv_D_p`` (rows x 3)."""
    for r in range(rows):
        a0, a1, a2 = A[r, 0], A[r, 1], A[r, 2]
        if col_pose >= 0:
            J[r, col_pose + 0] = a1 * p[2] - a2 * p[1]
            J[r, col_pose + 1] = -a0 * p[2] + a2 * p[0]
            J[r, col_pose + 2] = a0 * p[1] - a1 * p[0]
            J[r, col_pose + 3] = -a0
            J[r, col_pose + 4] = -a1
            J[r, col_pose + 5] = -a2
        if col_point >= 0:
            for c in range(3):
                J[r, col_point + c] = a0 * R[c, 0] + a1 * R[c, 1] + a2 * R[c, 2]


@njit(cache=True)
def scratch():
    """Work arrays of :func:`project_core`: ``p (3)``, ``Dk (2 x MAX_TANGENT_DIM)`` (zeros:
    columns past a model's tangent dimension stay 0), ``Dp (2 x 2)``, ``A (2 x 3)``."""
    return np.empty(3), np.zeros((2, CK.MAX_TANGENT_DIM)), np.empty((2, 2)), np.empty((2, 3))


@njit(cache=True, inline="always")
def project_core(model, R, t, k, X, reject, with_jac, uv, p, Dk, Dp, A):
    """Pixel ``uv`` of world point ``X``; fills ``p`` (camera frame), and with ``with_jac`` the
    model's ``Dk``, ``Dp`` and ``A = uv_D_p`` (2 x 3). Returns a status code."""
    to_camera(R, t, X, p)
    z = p[2]
    if (reject and not z > 0.0) or z == 0.0:
        return BEHIND
    iz = 1.0 / z
    x, y = p[0] * iz, p[1] * iz
    if not CK.uncalibrate(model, k, x, y, uv, Dk, Dp, with_jac):
        return INVALID_MODEL
    if with_jac:
        for r in range(2):
            A[r, 0] = Dp[r, 0] * iz
            A[r, 1] = Dp[r, 1] * iz
            A[r, 2] = -(Dp[r, 0] * x + Dp[r, 1] * y) * iz
    return OK


@njit(cache=True, nogil=True, inline="always")  # threads=N: chunks in parallel
def projection_batch(model, pose, point, cal, m, reject, cal_var, with_jac):
    """Reprojection errors ``uv(pose_i, point_i, cal_i) - m_i``.

    ``pose (n, 7)``, ``point (n, 3)``, ``cal (n, s)``, ``m (n, 2)`` -> res ``(n, 2)`` and jac
    ``(n, 2, 9 [+ dim])``: columns pose ``[w, v]``, point, then the calibration's tangent when
    ``cal_var``. Undefined projections give NaN residuals (see the module docstring).
    """
    if model == CAL3BUNDLER:
        return _bundler_batch(pose, cal, 0, point, m, reject, cal_var, with_jac,
                              9 if cal_var else -1, 6, 12 if cal_var else 9)
    n = pose.shape[0]
    d = CK.tangent_dim(model)
    ncol = 9 + (d if cal_var else 0)
    res = np.empty((n, 2))
    jac = np.zeros((n if with_jac else 0, 2, ncol))
    R = np.empty((3, 3))
    uv = np.empty(2)
    p, Dk, Dp, A = scratch()
    for i in range(n):
        k = cal[i]
        # a constant calibration was checked when it was built; a variable one is checked here
        if cal_var and not CK.parameters_valid(model, k):
            st = INVALID_MODEL
        else:
            quat_to_rotation(pose[i, :4], R)
            st = project_core(model, R, pose[i, 4:7], k, point[i], reject, with_jac, uv, p, Dk,
                              Dp, A)
        if st != OK:
            res[i, 0] = np.nan
            res[i, 1] = np.nan
            continue
        res[i, 0] = uv[0] - m[i, 0]
        res[i, 1] = uv[1] - m[i, 1]
        if with_jac:
            J = jac[i]
            _chain(A, p, R, J, 0, 6, 2)
            if cal_var:
                for r in range(2):
                    for c in range(d):
                        J[r, 9 + c] = Dk[r, c]
    return res, jac


@njit(cache=True, inline="always")
def project_points(model, R, t, k, X, reject, with_jac):
    """One camera, many points ``X (n, 3)``: ``uv (n, 2)``, ``uv_D_pose (n, 2, 6)``,
    ``uv_D_point (n, 2, 3)``, ``uv_D_k (n, 2, dim)``, ``status (n,)``."""
    n = X.shape[0]
    d = CK.tangent_dim(model)
    m = n if with_jac else 0
    uv = np.empty((n, 2))
    Jpose = np.zeros((m, 2, 6))
    Jpoint = np.zeros((m, 2, 3))
    Jk = np.zeros((m, 2, d))
    status = np.empty(n, dtype=np.int64)
    p, Dk, Dp, A = scratch()
    J = np.empty((2, 9))
    for i in range(n):
        st = project_core(model, R, t, k, X[i], reject, with_jac, uv[i], p, Dk, Dp, A)
        status[i] = st
        if st != OK:
            uv[i, 0] = np.nan
            uv[i, 1] = np.nan
            continue
        if with_jac:
            _chain(A, p, R, J, 0, 6, 2)
            for r in range(2):
                for c in range(6):
                    Jpose[i, r, c] = J[r, c]
                for c in range(3):
                    Jpoint[i, r, c] = J[r, 6 + c]
                for c in range(d):
                    Jk[i, r, c] = Dk[r, c]
    return uv, Jpose, Jpoint, Jk, status


@njit(cache=True)
def stereo_core(R, t, k, X, reject, with_jac, out, p, A, Jk):
    """``out = (uL, uR, v)`` of world point ``X`` for ``Cal3_S2Stereo`` ``k``; ``A = out_D_p``
    (3 x 3) and ``Jk = out_D_k`` (3 x 6) with ``with_jac``. Skew is ignored, as in GTSAM's
    ``StereoCamera``. Returns a status code."""
    to_camera(R, t, X, p)
    z = p[2]
    if (reject and not z > 0.0) or z == 0.0:
        return BEHIND
    fx, fy, u0, v0, b = k[0], k[1], k[3], k[4], k[5]
    iz = 1.0 / z
    x, y = p[0], p[1]
    out[0] = u0 + fx * x * iz
    out[1] = u0 + fx * (x - b) * iz
    out[2] = v0 + fy * y * iz
    if not (math.isfinite(out[0]) and math.isfinite(out[1]) and math.isfinite(out[2])):
        return INVALID_MODEL  # overflow at a tiny depth: no measurement, not an inf residual
    if with_jac:
        iz2 = iz * iz
        A[0, 0], A[0, 1], A[0, 2] = fx * iz, 0.0, -fx * x * iz2
        A[1, 0], A[1, 1], A[1, 2] = fx * iz, 0.0, -fx * (x - b) * iz2
        A[2, 0], A[2, 1], A[2, 2] = 0.0, fy * iz, -fy * y * iz2
        for r in range(3):
            for c in range(6):
                Jk[r, c] = 0.0
        Jk[0, 0], Jk[0, 3] = x * iz, 1.0
        Jk[1, 0], Jk[1, 3], Jk[1, 5] = (x - b) * iz, 1.0, -fx * iz
        Jk[2, 1], Jk[2, 4] = y * iz, 1.0
    return OK


@njit(cache=True, nogil=True)  # threads=N runs chunks in parallel
def stereo_batch(pose, point, cal, m, reject, cal_var, with_jac):
    """Stereo errors ``(uL, uR, v)(pose_i, point_i, cal_i) - m_i``: res ``(n, 3)``, jac
    ``(n, 3, 9 [+ 6])`` (pose, point, then the calibration when ``cal_var``)."""
    n = pose.shape[0]
    ncol = 15 if cal_var else 9
    res = np.empty((n, 3))
    jac = np.zeros((n if with_jac else 0, 3, ncol))
    R = np.empty((3, 3))
    out = np.empty(3)
    p = np.empty(3)
    A = np.empty((3, 3))
    Jk = np.empty((3, 6))
    for i in range(n):
        k = cal[i]
        if cal_var and not CK.parameters_valid(CK.CAL3_S2STEREO, k):
            st = INVALID_MODEL
        else:
            quat_to_rotation(pose[i, :4], R)
            st = stereo_core(R, pose[i, 4:7], k, point[i], reject, with_jac, out, p, A, Jk)
        if st != OK:
            for r in range(3):
                res[i, r] = np.nan
            continue
        for r in range(3):
            res[i, r] = out[r] - m[i, r]
        if with_jac:
            J = jac[i]
            _chain(A, p, R, J, 0, 6, 3)
            if cal_var:
                for r in range(3):
                    for c in range(6):
                        J[r, 9 + c] = Jk[r, c]
    return res, jac


@njit(cache=True)
def stereo_points(R, t, k, X, reject, with_jac):
    """One stereo camera, many points: ``out (n, 3)``, ``out_D_pose (n, 3, 6)``,
    ``out_D_point (n, 3, 3)``, ``out_D_k (n, 3, 6)``, ``status (n,)``."""
    n = X.shape[0]
    m = n if with_jac else 0
    out = np.empty((n, 3))
    Jpose = np.zeros((m, 3, 6))
    Jpoint = np.zeros((m, 3, 3))
    Jk6 = np.zeros((m, 3, 6))
    status = np.empty(n, dtype=np.int64)
    p = np.empty(3)
    A = np.empty((3, 3))
    Jk = np.empty((3, 6))
    J = np.empty((3, 9))
    for i in range(n):
        st = stereo_core(R, t, k, X[i], reject, with_jac, out[i], p, A, Jk)
        status[i] = st
        if st != OK:
            for r in range(3):
                out[i, r] = np.nan
            continue
        if with_jac:
            _chain(A, p, R, J, 0, 6, 3)
            for r in range(3):
                for c in range(6):
                    Jpose[i, r, c] = J[r, c]
                    Jk6[i, r, c] = Jk[r, c]
                for c in range(3):
                    Jpoint[i, r, c] = J[r, 6 + c]
    return out, Jpose, Jpoint, Jk6, status


@njit(cache=True)
def rotation_of_storage(pose):
    R = np.empty((3, 3))
    quat_to_rotation(pose[:4], R)
    return R



@njit(cache=True, nogil=True, inline="always")  # threads=N: chunks in parallel
def camera_projection_batch(model, cam, point, m, reject, with_jac):
    """Reprojection errors with one camera variable per observation: ``cam (n, 7 + s)`` =
    pose storage then calibration storage (GTSAM's ``PinholeCamera<Cal>`` manifold) -> res
    ``(n, 2)``, jac ``(n, 2, 6 + dim + 3)``: columns pose ``[w, v]``, calibration, point."""
    if model == CAL3BUNDLER:  # the camera's calibration follows its pose in its storage
        return _bundler_batch(cam, cam, 7, point, m, reject, True, with_jac, 6, 9, 12)
    n = cam.shape[0]
    d = CK.tangent_dim(model)
    res = np.empty((n, 2))
    jac = np.zeros((n if with_jac else 0, 2, 9 + d))
    R = np.empty((3, 3))
    uv = np.empty(2)
    p, Dk, Dp, A = scratch()
    for i in range(n):
        k = cam[i, 7:]
        if not CK.parameters_valid(model, k):  # the camera is a variable
            st = INVALID_MODEL
        else:
            quat_to_rotation(cam[i, :4], R)
            st = project_core(model, R, cam[i, 4:7], k, point[i], reject, with_jac, uv, p, Dk,
                              Dp, A)
        if st != OK:
            res[i, 0] = np.nan
            res[i, 1] = np.nan
            continue
        res[i, 0] = uv[0] - m[i, 0]
        res[i, 1] = uv[1] - m[i, 1]
        if with_jac:
            J = jac[i]
            _chain(A, p, R, J, 0, 6 + d, 2)
            for r in range(2):
                for c in range(d):
                    J[r, 6 + c] = Dk[r, c]
    return res, jac


@njit(cache=True, nogil=True)
def _bundler_batch(pose, cal, cal_col, point, m, reject, check_cal, with_jac, col_cal, col_point,
                   ncol):
    """:func:`projection_batch` / :func:`camera_projection_batch` for ``Cal3Bundler`` (BAL's
    model), the same numbers from scalar code: no work arrays or views per observation, so
    everything stays in registers (Ladybug-49's 31,843 observations in the camera form: 12 ms
    -> 1.4 ms; the per-model loop's calls and small arrays cost ~330 ns an observation).

    ``pose[i, :7]`` is observation ``i``'s pose storage, ``cal[i, cal_col:cal_col + 5]`` its
    calibration (the camera form passes its camera rows as both). Jacobian ``(n, 2, ncol)``:
    pose ``[w, v]`` in columns 0-5, the point at ``col_point``, the calibration's
    ``(f, k1, k2)`` at ``col_cal`` (``-1``: constant). Same statuses as the per-model loop:
    ``f <= 0`` or NaN (``check_cal``: a calibration the optimizer moves), a point at depth 0
    (or behind, with ``reject``) and a non-finite pixel give NaN residuals and zero Jacobian
    rows."""
    n = pose.shape[0]
    res = np.empty((n, 2))
    jac = np.zeros((n if with_jac else 0, 2, ncol))
    for i in range(n):
        qx, qy, qz, qw = pose[i, 0], pose[i, 1], pose[i, 2], pose[i, 3]
        f, k1, k2 = cal[i, cal_col], cal[i, cal_col + 1], cal[i, cal_col + 2]
        u0, v0 = cal[i, cal_col + 3], cal[i, cal_col + 4]
        # R of the quaternion (quat_to_rotation), p = R^T (X - t) (to_camera)
        r00 = 1.0 - 2.0 * (qy * qy + qz * qz)
        r01 = 2.0 * (qx * qy - qz * qw)
        r02 = 2.0 * (qx * qz + qy * qw)
        r10 = 2.0 * (qx * qy + qz * qw)
        r11 = 1.0 - 2.0 * (qx * qx + qz * qz)
        r12 = 2.0 * (qy * qz - qx * qw)
        r20 = 2.0 * (qx * qz - qy * qw)
        r21 = 2.0 * (qy * qz + qx * qw)
        r22 = 1.0 - 2.0 * (qx * qx + qy * qy)
        d0, d1, d2 = point[i, 0] - pose[i, 4], point[i, 1] - pose[i, 5], point[i, 2] - pose[i, 6]
        p0 = r00 * d0 + r10 * d1 + r20 * d2
        p1 = r01 * d0 + r11 * d1 + r21 * d2
        p2 = r02 * d0 + r12 * d1 + r22 * d2
        if (check_cal and not f > 0.0) or (reject and not p2 > 0.0) or p2 == 0.0:
            res[i, 0] = np.nan
            res[i, 1] = np.nan
            continue
        iz = 1.0 / p2
        x, y = p0 * iz, p1 * iz
        r = x * x + y * y
        g = 1.0 + (k1 + k2 * r) * r
        u, v = u0 + f * g * x, v0 + f * g * y
        if not (math.isfinite(u) and math.isfinite(v)):
            res[i, 0] = np.nan
            res[i, 1] = np.nan
            continue
        res[i, 0] = u - m[i, 0]
        res[i, 1] = v - m[i, 1]
        if not with_jac:
            continue
        a = 2.0 * (k1 + 2.0 * k2 * r)
        e01 = f * a * x * y  # uv_D_xy is symmetric
        for row in range(2):
            if row == 0:
                e0, e1, c = f * (g + a * x * x), e01, x
            else:
                e0, e1, c = e01, f * (g + a * y * y), y
            # A = uv_D_p, then [A hat(p), -A], A R^T and uv_D_k (_chain, _bundler)
            a0, a1, a2 = e0 * iz, e1 * iz, -(e0 * x + e1 * y) * iz
            J = jac[i, row]
            J[0] = a1 * p2 - a2 * p1
            J[1] = -a0 * p2 + a2 * p0
            J[2] = a0 * p1 - a1 * p0
            J[3] = -a0
            J[4] = -a1
            J[5] = -a2
            J[col_point] = a0 * r00 + a1 * r01 + a2 * r02
            J[col_point + 1] = a0 * r10 + a1 * r11 + a2 * r12
            J[col_point + 2] = a0 * r20 + a1 * r21 + a2 * r22
            if col_cal >= 0:
                J[col_cal] = g * c
                J[col_cal + 1] = f * r * c
                J[col_cal + 2] = f * r * r * c
    return res, jac
