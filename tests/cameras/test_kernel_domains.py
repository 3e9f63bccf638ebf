"""Domains of the camera kernels: where a lens model, an undistortion or a projection is undefined,
the public API raises an FgoptError naming the point or the factor, and inside the optimizer the
residual is NaN. Never a ZeroDivisionError from a numba kernel, an undistortion through a fold of
the distortion, an optimized calibration outside its class's invariant, or a finite pixel made
of overflowed intermediates."""

from __future__ import annotations

import itertools
import pickle

import numpy as np
import pytest

import fgopt
from fgopt import FactorGraph, PriorFactor, Variables, key
from fgopt.cameras import (Cal3_S2, Cal3_S2Stereo, Cal3Bundler, Cal3DS2, Cal3Fisheye,
                           Cal3Unified, DoubleSphere, GeneralSFMFactor, PinholeCamera,
                           ProjectionFactor, SmartProjectionFactor, StereoCamera, StereoFactor,
                           triangulate)
from fgopt.errors import (CalibrationError, CheiralityError, FgoptError, NonFiniteError,
                          TriangulationError)
from fgopt.manifolds import SE3, SO3
from fgopt.noise import Isotropic

X, L, C, K_ = (lambda i: key("x", i)), (lambda j: key("l", j)), (lambda i: key("c", i)), \
    (lambda i: key("k", i))


def by_name(cls):
    return cls.__name__


#: Pixels Newton's method used to "undistort" to a root past a fold of the distortion, where
#: ``1 + k r^2 < 0`` turns the image half around (found by scanning; each model's image ends
#: well before them).
FOLDED = [
    (Cal3DS2(500, 500, 0, 320, 240, -0.3, 0.0), [800.0, 240.0]),
    (Cal3Bundler(500, -0.3, 0.0), [480.0, 0.0]),
    (Cal3Fisheye(500, 500, 0, 320, 240, 0.0, -0.5, 0.0, 0.0), [-1250.0, 240.0]),
    (Cal3Unified(500, 500, 0, 320, 240, -0.5, 0.0, 0.0, 0.0, 0.1), [-1500.0, 240.0]),
]


def _distortion_jacobian(K, xy):
    """``M = K^-1 uv_D_xy`` at ``xy``: the distortion's own Jacobian (identity at the centre)."""
    _, _, Dp = K.uncalibrate(xy, jacobians=True)
    return np.linalg.solve(K.K()[:2, :2], Dp)


# ---------------------------------------------------------------------------- 1. no ZeroDivision
def test_degenerate_double_sphere_is_invalid_not_a_division_by_zero():
    """DoubleSphere at xi = -1, alpha = 1/2 (its validity test is 0 / 0) and at alpha = 1 on the
    rim of its image (the unprojection is 0 / 0) reports the point invalid through the public
    API (CheiralityError, CalibrationError, TriangulationError naming it)."""
    K = DoubleSphere(100, 100, 0, 0, -1.0, 0.5)
    with pytest.raises(CheiralityError, match=r"point 0 .* valid region"):
        K.uncalibrate([0.1, 0.1])
    with pytest.raises(CheiralityError, match="point 0"):
        PinholeCamera(SE3(), K).project([0.1, 0.1, 1.0])
    for xi in (0.0, -0.5):  # the rim r = fx: outside the image, or its singular edge
        with pytest.raises(CalibrationError, match=r"pixel 0 .* outside the model's image"):
            DoubleSphere(100, 100, 0, 0, xi, 1.0).calibrate([100.0, 0.0])
    K = DoubleSphere(100, 100, 0, 0, 0.0, 1.0)
    c0, c1 = PinholeCamera(SE3(), K), PinholeCamera(SE3.exp([0, 0, 0, 1.0, 0, 0]), K)
    with pytest.raises(TriangulationError, match="undistort"):
        triangulate([c0, c1], [[100.0, 0.0], [50.0, 0.0]])


