"""Numerical Jacobians by central differences in the tangent space.

``d e / d x_k`` column ``i`` is ``(e(x_k (+) h e_i) - e(x_k (+) -h e_i)) / 2h``, with the variable's
own ``retract``, so it is exactly the tangent-space Jacobian the optimizer needs (GTSAM's
``numericalDerivative``, Theseus' ``numeric_jacobian``).
"""

from __future__ import annotations

from typing import Any, Callable, Sequence

import numpy as np

from ..key import Key
from ..manifolds.base import ops_for
from .base import Factor


class _Overlay:
    """Read-only view of ``values`` with one key replaced (no copy of the whole map)."""

    __slots__ = ("_base", "_key", "_value")

    def __init__(self, base: Any, k: Key, value: Any):
        self._base, self._key, self._value = base, k, value

    def at(self, k: Key) -> Any:
        return self._value if k == self._key else self._base.at(k)

    __getitem__ = at

    def __contains__(self, k: object) -> bool:
        return k == self._key or k in self._base


def numerical_jacobian(fn: Callable[[Any], np.ndarray], values: Any, k: Key,
                       delta: float = 1e-6) -> np.ndarray:
    """Central-difference Jacobian of ``fn(values)`` w.r.t. the tangent space of key ``k``.

    Example: an SE(2) pose's translation moves with the pose's tangent ``[theta, x, y]`` as
    ``[0, R]`` (the translation step is in the body frame):

    >>> from fgopt.factors import numerical_jacobian
    >>> values = fgopt.Variables().add(key('x', 0), fgopt.SE2.from_xytheta(1.0, 2.0, 0.5))
    >>> J = numerical_jacobian(lambda v: v.at(key('x', 0)).translation(), values, key('x', 0))
    >>> np.round(J, 6)
    array([[ 0.      ,  0.877583, -0.479426],
           [ 0.      ,  0.479426,  0.877583]])
    """
    x = values.at(k)
    ops = ops_for(x)
    d = ops.dim(x)
    cols = []
    for i in range(d):
        step = np.zeros(d)
        step[i] = delta
        e_plus = np.asarray(fn(_Overlay(values, k, ops.retract(x, step))), dtype=float)
        e_minus = np.asarray(fn(_Overlay(values, k, ops.retract(x, -step))), dtype=float)
        cols.append((e_plus - e_minus).reshape(-1) / (2 * delta))
    return np.stack(cols, axis=1)


def numerical_jacobians(fn: Callable[[Any], np.ndarray], values: Any, keys: Sequence[Key],
                        delta: float = 1e-6) -> list[np.ndarray]:
    """Central-difference Jacobians of ``fn(values)`` in the tangent space of each of ``keys``
    (steps ``delta``), one ``(len(fn(values)), dim)`` array per key.

    Example:

    >>> from fgopt.factors import numerical_jacobians
    >>> values = fgopt.Variables().add(key('p', 0), np.array([3.0, 4.0]))
    >>> J, = numerical_jacobians(lambda v: np.array([np.linalg.norm(v.at(key('p', 0)))]),
    ...                          values, [key('p', 0)])
    >>> np.round(J, 6)
    array([[0.6, 0.8]])
    """
    return [numerical_jacobian(fn, values, k, delta) for k in keys]


class NumericalFactor(Factor):
    """A Python factor that only implements ``error``; Jacobians by central differences.

    Example:

    >>> class Range(fgopt.NumericalFactor):
    ...     def __init__(self, k, measured):
    ...         super().__init__([k], 1)
    ...         self.measured = measured
    ...     def error(self, values):
    ...         return np.array([np.linalg.norm(values.at(self.keys[0])) - self.measured])
    ...
    >>> values = fgopt.Variables().add(key('p', 0), np.array([3.0, 4.0]))
    >>> np.round(Range(key('p', 0), 4.0).jacobians(values)[0], 6)
    array([[0.6, 0.8]])
    """

    #: Step of the central differences, in tangent coordinates.
    delta: float = 1e-6

    def jacobians(self, values: Any) -> list[np.ndarray]:
        return numerical_jacobians(self.error, values, self.keys, self.delta)
