"""GTSAM's side of ``custom_factor.py``: the same factor as a ``gtsam.CustomFactor`` (a Python
error function; Jacobians by central differences in the tangent space, as a user writes it
without a derivation step), the same graph, LM. Prints JSON."""

import json
import sys
import time

t_start = time.perf_counter()
import numpy as np  # noqa: E402

import gtsam  # noqa: E402
from gtsam.symbol_shorthand import L, X  # noqa: E402

t_import = time.perf_counter() - t_start


def numerical(error, values, keys, H):
    """Fill ``H`` with d error / d (retract of each key), central differences."""
    e0 = error(values)
    for n, k in enumerate(keys):
        x = values.atPose2(k) if values.exists(k) and kind[k] == "pose2" else None
        dim = {"pose2": 3, "pose3": 6, "point2": 2}[kind[k]]
        J = np.zeros((e0.size, dim))
        for c in range(dim):
            d = np.zeros(dim)
            d[c] = 1e-6
            vp, vm = gtsam.Values(values), gtsam.Values(values)
            for vv, s in ((vp, 1), (vm, -1)):
                if kind[k] == "pose2":
                    vv.update(k, values.atPose2(k).retract(s * d))
                elif kind[k] == "pose3":
                    vv.update(k, values.atPose3(k).retract(s * d))
                else:
                    vv.update(k, values.atPoint2(k) + s * d)
            J[:, c] = (error(vp) - error(vm)) / 2e-6
        H[n] = J
        del x
    return e0


kind = {}


def range_bearing(measured):
    def error(v, pose_key, lm_key):
        d = v.atPose2(pose_key).transformTo(v.atPoint2(lm_key))
        e = np.array([np.linalg.norm(d), np.arctan2(d[1], d[0])]) - measured
        e[1] = np.arctan2(np.sin(e[1]), np.cos(e[1]))
        return e

    def f(this, values, H):
        keys = this.keys()
        err = lambda v: error(v, keys[0], keys[1])  # noqa: E731
        return numerical(err, values, keys, H) if H is not None else err(values)

    return f


def pose3_between(measured):
    def f(this, values, H):
        keys = this.keys()
        err = lambda v: gtsam.Pose3.Logmap(  # noqa: E731
            measured.inverse().compose(v.atPose3(keys[0]).inverse().compose(v.atPose3(keys[1]))))
        return numerical(err, values, keys, H) if H is not None else err(values)

    return f


def main():
    which = sys.argv[1]
    t0 = time.perf_counter()
    graph, initial = gtsam.NonlinearFactorGraph(), gtsam.Values()
    if which == "range_bearing":
        noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.1, 0.1, 0.05]))
        graph.add(gtsam.PriorFactorPose2(X(1), gtsam.Pose2(0, 0, 0), noise))
        for i in range(1, 3):
            graph.add(gtsam.BetweenFactorPose2(X(i), X(i + 1), gtsam.Pose2(2, 0, 0), noise))
        landmarks = {1: np.array([2.0, 2.0]), 2: np.array([4.0, -2.0])}
        unit = gtsam.noiseModel.Unit.Create(2)
        for i in range(3):
            kind[X(i + 1)] = "pose2"
            for j, lm in landmarks.items():
                kind[L(j)] = "point2"
                d = lm - np.array([2.0 * i, 0.0])
                m = np.array([np.hypot(*d), np.arctan2(d[1], d[0])])
                graph.add(gtsam.CustomFactor(unit, [X(i + 1), L(j)], range_bearing(m)))
            initial.insert(X(i + 1), gtsam.Pose2(2.0 * i + 0.2, 0.1, 0.05))
        for j, lm in landmarks.items():
            initial.insert(L(j), lm + 0.3)
    else:
        def pose(yaw, x, y, z):
            return gtsam.Pose3(gtsam.Rot3.Yaw(yaw), np.array([x, y, z]))

        noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.05] * 3 + [0.2] * 3))
        graph.add(gtsam.PriorFactorPose3(X(1), pose(0, 0, 0, 0), noise))
        step = pose(np.pi / 2, 2, 0, 0.1)
        unit = gtsam.noiseModel.Unit.Create(6)
        pairs = [(i + 1, i + 2) for i in range(19)] + [(20, 17)]  # custom_factor.py's 20
        for a, b in pairs:
            graph.add(gtsam.CustomFactor(unit, [X(a), X(b)], pose3_between(step)))
        rng = np.random.default_rng(0)
        truth = pose(0, 0, 0, 0)
        for i in range(20):
            kind[X(i + 1)] = "pose3"
            initial.insert(X(i + 1), truth.compose(gtsam.Pose3(
                gtsam.Rot3.Expmap(0.1 * rng.standard_normal(3)), 0.2 * rng.standard_normal(3))))
            truth = truth.compose(step)
    result = gtsam.LevenbergMarquardtOptimizer(graph, initial,
                                               gtsam.LevenbergMarquardtParams()).optimize()
    print(json.dumps({"definition to result": time.perf_counter() - t0, "import": t_import,
                      "final cost": graph.error(result)}))


if __name__ == "__main__":
    main()
