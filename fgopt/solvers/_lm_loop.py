"""Levenberg-Marquardt's iteration, written once for every problem size.

:func:`lm_loop` decides: damping, gain ratio, lambda policy, stopping tests and what each
iteration records. What it decides about is reached through seven operations on an opaque
``ctx``, looked up by name in the loop's globals:

=============================  ===============================================================
``_lm_trial(ctx, first)``       cost at the trial point (``first``: at the start point), NaN
                                when it or its linearization is not finite
``_lm_accept(ctx, cost)``       the trial point becomes the iterate
``_lm_reject(ctx)``             the trial point is dropped
``_lm_gradient(ctx)``           ``max |g|`` at the iterate
``_lm_step(ctx, lam, ...)``     solve ``(H + lam D) delta = -g``: ``(ok, |delta|, predicted
                                decrease of the model)``, the step kept for the next trial
``_lm_record(ctx, ...)``        log one iteration; True when the caller asks to stop
``_lm_state_norm(ctx)``         ``|x|`` of the iterate's storage
=============================  ===============================================================

This module defines them for the general path (``ctx`` a :class:`GeneralContext` over a
:class:`~fgopt.solvers._run.Run`: sparse or dense linear solvers, bounds, callbacks), and
:func:`lm_loop` runs on them as plain Python. The small-problem driver
(:mod:`fgopt.solvers.small`) pastes :func:`lm_loop`'s source into its generated module beside
dense numba versions of the seven, and numba compiles the same loop there: the code is in
the numba subset (scalars, tuples, calls; ``prm`` indexable).

``prm``: max_iterations, relative_tolerance, absolute_tolerance, gradient_tolerance,
step_tolerance, initial_lambda, min_lambda, max_lambda, min_diagonal, max_diagonal,
min_relative_decrease, identity damping (1/0), lambda by factor (1/0), lambda_factor
(:func:`loop_params`).
"""

from __future__ import annotations

import inspect
import math
from typing import Any

import numpy as np

from ..errors import NotPositiveDefiniteError

#: :func:`lm_loop`'s status codes (-1: the start point is not finite; the numba driver only,
#: the general path has raised by then).
CONVERGED, MAX_ITERATIONS, FAILED, STOPPED = 0, 1, 2, 3

MESSAGES = {
    1: lambda v, p, rel: f"gradient norm {v:.3g} <= {p.gradient_tolerance:g}",
    2: lambda v, p, rel: f"absolute cost decrease {v:.3g} < {p.absolute_tolerance:g}",
    3: lambda v, p, rel: f"relative cost decrease {v:.3g} < {rel:g}",
    4: lambda v, p, rel: f"step norm {v:.3g} below step_tolerance",
    5: lambda v, p, rel: ("damping exceeded max_lambda: the linear system stays singular (is a "
                          "variable unconstrained?)"),
    6: lambda v, p, rel: "no step decreases the cost (damping exceeded max_lambda)",
    7: lambda v, p, rel: f"reached max_iterations={p.max_iterations}",
    8: lambda v, p, rel: "callback asked to stop",
}


def lm_loop(ctx, prm):
    """LM from the start point until a stopping test holds: ``(status, message code, value,
    iterations, final cost, initial cost)`` (:data:`MESSAGES` formats the code with
    ``value``).

    Each iteration solves ``(H + lam D) delta = -g`` (``D = I`` or ``clip(diag H)``), predicts
    the model's decrease ``-(g.delta + 0.5 delta.H.delta)``, and accepts the trial point when
    ``rho = actual / predicted`` exceeds ``min_relative_decrease``. A failed solve retries with
    more damping without a new linearization. The trial point is linearized as soon as it is
    proposed (steps are usually accepted: its residuals are then not evaluated twice), at one
    call site (the numba driver inlines the whole linearization there once).
    """
    max_it = int(prm[0])
    rtol, atol, gtol, stol = prm[1], prm[2], prm[3], prm[4]
    lam, min_lam, max_lam = prm[5], prm[6], prm[7]
    min_diag, max_diag, min_dec = prm[8], prm[9], prm[10]
    identity, by_factor, lam_factor = prm[11] > 0.5, prm[12] > 0.5, prm[13]
    nu = 2.0
    cost = 0.0
    init = 0.0
    it = 0
    first = True
    step_norm = 0.0
    predicted = 0.0
    stop = False
    while True:
        new_cost = _lm_trial(ctx, first)
        if first:
            first = False
            if not math.isfinite(new_cost):
                return -1, 0, 0.0, 0, new_cost, new_cost
            _lm_accept(ctx, new_cost)
            cost = new_cost
            init = new_cost
            gn = _lm_gradient(ctx)
            if gn <= gtol:
                return CONVERGED, 1, gn, 0, cost, init
        else:
            old = cost
            rho = (old - new_cost) / predicted if predicted > 0 else -math.inf
            accepted = math.isfinite(new_cost) and rho > min_dec
            if accepted:
                _lm_accept(ctx, new_cost)
                cost = new_cost
                if by_factor:
                    lam = max(min_lam, lam / lam_factor)
                else:
                    lam = max(min_lam, lam * max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3))
                nu = 2.0
                stop = _lm_record(ctx, it, cost, new_cost, lam, step_norm, True, old, predicted)
                dec = old - new_cost
                if dec < atol:
                    return CONVERGED, 2, dec, it, cost, init
                if old > 0 and dec / old < rtol:
                    return CONVERGED, 3, dec / old, it, cost, init
                gn = _lm_gradient(ctx)
                if gn <= gtol:
                    return CONVERGED, 1, gn, it, cost, init
            else:
                _lm_reject(ctx)
                stop = _lm_record(ctx, it, cost, new_cost, lam, step_norm, False, old, predicted)
                if by_factor:
                    lam = lam * lam_factor
                else:
                    lam = lam * nu
                    nu = nu * 2.0
                if lam > max_lam:
                    return (CONVERGED if step_norm < 1e-8 else FAILED), 6, step_norm, it, cost, init
            if step_norm <= stol * (_lm_state_norm(ctx) + stol):
                return CONVERGED, 4, step_norm, it, cost, init
            if stop:
                return STOPPED, 8, 0.0, it, cost, init
        # propose the next step (failed factorizations retry with more damping, no linearization)
        while True:
            it += 1
            if it > max_it:
                return MAX_ITERATIONS, 7, 0.0, max_it, cost, init
            ok, step_norm, predicted = _lm_step(ctx, lam, identity, min_diag, max_diag)
            if ok:
                break
            stop = _lm_record(ctx, it, cost, math.nan, lam, math.nan, False, cost, math.inf)
            lam = lam * nu
            nu = nu * 2.0
            if lam > max_lam:
                return FAILED, 5, 0.0, it, cost, init
            if stop:
                return STOPPED, 8, 0.0, it, cost, init


