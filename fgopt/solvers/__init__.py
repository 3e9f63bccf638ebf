"""Nonlinear optimizers (LM, Gauss-Newton, Dogleg) over a compiled problem, ``optimize``, and
``check_jacobians`` (a factor's Jacobians against central differences)."""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

from ..errors import FgoptError
from .dogleg import Dogleg as Dogleg
from .gauss_newton import GaussNewton as GaussNewton
from .initialization import check as check_initialization
from .initialization import for_chordal_start, optimize_auto
from .linear.base import LinearSolver as LinearSolver
from .linear.base import make_linear_solver as make_linear_solver
from .lm import LevenbergMarquardt as LevenbergMarquardt
from .params import DoglegParams as DoglegParams
from .params import GaussNewtonParams as GaussNewtonParams
from .params import LMParams as LMParams
from .params import TerminationParams as TerminationParams
from .result import IterationRecord as IterationRecord
from .result import Result as Result
from .result import Status as Status



#: Loaded on first use: GNC and the Jacobian check are not on a plain solve's path (~2 ms of a
#: new process, ``fgopt solve``).
_LAZY = {"GNC": ".gnc", "GNCParams": ".gnc", "JacobianReport": ".jacobian_check",
         "check_jacobians": ".jacobian_check", "AugmentedLagrangianParams": ".constrained"}


def __getattr__(name: str):
    """``chordal_initialization`` and ``marginals`` load on first use (they import scipy's
    sparse package, which a small solve does not need), as do GNC and ``check_jacobians``."""
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(_LAZY[name], __name__), name)
        globals()[name] = value
        return value
    if name == "chordal_initialization":
        from .chordal import chordal_initialization

        return chordal_initialization
    if name == "marginals":
        from .covariance import marginals

        return marginals
    raise AttributeError(f"module 'fgopt.solvers' has no attribute {name!r}")


_METHODS = {"lm": (LevenbergMarquardt, LMParams), "gn": (GaussNewton, GaussNewtonParams),
            "dogleg": (Dogleg, DoglegParams), "gnc": None}  # gnc: resolved on first use


