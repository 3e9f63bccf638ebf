"""Synthetic pose graphs for demos and tests (no files needed).

``manhattan_2d`` walks a robot on a unit grid (Olson et al.'s "Manhattan world"): each step moves
1 m forward, turning by 0 or +-90 degrees at random; revisiting a grid cell already seen adds a
loop closure to one of the earlier poses there. Odometry and loop closures are the true relative
poses perturbed by Gaussian noise of the given sigmas; the initial guess composes the noisy
odometry, so it drifts. ``grid_3d`` does the same in a 3D grid with SE(3) poses.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .factors.library.prior_between import BetweenFactor, PriorFactor
from .noise.models import Diagonal
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