def test_degenerate_double_sphere_inside_optimize_is_named():
    """The same degenerate double spheres inside optimize: a ProjectionFactor and a
    SmartProjectionFactor get a NaN residual, so optimize raises NonFiniteError naming them."""
    g, v = FactorGraph(), Variables({X(0): SE3(), L(0): np.array([0.1, 0.1, 1.0])})
    g.add(ProjectionFactor(X(0), L(0), [10.0, 10.0], None, DoubleSphere(100, 100, 0, 0, -1, 0.5)))
    with pytest.raises(NonFiniteError, match=r"projection_doublesphere\(x0, l0\)"):
        fgopt.optimize(g, v)
    K = DoubleSphere(100, 100, 0, 0, 0.0, 1.0)
    poses = [SE3(), SE3.exp([0, 0, 0, 1.0, 0, 0])]
    g, v = FactorGraph(), Variables({X(0): poses[0], X(1): poses[1]})
    for i, p in enumerate(poses):
        g.add(PriorFactor(X(i), p, Isotropic.sigma(6, 1e-3)))
    g.add(SmartProjectionFactor([X(0), X(1)], [[100.0, 0.0], [50.0, 0.0]], K))
    with pytest.raises(NonFiniteError, match=r"smart_doublesphere_2views\(x0, x1\)"):
        fgopt.optimize(g, v)


def _edge_calibrations():
    """Every model at the edges of the parameters its constructor accepts (focal lengths are
    the only bounded ones besides the double sphere's and unified xi ranges)."""
    ks = (-1.0, 0.0, 1.0)
    yield Cal3_S2(100, 80, 0.5, 10, 20)
    yield Cal3_S2Stereo(100, 80, 0.5, 10, 20, 0.1)
    for k1, k2 in itertools.product(ks, ks):
        yield Cal3DS2(100, 80, 0.5, 10, 20, k1, k2, 0.01 * k1, -0.01 * k2)
        yield Cal3Bundler(100, k1, k2, 10, 20)
        yield Cal3Fisheye(100, 80, 0.5, 10, 20, k1, k2, -k1, k2)
        for xi in (0.0, 1.0, 3.0):
            yield Cal3Unified(100, 80, 0.5, 10, 20, k1, k2, 0.01, -0.01, xi)
    for xi, alpha in itertools.product((-1.0, -0.5, 0.0, 0.5, 1.0), (0.0, 0.5, 1.0)):
        yield DoubleSphere(100, 80, 10, 20, xi, alpha)


def test_calibration_kernels_only_raise_fgopt_errors_at_their_edges():
    """At the edges of every model's parameters, uncalibrate / calibrate (with Jacobians) and
    PinholeCamera.project either return finite numbers or raise an FgoptError: no division by
    zero, no NaN or inf passed off as a pixel (at 1e200 only the pixel: Jacobians there are
    products of two such numbers)."""
    xys = [[0.0, 0.0], [1e-9, 0.0], [0.3, -0.2], [1.0, 0.0], [0.0, 1.0], [1.7320508075688772, 0.0],
           [5.0, 5.0], [1e3, -1e3], [1e200, 1e200]]
    for K in _edge_calibrations():
        fx, fy, u0, v0 = K.K()[0, 0], K.K()[1, 1], K.K()[0, 2], K.K()[1, 2]
        pixels = [[u0, v0], [u0 + fx, v0], [u0, v0 + fy], [u0 + 0.5 * fx, v0 - 0.5 * fy],
                  [u0 + 3 * fx, v0], [u0 - 1e6, v0 + 1e6]]
        for xy in xys:
            jac = abs(xy[0]) < 1e100
            calls = [(K.uncalibrate, xy)]
            if not isinstance(K, Cal3_S2Stereo):
                calls.append((PinholeCamera(SE3(), K).project, [*xy, 1.0]))
            for call, arg in calls:
                try:
                    out = call(arg, jacobians=jac)
                except FgoptError:
                    continue
                for a in (out if jac else [out]):
                    assert np.all(np.isfinite(a)), (K, xy, out)
        for uv in pixels:
            try:
                out = K.calibrate(uv, jacobians=True)
            except FgoptError:
                continue
            for a in out:
                assert np.all(np.isfinite(a)), (K, uv, out)


