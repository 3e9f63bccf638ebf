"""numba kernels of the calibration models: ``uncalibrate`` / ``calibrate`` and their Jacobians.

One function per operation dispatches on an integer model id (like the Lie-group kernels'
group ids). The dispatchers and the kernels that pass the id on are inlined (numba IR), and
Python calls them through :func:`fgopt._jit.specialize`: an entry per model whose constant id
prunes the other models' branches before numba types them, so a problem compiles its own
model's code only.
Parameter vectors are GTSAM's ``vector()`` order, stored as given to the constructors:

=================  ==============================  ===  ==================================
model              storage                         dim  notes
=================  ==============================  ===  ==================================
``CAL3_S2``        fx fy s u0 v0                   5
``CAL3DS2``        fx fy s u0 v0 k1 k2 p1 p2       9    radial + tangential
``CAL3BUNDLER``    f k1 k2 u0 v0                   3    u0 v0 fixed (GTSAM)
``CAL3FISHEYE``    fx fy s u0 v0 k1 k2 k3 k4       9    Kannala-Brandt
``CAL3UNIFIED``    fx fy s u0 v0 k1 k2 p1 p2 xi    10   Mei: sphere, then DS2
``DOUBLESPHERE``   fx fy cx cy xi alpha            6    Usenko et al. 2018
``CAL3_S2STEREO``  fx fy s u0 v0 b                 6    as CAL3_S2 for one image
=================  ==============================  ===  ==================================

``dim`` is the tangent dimension: the Jacobian ``uv_D_k`` has that many columns (the first
``dim`` storage entries; Cal3Bundler's principal point is not a parameter, as in GTSAM).

Intrinsic coordinates ``(x, y)`` are the point on the normalized plane ``z = 1`` (the models that
take a ray - fisheye, unified, double sphere - get the ray ``(x, y, 1)``), as in GTSAM.

``calibrate`` inverts ``uncalibrate`` by Newton's method on ``uv(xy) = uv_measured`` with the
analytic ``uv_D_xy`` (GTSAM iterates a fixed point for DS2/Bundler/Unified and Newton for
Fisheye; Newton converges quadratically, so a tight pixel tolerance costs one extra step).
Closed forms for the pinhole models and the double sphere. Jacobians of ``calibrate`` follow
from the implicit function theorem at the solution: ``xy_D_uv = uv_D_xy^-1`` and
``xy_D_k = -uv_D_xy^-1 uv_D_k`` (GTSAM's ``calibrateJacobians``).

Domains. ``uncalibrate`` is False where a model is undefined (outside the unified / double
sphere valid region, a degenerate parameter set) and where the pixel is not finite (a point so
far off axis that an intermediate overflows: a saturating model would otherwise return its
principal point). ``calibrate`` accepts a Newton root only where the distortion's Jacobian
``M = K^-1 uv_D_xy`` (identity at the centre) has ``det M > 0`` and ``trace M > 0``: beyond a
fold (``1 + 3 k1 r^2 < 0``, or the half-turn where ``1 + k1 r^2 < 0``) a root is another ray
that lands on the same pixel, not an inverse. No division here can see a zero denominator for
parameters the constructors accept. :func:`parameters_valid` is the constructors' invariant,
for calibrations that are optimized variables.
"""

from __future__ import annotations

import math

import numpy as np
from .._jit import njit

CAL3_S2, CAL3DS2, CAL3BUNDLER, CAL3FISHEYE, CAL3UNIFIED, DOUBLESPHERE, CAL3_S2STEREO = range(7)
STORAGE_DIMS = (5, 9, 5, 9, 10, 6, 6)
TANGENT_DIMS = (5, 9, 3, 9, 10, 6, 6)
MAX_TANGENT_DIM = 10

#: ``calibrate`` status codes.
OK, NOT_CONVERGED, INVALID = 0, 1, 2


