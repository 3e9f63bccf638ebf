"""A singular information matrix raises, whatever the linear solver (issue 42, item 1).

Three SE(2) poses chained by two between factors and no prior leave H with a 3-dimensional null
space (the gauge). Rounding leaves a pivot of ~1e-16 x its diagonal there, of either sign: a
Cholesky that only tests ``d > 0`` accepted it about half the time and ``marginals`` returned
covariances of ~1e14 (CHOLMOD, the default with the extra) or -3e14. Every factorization now
tests each pivot against its diagonal entry of H (``linear.base.PIVOT_TOLERANCE``) and the
error names the variable (as GTSAM's ``IndeterminateSystemException`` names a key).
"""

from __future__ import annotations

import sys

import numpy as np
import pytest

import fgopt
from fgopt import BetweenFactor, FactorGraph, PriorFactor, Variables, key
from fgopt.errors import NotPositiveDefiniteError, have_extra
from fgopt.incremental import IncrementalSmoother
from fgopt.manifolds import SE2
from fgopt.noise import Diagonal
from fgopt.problem import Problem
from fgopt.solvers.linear.base import make_linear_solver

SOLVERS = ["cholmod", "dense", "block", "ldlt", "pcg"]
needs_cholmod = pytest.mark.skipif(not have_extra("sksparse"), reason="CHOLMOD extra absent")


def _param(name):
    return pytest.param(name, marks=needs_cholmod) if name == "cholmod" else name


def chain(n: int, prior: bool = False, seed: int = 0) -> tuple[FactorGraph, Variables]:
    """``n`` SE(2) poses, odometry between consecutive ones (a loop closure from the last to
    the first when ``n >= 4``), a prior on the first only if ``prior``; noisy initial values."""
    rng = np.random.default_rng(seed)
    noise = Diagonal.pose2(x=0.1, y=0.1, theta=0.05)
    g = FactorGraph()
    if prior:
        g.add(PriorFactor(key("x", 0), SE2.identity(), noise))
    for i in range(n - 1):
        g.add(BetweenFactor(key("x", i), key("x", i + 1), SE2.from_xytheta(1, 0, 0.3), noise))
    if n >= 4:
        g.add(BetweenFactor(key("x", n - 1), key("x", 0), SE2.from_xytheta(0.5, 0.2, 0.1), noise))
    v = Variables()
    for i in range(n):
        v.add(key("x", i), SE2.from_xytheta(i + 0.1 * rng.normal(), 0.1 * rng.normal(),
                                            0.3 * i + 0.1 * rng.normal()))
    return g, v


def _names_a_pose(message: str, n: int) -> bool:
    return any(f"x{i}" in message for i in range(n))


@pytest.mark.parametrize("n", [2, 3, 5])
@pytest.mark.parametrize("linear_solver", [None] + [_param(s) for s in SOLVERS])
def test_marginals_of_a_gauge_free_graph_raise(n, linear_solver):
    """``marginals`` on a graph without a prior raises NotPositiveDefiniteError for every
    linear solver (never covariances of 1e14), naming a variable for the direct solvers."""
    g, v = chain(n)
    r = fgopt.optimize(g, v, method="lm")
    with pytest.raises(NotPositiveDefiniteError, match="prior") as info:
        fgopt.marginals(r, linear_solver=linear_solver)
    if linear_solver not in ("pcg",):
        assert _names_a_pose(str(info.value), n), str(info.value)
    with pytest.raises(NotPositiveDefiniteError):
        fgopt.marginals(None, graph=g, values=v, linear_solver=linear_solver)


@pytest.mark.parametrize("linear_solver", [None] + [_param(s) for s in SOLVERS])
def test_marginals_with_a_prior_agree_across_solvers(linear_solver):
    """The pivot test refuses nothing that is definite: with a prior every solver returns the
    blocks of H^-1."""
    g, v = chain(5, prior=True)
    r = fgopt.optimize(g, v, method="lm")
    problem = r.problem
    problem.linearize(r.state)
    Hinv = np.linalg.inv(problem.pattern.full(problem.H_data).toarray())
    cov = fgopt.marginals(r, linear_solver=linear_solver)
    for k, c in cov.items():
        o = problem.pattern.var_offset[problem._var_of_key[k]]
        assert np.allclose(c, Hinv[o:o + 3, o:o + 3], rtol=1e-6, atol=1e-12), k


