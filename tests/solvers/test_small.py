"""The small-problem driver (fgopt.solvers.small) against the general LM path.

Every test solves with ``backend="numba"`` (the driver's condition) and compares with the same
solve forced onto the general path (``SMALL_MAX_SIZE = -1``): same iterations, statuses,
messages and costs, values equal to rounding.
"""

import pickle

import numpy as np
import pytest

import fgopt
from fgopt import SE2, SE3, SO3, BetweenFactor, FactorGraph, PriorFactor, Variables, key
from fgopt.errors import NonFiniteError
from fgopt.solvers import LevenbergMarquardt, LMParams, small
from fgopt.solvers.small import _driver

DRIVER = "dense cholesky (small-problem driver)"


@pytest.fixture(autouse=True)
def compile_drivers(monkeypatch):
    """Drivers compile in the test process (by default a cold one goes to a background process)."""
    monkeypatch.setattr(small, "COMPILE_IN_FOREGROUND", True)


def solve(graph, init, general=False, monkeypatch=None, **options):
    params = LMParams(backend="numba", **options)
    if general:
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(small, "SMALL_MAX_SIZE", -1)
            r = LevenbergMarquardt(params).optimize(graph, init)
        assert r.linear_solver != DRIVER
        return r
    return LevenbergMarquardt(params).optimize(graph, init)


def storage(values):
    out = {}
    for k in values.keys():
        x = values.at(k)
        out[int(k)] = np.asarray(x.to_storage() if hasattr(x, "to_storage") else x, dtype=float)
    return out


def assert_same(a, b, rtol=1e-9, atol=1e-8):
    """``a`` (driver) and ``b`` (general path) took the same iterations to the same point."""
    assert a.linear_solver == DRIVER
    assert (a.status, a.message, a.iterations) == (b.status, b.message, b.iterations)
    assert [r.accepted for r in a.iteration_records] == [r.accepted for r in b.iteration_records]
    np.testing.assert_allclose(a.cost_history, b.cost_history, rtol=rtol,
                               atol=1e-12 * b.initial_cost)
    np.testing.assert_allclose([r.lam for r in a.iteration_records],
                               [r.lam for r in b.iteration_records], rtol=1e-12)
    sa, sb = storage(a.values), storage(b.values)
    assert sa.keys() == sb.keys()
    for k in sa:
        np.testing.assert_allclose(sa[k], sb[k], atol=atol)


def mixed_graph(seed=0, n=4):
    """SE3 poses with priors and odometry (full / diagonal / unit noise), an SO3 chain and an R3
    chain: several kernels, storage layouts and noise forms in one problem."""
    rng = np.random.default_rng(seed)
    graph, init = FactorGraph(), Variables()
    full = np.linalg.cholesky(np.cov(rng.normal(size=(6, 40))))
    for i in range(n):
        init.add(key("x", i), SE3.exp(rng.normal(size=6) * 0.3))
        init.add(key("r", i), SO3.exp(rng.normal(size=3)))
        init.add(key("v", i), rng.normal(size=3))
    graph.add(PriorFactor(key("x", 0), SE3(), fgopt.noise.Isotropic.sigma(6, 0.01)))
    graph.add(PriorFactor(key("r", 0), SO3()))
    graph.add(PriorFactor(key("v", 0), np.zeros(3), fgopt.noise.Diagonal.sigmas([1, 2, 3.0])))
    for i in range(n - 1):
        step = SE3.exp(np.array([0.1, 0.0, 0.05, 1.0, 0.2, 0.0]) + 0.05 * rng.normal(size=6))
        noise = (fgopt.noise.Gaussian.from_covariance(full @ full.T) if i % 2 else
                 fgopt.noise.Diagonal.sigmas([0.1, 0.1, 0.1, 0.3, 0.3, 0.3]))
        graph.add(BetweenFactor(key("x", i), key("x", i + 1), step, noise))
        graph.add(BetweenFactor(key("r", i), key("r", i + 1), SO3.exp(rng.normal(size=3) * 0.2)))
        graph.add(BetweenFactor(key("v", i), key("v", i + 1), rng.normal(size=3)))
    return graph, init


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_same_iterations_as_the_general_path(seed):
    graph, init = mixed_graph(seed)
    before = storage(init)
    a = solve(graph, init)
    b = solve(graph, init, general=True)
    assert_same(a, b)
    assert a.final_cost < a.initial_cost
    after = storage(init)
    assert all(np.array_equal(before[k], after[k]) for k in before)  # caller's values untouched


