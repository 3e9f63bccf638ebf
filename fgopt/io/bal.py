"""Read and write Bundle Adjustment in the Large (BAL) problems.

Format (Agarwal, Snavely, Seitz, Szeliski, ECCV 2010)::

    num_cameras num_points num_observations
    camera_index point_index x y          (num_observations lines)
    9 numbers per camera: angle-axis r (3), t (3), f, k1, k2
    3 numbers per point

Parameters may be split over lines in any way (one per line in the original files; GTSAM's
copies add blank lines between sections). ``.bz2`` and ``.gz`` files are decompressed.

The graph holds one batch of reprojection factors with unit noise, so its cost is the standard
BAL cost ``0.5 * sum |e|^2`` in pixels; cameras are ``key('c', i)`` (R^9 vectors), points
``key('p', j)`` (R^3). Parsing is one vectorized pass (:mod:`fgopt.io._scan`).
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from ..errors import FgoptError, FileFormatError
from ..graph import FactorGraph
from ..key import key, key_str
from ..manifolds.base import vector_kind
from ..variables import Variables
from ._files import write_text
from ._scan import scan
from ._sfm import FORMS as _GTSAM_FORMS
from ._sfm import gtsam_form_graph, rotations_from_angle_axis

FORMS = ("snavely",) + _GTSAM_FORMS


def reprojection_kernel():
    """The kernel used for BAL observations: args ``(camera R^9, point R^3)``, constants ``m``.

    The generated kernel of the symbolic ``bal_reprojection`` factor
    (:mod:`fgopt.factors.library.reprojection`, ``camera`` and ``point`` variable) when the
    symbolic package is available, else the hand-written numba kernel of
    :mod:`fgopt.factors.library.bal_kernel` (the two agree to rounding; see the tests).

    Example: a camera at the origin (BAL cameras look down -z) with ``f = 500``; the residual
    is predicted minus measured pixels:

    >>> kernel = fgopt.io.reprojection_kernel()
    >>> [kind.name for kind in kernel.arg_kinds], kernel.residual_dim
    (['R9', 'R3'], 2)
    >>> camera = np.array([[0, 0, 0, 0, 0, 0, 500.0, 0, 0]])      # r, t, f, k1, k2
    >>> res, jac = kernel.linearize((camera, np.array([[0.1, -0.2, -1.0]])), np.array([[50.0, -99.0]]))
    >>> np.round(res, 6) + 0.0, jac.shape                          # (50, -100) predicted
    (array([[ 0., -1.]]), (1, 2, 12))
    """
    try:
        from ..factors.library.reprojection import bal_reprojection
    except ImportError:
        from ..factors.library.bal_kernel import bal_kernel

        return bal_kernel()
    return bal_reprojection.kernel(["camera", "point"])


def _is_bal_kernel(kernel: Any) -> bool:
    from ..factors.library.bal_kernel import bal_kernel

    return kernel is bal_kernel() or kernel is reprojection_kernel()


def read_bal(path: str | os.PathLike, data: bytes | None = None,
             form: str = "snavely", progress: bool = True) -> tuple[FactorGraph, Variables]:
    """Read a BAL file; returns ``(graph, initial)`` (see the module docstring).

    ``progress``: a progress bar on stderr when reading takes over a second (tqdm).
    ``form="snavely"`` (default) gives R^9 cameras ``c<i>``. GTSAM's camera form, same cost
    (see :mod:`fgopt.io._sfm`): ``"camera"`` (a PinholeCamera[Cal3Bundler] variable ``c<i>``:
    SE(3) pose looking down +z and Cal3Bundler), ``"pose+calibration"`` (SE3 ``x<i>`` and
    Cal3Bundler ``k<i>`` variables) or ``"pose"`` (SE3 ``x<i>``, calibrations fixed).

    Raises:
        FileFormatError: malformed input; the message names the file and line.

    Example:

    >>> import tempfile, pathlib
    >>> ba = fgopt.datasets.bal_synthetic(cameras=3, points=10, observations_per_point=2)
    >>> path = pathlib.Path(tempfile.mkdtemp()) / 'ba.txt'
    >>> ba.write(path)
    >>> graph, initial = fgopt.io.read_bal(path)
    >>> len(graph), len(initial)
    (20, 13)
    """
    if form not in FORMS:
        raise FgoptError(f"read_bal: form must be one of {FORMS}, got {form!r}")
    p = os.fspath(path)
    sc = scan(p, data=data, has_tag=False, comment=None, progress=progress)
    nrec = sc.line.shape[0]
    if nrec == 0:
        raise FileFormatError("the file is empty; a BAL file starts with 'num_cameras "
                              "num_points num_observations'", p)
    if sc.count[0] != 3:
        raise sc.error(f"the BAL header needs 3 numbers (cameras, points, observations), found "
                       f"{sc.count[0]}", sc.line[0])
    sc.check_values()
    header = sc.values[:3]
    if not (np.all(np.isfinite(header)) and np.all(header == np.floor(header))
            and header[0] >= 1 and header[1] >= 1 and header[2] >= 1 and header.max() < 2 ** 40):
        raise sc.error("the BAL header must be three positive integers (cameras, points, "
                       f"observations), found {' '.join(sc.token(i) for i in range(3))}",
                       sc.line[0])
    nc, npt, nobs = (int(x) for x in header)
    obs_rec = slice(1, min(1 + nobs, nrec))  # records (lines) of the observations
    if nrec - 1 < nobs:
        raise sc.error(f"the header announces {nobs} observations, the file has "
                       f"{nrec - 1} more lines", sc.line[-1])
    short = np.flatnonzero(sc.count[obs_rec] != 4)
    if short.shape[0] > 0:
        r = 1 + int(short[0])
        raise sc.error(f"observation {r - 1} needs 4 numbers (camera point x y), found "
                       f"{sc.count[r]}", sc.line[r])
    obs = sc.values[3:3 + 4 * nobs].reshape(nobs, 4)
    obs_lines = sc.line[obs_rec]
    sc.check_finite(slice(3, 3 + 4 * nobs))
    ci, pj = obs[:, 0], obs[:, 1]
    for what, idx, limit in (("camera", ci, nc), ("point", pj, npt)):
        bad = (idx != np.floor(idx)) | (idx < 0) | (idx >= limit)
        if bad.any():
            r = int(np.nonzero(bad)[0][0])
            raise sc.error(f"{what} index {sc.token(3 + 4 * r + (0 if what == 'camera' else 1))}"
                           f" is out of range (the header says {limit} {what}s)", obs_lines[r])
    start = 3 + 4 * nobs
    need = 9 * nc + 3 * npt
    have = sc.values.shape[0] - start
    if have < need:
        raise sc.error(f"expected {need} camera and point parameters after the observations "
                       f"(9 x {nc} + 3 x {npt}), found {have}", sc.line[-1])
    if have > need:
        raise sc.error(f"unexpected extra number {sc.token(start + need)!r} after the "
                       f"{need} camera and point parameters", sc.line_of_value(start + need))
    sc.check_finite(slice(start, start + need))
    cams = sc.values[start:start + 9 * nc].reshape(nc, 9)
    pts = sc.values[start + 9 * nc:].reshape(npt, 3)
    # every form: a non-positive focal length is a broken camera (the 9-vector kernel would
    # optimize it all the same, to a mirrored or degenerate projection)
    bad = ~(cams[:, 6] > 0.0)
    if np.any(bad):
        i = int(np.nonzero(bad)[0][0])
        raise sc.error(f"camera {i}: focal length {cams[i, 6]:g} is not positive",
                       sc.line_of_value(start + 9 * i + 6))
    if form != "snavely":
        return gtsam_form_graph(rotations_from_angle_axis(cams[:, :3]), cams[:, 3:6],
                                cams[:, 6:9], ci, pj, obs[:, 2:4], pts, form,
                                (str(p), _compact_lines(obs_lines)))
    cb, pb = int(key("c", 0)), int(key("p", 0))
    values = Variables()
    values.add_rows(np.arange(cb, cb + nc, dtype=np.int64), vector_kind(9), cams)
    values.add_rows(np.arange(pb, pb + npt, dtype=np.int64), vector_kind(3), pts)
    graph = FactorGraph()
    keys = np.column_stack([cb + ci.astype(np.int64), pb + pj.astype(np.int64)])
    graph.add_batch(reprojection_kernel(), keys, obs[:, 2:4], None,
                    origin=(str(p), _compact_lines(obs_lines)))
    return graph, values


def _compact_lines(lines: np.ndarray) -> np.ndarray:
    """Line numbers for error messages, as int32 when they fit (4 bytes per observation)."""
    return lines.astype(np.int32 if lines.shape[0] == 0 or lines[-1] < 2 ** 31 else np.int64)


def write_bal(path: str | os.PathLike, graph: Any, values: Any) -> None:
    """Write the reprojection factors of ``graph`` and their cameras / points as a BAL file.

    Cameras and points the factors use are numbered in key order (``c0, c1, ...`` ->
    ``0, 1, ...``; values no factor uses are not written); every camera must be an R^9 vector
    and every point an R^3 vector. ``.gz`` / ``.bz2`` paths are compressed.

    >>> import pathlib, tempfile
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> scene = fgopt.datasets.bal_synthetic(cameras=3, points=10, observations_per_point=3)
    >>> scene.write(folder / "scene.txt")
    >>> graph, initial = fgopt.io.read(folder / "scene.txt")
    >>> fgopt.io.write_bal(folder / "copy.txt", graph, initial)
    >>> (folder / "copy.txt").read_text() == (folder / "scene.txt").read_text()
    True
    """
    keys_l, meas_l = [], []
    for b in graph.batches:
        if _is_bal_kernel(b.kernel):
            if b.sqrt_information is not None or b.loss_code != 0:
                raise FgoptError("write_bal: BAL files have unit noise and no robust loss; "
                                 f"batch {b.kernel.name} has a noise model or loss")
            keys_l.append(b.keys)
            meas_l.append(b.constants)
    for f in graph.factors:
        if f.kernel is not None and _is_bal_kernel(f.kernel):
            keys_l.append(np.array([[int(k) for k in f.keys]], dtype=np.int64))
            meas_l.append(np.asarray(f.constants).reshape(1, 2))
    if not keys_l:
        raise FgoptError("write_bal: the graph has no BAL reprojection factors")
    keys = np.concatenate(keys_l)
    meas = np.concatenate(meas_l)
    cam_keys = np.unique(keys[:, 0])
    pt_keys = np.unique(keys[:, 1])
    rows = []
    for ks, dim, what in ((cam_keys, 9, "camera"), (pt_keys, 3, "point")):
        block = []
        for k in ks.tolist():
            v = np.asarray(values.at(k), dtype=float)
            if v.shape != (dim,):
                raise FgoptError(f"write_bal: {what} {key_str(k)} must be an R^{dim} vector, got "
                                 f"shape {v.shape}")
            block.append(v)
        rows.append(np.array(block))
    ci = np.searchsorted(cam_keys, keys[:, 0])
    pj = np.searchsorted(pt_keys, keys[:, 1])
    write_bal_arrays(path, ci, pj, meas, rows[0], rows[1])


def write_bal_arrays(path: str | os.PathLike, camera_index: np.ndarray, point_index: np.ndarray,
                     observations: np.ndarray, cameras: np.ndarray, points: np.ndarray) -> None:
    """Write a BAL file from arrays: per observation its camera and point index and ``(x, y)``;
    ``cameras (nc, 9)``, ``points (np, 3)``. Numbers round-trip exactly (``repr``).

    >>> import pathlib, tempfile
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "scene.txt"
    >>> s = fgopt.datasets.bal_synthetic(cameras=3, points=10, observations_per_point=3)
    >>> fgopt.io.write_bal_arrays(path, s.camera_index, s.point_index, s.observations,
    ...                           s.cameras, s.points)
    >>> graph, initial = fgopt.io.read(path)
    >>> len(graph), len(initial)             # 30 reprojection factors; 3 cameras + 10 points
    (30, 13)
    """
    ci = np.asarray(camera_index, dtype=np.int64)
    pj = np.asarray(point_index, dtype=np.int64)
    uv = np.asarray(observations, dtype=float).reshape(-1, 2)
    out = [f"{cameras.shape[0]} {points.shape[0]} {ci.shape[0]}"]
    out += [f"{c} {q} {x!r} {y!r}" for c, q, (x, y) in zip(ci.tolist(), pj.tolist(),
                                                           uv.tolist())]
    out += list(map(repr, np.asarray(cameras, dtype=float).reshape(-1).tolist()))
    out += list(map(repr, np.asarray(points, dtype=float).reshape(-1).tolist()))
    write_text(path, "\n".join(out) + "\n")
