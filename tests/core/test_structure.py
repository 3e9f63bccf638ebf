"""The Hessian pattern and scatter map: assembling blocks through them equals dense J^T J."""

import numpy as np
import pytest

from fgopt import _assembly as asm
from fgopt.errors import have_extra
from fgopt.structure import build_pattern, fill_reducing_order, scatter_positions


@pytest.mark.parametrize("m", [4, asm.WIDE_RESIDUAL + 3])
@pytest.mark.parametrize("ordering", ["natural", "amd", "mmd"] + [
    pytest.param(o, marks=pytest.mark.skipif(not have_extra("sksparse"),
                                             reason=f"ordering {o!r} needs the CHOLMOD extra"))
    for o in ("metis", "colamd")])
def test_scatter_equals_dense_normal_equations(ordering, m):
    """Random factors over mixed-size variables: scattered lower H equals the dense J^T J, for
    residuals below and above ``WIDE_RESIDUAL`` (fused and row-outer-product paths)."""
    rng = np.random.default_rng(0)
    var_dim = np.array([3, 6, 2, 6, 1, 3, 3, 6], dtype=np.int64)
    V = var_dim.shape[0]
    pairs = np.array([(0, 1), (1, 2), (2, 3), (3, 4), (4, 5), (5, 6), (6, 7), (7, 0), (1, 5)])
    order = fill_reducing_order(V, pairs[:, 0], pairs[:, 1], ordering)
    assert sorted(order) == list(range(V))
    pattern, lookup = build_pattern(var_dim, order, pairs[:, 0], pairs[:, 1])
    rank = np.empty(V, dtype=np.int64)
    rank[order] = np.arange(V)
    N = int(var_dim.sum())
    H_dense = np.zeros((N, N))
    g_dense = np.zeros(N)
    H_data = np.zeros(pattern.nnz)
    g = np.zeros(N)
    off = pattern.var_offset
    for i, j in pairs:  # one 2-variable factor per pair, residual dim m, both orders of args
        for var_idx in (np.array([[i, j]]), np.array([[j, i]])):
            dims = var_dim[var_idx[0]]
            D = int(dims.sum())
            res = rng.normal(size=(1, m))
            jac = rng.normal(size=(1, m, D))
            pos = scatter_positions(lookup, rank, var_idx)
            toff = off[var_idx]
            cost = asm.scatter_batch(res, jac, np.eye(m)[None], True, 0, 0.0, 0.0, dims,
                                     np.array([0, dims[0]]), toff, pos, pattern.col_shift,
                                     H_data, g, np.ones(1), 0.0)
            assert np.isclose(cost, 0.5 * res[0] @ res[0])
            cols = np.concatenate([np.arange(off[v], off[v] + var_dim[v]) for v in var_idx[0]])
            H_dense[np.ix_(cols, cols)] += jac[0].T @ jac[0]
            g_dense[cols] += jac[0].T @ res[0]
    assert np.allclose(pattern.full(H_data).toarray(), H_dense)
    assert np.allclose(g, g_dense)
    x = rng.normal(size=N)
    assert np.allclose(pattern.matvec(H_data, x), H_dense @ x)
    # the pattern is exactly the lower triangle of the block structure (no missing entries)
    L = pattern.matrix(H_data).toarray()
    assert np.allclose(np.tril(H_dense), L)


