"""GTSAM's vision examples reproduced: SFMExample (projection factors), its smart-factor version,
and StereoVOExample_large on the real data; estimates compared with GTSAM run on the same input."""

from __future__ import annotations

import numpy as np
import pytest

import fgopt
from fgopt import key
from fgopt.datasets import sfm_cube
from fgopt.io import read_stereo_vo


def _gtsam_sfm(sfm, smart: bool):
    """The same SFMExample graph and initial values in GTSAM."""
    import gtsam

    K = gtsam.Cal3_S2(50.0, 50.0, 0.0, 50.0, 50.0)
    pixel = gtsam.noiseModel.Isotropic.Sigma(2, 1.0)
    g, v = gtsam.NonlinearFactorGraph(), gtsam.Values()
    n_pose, n_pt = sfm.measurements.shape[:2]
    if smart:
        for j in range(n_pt):
            f = gtsam.SmartProjectionPoseFactorCal3_S2(pixel, K)
            for i in range(n_pose):
                f.add(sfm.measurements[i, j], key("x", i))
            g.add(f)
        s = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.1, 0.1, 0.1, 0.3, 0.3, 0.3]))
        for i in (0, 1):
            g.add(gtsam.PriorFactorPose3(key("x", i), gtsam.Pose3(sfm.truth.at(key("x", i))
                                                                  .matrix()), s))
    else:
        s = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.3, 0.3, 0.3, 0.1, 0.1, 0.1]))
        g.add(gtsam.PriorFactorPose3(key("x", 0), gtsam.Pose3(sfm.truth.at(key("x", 0)).matrix()),
                                     s))
        for i in range(n_pose):
            for j in range(n_pt):
                g.add(gtsam.GenericProjectionFactorCal3_S2(sfm.measurements[i, j], pixel,
                                                           key("x", i), key("l", j), K))
        g.add(gtsam.PriorFactorPoint3(key("l", 0), sfm.truth.at(key("l", 0)),
                                      gtsam.noiseModel.Isotropic.Sigma(3, 0.1)))
        for j in range(n_pt):
            v.insert(key("l", j), np.asarray(sfm.initial.at(key("l", j))))
    for i in range(n_pose):
        v.insert(key("x", i), gtsam.Pose3(sfm.initial.at(key("x", i)).matrix()))
    return g, v


def test_sfm_example_equals_gtsam():
    """SFMExample (8 cameras around a cube, Dogleg as GTSAM's script): the same initial error,
    and fgopt's Dogleg / LM estimates equal GTSAM's DoglegOptimizer's and the truth (1e-6),
    every optimizer run to full convergence."""
    gtsam = pytest.importorskip("gtsam")
    sfm = sfm_cube(seed=3)
    g, v = _gtsam_sfm(sfm, smart=False)
    assert sfm.graph.error(sfm.initial) == pytest.approx(g.error(v), rel=1e-10)
    params = gtsam.DoglegParams()  # both run to full convergence (the optimum is exact)
    params.setRelativeErrorTol(1e-14)
    params.setAbsoluteErrorTol(1e-20)
    ref = gtsam.DoglegOptimizer(g, v, params).optimize()
    for method in ("dogleg", "lm"):
        r = fgopt.optimize(sfm.graph, sfm.initial, method=method, relative_tolerance=1e-14,
                           absolute_tolerance=1e-20)
        assert r.final_cost < 1e-12
        for i in range(8):
            np.testing.assert_allclose(r.values.at(key("x", i)).matrix(),
                                       ref.atPose3(key("x", i)).matrix(), atol=1e-6)
            np.testing.assert_allclose(r.values.at(key("x", i)).matrix(),
                                       sfm.truth.at(key("x", i)).matrix(), atol=1e-6)
        for j in range(8):
            np.testing.assert_allclose(r.values.at(key("l", j)), ref.atPoint3(key("l", j)),
                                       atol=1e-6)


def test_smart_sfm_example_equals_gtsam():
    """The smart-factor SFM (SFMExample_SmartFactor's structure on the same scene): same initial
    error as GTSAM's SmartProjectionPoseFactor graph, LM estimates equal to 1e-9, and the
    landmarks the factors triangulate at the optimum are the true points."""
    gtsam = pytest.importorskip("gtsam")
    sfm = sfm_cube(smart=True)
    g, v = _gtsam_sfm(sfm, smart=True)
    assert sfm.graph.error(sfm.initial) == pytest.approx(g.error(v), rel=1e-10)
    ref = gtsam.LevenbergMarquardtOptimizer(g, v).optimize()
    r = fgopt.optimize(sfm.graph, sfm.initial)
    for i in range(8):
        np.testing.assert_allclose(r.values.at(key("x", i)).matrix(),
                                   ref.atPose3(key("x", i)).matrix(), atol=1e-9)
    corners = {tuple(p) for p in np.round([f.point(r.values) for f in sfm.graph.factors[:8]], 6)}
    assert corners == {(x, y, z) for x in (10.0, -10.0) for y in (10.0, -10.0)
                       for z in (10.0, -10.0)}


def test_stereo_vo_large_equals_gtsam(data_file):
    """StereoVOExample_large: fgopt's estimate equals GTSAM's example (NonlinearEquality on x1,
    LM with METIS) to 1e-4 on every pose (GTSAM stops at its 1e-5 relative tolerance and keeps
    the file's 6-digit, slightly non-orthonormal rotations), and the final costs agree to 1e-5."""
    gtsam = pytest.importorskip("gtsam")
    d = "vision/"
    paths = [data_file(d + n) for n in ("VO_calibration.txt", "VO_camera_poses_large.txt",
                                        "VO_stereo_factors_large.txt")]
    graph, initial, K = read_stereo_vo(*paths)
    gg, gv = gtsam.NonlinearFactorGraph(), gtsam.Values()
    GK = gtsam.Cal3_S2Stereo(*K.to_storage())
    for row in np.loadtxt(paths[1]):
        gv.insert(key("x", int(row[0])), gtsam.Pose3(row[1:].reshape(4, 4)))
    model = gtsam.noiseModel.Isotropic.Sigma(3, 1.0)
    for x, lm, uL, uR, vv, X, Y, Z in np.loadtxt(paths[2]):
        xk, lk = key("x", int(x)), key("l", int(lm))
        gg.add(gtsam.GenericStereoFactor3D(gtsam.StereoPoint2(uL, uR, vv), model, xk, lk, GK))
        if not gv.exists(lk):
            gv.insert(lk, gv.atPose3(xk).transformFrom(np.array([X, Y, Z])))
    gg.add(gtsam.NonlinearEqualityPose3(key("x", 1), gv.atPose3(key("x", 1))))
    params = gtsam.LevenbergMarquardtParams()
    params.setOrderingType("METIS")
    ref = gtsam.LevenbergMarquardtOptimizer(gg, gv, params).optimize()
    r = fgopt.optimize(graph, initial)
    assert len(graph) == 8190 and r.status.value == "converged"
    poses = [k for k in initial.keys() if k.char == "x"]
    assert len(poses) == 26
    for k in poses:
        np.testing.assert_allclose(r.values.at(k).matrix(), ref.atPose3(k).matrix(), atol=1e-4)
    assert r.final_cost == pytest.approx(gg.error(ref), rel=1e-5)
