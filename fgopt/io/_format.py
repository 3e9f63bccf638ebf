"""Text records for the writers, built in bulk: ``"TAG id ... x ...\\n"`` per row of arrays.

:func:`format_rows` gives exactly what ``f"{tag} {' '.join(map(str, ids))} {' '.join(map(repr,
nums))}"`` gives per row (``repr``: the shortest text that reads back to the same float), without
a Python step per row or per short number:

* a column whose numbers are all equal (an information matrix's zeros, a uniform diagonal) is
  formatted once;
* a number whose ``repr`` is positional with at most 15 significant digits (what files and
  measurements mostly hold: ``1.03039``, ``-0.0416997``, ``400.0``) is formatted by array passes
  (:func:`decimal_texts`);
* the rest (16-17 digit results of arithmetic, tiny or huge magnitudes) go through ``repr``,
  each distinct one once;
* lines are assembled by one gather over the distinct texts.

Non-finite numbers are refused: no reader of these formats takes ``inf`` or ``nan`` back.
"""

from __future__ import annotations

import numpy as np

from ..errors import FgoptError

_P10 = 10.0 ** np.arange(19)  # exact doubles (10**22 is the largest exact power of ten)
_I10 = 10 ** np.arange(19, dtype=np.int64)
#: At most this many significant digits on the array path: below 10**15 a double's rounding
#: interval (half an ulp each side, under 2**-53 relative) holds at most one decimal with that
#: many digits, so the decimal found is the one ``repr`` picks.
_DIGITS = 15


