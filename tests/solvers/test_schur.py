"""The Schur-complement solver equals the full sparse Cholesky solve (CHOLMOD's, or fgopt's block
Cholesky without the ``fgopt[cholmod]`` extra), and LM with it reaches the same cost.

Problems: a synthetic BAL-style bundle adjustment (Snavely cameras in R^9, points in R^3: the
fixed-size ``de = 3, df = 9`` kernel), a synthetic SE(3) pose / landmark graph with odometry
between poses (generic kernel, ``df = 6``, camera-camera blocks in H), ``dubrovnik-3-7`` and
Ladybug-49 from the shared data folder (skipped when absent).
"""

import numpy as np
import pytest

import fgopt
from fgopt.errors import FgoptError, NotPositiveDefiniteError, have_extra
from fgopt.factors.library.bal_kernel import bal_kernel
from fgopt.key import key
from fgopt.problem import Problem
from fgopt.solvers.linear.block_cholesky import BlockCholeskySolver
from fgopt.solvers.linear.cholmod import CholmodSolver
from fgopt.solvers.linear.schur import SchurSolver, choose_linear_solver

MODES = ["dense", "sparse"]


def full_cholesky():
    """The reference: a sparse Cholesky of the whole H (no Schur complement)."""
    return CholmodSolver() if have_extra("sksparse") else BlockCholeskySolver()


def bal_graph(cams, pts, obs):
    """Graph + values from BAL arrays, with the hand-written kernel (stable while the symbolic
    ``bal_reprojection`` evolves)."""
    cb, pb = int(key("c", 0)), int(key("p", 0))
    values = fgopt.Variables()
    for i, row in enumerate(cams):
        values.add(cb + i, np.array(row, dtype=float))
    for j, row in enumerate(pts):
        values.add(pb + j, np.array(row, dtype=float))
    graph = fgopt.FactorGraph()
    keys = np.column_stack([cb + obs[:, 0].astype(np.int64), pb + obs[:, 1].astype(np.int64)])
    graph.add_batch(bal_kernel(), keys, np.ascontiguousarray(obs[:, 2:4]))
    return graph, values


def read_bal_file(path):
    with open(path) as fh:
        v = np.array(fh.read().split(), dtype=float)
    nc, npt, nobs = (int(x) for x in v[:3])
    obs = v[3:3 + 4 * nobs].reshape(nobs, 4)
    start = 3 + 4 * nobs
    cams = v[start:start + 9 * nc].reshape(nc, 9)
    pts = v[start + 9 * nc:].reshape(npt, 3)
    return bal_graph(cams, pts, obs)


def synthetic_ba(nc=6, npt=40, seed=0):
    rng = np.random.default_rng(seed)
    cams = np.zeros((nc, 9))
    cams[:, 0:3] = rng.normal(0, 0.05, (nc, 3))
    cams[:, 3:6] = rng.normal(0, 0.3, (nc, 3))
    cams[:, 6] = 500 + rng.normal(0, 10, nc)
    cams[:, 7:9] = rng.normal(0, 1e-3, (nc, 2))
    pts = np.column_stack([rng.uniform(-2, 2, npt), rng.uniform(-2, 2, npt),
                           rng.uniform(-8, -4, npt)])  # BAL cameras look down -z
    obs = []
    for j in range(npt):
        seen = rng.choice(nc, size=rng.integers(2, nc + 1), replace=False)
        for i in seen:
            obs.append((i, j))
    obs = np.array(obs, dtype=float)
    graph, _ = bal_graph(cams, pts, np.column_stack([obs, np.zeros((len(obs), 2))]))
    res = graph.batches[0].kernel.residual(
        (cams[obs[:, 0].astype(int)], pts[obs[:, 1].astype(int)]), np.zeros((len(obs), 2)))
    meas = res + rng.normal(0, 0.5, res.shape)
    noisy_c = cams + np.concatenate([rng.normal(0, 1e-3, (nc, 6)), np.zeros((nc, 3))], axis=1)
    noisy_p = pts + rng.normal(0, 0.05, pts.shape)
    return bal_graph(noisy_c, noisy_p, np.column_stack([obs, meas]))


