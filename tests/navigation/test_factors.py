"""ImuFactor, CombinedImuFactor, GpsFactor: residuals equal GTSAM's evaluateError, Jacobians
equal central differences (rotation errors near 0 and pi), one kernel call per batch."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

import fgopt
from fgopt import Variables, key
from fgopt.errors import FgoptError
from fgopt.factors import numerical_jacobians
from fgopt.manifolds import SE3
from fgopt.navigation import (CombinedImuFactor, GpsFactor, ImuBias, ImuFactor, NavState,
                              PreintegratedCombinedImu, PreintegratedImu)
from fgopt.navigation.factors import imu_kernel
from fgopt.noise import Isotropic


def _load_helpers():
    name = "fgopt_tests_navigation_helpers"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, Path(__file__).with_name("_nav.py"))
        mod = importlib.util.module_from_spec(spec)
        sys.modules[name] = mod
        spec.loader.exec_module(mod)
    return sys.modules[name]


N = _load_helpers()
X, V, B = (lambda i: key("x", i)), (lambda i: key("v", i)), (lambda i: key("b", i))
CASES = {  # name: (body_P_sensor, omega_coriolis)
    "plain": (None, None),
    "sensor_coriolis": (N.SENSOR, [0.02, -0.01, 0.03]),
}


def _pim(rng, combined, error_mode="logmap", case="plain", n=100):
    sensor, omega = CASES[case]
    params = N.fgopt_params(combined, sensor, omega, error_mode)
    pim = (PreintegratedCombinedImu if combined else PreintegratedImu)(params, N.BIAS_HAT)
    acc, gyro, dt = N.samples(rng, n, rate=0.5)
    return pim.integrate(acc, gyro, dt), (acc, gyro, dt)


def _states(rng, pim, angle=None, bias=None):
    """A random state i and a state j near the prediction with ``bias`` (default bias_hat):
    rotation error ``angle`` if given."""
    xi = NavState.random(rng)
    pred = pim.predict(xi, pim.bias_hat if bias is None else bias)
    rot = (N.rotation_with_angle(rng, angle) if angle is not None
           else N.rotation_with_angle(rng, 0.4))
    xj = NavState(pred.attitude().compose(rot.inverse()),
                  pred.position() + 0.3 * rng.normal(size=3),
                  pred.velocity() + 0.3 * rng.normal(size=3))
    return xi, xj


@pytest.mark.parametrize("error_mode", ["logmap", "component_wise"])
@pytest.mark.parametrize("combined", [False, True], ids=["imu", "combined"])
@pytest.mark.parametrize("case", list(CASES))
def test_residual_equals_gtsam(error_mode, combined, case):
    """evaluate_error equals GTSAM's definition of the ImuFactor / CombinedImuFactor error (the
    ImuFactorErrorMode chart of state j at GTSAM's own manifold-preintegration predict; bias part
    b_i - b_j) at random states and biases, to 1e-9."""
    gtsam = pytest.importorskip("gtsam")
    rng = np.random.default_rng(11)
    sensor, omega = CASES[case]
    pim, (acc, gyro, dt) = _pim(rng, combined, error_mode, case)
    gp = N.gtsam_params(gtsam, combined, sensor, omega, error_mode)
    g_cls = (gtsam.PreintegratedCombinedMeasurementsManifold if combined
             else gtsam.PreintegratedImuMeasurementsManifold)
    gpim = g_cls(gp, N.bias(gtsam, N.BIAS_HAT))
    for k in range(acc.shape[0]):
        gpim.integrateMeasurement(acc[k], gyro[k], dt[k])
    for _ in range(3):
        xi, xj = _states(rng, pim)
        bi = N.BIAS_HAT + 0.05 * rng.normal(size=6)
        bj = N.BIAS_HAT + 0.05 * rng.normal(size=6)
        pred = gpim.predict(N.navstate(gtsam, xi), N.bias(gtsam, bi))
        gj = N.navstate(gtsam, xj)
        ref = gj.logmap(pred) if error_mode == "logmap" else gj.localCoordinates(pred)
        if combined:
            ref = np.concatenate([ref, bi - bj])
            e = CombinedImuFactor.evaluate_error(xi.pose(), xi.velocity(), xj.pose(),
                                                 xj.velocity(), bi, ImuBias.from_vector(bj), pim)
        else:
            e = ImuFactor.evaluate_error(xi.pose(), xi.velocity(), xj.pose(), xj.velocity(), bi,
                                         pim)
        assert np.allclose(e, ref, atol=1e-9, rtol=0)


@pytest.mark.parametrize("combined", [False, True], ids=["imu", "combined"])
def test_equals_gtsam_factor_evaluate_error(combined):
    """GTSAM's own ImuFactor / CombinedImuFactor.evaluateError (default tangent preintegration,
    Logmap chart) equal fgopt's on samples that rotate about one fixed axis, where the tangent
    and on-manifold schemes integrate identically, at random states and biases (bias changes
    along the rotation axis and the accelerometer, where the first-order corrections agree)."""
    gtsam = pytest.importorskip("gtsam")
    rng = np.random.default_rng(12)
    params, gp = N.fgopt_params(combined), N.gtsam_params(gtsam, combined)
    bias_hat = np.array([0.1, -0.2, 0.05, 0.0, 0.0, 0.02])
    pim = (PreintegratedCombinedImu if combined else PreintegratedImu)(params, bias_hat)
    gpim = (gtsam.PreintegratedCombinedMeasurements if combined
            else gtsam.PreintegratedImuMeasurements)(gp, N.bias(gtsam, bias_hat))
    acc = rng.normal(size=(80, 3)) + [0, 0, 9.81]
    gyro = np.zeros((80, 3))
    gyro[:, 2] = 0.7 + 0.1 * rng.normal(size=80)
    for k in range(80):
        gpim.integrateMeasurement(acc[k], gyro[k], 0.01)
    pim.integrate(acc, gyro, 0.01)
    keys = (X(0), V(0), X(1), V(1), B(0)) + ((B(1),) if combined else ())
    gf = (gtsam.CombinedImuFactor if combined else gtsam.ImuFactor)(*keys, gpim)
    for _ in range(3):
        xi, xj = _states(rng, pim)
        bi = bias_hat + np.concatenate([0.05 * rng.normal(size=3), [0, 0, 0.01]])
        bj = bias_hat + 0.05 * rng.normal(size=6)
        args = [N.pose(gtsam, xi.pose()), xi.velocity(), N.pose(gtsam, xj.pose()),
                xj.velocity(), N.bias(gtsam, bi)] + ([N.bias(gtsam, bj)] if combined else [])
        ref = gf.evaluateError(*args)
        if combined:
            e = CombinedImuFactor.evaluate_error(xi.pose(), xi.velocity(), xj.pose(),
                                                 xj.velocity(), bi, bj, pim)
        else:
            e = ImuFactor.evaluate_error(xi.pose(), xi.velocity(), xj.pose(), xj.velocity(), bi,
                                         pim)
        assert np.allclose(e, ref, atol=1e-9, rtol=0)


def test_gps_equals_gtsam():
    """GpsFactor residuals equal GTSAM's GPSFactor and GPSFactorArm evaluateError."""
    gtsam = pytest.importorskip("gtsam")
    rng = np.random.default_rng(13)
    for _ in range(5):
        pose, m, arm = SE3.random(rng), rng.normal(size=3), rng.normal(size=3)
        noise = gtsam.noiseModel.Isotropic.Sigma(3, 1.0)
        g = gtsam.GPSFactor(1, m, noise).evaluateError(N.pose(gtsam, pose))
        assert np.allclose(GpsFactor.evaluate_error(pose, m), g, atol=1e-12)
        g = gtsam.GPSFactorArm(1, m, arm, noise).evaluateError(N.pose(gtsam, pose))
        assert np.allclose(GpsFactor.evaluate_error(pose, m, arm), g, atol=1e-12)


