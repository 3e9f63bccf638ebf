"""The tiny 2D example with GTSAM (as its Pose2SLAMExample.py)."""

import numpy as np

import gtsam
from gtsam.symbol_shorthand import X

graph, initial = gtsam.NonlinearFactorGraph(), gtsam.Values()
noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.2, 0.2, 0.1]))  # GTSAM's order (x, y, theta)
graph.add(gtsam.PriorFactorPose2(X(1), gtsam.Pose2(0, 0, 0),
                                 gtsam.noiseModel.Diagonal.Sigmas(np.array([0.3, 0.3, 0.1]))))
for i, (x, y, t) in enumerate([(2, 0, 0), (2, 0, np.pi / 2), (2, 0, np.pi / 2), (2, 0, np.pi / 2)]):
    graph.add(gtsam.BetweenFactorPose2(X(i + 1), X(i + 2), gtsam.Pose2(x, y, t), noise))
graph.add(gtsam.BetweenFactorPose2(X(5), X(2), gtsam.Pose2(2, 0, np.pi / 2), noise))
for i, (x, y, t) in enumerate([(0.5, 0, 0.2), (2.3, 0.1, -0.2), (4.1, 0.1, np.pi / 2),
                               (4.0, 2.0, np.pi), (2.1, 2.1, -np.pi / 2)]):
    initial.insert(X(i + 1), gtsam.Pose2(x, y, t))
result = gtsam.LevenbergMarquardtOptimizer(graph, initial,
                                           gtsam.LevenbergMarquardtParams()).optimize()
print(result.atPose2(X(5)), graph.error(result))
