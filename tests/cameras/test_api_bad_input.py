"""Bad input to the camera API and the camera file readers: every error is an FgoptError subclass
whose message names the argument, factor, index or file:line; a factor's own Jacobians are never
a silent zero where its residual is undefined; valid neighbours of each bad case still work."""

from __future__ import annotations

import numpy as np
import pytest

import fgopt
from fgopt import PriorFactor, Variables, key
from fgopt.cameras import (Cal3_S2, Cal3_S2Stereo, Cal3Bundler, Cal3DS2, Cal3Fisheye,
                           Cal3Unified, DoubleSphere, GeneralSFMFactor, PinholeCamera,
                           ProjectionFactor, SmartProjectionFactor, StereoFactor, triangulate)
from fgopt.errors import (CalibrationError, CheiralityError, DimensionMismatchError, FgoptError,
                          FileFormatError, ManifoldError, NonFiniteError, TriangulationError)
from fgopt.io import read_bundler, read_stereo_vo
from fgopt.manifolds import SE3
from fgopt.noise import Isotropic

X, L = (lambda i: key("x", i)), (lambda j: key("l", j))
K = Cal3_S2(500, 500, 0, 320, 240)


def _cameras(n=3):
    return [PinholeCamera.lookat([float(i), 0, 0], [0, 0, 5], [0, -1, 0], K) for i in range(n)]


# ---------------------------------------------------------------- A: backproject's depth
def test_backproject_rejects_non_finite_non_positive_and_mismatched_depth():
    """backproject: a NaN / inf depth is a NonFiniteError, a depth <= 0 a CheiralityError, a
    depth array of the wrong length a DimensionMismatchError, each naming the depth's index;
    valid depths give pose * (depth * (x, y, 1)) as before."""
    cam = PinholeCamera(SE3(), Cal3DS2(500, 500, 0, 320, 240, -0.2, 0.05))
    uv = np.array([[300.0, 200.0], [330.0, 250.0]])
    with pytest.raises(NonFiniteError, match=r"backproject: depth 1 is nan"):
        cam.backproject(uv, [1.0, np.nan])
    with pytest.raises(NonFiniteError, match=r"depth 0 is inf"):
        cam.backproject(uv[0], np.inf)
    for bad in (-1.0, 0.0):
        with pytest.raises(CheiralityError, match=r"depth 0 is .*must be > 0"):
            cam.backproject(uv[0], bad)
    with pytest.raises(DimensionMismatchError, match=r"one per pixel \(2\), got 3"):
        cam.backproject(uv, [1.0, 2.0, 3.0])
    xy = cam.calibration().calibrate(uv)
    np.testing.assert_array_equal(cam.backproject(uv, [2.0, 3.0]),
                                  np.column_stack([xy * [[2.0], [3.0]], [2.0, 3.0]]))
    np.testing.assert_array_equal(cam.backproject(uv[1], [[3.0]]), cam.backproject(uv, 3.0)[1])


# ---------------------------------------------------------------- B: per-factor Jacobians
def test_projection_factor_jacobians_are_nan_where_its_residual_is():
    """A point behind the camera: ProjectionFactor.error is NaN and so is every Jacobian entry
    (not zeros); checked_jacobians and cost raise NonFiniteError naming the factor with the
    optimizer's cheirality hint. In front, the Jacobians are finite."""
    v = Variables({X(0): SE3(), L(0): np.array([0.1, 0.1, -5.0])})
    f = ProjectionFactor(X(0), L(0), [300.0, 200.0], None, K)
    assert np.all(np.isnan(f.error(v)))
    assert all(np.all(np.isnan(J)) for J in f.jacobians(v))
    with pytest.raises(NonFiniteError, match=r"ProjectionFactor\(x0, l0\): Jacobian .*"
                                             r"cheirality='allow'"):
        f.checked_jacobians(v)
    with pytest.raises(NonFiniteError, match=r"ProjectionFactor\(x0, l0\): residual .*"
                                             r"behind its camera .*cheirality='allow'"):
        f.cost(v)
    front = Variables({X(0): SE3(), L(0): np.array([0.1, 0.1, 5.0])})
    assert all(np.all(np.isfinite(J)) for J in f.checked_jacobians(front))


