"""SE(2) kernels: storage [cos, sin, x, y], tangent [theta, vx, vy].

Part of :mod:`fgopt.manifolds._kernels` (conventions in its docstring).
"""

from __future__ import annotations

import math

from ..._jit import njit

from .so2 import so2_compose
from .so3 import so3_coeffs


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