# inlined by numba: as a call, its few comparisons cost the batch kernels ~8% per row
@njit(cache=True, inline="always")
def parameters_valid(model, k):
    """The constructors' invariant on ``k`` (positive focal lengths and stereo baseline, unified
    ``xi >= 0``, double sphere ``xi`` in ``[-1, 1]`` and ``alpha`` in ``[0, 1]``), for a
    calibration the optimizer moves: a step across it must be rejected, or the solve could end
    on parameters no calibration object can hold. False for NaN too."""
    if model == CAL3BUNDLER:
        return k[0] > 0.0
    if not (k[0] > 0.0 and k[1] > 0.0):
        return False
    if model == CAL3_S2STEREO:
        return k[5] > 0.0
    if model == CAL3UNIFIED:
        return k[9] >= 0.0
    if model == DOUBLESPHERE:  # no chained comparisons: numba compiles them 10x slower
        return k[4] >= -1.0 and k[4] <= 1.0 and k[5] >= 0.0 and k[5] <= 1.0
    return True


@njit(cache=True, inline="always")
def tangent_dim(model):
    if model == CAL3BUNDLER:
        return 3
    if model == CAL3DS2 or model == CAL3FISHEYE:
        return 9
    if model == CAL3UNIFIED:
        return 10
    if model == DOUBLESPHERE or model == CAL3_S2STEREO:
        return 6
    return 5


@njit(cache=True)
def _pinhole(k, x, y, uv, Dk, Dp, with_jac):
    fx, fy, s, u0, v0 = k[0], k[1], k[2], k[3], k[4]
    uv[0] = fx * x + s * y + u0
    uv[1] = fy * y + v0
    if with_jac:
        Dk[0, 0], Dk[0, 1], Dk[0, 2], Dk[0, 3], Dk[0, 4] = x, 0.0, y, 1.0, 0.0
        Dk[1, 0], Dk[1, 1], Dk[1, 2], Dk[1, 3], Dk[1, 4] = 0.0, y, 0.0, 0.0, 1.0
        Dp[0, 0], Dp[0, 1], Dp[1, 0], Dp[1, 1] = fx, s, 0.0, fy


@njit(cache=True)
def _ds2(k, x, y, uv, Dk, Dp, with_jac):
    """Brown-Conrady: ``pn = g (x, y) + tangential``, ``g = 1 + k1 r^2 + k2 r^4``, then K."""
    fx, fy, s, u0, v0 = k[0], k[1], k[2], k[3], k[4]
    k1, k2, p1, p2 = k[5], k[6], k[7], k[8]
    xy, xx, yy = x * y, x * x, y * y
    rr = xx + yy
    r4 = rr * rr
    g = 1.0 + k1 * rr + k2 * r4
    dx = 2.0 * p1 * xy + p2 * (rr + 2.0 * xx)
    dy = 2.0 * p2 * xy + p1 * (rr + 2.0 * yy)
    pnx = g * x + dx
    pny = g * y + dy
    uv[0] = fx * pnx + s * pny + u0
    uv[1] = fy * pny + v0
    if with_jac:
        Dk[0, 0], Dk[0, 1], Dk[0, 2], Dk[0, 3], Dk[0, 4] = pnx, 0.0, pny, 1.0, 0.0
        Dk[1, 0], Dk[1, 1], Dk[1, 2], Dk[1, 3], Dk[1, 4] = 0.0, pny, 0.0, 0.0, 1.0
        # d pn / d (k1, k2, p1, p2), then through K = [[fx, s], [0, fy]]
        a0, a1, a2, a3 = x * rr, x * r4, 2.0 * xy, rr + 2.0 * xx
        b0, b1, b2, b3 = y * rr, y * r4, rr + 2.0 * yy, 2.0 * xy
        Dk[0, 5] = fx * a0 + s * b0
        Dk[0, 6] = fx * a1 + s * b1
        Dk[0, 7] = fx * a2 + s * b2
        Dk[0, 8] = fx * a3 + s * b3
        Dk[1, 5] = fy * b0
        Dk[1, 6] = fy * b1
        Dk[1, 7] = fy * b2
        Dk[1, 8] = fy * b3
        # d pn / d (x, y)
        c = 2.0 * (k1 + 2.0 * k2 * rr)
        m00 = g + c * xx + 2.0 * p1 * y + 6.0 * p2 * x
        m01 = c * xy + 2.0 * p1 * x + 2.0 * p2 * y
        m10 = c * xy + 2.0 * p2 * y + 2.0 * p1 * x
        m11 = g + c * yy + 2.0 * p2 * x + 6.0 * p1 * y
        Dp[0, 0] = fx * m00 + s * m10
        Dp[0, 1] = fx * m01 + s * m11
        Dp[1, 0] = fy * m10
        Dp[1, 1] = fy * m11