def test_stereo_and_sfm_factor_jacobians_are_nan_where_the_residual_is():
    """StereoFactor and GeneralSFMFactor: NaN Jacobians with the NaN residual of a point behind
    the camera, and checked_jacobians raises NonFiniteError naming the factor."""
    S = Cal3_S2Stereo(500, 500, 0, 320, 240, 0.1)
    v = Variables({X(0): SE3(), L(0): np.array([0.1, 0.1, -5.0])})
    f = StereoFactor(X(0), L(0), [330.0, 320.0, 200.0], None, S)
    assert all(np.all(np.isnan(J)) for J in f.jacobians(v))
    with pytest.raises(NonFiniteError, match=r"StereoFactor\(x0, l0\): Jacobian"):
        f.checked_jacobians(v)
    c = Variables({X(0): PinholeCamera(SE3(), Cal3Bundler(500, 0, 0)),
                   L(0): np.array([0.1, 0.1, -5.0])})
    g = GeneralSFMFactor(X(0), L(0), [300.0, 200.0], None, model=Cal3Bundler)
    assert all(np.all(np.isnan(J)) for J in g.jacobians(c))


def test_degenerate_smart_factor_jacobians_are_nan():
    """A smart factor whose poses coincide (no baseline): error NaN, every Jacobian NaN, and
    checked_jacobians raises NonFiniteError naming the factor and the degenerate='zero' hint."""
    cams = _cameras()
    pts = np.array([c.project([0.2, 0.1, 5.0]) for c in cams])
    sf = SmartProjectionFactor([X(i) for i in range(3)], pts, K)
    v = Variables({X(i): cams[0].pose() for i in range(3)})
    assert np.all(np.isnan(sf.error(v)))
    assert all(np.all(np.isnan(J)) for J in sf.jacobians(v))
    with pytest.raises(NonFiniteError, match=r"SmartProjectionFactor\(x0, x1, x2\).*"
                                             r"degenerate='zero'"):
        sf.checked_jacobians(v)


# ---------------------------------------------------------------- C: triangulation arguments
def test_triangulate_requires_positive_rank_tol_and_non_negative_iterations():
    """triangulate: rank_tol 0, negative or NaN and max_iterations < 0 raise FgoptError naming
    the argument (rank_tol 0 used to turn two identical cameras' rounding noise into a point)."""
    c = _cameras(1)[0]
    z = c.project([0.5, 0.4, 8.0])
    for tol in (0.0, -1.0, np.nan):
        with pytest.raises(FgoptError, match="rank_tol"):
            triangulate([c, c], [z, z], rank_tol=tol)
    c1, c2 = _cameras(2)
    z2 = [c1.project([0.2, 0.1, 5.0]), c2.project([0.2, 0.1, 5.0])]
    with pytest.raises(FgoptError, match="max_iterations"):
        triangulate([c1, c2], z2, method="nonlinear", max_iterations=-5)
    np.testing.assert_allclose(triangulate([c1, c2], z2, method="nonlinear", max_iterations=0),
                               [0.2, 0.1, 5.0], atol=1e-9)


def test_smart_factor_requires_positive_rank_tol():
    """SmartProjectionFactor(rank_tol=0) and a non-number rank_tol raise FgoptError naming
    rank_tol."""
    z = np.array([[300.0, 200.0], [310.0, 200.0]])
    for tol in (0.0, "a"):
        with pytest.raises(FgoptError, match="rank_tol"):
            SmartProjectionFactor([X(0), X(1)], z, K, rank_tol=tol)


def test_triangulate_names_parallel_rays_and_undistortion_failures():
    """The DLT's point at infinity is reported as such (not "rank 0"), and a pixel that cannot be
    undistorted is named by its index."""
    c1 = PinholeCamera.lookat([0, 0, 0], [0, 0, 5], [0, -1, 0], K)
    c2 = PinholeCamera.lookat([1, 0, 0], [1, 0, 5], [0, -1, 0], K)
    with pytest.raises(TriangulationError, match=r"at infinity \(parallel rays\)"):
        triangulate([c1, c2], [[320, 240], [320, 240]])
    D = Cal3DS2(500, 500, 0, 320, 240, -0.2, 0.05, 0.001, 0.001)
    d1, d2 = PinholeCamera(c1.pose(), D), PinholeCamera(c2.pose(), D)
    with pytest.raises(TriangulationError, match=r"measurement 1 .* cannot be undistorted"):
        triangulate([d1, d2], [[300, 200], [1e6, 1e6]])


