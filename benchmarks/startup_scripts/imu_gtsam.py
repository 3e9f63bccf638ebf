"""GTSAM's ImuFactorExample (its own scenario and runner; the IMU noise drawn by numpy), without
plots, seeded: the reference for ``imu_fgopt.py``. Prints the optimized last state, the bias and
the errors."""

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, V, X

SEED, SECONDS, DT = 7, 12, 0.01
NOISE = 0.0  # IMU white noise sigma (the example: 1e-3 / sqrt(DT)); see imu_fgopt.py
GRAVITY = 9.81


def run():
    rng = np.random.default_rng(SEED)
    per_second = round(1 / DT)
    imu_noise = NOISE * rng.standard_normal((SECONDS * per_second, 6))
    omega, velocity = np.radians([30.0, -30.0, 0.0]), np.array([2.0, 0.0, 0.0])
    bias = gtsam.imuBias.ConstantBias(np.array([-0.3, 0.1, 0.2]), np.array([0.1, 0.3, -0.1]))
    params = gtsam.PreintegrationParams.MakeSharedU(GRAVITY)
    params.setGyroscopeCovariance(1e-3 ** 2 * np.eye(3))
    params.setAccelerometerCovariance(1e-3 ** 2 * np.eye(3))
    params.setIntegrationCovariance(1e-7 ** 2 * np.eye(3))
    scenario = gtsam.ConstantTwistScenario(omega, velocity)
    runner = gtsam.ScenarioRunner(scenario, params, DT, bias)
    pose_noise = gtsam.noiseModel.Isotropic.Sigma(6, 0.1)
    velocity_noise = gtsam.noiseModel.Isotropic.Sigma(3, 0.1)
    graph, initial = gtsam.NonlinearFactorGraph(), gtsam.Values()

    def add_priors(i):
        state = scenario.navState(i)
        graph.push_back(gtsam.PriorFactorPose3(X(i), state.pose(), pose_noise))
        graph.push_back(gtsam.PriorFactorVector(V(i), state.velocity(), velocity_noise))

    initial.insert(B(0), bias)
    initial.insert(X(0), scenario.navState(0).pose())
    initial.insert(V(0), scenario.navState(0).velocity())
    add_priors(0)
    pim = gtsam.PreintegratedImuMeasurements(params, bias)
    i = 0
    for k in range(SECONDS * per_second):
        t = k * DT
        # the runner's own noisy samples use GTSAM's sampler: the same noise, drawn by numpy
        pim.integrateMeasurement(runner.actualSpecificForce(t) + bias.accelerometer()
                                 + imu_noise[k, :3],
                                 runner.actualAngularVelocity(t) + bias.gyroscope()
                                 + imu_noise[k, 3:], DT)
        if (k + 1) % per_second == 0:
            graph.push_back(gtsam.ImuFactor(X(i), V(i), X(i + 1), V(i + 1), B(0), pim))
            pim.resetIntegration()
            state = scenario.navState(i + 1.0)
            noise = gtsam.Pose3(gtsam.Rot3.Expmap(0.1 * rng.standard_normal(3)),
                                gtsam.Point3(*rng.standard_normal(3)))
            initial.insert(X(i + 1), state.pose().compose(noise))
            initial.insert(V(i + 1), state.velocity() + 0.1 * rng.standard_normal(3))
            i += 1
    add_priors(SECONDS - 1)
    result = gtsam.LevenbergMarquardtOptimizer(graph, initial,
                                               gtsam.LevenbergMarquardtParams()).optimize()
    return {"last pose": result.atPose3(X(SECONDS)).matrix(),
            "last velocity": result.atVector(V(SECONDS)),
            "bias": result.atConstantBias(B(0)).vector(),
            "initial error": graph.error(initial), "final error": graph.error(result)}


if __name__ == "__main__":
    np.set_printoptions(precision=6, suppress=True)
    for name, value in run().items():
        print(f"{name}: {np.round(value, 6) + 0.0}")  # + 0.0: no "-0."
