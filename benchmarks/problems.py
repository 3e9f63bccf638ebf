"""Benchmark problems: a registry, library-neutral numpy readers, and the synthetic problem.

Every runner gets the same :class:`PoseGraph` / :class:`BAL` / :class:`RobotLoc` data (plain numpy
arrays) and returns its final estimate in the same layout, so :mod:`benchmarks.yardstick` can
evaluate every library's result with one cost definition.

Conventions
-----------
* ``PoseGraph.poses``: 2D ``(N, 3)`` rows ``x, y, theta``; 3D ``(N, 7)`` rows
  ``x, y, z, qx, qy, qz, qw`` (the g2o vertex layout), in the order of ``PoseGraph.ids``.
* ``PoseGraph.info``: ``(M, d, d)`` information matrices **in GTSAM's tangent order**
  (2D ``x, y, theta`` = g2o order; 3D ``rot, trans``: g2o's ``trans, rot`` blocks swapped, exactly as
  ``gtsam.readG2o`` does). ``info_g2o`` keeps the file's order.
* ``BAL``: cameras ``(C, 9)`` Snavely ``angle-axis, t, f, k1, k2``; points ``(P, 3)``;
  observations ``cam, point, u, v`` as in the file.
* ``RobotLoc``: 2D localization against known landmarks (see :func:`robot_localization`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

REPO_ROOT = Path(__file__).resolve().parent.parent


def data_dir() -> Path:
    """``$FGOPT_DATA``, else ``../shared/data`` relative to the repository root."""
    env = os.environ.get("FGOPT_DATA")
    if env:
        return Path(env).expanduser().resolve()
    return (REPO_ROOT / ".." / "shared" / "data").resolve()


@dataclass(frozen=True)
class ProblemSpec:
    name: str
    kind: str  # "pose2d" | "pose3d" | "bal" | "robot_localization"
    relpath: str | None  # under data_dir(); None for synthetic problems
    label: str
    small: bool = False  # cheap enough for every peer in --quick mode
    note: str = ""

    @property
    def path(self) -> Path | None:
        return None if self.relpath is None else data_dir() / self.relpath


# The benchmark set (BENCHMARKS.md) first, then small files used to verify the runners.
PROBLEMS: dict[str, ProblemSpec] = {p.name: p for p in [
    ProblemSpec("m3500", "pose2d", "pose2d/input_M3500_g2o.g2o", "M3500"),
    ProblemSpec("intel", "pose2d", "pose2d/intel.g2o", "intel"),
    ProblemSpec("sphere2500", "pose3d", "pose3d/sphere2500.g2o", "sphere2500"),
    ProblemSpec("torus3d", "pose3d", "pose3d/torus3D.g2o", "torus3D"),
    ProblemSpec("garage", "pose3d", "pose3d/parking-garage.g2o", "garage"),
    ProblemSpec("cubicle", "pose3d", "pose3d/cubicle.g2o", "cubicle",
                note="5021 of 16869 edges have non-PD information: clipped for all but GTSAM "
                     "(gtsam.readG2o takes them as they are; its Cholesky of an indefinite "
                     "matrix gives a different square root)"),
    ProblemSpec("ladybug", "bal", "bal/problem-49-7776-pre.txt", "Ladybug-49"),
    ProblemSpec("robot_localization", "robot_localization", None, "robot loc. (synthetic)",
                small=True, note="5 poses, 20 known landmarks, bearing-range + odometry, "
                                 "poses start at the origin (SymForce paper Sec. VIII-C, in 2D)"),
    # small files to verify runners
    ProblemSpec("pose2example", "pose2d", "small/pose2example.txt", "pose2example", small=True),
    ProblemSpec("smallgrid3d", "pose3d", "pose3d/smallGrid3D.g2o", "smallGrid3D", small=True),
    ProblemSpec("dubrovnik3", "bal", "bal/dubrovnik-3-7-pre.txt", "Dubrovnik-3-7", small=True),
]}

DEFAULT_DATASETS = ["m3500", "intel", "sphere2500", "torus3d", "garage", "cubicle", "ladybug",
                    "robot_localization"]


# ----------------------------------------------------------------------------------------------
# data containers
# ----------------------------------------------------------------------------------------------
@dataclass
class PoseGraph:
    name: str
    is3d: bool
    ids: np.ndarray  # (N,) vertex ids from the file, sorted
    poses: np.ndarray  # (N, 3) or (N, 7) initial guess
    edge_i: np.ndarray  # (M,) indices into ids
    edge_j: np.ndarray
    meas: np.ndarray  # (M, 3) or (M, 7)
    info_g2o: np.ndarray  # (M, d, d) file order
    path: Path | None = None
    repaired: int = 0  # number of information matrices clipped to PD
    kind: str = field(init=False)

    def __post_init__(self):
        self.kind = "pose3d" if self.is3d else "pose2d"

    @property
    def dim(self) -> int:
        return 6 if self.is3d else 3

    @property
    def info(self) -> np.ndarray:
        """Information in GTSAM's tangent order (3D: rotation block first)."""
        if not self.is3d:
            return self.info_g2o
        p = np.array([3, 4, 5, 0, 1, 2])
        return self.info_g2o[:, p][:, :, p]

    def sqrt_info(self, order: str = "gtsam") -> np.ndarray:
        """Upper-triangular ``R`` with ``R^T R = info`` (``order``: "gtsam" or "g2o")."""
        info = self.info if order == "gtsam" else self.info_g2o
        L = np.linalg.cholesky(info)
        return np.swapaxes(L, 1, 2)

    def __repr__(self):
        return (f"PoseGraph({self.name}: {'3D' if self.is3d else '2D'}, {len(self.ids)} poses, "
                f"{len(self.edge_i)} edges)")