@pytest.mark.parametrize("case", list(CASES))
@pytest.mark.parametrize("error_mode", ["logmap", "component_wise"])
@pytest.mark.parametrize("combined", [False, True], ids=["imu", "combined"])
def test_jacobians_equal_central_differences(case, error_mode, combined):
    """The hand-written Jacobians of every variable (SE3 poses, velocities, biases) equal
    central differences through each variable's retraction, with rotation errors from 0 to
    near pi."""
    rng = np.random.default_rng(14)
    pim, _ = _pim(rng, combined, error_mode, case, n=50)
    for angle in N.FD_ANGLES:
        b0 = N.BIAS_HAT + 0.02 * rng.normal(size=6)
        xi, xj = _states(rng, pim, angle, b0)
        values = Variables()
        values.add(X(0), xi.pose())
        values.add(V(0), xi.velocity())
        values.add(X(1), xj.pose())
        values.add(V(1), xj.velocity())
        values.add(B(0), b0)
        values.add(B(1), N.BIAS_HAT + 0.02 * rng.normal(size=6))
        f = (CombinedImuFactor(X(0), V(0), X(1), V(1), B(0), B(1), pim) if combined
             else ImuFactor(X(0), V(0), X(1), V(1), B(0), pim))
        assert np.linalg.norm(f.error(values)[:3]) == pytest.approx(angle, abs=1e-9)
        for Ja, Jn in zip(f.jacobians(values), numerical_jacobians(f.error, values, f.keys)):
            assert np.allclose(Ja, Jn, atol=1e-6 * max(1.0, np.abs(Jn).max()), rtol=0)


