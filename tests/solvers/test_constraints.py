"""Equality / inequality constraints (``@fgopt.constraint``) solved by ``fgopt.optimize``'s
augmented-Lagrangian loop: closed-form optima and multipliers, manifolds (Pose2, the declared
Unit3), scipy's SLSQP / trust-constr on the same problems, and bad input."""

from __future__ import annotations

import numpy as np
import pytest

import fgopt
from fgopt import key
from fgopt.errors import FgoptError, KeyNotFoundError, NonFiniteError
from fgopt.solvers.constrained import AugmentedLagrangianParams
from fgopt.symbolic import V1, V2, V3, Pose2, Scalar, Unit3


@fgopt.factor
def pull2(x: V2, target: V2) -> V2:
    return x - target


@fgopt.factor
def pull1(x: Scalar, target: Scalar) -> Scalar:
    return x - target


@fgopt.constraint
def on_circle(x: V2, radius: Scalar) -> V1:
    return V1(x[0] * x[0] + x[1] * x[1] - radius * radius)


@fgopt.constraint(inequality=True)
def at_most(x: Scalar, upper: Scalar) -> Scalar:
    return x - upper


@fgopt.constraint(inequality=True)
def at_least(x: Scalar, lower: Scalar) -> Scalar:
    return lower - x


@fgopt.constraint
def equal_to(x: Scalar, value: Scalar) -> Scalar:
    return x - value


def _circle_problem(target=(2.0, 1.0), radius=1.0, start=(0.3, 0.2)):
    g = fgopt.FactorGraph()
    g.add(pull2(x=key("n", 0), target=np.array(target)))
    g.add(on_circle(x=key("n", 0), radius=radius))
    v = fgopt.Variables()
    v.add(key("n", 0), np.array(start))
    return g, v


def test_projection_onto_circle_matches_closed_form():
    """min 0.5|x - t|^2 s.t. |x| = r: x* = r t/|t|, multiplier (|t|/r - 1)/2 (from
    x - t + 2 lambda x = 0), violation below the tolerance, status CONVERGED."""
    g, v = _circle_problem(radius=1.5)
    r = fgopt.optimize(g, v)
    t = np.array([2.0, 1.0])
    assert r.status is fgopt.Status.CONVERGED
    assert r.constraint_violation <= 1e-8
    np.testing.assert_allclose(r.values.at(key("n", 0)), 1.5 * t / np.linalg.norm(t), atol=1e-6)
    assert len(r.multipliers) == 1
    np.testing.assert_allclose(r.multipliers[0], [(np.linalg.norm(t) / 1.5 - 1) / 2], rtol=1e-5)
    assert r.final_cost == pytest.approx(0.5 * (np.linalg.norm(t) - 1.5) ** 2, rel=1e-7)


def test_caller_values_untouched_and_graph_cost_excludes_constraints():
    """optimize leaves the caller's Variables as they were; graph.error ignores constraints
    (they are not part of the cost) and graph.constraints lists them apart from the factors."""
    g, v = _circle_problem()
    before = v.at(key("n", 0)).copy()
    fgopt.optimize(g, v)
    np.testing.assert_array_equal(v.at(key("n", 0)), before)
    assert len(g) == 1 and len(g.constraints) == 1
    assert g.error(v) == pytest.approx(0.5 * np.sum((before - [2.0, 1.0]) ** 2))
    assert "constraints: 1" in repr(g)


@pytest.mark.parametrize("upper, expected, multiplier", [(1.0, 1.0, 2.0), (5.0, 3.0, 0.0)])
def test_inequality_active_and_inactive(upper, expected, multiplier):
    """min 0.5 (x - 3)^2 s.t. x <= u: x* = min(3, u); the multiplier is 3 - u when active
    (x - 3 + lambda = 0) and exactly 0 when not."""
    g = fgopt.FactorGraph()
    g.add(pull1(x=key("x", 0), target=3.0))
    g.add(at_most(x=key("x", 0), upper=upper))
    v = fgopt.Variables()
    v.add(key("x", 0), 0.0)
    r = fgopt.optimize(g, v)
    assert r.status is fgopt.Status.CONVERGED
    assert r.values.at(key("x", 0)) == pytest.approx(expected, abs=1e-7)
    assert r.multipliers[0][0] == pytest.approx(multiplier, abs=1e-6)
    assert r.multipliers[0][0] >= 0.0


