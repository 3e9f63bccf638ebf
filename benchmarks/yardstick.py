"""One cost definition for every library's estimate: vectorized numpy, no gtsam needed.

``cost = 0.5 * sum_i e_i^T Lambda_i e_i`` over the problem's own measurements only (no gauge prior),
with the residuals GTSAM uses, so for pose graphs it equals ``gtsam`` ``graph.error`` over the
file's edges (checked in ``benchmarks/tests/test_yardstick.py``):

* Pose2 ``BetweenFactor``: ``e = Logmap(z^-1 p_i^-1 p_j)`` (the gtsam 4.3 wheel's Pose2 chart is the
  SE(2) logarithm; ``chart="xyt"`` gives the plain ``x, y, theta`` of the relative pose instead).
* Pose3 ``BetweenFactor``: ``e = Logmap(z^-1 p_i^-1 p_j)`` = ``[omega, V(omega)^-1 t]`` (GTSAM
  wheels are built with ``GTSAM_POSE3_EXPMAP``), information in ``rot, trans`` order.
* BAL: the Snavely model (``P = R(aa) X + t``, ``p = -P_xy / P_z``, ``f (1 + k1 r^2 + k2 r^4) p``
  minus the observation), unit noise, **every** observation counted (also points behind the
  camera, which GTSAM's factor silently zeroes).
* Robot localization: bearing (wrapped angle difference) and range, plus Pose2 odometry (Log).
"""

from __future__ import annotations

import numpy as np

from .problems import BAL, PoseGraph, RobotLoc


# ----------------------------------------------------------------------------------------------
# small vectorized Lie-group helpers
# ----------------------------------------------------------------------------------------------
def wrap(a):
    return np.arctan2(np.sin(a), np.cos(a))


def pose2_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rows ``x, y, theta``: ``a^-1 b``."""
    d = b[:, :2] - a[:, :2]
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    return np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1],
                     wrap(b[:, 2] - a[:, 2])], axis=1)


def pose2_logmap(p: np.ndarray) -> np.ndarray:
    """SE(2) logarithm ``[v, w]``: ``v = V(w)^-1 t`` with ``V^-1 = [[a, h], [-h, a]]``,
    ``h = w/2``, ``a = h cot h``."""
    w = wrap(p[:, 2])
    h = 0.5 * w
    small = np.abs(h) < 1e-8
    hs = np.where(small, 1.0, h)
    a = np.where(small, 1.0 - h * h / 3.0, hs / np.tan(hs))
    x, y = p[:, 0], p[:, 1]
    return np.stack([a * x + h * y, -h * x + a * y, w], axis=1)


def quat_mul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product of ``(..., 4)`` quaternions stored ``x, y, z, w``."""
    pv, pw = p[..., :3], p[..., 3:4]
    qv, qw = q[..., :3], q[..., 3:4]
    v = pw * qv + qw * pv + np.cross(pv, qv)
    w = pw * qw - np.sum(pv * qv, axis=-1, keepdims=True)
    return np.concatenate([v, w], axis=-1)


def quat_conj(q: np.ndarray) -> np.ndarray:
    return np.concatenate([-q[..., :3], q[..., 3:4]], axis=-1)


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate ``v`` by unit quaternions ``q`` (``x, y, z, w``)."""
    u, w = q[..., :3], q[..., 3:4]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def quat_to_rotvec(q: np.ndarray) -> np.ndarray:
    """Unit quaternion (``x, y, z, w``) -> rotation vector, angle in ``[0, pi]``."""
    q = np.where(q[..., 3:4] < 0, -q, q)
    v, w = q[..., :3], q[..., 3]
    n = np.linalg.norm(v, axis=-1)
    small = n < 1e-8
    ang = 2.0 * np.arctan2(n, w)
    ws = np.where(small, w, 1.0)  # w ~ 1 where small
    scale = np.where(small, 2.0 / ws * (1.0 - n * n / (3.0 * ws * ws)), ang / np.where(small, 1.0, n))
    return v * scale[..., None]


def rotvec_to_quat(r: np.ndarray) -> np.ndarray:
    th = np.linalg.norm(r, axis=-1)
    h = 0.5 * th
    small = th < 1e-8
    s = np.where(small, 0.5 - th * th / 48.0, np.sin(h) / np.where(small, 1.0, th))
    return np.concatenate([r * s[..., None], np.cos(h)[..., None]], axis=-1)


def so3_vinv(w: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``V(w)^-1 t``: ``t - 0.5 w x t + c (w x (w x t))``, ``c = (1 - th/2 cot(th/2)) / th^2``."""
    th2 = np.sum(w * w, axis=-1)
    th = np.sqrt(th2)
    small = th < 1e-4
    ths = np.where(small, 1.0, th)
    c = np.where(small, 1.0 / 12.0 + th2 / 720.0,
                 (1.0 - 0.5 * ths / np.tan(0.5 * ths)) / (ths * ths))
    wt = np.cross(w, t)
    return t - 0.5 * wt + c[..., None] * np.cross(w, wt)


