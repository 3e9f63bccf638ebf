"""LM's "auto" parameters per problem class: pose graphs, navigation-like mixed problems, and
BA-shaped / vector-only problems each get the damping and lambda rule measured best for them."""

from __future__ import annotations

import numpy as np
import pytest

import fgopt
from fgopt import key
from fgopt.noise import Isotropic
from fgopt.solvers import LMParams
from fgopt.solvers.lm import auto_policy, problem_class


def _pose_chain(n, with_vectors=False, points=0):
    graph, values = fgopt.FactorGraph(), fgopt.Variables()
    graph.add(fgopt.PriorFactor(key("x", 0), fgopt.SE3(), Isotropic.sigma(6, 0.1)))
    for i in range(n):
        values.add(key("x", i), fgopt.SE3(None, [i, 0, 0]))
        if i:
            graph.add(fgopt.BetweenFactor(key("x", i - 1), key("x", i), fgopt.SE3(None, [1, 0, 0]),
                                          Isotropic.sigma(6, 0.1)))
        if with_vectors:
            values.add(key("v", i), np.zeros(3))
            graph.add(fgopt.PriorFactor(key("v", i), np.zeros(3), Isotropic.sigma(3, 1.0)))
    from fgopt.factors.library.pose_point import PosePointFactor

    for j in range(points):
        values.add(key("l", j), np.array([j % 5, 1.0, 0.0]))
        for i in (j % n, (j + 1) % n):
            graph.add(PosePointFactor(key("x", i), key("l", j), [0.0, 1.0, 0.0],
                                      Isotropic.sigma(3, 0.1)))
    return fgopt.Problem(graph, values)


def test_problem_classes_and_policies():
    """Only Lie groups -> "pose" (identity damping, lambda by factor 10, GTSAM's pair); Lie
    groups with vectors, not BA-shaped (navigation) -> "mixed" (identity damping, Nielsen's
    rule); many independent points (BA-shaped) or only vectors -> "scaled" (diagonal damping,
    Nielsen). Explicit damping / lambda_policy override the class."""
    auto = LMParams()
    pose = _pose_chain(10)
    mixed = _pose_chain(10, with_vectors=True)
    ba = _pose_chain(4, points=30)
    assert problem_class(pose) == "pose" and auto_policy("pose", auto) == (True, True)
    assert problem_class(mixed) == "mixed" and auto_policy("mixed", auto) == (True, False)
    assert problem_class(ba) == "scaled" and auto_policy("scaled", auto) == (False, False)
    graph, values = fgopt.FactorGraph(), fgopt.Variables()
    graph.add(fgopt.PriorFactor(key("c", 0), np.ones(9), Isotropic.sigma(9, 1.0)))
    values.add(key("c", 0), np.zeros(9))
    assert problem_class(fgopt.Problem(graph, values)) == "scaled"
    assert auto_policy("mixed", LMParams(damping="diagonal")) == (False, False)
    assert auto_policy("scaled", LMParams(damping="identity", lambda_policy="factor")) == \
        (True, True)


@pytest.mark.parametrize("with_vectors", [False, True])
def test_auto_converges_on_small_problems(with_vectors):
    """The auto parameters solve small pose-chain problems (with and without vector variables)
    to the exact optimum of this consistent graph (cost 0)."""
    g, v = fgopt.FactorGraph(), fgopt.Variables()
    g.add(fgopt.PriorFactor(key("x", 0), fgopt.SE3(), Isotropic.sigma(6, 0.1)))
    for i in range(6):
        v.add(key("x", i), fgopt.SE3.exp(0.1 * np.ones(6) * (i + 1)))
        if i:
            g.add(fgopt.BetweenFactor(key("x", i - 1), key("x", i), fgopt.SE3(None, [1, 0, 0]),
                                      Isotropic.sigma(6, 0.1)))
        if with_vectors:
            v.add(key("v", i), np.ones(3))
            g.add(fgopt.PriorFactor(key("v", i), np.zeros(3), Isotropic.sigma(3, 1.0)))
    r = fgopt.optimize(g, v)
    assert r.status == fgopt.Status.CONVERGED and r.final_cost < 1e-10
