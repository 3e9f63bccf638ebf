"""Symbolic geometry agrees with its numeric twins (fgopt.manifolds) at random points."""

from __future__ import annotations

import numpy as np
import pytest

from fgopt.manifolds import SE2, SE3, SO2, SO3
from fgopt.symbolic import (
    M33,
    V1,
    V2,
    V3,
    V4,
    Matrix,
    Pose2,
    Pose3,
    Rot2,
    Rot3,
    Scalar,
    vector_type,
)
from fgopt.symbolic.ops import storage_of

from ._helpers import evaluator

GROUPS = [(Rot2, SO2), (Pose2, SE2), (Rot3, SO3), (Pose3, SE3)]
POINT_DIM = {Rot2: 2, Pose2: 2, Rot3: 3, Pose3: 3}


def _rotation_tangent(G, angle, rng):
    """A tangent vector of group G whose rotation part has the given angle."""
    d = G.dim()
    v = rng.normal(size=d)
    if G in (SO2, SE2):
        v[0] = angle
    else:
        axis = rng.normal(size=3)
        v[:3] = angle * axis / np.linalg.norm(axis)
    return v


def _elements(G, rng, n=6):
    out = [G.random(rng) for _ in range(n)]
    for angle in (0.0, 1e-9, 1e-5, np.pi - 1e-9, np.pi - 1e-4):
        out.append(G.exp(_rotation_tangent(G, angle, rng)))
    return out


@pytest.fixture(scope="module", params=GROUPS, ids=lambda p: p[0].__name__)
def group(request):
    T, G = request.param
    a, b = T.symbolic("a"), T.symbolic("b")
    v = vector_type(T.dim()).symbolic("v")
    p = vector_type(POINT_DIM[T]).symbolic("p")
    syms = storage_of(a) + storage_of(b) + list(v) + list(p)
    exprs = {
        "compose": storage_of(a * b),
        "inverse": storage_of(a.inverse()),
        "between": storage_of(a.between(b)),
        "exp": storage_of(T.exp(v)),
        "log": list(a.log()),
        "act": list(a * p),
        "retract": storage_of(a.retract(v)),
        "local": list(a.local(b)),
        "matrix": list(a.matrix()),
    }
    fns = {k: evaluator(syms, e) for k, e in exprs.items()}
    return T, G, fns


