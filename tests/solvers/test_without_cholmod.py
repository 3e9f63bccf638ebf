"""Without the ``fgopt[cholmod]`` extra (scikit-sparse hidden): the default solvers, orderings,
chordal initialization, marginals and leverages work and agree with the CHOLMOD paths; asking
for CHOLMOD names the pip command that adds it."""

import sys

import numpy as np
import pytest
import scipy.sparse as sp

import fgopt
from fgopt.datasets import manhattan_2d
from fgopt.errors import BackendUnavailableError, have_extra
from fgopt.structure import fill_reducing_order, minimum_degree_order


@pytest.fixture
def no_cholmod(monkeypatch):
    """Hide scikit-sparse: ``import sksparse`` fails and ``have_extra`` says so."""
    for name in ("sksparse", "sksparse.cholmod"):
        monkeypatch.setitem(sys.modules, name, None)
    assert not have_extra("sksparse")


def _grid_pairs(n):
    idx = np.arange(n * n).reshape(n, n)
    pi = np.concatenate([idx[:, :-1].ravel(), idx[:-1, :].ravel()])
    pj = np.concatenate([idx[:, 1:].ravel(), idx[1:, :].ravel()])
    return pi, pj


def _fill(V, pi, pj, order):
    """nnz of the Cholesky factor of the block graph eliminated in ``order`` (dense LU of the
    permuted, diagonally dominant pattern; exact structural fill for this small graph)."""
    A = np.eye(V) * (V + 1.0)
    A[pi, pj] = A[pj, pi] = 1.0
    P = A[np.ix_(order, order)]
    return int(np.count_nonzero(np.abs(np.linalg.cholesky(P)) > 0))


def test_minimum_degree_order_is_a_permutation_that_cuts_fill(no_cholmod):
    """The SuperLU MMD order of a 2D grid graph is a permutation with far less fill than the
    natural (row by row) order, and ``"amd"`` falls back to it without CHOLMOD on the NumPy
    backend (on numba it is fgopt's own kernel, ``tests/core/test_amd.py``)."""
    from fgopt import _jit

    n = 20
    pi, pj = _grid_pairs(n)
    V = n * n
    with _jit.numpy_mode():
        order = fill_reducing_order(V, pi, pj, "amd")
    assert sorted(order.tolist()) == list(range(V))
    assert _fill(V, pi, pj, order) < 0.75 * _fill(V, pi, pj, np.arange(V))
    A = sp.csc_matrix(np.eye(V) * (V + 1.0) + sp.coo_matrix((np.ones(pi.size), (pi, pj)),
                                                            shape=(V, V)).toarray())
    assert np.array_equal(minimum_degree_order(A + A.T), order)


def test_missing_extra_names_the_pip_command(no_cholmod):
    """``linear_solver='cholmod'`` and CHOLMOD-only orderings raise BackendUnavailableError (an
    FgoptError) naming ``pip install 'fgopt[cholmod]'``."""
    d = manhattan_2d(50, seed=1)
    with pytest.raises(BackendUnavailableError, match=r"pip install 'fgopt\[cholmod\]'"):
        fgopt.optimize(d.graph, d.initial, linear_solver="cholmod")
    pi, pj = _grid_pairs(6)
    with pytest.raises(fgopt.FgoptError, match=r"pip install 'fgopt\[cholmod\]'"):
        fill_reducing_order(36, pi, pj, "metis")


def test_solve_chordal_marginals_agree_with_cholmod(monkeypatch):
    """On a 300-pose Manhattan graph, LM (default solver, MMD order), chordal initialization and
    marginals without CHOLMOD match the results with CHOLMOD."""
    pytest.importorskip("sksparse")
    d = manhattan_2d(300, seed=4)
    ref = fgopt.optimize(d.graph, d.initial)
    ref_init = fgopt.chordal_initialization(d.graph, d.initial)
    k = list(d.initial.keys())[150]
    ref_cov = fgopt.marginals(ref, [k])[k]
    for name in ("sksparse", "sksparse.cholmod"):
        monkeypatch.setitem(sys.modules, name, None)
    r = fgopt.optimize(d.graph, d.initial)
    assert abs(r.final_cost - ref.final_cost) <= 1e-9 * ref.final_cost
    init = fgopt.chordal_initialization(d.graph, d.initial)
    for key in list(d.initial.keys())[::37]:
        assert np.allclose(init.at(key).translation(), ref_init.at(key).translation(), atol=1e-8)
    cov = fgopt.marginals(r, [k])[k]
    assert np.allclose(cov, ref_cov, rtol=1e-6, atol=1e-12)


def test_leverages_agree_with_cholmod(monkeypatch):
    """Leave-one-out residuals from fgopt's own solver (dense right-hand sides) equal the
    CHOLMOD sparse-forward-solve ones, on every factor that is not a bridge (removing a bridge
    leaves its residual undetermined: both paths return an arbitrary least-squares value)."""
    pytest.importorskip("sksparse")
    from fgopt.problem import Problem
    from fgopt.solvers.influence import leave_one_out_sq_norms

    d = manhattan_2d(120, seed=5)
    k0 = list(d.initial.keys())[0]
    d.graph.add(fgopt.PriorFactor(k0, d.initial.at(k0), fgopt.noise.Isotropic.sigma(3, 0.01)))
    p = Problem(d.graph, d.initial)
    s = p.initial_state()
    masks = [np.ones(len(b.source), bool) for b in p.batches]
    ref = leave_one_out_sq_norms(p, s, masks)
    for name in ("sksparse", "sksparse.cholmod"):
        monkeypatch.setitem(sys.modules, name, None)
    out = leave_one_out_sq_norms(p, s, masks)
    for a, b, batch in zip(out, ref, p.batches):
        keep = ~_bridges(batch.source.keys)
        assert keep.sum() > 0.8 * keep.size
        assert np.allclose(a[keep], b[keep], rtol=1e-6, atol=1e-9)


def _bridges(keys):
    """Which rows of an ``(n, 2)`` edge list are bridges (their removal disconnects the graph)."""
    from scipy.sparse.csgraph import connected_components

    if keys.shape[1] != 2:
        return np.zeros(keys.shape[0], bool)
    _, idx = np.unique(keys, return_inverse=True)
    e = idx.reshape(keys.shape)
    V = int(e.max()) + 1
    out = np.zeros(len(e), bool)
    for i in range(len(e)):
        rest = np.delete(e, i, axis=0)
        A = sp.coo_matrix((np.ones(len(rest)), (rest[:, 0], rest[:, 1])), shape=(V, V))
        out[i] = connected_components(A, directed=False)[0] > 1
    return out