def test_kkt_stationarity_with_several_constraints():
    """At the solution, grad f + sum_i J_i^T lambda_i = 0 (the multipliers' sign convention),
    with an equality and an active inequality over the same variables."""

    @fgopt.constraint(inequality=True)
    def below_line(x: V2) -> V1:
        return V1(x[0] + x[1] - 1.2)

    g = fgopt.FactorGraph()
    g.add(pull2(x=key("n", 0), target=np.array([2.0, 1.0])))
    g.add(on_circle(x=key("n", 0), radius=1.0))
    g.add(below_line(x=key("n", 0)))
    v = fgopt.Variables()
    v.add(key("n", 0), np.array([0.5, 0.5]))
    r = fgopt.optimize(g, v)
    assert r.status is fgopt.Status.CONVERGED
    x = r.values.at(key("n", 0))
    grad = x - np.array([2.0, 1.0])
    grad = grad + r.multipliers[0][0] * 2 * x + r.multipliers[1][0] * np.ones(2)
    np.testing.assert_allclose(grad, 0.0, atol=1e-5)
    assert x.sum() == pytest.approx(1.2, abs=1e-7) and x @ x == pytest.approx(1.0, abs=1e-7)
    assert r.multipliers[1][0] > 0


def test_constraint_jacobians_match_central_differences_on_pose2():
    """A constraint over Pose2 near theta = pi has tangent-space Jacobians equal to central
    differences through retract (the factor machinery's kernels)."""

    @fgopt.constraint
    def heading_dist(a: Pose2, b: Pose2, d: Scalar) -> V2:
        t = a.inverse().act(b.translation())
        return V2(t[0] * t[0] + t[1] * t[1] - d * d, t[1])

    vals = fgopt.Variables()
    vals.add(key("x", 0), fgopt.SE2.from_xytheta(0.3, -0.2, np.pi - 1e-3))
    vals.add(key("x", 1), fgopt.SE2.from_xytheta(1.1, 0.7, 0.4))
    c = heading_dist(a=key("x", 0), b=key("x", 1), d=1.0)
    Js = c.jacobians(vals)
    num = fgopt.factors.numerical_jacobians(c.error, vals, c.keys)
    for J, N in zip(Js, num):
        np.testing.assert_allclose(J, N, atol=1e-7)


def test_pose2_constraint_matches_scipy_slsqp():
    """Three Pose2 poses pulled to priors, the last one's position kept on the circle |t| = 2
    and x >= 1.2: the optimum matches scipy SLSQP over (x, y, theta) with the same cost
    (prior residual = [theta - theta0, R(theta0)^T (t - t0)] for Pose2 priors of fgopt's
    tangent order, here via a plain vector factor so both sides agree exactly)."""
    from scipy.optimize import minimize

    @fgopt.factor
    def prior_xyt(p: Pose2, target: V3) -> V3:
        t = p.translation()
        return V3(t[0] - target[0], t[1] - target[1], p.rotation().log() - target[2])

    @fgopt.constraint
    def radius(p: Pose2, r: Scalar) -> V1:
        t = p.translation()
        return V1(t[0] * t[0] + t[1] * t[1] - r * r)

    @fgopt.constraint(inequality=True)
    def min_x(p: Pose2, lo: Scalar) -> V1:
        return V1(lo - p.translation()[0])

    targets = np.array([[0.0, 0.0, 0.1], [1.0, 0.3, 0.2], [0.5, 2.5, -0.3]])
    g, v = fgopt.FactorGraph(), fgopt.Variables()
    for i, t in enumerate(targets):
        g.add(prior_xyt(p=key("x", i), target=t))
        v.add(key("x", i), fgopt.SE2.from_xytheta(0.0, 0.0, 0.0))
    g.add(radius(p=key("x", 2), r=2.0))
    g.add(min_x(p=key("x", 2), lo=1.2))
    r = fgopt.optimize(g, v)
    assert r.status is fgopt.Status.CONVERGED

    def f(z):
        return 0.5 * np.sum((z.reshape(3, 3) - targets) ** 2)

    cons = [{"type": "eq", "fun": lambda z: z[6] ** 2 + z[7] ** 2 - 4.0},
            {"type": "ineq", "fun": lambda z: z[6] - 1.2}]
    ref = minimize(f, np.r_[np.zeros(6), 1.5, 1.0, 0.0], method="SLSQP", constraints=cons,
                   options={"ftol": 1e-12, "maxiter": 500})
    assert ref.success
    p2 = r.values.at(key("x", 2))
    got = np.array([p2.translation()[0], p2.translation()[1], p2.theta()])
    np.testing.assert_allclose(got, ref.x[6:], atol=1e-6)
    assert r.final_cost == pytest.approx(ref.fun, rel=1e-7)


