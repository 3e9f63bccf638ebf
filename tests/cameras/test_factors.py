"""ProjectionFactor / StereoFactor: batched kernels against central differences (every model,
calibration constant or variable, rotations near pi), costs against GTSAM's factors, the
cheirality policy inside the optimizer, bad input."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest

import fgopt
from fgopt import PriorFactor, Variables, key
from fgopt.cameras import (Cal3_S2, Cal3_S2Stereo, Cal3Bundler, PinholeCamera, ProjectionFactor,
                           StereoCamera, StereoFactor, projection_kernel, stereo_kernel)
from fgopt.errors import FgoptError, NonFiniteError
from fgopt.manifolds import SE3
from fgopt.noise import Huber, Isotropic


def _helpers():
    name = "fgopt_tests_camera_helpers"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, Path(__file__).with_name("_helpers.py"))
        sys.modules[name] = mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
    return sys.modules[name]


H = _helpers()
by_name = lambda c: c.__name__  # noqa: E731
X, L, K_ = (lambda i: key("x", i)), (lambda j: key("l", j)), (lambda i: key("k", i))


def _instance(rng, cls, angle, var):
    pose = H.random_pose(rng, angle)
    p = H.random_params(cls, rng)
    point = H.point_in_front(rng, pose)
    m = rng.normal(size=2) * 3 + PinholeCamera(pose, cls(*p)).project(point)
    args = (pose.to_storage()[None], point[None]) + ((p[None],) if var else ())
    consts = (m if var else np.concatenate([m, p]))[None]
    return projection_kernel(cls, var), args, consts, (pose, point, cls(*p), m)


@pytest.mark.parametrize("var", [False, True], ids=["fixed_K", "variable_K"])
@pytest.mark.parametrize("cls", H.MODELS, ids=by_name)
def test_projection_kernel_jacobians_equal_central_differences(cls, var):
    """The kernel's Jacobian (pose, point[, calibration]) equals central differences through each
    argument's retract, at rotations 0 .. pi; its residual is PinholeCamera.project - measured."""
    rng = np.random.default_rng(31)
    for angle in H.ANGLES:
        kernel, args, consts, (pose, point, K, m) = _instance(rng, cls, angle, var)
        res, jac = kernel.linearize(args, consts)
        np.testing.assert_allclose(res[0], PinholeCamera(pose, K).project(point) - m,
                                   atol=1e-9)
        num = H.kernel_fd(kernel, args, consts)
        scale = max(1.0, np.abs(jac).max())
        np.testing.assert_allclose(jac[0], num, rtol=1e-6, atol=1e-6 * scale)


def test_read_only_inputs_compile_no_second_signature():
    """Read-only argument and constant arrays reach the projection kernel as writeable copies:
    one compiled signature serves them (numba types a read-only array apart and would compile
    the kernel again)."""
    from fgopt._jit import specialize
    from fgopt.cameras import _projection_kernels as PK

    rng = np.random.default_rng(32)
    kernel, args, consts, _ = _instance(rng, Cal3_S2, 0.3, False)
    expected = kernel.linearize(args, consts)
    batch = specialize(PK.projection_batch, Cal3_S2.MODEL)  # the kernel's entry
    signatures = len(batch.signatures)
    assert signatures >= 1
    frozen = [np.array(a, dtype=float) for a in (*args, consts)]
    for a in frozen:
        a.flags.writeable = False
    got = kernel.linearize(tuple(frozen[:-1]), frozen[-1])
    kernel.residual(tuple(frozen[:-1]), frozen[-1])
    assert len(batch.signatures) == signatures
    assert np.array_equal(got[0], expected[0]) and np.array_equal(got[1], expected[1])


