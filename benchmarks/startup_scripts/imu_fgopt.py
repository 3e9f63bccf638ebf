"""GTSAM's ImuFactorExample written with fgopt: a body on a constant twist ("sick twist": 30 deg/s
roll and -30 deg/s pitch, 2 m/s forward), IMU samples at 100 Hz with a constant bias, one
ImuFactor per second, noisy initial states (seeded), priors on the first and last pose and
velocity, Levenberg-Marquardt. Prints the optimized last state, the bias and the errors.

The samples are exact (``NOISE = 0``; GTSAM's example adds white noise of 1e-3 / sqrt(dt)): on
noisy samples fgopt's and GTSAM 4.3's preintegrated deltas differ by ~1e-7 (their integration
schemes agree to first order only), which moves the optimum by ~1e-5, too much to show that
the two scripts solve the same problem. The initial errors differ for the same reason (the
preintegrated covariances); the optimum does not."""

import numpy as np

import fgopt
from fgopt import SE3, SO3, PriorFactor, key
from fgopt.navigation import ImuBias, ImuFactor, PreintegratedImu, PreintegrationParams
from fgopt.noise import Isotropic

SEED, SECONDS, DT = 7, 12, 0.01
NOISE = 0.0  # IMU white noise sigma (GTSAM 1e-3 / sqrt(DT)): see the module docstring
GRAVITY = 9.81
OMEGA = np.radians([30.0, -30.0, 0.0])   # body angular rate, rad/s
VELOCITY = np.array([2.0, 0.0, 0.0])     # body velocity, m/s
BIAS = ImuBias([-0.3, 0.1, 0.2], [0.1, 0.3, -0.1])   # accelerometer, gyroscope


def truth(t):
    """world_T_body at time t, and the velocity in the world frame."""
    world_T_body = SE3.exp(np.concatenate([OMEGA, VELOCITY]) * t)
    return world_T_body, world_T_body.rotation().matrix() @ VELOCITY


def imu_samples(times, noise):
    """Measured specific force and angular rate at ``times``: truth + bias + white noise
    (``noise``: standard normal samples, one row of 6 per time; sigma 1e-3 / sqrt(DT))."""
    gravity = np.array([0.0, 0.0, -GRAVITY])
    accel = np.empty((len(times), 3))
    for n, t in enumerate(times):
        world_R_body = truth(t)[0].rotation().matrix()
        accel[n] = np.cross(OMEGA, VELOCITY) - world_R_body.T @ gravity
    accel += BIAS.accelerometer + NOISE * noise[:, :3]
    gyro = OMEGA + BIAS.gyroscope + NOISE * noise[:, 3:]
    return accel, gyro


def run():
    rng = np.random.default_rng(SEED)
    per_second = int(round(1 / DT))
    imu_noise = rng.standard_normal((SECONDS * per_second, 6))
    params = PreintegrationParams.make_u(GRAVITY, gyro_sigma=1e-3, accel_sigma=1e-3,
                                         integration_sigma=1e-7)
    graph, initial = fgopt.FactorGraph(), fgopt.Variables()
    pose_noise, velocity_noise = Isotropic.sigma(6, 0.1), Isotropic.sigma(3, 0.1)

    def add_priors(i):
        pose, velocity = truth(i)
        graph.add(PriorFactor(key("x", i), pose, pose_noise))
        graph.add(PriorFactor(key("v", i), velocity, velocity_noise))

    pose, velocity = truth(0.0)
    initial.add(key("b", 0), BIAS.vector())
    initial.add(key("x", 0), pose)
    initial.add(key("v", 0), velocity)
    add_priors(0)
    for i in range(SECONDS):
        pim = PreintegratedImu(params, BIAS)
        samples = slice(i * per_second, (i + 1) * per_second)
        pim.integrate(*imu_samples(np.arange(samples.start, samples.stop) * DT,
                                   imu_noise[samples]), DT)
        graph.add(ImuFactor(key("x", i), key("v", i), key("x", i + 1), key("v", i + 1),
                            key("b", 0), pim))
        pose, velocity = truth(i + 1.0)
        noise = SE3(SO3.exp(0.1 * rng.standard_normal(3)), rng.standard_normal(3))
        initial.add(key("x", i + 1), pose * noise)
        initial.add(key("v", i + 1), velocity + 0.1 * rng.standard_normal(3))
    add_priors(SECONDS - 1)
    result = fgopt.optimize(graph, initial, method="lm")
    last = result.values
    return {"last pose": last.at(key("x", SECONDS)).matrix(),
            "last velocity": np.asarray(last.at(key("v", SECONDS))),
            "bias": np.asarray(last.at(key("b", 0))),
            "initial error": graph.error(initial), "final error": result.final_cost}


if __name__ == "__main__":
    np.set_printoptions(precision=6, suppress=True)
    for name, value in run().items():
        print(f"{name}: {np.round(value, 6) + 0.0}")  # + 0.0: no "-0."
