"""The miniSAM paper's 2D pose-graph example: prior, 4 odometry edges, 1 loop closure.

Every method x backend reaches the same optimum, and all backends compute the same step.
"""

import numpy as np
import pytest

import fgopt
from fgopt import BetweenFactor, FactorGraph, PriorFactor, Variables, key
from fgopt.errors import have_extra
from fgopt.manifolds import SE2
from fgopt.noise import Diagonal
from fgopt.solvers import make_linear_solver

METHODS = ["lm", "gn", "dogleg"]
needs_cholmod = pytest.mark.skipif(not have_extra("sksparse"), reason="CHOLMOD extra absent")
SOLVERS = [pytest.param("cholmod", marks=needs_cholmod), "block", "ldlt", "pcg", "dense"]


def minisam_loop():
    g = FactorGraph()
    prior_noise = Diagonal.sigmas([0.1, 1.0, 1.0])   # (theta, x, y): rotation first
    odo_noise = Diagonal.sigmas([0.1, 0.5, 0.5])
    g.add(PriorFactor(key("x", 1), SE2.from_xytheta(0, 0, 0), prior_noise))
    g.add(BetweenFactor(key("x", 1), key("x", 2), SE2.from_xytheta(5, 0, 0), odo_noise))
    g.add(BetweenFactor(key("x", 2), key("x", 3), SE2.from_xytheta(5, 0, -np.pi / 2), odo_noise))
    g.add(BetweenFactor(key("x", 3), key("x", 4), SE2.from_xytheta(5, 0, -np.pi / 2), odo_noise))
    g.add(BetweenFactor(key("x", 4), key("x", 5), SE2.from_xytheta(5, 0, -np.pi / 2), odo_noise))
    g.add(BetweenFactor(key("x", 5), key("x", 2), SE2.from_xytheta(5, 0, -np.pi / 2), odo_noise))
    v = Variables()
    v.add(key("x", 1), SE2.from_xytheta(0.2, -0.3, 0.2))
    v.add(key("x", 2), SE2.from_xytheta(5.1, 0.3, -0.1))
    v.add(key("x", 3), SE2.from_xytheta(9.9, -0.1, -np.pi / 2 - 0.2))
    v.add(key("x", 4), SE2.from_xytheta(10.2, -5.0, -np.pi + 0.1))
    v.add(key("x", 5), SE2.from_xytheta(5.1, -5.1, np.pi / 2 - 0.1))
    return g, v


EXPECTED = {1: (0, 0, 0), 2: (5, 0, 0), 3: (10, 0, -np.pi / 2), 4: (10, -5, np.pi),
            5: (5, -5, np.pi / 2)}


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("method", METHODS)
def test_all_methods_and_backends_reach_the_optimum(method, solver):
    g, v = minisam_loop()
    r = fgopt.optimize(g, v, method=method, linear_solver=solver)
    assert r.success, r.message
    assert r.final_cost < 1e-10
    for i, (x, y, th) in EXPECTED.items():
        assert r.values.at(key("x", i)).equals(SE2.from_xytheta(x, y, th), 1e-5), (i, r.values)
    assert r.cost_history[0] == r.initial_cost and r.cost_history[-1] == r.final_cost
    assert set(r.timing) >= {"linearize", "assemble", "factorize+solve", "retract", "total"}


@pytest.mark.parametrize("solver", SOLVERS)
def test_backends_compute_the_same_step(solver):
    """Same damped system, every backend: its step agrees with NumPy's dense solve of the full
    H to 1e-9 (relative)."""
    g, v = minisam_loop()
    problem = fgopt.Problem(g, v)
    problem.linearize(problem.initial_state())
    H = problem.H_data.copy()
    H[problem.pattern.diag_pos] += 1e-3 * H[problem.pattern.diag_pos]
    s = make_linear_solver(solver, **({"rtol": 1e-14} if solver == "pcg" else {}))
    s.analyze(problem.pattern)
    s.factorize(H)
    step = s.solve(-problem.g)
    ref = np.linalg.solve(problem.pattern.full(H).toarray(), -problem.g)
    assert np.linalg.norm(step - ref) <= 1e-9 * np.linalg.norm(ref)


def test_graph_error_is_half_sum_of_squared_whitened_residuals():
    g, v = minisam_loop()
    manual = sum(0.5 * float(f.whitened_error(v) @ f.whitened_error(v)) for f in g)
    assert np.isclose(g.error(v), manual)
    assert "between_pose2" in repr(g) or "BetweenFactor" in repr(g)


def test_result_repr_and_records():
    g, v = minisam_loop()
    r = fgopt.optimize(g, v)
    text = repr(r)
    assert "converged" in text and "cost" in text
    assert "iter" in r.table() and "<table>" in r._repr_html_()
    assert r.iterations == len(r.iteration_records)
