"""PinholeCamera and StereoCamera: projection and Jacobians against GTSAM's cameras (1e-9) and
central differences in the pose's tangent space (rotations near 0 and pi), lookat, backproject,
cheirality errors."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from fgopt.cameras import Cal3_S2, Cal3_S2Stereo, Cal3Bundler, PinholeCamera, StereoCamera
from fgopt.errors import CheiralityError, FgoptError, NonFiniteError
from fgopt.manifolds import SE3


def _helpers():
    name = "fgopt_tests_camera_helpers"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, Path(__file__).with_name("_helpers.py"))
        sys.modules[name] = mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
    return sys.modules[name]


H = _helpers()
by_name = lambda c: c.__name__  # noqa: E731


def _close(a, b, tol=1e-9):
    np.testing.assert_allclose(a, b, rtol=1e-11, atol=tol)


MONOCULAR_GTSAM = tuple(m for m in H.GTSAM_MODELS if m is not Cal3_S2Stereo)


@pytest.mark.parametrize("cls", MONOCULAR_GTSAM, ids=by_name)
def test_project_equals_gtsam(cls):
    """project and its pose / point / calibration Jacobians equal GTSAM's PinholeCamera<Cal>
    at random poses (rotation angles 0 .. pi), calibrations and points (1e-9)."""
    pytest.importorskip("gtsam")
    rng = np.random.default_rng(21)
    for angle in H.ANGLES:
        pose = H.random_pose(rng, angle)
        K = cls(*H.random_params(cls, rng))
        cam, gcam = PinholeCamera(pose, K), H.gtsam_camera(pose, K)
        for _ in range(3):
            X = H.point_in_front(rng, pose)
            uv, Dpose, Dpoint, Dk = cam.project(X, jacobians=True)
            Hp, Hx, Hk = H.zeros_f(2, 6), H.zeros_f(2, 3), H.zeros_f(2, K.DIM)
            _close(uv, gcam.project(X, Hp, Hx, Hk))
            _close(Dpose, Hp)
            _close(Dpoint, Hx)
            _close(Dk, Hk)


@pytest.mark.parametrize("cls", H.MODELS, ids=by_name)
@pytest.mark.parametrize("angle", H.ANGLES)
def test_project_jacobians_equal_central_differences(cls, angle):
    """Every Jacobian of project equals central differences: the pose through SE3.retract
    (right perturbation, rotation first), the point and the calibration additively."""
    rng = np.random.default_rng(22)
    pose = H.random_pose(rng, angle)
    p = H.random_params(cls, rng)
    K = cls(*p)
    X = H.point_in_front(rng, pose)
    uv, Dpose, Dpoint, Dk = PinholeCamera(pose, K).project(X, jacobians=True)
    num_pose = H.central_diff(lambda d: PinholeCamera(pose.retract(d), K).project(X), np.zeros(6))
    num_point = H.central_diff(lambda x: PinholeCamera(pose, K).project(x), X)
    num_k = H.central_diff(lambda q: PinholeCamera(pose, K.retract(q - p[:K.DIM])).project(X),
                           p[:K.DIM])
    for J, N in ((Dpose, num_pose), (Dpoint, num_point), (Dk, num_k)):
        np.testing.assert_allclose(J, N, rtol=1e-6, atol=1e-6 * max(1.0, np.abs(J).max()))


def test_vectorized_projection_equals_one_point_at_a_time():
    """project on (n, 3) points gives the same pixels and Jacobians as n single calls."""
    rng = np.random.default_rng(23)
    pose = H.random_pose(rng)
    cam = PinholeCamera(pose, Cal3Bundler(*H.random_params(Cal3Bundler, rng)))
    X = np.array([H.point_in_front(rng, pose) for _ in range(7)])
    out = cam.project(X, jacobians=True)
    for i in range(7):
        for a, b in zip(out, cam.project(X[i], jacobians=True)):
            np.testing.assert_array_equal(a[i], b)


def test_lookat_equals_gtsam_and_rejects_degenerate_input():
    """lookat builds GTSAM's pose (z toward the target, y down) for SFMExample's cameras; a
    viewing direction parallel to up, or eye == target, is an FgoptError."""
    gtsam = pytest.importorskip("gtsam")
    K = Cal3_S2(50.0, 50.0, 0.0, 50.0, 50.0)
    for theta in np.linspace(0, 2 * np.pi, 8, endpoint=False):
        eye = np.array([40 * np.cos(theta), 40 * np.sin(theta), 10.0])
        cam = PinholeCamera.lookat(eye, np.zeros(3), np.array([0, 0, 1.0]), K)
        g = gtsam.PinholeCameraCal3_S2.Lookat(eye, np.zeros(3), np.array([0, 0, 1.0]),
                                             gtsam.Cal3_S2(50.0, 50.0, 0.0, 50.0, 50.0))
        _close(cam.pose().matrix(), g.pose().matrix(), 1e-12)
        np.testing.assert_allclose(cam.project(np.zeros(3)), [50.0, 50.0], atol=1e-9)
    with pytest.raises(FgoptError, match="parallel"):
        PinholeCamera.lookat([0, 0, 5], [0, 0, 0], [0, 0, 1], K)
    with pytest.raises(FgoptError, match="coincide"):
        PinholeCamera.lookat([1, 2, 3], [1, 2, 3], [0, 0, 1], K)


@pytest.mark.parametrize("cls", MONOCULAR_GTSAM, ids=by_name)
def test_backproject_inverts_project_and_equals_gtsam(cls):
    """backproject(project(X), depth(X)) = X, and equals GTSAM's PinholeCamera::backproject."""
    pytest.importorskip("gtsam")
    rng = np.random.default_rng(24)
    pose = H.random_pose(rng, 2.0)
    K = cls(*H.random_params(cls, rng))
    cam = PinholeCamera(pose, K)
    X = np.array([H.point_in_front(rng, pose) for _ in range(4)])
    depth = (pose.inverse() * X)[:, 2]
    uv = cam.project(X)
    np.testing.assert_allclose(cam.backproject(uv, depth), X, atol=1e-9)
    if cls is not Cal3Bundler:  # GTSAM's fixed-point calibrate may not converge off-centre
        g = H.gtsam_camera(pose, K)
        for i in range(4):
            np.testing.assert_allclose(cam.backproject(uv[i], depth[i]),
                                       g.backproject(uv[i], depth[i]), atol=1e-6)


