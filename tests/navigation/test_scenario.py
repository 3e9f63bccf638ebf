"""IMU scenarios (GTSAM's ConstantTwistScenario / AcceleratingScenario / ScenarioRunner): true
states and IMU signals equal GTSAM's, noise-free samples preintegrate to the true motion, and an
IMU-factor graph over noisy samples (with a few GPS fixes) recovers the true trajectory."""

from __future__ import annotations

import numpy as np
import pytest

import fgopt
from fgopt import SE3, SO3, Variables
from fgopt.navigation import GpsFactor, ImuBias, ImuFactor, PreintegrationParams
from fgopt.navigation.scenario import AcceleratingScenario, ConstantTwistScenario, ScenarioRunner
from fgopt.noise import Diagonal, Isotropic
from fgopt.symbol_shorthand import B, V, X

gtsam = pytest.importorskip("gtsam")

W, VB = np.array([0.05, -0.02, 0.3]), np.array([2.0, 0.1, 0.0])
R0, P0, V0 = (0.1, 0.2, 0.3), np.array([1.0, 2.0, 3.0]), np.array([0.5, 0.0, 0.1])
ACC, WA = np.array([0.0, 0.2, 0.1]), np.array([0.01, 0.02, 0.3])
TIMES = (0.0, 0.37, 1.0, 4.2)


def _pairs():
    T0 = SE3(SO3.ypr(0.3, -0.1, 0.2), [1.0, -2.0, 0.5])
    g_T0 = gtsam.Pose3(gtsam.Rot3.Ypr(0.3, -0.1, 0.2), np.array([1.0, -2.0, 0.5]))
    return [(ConstantTwistScenario(W, VB), gtsam.ConstantTwistScenario(W, VB)),
            (ConstantTwistScenario(W, VB, T0), gtsam.ConstantTwistScenario(W, VB, g_T0)),
            (AcceleratingScenario(SO3.ypr(*R0), P0, V0, ACC, WA),
             gtsam.AcceleratingScenario(gtsam.Rot3.Ypr(*R0), P0, V0, ACC, WA))]


def _params():
    return PreintegrationParams.make_u(9.81, accel_sigma=0.02, gyro_sigma=2e-3,
                                       integration_sigma=1e-4)


def _gtsam_params():
    p = gtsam.PreintegrationParams.MakeSharedU(9.81)
    p.setAccelerometerCovariance(np.eye(3) * 0.02 ** 2)
    p.setGyroscopeCovariance(np.eye(3) * 2e-3 ** 2)
    p.setIntegrationCovariance(np.eye(3) * 1e-8)
    return p


@pytest.mark.parametrize("i", range(3))
def test_true_states_match_gtsam(i):
    """Pose, world velocity and acceleration, body rate of each scenario equal GTSAM's."""
    ours, theirs = _pairs()[i]
    for t in TIMES:
        assert np.allclose(ours.pose(t).matrix(), theirs.pose(t).matrix(), atol=1e-12)
        assert np.allclose(ours.velocity_n(t), theirs.velocity_n(t), atol=1e-12)
        assert np.allclose(ours.acceleration_n(t), theirs.acceleration_n(t), atol=1e-12)
        assert np.allclose(ours.omega_b(t), theirs.omega_b(t), atol=1e-12)
        assert np.allclose(ours.velocity_b(t), theirs.velocity_b(t), atol=1e-12)
        nav = ours.nav_state(t)
        assert np.allclose(nav.velocity(), theirs.navState(t).velocity(), atol=1e-12)


