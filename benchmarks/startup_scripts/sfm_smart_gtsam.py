"""GTSAM's SFMExample_SmartFactor (a C++ example; here with GTSAM's Python wrapper), without
prints of the graph: the reference for ``sfm_smart_fgopt.py``. Prints the optimized cameras,
the corners triangulated at the optimum and the errors."""

import gtsam
import numpy as np
from gtsam.symbol_shorthand import X


def scene(K):
    """The cube's corners and the cameras (as ``sfm_gtsam.py``)."""
    corners = [np.array([x, y, z]) for z in (10.0, -10.0)
               for x, y in ((10.0, 10.0), (-10.0, 10.0), (-10.0, -10.0), (10.0, -10.0))]
    poses = [gtsam.PinholeCameraCal3_S2.Lookat(
        gtsam.Point3(40.0 * np.cos(a), 40.0 * np.sin(a), 10.0), gtsam.Point3(0, 0, 0),
        gtsam.Point3(0, 0, 1), K).pose() for a in np.linspace(0, 2 * np.pi, 8, endpoint=False)]
    return corners, poses


def run():
    K = gtsam.Cal3_S2(50.0, 50.0, 0.0, 50.0, 50.0)
    corners, poses = scene(K)
    pixel_noise = gtsam.noiseModel.Isotropic.Sigma(2, 1.0)
    graph = gtsam.NonlinearFactorGraph()
    smart = []
    for corner in corners:
        factor = gtsam.SmartProjectionPoseFactorCal3_S2(pixel_noise, K)
        for i, pose in enumerate(poses):
            factor.add(gtsam.PinholeCameraCal3_S2(pose, K).project(corner), X(i))
        smart.append(factor)
        graph.push_back(factor)
    prior = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.1, 0.1, 0.1, 0.3, 0.3, 0.3]))
    graph.push_back(gtsam.PriorFactorPose3(X(0), poses[0], prior))
    graph.push_back(gtsam.PriorFactorPose3(X(1), poses[1], prior))
    delta = gtsam.Pose3(gtsam.Rot3.Rodrigues(-0.1, 0.2, 0.25), gtsam.Point3(0.05, -0.10, 0.20))
    initial = gtsam.Values()
    for i, pose in enumerate(poses):
        initial.insert(X(i), pose.compose(delta))
    result = gtsam.LevenbergMarquardtOptimizer(graph, initial).optimize()
    answer = {f"x{i}": result.atPose3(X(i)).matrix() for i in range(len(poses))}
    answer.update({f"l{j}": f.point(result).get() for j, f in enumerate(smart)})
    answer.update({"initial error": graph.error(initial), "final error": graph.error(result)})
    return answer


if __name__ == "__main__":
    np.set_printoptions(precision=6, suppress=True)
    for name, value in run().items():
        print(f"{name}: {np.round(value, 6) + 0.0}")  # + 0.0: no "-0."
