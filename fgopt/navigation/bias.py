"""``ImuBias``: constant accelerometer and gyroscope biases (GTSAM's ``imuBias::ConstantBias``).

Order ``[accelerometer(3), gyroscope(3)]``, as GTSAM's ``ConstantBias::vector()``. In a factor
graph a bias is a plain 6-vector variable (``vector_kind(6)``): ``Variables.add(B(0),
ImuBias(...))`` stores its vector, and optimized values come back as 6-vectors
(``ImuBias.from_vector(v)`` wraps one again).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import DimensionMismatchError
from ..manifolds.base import BatchKind, register, vector_kind
from ..manifolds.lie import as_float_vector


class ImuBias:
    """Accelerometer bias (m/s^2) then gyroscope bias (rad/s); immutable.

    Example:

    >>> from fgopt.navigation import ImuBias
    >>> b = ImuBias(accelerometer=[0.1, 0.0, 0.0], gyroscope=[0.0, 0.0, 0.01])
    >>> b.vector()
    array([0.1 , 0.  , 0.  , 0.  , 0.  , 0.01])
    """

    __slots__ = ("_v",)

    def __init__(self, accelerometer: Any = (0.0, 0.0, 0.0), gyroscope: Any = (0.0, 0.0, 0.0)):
        v = np.empty(6)
        v[:3] = as_float_vector(accelerometer, 3, "ImuBias accelerometer")
        v[3:] = as_float_vector(gyroscope, 3, "ImuBias gyroscope")
        v.flags.writeable = False
        object.__setattr__(self, "_v", v)

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError("ImuBias values are immutable")

    @classmethod
    def from_vector(cls, v: Any) -> ImuBias:
        """From ``[accelerometer, gyroscope]`` (6 numbers)."""
        arr = as_float_vector(v, 6, "ImuBias.from_vector")
        return cls(arr[:3], arr[3:])

    @staticmethod
    def as_vector(bias: Any, what: str = "bias") -> np.ndarray:
        """``bias`` (an ImuBias, 6 numbers or ``None`` = zero) as a fresh 6-vector."""
        if bias is None:
            return np.zeros(6)
        if isinstance(bias, ImuBias):
            return bias.vector()
        try:
            return as_float_vector(bias, 6, what)
        except DimensionMismatchError:
            raise DimensionMismatchError(
                f"{what}: expected an ImuBias or 6 numbers [accelerometer, gyroscope], got "
                f"{bias!r}") from None

    @property
    def accelerometer(self) -> np.ndarray:
        return self._v[:3].copy()

    @property
    def gyroscope(self) -> np.ndarray:
        return self._v[3:].copy()

    def vector(self) -> np.ndarray:
        """``[accelerometer, gyroscope]``, a fresh 6-vector."""
        return self._v.copy()

    def __array__(self, dtype: Any = None, copy: Any = None) -> np.ndarray:
        return self._v.astype(dtype or float, copy=True)

    def correct_accelerometer(self, measured: Any) -> np.ndarray:
        """``measured - accelerometer``."""
        return np.asarray(measured, dtype=float) - self._v[:3]

    def correct_gyroscope(self, measured: Any) -> np.ndarray:
        """``measured - gyroscope``."""
        return np.asarray(measured, dtype=float) - self._v[3:]

    def __add__(self, other: Any) -> ImuBias:
        return ImuBias.from_vector(self._v + ImuBias.as_vector(other))

    def __sub__(self, other: Any) -> ImuBias:
        return ImuBias.from_vector(self._v - ImuBias.as_vector(other))

    def __neg__(self) -> ImuBias:
        return ImuBias.from_vector(-self._v)

    def equals(self, other: Any, tol: float = 1e-9) -> bool:
        try:
            return bool(np.max(np.abs(self._v - ImuBias.as_vector(other))) <= tol)
        except DimensionMismatchError:
            return False

    def __reduce__(self):
        return (ImuBias.from_vector, (self._v.copy(),))

    def __repr__(self) -> str:
        a, g = self._v[:3], self._v[3:]
        return (f"ImuBias(accelerometer=[{a[0]:.6g}, {a[1]:.6g}, {a[2]:.6g}], "
                f"gyroscope=[{g[0]:.6g}, {g[1]:.6g}, {g[2]:.6g}])")


class _ImuBiasOps:
    """An ImuBias is stored as the 6-vector variable it stands for."""

    def dim(self, x: Any) -> int:
        return 6

    storage_dim = dim

    def to_storage(self, x: Any) -> np.ndarray:
        return x.vector()

    def from_storage(self, like: Any, data: np.ndarray) -> ImuBias:
        return ImuBias.from_vector(data)

    def retract(self, x: Any, delta: np.ndarray) -> ImuBias:
        return x + delta

    def local(self, x: Any, y: Any) -> np.ndarray:
        return ImuBias.as_vector(y) - x.vector()

    def batch_kind(self, x: Any) -> BatchKind:
        return vector_kind(6)


register(ImuBias, _ImuBiasOps())
