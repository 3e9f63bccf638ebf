"""The numba tokenizer: records, tags, comments, and exact number parsing."""

from __future__ import annotations

import numpy as np
import pytest

from fgopt.errors import FileFormatError
from fgopt.io._scan import scan, tag_hash


def test_records_tags_comments_and_blank_lines():
    text = b"# header\nA 1 2.5 -3e-2\n\n  B 7 # trailing comment\r\nC\n   \nD 4"
    sc = scan("mem.txt", data=text)
    assert [sc.tag(r) for r in range(len(sc.line))] == ["A", "B", "C", "D"]
    assert sc.line.tolist() == [2, 4, 5, 7]
    assert sc.count.tolist() == [3, 1, 0, 1]
    assert sc.values.tolist() == [1.0, 2.5, -0.03, 7.0, 4.0]
    assert sc.tag_hash[0] == tag_hash("A")
    assert sc.line_of_value(3) == 4


def test_bad_tokens_are_flagged_and_reported_with_their_line():
    sc = scan("mem.txt", data=b"A 1 2\nB 3 x4 1_0 nan\n")
    assert sc.bad.tolist() == [False, False, False, True, True, False]
    with pytest.raises(FileFormatError, match=r"mem.txt:2: 'x4' is not a number"):
        sc.check_values()
    with pytest.raises(FileFormatError, match=r"mem.txt:2: 'nan' is not a finite number"):
        sc.check_finite(np.array([5]))


def test_numbers_equal_python_float_exactly():
    rng = np.random.default_rng(1)
    x = rng.standard_normal(20000) * 10.0 ** rng.integers(-40, 40, 20000)
    toks = [repr(float(v)) for v in x] + ["%.17e" % v for v in x[:3000]] + [
        "%.6f" % v for v in x[:3000]] + [
        "9007199254740993", "1e23", "123456789012345678e-5", "4.9e-324", "-0", "+.5", "5.",
        "1.7976931348623157e308", "2.2250738585072014e-308", "0.1e-400", "7E+2"]
    sc = scan("mem.txt", data=" ".join(toks).encode(), has_tag=False)
    ref = np.array([float(t) for t in toks])
    assert not sc.bad.any()
    assert np.array_equal(sc.values, ref)
    assert np.array_equal(np.signbit(sc.values), np.signbit(ref))


@pytest.mark.parametrize("tok", ["1e", ".", "-", "+e5", "1.2.3", "0x10", "1,5", "--1", "inf1",
                                 "\xe4", "1d5"])
def test_malformed_numbers_are_bad(tok):
    sc = scan("mem.txt", data=f"T {tok}".encode(), has_tag=True)
    assert sc.bad.tolist() == [True]


def test_missing_file_is_a_file_format_error(tmp_path):
    with pytest.raises(FileFormatError, match="no such file"):
        scan(tmp_path / "nope.g2o")


def test_sliced_scan_reports_progress_and_equals_one_pass(monkeypatch):
    """Large inputs are scanned in resumable slices (a progress bar between them): the result
    equals a one-slice scan, and the bar advances over every byte."""
    import fgopt.io._scan as S

    rng = np.random.default_rng(3)
    lines = [f"T{i % 3} {i} {rng.normal():.17g} # c\n" + ("\n" if i % 7 == 0 else "")
             for i in range(500)]
    data = "".join(lines).encode()
    whole = scan("mem.txt", data=data)

    class Bar:
        def __init__(self):
            self.n, self.closed = 0, False

        def update(self, k):
            self.n += k

        def close(self):
            self.closed = True

    bars = []
    monkeypatch.setattr(S, "SCAN_SLICE", 97)  # slices end mid-line and mid-token
    monkeypatch.setattr(S, "BAR_DELAY", 0.0)  # the bar appears after the first slice
    monkeypatch.setattr(S, "_progress_bar", lambda n, p: bars.append(Bar()) or bars[-1])
    sliced = scan("mem.txt", data=data)
    assert bars and bars[0].n == len(data) and bars[0].closed
    for name in ("values", "bad", "tok_start", "line", "first", "count", "tag_hash"):
        assert np.array_equal(getattr(sliced, name), getattr(whole, name)), name


def test_no_progress_bar_before_its_delay(monkeypatch):
    """A sliced scan that ends before ``BAR_DELAY`` seconds never makes a bar (tqdm's import
    is not paid by reads that end sooner)."""
    import fgopt.io._scan as S

    made = []
    monkeypatch.setattr(S, "SCAN_SLICE", 97)
    monkeypatch.setattr(S, "BAR_DELAY", 3600.0)
    monkeypatch.setattr(S, "_progress_bar", lambda n, p: made.append(n))
    data = "".join(f"T {i} {i * 0.5}\n" for i in range(200)).encode()
    sc = scan("mem.txt", data=data)
    assert sc.line.shape[0] == 200 and made == []


#: Plain decimals of at most 17 digits (leading zeros count) below 2**53: the array path.
_PLAIN = ["0", "-0", "+0.0", "-0.000", ".5", "5.", "+.5", "-5.", "00012", "1.030390", "-0.012958",
          "44.721360", "9007199254740991", "900719925474099.1", "0.9007199254740991",
          "0.0000000000000001", ".0000000000000009"]
#: Exponents, mantissas of 2**53 and above, more digits, nan / inf, garbage: NumPy's conversion.
_SLOW = ["9007199254740992", "9007199254740993", "12345678901234567", "1e5", "7E+2", "nan",
         "-inf", "1.5e-300", "0.00000000000000000000001", "123.456789012345678901", "1_0", "x4",
         "1.2.3", "+-1", "-", "."]


def test_numpy_token_parser_equals_float_and_takes_the_array_path_for_plain_decimals(
        monkeypatch):
    """``parse_tokens`` (the NumPy scan's number parser) gives ``float(token)`` bit for bit
    (signed zeros included) or ``bad`` where ``float`` refuses the token; plain decimals with a
    mantissa up to 2**53 and up to 22 decimals are parsed by its array path, everything else
    (exponents, longer mantissas, nan, garbage) by NumPy's string conversion."""
    from fgopt.io import _scan_np

    rng = np.random.default_rng(3)
    x = rng.standard_normal(5000) * 10.0 ** rng.integers(-6, 9, 5000)
    toks = _PLAIN + _SLOW + ["%.6f" % v for v in x] + [repr(float(v)) for v in x]
    data = (" ".join(toks) + "\n").encode()
    buf = np.frombuffer(data, dtype=np.uint8)
    ends = np.flatnonzero(np.frombuffer(data, np.uint8) == 32).tolist() + [len(data) - 1]
    start = np.array([0] + [e + 1 for e in ends[:-1]], dtype=np.int64)
    end = np.array(ends, dtype=np.int64)
    slow_calls = []
    real_slow = _scan_np._parse_slow

    def spy(b, s, e):
        slow_calls.extend(bytes(b[i:j]).decode("latin-1") for i, j in zip(s.tolist(), e.tolist()))
        return real_slow(b, s, e)

    monkeypatch.setattr(_scan_np, "_parse_slow", spy)
    values, bad = _scan_np.parse_tokens(buf, start, end)
    for tok, v, b in zip(toks, values.tolist(), bad.tolist()):
        try:
            ref = float(tok)
        except ValueError:
            ref = None
        if ref is None or "_" in tok:  # float() takes '1_0'; the scanners do not
            assert b, tok
        else:
            assert not b and np.float64(v).tobytes() == np.float64(ref).tobytes(), tok
    assert set(_SLOW) <= set(slow_calls)
    assert not set(_PLAIN + ["%.6f" % v for v in x]) & set(slow_calls)
