"""The tiny 3D example with GTSAM."""

import numpy as np

import gtsam
from gtsam.symbol_shorthand import X


def pose(yaw, x, y, z):
    return gtsam.Pose3(gtsam.Rot3.Yaw(yaw), np.array([x, y, z]))


graph, initial = gtsam.NonlinearFactorGraph(), gtsam.Values()
noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.05, 0.05, 0.05, 0.2, 0.2, 0.2]))
graph.add(gtsam.PriorFactorPose3(X(1), pose(0, 0, 0, 0),
                                 gtsam.noiseModel.Diagonal.Sigmas(np.array([0.01] * 3 + [0.05] * 3))))
step = pose(np.pi / 2, 2, 0, 0.1)
for i in range(4):
    graph.add(gtsam.BetweenFactorPose3(X(i + 1), X(i + 2), step, noise))
graph.add(gtsam.BetweenFactorPose3(X(5), X(2), step, noise))
for i, (yaw, x, y, z) in enumerate([(0.1, 0.2, 0, 0), (1.4, 2.2, 0.1, 0.1), (3.0, 2.1, 2.2, 0.2),
                                    (-1.4, 0.1, 1.9, 0.3), (0.2, 0.1, -0.1, 0.4)]):
    initial.insert(X(i + 1), pose(yaw, x, y, z))
result = gtsam.LevenbergMarquardtOptimizer(graph, initial,
                                           gtsam.LevenbergMarquardtParams()).optimize()
print(result.atPose3(X(5)), graph.error(result))
