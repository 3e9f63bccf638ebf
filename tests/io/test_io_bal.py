"""BAL reading / writing on small synthetic files."""

from __future__ import annotations

import numpy as np
import pytest

from fgopt import key
from fgopt.errors import FgoptError, FileFormatError
from fgopt.io import read, read_bal, write_bal, write_g2o

BAL = """2 3 4

0 0 -1.0 2.0
1 0 3.5e+00 -4.0
1 2 0.5 0.25
0 1 1 1

0.01
-0.02
0.03
0.1
0.2
-5
500
1e-3
-2e-6
0 0 0 0 0 -6 400 0 0
1 2 3
-1 0.5 0.25
0 0 1
"""


def _write(tmp_path, text, name="p.txt"):
    p = tmp_path / name
    p.write_text(text)
    return p


def _snavely(cam, X):
    th = np.linalg.norm(cam[:3])
    k = cam[:3] / th if th > 0 else np.zeros(3)
    RX = (X * np.cos(th) + np.cross(k, X) * np.sin(th) + k * (k @ X) * (1 - np.cos(th))
          if th > 0 else X)
    P = RX + cam[3:6]
    p = -P[:2] / P[2]
    r2 = p @ p
    return cam[6] * (1 + cam[7] * r2 + cam[8] * r2 * r2) * p


def test_read_bal_values_keys_and_standard_cost(tmp_path):
    graph, values = read_bal(_write(tmp_path, BAL))
    assert values.keys() == [key("c", 0), key("c", 1), key("p", 0), key("p", 1), key("p", 2)]
    assert np.allclose(values.at(key("c", 1)), [0, 0, 0, 0, 0, -6, 400, 0, 0])
    assert np.allclose(values.at(key("p", 2)), [0, 0, 1])
    (b,) = graph.batches
    assert b.keys.tolist() == [[key("c", 0), key("p", 0)], [key("c", 1), key("p", 0)],
                               [key("c", 1), key("p", 2)], [key("c", 0), key("p", 1)]]
    assert b.sqrt_information is None
    assert b._where(0).endswith("p.txt:3") and b._where(3).endswith("p.txt:6")
    expected = 0.0
    for (ci, pj), m in zip([(0, 0), (1, 0), (1, 2), (0, 1)], b.constants):
        e = _snavely(values.at(key("c", ci)), values.at(key("p", pj))) - m
        expected += 0.5 * e @ e
    assert graph.error(values) == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize("suffix", ["", ".gz", ".bz2"])
def test_round_trip_plain_and_compressed(tmp_path, suffix):
    graph, values = read_bal(_write(tmp_path, BAL))
    out = tmp_path / f"out.txt{suffix}"
    write_bal(out, graph, values)
    graph2, values2 = read(out)
    assert values2 == values
    assert np.array_equal(graph2.batches[0].keys, graph.batches[0].keys)
    assert np.array_equal(graph2.batches[0].constants, graph.batches[0].constants)


@pytest.mark.parametrize("text, match", [
    ("", "empty"),
    ("2 3\n", r":1: the BAL header needs 3 numbers"),
    ("2 3 -4\n", r":1: the BAL header must be three positive integers"),
    (BAL.replace("1 2 0.5 0.25", "1 2 0.5"), r":5: observation 2 needs 4 numbers"),
    (BAL.replace("1 2 0.5 0.25", "1 3 0.5 0.25"), r":5: point index 3 is out of range"),
    (BAL.replace("1 2 0.5 0.25", "2 2 0.5 0.25"), r":5: camera index 2 is out of range"),
    (BAL.replace("1 2 0.5 0.25", "1 1.5 0.5 0.25"), r":5: point index 1.5 is out of range"),
    (BAL.replace("0.5 0.25", "0.5 nan"), r":5: 'nan' is not a finite number"),
    (BAL.replace("-0.02", "-0.02x"), r":9: '-0.02x' is not a number"),
    (BAL.replace("0 0 1\n", "0 0\n"), r":20: expected 27 camera and point parameters .* found 26"),
    (BAL + "7\n", r":21: unexpected extra number '7'"),
    # a broken camera in every form (the 9-vector one too)
    (BAL.replace("0 0 0 0 0 -6 400 0 0", "0 0 0 0 0 -6 0 0 0"),
     r":17: camera 1: focal length 0 is not positive"),
    (BAL.replace("\n500\n", "\n-500\n"), r":14: camera 0: focal length -500 is not positive"),
    ("2 3 40\n0 0 1 1\n", r":2: the header announces 40 observations"),
])
def test_malformed_bal_names_file_and_line(tmp_path, text, match):
    with pytest.raises(FileFormatError, match=match):
        read_bal(_write(tmp_path, text))


def test_read_dispatches_by_content(tmp_path):
    graph, _ = read(_write(tmp_path, BAL, "anything.dat"))
    assert graph.batches[0].kernel.name == "bal_reprojection"
    with pytest.raises(FileFormatError, match="extension says g2o"):
        read(_write(tmp_path, BAL, "x.g2o"))
    with pytest.raises(FileFormatError, match="cannot tell the format"):
        read(_write(tmp_path, "%%% 1 2\n"))
    with pytest.raises(FgoptError, match="apply to g2o files"):
        read(_write(tmp_path, BAL), add_prior=True)


def test_write_bal_needs_reprojection_factors(tmp_path):
    graph, values = read_bal(_write(tmp_path, BAL))
    with pytest.raises(FgoptError, match="2D / 3D|SE2 / SE3"):
        write_g2o(tmp_path / "x.g2o", graph, values)
    from fgopt import FactorGraph

    with pytest.raises(FgoptError, match="no BAL reprojection factors"):
        write_bal(tmp_path / "x.txt", FactorGraph(), values)
