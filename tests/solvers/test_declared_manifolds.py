"""Declared manifolds (``@fgopt.manifold``) through the solvers: batched LM, the Python slow
path, marginals, GNC, pickling and plots."""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import fgopt
from fgopt import SO3, key
from fgopt.noise import Isotropic
from fgopt.solvers import GNCParams
from fgopt.symbolic import V2, V3, Rot3, SE23, Unit3

REPO = Path(__file__).resolve().parents[2]
U = Unit3.Value


@fgopt.factor
def direction_between(a: Unit3, b: Unit3, b_R_a: Rot3) -> V2:
    """Direction b against direction a rotated into b's frame (angle error, b's basis)."""
    return b.local(Unit3(b_R_a * a.point3()))


def rotation_between(a: np.ndarray, b: np.ndarray) -> SO3:
    """The smallest rotation taking unit vector a to unit vector b."""
    axis = np.cross(a, b)
    return SO3.from_axis_angle(axis / np.linalg.norm(axis), np.arctan2(np.linalg.norm(axis), a @ b))


def direction_graph(n: int, seed: int, outliers: int = 0, sigma: float = 0.01):
    """Directions linked to the next one and the one 5 further; a prior every 10; ``outliers``
    extra links with random rotations. Returns (graph, initial, truth, outlier factor ids)."""
    rng = np.random.default_rng(seed)
    truth = [U(rng.normal(size=3)) for _ in range(n)]
    graph, initial = fgopt.FactorGraph(), fgopt.Variables()
    noise = Isotropic.sigma(2, sigma)
    for i in range(n):
        for j in (i + 1, i + 5):
            if j < n:
                R = rotation_between(truth[i].to_storage(), truth[j].to_storage())
                R = R * SO3.exp(sigma * rng.normal(size=3))
                graph.add(direction_between(key("u", i), key("u", j), R, loss=noise))
    for i in range(0, n, 10):
        graph.add(fgopt.PriorFactor(key("u", i), truth[i], noise))
    bad = []
    for _ in range(outliers):
        i, j = rng.choice(n, 2, replace=False)
        bad.append(len(graph))
        graph.add(direction_between(key("u", int(i)), key("u", int(j)), SO3.random(rng),
                                    loss=noise))
    for i, t in enumerate(truth):
        initial.add(key("u", i), t.retract(0.2 * rng.normal(size=2)))
    return graph, initial, truth, bad


def max_angle(values, truth) -> float:
    return max(float(np.linalg.norm(t.local(values.at(key("u", i))))) for i, t in enumerate(truth))


class SlowUnit3:
    """The same manifold written as a plain Python class (the slow path)."""

    def __init__(self, p):
        p = np.asarray(p, dtype=float)
        self.p = p / np.linalg.norm(p)

    def dim(self):
        return 2

    def retract(self, v):
        return SlowUnit3(U(self.p).retract(v).to_storage())

    def local(self, other):
        return U(self.p).local(U(other.p))


class SlowDirection(fgopt.NumericalFactor):
    def __init__(self, a, b, R, loss):
        super().__init__([a, b], 2, loss)
        self.R = R.matrix()

    def error(self, values):
        a, b = values.at(self.keys[0]), values.at(self.keys[1])
        return U(b.p).local(U(self.R @ a.p))


class SlowPrior(fgopt.NumericalFactor):
    def __init__(self, k, m, loss):
        super().__init__([k], 2, loss)
        self.m = m

    def error(self, values):
        return U(self.m.p).local(U(values.at(self.keys[0]).p))


def test_batched_solve_matches_python_slow_path():
    """A Unit3 graph solves on the batched path (one batch per factor type, one storage array)
    to the truth, and the same graph on the Python slow path reaches the same cost."""
    graph, initial, truth, _ = direction_graph(40, seed=0)
    r = fgopt.optimize(graph, initial)
    assert r.success and max_angle(r.values, truth) < 0.05
    problem = r.problem
    assert len(problem.batches) == 2 and problem.kinds == [U.batch_kind()]
    assert problem._initial_storages[0].shape == (40, 3)
    slow_graph, slow_init = fgopt.FactorGraph(), fgopt.Variables()
    for f in graph:
        if f.kernel.name == "direction_between":
            R = SO3(f.constants)
            slow_graph.add(SlowDirection(f.keys[0], f.keys[1], R, f.loss))
        else:
            slow_graph.add(SlowPrior(f.keys[0], SlowUnit3(f.constants), f.loss))
    for k in initial.keys():
        slow_init.add(k, SlowUnit3(initial.at(k).to_storage()))
    s = fgopt.optimize(slow_graph, slow_init)
    assert s.success and np.isclose(s.final_cost, r.final_cost, rtol=1e-6)
    for k in initial.keys():
        assert np.allclose(s.values.at(k).p, r.values.at(k).to_storage(), atol=1e-6)
    assert initial.at(key("u", 3)).equals(initial.at(key("u", 3)))  # the caller's values kept


