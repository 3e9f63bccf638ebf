"""fgopt: factor-graph optimization on manifolds from Python.

>>> import fgopt
>>> from fgopt import key, SE2
>>> graph, initial = fgopt.FactorGraph(), fgopt.Variables()
>>> ... add factors and values ...
>>> result = fgopt.optimize(graph, initial, method="lm")
"""

from ._version import __version__ as __version__

# ``fgopt.key`` is both a submodule and the function: import it eagerly (it is tiny) so the
# function, not the module the import system binds, is what ``fgopt.key`` names.
from .errors import FgoptError as FgoptError
from .errors import FgoptWarning as FgoptWarning
from .key import Key as Key
from .key import key as key

# Every other public name loads on first use (PEP 562), so ``import fgopt`` costs what numpy's
# import does and nothing more: numba, scipy and SymPy load when a kernel, a sparse solve or a
# symbolic derivation first needs them (measured in benchmarks/startup.py).
_ATTRS = {
    "noise": (".noise", None),
    "symbol_shorthand": (".symbol_shorthand", None),
    "BetweenFactor": (".factors", "BetweenFactor"),
    "Factor": (".factors", "Factor"),
    "NumericalFactor": (".factors", "NumericalFactor"),
    "PriorFactor": (".factors", "PriorFactor"),
    "FactorGraph": (".graph", "FactorGraph"),
    "SE2": (".manifolds", "SE2"),
    "SE3": (".manifolds", "SE3"),
    "SO2": (".manifolds", "SO2"),
    "SO3": (".manifolds", "SO3"),
    "Sim3": (".manifolds", "Sim3"),
    "Problem": (".problem", "Problem"),
    "chordal_initialization": (".solvers", "chordal_initialization"),
    "check_jacobians": (".solvers", "check_jacobians"),
    "marginals": (".solvers", "marginals"),
    "optimize": (".solvers", "optimize"),
    "Result": (".solvers.result", "Result"),
    "Status": (".solvers.result", "Status"),
    "Variables": (".variables", "Variables"),
    "factor": (".factors.decorator", "factor"),
    "const": (".factors.decorator", "const"),
    "constraint": (".factors.constraint", "constraint"),
    "io": (".io", None),
    "plot": (".plot", None),
    "datasets": (".datasets", None),
    "symbolic": (".symbolic", None),
    "solvers": (".solvers", None),
    "distributed": (".distributed", None),
    "cameras": (".cameras", None),
    "navigation": (".navigation", None),
    # fgopt.navigation costs ~0.1 s to import: its classes load with it, on first use
    "NavState": (".navigation", "NavState"),
    "ImuBias": (".navigation", "ImuBias"),
    "PreintegrationParams": (".navigation", "PreintegrationParams"),
    "PreintegratedImu": (".navigation", "PreintegratedImu"),
    "PreintegratedCombinedImu": (".navigation", "PreintegratedCombinedImu"),
    "ImuFactor": (".navigation", "ImuFactor"),
    "CombinedImuFactor": (".navigation", "CombinedImuFactor"),
    "GpsFactor": (".navigation", "GpsFactor"),
    "solve_many": (".distributed", "solve_many"),
    "manifold": (".symbolic.declare", "manifold"),
    "Product": (".symbolic.declare", "Product"),
    "check_manifold": (".symbolic.declare", "check_manifold"),
    "incremental": (".incremental", None),
    "IncrementalSmoother": (".incremental", "IncrementalSmoother"),
    "IncrementalParams": (".incremental", "IncrementalParams"),
    "FixedLagSmoother": (".incremental", "FixedLagSmoother"),
}
#: Numeric value types of the manifolds shipped as declarations (their symbolic twins are
#: ``fgopt.symbolic.Unit3`` ...).
_DECLARED_VALUES = ("Unit3", "OrientedPlane3", "SE23")

__all__ = ["__version__", "FgoptError", "FgoptWarning", "Key", "key", *_ATTRS, *_DECLARED_VALUES]


def __getattr__(name: str):
    """Public names load on first use: ``fgopt.optimize``, ``fgopt.SE2``, ``fgopt.io`` ..."""
    import importlib

    if name in _DECLARED_VALUES:
        value = getattr(importlib.import_module(".symbolic.geometry", __name__), name).Value
        globals()[name] = value
        return value
    try:
        module, attr = _ATTRS[name]
    except KeyError:
        raise AttributeError(f"module 'fgopt' has no attribute {name!r}") from None
    mod = importlib.import_module(module, __name__)
    value = mod if attr is None else getattr(mod, attr)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_ATTRS) | set(_DECLARED_VALUES))
