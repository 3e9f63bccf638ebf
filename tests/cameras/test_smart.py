"""SmartProjectionFactor: error and Schur-complement linearization equal GTSAM's
SmartProjectionPoseFactor, the gradient equals central differences of the eliminated cost
(rotations near pi), the degenerate-track policy, bad input."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest

import fgopt
from fgopt import PriorFactor, Variables, key
from fgopt.cameras import (Cal3_S2, Cal3DS2, PinholeCamera, ProjectionFactor,
                           SmartProjectionFactor)
from fgopt.errors import DimensionMismatchError, FgoptError, NonFiniteError, TriangulationError
from fgopt.manifolds import SE3, SO3
from fgopt.noise import Huber, Isotropic


def _helpers():
    name = "fgopt_tests_camera_helpers"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, Path(__file__).with_name("_helpers.py"))
        sys.modules[name] = mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
    return sys.modules[name]


H = _helpers()
X = lambda i: key("x", i)  # noqa: E731


def _track(rng, K, m=4, noise=1.0):
    """``m`` cameras looking at a landmark ~8 units away, and its noisy pixels."""
    L = np.array([0.2, 0.1, 8.0])
    poses = [PinholeCamera.lookat(rng.normal(size=3), L + rng.normal(size=3) * 0.3, [0, -1, 0],
                                  K).pose() for _ in range(m)]
    ms = np.array([PinholeCamera(p, K).project(L) for p in poses])
    return poses, ms + rng.normal(size=(m, 2)) * noise


def _gtsam_smart(K, ms, sigma):
    import gtsam

    sf = getattr(gtsam, f"SmartProjectionPoseFactor{type(K).__name__}")(
        gtsam.noiseModel.Isotropic.Sigma(2, sigma), H.gtsam_calibration(K))
    for i, z in enumerate(ms):
        sf.add(z, X(i))
    return sf


def _values(poses):
    import gtsam

    v, gv = Variables(), gtsam.Values()
    for i, p in enumerate(poses):
        v.add(X(i), p)
        gv.insert(X(i), H.gtsam_pose(p))
    return v, gv


def test_error_and_hessian_equal_gtsam_smart_factor():
    """0.5|r|^2 equals GTSAM's SmartProjectionPoseFactor error and (J^T J, -J^T r, r^T r) its
    linearized Hessian factor [G g; g^T f] (relative 1e-9), for 2..6 views."""
    gtsam = pytest.importorskip("gtsam")
    rng = np.random.default_rng(51)
    K = Cal3_S2(500, 510, 0.2, 320, 240)
    for m in (2, 3, 6):
        poses, ms = _track(rng, K, m)
        f = SmartProjectionFactor([X(i) for i in range(m)], ms, K, Isotropic.sigma(2, 2.0))
        sf = _gtsam_smart(K, ms, 2.0)
        v, gv = _values(poses)
        assert f.cost(v) == pytest.approx(sf.error(gv), rel=1e-9)
        r = f.error(v)
        J = np.concatenate(f.jacobians(v), axis=1)
        A = sf.linearize(gv).augmentedInformation()
        scale = np.abs(A).max()
        np.testing.assert_allclose(J.T @ J, A[:-1, :-1], atol=1e-9 * scale)
        np.testing.assert_allclose(-J.T @ r, A[:-1, -1], atol=1e-9 * scale)
        assert r @ r == pytest.approx(A[-1, -1], rel=1e-9)
        gp = sf.point(gv)
        assert gp.valid()
        np.testing.assert_allclose(f.point(v), gp.get(), atol=1e-9)


def test_distorted_calibration_equals_gtsam_to_its_undistortion_tolerance():
    """With Cal3DS2, GTSAM undistorts pixels to 1e-5 px before the DLT: error agrees to 1e-5."""
    pytest.importorskip("gtsam")
    rng = np.random.default_rng(52)
    K = Cal3DS2(500, 510, 0.2, 320, 240, 0.05, -0.01, 0.001, 0.002)
    poses, ms = _track(rng, K, 5)
    f = SmartProjectionFactor([X(i) for i in range(5)], ms, K, Isotropic.sigma(2, 1.0))
    v, gv = _values(poses)
    assert f.cost(v) == pytest.approx(_gtsam_smart(K, ms, 1.0).error(gv), rel=1e-5)


@pytest.mark.parametrize("angle", [0.3, math.pi - 1e-4, math.pi])
def test_gradient_equals_central_differences_of_the_eliminated_cost(angle):
    """With triangulation='nonlinear' the factor's cost is min over the landmark of the track's
    reprojection error, whose gradient (envelope theorem) is F^T Q b = J^T r: it equals central
    differences of the cost through each pose's retract, with camera rotations near ``angle``;
    and the DLT cost is never below it."""
    rng = np.random.default_rng(53)
    K = Cal3DS2(500, 510, 0.2, 320, 240, 0.05, -0.01, 0.001, 0.002)
    L = np.array([0.2, 0.1, 8.0])
    axis = rng.normal(size=3)
    Rw = SE3(SO3.exp(axis / np.linalg.norm(axis) * angle))
    poses = [Rw * PinholeCamera.lookat(rng.normal(size=3), L + rng.normal(size=3) * 0.3,
                                       [0, -1, 0], K).pose() for _ in range(4)]
    ms = np.array([PinholeCamera(p, K).project(Rw * L) for p in poses]) + rng.normal(size=(4, 2))
    keys = [X(i) for i in range(4)]
    f = SmartProjectionFactor(keys, ms, K, Isotropic.sigma(2, 1.5), triangulation="nonlinear")
    v = Variables({k: p for k, p in zip(keys, poses)})
    r = f.error(v)
    g = np.concatenate(f.jacobians(v), axis=1).T @ r
    h = 1e-6
    num = []
    for i, k in enumerate(keys):
        for c in range(6):
            d = np.zeros(6)
            d[c] = h
            vp, vm = v.copy(), v.copy()
            vp.update(k, poses[i].retract(d))
            vm.update(k, poses[i].retract(-d))
            num.append((f.cost(vp) - f.cost(vm)) / (2 * h))
    np.testing.assert_allclose(g, num, rtol=1e-5, atol=1e-6 * max(1.0, np.abs(g).max()))
    dlt = SmartProjectionFactor(keys, ms, K, Isotropic.sigma(2, 1.5))
    assert f.cost(v) <= dlt.cost(v) + 1e-12


def test_schur_complement_equals_explicit_landmark_elimination():
    """J^T J and J^T r equal eliminating the landmark from the stacked ProjectionFactor
    Jacobians ([F E] at the triangulated point): F^T Q F and F^T Q b, Q = I - E (E^T E)^-1 E^T."""
    rng = np.random.default_rng(54)
    K = Cal3DS2(480, 470, 0.0, 300, 200, -0.03, 0.004, 0.0, 0.001)
    poses, ms = _track(rng, K, 5)
    keys = [X(i) for i in range(5)]
    noise = Isotropic.sigma(2, 0.7)
    f = SmartProjectionFactor(keys, ms, K, noise)
    v = Variables({k: p for k, p in zip(keys, poses)})
    Lp = f.point(v)
    v.add(key("l", 0), Lp)
    rows_F, rows_E, b = [], [], []
    for i, k in enumerate(keys):
        pf = ProjectionFactor(k, key("l", 0), ms[i], noise, K)
        Jp, Jl = pf.jacobians(v)
        rows_F.append(np.hstack([Jp if j == i else np.zeros((2, 6)) for j in range(5)]) / 0.7)
        rows_E.append(Jl / 0.7)
        b.append(pf.error(v) / 0.7)
    F, E, b = np.vstack(rows_F), np.vstack(rows_E), np.concatenate(b)
    Q = np.eye(10) - E @ np.linalg.solve(E.T @ E, E.T)
    r = f.error(v)
    J = np.concatenate(f.jacobians(v), axis=1)
    np.testing.assert_allclose(J.T @ J, F.T @ Q @ F, atol=1e-8 * np.abs(F.T @ F).max())
    np.testing.assert_allclose(J.T @ r, F.T @ Q @ b, atol=1e-8 * np.abs(F.T @ F).max())
    assert r @ r == pytest.approx(b @ b, rel=1e-12)


def test_degenerate_track_policy():
    """Parallel rays (two views from one centre, pure rotation): 'reject' makes graph.error NaN
    and optimize raise naming the smart factor and the cause; 'zero' drops the factor."""
    K = Cal3_S2(500, 500, 0, 320, 240)
    poses = [SE3(), SE3(SO3.exp([0.0, 0.05, 0.0]))]
    L = np.array([0.3, 0.2, 5.0])
    ms = np.array([PinholeCamera(p, K).project(L) for p in poses])
    g = fgopt.FactorGraph()
    g.add(SmartProjectionFactor([X(0), X(1)], ms, K))
    for i in range(2):
        g.add(PriorFactor(X(i), poses[i], Isotropic.sigma(6, 0.1)))
    v = Variables({X(0): poses[0], X(1): poses[1]})
    assert math.isnan(g.error(v))
    with pytest.raises(NonFiniteError, match=r"smart_cal3_s2_2views\(x0, x1\).*triangulated"):
        fgopt.optimize(g, v)
    zero = SmartProjectionFactor([X(0), X(1)], ms, K, degenerate="zero")
    assert zero.cost(v) == 0.0
    assert not np.any(np.concatenate(zero.jacobians(v), axis=1))
    assert zero.point(v) is None


def test_degenerate_policy_is_per_factor_in_one_kernel():
    """The degenerate policy is a constant of each factor, not of the kernel: tracks of both
    policies share one kernel (one batch, one small-problem driver), and in one batch call each
    row follows its own policy (zero residual and Jacobian / NaN) whichever row comes first."""
    K = Cal3_S2(500, 500, 0, 320, 240)
    poses = [SE3(), SE3(SO3.exp([0.0, 0.05, 0.0]))]  # one centre: every track degenerate
    ms = np.array([PinholeCamera(p, K).project(np.array([0.3, 0.2, 5.0])) for p in poses])
    zero = SmartProjectionFactor([X(0), X(1)], ms, K, degenerate="zero")
    reject = SmartProjectionFactor([X(0), X(1)], ms, K)
    assert zero.kernel is reject.kernel
    args = tuple(np.stack([p.to_storage()] * 2) for p in poses)
    for order in ((zero, reject), (reject, zero)):
        consts = np.stack([f.constants for f in order])
        res, jac = zero.kernel.linearize(args, consts)
        for i, f in enumerate(order):
            if f is zero:
                assert not np.any(res[i]) and not np.any(jac[i])
            else:
                assert np.all(np.isnan(res[i]))


def test_bad_input_is_named():
    """One view, NaN pixels, wrong shapes, a calibration key, a robust loss and unknown options
    raise FgoptError naming the factor (and index)."""
    K = Cal3_S2(500, 500, 0, 320, 240)
    with pytest.raises(TriangulationError, match=r"SmartProjectionFactor\(x4\).*two views"):
        SmartProjectionFactor([X(4)], [[1.0, 2.0]], K)
    with pytest.raises(NonFiniteError, match=r"measurement 1 \(of x1\)"):
        SmartProjectionFactor([X(0), X(1)], [[1.0, 2.0], [np.inf, 2.0]], K)
    with pytest.raises(DimensionMismatchError):
        SmartProjectionFactor([X(0), X(1)], [[1.0, 2.0]], K)
    with pytest.raises(FgoptError, match="constant Calibration"):
        SmartProjectionFactor([X(0), X(1)], np.zeros((2, 2)), key("k", 0))
    with pytest.raises(FgoptError, match="robust"):
        SmartProjectionFactor([X(0), X(1)], np.zeros((2, 2)), K, Huber(1.0, Isotropic.sigma(2, 1)))
    with pytest.raises(FgoptError, match="degenerate"):
        SmartProjectionFactor([X(0), X(1)], np.zeros((2, 2)), K, degenerate="ignore")
    with pytest.raises(FgoptError, match="repeated key"):
        SmartProjectionFactor([X(0), X(0)], np.zeros((2, 2)), K)


def _assembled(problem, state, structured: bool):
    """``(H_data, g, cost)`` of ``problem`` at ``state``: through the smart kernels' direct
    Hessian assembly, or (``structured=False``) through their residual / Jacobian + scatter."""
    import dataclasses

    saved = [b.kernel for b in problem.batches]
    calls = []

    def counted(fn):
        return lambda *args: calls.append(1) or fn(*args)

    for b in problem.batches:
        if b.kernel.scatter_hessian is not None:
            b.kernel = dataclasses.replace(
                b.kernel, scatter_hessian=counted(b.kernel.scatter_hessian) if structured else None)
    try:
        H, g = np.zeros_like(problem.H_data), np.zeros_like(problem.g)
        cost = problem._linearize_into(state, H, g)
    finally:
        for b, k in zip(problem.batches, saved):
            b.kernel = k
    assert bool(calls) == structured  # the path under test was taken
    return H, g, cost


def _smart_scene(rng, K, num_poses, track_sizes, **problem_options):
    """A compiled problem: ``num_poses`` cameras looking at (0, 0, 8), one noisy smart factor
    per entry of ``track_sizes`` (that many views of a point near (0, 0, 8)), a prior on x0."""
    from fgopt.problem import Problem

    poses = [PinholeCamera.lookat(c, [0.0, 0.0, 8.0] + rng.normal(size=3) * 0.3, [0, -1, 0],
                                  K).pose() for c in rng.normal(size=(num_poses, 3))]
    g = fgopt.FactorGraph()
    for m in track_sizes:
        views = rng.choice(num_poses, size=m, replace=False)
        L = np.array([0.0, 0.0, 8.0]) + rng.normal(size=3)
        ms = np.array([PinholeCamera(poses[i], K).project(L) for i in views])
        g.add(SmartProjectionFactor([X(int(i)) for i in views], ms + rng.normal(size=(m, 2)),
                                    K, Isotropic.sigma(2, 1.5)))
    g.add(PriorFactor(X(0), poses[0], Isotropic.sigma(6, 0.1)))
    return Problem(g, Variables({X(i): p for i, p in enumerate(poses)}), **problem_options)


def _assert_same_assembly(problem):
    """Direct and generic assembly agree at the problem's initial state (1e-10 relative)."""
    state = problem.initial_state()
    H1, g1, c1 = _assembled(problem, state, True)
    H0, g0, c0 = _assembled(problem, state, False)
    assert c1 == pytest.approx(c0, rel=1e-12)
    np.testing.assert_allclose(H1, H0, rtol=0, atol=1e-10 * np.abs(H0).max())
    np.testing.assert_allclose(g1, g0, rtol=0, atol=1e-10 * max(1.0, np.abs(g0).max()))


