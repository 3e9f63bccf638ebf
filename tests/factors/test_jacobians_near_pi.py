"""Jacobians of the camera and pose-point factors at rotation angles near pi.

The pinhole projection (generated), the BAL reprojection (generated and hand-written) and the
pose-to-point factors (hand-written, 2D and 3D) against central differences through each
variable's own retract, with the rotation angle at pi minus 1e-3 ... 1e-9, exactly pi and (BAL's
angle-axis, which a solver may push past pi) just above pi. Elsewhere these are checked at
random rotations and near 0.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fgopt.factors.library import reprojection as rp
from fgopt.factors.library.bal_kernel import bal_kernel
from fgopt.factors.library.pose_point import pose_point_kernel
from fgopt.key import key
from fgopt.manifolds import SE2, SE3
from tests.symbolic._helpers import assert_jacobian_matches_fd

NEAR_PI = [np.pi - 1e-3, np.pi - 1e-6, np.pi - 1e-9, np.pi]
SEEDS = range(3)


def se3_with_angle(angle: float, rng: np.random.Generator) -> SE3:
    """A pose whose rotation angle is ``angle`` about a random axis, random translation."""
    axis = rng.normal(size=3)
    R = Rotation.from_rotvec(angle * axis / np.linalg.norm(axis)).as_matrix()
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, rng.normal(size=3)
    return SE3.from_matrix(T)


def rotation_angle(pose: SE3) -> float:
    return float(np.linalg.norm(Rotation.from_matrix(pose.matrix()[:3, :3]).as_rotvec()))


def storage(pose: SE3, flip: bool) -> np.ndarray:
    """Storage row of ``pose``; ``flip``: with the other quaternion of the same rotation (near
    pi, w ~ 0 and a retract can land on either sign)."""
    s = pose.to_storage().copy()
    if flip:
        s[:4] = -s[:4]
    return s.reshape(1, -1)


@pytest.mark.parametrize("flip", [False, True], ids=["q", "-q"])
@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("angle", NEAR_PI)
def test_pinhole_projection_near_pi(angle, seed, flip):
    """Pinhole projection (Pose3 camera, point, Cal3_S2-like calibration): residual equals the
    pinhole model, Jacobians match central differences, with the camera rotated by ~pi (either
    quaternion sign)."""
    rng = np.random.default_rng(seed)
    f = rp.pinhole_projection(key("x", 0), key("l", 0), np.array([500.0, 510.0, 320.0, 240.0]),
                              np.array([300.0, 200.0]))
    pose = se3_with_angle(angle, rng)
    assert abs(rotation_angle(pose) - angle) < 1e-7
    pt = pose * (np.array([0.3, -0.2, 4.0]) + rng.normal(size=3) * 0.2)  # in front
    args = (storage(pose, flip), pt.reshape(1, 3))
    consts = f.constants.reshape(1, -1)
    pc = pose.inverse() * pt
    want = np.array([500 * pc[0] / pc[2] + 320, 510 * pc[1] / pc[2] + 240]) - [300, 200]
    np.testing.assert_allclose(f.kernel.residual(args, consts)[0], want, atol=1e-9)
    assert_jacobian_matches_fd(f.kernel, args, consts)


def bal_camera(angle: float, rng: np.random.Generator) -> np.ndarray:
    """BAL camera ``[r, t, f, k1, k2]`` with angle-axis ``|r| = angle``, points at z ~ -5."""
    axis = rng.normal(size=3)
    r = angle * axis / np.linalg.norm(axis)
    t = rng.normal(size=3) * 0.2
    return np.concatenate([r, t, [500.0 + rng.normal() * 10, -3e-7, 2e-13]])


def bal_point(cam: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A world point the camera sees (camera z = -5 +- noise: BAL cameras look down -z)."""
    P = np.array([0.3, -0.2, -5.0]) + rng.normal(size=3) * 0.3
    return Rotation.from_rotvec(cam[:3]).inv().apply(P - cam[3:6])


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("angle", NEAR_PI + [np.pi + 1e-6, np.pi + 1e-3])
def test_bal_reprojection_near_pi(angle, seed):
    """BAL reprojection (angle-axis camera): the generated and the hand-written kernels match the
    BAL model and central differences for ``|r|`` around pi, and agree with each other."""
    rng = np.random.default_rng(seed)
    cam = bal_camera(angle, rng)
    pt = bal_point(cam, rng)
    f = rp.bal_reprojection(key("c", 0), key("p", 0), np.array([10.0, -20.0]))
    args, consts = (cam.reshape(1, 9), pt.reshape(1, 3)), f.constants.reshape(1, -1)
    P = Rotation.from_rotvec(cam[:3]).apply(pt) + cam[3:6]
    p = -P[:2] / P[2]
    r2 = p @ p
    want = cam[6] * (1 + cam[7] * r2 + cam[8] * r2 * r2) * p - consts[0]
    for kernel in (f.kernel, bal_kernel()):
        np.testing.assert_allclose(kernel.residual(args, consts)[0], want, rtol=1e-12, atol=1e-9)
        assert_jacobian_matches_fd(kernel, args, consts)
    (r_g, j_g), (r_h, j_h) = f.kernel.linearize(args, consts), bal_kernel().linearize(args, consts)
    np.testing.assert_allclose(j_g, j_h, rtol=1e-7, atol=1e-7 * np.abs(j_h).max())


@pytest.mark.parametrize("flip", [False, True], ids=["q", "-q"])
@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("angle", NEAR_PI)
def test_pose_point_3d_near_pi(angle, seed, flip):
    """SE3 pose-to-point (g2o EDGE_SE3_TRACKXYZ) with the pose rotated by ~pi (either
    quaternion sign)."""
    rng = np.random.default_rng(seed)
    pose = se3_with_angle(angle, rng)
    pt = rng.normal(size=3) * 3
    args = (storage(pose, flip), pt.reshape(1, 3))
    m = rng.normal(size=(1, 3))
    kernel = pose_point_kernel(3)
    np.testing.assert_allclose(kernel.residual(args, m)[0], pose.inverse() * pt - m[0],
                               atol=1e-12)
    assert_jacobian_matches_fd(kernel, args, m)


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("theta", [s * a for a in NEAR_PI for s in (1.0, -1.0)])
def test_pose_point_2d_near_pi(theta, seed):
    """SE2 pose-to-point (g2o EDGE_SE2_XY) with heading ~ +-pi (where theta wraps)."""
    rng = np.random.default_rng(seed)
    x, y = rng.normal(size=2)
    pose = SE2.from_xytheta(x, y, theta)
    pt = rng.normal(size=2) * 3
    args = (np.array([pose.to_storage()]), pt.reshape(1, 2))
    m = rng.normal(size=(1, 2))
    kernel = pose_point_kernel(2)
    c, s = np.cos(theta), np.sin(theta)
    d = pt - [x, y]
    np.testing.assert_allclose(kernel.residual(args, m)[0],
                               [c * d[0] + s * d[1], -s * d[0] + c * d[1]] - m[0], atol=1e-12)
    assert_jacobian_matches_fd(kernel, args, m)
