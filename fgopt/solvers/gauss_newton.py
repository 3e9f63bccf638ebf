"""Gauss-Newton: solve ``H delta = -g`` and take the full step.

Without damping, H must be positive definite: fix the gauge with a prior (a pose graph without
one is singular). A step that increases the cost ends the run with the last good values. A step
to a point where a value, the cost, a residual or a Jacobian is not finite is rejected and
halved (backtracking along the Gauss-Newton direction) until it lands on a finite point; the
run fails only when the halved step falls below ``step_tolerance``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .._threads import blas_threads
from ..errors import NotPositiveDefiniteError
from ..variables import Variables
from ._run import Callback, Run, refuse_constraints, require_no_bounds
from .linear.base import describe_indefinite
from .params import GaussNewtonParams
from .result import Result, Status


class GaussNewton:
    """Gauss-Newton over the compiled problem (``method="gn"``; a step that raises the cost or
    is non-finite is halved); ``GaussNewton(params).optimize(graph, initial)`` ->
    :class:`~fgopt.solvers.Result`.

    Example:

    >>> from fgopt.solvers import GaussNewton
    >>> sample = fgopt.datasets.manhattan_2d(num_poses=20, seed=0)
    >>> GaussNewton().optimize(sample.graph, sample.initial).success
    True
    """

    def __init__(self, params: GaussNewtonParams | None = None, linear_solver: Any = None):
        self.params = params or GaussNewtonParams()
        self.linear_solver = linear_solver

    def optimize(self, graph: Any, initial: Variables, callback: Callback | None = None,
                 constant: Any = None, bounds: Any = None) -> Result:
        """``constant``: variables / coordinates held fixed (:mod:`fgopt.bounds`); bounds need
        ``method="lm"``."""
        refuse_constraints(graph, "GaussNewton")
        p = self.params
        require_no_bounds(bounds, "gn")
        run = Run(graph, initial, p, "gn", callback, self.linear_solver, constant=constant)
        with blas_threads(run.problem.size, run.problem.threads):
            return self.iterate(run)

    def iterate(self, run: Run) -> Result:
        p = self.params
        problem = run.problem
        msg = run.converged_by_gradient()
        if msg is not None:
            return run.finish(Status.CONVERGED, msg)
        delta = None  # a rejected (non-finite) step, halved on the next iteration
        for it in range(1, p.max_iterations + 1):
            old = run.cost
            if delta is None:
                try:
                    delta = run.solve_damped(None, -problem.g)
                except NotPositiveDefiniteError as exc:
                    return run.finish(Status.FAILED, str(describe_indefinite(
                        exc, problem.var_keys, "Gauss-Newton",
                        "add a prior to fix the gauge, or use method='lm'")))
                if not np.all(np.isfinite(delta)):
                    return run.finish(Status.FAILED, "the Gauss-Newton step is not finite")
            step_norm = float(np.linalg.norm(delta))
            candidate = problem.retract(run.state, delta)
            new_cost = problem.cost(candidate)
            if math.isfinite(new_cost) and new_cost > old:
                run.record(it, new_cost, 0.0, step_norm, False, old)
                return run.finish(Status.FAILED, f"the step increased the cost ({old:.6g} -> "
                                  f"{new_cost:.6g}); kept the last good values; try method='lm'")
            done = run.converged_by_decrease(old, new_cost) if math.isfinite(new_cost) else None
            if math.isfinite(new_cost) and done is None:
                # the next step needs the Jacobian here: a non-finite one rejects the point too
                new_cost = problem.linearize_candidate(candidate)
            if not math.isfinite(new_cost):
                problem.reject_candidate(run.state)  # H back to the current state's
                stop = run.record(it, new_cost, 0.0, step_norm, False, old)
                delta = 0.5 * delta
                if run.converged_by_step(0.5 * step_norm) is not None:
                    return run.finish(Status.FAILED, "no finite point along the Gauss-Newton "
                                      "step (a value, residual or Jacobian is NaN/inf there); "
                                      "kept the last good values; try method='lm'")
                if stop:
                    return run.finish(Status.STOPPED, "callback asked to stop")
                continue
            delta = None
            run.state = candidate
            if done is None:
                problem.accept_candidate()
                run.cost = new_cost
                done = run.converged_by_gradient() or run.converged_by_step(step_norm)
            else:
                run.cost = new_cost
            stop = run.record(it, new_cost, 0.0, step_norm, True, old)
            if done is not None:
                return run.finish(Status.CONVERGED, done)
            if stop:
                return run.finish(Status.STOPPED, "callback asked to stop")
        return run.finish(Status.MAX_ITERATIONS, f"reached max_iterations={p.max_iterations}")