@njit(cache=True)
def _bundler(k, x, y, uv, Dk, Dp, with_jac):
    """Snavely: ``u = u0 + f g x``, ``g = 1 + k1 r^2 + k2 r^4``."""
    f, k1, k2, u0, v0 = k[0], k[1], k[2], k[3], k[4]
    r = x * x + y * y
    g = 1.0 + (k1 + k2 * r) * r
    uv[0] = u0 + f * g * x
    uv[1] = v0 + f * g * y
    if with_jac:
        Dk[0, 0], Dk[0, 1], Dk[0, 2] = g * x, f * r * x, f * r * r * x
        Dk[1, 0], Dk[1, 1], Dk[1, 2] = g * y, f * r * y, f * r * r * y
        a = 2.0 * (k1 + 2.0 * k2 * r)
        Dp[0, 0] = f * (g + a * x * x)
        Dp[0, 1] = f * a * x * y
        Dp[1, 0] = Dp[0, 1]
        Dp[1, 1] = f * (g + a * y * y)


@njit(cache=True)
def _fisheye(k, x, y, uv, Dk, Dp, with_jac):
    """Kannala-Brandt: ``theta = atan(r)``, ``theta_d = theta (1 + k1 t^2 + .. + k4 t^8)``,
    ``(xd, yd) = theta_d / r (x, y)``, then K. False where ``r^2`` overflows."""
    fx, fy, s, u0, v0 = k[0], k[1], k[2], k[3], k[4]
    k1, k2, k3, k4 = k[5], k[6], k[7], k[8]
    r2 = x * x + y * y
    if not r2 < math.inf:  # atan saturates: theta / r = 0 would put the ray at the centre
        return False
    r = math.sqrt(r2)
    t = math.atan(r)
    t2 = t * t
    t4 = t2 * t2
    t6 = t2 * t4
    t8 = t4 * t4
    if r > 1e-8:
        scaling = t / r
    else:  # atan(r) / r by its series
        scaling = 1.0 - r2 / 3.0 + r2 * r2 / 5.0
    poly = 1.0 + k1 * t2 + k2 * t4 + k3 * t6 + k4 * t8
    sc = scaling * poly
    xd, yd = sc * x, sc * y
    uv[0] = fx * xd + s * yd + u0
    uv[1] = fy * yd + v0
    if with_jac:
        Dk[0, 0], Dk[0, 1], Dk[0, 2], Dk[0, 3], Dk[0, 4] = xd, 0.0, yd, 1.0, 0.0
        Dk[1, 0], Dk[1, 1], Dk[1, 2], Dk[1, 3], Dk[1, 4] = 0.0, yd, 0.0, 0.0, 1.0
        a = (fx * x + s * y) * scaling
        b = fy * y * scaling
        Dk[0, 5], Dk[0, 6], Dk[0, 7], Dk[0, 8] = a * t2, a * t4, a * t6, a * t8
        Dk[1, 5], Dk[1, 6], Dk[1, 7], Dk[1, 8] = b * t2, b * t4, b * t6, b * t8
        if r2 == 0.0:
            m00, m01, m11 = 1.0, 0.0, 1.0
        else:
            dtd_dt = 1.0 + 3.0 * k1 * t2 + 5.0 * k2 * t4 + 7.0 * k3 * t6 + 9.0 * k4 * t8
            dtd_dr = dtd_dt / (1.0 + r2)
            c2, s2, cs = x * x / r2, y * y / r2, x * y / r2
            m00 = dtd_dr * c2 + sc * (1.0 - c2)
            m01 = (dtd_dr - sc) * cs
            m11 = dtd_dr * s2 + sc * (1.0 - s2)
        Dp[0, 0] = fx * m00 + s * m01
        Dp[0, 1] = fx * m01 + s * m11
        Dp[1, 0] = fy * m01
        Dp[1, 1] = fy * m11
    return True


