"""fgopt: factor-graph optimization on manifolds from Python.

>>> import fgopt
>>> from fgopt import key, SE2
>>> graph, initial = fgopt.FactorGraph(), fgopt.Variables()
>>> ... add factors and values ...
>>> result = fgopt.optimize(graph, initial, method="lm")
"""

__version__ = "0.1.0"

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
         "solvers": ".solvers", "incremental": ".incremental"}


def __getattr__(name: str):
    """Heavier parts load on first use: ``fgopt.io``, ``fgopt.plot``, ``fgopt.factor`` ..."""
    import importlib

    if name in _LAZY:
        return importlib.import_module(_LAZY[name], __name__)
    if name in ("IncrementalSmoother", "IncrementalParams", "FixedLagSmoother"):
        from . import incremental

        return getattr(incremental, name)
    if name == "factor":
        from .symbolic.factor import factor

        return factor
    raise AttributeError(f"module 'fgopt' has no attribute {name!r}")