def pose_landmark_graph(n_poses=8, n_lm=30, seed=1):
    rng = np.random.default_rng(seed)
    values = fgopt.Variables()
    graph = fgopt.FactorGraph()
    poses = []
    for i in range(n_poses):
        T = fgopt.SE3.exp(np.concatenate([rng.normal(0, 0.1, 3), [i * 0.5, 0.0, 0.0]]))
        poses.append(T)
        values.add(key("x", i), fgopt.SE3.exp(rng.normal(0, 0.02, 6)) * T)
    for j in range(n_lm):
        values.add(key("l", j), rng.normal(0, 2, 3) + np.array([2.0, 0.0, 4.0]))
    graph.add(fgopt.PriorFactor(key("x", 0), poses[0]))
    for i in range(n_poses - 1):
        graph.add(fgopt.BetweenFactor(key("x", i), key("x", i + 1),
                                      poses[i].inverse() * poses[i + 1]))
    from fgopt.factors.library.pose_point import pose_point_kernel

    ks, ms = [], []
    for j in range(n_lm):
        for i in rng.choice(n_poses, size=rng.integers(1, 4), replace=False):
            ks.append((int(key("x", int(i))), int(key("l", j))))
            ms.append(rng.normal(0, 1, 3))
    graph.add_batch(pose_point_kernel(3), np.array(ks, dtype=np.int64), np.array(ms))
    return graph, values


def damped_system(graph, values, ordering="amd", lam=1e-4, linear_solver=None):
    P = Problem(graph, values, ordering=ordering, linear_solver=linear_solver)
    P.linearize(P.initial_state())
    H = P.H_data.copy()
    d = P.pattern.diag_pos
    H[d] += lam * np.clip(H[d], 1e-6, 1e32)
    return P, H, -P.g.copy()


def reference_solve(P, H, rhs):
    ref = full_cholesky()
    ref.analyze(P.pattern)
    ref.factorize(H)
    return ref.solve(rhs)


def check_equal(P, H, rhs, solver, rtol=1e-9):
    x_ref = reference_solve(P, H, rhs)
    solver.analyze(P.pattern)
    solver.factorize(H)
    x = solver.solve(rhs)
    err = np.linalg.norm(x - x_ref) / np.linalg.norm(x_ref)
    assert err < rtol, (solver.name, err)
    return solver


@pytest.mark.parametrize("ordering", ["amd", "natural"])
@pytest.mark.parametrize("mode", MODES)
def test_synthetic_ba_equals_cholmod(mode, ordering):
    graph, values = synthetic_ba()
    P, H, rhs = damped_system(graph, values, ordering)
    s = check_equal(P, H, rhs, SchurSolver(reduced=mode))
    assert s._fast and s.mode == mode


def test_both_block_orientations_are_covered():
    """Camera-point blocks sit in the point's columns (point before camera) or in the camera's
    (cameras first: natural order of the sorted keys); layouts with blocks of the second kind
    are gathered into a copy (AMD mixes both here)."""
    graph, values = synthetic_ba()
    seen = set()
    for ordering in ("amd", "natural"):
        P, H, rhs = damped_system(graph, values, ordering)
        s = check_equal(P, H, rhs, SchurSolver())
        assert s._gather is not None
        seen |= set(np.unique(s._gather[1]).tolist())
    assert seen == {0, 1}


@pytest.mark.parametrize("name", ["schur", "auto"])
def test_schur_layout_reads_blocks_in_place(name):
    """A problem compiled for a Schur solver (``linear_solver="schur"``, or ``"auto"`` on a
    BA-shaped problem) puts every point before every camera without a fill-reducing order: the
    solver reads the camera-point blocks from H itself (no copy) and solves as CHOLMOD does."""
    graph, values = synthetic_ba(nc=12, npt=80)  # 348 unknowns: "auto" picks Schur
    P, H, rhs = damped_system(graph, values, linear_solver=name)
    kinds = np.asarray(P.pattern.var_kind)
    is_pt = kinds == P.pattern.kind_names.index("R3")
    off = P.pattern.var_offset
    assert off[is_pt].max() < off[~is_pt].min()
    assert set(P.pattern.independent_kinds) == {0, 1}  # no camera-camera factor either
    s = check_equal(P, H, rhs, SchurSolver())
    assert s._gather is None and s._X is not None


