"""Non-finite values in every solver and every factor path (issue 10).

The matrix is method (LM, Gauss-Newton, Dogleg, GNC) x path (a batched
kernel written by hand, an ``@fgopt.factor`` generated kernel, a Python ``Factor``) x scenario:

* ``nan_residual``: the first full step lands where the residual is NaN (``sqrt(1 - x)`` beyond
  ``x = 1``). The step must be rejected and the method must adapt (LM damping, the dogleg radius,
  Gauss-Newton backtracking) and still reach the finite optimum ``x = 0.99``.
* ``nan_jacobian``: the first full step lands where the residual is finite and the cost lower,
  but the Jacobian is NaN (``x - 1.1 + sqrt(max(x - 1, 0))`` left of ``x = 1``). Accepting it used
  to raise from Gauss-Newton and Dogleg when they relinearized; it is a rejected step now.
* ``nan_initial``: non-finite at the initial values raises a NonFiniteError naming the factor.

Every run checks that the result holds only finite values and the caller's Variables are
untouched.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import fgopt
from fgopt import FactorGraph, Variables, key
from fgopt.errors import NonFiniteError
from fgopt.factors import Factor, KernelFactor
from fgopt.factors.kernel import FactorKernel
from fgopt.manifolds.base import SCALAR_KIND
from fgopt.solvers import GNCParams, LMParams
from fgopt.symbolic import Max, Scalar, sqrt

X = key("x", 0)

# ---------------------------------------------------------------------------- the two residuals
# (A) r = sqrt(1 - x) - 0.1: NaN residual for x > 1; optimum x = 0.99; from x = 0 the
#     Gauss-Newton step is 1.8 (into the NaN region).
# (B) r = x - 1.1 + sqrt(max(x - 1, 0)): finite residual everywhere, NaN Jacobian for x < 1;
#     optimum x = 1 + t^2 with t^2 + t = 0.1; from x = 5 the Gauss-Newton step lands at 0.28
#     (lower cost, NaN Jacobian).
T_B = (-1.0 + np.sqrt(1.4)) / 2.0
OPTIMUM = {"nan_residual": 0.99, "nan_jacobian": 1.0 + T_B * T_B}
START = {"nan_residual": 0.0, "nan_jacobian": 5.0, "nan_initial": 2.0}


def _res_a(x):
    with np.errstate(all="ignore"):
        return np.sqrt(1.0 - x) - 0.1, -0.5 / np.sqrt(1.0 - x)


def _res_b(x):
    with np.errstate(all="ignore"):
        m = np.maximum(x - 1.0, 0.0)
        return x - 1.1 + np.sqrt(m), 1.0 + np.where(x > 1.0, 1.0, 0.0) * (0.5 / np.sqrt(m))


FUNCS = {"a": _res_a, "b": _res_b}


# ---------------------------------------------------------------------------- path 1: a hand kernel
def _hand_kernel(which: str) -> FactorKernel:
    f = FUNCS[which]

    def residual(args, consts):
        return f(args[0][:, 0])[0][:, None]

    def linearize(args, consts):
        r, j = f(args[0][:, 0])
        return r[:, None], j[:, None, None]

    return FactorKernel(name=f"hand_{which}", arg_kinds=(SCALAR_KIND,), residual_dim=1,
                        num_constants=0, residual=residual, linearize=linearize)


HAND = {w: _hand_kernel(w) for w in FUNCS}


def hand_factor(which):
    return KernelFactor(HAND[which], [X], np.zeros(0))


# ---------------------------------------------------------------------------- path 2: @fgopt.factor
@fgopt.factor
def gen_a(x: Scalar) -> Scalar:
    return Scalar(sqrt(1 - x, epsilon=0) - 0.1)


@fgopt.factor
def gen_b(x: Scalar) -> Scalar:
    return Scalar(x - 1.1 + sqrt(Max(x - 1, 0), epsilon=0))


def generated_factor(which):
    return {"a": gen_a, "b": gen_b}[which](x=X)


# ---------------------------------------------------------------------------- path 3: Python factor
class PyA(Factor):
    def __init__(self, k):
        super().__init__([k], 1)

    def error(self, values):
        return np.array([_res_a(values.at(self.keys[0]))[0]])

    def jacobians(self, values):
        return [np.array([[_res_a(values.at(self.keys[0]))[1]]])]


class PyB(PyA):
    def error(self, values):
        return np.array([_res_b(values.at(self.keys[0]))[0]])

    def jacobians(self, values):
        return [np.array([[_res_b(values.at(self.keys[0]))[1]]])]


def python_factor(which):
    return {"a": PyA, "b": PyB}[which](X)


PATHS = {"hand": hand_factor, "generated": generated_factor, "python": python_factor}
NAMES = {("hand", "a"): "hand_a", ("generated", "a"): "gen_a", ("python", "a"): "PyA"}
METHODS = ["lm", "gn", "dogleg", "gnc"]


def problem(path, scenario):
    which = "b" if scenario == "nan_jacobian" else "a"
    v = Variables().add(X, START[scenario])
    return FactorGraph([PATHS[path](which)]), v


TIGHT = {"absolute_tolerance": 1e-14, "relative_tolerance": 1e-12}


def run(method, graph, v):
    if method == "gnc":
        return fgopt.optimize(graph, v, method="gnc",
                              params=GNCParams(lm=LMParams(**TIGHT), max_iterations=100))
    options = {"initial_radius": 10.0} if method == "dogleg" else {}  # full Gauss-Newton step first
    return fgopt.optimize(graph, v, method=method, max_iterations=100, **TIGHT, **options)


@pytest.mark.parametrize("scenario", ["nan_residual", "nan_jacobian"])
@pytest.mark.parametrize("path", list(PATHS))
@pytest.mark.parametrize("method", METHODS)
def test_nonfinite_trial_is_a_rejected_step(method, path, scenario):
    """The non-finite trial point is rejected, the method adapts and reaches the optimum; the
    result is finite and the caller's Variables are untouched."""
    graph, v = problem(path, scenario)
    before = v.copy()
    r = run(method, graph, v)
    x = float(r.values.at(X))
    assert v == before
    assert np.isfinite(x) and np.isfinite(r.final_cost)
    assert r.success, r
    assert abs(x - OPTIMUM[scenario]) < 1e-5, (x, r)
    assert r.final_cost < 1e-10
    if method != "gnc":  # GNC's result carries no per-iteration records
        assert any(not rec.accepted for rec in r.iteration_records), r.table()


