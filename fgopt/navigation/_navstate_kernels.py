"""Numba kernels of :class:`~fgopt.navigation.NavState`: per-element operations and batched loops.

Storage ``[qx, qy, qz, qw, px, py, pz, vx, vy, vz]`` (unit quaternion of ``world_R_body``, then
position and velocity in the world frame); tangent ``[rotation(3), position(3), velocity(3)]``.

Two sets of coordinates, as GTSAM's ``NavState``:

* the *chart* used by the optimizer (``retract`` / ``local``), a product of SO(3) with body-frame
  position and velocity increments::

      retract((R, p, v), [dR, dP, dV]) = (R Exp(dR), p + R dP, v + R dV)
      local(a, b) = [Log(Ra^T Rb), Ra^T (pb - pa), Ra^T (vb - va)]

* the group SE_2(3) (``compose``, ``inverse``, ``exp``, ``log``), the 5x5 matrices
  ``[[R, p, v], [0, 1, 0], [0, 0, 1]]``: ``a * b = (Ra Rb, Ra pb + pa, Ra vb + va)`` and
  ``Exp([w, rho, nu]) = (Exp(w), Jl(w) rho, Jl(w) nu)`` with the SO(3) left Jacobian
  ``Jl = I + (1 - cos t)/t^2 W + (t - sin t)/t^3 W^2`` (as ``V`` of SE(3)).

To first order the chart and ``x * Exp(d)`` agree, so tangent-space Jacobians are the same for
both. The SO(3) pieces (quaternion products, Exp / Log with their series near angle 0 and no
division by ``sin`` near pi) are those of :mod:`fgopt.manifolds._kernels`.
"""

from __future__ import annotations

import numpy as np
from .._jit import njit

from ..manifolds._kernels import (
    quat_mul,
    quat_normalize,
    quat_rotate,
    skew_poly_apply,
    so3_coeffs,
    so3_exp,
    so3_log,
)

STORAGE_DIM = 9 + 1
DIM = 9


@njit(cache=True)
def navstate_compose(a, b, out):
    """out = a * b in SE_2(3) (out must not alias a or b)."""
    quat_mul(a, b, out)
    quat_normalize(out)
    quat_rotate(a, b[4:7], out[4:7])
    quat_rotate(a, b[7:10], out[7:10])
    for i in range(4, 10):
        out[i] += a[i]


@njit(cache=True)
def navstate_inverse(a, out):
    """out = a^-1 = (R^T, -R^T p, -R^T v)."""
    out[0], out[1], out[2], out[3] = -a[0], -a[1], -a[2], a[3]
    quat_rotate(a, a[4:7], out[4:7], -1.0)
    quat_rotate(a, a[7:10], out[7:10], -1.0)
    for i in range(4, 10):
        out[i] = -out[i]


@njit(cache=True)
def navstate_exp(xi, out):
    """out = Exp(xi) of SE_2(3), xi = [w, rho, nu]."""
    so3_exp(xi, out)
    a, b, _ = so3_coeffs(xi[0] * xi[0] + xi[1] * xi[1] + xi[2] * xi[2])
    skew_poly_apply(xi, 1.0, a, b, xi[3:6], out[4:7])
    skew_poly_apply(xi, 1.0, a, b, xi[6:9], out[7:10])


@njit(cache=True)
def navstate_log(x, out):
    """out = Log(x) of SE_2(3): [w, Jl(w)^-1 p, Jl(w)^-1 v], |w| <= pi."""
    so3_log(x, out)
    _, _, c = so3_coeffs(out[0] * out[0] + out[1] * out[1] + out[2] * out[2])
    skew_poly_apply(out, 1.0, -0.5, c, x[4:7], out[3:6])
    skew_poly_apply(out, 1.0, -0.5, c, x[7:10], out[6:9])


@njit(cache=True)
def navstate_retract(x, d, out, tmp):
    """out = retract(x, d) in the chart (module docstring); ``tmp``: scratch of length >= 4."""
    so3_exp(d, tmp)
    quat_mul(x, tmp, out)
    quat_normalize(out)
    quat_rotate(x, d[3:6], out[4:7])
    quat_rotate(x, d[6:9], out[7:10])
    for i in range(4, 10):
        out[i] += x[i]


@njit(cache=True)
def navstate_local(a, b, out, tmp):
    """out = local(a, b) in the chart; ``tmp``: scratch of length >= 4."""
    tmp[0], tmp[1], tmp[2], tmp[3] = -a[0], -a[1], -a[2], a[3]
    q = np.empty(4)
    quat_mul(tmp, b, q)
    so3_log(q, out)
    for i in range(3):
        tmp[i] = b[4 + i] - a[4 + i]
    quat_rotate(a, tmp, out[3:6], -1.0)
    for i in range(3):
        tmp[i] = b[7 + i] - a[7 + i]
    quat_rotate(a, tmp, out[6:9], -1.0)


@njit(cache=True)
def navstate_retract_loop(x, d):
    """(n, 10), (n, 9) -> (n, 10): row-wise chart retraction."""
    out = np.empty((x.shape[0], STORAGE_DIM))
    tmp = np.empty(4)
    for i in range(x.shape[0]):
        navstate_retract(x[i], d[i], out[i], tmp)
    return out


@njit(cache=True)
def navstate_local_loop(a, b):
    """(n, 10), (n, 10) -> (n, 9): row-wise chart local coordinates."""
    out = np.empty((a.shape[0], DIM))
    tmp = np.empty(4)
    for i in range(a.shape[0]):
        navstate_local(a[i], b[i], out[i], tmp)
    return out


def navstate_retract_batch(x: np.ndarray, d: np.ndarray) -> np.ndarray:
    """``BatchKind.retract`` of NavState: C-contiguous float64 inputs (no recompilation)."""
    return navstate_retract_loop(np.ascontiguousarray(x, dtype=np.float64),
                                 np.ascontiguousarray(d, dtype=np.float64))


def navstate_local_batch(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``BatchKind.local`` of NavState."""
    return navstate_local_loop(np.ascontiguousarray(a, dtype=np.float64),
                               np.ascontiguousarray(b, dtype=np.float64))
