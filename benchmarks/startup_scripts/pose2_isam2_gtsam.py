"""GTSAM's Pose2ISAM2Example without plots, seeded, each update given only the new factors (the
example passes its whole, growing graph to every update, adding every factor again): the
reference for ``pose2_isam2_fgopt.py``. Prints the final poses (x, y, theta) and their
marginal covariances."""

import math

import gtsam
import numpy as np
from gtsam.symbol_shorthand import X

SEED = 5
PRIOR_SIGMAS = np.array([0.3, 0.3, math.radians(5)])
ODOMETRY_SIGMAS = np.array([0.2, 0.2, math.radians(5)])
TRUE_ODOMETRY = [(2, 0, 0)] + [(2, 0, math.pi / 2)] * 4


def loop_closure(odometry, estimate, i, xy_tol=0.8, theta_tol=25.0):
    """The earlier pose (1..i) the odometry from pose i + 1 lands on, if any."""
    last = estimate.atPose2(X(i + 1))
    xy = np.array([last.x(), last.y()]) + last.rotation().matrix() @ odometry[:2]
    theta = last.theta() + odometry[2]
    for k in range(1, i + 1):
        pose = estimate.atPose2(X(k))
        if (np.all(np.abs(np.array([pose.x(), pose.y()]) - xy) <= xy_tol)
                and abs(pose.theta() - theta) <= math.radians(theta_tol)):
            return k
    return None


def run():
    rng = np.random.default_rng(SEED)
    odometry = [np.array(o, float) + ODOMETRY_SIGMAS * rng.standard_normal(3)
                for o in TRUE_ODOMETRY]
    params = gtsam.ISAM2Params()
    params.setRelinearizeThreshold(0.1)
    params.relinearizeSkip = 1
    isam = gtsam.ISAM2(params)
    odometry_noise = gtsam.noiseModel.Diagonal.Sigmas(ODOMETRY_SIGMAS)
    graph, everything, values = gtsam.NonlinearFactorGraph(), gtsam.NonlinearFactorGraph(), \
        gtsam.Values()
    graph.push_back(gtsam.PriorFactorPose2(X(1), gtsam.Pose2(0, 0, 0),
                                           gtsam.noiseModel.Diagonal.Sigmas(PRIOR_SIGMAS)))
    values.insert(X(1), gtsam.Pose2(0.5, 0.0, 0.2))
    estimate = gtsam.Values(values)
    for i, odom in enumerate(odometry):
        step = gtsam.Pose2(*odom)
        closes = loop_closure(odom, estimate, i)
        if closes is not None:
            graph.push_back(gtsam.BetweenFactorPose2(X(i + 1), X(closes), step, odometry_noise))
        else:
            graph.push_back(gtsam.BetweenFactorPose2(X(i + 1), X(i + 2), step, odometry_noise))
            values.insert(X(i + 2), estimate.atPose2(X(i + 1)).compose(step))
        isam.update(graph, values)
        everything.push_back(graph)
        estimate = isam.calculateEstimate()
        graph.resize(0)
        values.clear()
    marginals = gtsam.Marginals(everything, estimate)
    answer = {}
    for k in sorted(estimate.keys()):
        pose = estimate.atPose2(k)
        index = gtsam.Symbol(k).index()
        answer[f"x{index}"] = np.array([pose.x(), pose.y(), pose.theta()])
        answer[f"x{index} covariance"] = marginals.marginalCovariance(k)
    return answer


if __name__ == "__main__":
    np.set_printoptions(precision=6, suppress=True)
    for name, value in run().items():
        print(f"{name}: {np.round(value, 6) + 0.0}")  # + 0.0: no "-0."