# ---------------------------------------------------------------- D: messages that apply
def test_allow_factor_at_camera_centre_does_not_suggest_allow():
    """cheirality='allow' with a point exactly at depth 0: the optimizer's and cost's messages
    say depth 0, not the 'reject' policy's "at or behind its camera" (which points to 'allow')."""
    f = ProjectionFactor(X(0), L(0), [300.0, 200.0], None, K, cheirality="allow")
    g = fgopt.FactorGraph()
    g.add(f)
    g.add(PriorFactor(X(0), SE3(), Isotropic.sigma(6, 0.01)))
    v = Variables({X(0): SE3(), L(0): np.array([1.0, 0.0, 0.0])})
    with pytest.raises(NonFiniteError, match="depth 0") as e:
        fgopt.optimize(g, v)
    assert "at or behind" not in str(e.value)  # the 'reject' policy's hint
    with pytest.raises(NonFiniteError, match="depth 0") as e:
        f.cost(v)
    assert "at or behind" not in str(e.value)


def test_lookat_non_finite_is_named():
    """PinholeCamera.lookat with a NaN / inf eye, target or up raises NonFiniteError naming it
    (not "eye and target coincide" / "up is parallel"); a wrong shape is a
    DimensionMismatchError naming it."""
    ok = ([0.0, 0, 0], [0.0, 0, 1], [0.0, 1, 0])
    for i, name in enumerate(("eye", "target", "up")):
        for bad in (np.nan, np.inf):
            args = [list(a) for a in ok]
            args[i][0] = bad
            with pytest.raises(NonFiniteError, match=f"lookat: {name} has a NaN or inf"):
                PinholeCamera.lookat(*args)
        args = [list(a) for a in ok]
        args[i] = [0.0, 0.0]
        with pytest.raises(DimensionMismatchError, match=f"lookat: {name} must be a 3-vector"):
            PinholeCamera.lookat(*args)


def test_calibrate_rejects_bad_tol_and_max_iterations():
    """calibrate on iterative models: tol NaN / inf / <= 0 and max_iterations < 0 raise
    CalibrationError naming the argument before any iteration; valid ones still converge."""
    for cal in (Cal3DS2(500, 500, 0, 320, 240, -0.2, 0.05), Cal3Bundler(500, -0.1, 0.01),
                Cal3Fisheye(500, 500, 0, 320, 240, 0.1, 0.01, 0, 0),
                Cal3Unified(500, 500, 0, 320, 240, -0.1, 0.01, 0, 0, 0.9),
                DoubleSphere(300, 300, 320, 240, -0.2, 0.6)):
        for tol in (np.nan, np.inf, 0.0, -1.0):
            with pytest.raises(CalibrationError, match="tol must be"):
                cal.calibrate([400, 300], tol=tol)
        with pytest.raises(CalibrationError, match="max_iterations must be"):
            cal.calibrate([400, 300], max_iterations=-1)
        np.testing.assert_allclose(cal.uncalibrate(cal.calibrate([400, 300], tol=1e-9,
                                                                 max_iterations=20.0)),
                                   [400, 300], atol=1e-8)


_BUNDLER = """# Bundle file v0.3
2 1
500 0.1 0.01
1 0 0
0 1 0
0 0 1
0 0 -5
510 0 0
1 0 0
0 1 0
0 0 1
1 0 -5
0.1 0.2 0.3
255 0 0
2 0 5 10.0 -3.0 1 7 -90.0 -3.0
"""


def test_bundler_reflection_is_named():
    """A Bundler camera whose R has det < 0 is reported as a reflection (det(R) < 0), not as
    "|R R^T - I| = 0"."""
    data = _BUNDLER.replace("0 1 0\n0 0 1\n0 0 -5", "0 1 0\n0 0 -1\n0 0 -5", 1).encode()
    with pytest.raises(FileFormatError, match=r"mem.out:4: camera 0: R is a reflection.*"
                                              r"det\(R\) = -1 < 0"):
        read_bundler("mem.out", data=data)


_VO_CAL = "721.5377 721.5377 0.0 609.5593 172.854 0.537150588\n"
_VO_POSES = "1  1 0 0 0  0 1 0 0  0 0 1 0  0 0 0 1\n2  1 0 0 0  0 1 0 0  0 0 1 1  0 0 0 1\n"
_VO_FACS = ("1 3 609.5593 590.0 172.854 0 0 20\n2 3 609.5593 590.0 172.854 0 0 19\n"
            "1 4 700 690 200 2 1 30\n")


def _vo(tmp_path, cal=_VO_CAL, poses=_VO_POSES, facs=_VO_FACS, **kw):
    paths = []
    for name, text in (("cal", cal), ("poses", poses), ("facs", facs)):
        p = tmp_path / f"vo_{name}.txt"
        p.write_text(text)
        paths.append(p)
    return read_stereo_vo(*paths, **kw)


