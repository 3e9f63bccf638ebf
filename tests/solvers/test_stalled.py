"""A run whose last steps were all rejected reports ``Status.STALLED``, never CONVERGED.

The case that motivated it (issue 10): miniSAM's GPS-factor example ported verbatim has a wrong
hand-written Jacobian (``[[1, 0, 0], [0, 1, 0]]``: miniSAM's SE(2) tangent order is
``(x, y, theta)`` and it ignores the rotation of the translation perturbation). LM used to end
0.84 m off reporting CONVERGED after ten rejected steps, once the step-size test fired.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import fgopt
from fgopt import FactorGraph, Variables, key
from fgopt.solvers import Status
from fgopt.symbolic import Scalar, sqrt

from ._minisam_gps import GPSFactor, gps_example


@pytest.mark.parametrize("method", ["lm", "dogleg"])
def test_gps_example_with_wrong_jacobian_is_not_converged(method):
    """LM and Dogleg stall on the wrong Jacobian: the status is STALLED (not a success), the
    message and the repr say every step since some iteration was rejected (LM) or fell far short
    of the model (Dogleg, whose gain ratio stays near 0.24 while its radius collapses)."""
    g, v = gps_example()
    r = fgopt.optimize(g, v, method=method)
    assert r.status is Status.STALLED, r
    assert not r.success
    assert "every step since iteration" in r.message
    assert "stalled" in repr(r) and "check_jacobians" in repr(r)
    recs = r.iteration_records
    if method == "lm":
        assert not recs[-1].accepted
    else:  # Dogleg's steps are still (barely) accepted while its radius collapses
        assert all(b.lam < a.lam for a, b in zip(recs[-10:], recs[-9:]))
    assert np.all(np.isfinite(r.values.at(key("x", 1)).translation()))


def test_gps_example_with_right_jacobian_converges():
    """The same graph with the right Jacobian converges to the GPS line (y = 0, theta = 0)."""
    g, v = gps_example(GPSFactor)
    for method in ("lm", "gn", "dogleg"):
        r = fgopt.optimize(g, v, method=method)
        assert r.status is Status.CONVERGED, (method, r)
        for i in (1, 2, 3):
            x = r.values.at(key("x", i))
            assert abs(x.y()) < 1e-4 and abs(x.theta()) < 1e-4 and abs(x.x() - 5 * (i - 1)) < 1e-4


@fgopt.factor
def edge(x: Scalar) -> Scalar:
    """sqrt(1 - x) + 0.1: decreasing up to x = 1, NaN beyond (no epsilon)."""
    return Scalar(sqrt(1 - x, epsilon=0) + 0.1)


def test_general_path_and_small_driver_report_the_same_stall(monkeypatch):
    """LM walks to the edge of the residual's domain, where every longer step is NaN: with
    step_tolerance 1e-7 the step test fires right after rejected (NaN) steps. Both the general
    path and the small-problem driver report STALLED, from the same iteration, with finite
    values."""
    from fgopt.solvers import LevenbergMarquardt, LMParams, small

    g = FactorGraph([edge(x=key("x", 0))])
    v = Variables().add(key("x", 0), 0.0)
    opts = {"absolute_tolerance": 0.0, "relative_tolerance": 0.0, "step_tolerance": 1e-7}
    monkeypatch.setattr(small, "COMPILE_IN_FOREGROUND", False)
    monkeypatch.setattr(small, "COMPILE_AFTER_SECONDS", float("inf"))
    monkeypatch.setattr(small, "_PLANS", {})
    monkeypatch.setattr(small._Plan, "marker", lambda self: Path("/nonexistent/x.ready"))
    rd = fgopt.optimize(g, v, **opts)
    monkeypatch.setattr(small, "COMPILE_IN_FOREGROUND", True)
    monkeypatch.setattr(small, "_PLANS", {})
    rf = LevenbergMarquardt(LMParams(backend="numba", **opts)).optimize(g, v)
    assert "driver" not in rd.linear_solver and "driver" in rf.linear_solver
    for r in (rd, rf):
        assert r.status is Status.STALLED, r
        assert not r.iteration_records[-1].accepted
        assert np.isfinite(float(r.values.at(key("x", 0))))
    assert rd.message == rf.message and rd.iterations == rf.iterations


def test_stall_rule():
    """The rule: CONVERGED becomes STALLED only after trailing rejected steps whose predicted
    decrease the cost could resolve (> 1e-10 of it)."""
    from fgopt.solvers.result import stall_status

    st, msg = stall_status(Status.CONVERGED, "step norm 1e-12 below step_tolerance", 0.14, 9, 0.1)
    assert st is Status.STALLED and "since iteration 9" in msg
    # a rejected step whose predicted decrease is below rounding of the cost is convergence
    assert stall_status(Status.CONVERGED, "x", 1e3, 9, 1e-12)[0] is Status.CONVERGED
    # an accepted last step (no trailing rejections) stays converged; other statuses unchanged
    assert stall_status(Status.CONVERGED, "x", 1.0, None, 0.0)[0] is Status.CONVERGED
    assert stall_status(Status.FAILED, "x", 1.0, 3, 1.0)[0] is Status.FAILED