@pytest.mark.parametrize("var", [False, True], ids=["fixed_K", "variable_K"])
def test_stereo_kernel_jacobians_equal_central_differences(var):
    """The stereo kernel's Jacobian equals central differences at rotations 0 .. pi."""
    rng = np.random.default_rng(32)
    kernel = stereo_kernel(var)
    for angle in H.ANGLES:
        pose = H.random_pose(rng, angle)
        p = H.random_params(Cal3_S2Stereo, rng)
        point = H.point_in_front(rng, pose)
        m = StereoCamera(pose, Cal3_S2Stereo(*p)).project(point) + rng.normal(size=3)
        args = (pose.to_storage()[None], point[None]) + ((p[None],) if var else ())
        consts = (m if var else np.concatenate([m, p]))[None]
        _, jac = kernel.linearize(args, consts)
        num = H.kernel_fd(kernel, args, consts)
        np.testing.assert_allclose(jac[0], num, rtol=1e-6, atol=1e-6 * np.abs(jac).max())


def _gtsam_values(pose, point, K=None):
    import gtsam

    v = gtsam.Values()
    v.insert(X(0), H.gtsam_pose(pose))
    v.insert(L(0), point)
    if K is not None:
        v.insert(K_(0), H.gtsam_calibration(K))
    return v


@pytest.mark.parametrize("cls", [m for m in H.GTSAM_MODELS if m is not Cal3_S2Stereo],
                         ids=by_name)
def test_projection_factor_cost_equals_gtsam(cls):
    """The cost of ProjectionFactor equals GTSAM's GenericProjectionFactor (fixed calibration,
    where GTSAM wraps one) and GeneralSFMFactor2 (calibration variable) at random values."""
    gtsam = pytest.importorskip("gtsam")
    rng = np.random.default_rng(33)
    sigma = 1.7
    for angle in (0.3, math.pi - 1e-4):
        _, _, _, (pose, point, K, m) = _instance(rng, cls, angle, False)
        values = Variables({X(0): pose, L(0): point, K_(0): K})
        ours = ProjectionFactor(X(0), L(0), m, Isotropic.sigma(2, sigma), K_(0), model=cls)
        theirs = getattr(gtsam, f"GeneralSFMFactor2{cls.__name__}")(
            m, gtsam.noiseModel.Isotropic.Sigma(2, sigma), X(0), L(0), K_(0))
        gv = _gtsam_values(pose, point, K)
        assert ours.cost(values) == pytest.approx(theirs.error(gv), rel=1e-10)
        if hasattr(gtsam, f"GenericProjectionFactor{cls.__name__}"):
            ours = ProjectionFactor(X(0), L(0), m, Isotropic.sigma(2, sigma), K)
            theirs = getattr(gtsam, f"GenericProjectionFactor{cls.__name__}")(
                m, gtsam.noiseModel.Isotropic.Sigma(2, sigma), X(0), L(0),
                H.gtsam_calibration(K))
            assert ours.cost(values) == pytest.approx(theirs.error(gv), rel=1e-10)


def test_stereo_factor_cost_equals_gtsam():
    """StereoFactor's cost equals GTSAM's GenericStereoFactor3D."""
    gtsam = pytest.importorskip("gtsam")
    rng = np.random.default_rng(34)
    p = H.random_params(Cal3_S2Stereo, rng)
    p[2] = 0.0
    K = Cal3_S2Stereo(*p)
    for angle in (0.0, 1.0, math.pi):
        pose = H.random_pose(rng, angle)
        point = H.point_in_front(rng, pose)
        m = StereoCamera(pose, K).project(point) + rng.normal(size=3)
        ours = StereoFactor(X(0), L(0), m, Isotropic.sigma(3, 0.5), K)
        theirs = gtsam.GenericStereoFactor3D(gtsam.StereoPoint2(*m),
                                             gtsam.noiseModel.Isotropic.Sigma(3, 0.5), X(0), L(0),
                                             gtsam.Cal3_S2Stereo(*p))
        values = Variables({X(0): pose, L(0): point})
        assert ours.cost(values) == pytest.approx(theirs.error(_gtsam_values(pose, point)),
                                                  rel=1e-10)


