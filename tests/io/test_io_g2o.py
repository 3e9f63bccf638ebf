"""g2o / TORO reading and writing on small synthetic files."""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest

import fgopt
from fgopt import FactorGraph, Variables, key
from fgopt.errors import FgoptError, FileFormatError
from fgopt.factors.library.pose_point import PosePointFactor
from fgopt.factors.library.prior_between import BetweenFactor
from fgopt.noise import Gaussian
from fgopt.io import FIX_SIGMA, read, read_g2o, write_g2o
from fgopt.manifolds import SE2, SE3

POSE2 = """# a comment
VERTEX_SE2 10 0 0 0
VERTEX_SE2 3 1 0 0.1   # ids need not be contiguous
VERTEX_XY 7 1 1

EDGE_SE2 10 3 1 0 0.1 10 1 2 20 3 30
EDGE_SE2_XY 3 7 0.1 1 5 1 6
"""

POSE3 = """VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1
VERTEX_SE3:QUAT 1 1 0 0 0 0 0.04997916927067833 0.9987502603949663
VERTEX_TRACKXYZ 5 1 1 1
EDGE_SE3:QUAT 0 1 1 0 0 0 0 0.04997916927067833 0.9987502603949663 1 0 0 0 0 0 2 0 0 0 0 3 0 0 0 4 0 0 5 0 6
EDGE_SE3_TRACKXYZ 1 5 0 0.09983341664682815 0.9950041652780258 1 1 0 0 1 0 1
FIX 0
"""


