"""The incremental smoother solves the same linear system as batch Gauss-Newton.

* Every update, whatever part of the tree it re-eliminates (incremental tops, orphans reused,
  batch steps, partial relinearization), leaves an exact Bayes tree of the batch system at
  the smoother's linearization point: ``estimate()`` equals one dense batch GN step from
  ``linearization_point()`` to rounding.
* With every variable relinearized at every update (threshold 0, skip 1) and extra passes,
  the estimate equals the converged batch Gauss-Newton solution to 1e-8 after every update.
"""

import numpy as np
import pytest

import fgopt
from fgopt import FactorGraph, IncrementalParams, IncrementalSmoother
from fgopt.manifolds import SE2, SE3

from ._streams import gauss_newton_step, max_tangent_difference, pose_stream

CASES = [(SE2, 30, 1), (SE3, 18, 2)]


@pytest.mark.parametrize("group,n,seed", CASES)
@pytest.mark.parametrize("params", [
    dict(enable_relinearization=False, batch_threshold=2.0),         # pure incremental tops
    dict(relinearize_threshold=0.05, relinearize_skip=1),             # partial relinearization
    dict(relinearize_threshold=0.02, relinearize_skip=3, batch_threshold=0.3),  # batch steps
], ids=["no-relin", "partial", "batch-steps"])
def test_tree_solves_the_batch_linear_system(group, n, seed, params):
    """After every update, estimate() == theta (+) (dense batch GN step at theta)."""
    isam = IncrementalSmoother(IncrementalParams(wildfire_threshold=0.0, **params))
    graph = FactorGraph()
    worst = 0.0
    for factors, values in pose_stream(group, n, seed):
        isam.update(factors, values)
        graph.extend(factors)
        ref = gauss_newton_step(graph, isam.linearization_point())
        worst = max(worst, max_tangent_difference(isam.estimate(), ref))
    assert worst < 1e-9


@pytest.mark.parametrize("group,n,seed", CASES)
def test_relinearize_everything_equals_batch_gauss_newton(group, n, seed):
    """Threshold 0, skip 1, extra GN passes: estimate == converged batch GN to 1e-8, always."""
    isam = IncrementalSmoother(IncrementalParams(
        relinearize_threshold=0.0, relinearize_skip=1, wildfire_threshold=0.0, extra_steps=8))
    graph = FactorGraph()
    initial = fgopt.Variables()
    for factors, values in pose_stream(group, n, seed, init_noise=0.05):
        isam.update(factors, values)
        graph.extend(factors)
        for k, v in values.items():
            initial.add(k, v)
        ref = fgopt.optimize(graph, initial, method="gn", max_iterations=30,
                             relative_tolerance=0.0, absolute_tolerance=0.0,
                             gradient_tolerance=1e-13, step_tolerance=1e-15).values
        assert max_tangent_difference(isam.estimate(), ref) < 1e-8


def test_one_key_estimate_with_wildfire_zero_is_exact():
    """estimate(key) reads the back-substituted delta; with wildfire 0 it equals estimate()."""
    isam = IncrementalSmoother(IncrementalParams(wildfire_threshold=0.0))
    for factors, values in pose_stream(SE2, 30, 5):
        isam.update(factors, values)
        full = isam.estimate()
        for k in list(values):
            assert np.abs(isam.estimate(k).local(full.at(k))).max() < 1e-12
