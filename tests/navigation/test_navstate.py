"""NavState: GTSAM's chart and SE_2(3) group, batched kernels, Variables, the symbolic twin."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest

import fgopt
from fgopt import Variables, key
from fgopt.errors import FgoptError, ManifoldError
from fgopt.factors import numerical_jacobians
from fgopt.manifolds import SE3, SO3, ops_for
from fgopt.navigation import ImuBias, NavState


def _load_helpers():
    name = "fgopt_tests_navigation_helpers"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, Path(__file__).with_name("_nav.py"))
        mod = importlib.util.module_from_spec(spec)
        sys.modules[name] = mod
        spec.loader.exec_module(mod)
    return sys.modules[name]


N = _load_helpers()


def test_retract_local_round_trip_and_layout():
    """local(a, retract(a, d)) == d (rotation below pi), storage [q, p, v], identity, accessors."""
    rng = np.random.default_rng(0)
    for angle in N.SPECIAL_ANGLES[:-1]:
        a = NavState.random(rng)
        d = rng.normal(size=9)
        d[:3] = d[:3] / np.linalg.norm(d[:3]) * angle
        b = a.retract(d)
        assert np.allclose(a.local(b), d, atol=1e-10)
        assert a.retract(a.local(b)).equals(b, 1e-12)
    x = NavState(SO3.from_rotvec([0.1, 0.2, 0.3]), [1, 2, 3], [4, 5, 6])
    s = x.to_storage()
    assert np.allclose(s[:4], SO3.from_rotvec([0.1, 0.2, 0.3]).to_storage())
    assert np.allclose(s[4:], [1, 2, 3, 4, 5, 6])
    assert NavState.from_storage(s).equals(x, 0.0)
    assert np.allclose(x.body_velocity(), x.rotation().T @ [4, 5, 6])
    assert x.pose().equals(SE3(SO3.from_rotvec([0.1, 0.2, 0.3]), [1, 2, 3]))
    assert NavState.from_pose_velocity(x.pose(), [4, 5, 6]).equals(x, 0.0)
    assert np.allclose(NavState.identity().matrix(), np.eye(5))
    assert "NavState(p=[1.000, 2.000, 3.000]" in repr(x)


def test_chart_and_group_equal_gtsam():
    """retract / local equal GTSAM's NavState retract / localCoordinates; exp, log, compose,
    between-log equal Expmap, Logmap, compose, logmap -- at random states, rotations up to pi."""
    gtsam = pytest.importorskip("gtsam")
    rng = np.random.default_rng(1)
    for angle in N.SPECIAL_ANGLES:
        a, b = NavState.random(rng), NavState.random(rng)
        ga, gb = N.navstate(gtsam, a), N.navstate(gtsam, b)
        xi = rng.normal(size=9)
        xi[:3] = xi[:3] / np.linalg.norm(xi[:3]) * angle
        r, gr = a.retract(xi), ga.retract(xi)
        assert np.allclose(r.rotation(), gr.attitude().matrix(), atol=1e-12)
        assert np.allclose(r.position(), gr.position(), atol=1e-12)
        assert np.allclose(r.velocity(), gr.velocity(), atol=1e-12)
        assert np.allclose(a.local(b), ga.localCoordinates(gb), atol=1e-9)
        e, ge = NavState.exp(xi), gtsam.NavState.Expmap(xi)
        assert np.allclose(e.rotation(), ge.attitude().matrix(), atol=1e-12)
        assert np.allclose(e.position(), ge.position(), atol=1e-12)
        assert np.allclose(e.velocity(), ge.velocity(), atol=1e-12)
        if angle < math.pi - 1e-6:  # at pi the axis sign is ambiguous
            assert np.allclose(e.log(), gtsam.NavState.Logmap(ge), atol=1e-8)
        c, gc = a * b, ga.compose(gb)
        assert np.allclose(c.position(), gc.position(), atol=1e-12)
        assert np.allclose(c.velocity(), gc.velocity(), atol=1e-12)
        assert np.allclose(a.between(b).log(), ga.logmap(gb), atol=1e-9)


def test_batched_kernels_equal_elementwise():
    """The BatchKind's (n, 10) retract / local loops equal the per-value methods."""
    rng = np.random.default_rng(2)
    xs = [NavState.random(rng) for _ in range(7)]
    ys = [NavState.random(rng) for _ in range(7)]
    kind = NavState.batch_kind()
    X = np.array([x.to_storage() for x in xs])
    Y = np.array([y.to_storage() for y in ys])
    D = rng.normal(size=(7, 9))
    R = kind.retract(X, D)
    L = kind.local(X, Y)
    for i in range(7):
        assert np.allclose(R[i], xs[i].retract(D[i]).to_storage(), atol=1e-14)
        assert np.allclose(L[i], xs[i].local(ys[i]), atol=1e-14)
    assert (kind.dim, kind.storage_dim) == (9, 10)
    assert ops_for(xs[0]).batch_kind(xs[0]) is kind


