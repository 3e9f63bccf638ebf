"""SO(2) kernels: storage [cos, sin], tangent [theta].

Part of :mod:`fgopt.manifolds._kernels` (conventions in its docstring).
"""

from __future__ import annotations

import math

from ..._jit import njit


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