@pytest.mark.parametrize("i", range(3))
def test_runner_signals_and_prediction_match_gtsam(i):
    """Specific force and angular rate equal GTSAM's ScenarioRunner's; noise-free samples with a
    bias preintegrate and predict the state GTSAM's runner predicts (and ~ the true state)."""
    ours, theirs = _pairs()[i]
    bias = ImuBias([0.01, -0.02, 0.03], [1e-3, 2e-3, -1e-3])
    g_bias = gtsam.imuBias.ConstantBias(bias.accelerometer, bias.gyroscope)
    run = ScenarioRunner(ours, _params(), dt=0.01, bias=bias)
    g_run = gtsam.ScenarioRunner(theirs, _gtsam_params(), 0.01, g_bias)
    for t in TIMES:
        assert np.allclose(run.actual_specific_force(t), g_run.actualSpecificForce(t), atol=1e-12)
        assert np.allclose(run.actual_angular_velocity(t), g_run.actualAngularVelocity(t),
                           atol=1e-12)
    for est, g_est in ((bias, g_bias), (ImuBias(), gtsam.imuBias.ConstantBias())):
        pim = run.integrate(2.0, est, corrupted=False)   # true signals, as GTSAM's runner
        g_pim = g_run.integrate(2.0, g_est, False)
        ours_pred, theirs_pred = run.predict(pim, est), g_run.predict(g_pim, g_est)
        assert np.allclose(ours_pred.pose().matrix(), theirs_pred.pose().matrix(), atol=1e-9)
        assert np.allclose(ours_pred.velocity(), theirs_pred.velocity(), atol=1e-9)
    truth = ours.nav_state(2.0)  # (the last prediction: true signals at the true zero bias)
    assert np.linalg.norm(ours_pred.position() - truth.position()) < 0.01


def test_noise_has_the_params_density():
    """Sample noise is N(0, covariance / dt): its empirical std matches within 5 %."""
    run = ScenarioRunner(ConstantTwistScenario(W, VB), _params(), dt=0.01, rng=3)
    _, acc, gyro = run.samples(40.0)
    _, acc0, gyro0 = run.samples(40.0, corrupted=False)
    assert np.std(acc - acc0) == pytest.approx(0.02 / np.sqrt(0.01), rel=0.05)
    assert np.std(gyro - gyro0) == pytest.approx(2e-3 / np.sqrt(0.01), rel=0.05)


def test_imu_factors_over_noisy_samples_recover_the_trajectory():
    """A circle driven for 10 s: ImuFactors between keyframes every second (noisy samples, a
    true bias), a prior at the start, a GPS fix every second; LM from dead-reckoned-and-perturbed
    values (dead reckoning alone drifts ~1.5 m with the accelerometer bias) recovers the true
    positions and velocities to a few cm (/s) and the attitudes to ~1 degree (yaw is the weakly
    observed part: only the 0.9 m/s^2 centripetal acceleration turns with it)."""
    scenario = ConstantTwistScenario([0.0, 0.0, 0.3], [3.0, 0.0, 0.0])
    bias = ImuBias([0.02, -0.01, 0.03], [1e-3, -2e-3, 5e-4])
    params = PreintegrationParams.make_u(9.81, accel_sigma=0.02, gyro_sigma=5e-4,
                                         integration_sigma=1e-4)
    run = ScenarioRunner(scenario, params, dt=0.01, bias=bias, rng=7)
    graph, values = fgopt.FactorGraph(), Variables()
    s0 = scenario.nav_state(0.0)
    graph.add(fgopt.PriorFactor(X(0), s0.pose(), Isotropic.sigma(6, 1e-3)))
    graph.add(fgopt.PriorFactor(V(0), s0.velocity(), Isotropic.sigma(3, 1e-3)))
    graph.add(fgopt.PriorFactor(B(0), np.zeros(6), Diagonal.sigmas([0.1] * 3 + [0.01] * 3)))
    values.add(B(0), np.zeros(6))
    rng = np.random.default_rng(0)
    state = s0
    for k in range(11):
        if k > 0:
            pim = run.integrate(1.0, ImuBias(), start=k - 1.0)
            graph.add(ImuFactor(X(k - 1), V(k - 1), X(k), V(k), B(0), pim))
            state = pim.predict(state, ImuBias())
        values.add(X(k), state.pose().retract(0.05 * rng.normal(size=6)))
        values.add(V(k), state.velocity() + 0.05 * rng.normal(size=3))
        if k > 0:
            graph.add(GpsFactor(X(k), scenario.pose(float(k)).translation(),
                                loss=Isotropic.sigma(3, 0.02)))
    r = fgopt.optimize(graph, values)
    assert r.success
    for k in range(11):
        truth = scenario.nav_state(float(k))
        est = r.values.at(X(k))
        assert np.linalg.norm(est.translation() - truth.position()) < 0.05
        assert np.linalg.norm(est.rotation().local(truth.attitude())) < 0.02
        assert np.linalg.norm(r.values.at(V(k)) - truth.velocity()) < 0.05
