"""Fast tokenizer for whitespace-separated numeric text files (g2o, TORO, BAL).

One numba pass over the raw bytes splits the file into *records* (non-empty lines after removing
``#`` comments) and parses every numeric token. Python never loops over lines on the fast path.

Number parsing is exact: results always equal ``float(token)``. A token's digits fold into an
integer mantissa ``m < 10**18`` and a decimal exponent. When ``m <= 2**53`` and the exponent is in
``[-22, 22]`` one multiply or divide by an exact power of ten is correctly rounded (Clinger's fast
path). Otherwise (17-digit ``repr`` output) ``m * 10**k`` is formed in double-double arithmetic
(error below 2**-100 relative) and accepted only when that bound proves the rounding; the rest
(more than 18 digits, ``nan``, ``1e400``, garbage, extreme exponents) is marked and converted by
numpy / Python ``float`` afterwards.

Output (:class:`Scan`):

- per record ``r``: ``line[r]`` (1-based line number), ``first[r]`` / ``count[r]`` (slice of its
  numeric values), and when ``has_tag``: ``tag_hash[r]`` (FNV-1a of the first token) and its byte
  span ``tag_start[r]:tag_end[r]``;
- per value ``v``: ``values[v]``, ``bad[v]`` (True when the token is not a number) and where
  its token starts, ``tok_start[v]`` (for error messages; ``Scan.token`` finds its end).

Outputs are sized exactly by a first counting pass; large files are scanned in slices with a
progress bar (tqdm) when that takes over a second.
"""

from __future__ import annotations

import functools
import math
import os
import time
from dataclasses import dataclass

import numpy as np

from .._jit import is_numba_loaded, njit, numpy_only
from ..errors import FileFormatError
from ._files import read_bytes
from ._scan_np import _FNV_OFFSET, _FNV_PRIME, _scan_np

_MAX_MANTISSA = 1 << 53


@njit(cache=True, inline="always")
def _is_space(c):
    return c == 32 or c == 9 or c == 13 or c == 11 or c == 12


def _pow10_table() -> tuple[np.ndarray, np.ndarray]:
    """``10**k`` for ``k`` in ``[-_EXP_RANGE, _EXP_RANGE]`` as double-double ``(hi, lo)``, exact to
    ~2**-106 relative (computed with rationals)."""
    from fractions import Fraction

    hi = np.empty(2 * _EXP_RANGE + 1)
    lo = np.empty(2 * _EXP_RANGE + 1)
    for k in range(-_EXP_RANGE, _EXP_RANGE + 1):
        x = Fraction(10) ** k
        h = float(x)
        hi[k + _EXP_RANGE] = h
        lo[k + _EXP_RANGE] = float(x - Fraction(h))
    return hi, lo


_EXP_RANGE = 250


#: the table, made on the numba scan's first use (~3 ms the NumPy scan's process skips)
_pow10 = functools.lru_cache(maxsize=1)(_pow10_table)


@njit(cache=True, inline="always")
def _two_prod(a, b):
    """Exact ``a * b = p + e`` (Dekker / Veltkamp splitting; no FMA needed)."""
    p = a * b
    c = 134217729.0 * a  # 2**27 + 1
    ah = c - (c - a)
    al = a - ah
    c = 134217729.0 * b
    bh = c - (c - b)
    bl = b - bh
    e = ((ah * bh - p) + ah * bl + al * bh) + al * bl
    return p, e


