"""Bookkeeping shared by the optimizers: set-up, records, callbacks, timing, the Result."""

from __future__ import annotations

import math
import time
from typing import Any, Callable

import numpy as np

from .. import _assembly as asm
from .. import _jit
from ..errors import FgoptError, NonFiniteError
from ..problem import Problem, State
from ..variables import Variables
from .diagnostics import clamp_hits, warn_clamps, warn_unused
from .linear.base import make_linear_solver
from .result import IterationRecord, Result, Status, stall_status

Callback = Callable[[IterationRecord], "bool | None"]

#: A solve that started on the NumPy backend (``backend="auto"``) moves to numba after this many
#: seconds when numba's cache holds its kernels (:mod:`fgopt.solvers._warmup`): numba's ~0.7 s of
#: import and cache loads then pay for themselves (torus3D, 73 iterations: 5.2 s on numba vs
#: 11.5 s on NumPy; sphere2500, 5 iterations: equal).
SWITCH_AFTER_SECONDS = 1.0

def _needs_numba(pattern: Any) -> bool:
    """BA-shaped problems (many small point blocks): their solver is the numba Schur complement."""
    if pattern.size <= 300:
        return False
    from .linear._schur_layout import is_ba_shaped

    return is_ba_shaped(pattern)


def refuse_constraints(graph: Any, method: str) -> None:
    """Raise when ``graph`` holds constraints: only ``fgopt.optimize`` enforces them (an
    optimizer class called directly would drop them without a word)."""
    cons = getattr(graph, "constraints", ())
    if len(cons) > 0:
        raise FgoptError(f"{method}: the graph holds {len(cons)} constraint(s) (e.g. "
                         f"{cons[0].describe()}), which this optimizer does not enforce; solve "
                         "it with fgopt.optimize(graph, initial), whose augmented-Lagrangian "
                         "loop does")


def compile_problem(graph: Any, initial: Variables, params: Any, linear_solver: Any,
                    build_structure: bool = True, constant: Any = None,
                    bounds: Any = None) -> Problem:
    """``graph`` compiled against ``initial`` for a user's solve (warns about unused keys);
    ``constant`` / ``bounds``: see :mod:`fgopt.bounds`."""
    if not isinstance(initial, Variables):
        raise FgoptError(f"initial values must be fgopt.Variables, got {type(initial).__name__}")
    problem = Problem(graph, initial, ordering=params.ordering,
                      threads=getattr(params, "threads", 1),
                      backend=getattr(params, "backend", "auto"), linear_solver=linear_solver,
                      build_structure=build_structure, constant=constant, bounds=bounds)
    warn_unused(problem.unused_keys)
    return problem


def require_no_bounds(bounds: Any, method: str) -> None:
    """Bounds are kept by LM's projected steps only (:mod:`fgopt.bounds`)."""
    if bounds:
        raise FgoptError(f"bounds need method='lm' (projected Levenberg-Marquardt); method "
                         f"{method!r} takes constant variables only")