def test_point_behind_camera_at_initial_estimate_is_named():
    """cheirality='reject': a point behind its camera at the initial estimate makes
    graph.error NaN and optimize raise NonFiniteError naming the factor and the cause;
    cheirality='allow' projects it like BAL (finite residual)."""
    K = Cal3_S2(500, 500, 0, 320, 240)
    g = fgopt.FactorGraph()
    g.add(ProjectionFactor(X(0), L(0), [330.0, 250.0], None, K))
    g.add(ProjectionFactor(X(0), L(1), [300.0, 200.0], None, K))
    g.add(PriorFactor(X(0), SE3(), Isotropic.sigma(6, 0.01)))
    v = Variables({X(0): SE3(), L(0): np.array([0.1, 0.1, 4.0]), L(1): np.array([0, 0, -2.0])})
    assert math.isnan(g.error(v))
    with pytest.raises(NonFiniteError, match=r"projection_cal3_s2\(x0, l1\).*cheirality"):
        fgopt.optimize(g, v)
    allow = ProjectionFactor(X(0), L(1), [300.0, 200.0], None, K, cheirality="allow")
    np.testing.assert_allclose(allow.error(v), [320.0 - 300.0, 240.0 - 200.0])


def test_optimizer_rejects_steps_that_cross_behind_the_camera():
    """With a prior pulling a point through the camera plane, every accepted LM state keeps the
    point in front (trial steps behind it are rejected, never returned)."""
    K = Cal3_S2(500, 500, 0, 320, 240)
    g = fgopt.FactorGraph()
    g.add(ProjectionFactor(X(0), L(0), K.uncalibrate([0.05, 0.0]), Isotropic.sigma(2, 1.0), K))
    g.add(PriorFactor(X(0), SE3(), Isotropic.sigma(6, 1e-3)))
    g.add(PriorFactor(L(0), np.array([0.0, 0.0, -3.0]), Isotropic.sigma(3, 0.05)))
    v = Variables({X(0): SE3(), L(0): np.array([0.1, 0.0, 2.0])})
    seen = []
    r = fgopt.optimize(g, v, callback=lambda rec: seen.append(rec) and False)
    assert (r.values.at(X(0)).inverse() * r.values.at(L(0)))[2] > 0.0
    assert np.all(np.isfinite(r.values.at(L(0))))
    assert any(not rec.accepted for rec in seen)


