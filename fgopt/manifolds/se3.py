"""SE(3), 3-D rigid motions."""

from __future__ import annotations

from typing import Any

import numpy as np

from . import _kernels as K
from .lie import LieGroup, as_float_vector, register_group
from .so2 import as_matrix, normalize_unit
from .so3 import SO3


def as_so3(rotation: Any, what: str) -> SO3:
    if rotation is None:
        return SO3()
    if isinstance(rotation, SO3):
        return rotation
    return SO3.from_matrix(as_matrix(rotation, 3, what))


class SE3(LieGroup):
    """A 3-D pose ``(R, t)`` acting as ``p -> R p + t``.

    Storage ``[qx, qy, qz, qw, tx, ty, tz]`` (unit quaternion, then translation); tangent
    ``[w(3), v(3)]``, rotation first as in GTSAM. ``Exp([w, v]) = (Exp_SO3(w), V(w) v)`` with
    ``V = I + (1 - cos t)/t^2 W + (t - sin t)/t^3 W^2`` -- the true SE(3) exponential, not the
    SO(3) x R^3 product. ``retract(x, d) = x * Exp(d)``, ``local(x, y) = Log(x^-1 * y)`` (right
    perturbation, GTSAM's Pose3 default). ``adjoint() = [[R, 0], [hat(t) R, R]]``.
    ``pose * p`` transforms points ``(3,)`` or ``(n, 3)``.

    Example:

    >>> from fgopt import SE3, SO3
    >>> p = SE3(SO3.from_rotvec([0.0, 0.0, np.pi / 2]), [1.0, 2.0, 3.0])
    >>> np.round(p.act(np.array([1.0, 0.0, 0.0])), 6)
    array([1., 3., 3.])
    >>> np.round(p.to_storage(), 6)
    array([0.      , 0.      , 0.707107, 0.707107, 1.      , 2.      ,
           3.      ])
    >>> np.round(SE3.exp(p.log()).matrix() - p.matrix(), 9).max()
    np.float64(0.0)
    """

    __slots__ = ()
    _GID = K.SE3_ID
    _DIM = 6
    _STORAGE_DIM = 7
    _POINT_DIM = 3
    _IDENTITY = np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0])

    def __init__(self, rotation: SO3 | None = None, translation: Any = (0.0, 0.0, 0.0)):
        """``rotation``: an :class:`SO3` or a 3x3 rotation matrix (default identity)."""
        data = np.empty(7)
        data[:4] = as_so3(rotation, "SE3 rotation")._data
        data[4:] = as_float_vector(translation, 3, "SE3 translation")
        self._set(data)

    @classmethod
    def _normalize(cls, data: np.ndarray) -> None:
        normalize_unit(data[:4], cls.__name__)

    @classmethod
    def from_matrix(cls, m: Any) -> SE3:
        """From a 4x4 homogeneous matrix ``[[R, t], [0, 1]]``."""
        m = as_matrix(m, 4, "SE3.from_matrix")
        return cls(SO3.from_matrix(m[:3, :3]), m[:3, 3])

    @classmethod
    def random(cls, rng: Any = None) -> SE3:
        rng = cls._rng(rng)
        return cls(SO3.random(rng), rng.normal(size=3))

    def rotation(self) -> SO3:
        return SO3._wrap(self._data[:4].copy())

    def translation(self) -> np.ndarray:
        return self._data[4:7].copy()

    def matrix(self) -> np.ndarray:
        """The 4x4 homogeneous matrix ``[[R, t], [0, 1]]``."""
        m = np.eye(4)
        K.rotation_block(self._buf, m, 0, 0, 1.0)
        m[:3, 3] = self._data[4:7]
        return m

    def __repr__(self) -> str:
        (x, y, z), (qw, qx, qy, qz) = self._data[4:7], self.rotation().quaternion()
        return (f"SE3(x={x:.3f}, y={y:.3f}, z={z:.3f}, "
                f"qw={qw:.3f}, qx={qx:.3f}, qy={qy:.3f}, qz={qz:.3f})")


register_group(SE3)