@njit(cache=True)
def _unified(k, x, y, uv, Dk, Dp, with_jac):
    """Mei's unified model: the ray ``(x, y, 1)`` on the unit sphere, shifted by ``xi`` along z,
    projected to ``m = (x, y) / (1 + xi |(x, y, 1)|)``, then Cal3DS2. False where undefined."""
    xi = k[9]
    sqrt_nx = math.sqrt(x * x + y * y + 1.0)
    den = 1.0 + xi * sqrt_nx
    if not (den > 0.0 and den < math.inf):  # an infinite one would map the ray to the centre
        return False
    q = 1.0 / den
    _ds2(k, x * q, y * q, uv, Dk, Dp, with_jac)
    if with_jac:
        b00, b01, b10, b11 = Dp[0, 0], Dp[0, 1], Dp[1, 0], Dp[1, 1]
        q2 = q * q
        du0 = -x * sqrt_nx * q2
        du1 = -y * sqrt_nx * q2
        Dk[0, 9] = b00 * du0 + b01 * du1
        Dk[1, 9] = b10 * du0 + b11 * du1
        denom = q2 / sqrt_nx
        mid = -xi * x * y * denom
        m00 = (sqrt_nx + xi * (y * y + 1.0)) * denom
        m11 = (sqrt_nx + xi * (x * x + 1.0)) * denom
        Dp[0, 0] = b00 * m00 + b01 * mid
        Dp[0, 1] = b00 * mid + b01 * m11
        Dp[1, 0] = b10 * m00 + b11 * mid
        Dp[1, 1] = b10 * mid + b11 * m11
    return True


@njit(cache=True)
def double_sphere_valid(xi, alpha, x, y, z):
    """Usenko et al.'s validity test of the projection of ``(x, y, z)``: ``z > -w2 d1``."""
    if alpha <= 0.5:
        w1 = alpha / (1.0 - alpha)
    else:
        w1 = (1.0 - alpha) / alpha
    s = 2.0 * w1 * xi + xi * xi + 1.0
    if not s > 0.0:
        # (xi + w1)^2 + 1 - w1^2 is 0 only at xi = -1, alpha = 1/2: w2 is 0 / 0 there (the
        # model sends the optical axis to a circle), so no ray has a well-defined pixel
        return False
    w2 = (w1 + xi) / math.sqrt(s)
    d1 = math.sqrt(x * x + y * y + z * z)
    return z > -w2 * d1


