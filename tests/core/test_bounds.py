"""Constant variables, constant coordinates and bounds (fgopt.bounds, issue 43 items 1, 2, 4)."""

from __future__ import annotations

import os

import numpy as np
import pytest

import fgopt
from fgopt import SE3, Key, key
from fgopt.cameras import Cal3_S2, ProjectionFactor
from fgopt.errors import FgoptError, have_extra
from fgopt.noise import Isotropic
from fgopt.symbolic import V1, V2, V3, exp

DATA = os.environ.get("FGOPT_DATA", "/work/shared/data")
M3500 = os.path.join(DATA, "pose2d/input_M3500_g2o.g2o")
LADYBUG = os.path.join(DATA, "bal/problem-49-7776-pre.txt")
TIGHT = dict(absolute_tolerance=0.0, relative_tolerance=1e-14, gradient_tolerance=1e-12,
             max_iterations=200)


@fgopt.factor
def decay_fit(p: V3, ty: V2) -> V1:
    return V1(p[0] * exp(-p[1] * ty[0]) + p[2] - ty[1])


@fgopt.factor
def pair_fit(a: V2, b: V2, m: V3) -> V3:
    """A coupled residual over two vector variables (a sparse, two-block problem)."""
    return V3(a[0] * b[0] - m[0], a[1] + b[1] * b[1] - m[1], a[0] - a[1] * b[1] - m[2])


P = key("p", 0)
T = np.linspace(0.0, 4.0, 40)
Y = 2.0 * np.exp(-1.3 * T) + 0.5 + 0.05 * np.random.default_rng(0).standard_normal(T.shape)


def decay_problem(x0=(1.0, 0.5, 0.7)):
    graph, initial = fgopt.FactorGraph(), fgopt.Variables()
    for t, y in zip(T, Y):
        graph.add(decay_fit(p=P, ty=np.array([t, y])))
    initial.add(P, np.array(x0, dtype=float))
    return graph, initial


def decay_residual(p):
    return p[0] * np.exp(-p[1] * T) + p[2] - Y


def _storage(x):
    return np.asarray(x.to_storage() if hasattr(x, "to_storage") else x, dtype=float)


# ----------------------------------------------------------------------------- item 1: constants
@pytest.fixture(scope="module")
def m3500():
    if not os.path.exists(M3500):
        pytest.skip("M3500 not available")
    return M3500


def _m3500_head(path: str, n: int, tmp_path) -> str:
    """The g2o file of M3500's first ``n`` poses and the edges among them."""
    out = []
    for line in open(path):
        f = line.split()
        if f and f[0] == "VERTEX_SE2" and int(f[1]) < n:
            out.append(line)
        elif f and f[0] == "EDGE_SE2" and int(f[1]) < n and int(f[2]) < n:
            out.append(line)
    p = tmp_path / f"m3500_head{n}.g2o"
    p.write_text("".join(out))
    return str(p)


def test_m3500_constant_poses_match_gtsam_nonlinear_equality(m3500, tmp_path):
    """M3500's first 1,000 poses with every 50th pose constant: those poses come back bit for
    bit, H holds only the free poses, and the optimum (cost and every pose) is GTSAM's with
    NonlinearEqualityPose2 on the same poses."""
    gtsam = pytest.importorskip("gtsam")
    n = 1000
    m3500 = _m3500_head(m3500, n, tmp_path)
    graph, initial = fgopt.io.read_g2o(m3500)
    held = list(range(0, n, 50))
    before = {i: _storage(initial.at(key("x", i))).copy() for i in held}
    result = fgopt.optimize(graph, initial, constant=[key("x", i) for i in held],
                            relative_tolerance=1e-12, absolute_tolerance=0.0,
                            max_iterations=500)
    assert result.status == fgopt.Status.CONVERGED
    assert result.problem.pattern.size == 3 * (n - len(held))
    for i in held:
        assert np.array_equal(_storage(result.values.at(key("x", i))), before[i])
        assert np.array_equal(_storage(initial.at(key("x", i))), before[i])
    g, v = gtsam.readG2o(m3500, False)
    for i in held:
        g.add(gtsam.NonlinearEqualityPose2(i, v.atPose2(i)))
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-12)
    params.setAbsoluteErrorTol(0.0)
    params.setMaxIterations(500)
    out = gtsam.LevenbergMarquardtOptimizer(g, v, params).optimize()
    assert result.final_cost == pytest.approx(g.error(out), rel=1e-6)
    worst = max(np.abs(np.asarray(result.values.at(key("x", i)).translation())
                       - out.atPose2(i).translation()).max() for i in range(n))
    assert worst < 1e-4