@dataclass
class BAL:
    name: str
    cameras: np.ndarray  # (C, 9)
    points: np.ndarray  # (P, 3)
    cam_idx: np.ndarray  # (O,)
    pt_idx: np.ndarray  # (O,)
    obs: np.ndarray  # (O, 2)
    path: Path | None = None
    kind: str = "bal"

    def __repr__(self):
        return (f"BAL({self.name}: {len(self.cameras)} cameras, {len(self.points)} points, "
                f"{len(self.obs)} observations)")


@dataclass
class RobotLoc:
    """2D robot localization: poses ``(N, 3)`` to estimate, landmarks ``(L, 2)`` known.

    ``br_pose``/``br_lm`` index the bearing-range measurements ``br_meas`` (bearing, range), noise
    ``br_sigmas``; odometry ``odom_meas[k]`` is ``pose_k^-1 * pose_{k+1}`` as ``x, y, theta`` with
    ``odom_sigmas``. No prior: the known landmarks fix the gauge.
    """
    name: str
    poses: np.ndarray  # initial guess (N, 3): all at the origin
    truth: np.ndarray  # ground truth (N, 3)
    landmarks: np.ndarray  # (L, 2)
    br_pose: np.ndarray
    br_lm: np.ndarray
    br_meas: np.ndarray  # (K, 2)
    br_sigmas: np.ndarray  # (2,)
    odom_meas: np.ndarray  # (N-1, 3)
    odom_sigmas: np.ndarray  # (3,)
    kind: str = "robot_localization"
    path: Path | None = None

    def __repr__(self):
        return (f"RobotLoc({len(self.poses)} poses, {len(self.landmarks)} landmarks, "
                f"{len(self.br_meas)} bearing-range, {len(self.odom_meas)} odometry)")


# ----------------------------------------------------------------------------------------------
# readers (pure numpy/python: the common ground truth of what the file says)
# ----------------------------------------------------------------------------------------------
def _sym_from_upper(vals: np.ndarray, d: int) -> np.ndarray:
    """(M, d(d+1)/2) row-major upper-triangular entries -> (M, d, d) symmetric."""
    iu = np.triu_indices(d)
    out = np.zeros((vals.shape[0], d, d))
    out[:, iu[0], iu[1]] = vals
    out[:, iu[1], iu[0]] = vals
    return out


def clip_information(info: np.ndarray, rel_floor: float = 1e-6) -> tuple[np.ndarray, int]:
    """Make information matrices positive definite by clipping eigenvalues.

    Eigenvalues below ``rel_floor * max(eigenvalue)`` are raised to it (symmetric eigen-
    decomposition, ``V diag(max(lam, floor)) V^T``). Returns ``(info, n_repaired)``; PD matrices
    are returned unchanged.
    """
    lam, V = np.linalg.eigh(info)
    floor = rel_floor * np.maximum(lam[:, -1:], 0.0)
    bad = lam[:, 0] <= floor[:, 0]
    if not bad.any():
        return info, 0
    out = info.copy()
    lam_c = np.maximum(lam[bad], floor[bad])
    Vb = V[bad]
    out[bad] = np.einsum("mij,mj,mkj->mik", Vb, lam_c, Vb)
    out[bad] = 0.5 * (out[bad] + np.swapaxes(out[bad], 1, 2))
    return out, int(bad.sum())


