"""IMU preintegration: equal to GTSAM's manifold preintegration, bias Jacobians, atomic input
checks, parameters."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from fgopt.errors import (DimensionMismatchError, FgoptError, NonFiniteError,
                          NotPositiveDefiniteError)
from fgopt.manifolds import SO3
from fgopt.navigation import (ImuBias, NavState, PreintegratedCombinedImu, PreintegratedImu,
                              PreintegrationParams)


def _load_helpers():
    name = "fgopt_tests_navigation_helpers"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, Path(__file__).with_name("_nav.py"))
        mod = importlib.util.module_from_spec(spec)
        sys.modules[name] = mod
        spec.loader.exec_module(mod)
    return sys.modules[name]


N = _load_helpers()

CASES = {  # name: (combined, body_P_sensor, omega_coriolis, Z up)
    "imu": (False, None, None, True),
    "combined": (True, None, None, True),
    "sensor_pose": (False, N.SENSOR, None, True),
    "sensor_rotation": (False, N.SENSOR_ROTATION, None, True),
    "combined_sensor_pose_ned": (True, N.SENSOR, None, False),
    "coriolis": (False, None, [1e-2, 2e-2, 7.29e-5], True),
    "earth_rate_combined": (True, N.SENSOR, [1e-5, 3e-5, 7.29e-5], False),
}


@pytest.mark.parametrize("case", list(CASES))
def test_equals_gtsam_manifold_preintegration(case):
    """Deltas, covariance (9x9 / 15x15, GTSAM's preintMeasCov order), the factor residual's
    covariance (GTSAM's residualCovariance / residualCovarianceAt, which differ from
    preintMeasCov with Coriolis and in the combined bias block) and predict(state, bias) at
    random biases equal GTSAM's PreintegratedImuMeasurementsManifold /
    PreintegratedCombinedMeasurementsManifold on the same samples to 1e-9 (predict exercises the
    first-order bias correction, i.e. the bias Jacobians)."""
    gtsam = pytest.importorskip("gtsam")
    combined, sensor, omega, up = CASES[case]
    rng = np.random.default_rng(len(case))
    params = N.fgopt_params(combined, sensor, omega, up=up)
    gp = N.gtsam_params(gtsam, combined, sensor, omega, up=up)
    g_cls = (gtsam.PreintegratedCombinedMeasurementsManifold if combined
             else gtsam.PreintegratedImuMeasurementsManifold)
    gpim = g_cls(gp, N.bias(gtsam, N.BIAS_HAT))
    pim = (PreintegratedCombinedImu if combined else PreintegratedImu)(params, N.BIAS_HAT)
    acc, gyro, dt = N.samples(rng, 150)
    for k in range(150):
        gpim.integrateMeasurement(acc[k], gyro[k], dt[k])
    pim.integrate(acc, gyro, dt)
    assert pim.delta_t == pytest.approx(gpim.deltaTij(), abs=1e-12)
    assert np.allclose(pim.delta_R_matrix, gpim.deltaRij().matrix(), atol=1e-9, rtol=0)
    assert np.allclose(pim.delta_p, gpim.deltaPij(), atol=1e-9, rtol=0)
    assert np.allclose(pim.delta_v, gpim.deltaVij(), atol=1e-9, rtol=0)
    assert pim.covariance.shape == ((15, 15) if combined else (9, 9))
    assert np.allclose(pim.covariance, gpim.preintMeasCov(), atol=1e-9, rtol=0)
    assert np.allclose(pim.residual_covariance, gpim.residualCovariance(), atol=1e-9, rtol=0)
    attitude = SO3.random(rng)
    assert np.allclose(pim.residual_covariance_at(attitude),
                       gpim.residualCovarianceAt(gtsam.Rot3(attitude.matrix())), atol=1e-9,
                       rtol=0)
    for _ in range(3):
        state = NavState.random(rng)
        b = N.BIAS_HAT + 0.05 * rng.normal(size=6)
        ours = pim.predict(state, b)
        theirs = gpim.predict(N.navstate(gtsam, state), N.bias(gtsam, b))
        assert np.allclose(ours.rotation(), theirs.attitude().matrix(), atol=1e-9, rtol=0)
        assert np.allclose(ours.position(), theirs.position(), atol=1e-9, rtol=0)
        assert np.allclose(ours.velocity(), theirs.velocity(), atol=1e-9, rtol=0)


def test_zero_rate_equals_gtsam_default_preintegration():
    """With zero angular rate (as in GTSAM's ImuFactorsExample data) GTSAM's default
    PreintegratedImuMeasurements (tangent-space) gives the same deltas and covariance: the two
    schemes differ only through rotation."""
    gtsam = pytest.importorskip("gtsam")
    rng = np.random.default_rng(7)
    pim = PreintegratedImu(N.fgopt_params())
    gpim = gtsam.PreintegratedImuMeasurements(N.gtsam_params(gtsam))
    acc = rng.normal(size=(200, 3))
    for a in acc:
        gpim.integrateMeasurement(a, np.zeros(3), 0.005)
    pim.integrate(acc, np.zeros((200, 3)), 0.005)
    assert np.allclose(pim.delta_p, gpim.deltaPij(), atol=1e-12)
    assert np.allclose(pim.delta_v, gpim.deltaVij(), atol=1e-12)
    assert np.allclose(pim.covariance, gpim.preintMeasCov(), atol=1e-12)


def test_bias_jacobian_is_derivative_of_reintegration():
    """bias_jacobian equals central differences of [Log(dR), dp, dv] re-integrated with a
    perturbed bias_hat (the exact derivative the first-order correction approximates)."""
    rng = np.random.default_rng(8)
    params = N.fgopt_params()
    acc, gyro, dt = N.samples(rng, 60, rate=0.5)

    def deltas(b):
        p = PreintegratedImu(params, b).integrate(acc, gyro, dt)
        return p

    base = deltas(N.BIAS_HAT)
    J = np.zeros((9, 6))
    h = 1e-6
    for j in range(6):
        e = np.zeros(6)
        e[j] = h
        plus, minus = deltas(N.BIAS_HAT + e), deltas(N.BIAS_HAT - e)
        dR = (SO3.from_matrix(base.delta_R_matrix.T @ plus.delta_R_matrix).log()
              - SO3.from_matrix(base.delta_R_matrix.T @ minus.delta_R_matrix).log())
        J[:3, j] = dR / (2 * h)
        J[3:6, j] = (plus.delta_p - minus.delta_p) / (2 * h)
        J[6:, j] = (plus.delta_v - minus.delta_v) / (2 * h)
    assert np.allclose(base.bias_jacobian, J, atol=1e-6)
    # first-order correction: bias_corrected_delta(bias_hat) is the uncorrected delta
    d0 = base.bias_corrected_delta(N.BIAS_HAT)
    assert np.allclose(d0[:3], base.delta_R.log())
    assert np.allclose(d0[3:], np.concatenate([base.delta_p, base.delta_v]))


def test_arrays_equal_one_sample_at_a_time_and_reset():
    """integrate on arrays equals sample-by-sample calls; scalar dt broadcasts; reset clears
    (and with a bias, sets bias_hat)."""
    rng = np.random.default_rng(9)
    params = N.fgopt_params(combined=True)
    acc, gyro, _ = N.samples(rng, 40)
    a = PreintegratedCombinedImu(params).integrate(acc, gyro, 0.01)
    b = PreintegratedCombinedImu(params)
    for k in range(40):
        b.integrate_measurement(acc[k], gyro[k], 0.01)
    assert np.allclose(a.covariance, b.covariance, atol=1e-15)
    assert np.allclose(a.delta_X.to_storage(), b.delta_X.to_storage(), atol=1e-14)
    assert a.delta_t == pytest.approx(0.4)
    a.reset()
    assert a.delta_t == 0 and np.all(a.covariance == 0) and a.delta_X.equals(NavState())
    a.reset(ImuBias([1, 2, 3], [0, 0, 0]))
    assert np.allclose(a.bias_hat.vector(), [1, 2, 3, 0, 0, 0])
    assert "PreintegratedCombinedImu(delta_t=0" in repr(a)


@pytest.mark.parametrize("bad, match", [
    (dict(acc_row=(17, [np.nan, 0, 0])), "sample 17 has a non-finite accelerometer"),
    (dict(gyro_row=(3, [0, np.inf, 0])), "sample 3 has a non-finite gyroscope"),
    (dict(dt_row=(25, 0.0)), "sample 25 has dt = 0.0"),
    (dict(dt_row=(5, -0.01)), "sample 5 has dt = -0.01"),
    (dict(dt_row=(6, np.nan)), "sample 6 has dt = nan"),
    (dict(gyro_rows=29), "30 accelerometer samples but 29 gyroscope"),
    (dict(acc_cols=4), r"accel must have shape \(3,\) or \(n, 3\)"),
    (dict(dt_len=7), r"dt must be a number or have shape \(30,\)"),
])
def test_bad_samples_are_rejected_atomically(bad, match):
    """Non-finite or wrongly shaped samples and non-positive dt raise an FgoptError naming the
    sample index; nothing is integrated (deltas and covariance unchanged)."""
    rng = np.random.default_rng(10)
    pim = PreintegratedImu(N.fgopt_params())
    acc0, gyro0, dt0 = N.samples(rng, 10)
    pim.integrate(acc0, gyro0, dt0)
    before = (pim.delta_t, pim.delta_X.to_storage(), pim.covariance, pim.bias_jacobian)
    acc, gyro, dt = N.samples(rng, 30)
    if "acc_row" in bad:
        acc[bad["acc_row"][0]] = bad["acc_row"][1]
    if "gyro_row" in bad:
        gyro[bad["gyro_row"][0]] = bad["gyro_row"][1]
    if "dt_row" in bad:
        dt[bad["dt_row"][0]] = bad["dt_row"][1]
    if "gyro_rows" in bad:
        gyro = gyro[:bad["gyro_rows"]]
    if "acc_cols" in bad:
        acc = np.zeros((30, bad["acc_cols"]))
    if "dt_len" in bad:
        dt = dt[:bad["dt_len"]]
    with pytest.raises(FgoptError, match=match):
        pim.integrate(acc, gyro, dt)
    after = (pim.delta_t, pim.delta_X.to_storage(), pim.covariance, pim.bias_jacobian)
    assert before[0] == after[0]
    for x, y in zip(before[1:], after[1:]):
        assert np.array_equal(x, y)


def test_params_from_sigmas_and_bad_noise():
    """make_u / make_d: gravity sign, sigma -> covariance (scalar, per axis, full matrix);
    non-positive-definite noise raises NotPositiveDefiniteError naming the parameter; the
    combined preintegration needs the bias random walks."""
    p = PreintegrationParams.make_u(9.8, gyro_sigma=0.1, accel_sigma=[0.1, 0.2, 0.3],
                                    integration_sigma=0.0)
    assert np.allclose(p.n_gravity, [0, 0, -9.8])
    assert np.allclose(p.gyroscope_covariance, 0.01 * np.eye(3))
    assert np.allclose(np.diag(p.accelerometer_covariance), [0.01, 0.04, 0.09])
    assert np.allclose(p.integration_covariance, 0)
    assert np.allclose(PreintegrationParams.make_d(9.8).n_gravity, [0, 0, 9.8])
    assert "gyro_sigma=0.1" in repr(p)
    with pytest.raises(NotPositiveDefiniteError, match="gyroscope_covariance"):
        PreintegrationParams.make_u(gyro_sigma=0.0)
    with pytest.raises(NotPositiveDefiniteError, match="accelerometer_covariance"):
        PreintegrationParams.make_u(accelerometer_covariance=np.diag([1.0, -1.0, 1.0]))
    with pytest.raises(NotPositiveDefiniteError, match="not symmetric"):
        PreintegrationParams.make_u(gyroscope_covariance=[[1, 0.5, 0], [0, 1, 0], [0, 0, 1]])
    with pytest.raises(FgoptError, match="not both"):
        PreintegrationParams.make_u(gyro_sigma=0.1, gyroscope_covariance=np.eye(3))
    with pytest.raises(DimensionMismatchError, match="3x3"):
        PreintegrationParams.make_u(gyroscope_covariance=np.eye(2))
    with pytest.raises(NonFiniteError):
        PreintegrationParams.make_u(accel_sigma=np.nan)
    with pytest.raises(FgoptError, match="error_mode"):
        PreintegrationParams.make_u(error_mode="tangent")
    with pytest.raises(NotPositiveDefiniteError, match="bias_acc_covariance"):
        PreintegratedCombinedImu(p)
