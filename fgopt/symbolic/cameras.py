"""Symbolic camera models: the BAL / Snavely camera and a pinhole camera.

Cameras are not manifold types of their own: a BAL camera is an R^9 variable (``V9``, additive
retraction as in Ceres) and a pinhole calibration is a ``V4`` constant; these classes give the
projection functions over such vectors.
"""

from __future__ import annotations

from typing import Any

from .lie import as_vector


def _s():
    from . import _sym

    return _sym


def _eps(epsilon: Any):
    return _s().epsilon if epsilon is None else _s().as_expr(epsilon)


def angle_axis_rotate(r: Any, point: Any, epsilon: Any = None):
    """Rotate ``point`` by the angle-axis vector ``r`` (Rodrigues), branchless.

    ``R X = X cos t + (r x X) sin t / t + r (r . X) (1 - cos t) / t^2`` with
    ``t = sqrt(|r|^2 + epsilon^2)`` (``1 - cos t`` written as ``2 sin^2(t/2)``); the coefficients
    multiply terms that vanish with ``r``, so value and gradient are exact at ``r = 0``.

    >>> from fgopt.symbolic import V3, angle_axis_rotate
    >>> X = angle_axis_rotate(V3(0, 0, np.pi / 2), V3(1, 0, 0), epsilon=0)   # 90 deg about z
    >>> [round(float(c), 6) for c in X]
    [0.0, 1.0, 0.0]
    """
    sp = _s().sp
    r = as_vector(r, 3, "angle_axis_rotate r")
    x = as_vector(point, 3, "angle_axis_rotate point")
    theta = sp.sqrt(r.squared_norm() + _eps(epsilon) ** 2)
    a = sp.sin(theta) / theta
    b = 2 * sp.sin(theta / 2) ** 2 / theta**2
    return x * sp.cos(theta) + r.cross(x) * a + r * (r.dot(x) * b)


class SnavelyCamera:
    """The Bundle Adjustment in the Large camera, stored as 9 numbers.

    Storage ``[r (angle-axis, 3), t (3), f, k1, k2]``. Projection (the BAL convention): ``P = R X
    + t``, ``p = -P_xy / P_z`` (points in front of the camera have negative ``z``),
    ``r2 = |p|^2``, ``u = f (1 + k1 r2 + k2 r2^2) p``. The division by ``P_z`` is shifted by
    ``snz(P_z) epsilon`` so that it never produces inf/NaN.

    >>> from fgopt.symbolic import SnavelyCamera, V3
    >>> cam = SnavelyCamera([0, 0, 0, 0, 0, 0, 500.0, 0.1, 0])   # r = t = 0, f = 500, k1 = 0.1
    >>> cam.project(V3(0.1, -0.2, -1.0), epsilon=0)          # 500 (1 + 0.1 * 0.05) (0.1, -0.2)
    V2([[50.2500000000000], [-100.500000000000]])
    """

    STORAGE_DIM = 9

    def __init__(self, storage: Any):
        v = as_vector(storage, 9, "SnavelyCamera")
        vals = list(v)
        self.r = as_vector(vals[0:3], 3, "")
        self.t = as_vector(vals[3:6], 3, "")
        self.f, self.k1, self.k2 = vals[6], vals[7], vals[8]

    @classmethod
    def from_storage(cls, storage: Any) -> SnavelyCamera:
        return cls(storage)

    def to_storage(self) -> list:
        return list(self.r) + list(self.t) + [self.f, self.k1, self.k2]

    def transform(self, point: Any, epsilon: Any = None):
        """World point -> camera frame: ``P = R(r) X + t``."""
        return angle_axis_rotate(self.r, point, epsilon) + self.t

    def project(self, point: Any, epsilon: Any = None):
        """Pixel ``u`` (``V2``) of a world point ``X``."""
        from .matrix import V2

        s = _s()
        p_cam = self.transform(point, epsilon)
        pz = p_cam[2]
        inv_z = -1 / (pz + s.snz(pz) * _eps(epsilon))
        p = V2(p_cam[0] * inv_z, p_cam[1] * inv_z)
        r2 = p.squared_norm()
        distortion = 1 + r2 * (self.k1 + self.k2 * r2)
        return p * (self.f * distortion)


class PinholeCamera:
    """A pinhole camera with calibration ``[fx, fy, cx, cy]`` (z forward, x right, y down).

    ``project(P_cam) = [fx P_x / P_z + cx, fy P_y / P_z + cy]``; the division is shifted by
    ``snz(P_z) epsilon``.

    >>> from fgopt.symbolic import PinholeCamera, V3
    >>> PinholeCamera([500.0, 500.0, 320.0, 240.0]).project(V3(0.1, -0.2, 1.0), epsilon=0)
    V2([[370.000000000000], [140.000000000000]])
    """

    STORAGE_DIM = 4

    def __init__(self, calibration: Any):
        fx, fy, cx, cy = list(as_vector(calibration, 4, "PinholeCamera calibration"))
        self.fx, self.fy, self.cx, self.cy = fx, fy, cx, cy

    @classmethod
    def from_storage(cls, storage: Any) -> PinholeCamera:
        return cls(storage)

    def to_storage(self) -> list:
        return [self.fx, self.fy, self.cx, self.cy]

    def project(self, point_in_camera: Any, epsilon: Any = None):
        from .matrix import V2

        s = _s()
        p = as_vector(point_in_camera, 3, "PinholeCamera.project")
        inv_z = 1 / (p[2] + s.snz(p[2]) * _eps(epsilon))
        return V2(self.fx * p[0] * inv_z + self.cx, self.fy * p[1] * inv_z + self.cy)

    def project_world(self, world_T_camera: Any, point: Any, epsilon: Any = None):
        """Pixel of world ``point`` seen by a camera with pose ``world_T_camera`` (a Pose3)."""
        return self.project(world_T_camera.inverse() * point, epsilon)
