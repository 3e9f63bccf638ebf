"""Equality and inequality constraints: an augmented-Lagrangian loop around Levenberg-Marquardt.

For the cost ``f(x) = 0.5 sum |R_i e_i(x)|^2``, equality constraints ``g_j(x) = 0`` and
inequality constraints ``h_k(x) <= 0`` (:func:`fgopt.constraint`), each outer iteration
minimizes, with LM warm-started from the last iterate, the augmented Lagrangian

    L(x) = f(x) + sum_j mu_j/2 |g_j(x) + lambda_j / mu_j|^2
                + sum_k mu_k/2 |max(0, h_k(x) + lambda_k / mu_k)|^2        (+ constants)

(the shifted-penalty form of Hestenes-Powell-Rockafellar). Both penalty terms are least-squares
residuals ``sqrt(mu) (c(x) + lambda / mu)`` (rows with ``h + lambda/mu <= 0`` zeroed), so the
inner problem is an ordinary sparse least-squares problem: one batched kernel per constraint
type wraps the constraint's generated kernel (value and tangent-space Jacobian), the problem is
compiled and its linear solver analyzed once, and every outer iteration only changes the
shifts and penalties the kernel reads. After each inner solve

    lambda_j <- lambda_j + mu_j g_j(x),     lambda_k <- max(0, lambda_k + mu_k h_k(x)),

and each instance whose violation did not fall below ``violation_reduction`` times the previous
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
from ..factors.kernel import FactorKernel
from ..key import key_str
from ..variables import Variables
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
    penalty_ratio: float = 10.0
    penalty_factor: float = 10.0
    max_penalty: float = 1e10
    violation_reduction: float = 0.25
    """An instance whose violation shrank by less than this factor gets a larger penalty."""
    verbose: bool = False
    """Print one line per outer iteration."""
    inner_relative_tolerance: float = 1e-13
    """The inner LM's ``relative_tolerance`` when the caller sets none (LM's own default, 1e-5,
    would stop far from the augmented Lagrangian's minimum and spoil the multiplier update)."""


_PROBLEM_TIMERS = ("linearize", "assemble", "retract", "cost")


class _Shifts:
    """What a penalty kernel reads per instance: ``shift = lambda / mu`` ``(n, m)`` and
    ``scale = sqrt(mu)`` ``(n,)`` (replaced between outer iterations)."""

    def __init__(self, n: int, m: int):
        self.shift = np.zeros((n, m))
        self.scale = np.ones(n)