def test_declared_manifold_unit3():
    """A constraint over the declared Unit3 (@fgopt.manifold): a direction pulled towards
    t = (1, 1, 1)/sqrt(3) and kept in the plane z = 0 ends at (1, 1, 0)/sqrt(2), the closest
    unit vector of the plane (the prior's residual is the tangent-space difference)."""

    @fgopt.factor
    def dir_prior(d: Unit3, target: Unit3) -> V2:
        return target.local(d)

    @fgopt.constraint
    def in_plane(d: Unit3) -> V1:
        return V1(d.point3()[2])

    t = fgopt.Unit3.from_storage(np.array([1.0, 1.0, 1.0]) / np.sqrt(3))
    g, v = fgopt.FactorGraph(), fgopt.Variables()
    g.add(dir_prior(d=key("d", 0), target=t))
    g.add(in_plane(d=key("d", 0)))
    v.add(key("d", 0), fgopt.Unit3.from_storage(np.array([0.2, 0.9, 0.4]) / np.linalg.norm(
        [0.2, 0.9, 0.4])))
    r = fgopt.optimize(g, v)
    assert r.status is fgopt.Status.CONVERGED
    np.testing.assert_allclose(r.values.at(key("d", 0)).to_storage(),
                               np.array([1.0, 1.0, 0.0]) / np.sqrt(2), atol=1e-6)


def test_contradictory_constraints_end_infeasible():
    """x = 0 and x = 1 together cannot hold: the run ends INFEASIBLE (never CONVERGED) with a
    violation near 0.5, and the caller's values are untouched."""
    g = fgopt.FactorGraph()
    g.add(pull1(x=key("x", 0), target=3.0))
    g.add(equal_to(x=key("x", 0), value=0.0))
    g.add(equal_to(x=key("x", 0), value=1.0))
    v = fgopt.Variables()
    v.add(key("x", 0), 0.7)
    r = fgopt.optimize(g, v)
    assert r.status is fgopt.Status.INFEASIBLE
    assert not r.success
    assert r.constraint_violation == pytest.approx(0.5, abs=1e-3)
    assert v.at(key("x", 0)) == 0.7


def test_contradictory_inequalities_end_infeasible():
    """x <= 0 and x >= 1: INFEASIBLE, with the largest violation reported."""
    g = fgopt.FactorGraph()
    g.add(pull1(x=key("x", 0), target=3.0))
    g.add(at_most(x=key("x", 0), upper=0.0))
    g.add(at_least(x=key("x", 0), lower=1.0))
    v = fgopt.Variables()
    v.add(key("x", 0), 0.2)
    r = fgopt.optimize(g, v)
    assert r.status is fgopt.Status.INFEASIBLE
    assert r.constraint_violation == pytest.approx(0.5, abs=1e-3)


def test_never_converged_above_tolerance():
    """Whatever the outer-iteration budget, a CONVERGED run has its violation within the
    tolerance; a run cut short reports INFEASIBLE instead."""
    g, v = _circle_problem(start=(3.0, -2.0))
    for outer in (1, 2, 3, 50):
        ap = AugmentedLagrangianParams(max_outer_iterations=outer, constraint_tolerance=1e-10)
        r = fgopt.optimize(g, v, constraint_params=ap)
        if r.status is fgopt.Status.CONVERGED:
            assert r.constraint_violation <= 1e-10
        else:
            assert r.status in (fgopt.Status.INFEASIBLE, fgopt.Status.MAX_ITERATIONS)
            if r.constraint_violation > 1e-10:
                assert r.status is fgopt.Status.INFEASIBLE


