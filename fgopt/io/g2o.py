"""Read g2o pose graphs (and GTSAM / TORO ``VERTEX2`` / ``EDGE2`` files) into a factor graph.

Records (one per line; ``#`` starts a comment; blank lines are skipped)::

    VERTEX_SE2 id x y theta                VERTEX2 id x y theta               (TORO)
    VERTEX_XY id x y
    VERTEX_SE3:QUAT id x y z qx qy qz qw
    VERTEX_TRACKXYZ id x y z
    EDGE_SE2 i j dx dy dtheta I11 I12 I13 I22 I23 I33            (g2o order: x y theta)
    EDGE2 i j dx dy dtheta Ixx Ixy Iyy Itt Ixt Iyt               (TORO order)
    EDGE_SE2_XY i j mx my I11 I12 I22
    EDGE_SE3:QUAT i j x y z qx qy qz qw I(21, upper triangle, translation first)
    EDGE_SE3_TRACKXYZ i j [param_id] mx my mz I(6)
    PARAMS_SE3OFFSET id x y z qx qy qz qw   (only the identity offset is supported)
    FIX id [id ...]                         EQUIV i j  (TORO; skipped with a warning)

Poses get keys ``key('x', id)``, points ``key('l', id)``. Edges become batches (one per tag) of
``between`` factors (GTSAM's residual ``Log(m^-1 a^-1 b)``) or pose-to-point factors, with the
information permuted from the file's translation-first order to fgopt's rotation-first tangent.
``FIX`` adds a tight prior (sigma :data:`FIX_SIGMA`) at the vertex's value. Parsing is vectorized
(:mod:`fgopt.io._scan`); every error names the file and line.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass

import numpy as np

from ..errors import FgoptError, FileFormatError
from ..graph import FactorGraph
from ..variables import Variables
from . import _information as info_mod
from ._graph_build import FIX_SIGMA as FIX_SIGMA
from ._graph_build import add_gauge_prior as add_gauge_prior
from ._graph_build import build_graph
from ._scan import Scan, scan

log = logging.getLogger("fgopt.io")

_MAX_ID = 2 ** 53


@dataclass(frozen=True)
class _Spec:
    role: str  # vertex | edge | fix | equiv | param
    dim: int  # 2 or 3; 0 for dimension-free records
    what: str = ""  # vertex: pose | point; edge: between | point
    counts: tuple[int, ...] = ()  # accepted numbers of numeric fields (empty: >= 1)
    toro: bool = False


SPECS: dict[str, _Spec] = {
    "VERTEX_SE2": _Spec("vertex", 2, "pose", (4,)),
    "VERTEX2": _Spec("vertex", 2, "pose", (4,)),
    "VERTEX_XY": _Spec("vertex", 2, "point", (3,)),
    "VERTEX_SE3:QUAT": _Spec("vertex", 3, "pose", (8,)),
    "VERTEX_TRACKXYZ": _Spec("vertex", 3, "point", (4,)),
    "EDGE_SE2": _Spec("edge", 2, "between", (11,)),
    "EDGE2": _Spec("edge", 2, "between", (11,), toro=True),
    "EDGE_SE2_XY": _Spec("edge", 2, "point", (7,)),
    "EDGE_SE3:QUAT": _Spec("edge", 3, "between", (30,)),
    "EDGE_SE3_TRACKXYZ": _Spec("edge", 3, "point", (11, 12)),
    "PARAMS_SE3OFFSET": _Spec("param", 3, "", (8,)),
    "FIX": _Spec("fix", 0),
    "EQUIV": _Spec("equiv", 0, "", (2,)),
}
_POSE_DIM = {2: 3, 3: 7}  # numbers after the id in a pose vertex / between measurement


@dataclass(eq=False)
class _Group:
    """All records of one tag: numbers ``(n, c)`` and line numbers ``(n,)``."""

    tag: str
    spec: _Spec
    rec: np.ndarray
    lines: np.ndarray
    data: np.ndarray


class _Reader:
    def __init__(self, path: str, sc: Scan, skip_unknown: bool):
        self.path, self.sc = path, sc
        self.groups: dict[str, _Group] = {}
        self.skipped: dict[str, int] = {}
        hashes, first, inverse = np.unique(sc.tag_hash, return_index=True, return_inverse=True)
        groups = []
        bad: tuple | None = None  # (line, message) of the first bad line of the file
        for u, r0 in enumerate(first.tolist()):
            tag = sc.tag(r0)
            rec = np.nonzero(inverse == u)[0]
            spec = SPECS.get(tag)
            if spec is None:
                if not skip_unknown:
                    found = (int(sc.line[r0]), f"unknown record {tag!r}; fgopt reads "
                             f"{', '.join(SPECS)} (pass skip_unknown=True to skip unknown lines)")
                    bad = found if bad is None or found[0] < bad[0] else bad
                self.skipped[tag] = rec.shape[0]
                continue
            found = self._count_error(tag, spec, rec)
            if found is not None:
                bad = found if bad is None or found[0] < bad[0] else bad
            groups.append((tag, spec, rec))
        if bad is not None:  # tags come in hash order: report the earliest line, not the first seen
            raise sc.error(bad[1], bad[0])
        for tag, spec, rec in groups:
            self.groups[tag] = self._numbers(tag, spec, rec)

    def _count_error(self, tag: str, spec: _Spec, rec: np.ndarray) -> tuple | None:
        """``(line, message)`` of the first record of ``rec`` with a wrong number count."""
        sc = self.sc
        cnt = sc.count[rec]
        ok = np.isin(cnt, spec.counts) if spec.counts else cnt >= 1
        if ok.all():
            return None
        r = int(rec[np.nonzero(~ok)[0][0]])
        want = " or ".join(map(str, spec.counts)) if spec.counts else "at least 1"
        return int(sc.line[r]), f"{tag} needs {want} numbers after the tag, found {sc.count[r]}"

    def _numbers(self, tag: str, spec: _Spec, rec: np.ndarray) -> _Group:
        sc = self.sc
        cnt = sc.count[rec]
        width = int(cnt.max())
        if not np.all(cnt == width):  # variable-length records (FIX, TRACKXYZ with param id)
            data = np.full((rec.shape[0], width), np.nan)
            for c in np.unique(cnt).tolist():
                sub = np.nonzero(cnt == c)[0]
                idx = sc.first[rec[sub]][:, None] + np.arange(c)
                sc.check_values(idx.reshape(-1))
                sc.check_finite(idx.reshape(-1))
                data[sub, :c] = sc.values[idx]
        else:
            idx = sc.first[rec][:, None] + np.arange(width)
            sc.check_values(idx.reshape(-1))
            sc.check_finite(idx.reshape(-1))
            data = sc.values[idx]
        return _Group(tag, spec, rec, sc.line[rec], data)

    def ids(self, g: _Group, cols: slice | list[int], rows: np.ndarray | None = None
            ) -> np.ndarray:
        """Integer ids in columns ``cols`` (of ``rows``, default all); non-integers and
        out-of-range ids are errors."""
        rows = np.arange(g.data.shape[0]) if rows is None else rows
        v = g.data[rows][:, cols]
        ok = (v == np.floor(v)) & (v >= 0) & (v < _MAX_ID)
        ok |= np.isnan(v)  # padding of variable-length records
        if not ok.all():
            row, col = (int(a[0]) for a in np.nonzero(~ok))
            row = int(rows[row])
            col = np.arange(g.data.shape[1])[cols][col]
            tok = self.sc.token(int(self.sc.first[g.rec[row]]) + int(col))
            raise self.sc.error(f"{g.tag}: id {tok!r} is not a non-negative integer",
                                g.lines[row])
        return np.where(np.isnan(v), -1, v).astype(np.int64)

    def error(self, message: str, line) -> FileFormatError:
        return self.sc.error(message, line)


def read_g2o(path: str | os.PathLike, add_prior: bool = False, skip_unknown: bool = False,
             repair_information: str | None = None, repair_floor: float = 1e-6,
             data: bytes | None = None, progress: bool = True,
             keep_edge_text: bool = False) -> tuple[FactorGraph, Variables]:
    """Read a g2o (or GTSAM / TORO) pose-graph file; returns ``(graph, initial)``.

    Args:
        path: the file (``.gz`` / ``.bz2`` are decompressed).
        add_prior: add a tight prior (sigma ``FIX_SIGMA``) on the lowest-id pose to fix the gauge,
            unless the file has ``FIX`` lines (which already do); see :func:`add_gauge_prior`.
        skip_unknown: skip records with unknown tags (counted in a warning) instead of failing.
        repair_information: ``None`` refuses information matrices that are not positive definite;
            ``"clip"`` clips their eigenvalues to ``repair_floor`` times the largest one.
        repair_floor: relative eigenvalue floor of the ``"clip"`` repair.
        data: the file's bytes, if already in memory (``path`` is then only used in messages).
        progress: a progress bar on stderr when scanning takes over a second (tqdm).
        keep_edge_text: keep the file's bytes with the graph, so that :func:`write_g2o` writes
            each edge batch that still holds what was read as the file's own records (the
            text as written; sphere2500's result wrote in 30 instead of 75 ms, ad hoc;
            ``fgopt solve --out`` reads so). Costs
            the file's size in memory for as long as the graph lives.

    Raises:
        FileFormatError: malformed input; the message names the file and line.

    Example:

    >>> import tempfile, pathlib
    >>> path = pathlib.Path(tempfile.mkdtemp()) / 'two.g2o'
    >>> _ = path.write_text('VERTEX_SE2 0 0 0 0\\nVERTEX_SE2 1 1.1 0 0\\nEDGE_SE2 0 1 1 0 0 100 0 0 100 0 400\\n')
    >>> graph, initial = fgopt.io.read_g2o(path)
    >>> len(graph), initial.keys()
    (1, [x0, x1])
    """
    if repair_information not in info_mod.REPAIR_CHOICES:
        raise FgoptError(f"repair_information must be None or 'clip', got {repair_information!r}")
    p = os.fspath(path)
    sc = scan(p, data=data, progress=progress)
    if sc.line.shape[0] == 0:
        raise FileFormatError("the file has no records (no vertices, no edges)", p)
    rd = _Reader(p, sc, skip_unknown)
    if rd.skipped:
        parts = ", ".join(f"{n} {t!r}" for t, n in rd.skipped.items())
        log.warning("%s: skipped %d lines with unknown tags (%s)", p, sum(rd.skipped.values()),
                    parts)
    dim = _dimension(rd)
    return build_graph(rd, dim, add_prior, repair_information, repair_floor, keep_edge_text)


def _dimension(rd: _Reader) -> int:
    first_line = {2: None, 3: None}
    for g in rd.groups.values():
        d = g.spec.dim
        if d in first_line and (first_line[d] is None or g.lines[0] < first_line[d][0]):
            first_line[d] = (int(g.lines[0]), g.tag)
    if first_line[2] is not None and first_line[3] is not None:
        (l2, t2), (l3, t3) = first_line[2], first_line[3]
        raise rd.error(f"the file mixes 2D records ({t2} at line {l2}) and 3D records "
                       f"({t3} at line {l3})", max(l2, l3))
    if first_line[2] is None and first_line[3] is None:
        raise rd.error("the file has no vertex or edge records", None)
    return 2 if first_line[2] is not None else 3
