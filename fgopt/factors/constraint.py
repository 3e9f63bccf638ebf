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

import hashlib
import inspect
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

    Example: the point of the unit circle closest to ``(2, 0.5)``:

    >>> from fgopt.noise import Isotropic
    >>> from fgopt.symbolic import V1, V2
    >>> @fgopt.constraint
    ... def on_circle(p: V2) -> V1:
    ...     return V1(p.squared_norm() - 1)
    ...
    >>> target = np.array([2.0, 0.5])
    >>> graph = fgopt.FactorGraph([fgopt.PriorFactor(key('p', 0), target, Isotropic.sigma(2, 1.0))])
    >>> _ = graph.add(on_circle(p=key('p', 0)))
    >>> result = fgopt.optimize(graph, fgopt.Variables().add(key('p', 0), target))
    >>> np.allclose(result.values.at(key('p', 0)), target / np.linalg.norm(target), atol=1e-6)
    True
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
        self._penalty: dict = {}  # penalty types by ("type", m), kernels by id(kernel)

    def penalty_kernel(self, kernel: Any) -> Any:
        """The generated kernel of the augmented-Lagrangian term of this type's constraints
        with kernel ``kernel`` (:mod:`fgopt.solvers.constrained`): residual rows
        ``scale_i (c_i(x) + shift_i)``, for an inequality ``scale_i max(0, c_i(x) + shift_i)``,
        with the constants ``shift`` and ``scale`` (one each per output row) after the
        constraint's own."""
        hit = self._penalty.get(id(kernel))
        if hit is None or hit[0] is not kernel:
            pattern = next(p for p, k in self._kernels.items() if k is kernel)
            hit = self._penalty[id(kernel)] = (kernel, self.penalty_type(
                kernel.residual_dim).kernel(pattern + (False, False)))
        return hit[1]

    def penalty_type(self, m: int) -> SymbolicFactorType:
        """The factor type of :meth:`penalty_kernel` (``m``: the constraint's output size)."""
        ftype = self._penalty.get(("type", m))
        if ftype is not None:
            return ftype
        from ..symbolic import Max, vector_type
        from ..symbolic.jacobians import output_storage
        from ..symbolic.ops import storage_of

        fn, ineq = self.fn, self.inequality

        def penalty(*args: Any) -> list:
            rows = [c + s for c, s in zip(output_storage(fn(*args[:-2])), storage_of(args[-2]))]
            return [(Max(r, 0) if ineq else r) * w for r, w in zip(rows, storage_of(args[-1]))]

        P = inspect.Parameter
        params = [P(n, P.POSITIONAL_OR_KEYWORD, annotation=tp) for n, tp in self.params]
        params += [P("penalty_shift", P.POSITIONAL_OR_KEYWORD, annotation=vector_type(m)),
                   P("penalty_scale", P.POSITIONAL_OR_KEYWORD, annotation=vector_type(m))]
        penalty.__signature__ = inspect.Signature(params, return_annotation=vector_type(m))
        penalty.__annotations__ = {p.name: p.annotation for p in params}
        penalty.__annotations__["return"] = vector_type(m)
        ftype = SymbolicFactorType(penalty, name=f"{self.name}_penalty", method=self.method,
                                   engine=self.engine, hessian=False, cache=self.use_cache,
                                   variables=None)
        # the kernel is decided by the constraint's code and the wrapper's own
        ftype._fingerprint = hashlib.sha256(
            f"{self.fingerprint} {penalty.__code__.co_code.hex()} {ineq} {m}".encode()
        ).hexdigest()
        ftype.recipe = (SymbolicConstraintType.penalty_type, (self, m))
        self._penalty[("type", m)] = ftype
        return ftype

    def __call__(self, *args: Any, loss: Any = None, **kwargs: Any) -> Constraint:
        if loss is not None:
            raise FgoptError(f"{self.name}: a constraint takes no loss (it holds exactly); "
                             "make a factor with @fgopt.factor for a soft penalty")
        return Constraint(self, super().__call__(*args, **kwargs))

    def __repr__(self) -> str:
        sig = ", ".join(f"{n}: {tp.__name__}" for n, tp in self.params)
        kind = "<= 0" if self.inequality else "== 0"
        return f"<fgopt constraint {self.name}({sig}) {kind}>"