def test_self_calibration_recovers_the_calibration_and_equals_gtsam():
    """Eight cameras around a cube with one shared, unknown Cal3_S2: fgopt recovers the true
    calibration from a perturbed guess, as GTSAM's GeneralSFMFactor2 graph does (same estimate
    to 1e-6)."""
    gtsam = pytest.importorskip("gtsam")
    K = Cal3_S2(50.0, 50.0, 0.0, 50.0, 50.0)
    pts = [np.array(p, float) for p in np.array(np.meshgrid([-10, 10], [-10, 10], [-10, 10]))
           .reshape(3, -1).T]
    pts += [np.array([0.0, 0.0, 3.0]), np.array([4.0, -2.0, 0.0])]
    poses = [PinholeCamera.lookat([40 * np.cos(t), 40 * np.sin(t), 10 + 5 * np.sin(3 * t)],
                                  [0, 0, 0], [0, 0, 1], K).pose()
             for t in np.linspace(0, 2 * np.pi, 8, endpoint=False)]
    g, gg = fgopt.FactorGraph(), gtsam.NonlinearFactorGraph()
    noise, gnoise = Isotropic.sigma(2, 1.0), gtsam.noiseModel.Isotropic.Sigma(2, 1.0)
    for i, pose in enumerate(poses):
        for j, p in enumerate(pts):
            m = PinholeCamera(pose, K).project(p)
            g.add(ProjectionFactor(X(i), L(j), m, noise, K_(0), model=Cal3_S2))
            gg.add(gtsam.GeneralSFMFactor2Cal3_S2(m, gnoise, X(i), L(j), K_(0)))
    priors = [(X(0), poses[0], 1e-3, 6), (X(1), poses[1], 1e-3, 6)]
    for k, val, s, d in priors:
        g.add(PriorFactor(k, val, Isotropic.sigma(d, s)))
        gg.add(gtsam.PriorFactorPose3(k, H.gtsam_pose(val), gtsam.noiseModel.Isotropic.Sigma(d, s)))
    rng = np.random.default_rng(35)
    v, gv = Variables(), gtsam.Values()
    for i, pose in enumerate(poses):
        x0 = pose.retract(rng.normal(size=6) * 0.02)
        v.add(X(i), x0)
        gv.insert(X(i), H.gtsam_pose(x0))
    for j, p in enumerate(pts):
        l0 = p + rng.normal(size=3) * 0.2
        v.add(L(j), l0)
        gv.insert(L(j), l0)
    K0 = Cal3_S2(55.0, 46.0, 0.5, 52.0, 47.0)
    v.add(K_(0), K0)
    gv.insert(K_(0), H.gtsam_calibration(K0))
    r = fgopt.optimize(g, v, relative_tolerance=1e-12, absolute_tolerance=1e-14)
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-12)
    params.setAbsoluteErrorTol(1e-14)
    gr = gtsam.LevenbergMarquardtOptimizer(gg, gv, params).optimize()
    np.testing.assert_allclose(r.values.at(K_(0)).to_storage(), K.to_storage(), atol=1e-6)
    np.testing.assert_allclose(r.values.at(K_(0)).to_storage(),
                               gr.atCal3_S2(K_(0)).vector(), atol=1e-6)
    for i in range(8):
        np.testing.assert_allclose(r.values.at(X(i)).matrix(), gr.atPose3(X(i)).matrix(),
                                   atol=1e-6)


def test_batched_factors_equal_individual_factors():
    """Factors added one by one and the same rows added as one batch give the same cost and
    the same optimum (the kernel is shared)."""
    rng = np.random.default_rng(36)
    K = Cal3Bundler(*H.random_params(Cal3Bundler, rng))
    pose = H.random_pose(rng, 0.4)
    pts = np.array([H.point_in_front(rng, pose) for _ in range(5)])
    ms = PinholeCamera(pose, K).project(pts) + rng.normal(size=(5, 2))
    g1, g2 = fgopt.FactorGraph(), fgopt.FactorGraph()
    for j in range(5):
        g1.add(ProjectionFactor(X(0), L(j), ms[j], None, K))
    keys = np.array([[X(0), L(j)] for j in range(5)], dtype=np.int64)
    g2.add_batch(projection_kernel(Cal3Bundler), keys,
                 np.column_stack([ms, np.tile(K.to_storage(), (5, 1))]))
    v = Variables({X(0): pose, **{L(j): pts[j] for j in range(5)}})
    assert g1.error(v) == pytest.approx(g2.error(v), rel=1e-14)


def test_bad_input_is_named():
    """NaN / inf pixels, a calibration key without a model, a wrong calibration type and an
    unknown cheirality policy raise FgoptError naming the factor; robust losses are accepted."""
    K = Cal3_S2(500, 500, 0, 320, 240)
    with pytest.raises(NonFiniteError, match=r"ProjectionFactor\(x3, l7\).*NaN"):
        ProjectionFactor(X(3), L(7), [np.nan, 1.0], None, K)
    with pytest.raises(NonFiniteError, match=r"StereoFactor\(x1, l2\)"):
        StereoFactor(X(1), L(2), [1.0, np.inf, 3.0], None, Cal3_S2Stereo(1, 1, 0, 0, 0, 1))
    with pytest.raises(FgoptError, match="model="):
        ProjectionFactor(X(0), L(0), [1.0, 2.0], None, K_(0))
    with pytest.raises(FgoptError, match="Cal3_S2Stereo"):
        StereoFactor(X(0), L(0), [1.0, 2.0, 3.0], None, K)
    with pytest.raises(FgoptError, match="cheirality"):
        ProjectionFactor(X(0), L(0), [1.0, 2.0], None, K, cheirality="ignore")
    with pytest.raises(FgoptError, match="calibration"):
        ProjectionFactor(X(0), L(0), [1.0, 2.0], None, None)
    f = ProjectionFactor(X(0), L(0), [1.0, 2.0], Huber(1.345, Isotropic.sigma(2, 2.0)), K)
    assert f.describe() == "ProjectionFactor(x0, l0)" and "Huber" in repr(f)


