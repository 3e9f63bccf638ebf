"""GTSAM's SFMExample written with fgopt: 8 cameras on a circle of radius 40 m looking at the 8
corners of a 20 m cube, a ProjectionFactor per (camera, corner) with 1-pixel noise, priors on
the first camera and the first corner, perturbed initial values (seeded), Powell's dogleg.
Prints the optimized cameras, corners and the errors."""

import numpy as np

import fgopt
from fgopt import PriorFactor, key
from fgopt.cameras import Cal3_S2, PinholeCamera, ProjectionFactor
from fgopt.noise import Diagonal, Isotropic

SEED = 11


def scene(K):
    """The cube's corners (world frame, m) and the cameras' world_T_camera."""
    corners = np.array([[10.0, 10.0, 10.0], [-10.0, 10.0, 10.0], [-10.0, -10.0, 10.0],
                        [10.0, -10.0, 10.0], [10.0, 10.0, -10.0], [-10.0, 10.0, -10.0],
                        [-10.0, -10.0, -10.0], [10.0, -10.0, -10.0]])
    poses = [PinholeCamera.lookat([40.0 * np.cos(a), 40.0 * np.sin(a), 10.0], [0.0, 0.0, 0.0],
                                  [0.0, 0.0, 1.0], K).pose()
             for a in np.linspace(0.0, 2.0 * np.pi, 8, endpoint=False)]
    return corners, poses


def run():
    rng = np.random.default_rng(SEED)
    K = Cal3_S2(50.0, 50.0, 0.0, 50.0, 50.0)
    corners, poses = scene(K)
    graph = fgopt.FactorGraph()
    graph.add(PriorFactor(key("x", 0), poses[0], Diagonal.sigmas([0.3, 0.3, 0.3, 0.1, 0.1, 0.1])))
    pixel_noise = Isotropic.sigma(2, 1.0)
    for i, pose in enumerate(poses):
        pixels = PinholeCamera(pose, K).project(corners)
        for j in range(len(corners)):
            graph.add(ProjectionFactor(key("x", i), key("l", j), pixels[j], pixel_noise, K))
    graph.add(PriorFactor(key("l", 0), corners[0], Isotropic.sigma(3, 0.1)))
    initial = fgopt.Variables()
    for i, pose in enumerate(poses):
        initial.add(key("x", i), pose.retract(0.1 * rng.standard_normal(6)))
    for j, corner in enumerate(corners):
        initial.add(key("l", j), corner + 0.1 * rng.standard_normal(3))
    result = fgopt.optimize(graph, initial, method="dogleg")
    answer = {f"x{i}": result.values.at(key("x", i)).matrix() for i in range(len(poses))}
    answer.update({f"l{j}": np.asarray(result.values.at(key("l", j)))
                   for j in range(len(corners))})
    answer.update({"initial error": graph.error(initial), "final error": result.final_cost})
    return answer


if __name__ == "__main__":
    np.set_printoptions(precision=6, suppress=True)
    for name, value in run().items():
        print(f"{name}: {np.round(value, 6) + 0.0}")  # + 0.0: no "-0."