def test_navstate_and_bias_as_variables():
    """NavState values live in Variables and optimize (a prior pulls them to the target);
    ImuBias values are stored as 6-vectors."""
    from fgopt.symbolic import NavState as SymNavState
    from fgopt.symbolic import V9

    @fgopt.factor
    def navstate_prior(x: SymNavState, prior: SymNavState) -> V9:
        return prior.local(x)

    rng = np.random.default_rng(3)
    target, start = NavState.random(rng), NavState.random(rng)
    graph, initial = fgopt.FactorGraph(), Variables()
    graph.add(navstate_prior(x=key("n", 0), prior=target))
    graph.add(fgopt.PriorFactor(key("b", 0), np.arange(6.0)))
    initial.add(key("n", 0), start)
    initial.add(key("b", 0), ImuBias([1, 1, 1], [0, 0, 0]))
    result = fgopt.optimize(graph, initial)
    assert result.values.at(key("n", 0)).equals(target, 1e-8)
    assert np.allclose(result.values.at(key("b", 0)), np.arange(6.0))
    assert initial.at(key("n", 0)) is start  # caller's values untouched


def test_imu_bias():
    """ImuBias: accelerometer then gyroscope, arithmetic, correction, errors."""
    b = ImuBias([1, 2, 3], [4, 5, 6])
    assert np.allclose(b.vector(), [1, 2, 3, 4, 5, 6])
    assert np.allclose(np.asarray(b), b.vector())
    assert np.allclose((b - b).vector(), 0)
    assert np.allclose(b.correct_accelerometer([1, 1, 1]), [0, -1, -2])
    assert np.allclose(b.correct_gyroscope([4, 5, 6]), 0)
    assert ImuBias.from_vector(b.vector()).equals(b)
    with pytest.raises(FgoptError, match="6 numbers"):
        ImuBias.as_vector([1, 2, 3])
    with pytest.raises(AttributeError):
        b.x = 1


def test_bad_values():
    """Wrong inputs raise FgoptError subclasses naming the problem."""
    with pytest.raises(FgoptError, match="NavState position"):
        NavState(None, [1, 2], [0, 0, 0])
    with pytest.raises(FgoptError, match="non-finite|NaN|inf"):
        NavState(None, [np.nan, 0, 0], [0, 0, 0])
    with pytest.raises(ManifoldError):
        NavState().local(SE3())
    with pytest.raises(FgoptError, match="cannot normalize"):
        NavState.from_storage(np.zeros(10))


# ----------------------------------------------------------------------------- symbolic twin
def test_symbolic_twin_matches_numeric():
    """fgopt.symbolic.NavState: storage, exp, log, compose, retract, local equal the numeric
    NavState (evaluated at numbers)."""
    from fgopt.symbolic import NavState as SN

    rng = np.random.default_rng(4)
    a, b = NavState.random(rng), NavState.random(rng)
    xi = rng.normal(size=9)
    sa, sb = SN.from_storage(list(a.to_storage())), SN.from_storage(list(b.to_storage()))

    def num(values):
        return np.array([float(v) for v in values])

    assert np.allclose(num(SN.exp(list(xi), epsilon=0).to_storage()),
                       NavState.exp(xi).to_storage(), atol=1e-12)
    assert np.allclose(num(sa.between(sb).log(epsilon=0)), a.between(b).log(), atol=1e-10)
    assert np.allclose(num(sa.compose(sb).to_storage()), (a * b).to_storage(), atol=1e-12)
    assert np.allclose(num(sa.retract(list(xi), epsilon=0).to_storage()),
                       a.retract(xi).to_storage(), atol=1e-12)
    assert np.allclose(num(sa.local(sb, epsilon=0)), a.local(b), atol=1e-10)
    assert np.allclose(num(sa.body_velocity()), a.body_velocity(), atol=1e-12)


@pytest.mark.parametrize("angle", N.FD_ANGLES)
def test_symbolic_twin_factor_jacobians(angle):
    """A between factor written over the symbolic NavState: residual equals the numeric
    definition, generated tangent Jacobians equal central differences through NavState's
    retraction, at relative rotations near 0 and near pi."""
    from fgopt.symbolic import NavState as SN
    from fgopt.symbolic import V9

    @fgopt.factor
    def navstate_between(a: SN, b: SN, measured: SN) -> V9:
        return measured.local(a.between(b))

    rng = np.random.default_rng(5)
    a = NavState.random(rng)
    m = NavState.random(rng)
    # a^-1 b = m * (rotation of `angle`), so the residual's rotation has exactly that angle
    rel = m.compose(NavState(N.rotation_with_angle(rng, angle), rng.normal(size=3),
                             rng.normal(size=3)))
    b = a * rel
    values = Variables()
    values.add(key("x", 0), a)
    values.add(key("x", 1), b)
    f = navstate_between(a=key("x", 0), b=key("x", 1), measured=m)
    assert np.allclose(f.error(values), m.local(a.between(b)), atol=1e-9)
    for Ja, Jn in zip(f.jacobians(values), numerical_jacobians(f.error, values, f.keys)):
        assert np.allclose(Ja, Jn, atol=1e-6)
