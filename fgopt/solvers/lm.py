"""Levenberg-Marquardt with a gain-ratio trust-region test.

Each iteration solves ``(H + lambda D) delta = -g``, with ``D = clip(diag H, min, max)`` (Ceres'
scale-invariant "diagonal damping") or ``D = I`` (GTSAM's default), predicts the decrease of the
quadratic model ``L(delta) = 0.5 |J delta + r|^2``, and accepts when ``rho = actual / predicted``
exceeds ``min_relative_decrease``. On success lambda shrinks by ``max(1/3, 1 - (2 rho - 1)^3)``
(Nielsen, as Ceres) or by a fixed factor 10 (GTSAM); on failure it grows by a factor ``nu`` that
doubles each consecutive failure (or by 10). ``LMParams.damping="auto"`` picks GTSAM's pair for
pose graphs, identity damping with Nielsen's rule for navigation-like problems (Lie groups
mixed with vectors), and Ceres' pair for BA-shaped and vector-only ones (:func:`auto_policy`).
Damping changes only H's diagonal, so the linear solver's analysis is reused.
"""

from __future__ import annotations

import time
from typing import Any

from .._threads import blas_threads
from ..manifolds.base import is_vector_kind
from ..variables import Variables
from . import small
from ._lm_loop import (
    CONVERGED,
    FAILED,
    MAX_ITERATIONS,
    MESSAGES,
    STOPPED,
    GeneralContext,
    lm_loop,
    loop_params,
)
from ._run import Callback, Run, compile_problem, refuse_constraints
from .params import LMParams
from .result import Result, Status

PROBLEM_CLASSES = ("pose", "mixed", "scaled")


def problem_class(problem: Any) -> str:
    """The class ``"auto"`` LM parameters are chosen by (see :func:`auto_policy`)."""
    return problem_class_for(problem.kinds, len(problem._slow_vars) > 0,
                             lambda: problem.pattern)


def problem_class_for(kinds: Any, has_slow: bool, pattern: Any) -> str:
    """:func:`problem_class` from a problem's batch ``kinds``, whether it has slow-path
    variables, and a callable returning its :class:`~fgopt.structure.HessianPattern` (asked only
    for problems mixing Lie groups and vectors): ``"pose"`` (only Lie groups), ``"mixed"``
    (Lie groups and vectors, not BA-shaped) or ``"scaled"`` (BA-shaped, vector-only, or with
    duck-typed variables)."""
    if has_slow:
        return "scaled"
    if not any(is_vector_kind(k) for k in kinds):
        return "pose"
    if all(is_vector_kind(k) for k in kinds):
        return "scaled"
    from .linear._schur_layout import is_ba_shaped

    pat = pattern()
    return "mixed" if pat is not None and not is_ba_shaped(pat) else "scaled"


def auto_policy(cls: str, p: LMParams) -> tuple[bool, bool]:
    """``(identity damping, lambda by a fixed factor)`` for problem class ``cls`` under
    ``LMParams.damping`` / ``lambda_policy`` (``"auto"`` resolved per class, measured):

    * ``"pose"`` (pose graphs): GTSAM's pair, identity damping and lambda multiplied / divided
      by 10. M3500 converges in 5 iterations instead of 8 with Ceres' pair, garage in 4 instead
      of 7; Nielsen's lambda rule would take 10 on garage, 6 on sphere2500.
    * ``"mixed"`` (navigation: SE3 poses, velocities, IMU biases): identity damping with
      Nielsen's lambda rule. The IMU factors make ``diag H`` ~1e8 times the curvature of the
      directions only GPS observes, so Marquardt's ``lambda diag H`` over-damps exactly those:
      GTSAM's ImuFactorsExample needs 41 iterations with diagonal damping, 3 with identity;
      with a GPS fix on every 5th state only (a harder, nonlinear problem) identity + Nielsen
      converges in 87 iterations, diagonal + Nielsen in 102, and GTSAM's pair not in 200.
    * ``"scaled"`` (BA-shaped, e.g. SE3 cameras + points, and vector-only problems such as
      BAL's R^9 cameras): Ceres' pair, scale-invariant diagonal damping and Nielsen's rule;
      identity damping needs 99 iterations on Ladybug-49 where diagonal needs 22.
    """
    identity = p.damping == "identity" or (p.damping == "auto" and cls in ("pose", "mixed"))
    by_factor = p.lambda_policy == "factor" or (p.lambda_policy == "auto" and identity
                                                and cls == "pose")
    return identity, by_factor