def optimize(graph: Any, initial: Any, method: str = "lm", linear_solver: Any = "auto",
             max_iterations: int | None = None, verbose: bool | None = None, callback: Any = None,
             params: Any = None, initialization: str = "auto",
             constraint_params: Any = None, constant: Any = None, bounds: Any = None,
             **options: Any) -> Result:
    """Minimize ``graph.error`` from ``initial``; returns a :class:`Result` (``initial`` untouched).

    Args:
        graph: the :class:`~fgopt.FactorGraph`.
        initial: :class:`~fgopt.Variables` with a value for every key the graph uses.
        method: ``"lm"`` (Levenberg-Marquardt), ``"gn"`` (Gauss-Newton), ``"dogleg"`` or
            ``"gnc"`` (graduated non-convexity around LM, for outliers; see ``GNCParams``).
        linear_solver: ``"auto" | "cholmod" | "ldlt" | "pcg" | "dense"`` or a solver object;
            ``"auto"`` picks by problem shape (dense for tiny, CHOLMOD otherwise, ...).
        max_iterations: iteration limit (every linear solve counts; default 100).
        verbose: print the per-iteration table (default False).
        callback: ``f(record: IterationRecord)``; return True to stop.
        params: a parameter dataclass (``LMParams`` ...) overriding the defaults; other keyword
            ``options`` (e.g. ``relative_tolerance=1e-8``) replace its fields.
        initialization: where to start (:mod:`fgopt.solvers.initialization`). ``"auto"``
            (default): from ``initial``; then, if the final cost is above what the noise models
            allow at an optimum (a chi-square test) and ``graph`` is a pose graph, also from
            the chordal relaxation, keeping the lower cost (torus3D: 12,118 instead of 29,954;
            nothing changes, and nothing is spent, where the test passes). ``"given"``: from
            ``initial`` only (GTSAM's behaviour). ``"chordal"``: from the chordal relaxation
            only (:func:`chordal_initialization`; ``initial`` names the keys and anchors the
            gauge). ``result.info["initialization"]`` says which start the result comes from,
            ``result.info["initialization_reason"]`` why. Methods ``"gnc"`` (which starts its
            rounds from chordal estimates itself) always start from ``initial``.
        constraint_params: for a graph holding constraints (:func:`fgopt.constraint`), an
            :class:`~fgopt.solvers.constrained.AugmentedLagrangianParams` (tolerance, penalty
            schedule). Such a graph is solved by an augmented-Lagrangian loop around LM from
            ``initial`` (``initialization="chordal"``: from the chordal relaxation of its cost;
            ``"auto"`` is ``"given"``), with ``constant`` and ``bounds`` kept by the inner LM
            (:mod:`fgopt.solvers.constrained`); the result carries
            ``constraint_violation`` and ``multipliers``, and ends ``Status.INFEASIBLE`` when the
            constraints cannot be met.
        constant: keys held fixed (they leave the linear system; their values come back bit
            for bit), or a dict ``{key: None | [coordinate indices]}`` holding whole variables
            and single coordinates of vector-valued ones (Ceres' subset manifold).
        bounds: ``{key: (lower, upper)}`` on vector, scalar and calibration variables (arrays
            of the tangent dimension or scalars; ``-inf`` / ``inf`` per coordinate); kept by
            projected LM steps, so every iterate is feasible (``method="lm"``). The initial
            values must be feasible. With ``constant`` or ``bounds`` the run starts from
            ``initial`` (``initialization="auto"`` is ``"given"``). See :mod:`fgopt.bounds`
            and the guide page "Constant variables and bounds".

    Example::

        result = fgopt.optimize(graph, initial, constant=[key("x", 0)],
                                bounds={key("k", 0): (0.0, np.inf)})
    """
    if method not in _METHODS:
        raise FgoptError(f"unknown method {method!r}: choose one of {', '.join(_METHODS)}")
    if method == "gnc":
        from .gnc import GNC, GNCParams

        _METHODS["gnc"] = (GNC, GNCParams)
    cls, params_cls = _METHODS[method]
    if params is None:
        params = _default_params(params_cls)
    fields = _field_names(type(params))
    unknown = set(options) - fields
    if unknown:
        raise FgoptError(f"unknown option(s) {sorted(unknown)} for method {method!r}; "
                         f"valid: {sorted(fields)}")
    overrides = dict(options)
    if max_iterations is not None:
        overrides["max_iterations"] = max_iterations  # checked by the params
    if verbose is not None:
        overrides["verbose"] = bool(verbose)
    if isinstance(linear_solver, str):
        overrides["linear_solver"] = linear_solver
        solver_obj = None
    else:
        solver_obj = linear_solver
    if any(_differs(getattr(params, k), v) for k, v in overrides.items()):
        params = dataclasses.replace(params, **overrides)  # frozen: unchanged ones are shared
    check_initialization(initialization)
    restrict = {}
    if constant is not None or bounds is not None:
        if method == "gnc" or initialization == "chordal":
            raise FgoptError("constant / bounds work with methods 'lm', 'gn' and 'dogleg', and "
                             "initialization 'given' or 'auto'")
        restrict = {"constant": constant, "bounds": bounds}
        initialization = "given"  # a chordal start would move the constant variables
    if len(getattr(graph, "constraints", ())) > 0:
        if method != "lm":
            raise FgoptError(f"method={method!r} does not enforce constraints and the graph "
                             f"holds {len(graph.constraints)}: use method='lm' (the default; an "
                             "augmented-Lagrangian loop around LM), or remove the constraints")
        from .constrained import inner_schedule, optimize_constrained

        start = initial
        if initialization == "chordal":  # the relaxation of the cost alone, then the loop
            from .chordal import chordal_initialization

            start = chordal_initialization(graph, initial)
        result = optimize_constrained(graph, start, inner_schedule(params, set(options),
                                                                   constraint_params),
                                      constraint_params, solver_obj, callback, **restrict)
        result.info["initialization"] = "chordal" if start is not initial else "given"
        return result

    def run(start: Any, run_params: Any) -> Result:
        return _optimize_from(graph, start, cls, run_params, solver_obj, method, callback,
                              **restrict)

    if method == "gnc" or initialization == "given":
        result = run(initial, params)
        result.info.setdefault("initialization", "given")
        return result
    if initialization == "chordal":
        from .chordal import chordal_initialization

        result = run(chordal_initialization(graph, initial), for_chordal_start(params))
        result.info["initialization"] = "chordal"
        return result
    return optimize_auto(graph, initial, params, run)


@functools.lru_cache(maxsize=None)
def _default_params(params_cls: type) -> Any:
    """One default parameter object per class (they are frozen): a solve's per-params caches
    (the small driver's parameter array) then hit on every default call instead of making a new
    object and entry each time (~5 us of a few-pose solve)."""
    return params_cls()


@functools.lru_cache(maxsize=None)
def _field_names(params_cls: type) -> frozenset:
    """The option names of a parameter dataclass (looked up once per class: ~5 us a call)."""
    return frozenset(f.name for f in dataclasses.fields(params_cls))


def _differs(a: Any, b: Any) -> bool:
    if a is b:
        return False
    try:
        return type(a) is not type(b) or bool(a != b)
    except (TypeError, ValueError):  # arrays and the like: assume they differ
        return True


def _optimize_from(graph: Any, initial: Any, cls: Any, params: Any, solver_obj: Any,
                   method: str, callback: Any, **restrict: Any) -> Result:
    if method == "gnc":
        if solver_obj is not None:
            raise FgoptError("method='gnc' takes linear_solver by name")
        return cls(params).optimize(graph, initial, callback=callback)
    return cls(params, solver_obj).optimize(graph, initial, callback=callback, **restrict)


#: The public names (each has an entry in the API reference: tests/test_docs_reference.py).
__all__ = ["Dogleg", "GaussNewton", "LinearSolver", "make_linear_solver", "LevenbergMarquardt",
           "DoglegParams", "GaussNewtonParams", "LMParams", "TerminationParams", "IterationRecord",
           "Result", "Status", "GNC", "GNCParams", "JacobianReport", "check_jacobians",
           "chordal_initialization", "marginals", "optimize"]
