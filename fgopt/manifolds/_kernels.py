"""Numba kernels of the Lie groups SO(2), SE(2), SO(3), SE(3) and Sim(3): one implementation.

Three layers, all ``@njit(cache=True)``:

1. per-element helpers, one per group and operation (``so3_exp(w, out)``, ``se3_jrinv(xi, out)``,
   ``quat_mul(a, b, out)``...). They write into ``out`` (which must not alias an input) and do
   not allocate, except the Sim(3) Jacobians;
2. per-element dispatchers over a group id (``lie_compose(gid, a, b, out)``, ``lie_log``,
   ``lie_jrinv``...), which the value classes call one element at a time and the factor
   kernels call inside their loops;
3. batched loops over ``(n, storage_dim)`` arrays (``batch_retract(gid, x, delta)``...), and
   ``<group>_retract_batch`` / ``<group>_local_batch`` entries per group for ``BatchKind``.

Layouts (float64, 1-D), tangent order rotation first::

    SO2   storage [cos, sin]                    tangent [theta]
    SE2   storage [cos, sin, x, y]              tangent [theta, vx, vy]
    SO3   storage [qx, qy, qz, qw]              tangent [wx, wy, wz]
    SE3   storage [qx, qy, qz, qw, tx, ty, tz]  tangent [w(3), v(3)]
    Sim3  storage [q(4), t(3), s]               tangent [w(3), v(3), lambda],  s = exp(lambda)

Conventions: ``retract(x, d) = x * Exp(d)``, ``local(a, b) = Log(a^-1 * b)`` (true group
exponential, right perturbation, as GTSAM's Pose2/Pose3 defaults). The adjoint satisfies
``x * Exp(v) = Exp(Adj(x) v) * x``; ``ad(xi)`` is its derivative, ``[hat(a), hat(b)] =
hat(ad(a) b)``. The right Jacobian satisfies ``Exp(xi + d) ~= Exp(xi) * Exp(Jr(xi) d)``, so
``Jr(xi) = phi(-ad(xi))`` with ``phi(A) = sum_k A^k / (k+1)!``, and ``Jl(xi) = Jr(-xi)``.

Exp(SE3) = (Exp(w), V(w) v) with V = Jl_SO3(w) = I + a W + b W^2, a = (1 - cos t)/t^2,
b = (t - sin t)/t^3 (W = hat(w), t = |w|); V^-1 = I - W/2 + c W^2, c = 1/t^2 - cot(t/2)/(2t).
The SE(3) Jacobian is block triangular, ``Jr = [[Jr_SO3, 0], [Q(-w, -v), Jr_SO3]]`` with
Barfoot's Q ("State Estimation for Robotics", eq. 7.86). Sim(3) (Eade, "Lie groups for computer
vision"): t = W(w, lambda) v with W = int_0^1 e^(s lambda) R(s w) ds = a0 I + a1 W + a2 W^2,
evaluated through the complex number (e^z - 1)/z, z = lambda + i t; its Jacobians are computed
to rounding error from ``phi(-ad)`` by scaling and squaring (no closed form here).

Removable singularities at angle 0 switch to Taylor series below thresholds where the
truncation error is below 1e-17; at angle pi no formula divides by sin(t) or 1 + cos(t).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

SO2_ID, SE2_ID, SO3_ID, SE3_ID, SIM3_ID = 0, 1, 2, 3, 4
GROUP_NAMES = ("SO2", "SE2", "SO3", "SE3", "Sim3")
STORAGE_DIMS = (2, 4, 4, 7, 8)
TANGENT_DIMS = (1, 3, 3, 6, 7)
MAX_STORAGE_DIM = 8
MAX_DIM = 7

# ----------------------------------------------------------------------------- small helpers


@njit(cache=True)
def storage_dim(gid):
    return 2 if gid == SO2_ID else 4 if gid <= SO3_ID else 7 if gid == SE3_ID else 8


@njit(cache=True)
def tangent_dim(gid):
    return 1 if gid == SO2_ID else 3 if gid <= SO3_ID else 6 if gid == SE3_ID else 7


@njit(cache=True)
def _cross(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@njit(cache=True)
def skew_poly_apply(w, c0, c1, c2, v, out):
    """out = (c0 I + c1 hat(w) + c2 hat(w)^2) v, for 3-vectors w, v (out may alias v)."""
    v0, v1, v2 = v[0], v[1], v[2]
    x0, x1, x2 = _cross(w[0], w[1], w[2], v0, v1, v2)
    y0, y1, y2 = _cross(w[0], w[1], w[2], x0, x1, x2)
    out[0] = c0 * v0 + c1 * x0 + c2 * y0
    out[1] = c0 * v1 + c1 * x1 + c2 * y1
    out[2] = c0 * v2 + c1 * x2 + c2 * y2


@njit(cache=True)
def skew_poly3(w, c0, c1, c2, out, r, c):
    """out[r:r+3, c:c+3] = c0 I + c1 hat(w) + c2 hat(w)^2, with hat(w)^2 = w w^T - |w|^2 I.

    Blocks are written through offsets rather than slices: 2-D slices are 'A'-layout arrays,
    each of which costs numba a separate compilation of the callee.
    """
    x, y, z = w[0], w[1], w[2]
    out[r, c] = c0 - c2 * (y * y + z * z)
    out[r + 1, c + 1] = c0 - c2 * (x * x + z * z)
    out[r + 2, c + 2] = c0 - c2 * (x * x + y * y)
    out[r, c + 1] = -c1 * z + c2 * x * y
    out[r + 1, c] = c1 * z + c2 * x * y
    out[r, c + 2] = c1 * y + c2 * x * z
    out[r + 2, c] = -c1 * y + c2 * x * z
    out[r + 1, c + 2] = -c1 * x + c2 * y * z
    out[r + 2, c + 1] = c1 * x + c2 * y * z


@njit(cache=True)
def fill_block(out, r, c, nr, nc, value):
    """out[r:r+nr, c:c+nc] = value."""
    for i in range(r, r + nr):
        for j in range(c, c + nc):
            out[i, j] = value


@njit(cache=True)
def copy_block3(m, rs, cs, rd, cd, scale):
    """m[rd:rd+3, cd:cd+3] = scale * m[rs:rs+3, cs:cs+3] (non-overlapping blocks)."""
    for i in range(3):
        for j in range(3):
            m[rd + i, cd + j] = scale * m[rs + i, cs + j]


@njit(cache=True)
def matmul_block3(m, ra, ca, rb, cb, rd, cd, scale):
    """m[rd:rd+3, cd:cd+3] = scale * A @ B for 3x3 blocks A at (ra, ca), B at (rb, cb) of m.

    The destination must not overlap A or B.
    """
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for k in range(3):
                acc += m[ra + i, ca + k] * m[rb + k, cb + j]
            m[rd + i, cd + j] = scale * acc


@njit(cache=True)
def matmul(a, b, out):
    """out = a @ b for small matrices (out must not alias a or b)."""
    for i in range(a.shape[0]):
        for j in range(b.shape[1]):
            acc = 0.0
            for k in range(a.shape[1]):
                acc += a[i, k] * b[k, j]
            out[i, j] = acc


@njit(cache=True)
def invert(a, out):
    """out = a^-1 by Gauss-Jordan elimination with partial pivoting (small square a)."""
    n = a.shape[0]
    m = a.copy()
    for i in range(n):
        for j in range(n):
            out[i, j] = 1.0 if i == j else 0.0
    for col in range(n):
        piv = col
        for r in range(col + 1, n):
            if abs(m[r, col]) > abs(m[piv, col]):
                piv = r
        if piv != col:
            for j in range(n):
                m[col, j], m[piv, j] = m[piv, j], m[col, j]
                out[col, j], out[piv, j] = out[piv, j], out[col, j]
        inv_p = 1.0 / m[col, col]
        for j in range(n):
            m[col, j] *= inv_p
            out[col, j] *= inv_p
        for r in range(n):
            if r != col and m[r, col] != 0.0:
                f = m[r, col]
                for j in range(n):
                    m[r, j] -= f * m[col, j]
                    out[r, j] -= f * out[col, j]


@njit(cache=True)
def phi_matrix(a, out):
    """out = phi(a) = sum_k a^k / (k+1)! = (e^a - I) a^-1, by Taylor and scaling-and-squaring.

    Squaring uses phi(2a) = phi(a) (e^a + I) / 2. Accurate to rounding error for any a.
    """
    n = a.shape[0]
    nrm = 0.0
    for i in range(n):
        row = 0.0
        for j in range(n):
            row += abs(a[i, j])
        nrm = max(nrm, row)
    s = 0
    while nrm > 0.5 and s < 60:
        nrm *= 0.5
        s += 1
    scale = 0.5 ** s
    b = np.empty((n, n))
    e = np.eye(n)
    term = np.eye(n)
    tmp = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            b[i, j] = a[i, j] * scale
            out[i, j] = 1.0 if i == j else 0.0
    for k in range(1, 18):  # e = exp(b), out = phi(b); |b| <= 1/2, so 18 terms reach 1e-21
        matmul(term, b, tmp)
        for i in range(n):
            for j in range(n):
                term[i, j] = tmp[i, j] / k
                e[i, j] += term[i, j]
                out[i, j] += term[i, j] / (k + 1)
    for _ in range(s):
        for i in range(n):
            e[i, i] += 1.0
        matmul(out, e, tmp)
        for i in range(n):
            e[i, i] -= 1.0
            for j in range(n):
                out[i, j] = 0.5 * tmp[i, j]
        matmul(e, e, tmp)
        for i in range(n):
            for j in range(n):
                e[i, j] = tmp[i, j]


@njit(cache=True)
def jr_from_ad(ad, out):
    """Right Jacobian from the ad matrix: out = phi(-ad) (any matrix Lie group)."""
    phi_matrix(-ad, out)


# ----------------------------------------------------------------------------- quaternions


@njit(cache=True)
def quat_mul(a, b, out):
    """Hamilton product out = a b of quaternions stored [x, y, z, w] (out may alias)."""
    ax, ay, az, aw = a[0], a[1], a[2], a[3]
    bx, by, bz, bw = b[0], b[1], b[2], b[3]
    out[0] = aw * bx + ax * bw + ay * bz - az * by
    out[1] = aw * by - ax * bz + ay * bw + az * bx
    out[2] = aw * bz + ax * by - ay * bx + az * bw
    out[3] = aw * bw - ax * bx - ay * by - az * bz


@njit(cache=True)
def quat_normalize(q):
    """Scale q[0:4] to unit norm in place."""
    inv = 1.0 / math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    for i in range(4):
        q[i] *= inv


@njit(cache=True)
def quat_rotate(q, p, out, sign=1.0):
    """out = R(q) p (sign=-1: R(q)^T p). Unit q; out may alias p."""
    x, y, z, w = sign * q[0], sign * q[1], sign * q[2], q[3]
    px, py, pz = p[0], p[1], p[2]
    tx, ty, tz = _cross(2.0 * x, 2.0 * y, 2.0 * z, px, py, pz)
    cx, cy, cz = _cross(x, y, z, tx, ty, tz)
    out[0] = px + w * tx + cx
    out[1] = py + w * ty + cy
    out[2] = pz + w * tz + cz


@njit(cache=True)
def rotation_block(q, out, r, c, scale):
    """out[r:r+3, c:c+3] = scale * R(q) for the unit quaternion q = [x, y, z, w]."""
    x, y, z, w = q[0], q[1], q[2], q[3]
    out[r, c] = scale * (1.0 - 2.0 * (y * y + z * z))
    out[r, c + 1] = scale * 2.0 * (x * y - z * w)
    out[r, c + 2] = scale * 2.0 * (x * z + y * w)
    out[r + 1, c] = scale * 2.0 * (x * y + z * w)
    out[r + 1, c + 1] = scale * (1.0 - 2.0 * (x * x + z * z))
    out[r + 1, c + 2] = scale * 2.0 * (y * z - x * w)
    out[r + 2, c] = scale * 2.0 * (x * z - y * w)
    out[r + 2, c + 1] = scale * 2.0 * (y * z + x * w)
    out[r + 2, c + 2] = scale * (1.0 - 2.0 * (x * x + y * y))


@njit(cache=True)
def quat_to_matrix(q, out):
    """out (3, 3) = rotation matrix of the unit quaternion q = [x, y, z, w]."""
    rotation_block(q, out, 0, 0, 1.0)


@njit(cache=True)
def quat_from_matrix(r, out):
    """out = unit quaternion [x, y, z, w] of rotation matrix r (Shepperd's method)."""
    tr = r[0, 0] + r[1, 1] + r[2, 2]
    if tr > 0.0:
        s = 2.0 * math.sqrt(tr + 1.0)
        out[3], out[0], out[1], out[2] = 0.25 * s, (r[2, 1] - r[1, 2]) / s, \
            (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s
    elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
        s = 2.0 * math.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
        out[3], out[0], out[1], out[2] = (r[2, 1] - r[1, 2]) / s, 0.25 * s, \
            (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s
    elif r[1, 1] > r[2, 2]:
        s = 2.0 * math.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2])
        out[3], out[0], out[1], out[2] = (r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, \
            0.25 * s, (r[1, 2] + r[2, 1]) / s
    else:
        s = 2.0 * math.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1])
        out[3], out[0], out[1], out[2] = (r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, \
            (r[1, 2] + r[2, 1]) / s, 0.25 * s
    quat_normalize(out)


# ----------------------------------------------------------------------------- SO(3)


@njit(cache=True)
def so3_coeffs(t2):
    """(a, b, c) = ((1-cos t)/t^2, (t-sin t)/t^3, 1/t^2 - cot(t/2)/(2t)) for t^2 = t2."""
    if t2 < 1e-2:  # t < 0.1: series to t^8, truncation < 1e-19
        a = 0.5 - t2 * (1 / 24 - t2 * (1 / 720 - t2 * (1 / 40320 - t2 / 3628800)))
        b = 1 / 6 - t2 * (1 / 120 - t2 * (1 / 5040 - t2 * (1 / 362880 - t2 / 39916800)))
        c = 1 / 12 + t2 * (1 / 720 + t2 * (1 / 30240 + t2 * (1 / 1209600 + t2 / 47900160)))
        return a, b, c
    t = math.sqrt(t2)
    h = 0.5 * t
    sh = math.sin(h)
    a = 2.0 * sh * sh / t2
    b = (t - math.sin(t)) / (t2 * t)
    c = 1.0 / t2 - math.cos(h) / (2.0 * t * sh)
    return a, b, c


@njit(cache=True)
def so3_exp(w, out):
    """out = quaternion [x, y, z, w] of Exp(w)."""
    t2 = w[0] * w[0] + w[1] * w[1] + w[2] * w[2]
    if t2 < 1e-8:  # t < 1e-4
        k = 0.5 - t2 / 48.0 + t2 * t2 / 3840.0
        c = 1.0 - t2 / 8.0 + t2 * t2 / 384.0
    else:
        t = math.sqrt(t2)
        k = math.sin(0.5 * t) / t
        c = math.cos(0.5 * t)
    out[0], out[1], out[2], out[3] = k * w[0], k * w[1], k * w[2], c


@njit(cache=True)
def so3_log(q, out):
    """out = Log(q), the shortest rotation vector (norm <= pi) of the quaternion q."""
    x, y, z, w = q[0], q[1], q[2], q[3]
    if w < 0.0:  # double cover: q and -q are the same rotation
        x, y, z, w = -x, -y, -z, -w
    n = math.sqrt(x * x + y * y + z * z)
    if n < 1e-8:  # 2 atan(n/w)/n = (2/w)(1 - n^2/(3 w^2) + ...)
        f = 2.0 / w * (1.0 - n * n / (3.0 * w * w))
    else:
        f = 2.0 * math.atan2(n, w) / n
    out[0], out[1], out[2] = f * x, f * y, f * z


@njit(cache=True)
def so3_compose(a, b, out):
    quat_mul(a, b, out)
    quat_normalize(out)


@njit(cache=True)
def so3_inverse(a, out):
    out[0], out[1], out[2], out[3] = -a[0], -a[1], -a[2], a[3]


@njit(cache=True)
def so3_adjoint(a, out):
    rotation_block(a, out, 0, 0, 1.0)


@njit(cache=True)
def so3_ad(w, out):
    skew_poly3(w, 0.0, 1.0, 0.0, out, 0, 0)


@njit(cache=True)
def _so3_jr_block(w, out, r, c):
    """out[r:r+3, c:c+3] = Jr(w) = I - a W + b W^2."""
    a, b, _ = so3_coeffs(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    skew_poly3(w, 1.0, -a, b, out, r, c)


@njit(cache=True)
def _so3_jrinv_block(w, out, r, c):
    """out[r:r+3, c:c+3] = Jr(w)^-1 = I + W/2 + c W^2 (finite for |w| <= pi)."""
    _, _, k = so3_coeffs(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    skew_poly3(w, 1.0, 0.5, k, out, r, c)


@njit(cache=True)
def so3_jr(w, out):
    """Right Jacobian Jr(w) = I - a W + b W^2."""
    _so3_jr_block(w, out, 0, 0)


@njit(cache=True)
def so3_jrinv(w, out):
    """Inverse right Jacobian Jr(w)^-1 = I + W/2 + c W^2 (finite for |w| <= pi)."""
    _so3_jrinv_block(w, out, 0, 0)


# ----------------------------------------------------------------------------- SO(2), SE(2)


@njit(cache=True)
def so2_compose(a, b, out):
    c = a[0] * b[0] - a[1] * b[1]
    s = a[1] * b[0] + a[0] * b[1]
    inv = 1.0 / math.sqrt(c * c + s * s)
    out[0], out[1] = c * inv, s * inv


@njit(cache=True)
def so2_inverse(a, out):
    out[0], out[1] = a[0], -a[1]


@njit(cache=True)
def so2_exp(v, out):
    out[0], out[1] = math.cos(v[0]), math.sin(v[0])


@njit(cache=True)
def so2_log(a, out):
    out[0] = math.atan2(a[1], a[0])


@njit(cache=True)
def so2_eye(v, out):
    """Adjoint, right Jacobian and its inverse of SO(2): all [[1]]."""
    out[0, 0] = 1.0


@njit(cache=True)
def so2_ad(v, out):
    out[0, 0] = 0.0


@njit(cache=True)
def _half_cot(t):
    """(t/2) cot(t/2), finite on [-pi, pi]."""
    if abs(t) < 1e-4:
        return 1.0 - t * t / 12.0
    h = 0.5 * t
    return h * math.cos(h) / math.sin(h)


@njit(cache=True)
def se2_compose(a, b, out):
    so2_compose(a, b, out)
    out[2] = a[0] * b[2] - a[1] * b[3] + a[2]
    out[3] = a[1] * b[2] + a[0] * b[3] + a[3]


@njit(cache=True)
def se2_inverse(a, out):
    c, s, x, y = a[0], a[1], a[2], a[3]
    out[0], out[1], out[2], out[3] = c, -s, -(c * x + s * y), s * x - c * y


@njit(cache=True)
def se2_exp(v, out):
    """Exp([t, vx, vy]) = (R(t), V(t) v), V = (sin t / t) I + ((1 - cos t) / t) J."""
    t = v[0]
    a2, b3, _ = so3_coeffs(t * t)
    a, b = 1.0 - t * t * b3, t * a2  # sin(t)/t, (1 - cos t)/t
    out[0], out[1] = math.cos(t), math.sin(t)
    out[2] = a * v[1] - b * v[2]
    out[3] = b * v[1] + a * v[2]


@njit(cache=True)
def se2_log(a, out):
    """Log(R, t) = [t, V^-1 t], V^-1 = (t/2) cot(t/2) I - (t/2) J."""
    t = math.atan2(a[1], a[0])
    p, h = _half_cot(t), 0.5 * t
    x, y = a[2], a[3]
    out[0], out[1], out[2] = t, p * x + h * y, -h * x + p * y


@njit(cache=True)
def se2_adjoint(a, out):
    c, s, x, y = a[0], a[1], a[2], a[3]
    out[0, 0], out[0, 1], out[0, 2] = 1.0, 0.0, 0.0
    out[1, 0], out[1, 1], out[1, 2] = y, c, -s
    out[2, 0], out[2, 1], out[2, 2] = -x, s, c


@njit(cache=True)
def se2_ad(v, out):
    out[0, 0], out[0, 1], out[0, 2] = 0.0, 0.0, 0.0
    out[1, 0], out[1, 1], out[1, 2] = v[2], 0.0, -v[0]
    out[2, 0], out[2, 1], out[2, 2] = -v[1], v[0], 0.0


@njit(cache=True)
def _se2_jr_parts(v):
    t, vx, vy = v[0], v[1], v[2]
    a2, b3, _ = so3_coeffs(t * t)
    a, b = 1.0 - t * t * b3, t * a2
    c1 = vx * t * b3 - vy * a2
    c2 = vx * a2 + vy * t * b3
    return a, b, c1, c2


@njit(cache=True)
def se2_jr(v, out):
    """Jr([t, v]) = [[1, 0], [c, M]], M = [[sin t/t, (1-cos t)/t], [-(1-cos t)/t, sin t/t]]."""
    a, b, c1, c2 = _se2_jr_parts(v)
    out[0, 0], out[0, 1], out[0, 2] = 1.0, 0.0, 0.0
    out[1, 0], out[1, 1], out[1, 2] = c1, a, b
    out[2, 0], out[2, 1], out[2, 2] = c2, -b, a


@njit(cache=True)
def se2_jrinv(v, out):
    """Jr^-1 = [[1, 0], [-M^-1 c, M^-1]], M^-1 = [[p, -t/2], [t/2, p]], p = (t/2) cot(t/2)."""
    _, _, c1, c2 = _se2_jr_parts(v)
    p, h = _half_cot(v[0]), 0.5 * v[0]
    out[0, 0], out[0, 1], out[0, 2] = 1.0, 0.0, 0.0
    out[1, 0], out[1, 1], out[1, 2] = -(p * c1 - h * c2), p, -h
    out[2, 0], out[2, 1], out[2, 2] = -(h * c1 + p * c2), h, p


# ----------------------------------------------------------------------------- SE(3)


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


# ----------------------------------------------------------------------------- Sim(3)


@njit(cache=True)
def _moment(k, lam):
    """int_0^1 s^k e^(s lam) ds."""
    if abs(lam) < 0.5:
        acc, term = 0.0, 1.0
        for j in range(30):
            acc += term / (k + j + 1)
            term *= lam / (j + 1)
        return acc
    m = math.expm1(lam) / lam
    el = math.exp(lam)
    for i in range(1, k + 1):
        m = (el - i * m) / lam
    return m


@njit(cache=True)
def sim3_w_coeffs(t2, lam):
    """(a0, a1, a2) with W(w, lam) = int_0^1 e^(s lam) Exp(s w) ds = a0 I + a1 W + a2 W^2.

    a0 = (e^lam - 1)/lam; with Q = (e^z - 1)/z, z = lam + i t: a1 = Im Q / t,
    a2 = (a0 - Re Q)/t^2; below t = 1e-3, series in t with moments of e^(s lam).
    """
    if abs(lam) < 1e-5:
        a0 = 1.0 + lam * (0.5 + lam * (1.0 / 6.0 + lam / 24.0))
    else:
        a0 = math.expm1(lam) / lam
    if t2 < 1e-6:
        a1 = _moment(1, lam) - t2 * _moment(3, lam) / 6.0 + t2 * t2 * _moment(5, lam) / 120.0
        a2 = _moment(2, lam) / 2.0 - t2 * _moment(4, lam) / 24.0 + t2 * t2 * _moment(6, lam) / 720.0
        return a0, a1, a2
    t = math.sqrt(t2)
    sh = math.sin(0.5 * t)
    p_re = math.expm1(lam) * math.cos(t) - 2.0 * sh * sh  # e^z - 1
    p_im = math.exp(lam) * math.sin(t)
    den = lam * lam + t2
    q_re = (p_re * lam + p_im * t) / den
    q_im = (p_im * lam - p_re * t) / den
    return a0, q_im / t, (a0 - q_re) / t2


@njit(cache=True)
def sim3_compose(a, b, out):
    so3_compose(a, b, out)
    quat_rotate(a, b[4:7], out[4:7])
    for i in range(4, 7):
        out[i] = a[7] * out[i] + a[i]
    out[7] = a[7] * b[7]


@njit(cache=True)
def sim3_inverse(a, out):
    se3_inverse(a, out)
    inv_s = 1.0 / a[7]
    for i in range(4, 7):
        out[i] *= inv_s
    out[7] = inv_s


@njit(cache=True)
def sim3_exp(xi, out):
    so3_exp(xi, out)
    a0, a1, a2 = sim3_w_coeffs(xi[0] * xi[0] + xi[1] * xi[1] + xi[2] * xi[2], xi[6])
    skew_poly_apply(xi, a0, a1, a2, xi[3:6], out[4:7])
    out[7] = math.exp(xi[6])


@njit(cache=True)
def sim3_log(x, out):
    """Log via W^-1 = b0 I + b1 W + b2 W^2: b0 = 1/a0, b1 = -a1/D, b2 = (a1^2 - a2 u)/(a0 D),
    u = a0 - a2 t^2, D = u^2 + a1^2 t^2 (W has eigenvalues 0, +-i t)."""
    so3_log(x, out)
    lam = math.log(x[7])
    t2 = out[0] * out[0] + out[1] * out[1] + out[2] * out[2]
    a0, a1, a2 = sim3_w_coeffs(t2, lam)
    u = a0 - a2 * t2
    d = u * u + a1 * a1 * t2
    skew_poly_apply(out, 1.0 / a0, -a1 / d, (a1 * a1 - a2 * u) / (a0 * d), x[4:7], out[3:6])
    out[6] = lam


@njit(cache=True)
def sim3_adjoint(x, out):
    """Adj = [[R, 0, 0], [hat(t) R, s R, -t], [0, 0, 1]]."""
    _se3_adjoint_scaled(x, out, x[7])
    fill_block(out, 0, 6, 6, 1, 0.0)
    fill_block(out, 6, 0, 1, 6, 0.0)
    for i in range(3):
        out[3 + i, 6] = -x[4 + i]
    out[6, 6] = 1.0


@njit(cache=True)
def sim3_ad(xi, out):
    """ad = [[W, 0, 0], [hat(v), W + lam I, -v], [0, 0, 0]]."""
    se3_ad(xi, out)
    fill_block(out, 0, 6, 3, 1, 0.0)
    fill_block(out, 6, 0, 1, 7, 0.0)
    for i in range(3):
        out[3 + i, 3 + i] = xi[6]
        out[3 + i, 6] = -xi[3 + i]


@njit(cache=True)
def sim3_jr(xi, out):
    ad = np.empty((7, 7))
    sim3_ad(xi, ad)
    jr_from_ad(ad, out)


@njit(cache=True)
def sim3_jrinv(xi, out):
    jr = np.empty((7, 7))
    sim3_jr(xi, jr)
    invert(jr, out)


# ----------------------------------------------------------------------------- dispatchers


@njit(cache=True)
def lie_compose(gid, a, b, out):
    """out = a * b for group ``gid`` (out must not alias a or b)."""
    if gid == SO2_ID:
        so2_compose(a, b, out)
    elif gid == SE2_ID:
        se2_compose(a, b, out)
    elif gid == SO3_ID:
        so3_compose(a, b, out)
    elif gid == SE3_ID:
        se3_compose(a, b, out)
    else:
        sim3_compose(a, b, out)


@njit(cache=True)
def lie_inverse(gid, a, out):
    if gid == SO2_ID:
        so2_inverse(a, out)
    elif gid == SE2_ID:
        se2_inverse(a, out)
    elif gid == SO3_ID:
        so3_inverse(a, out)
    elif gid == SE3_ID:
        se3_inverse(a, out)
    else:
        sim3_inverse(a, out)


@njit(cache=True)
def lie_exp(gid, v, out):
    if gid == SO2_ID:
        so2_exp(v, out)
    elif gid == SE2_ID:
        se2_exp(v, out)
    elif gid == SO3_ID:
        so3_exp(v, out)
    elif gid == SE3_ID:
        se3_exp(v, out)
    else:
        sim3_exp(v, out)


@njit(cache=True)
def lie_log(gid, a, out):
    if gid == SO2_ID:
        so2_log(a, out)
    elif gid == SE2_ID:
        se2_log(a, out)
    elif gid == SO3_ID:
        so3_log(a, out)
    elif gid == SE3_ID:
        se3_log(a, out)
    else:
        sim3_log(a, out)


@njit(cache=True)
def lie_adjoint(gid, a, out):
    if gid == SO2_ID:
        so2_eye(a, out)
    elif gid == SE2_ID:
        se2_adjoint(a, out)
    elif gid == SO3_ID:
        so3_adjoint(a, out)
    elif gid == SE3_ID:
        se3_adjoint(a, out)
    else:
        sim3_adjoint(a, out)


@njit(cache=True)
def lie_ad(gid, v, out):
    if gid == SO2_ID:
        so2_ad(v, out)
    elif gid == SE2_ID:
        se2_ad(v, out)
    elif gid == SO3_ID:
        so3_ad(v, out)
    elif gid == SE3_ID:
        se3_ad(v, out)
    else:
        sim3_ad(v, out)


@njit(cache=True)
def lie_jr(gid, v, out):
    if gid == SO2_ID:
        so2_eye(v, out)
    elif gid == SE2_ID:
        se2_jr(v, out)
    elif gid == SO3_ID:
        so3_jr(v, out)
    elif gid == SE3_ID:
        se3_jr(v, out)
    else:
        sim3_jr(v, out)


@njit(cache=True)
def lie_jrinv(gid, v, out):
    if gid == SO2_ID:
        so2_eye(v, out)
    elif gid == SE2_ID:
        se2_jrinv(v, out)
    elif gid == SO3_ID:
        so3_jrinv(v, out)
    elif gid == SE3_ID:
        se3_jrinv(v, out)
    else:
        sim3_jrinv(v, out)


@njit(cache=True)
def lie_retract(gid, x, delta, out, tmp):
    """out = x * Exp(delta); ``tmp`` is scratch of length >= storage dim."""
    lie_exp(gid, delta, tmp)
    lie_compose(gid, x, tmp, out)


@njit(cache=True)
def lie_local(gid, a, b, out, tmp1, tmp2):
    """out = Log(a^-1 * b); ``tmp1``, ``tmp2`` are scratch of length >= storage dim."""
    lie_inverse(gid, a, tmp1)
    lie_compose(gid, tmp1, b, tmp2)
    lie_log(gid, tmp2, out)


# ----------------------------------------------------------------------------- batched loops


@njit(cache=True)
def batch_compose(gid, a, b):
    """(n, s), (n, s) -> (n, s): row-wise a * b."""
    out = np.empty((a.shape[0], storage_dim(gid)))
    for i in range(a.shape[0]):
        lie_compose(gid, a[i], b[i], out[i])
    return out


@njit(cache=True)
def batch_inverse(gid, a):
    out = np.empty((a.shape[0], storage_dim(gid)))
    for i in range(a.shape[0]):
        lie_inverse(gid, a[i], out[i])
    return out


@njit(cache=True)
def batch_exp(gid, v):
    """(n, d) -> (n, s)."""
    out = np.empty((v.shape[0], storage_dim(gid)))
    for i in range(v.shape[0]):
        lie_exp(gid, v[i], out[i])
    return out


@njit(cache=True)
def batch_log(gid, a):
    """(n, s) -> (n, d)."""
    out = np.empty((a.shape[0], tangent_dim(gid)))
    for i in range(a.shape[0]):
        lie_log(gid, a[i], out[i])
    return out


@njit(cache=True)
def batch_retract(gid, x, delta):
    """(n, s), (n, d) -> (n, s): row-wise x * Exp(delta)."""
    out = np.empty((x.shape[0], storage_dim(gid)))
    tmp = np.empty(MAX_STORAGE_DIM)
    for i in range(x.shape[0]):
        lie_retract(gid, x[i], delta[i], out[i], tmp)
    return out


@njit(cache=True)
def batch_local(gid, a, b):
    """(n, s), (n, s) -> (n, d): row-wise Log(a^-1 * b)."""
    out = np.empty((a.shape[0], tangent_dim(gid)))
    tmp1 = np.empty(MAX_STORAGE_DIM)
    tmp2 = np.empty(MAX_STORAGE_DIM)
    for i in range(a.shape[0]):
        lie_local(gid, a[i], b[i], out[i], tmp1, tmp2)
    return out


# ``BatchKind.retract`` / ``.local`` of each group: thin Python entries over the two compiled
# loops (numba wrappers per group would each cost ~1 s of compilation for no run-time gain).
# Inputs are made C-contiguous float64 so that strided views do not trigger new compilations.


def _entry(loop, gid: int, name: str):
    def run(a, b):
        return loop(gid, np.ascontiguousarray(a, dtype=np.float64),
                    np.ascontiguousarray(b, dtype=np.float64))

    run.__name__ = run.__qualname__ = name
    run.__doc__ = f"Batched {name.split('_')[1]} of {GROUP_NAMES[gid]} over (n, storage) rows."
    return run


RETRACT_BATCH = tuple(_entry(batch_retract, g, f"{GROUP_NAMES[g].lower()}_retract_batch")
                      for g in range(5))
LOCAL_BATCH = tuple(_entry(batch_local, g, f"{GROUP_NAMES[g].lower()}_local_batch")
                    for g in range(5))
so2_retract_batch, se2_retract_batch, so3_retract_batch, se3_retract_batch, \
    sim3_retract_batch = RETRACT_BATCH
so2_local_batch, se2_local_batch, so3_local_batch, se3_local_batch, sim3_local_batch = LOCAL_BATCH
