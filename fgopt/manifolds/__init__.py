"""Manifolds: the traits protocol, registry, vector spaces and Lie groups."""

from .base import BatchKind as BatchKind
from .base import ManifoldOps as ManifoldOps
from .base import SCALAR_KIND as SCALAR_KIND
from .base import ops_for as ops_for
from .base import register as register
from .base import vector_kind as vector_kind
from .lie import InvalidGroupElementError as InvalidGroupElementError
from .lie import LieGroup as LieGroup
from .se2 import SE2 as SE2
from .se3 import SE3 as SE3
from .sim3 import Sim3 as Sim3
from .so2 import SO2 as SO2
from .so3 import SO3 as SO3

#: The public names (each has an entry in the API reference: tests/test_docs_reference.py).
__all__ = ["BatchKind", "ManifoldOps", "SCALAR_KIND", "ops_for", "register", "vector_kind",
           "InvalidGroupElementError", "LieGroup", "SE2", "SE3", "Sim3", "SO2", "SO3"]
