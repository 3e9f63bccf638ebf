"""Where ``fgopt.optimize`` starts: the given values, the chordal relaxation, or both.

Local least squares from a poor guess can end in a poor local minimum (torus3D from the file's
guess: 29,954 in fgopt and GTSAM alike, 12,118 from the chordal relaxation). Running from the
chordal start every time is no cure: on graphs whose given guess is good it is often a worse
start (parking-garage: a rotation-only relaxation bends long lever arms, 50-150 LM iterations
instead of 6; ais2klinik: a worse minimum, 20,354 vs 86.4). So ``initialization="auto"``:

1. solve from the given values (what GTSAM does, so the result is never worse than that);
2. test the result against the noise models: at the global optimum of a graph whose noise
   models are right, ``2 * cost`` is chi-square distributed with ``m - n`` degrees of freedom
   (m residual dimensions, n tangent dimensions). A cost above the 1 - 1e-3 quantile says
   "wrong basin" (or wrong noise models);
3. only then solve again from the chordal relaxation (pose graphs) and keep the lower cost.

A first run that ended at its iteration limit (or by its callback) is not at an optimum and is
returned as it is: the test does not apply, and a caller who capped the iterations asked for
that many (exactly 5 with the stopping tests off, in benchmarks), not for a second run.

Measured on 24 public 2D/3D pose graphs (``benchmarks/initialization.py``): the test fires on
exactly the files where the chordal start reaches a lower minimum (torus3D, MIT, M3500a/b/c,
sphere_bignoise), and on none of the others, where the given guess was as good or better
(M3500, intel, garage, sphere2500, cubicle, w20000, ais2klinik, city10000, kitti, ...). The
price where it fires is one chordal relaxation (a few sparse linear solves) plus a second LM
run; elsewhere it is nothing.

The chordal run resolves ``LMParams.damping="auto"`` to Ceres-style scale-invariant damping
(``"diagonal"``): from a chordal start (errors spread over the whole graph) it needed
fewer iterations on every file measured (MIT 67 vs 187, garage 53 vs 149, M3500b 51 vs 126)
and reached lower minima on two (M3500c 2,038 vs 2,817).
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Any, Callable

from ..errors import FgoptError
from .result import Result, Status, deferred_dims

INITIALIZATIONS = ("auto", "given", "chordal")
#: Upper-tail probability of the chi-square test of step 2.
CHI2_TAIL = 1e-3
_Z_TAIL = 3.090232306167813  # standard normal quantile of 1 - CHI2_TAIL


def chi2_upper(dof: int) -> float:
    """The ``1 - CHI2_TAIL`` quantile of chi-square(dof) (Wilson-Hilferty, slightly above the
    exact value: +0.6 % at 10 dof, +0.07 % at 60, below 1e-4 from 1000; no scipy.stats import
    on the solve path)."""
    a = 2.0 / (9.0 * dof)
    return dof * (1.0 - a + _Z_TAIL * math.sqrt(a)) ** 3


def cost_bound(problem: Any) -> tuple[float, int] | None:
    """``(bound, dof)``: the largest cost the noise models make plausible at the optimum, or
    ``None`` when the test does not apply (robust losses, GNC weights, no redundancy)."""
    if not hasattr(problem, "batches") or not hasattr(problem, "_slow"):
        return None  # not a compiled Problem: no test
    m = 0
    for b in problem.batches:
        if b.source.loss_code != 0:
            return None
        m += len(b.source) * b.kernel.residual_dim
    for s in problem._slow:
        if s.loss_code != 0:
            return None
        m += s.factor.dim
    return bound_of(m, problem.size)


def bound_of(residuals: int, unknowns: int) -> tuple[float, int] | None:
    """:func:`cost_bound` of ``residuals`` residual dimensions (no robust loss) over
    ``unknowns`` tangent dimensions."""
    dof = residuals - unknowns
    if dof < 10:
        return None
    return 0.5 * chi2_upper(dof), dof


def implausible(result: Result) -> str | None:
    """Why ``result`` may be a wrong local minimum (``None``: nothing suspicious)."""
    if result.status is Status.FAILED:
        return f"the solve from the given values failed ({result.message})"
    dims = deferred_dims(result)
    if dims is not None:
        bound = bound_of(*dims)  # (a fast path's problem, not compiled for this)
    elif result.problem is None:
        return None
    else:
        bound = cost_bound(result.problem)
    if bound is None:
        return None
    limit, dof = bound
    if result.final_cost > limit:
        return (f"final cost {result.final_cost:.6g} from the given values is above what the "
                f"noise models allow at an optimum ({limit:.6g}: chi-square, {dof} degrees of "
                f"freedom, tail {CHI2_TAIL:g})")
    return None


def for_chordal_start(params: Any) -> Any:
    """``params`` for a run from a chordal start: ``damping="auto"`` becomes ``"diagonal"``."""
    if getattr(params, "damping", None) == "auto":
        return dataclasses.replace(params, damping="diagonal")
    return params


def optimize_auto(graph: Any, initial: Any, params: Any,
                  run: Callable[[Any, Any], Result]) -> Result:
    """Step 1-3 of the module docstring; ``run(start, params)`` is one optimization."""
    t0 = time.perf_counter()
    first = run(initial, params)
    first.info["initialization"] = "given"
    if first.status in (Status.MAX_ITERATIONS, Status.STOPPED):
        # The test judges an optimum; a run cut short is not one, and its caller asked for at
        # most that many iterations (e.g. exactly 5 with the stopping tests off), not for a
        # relaxation plus a second run.
        first.info["initialization_reason"] = (
            f"given values: the run ended by {first.status.value} before converging, and the "
            "chi-square test applies to optima only: no second start")
        return first
    why = implausible(first)
    if why is None:
        first.info["initialization_reason"] = (
            "given values: the final cost is consistent with the noise models (or the test "
            "does not apply)")
        return first
    from .chordal import _PoseGraph, chordal_initialization  # scipy.sparse: only past the test

    if first.problem is not None and not _PoseGraph(first.problem).ok:
        first.info["initialization_reason"] = f"{why}; not a pose graph, no chordal start"
        return first
    try:
        start = chordal_initialization(graph, initial)
    except FgoptError:  # not a pose graph: no relaxation to fall back on
        first.info["initialization_reason"] = f"{why}; not a pose graph, no chordal start"
        return first
    second = run(start, for_chordal_start(params))
    better = second.final_cost < first.final_cost
    best, other = (second, first) if better else (first, second)
    best.info["initialization"] = "chordal" if better else "given"
    best.info["initialization_reason"] = (
        f"{why}; also solved from the chordal relaxation: {second.final_cost:.6g} "
        f"({second.iterations} iterations) vs {first.final_cost:.6g} from the given values "
        f"({first.iterations}); kept the {'chordal' if better else 'given'} start")
    best.info["initialization_costs"] = {"given": first.final_cost,
                                         "chordal": second.final_cost}
    best.info["restart"] = {"why": why, "given_initial_cost": first.initial_cost,
                            "given_final_cost": first.final_cost,
                            "chordal_initial_cost": second.initial_cost,
                            "chordal_final_cost": second.final_cost,
                            "kept": best.info["initialization"]}
    best.info["iterations_all_starts"] = first.iterations + second.iterations
    best.timing = dict(best.timing)
    best.timing["other_start"] = other.timing.get("total", 0.0)
    best.timing["total"] = time.perf_counter() - t0
    return best


def check(initialization: str) -> None:
    if initialization not in INITIALIZATIONS:
        raise FgoptError(f"unknown initialization {initialization!r}: "
                         f"{', '.join(repr(x) for x in INITIALIZATIONS)}")