class Run:
    """One optimization: the compiled problem, linear solver, current iterate and history."""

    def __init__(self, graph: Any, initial: Variables | None, params: Any, method: str,
                 callback: Callback | None, linear_solver: Any = None,
                 problem: Problem | None = None, state: State | None = None,
                 solver: Any = None, compiled: Problem | None = None, constant: Any = None,
                 bounds: Any = None):
        """Compile ``graph`` against ``initial`` (or take ``compiled``, what
        :func:`compile_problem` made of them), or continue on an already compiled ``problem``
        from ``state`` with an already analyzed ``solver`` (GNC re-solves this way)."""
        self.t0 = time.perf_counter()
        self.params = params
        self.method = method
        self.callback = callback
        self.verbose = bool(getattr(params, "verbose", False))
        choice = linear_solver if linear_solver is not None else params.linear_solver
        #: True when this run compiled its own problem (a user's call, not a GNC round): only
        #: then does it warn about unused keys and clamp hits.
        self.top_level = problem is None
        self._may_switch = False
        if problem is None:
            backend = getattr(params, "backend", "auto")
            if compiled is None:
                compiled = compile_problem(graph, initial, params, choice, constant=constant,
                                           bounds=bounds)
            problem = compiled.ensure_structure(params.ordering, choice)
            if backend == "auto" and problem.backend == "numpy" and _needs_numba(problem.pattern):
                problem.backend = "numba"  # BA-shaped: the Schur complement solver is numba's
            self._may_switch = backend == "auto" and problem.backend == "numpy"
        self.problem = problem
        if solver is None:
            solver = make_linear_solver(choice, pattern=problem.pattern,
                                        backend=problem.backend)
            solver.analyze(problem.pattern)
        self.solver = solver
        self._linear_choice = linear_solver if linear_solver is not None else params.linear_solver
        self._warm: bool | None = None
        self.t_setup = time.perf_counter() - self.t0
        self.t_solve = 0.0
        self.state: State = state if state is not None else problem.initial_state()
        try:
            self.cost = problem.linearize(self.state)
        except NonFiniteError as exc:  # names the factor; add clamped calls outside their domain
            hits, total = clamp_hits(problem, self.state)
            if total == 0:
                raise
            raise NonFiniteError(f"{exc}; at the initial values {total} clamped call(s) are "
                                 f"outside their domain, e.g. {hits[0]}") from None
        self.initial_cost = self.cost
        self.history = [self.cost]
        self.records: list[IterationRecord] = []
        #: First iteration of the trailing run of rejected steps (None after an accepted one),
        #: and the largest decrease the model predicted for one of them.
        self.rejected_since: int | None = None
        self.rejected_gain = 0.0
        if self.verbose:
            print(f"{method}: {problem.num_variables} variables, "
                  f"{sum(len(b.source) for b in problem.batches) + len(problem._slow)} factors, "
                  f"initial cost {self.cost:.6e}")
            print(IterationRecord.HEADER)

    # -- linear algebra with timing
    def solve(self, H_data: np.ndarray, rhs: np.ndarray) -> np.ndarray:
        t = time.perf_counter()
        try:
            self.solver.factorize(H_data)
            return self.solver.solve(rhs)
        finally:
            self.t_solve += time.perf_counter() - t

    def solve_damped(self, damping: np.ndarray | None, rhs: np.ndarray) -> np.ndarray:
        """Solve ``(H + diag(damping)) x = rhs`` with H the problem's current linearization.

        The damping is added to H's diagonal in place and the diagonal restored afterwards
        (exactly: the saved values are written back), instead of damping a copy of H: that copy
        was H's size again (1.1 GB at 5M BA observations).
        """
        # The move to numba is decided here, when another step is needed, not after an
        # iteration: a solve that has just converged would pay numba's loads (~1 s on sphere2500)
        # for nothing.
        self.maybe_switch()
        H, diag_pos = self.problem.H_data, self.problem.pattern.diag_pos
        if damping is None:
            return self.solve(H, rhs)
        if _jit.is_numba_loaded() and not _jit.numpy_only():
            # numba is in use already: one call each way (~25 us less than fancy indexing)
            undamped = np.empty(diag_pos.shape[0])
            asm.damp_diagonal(H, diag_pos, np.ascontiguousarray(damping, dtype=np.float64),
                              undamped)
            try:
                return self.solve(H, rhs)
            finally:
                asm.restore_diagonal(H, diag_pos, undamped)
        undamped = H[diag_pos]
        H[diag_pos] += damping
        try:
            return self.solve(H, rhs)
        finally:
            H[diag_pos] = undamped

    def maybe_switch(self) -> None:
        """Move a long NumPy-backend solve to numba when numba's cache is warm for it (see
        ``SWITCH_AFTER_SECONDS``): the problem's kernels and, for ``linear_solver="auto"``,
        the linear solver. Only the evaluation changes: the iterate, damping and history go on."""
        if not self._may_switch or time.perf_counter() - self.t0 < SWITCH_AFTER_SECONDS:
            return
        self._may_switch = False
        from . import _warmup

        self._warm = _warmup.is_warm(self.problem)
        if not self._warm:
            return
        self.problem.backend = "numba"
        if isinstance(self._linear_choice, str) and self._linear_choice == "auto":
            solver = make_linear_solver("auto", pattern=self.problem.pattern, backend="numba")
            solver.analyze(self.problem.pattern)
            self.solver = solver
        self.switched_at = len(self.records)

    def state_norm(self) -> float:
        return math.sqrt(sum(float(np.vdot(s, s)) for s in self.state.storages))

    def record(self, iteration: int, candidate_cost: float, lam: float, step_norm: float,
               accepted: bool, previous_cost: float, predicted: float = math.inf,
               poor: bool = False) -> bool:
        """Log one iteration; returns True when the callback asks to stop.

        ``predicted``: the decrease the method's model predicted for a rejected (or ``poor``)
        step, infinite when the trial point was not finite; kept to tell a stall from
        convergence. ``poor``: an accepted step that still counts as no progress (Dogleg: cut
        short by a trust region it then shrank, because the gain ratio was below 0.25).
        """
        if accepted and not poor:
            self.rejected_since, self.rejected_gain = None, 0.0
        else:
            if self.rejected_since is None:
                self.rejected_since = iteration
            gain = predicted if math.isfinite(candidate_cost) else math.inf
            self.rejected_gain = max(self.rejected_gain, gain if gain == gain else math.inf)
        rel = (previous_cost - candidate_cost) / previous_cost if previous_cost > 0 else 0.0
        rec = IterationRecord(iteration, self.cost, candidate_cost, rel if math.isfinite(rel)
                              else float("nan"), lam, step_norm, self.problem.gradient_norm(),
                              accepted, time.perf_counter() - self.t0)
        self.records.append(rec)
        if accepted:
            self.history.append(self.cost)
        if self.verbose:
            print(rec.row(), flush=True)
        if self.callback is not None:
            return bool(self.callback(rec))
        return False

    def converged_by_decrease(self, old: float, new: float) -> str | None:
        p = self.params
        dec = old - new
        if dec < p.absolute_tolerance:
            return f"absolute cost decrease {dec:.3g} < {p.absolute_tolerance:g}"
        rel_tol = getattr(self, "relative_tolerance", None)
        if rel_tol is None:
            rel_tol = p.relative_tolerance if p.relative_tolerance is not None else 1e-5
        if old > 0 and dec / old < rel_tol:
            return f"relative cost decrease {dec / old:.3g} < {rel_tol:g}"
        return None

    def converged_by_gradient(self) -> str | None:
        gn = self.problem.gradient_norm()
        if gn <= self.params.gradient_tolerance:
            return f"gradient norm {gn:.3g} <= {self.params.gradient_tolerance:g}"
        return None

    def converged_by_step(self, step_norm: float) -> str | None:
        tol = self.params.step_tolerance
        if step_norm <= tol * (self.state_norm() + tol):
            return f"step norm {step_norm:.3g} below step_tolerance"
        return None

    def finish(self, status: Status, message: str) -> Result:
        status, message = stall_status(status, message, self.cost, self.rejected_since,
                                       self.rejected_gain)
        clamps, num_clamped = clamp_hits(self.problem, self.state) if self.top_level else ([], 0)
        warn_clamps(clamps, num_clamped)
        total = time.perf_counter() - self.t0
        t = self.problem.timing
        timing = {"setup": self.t_setup, "linearize": t["linearize"], "assemble": t["assemble"],
                  "factorize+solve": self.t_solve, "retract": t["retract"], "cost": t["cost"],
                  "total": total}
        if self.verbose:
            print(f"{status.value}: {message}; cost {self.initial_cost:.6e} -> {self.cost:.6e} "
                  f"in {len(self.records)} iterations, {total:.3f} s")
        result = Result(None, status=status, message=message,
                        iterations=len(self.records), initial_cost=self.initial_cost,
                        final_cost=self.cost, cost_history=self.history,
                        iteration_records=self.records, timing=timing, method=self.method,
                        linear_solver=getattr(self.solver, "name", type(self.solver).__name__),
                        problem=self.problem, state=self.state,
                        unused_keys=tuple(self.problem.unused_keys), clamps=tuple(clamps),
                        num_clamped=num_clamped)
        result.info["backend"] = getattr(self.problem, "backend", "numba")
        if getattr(self.problem, "restrictions", None) is not None:
            #: bounded coordinates that end on a bound: (key, coordinate, "lower" | "upper")
            result.info["at_bounds"] = self.problem.restrictions.at_bounds(self.problem,
                                                                           self.state)
        if getattr(self, "switched_at", None) is not None:
            result.info["backend"] = f"numpy for {self.switched_at} iterations, then numba"
        if self.top_level:
            self._after(total)
        return result

    def _after(self, total: float) -> None:
        """A numba-backend solve marks the problem's kernels warm in numba's cache
        (:mod:`fgopt.solvers._warmup`): a later process's long NumPy solve of them may switch."""
        if self.problem.backend == "numba" and not self._warm:
            from . import _warmup

            _warmup.mark_warm(self.problem)
