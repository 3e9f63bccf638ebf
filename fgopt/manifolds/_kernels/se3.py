"""SE(3) kernels: storage [qx, qy, qz, qw, tx, ty, tz], tangent [w(3), v(3)]; Jr block triangular with Barfoot's Q.

Part of :mod:`fgopt.manifolds._kernels` (conventions in its docstring).
"""

from __future__ import annotations

import math

from ..._jit import njit

from ._common import _cross, copy_block3, fill_block, matmul_block3, skew_poly3, skew_poly_apply
from .so3 import (
    _so3_jr_block, _so3_jrinv_block, quat_rotate, rotation_block, so3_coeffs, so3_compose,
    so3_exp, so3_inverse, so3_log,
)


@njit(cache=True)
def se3_compose(a, b, out):
    so3_compose(a, b, out)
    quat_rotate(a, b[4:7], out[4:7])
    for i in range(4, 7):
        out[i] += a[i]


@njit(cache=True)
def se3_inverse(a, out):
    so3_inverse(a, out)
    quat_rotate(a, a[4:7], out[4:7], -1.0)
    for i in range(4, 7):
        out[i] = -out[i]


@njit(cache=True)
def se3_exp(xi, out):
    so3_exp(xi, out)
    a, b, _ = so3_coeffs(xi[0] * xi[0] + xi[1] * xi[1] + xi[2] * xi[2])
    skew_poly_apply(xi, 1.0, a, b, xi[3:6], out[4:7])


@njit(cache=True)
def se3_log(x, out):
    so3_log(x, out)
    _, _, c = so3_coeffs(out[0] * out[0] + out[1] * out[1] + out[2] * out[2])
    skew_poly_apply(out, 1.0, -0.5, c, x[4:7], out[3:6])


@njit(cache=True)
def _se3_adjoint_scaled(x, out, s):
    """out[:6, :6] = [[R, 0], [hat(t) R, s R]]."""
    rotation_block(x, out, 0, 0, 1.0)
    rotation_block(x, out, 3, 3, s)
    fill_block(out, 0, 3, 3, 3, 0.0)
    for j in range(3):
        c0, c1, c2 = _cross(x[4], x[5], x[6], out[0, j], out[1, j], out[2, j])
        out[3, j], out[4, j], out[5, j] = c0, c1, c2


@njit(cache=True)
def se3_adjoint(x, out):
    """Adj = [[R, 0], [hat(t) R, R]]."""
    _se3_adjoint_scaled(x, out, 1.0)


@njit(cache=True)
def se3_ad(xi, out):
    """ad = [[W, 0], [hat(v), W]] (written into out[:6, :6])."""
    fill_block(out, 0, 3, 3, 3, 0.0)
    skew_poly3(xi, 0.0, 1.0, 0.0, out, 0, 0)
    skew_poly3(xi, 0.0, 1.0, 0.0, out, 3, 3)
    skew_poly3(xi[3:6], 0.0, 1.0, 0.0, out, 3, 0)


@njit(cache=True)
def _q_coeffs(t2):
    """Barfoot's Q coefficients ((t - sin t)/t^3, (t^2 + 2cos t - 2)/(2t^4),
    (2t - 3 sin t + t cos t)/(2t^5))."""
    if t2 < 1e-2:
        c1 = 1 / 6 - t2 * (1 / 120 - t2 * (1 / 5040 - t2 * (1 / 362880 - t2 / 39916800)))
        c2 = 1 / 24 - t2 * (1 / 720 - t2 * (1 / 40320 - t2 * (1 / 3628800 - t2 / 479001600)))
        c3 = 1 / 120 - t2 * (1 / 2520 - t2 * (1 / 120960 - t2 * (1 / 9979200 - t2 / 1245404160)))
        return c1, c2, c3
    t = math.sqrt(t2)
    s, c = math.sin(t), math.cos(t)
    return (t - s) / (t2 * t), (t2 + 2.0 * c - 2.0) / (2.0 * t2 * t2), \
        (2.0 * t - 3.0 * s + t * c) / (2.0 * t2 * t2 * t)


@njit(cache=True)
def se3_q(w0, w1, w2, p0, p1, p2, out, r, c):
    """out[r:r+3, c:c+3] = Barfoot's Q(phi=w, rho=p), the lower-left block of Jl([w, p]).

    Q = P/2 + c1 (WP + PW + WPW) + c2 (WWP + PWW - 3 WPW) + c3 (WPWW + WWPW), built column
    by column with cross products (W = hat(w), P = hat(p)).
    """
    c1, c2, c3 = _q_coeffs(w0 * w0 + w1 * w1 + w2 * w2)
    for j in range(3):
        e0, e1, e2 = (1.0 if j == 0 else 0.0), (1.0 if j == 1 else 0.0), (1.0 if j == 2 else 0.0)
        pe = _cross(p0, p1, p2, e0, e1, e2)          # P e
        we = _cross(w0, w1, w2, e0, e1, e2)          # W e
        wpe = _cross(w0, w1, w2, pe[0], pe[1], pe[2])  # WP e
        pwe = _cross(p0, p1, p2, we[0], we[1], we[2])  # PW e
        wpwe = _cross(w0, w1, w2, pwe[0], pwe[1], pwe[2])  # WPW e
        wwpe = _cross(w0, w1, w2, wpe[0], wpe[1], wpe[2])  # WWP e
        wwe = _cross(w0, w1, w2, we[0], we[1], we[2])  # WW e
        pwwe = _cross(p0, p1, p2, wwe[0], wwe[1], wwe[2])  # PWW e
        wpwwe = _cross(w0, w1, w2, pwwe[0], pwwe[1], pwwe[2])  # WPWW e
        wwpwe = _cross(w0, w1, w2, wpwe[0], wpwe[1], wpwe[2])  # WWPW e
        for i in range(3):
            out[r + i, c + j] = (0.5 * pe[i] + c1 * (wpe[i] + pwe[i] + wpwe[i])
                         + c2 * (wwpe[i] + pwwe[i] - 3.0 * wpwe[i]) + c3 * (wpwwe[i] + wwpwe[i]))


@njit(cache=True)
def se3_jr(xi, out):
    """Jr([w, v]) = [[Jr(w), 0], [Q(-w, -v), Jr(w)]]."""
    _so3_jr_block(xi, out, 0, 0)
    copy_block3(out, 0, 0, 3, 3, 1.0)
    fill_block(out, 0, 3, 3, 3, 0.0)
    se3_q(-xi[0], -xi[1], -xi[2], -xi[3], -xi[4], -xi[5], out, 3, 0)


@njit(cache=True)
def se3_jrinv(xi, out):
    """Jr^-1 = [[Ji, 0], [-Ji Q(-w, -v) Ji, Ji]] with Ji = Jr(w)^-1."""
    _so3_jrinv_block(xi, out, 0, 0)
    copy_block3(out, 0, 0, 3, 3, 1.0)
    se3_q(-xi[0], -xi[1], -xi[2], -xi[3], -xi[4], -xi[5], out, 3, 0)
    matmul_block3(out, 3, 0, 0, 0, 0, 3, 1.0)  # Q Ji, using the upper-right block as scratch
    matmul_block3(out, 0, 0, 0, 3, 3, 0, -1.0)  # -Ji (Q Ji)
    fill_block(out, 0, 3, 3, 3, 0.0)