@pytest.mark.parametrize("m", [2, asm.WIDE_RESIDUAL + 2])
def test_whitening_and_robust_weights(m):
    """Whitened + Huber-weighted scatter equals w (RJ)^T (RJ) with w from the Huber loss (both
    scatter paths)."""
    rng = np.random.default_rng(1)
    var_dim = np.array([2], dtype=np.int64)
    pattern, lookup = build_pattern(var_dim, np.array([0]), np.zeros(0, int), np.zeros(0, int))
    R = np.triu(rng.normal(size=(m, m))) + 3 * np.eye(m)
    e = np.linspace(2.0, -1.0, m)[None]
    J = rng.normal(size=(1, m, 2))
    H_data, g, w = np.zeros(pattern.nnz), np.zeros(2), np.ones(1)
    pos = scatter_positions(lookup, np.array([0]), np.array([[0]]))
    k = 0.5
    cost = asm.scatter_batch(e, J, R[None], False, 1, k, 0.0, var_dim, np.array([0]),
                             np.array([[0]]), pos, pattern.col_shift, H_data, g, w, 0.0)
    r = R @ e[0]
    t = np.linalg.norm(r)
    assert t > k
    assert np.isclose(cost, k * t - 0.5 * k * k)
    assert np.isclose(w[0], k / t)
    RJ = R @ J[0]
    assert np.allclose(pattern.full(H_data).toarray(), w[0] * RJ.T @ RJ)
    assert np.allclose(g, w[0] * RJ.T @ r)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_pattern_kernel_equals_vectorized_pattern(seed):
    """The one-call numba pattern (used once numba is in use) gives the same offsets, block
    codes, column layout, block positions and column pointers as the vectorized NumPy steps,
    for random graphs with repeated pairs, self pairs, isolated variables and a random order."""
    from fgopt.structure import _pattern_kernel, _pattern_np

    rng = np.random.default_rng(seed)
    V = int(rng.integers(1, 80))
    var_dim = rng.integers(1, 7, V).astype(np.int64)
    m = int(rng.integers(0, 4 * V))
    pi = rng.integers(0, V, m).astype(np.int64)
    pj = rng.integers(0, V, m).astype(np.int64)
    pj[: m // 5] = pi[: m // 5]               # self pairs (ignored)
    pi = np.concatenate([pi, pi[: m // 3]])   # repeated pairs
    pj = np.concatenate([pj, pj[: m // 3]])
    order = rng.permutation(V).astype(np.int64)
    N = int(var_dim.sum())
    got = _pattern_kernel(var_dim, order, pi, pj, N)
    want = _pattern_np(var_dim, order, pi, pj, N)
    for name, g, w in zip(("var_offset", "codes", "indptr", "p00", "col_ptr"), got, want):
        assert np.array_equal(g, w), name


@pytest.mark.parametrize("seed", range(4))
def test_block_graph_kernel_equals_coo_conversion(seed):
    """The numba variable graph (the fill-reducing ordering's input once numba is in use) has
    the COO -> CSC conversion's pattern and values: sorted rows, repeated and self pairs summed,
    isolated variables with only their diagonal."""
    from fgopt.structure import _block_graph, _block_graph_np

    rng = np.random.default_rng(seed)
    V = int(rng.integers(1, 80))
    m = int(rng.integers(0, 4 * V))
    pi = rng.integers(0, V, m).astype(np.int64)
    pj = rng.integers(0, V, m).astype(np.int64)
    pj[: m // 5] = pi[: m // 5]
    pi, pj = np.concatenate([pi, pi[: m // 3]]), np.concatenate([pj, pj[: m // 3]])
    for name, g, w in zip(("data", "indices", "indptr"), _block_graph(V, pi, pj),
                          _block_graph_np(V, pi, pj)):
        assert np.array_equal(g, w), name


@pytest.mark.parametrize("seed", range(6))
def test_densely_banded_counts_distinct_coupled_pairs(seed):
    """The banded-order test keeps the given order exactly when every pair is within BANDED
    positions and at least half of the band's cells are coupled, counting each unordered pair
    once (repeats, reversed pairs and self pairs do not count twice)."""
    from fgopt.structure import BANDED, _densely_banded

    rng = np.random.default_rng(seed)
    V = int(rng.integers(2, 60))
    width = int(rng.integers(1, BANDED + 3))
    m = int(rng.integers(1, 3 * V * min(width, BANDED)))
    a = rng.integers(0, V, m)
    b = np.clip(a + rng.integers(-width, width + 1, m), 0, V - 1)
    a = np.concatenate([a, b[: m // 4]])      # reversed repeats
    b = np.concatenate([b, a[: m // 4]])
    distinct = {(min(x, y), max(x, y)) for x, y in zip(a.tolist(), b.tolist()) if x != y}
    w = int(np.max(np.abs(a - b)))
    want = 0 < w <= BANDED and len(distinct) >= 0.5 * V * w
    assert _densely_banded(V, a, b) == want


def test_independent_kinds_from_factor_arguments_equal_pair_scan():
    """The compiled problem reads its independent kinds (no factor joins two variables of the
    kind) from the factors' argument kinds; that equals the scan over every coupled pair, on a
    BA graph (points independent), a pose-landmark graph, a pose chain (nothing independent
    but the landmarks) and a graph with Python-path factors."""
    import fgopt
    from fgopt.factors import BetweenFactor
    from fgopt.structure import independent_kinds
    from tests.solvers.test_python_path import trilateration
    from tests.solvers.test_schur import pose_landmark_graph, synthetic_ba

    cases = [synthetic_ba(seed=1), pose_landmark_graph(), trilateration()]
    graph, values = fgopt.FactorGraph(), fgopt.Variables()
    for i in range(5):
        values.add(fgopt.key("x", i), fgopt.SE2(0.1 * i, (0.0, 0.0)))
        values.add(fgopt.key("l", i), np.array([i, 1.0]))
        if i:
            graph.add(BetweenFactor(fgopt.key("x", i - 1), fgopt.key("x", i),
                                    fgopt.SE2(0.1, (0.0, 0.0))))
    cases.append((graph, values))
    for case in cases:
        problem = fgopt.Problem(case[0], case[1])
        pi, pj = problem._coupled_pairs()
        assert problem._independent_kinds() == independent_kinds(problem.var_kind, pi, pj)