def test_constraint_over_missing_key_names_it():
    """A constraint over a key without an initial value: KeyNotFoundError naming the
    constraint and the key."""
    g, v = _circle_problem()
    g.add(at_most(x=key("q", 7), upper=1.0))
    with pytest.raises(KeyNotFoundError, match=r"at_most\(q7\).*q7"):
        fgopt.optimize(g, v)


def test_nonfinite_constraint_value_names_it():
    """A constraint that is NaN at the initial values: NonFiniteError naming the constraint."""
    @fgopt.constraint
    def root(x: Scalar) -> Scalar:
        return x * x * x * x - 1.0  # inf (overflow) at x = 1e100

    g = fgopt.FactorGraph()
    g.add(pull1(x=key("x", 0), target=3.0))
    g.add(root(x=key("x", 0)))
    v = fgopt.Variables()
    v.add(key("x", 0), 1e100)
    with pytest.raises(NonFiniteError, match=r"root\(x0\)"):
        fgopt.optimize(g, v)


def test_bad_usage_errors():
    """A constraint takes no loss; other methods than LM and bad constraint_params are refused
    with FgoptError."""
    with pytest.raises(FgoptError, match="no loss"):
        equal_to(x=key("x", 0), value=1.0, loss=fgopt.noise.Isotropic.sigma(1, 1.0))
    g, v = _circle_problem()
    with pytest.raises(FgoptError, match="method='lm'"):
        fgopt.optimize(g, v, method="gn")
    with pytest.raises(FgoptError, match="AugmentedLagrangianParams"):
        fgopt.optimize(g, v, constraint_params={"constraint_tolerance": 1e-3})


def test_only_constraints_no_factors():
    """A graph of constraints alone is a feasibility problem: the result satisfies them."""
    g = fgopt.FactorGraph()
    g.add(on_circle(x=key("n", 0), radius=2.0))
    v = fgopt.Variables()
    v.add(key("n", 0), np.array([0.5, 0.5]))
    r = fgopt.optimize(g, v)
    assert r.status is fgopt.Status.CONVERGED
    assert np.linalg.norm(r.values.at(key("n", 0))) == pytest.approx(2.0, abs=1e-8)


def test_optimizers_that_do_not_enforce_constraints_refuse_them():
    """LevenbergMarquardt / GaussNewton / Dogleg called directly, and the incremental smoother,
    raise FgoptError naming the constraint instead of dropping it (or treating it as a soft
    factor) without a word."""
    from fgopt.solvers import Dogleg, GaussNewton, LevenbergMarquardt

    g, v = _circle_problem()
    for cls in (LevenbergMarquardt, GaussNewton, Dogleg):
        with pytest.raises(FgoptError, match=r"on_circle\(n0\) == 0"):
            cls().optimize(g, v)
    smoother = fgopt.IncrementalSmoother()
    with pytest.raises(FgoptError, match="constraint"):
        smoother.update(g, v)
    with pytest.raises(FgoptError, match="constraint"):
        smoother.update([g.constraints[0]], v)


def _step_length_constraint():
    @fgopt.constraint
    def step_length(a: Pose2, b: Pose2, d: Scalar) -> V1:
        t = b.translation() - a.translation()
        return V1(t[0] * t[0] + t[1] * t[1] - d * d)

    return step_length


def test_real_pose_graph_constraints_that_hold_at_the_optimum_change_nothing():
    """w100 (a real TORO pose graph, 100 poses): step-length equalities on 20 odometry steps,
    with lengths taken from the unconstrained optimum, hold there: the constrained solve
    returns the same poses (to the solvers' tolerances) and cost, with multipliers ~0. With
    every length 5 % longer, the constraints hold to 1e-8, the cost rises and the multipliers
    are not zero."""
    import os

    path = os.path.join(os.environ.get("FGOPT_DATA", "/work/shared/data"), "small/w100.graph")
    if not os.path.exists(path):
        pytest.skip("FGOPT_DATA has no small/w100.graph")
    g, v = fgopt.io.read(path, add_prior=True, progress=False)
    free = fgopt.optimize(g, v, initialization="given", relative_tolerance=1e-12)
    keys = sorted(v.keys())
    step = _step_length_constraint()

    def length(values, a, b):
        return float(np.linalg.norm(np.asarray(values.at(b).translation())
                                    - np.asarray(values.at(a).translation())))

    pairs = [(keys[i], keys[i + 1]) for i in range(0, 80, 4)]
    for scale, same in ((1.0, True), (1.05, False)):
        gc = g.copy()
        for a, b in pairs:
            gc.add(step(a=a, b=b, d=scale * length(free.values, a, b)))
        r = fgopt.optimize(gc, v)
        assert r.status is fgopt.Status.CONVERGED, r
        assert r.constraint_violation <= 1e-8
        for a, b in pairs:
            assert length(r.values, a, b) == pytest.approx(scale * length(free.values, a, b),
                                                           abs=1e-7)
        if same:
            for k in keys:
                np.testing.assert_allclose(r.values.at(k).to_storage(),
                                           free.values.at(k).to_storage(), atol=1e-4)
            assert max(abs(float(m[0])) for m in r.multipliers) < 1e-4
            assert r.final_cost == pytest.approx(free.final_cost, rel=1e-6)
        else:
            assert r.final_cost > free.final_cost * (1 + 1e-3)
            assert max(abs(float(m[0])) for m in r.multipliers) > 1e-3


