"""GTSAM's ``VisualISAM2Example`` ported mechanically (``fgopt.cameras.ProjectionFactor`` with
``Cal3_S2(50, 50, 0, 50, 50)``): 8 cameras on a circle around a cube of 8 landmarks, 1 px
noise, priors on the first pose and landmark, frames added one at a time with the example's
iSAM2 parameters (threshold 0.01, skip 1) and one extra update per frame. Each frame's estimate
matches GTSAM ISAM2's on the same data, and the last one the truth."""

import numpy as np
import pytest

from fgopt import IncrementalParams, IncrementalSmoother, PriorFactor, key
from fgopt.cameras import Cal3_S2, ProjectionFactor
from fgopt.manifolds import SE3, SO3
from fgopt.noise import Diagonal, Isotropic

CAL = np.array([50.0, 50.0, 50.0, 50.0])     # fx fy cx cy
K = Cal3_S2(50.0, 50.0, 0.0, 50.0, 50.0)


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> SE3:
    """Camera pose at ``eye`` looking at ``target`` (z forward, x right, y down)."""
    z = np.asarray(target, float) - eye
    z /= np.linalg.norm(z)
    xc = np.cross(-np.asarray(up, float), z)
    xc /= np.linalg.norm(xc)
    return SE3(SO3.from_matrix(np.stack([xc, np.cross(z, xc), z], axis=1)), eye)


def scene():
    points = [np.array(p, float) for p in
              [(10, 10, 10), (-10, 10, 10), (-10, -10, 10), (10, -10, 10), (10, 10, -10),
               (-10, 10, -10), (-10, -10, -10), (10, -10, -10)]]
    poses = [look_at(np.array([40 * np.cos(t), 40 * np.sin(t), 10.0]), (0.0, 0.0, 0.0))
             for t in np.linspace(0, 2 * np.pi, 8, endpoint=False)]
    return points, poses


def pixel(pose: SE3, p: np.ndarray) -> np.ndarray:
    q = pose.inverse().act(p)
    return CAL[:2] * q[:2] / q[2] + CAL[2:]


def run_fgopt(points, poses):
    isam = IncrementalSmoother(IncrementalParams(relinearize_threshold=0.01, relinearize_skip=1))
    noise = Isotropic.sigma(2, 1.0)
    delta = SE3(SO3.from_rotvec([-0.1, 0.2, 0.25]), [0.05, -0.10, 0.20])
    factors, values, estimates = [], {}, []
    for i, pose in enumerate(poses):
        for j, p in enumerate(points):
            factors.append(ProjectionFactor(key("x", i), key("l", j), pixel(pose, p), noise, K))
        values[key("x", i)] = pose * delta
        if i == 0:
            factors.append(PriorFactor(key("x", 0), poses[0],
                                       Diagonal.sigmas([0.1, 0.1, 0.1, 0.3, 0.3, 0.3])))
            factors.append(PriorFactor(key("l", 0), points[0], Isotropic.sigma(3, 0.1)))
            for j, p in enumerate(points):
                values[key("l", j)] = p + np.array([-0.25, 0.20, 0.15])
            continue
        isam.update(factors, values)
        isam.update()
        estimates.append(isam.estimate())
        factors, values = [], {}
    return estimates


def run_gtsam(gtsam, points, poses):
    K = gtsam.Cal3_S2(50.0, 50.0, 0.0, 50.0, 50.0)
    p = gtsam.ISAM2Params()
    p.setRelinearizeThreshold(0.01)
    p.relinearizeSkip = 1
    isam = gtsam.ISAM2(p)
    g, v, out = gtsam.NonlinearFactorGraph(), gtsam.Values(), []
    noise = gtsam.noiseModel.Isotropic.Sigma(2, 1.0)
    to_g = lambda s: gtsam.Pose3(s.matrix())  # noqa: E731
    delta = gtsam.Pose3(gtsam.Rot3.Rodrigues(-0.1, 0.2, 0.25), gtsam.Point3(0.05, -0.10, 0.20))
    for i, pose in enumerate(poses):
        for j, pt in enumerate(points):
            g.push_back(gtsam.GenericProjectionFactorCal3_S2(
                pixel(pose, pt), noise, key("x", i), key("l", j), K))
        v.insert(key("x", i), to_g(pose).compose(delta))
        if i == 0:
            g.push_back(gtsam.PriorFactorPose3(key("x", 0), to_g(poses[0]),
                                               gtsam.noiseModel.Diagonal.Sigmas(
                                                   np.array([0.1, 0.1, 0.1, 0.3, 0.3, 0.3]))))
            g.push_back(gtsam.PriorFactorPoint3(key("l", 0), points[0],
                                                gtsam.noiseModel.Isotropic.Sigma(3, 0.1)))
            for j, pt in enumerate(points):
                v.insert(key("l", j), pt + np.array([-0.25, 0.20, 0.15]))
            continue
        isam.update(g, v)
        isam.update()
        out.append(isam.calculateEstimate())
        g.resize(0)
        v.clear()
    return out


def test_visual_isam2_example():
    points, poses = scene()
    ours = run_fgopt(points, poses)
    last = ours[-1]
    for i, pose in enumerate(poses):
        assert np.abs(last.at(key("x", i)).local(pose)).max() < 0.05
    for j, p in enumerate(points):
        assert np.abs(last.at(key("l", j)) - p).max() < 0.05
    gtsam = pytest.importorskip("gtsam")
    theirs = run_gtsam(gtsam, points, poses)
    for frame, (a, b) in enumerate(zip(ours, theirs), start=1):
        for i in range(frame + 1):
            m = b.atPose3(key("x", i)).matrix()
            assert np.abs(a.at(key("x", i)).local(SE3.from_matrix(m))).max() < 1e-6, (frame, i)
        for j in range(len(points)):
            assert np.abs(a.at(key("l", j)) - b.atPoint3(key("l", j))).max() < 1e-6, (frame, j)
