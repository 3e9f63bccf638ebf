"""Marginal covariances of chosen variables, from a sparse factorization of H at the solution.

For a Gaussian approximation at the optimum, the covariance of all tangent coordinates is
``H^-1`` (H = J^T W J, undamped). The marginal of variable ``k`` is the ``d_k x d_k`` block of
``H^-1`` at k's tangent indices: solve ``H X = E_k`` for the identity columns of k and keep the
block. Coordinates are those of k's tangent space at the estimate, under fgopt's retraction
``x Exp(delta)`` (GTSAM's convention for Pose2/Pose3; note the rotation-first order).
"""

from __future__ import annotations

from typing import Any, Iterable

import numpy as np

from ..errors import FgoptError, KeyNotFoundError, NotPositiveDefiniteError, have_extra
from ..key import Key, as_key, key_str
from .linear.base import describe_indefinite, make_linear_solver


#: Up to this many tangent columns, marginals come from solves with the identity's columns;
#: above, from the selected inverse of fgopt's block Cholesky (sphere2500, all 2,500 poses:
#: 17.7 s and a 15,000^2 dense right-hand side with CHOLMOD solves, 0.1 s this way).
SOLVE_MAX_COLUMNS = 256


def marginals(result: Any, keys: Iterable[int] | None = None, graph: Any = None,
              values: Any = None, linear_solver: str | None = None) -> dict[Key, np.ndarray]:
    """``{key: covariance}`` in each key's tangent space.

    Args:
        result: a :class:`~fgopt.Result` (its compiled problem and final state are reused), or
            ``None`` together with ``graph`` and ``values``.
        keys: the variables to report (default: all).
        linear_solver: backend for the factorization of H (default: fgopt's block Cholesky,
            whose selected inverse holds every marginal, when the keys have more than
            ``SOLVE_MAX_COLUMNS`` tangent dimensions in all or CHOLMOD is not installed, else
            CHOLMOD; or ``"dense"``...). With ``"block"`` the marginals always come from the
            selected inverse; with the others, from solves with the identity's columns.

    Example:

    >>> sample = fgopt.datasets.manhattan_2d(num_poses=20, seed=0)
    >>> result = fgopt.optimize(sample.graph, sample.initial)
    >>> cov = fgopt.marginals(result, [key('x', 19)])
    >>> cov[key('x', 19)].shape
    (3, 3)
    """
    if result is not None:
        problem, state = result.problem, result.state
        if problem is None:
            raise FgoptError("marginals: this Result has no compiled problem (it was pickled, "
                             "e.g. returned by solve_many); pass graph= and values=result.values")
    else:
        if graph is None or values is None:
            raise FgoptError("marginals: pass a Result, or graph= and values=")
        from ..problem import Problem

        problem = Problem(graph, values)
        state = problem.initial_state()
    problem.ensure_structure()  # a small problem's driver solved it without one
    problem.set_weights(None)
    problem.linearize(state)
    key_list = [as_key(k) for k in keys] if keys is not None else [
        Key(int(k)) for k in problem.var_keys]
    if not key_list:
        return {}
    if linear_solver is None:
        # many keys: every marginal from the selected inverse of one block factorization;
        # a few: a few solves (CHOLMOD when installed)
        many = sum(int(problem.var_dim[problem._var_of_key[k]]) for k in key_list
                   if k in problem._var_of_key) > SOLVE_MAX_COLUMNS
        linear_solver = "block" if many or not have_extra("sksparse") else "cholmod"
    solver = make_linear_solver(linear_solver, pattern=problem.pattern)
    solver.analyze(problem.pattern)
    # constant variables (fgopt.bounds) are not in H: their covariance is zero, and H's
    # variables are the free ones, numbered in order
    R = getattr(problem, "restrictions", None)
    held = R.const_var if R is not None else np.zeros(problem.var_keys.shape[0], dtype=bool)
    in_h = np.cumsum(~held) - 1

    def indefinite(exc: NotPositiveDefiniteError) -> NotPositiveDefiniteError:
        return describe_indefinite(
            exc, problem.var_keys[~held], "marginals",
            "fix the gauge with a prior (e.g. PriorFactor on the first pose) and give every "
            "variable enough factors")

    try:
        solver.factorize(problem.H_data.copy())
    except NotPositiveDefiniteError as exc:
        raise indefinite(exc) from None
    off, dim = problem.var_offset, problem.var_dim
    out: dict[Key, np.ndarray] = {}
    cols, spans = [], []
    for k in list(key_list):
        v = problem._var_of_key.get(k)
        if v is None:
            raise KeyNotFoundError(f"marginals: {key_str(k)} is not a variable of the problem")
        if held[v]:
            out[k] = np.zeros((int(dim[v]), int(dim[v])))
            key_list.remove(k)
            continue
        spans.append((len(cols), int(dim[v])))
        cols.extend(range(int(off[v]), int(off[v] + dim[v])))
    if hasattr(solver, "covariance_blocks"):  # the diagonal blocks of the selected inverse
        var = np.array([problem._var_of_key[k] for k in key_list], dtype=np.int64)
        dvar = dim[var]
        var = in_h[var]
        blocks: list = [None] * len(key_list)
        for d in np.unique(dvar).tolist():
            at = np.nonzero(dvar == d)[0]
            for i, block in zip(at.tolist(), solver.covariance_blocks(var[at][:, None], [d])):
                blocks[i] = block
        for k, block in zip(key_list, blocks):
            out[k] = 0.5 * (block + block.T)
        return out
    n = problem.pattern.size
    chunk = 256  # columns per multi-right-hand-side solve
    X_cols = []
    for start in range(0, len(cols), chunk):
        E = np.zeros((n, min(chunk, len(cols) - start)))
        E[cols[start:start + chunk], np.arange(E.shape[1])] = 1.0
        try:   # (an iterative solver finds no solution here)
            X = solver.solve(E) if E.shape[1] > 1 else solver.solve(E[:, 0])[:, None]
        except NotPositiveDefiniteError as exc:
            raise indefinite(exc) from None
        X_cols.append(np.asarray(X).reshape(n, -1))
    X = np.concatenate(X_cols, axis=1)
    for k, (c0, d) in zip(key_list, spans):
        v = problem._var_of_key[k]
        rows = np.arange(off[v], off[v] + d)
        block = X[rows, c0:c0 + d]
        out[k] = 0.5 * (block + block.T)
    return out
