"""Powell's dogleg trust-region method.

Per linearization: the Gauss-Newton step ``h_gn = -H^-1 g`` (one factorization, reused while the
radius shrinks) and the Cauchy step ``h_sd = -alpha g`` with ``alpha = g.g / g.H.g``. The step is
``h_gn`` if it fits the radius ``Delta``, else the scaled gradient step if even ``h_sd`` does not,
else the point where the segment ``h_sd -> h_gn`` leaves the trust region. The radius grows
(to ``max(Delta, 3|h|)``) when the gain ratio exceeds 0.75 and halves below 0.25. A rejected
step (no decrease, or a value, cost, residual or Jacobian that is not finite at the trial
point) sets the radius to half the rejected step's length, so the next trial is shorter.

A small cost decrease does not count as convergence when the step was cut short by the trust
region and the model predicted it poorly (gain ratio < 0.25): the decrease is small because the
region is. With right derivatives the gain ratio tends to 1 as the region shrinks, so a region
that keeps shrinking means the model is wrong (e.g. a wrong hand-written Jacobian: gain ratio
stuck near 0.24 on miniSAM's GPS example); such a run ends as ``Status.STALLED``, not converged.
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
from .params import DoglegParams
from .result import Result, Status


def _norm(x: np.ndarray) -> float:
    """``np.linalg.norm`` of a 1-D array (the same sqrt of the dot product), without its
    argument handling: a few us per call on the small systems where per-step overhead shows."""
    return math.sqrt(float(x @ x))


def dogleg_step(h_gn: np.ndarray, h_sd: np.ndarray, g: np.ndarray, radius: float) -> np.ndarray:
    n_gn = _norm(h_gn)
    if n_gn <= radius:
        return h_gn
    n_sd = _norm(h_sd)
    if n_sd >= radius:
        return -(radius / _norm(g)) * g
    # solve |h_sd + beta (h_gn - h_sd)| = radius for beta in [0, 1]
    d = h_gn - h_sd
    a, b, c = float(d @ d), 2.0 * float(h_sd @ d), n_sd * n_sd - radius * radius
    beta = (-b + math.sqrt(max(b * b - 4 * a * c, 0.0))) / (2 * a)
    return h_sd + beta * d


class Dogleg:
    """Powell's dogleg trust-region method over the compiled problem (``method="dogleg"``);
    ``Dogleg(params).optimize(graph, initial)`` -> :class:`~fgopt.solvers.Result`.

    Example:

    >>> from fgopt.solvers import Dogleg
    >>> sample = fgopt.datasets.manhattan_2d(num_poses=20, seed=0)
    >>> Dogleg().optimize(sample.graph, sample.initial).method
    'dogleg'
    """

    def __init__(self, params: DoglegParams | None = None, linear_solver: Any = None):
        self.params = params or DoglegParams()
        self.linear_solver = linear_solver

    def optimize(self, graph: Any, initial: Variables, callback: Callback | None = None,
                 constant: Any = None, bounds: Any = None) -> Result:
        """``constant``: variables / coordinates held fixed (:mod:`fgopt.bounds`); bounds need
        ``method="lm"``."""
        refuse_constraints(graph, "Dogleg")
        p = self.params
        require_no_bounds(bounds, "dogleg")
        run = Run(graph, initial, p, "dogleg", callback, self.linear_solver, constant=constant)
        with blas_threads(run.problem.size, run.problem.threads):
            return self.iterate(run)

    def iterate(self, run: Run) -> Result:
        p = self.params
        problem = run.problem
        pattern = problem.pattern
        radius = p.initial_radius
        msg = run.converged_by_gradient()
        if msg is not None:
            return run.finish(Status.CONVERGED, msg)
        h_gn = h_sd = None
        it = 0
        while it < p.max_iterations:
            H, g = problem.H_data, problem.g
            if h_gn is None:
                try:
                    h_gn = run.solve_damped(
                        p.regularization * np.maximum(H[pattern.diag_pos], 1e-6), -g)
                except NotPositiveDefiniteError as exc:
                    return run.finish(Status.FAILED, str(describe_indefinite(
                        exc, problem.var_keys, "dogleg", "add a prior or use method='lm'")))
                if not np.all(np.isfinite(h_gn)):
                    return run.finish(Status.FAILED, "the Gauss-Newton step is not finite")
                gHg = float(g @ pattern.matvec(H, g))
                h_sd = -(float(g @ g) / gHg) * g if gHg > 0 else -g
            it += 1
            old = run.cost
            h = dogleg_step(h_gn, h_sd, g, radius)
            step_norm = _norm(h)
            predicted = -float(g @ h) - 0.5 * float(h @ pattern.matvec(H, h))
            candidate = problem.retract(run.state, h)
            # Linearize the trial point right away (its cost comes with it, NaN when a value,
            # residual or Jacobian is not finite): steps are usually accepted, and the next one
            # needs the Jacobian there, so the residuals are not evaluated twice.
            new_cost = problem.linearize_candidate(candidate)
            rho = (old - new_cost) / predicted if predicted > 0 else -math.inf
            accepted = math.isfinite(new_cost) and rho > 0
            # a step the trust region cut short whose gain ratio is poor: its small decrease
            # says nothing about convergence (the region, not the optimum, made it small)
            poor = rho < 0.25 and step_norm < (1.0 - 1e-9) * _norm(h_gn)
            done = run.converged_by_decrease(old, new_cost) if accepted and not poor else None
            used_radius = radius
            if not accepted:
                # shrink below the rejected step, not only the radius: a Gauss-Newton step well
                # inside the region would otherwise be retried unchanged (a NaN trial forever)
                radius = 0.5 * min(radius, step_norm)
            elif rho > 0.75:
                radius = max(radius, 3.0 * step_norm)
            elif rho < 0.25:
                radius = 0.5 * radius
            if accepted:
                run.state = candidate
                problem.accept_candidate()
                if done is None:
                    done = run.converged_by_gradient()
                run.cost = new_cost
                h_gn = None
                stop = run.record(it, new_cost, used_radius, step_norm, True, old, predicted,
                                  poor=poor)
                if done is not None:
                    return run.finish(Status.CONVERGED, done)
            else:
                problem.reject_candidate(run.state)  # H back to the current state's (no-op
                # unless a trial was linearized into H itself)
                stop = run.record(it, new_cost, used_radius, step_norm, False, old, predicted)
                if radius < p.min_radius:
                    return run.finish(Status.CONVERGED, "trust region collapsed: no further decrease")
            done = run.converged_by_step(step_norm)
            if done is not None:
                return run.finish(Status.CONVERGED, done)
            if stop:
                return run.finish(Status.STOPPED, "callback asked to stop")
        return run.finish(Status.MAX_ITERATIONS, f"reached max_iterations={p.max_iterations}")