@njit(cache=True)
def _scale_exact(m, exp10, p10_hi, p10_lo):
    """Correctly rounded ``m * 10**exp10`` (``0 < m < 10**18``); ``ok`` False when unsure."""
    if exp10 == 0 and m <= _MAX_MANTISSA:
        return float(m), True
    if m <= _MAX_MANTISSA and 0 < exp10 <= 22:  # Clinger: one exact-operand rounding
        return float(m) * p10_hi[exp10 + _EXP_RANGE], True
    if m <= _MAX_MANTISSA and -22 <= exp10 < 0:
        return float(m) / p10_hi[-exp10 + _EXP_RANGE], True
    if exp10 < -_EXP_RANGE or exp10 > _EXP_RANGE:
        return 0.0, False
    # double-double product (error < 2**-100 relative), then a certified rounding
    xh = float(m)
    xl = float(m - np.int64(xh))
    yh = p10_hi[exp10 + _EXP_RANGE]
    yl = p10_lo[exp10 + _EXP_RANGE]
    p, e = _two_prod(xh, yh)
    e += xh * yl + xl * yh
    h = p + e
    lo = e - (h - p)
    mant, ex = math.frexp(abs(h))
    ulp = math.ldexp(1.0, ex - 53)
    tol = math.ldexp(1.0, ex - 98)
    if (lo > 0) == (h > 0):
        room = 0.5 * ulp - abs(lo)
    else:
        room = (0.25 * ulp if mant == 0.5 else 0.5 * ulp) - abs(lo)
    if room <= tol:
        return 0.0, False
    return h, True


@njit(cache=True, inline="always")
def _ends_token(buf, j, n, comment):
    """True at a token boundary: end of data, whitespace, line end or the comment character."""
    if j >= n:
        return True
    c = buf[j]
    return c == 10 or c == comment or _is_space(c)


@njit(cache=True, inline="always")  # inlined into the scan loop: 0.27 -> 0.24 s on 48 MB
def _parse_token(buf, s, n, comment, p10_hi, p10_lo):
    """Parse the token starting at ``s``; returns ``(value, ok, end)``, ``end`` = where the
    token ends. ``ok`` False: let Python decide (also for tokens that are not numbers).

    One pass: digits are consumed while the token is read (no separate search for its end).
    """
    j = s
    neg = False
    if buf[j] == 45 or buf[j] == 43:  # '-' '+'
        neg = buf[j] == 45
        j += 1
    m = 0
    nd = 0
    exp10 = 0
    digits = 0
    exact = True
    while j < n and 48 <= buf[j] <= 57:
        d = buf[j] - 48
        digits += 1
        if m == 0 and d == 0:
            pass
        elif nd < 18:
            m = m * 10 + d
            nd += 1
        else:
            exp10 += 1
            if d != 0:
                exact = False
        j += 1
    if j < n and buf[j] == 46:  # '.'
        j += 1
        while j < n and 48 <= buf[j] <= 57:
            d = buf[j] - 48
            digits += 1
            if m == 0 and d == 0:
                exp10 -= 1
            elif nd < 18:
                m = m * 10 + d
                nd += 1
                exp10 -= 1
            elif d != 0:
                exact = False
            j += 1
    ok = digits > 0
    if ok and j < n and (buf[j] == 101 or buf[j] == 69):  # 'e' 'E'
        j += 1
        eneg = False
        if j < n and (buf[j] == 45 or buf[j] == 43):
            eneg = buf[j] == 45
            j += 1
        edigits = 0
        ex = 0
        while j < n and 48 <= buf[j] <= 57:
            if ex < 100000:
                ex = ex * 10 + (buf[j] - 48)
            edigits += 1
            j += 1
        ok = edigits > 0
        exp10 += -ex if eneg else ex
    if not _ends_token(buf, j, n, comment):  # something else follows: not a plain number
        ok = False
        while not _ends_token(buf, j, n, comment):
            j += 1
    if not ok or not exact:
        return 0.0, False, j
    if m == 0:
        return (-0.0 if neg else 0.0), True, j
    v, ok = _scale_exact(m, exp10, p10_hi, p10_lo)
    return (-v if neg else v), ok, j


@njit(cache=True)
def _count(buf):
    """Upper bounds for the outputs: lines, and runs of non-space bytes (tokens)."""
    lines = 1
    toks = 0
    gap = True
    for i in range(buf.shape[0]):
        c = buf[i]
        if c == 10 or _is_space(c):
            lines += c == 10
            gap = True
        elif gap:
            toks += 1
            gap = False
    return lines, toks


