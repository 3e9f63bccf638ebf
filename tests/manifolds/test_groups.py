"""Group axioms, Exp/Log, adjoint, matrices, storage and constructors of the Lie group classes."""

from __future__ import annotations

import copy
import importlib.util
import math
import pickle
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg
from hypothesis import given, settings
from hypothesis import strategies as st

from fgopt.errors import DimensionMismatchError, FgoptError, NonFiniteError
from fgopt.manifolds import (
    SE2,
    SE3,
    SO2,
    SO3,
    InvalidGroupElementError,
    LieGroup,
    Sim3,
    ops_for,
)


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
angles = st.sampled_from(C.SPECIAL_ANGLES)
fast = settings(max_examples=30, deadline=None)


@over_groups
class TestAxioms:
    @fast
    @given(seed=seeds)
    def test_identity(self, G, seed):
        x = G.random(seed)
        e = G.identity()
        C.assert_same(x * e, x)
        C.assert_same(e * x, x)
        assert np.all(e.log() == 0.0)
        assert e.equals(G.exp(np.zeros(G.dim())), 0.0)

    @fast
    @given(seed=seeds)
    def test_inverse(self, G, seed):
        x = G.random(seed)
        C.assert_same(x * x.inverse(), G.identity())
        C.assert_same(x.inverse() * x, G.identity())
        C.assert_same(x.inverse().inverse(), x)

    @fast
    @given(seed=seeds)
    def test_associativity_and_closure(self, G, seed):
        rng = np.random.default_rng(seed)
        a, b, c = G.random(rng), G.random(rng), G.random(rng)
        ab = a * b
        assert type(ab) is G
        C.assert_same(ab * c, a * (b * c))
        q = ab.to_storage()
        if G in (SO2, SE2):
            assert abs(np.hypot(q[0], q[1]) - 1.0) < 1e-15
        else:
            assert abs(np.linalg.norm(q[:4]) - 1.0) < 1e-15
        C.assert_same(a.between(b), a.inverse() * b)
        assert a.compose(b).equals(ab, 0.0)


@over_groups
class TestExpLog:
    @fast
    @given(seed=seeds, angle=angles)
    def test_exp_matches_expm(self, G, seed, angle):
        v = C.random_tangent(G, np.random.default_rng(seed), angle)
        expected = scipy.linalg.expm(C.hat(G, v))
        np.testing.assert_allclose(G.exp(v).matrix(), expected, rtol=0, atol=1e-12 * max(
            1.0, np.max(np.abs(expected))))

    @fast
    @given(seed=seeds, angle=angles)
    def test_exp_log_round_trip(self, G, seed, angle):
        v = C.random_tangent(G, np.random.default_rng(seed), angle)
        x = G.exp(v)
        w = x.log()
        assert np.all(np.isfinite(w))
        rot = np.linalg.norm(C.rotation_part(G, w))
        assert rot <= math.pi + 1e-12
        C.assert_same(G.exp(w), x, 1e-12)
        if angle < math.pi - 1e-6:  # unique logarithm: recovers v itself
            np.testing.assert_allclose(w, v, rtol=0, atol=1e-9)
        if angle == math.pi:
            assert abs(rot - math.pi) < 1e-12

    @fast
    @given(seed=seeds)
    def test_log_exp_random_elements(self, G, seed):
        x = G.random(seed)
        C.assert_same(G.exp(x.log()), x, 1e-12)

    def test_exactly_zero_and_tiny(self, G):
        for eps in (0.0, 1e-300, 1e-12):
            v = np.full(G.dim(), eps)
            x = G.exp(v)
            assert np.all(np.isfinite(x.to_storage()))
            # storing s = e^lambda (not lambda) costs ~1e-16 absolute in lambda
            np.testing.assert_allclose(x.log(), v, rtol=1e-12, atol=1e-15 if G is Sim3 else 1e-300)

    def test_log_picks_shortest_rotation(self, G):
        if G in (SO2, SE2):
            x = G.exp(np.r_[1.5 * math.pi, np.zeros(G.dim() - 1)])
            assert abs(x.log()[0] + 0.5 * math.pi) < 1e-12
            return
        data = G.exp(np.r_[0.3, -0.2, 0.1, np.zeros(G.dim() - 3)]).to_storage()
        flipped = data.copy()
        flipped[:4] *= -1.0  # the same rotation, other sheet of the double cover
        np.testing.assert_allclose(G.from_storage(flipped).log(), G.from_storage(data).log(),
                                   atol=1e-14)
        assert G.from_storage(flipped).equals(G.from_storage(data), 1e-15)