@pytest.mark.parametrize("name", ["small/pose2example.txt", "small/noisyToyGraph.txt",
                                  "small/Klaus3.g2o", "small/pose3example.txt",
                                  "small/pose3Localizationexample.txt", "small/toyExample.g2o",
                                  "small/tinyGrid3D.g2o"])
def test_shared_tiny_files_match_the_general_path(data_file, name):
    """GTSAM's tiny example files (read as batches, one block of storage rows): 5 LM iterations
    with every stopping test off, then to convergence with the defaults."""
    graph, init = fgopt.io.read(str(data_file(name)), add_prior=True)
    off = dict(max_iterations=5, relative_tolerance=0.0, absolute_tolerance=0.0,
               gradient_tolerance=0.0, step_tolerance=0.0)
    assert_same_point(solve(graph, init, **off), solve(graph, init, general=True, **off))
    assert_same(solve(graph, init), solve(graph, init, general=True))


def assert_same_point(a, b, atol=1e-8):
    """``a`` (driver) and ``b`` (general path) ran the same number of iterations to the same
    cost and point. Once a tiny file has converged, a step's accept/reject is decided by
    round-off, and the driver's kernels and the general path's generated ones round differently
    (the same formulas, not the same instruction order): that tail is not compared."""
    assert a.linear_solver == DRIVER
    assert (a.status, a.iterations) == (b.status, b.iterations)
    np.testing.assert_allclose(a.final_cost, b.final_cost, rtol=1e-9, atol=1e-12 * b.initial_cost)
    sa, sb = storage(a.values), storage(b.values)
    assert sa.keys() == sb.keys()
    for k in sa:
        np.testing.assert_allclose(sa[k], sb[k], atol=atol)


def test_one_kernel_in_a_batch_and_in_single_factors(data_file):
    """A reader's batch and factors of the same kernel added one by one share a driver slot."""
    graph, init = fgopt.io.read(str(data_file("small/pose2example.txt")), add_prior=True)
    keys = sorted(int(k) for k in init.keys())
    graph.add(BetweenFactor(keys[0], keys[5], SE2.from_xytheta(4.0, 0.1, 0.2),
                            fgopt.noise.Diagonal.sigmas([0.3, 0.3, 0.1])))
    assert_same(solve(graph, init), solve(graph, init, general=True))


def test_one_driver_per_kernel_set_whatever_the_structure():
    """Graphs of other sizes, and the same factors added in another order, reuse the driver."""
    graph, init = mixed_graph(0, n=4)
    solve(graph, init)
    made = dict(small.STATS)
    for n in (2, 3, 5):
        g2, i2 = mixed_graph(1, n=n)
        solve(g2, i2)
        reordered = FactorGraph(list(reversed(g2.factors)))
        assert_same(solve(reordered, i2), solve(reordered, i2, general=True))
    assert small.STATS["generated"] == made["generated"]
    assert small.STATS["loaded"] == made["loaded"]
    assert small.STATS["solves"] == made["solves"] + 6


