"""``check_jacobians``: every factor's Jacobians against central differences (Ceres'
``GradientChecker``, GTSAM's ``numericalDerivative``), the check to run on a custom factor.

For factor ``e(x_1, ..., x_k)`` and variable ``x_j`` with tangent dimension ``d``, column ``i``
of the numerical Jacobian is the central difference through the variable's own retraction

    (e(x_j (+) h u_i) - e(x_j (+) -h u_i)) / (2 h),

the derivative fgopt's solvers assume (tangent space, right perturbation for Lie groups). Kernel
factors are differenced batch-wise (one retract and one residual call per batch and tangent
direction); Python factors one by one through ``values.at``.

A block fails when ``max |J - J_num| > atol + rtol * max(|J|, |J_num|)`` (entry-wise maxima);
``atol`` is raised to the rounding floor of the difference quotient, ``100 eps max|e| / h``, so
large residuals do not fail on rounding noise. Jacobians are compared unwhitened (as the factor
returns them); the noise model does not enter.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import FgoptError, NonFiniteError
from ..factors.base import Factor
from ..graph import FactorGraph
from ..key import Key, key_str
from ..manifolds.base import ops_for
from ..problem import Problem
from ..variables import Variables

_EPS = float(np.finfo(float).eps)


@dataclass(frozen=True)
class JacobianCheck:
    """One factor's Jacobian with respect to one of its variables."""

    factor: str
    """The factor (type, keys; batch rows also say where they came from)."""
    key: Key
    abs_error: float
    """``max |J - J_num|``."""
    rel_error: float
    """``abs_error / max(|J|, |J_num|)`` (entry-wise maxima; inf if the Jacobians are not
    finite)."""
    worst: tuple[int, int]
    """(residual row, tangent column) of the largest difference."""
    analytic: np.ndarray = field(repr=False)
    numerical: np.ndarray = field(repr=False)
    ok: bool = True

    def row(self) -> str:
        i, j = self.worst
        a, n = self.analytic, self.numerical
        where = (f" at [{i}, {j}]: J {a[i, j]:.6g}, numerical {n[i, j]:.6g}"
                 if a.size and np.isfinite(self.abs_error) else "")
        return (f"{'FAIL' if not self.ok else 'ok  '} {self.factor} wrt {key_str(self.key)}: "
                f"rel. error {self.rel_error:.3g} (abs {self.abs_error:.3g}){where}")


class JacobianReport:
    """What :func:`check_jacobians` returns: one :class:`JacobianCheck` per (factor, variable),
    worst first (largest relative error among the failures, then among the rest).

    >>> sample = fgopt.datasets.manhattan_2d(num_poses=10, seed=0)
    >>> report = fgopt.check_jacobians(sample.graph, sample.initial)
    >>> report.ok, len(report), report.failures, report.max_rel_error < 1e-6
    (True, 19, [], True)
    >>> report[0].key in sample.initial.keys()     # the worst block: factor, key, errors
    True
    """

    def __init__(self, checks: list[JacobianCheck], num_factors: int, step: float, rtol: float,
                 atol: float):
        self.checks = sorted(checks, key=lambda c: (c.ok, -_sort_key(c.rel_error),
                                                    -_sort_key(c.abs_error)))
        self.num_factors = num_factors
        self.step, self.rtol, self.atol = step, rtol, atol

    @property
    def failures(self) -> list[JacobianCheck]:
        return [c for c in self.checks if not c.ok]

    @property
    def ok(self) -> bool:
        """True when every Jacobian block agrees with central differences."""
        return all(c.ok for c in self.checks)

    @property
    def max_rel_error(self) -> float:
        return max((c.rel_error for c in self.checks), default=0.0)

    def __len__(self) -> int:
        return len(self.checks)

    def __iter__(self):
        return iter(self.checks)

    def __getitem__(self, i: int) -> JacobianCheck:
        return self.checks[i]

    def __bool__(self) -> bool:
        return True

    def __repr__(self, limit: int = 10) -> str:
        bad = self.failures
        head = (f"JacobianReport: {self.num_factors} factors, {len(self.checks)} Jacobian blocks "
                f"vs central differences (step {self.step:g}); ")
        head += (f"{len(bad)} FAIL (atol {self.atol:g} + rtol {self.rtol:g} * scale); worst first:"
                 if bad else f"all agree, max rel. error {self.max_rel_error:.2g}; worst first:")
        lines = [head] + ["  " + c.row() for c in self.checks[:limit]]
        if len(self.checks) > limit:
            lines.append(f"  ... {len(self.checks) - limit} more")
        return "\n".join(lines)


def _sort_key(x: float) -> float:
    return x if x == x else np.inf  # NaN sorts as worst