# ---------------------------------------------------------------------------- 2. distortion folds
@pytest.mark.parametrize("K, uv", FOLDED, ids=[type(K).__name__ for K, _ in FOLDED])
def test_calibrate_rejects_a_root_past_the_fold(K, uv):
    """A pixel beyond the image of the distortion's invertible part, where Newton's method finds
    a root on the far side of the fold (the ray turned half around), raises CalibrationError
    naming the pixel instead of returning that mirror point."""
    with pytest.raises(CalibrationError, match=r"pixel 0 .* outside the model's image"):
        K.calibrate(uv)
    with pytest.raises(CalibrationError, match=r"pixel 1 "):
        K.calibrate([K.principal_point(), uv], jacobians=True)
    xy = K.calibrate(K.uncalibrate([0.3, -0.2]))  # inside the image: unchanged
    np.testing.assert_allclose(xy, [0.3, -0.2], atol=1e-10)


@pytest.mark.parametrize("cls", [Cal3DS2, Cal3Bundler, Cal3Fisheye, Cal3Unified], ids=by_name)
def test_calibrate_results_lie_on_the_invertible_branch(cls):
    """For strong random distortions and pixels all over (and past) the image, every pixel
    calibrate accepts re-projects onto itself from a point where the distortion's Jacobian
    ``K^-1 uv_D_xy`` has a positive determinant and trace (the branch through the centre)."""
    rng = np.random.default_rng(41)
    accepted = 0
    for _ in range(40):
        k = rng.uniform(-0.6, 0.6, 4)
        if cls is Cal3DS2:
            K = Cal3DS2(500, 480, 1.0, 320, 240, k[0], k[1], 0.05 * k[2], 0.05 * k[3])
        elif cls is Cal3Bundler:
            K = Cal3Bundler(500, k[0], k[1])
        elif cls is Cal3Fisheye:
            K = Cal3Fisheye(500, 480, 1.0, 320, 240, *k)
        else:
            K = Cal3Unified(500, 480, 1.0, 320, 240, k[0], k[1], 0.05 * k[2], 0.05 * k[3],
                            rng.uniform(0.0, 2.0))
        for uv in rng.uniform(-1500, 2000, (25, 2)):
            try:
                xy = K.calibrate(uv)
            except CalibrationError:
                continue
            accepted += 1
            M = _distortion_jacobian(K, xy)
            assert np.linalg.det(M) > 0.0 and np.trace(M) > 0.0, (K, uv, xy)
            np.testing.assert_allclose(K.uncalibrate(xy), uv, atol=1e-8)
    assert accepted > 50


def test_triangulation_does_not_undistort_through_a_fold():
    """triangulate undistorts with calibrate, so a pixel whose Newton root lies past the fold is
    a TriangulationError, not a landmark on the wrong side of the image."""
    K = FOLDED[0][0]
    c0, c1 = PinholeCamera(SE3(), K), PinholeCamera(SE3.exp([0, 0, 0, 1.0, 0, 0]), K)
    for method in ("dlt", "nonlinear"):
        with pytest.raises(TriangulationError, match="undistort"):
            triangulate([c0, c1], [[800.0, 240.0], [900.0, 240.0]], method=method)


# ---------------------------------------------------------------------------- 3. self-calibration
def _scene():
    """Three camera poses looking at six points 5 units ahead."""
    poses = [PinholeCamera.lookat([i * 1.0, 0, 0], [0, 0, 5], [0, -1, 0]).pose() for i in range(3)]
    pts = np.array([[0.2, 0.1, 5], [-0.3, 0.4, 6], [0.5, -0.2, 4.5], [0.0, 0.0, 5.5],
                    [-0.4, -0.3, 5.2], [0.3, 0.3, 4.8]])
    return poses, pts


