"""Optimizer parameters: frozen dataclasses with the defaults GTSAM/Ceres users expect."""

from __future__ import annotations

from dataclasses import dataclass

from .._checks import is_count, is_positive, number
from ..errors import FgoptError


def check_numbers(params, integers: tuple[str, ...] = (), nonnegative: tuple[str, ...] = (),
                  positive: tuple[str, ...] = ()) -> None:
    """Raise an :class:`FgoptError` naming the field when a parameter is not a number of the
    kind it must be: ``integers`` whole numbers >= 0 (``20.0`` is stored as ``20``),
    ``nonnegative`` finite numbers >= 0, ``positive`` finite numbers > 0 (``None`` passes where
    it is the field's default)."""
    for f in integers:
        v = getattr(params, f)
        if type(v) is int and v >= 0:  # the common case first: every optimize call checks
            continue
        if not is_count(v):
            raise FgoptError(f"{type(params).__name__}.{f} must be an integer >= 0, got {v!r}")
        object.__setattr__(params, f, int(v))  # (frozen dataclass: set once, here)
    for f, low in [(f, 0.0) for f in nonnegative] + [(f, None) for f in positive]:
        v = getattr(params, f)
        if type(v) is float and (0.0 < v if low is None else 0.0 <= v) and v < _INF:
            continue
        if v is None and getattr(type(params), f, 0) is None:
            continue
        if low is None and not is_positive(v):
            raise FgoptError(f"{type(params).__name__}.{f} must be a finite number > 0, got "
                             f"{v!r}")
        x = number(v)
        if x is None or not 0.0 <= x < _INF:
            raise FgoptError(f"{type(params).__name__}.{f} must be a finite number >= 0, got "
                             f"{v!r}")


_INF = float("inf")


@dataclass(frozen=True)
class TerminationParams:
    """Stopping rules shared by every method (GTSAM's and Ceres' defaults, see each field).

    Example:

    >>> from fgopt.solvers import TerminationParams
    >>> TerminationParams().max_iterations, TerminationParams().gradient_tolerance
    (100, 1e-10)
    """

    max_iterations: int = 100
    """Upper bound on iterations (each linear solve counts, accepted or not)."""
    relative_tolerance: float | None = None
    """Stop when an accepted step decreases the cost by less than this fraction. ``None``: GTSAM's
    1e-5, or Ceres' 1e-6 where LM follows Ceres (problems with vector variables, e.g. BA, where
    1e-5 stops Ladybug-49 3e-5 above Ceres' final cost)."""
    absolute_tolerance: float = 1e-5
    """Stop when an accepted step decreases the cost by less than this amount (GTSAM's)."""
    gradient_tolerance: float = 1e-10
    """Stop when max |J^T W r| falls below this (Ceres' gradient_tolerance)."""
    step_tolerance: float = 1e-10
    """Stop when |delta| <= step_tolerance * (|x| + step_tolerance) (Ceres' parameter tolerance)."""

    # fields checked when the params are built (subclasses add theirs; no annotation: not fields)
    _INTEGERS = ("max_iterations",)
    _NONNEGATIVE = ("relative_tolerance", "absolute_tolerance", "gradient_tolerance",
                    "step_tolerance")
    _POSITIVE = ()

    def __post_init__(self):
        check_numbers(self, self._INTEGERS, self._NONNEGATIVE, self._POSITIVE)