def test_stereo_vo_pose_defects_are_named(tmp_path):
    """A stereo-VO pose with a bad bottom row or a reflection says which (not "|R R^T - I| =
    0"), naming the file and line."""
    bad_row = _VO_POSES.replace("0 0 1 1  0 0 0 1", "0 0 1 1  0 0 1 1")
    with pytest.raises(FileFormatError, match=r"vo_poses.txt:2: pose 2 .*bottom row"):
        _vo(tmp_path, poses=bad_row)
    mirror = _VO_POSES.replace("2  1 0 0 0", "2  -1 0 0 0")
    with pytest.raises(FileFormatError, match=r"vo_poses.txt:2: pose 2 .*reflection"):
        _vo(tmp_path, poses=mirror)


def test_read_stereo_vo_validates_sigma(tmp_path):
    """read_stereo_vo(sigma=0 / NaN / -1) and anchor_sigma=0 raise FgoptError naming the
    argument up front; sigma=2 still reads (the cost is the sigma=1 cost / 4 plus the anchor)."""
    for sigma in (0.0, np.nan, -1.0, np.inf):
        with pytest.raises(FgoptError, match=r"read_stereo_vo: sigma must be"):
            _vo(tmp_path, sigma=sigma)
    with pytest.raises(FgoptError, match=r"read_stereo_vo: anchor_sigma must be"):
        _vo(tmp_path, anchor_sigma=0.0)
    g1, v1, _ = _vo(tmp_path, anchor_sigma=None)
    g2, v2, _ = _vo(tmp_path, sigma=2.0, anchor_sigma=None)
    assert g2.error(v2) == pytest.approx(g1.error(v1) / 4, rel=1e-12)


def test_read_stereo_vo_behind_camera_message_points_to_the_estimate(tmp_path):
    """A stereo-VO landmark behind a camera at the initial estimate: optimize names the factor's
    file:line and asks to fix the estimate; it gives no instruction to pass cheirality='allow',
    which read_stereo_vo does not take."""
    facs = ("1 3 609.5593 590.0 172.854 0 0 -20\n2 3 609.5593 590.0 172.854 0 0 19\n")
    g, v, _ = _vo(tmp_path, facs=facs)
    with pytest.raises(NonFiniteError, match=r"vo_facs.txt:1.*behind its camera.*fix the "
                                             r"initial estimate") as e:
        fgopt.optimize(g, v)
    assert "use cheirality='allow'" not in str(e.value)


# ---------------------------------------------------------------- E: no bare Python errors
def test_calibration_constructors_raise_fgopt_errors():
    """Wrong parameter counts raise DimensionMismatchError with the count expected and GTSAM's
    parameter names (not TypeError); a non-number parameter raises CalibrationError naming it
    (not ValueError); keywords still work."""
    cases = [(lambda: Cal3_S2(1, 1, 0, 0), r"Cal3_S2\(fx, fy, s, u0, v0\) takes 5 .*got 4.*v0"),
             (lambda: Cal3Fisheye(1, 1, 0, 0, 0, 0, 0, 0),
              r"Cal3Fisheye\(fx, fy, s, u0, v0, k1, k2, k3, k4\) takes 9 .*got 8"),
             (lambda: Cal3DS2(*[1.0] * 10),
              r"Cal3DS2\(fx, .*k2\[, p1, p2\]\) takes 7 to 9 .*got 10"),
             (lambda: Cal3DS2(1, 1, 0, 0, 0, 0, 0, k3=1.0), r"unexpected keyword argument 'k3'")]
    for make, msg in cases:
        with pytest.raises(DimensionMismatchError, match=msg):
            make()
    for bad in ("a", None, np.array([1.0, 2.0])):
        with pytest.raises(CalibrationError, match=r"Cal3_S2: parameter fx must be a number"):
            Cal3_S2(bad, 1, 0, 0, 0)
    assert Cal3DS2(500, 500, 0, 320, 240, k1=0.1, k2=0.0, p2=0.01).p2() == 0.01
    assert Cal3_S2(fx=1, fy=2, s=0, u0=3, v0=4) == Cal3_S2(1, 2, 0, 3, 4)


def test_camera_and_triangulate_bad_arguments_raise_fgopt_errors():
    """PinholeCamera.local(non-camera) raises ManifoldError; triangulate(None, ...) FgoptError;
    ragged or non-numeric measurements DimensionMismatchError (not AttributeError / TypeError /
    ValueError)."""
    cam = _cameras(1)[0]
    with pytest.raises(ManifoldError, match=r"PinholeCamera.local: expected a PinholeCamera"):
        cam.local(3)
    with pytest.raises(FgoptError, match=r"triangulate: cameras must be"):
        triangulate(None, [[1, 2], [3, 4]])
    for meas in ([[1, 2], [3]], "ab"):
        with pytest.raises(DimensionMismatchError, match=r"triangulate: measurements"):
            triangulate([cam, cam], meas)


