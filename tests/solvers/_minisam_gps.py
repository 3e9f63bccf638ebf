"""miniSAM's GPS-factor example (examples/python/gps_factor_example.py), ported verbatim, with
its wrong hand-written Jacobian; and the same factor with the right one."""

from __future__ import annotations

import numpy as np

from fgopt import SE2, BetweenFactor, Factor, FactorGraph, Variables, key
from fgopt.noise import Diagonal, Unit


class WrongGPSFactor(Factor):
    """miniSAM's ``GPSPositionFactor``, ported verbatim (wrong Jacobian in fgopt's tangent order
    ``(theta, x, y)``, and wrong in miniSAM's too once the pose is rotated)."""

    def __init__(self, k, point, loss):
        super().__init__([k], 2, loss)
        self.p = np.asarray(point, dtype=float)

    def error(self, values):
        return values.at(self.keys[0]).translation() - self.p

    def jacobians(self, values):
        return [np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])]


class GPSFactor(WrongGPSFactor):
    """The same factor with the right Jacobian: d(t)/d(theta, x, y) = [0, R]."""

    def jacobians(self, values):
        return [np.hstack([np.zeros((2, 1)), values.at(self.keys[0]).rotation().matrix()])]


def gps_example(factor=WrongGPSFactor):
    """miniSAM's examples/python/gps_factor_example.py: x1 - x2 - x3 with odometry, GPS on each."""
    g = FactorGraph()
    odo = Unit(3)  # miniSAM: ScaleLoss.Scale(1.0)
    g.add(BetweenFactor(key("x", 1), key("x", 2), SE2.from_xytheta(5, 0, 0), odo))
    g.add(BetweenFactor(key("x", 2), key("x", 3), SE2.from_xytheta(5, 0, 0), odo))
    gps = Diagonal.sigmas([2.0, 2.0])
    for i, p in enumerate([(0, 0), (5, 0), (10, 0)]):
        g.add(factor(key("x", i + 1), p, gps))
    v = Variables()
    v.add(key("x", 1), SE2.from_xytheta(0.2, -0.3, 0.2))
    v.add(key("x", 2), SE2.from_xytheta(5.1, 0.3, -0.1))
    v.add(key("x", 3), SE2.from_xytheta(9.9, -0.1, -0.2))
    return g, v
