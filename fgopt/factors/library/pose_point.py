"""Pose-to-point factors: a landmark position measured in the pose's frame (g2o's
``EDGE_SE2_XY`` and ``EDGE_SE3_TRACKXYZ``).

Residual, with ``world_T_pose = (R, t)``, landmark ``world_p`` and measurement ``m``::

    e = R^T (world_p - t) - m          (2 or 3 rows)

Jacobians for right perturbations ``pose * Exp([w, v])`` (rotation first, the groups' retract)
and ``world_p + d``. With ``p = R^T (world_p - t)``, to first order the perturbed pose gives
``Exp(w)^T (p - v)``, so

* 2D: ``de/dtheta = (p_y, -p_x)``, ``de/dv = -I``, ``de/dworld_p = R^T``;
* 3D: ``de/dw = hat(p)`` (as ``-w x p = p x w``), ``de/dv = -I``, ``de/dworld_p = R^T``.

Kernels follow :class:`fgopt.factors.kernel.FactorKernel`: args ``(pose, point)``, constants
``m``; one object per dimension (cached), so all such factors batch together.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any

import numpy as np
from ..._jit import njit

from ...errors import DimensionMismatchError
from ...manifolds.base import vector_kind
from ..base import KernelFactor
from ..kernel import FactorKernel
from ...noise.models import Loss

_SOURCE = "hand-written in fgopt/factors/library/pose_point.py"


@njit(cache=True)
def pose2_point_batch(pose, point, m, with_jac):
    """``pose (n, 4)`` SE2 storage, ``point (n, 2)``, ``m (n, 2)`` -> res (n, 2), jac (n, 2, 5)."""
    n = pose.shape[0]
    res = np.empty((n, 2))
    jac = np.zeros((n if with_jac else 0, 2, 5))
    for i in range(n):
        c, s = pose[i, 0], pose[i, 1]
        dx = point[i, 0] - pose[i, 2]
        dy = point[i, 1] - pose[i, 3]
        px = c * dx + s * dy
        py = -s * dx + c * dy
        res[i, 0] = px - m[i, 0]
        res[i, 1] = py - m[i, 1]
        if with_jac:
            J = jac[i]
            J[0, 0] = py
            J[1, 0] = -px
            J[0, 1] = -1.0
            J[1, 2] = -1.0
            J[0, 3] = c
            J[0, 4] = s
            J[1, 3] = -s
            J[1, 4] = c
    return res, jac


@njit(cache=True)
def _rotation(q, R):
    """Rotation matrix of the unit quaternion ``q = (x, y, z, w)``."""
    x, y, z, w = q[0], q[1], q[2], q[3]
    R[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    R[0, 1] = 2.0 * (x * y - z * w)
    R[0, 2] = 2.0 * (x * z + y * w)
    R[1, 0] = 2.0 * (x * y + z * w)
    R[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    R[1, 2] = 2.0 * (y * z - x * w)
    R[2, 0] = 2.0 * (x * z - y * w)
    R[2, 1] = 2.0 * (y * z + x * w)
    R[2, 2] = 1.0 - 2.0 * (x * x + y * y)


@njit(cache=True)
def pose3_point_batch(pose, point, m, with_jac):
    """``pose (n, 7)`` SE3 storage, ``point (n, 3)``, ``m (n, 3)`` -> res (n, 3), jac (n, 3, 9)."""
    n = pose.shape[0]
    res = np.empty((n, 3))
    jac = np.zeros((n if with_jac else 0, 3, 9))
    R = np.empty((3, 3))
    d = np.empty(3)
    p = np.empty(3)
    for i in range(n):
        _rotation(pose[i, :4], R)
        for k in range(3):
            d[k] = point[i, k] - pose[i, 4 + k]
        for r in range(3):  # p = R^T d
            p[r] = R[0, r] * d[0] + R[1, r] * d[1] + R[2, r] * d[2]
            res[i, r] = p[r] - m[i, r]
        if with_jac:
            J = jac[i]
            # hat(p) = [[0, -pz, py], [pz, 0, -px], [-py, px, 0]]
            J[0, 1] = -p[2]
            J[0, 2] = p[1]
            J[1, 0] = p[2]
            J[1, 2] = -p[0]
            J[2, 0] = -p[1]
            J[2, 1] = p[0]
            for r in range(3):
                J[r, 3 + r] = -1.0
                for c in range(3):
                    J[r, 6 + c] = R[c, r]
    return res, jac


def _prepared(name: str, args: tuple, consts: np.ndarray, sdim: int, pdim: int):
    if len(args) != 2:
        raise DimensionMismatchError(f"{name}: expected 2 argument arrays, got {len(args)}")
    pose = np.ascontiguousarray(args[0], dtype=np.float64)
    point = np.ascontiguousarray(args[1], dtype=np.float64)
    c = np.ascontiguousarray(consts, dtype=np.float64)
    n = pose.shape[0] if pose.ndim == 2 else -1
    if (pose.shape != (n, sdim) or point.shape != (n, pdim) or c.shape != (n, pdim)):
        raise DimensionMismatchError(
            f"{name}: expected pose ({n}, {sdim}), point ({n}, {pdim}), constants ({n}, {pdim}); "
            f"got {pose.shape}, {point.shape}, {c.shape}")
    return pose, point, c


@lru_cache(maxsize=None)
def pose_point_kernel(dim: int) -> FactorKernel:
    """The kernel of pose-to-point factors in 2D (``dim=2``, SE2) or 3D (``dim=3``, SE3)."""
    from ...manifolds import SE2, SE3

    if dim == 2:
        pose_kind, fn = SE2.batch_kind(), pose2_point_batch
    elif dim == 3:
        pose_kind, fn = SE3.batch_kind(), pose3_point_batch
    else:
        raise DimensionMismatchError(f"pose_point_kernel: dim must be 2 or 3, got {dim}")
    name = f"pose_point_{pose_kind.name.lower()}"
    sdim = pose_kind.storage_dim

    def run(args, consts, with_jac):
        pose, point, c = _prepared(name, args, consts, sdim, dim)
        return fn(pose, point, c, with_jac)

    return FactorKernel(name, (pose_kind, vector_kind(dim)), dim, dim,
                        residual=lambda args, consts: run(args, consts, False)[0],
                        linearize=lambda args, consts: run(args, consts, True),
                        source=_SOURCE, recipe=(pose_point_kernel, (dim,)))


class PosePointFactor(KernelFactor):
    """``PosePointFactor(pose_key, point_key, measured, loss)``: ``measured`` is the point's
    position in the pose's frame (2 numbers with an SE2 pose, 3 with an SE3 pose)."""

    def __init__(self, pose_key: int, point_key: int, measured: Any, loss: Loss | None = None):
        m = np.asarray(measured, dtype=float).reshape(-1)
        if m.shape[0] not in (2, 3):
            raise DimensionMismatchError(
                f"PosePointFactor: measured must have 2 (SE2) or 3 (SE3) entries, got {m.shape[0]}")
        self.measured = m
        super().__init__(pose_point_kernel(m.shape[0]), [pose_key, point_key], m, loss)
