"""What the per-update shortcuts of the smoother rely on: a full ``estimate()`` also brings the
wildfire ``delta`` up to date (one back-substitution call, none left for ``estimate(key)``), a
factor linearized alone (row slices) writes the local system a gathered batch writes, and the
noise model cache per loss object never mixes two noise models."""

import numpy as np

from fgopt import BetweenFactor, FactorGraph, IncrementalParams, IncrementalSmoother
from fgopt.incremental import _solve
from fgopt.manifolds import SE2, SE3
from fgopt.noise import Diagonal

from ._streams import max_tangent_difference, pose_stream, x


def test_full_estimate_leaves_no_back_substitution_pending(monkeypatch):
    """After ``estimate()``, ``estimate(key)`` calls no back-substitution of its own, and
    returns bit for bit what a twin that never read the whole estimate returns (its own pending
    solve); the twins' relinearization choices stay the same."""
    steps = pose_stream(SE2, 50, 11)
    params = IncrementalParams(relinearize_skip=2, relinearize_threshold=0.01)
    a, b = IncrementalSmoother(params), IncrementalSmoother(params)
    for isam in (a, b):  # compiled before the Python-level name is wrapped below
        isam.update(*steps[0])
        isam.estimate()
        isam.estimate(x(0))
    calls = []
    pending = _solve.solve_pending
    monkeypatch.setattr(_solve, "solve_pending", lambda *args: (calls.append(1),
                                                                pending(*args))[1])
    for i, (factors, values) in enumerate(steps[1:], 1):
        ra, rb = a.update(factors, values), b.update(factors, values)
        assert ra.variables_relinearized == rb.variables_relinearized
        a.estimate()
        n = len(calls)
        for j in (0, i // 2, i):
            assert np.array_equal(a.estimate(x(j)).to_storage(), b.estimate(x(j)).to_storage())
        assert len(calls) == n + 1  # the twin's solve only


def test_one_factor_alone_writes_the_same_local_system_as_a_batch():
    """``linearize`` of one factor (row slices) and of the same factor among others (gathered
    rows) write identical local systems ``[H; g]``."""
    isam = IncrementalSmoother()
    for factors, values in pose_stream(SE3, 12, 5):
        isam.update(factors, values)
    facs, tree = isam._facs, isam._tree
    slots = np.array(sorted(facs.slot_of_handle.values())[3:7], np.int64)
    D = tree.fac_D[slots]
    facs.linearize(slots, slots.shape[0])
    together = [tree.hpool[o:o + d * d + d].copy() for o, d in zip(tree.fac_hoff[slots], D)]
    for s, d, block in zip(slots, D, together):
        facs.linearize(np.array([s], np.int64), 1)
        o = int(tree.fac_hoff[s])
        assert np.array_equal(tree.hpool[o:o + d * d + d], block)


def test_noise_models_are_not_mixed_by_the_loss_cache():
    """Factors whose noise objects are made and dropped one per update (so an object id can
    come back) keep their own noise: with loop closures that disagree with the odometry, where
    the optimum depends on every weight, the exact smoother ends at the batch optimum."""
    import fgopt

    rng = np.random.default_rng(2)
    exact = IncrementalParams(relinearize_threshold=0.0, relinearize_skip=1,
                              wildfire_threshold=0.0, extra_steps=8)
    isam, graph = IncrementalSmoother(exact), FactorGraph()
    factors, values = pose_stream(SE2, 2, 9)[0]
    isam.update(factors, values)
    graph.extend(factors)
    truth = [SE2()]
    for i in range(1, 30):
        step = SE2.from_xytheta(1.0, 0.1 * rng.normal(), 0.3 * rng.normal())
        truth.append(truth[-1] * step)
        noisy = step * SE2.exp(rng.normal(0.0, 0.05, 3))
        new = [BetweenFactor(x(i - 1), x(i), noisy,
                             Diagonal.sigmas(np.exp(rng.normal(0.0, 1.0, 3)) * 0.05))]
        if i >= 3:
            j = int(rng.integers(0, i - 1))
            m = truth[j].between(truth[i]) * SE2.exp(rng.normal(0.0, 0.05, 3))
            new.append(BetweenFactor(x(j), x(i), m,
                                     Diagonal.sigmas(np.exp(rng.normal(0.0, 1.0, 3)) * 0.05)))
        isam.update(new, {x(i): isam.estimate(x(i - 1)) * noisy})
        graph.extend(new)
        del new
    est = isam.estimate()
    best = fgopt.optimize(graph, est, method="gn", max_iterations=30, relative_tolerance=0.0,
                          absolute_tolerance=0.0, gradient_tolerance=1e-13,
                          step_tolerance=1e-15).values
    assert max_tangent_difference(est, best) < 1e-8