def pose3_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rows ``x, y, z, qx, qy, qz, qw``: ``a^-1 b``."""
    qa_inv = quat_conj(a[:, 3:7])
    t = quat_rotate(qa_inv, b[:, :3] - a[:, :3])
    q = quat_mul(qa_inv, b[:, 3:7])
    return np.concatenate([t, q], axis=1)


def pose3_logmap(p: np.ndarray) -> np.ndarray:
    """SE(3) logarithm ``[omega, V(omega)^-1 t]`` (GTSAM's ``Pose3::Logmap`` order)."""
    q = p[:, 3:7] / np.linalg.norm(p[:, 3:7], axis=1, keepdims=True)
    w = quat_to_rotvec(q)
    return np.concatenate([w, so3_vinv(w, p[:, :3])], axis=1)


# ----------------------------------------------------------------------------------------------
# residuals and costs
# ----------------------------------------------------------------------------------------------
def pose_graph_residuals(g: PoseGraph, poses: np.ndarray, chart: str = "log") -> np.ndarray:
    """Unwhitened errors ``(M, d)`` in GTSAM's tangent order."""
    poses = np.asarray(poses, dtype=float)
    a, b = poses[g.edge_i], poses[g.edge_j]
    if g.is3d:
        d = pose3_between(g.meas, pose3_between(a, b))
        return pose3_logmap(d)
    d = pose2_between(g.meas, pose2_between(a, b))
    return d if chart == "xyt" else pose2_logmap(d)


def pose_graph_cost(g: PoseGraph, poses: np.ndarray, chart: str = "log") -> float:
    e = pose_graph_residuals(g, poses, chart)
    return float(0.5 * np.einsum("mi,mij,mj->", e, g.info, e))


def angle_axis_rotate(aa: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Rodrigues: rotate rows of X by rows of angle-axis aa (as Ceres' AngleAxisRotatePoint)."""
    th2 = np.sum(aa * aa, axis=1)
    th = np.sqrt(th2)
    small = th2 < 1e-24
    ths = np.where(small, 1.0, th)
    k = aa / ths[:, None]
    c, s = np.cos(th), np.sin(th)
    kx = np.cross(k, X)
    rot = X * c[:, None] + kx * s[:, None] + k * (np.sum(k * X, axis=1) * (1 - c))[:, None]
    approx = X + np.cross(aa, X)
    return np.where(small[:, None], approx, rot)


def bal_residuals(p: BAL, cameras: np.ndarray, points: np.ndarray) -> np.ndarray:
    cam = np.asarray(cameras, dtype=float)[p.cam_idx]
    X = np.asarray(points, dtype=float)[p.pt_idx]
    P = angle_axis_rotate(cam[:, 0:3], X) + cam[:, 3:6]
    xp = -P[:, :2] / P[:, 2:3]
    r2 = np.sum(xp * xp, axis=1)
    dist = 1.0 + r2 * (cam[:, 7] + cam[:, 8] * r2)
    return cam[:, 6:7] * dist[:, None] * xp - p.obs


def bal_cost(p: BAL, cameras: np.ndarray, points: np.ndarray) -> float:
    r = bal_residuals(p, cameras, points)
    return float(0.5 * np.sum(r * r))


def robot_residuals(p: RobotLoc, poses: np.ndarray) -> np.ndarray:
    poses = np.asarray(poses, dtype=float)
    x = poses[p.br_pose]
    d = p.landmarks[p.br_lm] - x[:, :2]
    c, s = np.cos(x[:, 2]), np.sin(x[:, 2])
    lx, ly = c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]
    eb = wrap(np.arctan2(ly, lx) - p.br_meas[:, 0]) / p.br_sigmas[0]
    er = (np.hypot(lx, ly) - p.br_meas[:, 1]) / p.br_sigmas[1]
    odo = pose2_logmap(pose2_between(p.odom_meas, pose2_between(poses[:-1], poses[1:])))
    odo = odo / p.odom_sigmas
    return np.concatenate([eb, er, odo.ravel()])


def robot_cost(p: RobotLoc, poses: np.ndarray) -> float:
    r = robot_residuals(p, poses)
    return float(0.5 * np.sum(r * r))


def cost(problem, estimate: dict) -> float:
    """Yardstick cost of an estimate dict (``poses`` or ``cameras`` + ``points``)."""
    if isinstance(problem, PoseGraph):
        return pose_graph_cost(problem, estimate["poses"])
    if isinstance(problem, BAL):
        return bal_cost(problem, estimate["cameras"], estimate["points"])
    if isinstance(problem, RobotLoc):
        return robot_cost(problem, estimate["poses"])
    raise TypeError(type(problem))


def initial_estimate(problem) -> dict:
    if isinstance(problem, BAL):
        return {"cameras": problem.cameras, "points": problem.points}
    return {"poses": problem.poses}
