"""Random small online problems shared by the incremental tests (pose chains with loop
closures in 2D and 3D), and a dense batch Gauss-Newton step to compare against."""

from __future__ import annotations

import numpy as np

import fgopt
from fgopt import BetweenFactor, FactorGraph, PriorFactor, key
from fgopt.manifolds import SE3
from fgopt.noise import Diagonal
from fgopt.problem import Problem


def x(i: int):
    return key("x", i)


def pose_stream(group, n: int, seed: int, loop_prob: float = 0.3, noise: float = 0.02,
                init_noise: float = 0.2):
    """Steps ``(factors, {key: initial value})`` of a random pose graph, one pose per step.

    Every pose has odometry from the previous one; with probability ``loop_prob`` a loop
    closure to a random older pose arrives with it. Initial values are the true pose perturbed
    by ``init_noise`` (tangent, per component), independent of any estimate.
    """
    rng = np.random.default_rng(seed)
    d = 6 if group is SE3 else 3
    sig = Diagonal.sigmas(np.full(d, 0.05))
    truth = [group.identity()]
    for _ in range(1, n):
        truth.append(truth[-1] * group.exp(rng.normal(0, 0.4, d)))

    def meas(a, b):
        return (truth[a].inverse() * truth[b]) * group.exp(rng.normal(0, noise, d))

    steps = [([PriorFactor(x(0), truth[0], sig)], {x(0): truth[0]})]
    for i in range(1, n):
        fs = [BetweenFactor(x(i - 1), x(i), meas(i - 1, i), sig)]
        if i >= 3 and rng.random() < loop_prob:
            j = int(rng.integers(0, i - 1))
            fs.append(BetweenFactor(x(j), x(i), meas(j, i), sig))
        steps.append((fs, {x(i): truth[i] * group.exp(rng.normal(0, init_noise, d))}))
    return steps


def gauss_newton_step(graph: FactorGraph, values: fgopt.Variables) -> fgopt.Variables:
    """One dense Gauss-Newton step of the batch problem from ``values``."""
    p = Problem(graph, values)
    st = p.initial_state()
    p.linearize(st)
    H = p.pattern.full(p.H_data).toarray()
    return p.values(p.retract(st, np.linalg.solve(H, -p.g)))


def max_tangent_difference(a: fgopt.Variables, b: fgopt.Variables) -> float:
    assert set(a.keys()) == set(b.keys())
    worst = 0.0
    for k in a.keys():
        va, vb = a.at(k), b.at(k)
        d = va.local(vb) if hasattr(va, "local") else np.asarray(vb) - np.asarray(va)
        worst = max(worst, float(np.abs(d).max()))
    return worst
