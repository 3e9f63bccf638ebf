"""``@fgopt.factor``: a user-defined factor, its patterns, errors, and a solve with LM."""

from __future__ import annotations

import numpy as np
import pytest

import fgopt
from fgopt.errors import DimensionMismatchError, FgoptError
from fgopt.key import key
from fgopt.manifolds import SE2
from fgopt.symbolic import V2, Pose2, Scalar, atan2

from tests.symbolic._helpers import assert_jacobian_matches_fd


@fgopt.factor
def range_bearing(pose: Pose2, landmark: V2, measured: V2) -> V2:
    """Range and bearing of a landmark seen from a 2-D pose."""
    d = pose.inverse() * landmark
    return V2(d.norm(), atan2(d[1], d[0])) - measured


@fgopt.factor
def pose_prior_xy(pose: Pose2, x: Scalar, y: Scalar) -> V2:
    """Position of a pose minus (x, y); x and y may be constants or scalar variables."""
    return pose.translation() - V2(x, y)


def test_instances_and_kernels():
    f = range_bearing(pose=key("x", 1), landmark=key("l", 3), measured=np.array([4.0, 0.3]),
                      loss=fgopt.noise.Isotropic.sigma(2, 0.1)
                      if hasattr(fgopt.noise.Isotropic, "sigma") else None)
    g = range_bearing(key("x", 2), key("l", 3), [5.0, -0.2])  # positional, a list constant
    assert isinstance(f, fgopt.factors.KernelFactor)
    assert f.kernel is g.kernel  # one kernel per pattern: the two batch together
    assert f.keys == (key("x", 1), key("l", 3)) and f.dim == 2
    np.testing.assert_allclose(f.constants, [4.0, 0.3])
    assert f.describe() == "range_bearing(x1, l3)"
    assert f.kernel.arg_kinds == (SE2.batch_kind(), fgopt.manifolds.vector_kind(2))
    # a different pattern (the landmark known) is a different kernel
    h = range_bearing(key("x", 1), np.array([1.0, 2.0]), np.array([4.0, 0.3]))
    assert h.kernel is not f.kernel and h.kernel.num_constants == 4
    src = range_bearing.source
    assert "# total ops:" in src and "@njit(cache=True" in src and "def _linearize_kernel" in src


def test_values_and_jacobians_match_numpy():
    rng = np.random.default_rng(0)
    f = range_bearing(key("x", 1), key("l", 1), np.array([4.0, 0.3]))
    for _ in range(5):
        pose, lm = SE2.random(rng), rng.normal(size=2) * 3
        args = (np.array([pose.to_storage()]), lm.reshape(1, 2))
        consts = f.constants.reshape(1, -1)
        d = pose.inverse() * lm
        want = np.array([np.linalg.norm(d), np.arctan2(d[1], d[0])]) - [4.0, 0.3]
        np.testing.assert_allclose(f.kernel.residual(args, consts)[0], want, atol=1e-12)
        assert_jacobian_matches_fd(f.kernel, args, consts)


def test_batched_kernel_equals_per_instance():
    rng = np.random.default_rng(1)
    k = range_bearing.kernel(("pose", "landmark"))
    n = 257
    poses = np.array([SE2.random(rng).to_storage() for _ in range(n)])
    lms, meas = rng.normal(size=(n, 2)), rng.normal(size=(n, 2))
    res, jac = k.linearize((poses, lms), meas)
    assert res.shape == (n, 2) and jac.shape == (n, 2, 5)
    for i in (0, 100, n - 1):
        r1, j1 = k.linearize((poses[i:i + 1], lms[i:i + 1]), meas[i:i + 1])
        np.testing.assert_array_equal(r1[0], res[i])
        np.testing.assert_array_equal(j1[0], jac[i])
    np.testing.assert_array_equal(k.residual((poses, lms), meas), res)
    with pytest.raises(DimensionMismatchError):
        k.residual((poses[:, :3], lms), meas)


def test_scalar_arguments_as_variables_or_constants():
    f = pose_prior_xy(key("x", 0), 1.0, 2.0)
    g = pose_prior_xy(key("x", 0), key("s", 0), 2.0)
    assert f.kernel.num_constants == 2 and g.kernel.num_constants == 1
    assert g.kernel.arg_kinds[1] is fgopt.manifolds.SCALAR_KIND
    args = (np.array([[1.0, 0.0, 3.0, 4.0]]), np.array([[0.5]]))
    res, jac = g.kernel.linearize(args, g.constants.reshape(1, -1))
    np.testing.assert_allclose(res[0], [2.5, 2.0])
    np.testing.assert_allclose(jac[0, :, 3], [-1.0, 0.0])


def test_bare_int_is_refused_key_or_const_say_which():
    """``b=1`` for a Scalar argument used to become the constant 1.0 silently (the user may have
    meant the plain-int key 1): a bare int, bool or numpy integer is an FgoptError now; a Key
    makes it a variable, a float or fgopt.const(...) a constant."""
    with pytest.raises(FgoptError, match=r"argument 'x' \(Scalar\) got the int 1.*fgopt.const\(1\)"):
        pose_prior_xy(key("x", 0), 1, 2.0)
    for bad in (np.int64(3), True):
        with pytest.raises(FgoptError, match="could be a key or a number"):
            pose_prior_xy(key("x", 0), 1.0, bad)
    f = pose_prior_xy(key("x", 0), fgopt.const(1), 2.0)
    np.testing.assert_allclose(f.constants, [1.0, 2.0])
    assert f.keys == (key("x", 0),)
    g = pose_prior_xy(key("x", 0), fgopt.Key(7), 2.0)  # a plain-int key, explicitly
    assert g.keys == (key("x", 0), 7) and g.kernel.arg_kinds[1] is fgopt.manifolds.SCALAR_KIND
    with pytest.raises(FgoptError, match="a Key is a variable"):
        fgopt.const(key("s", 1))
    assert repr(fgopt.const(1)) == "fgopt.const(1)"


