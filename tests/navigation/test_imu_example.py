"""GTSAM's ImuFactorsExample data (real file): the reader, and the batch problem solved by fgopt's
default LM equal to GTSAM's LevenbergMarquardtOptimizer on the same problem."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

import fgopt
from fgopt.errors import FileFormatError
from fgopt.io.imu_gps import B, V, X, imu_factors_example, read_imu_gps_csv

REPO = Path(__file__).resolve().parents[2]
CSV = "navigation/imuAndGPSdata.csv"


def _trajectory(values, n):
    out = np.empty((n, 15))
    for k in range(n):
        pose = values.at(X(k))
        out[k, :3] = pose.translation()
        out[k, 3:6] = pose.rotation().log()
        out[k, 6:9] = values.at(V(k))
        out[k, 9:] = values.at(B(k))
    return out


def test_read_imu_and_gps_file(data_file):
    """The example file: an initial state (all-zero quaternion read as the identity, as GTSAM),
    20000 IMU samples, 100 GPS fixes, 200 samples between fixes (1 before the first)."""
    data = read_imu_gps_csv(data_file(CSV))
    assert data.imu.shape == (20000, 6) and data.gps.shape == (100, 7)
    assert data.initial_pose.equals(fgopt.SE3())
    assert np.allclose(data.initial_velocity, [0, 0, 1])
    assert data.imu_before_gps[0] == 1 and np.all(np.diff(data.imu_before_gps) == 200)
    assert np.all(data.imu[:, 1:] == 0.0)  # specific force along x only, no rotation


@pytest.mark.parametrize("combined", [False, True], ids=["ImuFactor", "CombinedImuFactor"])
def test_batch_solution_equals_gtsam(data_file, combined):
    """IMU factors between consecutive states, a GPS fix on each, priors on the first state:
    fgopt's default LM (identity damping for this problem class) converges in 3 iterations as
    GTSAM's LevenbergMarquardtOptimizer does from the same dead-reckoned initial values, and the
    optimized trajectories (positions, rotations, velocities, biases) agree to 1e-6."""
    gtsam = pytest.importorskip("gtsam")
    if str(REPO) not in sys.path:
        sys.path.insert(0, str(REPO))
    from benchmarks.peers import gtsam_navigation as GN

    data = read_imu_gps_csv(data_file(CSV))
    problem = imu_factors_example(data, combined=combined)
    graph, initial = GN.build(data, problem, combined=combined)
    compiled = fgopt.Problem(problem.graph, problem.initial)
    assert graph.error(initial) == pytest.approx(compiled.cost(compiled.initial_state()),
                                                 rel=1e-9)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, initial,
                                                  gtsam.LevenbergMarquardtParams())
    theirs = optimizer.optimize()
    ours = fgopt.optimize(problem.graph, problem.initial)
    assert ours.iterations <= 5
    assert ours.final_cost == pytest.approx(graph.error(theirs), rel=1e-6)
    diff = np.abs(_trajectory(ours.values, problem.num_states)
                  - GN.trajectory(theirs, problem.num_states))
    assert diff.max() < 1e-6, diff.max(axis=0)
    # the GPS pulls the dead-reckoned trajectory (z drifts with the initial velocity) back
    final = ours.values.at(X(problem.num_states - 1)).translation()
    assert np.linalg.norm(final - data.gps[-1, :3]) < 1.0


def test_gps_every_few_states(data_file):
    """With a GPS fix on every 5th state only (a much more nonlinear problem: the attitude is
    weakly observed), the default LM (identity damping, Nielsen's lambda rule for this problem
    class) converges, to states within a few metres of the every-state solution."""
    from fgopt.navigation import GpsFactor

    data = read_imu_gps_csv(data_file(CSV))
    every = imu_factors_example(data)
    sparse = imu_factors_example(data, gps_every=5)
    assert sum(isinstance(f, GpsFactor) for f in sparse.graph.factors) == 20
    a = fgopt.optimize(every.graph, every.initial)
    b = fgopt.optimize(sparse.graph, sparse.initial)
    assert b.status == fgopt.Status.CONVERGED, b.message
    diff = np.abs(_trajectory(a.values, every.num_states)[:, :3]
                  - _trajectory(b.values, sparse.num_states)[:, :3])
    assert diff.max() < 5.0


@pytest.mark.parametrize("text, line, match", [
    ("0,1,2,3,4,5,6\n", 1, "first record must be the initial state"),
    ("i,0,0,0,0,0,0,1,0,0,0\n0,1,2,3\n", 2, "needs 6 numbers, got 3"),
    ("i,0,0,0,0,0,0,1,0,0,0\n2,1,2,3,4,5,6\n", 2, "unknown record type"),
    ("i,0,0,0,0,0,0,1,0,0,0\n1,1,x,3,0,0,0,1\n", 2, "non-numeric"),
    ("i,0,0,0,0.5,0,0,0.5,0,0,0\n", 1, "not a unit quaternion"),
])
def test_reader_errors_name_file_and_line(tmp_path, text, line, match):
    """Malformed records raise FileFormatError with file:line."""
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(FileFormatError, match=match) as info:
        read_imu_gps_csv(path)
    assert f"bad.csv:{line}" in str(info.value)
