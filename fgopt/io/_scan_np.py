"""The tokenizer of :mod:`fgopt.io._scan` as NumPy array passes (no numba).

Used on the NumPy backend and for files up to ``fgopt.io._scan.NUMPY_SCAN_MAX_BYTES`` while numba
is not in use in the process; its outputs equal the numba scan's (tests/core/test_numpy_backend.py).
"""

from __future__ import annotations

import numpy as np

_FNV_OFFSET = np.uint64(0xCBF29CE484222325)
_FNV_PRIME = np.uint64(0x100000001B3)


def _scan_np(buf, has_tag, comment):
    """:func:`_scan` with NumPy array passes over the bytes (same outputs; values parsed by
    NumPy's string-to-float conversion, the grammar and rounding of ``float()``)."""
    n = buf.shape[0]
    nl = buf == 10
    line_id = np.cumsum(nl) - nl                      # line index of every byte ('\n': its line)
    sep = nl | (buf == 32) | (buf == 9) | (buf == 13) | (buf == 11) | (buf == 12)
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
    m = vstart.shape[0]
    values = np.empty(m)
    bad = np.zeros(m, dtype=bool)
    if m:
        width = int((vend - vstart).max())
        at = vstart[:, None] + np.arange(width)[None, :]
        chars = np.where(at < vend[:, None], buf[np.minimum(at, n - 1)], 0).astype(np.uint8)
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
    return values, bad, vstart, vend, rec_line, first, count, tag_hash, tag_start, tag_end
