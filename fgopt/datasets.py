"""Synthetic pose graphs and SfM scenes for demos and tests (no files needed).

``manhattan_2d`` walks a robot on a unit grid (Olson et al.'s "Manhattan world"): each step moves
1 m forward, turning by 0 or +-90 degrees at random; revisiting a grid cell already seen adds a
loop closure to one of the earlier poses there. Odometry and loop closures are the true relative
poses perturbed by Gaussian noise of the given sigmas; the initial guess composes the noisy
odometry, so it drifts. ``grid_3d`` does the same in a 3D grid with SE(3) poses. ``sfm_cube`` is
GTSAM's ``SFMExample`` scene (8 cameras around a cube of 8 points), with projection or smart factors.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .factors.library.prior_between import BetweenFactor, PriorFactor
from .factors.noise import Diagonal
from .graph import FactorGraph
from .key import key
from .manifolds import SE2, SE3, SO3
from .variables import Variables


def data_dir() -> Path:
    """The real benchmark data folder: env ``FGOPT_DATA``, else ``../shared/data`` beside the
    repository (it may not exist: callers skip or fall back to the generators below)."""
    env = os.environ.get("FGOPT_DATA")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[2] / "shared" / "data"


@dataclass
class SyntheticPoseGraph:
    graph: FactorGraph
    initial: Variables
    truth: Variables
    num_loop_closures: int


def manhattan_2d(num_poses: int = 3500, seed: int = 0, sigmas=(0.01, 0.05, 0.05),
                 loop_probability: float = 0.5, turn_probability: float = 0.3) -> SyntheticPoseGraph:
    """A Manhattan-world 2D pose graph; ``sigmas`` are (theta, x, y), fgopt's tangent order."""
    rng = np.random.default_rng(seed)
    sig = np.asarray(sigmas, dtype=float)
    noise = Diagonal.sigmas(sig)
    heading, pos = 0, np.array([0, 0])
    dirs = np.array([[1, 0], [0, 1], [-1, 0], [0, -1]])
    truth_poses = [SE2.from_xytheta(0.0, 0.0, 0.0)]
    cells: dict[tuple, list[int]] = {(0, 0): [0]}
    graph, initial, truth = FactorGraph(), Variables(), Variables()
    graph.add(PriorFactor(key("x", 0), truth_poses[0], Diagonal.sigmas(sig * 1e-3)))
    estimate = truth_poses[0]
    initial.add(key("x", 0), estimate)
    truth.add(key("x", 0), truth_poses[0])
    loops = 0
    for i in range(1, num_poses):
        if rng.random() < turn_probability:
            heading = (heading + rng.choice([1, 3])) % 4
        nxt = pos + dirs[heading]
        if abs(nxt).max() > max(4, int(np.sqrt(num_poses) / 2)):  # stay in a bounded city
            heading = (heading + 2) % 4
            nxt = pos + dirs[heading]
        pos = nxt
        pose = SE2.from_xytheta(float(pos[0]), float(pos[1]), heading * np.pi / 2)
        rel = truth_poses[-1].between(pose)
        measured = rel.retract(rng.normal(size=3) * sig)
        graph.add(BetweenFactor(key("x", i - 1), key("x", i), measured, noise))
        estimate = estimate * measured
        initial.add(key("x", i), estimate)
        truth.add(key("x", i), pose)
        seen = cells.setdefault((int(pos[0]), int(pos[1])), [])
        earlier = [j for j in seen if j < i - 2]
        if earlier and rng.random() < loop_probability:
            j = int(rng.choice(earlier))
            rel = truth_poses[j].between(pose)
            graph.add(BetweenFactor(key("x", j), key("x", i), rel.retract(rng.normal(size=3) * sig),
                                    noise))
            loops += 1
        seen.append(i)
        truth_poses.append(pose)
    return SyntheticPoseGraph(graph, initial, truth, loops)


def grid_3d(num_poses: int = 1000, seed: int = 0, rotation_sigma: float = 0.01,
            translation_sigma: float = 0.05, loop_probability: float = 0.5) -> SyntheticPoseGraph:
    """A 3D grid-world SE(3) pose graph (random walk on a unit lattice with loop closures)."""
    rng = np.random.default_rng(seed)
    sig = np.array([rotation_sigma] * 3 + [translation_sigma] * 3)
    noise = Diagonal.sigmas(sig)
    axes = np.vstack([np.eye(3), -np.eye(3)])
    pos = np.zeros(3, dtype=int)
    half = max(2, int(round(num_poses ** (1 / 3) / 2)))
    truth_poses = [SE3.identity()]
    cells: dict[tuple, list[int]] = {(0, 0, 0): [0]}
    graph, initial, truth = FactorGraph(), Variables(), Variables()
    graph.add(PriorFactor(key("x", 0), truth_poses[0], Diagonal.sigmas(sig * 1e-3)))
    initial.add(key("x", 0), truth_poses[0])
    truth.add(key("x", 0), truth_poses[0])
    estimate = truth_poses[0]
    loops = 0
    for i in range(1, num_poses):
        step = axes[rng.integers(6)].astype(int)
        if np.abs(pos + step).max() > half:
            step = -step
        pos = pos + step
        rot = SO3.exp(rng.normal(size=3) * 0.3)
        pose = SE3(rot, pos.astype(float))
        measured = truth_poses[-1].between(pose).retract(rng.normal(size=6) * sig)
        graph.add(BetweenFactor(key("x", i - 1), key("x", i), measured, noise))
        estimate = estimate * measured
        initial.add(key("x", i), estimate)
        truth.add(key("x", i), pose)
        seen = cells.setdefault(tuple(int(c) for c in pos), [])
        earlier = [j for j in seen if j < i - 2]
        if earlier and rng.random() < loop_probability:
            j = int(rng.choice(earlier))
            rel = truth_poses[j].between(pose).retract(rng.normal(size=6) * sig)
            graph.add(BetweenFactor(key("x", j), key("x", i), rel, noise))
            loops += 1
        seen.append(i)
        truth_poses.append(pose)
    return SyntheticPoseGraph(graph, initial, truth, loops)