@dataclass(frozen=True)
class LMParams(TerminationParams):
    """Levenberg-Marquardt parameters: damping, its update rule, the linear solver and ordering,
    threads, backend (fields below); ``fgopt.optimize``'s keyword options replace fields.

    Example:

    >>> from fgopt.solvers import LMParams
    >>> params = LMParams(max_iterations=20, damping="diagonal", lambda_policy="nielsen")
    >>> sample = fgopt.datasets.manhattan_2d(num_poses=20, seed=0)
    >>> fgopt.optimize(sample.graph, sample.initial, params=params).success
    True
    """

    _INTEGERS = ("max_iterations", "threads")
    _POSITIVE = ("threads", "initial_lambda", "min_lambda", "max_lambda", "lambda_factor")

    initial_lambda: float | None = None
    """Initial damping of ``H + lambda D``. ``None``: GTSAM's 1e-5 with identity damping, Ceres'
    1e-4 with diagonal damping (with 1e-5 the first Ladybug-49 step is rejected)."""
    min_lambda: float = 1e-12
    max_lambda: float = 1e12
    """Give up (no decrease possible) when the damping exceeds this."""
    min_diagonal: float = 1e-6
    max_diagonal: float = 1e32
    min_relative_decrease: float = 1e-3
    """A step is accepted when actual/predicted decrease exceeds this (Ceres' default)."""
    damping: str = "auto"
    """``"diagonal"``: D = clip(diag H) (Ceres, scale invariant); ``"identity"``: D = I (GTSAM);
    ``"auto"``: identity when the problem has Lie-group variables and is not BA-shaped (pose
    graphs: M3500 converges in 5 iterations instead of 8, garage 4 instead of 7; IMU + GPS
    navigation: 3 instead of 41), diagonal for BA-shaped and vector-only problems (identity
    damping needs 99 iterations on Ladybug-49 where diagonal needs 22), and diagonal for a run
    from a chordal start, whose errors are spread over the whole graph (``fgopt.optimize``'s
    ``initialization``: MIT 67 iterations instead of 187, garage 53 instead of 149); see
    ``fgopt.solvers.lm.auto_policy``."""
    lambda_policy: str = "auto"
    """``"nielsen"``: on success lambda *= max(1/3, 1 - (2 rho - 1)^3), on failure *= nu with nu
    doubling (Ceres); ``"factor"``: /= ``lambda_factor`` on success, *= on failure (GTSAM);
    ``"auto"``: ``"factor"`` for pose graphs (only Lie-group variables), ``"nielsen"``
    otherwise (``fgopt.solvers.lm.auto_policy``)."""
    lambda_factor: float = 10.0
    linear_solver: str = "auto"
    ordering: str = "amd"
    """Fill-reducing order of the variable graph: amd (fgopt's own on the numba backend,
    CHOLMOD's or SuperLU's MMD on NumPy) | mmd | cholmod_amd | metis | nesdis | colamd |
    natural."""
    threads: int = 1
    """Threads for linearization (numba prange + nogil kernels); 1 = serial (the default).
    The BLAS libraries loaded in the process use this many threads during the solve (restored
    after it; ``fgopt._threads.blas_threads``)."""
    backend: str = "auto"
    """``"numba"``: numba kernels for batches above 1000 factors; ``"numpy"``: NumPy twins,
    NumPy assembly and retracts and a no-numba linear solver (CHOLMOD / qdldl) for every batch;
    ``"auto"``: NumPy in a process that has not loaded numba yet, for problems of tangent
    dimension <= ``fgopt.problem.NUMPY_BACKEND_MAX_SIZE`` (``Problem.choose_backend``)."""
    verbose: bool = False


@dataclass(frozen=True)
class GaussNewtonParams(TerminationParams):
    """Gauss-Newton parameters (``method="gn"``): stopping rules, linear solver, ordering.

    Example:

    >>> from fgopt.solvers import GaussNewtonParams
    >>> sample = fgopt.datasets.manhattan_2d(num_poses=20, seed=0)
    >>> r = fgopt.optimize(sample.graph, sample.initial, method="gn",
    ...                    params=GaussNewtonParams(max_iterations=10))
    >>> r.method, r.success
    ('gn', True)
    """

    _INTEGERS = ("max_iterations", "threads")
    _POSITIVE = ("threads",)

    linear_solver: str = "auto"
    ordering: str = "amd"
    threads: int = 1
    backend: str = "auto"
    """``"numba"``: numba kernels for batches above 1000 factors; ``"numpy"``: NumPy twins,
    NumPy assembly and retracts and a no-numba linear solver (CHOLMOD / qdldl) for every batch;
    ``"auto"``: NumPy in a process that has not loaded numba yet, for problems of tangent
    dimension <= ``fgopt.problem.NUMPY_BACKEND_MAX_SIZE`` (``Problem.choose_backend``)."""
    verbose: bool = False


@dataclass(frozen=True)
class DoglegParams(TerminationParams):
    """Powell's dogleg parameters (``method="dogleg"``): trust-region radius and its updates.

    Example:

    >>> from fgopt.solvers import DoglegParams
    >>> sample = fgopt.datasets.manhattan_2d(num_poses=20, seed=0)
    >>> fgopt.optimize(sample.graph, sample.initial, method="dogleg",
    ...                params=DoglegParams(initial_radius=10.0)).success
    True
    """

    _INTEGERS = ("max_iterations", "threads")
    _POSITIVE = ("threads", "initial_radius")

    initial_radius: float = 1.0
    """Initial trust-region radius (GTSAM's deltaInitial)."""
    min_radius: float = 1e-12
    regularization: float = 1e-9
    """Tiny diagonal damping so gauge-free problems (no prior) still factor."""
    linear_solver: str = "auto"
    ordering: str = "amd"
    threads: int = 1
    backend: str = "auto"
    """``"numba"``: numba kernels for batches above 1000 factors; ``"numpy"``: NumPy twins,
    NumPy assembly and retracts and a no-numba linear solver (CHOLMOD / qdldl) for every batch;
    ``"auto"``: NumPy in a process that has not loaded numba yet, for problems of tangent
    dimension <= ``fgopt.problem.NUMPY_BACKEND_MAX_SIZE`` (``Problem.choose_backend``)."""
    verbose: bool = False
