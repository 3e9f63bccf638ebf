"""Sim(3), 3-D similarity transforms."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..errors import NonFiniteError
from . import _kernels as K
from .lie import InvalidGroupElementError, LieGroup, as_float, as_float_vector, register_group
from .se3 import as_so3
from .so2 import as_matrix, normalize_unit
from .so3 import SO3


class Sim3(LieGroup):
    """A similarity ``(R, t, s)`` acting as ``p -> s R p + t`` (``s > 0``).

    Storage ``[qx, qy, qz, qw, tx, ty, tz, s]``; tangent ``[w(3), v(3), lambda]`` with
    ``s = exp(lambda)``. ``Exp([w, v, lambda]) = (Exp_SO3(w), W(w, lambda) v, e^lambda)``, the
    matrix exponential of ``[[lambda I + hat(w), v], [0, 0]]``; ``W`` is Eade's closed form.
    Composition ``(R1, t1, s1)(R2, t2, s2) = (R1 R2, s1 R1 t2 + t1, s1 s2)``.
    ``retract(x, d) = x * Exp(d)``, ``local(x, y) = Log(x^-1 * y)`` (right perturbation).
    ``adjoint() = [[R, 0, 0], [hat(t) R, s R, -t], [0, 0, 1]]``.

    Example:

    >>> from fgopt import Sim3
    >>> S = Sim3.exp([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, np.log(2.0)])
    >>> round(S.scale(), 6)
    2.0
    """

    __slots__ = ()
    _GID = K.SIM3_ID
    _DIM = 7
    _STORAGE_DIM = 8
    _POINT_DIM = 3
    _IDENTITY = np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0])

    def __init__(self, rotation: SO3 | None = None, translation: Any = (0.0, 0.0, 0.0),
                 scale: float = 1.0):
        data = np.empty(8)
        data[:4] = as_so3(rotation, "Sim3 rotation")._data
        data[4:7] = as_float_vector(translation, 3, "Sim3 translation")
        data[7] = as_float(scale, "Sim3 scale")
        self._normalize(data)
        self._set(data)

    @classmethod
    def _normalize(cls, data: np.ndarray) -> None:
        normalize_unit(data[:4], cls.__name__)
        if not math.isfinite(data[7]):
            raise NonFiniteError(f"Sim3: scale must be finite, got {data[7]}")
        if not data[7] > 0.0:
            raise InvalidGroupElementError(f"Sim3: scale must be > 0, got {data[7]}")

    @classmethod
    def from_matrix(cls, m: Any) -> Sim3:
        """From a 4x4 matrix ``[[s R, t], [0, 1]]``."""
        m = as_matrix(m, 4, "Sim3.from_matrix")
        det = np.linalg.det(m[:3, :3])
        if not det > 0.0:
            raise InvalidGroupElementError(f"Sim3.from_matrix: det(sR) = {det:.3g} must be > 0")
        s = det ** (1.0 / 3.0)
        return cls(SO3.from_matrix(m[:3, :3] / s), m[:3, 3], s)

    @classmethod
    def random(cls, rng: Any = None) -> Sim3:
        rng = cls._rng(rng)
        return cls(SO3.random(rng), rng.normal(size=3), math.exp(0.5 * rng.normal()))

    def rotation(self) -> SO3:
        return SO3._wrap(self._data[:4].copy())

    def translation(self) -> np.ndarray:
        return self._data[4:7].copy()

    def scale(self) -> float:
        return float(self._data[7])

    def matrix(self) -> np.ndarray:
        """The 4x4 matrix ``[[s R, t], [0, 1]]``."""
        m = np.eye(4)
        K.rotation_block(self._buf, m, 0, 0, float(self._buf[7]))
        m[:3, 3] = self._data[4:7]
        return m

    def __repr__(self) -> str:
        (x, y, z), (qw, qx, qy, qz) = self._data[4:7], self.rotation().quaternion()
        return (f"Sim3(x={x:.3f}, y={y:.3f}, z={z:.3f}, qw={qw:.3f}, qx={qx:.3f}, "
                f"qy={qy:.3f}, qz={qz:.3f}, s={self.scale():.3f})")


register_group(Sim3)