@dataclass
class SyntheticSfm:
    graph: FactorGraph
    initial: Variables
    truth: Variables
    calibration: object
    measurements: np.ndarray  # (num_poses, num_points, 2) pixels


def sfm_cube(smart: bool = False, seed: int = 0, pose_noise: float = 0.1,
             point_noise: float = 0.1) -> SyntheticSfm:
    """GTSAM's ``SFMExample`` scene: 8 landmarks on the corners of a 20 m cube, 8 cameras
    ``Cal3_S2(50, 50, 0, 50, 50)`` on a circle of radius 40 m at height 10 m looking at its
    centre (``PinholeCamera.lookat``), exact pixel measurements with 1-pixel noise models.

    ``smart=False`` (``SFMExample.py``): a ProjectionFactor per (pose, point), priors on ``x0``
    (sigmas 0.3 rad, 0.1 m) and ``l0`` (0.1 m); initial poses ``retract(pose_noise * N(0, I))``
    and points ``+ point_noise * N(0, I)`` (``seed``). ``smart=True``
    (``SFMExample_SmartFactor.cpp``): a SmartProjectionFactor per landmark, priors on ``x0`` and
    ``x1`` (sigmas 0.1 rad, 0.3 m), initial poses ``pose * delta`` with GTSAM's fixed ``delta``
    (Rodrigues(-0.1, 0.2, 0.25), (0.05, -0.10, 0.20)).
    """
    from .cameras import Cal3_S2, PinholeCamera, ProjectionFactor, SmartProjectionFactor
    from .noise import Isotropic

    K = Cal3_S2(50.0, 50.0, 0.0, 50.0, 50.0)
    points = np.array([[x, y, z] for z in (10.0, -10.0)
                       for x, y in ((10.0, 10.0), (-10.0, 10.0), (-10.0, -10.0), (10.0, -10.0))])
    angles = np.linspace(0.0, 2.0 * np.pi, 8, endpoint=False)
    poses = [PinholeCamera.lookat([40.0 * np.cos(t), 40.0 * np.sin(t), 10.0], np.zeros(3),
                                  [0.0, 0.0, 1.0], K).pose() for t in angles]
    z = np.array([PinholeCamera(p, K).project(points) for p in poses])
    pixel = Isotropic.sigma(2, 1.0)
    graph, initial, truth = FactorGraph(), Variables(), Variables()
    for i, p in enumerate(poses):
        truth.add(key("x", i), p)
    rng = np.random.default_rng(seed)
    if smart:
        for j in range(points.shape[0]):
            graph.add(SmartProjectionFactor([key("x", i) for i in range(8)], z[:, j], K, pixel))
        prior = Diagonal.sigmas([0.1, 0.1, 0.1, 0.3, 0.3, 0.3])
        graph.add(PriorFactor(key("x", 0), poses[0], prior))
        graph.add(PriorFactor(key("x", 1), poses[1], prior))
        delta = SE3(SO3.exp([-0.1, 0.2, 0.25]), [0.05, -0.10, 0.20])
        for i, p in enumerate(poses):
            initial.add(key("x", i), p * delta)
        return SyntheticSfm(graph, initial, truth, K, z)
    graph.add(PriorFactor(key("x", 0), poses[0], Diagonal.sigmas([0.3, 0.3, 0.3, 0.1, 0.1, 0.1])))
    for i, p in enumerate(poses):
        for j in range(points.shape[0]):
            graph.add(ProjectionFactor(key("x", i), key("l", j), z[i, j], pixel, K))
    graph.add(PriorFactor(key("l", 0), points[0], Diagonal.sigmas([0.1, 0.1, 0.1])))
    for i, p in enumerate(poses):
        initial.add(key("x", i), p.retract(pose_noise * rng.normal(size=6)))
    for j, pt in enumerate(points):
        truth.add(key("l", j), pt)
        initial.add(key("l", j), pt + point_noise * rng.normal(size=3))
    return SyntheticSfm(graph, initial, truth, K, z)
