"""Levenberg-Marquardt with a gain-ratio trust-region test.

Each iteration solves ``(H + lambda D) delta = -g``, with ``D = clip(diag H, min, max)`` (Ceres'
scale-invariant "diagonal damping") or ``D = I`` (GTSAM's default), predicts the decrease of the quadratic model
``L(delta) = 0.5 |J delta + r|^2``, and accepts when ``rho = actual / predicted`` exceeds
``min_relative_decrease``. On success lambda shrinks by ``max(1/3, 1 - (2 rho - 1)^3)``
(Nielsen, as Ceres) or by a fixed factor 10 (GTSAM); on failure it grows by a factor ``nu`` that
doubles each consecutive failure (or by 10). ``LMParams.damping="auto"`` picks GTSAM's pair for
pure Lie-group problems and Ceres' for problems with vector variables (BA); see LMParams. Damping changes only H's diagonal, so the linear solver's analysis is reused.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..errors import NotPositiveDefiniteError
from ..manifolds.base import is_vector_kind
from ..variables import Variables
from ._run import Callback, Run
from .params import LMParams
from .result import Result, Status


class LevenbergMarquardt:
    """``LevenbergMarquardt(LMParams(...)).optimize(graph, initial)`` -> :class:`Result`."""

    def __init__(self, params: LMParams | None = None, linear_solver: Any = None):
        self.params = params or LMParams()
        self.linear_solver = linear_solver

    def optimize(self, graph: Any, initial: Variables, callback: Callback | None = None) -> Result:
        return self.iterate(Run(graph, initial, self.params, "lm", callback, self.linear_solver))

    def optimize_problem(self, problem: Any, state: Any = None, solver: Any = None,
                         callback: Callback | None = None) -> Result:
        """Continue on a compiled problem (from ``state``; reusing an analyzed ``solver``)."""
        return self.iterate(Run(None, None, self.params, "lm", callback, self.linear_solver,
                                problem=problem, state=state, solver=solver))

    def iterate(self, run: Run) -> Result:
        p = self.params
        problem = run.problem
        identity = p.damping == "identity" or (
            p.damping == "auto" and not any(is_vector_kind(k) for k in problem.kinds)
            and len(problem._slow_vars) == 0)
        by_factor = p.lambda_policy == "factor" or (p.lambda_policy == "auto" and identity)
        # GTSAM's defaults where LM follows GTSAM (identity damping), Ceres' where it follows Ceres
        run.relative_tolerance = p.relative_tolerance if p.relative_tolerance is not None else (
            1e-5 if identity else 1e-6)
        initial_lambda = p.initial_lambda if p.initial_lambda is not None else (
            1e-5 if identity else 1e-4)
        diag_pos = problem.pattern.diag_pos
        lam, nu = initial_lambda, 2.0
        msg = run.converged_by_gradient()
        if msg is not None:
            return run.finish(Status.CONVERGED, msg)
        for it in range(1, p.max_iterations + 1):
            H, g = problem.H_data, problem.g
            if identity:
                D = np.ones(diag_pos.shape[0])
            else:
                D = np.clip(H[diag_pos], p.min_diagonal, p.max_diagonal)
            old = run.cost
            try:
                delta = run.solve_damped(lam * D, -g)
                ok = bool(np.all(np.isfinite(delta)))
            except NotPositiveDefiniteError:
                ok, delta = False, None
            if not ok:
                stop = run.record(it, math.nan, lam, math.nan, False, old)
                lam, nu = lam * nu, nu * 2
                if lam > p.max_lambda:
                    return run.finish(Status.FAILED, "damping exceeded max_lambda: the linear "
                                      "system stays singular (is a variable unconstrained?)")
                if stop:
                    return run.finish(Status.STOPPED, "callback asked to stop")
                continue
            step_norm = float(np.linalg.norm(delta))
            # predicted decrease of the model: -(g.d + 0.5 d.H.d) with (H + lam D) d = -g
            predicted = 0.5 * float(delta @ (lam * D * delta) - g @ delta)
            candidate = problem.retract(run.state, delta)
            # Linearize the trial point right away (its cost comes with it): steps are usually
            # accepted, and then the residuals need not be evaluated a second time.
            new_cost = problem.linearize_candidate(candidate)
            rho = (old - new_cost) / predicted if predicted > 0 else -math.inf
            accepted = math.isfinite(new_cost) and rho > p.min_relative_decrease
            if accepted:
                run.state = candidate
                problem.accept_candidate()
                run.cost = new_cost
                if by_factor:
                    lam = max(p.min_lambda, lam / p.lambda_factor)
                else:
                    lam = max(p.min_lambda, lam * max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3))
                nu = 2.0
                done = run.converged_by_decrease(old, new_cost) or run.converged_by_gradient()
                stop = run.record(it, new_cost, lam, step_norm, True, old)
                if done is not None:
                    return run.finish(Status.CONVERGED, done)
            else:
                problem.reject_candidate(run.state)
                stop = run.record(it, new_cost, lam, step_norm, False, old)
                if by_factor:
                    lam *= p.lambda_factor
                else:
                    lam, nu = lam * nu, nu * 2
                if lam > p.max_lambda:
                    return run.finish(Status.CONVERGED if step_norm < 1e-8 else Status.FAILED,
                                      "no step decreases the cost (damping exceeded max_lambda)")
            done = run.converged_by_step(step_norm)
            if done is not None:
                return run.finish(Status.CONVERGED, done)
            if stop:
                return run.finish(Status.STOPPED, "callback asked to stop")
        return run.finish(Status.MAX_ITERATIONS, f"reached max_iterations={p.max_iterations}")
