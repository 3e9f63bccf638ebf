"""GTSAM's ImuFactorsExample played online, as the example does with iSAM2 (its parameters:
relinearize threshold 0.01, skip 1): at each GPS fix the IMU factor from the previous state, the
bias random walk and the GPS factor are added, the new state predicted from the current
estimate. The final estimate is within 1 % of the batch optimum
of the same graph and its positions within 1 cm of the batch solution."""

import numpy as np

import fgopt
from fgopt import FactorGraph, IncrementalParams, IncrementalSmoother
from fgopt.io.imu_gps import B, V, X, imu_factors_example
from fgopt.key import key_index
from fgopt.navigation import ImuBias, NavState


def test_imu_gps_example_online(data_file):
    problem = imu_factors_example(data_file("navigation/imuAndGPSdata.csv"))
    steps: dict[int, list] = {}
    for f in problem.graph:
        steps.setdefault(max(key_index(k) for k in f.keys), []).append(f)
    isam = IncrementalSmoother(IncrementalParams(relinearize_threshold=0.01, relinearize_skip=1))
    graph = FactorGraph()
    for k in sorted(steps):
        if k == 0:
            values = {K(0): problem.initial.at(K(0)) for K in (X, V, B)}
        else:
            state = NavState.from_pose_velocity(isam.estimate(X(k - 1)), isam.estimate(V(k - 1)))
            bias = isam.estimate(B(k - 1))
            predicted = problem.pims[k - 1].predict(state, ImuBias.from_vector(bias))
            values = {X(k): predicted.pose(), V(k): predicted.velocity(), B(k): bias}
        isam.update(steps[k], values)
        graph.extend(steps[k])
    est = isam.estimate()
    batch = fgopt.optimize(graph, problem.initial, relative_tolerance=1e-10,
                           absolute_tolerance=0.0)
    assert graph.error(est) <= 1.01 * batch.final_cost
    for k in range(problem.num_states):
        assert np.linalg.norm(est.at(X(k)).translation()
                              - batch.values.at(X(k)).translation()) < 0.01