def decimal_texts(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``repr`` of the numbers of ``x`` (1-D float64) that it writes positionally with at most
    15 significant digits, by array passes.

    Returns ``(ok, text)``: ``ok[i]`` whether ``x[i]`` is such a number (``1e-4 <= |x| < 1e15``,
    or zero), and for those rows of ``text`` (``(ok.sum(), width)`` uint8) the ASCII of
    ``repr(x[i])`` padded with zero bytes.

    Why it equals ``repr``: with ``y = rint(|x| * 10**d)`` (15 significant digits) the decimal
    ``y / 10**d`` reads back as ``x`` exactly when the double division ``y / 10**d`` equals
    ``|x|`` (``y < 2**53`` and ``10**d`` are exact, and IEEE division rounds correctly, as
    ``float()`` does). That decimal is the only one with at most 15 digits that reads back as
    ``x``, so ``repr`` (the shortest, nearest) is it with its trailing zeros dropped.
    """
    x = np.asarray(x, dtype=np.float64)
    a = np.abs(x)
    zero = a == 0.0
    ok = (a >= 1e-4) & (a < 1e15)
    a_ok = np.where(ok, a, 0.0)  # zeros give y = 0
    e = np.floor(np.log10(np.where(ok, a, 1.0))).astype(np.int64)
    # log10 may round up across a power of ten (99999999999999.9 -> 14): e is a's exponent
    e -= np.where(e >= 0, a_ok < _P10[np.maximum(e, 0)], a_ok * _P10[np.maximum(-e, 0)] < 1.0)
    d = np.clip(_DIGITS - 1 - e, 0, 18)
    y = np.rint(a_ok * _P10[d])
    d -= ok & (y >= 10.0 ** _DIGITS) & (d > 0)  # (or down: one digit too many)
    y = np.rint(a_ok * _P10[d])
    ok &= (y < 10.0 ** _DIGITS) & (y / _P10[d] == a)
    ok |= zero
    sel = np.flatnonzero(ok)
    y = y[sel].astype(np.int64)
    d = np.where(zero[sel], 0, d[sel])
    neg = np.signbit(x[sel])
    # drop trailing zeros of y (at most d of them): y = Y * 10**(d - D), D decimals remain
    q, tz = y.copy(), np.zeros(sel.shape[0], dtype=np.int64)
    for k in (8, 4, 2, 1):
        hit = (q % _I10[k] == 0) & (q != 0)
        q = np.where(hit, q // _I10[k], q)
        tz += k * hit
    drop = np.minimum(tz, d)
    Y, D = y // _I10[drop], d - drop
    # text: ['-'] int digits '.' D fraction digits (one '0' when D == 0); built right to left
    Z = np.where(D == 0, Y * 10, Y)
    nf = np.maximum(D, 1)
    ni = np.maximum(np.searchsorted(_I10, Y // _I10[D], side="right"), 1)
    length = neg + ni + 1 + nf
    width = int(length.max(initial=1))
    text = np.zeros((sel.shape[0], width), dtype=np.uint8)
    rows = np.arange(sel.shape[0])
    for i in range(width):  # i: position from the right end of each text
        col = length - 1 - i
        live = col >= 0
        digit = live & (i != nf) & (i < nf + 1 + ni)
        r, c = rows[digit], col[digit]
        text[r, c] = (Z[digit] % 10 + 48).astype(np.uint8)
        Z = np.where(digit, Z // 10, Z)
        dot = i == nf
        text[rows[dot], col[dot]] = 46
        sign = live & neg & (i == nf + 1 + ni)
        text[rows[sign], col[sign]] = 45
    return ok, text


def _distinct(a: np.ndarray) -> np.ndarray:
    """The sorted distinct values of a 1-D integer array. (``np.unique`` without an inverse
    imports ``numpy.ma``, ~5 ms of a new process; with one it argsorts, slower than a sort.)"""
    s = np.sort(a)
    keep = np.ones(s.shape[0], dtype=bool)
    np.not_equal(s[1:], s[:-1], out=keep[1:])
    return s[keep]


def format_rows(tag: str, ids: np.ndarray, nums: np.ndarray) -> bytes:
    """``n`` lines ``tag ids[i, 0] ... nums[i, 0] ...`` (ASCII, each ending in ``\\n``).

    ``ids``: ``(n, k)`` integers (written with ``str``); ``nums``: ``(n, c)`` finite floats
    (written as ``repr`` writes them). ``k`` or ``c`` may be 0.
    """
    ids = np.asarray(ids, dtype=np.int64)
    nums = np.asarray(nums, dtype=np.float64)
    n, c = nums.shape
    k = ids.shape[1]
    if ids.shape[0] != n:
        raise ValueError(f"format_rows: {ids.shape[0]} id rows for {n} number rows")
    if n == 0:
        return b""
    finite = np.isfinite(nums)
    if not finite.all():
        r, col = (int(a[0]) for a in np.nonzero(~finite))
        raise FgoptError(f"{tag} record {r} has a non-finite number ({nums[r, col]!r}); "
                         "the file could not be read back")
    # Tokens, each with an index into one text buffer: the tag, the distinct ids, one per
    # constant column, then every other number (repr'd ones first, array-formatted ones last).
    u_ids = _distinct(ids.reshape(-1))
    id_tok = np.searchsorted(u_ids, ids.reshape(-1))
    texts = [tag, *map(str, u_ids.tolist())]
    bits = np.ascontiguousarray(nums).view(np.int64)
    const = (bits == bits[0]).all(axis=0)
    seq = np.empty((n, 1 + k + c), dtype=np.int64)  # token of each field, row by row
    seq[:, 0] = 0
    seq[:, 1:1 + k] = 1 + id_tok.reshape(n, k)
    const_cols = np.flatnonzero(const)
    seq[:, 1 + k + const_cols] = len(texts) + np.arange(const_cols.shape[0])
    texts += map(repr, nums[0, const_cols].tolist())
    vary = np.flatnonzero(~const)
    fast_text = np.zeros((0, 1), dtype=np.uint8)
    if vary.shape[0]:
        v = nums[:, vary].reshape(-1)
        fast, fast_text = decimal_texts(v)
        slow = np.flatnonzero(~fast)
        tok = np.empty(v.shape[0], dtype=np.int64)
        slow_bits = v[slow].view(np.int64)
        distinct = _distinct(slow_bits)
        tok[slow] = len(texts) + np.searchsorted(distinct, slow_bits)
        texts += map(repr, distinct.view(np.float64).tolist())
        tok[fast] = len(texts) + np.arange(fast_text.shape[0])
        seq[:, 1 + k + vary] = tok.reshape(n, vary.shape[0])
    # fast texts: pad bytes dropped, a space after each (its first pad byte, or a new column)
    ft = np.zeros((fast_text.shape[0], fast_text.shape[1] + 1), dtype=np.uint8)
    ft[:, :-1] = fast_text
    ft[np.arange(ft.shape[0]), (fast_text != 0).sum(axis=1)] = 32
    vocab = np.frombuffer((" ".join(texts) + " ").encode("ascii") + ft[ft != 0].tobytes(),
                          dtype=np.uint8)
    ends = np.flatnonzero(vocab == 32)  # the space after each token (none has one inside)
    starts = np.empty_like(ends)
    starts[0] = 0
    starts[1:] = ends[:-1] + 1
    seq = seq.reshape(-1)
    tok_start = starts[seq]
    length = ends[seq] - tok_start + 1  # with the separator after it
    out_end = np.cumsum(length)
    # byte j of the output copies vocab[starts[token] + (j - out_start[token])]
    src = np.repeat(tok_start - (out_end - length), length)
    src += np.arange(out_end[-1])
    out = vocab[src]
    out[out_end[k + c::1 + k + c] - 1] = 10  # each row's last separator: a newline
    return out.tobytes()
