"""Read GTSAM's stereo visual-odometry example files (``StereoVOExample_large``).

Three text files:

* calibration: ``fx fy s u0 v0 b`` (a :class:`~fgopt.cameras.Cal3_S2Stereo`);
* poses: ``id`` then the 4x4 ``world_T_camera`` matrix row-major, one line per camera;
* factors: ``pose_id landmark_id uL uR v X Y Z`` per stereo observation, ``(X, Y, Z)`` the
  landmark in that camera's frame (triangulated by the data's producer).

As GTSAM's example: poses ``x<id>``, landmarks ``l<id>`` initialized from their first observation
(``world_T_camera * (X, Y, Z)``), one :class:`~fgopt.cameras.StereoFactor` per observation with
isotropic noise ``sigma`` (1 pixel), and the first pose held: GTSAM uses a
``NonlinearEquality``; fgopt has no constant variables, so ``anchor_sigma`` adds a prior that
tight (1e-6 rad / m by default; ``None`` adds none). Pose matrices with 6-digit rotation blocks
are re-orthonormalized (nearest rotation). Errors name the file and line.
"""

from __future__ import annotations

import os

import numpy as np

from ..cameras import Cal3_S2Stereo
from ..cameras.factors import stereo_kernel
from .._checks import is_positive
from ..errors import CalibrationError, FgoptError, FileFormatError
from ..factors import PriorFactor
from ..graph import FactorGraph
from ..key import key
from ..manifolds import SE3, SO3
from ..manifolds.base import vector_kind
from ..noise import Isotropic
from ..variables import Variables
from ._scan import scan


def _rows(path: str, width: int, what: str) -> tuple[np.ndarray, np.ndarray]:
    sc = scan(path, has_tag=False, comment="#")
    sc.check_values()
    bad = np.nonzero(sc.count != width)[0]
    if bad.shape[0] > 0:
        r = int(bad[0])
        raise sc.error(f"{what} lines need {width} numbers, found {sc.count[r]}", sc.line[r])
    sc.check_finite(np.arange(sc.values.shape[0]))
    return sc.values.reshape(-1, width), np.asarray(sc.line)


def _not_rigid(M: np.ndarray) -> str:
    """What makes the 4x4 ``M`` not ``[[R, t], [0, 0, 0, 1]]`` with ``R`` a rotation; ''."""
    if np.abs(M[3] - [0, 0, 0, 1]).max() > 0:
        return f"its bottom row is {M[3].tolist()}, not [0, 0, 0, 1]"
    R = M[:3, :3]
    err = np.abs(R @ R.T - np.eye(3)).max()
    if err > 1e-4:
        return f"its rotation block is not orthonormal (|R R^T - I| = {err:.2g})"
    det = np.linalg.det(R)
    if det <= 0:
        return f"its rotation block is a reflection (det(R) = {det:.4g} <= 0)"
    return ""


