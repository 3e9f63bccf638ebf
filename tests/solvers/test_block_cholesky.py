"""The block supernodal Cholesky agrees with dense / CHOLMOD solves and detects non-PD systems."""

import numpy as np
import pytest

import fgopt
from fgopt.datasets import grid_3d, manhattan_2d
from fgopt.errors import NotPositiveDefiniteError, have_extra
from fgopt.solvers.linear.block_cholesky import BlockCholeskySolver
from fgopt.structure import build_pattern, fill_reducing_order

NO_RELAX = ((1 << 62, 0.0),)
MUCH_RELAX = ((24, 1.0), (96, 0.5), (1 << 62, 0.3))
# Kernel paths forced one at a time: LAPACK/BLAS only, loop panels + tile updates, tiles only;
# then amalgamation variants and updates split into many column chunks.
CONFIGS = [{},
           {"small_panel": 0, "tile_panel": 0, "small_syrk": 0},
           {"small_panel": 10**6, "small_syrk": 10**6},
           {"small_panel": 0, "tile_panel": 10**6, "small_syrk": 10**6},
           {"relax": NO_RELAX}, {"relax": MUCH_RELAX, "small_panel": 3, "small_syrk": 9},
           {"chunk": 7}, {"chunk": 1, "small_syrk": 0}]


def random_block_system(seed, num_vars=60, dims=(1, 2, 3, 6, 9), extra_edges=80,
                        ordering="amd", margin=1e-2):
    """A random SPD H on a random block pattern (chain + random couplings), mixed block sizes."""
    rng = np.random.default_rng(seed)
    var_dim = rng.choice(np.array(dims), size=num_vars).astype(np.int64)
    chain = np.stack([np.arange(num_vars - 1), np.arange(1, num_vars)], axis=1)
    extra = rng.integers(0, num_vars, size=(extra_edges, 2))
    pairs = np.concatenate([chain, extra[extra[:, 0] != extra[:, 1]]])
    order = fill_reducing_order(num_vars, pairs[:, 0], pairs[:, 1], ordering)
    pattern, _ = build_pattern(var_dim, order, pairs[:, 0], pairs[:, 1])
    data = rng.normal(size=pattern.nnz)
    dense = pattern.full(data).toarray()
    shift = -np.linalg.eigvalsh(dense)[0] + margin   # smallest eigenvalue becomes `margin`
    data[pattern.diag_pos] += shift
    return pattern, data, pattern.full(data).toarray()


def rel(a, b):
    return np.linalg.norm(a - b) / np.linalg.norm(b)


@pytest.mark.parametrize("config", CONFIGS)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_blocks_match_dense(seed, config):
    """Random SPD systems under three orderings (METIS needs the CHOLMOD extra; SuperLU's MMD
    stands in without it): solves, multi-RHS solves and refactorization match NumPy's."""
    third = "metis" if have_extra("sksparse") else "mmd"
    pattern, data, dense = random_block_system(seed, ordering=["amd", "natural", third][seed])
    rng = np.random.default_rng(10 + seed)
    b = rng.normal(size=pattern.size)
    s = BlockCholeskySolver(**config)
    s.analyze(pattern)
    s.factorize(data)
    x_ref = np.linalg.solve(dense, b)
    assert rel(s.solve(b), x_ref) < 1e-9
    B = rng.normal(size=(pattern.size, 3))          # several right-hand sides at once
    assert rel(s.solve(B), np.linalg.solve(dense, B)) < 1e-9
    # the factor reproduces H: L L^T == P H P^T on the panels' rows
    s.factorize(2.0 * data)                          # refactorization with new numbers
    assert rel(s.solve(b), 0.5 * x_ref) < 1e-9


