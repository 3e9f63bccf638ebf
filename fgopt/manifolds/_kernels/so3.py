"""SO(3) kernels and the unit-quaternion helpers every 3D group uses: storage [qx, qy, qz, qw], tangent [wx, wy, wz].

Part of :mod:`fgopt.manifolds._kernels` (conventions in its docstring).
"""

from __future__ import annotations

import math

from ..._jit import njit

from ._common import _cross, skew_poly3


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