@pytest.mark.parametrize("cls", H.MODELS, ids=by_name)
def test_camera_variable_kernel_jacobians_equal_central_differences(cls):
    """GeneralSFMFactor's kernel (one PinholeCamera variable: pose + calibration) has the
    projection residual and Jacobians equal to central differences through the camera kind's
    retract, at rotations 0 .. pi."""
    from fgopt.cameras import camera_projection_kernel

    rng = np.random.default_rng(37)
    kernel = camera_projection_kernel(cls)
    for angle in H.ANGLES:
        pose = H.random_pose(rng, angle)
        K = cls(*H.random_params(cls, rng))
        point = H.point_in_front(rng, pose)
        m = PinholeCamera(pose, K).project(point) + rng.normal(size=2)
        args = (PinholeCamera(pose, K).to_storage()[None], point[None])
        res, jac = kernel.linearize(args, m[None])
        np.testing.assert_allclose(res[0], PinholeCamera(pose, K).project(point) - m, atol=1e-9)
        num = H.kernel_fd(kernel, args, m[None])
        np.testing.assert_allclose(jac[0], num, rtol=1e-6, atol=1e-6 * max(1, np.abs(jac).max()))


@pytest.mark.parametrize("cls", [m for m in H.GTSAM_MODELS if m is not Cal3_S2Stereo],
                         ids=by_name)
def test_general_sfm_factor_cost_equals_gtsam(cls):
    """GeneralSFMFactor's cost equals GTSAM's GeneralSFMFactor<PinholeCamera<Cal>, Point3>."""
    gtsam = pytest.importorskip("gtsam")
    from fgopt.cameras import GeneralSFMFactor

    rng = np.random.default_rng(38)
    for angle in (0.2, math.pi):
        _, _, _, (pose, point, K, m) = _instance(rng, cls, angle, False)
        ours = GeneralSFMFactor(key("c", 0), L(0), m, Isotropic.sigma(2, 0.8), model=cls)
        theirs = getattr(gtsam, f"GeneralSFMFactor{cls.__name__}")(
            m, gtsam.noiseModel.Isotropic.Sigma(2, 0.8), key("c", 0), L(0))
        gv = gtsam.Values()
        gv.insert(key("c", 0), H.gtsam_camera(pose, K))
        gv.insert(L(0), point)
        values = Variables({key("c", 0): PinholeCamera(pose, K), L(0): point})
        assert ours.cost(values) == pytest.approx(theirs.error(gv), rel=1e-10)


def test_camera_graphs_pickle():
    """Graphs of projection, camera-variable, stereo and smart factors and their values
    (calibrations, PinholeCamera) pickle (kernels by recipe) and keep their cost."""
    import pickle

    from fgopt.datasets import sfm_cube
    from fgopt.io import read_bundler

    for g, v in ((sfm_cube().graph, sfm_cube().initial),
                 (sfm_cube(smart=True).graph, sfm_cube(smart=True).initial),
                 read_bundler("mem.out", data=b"""# Bundle file v0.3
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
""")):
        g2, v2 = pickle.loads(pickle.dumps((g, v)))
        assert g2.error(v2) == g.error(v)
    K = Cal3_S2Stereo(700, 700, 0, 600, 170, 0.5)
    f = StereoFactor(X(0), L(0), [610.0, 590.0, 175.0], None, K)
    assert pickle.loads(pickle.dumps(f)).kernel is f.kernel


