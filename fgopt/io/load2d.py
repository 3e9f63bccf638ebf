"""Read 2-D SLAM files the way GTSAM's ``load2D`` does (Victoria Park, w10000 / w20000 ...).

Records (one per line, tags as GTSAM's ``dataset.cpp`` reads them)::

    VERTEX2 | VERTEX_SE2 | VERTEX id x y theta           a pose
    VERTEX_XY id x y                                    a landmark
    EDGE2 | EDGE | EDGE_SE2 | ODOMETRY i j dx dy dtheta v1 v2 v3 v4 v5 v6
    BR pose landmark bearing range bearing_std range_std
    LANDMARK pose landmark lx ly v1 v2 v3               (lx, ly in the robot frame)

``v1..v6`` are read per ``noise_format``: ``"g2o"`` / ``"toro"`` information in g2o order
(``xx xy xt yy yt tt``) / TORO order (``xx xy yy tt xt yt``), ``"cov"`` / ``"graph"`` the
covariance in those orders, ``"sqrt_information"`` iSAM's upper-triangular square-root
information (``xx xy xt yy yt tt``; Kaess's ``Loader.cpp``), or ``"auto"``: GTSAM's guess per
edge from the zero pattern, ``"graph"`` when exactly ``v1, v3, v4`` are non-zero and ``"cov"``
when exactly ``v1, v4, v6`` are (any other pattern is an error). A ``LANDMARK`` becomes a
bearing-range measurement, ``bearing = atan2(ly, lx)``, ``range = |l|``, with GTSAM's sigmas:
``sqrt(v1 / 10)`` and ``sqrt(v1)`` when ``v1 == v3`` (within 1e-4), else 1 and 1.

Poses get keys ``key('x', id)``, landmarks ``key('l', id)``. Edges become ``BetweenFactor``
(SE2) factors, landmark measurements ``range_bearing_factor`` (measured ``[range, bearing]``).
Initial values, as ``load2D``: the file's vertices; else a pose first seen as an edge's second
key is its first key's value composed with the measurement (the first key defaulting to the
identity), a landmark is placed at its first sighting.

:func:`parse_load2d` returns the records (for streaming them, as ``benchmarks/incremental.py``
does); :func:`load2d` builds ``(graph, initial)``.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np

from ..errors import FgoptError
from ..graph import FactorGraph
from ..key import key
from ..manifolds import SE2
from ..variables import Variables
from ._information import PERM_SE2, permute
from ._scan import scan

NOISE_FORMATS = ("auto", "g2o", "toro", "cov", "graph", "sqrt_information")
_EDGE_TAGS = ("EDGE2", "EDGE", "EDGE_SE2", "ODOMETRY")
_POSE_TAGS = ("VERTEX2", "VERTEX_SE2", "VERTEX")


@dataclass(eq=False)
class Load2D:
    """Records of a ``load2D`` file, in file order (see the module docstring)."""

    path: str
    #: pose vertices: id -> (x, y, theta); landmark vertices: id -> (x, y)
    poses: dict = field(default_factory=dict)
    points: dict = field(default_factory=dict)
    #: edges: ``(n,)`` ids, ``(n, 3)`` measurements ``(dx, dy, dtheta)``, ``(n, 3, 3)``
    #: square-root information in fgopt's tangent order ``[theta, x, y]``, file lines
    edge_i: np.ndarray = None
    edge_j: np.ndarray = None
    edge_meas: np.ndarray = None
    edge_sqrt_info: np.ndarray = None
    #: bearing-range measurements: pose id, landmark id, bearing, range, sigmas (bearing, range)
    br_pose: np.ndarray = None
    br_landmark: np.ndarray = None
    br_bearing: np.ndarray = None
    br_range: np.ndarray = None
    br_sigmas: np.ndarray = None
    #: file order of the measurements: ``(kind, index)`` with kind 0 = edge, 1 = bearing-range
    order: np.ndarray = None


def _noise_matrix(v: np.ndarray, fmt: str) -> tuple[np.ndarray, np.ndarray]:
    """``(M, is_information)``: ``(n, 3, 3)`` matrices in the file's (x, y, theta) order."""
    n = v.shape[0]
    if fmt == "auto":
        nz = v != 0
        graph = nz[:, 0] & ~nz[:, 1] & nz[:, 2] & nz[:, 3] & ~nz[:, 4] & ~nz[:, 5]
        cov = nz[:, 0] & ~nz[:, 1] & ~nz[:, 2] & nz[:, 3] & ~nz[:, 4] & nz[:, 5]
        Mg, _ = _noise_matrix(v, "graph")
        Mc, _ = _noise_matrix(v, "cov")
        M = np.where(graph[:, None, None], Mg, Mc)
        M[~(graph | cov)] = np.nan
        return M, np.zeros(n, dtype=bool)
    if fmt in ("g2o", "cov", "sqrt_information"):
        idx = [(0, 0, 0), (0, 1, 1), (0, 2, 2), (1, 1, 3), (1, 2, 4), (2, 2, 5)]
    elif fmt in ("toro", "graph"):
        idx = [(0, 0, 0), (0, 1, 1), (1, 1, 2), (2, 2, 3), (0, 2, 4), (1, 2, 5)]
    else:
        raise FgoptError(f"unknown noise_format {fmt!r}: choose one of {', '.join(NOISE_FORMATS)}")
    M = np.zeros((n, 3, 3))
    for a, b, k in idx:
        M[:, a, b] = v[:, k]
        if fmt != "sqrt_information":
            M[:, b, a] = v[:, k]
    if fmt == "sqrt_information":
        return np.einsum("nka,nkb->nab", M, M), np.ones(n, dtype=bool)
    return M, np.full(n, fmt in ("g2o", "toro"))


