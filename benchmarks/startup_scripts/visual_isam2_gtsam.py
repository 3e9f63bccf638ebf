"""GTSAM's VisualISAM2Example without plots and per-frame prints: the reference for
``visual_isam2_fgopt.py``. Prints the last frame's estimate of every camera and corner."""

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X


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
    params = gtsam.ISAM2Params()
    params.setRelinearizeThreshold(0.01)
    params.relinearizeSkip = 1
    isam = gtsam.ISAM2(params)
    pixel_noise = gtsam.noiseModel.Isotropic.Sigma(2, 1.0)
    delta = gtsam.Pose3(gtsam.Rot3.Rodrigues(-0.1, 0.2, 0.25), gtsam.Point3(0.05, -0.10, 0.20))
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for i, pose in enumerate(poses):
        camera = gtsam.PinholeCameraCal3_S2(pose, K)
        for j, corner in enumerate(corners):
            graph.push_back(gtsam.GenericProjectionFactorCal3_S2(
                camera.project(corner), pixel_noise, X(i), L(j), K))
        values.insert(X(i), pose.compose(delta))
        if i == 0:
            graph.push_back(gtsam.PriorFactorPose3(X(0), pose, gtsam.noiseModel.Diagonal.Sigmas(
                np.array([0.1, 0.1, 0.1, 0.3, 0.3, 0.3]))))
            graph.push_back(gtsam.PriorFactorPoint3(L(0), corners[0],
                                                    gtsam.noiseModel.Isotropic.Sigma(3, 0.1)))
            for j, corner in enumerate(corners):
                values.insert(L(j), corner + np.array([-0.25, 0.20, 0.15]))
            continue
        isam.update(graph, values)
        isam.update()
        estimate = isam.calculateEstimate()
        graph.resize(0)
        values.clear()
    answer = {f"x{i}": estimate.atPose3(X(i)).matrix() for i in range(len(poses))}
    answer.update({f"l{j}": estimate.atPoint3(L(j)) for j in range(len(corners))})
    return answer


if __name__ == "__main__":
    np.set_printoptions(precision=6, suppress=True)
    for name, value in run().items():
        print(f"{name}: {np.round(value, 6) + 0.0}")  # + 0.0: no "-0."
