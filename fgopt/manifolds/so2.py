"""SO(2), planar rotations."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..errors import DimensionMismatchError, NonFiniteError
from . import _kernels as K
from .lie import InvalidGroupElementError, LieGroup, as_float, register_group


def normalize_unit(data: np.ndarray, what: str) -> None:
    """Scale ``data`` (a cos/sin pair or a quaternion view) to unit norm in place."""
    n = float(np.linalg.norm(data))
    if not n > 1e-12:
        raise InvalidGroupElementError(
            f"{what}: cannot normalize {data} (norm {n:.3g}); pass a unit rotation")
    if abs(n - 1.0) > 1e-15:  # leave unit data bit-exact (storage round trips)
        data /= n


def as_matrix(value: Any, n: int, what: str) -> np.ndarray:
    """``value`` as a finite float64 ``(n, n)`` array, or a clear error."""
    m = np.array(value, dtype=np.float64)  # a C-contiguous copy
    if m.shape != (n, n):
        raise DimensionMismatchError(f"{what}: expected a {n}x{n} matrix, got shape {m.shape}")
    if not np.all(np.isfinite(m)):
        raise NonFiniteError(f"{what}: matrix has non-finite entries")
    return m


def check_rotation_matrix(r: np.ndarray, what: str, tol: float = 1e-6) -> None:
    err = np.max(np.abs(r.T @ r - np.eye(r.shape[0])))
    if err > tol or np.linalg.det(r) <= 0.0:
        raise InvalidGroupElementError(
            f"{what}: not a rotation matrix (|R^T R - I| = {err:.2g}, det = "
            f"{np.linalg.det(r):.3g}); orthonormalize it first")


class SO2(LieGroup):
    """A planar rotation ``R(theta)``.

    Storage ``[cos, sin]`` (normalized on construction); tangent ``[theta]``;
    ``Exp(theta) = R(theta)``, ``Log`` returns theta in (-pi, pi].
    ``retract(x, d) = x * Exp(d)``, ``local(x, y) = Log(x^-1 * y)`` (right perturbation);
    ``adjoint() = [[1]]``. ``rot * p`` rotates 2-D points ``(2,)`` or ``(n, 2)``.

    Example:

    >>> from fgopt import SO2
    >>> r = SO2(np.pi / 2)
    >>> np.round(r.matrix(), 6)
    array([[ 0., -1.],
           [ 1.,  0.]])
    >>> round(r.compose(SO2(0.1)).theta(), 6)
    1.670796
    """

    __slots__ = ()
    _GID = K.SO2_ID
    _DIM = 1
    _STORAGE_DIM = 2
    _POINT_DIM = 2
    _IDENTITY = np.array([1.0, 0.0])

    def __init__(self, theta: float = 0.0):
        t = as_float(theta, "SO2 angle")
        if not math.isfinite(t):
            raise NonFiniteError(f"SO2: angle must be finite, got {theta!r}")
        data = np.array([math.cos(t), math.sin(t)])
        self._set(data)

    @classmethod
    def _normalize(cls, data: np.ndarray) -> None:
        normalize_unit(data, cls.__name__)

    @classmethod
    def from_matrix(cls, r: Any) -> SO2:
        r = as_matrix(r, 2, "SO2.from_matrix")
        check_rotation_matrix(r, "SO2.from_matrix")
        return cls.from_storage([r[0, 0], r[1, 0]])

    @classmethod
    def random(cls, rng: Any = None) -> SO2:
        return cls(cls._rng(rng).uniform(-math.pi, math.pi))

    def theta(self) -> float:
        return math.atan2(self._data[1], self._data[0])

    def matrix(self) -> np.ndarray:
        c, s = self._data
        return np.array([[c, -s], [s, c]])

    def __repr__(self) -> str:
        return f"SO2(theta={self.theta():.3f})"


register_group(SO2)
