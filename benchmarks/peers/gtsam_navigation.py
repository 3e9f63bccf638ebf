"""GTSAM's side of the navigation comparisons: the ImuFactorsExample problem built with GTSAM's
own classes from the same samples and the same initial values as
:func:`fgopt.io.imu_gps.imu_factors_example` (used by ``benchmarks/navigation.py`` and
``tests/navigation/test_imu_example.py``).

GTSAM's ``PreintegratedImuMeasurements`` is its tangent-space preintegration by default (fgopt
preintegrates on the manifold, as GTSAM's ``ManifoldPreintegration``); on this data set the
gyroscope reads zero, the preintegrated rotation stays the identity, and the two agree to
rounding, so both libraries solve the same least-squares problem.
"""

from __future__ import annotations

import numpy as np


def gtsam_params(combined: bool = False):
    """GTSAM's ImuFactorsExample parameters (``MakeSharedD(0.0)``, its sensor sigmas)."""
    import gtsam

    cls = gtsam.PreintegrationCombinedParams if combined else gtsam.PreintegrationParams
    p = cls.MakeSharedD(0.0)
    p.setAccelerometerCovariance(np.eye(3) * 0.0003924 ** 2)
    p.setGyroscopeCovariance(np.eye(3) * 0.000205689024915 ** 2)
    p.setIntegrationCovariance(np.eye(3) * 1e-8)
    if combined:
        p.setBiasAccCovariance(np.eye(3) * 0.004905 ** 2)
        p.setBiasOmegaCovariance(np.eye(3) * 0.000001454441043 ** 2)
    return p


def to_gtsam_pose(pose):
    import gtsam

    return gtsam.Pose3(gtsam.Rot3(pose.rotation().matrix()), pose.translation())


def build(data, problem, combined: bool = False, gps_every: int = 1, dt: float = 0.005):
    """``(graph, initial)`` in GTSAM for ``data`` (an ``ImuGpsData``), with the initial values of
    the fgopt ``problem`` (same keys: GTSAM's ``Symbol('x', k)`` is fgopt's ``key('x', k)``)."""
    import gtsam
    from gtsam.symbol_shorthand import B, V, X

    p = gtsam_params(combined)
    graph = gtsam.NonlinearFactorGraph()
    bias_noise = gtsam.noiseModel.Isotropic.Sigma(6, 1e-3)
    pose0 = to_gtsam_pose(data.initial_pose)
    graph.add(gtsam.PriorFactorPose3(X(0), pose0, gtsam.noiseModel.Diagonal.Sigmas(
        np.array([0.01, 0.01, 0.01, 0.5, 0.5, 0.5]))))
    graph.add(gtsam.PriorFactorVector(V(0), data.initial_velocity,
                                      gtsam.noiseModel.Isotropic.Sigma(3, 0.1)))
    graph.add(gtsam.PriorFactorConstantBias(B(0), gtsam.imuBias.ConstantBias(), bias_noise))
    gps_noise = gtsam.noiseModel.Isotropic.Sigma(3, 1.0)
    start = 0
    for k in range(1, data.gps.shape[0] + 1):
        stop = int(data.imu_before_gps[k - 1])
        pim = (gtsam.PreintegratedCombinedMeasurements if combined
               else gtsam.PreintegratedImuMeasurements)(p, gtsam.imuBias.ConstantBias())
        for s in range(start, stop):
            pim.integrateMeasurement(data.imu[s, :3], data.imu[s, 3:], dt)
        start = stop
        if combined:
            graph.add(gtsam.CombinedImuFactor(X(k - 1), V(k - 1), X(k), V(k), B(k - 1), B(k),
                                              pim))
        else:
            graph.add(gtsam.ImuFactor(X(k - 1), V(k - 1), X(k), V(k), B(k - 1), pim))
            graph.add(gtsam.BetweenFactorConstantBias(B(k - 1), B(k),
                                                      gtsam.imuBias.ConstantBias(), bias_noise))
        if k % gps_every == 0:
            graph.add(gtsam.GPSFactor(X(k), data.gps[k - 1, :3], gps_noise))
    initial = gtsam.Values()
    for k in range(problem.num_states):
        initial.insert(X(k), to_gtsam_pose(problem.initial.at(X(k))))
        initial.insert(V(k), np.asarray(problem.initial.at(V(k)), dtype=float))
        b = np.asarray(problem.initial.at(B(k)), dtype=float)
        initial.insert(B(k), gtsam.imuBias.ConstantBias(b[:3], b[3:]))
    return graph, initial


def trajectory(values, num_states: int) -> np.ndarray:
    """``(num_states, 3 + 3 + 3 + 6)``: position, rotation vector, velocity, bias per state."""
    from gtsam.symbol_shorthand import B, V, X

    out = np.empty((num_states, 15))
    for k in range(num_states):
        pose = values.atPose3(X(k))
        out[k, :3] = pose.translation()
        out[k, 3:6] = _rotvec(pose.rotation().matrix())
        out[k, 6:9] = values.atVector(V(k))
        out[k, 9:] = values.atConstantBias(B(k)).vector()
    return out


def _rotvec(R: np.ndarray) -> np.ndarray:
    from fgopt.manifolds import SO3

    return SO3.from_matrix(R).log()
