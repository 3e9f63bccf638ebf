"""Generated problems: the synthetic BAL problem is consistent (its truth sits at the pixel-noise
floor, LM from its initial guess gets there) and round-trips through a BAL file exactly; a
generated 3D grid written as g2o reads back with the same cost."""

from __future__ import annotations

import numpy as np
import pytest

import fgopt
from fgopt.datasets import bal_synthetic, grid_3d
from fgopt.io import read, read_bal, write_g2o


def test_bal_synthetic_truth_is_at_the_noise_floor_and_lm_reaches_it(tmp_path):
    """Cost at the true cameras/points is ~ noise^2 * 2m / 2 (chi-square mean), the initial
    guess is far above, and LM ends at or below the truth's cost."""
    s = bal_synthetic(cameras=30, points=2000, observations_per_point=4, seed=3, noise=0.5)
    m = s.observations.shape[0]
    assert m == 8000 and s.camera_index.max() == 29
    path = tmp_path / "syn.txt"
    s.write(path)
    graph, initial = read_bal(path)
    assert np.array_equal(np.asarray(initial.at(fgopt.key("c", 7))), s.cameras[7])
    truth = fgopt.Variables()
    for i, c in enumerate(s.true_cameras):
        truth.add(fgopt.key("c", i), c)
    for j, p in enumerate(s.true_points):
        truth.add(fgopt.key("p", j), p)
    floor = graph.error(truth)
    expected = 0.5 * 0.25 * 2 * m
    assert 0.9 * expected < floor < 1.1 * expected
    assert graph.error(initial) > 10 * floor
    result = fgopt.optimize(graph, initial, max_iterations=50)
    assert result.final_cost <= floor


def test_grid_3d_round_trips_through_g2o(tmp_path):
    """A generated SE(3) grid written as g2o reads back with the same edge cost."""
    g = grid_3d(200, seed=1)
    path = tmp_path / "grid.g2o"
    write_g2o(path, g.graph, g.initial)
    graph, initial = read(path)
    edges = fgopt.FactorGraph([f for f in g.graph if "prior" not in type(f).__name__.lower()
                               and "prior" not in getattr(f.kernel, "name", "")])
    assert np.isclose(graph.error(initial), edges.error(g.initial), rtol=1e-9)


def test_bal_synthetic_rejects_bad_sizes_with_an_fgopt_error():
    """A scene that cannot be built (one camera, or more observations per point than cameras)
    raises FgoptError naming the function, not a bare ValueError."""
    from fgopt.datasets import bal_synthetic
    from fgopt.errors import FgoptError

    for kwargs in (dict(cameras=1, points=5), dict(cameras=3, points=5, observations_per_point=4)):
        with pytest.raises(FgoptError, match="bal_synthetic"):
            bal_synthetic(**kwargs)


def test_generators_reject_bad_counts_and_fractions():
    """Pose counts below 1 or not integers, negative fractions and a reference too small for
    any non-consecutive pair are FgoptErrors (num_poses=-1 used to return a one-pose graph, and
    two poses made random_loop_closures draw forever)."""
    from fgopt.datasets import manhattan_2d, random_loop_closures
    from fgopt.errors import FgoptError

    for bad in (0, -1, 2.5, True):
        with pytest.raises(FgoptError, match="num_poses"):
            manhattan_2d(num_poses=bad)
        with pytest.raises(FgoptError, match="num_poses"):
            grid_3d(num_poses=bad)
    s = manhattan_2d(num_poses=10, seed=0)
    for bad in (-0.1, float("nan"), float("inf")):
        with pytest.raises(FgoptError, match="fraction"):
            random_loop_closures(s.graph, s.initial, bad)
    two = manhattan_2d(num_poses=2, seed=0)
    with pytest.raises(FgoptError, match="at least 3 poses"):
        random_loop_closures(two.graph, two.initial, 1.0)
    assert random_loop_closures(s.graph, s.initial, 0.0)[1] == 0
