"""Tangent-space Jacobians: retraction == chain rule == finite differences, both engines."""

from __future__ import annotations

import numpy as np
import pytest

from fgopt.manifolds import SE2, SE3, SO3
from fgopt.symbolic import (
    V3,
    Pose2,
    Pose3,
    Rot3,
    linearization_program,
    tangent_jacobians,
)
from fgopt.symbolic.ops import storage_of

from ._helpers import evaluator

NUMERIC = {Pose2: SE2, Pose3: SE3, Rot3: SO3}


def _numeric_value(T, rng):
    if T in NUMERIC:
        return NUMERIC[T].random(rng)
    return rng.normal(size=T.storage_dim())


def _retract(T, x, d):
    return x.retract(d) if T in NUMERIC else x + d


def _storage(x):
    return np.asarray(x.to_storage() if hasattr(x, "to_storage") else x, dtype=float)


CASES = {
    "inverse_compose": (lambda a, p: a.inverse() * p, (Pose3, V3)),
    "pose2_between_log": (lambda a, b: a.between(b).log(), (Pose2, Pose2)),
    "rot3_compose_log": (lambda a, b: (a * b).log(), (Rot3, Rot3)),
}


def _numeric_fn(name):
    if name == "inverse_compose":
        return lambda a, p: a.inverse() * p
    if name == "pose2_between_log":
        return lambda a, b: a.between(b).log()
    return lambda a, b: (a * b).log()


@pytest.mark.parametrize("name, engine", [(n, "dag") for n in CASES]
                         + [("inverse_compose", "tree"), ("pose2_between_log", "tree")])
def test_methods_agree_with_each_other_and_fd(name, engine):
    fn, types = CASES[name]
    args = [T.symbolic(f"a{i}") for i, T in enumerate(types)]
    syms = [s for a in args for s in storage_of(a)]
    jacs = {}
    for method in ("retraction", "chain"):
        prog = linearization_program(fn(*args), args, method=method, engine=engine)
        jacs[method] = evaluator(syms, prog, "jac")
    rng = np.random.default_rng(5)
    nfn = _numeric_fn(name)
    for _ in range(3):
        vals = [_numeric_value(T, rng) for T in types]
        flat = np.concatenate([_storage(v) for v in vals])
        r = len(np.atleast_1d(nfn(*vals)))
        J1 = jacs["retraction"](*flat).reshape(r, -1)
        J2 = jacs["chain"](*flat).reshape(r, -1)
        np.testing.assert_allclose(J1, J2, atol=1e-12)
        h, cols = 1e-6, []
        for i, T in enumerate(types):
            for j in range(T.dim()):
                d = np.zeros(T.dim())
                d[j] = h
                plus, minus = list(vals), list(vals)
                plus[i] = _retract(T, vals[i], d)
                minus[i] = _retract(T, vals[i], -d)
                cols.append((np.asarray(nfn(*plus)) - np.asarray(nfn(*minus))) / (2 * h))
        np.testing.assert_allclose(J1, np.stack(cols, axis=1), atol=1e-7)


@pytest.mark.parametrize("T, G", [(Pose3, SE3), (Pose2, SE2)], ids=["Pose3", "Pose2"])
def test_group_valued_function_jacobians_are_adjoints(T, G):
    """d inverse(x) = -Adj(x); d (a*b)/da = Adj(b^-1), d (a*b)/db = I (right perturbations)."""
    a, b = T.symbolic("a"), T.symbolic("b")
    syms = storage_of(a) + storage_of(b)
    (j_inv,) = tangent_jacobians(a.inverse(), [a])
    j_a, j_b = tangent_jacobians(a * b, [a, b]) if T is Pose2 else (None, None)
    ev_inv = evaluator(syms, list(j_inv))
    d = T.dim()
    rng = np.random.default_rng(2)
    for _ in range(3):
        x, y = G.random(rng), G.random(rng)
        vals = list(x.to_storage()) + list(y.to_storage())
        np.testing.assert_allclose(ev_inv(*vals).reshape(d, d), -x.adjoint(), atol=1e-12)
        if j_a is not None:
            ev_a, ev_b = evaluator(syms, list(j_a)), evaluator(syms, list(j_b))
            np.testing.assert_allclose(ev_a(*vals).reshape(d, d), y.inverse().adjoint(),
                                       atol=1e-12)
            np.testing.assert_allclose(ev_b(*vals).reshape(d, d), np.eye(d), atol=1e-12)


def test_hessian_outputs_are_jtj_and_jtr():
    a, p = Pose3.symbolic("a"), V3.symbolic("p")
    prog = linearization_program(a.inverse() * p, [a], hessian=True)
    syms = storage_of(a) + storage_of(p)
    ev = {k: evaluator(syms, prog, k) for k in ("res", "jac", "hess", "rhs")}
    x, q = SE3.random(0), np.array([1.0, -2.0, 0.5])
    vals = list(x.to_storage()) + list(q)
    J = ev["jac"](*vals).reshape(3, 6)
    r = ev["res"](*vals)
    np.testing.assert_allclose(ev["hess"](*vals).reshape(6, 6), J.T @ J, atol=1e-12)
    np.testing.assert_allclose(ev["rhs"](*vals), J.T @ r, atol=1e-12)