def penalty_kernel(inner: FactorKernel, inequality: bool, table: _Shifts) -> FactorKernel:
    """The least-squares kernel of one constraint type's augmented-Lagrangian terms.

    Its constants are the constraint's own, then the instance's row in ``table`` (a float):
    residual ``scale (c + shift)`` (inequality: ``scale max(0, c + shift)``, zero Jacobian rows
    where inactive), Jacobian ``scale dc/dx`` in the same tangent spaces as ``inner``.
    """
    # ``linearize``, not ``trusted_linearize``: on the NumPy backend the inner kernel must take
    # its NumPy twin (this wrapper is NumPy, so the penalty kernel has one when the inner has)
    lin = inner.linearize

    def split(consts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return consts[:, -1].astype(np.intp), np.ascontiguousarray(consts[:, :-1])

    def residual(args: tuple, consts: np.ndarray) -> np.ndarray:
        idx, c = split(consts)
        r = inner.residual(args, c) + table.shift[idx]
        if inequality:
            r = np.maximum(r, 0.0)
        return r * table.scale[idx, None]

    def linearize(args: tuple, consts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        idx, c = split(consts)
        res, jac = lin(args, c)
        r = res + table.shift[idx]
        s = table.scale[idx, None]
        if inequality:
            w = (r > 0.0) * s
            return np.maximum(r, 0.0) * s, jac * w[:, :, None]
        return r * s, jac * s[:, :, None]

    return FactorKernel(name=f"{inner.name} ({'<=' if inequality else '=='} 0)",
                        arg_kinds=inner.arg_kinds, residual_dim=inner.residual_dim,
                        num_constants=inner.num_constants + 1, residual=residual,
                        linearize=linearize, source=inner.source,
                        nonfinite_hint=inner.nonfinite_hint, numpy_twin=inner.numpy_twin)


@dataclass(eq=False)
class _Group:
    """The constraints of one kernel and kind (equality / inequality)."""

    inner: FactorKernel
    inequality: bool
    members: list          # positions in graph.constraints
    table: _Shifts
    kernel: FactorKernel   # the penalty kernel
    lam: np.ndarray        # (n, m)
    mu: np.ndarray         # (n,)
    batch: Any = None      # the compiled problem's batch of this group
    last: np.ndarray | None = None  # (n,) violation measure after the last outer iteration
    prev: np.ndarray | None = None  # (n,) and after the one before


def _groups(graph: Any, initial: Variables) -> list[_Group]:
    by_kernel: dict = {}
    for i, c in enumerate(graph.constraints):
        for k in c.keys:
            if k not in initial:
                raise KeyNotFoundError(f"constraint {c.describe()} uses {key_str(k)}, which is "
                                       f"not in the initial values: add it with "
                                       f"Variables.add({key_str(k)}, value)")
        by_kernel.setdefault((id(c.kernel), c.inequality), []).append(i)
    groups = []
    for (_, ineq), members in by_kernel.items():
        inner = graph.constraints[members[0]].kernel
        n, m = len(members), inner.residual_dim
        table = _Shifts(n, m)
        groups.append(_Group(inner, ineq, members, table, penalty_kernel(inner, ineq, table),
                             np.zeros((n, m)), np.ones(n)))
    return groups


def _penalty_graph(graph: Any, groups: list[_Group]) -> Any:
    pg = type(graph)()
    pg._factors = list(graph.factors)
    pg._batches = list(graph.batches)
    cons = graph.constraints
    for g in groups:
        keys = np.array([[int(k) for k in cons[i].keys] for i in g.members], dtype=np.int64)
        consts = np.column_stack([np.stack([cons[i].constants for i in g.members]),
                                  np.arange(len(g.members), dtype=float)])
        pg.add_batch(g.kernel, keys, consts)
    return pg


def _values(problem: Any, g: _Group, state: Any) -> np.ndarray:
    """``c(x)`` of the group's instances ``(n, m)``, in the group's order."""
    b = g.batch
    consts = b.source.constants
    with problem.kernel_mode():
        c = g.inner.residual(b.gather(state), np.ascontiguousarray(consts[:, :-1]))
    out = np.empty_like(c)
    out[consts[:, -1].astype(np.intp)] = c
    return out


def _objective(problem: Any, groups: list[_Group], state: Any) -> float:
    """``f(x)``: the cost without the penalty terms."""
    saved = [g.table.scale for g in groups]
    try:
        for g in groups:
            g.table.scale = np.zeros_like(g.table.scale)
        return problem.cost(state)
    finally:
        for g, s in zip(groups, saved):
            g.table.scale = s


def inner_schedule(params: LMParams, explicit: set,
                   ap: AugmentedLagrangianParams | None = None) -> list[LMParams]:
    """The inner LM's parameters per outer iteration (the last repeats): the caller's, with the
    cost-decrease tolerances tightened by 1e-3 per outer iteration from LM's defaults down to
    ``inner_relative_tolerance`` (early solves need not be exact: their multipliers are
    provisional; a tight first solve took 20 LM iterations on M3500 where 5 do). A caller's
    own ``relative_tolerance`` is used throughout."""
    ap = ap if ap is not None else AugmentedLagrangianParams()
    if not isinstance(ap, AugmentedLagrangianParams):
        raise FgoptError(f"constraint_params must be an AugmentedLagrangianParams, got "
                         f"{type(ap).__name__}")
    if "relative_tolerance" in explicit or params.relative_tolerance is not None:
        return [params]
    out, rel, absolute = [], 1e-5, params.absolute_tolerance
    while True:
        rel, absolute = max(rel, ap.inner_relative_tolerance), max(absolute, 1e-12)
        out.append(dataclasses.replace(params, relative_tolerance=rel,
                                       absolute_tolerance=absolute))
        if rel <= ap.inner_relative_tolerance and absolute <= 1e-12:
            return out
        rel, absolute = rel * 1e-3, absolute * 1e-3


def optimize_constrained(graph: Any, initial: Variables, schedule: list[LMParams],
                         constraint_params: AugmentedLagrangianParams | None = None,
                         linear_solver: Any = None, callback: Callable | None = None) -> Result:
    """Minimize ``graph``'s cost subject to ``graph.constraints`` (see the module docstring);
    ``schedule``: the inner LM's parameters per outer iteration (:func:`inner_schedule`)."""
    params = schedule[0]
    t0 = time.perf_counter()
    ap = constraint_params if constraint_params is not None else AugmentedLagrangianParams()
    if not isinstance(ap, AugmentedLagrangianParams):
        raise FgoptError(f"constraint_params must be an AugmentedLagrangianParams, got "
                         f"{type(ap).__name__}")
    if not isinstance(initial, Variables):
        raise FgoptError(f"initial values must be fgopt.Variables, got {type(initial).__name__}")
    groups = _groups(graph, initial)
    choice = linear_solver if linear_solver is not None else params.linear_solver
    problem = compile_problem(_penalty_graph(graph, groups), initial, params, choice)
    problem.ensure_structure(params.ordering, choice)
    for g in groups:
        g.batch = next(b for b in problem.batches if b.kernel is g.kernel)
    solver = make_linear_solver(choice, pattern=problem.pattern, backend=problem.backend)
    solver.analyze(problem.pattern)
    state = problem.initial_state()
    values = [_values(problem, g, state) for g in groups]
    bad = _first_nonfinite(graph, groups, values)
    if bad is not None:
        raise NonFiniteError(f"constraint {bad} is NaN or inf at the initial values")
    f0 = _objective(problem, groups, state)
    mu0 = ap.initial_penalty if ap.initial_penalty is not None else _initial_penalty(
        problem, groups, state, ap.penalty_ratio)
    for g in groups:
        g.mu[:] = mu0
    records, augmented, its = [], [], 0
    timing: dict = {}
    status, message = None, ""
    inner = None
    feas = _feasibility(groups, values)
    outer = 0
    for outer in range(1, ap.max_outer_iterations + 1):
        for g in groups:
            g.table.shift = g.lam / g.mu[:, None]
            g.table.scale = np.sqrt(g.mu)
        lm = LevenbergMarquardt(schedule[min(outer, len(schedule)) - 1], linear_solver)
        inner = lm.optimize_problem(problem, state, solver, callback)
        state = inner.state
        its += inner.iterations
        records += inner.iteration_records
        for k, v in inner.timing.items():  # the problem's own timers count since it was made
            timing[k] = v if k in _PROBLEM_TIMERS else timing.get(k, 0.0) + v
        values = [_values(problem, g, state) for g in groups]
        feas = _feasibility(groups, values)
        measure = max(_update(g, v, ap) for g, v in zip(groups, values))
        augmented.append(inner.final_cost)
        if ap.verbose:
            print(f"outer {outer}: {inner.iterations} LM iterations ({inner.status.value}), "
                  f"augmented cost {augmented[-1]:.9e}, violation {feas:.3e}, measure {measure:.3e}, "
                  f"penalty <= {max(float(g.mu.max()) for g in groups):.3g}")
        if inner.status is Status.STOPPED:
            status, message = Status.STOPPED, "callback asked to stop"
            break
        if (max(feas, measure) <= ap.constraint_tolerance and inner.status is Status.CONVERGED
                and outer >= len(schedule)):
            status, message = Status.CONVERGED, (
                f"constraints hold to {max(feas, measure):.3g} <= "
                f"{ap.constraint_tolerance:g} after {outer} outer iterations ({inner.message})")
            break
        if _at_cap(groups, ap) and _stuck(groups, ap):
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
    f = _objective(problem, groups, state)
    multipliers = [None] * len(graph.constraints)
    for g in groups:
        for row, i in enumerate(g.members):
            multipliers[i] = g.lam[row].copy()
    timing["total"] = time.perf_counter() - t0
    return Result(None, status=status, message=message, iterations=its, initial_cost=f0,
                  final_cost=f, cost_history=[f0, f], iteration_records=records,
                  timing=timing, method="lm+augmented-lagrangian",
                  linear_solver=getattr(solver, "name", type(solver).__name__), problem=problem,
                  state=state, info={"outer_iterations": outer, "augmented_costs": augmented,
                                     "penalty_max": max(float(g.mu.max()) for g in groups)},
                  unused_keys=tuple(problem.unused_keys), constraint_violation=feas,
                  multipliers=tuple(multipliers))


def _initial_penalty(problem: Any, groups: list[_Group], state: Any, ratio: float) -> float:
    """``ratio`` times the median diagonal of the cost's ``H`` over the median nonzero
    ``diag(J_c^T J_c)`` of the constraints at ``state``: a penalty whose curvature is ``ratio``
    times the cost's whatever the units (then each outer iteration shrinks a linear
    constraint's violation by about ``1 / (1 + ratio)``)."""
    for g in groups:
        g.table.scale = np.zeros_like(g.table.scale)
    problem.linearize(state)
    h = problem.H_data[problem.pattern.diag_pos]
    h = h[h > 0]
    cols = []
    for g in groups:
        b = g.batch
        with problem.kernel_mode():
            _, jac = g.inner.linearize(b.gather(state),
                                       np.ascontiguousarray(b.source.constants[:, :-1]))
        cols.append((jac ** 2).sum(axis=1).reshape(-1))
    c = np.concatenate(cols)
    c = c[np.isfinite(c) & (c > 0)]
    if h.shape[0] == 0 or c.shape[0] == 0:
        return 1.0
    return float(ratio * np.median(h) / np.median(c))


def _active(g: _Group, v: np.ndarray) -> np.ndarray:
    return np.maximum(v, 0.0) if g.inequality else v


def _feasibility(groups: list[_Group], values: list[np.ndarray]) -> float:
    """``max(|g|, max(h, 0))`` over every constraint."""
    return max(float(np.max(np.abs(_active(g, v)), initial=0.0)) for g, v in zip(groups, values))


def _update(g: _Group, v: np.ndarray, ap: AugmentedLagrangianParams) -> float:
    """Multiplier and penalty update of one group at constraint values ``v``; returns its
    largest violation measure (equality ``|g|``, inequality ``|max(h, -lambda/mu)|``)."""
    if g.inequality:
        meas = np.max(np.abs(np.maximum(v, -g.lam / g.mu[:, None])), axis=1)
        g.lam = np.maximum(0.0, g.lam + g.mu[:, None] * v)
    else:
        meas = np.max(np.abs(v), axis=1)
        g.lam = g.lam + g.mu[:, None] * v
    if g.last is not None:
        grow = (meas > ap.violation_reduction * g.last) & (meas > ap.constraint_tolerance)
        g.mu = np.where(grow, np.minimum(g.mu * ap.penalty_factor, ap.max_penalty), g.mu)
        g.prev = g.last
    g.last = meas
    return float(meas.max(initial=0.0))


def _at_cap(groups: list[_Group], ap: AugmentedLagrangianParams) -> bool:
    """Every instance still violated has its penalty at ``max_penalty``."""
    return all(bool(np.all(g.mu[g.last > ap.constraint_tolerance] >= ap.max_penalty))
               for g in groups)


def _stuck(groups: list[_Group], ap: AugmentedLagrangianParams) -> bool:
    """The violation did not shrink in the last outer iteration (by 1 %)."""
    if any(g.prev is None for g in groups):
        return False
    before = max(float(g.prev.max(initial=0.0)) for g in groups)
    now = max(float(g.last.max(initial=0.0)) for g in groups)
    return now > ap.constraint_tolerance and now >= 0.99 * before


def _first_nonfinite(graph: Any, groups: list[_Group], values: list[np.ndarray]) -> str | None:
    for g, v in zip(groups, values):
        rows = np.nonzero(~np.all(np.isfinite(v), axis=1))[0]
        if rows.shape[0] > 0:
            return graph.constraints[g.members[int(rows[0])]].describe()
    return None