def check_jacobians(graph: Any, values: Variables, step: float = 1e-6, rtol: float = 1e-5,
                    atol: float = 1e-7) -> JacobianReport:
    """Compare every factor's Jacobians at ``values`` with central differences.

    Args:
        graph: the :class:`~fgopt.FactorGraph` (individual factors and batches), or one factor
            or a list of factors.
        values: :class:`~fgopt.Variables` with every key the graph uses (not modified).
        step: difference step ``h`` in each variable's tangent space.
        rtol, atol: a block fails when ``max |J - J_num| > atol + rtol * max(|J|, |J_num|)``
            (``atol`` raised to the rounding floor ``100 eps max|e| / h``).

    Returns:
        A :class:`JacobianReport`: ``report.ok``, ``report.failures``, iterable, worst first.

    Example:

    >>> sample = fgopt.datasets.manhattan_2d(num_poses=10, seed=0)
    >>> report = fgopt.check_jacobians(sample.graph, sample.initial)
    >>> report.ok
    True
    """
    if not isinstance(values, Variables):
        raise FgoptError(f"values must be fgopt.Variables, got {type(values).__name__}")
    if isinstance(graph, Factor):
        graph = FactorGraph([graph])
    elif isinstance(graph, (list, tuple)):
        graph = FactorGraph(graph)
    step = float(step)
    if not step > 0:
        raise FgoptError(f"check_jacobians: step must be positive, got {step}")
    problem = Problem(graph, values, ordering=None, build_structure=False)
    state = problem.initial_state()
    checks: list[JacobianCheck] = []
    for b in problem.batches:
        checks += _check_batch(b, state, step, rtol, atol)
    for s in problem._slow:
        checks += _check_python(s.factor, values, step, rtol, atol)
    return JacobianReport(checks, len(graph), step, rtol, atol)


def _compare(factor: str, k: Key, J: np.ndarray, Jn: np.ndarray, res_scale: float, step: float,
             rtol: float, atol: float) -> JacobianCheck:
    if not (np.all(np.isfinite(J)) and np.all(np.isfinite(Jn))):
        bad = ~(np.isfinite(J) & np.isfinite(Jn))
        i, j = (int(x) for x in np.argwhere(bad)[0])
        return JacobianCheck(factor, k, np.inf, np.inf, (i, j), J, Jn, False)
    diff = np.abs(J - Jn)
    i, j = (int(x) for x in np.unravel_index(int(np.argmax(diff)), diff.shape))
    err = float(diff[i, j])
    scale = max(float(np.abs(J).max()), float(np.abs(Jn).max()))
    rel = err / scale if scale > 0 else (0.0 if err == 0 else np.inf)
    floor = max(atol, 100.0 * _EPS * res_scale / step)
    return JacobianCheck(factor, k, err, rel, (i, j), J, Jn, err <= floor + rtol * scale)


def _check_batch(b: Any, state: Any, h: float, rtol: float, atol: float) -> list[JacobianCheck]:
    kernel, src = b.kernel, b.source
    args = list(b.gather(state))
    consts = src.constants
    res, jac = kernel.linearize(tuple(args), consts)
    n, r = res.shape
    num = np.empty_like(jac)
    scale = np.abs(res).max(axis=1)
    for j, (kind, off) in enumerate(zip(kernel.arg_kinds, kernel.arg_offsets)):
        for i in range(kind.dim):
            d = np.zeros((n, kind.dim))
            d[:, i] = h
            out = []
            for sgn in (1.0, -1.0):
                trial = list(args)
                trial[j] = kind.retract(np.ascontiguousarray(args[j]), sgn * d)
                rr = kernel.residual(tuple(trial), consts)
                scale = np.maximum(scale, np.abs(rr).max(axis=1))
                out.append(rr)
            num[:, :, off + i] = (out[0] - out[1]) / (2.0 * h)
    checks = []
    for row in range(n):
        keys = [Key(int(q)) for q in src.keys[row]]
        name = f"{kernel.name}({', '.join(key_str(q) for q in keys)}) (factor {src._where(row)})"
        for k, kind, off in zip(keys, kernel.arg_kinds, kernel.arg_offsets):
            checks.append(_compare(name, k, np.array(jac[row, :, off:off + kind.dim]),
                                   np.array(num[row, :, off:off + kind.dim]),
                                   float(scale[row]), h, rtol, atol))
    return checks


class _Override:
    """``values`` with one key replaced (what a Python factor reads during a difference)."""

    def __init__(self, values: Variables, k: Key, x: Any):
        self._v, self._k, self._x = values, k, x

    def at(self, k: Any) -> Any:
        return self._x if k == self._k else self._v.at(k)

    __getitem__ = at

    def __contains__(self, k: object) -> bool:
        return k in self._v


def _check_python(f: Any, values: Variables, h: float, rtol: float,
                  atol: float) -> list[JacobianCheck]:
    name = f.describe()
    try:
        e0 = f.checked_error(values)
        Js = f.checked_jacobians(values)
    except NonFiniteError:
        nan = np.full((f.dim, 1), np.nan)
        return [JacobianCheck(name, k, np.inf, np.inf, (0, 0), nan, nan, False) for k in f.keys]
    checks = []
    for k, J in zip(f.keys, Js):
        x = values.at(k)
        ops = ops_for(x)
        d = ops.dim(x)
        Jn = np.empty((f.dim, d))
        scale = float(np.abs(e0).max(initial=0.0))
        for i in range(d):
            u = np.zeros(d)
            u[i] = h
            ep = np.asarray(f.error(_Override(values, k, ops.retract(x, u))), dtype=float)
            em = np.asarray(f.error(_Override(values, k, ops.retract(x, -u))), dtype=float)
            Jn[:, i] = (ep.reshape(-1) - em.reshape(-1)) / (2.0 * h)
            scale = max(scale, float(np.abs(ep).max(initial=0.0)),
                        float(np.abs(em).max(initial=0.0)))
        checks.append(_compare(name, k, J, Jn, scale, h, rtol, atol))
    return checks