@njit(cache=True)
def _scan_part(buf, stop_at, has_tag, comment, p10_hi, p10_lo, values, slow, tok_start,
               rec_line, rec_first, rec_count, tag_hash, tag_start, tag_end, state):
    """Scan the lines starting before byte ``stop_at``; resumable: ``state`` = ``[next byte,
    values so far, records so far, next line number]`` is read and updated. Each byte is read
    once (tokens are parsed as they are found)."""
    n = buf.shape[0]
    i, nv, nr, line = state[0], state[1], state[2], state[3]
    while i <= n and i < stop_at:
        j = i
        started = False
        need_tag = has_tag
        while True:
            while j < n and _is_space(buf[j]):
                j += 1
            if j >= n or buf[j] == 10:
                break
            if buf[j] == comment:  # the rest of the line is a comment
                while j < n and buf[j] != 10:
                    j += 1
                break
            s = j
            if not started:
                started = True
                rec_line[nr] = line
                rec_first[nr] = nv
            if need_tag:
                need_tag = False
                h = _FNV_OFFSET
                while not _ends_token(buf, j, n, comment):
                    h = (h ^ np.uint64(buf[j])) * _FNV_PRIME
                    j += 1
                tag_hash[nr] = h
                tag_start[nr] = s
                tag_end[nr] = j
                rec_first[nr] = nv
                continue
            v, ok, j = _parse_token(buf, s, n, comment, p10_hi, p10_lo)
            values[nv] = v
            if not ok:
                slow[nv] = 1
                for q in range(s, j):
                    if buf[q] == 95 or buf[q] > 127:  # '_' or non-ASCII: float() is too lax
                        slow[nv] = 2
            tok_start[nv] = s
            nv += 1
        if started:
            rec_count[nr] = nv - rec_first[nr]
            nr += 1
        line += 1
        i = j + 1  # j is at the line's newline (or the end of the data)
    state[0], state[1], state[2], state[3] = i, nv, nr, line


@njit(cache=True)
def _token_ends(buf, starts, comment):
    """Where each token starting at ``starts`` ends (whitespace, line end or comment)."""
    out = np.empty(starts.shape[0], dtype=np.int64)
    n = buf.shape[0]
    for t in range(starts.shape[0]):
        j = starts[t]
        while j < n and buf[j] != 10 and buf[j] != comment and not _is_space(buf[j]):
            j += 1
        out[t] = j
    return out


@njit(cache=True)
def _gather_tokens(buf, start, end, width):
    out = np.zeros((start.shape[0], width), dtype=np.uint8)
    for i in range(start.shape[0]):
        for q in range(start[i], end[i]):
            out[i, q - start[i]] = buf[q]
    return out


def _parse_slow(buf: np.ndarray, start: np.ndarray, end: np.ndarray):
    """Python-float semantics for tokens the fast path left: ``(values, bad)``."""
    width = int((end - start).max())
    toks = _gather_tokens(buf, start, end, width).view(f"S{width}").reshape(-1)
    try:  # numpy's vectorized conversion (same grammar as float())
        return toks.astype(float), np.zeros(toks.shape[0], dtype=bool)
    except ValueError:
        pass
    vals = np.empty(toks.shape[0])
    bad = np.zeros(toks.shape[0], dtype=bool)
    for i, t in enumerate(toks.tolist()):
        try:
            vals[i] = float(t)
        except ValueError:
            vals[i], bad[i] = np.nan, True
    return vals, bad


def tag_hash(tag: str) -> int:
    """The FNV-1a hash the scanner computes for a tag token."""
    h = int(_FNV_OFFSET)
    for c in tag.encode("ascii"):
        h = ((h ^ c) * int(_FNV_PRIME)) & 0xFFFFFFFFFFFFFFFF
    return h