def test_operations_match_numeric(group):
    T, G, fns = group
    rng = np.random.default_rng(7)
    pd = POINT_DIM[T]
    for a in _elements(G, rng):
        b = G.random(rng)
        v = rng.normal(size=G.dim()) * 0.7
        p = rng.normal(size=pd)
        vals = list(a.to_storage()) + list(b.to_storage()) + list(v) + list(p)

        def mat(storage):
            return G.from_storage(storage).matrix()

        np.testing.assert_allclose(mat(fns["compose"](*vals)), a.compose(b).matrix(), atol=1e-12)
        np.testing.assert_allclose(mat(fns["inverse"](*vals)), a.inverse().matrix(), atol=1e-12)
        np.testing.assert_allclose(mat(fns["between"](*vals)), a.between(b).matrix(), atol=1e-12)
        np.testing.assert_allclose(mat(fns["exp"](*vals)), G.exp(v).matrix(), atol=1e-12)
        np.testing.assert_allclose(mat(fns["retract"](*vals)), a.retract(v).matrix(), atol=1e-12)
        np.testing.assert_allclose(fns["act"](*vals), a * p, atol=1e-12)
        np.testing.assert_allclose(fns["matrix"](*vals).reshape(a.matrix().shape), a.matrix(),
                                   atol=1e-12)
        np.testing.assert_allclose(fns["local"](*vals), a.local(b), atol=1e-9)
        # log: equal away from pi; at pi both are valid, so compare through exp
        np.testing.assert_allclose(G.exp(fns["log"](*vals)).matrix(), a.matrix(), atol=1e-9)
        if np.linalg.norm(a.log()[:max(1, G.dim() // 2)]) < np.pi - 1e-6:
            np.testing.assert_allclose(fns["log"](*vals), a.log(), atol=1e-9)


def test_exp_log_near_identity_exact(group):
    """At angle 0 and tiny angles exp/log are exact to rounding (epsilon shifts are harmless)."""
    T, G, fns = group
    rng = np.random.default_rng(3)
    for angle in (0.0, 1e-12, 1e-8):
        v = _rotation_tangent(G, angle, rng)
        x = G.exp(v)
        vals = list(x.to_storage()) * 2 + list(v) + [0.0] * POINT_DIM[T]
        np.testing.assert_allclose(fns["log"](*vals), v, atol=1e-14, rtol=1e-12)
        np.testing.assert_allclose(fns["exp"](*vals), x.to_storage(), atol=1e-14)


@pytest.mark.parametrize("T, G", GROUPS, ids=lambda p: getattr(p, "__name__", ""))
def test_storage_d_tangent(T, G):
    """storage_D_tangent is d S(x * Exp(v)) / dv at 0; tangent_D_storage is a left inverse."""
    x = T.symbolic("x")
    syms = storage_of(x)
    D = evaluator(syms, list(x.storage_D_tangent()))
    Dinv = evaluator(syms, list(x.tangent_D_storage()))
    rng = np.random.default_rng(1)
    for _ in range(4):
        xn = G.random(rng)
        s = xn.to_storage()
        Dn = D(*s).reshape(G.storage_dim(), G.dim())
        h = 1e-6
        fd = np.stack([(xn.retract(h * e).to_storage() - xn.retract(-h * e).to_storage()) / (2 * h)
                       for e in np.eye(G.dim())], axis=1)
        np.testing.assert_allclose(Dn, fd, atol=1e-8)
        np.testing.assert_allclose(Dinv(*s).reshape(G.dim(), -1) @ Dn, np.eye(G.dim()), atol=1e-12)


def test_storage_layouts_match_numeric():
    assert Rot2.identity().to_storage() == [1, 0]
    assert [float(v) for v in Pose3.identity().to_storage()] == list(SE3.identity().to_storage())
    for T, G in GROUPS:
        assert T.storage_dim() == G.storage_dim() and T.dim() == G.dim()


def test_vectors_and_matrices():
    a, b, c = Scalar.symbolic("a"), Scalar.symbolic("b"), Scalar.symbolic("c")
    v = V3(a, b, c)
    assert V3([a, b, c]).to_storage() == v.to_storage()
    assert V3().to_storage() == [0, 0, 0]
    assert v[1] == b and v.y == b and len(v) == 3
    w = V3(1, 2, 3)
    assert isinstance(v + w, V3) and isinstance(2 * v, V3) and isinstance(v / 2, V3)
    assert (v.dot(w) - (a + 2 * b + 3 * c)).expand() == 0
    assert list(V3(1, 0, 0).cross(V3(0, 1, 0))) == [0, 0, 1]
    m = M33([[1, 2, 3], [4, 5, 6], [7, 8, 10]])
    assert isinstance(m * w, V3) and list(m * w) == [14, 32, 53]
    assert isinstance(m.T, M33) and m.T[0, 1] == 4
    assert isinstance(v[0:2], V2)
    assert float(V2(3, 4).norm(epsilon=0)) == 5.0
    n = V2(3, 4).normalized()
    import fgopt.symbolic as fs

    assert abs(float(n[0].subs(fs.epsilon, 0)) - 0.6) < 1e-15
    assert V4.storage_dim() == 4 and isinstance(V1(a), V1)
    assert Matrix([[1, 2], [3, 4]]).shape == (2, 2)
    with pytest.raises(ValueError):
        V3(1, 2)
    assert [float(x) for x in V3.from_storage(np.array([1.0, 2.0, 3.0]))] == [1, 2, 3]
    assert V3(np.arange(3)).to_storage() == [0, 1, 2]
