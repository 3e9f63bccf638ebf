"""GTSAM's VisualISAM2Example written with fgopt: the SFMExample scene (``sfm_fgopt.py``), the
cameras added one per frame with their 8 projections, every camera started at ``pose * delta``
and every corner offset by (-0.25, 0.20, 0.15), priors on the first camera and corner,
incremental smoothing (relinearize threshold 0.01, skip 1) with one extra update per frame.
Prints the last frame's estimate of every camera and corner."""

import numpy as np

from fgopt import SE3, SO3, IncrementalParams, IncrementalSmoother, PriorFactor, key
from fgopt.cameras import Cal3_S2, PinholeCamera, ProjectionFactor
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
    isam = IncrementalSmoother(IncrementalParams(relinearize_threshold=0.01, relinearize_skip=1))
    pixel_noise = Isotropic.sigma(2, 1.0)
    delta = SE3(SO3.exp([-0.1, 0.2, 0.25]), [0.05, -0.10, 0.20])
    factors, values = [], {}
    for i, pose in enumerate(poses):
        pixels = PinholeCamera(pose, K).project(corners)
        for j in range(len(corners)):
            factors.append(ProjectionFactor(key("x", i), key("l", j), pixels[j], pixel_noise, K))
        values[key("x", i)] = pose * delta
        if i == 0:  # the first frame alone cannot fix the corners: wait for the second
            factors.append(PriorFactor(key("x", 0), pose,
                                       Diagonal.sigmas([0.1, 0.1, 0.1, 0.3, 0.3, 0.3])))
            factors.append(PriorFactor(key("l", 0), corners[0], Isotropic.sigma(3, 0.1)))
            for j, corner in enumerate(corners):
                values[key("l", j)] = corner + np.array([-0.25, 0.20, 0.15])
            continue
        isam.update(factors, values)
        isam.update()
        estimate = isam.estimate()
        factors, values = [], {}
    answer = {f"x{i}": estimate.at(key("x", i)).matrix() for i in range(len(poses))}
    answer.update({f"l{j}": np.asarray(estimate.at(key("l", j))) for j in range(len(corners))})
    return answer


if __name__ == "__main__":
    np.set_printoptions(precision=6, suppress=True)
    for name, value in run().items():
        print(f"{name}: {np.round(value, 6) + 0.0}")  # + 0.0: no "-0."