@pytest.fixture(scope="module")
def ladybug():
    if not os.path.exists(LADYBUG):
        pytest.skip("Ladybug-49 not available")
    return fgopt.io.read_bal(LADYBUG, progress=False)


def test_ladybug_constant_cameras_leave_the_schur_system(ladybug):
    """Ladybug-49 with 20 of 49 cameras constant: H (and the Schur complement) holds only the 29
    free cameras and the points, the constant cameras come back bit for bit, and the Schur
    path takes the same steps as a sparse Cholesky (CHOLMOD, else fgopt's block one) on the
    full reduced system."""
    graph, initial = ladybug
    held = [key("c", i) for i in range(20)]
    before = [_storage(initial.at(k)).copy() for k in held]
    runs = {}
    full = "cholmod" if have_extra("sksparse") else "block"
    for solver in ("auto", full):
        r = fgopt.optimize(graph, initial, constant=held, linear_solver=solver,
                           max_iterations=5)
        assert r.problem.pattern.size == 29 * 9 + 7776 * 3
        for k, x in zip(held, before):
            assert np.array_equal(_storage(r.values.at(k)), x)
        runs[solver] = r
    assert "schur" in runs["auto"].linear_solver.lower()
    assert runs["auto"].final_cost < runs["auto"].initial_cost
    assert runs["auto"].final_cost == pytest.approx(runs[full].final_cost, rel=1e-7)


def test_constant_coordinates_match_scipy_on_the_reduced_problem():
    """constant={p: [2]} holds coordinate 2 bit for bit and gives scipy's optimum over the
    other two coordinates (Ceres' SubsetManifold)."""
    so = pytest.importorskip("scipy.optimize")
    graph, initial = decay_problem()
    r = fgopt.optimize(graph, initial, constant={P: [2]}, **TIGHT)
    x = _storage(r.values.at(P))
    assert x[2] == 0.7
    ref = so.least_squares(lambda q: decay_residual([q[0], q[1], 0.7]), [1.0, 0.5],
                           xtol=1e-15, ftol=1e-15, gtol=1e-15)
    np.testing.assert_allclose(x[:2], ref.x, rtol=1e-7)
    assert r.final_cost == pytest.approx(0.5 * np.sum(ref.fun ** 2), rel=1e-10)


def test_mixed_whole_and_subset_constants_with_every_method():
    """A dict mixing a whole constant variable and constant coordinates works for LM, GN and
    Dogleg: the held values stay bit for bit, the rest reaches the reduced optimum."""
    so = pytest.importorskip("scipy.optimize")
    A, B = key("a", 0), key("b", 0)
    meas = list(np.random.default_rng(1).normal(size=(6, 3)))
    graph, initial = fgopt.FactorGraph(), fgopt.Variables()
    for m in meas:
        graph.add(pair_fit(a=A, b=B, m=m))
    initial.add(A, np.array([0.3, -0.2]))
    initial.add(B, np.array([0.8, 0.4]))

    def residual(q):
        a0, a1, b0, b1 = q[0], -0.2, 0.8, 0.4
        return np.concatenate([[a0 * b0 - m[0], a1 + b1 * b1 - m[1], a0 - a1 * b1 - m[2]]
                               for m in meas])

    ref = so.least_squares(residual, [0.3], xtol=1e-15, ftol=1e-15, gtol=1e-15)
    for method in ("lm", "gn", "dogleg"):
        r = fgopt.optimize(graph, initial, method=method, constant={A: [1], B: None},
                           max_iterations=50)
        a, b = _storage(r.values.at(A)), _storage(r.values.at(B))
        assert a[1] == -0.2 and np.array_equal(b, [0.8, 0.4])
        assert a[0] == pytest.approx(ref.x[0], rel=1e-6), method


