"""``@fgopt.constraint``: equality ``g(x) = 0`` and inequality ``h(x) <= 0`` constraints written
like factors.

    @fgopt.constraint
    def on_plane(p: V3, plane: V4) -> V1:
        return V1(plane[0] * p[0] + plane[1] * p[1] + plane[2] * p[2] + plane[3])

    @fgopt.constraint(inequality=True)
    def below(q: Scalar, upper: Scalar) -> Scalar:
        return q - upper                      # q <= upper

    graph.add(on_plane(p=key('p', 0), plane=np.array([0.0, 0.0, 1.0, -2.0])))

The decorated function is an ordinary symbolic residual function: the kernel (value and
tangent-space Jacobian, batched, on every manifold including ``@fgopt.manifold`` ones) is the
one :func:`fgopt.factor` would generate for it, from the same code generator and cache. Each
output row is one scalar constraint: ``g_j(x) = 0`` (equality) or ``h_j(x) <= 0``
(inequality). Instances carry no noise model; ``graph.add`` keeps them apart from the factors
(``graph.constraints``), and :func:`fgopt.optimize` solves a graph holding them with an
augmented-Lagrangian loop (:mod:`fgopt.solvers.constrained`).
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np

from ..errors import FgoptError
from .decorator import SymbolicFactor, SymbolicFactorType


def constraint(fn: Callable | None = None, *, inequality: bool = False, name: str | None = None,
               method: str = "retraction", engine: str = "auto", cache: bool = True,
               variables: Iterable[str] | None = None):
    """Decorator: make a constraint type from a typed symbolic function.

    Args:
        fn: ``def g(a: Pose3, b: V3, ...) -> V2`` over symbolic types, as for
            :func:`fgopt.factor`; its output ``c(x)`` must be ``0`` (equality) or ``<= 0``
            componentwise (``inequality=True``).
        inequality: ``False``: ``c(x) = 0``; ``True``: ``c(x) <= 0``.
        name, method, engine, cache, variables: as for :func:`fgopt.factor`.

    Instances are made like factor instances (keys are variables, numbers constants) but take no
    ``loss``: ``graph.add(on_plane(p=key('p', 0), plane=n))``.
    """
    def wrap(f: Callable, scope: dict | None = None) -> SymbolicConstraintType:
        if scope is None:
            scope = sys._getframe(1).f_locals
        return SymbolicConstraintType(f, inequality=bool(inequality), name=name, method=method,
                                      engine=engine, hessian=False, cache=cache,
                                      variables=variables, scope=scope)

    if fn is not None and not callable(fn):
        raise FgoptError(f"@fgopt.constraint: expected a function, got {fn!r} (write "
                         "@fgopt.constraint or @fgopt.constraint(inequality=True))")
    return wrap if fn is None else wrap(fn, sys._getframe(1).f_locals)


class Constraint(SymbolicFactor):
    """An instance of a :class:`SymbolicConstraintType`: ``c(x) = 0`` or ``c(x) <= 0``.

    ``error(values)`` is ``c(x)``, ``jacobians(values)`` its tangent-space Jacobians (as for a
    factor, without a noise model).
    """

    #: How :class:`fgopt.FactorGraph` tells a constraint from a factor.
    is_constraint = True

    def __init__(self, constraint_type: SymbolicConstraintType, factor: SymbolicFactor):
        self.inequality = constraint_type.inequality
        super().__init__(constraint_type, factor.kernel, list(factor.keys), factor.constants, None)

    def violation(self, values: Any) -> float:
        """Largest violation at ``values``: ``max |g|`` or ``max(max h, 0)``."""
        c = self.error(values)
        return float(np.max(np.maximum(c, 0.0)) if self.inequality else np.max(np.abs(c)))

    def describe(self) -> str:
        return f"{super().describe()} {'<=' if self.inequality else '=='} 0"

    def __repr__(self) -> str:
        return f"<constraint {self.describe()}>"


class SymbolicConstraintType(SymbolicFactorType):
    """A constraint type made by :func:`constraint`; call it to make instances."""

    def __init__(self, fn: Callable, *, inequality: bool, **options: Any):
        super().__init__(fn, **options)
        self.inequality = inequality
        self._options["inequality"] = inequality

    def __call__(self, *args: Any, loss: Any = None, **kwargs: Any) -> Constraint:
        if loss is not None:
            raise FgoptError(f"{self.name}: a constraint takes no loss (it holds exactly); "
                             "make a factor with @fgopt.factor for a soft penalty")
        return Constraint(self, super().__call__(*args, **kwargs))

    def __repr__(self) -> str:
        sig = ", ".join(f"{n}: {tp.__name__}" for n, tp in self.params)
        kind = "<= 0" if self.inequality else "== 0"
        return f"<fgopt constraint {self.name}({sig}) {kind}>"