def test_factor_constructors_raise_fgopt_errors():
    """ProjectionFactor(measured='ab'), SmartProjectionFactor(5, ...), ragged smart measurements
    and GeneralSFMFactor without model= raise FgoptErrors naming the factor / argument."""
    with pytest.raises(DimensionMismatchError, match=r"ProjectionFactor\(x0, l0\): the measured"):
        ProjectionFactor(X(0), L(0), "ab", None, K)
    with pytest.raises(FgoptError, match="pose_keys must be"):
        SmartProjectionFactor(5, [[1, 2], [3, 4]], K)
    with pytest.raises(DimensionMismatchError, match=r"SmartProjectionFactor\(x0, x1\): "
                                                     r"measurements"):
        SmartProjectionFactor([X(0), X(1)], [[1, 2], [3]], K)
    with pytest.raises(FgoptError, match=r"GeneralSFMFactor\(x0, l0\): pass model="):
        GeneralSFMFactor(X(0), L(0), [1.0, 2.0])


def test_smart_point_with_non_pose_value_is_a_manifold_error():
    """SmartProjectionFactor.point raises ManifoldError (as error() does) when a key holds a
    value that is not an SE3, not AttributeError."""
    sf = SmartProjectionFactor([X(0), X(1)], [[300.0, 200.0], [310.0, 200.0]], K)
    v = Variables({X(0): np.zeros(3), X(1): np.zeros(3)})
    with pytest.raises(ManifoldError, match=r"SmartProjectionFactor\(x0, x1\): variable x0"):
        sf.point(v)
    cams = _cameras(2)
    z = [c.project([0.2, 0.1, 5.0]) for c in cams]
    sf = SmartProjectionFactor([X(0), X(1)], z, K)
    np.testing.assert_allclose(sf.point(Variables({X(i): c.pose() for i, c in enumerate(cams)})),
                               [0.2, 0.1, 5.0], atol=1e-9)


# ---------------------------------------------------------------- F: parameter ranges
def test_double_sphere_and_unified_xi_ranges():
    """DoubleSphere needs xi in [-1, 1] (Usenko et al.; basalt's DoubleSphereCamera) and
    Cal3Unified xi >= 0 (Mei: the sphere-to-projection-centre distance): outside, a
    CalibrationError naming xi; the range ends are accepted."""
    for xi in (-3.0, -1.0001, 1.0001):
        with pytest.raises(CalibrationError, match=r"DoubleSphere: xi must be in \[-1, 1\]"):
            DoubleSphere(300, 300, 320, 240, xi, 0.6)
    for xi in (-1.0, 1.0):
        DoubleSphere(300, 300, 320, 240, xi, 0.6)
    for xi in (-5.0, -1e-9):
        with pytest.raises(CalibrationError, match=r"Cal3Unified: xi must be >= 0"):
            Cal3Unified(500, 500, 0, 320, 240, 0, 0, 0, 0, xi)
    assert Cal3Unified(500, 500, 0, 320, 240, 0, 0, 0, 0, 0.0).xi() == 0.0
    assert Cal3Unified(500, 500, 0, 320, 240, 0, 0, 0, 0, 2.0).xi() == 2.0


# ---------------------------------------------------------------- G: Bundler tracks
def test_bundler_track_with_fewer_than_two_views_is_named():
    """A Bundler point seen by 0 or 1 cameras (unconstrained; LM used to report convergence on
    it) raises FileFormatError naming the file:line of its view list and the point's index."""
    one = _BUNDLER.replace("2 0 5 10.0 -3.0 1 7 -90.0 -3.0", "1 0 5 10.0 -3.0")
    with pytest.raises(FileFormatError, match=r"mem.out:15: point 0 has 1 view;"):
        read_bundler("mem.out", data=one.encode())
    none = _BUNDLER.replace("2 1\n", "2 2\n").replace(
        "2 0 5 10.0 -3.0 1 7 -90.0 -3.0\n", "2 0 5 10.0 -3.0 1 7 -90.0 -3.0\n0 0 0\n0 0 0\n0\n")
    with pytest.raises(FileFormatError, match=r"mem.out:18: point 1 has 0 views"):
        read_bundler("mem.out", data=none.encode())
    g, v = read_bundler("mem.out", data=_BUNDLER.encode())
    assert len(g) == 2 and np.isfinite(g.error(v))
