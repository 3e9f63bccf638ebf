"""``IncrementalSmoother.estimate()`` of all variables: built in bulk (no Python step per
variable until values are read), equal to the per-key estimates, and a value the caller may keep
(later updates do not change it)."""

import numpy as np
import pytest

from fgopt import FactorGraph, IncrementalParams, IncrementalSmoother
from fgopt.manifolds import SE2, SE3

from ._streams import gauss_newton_step, max_tangent_difference, pose_stream, x


def _wrap_calls(group):
    """Count the per-value ``wrap`` calls of ``group``'s batch kind (a frozen dataclass)."""
    from fgopt.manifolds.base import ops_for
    kind = ops_for(group.identity()).batch_kind(group.identity())
    calls = []
    wrap = kind.wrap
    object.__setattr__(kind, "wrap", lambda row: (calls.append(1), wrap(row))[1])
    return kind, wrap, calls


def test_full_estimate_makes_no_object_per_variable():
    """Reading the whole estimate after an update wraps no value one by one (the cost that
    made a per-update full read ~0.23 ms at 434 poses); the values appear when read."""
    isam = IncrementalSmoother(IncrementalParams(wildfire_threshold=0.0))
    for factors, values in pose_stream(SE2, 60, 1):
        isam.update(factors, values)
    kind, wrap, calls = _wrap_calls(SE2)
    try:
        est = isam.estimate()
    finally:
        object.__setattr__(kind, "wrap", wrap)
    assert len(est) == 60 and calls == []
    for i in (0, 17, 59):  # the values read equal the per-key estimates
        assert np.allclose(est.at(x(i)).to_storage(), isam.estimate(x(i)).to_storage(),
                           atol=1e-12)


def test_full_estimate_is_kept_by_the_caller():
    """A full estimate taken before later updates keeps its values bit for bit: the storage
    rows are the caller's copy (read-only), not views of the smoother's arrays."""
    steps = pose_stream(SE3, 40, 2)
    isam = IncrementalSmoother(IncrementalParams(relinearize_skip=1, relinearize_threshold=0.0))
    for factors, values in steps[:20]:
        isam.update(factors, values)
    est = isam.estimate()
    before = {k: v.to_storage().copy() for k, v in isam.estimate().items()}
    for factors, values in steps[20:]:
        isam.update(factors, values)
    assert sorted(est.keys()) == sorted(before)
    for k, v in est.items():
        assert np.array_equal(v.to_storage(), before[k])
    later = isam.estimate()
    assert len(later) == 40 and len(est) == 20


@pytest.mark.parametrize("group,n,seed", [(SE2, 60, 3), (SE3, 30, 4)])
def test_full_estimate_after_every_update_is_the_exact_step(group, n, seed):
    """With the default wildfire threshold (1e-3, which only ``estimate(key)`` uses),
    ``estimate()`` read after every update equals the exact Gauss-Newton step at the
    linearization point to 1e-7: it re-solves a subtree only when a separator variable moved by
    more than ``ESTIMATE_TOLERANCE`` (1e-9) since the subtree was last solved, so the error is
    at most that times the gains of the conditionals below it, and does not add up over reads
    (1e-7 leaves two orders of margin on these chains)."""
    from fgopt.incremental.smoother import ESTIMATE_TOLERANCE
    assert ESTIMATE_TOLERANCE <= 1e-9
    isam = IncrementalSmoother()
    graph = FactorGraph()
    worst = 0.0
    for factors, values in pose_stream(group, n, seed):
        isam.update(factors, values)
        graph.extend(factors)
        worst = max(worst, max_tangent_difference(
            isam.estimate(), gauss_newton_step(graph, isam.linearization_point())))
    assert worst < 1e-7


def test_full_estimate_resolves_only_what_an_update_moved():
    """After an update that only appends a pose by odometry (the old poses' solution is
    unchanged), ``estimate()`` back-substitutes a few cliques, not the whole tree."""
    steps = pose_stream(SE2, 80, 6, loop_prob=0.0)
    isam = IncrementalSmoother(IncrementalParams(enable_relinearization=False))
    for factors, values in steps[:-1]:
        isam.update(factors, values)
    isam.estimate()
    isam.update(*steps[-1])
    est = isam.estimate()
    assert len(est) == 80
    assert 0 < isam.last_estimate_cliques <= 5 < isam.update([], {}).cliques
