"""The fixed formulation reads a graph's batches as arrays (fgopt/solvers/fixed/_collect.py):
same structure key, module and result as the same factors added one by one; results keep the
caller's other values; bad batches are named."""

from __future__ import annotations

import numpy as np
import pytest

import fgopt
from fgopt import SE2, BetweenFactor, FactorGraph, PriorFactor, Variables
from fgopt.errors import FgoptError
from fgopt.factors.library.prior_between import between_kernel_for, prior_kernel_for
from fgopt.solvers import fixed as fx


def _pose_rows(n: int, seed: int = 0) -> np.ndarray:
    """(n, 4) SE2 storage rows (cos, sin, x, y) of a noisy walk."""
    rng = np.random.default_rng(seed)
    th = np.cumsum(rng.normal(0.3, 0.1, n))
    xy = np.cumsum(np.stack([np.cos(th), np.sin(th)], axis=1), axis=0) + rng.normal(0, 0.2, (n, 2))
    return np.column_stack([np.cos(th), np.sin(th), xy])


def _kind():
    x = SE2.from_xytheta(0.0, 0.0, 0.0)
    from fgopt.manifolds.base import ops_for

    return ops_for(x).batch_kind(x)


def pose_graph_two_ways(n: int = 6):
    """The same pose graph (odometry, two loop closures, a prior) as batches over bulk values and
    as factor objects over per-key values."""
    kind = _kind()
    rows = _pose_rows(n)
    edges = [(i, i + 1) for i in range(n - 1)] + [(0, n - 1), (1, n - 2)]
    truth = [SE2.from_xytheta(2.0 * np.cos(0.5 * i), 2.0 * np.sin(0.5 * i), 0.5 * i)
             for i in range(n)]
    meas = [truth[i].inverse() * truth[j] for i, j in edges]
    R = np.diag([10.0, 10.0, 20.0])
    batched, bulk = FactorGraph(), Variables()
    bulk.add_rows(np.arange(n), kind, rows)
    batched.add_batch(between_kernel_for(kind), np.array(edges),
                      np.array([kind.to_storage(m) for m in meas]),
                      np.repeat(R[None], len(edges), 0),
                      origin=[f"edge {e}" for e in range(len(edges))])
    batched.add_batch(prior_kernel_for(kind), np.array([[0]]), rows[:1], R[None] * 100.0)
    single, per_key = FactorGraph(), Variables()
    for i in range(n):
        per_key.add(i, kind.from_storage(rows[i]))
    noise = fgopt.noise.Gaussian(R)
    for (i, j), m in zip(edges, meas):
        single.add(BetweenFactor(i, j, m, noise))
    single.add(PriorFactor(0, kind.from_storage(rows[0]), fgopt.noise.Gaussian(R * 100.0)))
    return batched, bulk, single, per_key


def test_batches_and_factor_objects_share_the_module_and_the_result():
    """Rows of graph.add_batch over Variables.add_rows values are read as arrays, yet give the
    structure key, generated module, iterates and values of the same factors added one by one
    (and of the dynamic formulation)."""
    batched, bulk, single, per_key = pose_graph_two_ways()
    fb = fx.compile_fixed(batched, bulk)
    fs = fx.compile_fixed(single, per_key)
    assert fb.structure_key == fs.structure_key and fb.module is fs.module
    np.testing.assert_allclose(fb._x0, fs._x0, rtol=1e-15, atol=1e-15)  # from_storage normalizes
    np.testing.assert_array_equal(fb._consts, fs._consts)
    np.testing.assert_array_equal(fb._wvals, fs._wvals)
    rb, rs = fb.optimize(), fs.optimize()
    assert rb.iterations == rs.iterations
    assert abs(rb.final_cost - rs.final_cost) <= 1e-12 * rs.final_cost
    rd = fgopt.optimize(batched, bulk)
    assert abs(rb.final_cost - rd.final_cost) <= 1e-9 * max(1.0, rd.final_cost)
    assert list(rb.values.keys()) == list(bulk.keys())
    for k in bulk.keys():
        a, b, d = (r.values.at(k).to_storage() for r in (rb, rs, rd))
        np.testing.assert_allclose(a, b, atol=1e-12)
        np.testing.assert_allclose(a, d, atol=1e-9)
    assert rb.values.at(2).__class__ is SE2