def _sqrt_information(v: np.ndarray, fmt: str, path: str, lines: np.ndarray) -> np.ndarray:
    """Upper-triangular square-root information, fgopt tangent order ``[theta, x, y]``."""
    M, is_info = _noise_matrix(v, fmt)
    unknown = np.isnan(M[:, 0, 0])
    if np.any(unknown):
        raise FgoptError(f"{path}:{int(lines[np.nonzero(unknown)[0][0]])}: cannot guess the "
                         "noise format from its zero pattern (GTSAM's rule); pass noise_format=")
    M = permute(M, PERM_SE2)
    out = np.empty_like(M)
    for flag in (True, False):
        sel = np.nonzero(is_info == flag)[0]
        if sel.shape[0] == 0:
            continue
        try:
            info = M[sel] if flag else np.linalg.inv(M[sel])
            out[sel] = np.transpose(np.linalg.cholesky(info), (0, 2, 1))
        except np.linalg.LinAlgError:
            for i in sel.tolist():
                try:
                    np.linalg.cholesky(M[i] if flag else np.linalg.inv(M[i]))
                except np.linalg.LinAlgError:
                    raise FgoptError(f"{path}:{int(lines[i])}: the noise matrix is not "
                                     f"positive definite (read as {fmt!r})") from None
            raise
    return np.ascontiguousarray(out)


def parse_load2d(path: str | os.PathLike, noise_format: str = "auto") -> Load2D:
    """The records of ``path`` (see the module docstring).

    Example: one odometry edge whose ``v1, v4, v6`` are non-zero, so read as a covariance
    (GTSAM's guess), and one bearing-range measurement:

    >>> import tempfile, pathlib
    >>> path = pathlib.Path(tempfile.mkdtemp()) / 'slam.txt'
    >>> _ = path.write_text('ODOMETRY 0 1 1.0 0.0 0.0 100 0 0 100 0 1000\\n'
    ...                     'BR 1 5 0.0 2.0 0.1 0.2\\n')
    >>> rec = fgopt.io.parse_load2d(path)
    >>> rec.edge_i, rec.edge_j, np.round(np.diag(rec.edge_sqrt_info[0]), 4)   # [theta, x, y]
    (array([0]), array([1]), array([0.0316, 0.1   , 0.1   ]))
    >>> rec.br_pose, rec.br_landmark, rec.br_range, rec.order.tolist()
    (array([1]), array([5]), array([2.]), [[0, 0], [1, 0]])
    """
    p = os.fspath(path)
    sc = scan(p)
    out = Load2D(p)
    tags = {}
    for h in np.unique(sc.tag_hash).tolist():
        r = int(np.nonzero(sc.tag_hash == h)[0][0])
        tags[h] = sc.tag(r)
    kinds = np.full(sc.line.shape[0], -1, np.int64)
    for h, tag in tags.items():
        sel = sc.tag_hash == h
        if tag in _EDGE_TAGS:
            kinds[sel] = 0
        elif tag in ("BR", "LANDMARK"):
            kinds[sel] = 1 if tag == "BR" else 2
        elif tag in _POSE_TAGS:
            kinds[sel] = 3
        elif tag == "VERTEX_XY":
            kinds[sel] = 4
        else:
            raise sc.error(f"unknown record {tag!r} for a load2D file", int(sc.line[sel][0]))
    need = {0: 11, 1: 6, 2: 7, 3: 4, 4: 3}
    for k, c in need.items():
        rows = np.nonzero(kinds == k)[0]
        bad = rows[sc.count[rows] < c]
        if bad.shape[0]:
            raise sc.error(f"record needs {c} numbers after its tag, found "
                           f"{int(sc.count[bad[0]])}", int(sc.line[bad[0]]))
    sc.check_values()

    def numbers(rows: np.ndarray, c: int) -> np.ndarray:
        idx = sc.first[rows][:, None] + np.arange(c)
        sc.check_finite(idx.reshape(-1))
        return sc.values[idx]

    for r, row in zip(np.nonzero(kinds == 3)[0].tolist(), numbers(np.nonzero(kinds == 3)[0], 4)):
        out.poses[int(row[0])] = (row[1], row[2], row[3])
    for row in numbers(np.nonzero(kinds == 4)[0], 3):
        out.points[int(row[0])] = (row[1], row[2])
    er = np.nonzero(kinds == 0)[0]
    e = numbers(er, 11)
    out.edge_i, out.edge_j = e[:, 0].astype(np.int64), e[:, 1].astype(np.int64)
    out.edge_meas = e[:, 2:5].copy()
    out.edge_sqrt_info = _sqrt_information(e[:, 5:11], noise_format, p, sc.line[er]) if \
        er.shape[0] else np.zeros((0, 3, 3))
    brr = np.nonzero(kinds == 1)[0]
    lmr = np.nonzero(kinds == 2)[0]
    br = numbers(brr, 6)
    lm = numbers(lmr, 7)
    lx, ly, v1, v3 = lm[:, 2], lm[:, 3], lm[:, 4], lm[:, 6]
    same = np.abs(v1 - v3) < 1e-4
    lm_sig = np.stack([np.where(same, np.sqrt(np.abs(v1) / 10.0), 1.0),
                       np.where(same, np.sqrt(np.abs(v1)), 1.0)], axis=1)
    rows = np.concatenate([brr, lmr])
    srt = np.argsort(rows, kind="stable")
    out.br_pose = np.concatenate([br[:, 0], lm[:, 0]]).astype(np.int64)[srt]
    out.br_landmark = np.concatenate([br[:, 1], lm[:, 1]]).astype(np.int64)[srt]
    out.br_bearing = np.concatenate([br[:, 2], np.arctan2(ly, lx)])[srt]
    out.br_range = np.concatenate([br[:, 3], np.hypot(lx, ly)])[srt]
    out.br_sigmas = np.concatenate([br[:, 4:6], lm_sig])[srt]
    if np.any(out.br_sigmas <= 0):
        i = int(np.nonzero(np.any(out.br_sigmas <= 0, axis=1))[0][0])
        raise sc.error("bearing / range sigma must be positive", int(sc.line[rows[srt][i]]))
    meas_rows = np.concatenate([er, rows[srt]])
    kind = np.concatenate([np.zeros(er.shape[0], np.int64), np.ones(rows.shape[0], np.int64)])
    index = np.concatenate([np.arange(er.shape[0]), np.arange(rows.shape[0])])
    o = np.argsort(meas_rows, kind="stable")
    out.order = np.stack([kind[o], index[o]], axis=1)
    return out