# ----------------------------------------------------------------------------- item 2: bounds
def test_bounds_match_scipy_trf():
    """Bounds with an active upper bound on p0 and lower bound on p2 (the unbounded fit lies
    outside both): the bounded optimum is scipy's ``least_squares(method='trf')`` one, and the
    active coordinates sit exactly on their bounds."""
    so = pytest.importorskip("scipy.optimize")
    graph, initial = decay_problem()
    lo, hi = np.array([0.0, 0.0, 0.6]), np.array([1.8, np.inf, np.inf])
    r = fgopt.optimize(graph, initial, bounds={P: (lo, hi)}, **TIGHT)
    assert r.status == fgopt.Status.CONVERGED
    x = _storage(r.values.at(P))
    ref = so.least_squares(decay_residual, [1.0, 0.5, 0.7], bounds=(lo, hi), method="trf",
                           xtol=1e-15, ftol=1e-15, gtol=1e-15)
    assert x[0] == 1.8 and x[2] == 0.6
    assert r.info["at_bounds"] == [(P, 2, "lower"), (P, 0, "upper")]
    np.testing.assert_allclose(x, ref.x, rtol=1e-7)
    assert r.final_cost == pytest.approx(0.5 * np.sum(ref.fun ** 2), rel=1e-10)
    free = fgopt.optimize(graph, initial, **TIGHT)
    assert free.final_cost < r.final_cost  # the bounds bind


def test_bounds_match_pyceres():
    """The same bounded fit as Ceres with set_parameter_lower_bound / upper_bound: the same
    active set, exactly on the bounds, and a cost no higher than Ceres' (Ceres projects its
    steps onto the box and stops ~5e-6 relative above the bounded optimum, which scipy's trf
    and fgopt reach: test_bounds_match_scipy_trf)."""
    pyceres = pytest.importorskip("pyceres")
    graph, initial = decay_problem()
    lo, hi = np.array([0.0, 0.0, 0.6]), np.array([1.8, 10.0, 10.0])
    r = fgopt.optimize(graph, initial, bounds={P: (lo, hi)}, **TIGHT)

    class Cost(pyceres.CostFunction):
        def __init__(self):
            super().__init__()
            self.set_num_residuals(T.shape[0])
            self.set_parameter_block_sizes([3])

        def Evaluate(self, parameters, residuals, jacobians):
            p = parameters[0]
            e = np.exp(-p[1] * T)
            residuals[:] = p[0] * e + p[2] - Y
            if jacobians is not None and jacobians[0] is not None:
                J = np.stack([e, -p[0] * T * e, np.ones_like(T)], axis=1)
                jacobians[0][:] = J.reshape(-1)
            return True

    x = np.array([1.0, 0.5, 0.7])
    prob = pyceres.Problem()
    prob.add_residual_block(Cost(), None, [x])
    for i in range(3):
        prob.set_parameter_lower_bound(x, i, lo[i])
        prob.set_parameter_upper_bound(x, i, hi[i])
    opts = pyceres.SolverOptions()
    opts.function_tolerance = opts.gradient_tolerance = opts.parameter_tolerance = 1e-15
    opts.max_num_iterations = 200
    summary = pyceres.SolverSummary()
    pyceres.solve(opts, prob, summary)
    ours = _storage(r.values.at(P))
    assert summary.termination_type == pyceres.TerminationType.CONVERGENCE
    assert ours[0] == x[0] == 1.8 and ours[2] == x[2] == 0.6
    np.testing.assert_allclose(ours, x, rtol=1e-3)
    assert r.final_cost <= summary.final_cost
    assert r.final_cost == pytest.approx(summary.final_cost, rel=1e-4)


def test_bounds_on_two_coupled_variables_match_scipy():
    """Bounds on both variables of a coupled two-block problem (lower on one, box on the
    other): scipy trf's bounded optimum."""
    so = pytest.importorskip("scipy.optimize")
    A, B = key("a", 0), key("b", 0)
    rng = np.random.default_rng(3)
    meas = [rng.normal(size=3) + np.array([1.0, 1.0, 0.0]) for _ in range(8)]
    graph, initial = fgopt.FactorGraph(), fgopt.Variables()
    for m in meas:
        graph.add(pair_fit(a=A, b=B, m=m))
    lo_a, hi_a = np.array([0.6, -np.inf]), np.array([np.inf, 0.7])
    lo_b, hi_b = np.array([0.0, 0.0]), np.array([0.9, 0.9])

    def residual(q):
        a0, a1, b0, b1 = q
        return np.concatenate([[a0 * b0 - m[0], a1 + b1 * b1 - m[1], a0 - a1 * b1 - m[2]]
                               for m in meas])

    initial_ok = np.array([0.6, 0.5, 0.5, 0.5])
    initial.add(A, initial_ok[:2])
    initial.add(B, initial_ok[2:])
    r = fgopt.optimize(graph, initial, bounds={A: (lo_a, hi_a), B: (lo_b, hi_b)}, **TIGHT)
    ref = so.least_squares(residual, initial_ok, method="trf",
                           bounds=(np.r_[lo_a, lo_b], np.r_[hi_a, hi_b]),
                           xtol=1e-15, ftol=1e-15, gtol=1e-15)
    x = np.r_[_storage(r.values.at(A)), _storage(r.values.at(B))]
    np.testing.assert_allclose(x, ref.x, atol=1e-7)
    assert r.final_cost == pytest.approx(0.5 * np.sum(ref.fun ** 2), rel=1e-9)