def test_points_behind_the_camera_raise_cheirality_errors():
    """A point behind the camera raises CheiralityError naming its index and depth; a NaN point
    raises NonFiniteError."""
    cam = PinholeCamera(SE3(), Cal3_S2(500, 500, 0, 320, 240))
    pts = np.array([[0.0, 0.0, 2.0], [0.1, 0.0, 1.0], [0.0, 0.0, -3.0]])
    with pytest.raises(CheiralityError, match=r"point 2 .* behind the camera \(depth -3"):
        cam.project(pts)
    with pytest.raises(CheiralityError, match="point 0"):
        cam.project(np.array([1.0, 1.0, 0.0]))
    with pytest.raises(NonFiniteError, match="point 1"):
        cam.project(np.array([[0.0, 0.0, 1.0], [np.nan, 0.0, 1.0]]))


def test_stereo_equals_gtsam():
    """StereoCamera.project and its pose / point Jacobians equal GTSAM's StereoCamera.project2
    (1e-9), the calibration Jacobian equals central differences, and backproject equals
    GTSAM's and inverts project."""
    gtsam = pytest.importorskip("gtsam")
    rng = np.random.default_rng(25)
    for angle in H.ANGLES:
        pose = H.random_pose(rng, angle)
        p = H.random_params(Cal3_S2Stereo, rng)
        p[2] = 0.0  # GTSAM's stereo projection ignores skew; so does fgopt's (zero here anyway)
        K = Cal3_S2Stereo(*p)
        cam = StereoCamera(pose, K)
        g = gtsam.StereoCamera(H.gtsam_pose(pose), gtsam.Cal3_S2Stereo(*p))
        X = H.point_in_front(rng, pose)
        out, Dpose, Dpoint, Dk = cam.project(X, jacobians=True)
        Hp, Hx = H.zeros_f(3, 6), H.zeros_f(3, 3)
        _close(out, g.project2(X, Hp, Hx).vector())
        _close(Dpose, Hp)
        _close(Dpoint, Hx)
        num_k = H.central_diff(lambda q: StereoCamera(pose, Cal3_S2Stereo(*q)).project(X), p)
        np.testing.assert_allclose(Dk, num_k, rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(cam.backproject(out), X, atol=1e-9)
        _close(cam.backproject(out), g.backproject(gtsam.StereoPoint2(*out)), 1e-9)
    with pytest.raises(CheiralityError, match="behind"):
        cam.project(pose * np.array([0.0, 0.0, -1.0]))
    with pytest.raises(CheiralityError, match="disparity"):
        cam.backproject(np.array([100.0, 120.0, 50.0]))


def test_stereo_jacobians_near_pi_equal_central_differences():
    """Stereo pose / point Jacobians equal central differences at rotations near pi."""
    rng = np.random.default_rng(26)
    K = Cal3_S2Stereo(721.5, 721.5, 0.0, 609.6, 172.9, 0.537)
    for angle in (math.pi - 1e-4, math.pi):
        pose = H.random_pose(rng, angle)
        X = H.point_in_front(rng, pose)
        _, Dpose, Dpoint, _ = StereoCamera(pose, K).project(X, jacobians=True)
        num = H.central_diff(lambda d: StereoCamera(pose.retract(d), K).project(X), np.zeros(6))
        np.testing.assert_allclose(Dpose, num, rtol=1e-6, atol=1e-5)
        num = H.central_diff(lambda x: StereoCamera(pose, K).project(x), X)
        np.testing.assert_allclose(Dpoint, num, rtol=1e-6, atol=1e-5)


@pytest.mark.parametrize("cls", H.MODELS, ids=by_name)
def test_pinhole_camera_is_a_manifold(cls):
    """PinholeCamera is GTSAM's camera manifold: retract = (pose Exp(d[:6]), K + d[6:]), local
    inverts it, its batch kind's retract / local / storage agree with the value's, and
    Variables / optimize accept it."""
    from fgopt import Variables, key
    from fgopt.manifolds import ops_for

    rng = np.random.default_rng(27)
    cam = PinholeCamera(H.random_pose(rng, 2.0), cls(*H.random_params(cls, rng)))
    d = rng.normal(size=cam.dim()) * 1e-2
    moved = cam.retract(d)
    np.testing.assert_allclose(moved.pose().matrix(), cam.pose().retract(d[:6]).matrix())
    np.testing.assert_allclose(cam.local(moved), d, atol=1e-12)
    kind = ops_for(cam).batch_kind(cam)
    assert kind is PinholeCamera.batch_kind_of(cls) and kind.dim == 6 + cls.DIM
    rows = kind.retract(cam.to_storage()[None], d[None])
    np.testing.assert_allclose(kind.from_storage(rows[0]).pose().matrix(), moved.pose().matrix(),
                               atol=1e-12)
    np.testing.assert_allclose(kind.local(cam.to_storage()[None], rows)[0], d, atol=1e-12)
    v = Variables()
    v.add(key("c", 0), cam)
    assert v.at(key("c", 0)) is cam