def read_stereo_vo(calibration: str | os.PathLike, poses: str | os.PathLike,
                   factors: str | os.PathLike, sigma: float = 1.0,
                   anchor_sigma: float | None = 1e-6
                   ) -> tuple[FactorGraph, Variables, Cal3_S2Stereo]:
    """Read the three files; returns ``(graph, initial, calibration)`` (module docstring).

    ``sigma`` (pixels) and ``anchor_sigma`` must be finite and > 0 (``anchor_sigma`` may be
    ``None``).

    Example: two poses 1 m apart and one landmark 2 m ahead (its ``(X, Y, Z)`` in each
    camera's frame):

    >>> import tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> _ = (d / 'calib.txt').write_text('500 500 0 320 240 0.2\\n')      # fx fy s u0 v0 b
    >>> _ = (d / 'poses.txt').write_text('0 1 0 0 0  0 1 0 0  0 0 1 0  0 0 0 1\\n'
    ...                                  '1 1 0 0 1  0 1 0 0  0 0 1 0  0 0 0 1\\n')
    >>> _ = (d / 'factors.txt').write_text('0 7 370 320 140 0.2 -0.4 2.0\\n'
    ...                                    '1 7 120 70 140 -0.8 -0.4 2.0\\n')
    >>> graph, initial, K = fgopt.io.read_stereo_vo(d / 'calib.txt', d / 'poses.txt',
    ...                                             d / 'factors.txt')
    >>> len(graph), sorted(initial.keys()), K.baseline()     # 2 stereo factors + the anchor
    (3, [l7, x0, x1], 0.2)
    >>> np.round(initial.at(key('l', 7)), 6), graph.error(initial)
    (array([ 0.2, -0.4,  2. ]), 0.0)
    """
    if not is_positive(sigma):
        raise FgoptError(f"read_stereo_vo: sigma must be a finite number of pixels > 0, got "
                         f"{sigma!r}")
    if anchor_sigma is not None and not is_positive(anchor_sigma):
        raise FgoptError(f"read_stereo_vo: anchor_sigma must be a finite number > 0 or None, "
                         f"got {anchor_sigma!r}")
    cal_p, pose_p, fac_p = (os.fspath(p) for p in (calibration, poses, factors))
    c, c_lines = _rows(cal_p, 6, "the calibration")
    if c.shape[0] != 1:
        raise FileFormatError("expected one line 'fx fy s u0 v0 b'", cal_p,
                              int(c_lines[1]) if c.shape[0] > 1 else None)
    try:
        K = Cal3_S2Stereo(*c[0])
    except CalibrationError as exc:
        raise FileFormatError(str(exc), cal_p, int(c_lines[0])) from None
    P, p_lines = _rows(pose_p, 17, "pose")
    values = Variables()
    first = None
    for row, line in zip(P, p_lines):
        if row[0] != np.floor(row[0]) or row[0] < 0:
            raise FileFormatError(f"pose id {row[0]:g} is not a non-negative integer", pose_p,
                                  int(line))
        M = row[1:].reshape(4, 4)
        why = _not_rigid(M)
        if why:
            raise FileFormatError(f"pose {int(row[0])} is not a rigid transform: {why}", pose_p,
                                  int(line))
        u, _, vt = np.linalg.svd(M[:3, :3])
        pose = SE3(SO3.from_matrix(u @ vt), M[:3, 3])
        k = key("x", int(row[0]))
        if k in values:
            raise FileFormatError(f"pose id {int(row[0])} appears twice", pose_p, int(line))
        values.add(k, pose)
        first = (k, pose) if first is None else first
    F, f_lines = _rows(fac_p, 8, "stereo factor")
    ids = F[:, :2]
    if np.any(ids != np.floor(ids)) or np.any(ids < 0):
        r = int(np.nonzero(np.any((ids != np.floor(ids)) | (ids < 0), axis=1))[0][0])
        raise FileFormatError("pose and landmark ids must be non-negative integers", fac_p,
                              int(f_lines[r]))
    xk = np.array([key("x", int(i)) for i in F[:, 0]], dtype=np.int64)
    lk = np.array([key("l", int(j)) for j in F[:, 1]], dtype=np.int64)
    for r in range(F.shape[0]):
        if xk[r] not in values:
            raise FileFormatError(f"pose {int(F[r, 0])} has no line in {pose_p}", fac_p,
                                  int(f_lines[r]))
    _, first_obs = np.unique(lk, return_index=True)
    landmarks = np.array([values.at(int(xk[r])) * F[r, 5:8] for r in first_obs])
    values.add_rows(lk[first_obs], vector_kind(3), landmarks)
    graph = FactorGraph()
    consts = np.column_stack([F[:, 2:5], np.tile(K.to_storage(), (F.shape[0], 1))])
    R = np.eye(3) / float(sigma)
    graph.add_batch(stereo_kernel(False, "reject"), np.column_stack([xk, lk]), consts,
                    None if sigma == 1.0 else np.broadcast_to(R, (F.shape[0], 3, 3)).copy(),
                    origin=(fac_p, f_lines.astype(np.int64)))
    if anchor_sigma is not None and first is not None:
        graph.add(PriorFactor(first[0], first[1], Isotropic.sigma(6, anchor_sigma)))
    return graph, values, K
