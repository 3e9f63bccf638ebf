"""Equality and inequality constraints: an augmented-Lagrangian loop around Levenberg-Marquardt.

For the cost ``f(x) = 0.5 sum |R_i e_i(x)|^2``, equality constraints ``g_j(x) = 0`` and
inequality constraints ``h_k(x) <= 0`` (:func:`fgopt.constraint`), each outer iteration
minimizes, with LM warm-started from the last iterate, the augmented Lagrangian

    L(x) = f(x) + sum_j mu_j/2 |g_j(x) + lambda_j / mu_j|^2
                + sum_k mu_k/2 |max(0, h_k(x) + lambda_k / mu_k)|^2        (+ constants)

(the shifted-penalty form of Hestenes-Powell-Rockafellar). Both penalty terms are least-squares
residuals ``sqrt(mu) (c(x) + lambda / mu)`` (rows with ``h + lambda/mu <= 0`` zeroed), so the
inner problem is an ordinary sparse least-squares problem: each constraint type has a
generated penalty kernel (:meth:`~fgopt.factors.constraint.SymbolicConstraintType.penalty_kernel`)
whose constants carry the shifts and penalties, the problem is compiled once (its linear solver
analyzed once; a small problem runs each inner solve in one call of the small-problem driver),
and every outer iteration only rewrites those constants. After each inner solve

    lambda_j <- lambda_j + mu_j g_j(x),     lambda_k <- max(0, lambda_k + mu_k h_k(x)),

and each scalar constraint whose violation did not fall below ``violation_reduction`` times the previous
one gets ``mu <- penalty_factor * mu`` (up to ``max_penalty``). The run converges when every
constraint holds to ``constraint_tolerance`` (for inequalities also complementarity:
``|max(h, -lambda/mu)| <= tol``) after a converged inner solve; it ends ``INFEASIBLE`` when the
violation stays above the tolerance (out of outer iterations, or the penalty at its cap without
progress): never ``CONVERGED`` with a violation above tolerance.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import FgoptError, KeyNotFoundError, NonFiniteError
from ..key import key_str
from ..variables import Variables
from . import small
from ._run import compile_problem
from .linear.base import make_linear_solver
from .lm import LevenbergMarquardt
from .params import LMParams
from .result import Result, Status


@dataclass(frozen=True)
class AugmentedLagrangianParams:
    """Outer-loop settings of :func:`optimize_constrained` (``fgopt.optimize(...,
    constraint_params=AugmentedLagrangianParams(...))``); the inner LM takes ``optimize``'s
    usual options."""

    constraint_tolerance: float = 1e-8
    """Converged when ``max |g| <= tol`` and ``max |max(h, -lambda/mu)| <= tol`` (units of the
    constraint functions' outputs)."""
    max_outer_iterations: int = 50
    initial_penalty: float | None = None
    """``mu`` of every constraint at the start. ``None``: ``penalty_ratio`` times the cost's
    curvature over the constraints' (median diagonals of ``H`` and ``J_c^T J_c`` at the start),
    so the choice does not depend on units."""
    penalty_ratio: float = 100.0
    """(10 took 8-12 outer iterations on the small problems of ``benchmarks.constraints``, 100
    takes 4-7; M3500 with 1,000 constraints 5 -> 4.)"""
    penalty_factor: float = 10.0
    max_penalty: float = 1e10
    violation_reduction: float = 0.1
    """A scalar constraint whose violation shrank by less than this factor gets a larger
    penalty (0.25 took 7 outer iterations on the 10-link arm of ``benchmarks.constraints``,
    0.1 takes 5; M3500 and a 10,000-pose grid with 1,000 constraints: 4 either way)."""
    verbose: bool = False
    """Print one line per outer iteration."""
    inner_relative_tolerance: float = 1e-13
    """The inner LM's ``relative_tolerance`` when the caller sets none (LM's own default, 1e-5,
    would stop far from the augmented Lagrangian's minimum and spoil the multiplier update)."""


_PROBLEM_TIMERS = ("linearize", "assemble", "retract", "cost")


class _Rows:
    """Every scalar constraint row, flat (groups of one kernel in turn, instance-major): the
    multipliers ``lam``, penalties ``mu``, which rows are inequalities, and per group the
    compiled penalty batch (its constants: the constraints' own, then ``shift = lam / mu`` and
    ``scale = sqrt(mu)`` per row, rewritten in place between outer iterations)."""

    def __init__(self, graph: Any):
        cons = graph.constraints
        by_kernel: dict = {}
        for i, c in enumerate(cons):
            by_kernel.setdefault(id(c.kernel), []).append(i)
        self.members = list(by_kernel.values())  # per group, positions in graph.constraints
        self.inner = [cons[m[0]].kernel for m in self.members]
        self.consts = [np.array([cons[i].constants for i in m]).reshape(len(m), -1)
                       for m in self.members]
        sizes = [len(m) * k.residual_dim for m, k in zip(self.members, self.inner)]
        self.slices = [slice(a - n, a) for a, n in zip(np.cumsum(sizes), sizes)]
        self.ineq = np.repeat([cons[m[0]].inequality for m in self.members], sizes)
        self.lam, self.mu = np.zeros(self.ineq.shape[0]), np.ones(self.ineq.shape[0])
        self.last = self.prev = None  # violation measures after the last two outer iterations
        self.batches: list = []
        self._views: list | None = None

    @staticmethod
    def check_keys(graph: Any, initial: Variables) -> None:
        """Raise naming the first constraint over a key without an initial value."""
        for c in graph.constraints:
            for k in c.keys:
                if k not in initial:
                    raise KeyNotFoundError(f"constraint {c.describe()} uses {key_str(k)}, which "
                                           f"is not in the initial values: add it with "
                                           f"Variables.add({key_str(k)}, value)")

    def add_penalties(self, graph: Any) -> Any:
        """A copy of ``graph`` (without its constraints) with one penalty batch per group."""
        pg = type(graph)()
        pg._factors, pg._batches = list(graph.factors), list(graph.batches)
        cons = graph.constraints
        for m, k, c in zip(self.members, self.inner, self.consts):
            consts = np.zeros((len(m), c.shape[1] + 2 * k.residual_dim))
            consts[:, :c.shape[1]] = c
            pg.add_batch(cons[m[0]].factor_type.penalty_kernel(k),
                         np.array([cons[i].keys for i in m], dtype=np.int64), consts)
        self.sources = pg.batches[len(graph.batches):]
        return pg

    def set_penalty(self) -> None:
        """Write ``shift = lam / mu`` and ``scale = sqrt(mu)`` into the penalty batches'
        constants."""
        if self._views is None:  # (n, m) views of each batch's shift and scale columns
            self._views = []
            for b, c, sl in zip(self.batches, self.consts, self.slices):
                n, nc = c.shape
                m = (sl.stop - sl.start) // n
                a = b.source.constants
                self._views.append((sl, (n, m), a[:, nc:nc + m], a[:, nc + m:]))
        shift, scale = self.lam / self.mu, np.sqrt(self.mu)
        for sl, shape, sv, wv in self._views:
            sv[...] = shift[sl].reshape(shape)
            wv[...] = scale[sl].reshape(shape)

    def penalty(self, v: np.ndarray) -> float:
        """The penalty terms' cost at constraint values ``v`` (before :meth:`update`):
        ``0.5 sum mu (c + lam / mu)^2`` over equalities and active inequalities."""
        r = v + self.lam / self.mu
        r = np.where(self.ineq, np.maximum(r, 0.0), r)
        return 0.5 * float(self.mu @ (r * r))

    def values(self, problem: Any, state: Any) -> tuple[np.ndarray, list]:
        """``c(x)`` of every row at ``state``, and each group's Jacobians ``(n, m, D)``."""
        with problem.kernel_mode():
            out = [_linearize(problem, k)(b.gather(state), c)
                   for k, b, c in zip(self.inner, self.batches, self.consts)]
        return np.concatenate([r.reshape(-1) for r, _ in out]), [j for _, j in out]

    def update(self, v: np.ndarray, ap: AugmentedLagrangianParams) -> tuple[float, float]:
        """Multiplier and penalty update at constraint values ``v``; returns the largest
        violation measure (equality ``|g|``, inequality ``|max(h, -lambda/mu)|``) and the
        penalty terms' cost at ``v`` before the update (:meth:`penalty`)."""
        shift = self.lam / self.mu
        meas = np.abs(np.where(self.ineq, np.maximum(v, -shift), v))
        r = np.where(self.ineq, np.maximum(v + shift, 0.0), v + shift)
        pen = 0.5 * float(self.mu @ (r * r))
        lam = self.lam + self.mu * v
        self.lam = np.where(self.ineq, np.maximum(lam, 0.0), lam)
        if self.last is not None:
            grow = (meas > ap.violation_reduction * self.last) & (meas > ap.constraint_tolerance)
            self.mu = np.where(grow, np.minimum(self.mu * ap.penalty_factor, ap.max_penalty),
                               self.mu)
        self.prev, self.last = self.last, meas
        return float(meas.max(initial=0.0)), pen

    def feasibility(self, v: np.ndarray) -> float:
        """``max(|g|, max(h, 0))`` over every row."""
        return float(np.abs(np.where(self.ineq, np.maximum(v, 0.0), v)).max(initial=0.0))

    def at_cap(self, ap: AugmentedLagrangianParams) -> bool:
        """Every row still violated has its penalty at ``max_penalty``."""
        return bool(np.all(self.mu[self.last > ap.constraint_tolerance] >= ap.max_penalty))

    def stuck(self, ap: AugmentedLagrangianParams) -> bool:
        """The violation did not shrink in the last outer iteration (by 1 %)."""
        if self.prev is None:
            return False
        now = float(self.last.max(initial=0.0))
        return now > ap.constraint_tolerance and now >= 0.99 * float(self.prev.max(initial=0.0))

    def multipliers(self, count: int) -> list:
        out = [None] * count
        for m, k, sl in zip(self.members, self.inner, self.slices):
            lam = self.lam[sl].reshape(len(m), k.residual_dim)
            for row, i in enumerate(m):
                out[i] = lam[row].copy()
        return out

    def first_nonfinite(self, graph: Any, v: np.ndarray) -> str | None:
        for m, k, sl in zip(self.members, self.inner, self.slices):
            bad = ~np.all(np.isfinite(v[sl].reshape(len(m), k.residual_dim)), axis=1)
            if bad.any():
                return graph.constraints[m[int(np.argmax(bad))]].describe()
        return None


def inner_schedule(params: LMParams, explicit: set,
                   ap: AugmentedLagrangianParams | None = None) -> list[LMParams]:
    """The inner LM's parameters per outer iteration (the last repeats): the caller's, with the
    cost-decrease tolerances tightened by 1e-3 per outer iteration from LM's defaults down to
    ``inner_relative_tolerance`` (early solves need not be exact: their multipliers are
    provisional; a tight first solve took 20 LM iterations on M3500 where 5 do). A caller's
    own ``relative_tolerance`` is used throughout."""
    ap = _checked(ap)
    if "relative_tolerance" in explicit or params.relative_tolerance is not None:
        return [params]
    hit = _SCHEDULES.get((id(params), id(ap)))  # (both frozen; the entry keeps them alive)
    if hit is not None and hit[0] is params and hit[1] is ap:
        return hit[2]
    if len(_SCHEDULES) > 64:
        _SCHEDULES.clear()
    out = _SCHEDULES[(id(params), id(ap))] = (params, ap, _schedule(params, ap))
    return out[2]


def _checked(ap: AugmentedLagrangianParams | None) -> AugmentedLagrangianParams:
    ap = ap if ap is not None else _DEFAULT
    if not isinstance(ap, AugmentedLagrangianParams):
        raise FgoptError(f"constraint_params must be an AugmentedLagrangianParams, got "
                         f"{type(ap).__name__}")
    if ap.max_outer_iterations < 1:
        raise FgoptError(f"AugmentedLagrangianParams.max_outer_iterations must be >= 1, got "
                         f"{ap.max_outer_iterations}")
    return ap


_DEFAULT = AugmentedLagrangianParams()
_ABS_FLOOR = 1e-12
_SCHEDULES: dict = {}


def _schedule(params: LMParams, ap: AugmentedLagrangianParams) -> list[LMParams]:
    out, rel, absolute = [], 1e-5, params.absolute_tolerance
    while True:
        rel, absolute = max(rel, ap.inner_relative_tolerance), max(absolute, _ABS_FLOOR)
        out.append(dataclasses.replace(params, relative_tolerance=rel,
                                       absolute_tolerance=absolute))
        if rel <= ap.inner_relative_tolerance and absolute <= _ABS_FLOOR:
            return out
        rel, absolute = rel * 1e-3, absolute * 1e-3


def optimize_constrained(graph: Any, initial: Variables, schedule: list[LMParams],
                         constraint_params: AugmentedLagrangianParams | None = None,
                         linear_solver: Any = None, callback: Callable | None = None,
                         constant: Any = None, bounds: Any = None) -> Result:
    """Minimize ``graph``'s cost subject to ``graph.constraints`` (see the module docstring);
    ``schedule``: the inner LM's parameters per outer iteration (:func:`inner_schedule`);
    ``constant`` / ``bounds``: as for :func:`fgopt.optimize` (kept by the inner LM)."""
    params = schedule[0]
    t0 = time.perf_counter()
    ap = _checked(constraint_params)
    if not isinstance(initial, Variables):
        raise FgoptError(f"initial values must be fgopt.Variables, got {type(initial).__name__}")
    rows = _Rows(graph)
    choice = linear_solver if linear_solver is not None else params.linear_solver
    try:
        problem = compile_problem(rows.add_penalties(graph), initial, params, choice,
                                  build_structure=False, constant=constant, bounds=bounds)
    except KeyNotFoundError:
        rows.check_keys(graph, initial)  # (names the constraint when one is the culprit)
        raise
    by_source = {id(b.source): b for b in problem.batches}
    rows.batches = [by_source[id(s)] for s in rows.sources]
    inner_solve = _InnerSolve(problem, linear_solver, callback)
    state = problem.initial_state()
    values, jacobians = rows.values(problem, state)
    bad = rows.first_nonfinite(graph, values)
    if bad is not None:
        raise NonFiniteError(f"constraint {bad} is NaN or inf at the initial values")
    rows.mu[:] = ap.initial_penalty if ap.initial_penalty is not None else _initial_penalty(
        problem, rows, state, jacobians, ap.penalty_ratio)
    records, augmented, its = [], [], 0
    timing: dict = {}
    status, message = None, ""
    inner = None
    feas = rows.feasibility(values)
    outer = 0
    for outer in range(1, ap.max_outer_iterations + 1):
        rows.set_penalty()
        inner = inner_solve(schedule[min(outer, len(schedule)) - 1], state)
        state = inner.state
        its += inner.iterations
        records += inner.iteration_records
        for k, v in inner.timing.items():  # the problem's own timers count since it was made
            timing[k] = v if k in _PROBLEM_TIMERS else timing.get(k, 0.0) + v
        if outer == 1:  # f(x0) = L(x0) - P(x0): the cost without the penalty terms
            f0 = inner.initial_cost - rows.penalty(values)
        values = rows.values(problem, state)[0]
        feas = rows.feasibility(values)
        measure, pen = rows.update(values, ap)
        f = inner.final_cost - pen
        augmented.append(inner.final_cost)
        if ap.verbose:
            print(f"outer {outer}: {inner.iterations} LM iterations ({inner.status.value}), "
                  f"augmented cost {augmented[-1]:.9e}, violation {feas:.3e}, measure {measure:.3e}, "
                  f"penalty <= {float(rows.mu.max()):.3g}")
        if inner.status is Status.STOPPED:
            status, message = Status.STOPPED, "callback asked to stop"
            break
        if (max(feas, measure) <= ap.constraint_tolerance and inner.status is Status.CONVERGED
                and outer >= len(schedule)):
            status, message = Status.CONVERGED, (
                f"constraints hold to {max(feas, measure):.3g} <= "
                f"{ap.constraint_tolerance:g} after {outer} outer iterations ({inner.message})")
            break
        if rows.mu.max() >= ap.max_penalty and rows.at_cap(ap) and rows.stuck(ap):
            status, message = Status.INFEASIBLE, (
                f"the constraints cannot be met: the largest violation stays {feas:.3g} with the "
                f"penalty at max_penalty={ap.max_penalty:g}; are the constraints contradictory?")
            break
    if status is None:
        if feas > ap.constraint_tolerance:
            status, message = Status.INFEASIBLE, (
                f"largest constraint violation {feas:.3g} > {ap.constraint_tolerance:g} after "
                f"max_outer_iterations={ap.max_outer_iterations}")
        else:
            status, message = Status.MAX_ITERATIONS, (
                f"feasible to {feas:.3g} but not converged (last inner solve: {inner.message}) "
                f"after max_outer_iterations={ap.max_outer_iterations}")
    timing["total"] = time.perf_counter() - t0
    return Result(None, status=status, message=message, iterations=its, initial_cost=f0,
                  final_cost=f, cost_history=[f0, f], iteration_records=records,
                  timing=timing, method="lm+augmented-lagrangian",
                  linear_solver=inner.linear_solver, problem=problem, state=state,
                  info={"outer_iterations": outer, "augmented_costs": augmented,
                        "penalty_max": float(rows.mu.max())},
                  unused_keys=tuple(problem.unused_keys), constraint_violation=feas,
                  multipliers=tuple(rows.multipliers(len(graph.constraints))))


class _InnerSolve:
    """The inner LM on the compiled penalty problem: on a small problem one call of the
    small-problem driver (:mod:`fgopt.solvers.small`), else LM's general path with one linear
    solver, analyzed on first use and kept."""

    def __init__(self, problem: Any, linear_solver: Any, callback: Callable | None):
        self.problem, self.linear_solver, self.callback = problem, linear_solver, callback
        self.solver = None
        self.driver = (problem.restrictions is None and callback is None
                       and linear_solver is None)

    def __call__(self, params: LMParams, state: Any) -> Result:
        problem, t0 = self.problem, time.perf_counter()
        driver = self.driver and small.qualifies(problem, params)
        if driver:
            result = small.optimize_small(problem, params, t0, state)
            if result is not None:
                return result
        if self.solver is None:
            choice = self.linear_solver if self.linear_solver is not None else \
                params.linear_solver
            problem.ensure_structure(params.ordering, choice)
            self.solver = make_linear_solver(choice, pattern=problem.pattern,
                                             backend=problem.backend)
            self.solver.analyze(problem.pattern)
        result = LevenbergMarquardt(params, self.linear_solver).optimize_problem(
            problem, state, self.solver, self.callback)
        if driver:
            small.charge_general(problem, time.perf_counter() - t0)
        return result


def _initial_penalty(problem: Any, rows: _Rows, state: Any, jacobians: list,
                     ratio: float) -> float:
    """``ratio`` times the median diagonal of the cost's Gauss-Newton ``H`` over the median
    nonzero ``diag(J_c^T J_c)`` of the constraints at ``state``: a penalty whose curvature is
    ``ratio`` times the cost's whatever the units (then each outer iteration shrinks a linear
    constraint's violation by about ``1 / (1 + ratio)``). The diagonals come from the batches'
    Jacobians (no sparse structure needed); Python factors are left out of the median."""
    penalty = {id(b) for b in rows.batches}
    voff = np.concatenate([[0], np.cumsum(problem.var_dim)])
    h = np.zeros(voff[-1])
    with problem.kernel_mode():
        for b in problem.batches:
            if id(b) in penalty:
                continue
            _, jac = _linearize(problem, b.kernel)(b.gather(state), b.source.constants)
            if not b.unit:
                jac = np.matmul(b.sqrt_info, jac)
            d = (jac ** 2).sum(axis=1)  # (n, D): the diagonal of each factor's J^T J
            for j, (dim, off) in enumerate(zip(b.arg_dims, b.arg_local_off)):
                np.add.at(h, voff[b.var_idx[:, j], None] + np.arange(dim), d[:, off:off + dim])
    h, c = h[h > 0], np.concatenate([(j ** 2).sum(axis=1).reshape(-1) for j in jacobians])
    c = c[np.isfinite(c) & (c > 0)]
    if h.shape[0] == 0 or c.shape[0] == 0:
        return 1.0
    # (the upper median by partition: np.median's checks cost 60 us a call on a tiny array)
    return float(ratio * np.partition(h, h.shape[0] // 2)[h.shape[0] // 2]
                 / np.partition(c, c.shape[0] // 2)[c.shape[0] // 2])


def _linearize(problem: Any, kernel: Any) -> Callable:
    """``kernel``'s linearization for ``problem``'s batches: the trusted numba entry on the
    numba backend (the batches' arrays are C-contiguous float64; 35 us less per call than
    ``residual``'s checks, a third of an outer iteration's constraint values on the
    10-link arm), else ``linearize`` (NumPy twins inside ``kernel_mode``)."""
    if problem.backend == "numba" and kernel.trusted_linearize is not None:
        return kernel.trusted_linearize
    return kernel.linearize