_DEFAULT_PARAMS = LMParams()


class LevenbergMarquardt:
    """``LevenbergMarquardt(LMParams(...)).optimize(graph, initial)`` -> :class:`Result`.

    Example:

    >>> from fgopt.solvers import LevenbergMarquardt, LMParams
    >>> sample = fgopt.datasets.manhattan_2d(num_poses=20, seed=0)
    >>> LevenbergMarquardt(LMParams(max_iterations=5)).optimize(sample.graph, sample.initial).iterations <= 5
    True
    """

    def __init__(self, params: LMParams | None = None, linear_solver: Any = None):
        self.params = params or _DEFAULT_PARAMS  # (frozen: one shared default)
        self.linear_solver = linear_solver

    def optimize(self, graph: Any, initial: Variables, callback: Callback | None = None,
                 constant: Any = None, bounds: Any = None) -> Result:
        """``constant``: variables / coordinates held fixed; ``bounds``: key -> (lower, upper)
        on vector-valued variables, kept by projected steps (:mod:`fgopt.bounds`)."""
        refuse_constraints(graph, "LevenbergMarquardt")
        t0 = time.perf_counter()
        plain = constant is None and bounds is None
        if (plain and callback is None and self.linear_solver is None
                and isinstance(initial, Variables)):
            result = small.optimize_file(graph, initial, self.params, t0)
            if result is not None:  # a file's small graph: no Problem compiled first
                return result
        choice = self.linear_solver if self.linear_solver is not None else self.params.linear_solver
        problem = compile_problem(graph, initial, self.params, choice, build_structure=False,
                                  constant=constant, bounds=bounds)
        driver = (problem.restrictions is None and callback is None
                  and self.linear_solver is None and small.qualifies(problem, self.params))
        if driver:
            # a small problem in one compiled call (same iteration, dense; None: the driver is
            # not compiled yet, or the initial linearization is not finite and the general path
            # names the factor)
            result = small.optimize_small(problem, self.params, t0)
            if result is not None:
                return result
        with blas_threads(problem.size, problem.threads):
            result = self.iterate(Run(graph, initial, self.params, "lm", callback,
                                      self.linear_solver, compiled=problem))
        if driver:
            small.charge_general(problem, time.perf_counter() - t0)
        return result

    def optimize_problem(self, problem: Any, state: Any = None, solver: Any = None,
                         callback: Callback | None = None) -> Result:
        """Continue on a compiled problem (from ``state``; reusing an analyzed ``solver``)."""
        with blas_threads(problem.size, problem.threads):
            return self.iterate(Run(None, None, self.params, "lm", callback, self.linear_solver,
                                    problem=problem, state=state, solver=solver))

    def iterate(self, run: Run) -> Result:
        """:func:`~fgopt.solvers._lm_loop.lm_loop` on ``run`` (the loop the small-problem
        driver compiles)."""
        p = self.params
        identity, by_factor = auto_policy(problem_class(run.problem), p)
        prm, rel_tol = loop_params(p, identity, by_factor)
        run.relative_tolerance = rel_tol
        status, msg, value, _, _, _ = lm_loop(GeneralContext(run, identity), prm)
        return run.finish(_STATUS[status], MESSAGES[msg](value, p, rel_tol))


_STATUS = {CONVERGED: Status.CONVERGED, MAX_ITERATIONS: Status.MAX_ITERATIONS,
           FAILED: Status.FAILED, STOPPED: Status.STOPPED}