def test_marginals_without_cholmod_raise(monkeypatch):
    """Without the CHOLMOD extra the default path (fgopt's block Cholesky) raises too."""
    for name in ("sksparse", "sksparse.cholmod"):
        monkeypatch.setitem(sys.modules, name, None)
    assert not have_extra("sksparse")
    g, v = chain(3)
    with pytest.raises(NotPositiveDefiniteError, match="x[012]"):
        fgopt.marginals(None, graph=g, values=v)


@pytest.mark.parametrize("name", [_param(s) for s in ["cholmod", "dense", "block", "ldlt"]])
def test_factorize_names_the_unconstrained_variable(name):
    """A solver's factorize raises on a singular H with ``variable`` set to a variable of the
    part H does not constrain: a chain with a prior plus two poses tied only to each other
    (a component without a gauge), whatever the elimination order."""
    g, v = chain(3, prior=True)
    noise = Diagonal.pose2(x=0.1, y=0.1, theta=0.05)
    g.add(BetweenFactor(key("y", 0), key("y", 1), SE2.from_xytheta(1, 0, 0.2), noise))
    v.add(key("y", 0), SE2.from_xytheta(5, 5, 0.1)).add(key("y", 1), SE2.from_xytheta(6, 5, 0.2))
    problem = Problem(g, v)
    problem.ensure_structure()
    problem.linearize(problem.initial_state())
    pat = problem.pattern
    solver = make_linear_solver(name, pattern=pat)
    solver.analyze(pat)
    with pytest.raises(NotPositiveDefiniteError) as info:
        solver.factorize(problem.H_data.copy())
    free = {problem._var_of_key[key("y", 0)], problem._var_of_key[key("y", 1)]}
    assert info.value.variable in free, str(info.value)
    H = problem.H_data.copy()
    H[pat.diag_pos] += 1e-6  # damped: definite, accepted
    solver.factorize(H)


@pytest.mark.parametrize("linear_solver", ["auto"] + [_param(s) for s in SOLVERS])
def test_gauss_newton_on_a_gauge_free_graph_fails_clearly(linear_solver):
    """Gauss-Newton (no damping) on a gauge-free graph ends FAILED with a message naming a
    variable and asking for a prior, instead of stepping along the null space (CHOLMOD's
    factor of H took such steps and reported convergence); LM's damping solves it."""
    g, v = chain(5)
    r = fgopt.optimize(g, v, method="gn", linear_solver=linear_solver)
    if linear_solver == "pcg":  # CG solves the consistent singular system: a fine GN step
        assert r.success
    else:
        assert r.status == fgopt.Status.FAILED, r.message
        assert "prior" in r.message and _names_a_pose(r.message, 5), r.message
        assert np.isfinite(r.final_cost)
    lm = fgopt.optimize(g, v, method="lm", linear_solver=linear_solver)
    assert lm.success, lm.message
    withprior = fgopt.optimize(*chain(5, prior=True), method="lm")
    assert lm.final_cost == pytest.approx(withprior.final_cost, rel=1e-6, abs=1e-9)


def test_incremental_smoother_refuses_a_singular_system():
    """IncrementalSmoother: an update leaving the system without a gauge (a chain without a
    prior, or removing the only prior) raises naming the variable, the smoother unchanged;
    its marginals stay those of the last definite system."""
    s = IncrementalSmoother()
    g, v = chain(3)
    with pytest.raises(NotPositiveDefiniteError, match="x[012]"):
        s.update(g, v)
    assert len(s.keys()) == 0
    g, v = chain(3, prior=True)
    handles = s.update(g, v).new_factor_indices
    before = s.marginal(key("x", 2))
    with pytest.raises(NotPositiveDefiniteError, match="x[012]"):
        s.update(remove=[handles[0]])
    assert np.array_equal(s.marginal(key("x", 2)), before)
