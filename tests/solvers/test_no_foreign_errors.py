"""Only a ``Result`` or an ``FgoptError`` leaves ``fgopt.optimize`` / ``fgopt.marginals``
(issue 42, item 3): every method x every linear solver over singular (no gauge), indefinite
(a noise model that is not positive definite), NaN (initial values) and outlier-heavy
(50 % random-pair wrong loop closures) inputs. Small graphs: this runs in ``make test``."""

from __future__ import annotations

import numpy as np
import pytest

import fgopt
from fgopt import BetweenFactor, FactorGraph, PriorFactor, Variables, key
from fgopt.datasets import random_loop_closures
from fgopt.errors import FgoptError, have_extra
from fgopt.manifolds import SE2
from fgopt.noise import Diagonal

METHODS = ["lm", "gn", "dogleg", "gnc"]
SOLVERS = ["auto", "cholmod", "dense", "block", "ldlt", "pcg"]


def _chain(n: int, prior: bool, seed: int = 0) -> tuple[FactorGraph, Variables]:
    rng = np.random.default_rng(seed)
    noise = Diagonal.pose2(x=0.1, y=0.1, theta=0.05)
    g = FactorGraph()
    if prior:
        g.add(PriorFactor(key("x", 0), SE2.identity(), noise))
    for i in range(n - 1):
        g.add(BetweenFactor(key("x", i), key("x", i + 1), SE2.from_xytheta(1, 0, 0.3), noise))
    for i in range(0, n - 3, 3):
        g.add(BetweenFactor(key("x", i), key("x", i + 3),
                            SE2.from_xytheta(1, 0, 0.3) * SE2.from_xytheta(1, 0, 0.3)
                            * SE2.from_xytheta(1, 0, 0.3), noise))
    v = Variables()
    for i in range(n):
        v.add(key("x", i), SE2.from_xytheta(i + 0.1 * rng.normal(), 0.1 * rng.normal(),
                                            0.3 * i + 0.1 * rng.normal()))
    return g, v


def _singular():
    return _chain(12, prior=False)


def _indefinite():
    g, v = _chain(12, prior=True)
    from fgopt.noise import Gaussian

    bad = Gaussian.from_information(np.diag([1.0, -1.0, 1.0]))  # FgoptError here, or later
    g.add(BetweenFactor(key("x", 0), key("x", 2), SE2.from_xytheta(2, 0, 0.6), bad))
    return g, v


def _nan():
    g, v = _chain(12, prior=True)
    v2 = Variables()
    for k in v.keys():
        v2.add(k, v.at(k))
    v2.update(key("x", 5), SE2.from_xytheta(float("nan"), 0.0, 0.0))
    return g, v2


def _outliers():
    g, v = _chain(30, prior=True)
    ref = fgopt.optimize(g, v)
    bad, _ = random_loop_closures(g, ref.values, 0.5, seed=1)
    return bad, v


CASES = {"singular": _singular, "indefinite": _indefinite, "nan": _nan, "outliers": _outliers}


@pytest.mark.parametrize("case", list(CASES))
@pytest.mark.parametrize("linear_solver", SOLVERS)
@pytest.mark.parametrize("method", METHODS)
def test_only_results_or_fgopt_errors(method, linear_solver, case):
    """optimize then marginals on each bad input: each call returns or raises an FgoptError."""
    if linear_solver == "cholmod" and not have_extra("sksparse"):
        pytest.skip("CHOLMOD extra absent")
    try:
        g, v = CASES[case]()
    except FgoptError:
        return  # refused while building the input (e.g. an indefinite noise model)
    try:
        r = fgopt.optimize(g, v, method=method, linear_solver=linear_solver)
    except FgoptError:
        return
    assert isinstance(r, fgopt.Result)
    assert np.isfinite(r.final_cost) or not r.success
    try:
        cov = fgopt.marginals(r, linear_solver=None if linear_solver == "auto" else linear_solver)
    except FgoptError:
        return
    for c in cov.values():
        assert np.all(np.isfinite(c)) and np.all(np.linalg.eigvalsh(c) > 0)
