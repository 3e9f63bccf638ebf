"""Python factors and Python manifolds (the slow path) solve; bad input raises FgoptErrors."""

import numpy as np
import pytest

import fgopt
from fgopt import FactorGraph, Variables, key
from fgopt.errors import (DimensionMismatchError, EmptyProblemError, FgoptError,
                          KeyNotFoundError, NonFiniteError)
from fgopt.factors import Factor, NumericalFactor
from fgopt.noise import Isotropic


class Prior2(Factor):
    """miniSAM snippet 2 in spirit: a hand-written prior on a 2-vector."""

    def __init__(self, k, m, loss=None):
        super().__init__([k], 2, loss)
        self.m = np.asarray(m, float)

    def error(self, values):
        return values.at(self.keys[0]) - self.m

    def jacobians(self, values):
        return [np.eye(2)]


class Range(NumericalFactor):
    """Distance between two 2-D points (nonlinear), Jacobians numerical."""

    def __init__(self, a, b, r, loss=None):
        super().__init__([a, b], 1, loss)
        self.r = r

    def error(self, values):
        d = values.at(self.keys[1]) - values.at(self.keys[0])
        return np.array([np.hypot(d[0], d[1]) - self.r])


class Angle:
    """A custom manifold (miniSAM snippet 3 in spirit): an angle on the circle, duck-typed."""

    def __init__(self, theta):
        self.theta = float(np.arctan2(np.sin(theta), np.cos(theta)))

    def dim(self):
        return 1

    def retract(self, v):
        return Angle(self.theta + float(v[0]))

    def local(self, other):
        d = other.theta - self.theta
        return np.array([np.arctan2(np.sin(d), np.cos(d))])


class AngleDiff(NumericalFactor):
    def __init__(self, a, b, measured, loss=None):
        super().__init__([a, b], 1, loss)
        self.measured = measured

    def error(self, values):
        d = values.at(self.keys[1]).theta - values.at(self.keys[0]).theta - self.measured
        return np.array([np.arctan2(np.sin(d), np.cos(d))])


class AnglePrior(NumericalFactor):
    def __init__(self, a, value, loss=None):
        super().__init__([a], 1, loss)
        self.value = value

    def error(self, values):
        return values.at(self.keys[0]).local(self.value) * -1.0


def trilateration():
    g = FactorGraph()
    anchors = {0: [0, 0], 1: [4, 0], 2: [0, 4]}
    v = Variables()
    truth = np.array([1.0, 2.0])
    for i, a in anchors.items():
        g.add(Prior2(key("a", i), a, Isotropic.sigma(2, 1e-3)))
        g.add(Range(key("a", i), key("p", 0), float(np.linalg.norm(truth - a)),
                    Isotropic.sigma(1, 0.1)))
        v.add(key("a", i), np.array(a, float) + 0.01)
    v.add(key("p", 0), np.array([2.5, 2.5]))
    return g, v, truth


@pytest.mark.parametrize("method", ["lm", "gn", "dogleg"])
def test_python_factors_solve(method):
    g, v, truth = trilateration()
    before = v.copy()
    r = fgopt.optimize(g, v, method=method)
    assert r.success, r.message
    assert np.allclose(r.values.at(key("p", 0)), truth, atol=1e-4)
    assert r.final_cost < 1e-8
    assert v == before  # the caller's initial values are untouched


def test_custom_python_manifold_solves():
    g = FactorGraph()
    v = Variables()
    g.add(AnglePrior(key("t", 0), Angle(3.0), Isotropic.sigma(1, 0.01)))
    for i in range(4):  # wraps around pi: tests that local() is used, not subtraction
        g.add(AngleDiff(key("t", i), key("t", i + 1), 0.2, Isotropic.sigma(1, 0.1)))
        v.add(key("t", i), Angle(3.0 + 0.1 * i))
    v.add(key("t", 4), Angle(-3.0))
    r = fgopt.optimize(g, v)
    assert r.success
    expected = np.arctan2(np.sin(3.0 + 0.8), np.cos(3.0 + 0.8))
    assert abs(r.values.at(key("t", 4)).theta - expected) < 1e-6
    assert "Python" in repr(r.problem)