def read_g2o(path: str | os.PathLike, name: str | None = None) -> PoseGraph:
    """g2o 2D (VERTEX_SE2/EDGE_SE2) or 3D (VERTEX_SE3:QUAT/EDGE_SE3:QUAT) file -> PoseGraph."""
    path = Path(path)
    vids, vrows, erows = [], [], []
    is3d = None
    with open(path) as fh:
        for line in fh:
            t = line.split()
            if not t:
                continue
            tag = t[0]
            if tag == "VERTEX_SE2" or tag == "VERTEX_SE3:QUAT":
                vids.append(int(t[1]))
                vrows.append(t[2:])
                is3d = tag == "VERTEX_SE3:QUAT"
            elif tag == "EDGE_SE2" or tag == "EDGE_SE3:QUAT":
                erows.append(t[1:])
                is3d = tag == "EDGE_SE3:QUAT"
    if is3d is None:
        raise ValueError(f"{path}: no g2o SE2/SE3:QUAT vertices or edges")
    d = 6 if is3d else 3
    nm = 7 if is3d else 3
    E = np.array(erows, dtype=float)
    ei = E[:, 0].astype(np.int64)
    ej = E[:, 1].astype(np.int64)
    meas = E[:, 2:2 + nm].copy()
    info = _sym_from_upper(E[:, 2 + nm:], d)
    if vids:
        ids = np.array(vids, dtype=np.int64)
        V = np.array(vrows, dtype=float)
        order = np.argsort(ids, kind="stable")
        ids, V = ids[order], V[order]
    else:
        raise ValueError(f"{path}: no VERTEX lines (no initial guess)")
    pos = np.searchsorted(ids, ei), np.searchsorted(ids, ej)
    if is3d:
        # normalize quaternions (files carry rounded values)
        V[:, 3:7] /= np.linalg.norm(V[:, 3:7], axis=1, keepdims=True)
        meas[:, 3:7] /= np.linalg.norm(meas[:, 3:7], axis=1, keepdims=True)
    info, nrep = clip_information(info)
    return PoseGraph(name or path.stem, is3d, ids, V, pos[0], pos[1], meas, info, path, nrep)


def read_bal(path: str | os.PathLike, name: str | None = None) -> BAL:
    path = Path(path)
    with open(path) as fh:
        nc, npnt, nobs = (int(x) for x in fh.readline().split())
        tok = np.array(fh.read().split(), dtype=float)
    O = tok[:4 * nobs].reshape(nobs, 4)
    params = tok[4 * nobs:]
    cams = params[:9 * nc].reshape(nc, 9).copy()
    pts = params[9 * nc:9 * nc + 3 * npnt].reshape(npnt, 3).copy()
    return BAL(name or path.stem, cams, pts, O[:, 0].astype(np.int64), O[:, 1].astype(np.int64),
               O[:, 2:4].copy(), path)


def robot_localization(num_poses: int = 5, num_landmarks: int = 20, seed: int = 0) -> RobotLoc:
    """Synthetic 2D localization like the SymForce paper's Sec. VIII-C example.

    The robot drives an arc; 20 landmarks at known positions; every pose measures bearing and
    range to every landmark, plus odometry between consecutive poses; all with Gaussian noise.
    The poses start at the origin. Deterministic for a given seed.
    """
    rng = np.random.default_rng(seed)
    k = np.arange(num_poses)
    theta = 0.35 * k
    truth = np.stack([3.0 * np.sin(theta), 3.0 * (1 - np.cos(theta)), theta], axis=1)
    landmarks = rng.uniform(-10.0, 10.0, size=(num_landmarks, 2))
    br_sigmas = np.array([0.05, 0.1])
    odom_sigmas = np.array([0.05, 0.05, 0.02])
    bp, bl = np.meshgrid(k, np.arange(num_landmarks), indexing="ij")
    bp, bl = bp.ravel(), bl.ravel()
    d = landmarks[bl] - truth[bp, :2]
    c, s = np.cos(truth[bp, 2]), np.sin(truth[bp, 2])
    local = np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], axis=1)
    bearing = np.arctan2(local[:, 1], local[:, 0])
    rng_ = np.linalg.norm(local, axis=1)
    br = np.stack([bearing, rng_], axis=1) + rng.normal(size=(len(bp), 2)) * br_sigmas
    br[:, 0] = np.arctan2(np.sin(br[:, 0]), np.cos(br[:, 0]))
    a, b = truth[:-1], truth[1:]
    dd = b[:, :2] - a[:, :2]
    ca, sa = np.cos(a[:, 2]), np.sin(a[:, 2])
    odom = np.stack([ca * dd[:, 0] + sa * dd[:, 1], -sa * dd[:, 0] + ca * dd[:, 1],
                     b[:, 2] - a[:, 2]], axis=1) + rng.normal(size=(num_poses - 1, 3)) * odom_sigmas
    return RobotLoc("robot_localization", np.zeros((num_poses, 3)), truth, landmarks, bp, bl, br,
                    br_sigmas, odom, odom_sigmas)


def load(name: str):
    """Problem name -> PoseGraph | BAL | RobotLoc."""
    spec = PROBLEMS[name]
    if spec.kind == "robot_localization":
        return robot_localization()
    if spec.kind == "bal":
        return read_bal(spec.path, name)
    return read_g2o(spec.path, name)
