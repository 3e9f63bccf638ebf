"""Read Bundler ``.out`` files (Snavely's Bundler v0.3) into a graph in GTSAM's camera form.

Format::

    # Bundle file v0.3
    num_cameras num_points
    f k1 k2                      \\
    R (3 lines of 3)              > per camera (world-to-camera, OpenGL: looking down -z)
    t                            /
    x y z                        \\
    r g b                         > per point
    n  cam key u v  cam key u v ... /  (n views; u, v with the image centre as origin, y up)

The graph is built as in :mod:`fgopt.io._sfm` (GTSAM's camera form: SE(3) poses looking down
+z with ``Cal3Bundler`` calibrations, as one PinholeCamera variable per camera or as separate
pose / calibration variables; points ``p<j>``; one batch of projection factors with unit noise),
with GTSAM's ``SfmData::FromBundlerFile`` conventions. Errors name the file and line.
"""

from __future__ import annotations

import os

import numpy as np

from ..errors import FgoptError, FileFormatError
from ..graph import FactorGraph
from ..variables import Variables
from ._scan import scan
from ._sfm import FORMS, gtsam_form_graph


def _is_int(x: np.ndarray) -> np.ndarray:
    return np.isfinite(x) & (x == np.floor(x))


def read_bundler(path: str | os.PathLike, form: str = "camera",
                 data: bytes | None = None) -> tuple[FactorGraph, Variables]:
    """Read a Bundler ``.out`` file; returns ``(graph, initial)``.

    Args:
        form: ``"camera"`` (a PinholeCamera[Cal3Bundler] variable ``c<i>`` per camera),
            ``"pose+calibration"`` (SE3 ``x<i>`` + Cal3Bundler ``k<i>``) or ``"pose"``
            (SE3 ``x<i>``, calibrations fixed); see :mod:`fgopt.io._sfm`.

    Raises:
        FileFormatError: malformed input, a non-rotation R, a non-positive focal length, an
            index out of range, a point seen by fewer than two cameras; the message names the
            file and line.

    Example: two cameras 1 m apart and one point 5 m ahead (Bundler's cameras look down -z;
    pixels from the image centre, y up); the initial values reproduce the pixels:

    >>> import tempfile, pathlib
    >>> path = pathlib.Path(tempfile.mkdtemp()) / 'scene.out'
    >>> identity = "1 0 0\\n0 1 0\\n0 0 1\\n"
    >>> _ = path.write_text("# Bundle file v0.3\\n2 1\\n"
    ...                     "500 0 0\\n" + identity + "0 0 0\\n"          # f k1 k2, R, t
    ...                     "500 0 0\\n" + identity + "-1 0 0\\n"
    ...                     "0 0 -5\\n255 255 255\\n2 0 0 0 0 1 1 -100 0\\n")  # point, colour, views
    >>> graph, initial = fgopt.io.read_bundler(path)
    >>> len(graph), sorted(initial.keys()), graph.error(initial)
    (2, [c0, c1, p0], 0.0)
    """
    if form not in FORMS:
        raise FgoptError(f"read_bundler: form must be one of {FORMS}, got {form!r}")
    p = os.fspath(path)
    sc = scan(p, data=data, has_tag=False, comment="#")
    if sc.line.shape[0] == 0:
        raise FileFormatError("the file is empty; a Bundler file has 'num_cameras num_points' "
                              "after its '# Bundle file' line", p)
    sc.check_values()
    v = sc.values
    if sc.count[0] != 2 or not np.all(_is_int(v[:2])) or v[0] < 1 or v[1] < 0:
        raise sc.error("the header must be two integers 'num_cameras num_points'", sc.line[0])
    nc, npt = int(v[0]), int(v[1])
    cam_end = 2 + 15 * nc
    if v.shape[0] < cam_end:
        raise sc.error(f"expected {nc} cameras of 15 numbers, the file ends first", sc.line[-1])
    sc.check_finite(np.arange(2, cam_end))
    cams = v[2:cam_end].reshape(nc, 15)
    f, R, t = cams[:, 0], cams[:, 3:12].reshape(nc, 3, 3), cams[:, 12:15]
    for i in range(nc):
        where = sc.line_of_value(2 + 15 * i)
        if not f[i] > 0.0:
            raise sc.error(f"camera {i}: focal length {f[i]:g} is not positive (an unregistered "
                           "camera?)", where)
        err = np.abs(R[i] @ R[i].T - np.eye(3)).max()
        if err > 1e-6:
            raise sc.error(f"camera {i}: R is not a rotation matrix (|R R^T - I| = {err:.2g})",
                           sc.line_of_value(2 + 15 * i + 3))
        det = np.linalg.det(R[i])
        if det < 0.0:
            raise sc.error(f"camera {i}: R is a reflection, not a rotation (det(R) = {det:.4g} "
                           "< 0)", sc.line_of_value(2 + 15 * i + 3))
        u, _, vt = np.linalg.svd(R[i])  # re-orthonormalize the 10-digit matrix
        R[i] = u @ vt
    points = np.empty((npt, 3))
    cam_idx, pt_idx, obs_at = [], [], []
    pos = cam_end
    for j in range(npt):
        if pos + 7 > v.shape[0]:
            raise sc.error(f"point {j}: the file ends before its position, color and view count",
                           sc.line[-1])
        points[j] = v[pos:pos + 3]
        n = v[pos + 6]
        if not (_is_int(np.array([n]))[0] and n >= 0):
            raise sc.error(f"point {j}: view count {sc.token(pos + 6)!r} is not a count",
                           sc.line_of_value(pos + 6))
        n = int(n)
        if n < 2:
            # one view leaves the point free along its ray (and none leaves it unused): the
            # solver would report convergence on a rank-deficient problem
            raise sc.error(f"point {j} has {n} view{'' if n == 1 else 's'}; a point needs at "
                           "least two to be constrained", sc.line_of_value(pos + 6))
        start = pos + 7
        if start + 4 * n > v.shape[0]:
            raise sc.error(f"point {j}: {sc.token(pos + 6)} views announced, the file ends first",
                           sc.line[-1])
        cam_idx.append(v[start:start + 4 * n:4])
        pt_idx.append(np.full(n, j))
        obs_at.append(start + 4 * np.arange(n))
        pos = start + 4 * n
    if pos != v.shape[0]:
        raise sc.error(f"unexpected extra number {sc.token(pos)!r} after {npt} points",
                       sc.line_of_value(pos))
    sc.check_finite(np.arange(cam_end, pos))
    obs_at = np.concatenate(obs_at) if obs_at else np.zeros(0, dtype=np.int64)
    ci = np.concatenate(cam_idx) if cam_idx else np.zeros(0)
    bad = ~_is_int(ci) | (ci < 0) | (ci >= nc)
    if np.any(bad):
        k = int(np.nonzero(bad)[0][0])
        raise sc.error(f"camera index {sc.token(int(obs_at[k]))} is out of range (the header "
                       f"says {nc} cameras)", sc.line_of_value(int(obs_at[k])))
    uv = np.column_stack([v[obs_at + 2], v[obs_at + 3]])
    rec = np.maximum(np.searchsorted(sc.first, obs_at, side="right") - 1, 0)
    lines = np.asarray(sc.line[rec], dtype=np.int64)
    intrinsics = cams[:, 0:3]
    return gtsam_form_graph(R, t, intrinsics, ci, np.concatenate(pt_idx) if pt_idx else ci,
                            uv, points, form, (str(p), lines))