def test_empty_graph():
    with pytest.raises(EmptyProblemError):
        fgopt.optimize(FactorGraph(), Variables())


def test_unknown_key_names_factor_and_key():
    g, v, _ = trilateration()
    g.add(Range(key("a", 0), key("q", 7), 1.0))
    with pytest.raises(KeyNotFoundError, match="q7"):
        fgopt.optimize(g, v)


def test_wrong_sized_error_and_jacobian():
    class Bad(Factor):
        def __init__(self, k, n_err, n_jac):
            super().__init__([k], 2)
            self.n_err, self.n_jac = n_err, n_jac

        def error(self, values):
            return np.zeros(self.n_err)

        def jacobians(self, values):
            return [np.zeros((2, self.n_jac))]

    v = Variables().add(key("x", 0), np.zeros(2))
    with pytest.raises(DimensionMismatchError, match="x0"):
        fgopt.optimize(FactorGraph([Bad(key("x", 0), 2, 3)]), v)
    with pytest.raises(DimensionMismatchError, match="Bad"):
        fgopt.optimize(FactorGraph([Bad(key("x", 0), 3, 2)]), v)
    with pytest.raises(DimensionMismatchError):
        Prior2(key("x", 0), [0, 0], Isotropic.sigma(3, 1.0))


def test_nan_at_initial_guess_names_factor():
    g, v, _ = trilateration()

    class NaNFactor(Factor):
        def __init__(self, k):
            super().__init__([k], 1)

        def error(self, values):
            return np.array([np.nan])

        def jacobians(self, values):
            return [np.zeros((1, 2))]

    g.add(NaNFactor(key("p", 0)))
    with pytest.raises(NonFiniteError, match="NaNFactor"):
        fgopt.optimize(g, v)


def test_nan_during_iterations_is_rejected_not_returned():
    """A residual that is NaN beyond x > 1: LM's first step overshoots there, is rejected,
    and the optimizer still converges to the finite optimum with finite values."""

    class SqrtFactor(Factor):
        def __init__(self, k):
            super().__init__([k], 1)

        def error(self, values):
            x = values.at(self.keys[0])[0]
            return np.array([np.sqrt(1.0 - x) if x <= 1.0 else np.nan]) - 0.1

        def jacobians(self, values):
            x = values.at(self.keys[0])[0]
            return [np.array([[-0.5 / np.sqrt(1.0 - x)]])]

    v = Variables().add(key("x", 0), np.array([0.0]))
    r = fgopt.optimize(FactorGraph([SqrtFactor(key("x", 0))]), v, max_iterations=200)
    assert np.all(np.isfinite(r.values.at(key("x", 0))))
    assert np.isfinite(r.final_cost) and r.final_cost < 1e-6
    assert abs(r.values.at(key("x", 0))[0] - 0.99) < 1e-3
    assert any(not rec.accepted for rec in r.iteration_records)


def test_factor_not_initialized_and_non_factor():
    class Lazy(Factor):
        def __init__(self):
            pass

    with pytest.raises(FgoptError, match="super"):
        FactorGraph().add(Lazy())
    with pytest.raises(FgoptError):
        FactorGraph().add("nope")


def test_unknown_method_solver_option():
    g, v, _ = trilateration()
    with pytest.raises(FgoptError, match="method"):
        fgopt.optimize(g, v, method="newton")
    with pytest.raises(FgoptError, match="linear solver"):
        fgopt.optimize(g, v, linear_solver="magic")
    with pytest.raises(FgoptError, match="unknown option"):
        fgopt.optimize(g, v, lambda_=3)


def test_callback_and_verbose(capsys):
    g, v, _ = trilateration()
    seen = []
    r = fgopt.optimize(g, v, callback=lambda rec: seen.append(rec) or len(seen) >= 2,
                       verbose=True)
    assert r.status is fgopt.Status.STOPPED and len(seen) == 2
    out = capsys.readouterr().out
    assert "iter" in out and "cost" in out
