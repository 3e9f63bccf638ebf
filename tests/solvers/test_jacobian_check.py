"""``fgopt.check_jacobians``: every factor's Jacobians against central differences through each
variable's retraction; the report lists the worst blocks first and flags wrong ones."""

from __future__ import annotations

import numpy as np
import pytest

import fgopt
from fgopt import SE2, SE3, SO3, BetweenFactor, FactorGraph, PriorFactor, Variables, key
from fgopt.factors import KernelFactor, NumericalFactor
from fgopt.factors.kernel import FactorKernel
from fgopt.manifolds.base import vector_kind
from fgopt.noise import Isotropic
from fgopt.symbolic import V2, Pose2, atan2

from ._minisam_gps import GPSFactor, WrongGPSFactor, gps_example


def test_minisam_gps_example_wrong_jacobian_is_flagged():
    """The ported miniSAM GPS factor (Jacobian [[1,0,0],[0,1,0]]) fails on every instance and
    is listed before the (right) between factors; the repr names it and its key."""
    g, v = gps_example(WrongGPSFactor)
    report = fgopt.check_jacobians(g, v)
    assert not report.ok
    assert len(report) == 3 + 2 * 2  # 3 GPS blocks, 2 between factors x 2 variables
    bad = report.failures
    assert [c.factor.split("(")[0] for c in bad] == ["WrongGPSFactor"] * 3
    assert all(c.ok for c in report.checks[3:])
    assert report[0].rel_error > 1.0  # theta column 1 vs 0, and R(theta) vs I
    text = repr(report)
    assert "3 FAIL" in text and "WrongGPSFactor(x1) wrt x1" in text
    assert text.index("FAIL Wrong") < text.index("ok   between")
    one = fgopt.check_jacobians(g[2], v)  # a single factor: what a user runs on a new one
    assert len(one) == 1 and not one.ok and "WrongGPSFactor(x1)" in repr(one)


def test_right_jacobians_pass():
    """The same graph with the right GPS Jacobian passes, with small relative errors."""
    g, v = gps_example(GPSFactor)
    report = fgopt.check_jacobians(g, v)
    assert report.ok, report
    assert report.max_rel_error < 1e-7
    assert "all agree" in repr(report)


def _wrong_kernel() -> FactorKernel:
    """A batched hand kernel e = a - b on R^2 whose Jacobian w.r.t. b has the wrong sign."""
    def residual(args, consts):
        return args[0] - args[1]

    def linearize(args, consts):
        n = args[0].shape[0]
        jac = np.zeros((n, 2, 4))
        jac[:, :, :2] = np.eye(2)
        jac[:, :, 2:] = np.eye(2)  # should be -I
        return residual(args, consts), jac

    R2 = vector_kind(2)
    return FactorKernel("diff_wrong", (R2, R2), 2, 0, residual, linearize)


def test_wrong_batched_kernel_is_flagged_per_row_and_variable():
    """In a batch of 4 rows of a hand kernel, every row's block for the second variable fails
    (abs error 2) and the first variable's block passes."""
    k = _wrong_kernel()
    g, v = FactorGraph(), Variables()
    for i in range(5):
        v.add(key("p", i), np.array([i, 2.0 * i]))
    for i in range(4):
        g.add(KernelFactor(k, [key("p", i), key("p", i + 1)], np.zeros(0)))
    report = fgopt.check_jacobians(g, v)
    assert {c.key for c in report.failures} == {key("p", i) for i in range(1, 5)}
    assert all(abs(c.abs_error - 2.0) < 1e-6 for c in report.failures)
    assert all("diff_wrong" in c.factor for c in report.failures)


@fgopt.factor
def range_bearing_check(pose: Pose2, landmark: V2, measured: V2) -> V2:
    d = pose.inverse() * landmark
    return V2(d.norm(), atan2(d[1], d[0])) - measured


class RangeNumerical(NumericalFactor):
    def __init__(self, a, b, r):
        super().__init__([a, b], 1)
        self.r = r

    def error(self, values):
        d = values.at(self.keys[1]) - values.at(self.keys[0])
        return np.array([np.hypot(d[0], d[1]) - self.r])


@pytest.mark.parametrize("angle", [0.3, np.pi - 1e-4])
def test_builtin_generated_and_numerical_factors_pass(angle):
    """Built-in kernels (SE2/SE3 priors and betweens), a generated @factor and a
    NumericalFactor agree with central differences, with rotations near 0 and near pi."""
    rng = np.random.default_rng(3)
    g, v = FactorGraph(), Variables()
    noise3, noise6 = Isotropic.sigma(3, 0.1), Isotropic.sigma(6, 0.1)
    for i in range(3):
        v.add(key("x", i), SE2.from_xytheta(*rng.normal(size=2), angle + 0.01 * i))
        axis = rng.normal(size=3)
        rot = SO3.exp(angle * axis / np.linalg.norm(axis))
        v.add(key("y", i), SE3(rot, rng.normal(size=3)))
    g.add(PriorFactor(key("x", 0), SE2.from_xytheta(0.1, 0.2, -angle), noise3))
    g.add(PriorFactor(key("y", 0), SE3.exp(np.full(6, 0.2)), noise6))
    for i in range(2):
        g.add(BetweenFactor(key("x", i), key("x", i + 1), SE2.from_xytheta(1, 0, angle), noise3))
        g.add(BetweenFactor(key("y", i), key("y", i + 1), SE3.exp(np.full(6, -angle / 2)),
                            noise6))
    v.add(key("l", 0), np.array([3.0, -1.0]))
    v.add(key("l", 1), np.array([-2.0, 1.5]))
    g.add(range_bearing_check(pose=key("x", 0), landmark=key("l", 0),
                              measured=np.array([3.0, 0.2])))
    g.add(RangeNumerical(key("l", 0), key("l", 1), 5.0))
    report = fgopt.check_jacobians(g, v)
    assert report.ok, report
    assert len(report) == 2 + 4 * 2 + 2 + 2


def test_bad_arguments_are_fgopt_errors():
    """Wrong values type or step raise FgoptError; missing keys the usual KeyNotFoundError."""
    g, v = gps_example(GPSFactor)
    with pytest.raises(fgopt.FgoptError):
        fgopt.check_jacobians(g, {"x1": 1})
    with pytest.raises(fgopt.FgoptError, match="step"):
        fgopt.check_jacobians(g, v, step=0.0)
    with pytest.raises(fgopt.FgoptError, match="x3"):
        w = Variables().add(key("x", 1), SE2()).add(key("x", 2), SE2())
        fgopt.check_jacobians(g, w)