def _fixed_scene(g, v):
    """:func:`_scene`'s poses and points as variables held by tight priors."""
    poses, pts = _scene()
    for i, p in enumerate(poses):
        v.add(X(i), p)
        g.add(PriorFactor(X(i), p, Isotropic.sigma(6, 1e-6)))
    for j, p in enumerate(pts):
        v.add(L(j), p.copy())
        g.add(PriorFactor(L(j), p.copy(), Isotropic.sigma(3, 1e-6)))
    return poses, pts


def _rebuildable(Kr):
    """The estimate satisfies its class invariant: it can be rebuilt, retracted and pickled."""
    assert type(Kr).from_storage(Kr.to_storage()) == Kr
    Kr.retract(np.zeros(Kr.DIM))
    pickle.loads(pickle.dumps(Kr))


def test_self_calibration_does_not_cross_zero_focal_length():
    """Pixels that only a negative fx explains (mirrored about u0), a Cal3_S2 variable starting
    at fx = 10: LM rejects the steps across fx = 0, so the estimate keeps fx > 0 and is a valid
    Cal3_S2 (previously it converged to fx = -500, which no Cal3_S2 can hold)."""
    g, v = FactorGraph(), Variables()
    poses, pts = _fixed_scene(g, v)
    K = Cal3_S2(500, 500, 0, 320, 240)
    v.add(K_(0), Cal3_S2(10, 500, 0, 320, 240))
    for i, pose in enumerate(poses):
        for j, p in enumerate(pts):
            uv = PinholeCamera(pose, K).project(p)
            uv[0] = 640.0 - uv[0]
            g.add(ProjectionFactor(X(i), L(j), uv, None, K_(0), model=Cal3_S2))
    r = fgopt.optimize(g, v)
    Kr = r.values.at(K_(0))
    assert Kr.fx() > 0.0 and Kr.fy() > 0.0
    _rebuildable(Kr)


def test_self_calibration_keeps_a_positive_stereo_baseline():
    """Stereo measurements that a negative baseline explains (right image shifted the wrong
    way), a Cal3_S2Stereo variable starting at b = 0.05: the estimate keeps b > 0."""
    g, v = FactorGraph(), Variables()
    poses, pts = _fixed_scene(g, v)
    K = Cal3_S2Stereo(500, 500, 0, 320, 240, 0.1)
    v.add(K_(0), Cal3_S2Stereo(500, 500, 0, 320, 240, 0.05))
    for i, pose in enumerate(poses):
        for j, p in enumerate(pts):
            uL, uR, vv = StereoCamera(pose, K).project(p)
            g.add(StereoFactor(X(i), L(j), [uL, 2 * uL - uR, vv], None, K_(0)))
    Kr = fgopt.optimize(g, v).values.at(K_(0))
    assert Kr.baseline() > 0.0
    _rebuildable(Kr)


@pytest.mark.parametrize("method", ["lm", "dogleg", "gn"])
def test_camera_variable_keeps_a_positive_bundler_focal_length(method):
    """GeneralSFMFactor with PinholeCamera[Cal3Bundler] variables that start turned half around
    the optical axis with f = 50 (points held): the nearest fit is f = -500 (the same image), so
    the optimizer used to end there; now every camera's estimate keeps f > 0."""
    rng = np.random.default_rng(2)
    poses = _scene()[0]
    pts = np.column_stack([rng.uniform(-1, 1, 12), rng.uniform(-1, 1, 12), rng.uniform(4, 6, 12)])
    K = Cal3Bundler(500, 0.0, 0.0)
    half_turn = SE3(SO3.exp([0, 0, np.pi]), np.zeros(3))
    g, v = FactorGraph(), Variables()
    for i, pose in enumerate(poses):
        v.add(C(i), PinholeCamera(pose * half_turn, Cal3Bundler(50, 0.0, 0.0)))
        for j, p in enumerate(pts):
            g.add(GeneralSFMFactor(C(i), L(j), PinholeCamera(pose, K).project(p), None,
                                   model=Cal3Bundler))
    for j, p in enumerate(pts):
        v.add(L(j), p.copy())
        g.add(PriorFactor(L(j), p.copy(), Isotropic.sigma(3, 1e-6)))
    r = fgopt.optimize(g, v, method=method)
    for i in range(len(poses)):
        Kr = r.values.at(C(i)).calibration()
        assert Kr.fx() > 0.0
        _rebuildable(Kr)