@pytest.mark.parametrize("reject", [True, False])
def test_bundler_scalar_loop_equals_the_per_model_code(reject):
    """The scalar Cal3Bundler loop (BAL's model) behind projection_batch and
    camera_projection_batch returns what the per-model code (project_points: project_core,
    uncalibrate) returns for each observation's camera: residuals, Jacobians in each kernel's
    column layout, and NaN statuses (f <= 0 or NaN for a moved calibration, depth 0, points
    behind under either cheirality policy)."""
    from fgopt.cameras import _calib_kernels as CK
    from fgopt.cameras import _projection_kernels as PK

    rng = np.random.default_rng(41)
    n = 300
    poses = np.array([H.random_pose(rng, a).to_storage() for a in rng.uniform(0, math.pi, n)])
    cal = np.column_stack([rng.uniform(200, 800, n), rng.normal(scale=0.1, size=n),
                           rng.normal(scale=0.01, size=n), rng.normal(size=n), rng.normal(size=n)])
    points = rng.normal(scale=5.0, size=(n, 3))  # about half behind each camera
    cal[:4, 0] = [0.0, -3.0, np.nan, 1e-300]
    points[5] = poses[5, 4:7]  # at the camera centre: depth 0
    m = rng.normal(scale=50.0, size=(n, 2))
    ref_res = np.full((n, 2), np.nan)
    ref_pose, ref_point, ref_k = (np.zeros((n, 2, d)) for d in (6, 3, 3))
    for i in range(n):
        R = PK.rotation_of_storage(poses[i])
        uv, jp, jx, jk, status = PK.project_points(CK.CAL3BUNDLER, R, poses[i, 4:7], cal[i],
                                                   points[i:i + 1], reject, True)
        if status[0] == PK.OK:
            ref_res[i] = uv[0] - m[i]
            ref_pose[i], ref_point[i], ref_k[i] = jp[0], jx[0], jk[0]
    moved = ref_res.copy()
    moved[:3] = np.nan  # f <= 0 or NaN: invalid when the calibration is a variable
    cam = np.ascontiguousarray(np.hstack([poses, cal]))
    runs = {"camera form": (PK.camera_projection_batch(CK.CAL3BUNDLER, cam, points, m, reject,
                                                        True), moved, (0, 9, 6)),
            "variable K": (PK.projection_batch(CK.CAL3BUNDLER, poses, points, cal, m, reject,
                                               True, True), moved, (0, 6, 9)),
            "constant K": (PK.projection_batch(CK.CAL3BUNDLER, poses[4:], points[4:], cal[4:],
                                               m[4:], reject, False, True), ref_res[4:],
                           (0, 6, None))}
    for name, ((res, jac), expected, (c_pose, c_point, c_k)) in runs.items():
        rows = slice(4, None) if name == "constant K" else slice(None)
        np.testing.assert_array_equal(np.isnan(res), np.isnan(expected), err_msg=name)
        ok = ~np.isnan(res[:, 0])
        assert 0 < ok.sum() < len(ok)
        np.testing.assert_allclose(res[ok], expected[ok], rtol=1e-13, atol=1e-9, err_msg=name)
        blocks = [(c_pose, ref_pose), (c_point, ref_point)] + ([(c_k, ref_k)] if c_k else [])
        for col, ref in blocks:
            ref = ref[rows][ok]
            np.testing.assert_allclose(jac[ok][:, :, col:col + ref.shape[2]], ref, rtol=1e-12,
                                       atol=1e-9 * np.abs(ref).max(), err_msg=name)
        assert not jac[~ok].any()