def test_edge_cases_single_variable_and_forest():
    for dims, pairs in [((6,), np.zeros((0, 2), np.int64)),
                        ((3, 1, 9, 2), np.array([[0, 1], [2, 3]]))]:   # two components
        var_dim = np.array(dims, np.int64)
        order = np.arange(var_dim.shape[0])
        pattern, _ = build_pattern(var_dim, order, pairs[:, 0], pairs[:, 1])
        rng = np.random.default_rng(0)
        data = rng.normal(size=pattern.nnz)
        data[pattern.diag_pos] += 20.0
        dense = pattern.full(data).toarray()
        b = rng.normal(size=pattern.size)
        for config in CONFIGS:
            s = BlockCholeskySolver(**config)
            s.analyze(pattern)
            s.factorize(data)
            assert rel(s.solve(b), np.linalg.solve(dense, b)) < 1e-9


def _pose_graph_system(synthetic):
    p = fgopt.Problem(synthetic.graph, synthetic.initial, ordering="amd")
    p.linearize(p.initial_state())
    H = p.H_data.copy()
    H[p.pattern.diag_pos] *= 1.0001                  # LM-style damping
    return p.pattern, H, p.g.copy()


@pytest.mark.parametrize("make", [lambda: grid_3d(200), lambda: manhattan_2d(300)],
                         ids=["grid_3d", "manhattan_2d"])
def test_pose_graphs_match_dense_and_cholmod(make):
    pattern, H, g = _pose_graph_system(make())
    x_ref = np.linalg.solve(pattern.full(H).toarray(), g)
    for config in CONFIGS:
        s = BlockCholeskySolver(**config)
        s.analyze(pattern)
        s.factorize(H)
        assert rel(s.solve(g), x_ref) < 1e-9
    try:
        from fgopt.solvers.linear.cholmod import CholmodSolver
        c = CholmodSolver()
    except fgopt.errors.BackendUnavailableError:
        return
    c.analyze(pattern)
    c.factorize(H)
    assert rel(s.solve(g), c.solve(g)) < 1e-9