def test_retract_keeps_iterates_in_the_box():
    """Whatever step the solver proposes, the compiled problem's retraction returns a state
    inside the bounds (iterates stay feasible)."""
    graph, initial = decay_problem()
    lo, hi = np.array([0.5, 0.0, 0.6]), np.array([1.8, 2.0, 0.9])
    problem = fgopt.problem.Problem(graph, initial, bounds={P: (lo, hi)})
    state = problem.initial_state()
    rng = np.random.default_rng(0)
    for _ in range(20):
        state = problem.retract(state, 10.0 * rng.standard_normal(problem.size))
        x = state.storages[0][0]
        assert np.all(x >= lo) and np.all(x <= hi)


def test_calibration_bounds_match_scipy():
    """A Cal3_S2 calibration with fx bounded above its true value (poses and points constant):
    fx ends exactly on the bound, the other parameters at scipy trf's bounded optimum of the
    same pinhole residuals."""
    so = pytest.importorskip("scipy.optimize")
    K = key("k", 0)
    truth = np.array([500.0, 490.0, 0.0, 320.0, 240.0])
    rng = np.random.default_rng(2)
    pts = rng.uniform([-2, -2, 4], [2, 2, 8], size=(30, 3))
    cams = [np.array([0.3 * i, 0.0, 0.0]) for i in range(3)]
    graph, initial = fgopt.FactorGraph(), fgopt.Variables()
    obs = []
    for ci, t in enumerate(cams):
        initial.add(key("x", ci), SE3(None, t))
        for j, p in enumerate(pts):
            c = p - t
            uv = np.array([truth[0] * c[0] / c[2] + truth[2] * c[1] / c[2] + truth[3],
                           truth[1] * c[1] / c[2] + truth[4]]) + rng.normal(0, 0.5, 2)
            obs.append((c, uv))
            graph.add(ProjectionFactor(key("x", ci), key("l", j), uv, Isotropic.sigma(2, 1.0),
                                       calibration=K, model=Cal3_S2))
    for j, p in enumerate(pts):
        initial.add(key("l", j), p.copy())
    initial.add(K, Cal3_S2(470.0, 470.0, 0.0, 300.0, 250.0))
    lo = np.array([400.0, 400.0, -1.0, 0.0, 0.0])
    hi = np.array([480.0, 600.0, 1.0, 640.0, 480.0])
    held = [key("x", i) for i in range(3)] + [key("l", j) for j in range(30)]
    r = fgopt.optimize(graph, initial, constant=held, bounds={K: (lo, hi)}, **TIGHT)
    k = _storage(r.values.at(K))
    C = np.array([c for c, _ in obs])
    UV = np.array([uv for _, uv in obs])

    def residual(q):
        u = q[0] * C[:, 0] / C[:, 2] + q[2] * C[:, 1] / C[:, 2] + q[3]
        v = q[1] * C[:, 1] / C[:, 2] + q[4]
        return np.concatenate([u - UV[:, 0], v - UV[:, 1]])

    ref = so.least_squares(residual, [470.0, 470.0, 0.0, 300.0, 250.0], bounds=(lo, hi),
                           method="trf", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    assert k[0] == 480.0
    np.testing.assert_allclose(k, ref.x, rtol=1e-7, atol=1e-7)


# ----------------------------------------------------------------------------- item 4: bad input
def _raises(match, **kw):
    graph, initial = decay_problem()
    before = _storage(initial.at(P)).copy()
    with pytest.raises(FgoptError, match=match):
        fgopt.optimize(graph, initial, **kw)
    assert np.array_equal(_storage(initial.at(P)), before)


@pytest.mark.parametrize("kw, match", [
    (dict(bounds={P: ([1, 0, 0], [0, 1, 1])}), "p0.*lower 1 > upper 0 at coordinate 0"),
    (dict(bounds={P: ([0, 0], [1, 1])}), "lower bound of p0 has shape"),
    (dict(bounds={P: ([0, 0, 0.8], [5, 5, 5])}), "initial value of p0 is outside"),
    (dict(bounds={key("q", 1): (0, 1)}), "q1 is not a variable"),
    (dict(constant=[key("q", 1)]), "q1 is not a variable"),
    (dict(constant={P: [3]}), "coordinate 3 of p0 is out of range"),
    (dict(constant={P: [0.5]}), "p0 must be integer"),
    (dict(bounds={P: ([0, 0, np.nan], [1, 1, 1])}), "NaN"),
    (dict(constant=[P]), "every variable of the problem is constant"),
    (dict(bounds={P: (0, 5)}, method="dogleg"), "bounds need method='lm'"),
])
def test_bad_input_raises_naming_the_key(kw, match):
    """Contradictory or malformed constants / bounds raise FgoptError naming the key; the
    caller's Variables are untouched."""
    _raises(match, **kw)


def test_bounds_on_a_pose_raise():
    """Bounds on a non-vector manifold variable (an SE3 pose) raise FgoptError naming it."""
    graph, initial = fgopt.FactorGraph(), fgopt.Variables()
    X = key("x", 0)
    graph.add(fgopt.PriorFactor(X, SE3(), Isotropic.sigma(6, 1.0)))
    initial.add(X, SE3())
    with pytest.raises(FgoptError, match="bounds on x0: it is a SE3"):
        fgopt.optimize(graph, initial, bounds={X: (-1, 1)})
    with pytest.raises(FgoptError, match="constant coordinates on x0"):
        fgopt.optimize(graph, initial, constant={X: [0]})


def test_marginals_with_constant_variables():
    """Marginals of a result with a constant pose: zero for the constant pose, and for the
    others the covariance of the same chain with that pose pinned by a tight prior
    (both factorization paths: CHOLMOD solves and the block selected inverse)."""
    from fgopt import SE2, BetweenFactor, PriorFactor
    from fgopt.noise import Diagonal

    noise = Diagonal.pose2(x=0.1, y=0.1, theta=0.05)
    graph, initial = fgopt.FactorGraph(), fgopt.Variables()
    for i in range(6):
        graph.add(BetweenFactor(key("x", i), key("x", i + 1), SE2.from_xytheta(1, 0, 0.1),
                                noise))
    for i in range(7):
        initial.add(key("x", i), SE2.from_xytheta(1.05 * i, 0.02 * i, 0.1 * i))
    pinned = fgopt.FactorGraph()
    for f in graph.factors:
        pinned.add(f)
    pinned.add(PriorFactor(key("x", 2), initial.at(key("x", 2)),
                           Diagonal.pose2(x=1e-9, y=1e-9, theta=1e-9)))
    r = fgopt.optimize(graph, initial, constant=[key("x", 2)])
    ref = fgopt.optimize(pinned, initial)
    keys = [key("x", i) for i in range(7)]
    for solver in ("block", "dense"):
        ours = fgopt.marginals(r, keys, linear_solver=solver)
        theirs = fgopt.marginals(ref, keys, linear_solver=solver)
        assert np.array_equal(ours[key("x", 2)], np.zeros((3, 3)))
        for k in keys:
            if k != key("x", 2):
                np.testing.assert_allclose(ours[k], theirs[k], rtol=1e-5, atol=1e-12)


@pytest.mark.parametrize("backend, threads", [("numpy", 1), ("numba", 1), ("numba", 2)])
def test_constant_variables_give_the_free_block_of_h(tmp_path, backend, threads):
    """With 3 of 8 cameras constant, H and g are exactly the full problem's H and g restricted
    to the free variables (constant columns removed), on every assembly path: NumPy twins,
    numba's shape-specialized scatter, the threaded linearization."""
    from fgopt.datasets import bal_synthetic
    from fgopt.problem import Problem

    path = tmp_path / "ba.txt"
    bal_synthetic(8, 300, seed=4).write(path)
    graph, initial = fgopt.io.read_bal(path, progress=False)
    held = [key("c", i) for i in (0, 3, 5)]
    full = Problem(graph, initial, backend=backend, threads=threads)
    part = Problem(graph, initial, backend=backend, threads=threads, constant=held)
    full.linearize(full.initial_state())
    part.linearize(part.initial_state())
    idx = []
    free = [v for v in range(full.num_variables) if Key(int(full.var_keys[v])) not in held]
    for v in sorted(free, key=lambda v: part.var_offset[v]):
        idx.extend(range(full.var_offset[v], full.var_offset[v] + full.var_dim[v]))
    idx = np.array(idx)
    assert part.pattern.size == idx.shape[0] == full.pattern.size - 27
    Hf = full.pattern.full(full.H_data).toarray()[np.ix_(idx, idx)]
    Hp = part.pattern.full(part.H_data).toarray()
    np.testing.assert_allclose(Hp, Hf, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(part.g, full.g[idx], rtol=1e-12, atol=1e-9)


@fgopt.factor
def linear_row(x: V3, a: V3, b: V1) -> V1:
    return V1(a[0] * x[0] + a[1] * x[1] + a[2] * x[2] - b[0])


@pytest.mark.parametrize("seed", range(10))
def test_bounded_linear_least_squares_match_bvls(seed):
    """Random box-constrained linear least squares (badly scaled columns, some sides open):
    the projected LM reaches scipy's exact BVLS optimum (the active set found, not just
    approached)."""
    so = pytest.importorskip("scipy.optimize")
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(12, 3))
    A[:, 2] *= 10 ** rng.uniform(-2, 2)
    b = 3.0 * rng.normal(size=12)
    lo = rng.uniform(-1, 0, 3)
    hi = lo + rng.uniform(0.1, 1.5, 3)
    lo[rng.random(3) < 0.2] = -np.inf
    X = key("x", 0)
    graph, initial = fgopt.FactorGraph(), fgopt.Variables()
    for a, bi in zip(A, b):
        graph.add(linear_row(x=X, a=a, b=np.array([bi])))
    initial.add(X, np.clip((np.where(np.isfinite(lo), lo, hi - 1) + hi) / 2, lo, hi))
    r = fgopt.optimize(graph, initial, bounds={X: (lo, hi)}, **TIGHT)
    ref = so.lsq_linear(A, b, bounds=(lo, hi), method="bvls", tol=1e-14)
    x = _storage(r.values.at(X))
    assert np.all(x >= lo) and np.all(x <= hi)
    c_ref = 0.5 * np.sum((A @ ref.x - b) ** 2)
    assert r.final_cost == pytest.approx(c_ref, rel=1e-9, abs=1e-12)
    np.testing.assert_allclose(x, ref.x, atol=1e-6)


def test_ladybug_bounds_on_camera_intrinsics(ladybug):
    """Ladybug-49, 5 LM iterations with bounds on every camera's focal length (+-0.5 % of its
    initial value) and radial distortion: every camera ends inside its box, some bounds end
    active, the cost decreases; bounds wide enough never to bind give the unbounded run bit for
    bit (the projection and the active set only act at a bound)."""
    graph, initial = ladybug
    cams = [key("c", i) for i in range(49)]
    tight, wide = {}, {}
    for k in cams:
        x = _storage(initial.at(k))
        lo, hi = np.full(9, -np.inf), np.full(9, np.inf)
        lo[6], hi[6] = 0.995 * x[6], 1.005 * x[6]
        lo[7], hi[7] = min(-0.05, x[7]), max(0.05, x[7])
        tight[k] = (lo, hi)
        wide[k] = (np.full(9, -1e9), np.full(9, 1e9))
    r = fgopt.optimize(graph, initial, bounds=tight, max_iterations=5)
    assert r.final_cost < r.initial_cost
    assert r.info["at_bounds"]
    for k in cams:
        x = _storage(r.values.at(k))
        assert np.all(x >= tight[k][0]) and np.all(x <= tight[k][1])
    free = fgopt.optimize(graph, initial, max_iterations=5, initialization="given")
    loose = fgopt.optimize(graph, initial, bounds=wide, max_iterations=5)
    assert loose.final_cost == free.final_cost
