"""GTSAM's Pose2ISAM2Example written with fgopt: a robot drives a 2 m square with noisy odometry
(seeded), a loop closure is detected by comparing the odometry's prediction with the earlier
poses, iSAM2-class incremental smoothing (relinearize threshold 0.1, skip 1) adds one pose at a
time. Prints the final poses (x, y, theta) and their marginal covariances in GTSAM's Pose2
tangent order (x, y, theta)."""

import math

import numpy as np

import fgopt
from fgopt import SE2, BetweenFactor, IncrementalParams, IncrementalSmoother, PriorFactor, key
from fgopt.noise import Diagonal

SEED = 5
PRIOR_SIGMAS = np.array([0.3, 0.3, math.radians(5)])      # x, y (m), theta (rad)
ODOMETRY_SIGMAS = np.array([0.2, 0.2, math.radians(5)])
TRUE_ODOMETRY = [(2, 0, 0)] + [(2, 0, math.pi / 2)] * 4
GTSAM_ORDER = [1, 2, 0]  # fgopt's SE2 tangent is (theta, x, y); GTSAM's Pose2 (x, y, theta)


def sigmas(xy_theta):
    """Sigmas in fgopt's SE2 tangent order (theta, x, y)."""
    return Diagonal.sigmas([xy_theta[2], xy_theta[0], xy_theta[1]])


def loop_closure(odometry, estimate, i, xy_tol=0.8, theta_tol=25.0):
    """The earlier pose (1..i) the odometry from pose i + 1 lands on, if any (the example's
    brute-force test: x, y within ``xy_tol`` m, theta within ``theta_tol`` degrees)."""
    last = estimate.at(key("x", i + 1))
    xy = last.translation() + last.rotation().matrix() @ odometry[:2]
    theta = last.theta() + odometry[2]
    for k in range(1, i + 1):
        pose = estimate.at(key("x", k))
        if (np.all(np.abs(pose.translation() - xy) <= xy_tol)
                and abs(pose.theta() - theta) <= math.radians(theta_tol)):
            return k
    return None


def run():
    rng = np.random.default_rng(SEED)
    odometry = [np.array(o, float) + ODOMETRY_SIGMAS * rng.standard_normal(3)
                for o in TRUE_ODOMETRY]
    isam = IncrementalSmoother(IncrementalParams(relinearize_threshold=0.1, relinearize_skip=1))
    factors = [PriorFactor(key("x", 1), SE2.from_xytheta(0, 0, 0), sigmas(PRIOR_SIGMAS))]
    values = {key("x", 1): SE2.from_xytheta(0.5, 0.0, 0.2)}
    estimate = fgopt.Variables()
    estimate.add(key("x", 1), values[key("x", 1)])
    for i, odom in enumerate(odometry):
        step = SE2.from_xytheta(*odom)
        closes = loop_closure(odom, estimate, i)
        if closes is not None:
            factors.append(BetweenFactor(key("x", i + 1), key("x", closes), step,
                                         sigmas(ODOMETRY_SIGMAS)))
        else:
            factors.append(BetweenFactor(key("x", i + 1), key("x", i + 2), step,
                                         sigmas(ODOMETRY_SIGMAS)))
            values[key("x", i + 2)] = estimate.at(key("x", i + 1)) * step
        isam.update(factors, values)
        estimate = isam.estimate()
        factors, values = [], {}
    covariances = fgopt.marginals(None, graph=isam.factors(), values=estimate)
    answer = {}
    for k in sorted(estimate.keys()):
        pose = estimate.at(k)
        answer[f"x{k.index}"] = np.array([pose.x(), pose.y(), pose.theta()])
        answer[f"x{k.index} covariance"] = covariances[k][np.ix_(GTSAM_ORDER, GTSAM_ORDER)]
    return answer


if __name__ == "__main__":
    np.set_printoptions(precision=6, suppress=True)
    for name, value in run().items():
        print(f"{name}: {np.round(value, 6) + 0.0}")  # + 0.0: no "-0."
