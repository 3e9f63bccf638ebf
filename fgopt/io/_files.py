"""Reading and writing a file's bytes, with ``.gz`` / ``.bz2`` (de)compression by suffix and
:class:`~fgopt.errors.FileFormatError` for what cannot be read."""

from __future__ import annotations

import bz2
import gzip
import os
import zlib

from ..errors import FgoptError, FileFormatError


def read_bytes(path: str | os.PathLike) -> bytes:
    """The file's bytes; ``.gz`` and ``.bz2`` are decompressed."""
    p = os.fspath(path)
    try:
        if p.endswith(".bz2"):
            with bz2.open(p, "rb") as f:
                return f.read()
        if p.endswith(".gz"):
            with gzip.open(p, "rb") as f:
                return f.read()
        with open(p, "rb") as f:
            return f.read()
    except FileNotFoundError:
        raise FileFormatError("no such file", p) from None
    except IsADirectoryError:
        raise FileFormatError("is a directory, expected a file", p) from None
    except (OSError, EOFError, zlib.error) as exc:  # zlib.error: a damaged deflate stream
        raise FileFormatError(f"cannot read: {exc}", p) from None


def write_text(path: str | os.PathLike, text: str) -> None:
    write_bytes(path, text.encode("utf-8"))


def write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data``; ``.gz`` / ``.bz2`` paths are compressed."""
    p = os.fspath(path)
    opener = bz2.open if p.endswith(".bz2") else gzip.open if p.endswith(".gz") else open
    try:
        with opener(p, "wb") as f:
            f.write(data)
    except OSError as exc:  # a missing folder, a directory, no permission, a full disk
        raise FgoptError(f"{p}: cannot write: {exc.strerror or exc}") from None
