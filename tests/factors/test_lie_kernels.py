"""Between / Prior factor kernels: residuals and exact Jacobians against finite differences."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fgopt.errors import DimensionMismatchError, ManifoldError
from fgopt.factors.kernel import FactorKernel
from fgopt.factors.library.lie_kernels import between_kernel, prior_kernel
from fgopt.manifolds import SCALAR_KIND, SE3, BatchKind, vector_kind


def _load_checks():
    name = "fgopt_tests_manifold_checks"
    if name not in sys.modules:
        path = Path(__file__).resolve().parents[1] / "manifolds" / "_checks.py"
        spec = importlib.util.spec_from_file_location(name, path)
        sys.modules[name] = module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    return sys.modules[name]


C = _load_checks()
over_groups = C.over_groups
seeds = st.integers(0, 2**32 - 1)
#: Rotation angle of the residual: exactly 0, tiny, generic, and near pi (FD steps stay below pi).
residual_angles = st.sampled_from([0.0, 1e-12, 1e-6, 0.3, 2.0, math.pi - 1e-3])


def _between_ref(a, b, m):
    return (m.inverse() * (a.inverse() * b)).log()


def _prior_ref(x, m):
    return (m.inverse() * x).log()


def _row(x):
    return x.to_storage()[None, :]


def _case(G, seed, angle):
    """Random a, b and a measurement m with Log(m^-1 a^-1 b) of rotation angle ``angle``."""
    rng = np.random.default_rng(seed)
    a, b = G.random(rng), G.random(rng)
    err = G.exp(C.random_tangent(G, rng, angle, scale=0.5))
    m = a.between(b) * err.inverse()
    return a, b, m, err


@over_groups
class TestLieKernels:
    @settings(max_examples=20, deadline=None)
    @given(seed=seeds, angle=residual_angles)
    def test_between(self, G, seed, angle):
        a, b, m, _ = _case(G, seed, angle)
        kern = between_kernel(G.batch_kind())
        res, jac = kern.linearize((_row(a), _row(b)), _row(m))
        assert res.shape == (1, G.dim()) and jac.shape == (1, G.dim(), 2 * G.dim())
        np.testing.assert_allclose(res[0], _between_ref(a, b, m), atol=1e-12)
        np.testing.assert_allclose(kern.residual((_row(a), _row(b)), _row(m)), res, atol=0)
        assert np.linalg.norm(C.rotation_part(G, res[0])) == pytest.approx(angle, abs=1e-9)
        for i, off in enumerate(kern.arg_offsets):
            num = C.numerical_jacobian(lambda x, y: _between_ref(x, y, m), [a, b], i)
            C.assert_jacobian_close(jac[0, :, off:off + G.dim()], num)

    @settings(max_examples=20, deadline=None)
    @given(seed=seeds, angle=residual_angles)
    def test_prior(self, G, seed, angle):
        _, x, m, _ = _case(G, seed, angle)
        m = x * G.exp(C.random_tangent(G, np.random.default_rng(seed), angle, 0.5)).inverse()
        kern = prior_kernel(G.batch_kind())
        res, jac = kern.linearize((_row(x),), _row(m))
        np.testing.assert_allclose(res[0], _prior_ref(x, m), atol=1e-12)
        num = C.numerical_jacobian(lambda y: _prior_ref(y, m), [x], 0)
        C.assert_jacobian_close(jac[0], num)

    def test_batched_rows_equal_single_rows(self, G):
        cases = [_case(G, s, ang) for s, ang in enumerate([0.0, 0.1, 1.0, 3.0, 1e-9, 2.5])]
        A = np.concatenate([_row(c[0]) for c in cases])
        B = np.concatenate([_row(c[1]) for c in cases])
        M = np.concatenate([_row(c[2]) for c in cases])
        kern = between_kernel(G.batch_kind())
        res, jac = kern.linearize((A, B), M)
        for i, (a, b, m, _) in enumerate(cases):
            r1, j1 = kern.linearize((_row(a), _row(b)), _row(m))
            np.testing.assert_array_equal(res[i], r1[0])
            np.testing.assert_array_equal(jac[i], j1[0])
        pres, pjac = prior_kernel(G.batch_kind()).linearize((B,), M)
        assert pres.shape == (6, G.dim()) and pjac.shape == (6, G.dim(), G.dim())
        empty = np.zeros((0, G.storage_dim()))
        r0, j0 = kern.linearize((empty, empty), empty)
        assert r0.shape == (0, G.dim()) and j0.shape == (0, G.dim(), 2 * G.dim())

    def test_kernel_object(self, G):
        kind = G.batch_kind()
        kern = between_kernel(kind)
        assert isinstance(kern, FactorKernel) and kern is between_kernel(kind)
        assert kern.name == f"between_{G.__name__.lower()}"
        assert kern.arg_kinds == (kind, kind) and kern.residual_dim == G.dim()
        assert kern.num_constants == G.storage_dim() and kern.tangent_dim == 2 * G.dim()
        pk = prior_kernel(kind)
        assert pk is prior_kernel(kind) and pk.arg_kinds == (kind,) and pk is not kern
        with pytest.raises(DimensionMismatchError):
            kern.residual((np.zeros((2, G.storage_dim())),) * 2, np.zeros((2, G.storage_dim() + 1)))
        with pytest.raises(DimensionMismatchError):
            kern.residual((np.zeros((2, G.storage_dim())),), np.zeros((2, G.storage_dim())))


@pytest.mark.parametrize("kind", [vector_kind(3), vector_kind(1), SCALAR_KIND],
                         ids=lambda k: k.name)
def test_vector_kernels(kind):
    rng = np.random.default_rng(0)
    n, d = 4, kind.dim
    a, b, m = rng.normal(size=(n, d)), rng.normal(size=(n, d)), rng.normal(size=(n, d))
    res, jac = between_kernel(kind).linearize((a, b), m)
    np.testing.assert_allclose(res, (b - a) - m)
    np.testing.assert_array_equal(jac, np.broadcast_to(np.hstack([-np.eye(d), np.eye(d)]),
                                                       (n, d, 2 * d)))
    res, jac = prior_kernel(kind).linearize((a,), m)
    np.testing.assert_allclose(res, a - m)
    np.testing.assert_array_equal(jac, np.broadcast_to(np.eye(d), (n, d, d)))
    np.testing.assert_allclose(between_kernel(kind).residual((a, b), m), (b - a) - m)
    assert between_kernel(kind) is between_kernel(kind)
    assert between_kernel(kind).name == f"between_{kind.name.lower()}"


def test_unknown_kind_is_rejected():
    fake = BatchKind("Fake", 2, 2, retract=None, local=None, from_storage=None, to_storage=None)
    with pytest.raises(ManifoldError, match="Fake"):
        between_kernel(fake)
    with pytest.raises(ManifoldError, match="Fake"):
        prior_kernel(fake)


def test_between_matches_gtsam_pose3():
    """Differential test against GTSAM's BetweenFactorPose3 (same residual and charts)."""
    gtsam = pytest.importorskip("gtsam")
    rng = np.random.default_rng(11)
    for _ in range(5):
        a, b, m = SE3.random(rng), SE3.random(rng), SE3.random(rng)
        values = gtsam.Values()
        values.insert(0, gtsam.Pose3(a.matrix()))
        values.insert(1, gtsam.Pose3(b.matrix()))
        factor = gtsam.BetweenFactorPose3(0, 1, gtsam.Pose3(m.matrix()),
                                          gtsam.noiseModel.Unit.Create(6))
        lin = factor.linearize(values)
        jac_g, rhs = lin.jacobian()
        res, jac = between_kernel(SE3.batch_kind()).linearize((_row(a), _row(b)), _row(m))
        np.testing.assert_allclose(res[0], -rhs, atol=1e-9)
        np.testing.assert_allclose(jac[0], jac_g, atol=1e-9)
