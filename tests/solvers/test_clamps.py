"""Clamped symbolic functions are reported (issue 10): a start outside ``sqrt``'s domain used to
"converge after 0 iterations" silently; the result (and a warning) now name the factor, the
clamped call's file:line and the argument, in every method and the small-problem driver."""

from __future__ import annotations

import inspect
import warnings

import numpy as np
import pytest

import fgopt
from fgopt import FactorGraph, PriorFactor, Variables, key
from fgopt.symbolic import V2, Scalar, acos, log, sqrt


@fgopt.factor
def clamp_dist(p: V2, q: V2, measured: Scalar) -> Scalar:
    d = q - p
    return Scalar(sqrt(d.dot(d) - 1.0) - measured)  # the clamped call


@fgopt.factor
def clamp_log_acos(p: V2, measured: V2) -> V2:
    return V2(log(p[0]) - measured[0], acos(p[1]) - measured[1])


@fgopt.factor
def no_clamp(p: V2, measured: V2) -> V2:
    return p - measured


SQRT_LINE = (f"{__file__}:"
             f"{inspect.getsourcelines(clamp_dist.fn)[1] + 3}")


def graph(start_q):
    g = FactorGraph([clamp_dist(p=key("p", 0), q=key("p", 1), measured=2.0)])
    g.add(PriorFactor(key("p", 0), np.zeros(2)))
    v = Variables().add(key("p", 0), np.zeros(2)).add(key("p", 1), np.array(start_q, float))
    return g, v


def _run(kind, g, v):
    if kind == "lm driver":  # the small-problem driver (numba; compiled here if new)
        from fgopt.solvers import LevenbergMarquardt, LMParams, small

        small.COMPILE_IN_FOREGROUND, before = True, small.COMPILE_IN_FOREGROUND
        try:
            r = LevenbergMarquardt(LMParams(backend="numba")).optimize(g, v)
        finally:
            small.COMPILE_IN_FOREGROUND = before
        assert r.linear_solver == "dense cholesky (small-problem driver)"
        return r
    return fgopt.optimize(g, v, method=kind)


@pytest.mark.parametrize("kind", ["lm", "lm driver", "gn", "dogleg", "gnc"])
def test_start_outside_sqrt_domain_is_reported(kind):
    """|q - p|^2 - 1 = -0.75 < 0 at the start: gradient zero, "converged" at once; the result
    lists the factor, the sqrt's file:line and the argument, the repr says so, and a
    FgoptWarning is raised."""
    g, v = graph([0.5, 0.0])
    with pytest.warns(fgopt.FgoptWarning, match="clamped function argument"):
        r = _run(kind, g, v)
    assert r.num_clamped == 1 and len(r.clamps) == 1
    hit = r.clamps[0]
    assert hit.function == "sqrt" and hit.factor.startswith("clamp_dist(p0, p1)")
    assert hit.where == SQRT_LINE and "sqrt(d.dot(d) - 1.0)" in hit.code
    assert np.isclose(hit.value, -0.75)
    assert "clamped: 1 factor(s)" in repr(r) and SQRT_LINE in repr(r)


@pytest.mark.parametrize("kind", ["lm", "lm driver"])
def test_start_inside_the_domain_reports_nothing(kind):
    """From inside the domain the solve converges to |q - p| = sqrt(5) with no report."""
    g, v = graph([3.0, 0.0])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        r = _run(kind, g, v)
    assert r.success and r.num_clamped == 0 and r.clamps == ()
    assert np.isclose(np.linalg.norm(r.values.at(key("p", 1))), np.sqrt(5.0), atol=1e-6)


def test_log_and_acos_bounds_and_factors_without_clamps():
    """log clamps below epsilon, acos outside [-1, 1]; a kernel without clamped calls has no
    clamp_arguments (nothing to evaluate after a solve)."""
    k = clamp_log_acos(key("p", 0), np.zeros(2)).kernel
    assert [c["function"] for c in k.clamps] == ["log", "acos"]
    assert k.clamps[1]["low"] == -1.0 and k.clamps[1]["high"] == 1.0
    vals = k.clamp_arguments((np.array([[-2.0, 1.5]]),), np.zeros((1, 2)))
    np.testing.assert_allclose(vals, [[-2.0, 1.5]])
    g = FactorGraph([clamp_log_acos(key("p", 0), np.array([0.0, 0.5]))])
    v = Variables().add(key("p", 0), np.array([-2.0, 0.5]))
    with pytest.warns(fgopt.FgoptWarning):
        r = fgopt.optimize(g, v)
    assert [h.function for h in r.clamps] == ["log"] and r.clamps[0].value == -2.0
    assert no_clamp(key("p", 0), np.zeros(2)).kernel.clamp_arguments is None


@pytest.mark.parametrize("kind", ["lm", "gn"])
def test_nonfinite_start_at_a_clamp_says_which_clamp(kind):
    """acos's clamp keeps the value finite but not its Jacobian (-1/sqrt(1 - 1) times 0): from
    acos(1.5) the start is non-finite; the NonFiniteError names the factor and the clamp."""
    g = FactorGraph([clamp_log_acos(key("p", 0), np.array([0.0, 0.5]))])
    v = Variables().add(key("p", 0), np.array([2.0, 1.5]))
    with pytest.raises(fgopt.errors.NonFiniteError, match=r"clamp_log_acos\(p0\).*acos at .*"
                       r"argument 1\.5 above 1"):
        _run(kind, g, v)
