"""Hand-written batched kernel of the BAL reprojection error (Snavely camera).

Camera ``c = [r(3), t(3), f, k1, k2]`` in R^9 (angle-axis ``r``), point ``X`` in R^3,
measurement ``m`` (pixels)::

    P = R(r) X + t,   p = -P[:2] / P[2],   r2 = |p|^2,   d = 1 + k1 r2 + k2 r2^2
    e = f d p - m

This is the cost of the BAL paper and Ceres' ``SnavelyReprojectionError``. Both arguments are
plain vectors, so Jacobians are ordinary derivatives. For the rotation,
``R(r + delta) = Exp(Jl(r) delta) R(r)`` to first order, hence
``d(R X)/dr = -hat(R X) Jl(r)`` with the left Jacobian
``Jl = I + (1 - cos t)/t^2 hat(r) + (t - sin t)/t^3 hat(r)^2`` (series near ``t = 0``).
Then ``dP/dt = I``, ``dP/dX = R``, ``dp/dP = [[-1/Pz, 0, Px/Pz^2], [0, -1/Pz, Py/Pz^2]]``,
``de/dp = f (d I + 2 (k1 + 2 k2 r2) p p^T)``, ``de/df = d p``, ``de/dk1 = f r2 p``,
``de/dk2 = f r2^2 p``. Jacobian columns: camera ``[r, t, f, k1, k2]`` then point ``X``.

Points behind the camera are not special-cased (GTSAM zeroes them; BENCHMARKS.md counts them).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from ..._jit import njit

from ...errors import DimensionMismatchError
from ...manifolds.base import vector_kind
from ..kernel import FactorKernel

_SOURCE = "hand-written in fgopt/factors/library/bal_kernel.py"


@njit(cache=True)
def _hat_sq_coeffs(t2):
    """``a = sin t / t``, ``b = (1 - cos t) / t^2``, ``c = (t - sin t) / t^3`` (series at 0)."""
    if t2 < 1e-8:
        return 1.0 - t2 / 6.0, 0.5 - t2 / 24.0, 1.0 / 6.0 - t2 / 120.0
    t = math.sqrt(t2)
    s, co = math.sin(t), math.cos(t)
    return s / t, (1.0 - co) / t2, (t - s) / (t2 * t)


@njit(cache=True)
def bal_batch(cam, pt, m, with_jac):
    """``cam (n, 9)``, ``pt (n, 3)``, ``m (n, 2)`` -> res ``(n, 2)``, jac ``(n, 2, 12)``."""
    n = cam.shape[0]
    res = np.empty((n, 2))
    jac = np.zeros((n if with_jac else 0, 2, 12))
    H = np.empty((3, 3))
    R = np.empty((3, 3))
    Jl = np.empty((3, 3))
    dPdr = np.empty((3, 3))
    P = np.empty(3)
    RX = np.empty(3)
    for i in range(n):
        r0, r1, r2_ = cam[i, 0], cam[i, 1], cam[i, 2]
        t2 = r0 * r0 + r1 * r1 + r2_ * r2_
        a, b, c = _hat_sq_coeffs(t2)
        # hat(r) and hat(r)^2 = r r^T - t2 I
        H[0, 0], H[0, 1], H[0, 2] = 0.0, -r2_, r1
        H[1, 0], H[1, 1], H[1, 2] = r2_, 0.0, -r0
        H[2, 0], H[2, 1], H[2, 2] = -r1, r0, 0.0
        rv = (r0, r1, r2_)
        for p in range(3):
            for q in range(3):
                h2 = rv[p] * rv[q] - (t2 if p == q else 0.0)
                eye = 1.0 if p == q else 0.0
                R[p, q] = eye + a * H[p, q] + b * h2
                Jl[p, q] = eye + b * H[p, q] + c * h2
        for p in range(3):
            RX[p] = R[p, 0] * pt[i, 0] + R[p, 1] * pt[i, 1] + R[p, 2] * pt[i, 2]
            P[p] = RX[p] + cam[i, 3 + p]
        iz = 1.0 / P[2]
        px = -P[0] * iz
        py = -P[1] * iz
        f, k1, k2 = cam[i, 6], cam[i, 7], cam[i, 8]
        rr = px * px + py * py
        d = 1.0 + k1 * rr + k2 * rr * rr
        res[i, 0] = f * d * px - m[i, 0]
        res[i, 1] = f * d * py - m[i, 1]
        if not with_jac:
            continue
        J = jac[i]
        g = 2.0 * (k1 + 2.0 * k2 * rr)
        # de/dp (2x2) then de/dP = de/dp @ dp/dP (2x3)
        e00 = f * (d + g * px * px)
        e01 = f * g * px * py
        e11 = f * (d + g * py * py)
        dpdP00 = -iz
        dpdP02 = P[0] * iz * iz
        dpdP11 = -iz
        dpdP12 = P[1] * iz * iz
        A = np.empty((2, 3))
        A[0, 0] = e00 * dpdP00
        A[0, 1] = e01 * dpdP11
        A[0, 2] = e00 * dpdP02 + e01 * dpdP12
        A[1, 0] = e01 * dpdP00
        A[1, 1] = e11 * dpdP11
        A[1, 2] = e01 * dpdP02 + e11 * dpdP12
        # dP/dr = -hat(RX) Jl
        hx, hy, hz = RX[0], RX[1], RX[2]
        for q in range(3):
            dPdr[0, q] = -(-hz * Jl[1, q] + hy * Jl[2, q])
            dPdr[1, q] = -(hz * Jl[0, q] - hx * Jl[2, q])
            dPdr[2, q] = -(-hy * Jl[0, q] + hx * Jl[1, q])
        for row in range(2):
            for q in range(3):
                J[row, q] = (A[row, 0] * dPdr[0, q] + A[row, 1] * dPdr[1, q]
                             + A[row, 2] * dPdr[2, q])
                J[row, 3 + q] = A[row, q]
                J[row, 9 + q] = A[row, 0] * R[0, q] + A[row, 1] * R[1, q] + A[row, 2] * R[2, q]
        J[0, 6] = d * px
        J[1, 6] = d * py
        J[0, 7] = f * rr * px
        J[1, 7] = f * rr * py
        J[0, 8] = f * rr * rr * px
        J[1, 8] = f * rr * rr * py
    return res, jac


def _prepared(args: tuple, consts: np.ndarray):
    if len(args) != 2:
        raise DimensionMismatchError(
            f"bal_reprojection: expected 2 argument arrays, got {len(args)}")
    cam = np.ascontiguousarray(args[0], dtype=np.float64)
    pt = np.ascontiguousarray(args[1], dtype=np.float64)
    c = np.ascontiguousarray(consts, dtype=np.float64)
    n = cam.shape[0] if cam.ndim == 2 else -1
    if cam.shape != (n, 9) or pt.shape != (n, 3) or c.shape != (n, 2):
        raise DimensionMismatchError(
            f"bal_reprojection: expected camera ({n}, 9), point ({n}, 3), constants ({n}, 2); got "
            f"{cam.shape}, {pt.shape}, {c.shape}")
    return cam, pt, c


@lru_cache(maxsize=None)
def bal_kernel() -> FactorKernel:
    """The BAL reprojection kernel: args ``(camera R^9, point R^3)``, constants ``m (2,)``."""

    def run(args, consts, with_jac):
        cam, pt, c = _prepared(args, consts)
        return bal_batch(cam, pt, c, with_jac)

    return FactorKernel("bal_reprojection", (vector_kind(9), vector_kind(3)), 2, 2,
                        residual=lambda args, consts: run(args, consts, False)[0],
                        linearize=lambda args, consts: run(args, consts, True),
                        source=_SOURCE, recipe=(bal_kernel, ()))