def test_constants_accept_numeric_group_values():
    @fgopt.factor
    def pose_between(a: Pose2, b: Pose2, measured: Pose2):
        return measured.local(a.between(b))

    m = SE2.from_xytheta(1.0, 0.5, 0.2)
    f = pose_between(key("x", 0), key("x", 1), m)
    np.testing.assert_allclose(f.constants, m.to_storage())
    with pytest.raises(FgoptError, match="SE2"):
        pose_between(key("x", 0), key("x", 1), fgopt.SO2(0.3))


def test_errors_are_clear():
    with pytest.raises(FgoptError, match="missing"):
        range_bearing(key("x", 1), key("l", 1))
    with pytest.raises(FgoptError, match="unknown argument"):
        range_bearing(key("x", 1), key("l", 1), [1.0, 2.0], bogus=3)
    with pytest.raises(FgoptError, match="no argument is a variable"):
        range_bearing(SE2(), np.zeros(2), np.zeros(2))
    with pytest.raises(DimensionMismatchError, match="needs 2 numbers"):
        range_bearing(key("x", 1), key("l", 1), [1.0, 2.0, 3.0])
    with pytest.raises(FgoptError, match="int 5"):
        range_bearing(key("x", 1), 5, [1.0, 2.0])
    with pytest.raises(FgoptError, match="type annotation"):
        fgopt.factor(lambda a, b: a)

    @fgopt.factor
    def branches(x: V2) -> V2:
        if x[0] > 0:  # not allowed: runs once, on symbols
            return x
        return -x

    with pytest.raises(FgoptError, match="branchless"):
        branches(key("x", 9))


def test_user_factor_solved_with_lm():
    """A landmark SLAM toy problem with a user-defined factor, solved through the batched path."""
    rng = np.random.default_rng(2)
    poses = [SE2.from_xytheta(2.0 * i, 0.5 * np.sin(i), 0.3 * i) for i in range(5)]
    landmarks = [np.array([3.0, 4.0]), np.array([6.0, -3.0]), np.array([-1.0, 2.5])]
    graph, initial = fgopt.FactorGraph(), fgopt.Variables()
    graph.add(fgopt.PriorFactor(key("x", 0), poses[0], fgopt.noise.Isotropic.sigma(3, 1e-3)))
    for i, p in enumerate(poses):
        initial.add(key("x", i), p.retract(rng.normal(size=3) * 0.1))
        if i > 0:
            graph.add(fgopt.BetweenFactor(key("x", i - 1), key("x", i), poses[i - 1].between(p),
                                          fgopt.noise.Isotropic.sigma(3, 0.05)))
        for j, lm in enumerate(landmarks):
            d = p.inverse() * lm
            z = np.array([np.linalg.norm(d), np.arctan2(d[1], d[0])])
            graph.add(range_bearing(key("x", i), key("l", j), z,
                                    loss=fgopt.noise.Isotropic.sigma(2, 0.01)))
    for j, lm in enumerate(landmarks):
        initial.add(key("l", j), lm + rng.normal(size=2) * 0.3)
    result = fgopt.optimize(graph, initial, method="lm")
    assert result.success, result
    batches = getattr(result.problem, "batches", None)
    if batches is not None:  # the user factor ran as one batch of 15 through its kernel
        sizes = {b.kernel.name: len(b.source.keys) for b in batches}
        assert sizes.get("range_bearing") == 15, sizes
    assert result.final_cost < 1e-12
    for j, lm in enumerate(landmarks):
        np.testing.assert_allclose(result.values.at(key("l", j)), lm, atol=1e-6)
    for i, p in enumerate(poses):
        np.testing.assert_allclose(result.values.at(key("x", i)).local(p), 0.0, atol=1e-6)


def test_math_functions_compile_and_differentiate():
    from fgopt.symbolic import (
        Abs,
        Max,
        Min,
        acos,
        clamp,
        exp,
        log,
        safe_div,
        sign,
        sin,
        sqrt,
    )

    @fgopt.factor(hessian=True)
    def funky(x: fgopt.symbolic.V3, w: Scalar) -> fgopt.symbolic.V3:
        return fgopt.symbolic.V3(
            sqrt(x[0] ** 2 + w), acos(clamp(x[1], -0.5, 0.5)) + Abs(x[2]) * sign(w),
            log(exp(x[0]) + Max(x[1], w)) + safe_div(x[2], w) + Min(x[0], 0.3) * sin(w))

    f = funky(key("x", 0), key("w", 0))
    args = (np.array([[0.3, 0.2, -0.7]]), np.array([[1.3]]))
    consts = np.zeros((1, 0))
    assert_jacobian_matches_fd(f.kernel, args, consts)
    res, jac, hess, rhs = funky.linearize_hessian(("x", "w"))(args, consts)
    np.testing.assert_allclose(hess[0], jac[0].T @ jac[0], atol=1e-12)
    np.testing.assert_allclose(rhs[0], jac[0].T @ res[0], atol=1e-12)