@pytest.mark.parametrize("mode", MODES)
def test_generic_kernel_equals_fast_kernel(mode):
    graph, values = synthetic_ba(seed=3)
    P, H, rhs = damped_system(graph, values, "natural")
    s = SchurSolver(reduced=mode)
    s.analyze(P.pattern)
    s.factorize(H)
    x_fast = s.solve(rhs)
    s._fast = False
    s.factorize(H)
    assert np.allclose(s.solve(rhs), x_fast, rtol=1e-10, atol=1e-12 * np.abs(x_fast).max())


PCG_TIGHT = {"pcg_rtol": 1e-14, "pcg_max_iterations": 10_000}


@pytest.mark.parametrize("mode", [*MODES, "pcg-explicit", "pcg-implicit"])
def test_pose_landmark_graph(mode):
    graph, values = pose_landmark_graph()
    P, H, rhs = damped_system(graph, values)
    if mode.startswith("pcg"):
        s = SchurSolver(reduced="pcg", eliminate="R3", pcg_explicit=mode == "pcg-explicit",
                        **PCG_TIGHT)
    else:
        s = SchurSolver(reduced=mode, eliminate="R3")
    check_equal(P, H, rhs, s, rtol=1e-9 if mode in MODES else 1e-7)
    assert not s._fast and len(s._a_src) > 0


@pytest.mark.parametrize("explicit", [True, False])
def test_pcg_converges_to_direct_solution(explicit):
    graph, values = synthetic_ba(seed=5)
    P, H, rhs = damped_system(graph, values, lam=1e-2)
    s = SchurSolver(reduced="pcg", pcg_explicit=explicit, **PCG_TIGHT)
    check_equal(P, H, rhs, s, rtol=1e-8)
    assert s.last_pcg_iterations > 0 and s._explicit == explicit


@pytest.mark.parametrize("mode", MODES)
def test_dubrovnik_3_7_equals_cholmod(mode, data_file):
    graph, values = read_bal_file(data_file("bal/dubrovnik-3-7-pre.txt"))
    P, H, rhs = damped_system(graph, values)
    check_equal(P, H, rhs, SchurSolver(reduced=mode))


def test_eliminate_options_and_errors():
    graph, values = synthetic_ba(nc=4, npt=12)
    P, H, rhs = damped_system(graph, values)
    kinds = P.pattern.kind_names
    pts = np.asarray(P.pattern.var_kind) == kinds.index("R3")
    for opt in ("R3", pts, np.nonzero(pts)[0]):
        check_equal(P, H, rhs, SchurSolver(eliminate=opt))
    with pytest.raises(FgoptError, match="not independent"):
        SchurSolver(eliminate=np.ones_like(pts)).analyze(P.pattern)
    with pytest.raises(FgoptError, match="not a variable kind"):
        SchurSolver(eliminate="SE3").analyze(P.pattern)
    with pytest.raises(FgoptError, match="unknown reduced"):
        SchurSolver(reduced="qr")
    s = SchurSolver()
    s.analyze(P.pattern)
    with pytest.raises(NotPositiveDefiniteError):
        s.factorize(np.zeros_like(H))
    Hbad = H.copy()
    Hbad[P.pattern.diag_pos[np.asarray(P.pattern.var_offset)[~pts]]] *= -1.0
    with pytest.raises(NotPositiveDefiniteError):
        s.factorize(Hbad)


def test_choose_linear_solver():
    graph, values = synthetic_ba(nc=5, npt=60)
    P = Problem(graph, values)
    assert isinstance(choose_linear_solver(P.pattern), SchurSolver)
    pg = fgopt.FactorGraph()
    v = fgopt.Variables()
    for i in range(5):
        v.add(key("x", i), fgopt.SE2.exp(np.array([float(i), 0.0, 0.0])))
    pg.add(fgopt.PriorFactor(key("x", 0), fgopt.SE2.exp(np.zeros(3))))
    for i in range(4):
        step = fgopt.SE2.exp(np.array([1.0, 0.0, 0.0]))
        pg.add(fgopt.BetweenFactor(key("x", i), key("x", i + 1), step))
    assert choose_linear_solver(Problem(pg, v).pattern) is None


def test_lm_with_schur_matches_cholmod_synthetic():
    graph, values = synthetic_ba(nc=8, npt=80, seed=7)
    costs = []
    for solver in (full_cholesky(), SchurSolver(reduced="dense"), SchurSolver(reduced="sparse")):
        r = fgopt.optimize(graph, values, method="lm", linear_solver=solver, max_iterations=30)
        costs.append(r.final_cost)
    assert costs[0] < 0.01 * r.initial_cost
    assert np.allclose(costs, costs[0], rtol=1e-8), costs


