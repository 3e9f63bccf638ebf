"""A file's own text for the batches read from it, so a writer can give those records back as
they were.

Solving a g2o file changes its vertices, not its edges. Writing the result formatted every edge
again: sphere2500's 4949 edges are ~150,000 numbers, ~60 ms of a 0.7 s ``fgopt solve``, and the
text differed from the file's while meaning the same (``10.000000000000002`` for ``10``: the
information went through ``R^T R`` and back; quaternions were normalized). So a reader asked to
(``read_g2o(keep_edge_text=True)``) remembers, per batch it made, where the batch's records lie
in the file's bytes, the tag they had, and a digest of the batch's kernel, keys, constants and
square-root information as read. A writer that would write the same tag asks :func:`recall`:
while the batch still holds the same contents, it gets the records' bytes (each record from its
tag to the end of its last number: comments and line-end whitespace left out), else ``None``
and formats the rows itself.

The table is weak: a batch's entry (and with it the file's bytes) lives as long as the batch.
Nothing is pickled with a batch; a copy made elsewhere is formatted. Opt-in, because keeping a
file's bytes costs its size in memory (a 100k-pose grid: ~35 MB) and the digest ~0.5 ms per MB
of arrays, for graphs that are mostly never written back.
"""

from __future__ import annotations

import hashlib
import threading
import weakref

import numpy as np

from ._scan_np import _IS_SPACE


class _Records:
    """Where a batch's rows were read from (a plain class: a dataclass costs ~1 ms of every
    process that reads a file)."""

    __slots__ = ("tag", "buf", "start", "end", "digest")

    def __init__(self, tag: str, buf: np.ndarray, start: np.ndarray, end: np.ndarray,
                 digest: bytes):
        self.tag = tag
        self.buf = buf  # the file's bytes (uint8; the reader's buffer, not a copy)
        self.start = start  # (n,) byte where each row's record starts (its tag)
        self.end = end  # (n,) byte after its last number
        self.digest = digest


_table: "weakref.WeakKeyDictionary[object, _Records]" = weakref.WeakKeyDictionary()
_lock = threading.Lock()


def _digest(batch) -> bytes:
    """What a record's text stands for: the kernel, and the bytes and shapes of the arrays."""
    h = hashlib.blake2b(digest_size=16)
    h.update(f"{batch.kernel.name}|{id(batch.kernel)}".encode())
    for a in (batch.keys, batch.constants, batch.sqrt_information):
        if a is None:
            h.update(b"none")
            continue
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.view(np.uint8).reshape(-1))
    return h.digest()


def token_ends(buf: np.ndarray, starts: np.ndarray, comment: int, window: int = 48
               ) -> np.ndarray:
    """Where each token starting at ``starts`` ends: the first whitespace, line end or
    ``comment`` byte (``-1``: none) at or after it, or the end of ``buf``."""
    n = buf.shape[0]
    starts = np.asarray(starts, dtype=np.int64)
    ends = np.empty(starts.shape[0], dtype=np.int64)
    if starts.shape[0] == 0:
        return ends
    at = starts[:, None] + np.arange(window)
    b = buf[np.minimum(at, n - 1)]
    stop = _IS_SPACE[b] | (at >= n)
    if comment >= 0:
        stop |= b == comment
    found = stop.any(axis=1)
    ends[:] = starts + stop.argmax(axis=1)
    for t in np.flatnonzero(~found).tolist():  # tokens longer than the window (rare)
        j = int(starts[t]) + window
        while j < n and not (_IS_SPACE[buf[j]] or int(buf[j]) == comment):
            j += 1
        ends[t] = j
    return ends


def remember(batch, tag: str, buf: np.ndarray, start: np.ndarray, end: np.ndarray) -> None:
    """Note that row ``i`` of ``batch`` was read from ``buf[start[i]:end[i]]``, a ``tag``
    record (the batch's arrays must be final: their digest is taken now)."""
    rec = _Records(tag, buf, np.asarray(start, np.int64), np.asarray(end, np.int64),
                   _digest(batch))
    with _lock:
        _table[batch] = rec


def recall(batch, tag: str) -> bytes | None:
    """The records ``batch`` was read from, one per line in row order, if they were ``tag``
    records and the batch still holds what was read from them; else ``None``."""
    with _lock:
        rec = _table.get(batch)
    if rec is None or rec.tag != tag or rec.start.shape[0] != len(batch):
        return None
    if rec.digest != _digest(batch):
        return None
    start, end = rec.start, rec.end
    if start.shape[0] == 0:
        return b""
    buf = rec.buf
    # the usual layout: one tag's records on consecutive lines, one '\n' apart
    if (np.all(start[1:] == end[:-1] + 1) and np.all(buf[end[:-1]] == 10)):
        return buf[start[0]:end[-1]].tobytes() + b"\n"
    length = end - start + 1  # with its newline
    out_end = np.cumsum(length)
    src = np.repeat(start - (out_end - length), length)
    src += np.arange(out_end[-1])
    src[out_end - 1] = 0  # placeholders for the newlines
    out = buf[src]
    out[out_end - 1] = 10
    return out.tobytes()