def test_read_only_inputs_compile_no_second_signature():
    """Read-only arrays (frozen values, a preintegration's packed state) reach the IMU kernel as
    writeable copies: its one compiled signature serves them (numba types a read-only array
    apart; each extra compile of this kernel took ~40 s)."""
    from fgopt.navigation import _imu_kernels as IK

    rng = np.random.default_rng(18)
    pim, _ = _pim(rng, False, n=20)
    xi, xj = _states(rng, pim)
    values = Variables()
    for k, x in ((X(0), xi.pose()), (V(0), xi.velocity()), (X(1), xj.pose()),
                 (V(1), xj.velocity()), (B(0), N.BIAS_HAT)):
        values.add(k, x)
    f = ImuFactor(X(0), V(0), X(1), V(1), B(0), pim)
    args, consts = f._gather(values), f.constants.reshape(1, -1).copy()
    expected = f.kernel.linearize(args, consts)
    signatures = len(IK.imu_batch.signatures)
    frozen = [a.copy() for a in (*args, consts)]
    for a in frozen:
        a.flags.writeable = False
    got = f.kernel.linearize(tuple(frozen[:-1]), frozen[-1])
    f.kernel.residual(tuple(frozen[:-1]), frozen[-1])
    assert len(IK.imu_batch.signatures) == signatures
    assert np.array_equal(got[0], expected[0]) and np.array_equal(got[1], expected[1])


def test_gps_jacobians():
    """GpsFactor Jacobians (with and without lever arm) equal central differences."""
    rng = np.random.default_rng(15)
    for arm in (None, [0.3, -0.2, 1.0]):
        values = Variables()
        values.add(X(0), SE3.random(rng))
        f = GpsFactor(X(0), rng.normal(size=3), Isotropic.sigma(3, 0.5), lever_arm=arm)
        assert np.allclose(f.jacobians(values)[0],
                           numerical_jacobians(f.error, values, f.keys)[0], atol=1e-8)
        assert np.allclose(f.lever_arm, arm if arm is not None else 0)