@dataclass(eq=False)
class Scan:
    """Records and numeric values of a text file; see the module docstring."""

    path: str
    buf: np.ndarray
    values: np.ndarray
    bad: np.ndarray
    tok_start: np.ndarray
    line: np.ndarray
    first: np.ndarray
    count: np.ndarray
    tag_hash: np.ndarray
    tag_start: np.ndarray
    tag_end: np.ndarray
    comment: int = -1

    def token(self, v: int) -> str:
        s = int(self.tok_start[v])
        e = int(_token_ends(self.buf, self.tok_start[v:v + 1], self.comment)[0])
        return _text(self.buf[s:e])

    def tag(self, r: int) -> str:
        return _text(self.buf[self.tag_start[r]:self.tag_end[r]])

    def line_of_value(self, v: int) -> int:
        r = int(np.searchsorted(self.first, v, side="right")) - 1
        return int(self.line[max(r, 0)])

    def error(self, message: str, line: int | None) -> FileFormatError:
        return FileFormatError(message, self.path, None if line is None else int(line))

    def check_values(self, which: np.ndarray | slice | None = None) -> None:
        """Raise for the first non-number token (among ``which`` value indices or a slice of
        them, default all)."""
        which = _as_index(which, self.values.shape[0])
        bad = self.bad[which]
        if bad.any():
            v = _nth(which, int(np.argmax(bad)))
            raise self.error(f"{self.token(v)!r} is not a number", self.line_of_value(v))

    def check_finite(self, which: np.ndarray | slice | None = None) -> None:
        """Raise for the first NaN / inf value among value indices ``which`` (or a slice)."""
        which = _as_index(which, self.values.shape[0])
        a = np.ascontiguousarray(self.values[which]).reshape(-1)
        fin = (_first_nonfinite_np(a) if numpy_only() or not is_numba_loaded()
               else _first_nonfinite(a))
        if fin >= 0:
            v = _nth(which, fin)
            raise self.error(f"{self.token(v)!r} is not a finite number", self.line_of_value(v))


def _as_index(which, n: int):
    return slice(0, n) if which is None else which


def _nth(which, i: int) -> int:
    """The value index of the ``i``-th element selected by ``which`` (array or slice)."""
    if isinstance(which, slice):
        return (which.start or 0) + i * (which.step or 1)
    return int(which[i])


def _first_nonfinite_np(a, step: int = 1 << 20) -> int:
    """:func:`_first_nonfinite` in NumPy (no numba import), in slices: the mask stays 1 MB."""
    for lo in range(0, a.shape[0], step):
        bad = ~np.isfinite(a[lo:lo + step])
        if bad.any():
            return lo + int(np.argmax(bad))
    return -1


@njit(cache=True)
def _first_nonfinite(a):
    """Index of the first non-finite entry of the 1-D array ``a``, or -1 (no temporary mask)."""
    for i in range(a.shape[0]):
        if not np.isfinite(a[i]):
            return i
    return -1


def _text(b: np.ndarray) -> str:
    return bytes(b).decode("utf-8", errors="replace")


#: Files are scanned in slices of this many bytes (progress is reported between slices).
SCAN_SLICE = 1 << 24
#: Seconds of scanning before the progress bar appears (tqdm's import alone is ~50 ms, so it is
#: imported only then).
BAR_DELAY = 1.0

#: Files up to this many bytes are scanned by :func:`_scan_np` while numba is not in use in the
#: process (numba's scan needs its import, and 4.5 s of compilation with an empty cache). Its
#: arrays take ~40 bytes per input byte: at 32 MB (main's limit) a 500k-observation BAL file
#: (29 MB) peaked at 1.5 GB instead of 0.45 GB and read in 3.2 s instead of 0.7 s, so the limit
#: is 4 MB (every shipped pose graph; torus3D is 3.2 MB).
NUMPY_SCAN_MAX_BYTES = 4 << 20