@njit(cache=True)
def _double_sphere(k, x, y, uv, Dk, Dp, with_jac):
    """Double sphere (Usenko, Demmel, Cremers 2018) of the ray ``(x, y, 1)``:
    ``d1 = |(x, y, 1)|``, ``w = xi d1 + 1``, ``d2 = |(x, y, w)|``,
    ``u = fx x / (alpha d2 + (1 - alpha) w) + cx`` (same for v). False where undefined."""
    fx, fy, cx, cy, xi, alpha = k[0], k[1], k[2], k[3], k[4], k[5]
    rr = x * x + y * y
    d1 = math.sqrt(rr + 1.0)
    w = xi * d1 + 1.0
    d2 = math.sqrt(rr + w * w)
    den = alpha * d2 + (1.0 - alpha) * w
    # den > 0 also keeps d2 > 0 for the Jacobian; an infinite den (overflow far off axis) would
    # map the ray to the centre
    if not (den > 0.0 and den < math.inf and double_sphere_valid(xi, alpha, x, y, 1.0)):
        return False
    inv = 1.0 / den
    uv[0] = fx * x * inv + cx
    uv[1] = fy * y * inv + cy
    if with_jac:
        inv2 = inv * inv
        dden_dxi = alpha * w * d1 / d2 + (1.0 - alpha) * d1
        dden_dalpha = d2 - w
        Dk[0, 0], Dk[0, 1], Dk[0, 2], Dk[0, 3] = x * inv, 0.0, 1.0, 0.0
        Dk[1, 0], Dk[1, 1], Dk[1, 2], Dk[1, 3] = 0.0, y * inv, 0.0, 1.0
        Dk[0, 4] = -fx * x * inv2 * dden_dxi
        Dk[1, 4] = -fy * y * inv2 * dden_dxi
        Dk[0, 5] = -fx * x * inv2 * dden_dalpha
        Dk[1, 5] = -fy * y * inv2 * dden_dalpha
        # d den / d(x, y): dd1/dx = x/d1, dw/dx = xi x/d1, dd2/dx = (x + w dw/dx)/d2
        dwdx, dwdy = xi * x / d1, xi * y / d1
        ddx = alpha * (x + w * dwdx) / d2 + (1.0 - alpha) * dwdx
        ddy = alpha * (y + w * dwdy) / d2 + (1.0 - alpha) * dwdy
        Dp[0, 0] = fx * (inv - x * inv2 * ddx)
        Dp[0, 1] = -fx * x * inv2 * ddy
        Dp[1, 0] = -fy * y * inv2 * ddx
        Dp[1, 1] = fy * (inv - y * inv2 * ddy)
    return True


@njit(cache=True, inline="always")
def uncalibrate(model, k, x, y, uv, Dk, Dp, with_jac):
    """Pixel ``uv`` of intrinsic point ``(x, y)``; ``Dk (2, >= dim)``, ``Dp (2, 2)`` when
    ``with_jac``. Returns False where the model is undefined or the pixel is not finite
    (``uv`` then unspecified)."""
    ok = True
    if model == CAL3_S2:
        _pinhole(k, x, y, uv, Dk, Dp, with_jac)
    elif model == CAL3_S2STEREO:
        _pinhole(k, x, y, uv, Dk, Dp, with_jac)
        if with_jac:
            Dk[0, 5] = 0.0
            Dk[1, 5] = 0.0
    elif model == CAL3DS2:
        _ds2(k, x, y, uv, Dk, Dp, with_jac)
    elif model == CAL3BUNDLER:
        _bundler(k, x, y, uv, Dk, Dp, with_jac)
    elif model == CAL3FISHEYE:
        ok = _fisheye(k, x, y, uv, Dk, Dp, with_jac)
    elif model == CAL3UNIFIED:
        ok = _unified(k, x, y, uv, Dk, Dp, with_jac)
    elif model == DOUBLESPHERE:
        ok = _double_sphere(k, x, y, uv, Dk, Dp, with_jac)
    # the polynomial models overflow to inf / NaN (1e-300 depth): no pixel, not a residual
    return ok and math.isfinite(uv[0]) and math.isfinite(uv[1])


@njit(cache=True, inline="always")
def pinhole_part(model, k, out):
    """``out = (fx, fy, s, u0, v0)`` of the model's linear part (GTSAM's ``K()``)."""
    if model == CAL3BUNDLER:
        out[0], out[1], out[2], out[3], out[4] = k[0], k[0], 0.0, k[3], k[4]
    elif model == DOUBLESPHERE:
        out[0], out[1], out[2], out[3], out[4] = k[0], k[1], 0.0, k[2], k[3]
    else:
        out[0], out[1], out[2], out[3], out[4] = k[0], k[1], k[2], k[3], k[4]


