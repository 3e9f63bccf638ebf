"""GTSAM's SFMExample without plots and prints of the graph, seeded: the reference for
``sfm_fgopt.py``. Prints the optimized cameras, corners and the errors."""

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X

SEED = 11


def scene(K):
    """The cube's corners and the cameras (radius 40 m, height 10 m, looking at the centre: the
    scene of GTSAM's SFMdata.py at its repository's HEAD; the 4.3 wheel's differs)."""
    corners = [np.array([x, y, z]) for z in (10.0, -10.0)
               for x, y in ((10.0, 10.0), (-10.0, 10.0), (-10.0, -10.0), (10.0, -10.0))]
    poses = [gtsam.PinholeCameraCal3_S2.Lookat(
        gtsam.Point3(40.0 * np.cos(a), 40.0 * np.sin(a), 10.0), gtsam.Point3(0, 0, 0),
        gtsam.Point3(0, 0, 1), K).pose() for a in np.linspace(0, 2 * np.pi, 8, endpoint=False)]
    return corners, poses


def run():
    rng = np.random.default_rng(SEED)
    K = gtsam.Cal3_S2(50.0, 50.0, 0.0, 50.0, 50.0)
    corners, poses = scene(K)
    graph = gtsam.NonlinearFactorGraph()
    graph.push_back(gtsam.PriorFactorPose3(X(0), poses[0], gtsam.noiseModel.Diagonal.Sigmas(
        np.array([0.3, 0.3, 0.3, 0.1, 0.1, 0.1]))))
    pixel_noise = gtsam.noiseModel.Isotropic.Sigma(2, 1.0)
    for i, pose in enumerate(poses):
        camera = gtsam.PinholeCameraCal3_S2(pose, K)
        for j, corner in enumerate(corners):
            graph.push_back(gtsam.GenericProjectionFactorCal3_S2(
                camera.project(corner), pixel_noise, X(i), L(j), K))
    graph.push_back(gtsam.PriorFactorPoint3(L(0), corners[0],
                                            gtsam.noiseModel.Isotropic.Sigma(3, 0.1)))
    initial = gtsam.Values()
    for i, pose in enumerate(poses):
        initial.insert(X(i), pose.retract(0.1 * rng.standard_normal(6)))
    for j, corner in enumerate(corners):
        initial.insert(L(j), corner + 0.1 * rng.standard_normal(3))
    result = gtsam.DoglegOptimizer(graph, initial, gtsam.DoglegParams()).optimize()
    answer = {f"x{i}": result.atPose3(X(i)).matrix() for i in range(len(poses))}
    answer.update({f"l{j}": result.atPoint3(L(j)) for j in range(len(corners))})
    answer.update({"initial error": graph.error(initial), "final error": graph.error(result)})
    return answer


if __name__ == "__main__":
    np.set_printoptions(precision=6, suppress=True)
    for name, value in run().items():
        print(f"{name}: {np.round(value, 6) + 0.0}")  # + 0.0: no "-0."