@pytest.mark.parametrize("model", ["s2", "ds2"])
def test_direct_hessian_assembly_equals_the_jacobian_scatter(model, monkeypatch):
    """The smart kernels' direct assembly (blocks F_i^T F_i - V_i V_j^T, no dense (2m-3) x 6m
    Jacobian) gives the same H, g and cost as the generic J^T J / J^T r scatter of their
    residual and Jacobian (1e-10 relative), for tracks of 2..7 views sharing poses, including
    one degenerate track under 'zero' (adds nothing) and 'reject' (cost NaN)."""
    from fgopt import _jit
    from fgopt.problem import Problem

    monkeypatch.setattr(_jit, "NUMPY_BUDGET_SECONDS", 0.0)  # numba assembly, where it applies
    rng = np.random.default_rng(55)
    K = (Cal3_S2(500, 510, 0.2, 320, 240) if model == "s2"
         else Cal3DS2(500, 510, 0.2, 320, 240, 0.05, -0.01, 0.001, 0.002))
    _assert_same_assembly(_smart_scene(rng, K, 9, [2 + t % 6 for t in range(12)]))

    # one degenerate track (two views from one centre) among good ones
    bad = [SE3(), SE3(SO3.exp([0.0, 0.05, 0.0]))]
    Lb = np.array([0.3, 0.2, 5.0])
    msb = np.array([PinholeCamera(p, K).project(Lb) for p in bad])
    for policy in ("zero", "reject"):
        g2 = fgopt.FactorGraph()
        g2.add(SmartProjectionFactor([X(0), X(1)], msb, K, degenerate=policy))
        g2.add(SmartProjectionFactor([X(1), X(0)], msb[::-1] + 3.0, K, degenerate=policy))
        for i in range(2):
            g2.add(PriorFactor(X(i), bad[i], Isotropic.sigma(6, 0.1)))
        p2 = Problem(g2, Variables({X(0): bad[0], X(1): bad[1]}))
        if policy == "zero":
            _assert_same_assembly(p2)
        else:
            s2 = p2.initial_state()
            assert math.isnan(_assembled(p2, s2, True)[2])
            assert math.isnan(_assembled(p2, s2, False)[2])


def test_direct_hessian_assembly_is_taken_with_threads(monkeypatch):
    """With threads=2 on a batch large enough for the threaded path (>= PARALLEL_MIN_BATCH
    tracks), the direct assembly is still used (serial: measured 3.5x faster than the parallel
    dense J^T J) and equals the threaded generic path's H, g and cost."""
    from fgopt import _jit
    from fgopt._threads import PARALLEL_MIN_BATCH

    monkeypatch.setattr(_jit, "NUMPY_BUDGET_SECONDS", 0.0)
    rng = np.random.default_rng(56)
    K = Cal3_S2(500, 510, 0.2, 320, 240)
    _assert_same_assembly(_smart_scene(rng, K, 6, [3] * (PARALLEL_MIN_BATCH + 8), threads=2))