def test_small_constrained_solve_runs_on_numpy_twins():
    """A small constrained solve in a new process stays on the NumPy backend (the penalty
    kernels have NumPy twins when the constraints' kernels do): numba is not imported."""
    import subprocess
    import sys
    from pathlib import Path

    code = (
        "import sys, numpy as np, fgopt\n"
        "from fgopt import key\n"
        "from fgopt.symbolic import V1, V2, Scalar\n"
        "@fgopt.factor\n"
        "def pull2(x: V2, target: V2) -> V2:\n"
        "    return x - target\n"
        "@fgopt.constraint\n"
        "def on_circle(x: V2, radius: Scalar) -> V1:\n"
        "    return V1(x[0] * x[0] + x[1] * x[1] - radius * radius)\n"
        "g, v = fgopt.FactorGraph(), fgopt.Variables()\n"
        "g.add(pull2(x=key('n', 0), target=np.array([2.0, 1.0])))\n"
        "g.add(on_circle(x=key('n', 0), radius=1.0))\n"
        "v.add(key('n', 0), np.array([0.3, 0.2]))\n"
        "r = fgopt.optimize(g, v)\n"
        "print(r.status.name, r.problem.backend, 'numba' in sys.modules)\n")
    root = Path(__file__).resolve().parents[2]
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=root, env={**__import__("os").environ, "PYTHONPATH": str(root)},
                         timeout=600)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["CONVERGED", "numpy", "False"], out.stdout + out.stderr


@fgopt.constraint
def distance_to(x: V2, center: V2, radius: Scalar) -> V1:
    d = x - center
    return V1(d[0] * d[0] + d[1] * d[1] - radius * radius)


def test_constant_and_bounds_with_constraints_match_scipy_and_closed_form():
    """constant= and bounds= on a graph holding constraints: x pulled to (2, 1), kept at
    distance 1 from a center c that is held constant at 0 (its own factor pulls it to
    (0.5, 0.5)), and x_1 <= 0.3 by a bound. The optimum is (sqrt(1 - 0.09), 0.3) (closed
    form; SLSQP with the same bound agrees), c keeps its value bit for bit, the bound's
    multiplier-free side stays feasible, and the caller's Variables are untouched."""
    from scipy.optimize import minimize

    g = fgopt.FactorGraph()
    g.add(pull2(x=key("x", 0), target=np.array([2.0, 1.0])))
    g.add(pull2(x=key("c", 0), target=np.array([0.5, 0.5])))
    g.add(distance_to(x=key("x", 0), center=key("c", 0), radius=1.0))
    v = fgopt.Variables()
    v.add(key("x", 0), np.array([0.3, 0.2]))
    c0 = np.array([1e-17, -0.0])
    v.add(key("c", 0), c0.copy())
    before = {k: np.array(v.at(k)).copy() for k in v}
    r = fgopt.optimize(g, v, constant=[key("c", 0)],
                       bounds={key("x", 0): (np.array([-np.inf, -np.inf]), np.array([np.inf, 0.3]))},
                       constraint_params=AugmentedLagrangianParams(constraint_tolerance=1e-10))
    assert r.status is fgopt.Status.CONVERGED, r
    assert r.values.at(key("c", 0)).tobytes() == c0.tobytes()
    x = r.values.at(key("x", 0))
    np.testing.assert_allclose(x, [np.sqrt(1 - 0.09), 0.3], atol=1e-8)
    ref = minimize(lambda z: 0.5 * np.sum((z - [2.0, 1.0]) ** 2), [0.3, 0.2], method="SLSQP",
                   bounds=[(None, None), (None, 0.3)], options={"ftol": 1e-14},
                   constraints=[{"type": "eq", "fun": lambda z: z @ z - 1.0}])
    np.testing.assert_allclose(x, ref.x, atol=1e-7)
    for k, val in before.items():
        assert np.array(v.at(k)).tobytes() == val.tobytes()


