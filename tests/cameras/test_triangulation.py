"""triangulate: the DLT equals GTSAM's triangulatePoint3, the nonlinear refinement reaches the
reprojection-error minimum (at or below GTSAM's optimize=true result), rank / cheirality /
view-count errors."""

from __future__ import annotations

import numpy as np
import pytest

from fgopt.cameras import (Cal3_S2, Cal3Bundler, Cal3DS2, Cal3Fisheye, DoubleSphere,
                           PinholeCamera, triangulate)
from fgopt.errors import CheiralityError, DimensionMismatchError, NonFiniteError, TriangulationError
from fgopt.manifolds import SE3


def _views(rng, K, X, m=4, noise=0.5):
    cams = [PinholeCamera.lookat(rng.normal(size=3) * 2, X + rng.normal(size=3) * 0.3,
                                 [0, -1, 0], K) for _ in range(m)]
    z = np.array([c.project(X) for c in cams]) + rng.normal(size=(m, 2)) * noise
    return cams, z


def _cost(cams, z, X):
    return 0.5 * sum(float(((c.project(X) - zz) ** 2).sum()) for c, zz in zip(cams, z))


def _gtsam_calibration(K):
    import gtsam

    p = K.to_storage()
    if isinstance(K, Cal3Fisheye):
        return gtsam.Cal3Fisheye(*p, 1e-11)  # GTSAM's undistortion to 1e-11 px
    if isinstance(K, Cal3Bundler):
        return gtsam.Cal3Bundler(*p, 1e-11)
    return getattr(gtsam, type(K).__name__)(*p)


CASES = [Cal3_S2(500, 510, 0.3, 320, 240),
         Cal3Fisheye(500, 510, 0.3, 320, 240, 0.05, -0.01, 0.002, 0.001),
         Cal3Bundler(480, 0.01, -0.002, 300, 200)]


@pytest.mark.parametrize("K", CASES, ids=lambda K: type(K).__name__)
def test_dlt_equals_gtsam_triangulate_point3(K):
    """method='dlt' equals gtsam.triangulatePoint3(optimize=False) to 1e-9 on noisy pixels
    (GTSAM's calibrations built with a 1e-11 px undistortion tolerance)."""
    gtsam = pytest.importorskip("gtsam")
    rng = np.random.default_rng(41)
    for _ in range(4):
        X = np.array([0.3, -0.2, 8.0]) + rng.normal(size=3)
        cams, z = _views(rng, K, X, noise=0.5 if isinstance(K, Cal3_S2) else 0.05)
        poses = [gtsam.Pose3(c.pose().matrix()) for c in cams]
        ref = gtsam.triangulatePoint3(poses, _gtsam_calibration(K), z, 1e-9, False, None, False)
        np.testing.assert_allclose(triangulate(cams, z), ref, atol=1e-9)


def test_dlt_with_gtsam_default_tolerance_agrees_to_it():
    """Cal3DS2 (GTSAM undistorts to its fixed 1e-5 px): the DLT points agree to 1e-6."""
    gtsam = pytest.importorskip("gtsam")
    rng = np.random.default_rng(42)
    K = Cal3DS2(500, 510, 0.3, 320, 240, 0.1, -0.05, 0.001, 0.002)
    X = np.array([0.3, -0.2, 8.0])
    cams, z = _views(rng, K, X)
    ref = gtsam.triangulatePoint3([gtsam.Pose3(c.pose().matrix()) for c in cams],
                                  gtsam.Cal3DS2(*K.to_storage()), z, 1e-9, False, None, False)
    np.testing.assert_allclose(triangulate(cams, z), ref, atol=1e-6)


@pytest.mark.parametrize("K", CASES + [DoubleSphere(300, 310, 320, 240, -0.1, 0.55)],
                         ids=lambda K: type(K).__name__)
def test_nonlinear_reaches_the_reprojection_minimum(K):
    """method='nonlinear' has a zero reprojection gradient (central differences), a cost no
    higher than the DLT's and GTSAM's optimize=True result, and agrees with GTSAM's to 1e-5
    (GTSAM stops when the error decreases by less than 1.0)."""
    gtsam = pytest.importorskip("gtsam")
    rng = np.random.default_rng(43)
    X = np.array([0.3, -0.2, 8.0])
    cams, z = _views(rng, K, X, m=5)
    ours = triangulate(cams, z, method="nonlinear")
    grad = [(_cost(cams, z, ours + e) - _cost(cams, z, ours - e)) / 2e-6
            for e in np.eye(3) * 1e-6]
    assert np.abs(grad).max() < 1e-4
    assert _cost(cams, z, ours) <= _cost(cams, z, triangulate(cams, z)) + 1e-12
    if not isinstance(K, DoubleSphere):
        ref = gtsam.triangulatePoint3([gtsam.Pose3(c.pose().matrix()) for c in cams],
                                      _gtsam_calibration(K), z, 1e-9, True, None, False)
        assert _cost(cams, z, ours) <= _cost(cams, z, ref) + 1e-9
        np.testing.assert_allclose(ours, ref, atol=1e-5)


def test_exact_pixels_give_the_point_back():
    """Noise-free pixels: both methods return the true point (1e-9)."""
    rng = np.random.default_rng(44)
    K = Cal3DS2(500, 510, 0.0, 320, 240, 0.1, -0.05, 0.001, 0.002)
    X = np.array([1.0, 2.0, 9.0])
    cams, z = _views(rng, K, X, m=3, noise=0.0)
    for method in ("dlt", "nonlinear"):
        np.testing.assert_allclose(triangulate(cams, z, method=method), X, atol=1e-9)


def test_bad_tracks_raise():
    """One view, coincident cameras (rank 2), a point behind the cameras, NaN pixels and
    mismatched shapes raise TriangulationError / CheiralityError / NonFiniteError /
    DimensionMismatchError with the reason."""
    K = Cal3_S2(500, 500, 0, 320, 240)
    cam = PinholeCamera(SE3(), K)
    with pytest.raises(TriangulationError, match="at least two views"):
        triangulate([cam], [[320.0, 240.0]])
    with pytest.raises(TriangulationError, match="rank"):
        triangulate([cam, cam], [[330.0, 250.0], [330.0, 250.0]])
    left, right = PinholeCamera(SE3(None, [-1, 0, 0]), K), PinholeCamera(SE3(None, [1, 0, 0]), K)
    behind = np.array([0.0, 0.0, -5.0])  # pixels of a point behind both cameras (u = fx x/z)
    z = np.array([[320 + 500 * 1.0 / -5.0, 240.0], [320 + 500 * -1.0 / -5.0, 240.0]])
    with pytest.raises(CheiralityError, match="behind camera 0"):
        triangulate([left, right], z)
    np.testing.assert_allclose(triangulate([left, right], z[::-1]), -behind, atol=1e-9)
    with pytest.raises(NonFiniteError, match="measurement 1"):
        triangulate([left, right], [[1.0, 2.0], [np.nan, 2.0]])
    with pytest.raises(DimensionMismatchError):
        triangulate([left, right], [[1.0, 2.0]])
