"""The writers' bulk line formatter (:mod:`fgopt.io._format`) writes what ``str`` / ``repr`` per
number would, and a written g2o file reads back to the same numbers, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from fgopt import SE2, FactorGraph, Variables
from fgopt.errors import FgoptError
from fgopt.io import read_g2o, write_g2o
from fgopt.io import _records
from fgopt.io._format import decimal_texts, format_rows

EDGE_CASES = [0.0, -0.0, 1.0, -1.0, 5.0, 0.1, 0.30000000000000004, 1e-4, -1e-4,
              9.999999999999999e-05, 0.00010000000000000002, 1e-5, 1e-300, 5e-324,
              -2.2250738585072014e-308, 1e14, 99999999999999.9, 999999999999999.0, 1e15,
              123456789012345.6, 1e16, 1e22, 1e23, 1.7976931348623157e308, 2.0 ** 53,
              44.721360000000004, 44.72136, 0.00193512, -0.0416997, 10.000000000000002,
              400.0210000000001, 1234.5, 0.000123456789012345]


def _reference(tag: str, ids: np.ndarray, nums: np.ndarray) -> bytes:
    return "".join(" ".join([tag, *map(str, i), *map(repr, r)]) + "\n"
                   for i, r in zip(ids.tolist(), nums.tolist())).encode()


def _numbers(rng: np.random.Generator, n: int) -> np.ndarray:
    """Short decimals, 17-digit results of arithmetic, and magnitudes from 1e-320 to 1e300."""
    x = rng.standard_normal(n) * 10.0 ** rng.integers(-8, 16, n)
    scale = 10.0 ** rng.integers(0, 9, n)
    short = np.rint(x * scale) / scale  # 0 to 8 decimals
    wide = rng.standard_normal(n) * 10.0 ** rng.uniform(-320, 300, n)
    return np.concatenate([x, short, wide, EDGE_CASES, np.negative(EDGE_CASES)])


def test_decimal_texts_equal_repr_and_cover_short_decimals():
    """The array path's text is ``repr``'s wherever it claims a number, and it claims every
    nonzero number of at most 15 significant digits in [1e-4, 1e15), and zeros."""
    rng = np.random.default_rng(0)
    x = _numbers(rng, 20000)
    ok, text = decimal_texts(x)
    got = [bytes(row[row != 0]).decode() for row in text]
    assert got == [repr(v) for v in x[ok].tolist()]
    a = np.abs(x)
    short = [len(repr(v).replace("-", "").replace(".", "").lstrip("0")) <= 15
             for v in x.tolist()]
    expect = (a == 0) | ((a >= 1e-4) & (a < 1e15) & np.array(short)
                         & np.array(["e" not in repr(v) for v in x.tolist()]))
    # repr of an integral value ends in ".0", one more digit than the number has
    integral = (x == np.round(x)) & (a >= 1) & (a < 1e15)
    assert np.array_equal(ok | integral, expect | integral)
    assert ok[integral].all()


@pytest.mark.parametrize("k,c", [(2, 9), (1, 3), (0, 4), (3, 0), (2, 30)])
def test_format_rows_equals_str_and_repr_per_row(k, c):
    """Lines equal the per-row ``f"{tag} {ids} {reprs}"``: constant columns (zeros, a uniform
    diagonal), columns of -0.0 and 0.0 (told apart), repeated long numbers, short decimals."""
    rng = np.random.default_rng(k * 100 + c)
    n = 300
    nums = rng.choice(_numbers(rng, 2000), size=(n, c))
    if c >= 4:
        nums[:, 1] = 0.0
        nums[:, 2] = 44.721360000000004
        nums[::3, 3] = -0.0
    ids = rng.integers(0, 10 ** 12, size=(n, k))
    assert format_rows("EDGE_X", ids, nums) == _reference("EDGE_X", ids, nums)
    assert format_rows("T", ids[:0], nums[:0]) == b""


@pytest.mark.parametrize("bad", [np.inf, -np.inf, np.nan])
def test_format_rows_refuses_non_finite_numbers(bad):
    """A file with inf or nan could not be read back: the record is named instead."""
    nums = np.ones((4, 3))
    nums[2, 1] = bad
    with pytest.raises(FgoptError, match=r"EDGE_SE2 record 2 has a non-finite number"):
        format_rows("EDGE_SE2", np.zeros((4, 2), np.int64), nums)


def _rebuilt(graph: FactorGraph) -> FactorGraph:
    """The same factors in new batch objects (equal arrays)."""
    out = FactorGraph(graph.factors)
    for b in graph.batches:
        out.add_batch(b.kernel, b.keys.copy(), b.constants.copy(),
                      None if b.sqrt_information is None else b.sqrt_information.copy(),
                      b.loss_code, b.loss_param, b.origin, loss_shape=b.loss_shape)
    return out


@pytest.mark.parametrize("rel", ["pose2d/input_M3500_g2o.g2o", "pose3d/sphere2500.g2o"])
def test_written_file_holds_the_exact_numbers_and_reads_back(data_file, tmp_path, rel):
    """After a perturbation that makes every pose 17-digit, each number of the file parses
    (``float``) to the bits of the number written (vertex file vectors, edge measurements and
    information), the lines are the per-number ``repr`` lines, and reading the file back gives
    the same values and graph."""
    from fgopt.io import _information as im
    from fgopt.io._poses import se2_file, se3_file

    read_graph, values = read_g2o(data_file(rel), keep_edge_text=True)
    graph = _rebuilt(read_graph)  # new batches: formatted, not the file's own records
    rng = np.random.default_rng(5)
    moved = Variables()
    for k, x in values.items():
        moved.add(k, x.retract(rng.standard_normal(x.dim()) * 1e-3))
    write_g2o(tmp_path / "out.g2o", graph, moved)
    lines = (tmp_path / "out.g2o").read_bytes().decode().splitlines()
    vals = list(moved.values())
    storage = np.array([x.to_storage() for x in vals])
    is2d = isinstance(vals[0], SE2)
    file_vec = se2_file(storage) if is2d else se3_file(storage)
    ids = np.array([int(k) & ((1 << 56) - 1) for k in moved.keys()])[:, None]
    tag = "VERTEX_SE2" if is2d else "VERTEX_SE3:QUAT"
    want_vertices = _reference(tag, ids, file_vec).decode().splitlines()
    assert lines[:len(vals)] == want_vertices
    b = graph.batches[0]
    perm = im.inverse_permutation(im.PERM_SE2 if is2d else im.PERM_SE3)
    info = im.pack_upper(im.permute(im.information_of(b.sqrt_information), perm))
    meas = se2_file(b.constants) if is2d else se3_file(b.constants)
    nums = np.array([[float(t) for t in ln.split()[3:]] for ln in lines[len(vals):]])
    assert np.array_equal(nums.view(np.int64), np.hstack([meas, info]).view(np.int64))
    graph2, back = read_g2o(tmp_path / "out.g2o")
    assert back == moved
    assert graph2.error(back) == pytest.approx(graph.error(moved), rel=1e-12)


_ODD_LAYOUT = """# a 2D graph with comments, CRLF line ends, tabs and a TORO edge
VERTEX_SE2 0 0 0 0\r
VERTEX_SE2 1 1.0 0 0.1
VERTEX_SE2 2 2.0 0.5 0.2   # trailing comment
VERTEX_XY 7 1.5 1.5
EDGE_SE2 0 1\t1.0 0 0.1 100 0 0 100 0 400\r
EDGE2 1 2 1.0 0.5 0.1 50 0 50 300 0 0
EDGE_SE2 1 2 1.00000 0.5 0.1 100 0 0 100 0 400 # it continues here
EDGE_SE2_XY 1 7 0.5 1.5 10 0 10
EDGE_SE2 0 2 2.0 0.5 0.2 1e2 0 0 100 0 400
"""


def test_edges_read_from_a_file_are_written_back_as_the_file_had_them(tmp_path):
    """Solving changes vertices, not edges: a batch read from a file and left as it was is
    written as the file's own records (tag to last number: no comments, no CR, in row order),
    whatever its line ends and separators; TORO's EDGE2 is still formatted as EDGE_SE2. A batch
    whose arrays changed (in place or replaced) is formatted from its arrays. Every written
    file reads back to the graph written."""
    src = tmp_path / "odd.g2o"
    src.write_bytes(_ODD_LAYOUT.encode())
    graph, values = read_g2o(src, keep_edge_text=True)
    write_g2o(tmp_path / "out.g2o", graph, values)
    out = (tmp_path / "out.g2o").read_bytes().decode()
    assert "\r" not in out and "#" not in out
    edges = [ln for ln in out.splitlines() if ln.startswith("EDGE")]
    assert edges[:3] == ["EDGE_SE2 0 1\t1.0 0 0.1 100 0 0 100 0 400",
                         "EDGE_SE2 1 2 1.00000 0.5 0.1 100 0 0 100 0 400",
                         "EDGE_SE2 0 2 2.0 0.5 0.2 1e2 0 0 100 0 400"]
    assert edges[3].startswith("EDGE_SE2 1 2 ")  # EDGE2, formatted in g2o's order
    assert np.allclose([float(t) for t in edges[3].split()[3:]],
                       [1.0, 0.5, 0.1, 50, 0, 0, 50, 0, 300], rtol=1e-14, atol=1e-14)
    assert edges[4] == "EDGE_SE2_XY 1 7 0.5 1.5 10 0 10"
    graph2, values2 = read_g2o(tmp_path / "out.g2o")
    assert values2 == values
    assert graph2.error(values) == pytest.approx(graph.error(values), rel=1e-14)

    # in place: the EDGE_SE2 batch's measurement of row 1, x 1.0 -> 1.25 (storage: c, s, x, y)
    b = next(b for b in graph.batches if len(b) == 3)
    b.constants[1, 2] += 0.25
    write_g2o(tmp_path / "changed.g2o", graph, values)
    changed = [ln for ln in (tmp_path / "changed.g2o").read_text().splitlines()
               if ln.startswith("EDGE_SE2 ")]
    assert changed[0].startswith("EDGE_SE2 0 1 1.0 0.0 ")  # the batch is formatted
    assert float(changed[1].split()[3]) == 1.25
    graph3, _ = read_g2o(tmp_path / "changed.g2o")
    assert graph3.error(values) == pytest.approx(graph.error(values), rel=1e-14)
    # replaced: new arrays with the file's contents are the same records again
    b.constants = b.constants.copy()
    b.constants[1, 2] -= 0.25
    write_g2o(tmp_path / "again.g2o", graph, values)
    assert (tmp_path / "again.g2o").read_bytes() == (tmp_path / "out.g2o").read_bytes()
    # without keep_edge_text (the default) nothing is kept: every batch is formatted
    plain, _ = read_g2o(src)
    write_g2o(tmp_path / "plain.g2o", plain, values)
    assert "EDGE_SE2 0 1\t" not in (tmp_path / "plain.g2o").read_text()
    assert not any(b in _records._table for b in plain.batches)


def test_repaired_information_is_written_as_repaired(tmp_path):
    """Edges whose information was repaired on reading are written with the repaired numbers,
    not the file's (the file's text would read back to a different graph)."""
    src = tmp_path / "bad.g2o"
    src.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\n"
                   "EDGE_SE2 0 1 1 0 0 100 0 0 -1 0 400\n")
    graph, values = read_g2o(src, repair_information="clip", keep_edge_text=True)
    write_g2o(tmp_path / "out.g2o", graph, values)
    edge = (tmp_path / "out.g2o").read_text().splitlines()[-1]
    assert edge != "EDGE_SE2 0 1 1 0 0 100 0 0 -1 0 400"
    graph2, _ = read_g2o(tmp_path / "out.g2o")
    assert graph2.error(values) == pytest.approx(graph.error(values), rel=1e-12)