def test_marginals_in_the_tangent_space():
    """One prior with sigma on a Unit3: the marginal covariance is sigma^2 I (its Jacobian is
    the identity at the optimum); with two independent priors, sigma^2 / 2."""
    m = U([0.2, -0.3, 0.9])
    graph = fgopt.FactorGraph([fgopt.PriorFactor(key("u", 0), m, Isotropic.sigma(2, 0.1))])
    initial = fgopt.Variables({key("u", 0): m.retract([0.3, -0.2])})
    r = fgopt.optimize(graph, initial)
    assert r.values.at(key("u", 0)).equals(m, 1e-9)
    cov = fgopt.marginals(r, [key("u", 0)], linear_solver="dense")[key("u", 0)]
    np.testing.assert_allclose(cov, 0.01 * np.eye(2), atol=1e-10)
    graph.add(fgopt.PriorFactor(key("u", 0), m, Isotropic.sigma(2, 0.1)))
    r = fgopt.optimize(graph, initial)
    cov = fgopt.marginals(r, [key("u", 0)], linear_solver="dense")[key("u", 0)]
    np.testing.assert_allclose(cov, 0.005 * np.eye(2), atol=1e-10)


def test_gnc_rejects_wrong_directions():
    """GNC on a Unit3 graph with random wrong links flags them and recovers the truth, where
    plain LM is pulled off."""
    graph, initial, truth, bad = direction_graph(40, seed=1, outliers=4)
    plain = fgopt.optimize(graph, initial)
    r = fgopt.optimize(graph, initial, method="gnc", params=GNCParams(loss="tls"))
    assert r.success, r.message
    assert r.info["outliers"] == len(bad)
    assert max_angle(r.values, truth) < 0.05 < max_angle(plain.values, truth)


def test_pickling_values_and_variables():
    """Declared values pickle by their declaration: same storage back, in this process and in a
    new one (which imports the declaration from fgopt.symbolic.geometry)."""
    rng = np.random.default_rng(3)
    values = fgopt.Variables({key("u", 0): U(rng.normal(size=3)),
                              key("x", 0): SE23.Value().retract(rng.normal(size=9)),
                              key("p", 0): fgopt.OrientedPlane3([0.0, 0.6, 0.8, 2.0])})
    back = pickle.loads(pickle.dumps(values))
    assert back == values and type(back.at(key("x", 0))) is SE23.Value
    code = ("import pickle, sys; v = pickle.load(sys.stdin.buffer); "
            "print(type(v.at(%d)).__name__, v.at(%d).to_storage().round(6).tolist())"
            % (key("u", 0), key("u", 0)))
    env = dict(os.environ, PYTHONPATH=str(REPO))
    out = subprocess.run([sys.executable, "-c", code], input=pickle.dumps(values), cwd=REPO,
                         env=env, capture_output=True, timeout=300)
    assert out.returncode == 0, out.stderr.decode()[-2000:]
    assert out.stdout.decode().split(" ", 1) == [
        "Unit3", f"{values.at(key('u', 0)).to_storage().round(6).tolist()}\n"]


def test_plot_draws_se23_positions():
    """plot_pose_graph draws a trajectory of SE23 values at their positions (the declaration's
    position accessor)."""
    pytest.importorskip("matplotlib")
    from fgopt.plot import plot_pose_graph

    values = fgopt.Variables()
    for i in range(5):
        values.add(key("x", i), SE23.Value(np.r_[0, 0, 0, 1, 0, 0, 0, i, 2.0 * i, 1.0]))
    ax = plot_pose_graph(None, values)
    line = ax.get_lines()[0]
    xs, ys, zs = line.get_data_3d()
    np.testing.assert_allclose(xs, np.arange(5))
    np.testing.assert_allclose(ys, 2.0 * np.arange(5))


def test_se23_navigation_graph():
    """SE23 states with generated prior / between (a declared group) and a position factor
    (accessor in the body) solve to the truth."""
    @fgopt.factor
    def position_fix(x: SE23, measured: V3) -> V3:
        return x.position() - measured

    rng = np.random.default_rng(5)
    truth = [SE23.Value().retract(rng.normal(size=9))]
    for _ in range(9):
        truth.append(truth[-1].retract(0.3 * rng.normal(size=9)))
    graph, initial = fgopt.FactorGraph(), fgopt.Variables()
    graph.add(fgopt.PriorFactor(key("x", 0), truth[0], Isotropic.sigma(9, 0.01)))
    for i in range(9):
        m = SE23.Value().retract(truth[i].local(truth[i + 1]))
        graph.add(fgopt.BetweenFactor(key("x", i), key("x", i + 1), m, Isotropic.sigma(9, 0.01)))
    for i, t in enumerate(truth):
        graph.add(position_fix(key("x", i), t.position(), loss=Isotropic.sigma(3, 0.1)))
        initial.add(key("x", i), t.retract(0.1 * rng.normal(size=9)))
    r = fgopt.optimize(graph, initial)
    assert r.success and r.final_cost < 1e-12
    for i, t in enumerate(truth):
        assert r.values.at(key("x", i)).equals(t, 1e-6)
