"""Where the file-record memory of :mod:`fgopt.io._records` finds a token's end."""

from __future__ import annotations

import numpy as np

from fgopt.io._records import token_ends


def _reference(text: bytes, start: int, comment: int) -> int:
    j = start
    while j < len(text) and text[j] not in b" \t\n\r\v\f" and text[j] != comment:
        j += 1
    return j


def test_token_ends_match_a_byte_by_byte_scan():
    """Every token's end is the first whitespace, line end or comment byte after it (or the
    end of the text), for tokens shorter and longer than the search window, with and without a
    comment character."""
    rng = np.random.default_rng(3)
    pieces = []
    for _ in range(400):
        width = int(rng.choice([1, 5, 17, 47, 48, 49, 120]))
        pieces.append(bytes(rng.choice(list(b"0123456789.-e"), width).tolist()))
        pieces.append(bytes(rng.choice(list(b" \t\n\r#"), int(rng.integers(1, 3))).tolist()))
    text = b"".join(pieces) + b"12345678901234567890123456789012345678901234567890123"
    buf = np.frombuffer(text, dtype=np.uint8)
    is_sep = np.isin(buf, list(b" \t\n\r#"))
    starts = np.flatnonzero(~is_sep & np.concatenate(([True], is_sep[:-1])))
    for comment in (ord("#"), -1):
        want = [_reference(text, s, comment) for s in starts.tolist()]
        assert token_ends(buf, starts, comment, window=16).tolist() == want
        assert token_ends(buf, starts, comment).tolist() == want
