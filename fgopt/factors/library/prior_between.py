"""Built-in ``PriorFactor`` and ``BetweenFactor`` for every Lie group and vector space.

Residuals follow GTSAM: prior ``e = Log(m^-1 x)``, between ``e = Log(m^-1 (a^-1 b))``; for vectors
``e = x - m`` and ``e = (b - a) - m``. Kernels come from the symbolic pipeline
(:mod:`fgopt.factors.library.generated`: SO2, SE2, SO3, SE3, R^1..R^9); Sim3 and longer vectors
use the hand-written kernels of :mod:`fgopt.factors.library.lie_kernels` (same residuals, tested
equal). Declared manifolds (``@fgopt.manifold``) get a generated prior ``e = local(m, x)`` and,
when they declare ``compose`` / ``inverse``, a between ``e = local(m, a^-1 b)``. Other manifolds
(duck-typed classes) get a prior ``e = local(m, x)`` with numerical Jacobians.
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

from ...errors import ManifoldError
from ...manifolds.base import ops_for
from ..base import KernelFactor
from ...noise.models import Loss
from ..numerical import numerical_jacobians


def _kind_of(value: Any, what: str):
    ops = ops_for(value)
    return ops, ops.batch_kind(value)


def between_kernel_for(kind):
    """The kernel every built-in between factor of ``kind`` uses (generated when possible)."""
    return _builtin_kernel(kind, "between")


def prior_kernel_for(kind):
    """The kernel every built-in prior of ``kind`` uses (generated when possible)."""
    return _builtin_kernel(kind, "prior")


@functools.lru_cache(maxsize=None)
def _builtin_kernel(kind, which: str):
    from ...errors import ManifoldError
    from . import lie_kernels

    try:
        from . import generated

        make = generated.generated_between_kernel if which == "between" else \
            generated.generated_prior_kernel
        return make(kind)
    except ManifoldError:  # no symbolic twin (Sim3, R^n with n > 9)
        from ...manifolds.declared import declared_type

        if declared_type(kind) is not None:
            raise
        make = lie_kernels.between_kernel if which == "between" else lie_kernels.prior_kernel
        return make(kind)


class PriorFactor(KernelFactor):
    """``PriorFactor(key, value, loss)``: pulls variable ``key`` toward ``value``.

    Example:

    >>> from fgopt import SE2, PriorFactor
    >>> from fgopt.noise import Diagonal
    >>> f = PriorFactor(key('x', 0), SE2.from_xytheta(1.0, 0.0, 0.0), Diagonal.pose2(x=0.1, y=0.1, theta=0.05))
    >>> values = fgopt.Variables().add(key('x', 0), SE2.from_xytheta(1.0, 0.2, 0.0))
    >>> np.round(f.error(values), 6)
    array([0. , 0. , 0.2])
    """

    def __init__(self, key: int, value: Any, loss: Loss | None = None):
        ops, kind = _kind_of(value, "prior")
        self.prior = value
        if kind is None:  # duck-typed manifold: slow path
            self.kernel = None
            self._ops = ops
            self.constants = np.zeros(0)
            super(KernelFactor, self).__init__([key], ops.dim(value), loss)
            return
        super().__init__(prior_kernel_for(kind), [key], kind.to_storage(value), loss)

    def error(self, values: Any) -> np.ndarray:
        if self.kernel is None:
            return self._ops.local(self.prior, values.at(self.keys[0]))
        return super().error(values)

    def jacobians(self, values: Any) -> list[np.ndarray]:
        if self.kernel is None:
            return numerical_jacobians(self.error, values, self.keys)
        return super().jacobians(values)

    def describe(self) -> str:
        return f"PriorFactor({self.keys[0]!r})" if hasattr(self, "keys") else "PriorFactor"


class BetweenFactor(KernelFactor):
    """``BetweenFactor(k1, k2, measured, loss)``: relative measurement ``measured ~ x1^-1 x2``.

    Example:

    >>> from fgopt import SE2, BetweenFactor
    >>> f = BetweenFactor(key('x', 0), key('x', 1), SE2.from_xytheta(1.0, 0.0, 0.0))
    >>> values = fgopt.Variables().add(key('x', 0), SE2()).add(key('x', 1), SE2.from_xytheta(1.0, 0.5, 0.0))
    >>> np.round(f.error(values), 6)
    array([0. , 0. , 0.5])
    """

    def __init__(self, key1: int, key2: int, measured: Any, loss: Loss | None = None):
        ops, kind = _kind_of(measured, "between")
        if kind is None:
            raise ManifoldError(
                f"BetweenFactor needs a Lie group or vector measurement, got "
                f"{type(measured).__name__}; write a custom factor for other manifolds")
        self.measured = measured
        super().__init__(between_kernel_for(kind), [key1, key2], kind.to_storage(measured), loss)

    def describe(self) -> str:
        if hasattr(self, "keys"):
            return f"BetweenFactor({self.keys[0]!r}, {self.keys[1]!r})"
        return "BetweenFactor"
