"""The numpy yardstick equals GTSAM's graph.error (run: pytest benchmarks/tests)."""

import numpy as np
import pytest

from benchmarks import problems, yardstick

gtsam = pytest.importorskip("gtsam")


def _have(name):
    spec = problems.PROBLEMS[name]
    return spec.path is None or spec.path.exists()


def _perturbed(g, rng, scale):
    x = g.poses.copy()
    if g.is3d:
        x[:, :3] += rng.normal(size=(len(x), 3)) * scale
        dq = yardstick.rotvec_to_quat(rng.normal(size=(len(x), 3)) * scale)
        x[:, 3:7] = yardstick.quat_mul(x[:, 3:7], dq)
    else:
        x += rng.normal(size=x.shape) * scale
    return x


def _gtsam_values(g, x):
    v = gtsam.Values()
    for i, r in zip(g.ids, x):
        if g.is3d:
            v.insert(int(i), gtsam.Pose3(gtsam.Rot3.Quaternion(r[6], r[3], r[4], r[5]), r[:3]))
        else:
            v.insert(int(i), gtsam.Pose2(*r))
    return v


@pytest.mark.parametrize("name", ["pose2example", "smallgrid3d", "m3500", "sphere2500"])
def test_pose_graph_cost_matches_gtsam(name):
    if not _have(name):
        pytest.skip("data not found")
    g = problems.load(name)
    graph, _ = gtsam.readG2o(str(problems.PROBLEMS[name].path), g.is3d)
    rng = np.random.default_rng(0)
    for scale in (0.0, 0.05, 0.5):
        x = _perturbed(g, rng, scale)
        want = graph.error(_gtsam_values(g, x))
        got = yardstick.pose_graph_cost(g, x)
        assert got == pytest.approx(want, rel=1e-9)


def test_bal_cost_matches_gtsam_in_front_of_cameras():
    if not _have("dubrovnik3"):
        pytest.skip("data not found")
    from benchmarks.peers.gtsam_runner import RUNNER

    spec = problems.PROBLEMS["dubrovnik3"]
    b = problems.load("dubrovnik3")
    st = RUNNER.load(spec)
    assert yardstick.bal_cost(b, b.cameras, b.points) == pytest.approx(
        st["graph"].error(st["initial"]), rel=1e-9)
    # the GTSAM -> BAL camera conversion round-trips
    est = RUNNER.estimate(st, type("Out", (), {"raw": st["initial"]})())
    np.testing.assert_allclose(est["cameras"], b.cameras, atol=1e-9)


def test_robot_cost_matches_gtsam():
    from benchmarks.peers.gtsam_runner import RUNNER

    p = problems.robot_localization()
    st = RUNNER.load(problems.PROBLEMS["robot_localization"])
    # landmark priors are zero at the known positions
    assert yardstick.robot_cost(p, p.poses) == pytest.approx(
        st["graph"].error(st["initial"]), rel=1e-12)


def test_lie_helpers():
    rng = np.random.default_rng(1)
    r = rng.normal(size=(50, 3))
    r *= (rng.uniform(0, 3.1, size=50) / np.linalg.norm(r, axis=1))[:, None]
    np.testing.assert_allclose(yardstick.quat_to_rotvec(yardstick.rotvec_to_quat(r)), r,
                               atol=1e-12)
    th = rng.uniform(-3, 3, size=20)
    p = np.stack([rng.normal(size=20), rng.normal(size=20), th], 1)
    for row, lg in zip(p, yardstick.pose2_logmap(p)):
        want = gtsam.Pose2.Logmap(gtsam.Pose2(*row))
        np.testing.assert_allclose(lg, want, atol=1e-12)