@over_groups
class TestManifold:
    @fast
    @given(seed=seeds)
    def test_retract_local_round_trip(self, G, seed):
        rng = np.random.default_rng(seed)
        x, y = G.random(rng), G.random(rng)
        C.assert_same(x.retract(x.local(y)), y, 1e-9)
        d = C.random_tangent(G, rng, scale=0.3)
        np.testing.assert_allclose(x.local(x.retract(d)), d, atol=1e-9)
        C.assert_same(x.retract(d), x * G.exp(d), 1e-12)
        np.testing.assert_allclose(x.local(y), (x.inverse() * y).log(), atol=1e-12)

    @fast
    @given(seed=seeds)
    def test_adjoint(self, G, seed):
        rng = np.random.default_rng(seed)
        x = G.random(rng)
        v = C.random_tangent(G, rng)
        adj = x.adjoint()
        assert adj.shape == (G.dim(), G.dim())
        C.assert_same(x * G.exp(v), G.exp(adj @ v) * x, 1e-9)
        m = x.matrix()
        np.testing.assert_allclose(C.hat(G, adj @ v), m @ C.hat(G, v) @ np.linalg.inv(m),
                                   atol=1e-10)
        np.testing.assert_allclose(x.inverse().adjoint(), np.linalg.inv(adj), atol=1e-10)

    @fast
    @given(seed=seeds)
    def test_matrix_consistency(self, G, seed):
        rng = np.random.default_rng(seed)
        a, b = G.random(rng), G.random(rng)
        np.testing.assert_allclose((a * b).matrix(), a.matrix() @ b.matrix(), atol=1e-12)
        np.testing.assert_allclose(a.inverse().matrix(), np.linalg.inv(a.matrix()), atol=1e-10)
        k = 2 if G in (SO2, SE2) else 3
        pts = rng.normal(size=(5, k))
        m = a.matrix()
        hom = np.c_[pts, np.ones(5)] if m.shape[0] == k + 1 else pts
        expected = (hom @ m.T)[:, :k]
        np.testing.assert_allclose(a * pts, expected, atol=1e-12)
        np.testing.assert_allclose(a * pts[0], expected[0], atol=1e-12)
        np.testing.assert_allclose(a * list(pts[1]), expected[1], atol=1e-12)
        np.testing.assert_allclose((a * b) * pts, a * (b * pts), atol=1e-10)
        with pytest.raises(DimensionMismatchError):
            a * np.zeros(k + 1)


@over_groups
class TestStorageAndTraits:
    @fast
    @given(seed=seeds)
    def test_storage_round_trip(self, G, seed):
        x = G.random(seed)
        s = x.to_storage()
        assert s.shape == (G.storage_dim(),) and s.dtype == np.float64
        assert G.from_storage(s).equals(x, 0.0)
        s[0] += 1.0  # a copy: the value does not change
        assert G.from_storage(x.to_storage()).equals(x, 0.0)

    def test_dims_on_class_and_instance(self, G):
        x = G.identity()
        assert G.dim() == x.dim() and G.storage_dim() == x.storage_dim()
        assert (G.dim(), G.storage_dim()) == {SO2: (1, 2), SE2: (3, 4), SO3: (3, 4),
                                              SE3: (6, 7), Sim3: (7, 8)}[G]

    def test_immutable(self, G):
        x = G.random(0)
        with pytest.raises(ValueError):
            x._data[0] = 2.0
        with pytest.raises(AttributeError):
            x.foo = 1
        assert copy.deepcopy(x) is x
        y = pickle.loads(pickle.dumps(x))
        assert type(y) is G and y.equals(x, 0.0)

    def test_from_storage_validates_and_normalizes(self, G):
        with pytest.raises(DimensionMismatchError):
            G.from_storage(np.zeros(G.storage_dim() + 1))
        bad = G.identity().to_storage()
        bad[-1] = np.nan
        with pytest.raises(NonFiniteError):
            G.from_storage(bad)
        with pytest.raises(InvalidGroupElementError):
            G.from_storage(np.zeros(G.storage_dim()))
        s = G.random(1).to_storage()
        k = 2 if G in (SO2, SE2) else 4
        s2 = s.copy()
        s2[:k] *= 3.0
        assert G.from_storage(s2).equals(G.from_storage(s), 1e-15)

    def test_registered_traits(self, G):
        x, y = G.random(2), G.random(3)
        ops = ops_for(x)
        kind = ops.batch_kind(x)
        assert kind is G.batch_kind() and kind is ops.batch_kind(y)
        assert (kind.dim, kind.storage_dim, kind.name) == (G.dim(), G.storage_dim(), G.__name__)
        assert ops.dim(x) == G.dim() and ops.storage_dim(x) == G.storage_dim()
        C.assert_same(ops.from_storage(x, ops.to_storage(y)), y, 0.0)
        np.testing.assert_allclose(ops.local(x, y), x.local(y))
        C.assert_same(ops.retract(x, ops.local(x, y)), y)
        C.assert_same(kind.from_storage(kind.to_storage(y)), y, 0.0)

    def test_repr_and_type_errors(self, G):
        r = repr(G.identity())
        assert r.startswith(G.__name__ + "(") and "0.000" in r
        other = SE3 if G is not SE3 else SE2
        with pytest.raises(FgoptError):
            G.identity().compose(other.identity())
        with pytest.raises(DimensionMismatchError):
            G.exp(np.zeros(G.dim() + 1))
        assert not G.identity().equals(other.identity())
        assert isinstance(G.identity(), LieGroup)


