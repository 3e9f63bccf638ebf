"""Jacobians of the pose-to-point and BAL kernels against central differences in the tangent
space (the variables' own retract)."""

from __future__ import annotations

import numpy as np
import pytest

from fgopt import Variables, key
from fgopt.factors.base import KernelFactor
from fgopt.factors.library.bal_kernel import bal_kernel
from fgopt.factors.library.pose_point import PosePointFactor, pose_point_kernel
from fgopt.factors.numerical import numerical_jacobians
from fgopt.manifolds import SE2, SE3


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("dim", [2, 3])
def test_pose_point_jacobians_match_central_differences(dim, seed):
    rng = np.random.default_rng(seed)
    pose = (SE2 if dim == 2 else SE3).random(rng)
    values = Variables()
    values.add(key("x", 0), pose)
    values.add(key("l", 0), rng.normal(size=dim) * 3)
    f = PosePointFactor(key("x", 0), key("l", 0), rng.normal(size=dim))
    analytic = f.jacobians(values)
    numeric = numerical_jacobians(f.error, values, f.keys)
    for a, n in zip(analytic, numeric):
        assert np.allclose(a, n, atol=1e-7, rtol=1e-6)
    expected = pose.inverse().act(values.at(key("l", 0))) - f.measured
    assert np.allclose(f.error(values), expected)


def test_pose_point_kernel_is_shared_and_batched():
    assert pose_point_kernel(2) is pose_point_kernel(2)
    rng = np.random.default_rng(0)
    poses = np.array([SE3.random(rng).to_storage() for _ in range(4)])
    pts, m = rng.normal(size=(4, 3)), rng.normal(size=(4, 3))
    res, jac = pose_point_kernel(3).linearize((poses, pts), m)
    assert res.shape == (4, 3) and jac.shape == (4, 3, 9)
    assert np.allclose(pose_point_kernel(3).residual((poses, pts), m), res)


@pytest.mark.parametrize("seed", range(6))
def test_bal_jacobians_match_central_differences(seed):
    rng = np.random.default_rng(seed)
    r = rng.normal(size=3) * (1e-7 if seed == 0 else 0.7)  # seed 0: the small-angle series
    cam = np.concatenate([r, rng.normal(size=2), [-6 + rng.random()], [400 + 100 * rng.random()],
                          rng.normal(size=2) * 0.05])
    values = Variables()
    values.add(key("c", 0), cam)
    values.add(key("p", 0), rng.normal(size=3))
    f = KernelFactor(bal_kernel(), [key("c", 0), key("p", 0)], rng.normal(size=2) * 100)
    analytic = f.jacobians(values)
    numeric = numerical_jacobians(f.error, values, f.keys, delta=1e-6)
    for a, n in zip(analytic, numeric):
        scale = max(1.0, np.abs(a).max())
        assert np.allclose(a, n, atol=1e-6 * scale)


def test_generated_and_hand_written_bal_kernels_agree():
    from fgopt.io import reprojection_kernel

    generated = reprojection_kernel()
    rng = np.random.default_rng(3)
    n = 200
    cam = np.column_stack([rng.normal(size=(n, 3)) * 0.5, rng.normal(size=(n, 2)),
                           -5 - rng.random((n, 1)), 500 + rng.random((n, 1)),
                           rng.normal(size=(n, 2)) * 0.01])
    pt, m = rng.normal(size=(n, 3)), rng.normal(size=(n, 2)) * 100
    r1, j1 = generated.linearize((cam, pt), m)
    r2, j2 = bal_kernel().linearize((cam, pt), m)
    assert np.allclose(r1, r2, rtol=1e-12, atol=1e-9)
    assert np.allclose(j1, j2, rtol=1e-12, atol=1e-9 * np.abs(j2).max())
