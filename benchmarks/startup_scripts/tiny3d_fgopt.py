"""A tiny 3D example: 5 SE(3) poses around a square, odometry + one loop closure (fgopt)."""

import numpy as np

import fgopt
from fgopt import SE3, SO3, BetweenFactor, PriorFactor, key
from fgopt.noise import Diagonal


def pose(yaw, x, y, z):
    return SE3(SO3.exp(np.array([0.0, 0.0, yaw])), np.array([x, y, z]))


graph, initial = fgopt.FactorGraph(), fgopt.Variables()
noise = Diagonal.sigmas([0.05, 0.05, 0.05, 0.2, 0.2, 0.2])  # tangent order of SE(3): (w, v)
graph.add(PriorFactor(key("x", 1), pose(0, 0, 0, 0), Diagonal.sigmas([0.01] * 3 + [0.05] * 3)))
step = pose(np.pi / 2, 2, 0, 0.1)
for i in range(4):
    graph.add(BetweenFactor(key("x", i + 1), key("x", i + 2), step, noise))
graph.add(BetweenFactor(key("x", 5), key("x", 2), step, noise))
for i, (yaw, x, y, z) in enumerate([(0.1, 0.2, 0, 0), (1.4, 2.2, 0.1, 0.1), (3.0, 2.1, 2.2, 0.2),
                                    (-1.4, 0.1, 1.9, 0.3), (0.2, 0.1, -0.1, 0.4)]):
    initial.add(key("x", i + 1), pose(yaw, x, y, z))
result = fgopt.optimize(graph, initial, method="lm")
print(result.values.at(key("x", 5)), result.final_cost)
