"""Factors: the ``Factor`` base (slow path), kernel factors (fast path), ``@factor``, built-ins.

``factor`` / ``SymbolicFactorType`` (:mod:`.decorator`) load on first use: they pull in the
symbolic layer, which ``import fgopt`` does not need.
"""

from .base import Factor as Factor
from .base import KernelFactor as KernelFactor
from .kernel import FactorKernel as FactorKernel
from .library.prior_between import BetweenFactor as BetweenFactor
from .library.prior_between import PriorFactor as PriorFactor
from .numerical import NumericalFactor as NumericalFactor
from .numerical import numerical_jacobian as numerical_jacobian
from .numerical import numerical_jacobians as numerical_jacobians

_DECORATOR_NAMES = ("factor", "const", "SymbolicFactor", "SymbolicFactorType")
_CONSTRAINT_NAMES = ("constraint", "Constraint", "SymbolicConstraintType")


def __getattr__(name: str):
    if name in _DECORATOR_NAMES:
        from . import decorator

        return getattr(decorator, name)
    if name in _CONSTRAINT_NAMES:
        from . import constraint

        return getattr(constraint, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

#: The public names (each has an entry in the API reference: tests/test_docs_reference.py).
__all__ = ["Factor", "KernelFactor", "FactorKernel", "BetweenFactor", "PriorFactor",
           "NumericalFactor", "numerical_jacobian", "numerical_jacobians", "factor", "const",
           "SymbolicFactor", "SymbolicFactorType"]