@njit(cache=True)
def _pinhole_inverse(K5, u, v, xy):
    y = (v - K5[4]) / K5[1]
    xy[1] = y
    xy[0] = (u - K5[3] - K5[2] * y) / K5[0]


@njit(cache=True)
def _double_sphere_unproject(k, u, v, xy):
    """Closed-form inverse of the double sphere; False outside the image of the model."""
    fx, fy, cx, cy, xi, alpha = k[0], k[1], k[2], k[3], k[4], k[5]
    mx = (u - cx) / fx
    my = (v - cy) / fy
    r2 = mx * mx + my * my
    disc = 1.0 - (2.0 * alpha - 1.0) * r2
    if not disc >= 0.0:
        return False
    den = alpha * math.sqrt(disc) + 1.0 - alpha
    if not den > 0.0:
        # alpha = 1 on the rim r2 = 1: mz is 0 / 0. The rim is the largest radius the model
        # reaches (d radius / d ray = 0 there), so it has no invertible preimage either way
        return False
    mz = (1.0 - alpha * alpha * r2) / den
    disc2 = mz * mz + (1.0 - xi * xi) * r2
    if not disc2 >= 0.0:
        return False
    scale = (mz * xi + math.sqrt(disc2)) / (mz * mz + r2)
    z = scale * mz - xi
    if not z > 0.0:
        return False
    xy[0] = scale * mx / z
    xy[1] = scale * my / z
    return True


@njit(cache=True, inline="always")
def calibrate(model, k, u, v, tol, max_iterations, xy):
    """Intrinsic point ``xy`` of pixel ``(u, v)``: a status code (``OK``, ``NOT_CONVERGED``,
    ``INVALID``: outside the model's image, or the root found lies past a fold). Iterative models
    stop when ``|uncalibrate(xy) - (u, v)| <= tol`` pixels."""
    K5 = np.empty(5)
    pinhole_part(model, k, K5)
    if model == CAL3_S2 or model == CAL3_S2STEREO:
        _pinhole_inverse(K5, u, v, xy)
        return OK
    uv = np.empty(2)
    Dk = np.empty((2, MAX_TANGENT_DIM))
    Dp = np.empty((2, 2))
    if model == DOUBLESPHERE:
        if not _double_sphere_unproject(k, u, v, xy):
            return INVALID
    else:
        _pinhole_inverse(K5, u, v, xy)
        if model == CAL3FISHEYE:  # start from the equidistant model: theta_d ~ theta
            th = math.sqrt(xy[0] * xy[0] + xy[1] * xy[1])
            if th > 0.0:
                sc = math.tan(min(th, 1.4)) / th
                xy[0] *= sc
                xy[1] *= sc
        elif model == CAL3UNIFIED:  # sphere model without distortion, inverted exactly
            xi = k[9]
            r2 = xy[0] * xy[0] + xy[1] * xy[1]
            d = 1.0 + (1.0 - xi * xi) * r2
            if d >= 0.0:
                sq = (xi + math.sqrt(d)) / (r2 + 1.0)
                if sq - xi > 0.0:
                    xy[0] *= sq / (sq - xi)
                    xy[1] *= sq / (sq - xi)
    for _ in range(max_iterations + 1):
        if not uncalibrate(model, k, xy[0], xy[1], uv, Dk, Dp, True):
            return INVALID
        e0, e1 = uv[0] - u, uv[1] - v
        det = Dp[0, 0] * Dp[1, 1] - Dp[0, 1] * Dp[1, 0]
        if math.sqrt(e0 * e0 + e1 * e1) <= tol:
            if det == 0.0 or not math.isfinite(det):  # calibrate_batch inverts uv_D_xy
                return INVALID
            if model == DOUBLESPHERE:  # the paper's closed-form inverse, only polished
                return OK
            # Beyond a fold of the distortion a root is another ray that the model sends onto
            # this pixel, not its inverse: past the first fold det < 0, and where the radial
            # factor 1 + k1 r^2 < 0 the map is a half-turn (det > 0, both eigenvalues < 0). So
            # both eigenvalues of M = K^-1 uv_D_xy (identity at the centre) must have positive
            # real parts: det > 0 and trace(M) fx fy > 0.
            trace = K5[1] * Dp[0, 0] - K5[2] * Dp[1, 0] + K5[0] * Dp[1, 1]
            return OK if det > 0.0 and trace > 0.0 else INVALID
        if det == 0.0 or not math.isfinite(det):
            return NOT_CONVERGED
        xy[0] -= (Dp[1, 1] * e0 - Dp[0, 1] * e1) / det
        xy[1] -= (-Dp[1, 0] * e0 + Dp[0, 0] * e1) / det
    return NOT_CONVERGED


