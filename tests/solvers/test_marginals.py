"""Marginal covariances equal the blocks of H^-1 and match GTSAM's Marginals to 1e-6."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

import fgopt
from fgopt import BetweenFactor, FactorGraph, PriorFactor, Variables, key
from fgopt.errors import NotPositiveDefiniteError
from fgopt.manifolds import SE2, SE3, SO3
from fgopt.noise import Diagonal

_spec = importlib.util.spec_from_file_location(
    "minisam_loop_case", Path(__file__).with_name("test_minisam_loop.py"))
_case = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_case)


def test_marginals_are_blocks_of_inverse_hessian():
    g, v = _case.minisam_loop()
    r = fgopt.optimize(g, v)
    cov = fgopt.marginals(r, [key("x", 1), key("x", 3)])
    problem = r.problem
    problem.linearize(r.state)
    Hinv = np.linalg.inv(problem.pattern.full(problem.H_data).toarray())
    for k in (key("x", 1), key("x", 3)):
        vi = problem._var_of_key[k]
        o = problem.pattern.var_offset[vi]
        assert np.allclose(cov[k], Hinv[o:o + 3, o:o + 3], rtol=1e-9, atol=1e-12)
        assert np.all(np.linalg.eigvalsh(cov[k]) > 0)
    # the prior's covariance bounds the first pose's marginal
    assert cov[key("x", 1)][0, 0] <= 0.1 ** 2 + 1e-12


def test_gauge_free_graph_is_reported():
    g = FactorGraph([BetweenFactor(key("x", 0), key("x", 1), SE2.from_xytheta(1, 0, 0))])
    v = Variables().add(key("x", 0), SE2.identity()).add(key("x", 1), SE2.from_xytheta(1, 0, 0))
    with pytest.raises(NotPositiveDefiniteError, match="prior"):
        fgopt.marginals(None, graph=g, values=v)


def test_no_keys_gives_no_marginals():
    """An empty key list is an empty answer (it raised NumPy's "need at least one array")."""
    g, v = _case.minisam_loop()
    assert fgopt.marginals(fgopt.optimize(g, v), []) == {}


def test_matches_gtsam_pose2():
    gtsam = pytest.importorskip("gtsam", reason="gtsam (the [test] extra) is not installed")
    g, v = _case.minisam_loop()
    r = fgopt.optimize(g, v)
    gg = gtsam.NonlinearFactorGraph()
    vals = gtsam.Values()
    to_g = [1, 2, 0]    # GTSAM Pose2 tangent (x, y, theta) from fgopt's (theta, x, y)
    from_g = [2, 0, 1]  # and back
    for f in g:
        R = f.noise.sqrt_information[np.ix_(to_g, to_g)]
        model = gtsam.noiseModel.Gaussian.SqrtInformation(R)
        if len(f.keys) == 1:
            m = f.prior
            gg.add(gtsam.PriorFactorPose2(int(f.keys[0]), gtsam.Pose2(m.x(), m.y(), m.theta()), model))
        else:
            m = f.measured
            gg.add(gtsam.BetweenFactorPose2(int(f.keys[0]), int(f.keys[1]),
                                            gtsam.Pose2(m.x(), m.y(), m.theta()), model))
    for k in r.values.keys():
        p = r.values.at(k)
        vals.insert(int(k), gtsam.Pose2(p.x(), p.y(), p.theta()))
    gm = gtsam.Marginals(gg, vals)
    ours = fgopt.marginals(r)
    for k in r.values.keys():
        theirs = gm.marginalCovariance(int(k))[np.ix_(from_g, from_g)]
        assert np.allclose(ours[k], theirs, rtol=1e-6, atol=1e-10), k


def test_matches_gtsam_pose3():
    gtsam = pytest.importorskip("gtsam", reason="gtsam (the [test] extra) is not installed")
    rng = np.random.default_rng(3)
    sig = np.array([0.05, 0.05, 0.05, 0.2, 0.2, 0.2])
    g, v = FactorGraph(), Variables()
    poses = [SE3(SO3.exp(rng.normal(size=3) * 0.5), rng.normal(size=3)) for _ in range(5)]
    g.add(PriorFactor(key("x", 0), poses[0], Diagonal.sigmas(sig / 10)))
    for i in range(5):
        j = (i + 1) % 5
        g.add(BetweenFactor(key("x", i), key("x", j),
                            poses[i].between(poses[j]).retract(rng.normal(size=6) * 0.05),
                            Diagonal.sigmas(sig)))
    for i, p in enumerate(poses):
        v.add(key("x", i), p)
    r = fgopt.optimize(g, v)
    gg, vals = gtsam.NonlinearFactorGraph(), gtsam.Values()

    def to_gtsam(p):
        return gtsam.Pose3(p.matrix())

    for f in g:
        model = gtsam.noiseModel.Gaussian.SqrtInformation(f.noise.sqrt_information)
        if len(f.keys) == 1:
            gg.add(gtsam.PriorFactorPose3(int(f.keys[0]), to_gtsam(f.prior), model))
        else:
            gg.add(gtsam.BetweenFactorPose3(int(f.keys[0]), int(f.keys[1]),
                                            to_gtsam(f.measured), model))
    for k in r.values.keys():
        vals.insert(int(k), to_gtsam(r.values.at(k)))
    assert np.isclose(gg.error(vals), r.final_cost, rtol=1e-9)
    gm = gtsam.Marginals(gg, vals)
    ours = fgopt.marginals(r)
    for k in r.values.keys():
        assert np.allclose(ours[k], gm.marginalCovariance(int(k)), rtol=1e-6, atol=1e-12), k


@pytest.mark.parametrize("rel", ["small/w100.graph", "small/pose3example-grid.txt"])
def test_selected_inverse_marginals_equal_the_solves(data_file, rel):
    """Every marginal of a real graph from the selected inverse (``linear_solver="block"``, the
    default for many keys) equals the one from solves with the identity's columns (dense H),
    poses of every dimension included."""
    g, v = fgopt.io.read(data_file(rel))
    fgopt.io.add_gauge_prior(g, v)
    r = fgopt.optimize(g, v)
    by_blocks = fgopt.marginals(r, linear_solver="block")
    keys = list(by_blocks)[::max(1, len(by_blocks) // 40)]
    by_solves = fgopt.marginals(r, keys, linear_solver="dense")
    assert len(by_blocks) == len(r.values)
    for k in keys:
        scale = np.abs(by_solves[k]).max()
        assert np.allclose(by_blocks[k], by_solves[k], rtol=1e-7, atol=1e-9 * scale), k
        assert np.array_equal(by_blocks[k], by_blocks[k].T)