@pytest.mark.parametrize("config", CONFIGS)
def test_not_positive_definite_raises_and_recovers(config):
    pattern, data, dense = random_block_system(3)
    s = BlockCholeskySolver(**config)
    s.analyze(pattern)
    for where in (0, pattern.size // 2, pattern.size - 1):   # leaf, middle, root of the tree
        bad = data.copy()
        bad[pattern.diag_pos[where]] = -1.0
        with pytest.raises(NotPositiveDefiniteError):
            s.factorize(bad)
        with pytest.raises(NotPositiveDefiniteError):
            s.solve(np.ones(pattern.size))           # no stale factor after a failure
    indefinite = data.copy()
    indefinite[pattern.diag_pos] -= 1.0               # shifts the spectrum below zero
    with pytest.raises(NotPositiveDefiniteError):
        s.factorize(indefinite)
    s.factorize(data)                                 # a good matrix factors again
    b = np.arange(pattern.size, dtype=float)
    assert rel(s.solve(b), np.linalg.solve(dense, b)) < 1e-9


@pytest.mark.parametrize("config", CONFIGS[:4])
def test_nan_pivot_is_not_positive_definite(config):
    pattern, data, _ = random_block_system(4)
    s = BlockCholeskySolver(**config)
    s.analyze(pattern)
    for where in (0, pattern.size // 2, pattern.size - 1):
        bad = data.copy()
        bad[pattern.diag_pos[where]] = np.nan
        with pytest.raises(NotPositiveDefiniteError):
            s.factorize(bad)


def test_misuse_raises_fgopt_errors():
    pattern, data, _ = random_block_system(5, num_vars=10)
    s = BlockCholeskySolver()
    with pytest.raises(fgopt.errors.FgoptError):
        s.factorize(data)                            # before analyze
    s.analyze(pattern)
    with pytest.raises(fgopt.errors.DimensionMismatchError):
        s.factorize(data[:-1])
    with pytest.raises(NotPositiveDefiniteError):
        s.solve(np.ones(pattern.size))               # before a successful factorize
    s.factorize(data)
    with pytest.raises(fgopt.errors.DimensionMismatchError):
        s.solve(np.ones(pattern.size + 1))


def test_auto_picks_dense_only_for_small_and_mostly_full_systems(monkeypatch):
    """``"auto"`` on a small system: the dense Cholesky when H is at least a quarter full (a
    tiny scene where every camera sees every point), the block Cholesky when it is sparse (a
    100-pose graph: 300 unknowns, ~3 % full, where dense factors 2x slower) once the process
    runs compiled kernels; before (a fresh script within its NumPy budget) LAPACK's dense
    Cholesky, which needs no compilation. All solve to the same optimum."""
    import fgopt._jit
    from fgopt.datasets import sfm_cube
    from fgopt.solvers.linear.base import choose_linear_solver
    from fgopt.structure import DENSE_MAX_SIZE, DENSE_MIN_FILL

    d = manhattan_2d(100, seed=1)
    monkeypatch.setattr(fgopt._jit, "NUMPY_BUDGET_SECONDS", 0.0)
    r = fgopt.optimize(d.graph, d.initial)
    p = r.problem.pattern
    assert p.size <= DENSE_MAX_SIZE and 2 * p.nnz - p.size < DENSE_MIN_FILL * p.size ** 2
    assert choose_linear_solver(p) == "block" and r.linear_solver == "block"
    dense = fgopt.optimize(d.graph, d.initial, linear_solver="dense")
    assert dense.final_cost == pytest.approx(r.final_cost, rel=1e-9)
    monkeypatch.setattr(fgopt._jit, "NUMPY_BUDGET_SECONDS", float("inf"))
    assert choose_linear_solver(p) == "dense"
    assert choose_linear_solver(p, backend="numpy") == "dense"
    s = sfm_cube(smart=True, seed=3)
    assert fgopt.optimize(s.graph, s.initial).linear_solver == "dense"


_LAPACK_ROUTE = """
import importlib.util, sys
import numpy as np
if sys.argv[1] == "cython":  # as if scipy were not a wheel (conda, a distro): no scipy.libs
    real = importlib.util.find_spec
    importlib.util.find_spec = lambda name, *a: None if name == "scipy" else real(name, *a)
from fgopt.solvers.linear import _block_kernels as K
sys.path.insert(0, sys.argv[2])
from test_block_cholesky import random_block_system
from fgopt.solvers.linear.block_cholesky import BlockCholeskySolver
pattern, data, dense = random_block_system(3, num_vars=40)
s = BlockCholeskySolver(small_panel=0, tile_panel=0, small_syrk=0)  # LAPACK/BLAS calls only
s.analyze(pattern)
s.factorize(data)
b = np.arange(pattern.size, dtype=float)
print(K._OPENBLAS is not None, "scipy.linalg" in sys.modules,
      float(np.linalg.norm(s.solve(b) - np.linalg.solve(dense, b))))
"""


@pytest.mark.parametrize("route", ["openblas", "cython"])
def test_lapack_routines_bound_without_scipy_linalg_or_through_it(route, tmp_path):
    """In a scipy wheel the block Cholesky binds dpotrf / dtrsm / dsyrk / dgemm from scipy's
    bundled OpenBLAS by path, so a new process that factors with them never imports
    scipy.linalg (0.2-0.4 s); where that library is not found it binds scipy's cython_lapack
    wrappers instead. Both routes solve a system whose panels go through LAPACK/BLAS only
    (checked in a second process: the first may compile, and compiling imports scipy.linalg)."""
    import subprocess
    import sys
    from pathlib import Path

    import scipy

    wheel = (Path(scipy.__file__).parents[1] / "scipy.libs").is_dir()
    if route == "openblas" and not wheel:
        pytest.skip("scipy is not a wheel here (no scipy.libs): only the cython route applies")
    for _ in range(2):  # the second process loads the kernels (a compile imports numba's
        # lowering registries, scipy.linalg among them)
        out = subprocess.run([sys.executable, "-c", _LAPACK_ROUTE, route,
                              str(Path(__file__).parent)], capture_output=True, text=True,
                             check=True, cwd=tmp_path).stdout.split()
    assert out[:2] == (["True", "False"] if route == "openblas" else ["False", "True"])
    assert float(out[2]) < 1e-9