def landmark_guess(pose: SE2, bearing: float, range_: float) -> np.ndarray:
    """A landmark's position from a pose and a bearing-range measurement."""
    local = np.array([range_ * math.cos(bearing), range_ * math.sin(bearing)])
    return pose.act(local)


def load2d(path: str | os.PathLike, noise_format: str = "auto"
           ) -> tuple[FactorGraph, Variables]:
    """``(graph, initial)`` of a ``load2D`` file (see the module docstring).

    Example:

    >>> import tempfile, pathlib
    >>> path = pathlib.Path(tempfile.mkdtemp()) / 'slam.txt'
    >>> _ = path.write_text('ODOMETRY 0 1 1.0 0.0 0.0 0.01 0 0 0.01 0 0.001\\n')
    >>> graph, initial = fgopt.io.load2d(path)
    >>> len(graph), sorted(initial.keys())
    (1, [x0, x1])
    """
    from ..factors import BetweenFactor
    from ..factors.library.range_bearing import range_bearing_factor
    from ..noise import Diagonal, Gaussian

    d = parse_load2d(path, noise_format)
    graph, initial = FactorGraph(), Variables()
    for i, (x, y, t) in d.poses.items():
        initial.add(key("x", i), SE2.from_xytheta(x, y, t))
    for i, (x, y) in d.points.items():
        initial.add(key("l", i), np.array([x, y]))
    for kind, idx in d.order.tolist():
        if kind == 0:
            i, j = int(d.edge_i[idx]), int(d.edge_j[idx])
            m = SE2.from_xytheta(*d.edge_meas[idx])
            graph.add(BetweenFactor(key("x", i), key("x", j), m,
                                    Gaussian.from_sqrt_information(d.edge_sqrt_info[idx])))
            if key("x", i) not in initial:
                initial.add(key("x", i), SE2.identity())
            if key("x", j) not in initial:
                initial.add(key("x", j), initial.at(key("x", i)) * m)
        else:
            pk, lk = key("x", int(d.br_pose[idx])), key("l", int(d.br_landmark[idx]))
            b, r = float(d.br_bearing[idx]), float(d.br_range[idx])
            s_b, s_r = d.br_sigmas[idx]
            graph.add(range_bearing_factor(pose=pk, landmark=lk, measured=np.array([r, b]),
                                           loss=Diagonal.sigmas([s_r, s_b])))
            if pk not in initial:
                initial.add(pk, SE2.identity())
            if lk not in initial:
                initial.add(lk, landmark_guess(initial.at(pk), b, r))
    return graph, initial