def _write(tmp_path, text, name="g.g2o"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_read_2d_keys_values_and_permuted_information(tmp_path):
    graph, values = read_g2o(_write(tmp_path, POSE2))
    assert values.keys() == [key("x", 10), key("x", 3), key("l", 7)]
    assert np.allclose(values.at(key("x", 3)).to_storage(), [math.cos(0.1), math.sin(0.1), 1, 0])
    assert np.allclose(values.at(key("l", 7)), [1, 1])
    between, point = graph.batches
    assert between.keys.tolist() == [[key("x", 10), key("x", 3)]]
    assert point.keys.tolist() == [[key("x", 3), key("l", 7)]]
    R = between.sqrt_information[0]
    info = R.T @ R
    g2o = np.array([[10, 1, 2], [1, 20, 3], [2, 3, 30.0]])  # x y theta
    assert np.allclose(info, g2o[[2, 0, 1]][:, [2, 0, 1]])  # theta x y
    assert np.allclose(np.tril(R, -1), 0)
    assert [between._where(0)] == [f"{tmp_path / 'g.g2o'}:6"]
    e = np.array([math.sin(0.1) - 0.1, math.cos(0.1) - 1.0])  # R(0.1)^T (l - t) - m
    assert graph.error(values) == pytest.approx(0.5 * e @ np.array([[5, 1], [1, 6.0]]) @ e,
                                                rel=1e-12)


def test_read_3d_with_trackxyz_and_fix(tmp_path):
    graph, values = read_g2o(_write(tmp_path, POSE3))
    names = [b.kernel.name for b in graph.batches]
    assert names == ["between_pose3", "pose_point_se3", "prior_pose3"]
    R = graph.batches[0].sqrt_information[0]
    assert np.allclose(np.diag(R.T @ R), [4, 5, 6, 1, 2, 3])  # rotation first
    prior = graph.batches[2]
    assert prior.keys.tolist() == [[key("x", 0)]]
    assert np.allclose(prior.sqrt_information[0], np.eye(6) / FIX_SIGMA)
    assert isinstance(values.at(key("x", 1)), SE3)
    assert graph.error(values) < 1e-20


@pytest.mark.parametrize("with_param_line", [False, True])
def test_trackxyz_without_parameter_id_takes_a_fractional_measurement(tmp_path,
                                                                       with_param_line):
    """EDGE_SE3_TRACKXYZ without a parameter id (11 numbers) reads its measurement from column 2,
    alone or next to lines with an id (found by the fuzzer: column 2 was checked as an integer
    id on every line, so a valid file was refused)."""
    lines = POSE3.replace("EDGE_SE3_TRACKXYZ 1 5 0 0.0998", "EDGE_SE3_TRACKXYZ 1 5 0.0998")
    if with_param_line:
        lines += "EDGE_SE3_TRACKXYZ 0 5 0 1 1 1 5 0 0 5 0 5\n"
    graph, values = read_g2o(_write(tmp_path, lines))
    (point,) = [b for b in graph.batches if b.kernel.name == "pose_point_se3"]
    assert np.allclose(point.constants[0], [0.09983341664682815, 0.9950041652780258, 1])
    if with_param_line:
        assert np.allclose(point.constants[1], [1, 1, 1])
        assert np.allclose(point.sqrt_information[1], np.sqrt(5) * np.eye(3))


def test_toro_information_order(tmp_path):
    text = "VERTEX2 0 0 0 0\nVERTEX2 1 1 0 0\nEDGE2 0 1 1 0 0 11 12 22 33 13 23\nEQUIV 0 1\n"
    graph, _ = read_g2o(_write(tmp_path, text, "t.graph"))
    R = graph.batches[0].sqrt_information[0]
    xyt = np.array([[11, 12, 13], [12, 22, 23], [13, 23, 33.0]])
    assert np.allclose(R.T @ R, xyt[[2, 0, 1]][:, [2, 0, 1]])


def test_equiv_lines_are_skipped_with_a_counted_warning(tmp_path, caplog):
    text = "VERTEX2 0 0 0 0\nVERTEX2 1 1 0 0\nEDGE2 0 1 1 0 0 1 0 1 1 0 0\nEQUIV 0 1\nEQUIV 1 0\n"
    with caplog.at_level(logging.WARNING, logger="fgopt.io"):
        read_g2o(_write(tmp_path, text, "t.graph"))
    assert "skipped 2 EQUIV lines" in caplog.text


def test_edges_only_file_builds_a_spanning_tree_guess(tmp_path, caplog):
    text = ("EDGE_SE2 0 1 1 0 1.5707963267948966 1 0 0 1 0 1\n"
            "EDGE_SE2 2 1 -1 0 0 1 0 0 1 0 1\n"  # stored backwards: 1 = 2 * m
            "EDGE_SE2_XY 2 9 1 0 1 0 1\n")
    with caplog.at_level(logging.INFO, logger="fgopt.io"):
        graph, values = read_g2o(_write(tmp_path, text))
    assert "no VERTEX lines" in caplog.text and "spanning tree" in caplog.text
    x2 = values.at(key("x", 2))
    assert np.allclose([x2.x(), x2.y(), x2.theta()], [1, 1, math.pi / 2])
    assert np.allclose(values.at(key("l", 9)), [1, 2])
    assert graph.error(values) < 1e-20


def test_add_prior_fixes_the_lowest_pose_once(tmp_path):
    graph, _ = read_g2o(_write(tmp_path, POSE2), add_prior=True)
    prior = graph.batches[-1]
    assert prior.kernel.name == "prior_pose2" and prior.keys.tolist() == [[key("x", 3)]]
    graph, _ = read_g2o(_write(tmp_path, POSE3), add_prior=True)  # has FIX: no second prior
    assert [b.kernel.name for b in graph.batches].count("prior_pose3") == 1


V0 = "VERTEX_SE2 0 0 0 0\n"
V1 = "VERTEX_SE2 1 0 0 0\n"
UNIT = "1 0 0 1 0 1"


@pytest.mark.parametrize("text, match", [
    ("VERTEX_SE2 0 0 0\n", r":1: VERTEX_SE2 needs 4 numbers after the tag, found 3"),
    ("VERTEX_SE2 0 0 0 0 9\n", r":1: VERTEX_SE2 needs 4 numbers"),
    ("VERTEX_SE2 0 0 zero 0\n", r":1: 'zero' is not a number"),
    ("VERTEX_SE2 0 0 0 nan\n", r":1: 'nan' is not a finite number"),
    (V0 + "VERTEX_SE2 1.5 0 0 0\n", r":2: VERTEX_SE2: id '1.5' is not"),
    (V0 + "VERTEX_SE2 -1 0 0 0\n", r":2: VERTEX_SE2: id '-1' is not"),
    (V0 + "VERTEX_SE2 0 1 0 0\n", r":2: vertex id 0 is defined twice \(first at line 1\)"),
    (V0 + f"EDGE_SE2 0 4 1 0 0 {UNIT}\n", r":2: EDGE_SE2 refers to vertex 4, which has no"),
    (V0 + f"EDGE_SE2 0 0 1 0 0 {UNIT}\n", r":2: EDGE_SE2 connects vertex 0 to itself"),
    (V0 + f"VERTEX_XY 1 0 0\nEDGE_SE2 0 1 1 0 0 {UNIT}\n", r":3: EDGE_SE2: vertex 1 must be"),
    (V0 + V1 + "EDGE_SE2 0 1 1 0 0 1 0 0 -1 0 1\n",
     r":3: 1 of 1 edges have information matrices that are not positive definite"),
    (V0 + "FOO 1 2\n", r":2: unknown record 'FOO'.*skip_unknown=True"),
    (V0 + "VERTEX_SE3:QUAT 1 0 0 0 0 0 0 1\n",
     r":2: the file mixes 2D records \(VERTEX_SE2 at line 1\) and 3D"),
    ("VERTEX_SE3:QUAT 1 0 0 0 0 0 0 2\n", r":1: VERTEX_SE3:QUAT: quaternion norm is 2"),
    (V0 + "FIX 3\n", r":2: FIX refers to vertex 3"),
    ("# only a comment\n\n", r"no records"),
    ("PARAMS_SE3OFFSET 0 1 0 0 0 0 0 1\n", r":1: PARAMS_SE3OFFSET: only the identity"),
])
def test_malformed_input_names_file_and_line(tmp_path, text, match):
    with pytest.raises(FileFormatError, match=match):
        read_g2o(_write(tmp_path, text))


def test_unknown_tags_can_be_skipped_with_a_counted_warning(tmp_path, caplog):
    text = POSE2 + "FOO 1 2\nFOO 3\nBAR\n"
    with caplog.at_level(logging.WARNING, logger="fgopt.io"):
        graph, _ = read_g2o(_write(tmp_path, text), skip_unknown=True)
    assert len(graph) == 2
    assert "skipped 3 lines with unknown tags" in caplog.text and "2 'FOO'" in caplog.text


def test_repair_clip_logs_and_makes_information_positive_definite(tmp_path, caplog):
    text = "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 2 0 1 0 1\n"
    with pytest.raises(FileFormatError, match="repair_information='clip'"):
        read_g2o(_write(tmp_path, text))
    with caplog.at_level(logging.WARNING, logger="fgopt.io"):
        graph, _ = read_g2o(_write(tmp_path, text), repair_information="clip")
    R = graph.batches[0].sqrt_information[0]
    assert np.linalg.eigvalsh(R.T @ R).min() > 0
    assert "repaired 1 of 1 information matrices" in caplog.text
    with pytest.raises(FgoptError, match="repair_information"):
        read_g2o(_write(tmp_path, text), repair_information="fix-it")


@pytest.mark.parametrize("text", [POSE2, POSE3])
def test_round_trip(tmp_path, text):
    graph, values = read_g2o(_write(tmp_path, text))
    write_g2o(tmp_path / "out.g2o", graph, values)
    graph2, values2 = read_g2o(tmp_path / "out.g2o")
    assert values2 == values
    assert [b.kernel for b in graph2.batches] == [b.kernel for b in graph.batches]
    for a, b in zip(graph.batches, graph2.batches):
        assert np.array_equal(a.keys, b.keys)
        assert np.allclose(a.constants, b.constants, rtol=1e-15, atol=1e-15)
        assert np.allclose(a.sqrt_information, b.sqrt_information, rtol=1e-12)


def test_write_user_graph_with_individual_factors(tmp_path, caplog):
    graph, values = FactorGraph(), Variables()
    values.add(key("x", 0), SE2.from_xytheta(0, 0, 0))
    values.add(key("x", 1), SE2.from_xytheta(1, 0, 0.2))
    values.add(key("l", 2), np.array([2.0, 1.0]))
    info = np.array([[3.0, 0.5, 0], [0.5, 2, 0], [0, 0, 1]])
    graph.add(BetweenFactor(key("x", 0), key("x", 1), SE2.from_xytheta(1, 0, 0.1),
                            Gaussian.from_information(info)))
    graph.add(PosePointFactor(key("x", 1), key("l", 2), [1.0, 1.0]))
    p = tmp_path / "user.g2o.gz"
    write_g2o(p, graph, values)
    graph2, values2 = read(p)
    assert values2 == values
    assert graph2.error(values2) == pytest.approx(graph.error(values), rel=1e-12)
    R = graph2.batches[0].sqrt_information[0]
    assert np.allclose(R.T @ R, info)


def test_write_rejects_colliding_ids_and_mixed_dimensions(tmp_path):
    values = Variables()
    values.add(key("x", 1), SE2.identity())
    values.add(key("l", 1), np.zeros(2))
    with pytest.raises(FgoptError, match="g2o id 1"):
        write_g2o(tmp_path / "a.g2o", FactorGraph(), values)
    values = Variables()
    values.add(key("x", 1), SE2.identity())
    values.add(key("x", 2), SE3.identity())
    with pytest.raises(FgoptError, match="mix 2D and 3D"):
        write_g2o(tmp_path / "a.g2o", FactorGraph(), values)


def test_write_takes_bulk_rows_as_arrays(tmp_path):
    """Values read from a file (one block of storage rows per kind) write the same bytes as the
    same values held one by one, without turning the rows into objects; a block mixed with
    values held by key writes the same bytes too, and a colliding id is still named."""
    from fgopt.datasets import manhattan_2d

    d = manhattan_2d(40, seed=3)
    write_g2o(tmp_path / "in.g2o", d.graph, d.initial)
    graph, values = read(tmp_path / "in.g2o")
    assert values._pending and not values._dict
    write_g2o(tmp_path / "bulk.g2o", graph, values)
    assert values._pending and all(blk._objects is None for blk in values._pending)
    blk = values._pending[0]
    held = Variables()
    for k in values.keys():
        held.add(k, values.at(k))
    assert not held._pending
    write_g2o(tmp_path / "held.g2o", graph, held)
    assert (tmp_path / "bulk.g2o").read_bytes() == (tmp_path / "held.g2o").read_bytes()
    mixed = Variables().add(key("l", 900), np.array([1.5, -2.0]))
    mixed.add_rows(blk.keys, blk.kind, blk.rows)
    held.add(key("l", 900), np.array([1.5, -2.0]))
    write_g2o(tmp_path / "mixed.g2o", graph, mixed)
    write_g2o(tmp_path / "held2.g2o", graph, held)
    assert mixed._pending and b"VERTEX_XY 900" in (tmp_path / "mixed.g2o").read_bytes()
    assert sorted((tmp_path / "mixed.g2o").read_bytes().splitlines()) == sorted(
        (tmp_path / "held2.g2o").read_bytes().splitlines())
    _, clash = read(tmp_path / "in.g2o")
    clash.add(key("l", 3), np.zeros(2))
    with pytest.raises(FgoptError, match="g2o id 3"):
        write_g2o(tmp_path / "c.g2o", graph, clash)


def test_one_information_for_every_edge_factors_once_and_gives_the_same_bits(monkeypatch):
    """A stack of one repeated information matrix (the fast path of most files) is factored as
    one matrix and gives the same square roots, bit for bit, as the factorization of a stack
    that differs; a repeated matrix that is not positive definite marks every row bad."""
    from fgopt.io import _information as im

    rng = np.random.default_rng(0)
    a = rng.standard_normal((6, 6))
    one = a @ a.T + 6 * np.eye(6)
    same = np.repeat(one[None], 50, axis=0)
    shapes = []
    cholesky = np.linalg.cholesky
    monkeypatch.setattr(np.linalg, "cholesky", lambda m: shapes.append(m.shape) or cholesky(m))
    R, bad = im.checked_sqrt_information(same)
    assert shapes == [(6, 6)]
    varied = same.copy()
    varied[-1] *= 2.0
    R_ref, bad_ref = im.checked_sqrt_information(varied)
    assert not bad.any() and not bad_ref.any()
    assert np.array_equal(R[:-1], R_ref[:-1]) and R.flags.c_contiguous and R.flags.writeable
    not_pd = np.repeat(np.diag([1.0, -1.0, 1.0, 1.0, 1.0, 1.0])[None], 4, axis=0)
    R_bad, bad_all = im.checked_sqrt_information(not_pd)
    assert R_bad is None and bad_all.tolist() == [True] * 4
    packed = np.repeat(im.pack_upper(one[None]), 7, axis=0)
    unpacked = im.unpack_upper(packed, 6, im.PERM_SE3)
    packed[-1, 0] += 1.0  # no longer one matrix: the general path
    assert np.array_equal(unpacked[:-1], im.unpack_upper(packed, 6, im.PERM_SE3)[:-1])


def test_every_edge_with_the_same_bad_information_is_named_and_repaired(tmp_path, caplog):
    """Edges that share one information matrix that is not positive definite: the error names
    their lines; the clip repair repairs every one of them."""
    v = "".join(f"VERTEX_SE2 {i} {i} 0 0\n" for i in range(4))
    e = "".join(f"EDGE_SE2 {i} {i + 1} 1 0 0 1 2 0 1 0 1\n" for i in range(3))
    with pytest.raises(FileFormatError, match=r"3 of 3 edges .* \(lines 5, 6, 7\)"):
        read_g2o(_write(tmp_path, v + e))
    with caplog.at_level(logging.WARNING, logger="fgopt.io"):
        graph, _ = read_g2o(_write(tmp_path, v + e), repair_information="clip")
    assert "repaired 3 of 3 information matrices" in caplog.text
    R = graph.batches[0].sqrt_information
    assert np.linalg.eigvalsh(np.einsum("nki,nkj->nij", R, R)).min() > 0


def test_first_bad_line_is_reported_whatever_the_tags(tmp_path):
    """A text that is no g2o file (the project README) reports its first bad line, not the first
    tag in hash order; an unknown tag before a short record, and after it, both report the
    earlier line."""
    import pathlib

    readme = pathlib.Path(__file__).resolve().parents[2] / "README.md"
    lines = readme.read_text().splitlines()
    first = next(i + 1 for i, ln in enumerate(lines)
                 if ln.strip() and not ln.lstrip().startswith("#"))
    with pytest.raises(FileFormatError, match=rf"README.md:{first}: "):
        read(str(readme), format="g2o")
    with pytest.raises(FileFormatError, match=r":2: unknown record 'ZZZ'"):
        read_g2o(_write(tmp_path, V0 + "ZZZ 1\nAAA 2\nVERTEX_SE2 1 0 0\n"))
    with pytest.raises(FileFormatError, match=r":2: VERTEX_SE2 needs 4"):
        read_g2o(_write(tmp_path, V0 + "VERTEX_SE2 1 0 0\nZZZ 1\nAAA 2\n"))


@pytest.mark.parametrize("where", ["missing_folder/out.g2o", ".", "folder.g2o.gz"])
def test_write_to_an_unwritable_path_raises_an_fgopt_error_naming_it(tmp_path, where):
    """A path that cannot be written (no such folder, a directory) is an FgoptError naming the
    path, not Python's OSError."""
    from fgopt.errors import FgoptError

    sample = fgopt.datasets.manhattan_2d(num_poses=4, seed=0)
    path = tmp_path / where
    if where.startswith("folder"):
        path.mkdir()  # a directory named like a compressed file
    with pytest.raises(FgoptError, match="cannot write"):
        fgopt.io.write_g2o(path, sample.graph, sample.initial)
