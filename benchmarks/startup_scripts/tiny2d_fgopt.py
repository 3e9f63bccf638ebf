"""A tiny 2D example as a new user writes it: 5 poses, odometry, one loop closure (fgopt)."""

import numpy as np

import fgopt
from fgopt import SE2, BetweenFactor, PriorFactor, key
from fgopt.noise import Diagonal

graph, initial = fgopt.FactorGraph(), fgopt.Variables()
noise = Diagonal.sigmas([0.1, 0.2, 0.2])  # tangent order of SE(2): (theta, x, y)
graph.add(PriorFactor(key("x", 1), SE2.from_xytheta(0, 0, 0), Diagonal.sigmas([0.1, 0.3, 0.3])))
for i, (x, y, t) in enumerate([(2, 0, 0), (2, 0, np.pi / 2), (2, 0, np.pi / 2), (2, 0, np.pi / 2)]):
    graph.add(BetweenFactor(key("x", i + 1), key("x", i + 2), SE2.from_xytheta(x, y, t), noise))
graph.add(BetweenFactor(key("x", 5), key("x", 2), SE2.from_xytheta(2, 0, np.pi / 2), noise))
for i, (x, y, t) in enumerate([(0.5, 0, 0.2), (2.3, 0.1, -0.2), (4.1, 0.1, np.pi / 2),
                               (4.0, 2.0, np.pi), (2.1, 2.1, -np.pi / 2)]):
    initial.add(key("x", i + 1), SE2.from_xytheta(x, y, t))
result = fgopt.optimize(graph, initial, method="lm")
print(result.values.at(key("x", 5)), result.final_cost)