def loop_source() -> str:
    """:func:`lm_loop`'s source, for a generated module that defines the seven operations."""
    return inspect.getsource(lm_loop)


def loop_params(p: Any, identity: bool, by_factor: bool) -> tuple[tuple, float]:
    """``prm`` for LM params ``p`` under a damping policy (see
    :func:`~fgopt.solvers.lm.auto_policy`), and the relative tolerance in it (GTSAM's default
    where LM follows GTSAM, identity damping; Ceres' where it follows Ceres)."""
    rel_tol = p.relative_tolerance if p.relative_tolerance is not None else (
        1e-5 if identity else 1e-6)
    lam0 = p.initial_lambda if p.initial_lambda is not None else (1e-5 if identity else 1e-4)
    return (float(p.max_iterations), rel_tol, p.absolute_tolerance, p.gradient_tolerance,
            p.step_tolerance, lam0, p.min_lambda, p.max_lambda, p.min_diagonal, p.max_diagonal,
            p.min_relative_decrease, float(identity), float(by_factor), p.lambda_factor), rel_tol


class GeneralContext:
    """The general path's ``ctx``: a :class:`~fgopt.solvers._run.Run` (its problem's sparse or
    dense H, its linear solver, bounds, records and callback), the last step and trial point."""

    __slots__ = ("bounded", "candidate", "delta", "ones", "problem", "run")

    def __init__(self, run: Any, identity: bool):
        self.run = run
        self.problem = run.problem
        self.ones = np.ones(self.problem.pattern.diag_pos.shape[0]) if identity else None
        restrictions = self.problem.restrictions
        self.bounded = restrictions is not None and restrictions.has_bounds
        self.delta: Any = None
        self.candidate: Any = None


def _lm_trial(ctx: GeneralContext, first: bool) -> float:
    if first:  # the Run linearized the start point (and named a non-finite factor)
        return ctx.run.cost
    ctx.candidate = ctx.problem.retract(ctx.run.state, ctx.delta)
    return ctx.problem.linearize_candidate(ctx.candidate)


def _lm_accept(ctx: GeneralContext, cost: float) -> None:
    if ctx.candidate is not None:
        ctx.run.state = ctx.candidate
        ctx.problem.accept_candidate()
        ctx.run.cost = cost
        ctx.candidate = None


def _lm_reject(ctx: GeneralContext) -> None:
    ctx.problem.reject_candidate(ctx.run.state)
    ctx.candidate = None


def _lm_gradient(ctx: GeneralContext) -> float:
    return ctx.problem.gradient_norm()


def _lm_state_norm(ctx: GeneralContext) -> float:
    return ctx.run.state_norm()


def _lm_record(ctx: GeneralContext, it: int, cost: float, candidate_cost: float, lam: float,
               step_norm: float, accepted: bool, old: float, predicted: float) -> bool:
    return ctx.run.record(it, candidate_cost, lam, step_norm, accepted, old, predicted)


def _lm_step(ctx: GeneralContext, lam: float, identity: bool, min_diag: float,
             max_diag: float) -> tuple[bool, float, float]:
    problem = ctx.problem
    H, g = problem.H_data, problem.g
    D = ctx.ones if identity else np.clip(H[problem.pattern.diag_pos], min_diag, max_diag)
    try:
        delta = ctx.run.solve_damped(lam * D, -g)
        # |delta|^2 is finite iff every entry is (unless it overflows: check those)
        step_sq = float(delta @ delta)
        ok = math.isfinite(step_sq) or bool(np.all(np.isfinite(delta)))
    except NotPositiveDefiniteError:
        ok = False
    if not ok:
        return False, math.nan, math.nan
    predicted = 0.5 * float(delta @ (lam * D * delta) - g @ delta)
    if ctx.bounded:  # the step projected into the box, and its own model decrease
        delta, predicted = problem.restrictions.project_step(problem, ctx.run.state, delta,
                                                             predicted)
        step_sq = float(delta @ delta)
    ctx.delta = delta
    return True, math.sqrt(step_sq), predicted