def test_what_the_driver_does_not_take_goes_the_general_way():
    graph, init = mixed_graph(0, n=3)
    robust = FactorGraph(list(graph.factors))
    robust.add(PriorFactor(key("v", 1), np.ones(3), fgopt.noise.Huber(1.0, fgopt.noise.Unit(3))))
    seen = []
    cases = {
        "robust loss": (robust, init, LMParams(backend="numba")),
        "verbose": (graph, init, LMParams(backend="numba", verbose=True)),
        "chosen linear solver": (graph, init, LMParams(backend="numba", linear_solver="ldlt")),
        "numpy backend": (graph, init, LMParams(backend="numpy")),
    }
    for why, (g, i, p) in cases.items():
        r = LevenbergMarquardt(p).optimize(g, i)
        assert r.linear_solver != DRIVER, why
    r = LevenbergMarquardt(LMParams(backend="numba")).optimize(graph, init, callback=seen.append)
    assert r.linear_solver != DRIVER and len(seen) == r.iterations
    big_graph, big_init = mixed_graph(0, n=small.SMALL_MAX_SIZE // 12 + 1)
    assert solve(big_graph, big_init).linear_solver != DRIVER


def driver_module():
    graph, init = mixed_graph(0, n=2)
    problem = fgopt.Problem(graph, init, backend="numba", build_structure=False)
    plan = small._plan(problem.batches)
    assert plan.ready()
    return plan.module


def envelope_matrix(rng, n):
    """A random SPD matrix with a random envelope (row i's first nonzero column) and it."""
    first = np.array([max(0, i - int(rng.integers(0, n))) if rng.random() < 0.7 else i
                      for i in range(n)])
    A = np.zeros((n, n))
    for i in range(n):
        A[i, first[i]:i] = rng.normal(size=i - first[i])
    A = A + A.T
    A += np.diag(np.abs(A).sum(axis=1) + 0.5)  # diagonally dominant: positive definite
    return A, first


@pytest.mark.parametrize("seed", range(6))
def test_envelope_cholesky_solves_like_numpy(seed):
    """The driver's Cholesky reads only each row's envelope and solves A y = b as NumPy does,
    for random envelopes, a dense one (every row from column 0) and a diagonal one."""
    m = driver_module()
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 70))
    A, first = envelope_matrix(rng, n)
    b = rng.normal(size=n)
    for env in (first, np.zeros(n, dtype=np.int64)):
        L, y = np.full((n, n), np.nan), np.empty(n)  # NaN: an entry read outside the envelope
        np.fill_diagonal(L, 0.0)
        assert m._cholesky_solve(A, b, L, y, env.astype(np.int64))
        np.testing.assert_allclose(y, np.linalg.solve(A, b), rtol=1e-10, atol=1e-12)
    D = np.diag(rng.uniform(1, 2, size=n))
    y = np.empty(n)
    assert m._cholesky_solve(D, b, np.zeros((n, n)), y, np.arange(n, dtype=np.int64))
    np.testing.assert_allclose(y, b / np.diag(D))
    A[n // 2, n // 2] = -1.0  # not positive definite
    assert not m._cholesky_solve(A, b, np.zeros((n, n)), y, first.astype(np.int64))


def test_envelope_work_counts_each_rows_reach():
    """A chain's rows reach one variable back; a factor from the last variable to the first
    widens the last one's rows to the whole H (dense: sum of w^2 / 2 over widths 1..N)."""
    graph, init = FactorGraph(), Variables()
    for i in range(4):
        init.add(key("v", i), np.zeros(3))
    graph.add(PriorFactor(key("v", 0), np.zeros(3)))
    for i in range(3):
        graph.add(BetweenFactor(key("v", i), key("v", i + 1), np.ones(3)))
    problem = fgopt.Problem(graph, init, backend="numba", build_structure=False)
    chain = 0.5 * (1 + 4 + 9 + 3 * (16 + 25 + 36))
    assert small.envelope_work(problem) == chain
    graph.add(BetweenFactor(key("v", 3), key("v", 0), np.ones(3)))
    problem = fgopt.Problem(graph, init, backend="numba", build_structure=False)
    assert small.envelope_work(problem) == chain - 0.5 * (16 + 25 + 36) + 0.5 * (100 + 121 + 144)


def test_larger_problem_with_a_narrow_envelope_takes_the_driver():
    """Past SMALL_DENSE_SIZE a chain (narrow envelope) still takes the driver, with the general
    path's iterations; a loop closure from the last pose to the first widens the envelope past
    SMALL_MAX_WORK, and the problem goes the general way."""
    graph, init = mixed_graph(1, n=10)  # 120 unknowns
    assert fgopt.Problem(graph, init, backend="numba", build_structure=False).size > \
        small.SMALL_DENSE_SIZE
    assert_same(solve(graph, init), solve(graph, init, general=True))
    graph, init = mixed_graph(1, n=20)  # 240 unknowns
    assert solve(graph, init).linear_solver == DRIVER
    graph.add(BetweenFactor(key("x", 19), key("x", 0), SE3()))
    problem = fgopt.Problem(graph, init, backend="numba", build_structure=False)
    assert small.envelope_work(problem) + 3 * problem.size ** 2 > small.SMALL_MAX_WORK
    assert solve(graph, init).linear_solver != DRIVER


def test_pose3example_grid_takes_the_driver(data_file):
    """GTSAM's 27-pose grid (162 unknowns): the driver, with the general path's iterations."""
    graph, init = fgopt.io.read(str(data_file("small/pose3example-grid.txt")), add_prior=True)
    off = dict(max_iterations=5, relative_tolerance=0.0, absolute_tolerance=0.0,
               gradient_tolerance=0.0, step_tolerance=0.0)
    assert_same(solve(graph, init, **off), solve(graph, init, general=True, **off))
    assert_same(solve(graph, init), solve(graph, init, general=True))


def test_nonfinite_start_raises_the_general_paths_error():
    """The driver reports a non-finite start; the general path then raises its error."""
    graph, init = mixed_graph(0, n=3)
    bad = Variables()
    for k in init.keys():
        bad.add(k, init.at(k))
    bad.update(key("v", 2), np.array([1e200, 0.0, 0.0]))  # its residual squared overflows
    with pytest.raises(NonFiniteError) as general:
        solve(graph, bad, general=True)
    with pytest.raises(NonFiniteError) as driver:
        solve(graph, bad)
    assert str(driver.value) == str(general.value)
    assert solve(graph, init).linear_solver == DRIVER


def test_result_supports_marginals_and_pickling():
    graph, init = mixed_graph(0, n=3)
    a = solve(graph, init)
    b = solve(graph, init, general=True)
    ma = fgopt.marginals(a, keys=[key("x", 2), key("v", 1)])
    mb = fgopt.marginals(b, keys=[key("x", 2), key("v", 1)])
    for k in ma:
        np.testing.assert_allclose(ma[k], mb[k], rtol=1e-6, atol=1e-12)
    back = pickle.loads(pickle.dumps(a))
    sa, sb = storage(back.values), storage(a.values)
    assert all(np.array_equal(sa[k], sb[k]) for k in sa)


def test_a_cold_driver_is_compiled_after_the_general_path_has_cost_as_much(monkeypatch,
                                                                           capsys):
    """Rent-or-buy, in this process: a kernel set whose driver is not compiled takes the general
    path until those solves have cost ``COMPILE_AFTER_SECONDS``; then the driver is compiled here
    (one line on stderr says so) and used; a new process finds it through its marker."""
    monkeypatch.setattr(small, "COMPILE_IN_FOREGROUND", False)
    monkeypatch.setattr(small, "COMPILE_AFTER_SECONDS", 1e-9)
    monkeypatch.setattr(small, "_PLANS", {})
    graph, init = mixed_graph(3, n=2)
    problem = fgopt.Problem(graph, init, backend="numba", build_structure=False)
    small._plan(problem.batches).marker().unlink(missing_ok=True)
    assert solve(graph, init).linear_solver != DRIVER  # nothing spent yet: the general path
    assert small._plan(problem.batches).general_seconds > 0.0
    assert solve(graph, init).linear_solver == DRIVER  # compiles, then marks it compiled
    assert "compiling the small-problem LM driver" in capsys.readouterr().err
    monkeypatch.setattr(small, "COMPILE_AFTER_SECONDS", float("inf"))
    monkeypatch.setattr(small, "_PLANS", {})  # a new process: the marker says it is compiled
    assert solve(graph, init).linear_solver == DRIVER
    assert "compiling" not in capsys.readouterr().err


def test_driver_source_names_its_kernels():
    graph, init = mixed_graph(0, n=3)
    problem = fgopt.Problem(graph, init, backend="numba", build_structure=False)
    plan = small._plan(problem.batches)
    assert plan.ready()
    names = plan.module.KERNELS
    assert sorted(names) == sorted({b.kernel.name for b in problem.batches})
    sigs = tuple(_driver.signature(b.kernel) for b in problem.batches)
    assert _driver.module_key(sigs) != _driver.module_key(tuple(reversed(sigs)))


def smart_scene(seed=0, degenerate="reject"):
    """SFMExample's cube seen by 8 cameras as smart factors: four 8-view tracks and four 3-view
    tracks (two kernels whose driver call adds the Schur complement itself), noisy pixels, the
    SFM priors on x0 and x1."""
    from fgopt.cameras import SmartProjectionFactor
    from fgopt.datasets import sfm_cube

    sfm = sfm_cube(smart=True)
    rng = np.random.default_rng(seed)
    z = sfm.measurements + rng.normal(scale=0.5, size=sfm.measurements.shape)
    graph = FactorGraph()
    for f in sfm.graph.factors:
        if not isinstance(f, SmartProjectionFactor):
            graph.add(f)
    pixel = fgopt.noise.Isotropic.sigma(2, 1.0)
    for j in range(z.shape[1]):
        views = list(range(8)) if j < 4 else [j - 4, j - 3, j - 2]
        graph.add(SmartProjectionFactor([key("x", i) for i in views], z[views, j],
                                        sfm.calibration, pixel, degenerate=degenerate))
    return graph, sfm.initial


@pytest.mark.parametrize("seed", [0, 1])
def test_smart_factors_match_the_general_path(seed):
    """Smart factors' Schur complements added by the driver (a dense B B^T) equal the general
    path's scattered blocks: same iterations, lambdas and costs."""
    graph, init = smart_scene(seed)
    a, b = solve(graph, init), solve(graph, init, general=True)
    assert_same(a, b, atol=1e-7)
    assert a.final_cost < 0.01 * a.initial_cost


def test_smart_factor_degenerate_track_policies():
    """Tracks degenerate at the start (x0 and x1 turned to look away: the landmarks are behind
    them) follow their policy in the driver as on the general path: 'zero' adds nothing there
    (same iterations), 'reject' makes the solve raise the general path's error naming a factor.
    The policy is the factors' data: both scenes run one driver (compiled once)."""
    turn = SE3(SO3.exp([0.0, np.pi, 0.0]), np.zeros(3))
    keys = set()
    for degenerate in ("zero", "reject"):
        graph, init = smart_scene(0, degenerate=degenerate)
        keys.add(small._plan(fgopt.Problem(graph, init, backend="numba",
                                           build_structure=False).batches).key)
        start = Variables()
        for k in init.keys():
            start.add(k, init.at(k) * turn if k in (key("x", 0), key("x", 1)) else init.at(k))
        track = graph.factors[-4]  # views x0, x1, x2
        assert [int(k) for k in track.keys] == [key("x", i) for i in range(3)]
        assert track.point(start) is None  # behind x0 and x1: not triangulable
        if degenerate == "zero":
            a = solve(graph, start)
            assert_same(a, solve(graph, start, general=True), atol=1e-7)
        else:
            with pytest.raises(NonFiniteError, match=r"smart_cal3_s2_\dviews\(x"):
                solve(graph, start)
    assert len(keys) == 1


def sim3_chain(n=4, seed=0):
    """Sim(3) poses with a prior and noisy relative constraints (the driver retracts Sim(3)
    through ``lie_retract``, not an inlined group)."""
    rng = np.random.default_rng(seed)
    graph, init = FactorGraph(), Variables()
    graph.add(PriorFactor(key("s", 0), fgopt.Sim3()))
    for i in range(n):
        init.add(key("s", i), fgopt.Sim3.exp(rng.normal(size=7) * 0.2))
    for i in range(n - 1):
        graph.add(BetweenFactor(key("s", i), key("s", i + 1),
                                fgopt.Sim3.exp(rng.normal(size=7) * 0.1)))
    return graph, init


def test_driver_runs_release_every_array(tmp_path):
    """The driver's core and most of what it calls count no references (``_nrt=False``): a
    reference taken there and never released would leak what it refers to. Numba's allocation
    counters balance after solves of each kind of driver: kernels that fill their outputs (a
    file's graph), kernels returning them (counted ``_lin``), smart factors (their own
    ``J^T J``), Sim(3) (retracted by ``lie_retract``)."""
    import gc

    from numba.core.runtime import _nrt_python, rtsys

    g2o = tmp_path / "square.g2o"
    g2o.write_text("".join(f"VERTEX_SE2 {i} {x} {y} {t}\n" for i, (x, y, t) in enumerate(
        [(0, 0, 0), (1.1, 0.1, 1.5), (0.9, 1.2, 3.0), (-0.1, 0.9, -1.6)])) + "".join(
        f"EDGE_SE2 {i} {(i + 1) % 4} 1 0 1.5708 1 0 0 1 0 1\n" for i in range(4)))
    scenes = {"file": fgopt.io.read(str(g2o), add_prior=True), "returned outputs": mixed_graph(),
              "smart": smart_scene(), "sim3": sim3_chain()}
    was = _nrt_python.memsys_stats_enabled()
    _nrt_python.memsys_enable_stats()
    try:
        for name, (graph, init) in scenes.items():
            assert solve(graph, init).linear_solver == DRIVER, name  # (compiled here)
            gc.collect()
            before = rtsys.get_allocation_stats()
            for _ in range(3):
                r = solve(graph, init)
                r.values
                del r
            gc.collect()
            after = rtsys.get_allocation_stats()
            if name in ("returned outputs", "smart"):  # (kernels that allocate: counted)
                assert after.alloc - before.alloc > 0, name
            assert after.alloc - before.alloc == after.free - before.free, name
            assert after.mi_alloc - before.mi_alloc == after.mi_free - before.mi_free, name
    finally:
        if not was:
            _nrt_python.memsys_disable_stats()
