"""Every file in the shared data folder: read, round-trip, and GTSAM's cost at the initial guess.

Skips with a reason when the data folder (``FGOPT_DATA``, default ``../shared/data``) is absent.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np
import pytest

from fgopt.errors import FileFormatError
from fgopt.io import read, read_bal, read_g2o, write_bal, write_g2o


def data_dir() -> Path:  # as tests/conftest.py (which pytest does not make importable)
    return Path(os.environ.get("FGOPT_DATA", Path(__file__).resolve().parents[2].parent / "shared"
                               / "data"))


POSE_FILES = sorted(str(p.relative_to(data_dir())) for pattern in ("*/*.g2o", "*/*.graph",
                                                                   "small/*.txt")
                    for p in data_dir().glob(pattern)) if data_dir().is_dir() else []
BAL_FILES = ["bal/dubrovnik-1-1-pre.txt", "bal/dubrovnik-3-7-pre.txt",
             "bal/problem-49-7776-pre.txt"]
# vertices, edges from MANIFEST.md
COUNTS = {"pose2d/input_M3500_g2o.g2o": (3500, 5453), "pose2d/manhattan.g2o": (3500, 5453),
          "pose2d/intel.g2o": (1728, 2512), "pose2d/FR079_P_toro.graph": (989, 1217),
          "pose3d/sphere2500.g2o": (2500, 4949), "pose3d/torus3D.g2o": (5000, 9048),
          "pose3d/parking-garage.g2o": (1661, 6275), "pose3d/cubicle.g2o": (5750, 16869),
          "small/w100.graph": (100, 300)}


def _read(path):
    return read(path, repair_information="clip" if "cubicle" in str(path) else None)


def _info(b):
    return np.einsum("nki,nkj->nij", b.sqrt_information, b.sqrt_information)


def assert_same_graph(g1, v1, g2, v2):
    assert v1.keys() == v2.keys()
    for k in v1.keys():
        a, b = v1.at(k), v2.at(k)
        sa = a.to_storage() if hasattr(a, "to_storage") else a
        sb = b.to_storage() if hasattr(b, "to_storage") else b
        assert np.allclose(sa, sb, rtol=1e-14, atol=1e-14), k
    assert [b.kernel for b in g1.batches] == [b.kernel for b in g2.batches]
    for a, b in zip(g1.batches, g2.batches):
        assert np.array_equal(a.keys, b.keys)
        assert np.allclose(a.constants, b.constants, rtol=1e-14, atol=1e-14)
        if a.sqrt_information is None:
            assert b.sqrt_information is None
            continue
        Ia, Ib = _info(a), _info(b)
        assert np.all(np.abs(Ia - Ib) <= 1e-13 * np.abs(Ia).max(axis=(1, 2), keepdims=True))


@pytest.mark.parametrize("rel", POSE_FILES)
def test_g2o_round_trip(data_file, tmp_path, rel):
    graph, values = _read(data_file(rel))
    if rel in COUNTS:
        assert (len(values), len(graph)) == COUNTS[rel]
    write_g2o(tmp_path / "out.g2o", graph, values)
    graph2, values2 = read_g2o(tmp_path / "out.g2o")
    assert_same_graph(graph, values, graph2, values2)


@pytest.mark.parametrize("rel", [f for f in POSE_FILES if f.endswith((".g2o", ".txt"))
                                 and "manhattan" not in f])
def test_initial_cost_matches_gtsam(data_file, rel):
    gtsam = pytest.importorskip("gtsam")
    path = data_file(rel)
    graph, values = _read(path)
    is3d = graph.batches[0].kernel.name.endswith("se3")
    g_graph, g_values = gtsam.readG2o(str(path), is3d)
    expected = g_graph.error(g_values)
    assert graph.error(values) == pytest.approx(expected, rel=1e-9, abs=1e-20 if expected < 1e-6
                                                else 0)


def test_cubicle_refuses_non_positive_definite_information_by_default(data_file, caplog):
    path = data_file("pose3d/cubicle.g2o")
    with pytest.raises(FileFormatError, match=r"5021 of 16869 edges have information matrices "
                                              r"that are not positive definite \(lines 5753, "):
        read_g2o(path)
    with caplog.at_level(logging.WARNING, logger="fgopt.io"):
        graph, values = read_g2o(path, repair_information="clip")
    assert "repaired 5021 of 16869" in caplog.text
    R = graph.batches[0].sqrt_information
    assert np.linalg.eigvalsh(np.einsum("nki,nkj->nij", R, R)).min() > 0


def test_manhattan_edges_only_matches_m3500_graph(data_file, caplog):
    with caplog.at_level(logging.INFO, logger="fgopt.io"):
        g1, v1 = read_g2o(data_file("pose2d/manhattan.g2o"))
    assert "no VERTEX lines" in caplog.text
    g2, v2 = read_g2o(data_file("pose2d/input_M3500_g2o.g2o"))
    assert sorted(v1.keys()) == sorted(v2.keys())
    b1, b2 = g1.batches[0], g2.batches[0]
    assert np.array_equal(b1.keys, b2.keys)
    assert np.allclose(b1.constants, b2.constants, atol=1e-6)
    assert np.isfinite(g1.error(v1))


@pytest.mark.parametrize("rel", BAL_FILES)
def test_bal_round_trip(data_file, tmp_path, rel):
    graph, values = read_bal(data_file(rel))
    out = tmp_path / "out.txt.bz2"
    write_bal(out, graph, values)
    graph2, values2 = read(out)
    assert_same_graph(graph, values, graph2, values2)


def test_ladybug_counts_and_finite_cost(data_file):
    graph, values = read_bal(data_file("bal/problem-49-7776-pre.txt"))
    assert (len(values), len(graph)) == (49 + 7776, 31843)
    assert np.isfinite(graph.error(values))


def test_w20000_edge2_covariances_read_as_gtsam_load2d(data_file, caplog):
    """GTSAM's w20000.txt writes EDGE2 entries as covariances in g2o order (not TORO information:
    read that way every matrix would be singular); fgopt reads them as GTSAM's load2D does, so
    both libraries' costs agree at the same values, and says so in a warning."""
    gtsam = pytest.importorskip("gtsam")
    path = data_file("pose2d/w20000.txt")
    with caplog.at_level(logging.WARNING, logger="fgopt.io"):
        graph, values = read(path)
    assert "covariances in g2o order" in caplog.text
    g_graph, _ = gtsam.load2D(str(path))
    g_values = gtsam.Values()
    for k in values.keys():
        s = values.at(k).to_storage()
        g_values.insert(int(str(k)[1:]), gtsam.Pose2(s[2], s[3], np.arctan2(s[1], s[0])))
    assert graph.error(values) == pytest.approx(g_graph.error(g_values), rel=1e-9)