def test_factor_specs_match_what_one_factor_at_a_time_reads():
    """The per-factor specs the derivation consumes, rebuilt from the runs, list each factor's
    variables, constant and whitening offsets in graph order."""
    batched, bulk, _, _ = pose_graph_two_ways(5)
    col = fx.formulation._collect(batched, bulk)
    specs = col.factors
    assert [s.var_idx for s in specs] == [(0, 1), (1, 2), (2, 3), (3, 4), (0, 4), (1, 3), (0,)]
    assert [s.const_off for s in specs] == [4 * i for i in range(7)]
    assert [s.w_off for s in specs] == [3 * i for i in range(7)]  # diagonal R: 3 entries
    assert all(sum(s.wmask) == 3 for s in specs)
    assert [v.storage_off for v in col.variables] == [4 * i for i in range(5)]
    assert [v.tangent_off for v in col.variables] == [3 * i for i in range(5)]
    sources = col.sources
    assert len(sources) == 7 and [list(f.keys) for f in sources[:2]] == [[0, 1], [1, 2]]


def test_values_keep_unused_keys_and_the_initial_order():
    """Keys no factor uses (a bulk block's rows and per-key values) come back unchanged, every
    key in the initial values' order."""
    batched, _, _, _ = pose_graph_two_ways(4)
    kind = _kind()
    extra_rows = _pose_rows(2, seed=5)
    values = Variables()
    values.add(100, np.array([1.0, 2.0]))
    values.add_rows(np.arange(4), kind, _pose_rows(4))  # what pose_graph_two_ways(4) uses
    values.add_rows(np.array([200, 201]), kind, extra_rows)
    with pytest.warns(fgopt.errors.FgoptWarning, match="used by no factor"):
        r = fgopt.optimize(batched, values, formulation="fixed")
    assert list(r.values.keys()) == list(values.keys())
    np.testing.assert_array_equal(r.values.at(100), [1.0, 2.0])
    np.testing.assert_array_equal(r.values.at(201).to_storage(), extra_rows[1])
    assert not np.array_equal(r.values.at(3).to_storage(), values.at(3).to_storage())


def test_bad_batches_are_named():
    """A batch row whose key has no value, a batch with a robust loss and a row whose variable
    has another kind raise FgoptError naming the row."""
    batched, bulk, _, _ = pose_graph_two_ways(4)
    kind = _kind()
    missing = FactorGraph()
    missing.add_batch(between_kernel_for(kind), np.array([[0, 1], [1, 9]]),
                      np.tile(kind.to_storage(SE2.from_xytheta(1, 0, 0)), (2, 1)),
                      origin=["odometry a", "odometry b"])
    with pytest.raises(FgoptError, match=r"\(1, 9\) \(factor odometry b\) uses 9, which is not"):
        fx.compile_fixed(missing, bulk)
    robust = FactorGraph()
    robust.add_batch(between_kernel_for(kind), np.array([[0, 1]]),
                     kind.to_storage(SE2.from_xytheta(1, 0, 0))[None], loss_code=1, loss_param=1.0)
    with pytest.raises(FgoptError, match="robust loss"):
        fx.compile_fixed(robust, bulk)
    mixed = Variables()
    mixed.add(0, SE2.from_xytheta(0, 0, 0))
    mixed.add(1, np.array([1.0, 2.0]))
    wrong_kind = FactorGraph().add_batch(between_kernel_for(kind), np.array([[0, 1]]),
                                         kind.to_storage(SE2.from_xytheta(1, 0, 0))[None],
                                         origin=["row z"])
    with pytest.raises(FgoptError, match=r"\(factor row z\): 1 is a R2, the factor expects SE2"):
        fx.compile_fixed(wrong_kind, mixed)


def test_bad_factor_objects_are_named():
    """Individually added factors read a run at a time: a missing key and a variable of another
    kind still raise FgoptError naming that factor (not the run's first)."""
    _, _, single, per_key = pose_graph_two_ways(4)
    graph = FactorGraph(list(single.factors))
    graph.add(BetweenFactor(2, 7, SE2.from_xytheta(1, 0, 0), fgopt.noise.Isotropic.sigma(3, 1.0)))
    with pytest.raises(FgoptError,
                       match=r"BetweenFactor\(2, 7\) uses 7, which is not in the initial"):
        fx.compile_fixed(graph, per_key)
    values = per_key.copy()
    values.add(9, np.array([1.0, 2.0]))
    graph = FactorGraph(list(single.factors))
    graph.add(BetweenFactor(3, 9, SE2.from_xytheta(1, 0, 0), fgopt.noise.Isotropic.sigma(3, 1.0)))
    with pytest.raises(FgoptError,
                       match=r"BetweenFactor\(3, 9\): 9 is a R2, the factor expects SE2"):
        fx.compile_fixed(graph, values)
