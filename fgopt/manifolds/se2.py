"""SE(2), planar rigid motions."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from . import _kernels as K
from .lie import LieGroup, as_float_vector, register_group
from .so2 import SO2, as_matrix, check_rotation_matrix, normalize_unit


class SE2(LieGroup):
    """A planar pose ``(R(theta), t)`` acting as ``p -> R p + t``.

    Storage ``[cos, sin, x, y]``; tangent ``[theta, vx, vy]`` (rotation first).
    ``Exp([theta, v]) = (R(theta), V(theta) v)`` with ``V = (sin t / t) I + ((1 - cos t) / t) J``,
    the true SE(2) exponential; ``Log`` is its inverse with theta in (-pi, pi].
    ``retract(x, d) = x * Exp(d)``, ``local(x, y) = Log(x^-1 * y)`` (right perturbation, GTSAM's
    Pose2 default). ``adjoint() = [[1, 0, 0], [y, c, -s], [-x, s, c]]``.
    ``pose * p`` transforms 2-D points ``(2,)`` or ``(n, 2)``.

    Example:

    >>> from fgopt import SE2
    >>> a = SE2.from_xytheta(1.0, 2.0, np.pi / 2)
    >>> a.translation(), round(a.rotation().theta(), 6)
    (array([1., 2.]), 1.570796)
    >>> np.round(a.act(np.array([1.0, 0.0])), 6)
    array([1., 3.])
    >>> b = a.retract(np.array([0.1, 0.2, 0.3]))
    >>> np.round(a.local(b), 6)
    array([0.1, 0.2, 0.3])
    """

    __slots__ = ()
    _GID = K.SE2_ID
    _DIM = 3
    _STORAGE_DIM = 4
    _POINT_DIM = 2
    _IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])

    def __init__(self, rotation: SO2 | float | None = None, translation: Any = (0.0, 0.0)):
        rot = rotation if isinstance(rotation, SO2) else SO2(0.0 if rotation is None else rotation)
        data = np.empty(4)
        data[:2] = rot._data
        data[2:] = as_float_vector(translation, 2, "SE2 translation")
        self._set(data)

    @classmethod
    def _normalize(cls, data: np.ndarray) -> None:
        normalize_unit(data[:2], cls.__name__)

    @classmethod
    def from_xytheta(cls, x: float, y: float, theta: float) -> SE2:
        return cls(SO2(theta), (x, y))

    @classmethod
    def from_matrix(cls, m: Any) -> SE2:
        """From a 3x3 homogeneous matrix ``[[R, t], [0, 1]]``."""
        m = as_matrix(m, 3, "SE2.from_matrix")
        check_rotation_matrix(m[:2, :2], "SE2.from_matrix")
        return cls.from_storage([m[0, 0], m[1, 0], m[0, 2], m[1, 2]])

    @classmethod
    def random(cls, rng: Any = None) -> SE2:
        rng = cls._rng(rng)
        return cls(SO2.random(rng), rng.normal(size=2))

    def x(self) -> float:
        return float(self._data[2])

    def y(self) -> float:
        return float(self._data[3])

    def theta(self) -> float:
        return math.atan2(self._data[1], self._data[0])

    def rotation(self) -> SO2:
        return SO2._wrap(self._data[:2].copy())

    def translation(self) -> np.ndarray:
        return self._data[2:].copy()

    def matrix(self) -> np.ndarray:
        """The 3x3 homogeneous matrix ``[[R, t], [0, 1]]``."""
        c, s, x, y = self._data
        return np.array([[c, -s, x], [s, c, y], [0.0, 0.0, 1.0]])

    def __repr__(self) -> str:
        return f"SE2(x={self.x():.3f}, y={self.y():.3f}, theta={self.theta():.3f})"


register_group(SE2)
