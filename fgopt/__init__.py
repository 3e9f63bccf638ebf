"""fgopt: factor-graph optimization on manifolds from Python.

>>> import fgopt
>>> from fgopt import key, SE2
>>> graph, initial = fgopt.FactorGraph(), fgopt.Variables()
>>> ... add factors and values ...
>>> result = fgopt.optimize(graph, initial, method="lm")
"""

from ._version import __version__ as __version__

import os as _os

# fgopt is single-threaded unless asked (``threads=``): a BLAS that spins threads beside numba
# kernels made LM on Ladybug-49 5.5x slower on a 2-core machine (12.7 s vs 2.3 s). Only a
# default: set the variables yourself (before numpy is imported) to override.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_var, "1")

from . import noise as noise
from .errors import FgoptError as FgoptError
from .factors import BetweenFactor as BetweenFactor
from .factors import Factor as Factor
from .factors import NumericalFactor as NumericalFactor
from .factors import PriorFactor as PriorFactor
from .graph import FactorGraph as FactorGraph
from .key import Key as Key
from .key import key as key
from .manifolds import SE2 as SE2
from .manifolds import SE3 as SE3
from .manifolds import SO2 as SO2
from .manifolds import SO3 as SO3
from .manifolds import Sim3 as Sim3
from .problem import Problem as Problem
from .solvers import chordal_initialization as chordal_initialization
from .solvers import marginals as marginals
from .solvers import optimize as optimize
from .solvers.result import Result as Result
from .solvers.result import Status as Status
from .variables import Variables as Variables

_LAZY = {"io": ".io", "plot": ".plot", "datasets": ".datasets", "symbolic": ".symbolic",
         "distributed": ".distributed",
         "solvers": ".solvers", "cameras": ".cameras"}


def __getattr__(name: str):
    """Heavier parts load on first use: ``fgopt.io``, ``fgopt.plot``, ``fgopt.factor``,
    ``fgopt.manifold`` / ``Product`` / ``check_manifold``, and the numeric ``Unit3``,
    ``OrientedPlane3``, ``SE23`` (their symbolic twins are ``fgopt.symbolic.Unit3`` ...)."""
    import importlib

    if name in _LAZY:
        return importlib.import_module(_LAZY[name], __name__)
    if name == "solve_many":
        from .distributed import solve_many

        return solve_many
    if name == "factor":
        from .factors.decorator import factor

        return factor
    if name in ("manifold", "Product", "check_manifold"):
        from .symbolic import declare

        return getattr(declare, name)
    if name in ("Unit3", "OrientedPlane3", "SE23"):  # numeric value types of shipped manifolds
        from .symbolic import geometry

        return getattr(geometry, name).Value
    raise AttributeError(f"module 'fgopt' has no attribute {name!r}")
