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
- per value ``v``: ``values[v]``, ``bad[v]`` (True when the token is not a number) and its byte
  span ``tok_start[v]:tok_end[v]`` for error messages.
"""

from __future__ import annotations

import bz2
import gzip
import math
import os
import zlib
from dataclasses import dataclass

from .._jit import njit
import numpy as np

from ..errors import FileFormatError

_FNV_OFFSET = np.uint64(0xCBF29CE484222325)
_FNV_PRIME = np.uint64(0x100000001B3)
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
_P10_HI, _P10_LO = _pow10_table()


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


@njit(cache=True)
def _parse_number(buf, s, e, p10_hi, p10_lo):
    """Parse ``buf[s:e]``; returns ``(value, ok)``. ``ok`` False: let Python decide."""
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
    while j < e and 48 <= buf[j] <= 57:
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
    if j < e and buf[j] == 46:  # '.'
        j += 1
        while j < e and 48 <= buf[j] <= 57:
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
    if digits == 0:
        return 0.0, False
    if j < e and (buf[j] == 101 or buf[j] == 69):  # 'e' 'E'
        j += 1
        eneg = False
        if j < e and (buf[j] == 45 or buf[j] == 43):
            eneg = buf[j] == 45
            j += 1
        edigits = 0
        ex = 0
        while j < e and 48 <= buf[j] <= 57:
            if ex < 100000:
                ex = ex * 10 + (buf[j] - 48)
            edigits += 1
            j += 1
        if edigits == 0:
            return 0.0, False
        exp10 += -ex if eneg else ex
    if j != e or not exact:
        return 0.0, False
    if m == 0:
        return (-0.0 if neg else 0.0), True
    v, ok = _scale_exact(m, exp10, p10_hi, p10_lo)
    return (-v if neg else v), ok


@njit(cache=True)
def _scan(buf, has_tag, comment, p10_hi, p10_lo):
    n = buf.shape[0]
    num_lines = 1
    for i in range(n):
        if buf[i] == 10:
            num_lines += 1
    max_tok = n // 2 + 1
    values = np.empty(max_tok)
    slow = np.zeros(max_tok, dtype=np.int8)
    tok_start = np.empty(max_tok, dtype=np.int64)
    tok_end = np.empty(max_tok, dtype=np.int64)
    rec_line = np.empty(num_lines, dtype=np.int64)
    rec_first = np.empty(num_lines, dtype=np.int64)
    rec_count = np.empty(num_lines, dtype=np.int64)
    tag_hash = np.zeros(num_lines, dtype=np.uint64)
    tag_start = np.zeros(num_lines, dtype=np.int64)
    tag_end = np.zeros(num_lines, dtype=np.int64)
    nv = 0
    nr = 0
    line = 1
    i = 0
    while i <= n:
        line_end = i
        while line_end < n and buf[line_end] != 10:
            line_end += 1
        stop = line_end
        if comment >= 0:
            for j in range(i, line_end):
                if buf[j] == comment:
                    stop = j
                    break
        j = i
        started = False
        need_tag = has_tag
        while True:
            while j < stop and _is_space(buf[j]):
                j += 1
            if j >= stop:
                break
            s = j
            while j < stop and not _is_space(buf[j]):
                j += 1
            if not started:
                started = True
                rec_line[nr] = line
                rec_first[nr] = nv
            if need_tag:
                need_tag = False
                h = _FNV_OFFSET
                for q in range(s, j):
                    h = (h ^ np.uint64(buf[q])) * _FNV_PRIME
                tag_hash[nr] = h
                tag_start[nr] = s
                tag_end[nr] = j
                rec_first[nr] = nv
                continue
            v, ok = _parse_number(buf, s, j, p10_hi, p10_lo)
            values[nv] = v
            if not ok:
                slow[nv] = 1
                for q in range(s, j):
                    if buf[q] == 95 or buf[q] > 127:  # '_' or non-ASCII: float() is too lax
                        slow[nv] = 2
            tok_start[nv] = s
            tok_end[nv] = j
            nv += 1
        if started:
            rec_count[nr] = nv - rec_first[nr]
            nr += 1
        line += 1
        i = line_end + 1
    return (values[:nv], slow[:nv], tok_start[:nv], tok_end[:nv], rec_line[:nr], rec_first[:nr],
            rec_count[:nr], tag_hash[:nr], tag_start[:nr], tag_end[:nr])


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
    tok_end: np.ndarray
    line: np.ndarray
    first: np.ndarray
    count: np.ndarray
    tag_hash: np.ndarray
    tag_start: np.ndarray
    tag_end: np.ndarray

    def token(self, v: int) -> str:
        return _text(self.buf[self.tok_start[v]:self.tok_end[v]])

    def tag(self, r: int) -> str:
        return _text(self.buf[self.tag_start[r]:self.tag_end[r]])

    def line_of_value(self, v: int) -> int:
        r = int(np.searchsorted(self.first, v, side="right")) - 1
        return int(self.line[max(r, 0)])

    def error(self, message: str, line: int | None) -> FileFormatError:
        return FileFormatError(message, self.path, None if line is None else int(line))

    def check_values(self, which: np.ndarray | None = None) -> None:
        """Raise for the first non-number token (among ``which`` value indices, default all)."""
        bad = self.bad if which is None else self.bad[which]
        if bad.any():
            v = int(np.nonzero(bad)[0][0]) if which is None else int(which[np.nonzero(bad)[0][0]])
            raise self.error(f"{self.token(v)!r} is not a number", self.line_of_value(v))

    def check_finite(self, which: np.ndarray) -> None:
        """Raise for the first NaN / inf value among value indices ``which``."""
        vals = self.values[which]
        fin = np.isfinite(vals)
        if not fin.all():
            v = int(which[np.nonzero(~fin)[0][0]])
            raise self.error(f"{self.token(v)!r} is not a finite number", self.line_of_value(v))


def _text(b: np.ndarray) -> str:
    return bytes(b).decode("utf-8", errors="replace")


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
    """Write ``text``; ``.gz`` / ``.bz2`` paths are compressed."""
    p = os.fspath(path)
    data = text.encode("utf-8")
    opener = bz2.open if p.endswith(".bz2") else gzip.open if p.endswith(".gz") else open
    with opener(p, "wb") as f:
        f.write(data)


def scan(path: str | os.PathLike, data: bytes | None = None, has_tag: bool = True,
         comment: str | None = "#") -> Scan:
    """Tokenize ``path`` (or ``data``, its bytes); see the module docstring."""
    p = os.fspath(path)
    if data is None:
        data = read_bytes(p)
    buf = np.frombuffer(data, dtype=np.uint8)
    out = _scan(buf, has_tag, -1 if comment is None else ord(comment), _P10_HI, _P10_LO)
    values, slow = out[0].copy(), out[1]
    bad = slow == 2
    values[bad] = np.nan
    idx = np.nonzero(slow == 1)[0]
    if idx.shape[0] > 0:  # long mantissas (17-digit repr), nan/inf, garbage
        values[idx], bad[idx] = _parse_slow(buf, out[2][idx], out[3][idx])
    return Scan(p, buf, values, bad, out[2], out[3], out[4], out[5], out[6], out[7], out[8],
                out[9])
