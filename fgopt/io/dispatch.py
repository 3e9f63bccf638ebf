"""``read(path)``: pick the reader from the file's content (and extension).

A file starting with ``# Bundle file`` is a Bundler ``.out`` file; otherwise a file whose first
token is a number is BAL (its header ``cameras points observations``); a file whose first token
is ``ODOMETRY`` / ``LANDMARK`` / ``BR`` is a GTSAM ``load2D`` SLAM file; any other record tag
(``VERTEX_SE2``, ``EDGE2``, ...) is g2o / TORO.
``.gz`` / ``.bz2`` files are decompressed first.
"""

from __future__ import annotations

import os
import re

from ..errors import FgoptError, FileFormatError
from ..graph import FactorGraph
from ..variables import Variables
from ._files import read_bytes

FORMATS = ("g2o", "bal", "bundler", "load2d")
#: First tags of GTSAM ``load2D`` SLAM files that the g2o reader does not read.
_LOAD2D_TAGS = (b"ODOMETRY", b"LANDMARK", b"BR")
_FIRST_TOKEN = re.compile(rb"^[ \t\r\f\v]*([^\s#]+)", re.MULTILINE)
_G2O_EXT = (".g2o", ".graph")


def detect_format(path: str | os.PathLike, data: bytes | None = None) -> str:
    """``"g2o"``, ``"bal"``, ``"bundler"`` or ``"load2d"``; raises :class:`FileFormatError` when
    none fits.

    >>> import pathlib, tempfile
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "tiny.g2o"
    >>> _ = path.write_text("VERTEX_SE2 0 0 0 0")
    >>> fgopt.io.detect_format(path)
    'g2o'
    """
    p = os.fspath(path)
    if data is None:
        data = read_bytes(p)
    if data.lstrip()[:13] == b"# Bundle file":
        return "bundler"
    m = _FIRST_TOKEN.search(data[:1 << 16])
    if m is None:
        raise FileFormatError("the file is empty (no records)", p)
    tok = m.group(1)
    line = data[:m.start(1)].count(b"\n") + 1
    if re.fullmatch(rb"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?", tok):
        return "bal"
    if tok in _LOAD2D_TAGS:
        return "load2d"
    if re.fullmatch(rb"[A-Za-z_][A-Za-z0-9_:]*", tok):
        return "g2o"
    raise FileFormatError(f"cannot tell the format from the first token {tok[:40]!r}: expected "
                          "a g2o / TORO tag or a BAL header", p, line)


def read(path: str | os.PathLike, *, format: str | None = None, add_prior: bool = False,
         skip_unknown: bool = False, repair_information: str | None = None,
         progress: bool = True, keep_edge_text: bool = False) -> tuple[FactorGraph, Variables]:
    """Read any supported file; returns ``(graph, initial)``.

    Args:
        path: a g2o / TORO pose graph (``.g2o``, ``.graph``, ``.txt``), a BAL problem or a
            Bundler ``.out`` file, optionally ``.gz`` / ``.bz2`` compressed.
        format: ``"g2o"``, ``"bal"``, ``"bundler"`` or ``"load2d"`` (GTSAM's 2-D SLAM files
            with ``ODOMETRY`` / ``LANDMARK`` / ``BR`` records, :func:`fgopt.io.load2d`) to skip
            detection.
        add_prior, skip_unknown, repair_information, keep_edge_text: g2o options, see
            :func:`read_g2o`
            (BAL files have no gauge prior, unknown tags or information matrices; passing a
            non-default value for one is an error).
        progress: show a progress bar on stderr (tqdm, when installed) if scanning the file
            takes over a second.

    Example:

    >>> import tempfile, pathlib
    >>> sample = fgopt.datasets.manhattan_2d(num_poses=30, seed=0)
    >>> path = pathlib.Path(tempfile.mkdtemp()) / 'm30.g2o'
    >>> fgopt.io.write_g2o(path, sample.graph, sample.initial)
    >>> graph, initial = fgopt.io.read(path)
    >>> len(initial), fgopt.Key(0) in initial
    (30, False)
    """
    p = os.fspath(path)
    data = read_bytes(p)
    if format is None:
        format = detect_format(p, data)
        base = p[:-4] if p.endswith(".bz2") else p[:-3] if p.endswith(".gz") else p
        if format == "bal" and base.endswith(_G2O_EXT):
            raise FileFormatError("the extension says g2o but the file starts with a number; "
                                  "pass format='bal' if it is a BAL file", p, 1)
    if format == "g2o":
        from .g2o import read_g2o

        return read_g2o(p, add_prior=add_prior, skip_unknown=skip_unknown,
                        repair_information=repair_information, data=data, progress=progress,
                        keep_edge_text=keep_edge_text)
    if format == "bal":
        if add_prior or skip_unknown or repair_information is not None or keep_edge_text:
            raise FgoptError("read: add_prior, skip_unknown, repair_information and "
                             "keep_edge_text apply to g2o "
                             f"files; {p} is a BAL file")
        from .bal import read_bal

        return read_bal(p, data=data, progress=progress)
    if format == "bundler":
        if add_prior or skip_unknown or repair_information is not None or keep_edge_text:
            raise FgoptError("read: add_prior, skip_unknown, repair_information and "
                             "keep_edge_text apply to g2o "
                             f"files; {p} is a Bundler file")
        from .bundler import read_bundler

        return read_bundler(p, data=data)
    if format == "load2d":
        if add_prior or skip_unknown or repair_information is not None or keep_edge_text:
            raise FgoptError("read: add_prior, skip_unknown, repair_information and "
                             "keep_edge_text apply to g2o "
                             f"files; {p} is a load2D file (see fgopt.io.load2d for its options)")
        from .load2d import load2d

        return load2d(p)
    raise FgoptError(f"read: unknown format {format!r}; choose one of {', '.join(FORMATS)}")
