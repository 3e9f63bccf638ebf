"""Numeric cameras: ``PinholeCamera(pose, calibration)`` and ``StereoCamera(pose, calibration)``.

Conventions (GTSAM's): ``pose`` is ``world_T_camera`` (an :class:`~fgopt.manifolds.SE3`, the
camera in the world); the camera looks along its +z axis with x to the right and y down in the
image. A world point ``X`` is at ``p = R^T (X - t)`` in the camera and projects to
``uncalibrate(p_x / p_z, p_y / p_z)``. Jacobians are with respect to the pose's right
perturbation ``pose * Exp([w, v])`` (fgopt's SE3 retract, rotation first) and the calibration's
tangent (see :mod:`fgopt.cameras._projection_kernels`).

``project`` takes one point ``(3,)`` or many ``(n, 3)``; a point with ``p_z <= 0`` (behind the
camera) raises :class:`~fgopt.errors.CheiralityError` naming its index.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any

import numpy as np

from .._jit import specialize
from ..errors import (CheiralityError, DimensionMismatchError, FgoptError, ManifoldError,
                      NonFiniteError)
from ..manifolds import SE3, SO3
from ..manifolds.base import BatchKind, register
from . import _projection_kernels as PK
from .._checks import float_array
from .calibration import Cal3_S2, Cal3_S2Stereo, Calibration, as_points2


def as_points3(values: Any, what: str) -> tuple[np.ndarray, bool]:
    """``(n, 3)`` float array of ``values`` (one ``(3,)`` point or many), and whether it was one."""
    a = float_array(values, what, "a (3,) point or an (n, 3) array of numbers")
    single = a.ndim == 1
    a = np.ascontiguousarray(a.reshape(1, -1) if single else a)
    if a.ndim != 2 or a.shape[1] != 3:
        raise DimensionMismatchError(f"{what}: expected a (3,) point or an (n, 3) array, got "
                                     f"shape {np.shape(values)}")
    if not np.all(np.isfinite(a)):
        i = int(np.nonzero(~np.all(np.isfinite(a), axis=1))[0][0])
        raise NonFiniteError(f"{what}: point {i} has a NaN or inf: {a[i]}")
    return a, single


def _check_pose(pose: Any, what: str) -> SE3:
    if not isinstance(pose, SE3):
        raise FgoptError(f"{what}: pose must be an fgopt.manifolds.SE3 (world_T_camera), got "
                         f"{type(pose).__name__}")
    return pose


def _raise_status(status: np.ndarray, pts: np.ndarray, pose: SE3, what: str) -> None:
    bad = status != PK.OK
    if np.any(bad):
        i = int(np.nonzero(bad)[0][0])
        z = (pose.inverse() * pts[i])[2]
        if status[i] == PK.BEHIND:
            raise CheiralityError(f"{what}: point {i} {pts[i]} is behind the camera (depth "
                                  f"{z:.4g} <= 0)")
        raise CheiralityError(f"{what}: point {i} {pts[i]} is outside the lens model's valid "
                              "region")


class PinholeCamera:
    """A calibrated camera at ``pose = world_T_camera`` (z forward, x right, y down).

    ``PinholeCamera(pose, calibration)`` with any :class:`~fgopt.cameras.Calibration`. It is also
    a manifold (GTSAM's ``PinholeCamera<Cal>``: a variable holding pose and calibration, e.g. a
    BAL camera): storage ``[qx, qy, qz, qw, tx, ty, tz, k...]``, tangent ``[w, v, dk]``,
    ``retract(d) = (pose * Exp(d[:6]), calibration + d[6:])``.

    Example:

    >>> from fgopt import SE3
    >>> from fgopt.cameras import Cal3_S2, PinholeCamera
    >>> cam = PinholeCamera(SE3(), Cal3_S2(500.0, 500.0, 0.0, 320.0, 240.0))
    >>> cam.project(np.array([0.2, -0.4, 2.0]))
    array([370., 140.])
    >>> cam.backproject(np.array([370.0, 140.0]), 2.0)
    array([ 0.2, -0.4,  2. ])
    """

    __slots__ = ("_pose", "_calibration", "_R")

    def __init__(self, pose: SE3 | None = None, calibration: Calibration | None = None):
        pose = SE3() if pose is None else _check_pose(pose, "PinholeCamera")
        calibration = Cal3_S2(1.0, 1.0, 0.0, 0.0, 0.0) if calibration is None else calibration
        if not isinstance(calibration, Calibration):
            raise FgoptError(f"PinholeCamera: calibration must be a Calibration (Cal3_S2, "
                             f"Cal3DS2, ...), got {type(calibration).__name__}")
        self._pose, self._calibration = pose, calibration
        self._R = np.ascontiguousarray(pose.rotation().matrix())

    def pose(self) -> SE3:
        return self._pose

    def calibration(self) -> Calibration:
        return self._calibration

    @classmethod
    def lookat(cls, eye: Any, target: Any, up: Any,
               calibration: Calibration | None = None) -> PinholeCamera:
        """A camera at ``eye`` looking at ``target``, with ``up`` pointing up in the image
        (GTSAM's ``Lookat``: ``z = (target - eye) / |.|``, ``x = (-up) x z / |.|``,
        ``y = z x x``)."""
        vecs = []
        for name, v in (("eye", eye), ("target", target), ("up", up)):
            a = float_array(v, f"PinholeCamera.lookat: {name}", "3 numbers")
            if a.shape != (3,):
                raise DimensionMismatchError(f"PinholeCamera.lookat: {name} must be a 3-vector, "
                                             f"got shape {a.shape}")
            if not np.all(np.isfinite(a)):
                raise NonFiniteError(f"PinholeCamera.lookat: {name} has a NaN or inf: {a}")
            vecs.append(a)
        eye, target, up = vecs
        z = target - eye
        nz = np.linalg.norm(z)
        if not nz > 0.0:
            raise FgoptError("PinholeCamera.lookat: eye and target coincide")
        z = z / nz
        x = np.cross(-up, z)
        nx = np.linalg.norm(x)
        if not nx > 1e-12:
            raise FgoptError("PinholeCamera.lookat: up is parallel to the viewing direction")
        x = x / nx
        y = np.cross(z, x)
        return cls(SE3(SO3.from_matrix(np.column_stack([x, y, z])), eye), calibration)

    def project(self, points: Any, jacobians: bool = False):
        """Pixels of world ``points`` (``(3,)`` or ``(n, 3)``).

        With ``jacobians=True`` returns ``(uv, uv_D_pose (.., 2, 6), uv_D_point (.., 2, 3),
        uv_D_calibration (.., 2, dim))``. Raises :class:`CheiralityError` for a point behind
        the camera (or outside the lens model's valid region), naming its index.
        """
        pts, single = as_points3(points, "PinholeCamera.project")
        k = self._calibration
        uv, Dpose, Dpoint, Dk, status = specialize(PK.project_points, k.MODEL)(
            self._R, np.ascontiguousarray(self._pose.translation()), k._data, pts, True,
            bool(jacobians))
        _raise_status(status, pts, self._pose, "PinholeCamera.project")
        if not jacobians:
            return uv[0] if single else uv
        if single:
            return uv[0], Dpose[0], Dpoint[0], Dk[0]
        return uv, Dpose, Dpoint, Dk

    def backproject(self, uv: Any, depth: Any) -> np.ndarray:
        """World points at ``depth`` (along the optical axis) through pixels ``uv``:
        ``pose * (depth * (x, y, 1))`` with ``(x, y) = calibrate(uv)``.

        ``depth`` is one number or one per pixel, finite and > 0 (else
        :class:`NonFiniteError` / :class:`CheiralityError` naming its index)."""
        what = "PinholeCamera.backproject"
        pix, single = as_points2(uv, what)
        d = float_array(depth, what, "a number per pixel").reshape(-1)
        n = pix.shape[0]
        if d.shape[0] == 1:
            d = np.full(n, d[0])
        elif d.shape[0] != n:
            raise DimensionMismatchError(f"{what}: depth must be one number or one per pixel "
                                         f"({n}), got {d.shape[0]} numbers")
        bad = ~np.isfinite(d)
        if np.any(bad):
            i = int(np.nonzero(bad)[0][0])
            raise NonFiniteError(f"{what}: depth {i} is {d[i]}")
        bad = ~(d > 0.0)
        if np.any(bad):
            i = int(np.nonzero(bad)[0][0])
            raise CheiralityError(f"{what}: depth {i} is {d[i]:g}; it must be > 0 (a point in "
                                  "front of the camera)")
        xy = np.atleast_2d(self._calibration.calibrate(pix))
        pc = np.column_stack([xy * d[:, None], d])
        out = self._pose * pc
        return out[0] if single else out

    def projection_matrix(self) -> np.ndarray:
        """``K [R^T | -R^T t]`` (3 x 4) of the linear part (GTSAM's ``cameraProjectionMatrix``)."""
        R, t = self._R, self._pose.translation()
        return self._calibration.K() @ np.column_stack([R.T, -R.T @ t])

    # ------------------------------------------------------------------ manifold (GTSAM's)
    def dim(self) -> int:
        """Tangent dimension ``6 + calibration.dim()``: pose ``[w, v]`` then calibration."""
        return 6 + self._calibration.DIM

    def to_storage(self) -> np.ndarray:
        """``[qx, qy, qz, qw, tx, ty, tz, calibration storage...]``."""
        return np.concatenate([self._pose.to_storage(), self._calibration._data])

    def retract(self, delta: Any) -> PinholeCamera:
        """``(pose * Exp(delta[:6]), calibration + delta[6:])`` (GTSAM's PinholeCamera retract)."""
        d = np.asarray(delta, dtype=float).reshape(-1)
        if d.shape[0] != self.dim():
            raise DimensionMismatchError(f"PinholeCamera.retract: delta must have {self.dim()} "
                                         f"entries, got {d.shape[0]}")
        return PinholeCamera(self._pose.retract(d[:6]), self._calibration.retract(d[6:]))

    def local(self, other: PinholeCamera) -> np.ndarray:
        if not isinstance(other, PinholeCamera):
            raise ManifoldError(f"PinholeCamera.local: expected a PinholeCamera, got "
                                f"{type(other).__name__}")
        return np.concatenate([self._pose.local(other.pose()),
                               self._calibration.local(other.calibration())])

    @classmethod
    def batch_kind_of(cls, model: type[Calibration]) -> BatchKind:
        """The batch kind of cameras with calibration ``model`` (one per model)."""
        return _camera_kind(model)

    def __repr__(self) -> str:
        return f"PinholeCamera({self._pose!r}, {self._calibration!r})"


class StereoCamera:
    """A rectified stereo pair: the left camera at ``pose = world_T_camera`` (z forward), the
    right one ``b`` along its x axis, both with ``Cal3_S2Stereo`` intrinsics.

    ``project(X) = (uL, uR, v)`` with ``uL = u0 + fx x / z``, ``uR = u0 + fx (x - b) / z``,
    ``v = v0 + fy y / z`` for ``(x, y, z) = pose^-1 X`` (skew ignored, as GTSAM's).

    >>> from fgopt.cameras import Cal3_S2Stereo, StereoCamera
    >>> camera = StereoCamera(fgopt.SE3(), Cal3_S2Stereo(500.0, 500.0, 0.0, 320.0, 240.0, 0.2))
    >>> camera.project(np.array([1.0, 0.5, 5.0]))            # (uL, uR, v)
    array([420., 400., 290.])
    >>> np.round(camera.backproject(np.array([420.0, 400.0, 290.0])), 9)
    array([1. , 0.5, 5. ])
    """

    __slots__ = ("_pose", "_calibration", "_R")

    def __init__(self, pose: SE3, calibration: Cal3_S2Stereo):
        self._pose = _check_pose(pose, "StereoCamera")
        if not isinstance(calibration, Cal3_S2Stereo):
            raise FgoptError(f"StereoCamera: calibration must be a Cal3_S2Stereo, got "
                             f"{type(calibration).__name__}")
        self._calibration = calibration
        self._R = np.ascontiguousarray(pose.rotation().matrix())

    def pose(self) -> SE3:
        return self._pose

    def calibration(self) -> Cal3_S2Stereo:
        return self._calibration

    def baseline(self) -> float:
        return self._calibration.baseline()

    def project(self, points: Any, jacobians: bool = False):
        """``(uL, uR, v)`` of world ``points`` (``(3,)`` or ``(n, 3)``); with ``jacobians=True``
        also ``D_pose (.., 3, 6)``, ``D_point (.., 3, 3)``, ``D_calibration (.., 3, 6)``."""
        pts, single = as_points3(points, "StereoCamera.project")
        out, Dpose, Dpoint, Dk, status = PK.stereo_points(
            self._R, np.ascontiguousarray(self._pose.translation()), self._calibration._data,
            pts, True, bool(jacobians))
        _raise_status(status, pts, self._pose, "StereoCamera.project")
        if not jacobians:
            return out[0] if single else out
        if single:
            return out[0], Dpose[0], Dpoint[0], Dk[0]
        return out, Dpose, Dpoint, Dk

    def backproject(self, measured: Any) -> np.ndarray:
        """World point of a stereo measurement ``(uL, uR, v)`` (``(3,)`` or ``(n, 3)``):
        depth ``z = b fx / (uL - uR)``; raises :class:`CheiralityError` for a disparity <= 0."""
        m, single = as_points3(measured, "StereoCamera.backproject")
        k = self._calibration._data
        fx, fy, u0, v0, b = k[0], k[1], k[3], k[4], k[5]
        disparity = m[:, 0] - m[:, 1]
        if np.any(~(disparity > 0.0)):
            i = int(np.nonzero(~(disparity > 0.0))[0][0])
            raise CheiralityError(f"StereoCamera.backproject: measurement {i} {m[i]} has "
                                  f"disparity {disparity[i]:g} <= 0 (point at or beyond infinity)")
        z = b * fx / disparity
        pc = np.column_stack([z * (m[:, 0] - u0) / fx, z * (m[:, 2] - v0) / fy, z])
        out = self._pose * pc
        return out[0] if single else out

    def __repr__(self) -> str:
        return f"StereoCamera({self._pose!r}, {self._calibration!r})"


@lru_cache(maxsize=None)
def _camera_kind(model: type[Calibration]) -> BatchKind:
    """``PinholeCamera[model]`` rows ``[pose (7), calibration (s)]``; retract / local act on the
    pose (SE3's batched kernels) and the calibration (its kind's) separately."""
    se3, cal = SE3.batch_kind(), model.batch_kind()

    def retract(x, delta):
        out = np.empty_like(x)
        out[:, :7] = se3.retract(np.ascontiguousarray(x[:, :7]), np.ascontiguousarray(delta[:, :6]))
        out[:, 7:] = cal.retract(np.ascontiguousarray(x[:, 7:]), np.ascontiguousarray(delta[:, 6:]))
        return out

    def local(a, b):
        return np.concatenate([se3.local(np.ascontiguousarray(a[:, :7]),
                                         np.ascontiguousarray(b[:, :7])),
                               cal.local(np.ascontiguousarray(a[:, 7:]),
                                         np.ascontiguousarray(b[:, 7:]))], axis=1)

    def from_storage(row):
        row = np.asarray(row, dtype=float)
        return PinholeCamera(SE3.from_storage(row[:7]), cal.from_storage(row[7:]))

    def to_storage(x):
        if not (isinstance(x, PinholeCamera) and type(x.calibration()) is model):
            raise DimensionMismatchError(f"PinholeCamera[{model.__name__}] storage requested "
                                         f"for {x!r}")
        return x.to_storage()

    return BatchKind(name=f"PinholeCamera[{model.__name__}]", dim=6 + model.DIM,
                     storage_dim=7 + len(model.PARAMS), retract=retract, local=local,
                     from_storage=from_storage, to_storage=to_storage)


class _CameraOps:
    """Manifold traits of :class:`PinholeCamera` (GTSAM's product manifold SE(3) x K)."""

    def dim(self, x: Any) -> int:
        return x.dim()

    def storage_dim(self, x: Any) -> int:
        return 7 + len(x.calibration().PARAMS)

    def to_storage(self, x: Any) -> np.ndarray:
        return x.to_storage()

    def from_storage(self, like: Any, data: np.ndarray) -> Any:
        return _camera_kind(type(like.calibration())).from_storage(data)

    def retract(self, x: Any, delta: np.ndarray) -> Any:
        return x.retract(delta)

    def local(self, x: Any, y: Any) -> np.ndarray:
        return x.local(y)

    def batch_kind(self, x: Any) -> BatchKind:
        return _camera_kind(type(x.calibration()))


register(PinholeCamera, _CameraOps())