def test_many_factors_one_batch_and_noise():
    """50 ImuFactors compile into one batch (one kernel call per linearization); each factor's
    noise is its preintegration covariance; the graph's cost is 0.5 sum e^T Sigma^-1 e."""
    rng = np.random.default_rng(16)
    graph, values = fgopt.FactorGraph(), Variables()
    expected = 0.0
    state = NavState.random(rng)
    values.add(X(0), state.pose())
    values.add(V(0), state.velocity())
    for k in range(50):
        pim, _ = _pim(rng, False, n=20)
        values.add(B(k), N.BIAS_HAT)
        nxt = pim.predict(state, N.BIAS_HAT).retract(0.01 * rng.normal(size=9))
        values.add(X(k + 1), nxt.pose())
        values.add(V(k + 1), nxt.velocity())
        f = ImuFactor(X(k), V(k), X(k + 1), V(k + 1), B(k), pim)
        assert np.allclose(f.noise.covariance, pim.covariance)
        e = f.error(values)
        expected += 0.5 * e @ np.linalg.solve(pim.covariance, e)
        graph.add(f)
        state = nxt
    problem = fgopt.Problem(graph, values)
    imu_batches = [b for b in problem.batches if b.kernel is imu_kernel()]
    assert len(imu_batches) == 1 and len(imu_batches[0].source) == 50
    assert problem.cost(problem.initial_state()) == pytest.approx(expected, rel=1e-10)


def test_factor_input_errors():
    """Empty or wrong preintegrations and wrong value types raise FgoptError naming the factor."""
    params = N.fgopt_params(combined=True)
    empty = PreintegratedImu(params)
    with pytest.raises(FgoptError, match=r"ImuFactor\(x0, v0, x1, v1, b0\): the preintegration"):
        ImuFactor(X(0), V(0), X(1), V(1), B(0), empty)
    combined = PreintegratedCombinedImu(params).integrate([0, 0, 9.81], [0, 0, 0], 0.01)
    with pytest.raises(FgoptError, match="PreintegratedImu"):
        ImuFactor(X(0), V(0), X(1), V(1), B(0), combined)
    with pytest.raises(FgoptError, match="PreintegratedCombinedImu"):
        CombinedImuFactor(X(0), V(0), X(1), V(1), B(0), B(1), PreintegratedImu(params))
    with pytest.raises(FgoptError, match="pose_i must be an fgopt SE3"):
        ImuFactor.evaluate_error(NavState(), np.zeros(3), SE3(), np.zeros(3), np.zeros(6),
                                 PreintegratedImu(params).integrate([0, 0, 9.81], [0, 0, 0], 0.01))
    with pytest.raises(FgoptError, match="position needs 3 numbers"):
        GpsFactor(X(0), [1, 2], Isotropic.sigma(3, 1.0))


def test_graph_with_navigation_factors_pickles():
    """IMU / GPS factors, NavState and bias values pickle (for fgopt.distributed workers): the
    kernels are rebuilt by recipe and the unpickled problem has the same cost."""
    import pickle

    rng = np.random.default_rng(17)
    pim, _ = _pim(rng, True, n=20)
    xi, xj = _states(rng, pim)
    graph, values = fgopt.FactorGraph(), Variables()
    graph.add(CombinedImuFactor(X(0), V(0), X(1), V(1), B(0), B(1), pim))
    graph.add(GpsFactor(X(1), xj.position() + 0.1, Isotropic.sigma(3, 1.0), lever_arm=[0, 0, 1]))
    for k, x in ((0, xi), (1, xj)):
        values.add(X(k), x.pose())
        values.add(V(k), x.velocity())
        values.add(B(k), ImuBias.from_vector(N.BIAS_HAT))
    values.add(key("n", 0), xi)
    graph2, values2 = pickle.loads(pickle.dumps((graph, values)))
    p1, p2 = fgopt.Problem(graph, values), fgopt.Problem(graph2, values2)
    assert p2.cost(p2.initial_state()) == p1.cost(p1.initial_state())
    assert values2.at(key("n", 0)).equals(xi, 0.0)