@pytest.mark.parametrize("path", list(PATHS))
@pytest.mark.parametrize("method", METHODS)
def test_nonfinite_initial_point_names_the_factor(method, path):
    """NaN at the initial values raises a NonFiniteError naming the factor; the caller's
    Variables are untouched."""
    graph, v = problem(path, "nan_initial")
    before = v.copy()
    with pytest.raises(NonFiniteError, match=NAMES[path, "a"]):
        run(method, graph, v)
    assert v == before


def test_dogleg_shrinks_its_radius_on_a_nan_step():
    """Dogleg used to retry the same NaN step (its gain ratio was NaN, so the radius never
    changed) until max_iterations; now each rejection shrinks the radius below the step."""
    graph, v = problem("python", "nan_residual")
    r = fgopt.optimize(graph, v, method="dogleg", initial_radius=10.0)
    radii = [rec.lam for rec in r.iteration_records]
    assert r.success and r.iterations < 30, r.table()
    assert radii[1] < radii[0], r.table()


def test_nonfinite_jacobian_among_other_factors_is_rejected_mid_run():
    """Three variables, two kernels: the step that makes one Jacobian NaN is rejected as a whole;
    LM, Gauss-Newton and Dogleg still reach every optimum."""
    g = FactorGraph()
    v = Variables()
    for i in range(3):
        k = key("x", i)
        g.add(KernelFactor(HAND["b" if i == 1 else "a"], [k], np.zeros(0)))
        v.add(k, 5.0 if i == 1 else 0.0)
    for method in ("lm", "gn", "dogleg"):
        r = run(method, g, v)
        assert r.success, (method, r)
        xs = [float(r.values.at(key("x", i))) for i in range(3)]
        assert np.allclose(xs, [0.99, OPTIMUM["nan_jacobian"], 0.99], atol=1e-5), (method, xs)


_entries = st.one_of(st.floats(allow_nan=True, allow_infinity=True),
                     st.sampled_from([1e308, -1e308, 1.7e308, np.inf, -np.inf, np.nan]))


@settings(max_examples=300, deadline=None)
@given(st.lists(_entries, min_size=0, max_size=12), st.lists(_entries, min_size=1, max_size=6),
       _entries)
def test_finiteness_checks_agree_with_isfinite_entry_by_entry(h, g, total):
    """The solvers' finiteness tests (a sum of squares is finite iff every entry is, unless it
    overflows: then entry by entry) say exactly what ``np.isfinite(...).all()`` says, also for
    arrays of huge finite entries whose sum of squares overflows."""
    from fgopt.problem import _all_finite, _linearization_finite

    H, gv = np.array(h, dtype=float), np.array(g, dtype=float)
    assert _all_finite(H) == bool(np.isfinite(H).all())
    assert _all_finite(H.reshape(-1, 1)) == bool(np.isfinite(H).all())
    expected = bool(np.isfinite(total) and np.isfinite(H).all() and np.isfinite(gv).all())
    assert _linearization_finite(total, H, gv) == expected
