"""SO(3), 3-D rotations stored as unit quaternions."""

from __future__ import annotations

from typing import Any

import numpy as np

from . import _kernels as K
from .lie import LieGroup, as_float, as_float_vector, register_group
from .so2 import as_matrix, check_rotation_matrix, normalize_unit


class SO3(LieGroup):
    """A 3-D rotation.

    Storage: unit quaternion ``[qx, qy, qz, qw]`` (normalized on construction; ``q`` and ``-q``
    are the same rotation, either sign may be stored). Tangent: rotation vector ``[wx, wy, wz]``.
    ``Exp(w)`` rotates by ``|w|`` about ``w / |w|``; ``Log`` picks the shortest rotation
    (``|w| <= pi``). ``retract(x, d) = x * Exp(d)``, ``local(x, y) = Log(x^-1 * y)`` (right
    perturbation). ``adjoint() = R``. ``rot * p`` rotates points ``(3,)`` or ``(n, 3)``.

    Example:

    >>> from fgopt import SO3
    >>> R = SO3.from_axis_angle([0.0, 0.0, 1.0], np.pi / 2)
    >>> np.round(R.act(np.array([1.0, 0.0, 0.0])), 6)
    array([0., 1., 0.])
    >>> np.round(R.quaternion(), 6)
    array([0.707107, 0.      , 0.      , 0.707107])
    >>> np.round(R.log(), 6)
    array([0.      , 0.      , 1.570796])
    """

    __slots__ = ()
    _GID = K.SO3_ID
    _DIM = 3
    _STORAGE_DIM = 4
    _POINT_DIM = 3
    _IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])

    def __init__(self, xyzw: Any = None):
        """``SO3()`` is the identity; ``SO3(xyzw)`` takes a quaternion in storage order."""
        data = self._IDENTITY.copy() if xyzw is None else as_float_vector(xyzw, 4, "SO3")
        self._normalize(data)
        self._set(data)

    @classmethod
    def _normalize(cls, data: np.ndarray) -> None:
        normalize_unit(data[:4], cls.__name__)

    @classmethod
    def from_quaternion(cls, w: float, x: float, y: float, z: float) -> SO3:
        """From quaternion components given scalar first (``w, x, y, z``)."""
        return cls((x, y, z, w))

    @classmethod
    def from_matrix(cls, r: Any) -> SO3:
        r = as_matrix(r, 3, "SO3.from_matrix")
        check_rotation_matrix(r, "SO3.from_matrix")
        out = np.empty(4)
        K.quat_from_matrix(r, out)
        return cls._wrap(out)

    @classmethod
    def from_rotvec(cls, w: Any) -> SO3:
        """``Exp(w)``: rotation by angle ``|w|`` about axis ``w / |w|``."""
        return cls.exp(w)

    @classmethod
    def from_axis_angle(cls, axis: Any, angle: float) -> SO3:
        axis = as_float_vector(axis, 3, "SO3.from_axis_angle")
        return cls.exp(axis / np.linalg.norm(axis) * as_float(angle, "SO3 angle"))

    @classmethod
    def rz_ry_rx(cls, x: float, y: float, z: float) -> SO3:
        """``Rz(z) Ry(y) Rx(x)`` (angles in radians, about the fixed axes: first ``x`` about X,
        then ``y`` about Y, then ``z`` about Z), as GTSAM's ``Rot3.RzRyRx``.

        >>> SO3.rz_ry_rx(0.1, 0.2, 0.3)
        """
        e = np.eye(3)
        return (cls.exp(e[2] * as_float(z, "SO3 z angle"))
                * cls.exp(e[1] * as_float(y, "SO3 y angle"))
                * cls.exp(e[0] * as_float(x, "SO3 x angle")))

    @classmethod
    def ypr(cls, yaw: float, pitch: float, roll: float) -> SO3:
        """From yaw (about Z), pitch (about Y), roll (about X), radians: ``Rz(yaw) Ry(pitch)
        Rx(roll)``, as GTSAM's ``Rot3.Ypr`` (navigation frame to body: yaw first).

        >>> SO3.ypr(0.3, 0.2, 0.1)  # == SO3.rz_ry_rx(0.1, 0.2, 0.3)
        """
        return cls.rz_ry_rx(roll, pitch, yaw)

    @classmethod
    def rodrigues(cls, w: Any) -> SO3:
        """``Exp(w)``: rotation by ``|w|`` radians about ``w / |w|`` (GTSAM's
        ``Rot3.Rodrigues``)."""
        return cls.exp(as_float_vector(w, 3, "SO3.rodrigues"))

    @classmethod
    def random(cls, rng: Any = None) -> SO3:
        """Uniformly distributed rotation."""
        return cls(cls._rng(rng).normal(size=4))

    def quaternion(self) -> tuple[float, float, float, float]:
        """``(w, x, y, z)``, scalar first."""
        x, y, z, w = (float(c) for c in self._data[:4])
        return w, x, y, z

    def rotvec(self) -> np.ndarray:
        return self.log()

    def matrix(self) -> np.ndarray:
        out = np.empty((3, 3))
        K.quat_to_matrix(self._buf, out)
        return out

    def __repr__(self) -> str:
        return "SO3(qw={:.3f}, qx={:.3f}, qy={:.3f}, qz={:.3f})".format(*self.quaternion())


register_group(SO3)
