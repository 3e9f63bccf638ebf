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


def _streamed(group, n, closures, first, last):
    """A smoother fed ``pose_stream(group, n, closures)``; its factor store, tree and the slots
    of factors ``first:last`` (in slot order)."""
    isam = IncrementalSmoother()
    for factors, values in pose_stream(group, n, closures):
        isam.update(factors, values)
    facs, tree = isam._facs, isam._tree
    return facs, tree, np.array(sorted(facs.slot_of_handle.values())[first:last], np.int64)


def test_one_factor_alone_writes_the_same_local_system_as_a_batch():
    """``linearize`` of one factor (row slices) and of the same factor among others (gathered
    rows) write identical local systems ``[H; g]``."""
    facs, tree, slots = _streamed(SE3, 12, 5, 3, 7)
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


def test_free_slots_keep_a_zero_update():
    """A removed variable's slot goes back with ``delta``, the estimate's ``xdelta`` and
    ``xprop`` all zero (a new variable in that slot starts from them unwritten), and a variable
    re-added in the reused slot reads back as the estimate of a twin that never removed one."""
    steps = pose_stream(SE2, 12, 4, loop_prob=0.0)
    a, b = IncrementalSmoother(), IncrementalSmoother()
    for factors, values in steps:
        a.update(factors, values)
        b.update(factors, values)
    a.estimate()
    extra = x(100)
    step = SE2.from_xytheta(1.0, 0.2, 0.1)
    noise = Diagonal.sigmas(np.full(3, 0.05))
    r = a.update([BetweenFactor(x(11), extra, step, noise)], {extra: a.estimate(x(11)) * step})
    a.estimate()
    slot = a._vars.slot(extra)
    assert np.any(a._tree.xdelta[slot] != 0.0)
    a.update(remove=r.new_factor_indices)  # drops x100: its slot is free again
    assert extra not in a and slot in a._vars.free
    for name in ("delta", "xdelta", "xprop"):
        assert not np.any(getattr(a._tree, name)[slot]), name
    for isam in (a, b):
        isam.update([BetweenFactor(x(11), x(12), step, noise)], {x(12): step})
    assert a._vars.slot(x(12)) == slot
    assert max_tangent_difference(a.estimate(), b.estimate()) < 1e-12


def test_tops_ordered_by_amd_give_the_same_estimate(monkeypatch):
    """Every top handed back for AMD ordering (the packed ``NEED_ORDER`` result of
    ``tree_update``, split by ``unpack_top``) gives the estimate the in-kernel ordering gives,
    to rounding."""
    from fgopt.incremental import _ordering

    steps = pose_stream(SE3, 25, 6)
    a = IncrementalSmoother(IncrementalParams(relinearize_skip=1))
    for factors, values in steps:
        a.update(factors, values)
    monkeypatch.setattr(_ordering, "BITSET_LIMIT", 1)
    b = IncrementalSmoother(IncrementalParams(relinearize_skip=1))
    for factors, values in steps:
        r = b.update(factors, values)
        assert r.variables_reeliminated <= 1 or "order" in r.timing
    assert max_tangent_difference(a.estimate(), b.estimate()) < 1e-9


def test_gathered_rows_in_any_order_write_the_same_local_systems():
    """Factors of one batch linearized together write the same ``[H; g]`` whether their batch
    rows are consecutive (sliced) or not (gathered), in any order."""
    facs, tree, slots = _streamed(SE2, 14, 8, 2, 8)
    D = tree.fac_D[slots]

    def blocks(order):
        facs.linearize(order, order.shape[0])
        return {int(s): tree.hpool[o:o + d * d + d].copy()
                for s, o, d in zip(order, tree.fac_hoff[order], tree.fac_D[order])}

    ref = blocks(slots)
    for order in (slots[::-1].copy(), slots[[0, 2, 4, 1, 3, 5]].copy()):
        got = blocks(order)
        assert all(np.array_equal(got[int(s)], ref[int(s)]) for s in slots)
    assert D.shape[0] == 6


def test_update_result_has_every_field_of_the_dataclass():
    """The result ``update`` builds without the dataclass ``__init__`` has exactly its fields
    (so equality, ``repr`` and ``dataclasses.asdict`` work) and equals one built by it."""
    import dataclasses

    from fgopt.incremental import UpdateResult

    isam = IncrementalSmoother()
    for factors, values in pose_stream(SE2, 6, 3):
        r = isam.update(factors, values)
    names = [f.name for f in dataclasses.fields(UpdateResult)]
    assert sorted(vars(r)) == sorted(names)
    assert UpdateResult(**{n: getattr(r, n) for n in names}) == r
    assert dataclasses.asdict(r)["variables_reeliminated"] == r.variables_reeliminated
    assert "new factors" in repr(r)
