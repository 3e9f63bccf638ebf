"""NumPy twins of the batched retract (``x * Exp(delta)`` row-wise) of SO(2), SE(2), SO(3), SE(3).

The same formulas as the per-element kernels (``so2.py`` ... ``se3.py``: the same series
switch-overs, the same renormalization after composing), on whole columns: used by the NumPy
backend (:func:`fgopt._jit.numpy_mode`) and for any batch while numba is not in use in the process,
so a solve on the NumPy backend needs no numba. Sim(3) has no twin (its retract is the numba
kernel), so problems with Sim(3) values run on the numba backend.
"""

from __future__ import annotations

import numpy as np


def _so3_ab(t2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``so3_coeffs``' (a, b) = ((1-cos t)/t^2, (t-sin t)/t^3) for t^2 = t2, per element."""
    small = t2 < 1e-2
    a = np.empty_like(t2)
    b = np.empty_like(t2)
    ts = t2[small]
    a[small] = 0.5 - ts * (1 / 24 - ts * (1 / 720 - ts * (1 / 40320 - ts / 3628800)))
    b[small] = 1 / 6 - ts * (1 / 120 - ts * (1 / 5040 - ts * (1 / 362880 - ts / 39916800)))
    big = ~small
    tb = t2[big]
    t = np.sqrt(tb)
    sh = np.sin(0.5 * t)
    a[big] = 2.0 * sh * sh / tb
    b[big] = (t - np.sin(t)) / (tb * t)
    return a, b


def _so2_compose(ac, as_, bc, bs):
    c = ac * bc - as_ * bs
    s = as_ * bc + ac * bs
    inv = 1.0 / np.sqrt(c * c + s * s)
    return c * inv, s * inv


def so2_retract(x: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """(n, 2) [cos, sin], (n, 1) -> (n, 2)."""
    out = np.empty((x.shape[0], 2))
    t = delta[:, 0]
    out[:, 0], out[:, 1] = _so2_compose(x[:, 0], x[:, 1], np.cos(t), np.sin(t))
    return out


def se2_retract(x: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """(n, 4) [cos, sin, x, y], (n, 3) [theta, vx, vy] -> (n, 4)."""
    t, vx, vy = delta[:, 0], delta[:, 1], delta[:, 2]
    a2, b3 = _so3_ab(t * t)
    a, b = 1.0 - t * t * b3, t * a2
    ec, es = np.cos(t), np.sin(t)
    ex = a * vx - b * vy
    ey = b * vx + a * vy
    out = np.empty((x.shape[0], 4))
    c, s = x[:, 0], x[:, 1]
    out[:, 0], out[:, 1] = _so2_compose(c, s, ec, es)
    out[:, 2] = c * ex - s * ey + x[:, 2]
    out[:, 3] = s * ex + c * ey + x[:, 3]
    return out


def _so3_exp(w: np.ndarray) -> np.ndarray:
    """(n, 3) -> (n, 4) quaternions [x, y, z, w]."""
    t2 = np.einsum("ij,ij->i", w, w)
    small = t2 < 1e-8
    k = np.empty_like(t2)
    c = np.empty_like(t2)
    ts = t2[small]
    k[small] = 0.5 - ts / 48.0 + ts * ts / 3840.0
    c[small] = 1.0 - ts / 8.0 + ts * ts / 384.0
    t = np.sqrt(t2[~small])
    k[~small] = np.sin(0.5 * t) / t
    c[~small] = np.cos(0.5 * t)
    q = np.empty((w.shape[0], 4))
    q[:, :3] = k[:, None] * w
    q[:, 3] = c
    return q


def _quat_mul_normalized(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    ax, ay, az, aw = a[:, 0], a[:, 1], a[:, 2], a[:, 3]
    bx, by, bz, bw = b[:, 0], b[:, 1], b[:, 2], b[:, 3]
    x = aw * bx + ax * bw + ay * bz - az * by
    y = aw * by - ax * bz + ay * bw + az * bx
    z = aw * bz + ax * by - ay * bx + az * bw
    w = aw * bw - ax * bx - ay * by - az * bz
    inv = 1.0 / np.sqrt(x * x + y * y + z * z + w * w)
    out[:, 0], out[:, 1], out[:, 2], out[:, 3] = x * inv, y * inv, z * inv, w * inv


def _cross(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


def so3_retract(x: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """(n, 4) quaternions, (n, 3) -> (n, 4)."""
    out = np.empty((x.shape[0], 4))
    _quat_mul_normalized(x, _so3_exp(delta), out)
    return out


def se3_retract(x: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """(n, 7) [qx, qy, qz, qw, tx, ty, tz], (n, 6) [w, v] -> (n, 7)."""
    w = delta[:, :3]
    q = _so3_exp(w)
    a, b = _so3_ab(np.einsum("ij,ij->i", w, w))
    # translation of Exp: (I + a W + b W^2) v
    w0, w1, w2 = w[:, 0], w[:, 1], w[:, 2]
    v0, v1, v2 = delta[:, 3], delta[:, 4], delta[:, 5]
    x0, x1, x2 = _cross(w0, w1, w2, v0, v1, v2)
    y0, y1, y2 = _cross(w0, w1, w2, x0, x1, x2)
    t0, t1, t2 = v0 + a * x0 + b * y0, v1 + a * x1 + b * y1, v2 + a * x2 + b * y2
    out = np.empty((x.shape[0], 7))
    _quat_mul_normalized(x, q, out)
    # x's rotation applied to the translation of Exp, plus x's translation
    qx, qy, qz, qw = x[:, 0], x[:, 1], x[:, 2], x[:, 3]
    u0, u1, u2 = _cross(2.0 * qx, 2.0 * qy, 2.0 * qz, t0, t1, t2)
    c0, c1, c2 = _cross(qx, qy, qz, u0, u1, u2)
    out[:, 4] = t0 + qw * u0 + c0 + x[:, 4]
    out[:, 5] = t1 + qw * u1 + c1 + x[:, 5]
    out[:, 6] = t2 + qw * u2 + c2 + x[:, 6]
    return out


#: By group id (SO2, SE2, SO3, SE3); Sim(3) (id 4) has none.
RETRACT_NUMPY = (so2_retract, se2_retract, so3_retract, se3_retract, None)
