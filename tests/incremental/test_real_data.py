"""Real data: the first 1000 poses of M3500 played one pose at a time (loop closures with their
later pose, new poses from the current estimate and the odometry), default parameters. The
final cost is within 1 % of the batch optimum and no higher than GTSAM ISAM2's on the same
stream (same relinearization threshold and skip)."""

import numpy as np
import pytest

import fgopt
from fgopt import FactorGraph, IncrementalSmoother, PriorFactor, key
from fgopt.manifolds import SE2
from fgopt.noise import Diagonal

N = 1000


def m3500_steps(path):
    graph, init = fgopt.io.read(path)
    steps: dict[int, list] = {}
    for b in graph.batches:
        for r in range(len(b)):
            i, j = (int(k) & ((1 << 56) - 1) for k in b.keys[r])
            if max(i, j) < N:
                steps.setdefault(max(i, j), []).append(b.factor(r))
    return init.at(key("x", 0)), [steps[p] for p in sorted(steps)]


def replay(x0, steps, read_all):
    """Play ``steps`` into a new smoother (a prior on the first pose, each new pose from the
    previous estimate and its odometry); ``read_all``: read the whole estimate after every
    update (the last read is returned) instead of the previous pose only."""
    prior = PriorFactor(key("x", 0), x0, Diagonal.sigmas([1e-3] * 3))
    isam = IncrementalSmoother()
    graph = FactorGraph([prior])
    est = None
    for n, fs in enumerate(steps, start=1):
        odo = next(f for f in fs if f.keys == (key("x", n - 1), key("x", n)))
        prev = x0 if n == 1 else (est.at(key("x", n - 1)) if read_all
                                  else isam.estimate(key("x", n - 1)))
        values = {key("x", n): prev * SE2.from_storage(odo.constants)}
        if n == 1:
            values[key("x", 0)] = x0
        isam.update(([prior] if n == 1 else []) + fs, values)
        graph.extend(fs)
        if read_all:
            est = isam.estimate()
    return isam, graph, est


def test_m3500_prefix_close_to_batch_and_gtsam(data_file):
    x0, steps = m3500_steps(data_file("pose2d/input_M3500_g2o.g2o"))
    isam, graph, _ = replay(x0, steps, read_all=False)
    est = isam.estimate()
    cost = graph.error(est)
    best = fgopt.optimize(graph, est, relative_tolerance=1e-12, absolute_tolerance=0.0).final_cost
    assert cost <= 1.01 * best

    gtsam = pytest.importorskip("gtsam")
    g_isam = gtsam.ISAM2(gtsam.ISAM2Params())
    to_pose = lambda f: gtsam.Pose2(*f.constants[2:4], np.arctan2(f.constants[1], f.constants[0]))  # noqa: E731
    for n, fs in enumerate(steps, start=1):
        g = gtsam.NonlinearFactorGraph()
        v = gtsam.Values()
        if n == 1:
            g.add(gtsam.PriorFactorPose2(key("x", 0), gtsam.Pose2(x0.x(), x0.y(), x0.theta()),
                                         gtsam.noiseModel.Diagonal.Sigmas(np.full(3, 1e-3))))
            v.insert(key("x", 0), gtsam.Pose2(x0.x(), x0.y(), x0.theta()))
        for f in fs:
            info = f.noise.information[np.ix_([1, 2, 0], [1, 2, 0])]
            g.add(gtsam.BetweenFactorPose2(f.keys[0], f.keys[1], to_pose(f),
                                           gtsam.noiseModel.Gaussian.Information(info)))
        odo = next(f for f in fs if f.keys == (key("x", n - 1), key("x", n)))
        prev = v.atPose2(key("x", 0)) if n == 1 else g_isam.calculateEstimatePose2(key("x", n - 1))
        v.insert(key("x", n), prev.compose(to_pose(odo)))
        g_isam.update(g, v)
    ge = g_isam.calculateEstimate()
    g_values = fgopt.Variables({k: SE2.from_xytheta(ge.atPose2(k).x(), ge.atPose2(k).y(),
                                                     ge.atPose2(k).theta()) for k in ge.keys()})
    assert cost <= graph.error(g_values) * (1 + 1e-9)


def test_m3500_full_estimate_after_every_update(data_file):
    """M3500's first 300 poses, the whole estimate read after every update (GTSAM's
    VisualISAM2Example pattern): the last read equals the exact Gauss-Newton step at the
    smoother's linearization point to 1e-7 (a sparse solve of the batch system; the reads
    re-solve only subtrees whose separator moved by > 1e-9), and its cost is no higher than that
    of GTSAM ISAM2's ``calculateEstimate`` read the same way."""
    import scipy.sparse.linalg as sla

    from fgopt.problem import Problem

    x0, steps = m3500_steps(data_file("pose2d/input_M3500_g2o.g2o"))
    steps = steps[:299]
    isam, graph, est = replay(x0, steps, read_all=True)
    p = Problem(graph, isam.linearization_point())
    st = p.initial_state()
    p.linearize(st)
    exact = p.values(p.retract(st, sla.spsolve(p.pattern.full(p.H_data).tocsc(), -p.g)))
    worst = max(float(np.abs(est.at(k).local(exact.at(k))).max()) for k in exact.keys())
    assert len(est) == 300 and worst < 1e-7

    gtsam = pytest.importorskip("gtsam")
    g_isam = gtsam.ISAM2(gtsam.ISAM2Params())
    to_pose = lambda f: gtsam.Pose2(*f.constants[2:4], np.arctan2(f.constants[1], f.constants[0]))  # noqa: E731
    x0g = gtsam.Pose2(x0.x(), x0.y(), x0.theta())
    ge = None
    for n, fs in enumerate(steps, start=1):
        g = gtsam.NonlinearFactorGraph()
        v = gtsam.Values()
        if n == 1:
            g.add(gtsam.PriorFactorPose2(key("x", 0), x0g,
                                         gtsam.noiseModel.Diagonal.Sigmas(np.full(3, 1e-3))))
            v.insert(key("x", 0), x0g)
        for f in fs:
            info = f.noise.information[np.ix_([1, 2, 0], [1, 2, 0])]
            g.add(gtsam.BetweenFactorPose2(f.keys[0], f.keys[1], to_pose(f),
                                           gtsam.noiseModel.Gaussian.Information(info)))
        odo = next(f for f in fs if f.keys == (key("x", n - 1), key("x", n)))
        prev = x0g if n == 1 else ge.atPose2(key("x", n - 1))  # the last read
        v.insert(key("x", n), prev.compose(to_pose(odo)))
        g_isam.update(g, v)
        ge = g_isam.calculateEstimate()
    g_values = fgopt.Variables({k: SE2.from_xytheta(ge.atPose2(k).x(), ge.atPose2(k).y(),
                                                     ge.atPose2(k).theta()) for k in ge.keys()})
    assert graph.error(est) <= graph.error(g_values) * (1 + 1e-6)
