"""The tokenizer of :mod:`fgopt.io._scan` as NumPy array passes (no numba).

Used on the NumPy backend and for files up to ``fgopt.io._scan.NUMPY_SCAN_MAX_BYTES`` while numba
is not in use in the process; its outputs equal the numba scan's (tests/core/test_numpy_backend.py).
"""

from __future__ import annotations

import numpy as np

_FNV_OFFSET = np.uint64(0xCBF29CE484222325)
_FNV_PRIME = np.uint64(0x100000001B3)

_IS_SPACE = np.zeros(256, dtype=bool)
_IS_SPACE[[9, 10, 11, 12, 13, 32]] = True
#: Per byte, one count field of the plain-decimal grammar ``[+-]digits[.digits]``: digits (bits
#: 0-7), '.' (8-15), '+' / '-' (16-23), anything else (24-31); summed over a token (shorter than
#: 256 bytes) they give its four counts at once.
_FIELD = np.full(256, 1 << 24, dtype=np.int32)
_FIELD[48:58] = 1
_FIELD[46] = 1 << 8
_FIELD[[43, 45]] = 1 << 16
_P10 = 10.0 ** np.arange(23)  # exact doubles
_SHORT_DIGITS = 4


def _scan_np(buf, has_tag, comment):
    """:func:`_scan` with NumPy array passes over the bytes (same outputs; values parsed by
    NumPy's string-to-float conversion, the grammar and rounding of ``float()``)."""
    n = buf.shape[0]
    nl = buf == 10
    line_id = np.cumsum(nl) - nl                      # line index of every byte ('\n': its line)
    sep = _IS_SPACE[buf]                              # ' ' \t \n \v \f \r
    if comment >= 0:
        is_c = buf == comment
        if is_c.any():
            cum = np.cumsum(is_c)
            line_start = np.concatenate(([0], np.nonzero(nl)[0] + 1))
            before = np.concatenate(([0], cum))[line_start]
            sep |= (cum - before[line_id]) > 0
    tok = ~sep
    edge = np.diff(np.concatenate(([False], tok, [False])).view(np.int8))
    start = np.nonzero(edge == 1)[0].astype(np.int64)
    end = np.nonzero(edge == -1)[0].astype(np.int64)
    tline = line_id[start]
    new_rec = np.ones(start.shape[0], dtype=bool)
    new_rec[1:] = tline[1:] != tline[:-1]
    rec_tok = np.nonzero(new_rec)[0]                  # first token of each record
    rec_line = tline[rec_tok] + 1
    num_rec = rec_tok.shape[0]
    if has_tag:
        tag_start, tag_end = start[rec_tok], end[rec_tok]
        is_val = ~new_rec
        h = np.full(num_rec, _FNV_OFFSET, dtype=np.uint64)
        tag_len = tag_end - tag_start
        for j in range(int(tag_len.max(initial=0))):
            on = j < tag_len
            byte = buf[np.minimum(tag_start + j, n - 1)].astype(np.uint64)
            h = np.where(on, (h ^ byte) * _FNV_PRIME, h)
        tag_hash = h
    else:
        tag_start = np.zeros(num_rec, np.int64)
        tag_end = np.zeros(num_rec, np.int64)
        tag_hash = np.zeros(num_rec, np.uint64)
        is_val = np.ones(start.shape[0], dtype=bool)
    vstart, vend = start[is_val], end[is_val]
    rec_of_tok = np.cumsum(new_rec) - 1
    count = np.bincount(rec_of_tok[is_val], minlength=num_rec).astype(np.int64)
    first = np.zeros(num_rec, np.int64)
    np.cumsum(count[:-1], out=first[1:])
    values, bad = parse_tokens(buf, vstart, vend)
    return values, bad, vstart, vend, rec_line, first, count, tag_hash, tag_start, tag_end