class TestConstructors:
    def test_so2(self):
        r = SO2(0.5)
        assert abs(r.theta() - 0.5) < 1e-15 and repr(r) == "SO2(theta=0.500)"
        assert SO2.from_matrix(r.matrix()).equals(r, 1e-15)
        np.testing.assert_allclose(r * np.array([1.0, 0.0]), [math.cos(0.5), math.sin(0.5)])
        with pytest.raises(InvalidGroupElementError):
            SO2.from_matrix(2.0 * np.eye(2))

    def test_se2(self):
        p = SE2.from_xytheta(1.0, 2.0, 0.5)
        assert repr(p) == "SE2(x=1.000, y=2.000, theta=0.500)"
        assert (p.x(), p.y(), p.theta()) == (1.0, 2.0, 0.5)
        assert SE2(SO2(0.5), [1.0, 2.0]).equals(p, 0.0) and SE2(0.5, (1, 2)).equals(p, 0.0)
        assert p.rotation().equals(SO2(0.5), 0.0)
        np.testing.assert_array_equal(p.translation(), [1.0, 2.0])
        assert SE2.from_matrix(p.matrix()).equals(p, 1e-15)
        np.testing.assert_allclose(p * np.zeros(2), [1.0, 2.0])
        assert SE2().equals(SE2.identity(), 0.0)

    def test_so3(self):
        r = SO3.from_quaternion(0.5, 0.5, 0.5, 0.5)  # w, x, y, z
        np.testing.assert_allclose(r.to_storage(), [0.5, 0.5, 0.5, 0.5])
        assert r.quaternion() == (0.5, 0.5, 0.5, 0.5)
        q = SO3.from_quaternion(2.0, 0.0, 0.0, 0.0)
        assert q.quaternion() == (1.0, 0.0, 0.0, 0.0)
        np.testing.assert_allclose(r * np.array([1.0, 0.0, 0.0]), [0.0, 1.0, 0.0], atol=1e-15)
        z90 = SO3.from_axis_angle([0, 0, 2], math.pi / 2)
        np.testing.assert_allclose(z90.matrix(), [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-15)
        assert SO3.from_rotvec([0, 0, math.pi / 2]).equals(z90, 1e-15)
        np.testing.assert_allclose(z90.rotvec(), [0, 0, math.pi / 2])
        with pytest.raises(InvalidGroupElementError):
            SO3.from_matrix(np.diag([1.0, 1.0, -1.0]))
        with pytest.raises(DimensionMismatchError):
            SO3.from_matrix(np.eye(4))

    @settings(max_examples=50, deadline=None)
    @given(seed=seeds, angle=angles)
    def test_so3_from_matrix_all_branches(self, seed, angle):
        v = C.random_tangent(SO3, np.random.default_rng(seed), angle)
        r = SO3.exp(v)
        assert SO3.from_matrix(r.matrix()).equals(r, 1e-14)
        for d in ([1, -1, -1], [-1, 1, -1], [-1, -1, 1]):  # angle pi about each axis
            m = np.diag(np.array(d, dtype=float))
            assert np.allclose(SO3.from_matrix(m).matrix(), m, atol=1e-15)

    def test_se3_and_sim3(self):
        r = SO3.from_rotvec([0.1, -0.2, 0.3])
        p = SE3(r, [1.0, 2.0, 3.0])
        assert p.rotation().equals(r, 0.0)
        np.testing.assert_array_equal(p.translation(), [1.0, 2.0, 3.0])
        assert SE3.from_matrix(p.matrix()).equals(p, 1e-14)
        assert SE3(r.matrix(), [1.0, 2.0, 3.0]).equals(p, 1e-14)
        assert repr(SE3()) == ("SE3(x=0.000, y=0.000, z=0.000, qw=1.000, qx=0.000, qy=0.000, "
                               "qz=0.000)")
        s = Sim3(r, [1.0, 2.0, 3.0], 2.0)
        assert s.scale() == 2.0 and s.rotation().equals(r, 0.0)
        assert Sim3.from_matrix(s.matrix()).equals(s, 1e-14)
        pt = np.array([0.3, 0.2, 0.1])
        np.testing.assert_allclose(s * pt, 2.0 * (r * pt) + [1.0, 2.0, 3.0])
        np.testing.assert_allclose(s.log()[6], math.log(2.0))
        assert "s=2.000" in repr(s)
        with pytest.raises(InvalidGroupElementError):
            Sim3(r, [0, 0, 0], 0.0)
        with pytest.raises(InvalidGroupElementError):
            Sim3(r, [0, 0, 0], -1.0)
        with pytest.raises(InvalidGroupElementError):
            Sim3.from_matrix(-np.eye(4))

    def test_random_accepts_seed_or_generator(self):
        for G in C.GROUPS:
            assert G.random(5).equals(G.random(np.random.default_rng(5)), 0.0)


class TestAgainstGtsam:
    """Differential checks against GTSAM's Pose2 / Pose3 / Rot3 (same charts), when installed."""

    def test_expmap_logmap(self):
        gtsam = pytest.importorskip("gtsam")
        rng = np.random.default_rng(7)
        for angle in C.SPECIAL_ANGLES[:-1]:
            v = C.random_tangent(SE3, rng, angle)
            np.testing.assert_allclose(SE3.exp(v).matrix(), gtsam.Pose3.Expmap(v).matrix(),
                                       atol=1e-12)
            x = SE3.random(rng)
            np.testing.assert_allclose(x.log(), gtsam.Pose3.Logmap(gtsam.Pose3(x.matrix())),
                                       atol=1e-9)
            np.testing.assert_allclose(x.adjoint(), gtsam.Pose3(x.matrix()).AdjointMap(),
                                       atol=1e-12)
            v2 = C.random_tangent(SE2, rng, angle)
            g2 = gtsam.Pose2.Expmap(np.r_[v2[1:], v2[0]])  # GTSAM's Pose2 tangent: [v, theta]
            np.testing.assert_allclose(SE2.exp(v2).matrix(), g2.matrix(), atol=1e-12)


def test_new_and_stored_values_share_one_compiled_element_operation():
    """A new value and a value read from a Variables reach numba with the same array type (both
    read-only), so ``stored * new`` after ``new * new`` compiles no second signature of the
    group's compose (a mix of writable and read-only storage compiled every element operation
    once per combination)."""
    import numba  # noqa: F401 - element operations run compiled once numba is loaded

    from fgopt import Variables
    from fgopt._jit import specialize
    from fgopt.manifolds import _kernels as K

    compose = specialize(K.lie_compose, SE2._GID)
    new = SE2.from_xytheta(1.0, 2.0, 0.3)
    step = SE2.from_xytheta(0.5, 0.0, -0.1)
    expected = (new * step).matrix()
    stored = Variables()
    stored.add(0, new)
    signatures = len(compose.signatures)
    assert np.allclose((stored.at(0) * step).matrix(), expected, atol=1e-12)
    assert np.allclose((step.inverse() * stored.at(0)).matrix(),
                       (step.inverse() * new).matrix(), atol=1e-12)
    assert len(compose.signatures) == max(signatures, 1)
    assert new.to_storage().flags.writeable  # to_storage is still a copy the user owns