# ---------------------------------------------------------------------------- 4. overflow
@pytest.mark.parametrize("cls", [Cal3DS2, Cal3Bundler, Cal3Fisheye, Cal3Unified, DoubleSphere],
                         ids=by_name)
def test_point_at_a_vanishing_depth_is_invalid_not_a_wrong_pixel(cls):
    """A point at depth 1e-300 (intrinsic coordinates that overflow the model) raises
    CheiralityError naming it, in project and uncalibrate, instead of returning NaN, inf or the
    principal point (what saturating atan / division made of the overflow)."""
    K = cls(*{Cal3DS2: (500, 500, 0, 320, 240, -0.2, 0.05),
              Cal3Bundler: (500, -0.1, 0.01),
              Cal3Fisheye: (500, 500, 0, 320, 240, 0.1, 0.01, 0, 0),
              Cal3Unified: (500, 500, 0, 320, 240, -0.1, 0.01, 0, 0, 0.9),
              DoubleSphere: (300, 300, 320, 240, -0.2, 0.6)}[cls])
    cam = PinholeCamera(SE3(), K)
    with pytest.raises(CheiralityError, match="point 1"):
        cam.project([[0.1, 0.1, 1.0], [1.0, 1.0, 1e-300]])
    with pytest.raises(CheiralityError, match="point 0"):
        K.uncalibrate([1e300, 1e300])
    assert np.all(np.isfinite(cam.project([1.0, 1.0, 1e-150]) if cls is Cal3Fisheye
                              else cam.project([0.1, 0.1, 1.0])))


def test_pinhole_and_stereo_overflow_is_invalid():
    """A depth so small that 1/z overflows (1e-310) makes the pinhole and stereo projections
    raise CheiralityError rather than return inf; a huge but finite pixel is still returned."""
    K = Cal3_S2(500, 500, 0, 320, 240)
    with pytest.raises(CheiralityError, match="point 0"):
        PinholeCamera(SE3(), K).project([1.0, 1.0, 1e-310])
    with pytest.raises(CheiralityError, match="point 0"):
        StereoCamera(SE3(), Cal3_S2Stereo(500, 500, 0, 320, 240, 0.1)).project([1.0, 1.0, 1e-310])
    np.testing.assert_allclose(PinholeCamera(SE3(), K).project([1.0, 0.0, 1e-300]),
                               [5e302, 240.0])


def test_vanishing_depth_inside_optimize_is_named():
    """A Cal3Fisheye ProjectionFactor whose point starts at depth 1e-300 has a NaN residual (it
    was the principal point minus the measurement, with a NaN Jacobian), so graph.error is NaN
    and optimize raises NonFiniteError naming the factor's residual."""
    K = Cal3Fisheye(500, 500, 0, 320, 240, 0.1, 0.01, 0, 0)
    g = FactorGraph()
    factor = ProjectionFactor(X(0), L(0), [330.0, 250.0], None, K)
    g.add(factor)
    g.add(PriorFactor(X(0), SE3(), Isotropic.sigma(6, 0.01)))
    v = Variables({X(0): SE3(), L(0): np.array([1.0, 1.0, 1e-300])})
    assert np.all(np.isnan(factor.error(v)))
    assert np.isnan(g.error(v))
    with pytest.raises(NonFiniteError,
                       match=r"projection_cal3fisheye\(x0, l0\).*non-finite residual"):
        fgopt.optimize(g, v)
