"""SO(3) in rotation-matrix form for the IMU kernels (numba; 3x3 arrays written in place).

With ``W = hat(w)``, ``t = |w|``, ``a = (1 - cos t)/t^2``, ``b = (t - sin t)/t^3`` and
``c = 1/t^2 - cot(t/2)/(2t)`` (``so3_coeffs`` of :mod:`fgopt.manifolds._kernels`, with series
near 0 and no division by ``sin t`` near pi)::

    Exp(w)   = I + (1 - t^2 b) W + a W^2          Jr(w)    = I - a W + b W^2
    Jr^-1(w) = I + W/2 + c W^2                     Jl^-1(w) = I - W/2 + c W^2

``dlinv_apply`` is the derivative of ``Jl^-1(w) r`` with respect to ``w`` (needed by the
SE_2(3) Logmap residual of the IMU factors)::

    d/dw [Jl^-1(w) r] = hat(r)/2 + c ((w.r) I + w r^T - 2 r w^T) + (c'(t)/t) (w x (w x r)) w^T

``c'(t)/t`` has a removable singularity at 0 (series ``1/360 + t^2/7560 + ...`` below t = 0.1).
"""

from __future__ import annotations

import math

from .._jit import njit

from ..manifolds._kernels import quat_from_matrix, skew_poly3, so3_coeffs, so3_log


@njit(cache=True)
def hat_into(w, out):
    skew_poly3(w, 0.0, 1.0, 0.0, out, 0, 0)


@njit(cache=True)
def exp_matrix(w, out):
    """out = Exp(w) as a rotation matrix."""
    a, b, _ = so3_coeffs(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    t2 = w[0] * w[0] + w[1] * w[1] + w[2] * w[2]
    skew_poly3(w, 1.0, 1.0 - t2 * b, a, out, 0, 0)


@njit(cache=True)
def jr_matrix(w, out):
    a, b, _ = so3_coeffs(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    skew_poly3(w, 1.0, -a, b, out, 0, 0)


@njit(cache=True)
def jrinv_matrix(w, out):
    _, _, c = so3_coeffs(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    skew_poly3(w, 1.0, 0.5, c, out, 0, 0)


@njit(cache=True)
def jlinv_matrix(w, out):
    _, _, c = so3_coeffs(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    skew_poly3(w, 1.0, -0.5, c, out, 0, 0)


@njit(cache=True)
def log_matrix(r, q, out):
    """out = Log(r) of a rotation matrix (through its quaternion, accurate up to angle pi);
    ``q``: scratch of length 4."""
    quat_from_matrix(r, q)
    so3_log(q, out)


@njit(cache=True)
def _dc_over_t(t2):
    """c'(t)/t for c = 1/t^2 - cot(t/2)/(2t), at t^2 = t2."""
    if t2 < 1e-2:  # series; the next term (5.3e-9 t^8) is below 1e-24 here
        return 1.0 / 360.0 + t2 * (1.0 / 7560.0 + t2 * (1.0 / 201600.0 + t2 / 5987520.0))
    t = math.sqrt(t2)
    h = 0.5 * t
    sh = math.sin(h)
    return (-2.0 / (t2 * t) + math.cos(h) / (2.0 * t2 * sh) + 1.0 / (4.0 * t * sh * sh)) / t


@njit(cache=True)
def dlinv_apply(w, r, out):
    """out (3, 3) = d/dw [Jl^-1(w) r] (module docstring)."""
    t2 = w[0] * w[0] + w[1] * w[1] + w[2] * w[2]
    _, _, c = so3_coeffs(t2)
    k = _dc_over_t(t2)
    wr = w[0] * r[0] + w[1] * r[1] + w[2] * r[2]
    # w x (w x r) = w (w.r) - r |w|^2
    u0, u1, u2 = w[0] * wr - r[0] * t2, w[1] * wr - r[1] * t2, w[2] * wr - r[2] * t2
    for i in range(3):
        ui = u0 if i == 0 else u1 if i == 1 else u2
        for j in range(3):
            out[i, j] = c * (w[i] * r[j] - 2.0 * r[i] * w[j]) + k * ui * w[j]
        out[i, i] += c * wr
    out[0, 1] += -0.5 * r[2]
    out[0, 2] += 0.5 * r[1]
    out[1, 0] += 0.5 * r[2]
    out[1, 2] += -0.5 * r[0]
    out[2, 0] += -0.5 * r[1]
    out[2, 1] += 0.5 * r[0]


@njit(cache=True)
def mm3(a, b, out):
    """out = a @ b for 3x3 (out must not alias a or b)."""
    for i in range(3):
        for j in range(3):
            out[i, j] = a[i, 0] * b[0, j] + a[i, 1] * b[1, j] + a[i, 2] * b[2, j]


@njit(cache=True)
def mtm3(a, b, out):
    """out = a^T @ b for 3x3."""
    for i in range(3):
        for j in range(3):
            out[i, j] = a[0, i] * b[0, j] + a[1, i] * b[1, j] + a[2, i] * b[2, j]


@njit(cache=True)
def mv3(a, v, out):
    """out = a @ v (out must not alias v)."""
    for i in range(3):
        out[i] = a[i, 0] * v[0] + a[i, 1] * v[1] + a[i, 2] * v[2]


@njit(cache=True)
def mtv3(a, v, out):
    """out = a^T @ v (out must not alias v)."""
    for i in range(3):
        out[i] = a[0, i] * v[0] + a[1, i] * v[1] + a[2, i] * v[2]
