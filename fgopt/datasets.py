"""Synthetic problems for demos, tests and scale benchmarks (no files needed): pose graphs,
bundle adjustment and small SfM scenes.

``manhattan_2d`` walks a robot on a unit grid (Olson et al.'s "Manhattan world"): each step moves
1 m forward, turning by 0 or +-90 degrees at random; revisiting a grid cell already seen adds a
loop closure to one of the earlier poses there. Odometry and loop closures are the true relative
poses perturbed by Gaussian noise of the given sigmas; the initial guess composes the noisy
odometry, so it drifts. ``grid_3d`` does the same in a 3D grid with SE(3) poses. ``sfm_cube`` is
GTSAM's ``SFMExample`` scene (8 cameras around a cube of 8 points), with projection or smart
factors; ``bal_synthetic`` a BAL-convention bundle-adjustment problem of any size.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ._checks import is_count, number
from .errors import FgoptError
from .factors.library.prior_between import BetweenFactor, PriorFactor
from .noise.models import Diagonal
from .graph import FactorGraph
from .key import key
from .manifolds import SE2, SE3, SO3
from .variables import Variables


def _check_count(where: str, name: str, value, minimum: int) -> int:
    if not is_count(value) or value < minimum:
        raise FgoptError(f"{where}: {name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def data_dir() -> Path:
    """The real benchmark data folder: env ``FGOPT_DATA``, else ``../shared/data`` beside the
    repository (it may not exist: callers skip or fall back to the generators below).

    >>> import os, pathlib
    >>> folder = fgopt.datasets.data_dir()          # e.g. folder / "pose2d" / "intel.g2o"
    >>> folder == pathlib.Path(os.environ.get("FGOPT_DATA", folder))
    True
    """
    env = os.environ.get("FGOPT_DATA")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[2] / "shared" / "data"


@dataclass
class SyntheticPoseGraph:
    """A generated pose graph (:func:`manhattan_2d`, :func:`grid_3d`): the factors, a noisy
    initial guess, the ground truth, and how many factors are loop closures.

    >>> s = fgopt.datasets.manhattan_2d(num_poses=50, seed=0)
    >>> len(s.truth) == len(s.initial) == 50, len(s.graph) > 50
    (True, True)
    """

    graph: FactorGraph
    initial: Variables
    truth: Variables
    num_loop_closures: int


def manhattan_2d(num_poses: int = 3500, seed: int = 0, sigmas=(0.01, 0.05, 0.05),
                 loop_probability: float = 0.5, turn_probability: float = 0.3) -> SyntheticPoseGraph:
    """A Manhattan-world 2D pose graph; ``sigmas`` are (theta, x, y), fgopt's tangent order.

    Example:

    >>> s = fgopt.datasets.manhattan_2d(num_poses=100, seed=0)
    >>> len(s.initial), s.num_loop_closures > 0
    (100, True)
    >>> fgopt.optimize(s.graph, s.initial).success
    True
    """
    num_poses = _check_count("manhattan_2d", "num_poses", num_poses, 1)
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
    """A 3D grid-world SE(3) pose graph (random walk on a unit lattice with loop closures).

    Example:

    >>> s = fgopt.datasets.grid_3d(num_poses=27, seed=0)
    >>> len(s.initial), type(s.initial.at(key('x', 0))).__name__
    (27, 'SE3')
    """
    num_poses = _check_count("grid_3d", "num_poses", num_poses, 1)
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
    """A generated structure-from-motion scene (:func:`sfm_cube`): the graph, initial guess,
    truth, the shared calibration and the pixel measurements ``(num_poses, num_points, 2)``.

    >>> scene = fgopt.datasets.sfm_cube()
    >>> type(scene.calibration).__name__, scene.measurements.shape
    ('Cal3_S2', (8, 8, 2))
    """

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

    Example:

    >>> scene = fgopt.datasets.sfm_cube()
    >>> scene.measurements.shape
    (8, 8, 2)
    >>> fgopt.optimize(scene.graph, scene.initial).success
    True
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


@dataclass
class SyntheticBAL:
    """A generated bundle-adjustment problem in BAL's conventions (Snavely cameras):
    :func:`bal_synthetic`. ``read()`` gives ``(graph, initial)``, ``write(path)`` a BAL file.

    >>> ba = fgopt.datasets.bal_synthetic(cameras=3, points=10, observations_per_point=3)
    >>> graph, initial = ba.read()
    >>> len(graph), ba.true_cameras.shape
    (30, (3, 9))
    """

    camera_index: np.ndarray   # (m,) camera of each observation
    point_index: np.ndarray    # (m,) point of each observation
    observations: np.ndarray   # (m, 2) noisy pixel measurements
    cameras: np.ndarray        # (nc, 9) initial guess: angle-axis, t, f, k1, k2
    points: np.ndarray         # (np, 3) initial guess
    true_cameras: np.ndarray
    true_points: np.ndarray

    def write(self, path: str | os.PathLike) -> None:
        """Write the problem (initial guess) as a BAL file (fgopt and Ceres' example read it)."""
        from .io.bal import write_bal_arrays

        write_bal_arrays(path, self.camera_index, self.point_index, self.observations,
                         self.cameras, self.points)

    def read(self):
        """``(graph, initial)`` built like :func:`fgopt.io.read_bal` builds them."""
        import tempfile

        from .io.bal import read_bal

        with tempfile.TemporaryDirectory() as d:
            p = Path(d) / "synthetic.txt"
            self.write(p)
            return read_bal(p)


def bal_synthetic(cameras: int, points: int, observations_per_point: int = 5, seed: int = 0,
                  noise: float = 0.5, focal: float = 500.0) -> SyntheticBAL:
    """A BAL problem of ``cameras`` cameras on a circle of radius 20 looking at its centre and
    ``points`` points in a ball of radius 4 there, each seen by ``observations_per_point``
    cameras that are neighbours on the circle (local visibility, as in a real sequence: the
    reduced camera system is banded, not dense). Pixels get Gaussian ``noise``; the initial
    guess moves every camera by 0.01 rad / 0.05 m and every point by 0.05 m (seeded).

    BAL's camera model: ``P = R(w) X + t``, ``p = -P[:2] / P[2]``, ``uv = f (1 + k1 |p|^2 +
    k2 |p|^4) p`` (cameras look down their -z axis). Fully vectorized: 5M observations in
    seconds.

    Example:

    >>> ba = fgopt.datasets.bal_synthetic(cameras=4, points=20, observations_per_point=3)
    >>> ba.cameras.shape, ba.points.shape, ba.observations.shape
    ((4, 9), (20, 3), (60, 2))
    """
    from scipy.spatial.transform import Rotation

    k = int(observations_per_point)
    if cameras < 2 or points < 1 or not 2 <= k <= cameras:
        raise FgoptError("bal_synthetic: need cameras >= 2, points >= 1, "
                         "2 <= observations_per_point <= cameras")
    rng = np.random.default_rng(seed)
    angle = 2 * np.pi * np.arange(cameras) / cameras
    centre = np.column_stack([20 * np.cos(angle), 20 * np.sin(angle),
                              rng.normal(0, 0.5, cameras)])
    z = centre / np.linalg.norm(centre, axis=1, keepdims=True)  # -z looks at the origin
    x = np.cross(np.array([0.0, 0.0, 1.0]), z)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.cross(z, x)
    R = np.stack([x, y, z], axis=1)  # rows: camera axes in the world (world -> camera)
    w = Rotation.from_matrix(R).as_rotvec()
    t = -np.einsum("nij,nj->ni", R, centre)
    cams = np.column_stack([w, t, np.full(cameras, focal), np.zeros((cameras, 2))])
    u = rng.normal(size=(points, 3))
    pts = 4 * u / np.linalg.norm(u, axis=1, keepdims=True) * rng.random((points, 1)) ** (1 / 3)
    # each point: k neighbouring cameras from the arc facing it
    base = np.floor((np.arctan2(pts[:, 1], pts[:, 0]) % (2 * np.pi)) / (2 * np.pi) * cameras)
    first = (base.astype(np.int64) - k // 2 + rng.integers(-2, 3, points)) % cameras
    ci = ((first[:, None] + np.arange(k)[None, :]) % cameras).reshape(-1)
    pj = np.repeat(np.arange(points, dtype=np.int64), k)
    P = np.einsum("mij,mj->mi", R[ci], pts[pj]) + t[ci]
    uv = -focal * P[:, :2] / P[:, 2:3] + rng.normal(0.0, noise, (ci.shape[0], 2))
    init_cams = cams.copy()
    init_cams[:, :3] = (Rotation.from_rotvec(rng.normal(0, 0.01, (cameras, 3)))
                        * Rotation.from_rotvec(w)).as_rotvec()
    init_cams[:, 3:6] += rng.normal(0, 0.05, (cameras, 3))
    init_pts = pts + rng.normal(0, 0.05, pts.shape)
    return SyntheticBAL(ci, pj, uv, init_cams, init_pts, cams, pts)


#: Chi-square 0.999 quantiles by tangent dimension (a drawn error below it is not gross).
_CHI2_999 = {3: 16.266, 6: 22.458}


def gross_error(rng: np.random.Generator, is3d: bool, sigma_of, max_rotation: float = 0.5,
                max_translation: float = 5.0):
    """A relative-pose error (rotation angle uniform up to ``max_rotation`` rad, about a random
    axis in 3D; translation uniform in ``[-max_translation, max_translation]`` m per axis) whose
    squared whitened norm ``sigma_of(err)`` exceeds the chi-square 0.999 quantile (a draw the
    noise model would call plausible is redrawn).

    >>> rng = np.random.default_rng(0)
    >>> whitened = lambda e: float(np.sum(e.log() ** 2)) / 0.1 ** 2   # sigma 0.1 per axis
    >>> errors = [fgopt.datasets.gross_error(rng, False, whitened) for _ in range(100)]
    >>> min(whitened(e) for e in errors) > 16.27      # chi-square(3) 0.999 quantile: 16.266
    True
    >>> max(abs(e.theta()) for e in errors) <= 0.5
    True
    """
    dim = 6 if is3d else 3
    while True:
        if is3d:
            axis = rng.normal(size=3)
            rot = axis / np.linalg.norm(axis) * rng.uniform(0, max_rotation)
            err = SE3.exp(np.concatenate([rot, rng.uniform(-max_translation, max_translation, 3)]))
        else:
            err = SE2.from_xytheta(*rng.uniform(-max_translation, max_translation, 2),
                                   rng.uniform(-max_rotation, max_rotation))
        if sigma_of(err) > _CHI2_999[dim]:
            return err


def random_loop_closures(graph: FactorGraph, reference: Variables, fraction: float,
                         seed: int = 0, sigma: float = 0.1, max_rotation: float = 0.5,
                         max_translation: float = 5.0) -> tuple[FactorGraph, int]:
    """``graph`` plus ``round(fraction * edges)`` wrong loop closures between random pairs of
    non-consecutive poses of ``reference`` (SE2 or SE3 values): each measures the reference
    relative pose times a :func:`gross_error`, under an isotropic noise of ``sigma`` (m and rad).
    Returns ``(graph, number added)``; the added factors come last.

    >>> s = fgopt.datasets.manhattan_2d(num_poses=50, seed=0)
    >>> clean = fgopt.optimize(s.graph, s.initial)
    >>> bad, n = fgopt.datasets.random_loop_closures(s.graph, clean.values, 0.1)
    >>> n, len(bad) - len(s.graph)
    (5, 5)
    """
    from .noise.models import Isotropic

    if number(fraction) is None or not 0.0 <= fraction < np.inf:
        raise FgoptError(f"random_loop_closures: fraction must be a finite number >= 0, got "
                         f"{fraction!r}")
    rng = np.random.default_rng(seed)
    keys = reference.keys()
    edges = sum(1 for f in graph if len(f.keys) == 2)
    n = int(round(fraction * edges))
    if n and len(keys) < 3:  # two poses have no non-consecutive pair: the draw would not end
        raise FgoptError(f"random_loop_closures: needs at least 3 poses in reference, got "
                         f"{len(keys)}")
    is3d = n > 0 and isinstance(reference.at(keys[0]), SE3)
    dim = 6 if is3d else 3
    noise = Isotropic.sigma(dim, sigma)
    out = FactorGraph(list(graph))
    for _ in range(n):
        while True:
            i, j = (int(x) for x in rng.choice(len(keys), 2, replace=False))
            if abs(i - j) > 1:  # consecutive poses would pass for odometry
                break
        err = gross_error(rng, is3d, lambda e: float(np.sum(e.log() ** 2)) / sigma ** 2,
                          max_rotation, max_translation)
        true = reference.at(keys[i]).between(reference.at(keys[j]))
        out.add(BetweenFactor(keys[i], keys[j], true * err, noise))
    return out, n


#: The public names (each has an entry in the API reference: tests/test_docs_reference.py).
__all__ = ["data_dir", "SyntheticPoseGraph", "manhattan_2d", "grid_3d", "SyntheticSfm", "sfm_cube",
           "SyntheticBAL", "bal_synthetic",
           "gross_error", "random_loop_closures"]