def parse_tokens(buf: np.ndarray, start: np.ndarray, end: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """``float(buf[start[i]:end[i]])`` of every token: ``(values, bad)``, ``bad`` where the
    token is not a number (its value NaN).

    Plain decimals (``[+-]digits[.digits]`` with a mantissa below 2**53 and at most 22 decimals,
    nearly every token of a pose-graph or BAL file) take array passes: the mantissa ``m`` and
    ``10**k`` are exact doubles, so ``m / 10**k`` is the correctly rounded value of the decimal
    (Clinger's fast path), which is what ``float()`` returns. The mantissa is a matrix-vector
    product of the digits (right-aligned, the dot skipped) with the powers of ten: every product
    and partial sum is an integer below 2**53, so exact in any order. Other tokens (exponents,
    long mantissas, ``nan``, garbage) go through NumPy's string conversion (``float()``'s grammar
    and rounding)."""
    m = start.shape[0]
    values = np.empty(m)
    bad = np.zeros(m, dtype=bool)
    if m == 0:
        return values, bad
    n = buf.shape[0]
    field = np.zeros(n + 1, dtype=np.int32)
    field[:n] = _FIELD[buf]
    bounds = np.empty(2 * m, dtype=np.int64)
    bounds[0::2], bounds[1::2] = start, end
    counts = np.add.reduceat(field, bounds)[0::2]  # sums over [start, end)
    length = end - start
    ndig, ndot = counts & 255, (counts >> 8) & 255
    nsign, nother = (counts >> 16) & 255, counts >> 24
    first = buf[start]
    plain = ((length < 256) & (nother == 0) & (ndig >= 1) & (ndig <= 17) & (ndot <= 1)
             & (nsign == ((first == 43) | (first == 45))))
    # decimals: the bytes after the dot (all digits in a plain token)
    decimals = np.zeros(m, dtype=np.int64)
    with_dot = np.flatnonzero(plain & (ndot == 1))
    dots = np.flatnonzero(buf == 46)
    decimals[with_dot] = end[with_dot] - 1 - dots[np.searchsorted(dots, start[with_dot])]
    plain &= decimals <= 22
    # tokens of few digits (a file's 0, 1, 10: a third to a half of a pose graph's) in their own
    # pass: the digit matrix is as wide as the pass's longest token
    short = ndig <= _SHORT_DIGITS
    for idx in (np.flatnonzero(plain & short), np.flatnonzero(plain & ~short)):
        if idx.shape[0]:
            v, exact = _plain_values(buf, end[idx], ndig[idx], ndot[idx], decimals[idx])
            values[idx] = np.where(first[idx] == 45, -v, v)
            plain[idx[~exact]] = False
    rest = np.flatnonzero(~plain)
    if rest.shape[0]:
        values[rest], bad[rest] = _parse_slow(buf, start[rest], end[rest])
    return values, bad


def _plain_values(buf: np.ndarray, end: np.ndarray, ndig: np.ndarray, ndot: np.ndarray,
                  decimals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``|value|`` of plain tokens ending at ``end`` (``ndig`` digits, ``ndot`` dots,
    ``decimals`` digits after the dot), and whether it is exact (mantissa below 2**53)."""
    small = np.int32 if buf.shape[0] < 2 ** 31 else np.int64
    width = int(ndig.max())
    # digit k from the right sits at byte end - 1 - k, one further left past the dot
    skip = decimals.astype(small)
    skip[ndot == 0] = width  # no dot: nothing to skip
    k = np.arange(width, dtype=small)
    pos = (end.astype(small) - 1)[:, None] - k - (k >= skip[:, None])
    dead = k >= ndig[:, None]
    pos[dead] = 0
    digits = buf[pos].astype(np.float64)
    digits -= 48.0
    digits[dead] = 0.0
    mant = digits @ _P10[:width]
    return mant / _P10[decimals], mant < 2.0 ** 53


def _parse_slow(buf: np.ndarray, start: np.ndarray, end: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`parse_tokens` by NumPy's string-to-float conversion (``float()``'s grammar)."""
    m = start.shape[0]
    n = buf.shape[0]
    values = np.empty(m)
    bad = np.zeros(m, dtype=bool)
    width = int((end - start).max())
    at = start[:, None] + np.arange(width)[None, :]
    chars = np.where(at < end[:, None], buf[np.minimum(at, n - 1)], 0).astype(np.uint8)
    # '_' or non-ASCII: float() would accept them, the fast scanner does not
    odd = ((chars == 95) | (chars > 127)).any(axis=1)
    toks = np.ascontiguousarray(chars).view(f"S{width}").reshape(-1)
    good = ~odd
    try:
        values[good] = toks[good].astype(float)
    except ValueError:
        for i in np.nonzero(good)[0].tolist():
            try:
                values[i] = float(toks[i])
            except ValueError:
                values[i], bad[i] = np.nan, True
    values[odd], bad[odd] = np.nan, True
    return values, bad
