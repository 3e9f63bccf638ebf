"""GTSAM's SFMExample_SmartFactor written with fgopt: the SFMExample scene (``sfm_fgopt.py``)
with one SmartProjectionFactor per corner (the corner is triangulated inside the factor, not a
variable), priors on the first two cameras, every camera started at ``pose * delta``,
Levenberg-Marquardt. Prints the optimized cameras, the corners triangulated at the optimum and
the errors."""

import numpy as np

import fgopt
from fgopt import SE3, SO3, PriorFactor, key
from fgopt.cameras import Cal3_S2, PinholeCamera, SmartProjectionFactor
from fgopt.noise import Diagonal, Isotropic


def scene(K):
    """The cube's corners (world frame, m) and the cameras' world_T_camera."""
    corners = np.array([[x, y, z] for z in (10.0, -10.0)
                        for x, y in ((10.0, 10.0), (-10.0, 10.0), (-10.0, -10.0), (10.0, -10.0))])
    poses = [PinholeCamera.lookat([40.0 * np.cos(a), 40.0 * np.sin(a), 10.0], [0.0, 0.0, 0.0],
                                  [0.0, 0.0, 1.0], K).pose()
             for a in np.linspace(0.0, 2.0 * np.pi, 8, endpoint=False)]
    return corners, poses


def run():
    K = Cal3_S2(50.0, 50.0, 0.0, 50.0, 50.0)
    corners, poses = scene(K)
    cameras = [key("x", i) for i in range(len(poses))]
    pixels = np.array([PinholeCamera(pose, K).project(corners) for pose in poses])
    graph = fgopt.FactorGraph()
    smart = [SmartProjectionFactor(cameras, pixels[:, j], K, Isotropic.sigma(2, 1.0))
             for j in range(len(corners))]
    for factor in smart:
        graph.add(factor)
    prior = Diagonal.sigmas([0.1, 0.1, 0.1, 0.3, 0.3, 0.3])
    graph.add(PriorFactor(cameras[0], poses[0], prior))
    graph.add(PriorFactor(cameras[1], poses[1], prior))
    delta = SE3(SO3.exp([-0.1, 0.2, 0.25]), [0.05, -0.10, 0.20])
    initial = fgopt.Variables()
    for camera, pose in zip(cameras, poses):
        initial.add(camera, pose * delta)
    result = fgopt.optimize(graph, initial)
    answer = {f"x{i}": result.values.at(c).matrix() for i, c in enumerate(cameras)}
    answer.update({f"l{j}": f.point(result.values) for j, f in enumerate(smart)})
    answer.update({"initial error": graph.error(initial), "final error": result.final_cost})
    return answer


if __name__ == "__main__":
    np.set_printoptions(precision=6, suppress=True)
    for name, value in run().items():
        print(f"{name}: {np.round(value, 6) + 0.0}")  # + 0.0: no "-0."