def test_lm_ladybug_schur_matches_cholmod(data_file):
    graph, values = read_bal_file(data_file("bal/problem-49-7776-pre.txt"))
    kw = {"method": "lm", "max_iterations": 5, "initial_lambda": 1e-4}
    r_chol = fgopt.optimize(graph, values, linear_solver=full_cholesky(), **kw)
    r_schur = fgopt.optimize(graph, values, linear_solver=SchurSolver(), **kw)
    assert r_schur.final_cost < 13500.0
    assert np.isclose(r_schur.final_cost, r_chol.final_cost, rtol=1e-7), (
        r_schur.final_cost, r_chol.final_cost)


def test_auto_mode_rule():
    graph, values = synthetic_ba(nc=6, npt=40)  # every camera pair shares a point: S is full
    P, H, rhs = damped_system(graph, values)
    for kw, mode in (({}, "dense"), ({"dense_max": 20}, "dense"), ({"dense_max": 5}, "sparse"),
                     ({"dense_max": 5, "pcg_min": 50}, "pcg")):
        s = SchurSolver(**kw, pcg_rtol=1e-14, pcg_max_iterations=10_000)
        check_equal(P, H, rhs, s, rtol=1e-8)
        assert s.mode == mode and s.name == "schur", (kw, s.mode)


def _with_loss(graph, code, k=0.0, alpha=0.0):
    b = graph.batches[0]
    out = fgopt.FactorGraph()
    out.add_batch(b.kernel, b.keys, b.constants, b.sqrt_information, code, k, loss_shape=alpha)
    return out


@pytest.mark.parametrize("loss", [("huber", 1, 1.0, 0.0), ("cauchy", 2, 1.0, 0.0),
                                  ("barron-0.5", 5, 1.0, 0.5), ("barron-0", 5, 1.0, 0.0),
                                  ("barron--2", 5, 2.0, -2.0)])
def test_robust_ba_rejects_gross_outliers_with_schur(loss):
    """Robust losses in BA: with 8 % of the observations moved by up to 60 px, the robust solution
    (Schur solver, weights applied inside the kernels) fits the inliers about as well as their
    own least squares solution (within 5 % for redescending losses), the plain L2 solution is
    several times worse, and Schur and CHOLMOD agree on
    the robust problem."""
    _, code, k, alpha = loss
    clean, values = synthetic_ba(nc=8, npt=80, seed=3)
    b = clean.batches[0]
    rng = np.random.default_rng(5)
    bad_rows = rng.choice(len(b), size=int(0.08 * len(b)), replace=False)
    meas = b.constants.copy()
    meas[bad_rows] += rng.uniform(-60, 60, (len(bad_rows), 2))
    corrupted = fgopt.FactorGraph()
    corrupted.add_batch(b.kernel, b.keys, meas)
    kw = {"method": "lm", "max_iterations": 60}
    plain = fgopt.optimize(corrupted, values, **kw).values
    robust_graph = _with_loss(corrupted, code, k, alpha)
    robust = fgopt.optimize(robust_graph, values, linear_solver=SchurSolver(), **kw)
    five = {"method": "lm", "max_iterations": 5}  # same iterates when the linear solves agree
    r_schur = fgopt.optimize(robust_graph, values, linear_solver=SchurSolver(), **five)
    r_chol = fgopt.optimize(robust_graph, values, linear_solver=full_cholesky(), **five)
    assert np.isclose(r_schur.final_cost, r_chol.final_cost, rtol=1e-9)

    # gauge-free yardstick: the inlier observations' cost at each solution
    inlier = np.ones(len(b), dtype=bool)
    inlier[bad_rows] = False
    inliers_only = fgopt.FactorGraph()
    inliers_only.add_batch(b.kernel, b.keys[inlier], meas[inlier])
    best = fgopt.optimize(inliers_only, values, **kw).final_cost
    at_robust, at_plain = inliers_only.error(robust.values), inliers_only.error(plain)
    # redescending losses ignore the outliers; Huber-like ones still feel them (Huber: linearly)
    bound = {1: 40.0, 5: 3.0}.get(code, 1.05) if alpha > 0.0 or code == 1 else 1.05
    assert at_robust < bound * best and at_robust < 0.25 * at_plain, (best, at_robust, at_plain)