@njit(cache=True, inline="always")
def uncalibrate_batch(model, k, xy, with_jac):
    """``xy (n, 2)`` -> ``uv (n, 2)``, ``uv_D_k (n, 2, dim)``, ``uv_D_xy (n, 2, 2)``,
    ``valid (n,)``."""
    n = xy.shape[0]
    d = tangent_dim(model)
    uv = np.empty((n, 2))
    Dk = np.zeros((n if with_jac else 0, 2, d))
    Dp = np.zeros((n if with_jac else 0, 2, 2))
    dk = np.zeros((2, MAX_TANGENT_DIM))
    dp = np.zeros((2, 2))
    valid = np.empty(n, dtype=np.bool_)
    for i in range(n):
        valid[i] = uncalibrate(model, k, xy[i, 0], xy[i, 1], uv[i], dk, dp, with_jac)
        if with_jac:
            Dk[i] = dk[:, :d]
            Dp[i] = dp
    return uv, Dk, Dp, valid


@njit(cache=True, inline="always")
def calibrate_batch(model, k, uv, tol, max_iterations, with_jac):
    """``uv (n, 2)`` -> ``xy (n, 2)``, ``xy_D_k (n, 2, dim)``, ``xy_D_uv (n, 2, 2)``,
    ``status (n,)``."""
    n = uv.shape[0]
    d = tangent_dim(model)
    xy = np.empty((n, 2))
    Dk = np.zeros((n if with_jac else 0, 2, d))
    Dp = np.zeros((n if with_jac else 0, 2, 2))
    status = np.empty(n, dtype=np.int64)
    dk = np.zeros((2, MAX_TANGENT_DIM))
    dp = np.zeros((2, 2))
    tmp = np.empty(2)
    for i in range(n):
        status[i] = calibrate(model, k, uv[i, 0], uv[i, 1], tol, max_iterations, xy[i])
        if with_jac and status[i] == OK:
            uncalibrate(model, k, xy[i, 0], xy[i, 1], tmp, dk, dp, True)
            det = dp[0, 0] * dp[1, 1] - dp[0, 1] * dp[1, 0]
            i00, i01 = dp[1, 1] / det, -dp[0, 1] / det
            i10, i11 = -dp[1, 0] / det, dp[0, 0] / det
            Dp[i, 0, 0], Dp[i, 0, 1], Dp[i, 1, 0], Dp[i, 1, 1] = i00, i01, i10, i11
            for c in range(d):
                Dk[i, 0, c] = -(i00 * dk[0, c] + i01 * dk[1, c])
                Dk[i, 1, c] = -(i10 * dk[0, c] + i11 * dk[1, c])
    return xy, Dk, Dp, status


@njit(cache=True)
def bundler_retract(x, delta):
    """Cal3Bundler storage ``[f, k1, k2, u0, v0]`` (+) ``[df, dk1, dk2]`` (u0, v0 fixed)."""
    out = x.copy()
    out[:, :3] += delta
    return out


@njit(cache=True)
def bundler_local(a, b):
    return b[:, :3] - a[:, :3]


@njit(cache=True)
def vector_retract(x, delta):
    return x + delta


@njit(cache=True)
def vector_local(a, b):
    return b - a