def scan(path: str | os.PathLike, data: bytes | None = None, has_tag: bool = True,
         comment: str | None = "#", progress: bool = True) -> Scan:
    """Tokenize ``path`` (or ``data``, its bytes); see the module docstring.

    With ``progress``, a bar (tqdm, when installed) appears on stderr when scanning takes
    longer than a second.
    """
    p = os.fspath(path)
    if data is None:
        data = read_bytes(p)
    buf = np.frombuffer(data, dtype=np.uint8)
    cm = -1 if comment is None else ord(comment)
    n = buf.shape[0]
    if numpy_only() or (n <= NUMPY_SCAN_MAX_BYTES and not is_numba_loaded()):
        # NumPy backend, or a small file while numba is not in use: no numba import
        values, bad, vstart, _, line, first, count, tag_hash, tag_start, tag_end = \
            _scan_np(buf, has_tag, cm)
        if not has_tag:
            tag_hash = np.zeros(0, dtype=np.uint64)
            tag_start = tag_end = np.zeros(0, dtype=np.int64)
        return Scan(p, buf, values, bad, vstart, line, first, count, tag_hash, tag_start,
                    tag_end, comment=cm)
    out = _scan_numba(buf, has_tag, cm, p if progress and n > SCAN_SLICE else None)
    return Scan(p, buf, *out, comment=cm)


def _scan_numba(buf: np.ndarray, has_tag: bool, cm: int, label: str | None = None) -> tuple:
    """The numba scan in slices of ``SCAN_SLICE`` bytes (with ``label``, a progress bar naming it
    once the scan has taken ``BAR_DELAY`` seconds):
    ``(values, bad, tok_start, line, first, count, tag_hash, tag_start, tag_end)``."""
    n = buf.shape[0]
    lines, toks = _count(buf)  # exact-size outputs: no over-allocation, no copies
    values = np.empty(toks)
    slow = np.zeros(toks, dtype=np.int8)
    tok_start = np.empty(toks, dtype=np.int64)
    rec = [np.empty(lines, dtype=np.int64) for _ in range(3)]
    tags = ([np.zeros(lines, dtype=np.uint64), np.zeros(lines, dtype=np.int64),
             np.zeros(lines, dtype=np.int64)] if has_tag
            else [np.zeros(0, dtype=np.uint64), np.zeros(0, dtype=np.int64),
                  np.zeros(0, dtype=np.int64)])
    state = np.array([0, 0, 0, 1], dtype=np.int64)
    bar, start = None, time.perf_counter()
    try:
        while state[0] <= n:
            done = int(state[0])
            _scan_part(buf, min(done + SCAN_SLICE, n + 1), has_tag, cm, *_pow10(),
                       values, slow, tok_start, rec[0], rec[1], rec[2], tags[0], tags[1],
                       tags[2], state)
            if bar is None and label is not None and time.perf_counter() - start >= BAR_DELAY:
                bar, label = _progress_bar(n, label), None  # None without tqdm: not again
                done = 0  # the bar starts with what is scanned so far
            if bar is not None:
                bar.update(min(int(state[0]), n) - done)
    finally:
        if bar is not None:
            bar.close()
    nv, nr = int(state[1]), int(state[2])
    values, slow, tok_start = values[:nv], slow[:nv], tok_start[:nv]
    bad = slow == 2
    values[bad] = np.nan
    idx = np.nonzero(slow == 1)[0]
    if idx.shape[0] > 0:  # long mantissas, nan/inf, garbage
        starts = tok_start[idx]
        values[idx], bad[idx] = _parse_slow(buf, starts, _token_ends(buf, starts, cm))
    if has_tag:
        tags = [t[:nr] for t in tags]
    return (values, bad, tok_start, rec[0][:nr], rec[1][:nr], rec[2][:nr], tags[0], tags[1],
            tags[2])


def _progress_bar(total: int, path: str):
    """A byte-count progress bar, or None without tqdm."""
    try:
        from tqdm.auto import tqdm
    except ImportError:
        return None
    return tqdm(total=total, unit="B", unit_scale=True, unit_divisor=1024,
                desc=f"reading {os.path.basename(path)}", leave=False)