def test_constant_variable_inside_a_constraint_matches_a_free_solve_with_it_fixed():
    """A constant variable that only a constraint and its own prior see: the result equals
    the solve in which that variable's value is a number in the constraint (the same
    problem without it), to solver tolerance (LM's relative cost decrease 1e-13 leaves ~3e-7
    along the circle)."""
    g = fgopt.FactorGraph()
    g.add(pull2(x=key("x", 0), target=np.array([2.0, 1.0])))
    g.add(pull2(x=key("c", 0), target=np.array([5.0, 5.0])))
    g.add(distance_to(x=key("x", 0), center=key("c", 0), radius=0.5))
    v = fgopt.Variables()
    v.add(key("x", 0), np.array([1.0, 0.4]))
    v.add(key("c", 0), np.array([1.0, 0.5]))
    r = fgopt.optimize(g, v, constant={key("c", 0): None})
    g2 = fgopt.FactorGraph()
    g2.add(pull2(x=key("x", 0), target=np.array([2.0, 1.0])))
    g2.add(distance_to(x=key("x", 0), center=np.array([1.0, 0.5]), radius=0.5))
    v2 = fgopt.Variables()
    v2.add(key("x", 0), np.array([1.0, 0.4]))
    r2 = fgopt.optimize(g2, v2)
    assert r.status is r2.status is fgopt.Status.CONVERGED
    assert r.values.at(key("c", 0)).tobytes() == np.array([1.0, 0.5]).tobytes()
    # closed form: the center plus radius times the unit direction to the target
    exact = np.array([1.0, 0.5]) + 0.5 * np.array([1.0, 0.5]) / np.sqrt(1.25)
    for res in (r, r2):
        np.testing.assert_allclose(res.values.at(key("x", 0)), exact, atol=1e-6)


def test_gnc_and_chordal_start_on_constrained_graphs():
    """method='gnc' on a graph with constraints raises an FgoptError saying GNC does not
    enforce them and to use method='lm'; initialization='chordal' starts the augmented-
    Lagrangian loop from the chordal relaxation (M3500, real; 20 step lengths 5 % longer
    than at the unconstrained optimum), reaching the same constrained optimum as the start from
    the file's values, and says so in result.info."""
    import os

    g, v = _circle_problem()
    with pytest.raises(FgoptError, match=r"method='gnc' does not enforce constraints.*"
                                         r"use method='lm'"):
        fgopt.optimize(g, v, method="gnc")
    path = os.path.join(os.environ.get("FGOPT_DATA", "/work/shared/data"),
                        "pose2d/input_M3500_g2o.g2o")
    if not os.path.exists(path):
        pytest.skip("FGOPT_DATA has no pose2d/input_M3500_g2o.g2o")
    g, v = fgopt.io.read(path, add_prior=True, progress=False)
    keys = sorted(v.keys())
    step = _step_length_constraint()
    free = fgopt.optimize(g, v, initialization="given").values
    gc = g.copy()
    for a, b in [(keys[i], keys[i + 1]) for i in range(0, 3400, 170)]:
        d = np.linalg.norm(np.asarray(free.at(b).translation() - free.at(a).translation()))
        gc.add(step(a=a, b=b, d=1.05 * d))
    given = fgopt.optimize(gc, v)
    chordal = fgopt.optimize(gc, v, initialization="chordal")
    assert (given.info["initialization"], chordal.info["initialization"]) == ("given", "chordal")
    for r in (given, chordal):
        assert r.status is fgopt.Status.CONVERGED, r
    assert chordal.final_cost == pytest.approx(given.final_cost, rel=1e-6)
