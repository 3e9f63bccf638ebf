"""Graduated non-convexity (GNC) for outlier-robust estimation (Yang et al. 2020; GTSAM's
``GncOptimizer``).

GNC minimizes ``sum_i w_i r_i^2`` while a surrogate of a robust loss is gradually made less
convex. With the scale-free residual ``s_i = r_i^2 / c_i^2`` (``r_i^2`` the squared whitened
residual, ``c_i^2`` the inlier threshold = chi-square quantile of the factor's dimension):

* Geman-McClure: weights ``w = (mu / (s + mu))^2``; ``mu`` starts at ``2 max s`` and is divided by
  ``mu_step`` each round down to 1 (the true GM loss);
* truncated least squares: ``w = 1`` for ``s <= mu/(mu+1)``, ``0`` for ``s >= (mu+1)/mu``, else
  ``sqrt(mu (mu + 1) / s) - mu``; ``mu`` starts at ``1 / (2 max s - 1)`` and is multiplied by
  ``mu_step`` until the weights are binary.

Each round re-solves the weighted problem with Levenberg-Marquardt on the factors whose weight
is at least ``active_weight`` (:mod:`fgopt.solvers._subproblem`: a near-rejected wrong loop
closure would only add Cholesky fill; every factor's residual is still evaluated each round).
Known inliers (by default: priors and odometry, i.e. between factors of consecutive indices)
keep weight 1.

Four differences from GTSAM, each measured on M3500 with wrong loop closures
(``benchmarks/gnc.py``), where GTSAM-style GNC ends 85-90 m off:

1. GNC's guarantees assume each weighted least squares is solved globally (Yang et al. use
   SE-Sync). On SE(2)/SE(3) pose graphs every round starts from the chordal relaxation of the
   weighted graph (:mod:`fgopt.solvers.chordal`) instead of the previous estimate.
2. ``finalize``: classify each factor by its own threshold, drop the outliers and re-solve, so
   the result is exactly the inliers' least-squares solution, not one still pulled by
   down-weighted (GM) outliers.
3. ``estimate_scale`` (default): where the noise models overstate the errors (M3500's optimum
   is ~1/50 of the chi-square expectation), bending the graph to fit an outlier costs less than
   its truncated cost, so even the global truncated-least-squares optimum accepts some. The
   consistency step (:meth:`fgopt.solvers._gnc_check._Verifier.consistency`) tests each
   factor's leave-one-out residual against the accepted factors' real noise scale (Baarda's
   data snooping) and re-solves until the classification is stable; once that rejects nothing
   more, a family-wise test at the tested factors' own (standardized) scale rejects outliers
   that lie inside the nominal ellipse but are gross at the real scale (a wrong copy of a true
   loop closure on sphere2500, 21.97 < 22.46 nominal, ~250 in the real units).
4. ``verify`` (off by default): a leave-one-out check that rejects accepted factors one at a
   time while that lowers the truncated-least-squares objective (slower; what 3 does in
   passes).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from ..errors import FgoptError
from ..key import key_char, key_index
from ..problem import Problem
from ..variables import Variables
from ._gnc_check import _thresholds, _Verifier
from ._subproblem import Restricted
from .diagnostics import clamp_hits, warn_clamps, warn_unused
from ._run import refuse_constraints
from .lm import LevenbergMarquardt
from .params import LMParams, check_numbers
from .result import Result, Status


@dataclass(frozen=True)
class GNCParams:
    """Graduated non-convexity parameters (``method="gnc"``): the robust loss, its schedule,
    which factors are known inliers, the inner LM.

    Example:

    >>> from fgopt.solvers import GNCParams
    >>> GNCParams(loss="gm").loss, GNCParams().known_inliers
    ('gm', 'odometry')
    """

    loss: str = "tls"
    """``"tls"`` (truncated least squares) or ``"gm"`` (Geman-McClure, GTSAM's default). Both
    recover the outlier-free solution on M3500 / sphere2500 with 10 % wrong loop closures; TLS
    stops once the weights are binary and was 1.2x / 3.5x faster there (126 s vs 154 s, 93 s vs
    327 s)."""
    inlier_probability: float = 0.999
    """Inlier threshold c_i^2 = chi2.ppf(p, dim_i) on the squared whitened residual."""
    finalize: bool = True
    """After GNC, classify factors (inlier iff r^2 <= c^2), drop the outliers and re-solve, so
    the estimate is exactly the least-squares solution of the inliers."""
    mu_step: float = 1.4
    """Factor by which ``mu`` grows (TLS) or shrinks (GM) each round (GTSAM's default). A
    coarser schedule is faster but less robust: with 3, 17 of the 18 cases of the GNC benchmark
    stayed exact (sphere2500 with 30 % random wrong closures in 13 s instead of 30), but M3500
    without a prior and 30 % wrong closures (the ``file`` generator) ended at 33 times the
    optimum's cost with 21 true closures rejected (with 2: 18)."""
    max_rounds: int = 100
    weights_tolerance: float = 1e-4
    cost_tolerance: float = 1e-5
    known_inliers: str = "odometry"
    """``"odometry"`` (priors + between factors of consecutive keys), ``"priors"`` or ``"none"``."""
    lm: LMParams = field(default_factory=LMParams)
    linear_solver: str = "auto"
    ordering: str = "amd"
    threads: int = 1
    verbose: bool = False
    max_iterations: int = 100
    """Inner LM iteration limit per round."""
    verify: bool = False
    """After the scale step, also try rejecting accepted factors one at a time by their
    leave-one-out cost drop, keeping a rejection only if the truncated objective falls
    (:meth:`_Verifier.verify`; slow: one classification per trial). Off by default since
    :meth:`_Verifier.consistency` does this job in passes."""
    max_verify: int = 50
    """At most this many rejections by the check."""
    estimate_scale: bool = True
    """After the GNC rounds, classify every factor by how the rest of the graph predicts it,
    at the accepted factors' real noise scale (:meth:`_Verifier.consistency`). See the module
    docstring, point 3."""
    active_weight: float = 1e-2
    """Factors whose weight is below this are left out of a round's solve (their blocks would
    only add Cholesky fill; see :mod:`fgopt.solvers._subproblem`); their residuals are still
    evaluated every round, so they come back if the estimate moves towards them."""
    consistency_probability: float = 0.99
    """The consistency step's significance at the inliers' real scale: an accepted factor
    whose leave-one-out residual is outside its ``c^2`` ellipse is rejected when
    ``w^2 > s^2 chi2.ppf(p, dim)``; a rejected one comes back when it is inside the ellipse and
    ``w^2 <= s^2 chi2.ppf(p, dim)`` (between the two, a factor keeps its class: no cycles).
    0.99, since the ellipse test already protects true factors (M3500: 99 % of the true loop
    closures' leave-one-out residuals are below 0.06 c^2) and an outlier among others in one
    region can look only mildly significant (M3500 with 30 % wrong closures: one at
    ``w^2 = 13 s^2``, accepted at 0.999)."""
    snooping_alpha: float = 0.05
    """Family-wise significance level of the consistency step's test (Bonferroni over the
    factors): a factor is significant when ``w^2 > s^2 chi2.isf(alpha / m, dim)`` (m factors).
    Per factor at the inlier threshold's 0.999, a clean graph of a few thousand factors would
    lose a few true ones to chance. Used to bring rejected factors back at the end and, at the
    tested factors' standardized scale, to reject accepted ones whatever the nominal ellipse
    says (:meth:`~fgopt.solvers._gnc_check._Verifier.consistency`)."""
    time_limit: float | None = None
    """Seconds: stop the GNC rounds when exceeded (status ``MAX_ITERATIONS``) and finish with
    the classification steps; ``None``: no limit."""
    initialization: str = "auto"
    """Start of each round's weighted least squares: ``"chordal"`` (a chordal relaxation of the
    weighted pose graph, see :mod:`fgopt.solvers.chordal`), ``"previous"`` (the last round's
    estimate, as GTSAM does) or ``"auto"`` (chordal for SE(2)/SE(3) pose graphs, else previous)."""

    def __post_init__(self):
        check_numbers(self, integers=("max_rounds", "max_iterations", "max_verify", "threads"),
                      nonnegative=("weights_tolerance", "cost_tolerance", "active_weight"),
                      positive=("mu_step", "time_limit", "threads"))
        for f in ("inlier_probability", "consistency_probability", "snooping_alpha"):
            if not 0.0 < getattr(self, f) < 1.0:
                raise FgoptError(f"GNCParams.{f} must be a probability in (0, 1), got "
                                 f"{getattr(self, f)!r}")
        if self.mu_step <= 1.0:
            raise FgoptError(f"GNCParams.mu_step must be > 1 (mu grows or shrinks by it each "
                             f"round), got {self.mu_step!r}")


def _known_inlier_mask(problem: Problem, policy: str) -> list[np.ndarray]:
    masks = []
    for b in problem.batches:
        keys = b.source.keys
        n, k = keys.shape
        if policy == "none":
            masks.append(np.zeros(n, dtype=bool))
        elif k == 1:
            masks.append(np.ones(n, dtype=bool))
        elif policy == "odometry" and k == 2:
            chars = np.right_shift(keys, 56)
            idx = np.bitwise_and(keys, (1 << 56) - 1)
            masks.append((chars[:, 0] == chars[:, 1]) & (np.abs(idx[:, 0] - idx[:, 1]) == 1))
        else:
            masks.append(np.zeros(n, dtype=bool))
    slow = []
    for s in problem._slow:
        ks = s.factor.keys
        if policy == "none":
            slow.append(False)
        elif len(ks) == 1:
            slow.append(True)
        else:
            slow.append(policy == "odometry" and len(ks) == 2 and key_char(ks[0]) == key_char(ks[1])
                        and abs(key_index(ks[0]) - key_index(ks[1])) == 1)
    masks.append(np.array(slow, dtype=bool))
    return masks


def gnc_weights(loss: str, s: np.ndarray, mu: float) -> np.ndarray:
    """Weights of scale-free residuals ``s = r^2 / c^2`` at control parameter ``mu``."""
    if loss == "gm":
        return (mu / (s + mu)) ** 2
    w = np.sqrt(mu * (mu + 1.0) / np.maximum(s, 1e-12)) - mu  # s <= 1e-12 gets w = 1 below
    w = np.where(s <= mu / (mu + 1.0), 1.0, w)
    return np.clip(np.where(s >= (mu + 1.0) / mu, 0.0, w), 0.0, 1.0)


class GNC:
    """``GNC(GNCParams(loss="tls")).optimize(graph, initial)`` -> :class:`Result`.

    ``result.info["weights"]`` holds the final weight of every factor (per batch of the graph's
    compiled problem, then one array for Python factors) and ``result.info["outliers"]`` the
    number of factors with weight < 0.5. ``result.problem`` is the compiled problem of the
    accepted factors (for :func:`fgopt.marginals`).

    Six wrong loop closures added to a 30-pose graph are found and switched off:

    >>> from fgopt.solvers import GNC, GNCParams
    >>> sample = fgopt.datasets.manhattan_2d(num_poses=30, seed=0)
    >>> clean = fgopt.optimize(sample.graph, sample.initial)
    >>> graph, n = fgopt.datasets.random_loop_closures(sample.graph, clean.values, 0.2)
    >>> result = GNC(GNCParams(loss="tls")).optimize(graph, sample.initial)
    >>> n, result.success, result.info["outliers"]
    (6, True, 6)
    >>> np.concatenate(result.info["weights"])[-n:]     # the added factors come last
    array([0., 0., 0., 0., 0., 0.])
    """

    def __init__(self, params: GNCParams | None = None):
        self.params = params or GNCParams()
        if self.params.loss not in ("gm", "tls"):
            raise FgoptError(f"GNC loss must be 'gm' or 'tls', got {self.params.loss!r}")

    def optimize(self, graph: Any, initial: Variables,
                 callback: Callable | None = None) -> Result:
        refuse_constraints(graph, "GNC")
        p = self.params
        t0 = time.perf_counter()
        deadline = t0 + p.time_limit if p.time_limit is not None else float("inf")
        if not isinstance(initial, Variables):
            raise FgoptError(f"initial values must be fgopt.Variables, got {type(initial).__name__}")
        if p.initialization not in ("auto", "chordal", "previous"):
            raise FgoptError(f"GNC initialization must be 'auto', 'chordal' or 'previous', got "
                             f"{p.initialization!r}")
        # every factor's residual is evaluated on ``full``; solves run on the factors that
        # matter (:class:`Restricted`), so (near-)rejected outliers add no Cholesky fill
        full = Problem(graph, initial, ordering=p.ordering, threads=p.threads,
                       build_structure=False)
        warn_unused(full.unused_keys)
        from .chordal import _PoseGraph, chordal_state  # scipy.sparse: only when GNC runs

        use_chordal = p.initialization in ("auto", "chordal") and _PoseGraph(full).ok
        if p.initialization == "chordal" and not use_chordal:
            raise FgoptError("GNC initialization='chordal' needs a pose graph (SE2 or SE3 poses, "
                             "between factors and priors only)")
        lm = LevenbergMarquardt(dataclasses.replace(p.lm, max_iterations=p.max_iterations,
                                                    verbose=False))
        inliers = _known_inlier_mask(full, p.known_inliers)
        c2 = _thresholds(full, p.inlier_probability)
        solver = _Solves(full, p, lm, use_chordal, callback)
        ones = [np.ones(len(m)) for m in inliers]

        initial_cost = full.cost(full.initial_state())
        if use_chordal:  # the residuals that set mu's start: the chordal estimate's (a solve
            # over every factor would pay the fill of every wrong closure)
            state = chordal_state(full, full.initial_state(), ones)
            cost = full.cost(state)
        else:
            state, cost = solver.solve(full.initial_state(), ones)
        history = [initial_cost, cost]

        def scaled(state, c2=c2):
            return [r / c for r, c in zip(full.squared_residuals(state), c2)]

        s = scaled(state)
        s_max = max((float(np.max(np.where(m, 0.0, x))) for x, m in zip(s, inliers) if x.size),
                    default=0.0)
        if p.loss == "gm":
            mu = max(1.0, 2.0 * s_max)
        else:
            mu = 1.0 / (2.0 * s_max - 1.0) if s_max > 1.0 else None
        status, message = Status.CONVERGED, "no outliers above the inlier threshold"
        weights = ones
        rounds = 0
        prev_cost = cost
        while mu is not None and rounds < p.max_rounds:
            if time.perf_counter() > deadline:
                status, message = Status.MAX_ITERATIONS, f"time limit {p.time_limit:g} s reached"
                break
            rounds += 1
            weights = [np.where(m, 1.0, gnc_weights(p.loss, x, mu)) for x, m in zip(s, inliers)]
            state, cost = solver.solve(state, weights)
            history.append(cost)
            s = scaled(state)
            if p.verbose:
                n_out = sum(int(np.sum(w < 0.5)) for w in weights)
                print(f"GNC round {rounds}: mu {mu:.4g}, weighted cost {cost:.6g}, "
                      f"{n_out} factors with weight < 0.5, "
                      f"{sum(int(np.sum(w >= p.active_weight)) for w in weights)} solved, "
                      f"{time.perf_counter() - t0:.1f} s")
            if p.loss == "gm":
                if mu <= 1.0:
                    message = "mu reached 1 (Geman-McClure loss)"
                    break
                mu = max(1.0, mu / p.mu_step)
            else:
                binary = all(np.all((w < p.weights_tolerance) | (w > 1 - p.weights_tolerance))
                             for w in weights)
                if binary:
                    message = "weights converged to 0/1 (truncated least squares)"
                    break
                mu *= p.mu_step
            if abs(prev_cost - cost) <= p.cost_tolerance * max(prev_cost, 1e-300) \
                    and p.loss == "tls":
                message = "weighted cost converged"
                break
            prev_cost = cost
        else:
            if mu is not None:
                status, message = Status.MAX_ITERATIONS, f"reached max_rounds={p.max_rounds}"
        removed, scale2 = 0, 1.0
        if (p.finalize and mu is not None) or p.verify or p.estimate_scale:
            check = _Verifier(full, solver, inliers, c2, p.snooping_alpha,
                              p.consistency_probability)
            state, weights = check.classify(state)
            if p.estimate_scale:
                state, weights, scale2 = check.consistency(state, weights, p.verbose, deadline)
                if scale2 < 1.0:
                    message += f"; noise scale s^2 {scale2:.3g}"
            if p.verify:
                state, weights, removed = check.verify(state, weights, p.max_verify, p.verbose,
                                                       deadline)
            history.append(check.objective(state))
            if removed:
                message += f"; {removed} accepted factors rejected by the leave-one-out check"
        # the result lives on the compiled problem of the accepted factors (marginals need H)
        sub, sub_state = solver.restricted.prepare(state, weights)
        final = sub.cost(sub_state)
        outliers = sum(int(np.sum(w < 0.5)) for w in weights)
        timing = {"total": time.perf_counter() - t0}
        clamps, num_clamped = clamp_hits(sub, sub_state)
        warn_clamps(clamps, num_clamped)
        return Result(None, status=status, message=f"{message}; {outliers} outliers",
                      iterations=solver.iterations, initial_cost=initial_cost, final_cost=final,
                      cost_history=history, timing=timing, method=f"gnc-{p.loss}",
                      linear_solver=getattr(solver.restricted.solver, "name", ""), problem=sub,
                      state=sub_state, unused_keys=tuple(full.unused_keys), clamps=tuple(clamps),
                      num_clamped=num_clamped,
                      info={"weights": weights, "outliers": outliers, "rounds": rounds,
                            "rejected_by_check": removed, "noise_scale2": scale2,
                            "compilations": solver.restricted.rebuilds})


class _Solves:
    """One weighted least-squares solve of GNC: on the factors with weight >= ``active_weight``
    (:class:`Restricted`), from the chordal relaxation of the weighted pose graph or the
    current estimate."""

    def __init__(self, full, params, lm, use_chordal: bool, callback):
        self.full, self.lm, self.use_chordal, self.callback = full, lm, use_chordal, callback
        self.restricted = Restricted(full, params, params.active_weight)
        self.iterations = 0

    def solve(self, state, weights, chordal: bool = True) -> tuple[Any, float]:
        """(new full state, weighted cost): LM from the chordal relaxation of the weighted pose
        graph (a GNC round, where many weights changed) or, with ``chordal=False`` or where
        there is none, from ``state`` (the classification steps, which move few factors)."""
        sub, start = self.restricted.prepare(state, weights)
        if chordal and self.use_chordal:
            from .chordal import chordal_state

            fresh = chordal_state(sub, start, self.restricted.sub_weights)
            start = start if fresh is None else fresh
        best = self.lm.optimize_problem(sub, start, self.restricted.solver, self.callback)
        self.iterations += best.iterations
        return self.restricted.to_full(best.state, state), best.final_cost
