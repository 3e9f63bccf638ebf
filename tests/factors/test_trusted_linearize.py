"""``FactorKernel.trusted_linearize`` (the compiled problem's numba entry without argument checks)
returns what the checked ``linearize`` returns, for every built-in kernel family: generated
modules (shipped and custom), hand-written Lie / vector kernels, IMU and GPS, projection
(constant and optimized calibration), camera, stereo and smart factors."""

from __future__ import annotations

import math

import numpy as np
import pytest

import fgopt
from fgopt import key
from fgopt.cameras import (Cal3_S2, Cal3_S2Stereo, Cal3DS2, PinholeCamera,
                           camera_projection_kernel, projection_kernel, stereo_kernel)
from fgopt.datasets import sfm_cube
from fgopt.factors.library.lie_kernels import between_kernel, prior_kernel
from fgopt.manifolds import SE2, SE3, SO2, SO3, vector_kind
from fgopt.problem import Problem


def _same(kernel, args, consts) -> None:
    assert kernel.trusted_linearize is not None, f"{kernel.name} has no trusted_linearize"
    got = kernel.trusted_linearize(args, consts)
    ref = kernel.linearize(args, consts)
    for a, b in zip(got, ref):
        assert a.shape == b.shape, kernel.name
        np.testing.assert_allclose(a, b, rtol=1e-11, atol=1e-11, equal_nan=True,
                                   err_msg=kernel.name)


def _every_batch_same(graph, values) -> set[str]:
    problem = Problem(graph, values, backend="numba")
    state = problem.initial_state()
    for b in problem.batches:
        _same(b.kernel, b.gather(state), b.source.constants)
    return {b.kernel.name for b in problem.batches}


def test_imu_example_kernels():
    """IMU, GPS, the generated between / prior kernels and vector priors of the IMU example."""
    from fgopt.io.imu_gps import imu_factors_example, read_imu_gps_csv
    from fgopt.datasets import data_dir

    path = data_dir() / "navigation" / "imuAndGPSdata.csv"
    if not path.exists():
        pytest.skip(f"{path} not found (set FGOPT_DATA)")
    data = read_imu_gps_csv(path)
    for combined in (False, True):
        ex = imu_factors_example(data, combined=combined)
        names = _every_batch_same(ex.graph, ex.initial)
        assert ("combined_imu_factor" if combined else "imu_factor") in names
        assert "gps_factor" in names


@pytest.mark.parametrize("smart", [False, True])
def test_sfm_kernels(smart):
    """Projection factors with a constant calibration, and smart factors, of the SFM cube."""
    scene = sfm_cube(smart=smart, seed=5)
    names = _every_batch_same(scene.graph, scene.initial)
    assert any(n.startswith("smart_" if smart else "projection_") for n in names)


@pytest.mark.parametrize("group", [SO2, SE2, SO3, SE3], ids=lambda g: g.__name__)
def test_lie_and_vector_kernels(group):
    """Hand-written between / prior kernels of the Lie groups (rotations near 0 and pi) and of
    vectors."""
    rng = np.random.default_rng(3)
    kind = group.batch_kind()
    xs = np.array([group.random(rng).to_storage() for _ in range(7)])
    ys = np.array([group.random(rng).to_storage() for _ in range(7)])
    ms = np.array([group.random(rng).to_storage() for _ in range(7)])
    _same(between_kernel(kind), (xs, ys), ms)
    _same(prior_kernel(kind), (xs,), ms)
    v = vector_kind(4)
    a, b, m = (rng.normal(size=(5, 4)) for _ in range(3))
    _same(between_kernel(v), (a, b), m)
    _same(prior_kernel(v), (a,), m)


def test_camera_kernels():
    """Projection with an optimized calibration, a PinholeCamera variable, and stereo with a
    constant and an optimized calibration (points in front, and one behind: NaN both ways)."""
    rng = np.random.default_rng(11)
    poses = [SE3(SO3.exp(rng.normal(size=3) * a), rng.normal(size=3))
             for a in (0.0, 0.4, 1.3, math.pi - 1e-6)]
    points = []
    for p in poses:
        z = rng.uniform(2.0, 6.0)
        points.append(p * np.array([*(rng.uniform(-0.4, 0.4, 2) * z), z]))
    points[-1] = poses[-1] * np.array([0.1, 0.2, -3.0])  # behind the last camera
    P = np.array([p.to_storage() for p in poses])
    X = np.array(points)
    m2 = rng.normal(300.0, 50.0, size=(len(poses), 2))
    K = Cal3DS2(500.0, 480.0, 0.5, 320.0, 240.0, 0.1, -0.05, 0.001, -0.002)
    Ks = np.repeat(K.to_storage()[None], len(poses), axis=0)
    _same(projection_kernel(Cal3DS2, True), (P, X, Ks), m2)
    _same(projection_kernel(Cal3DS2, False), (P, X), np.hstack([m2, Ks]))
    cams = np.array([PinholeCamera(p, Cal3_S2(400.0, 410.0, 0.0, 300.0, 200.0)).to_storage()
                     for p in poses])
    _same(camera_projection_kernel(Cal3_S2), (cams, X), m2)
    S = Cal3_S2Stereo(400.0, 400.0, 0.0, 320.0, 240.0, 0.2)
    Ss = np.repeat(S.to_storage()[None], len(poses), axis=0)
    m3 = rng.normal(300.0, 50.0, size=(len(poses), 3))
    _same(stereo_kernel(True), (P, X, Ss), m3)
    _same(stereo_kernel(False), (P, X), np.hstack([m3, Ss]))


def test_custom_factor_kernel():
    """A ``@fgopt.factor`` kernel (a generated module) gets a trusted entry too."""
    from fgopt.symbolic import Pose2, V2

    @fgopt.factor
    def landmark_offset(pose: Pose2, landmark: V2, measured: V2) -> V2:
        return pose.inverse() * landmark - measured

    rng = np.random.default_rng(2)
    graph, values = fgopt.FactorGraph(), fgopt.Variables()
    for i in range(4):
        values.add(key("x", i), SE2.random(rng))
        values.add(key("l", i), rng.normal(size=2))
        graph.add(landmark_offset(key("x", i), key("l", i), measured=rng.normal(size=2)))
    assert "landmark_offset" in " ".join(_every_batch_same(graph, values))
