"""add_gauge_prior: the lowest pose key, found without turning bulk pose rows into objects."""

import numpy as np

import fgopt
from fgopt.datasets import grid_3d
from fgopt.io import add_gauge_prior, read, write_g2o
from fgopt.manifolds import SE3


def test_gauge_prior_on_lowest_pose_keeps_bulk_rows(tmp_path):
    d = grid_3d(30, seed=0)
    path = tmp_path / "g.g2o"
    write_g2o(path, d.graph, d.initial)
    graph, values = read(path)
    assert values._pending  # the reader's poses are bulk rows
    n = len(graph)
    k = add_gauge_prior(graph, values)
    assert k == min(values._pending[0].keys.tolist())
    assert values._pending  # still arrays: no per-key objects were made
    assert len(graph) == n + 1
    assert add_gauge_prior(graph, values) is None  # a pose prior is there now


def test_keys_of_kinds_covers_bulk_rows_and_per_key_values():
    v = fgopt.Variables()
    v.add(7, SE3.identity())
    v.add(3, np.zeros(3))
    v.add_rows(np.array([10, 11]), SE3.batch_kind(), np.tile(SE3.identity().to_storage(), (2, 1)))
    got = v.keys_of_kinds({SE3.batch_kind()})
    assert sorted(got.tolist()) == [7, 10, 11]
    assert v._pending
