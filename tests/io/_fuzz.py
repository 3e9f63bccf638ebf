"""Shared pieces of the reader fuzzers (tests/io/test_io_fuzz.py, benchmarks/fuzz_readers.py).

Base files (g2o 2D / 3D, TORO, BAL), a hypothesis strategy that mutates their lines, and
independent reference parsers written here, line by line, from the format descriptions (slow,
obviously correct). ``check_*`` feed one input to fgopt's reader and to the reference: the reader
must either raise an ``FgoptError`` where the reference finds the file invalid, or return exactly
the graph the reference builds - never another exception, never a silently different graph.
Compressed inputs (``.gz`` / ``.bz2``, possibly corrupted) go through ``fgopt.io.read`` from a
file; the reference decompresses with Python's ``gzip`` / ``bz2`` and detects the format from the
first token itself.
"""

from __future__ import annotations

import bz2
import gzip
import math
import re
from pathlib import Path

import numpy as np
from hypothesis import strategies as st

from fgopt.errors import FgoptError
from fgopt.io import read, read_bal, read_g2o
from fgopt.key import key

POSE2 = """VERTEX_SE2 0 0 0 0
VERTEX_SE2 1 1.0 0.1 0.2
VERTEX_SE2 5 2 0.5 -0.3
VERTEX_XY 9 1.5 1.5
EDGE_SE2 0 1 1 0.1 0.2 100 2 0 50 0 400
EDGE_SE2 1 5 1 0.3 -0.5 100 0 1 100 0 300
EDGE_SE2 0 5 2 0.5 -0.3 10 0 0 10 0 10
EDGE_SE2_XY 1 9 0.5 1.4 20 1 30
FIX 0
"""
POSE3 = """VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1
VERTEX_SE3:QUAT 1 1 0 0 0 0 0.0499792 0.99875
VERTEX_TRACKXYZ 4 1 1 1
EDGE_SE3:QUAT 0 1 1 0 0 0 0 0.0499792 0.99875 10 0 0 0 0 0 10 0 0 0 0 10 0 0 0 20 1 0 20 0 20
EDGE_SE3_TRACKXYZ 1 4 0 0.1 1 1 1 0 0 2 0 3
EDGE_SE3_TRACKXYZ 0 4 1 1 1 5 0 0 5 0 5
"""
TORO = """VERTEX2 0 0 0 0
VERTEX2 1 1.0 0.1 0.2
VERTEX2 2 2.0 0.5 -0.3
VERTEX2 3 2.9 1.4 1.7
EDGE2 0 1 1 0.1 0.2 100 2 50 400 0 1
EDGE2 1 2 1 0.3 -0.5 100 0 100 300 1 0
EDGE2 2 3 0.9 0.8 1.5 20 0 20 40 0 0
EDGE2 0 2 2 0.5 -0.3 10 0 10 10 0 0
EQUIV 1 2
"""
#: TORO lines as GTSAM's example files (w10000) write them: covariance in g2o order.
TORO_COV = """VERTEX2 0 0 0 0
VERTEX2 1 1.0 0.1 0.2
VERTEX2 2 2.0 0.5 -0.3
EDGE2 0 1 1 0.1 0.2 0.01 0 0 0.01 0 0.0001
EDGE2 1 2 1 0.3 -0.5 0.04 0.001 0 0.02 0 0.0004
EDGE2 0 2 2 0.5 -0.3 0.09 0 0.0001 0.09 0 0.001
"""
BAL = """2 2 3
0 0 -1.0 2.0
1 0 3.5e+00 -4.0
1 1 0.5 0.25
0.01 -0.02 0.03 0.1 0.2 -5 500 1e-3 -2e-6
0 0 0 0 0 -6 400 0 0
1 2 3
-1 0.5 0.25
"""

TOKENS = ["abc", "nan", "inf", "-inf", "1e400", "1e-400", "1_0", "0x1", "-", "1e", ".", "3.5",
          "-7", "0", "1", "4", "99999999999999999999", "2.5e3", "#", "VERTEX_SE2", "EDGE_SE2",
          "EDGE2", "VERTEX_XY", "FIX", "EQUIV", "EDGE_SE3:QUAT", "VERTEX_TRACKXYZ", "\u0661",
          "1e+5", "-0", "+2", "0.0499792", "PARAMS_SE3OFFSET", "VERTEX2", "VERTEX3", "EDGE3",
          "\t", "\r", "\x00", "\xa0", "\u2028", "1e22", "1e23", "0.1e-400"]

# ----------------------------------------------------------------------------- mutations


@st.composite
def mutated(draw, text: str) -> str:
    lines = text.split("\n")
    for _ in range(draw(st.integers(1, 2))):
        i = draw(st.integers(0, len(lines) - 1))
        toks = lines[i].split(" ")
        kind = draw(st.sampled_from(["replace", "delete", "insert", "dup_token", "truncate",
                                     "del_line", "dup_line", "swap_lines", "garbage", "number"]))
        j = draw(st.integers(0, max(len(toks) - 1, 0)))
        if kind == "replace":
            toks[j] = draw(st.sampled_from(TOKENS))
        elif kind == "delete" and toks:
            del toks[j]
        elif kind == "insert":
            toks.insert(j, draw(st.sampled_from(TOKENS)))
        elif kind == "dup_token" and toks:
            toks.insert(j, toks[j])
        elif kind == "truncate":
            lines[i] = lines[i][:draw(st.integers(0, len(lines[i])))]
            continue
        elif kind == "del_line":
            del lines[i]
            if not lines:
                lines = [""]
            continue
        elif kind == "dup_line":
            lines.insert(i, lines[i])
            continue
        elif kind == "swap_lines":
            k = draw(st.integers(0, len(lines) - 1))
            lines[i], lines[k] = lines[k], lines[i]
            continue
        elif kind == "garbage":
            toks.insert(j, draw(st.text(st.characters(min_codepoint=1, max_codepoint=300),
                                        min_size=1, max_size=6)))
        elif kind == "number":
            toks[j] = repr(draw(st.floats(allow_nan=False, allow_infinity=False, width=64)))
        lines[i] = " ".join(toks)
    return "\n".join(lines)


# ----------------------------------------------------------------------------- reference


class Invalid(Exception):
    pass


def _num(t: str) -> float:
    if "_" in t or any(ord(c) > 127 for c in t):
        raise Invalid(t)
    try:
        v = float(t)
    except ValueError:
        raise Invalid(t) from None
    if not math.isfinite(v):
        raise Invalid(t)
    return v


def _id(v: float) -> int:
    if v != math.floor(v) or v < 0 or v >= 2 ** 53:
        raise Invalid(v)
    return int(v)


def _symmetric(packed, d):
    M = np.zeros((d, d))
    iu = np.triu_indices(d)
    M[iu] = packed
    M[(iu[1], iu[0])] = packed
    return M


def _is_pd(M) -> bool:
    try:
        np.linalg.cholesky(M)
    except np.linalg.LinAlgError:
        return False
    return True


def _sym(packed, d):
    M = _symmetric(packed, d)
    if not _is_pd(M):
        raise Invalid("not PD")
    return M


def _toro_packed(v):
    """TORO's ``Ixx Ixy Iyy Itt Ixt Iyt`` as g2o's upper triangle ``xx xy xt yy yt tt``."""
    t = v[5:11]
    return [t[0], t[1], t[4], t[2], t[5], t[3]]


def _edge2_covariance(recs) -> bool:
    """GTSAM's load2D layout: EDGE2 numbers are a covariance in g2o order when some line is not
    a TORO information matrix and every line is a positive definite covariance."""
    toro = [v for _n, tag, v in recs if tag == "EDGE2"]
    return (any(not _is_pd(_symmetric(_toro_packed(v), 3)) for v in toro)
            and all(_is_pd(_symmetric(v[5:11], 3)) for v in toro))


def _quat(q):
    n = math.sqrt(sum(x * x for x in q))
    if abs(n - 1) > 1e-3:
        raise Invalid("quaternion")
    return [x / n for x in q]


G2O_COUNTS = {"VERTEX_SE2": (4,), "VERTEX_XY": (3,), "EDGE_SE2": (11,), "EDGE2": (11,),
              "VERTEX2": (4,), "EDGE_SE2_XY": (7,), "VERTEX_SE3:QUAT": (8,),
              "VERTEX_TRACKXYZ": (4,), "EDGE_SE3:QUAT": (30,), "EDGE_SE3_TRACKXYZ": (11, 12),
              "PARAMS_SE3OFFSET": (8,), "EQUIV": (2,), "FIX": None}
DIM = {"VERTEX_SE2": 2, "VERTEX2": 2, "VERTEX_XY": 2, "EDGE_SE2": 2, "EDGE2": 2,
       "EDGE_SE2_XY": 2, "VERTEX_SE3:QUAT": 3, "VERTEX_TRACKXYZ": 3, "EDGE_SE3:QUAT": 3,
       "EDGE_SE3_TRACKXYZ": 3, "PARAMS_SE3OFFSET": 3}


def reference_g2o(text: str):
    """-> (vertices {key: storage}, edges [(line, kind, keys, consts, info)], fixed keys) or
    raises Invalid; ``None`` for edges-only files (not compared)."""
    recs = []
    for n, line in enumerate(text.split("\n"), 1):
        toks = [t for t in re.split(r"[ \t\r\v\f]+", line.split("#")[0]) if t]
        if not toks:
            continue
        tag = toks[0]
        if tag not in G2O_COUNTS:
            raise Invalid(tag)
        counts = G2O_COUNTS[tag]
        if (counts is not None and len(toks) - 1 not in counts) or len(toks) < 2:
            raise Invalid("count")
        recs.append((n, tag, [_num(t) for t in toks[1:]]))
    if not recs:
        raise Invalid("empty")
    dims = {DIM[t] for _, t, _ in recs if t in DIM}
    if len(dims) != 1:
        raise Invalid("dims")
    verts, is_point = {}, {}
    params = {}
    for _n, tag, v in recs:
        if tag.startswith("VERTEX"):
            i = _id(v[0])
            if i in verts:
                raise Invalid("dup")
            if tag in ("VERTEX_SE2", "VERTEX2"):
                verts[i] = [math.cos(v[3]), math.sin(v[3]), v[1], v[2]]
            elif tag == "VERTEX_SE3:QUAT":
                verts[i] = _quat(v[4:8]) + v[1:4]
            else:
                verts[i] = v[1:]
            is_point[i] = tag in ("VERTEX_XY", "VERTEX_TRACKXYZ")
        elif tag == "PARAMS_SE3OFFSET":
            if max(abs(abs(a) - b) for a, b in zip(v[1:], [0, 0, 0, 0, 0, 0, 1])) > 1e-9:
                raise Invalid("offset")
            params[_id(v[0])] = True
    edges = []
    covariance = _edge2_covariance(recs)
    for n, tag, v in recs:
        if not tag.startswith("EDGE"):
            continue
        i, j = _id(v[0]), _id(v[1])
        if i == j:
            raise Invalid("loop")
        point = tag in ("EDGE_SE2_XY", "EDGE_SE3_TRACKXYZ")
        if verts and (i not in verts or j not in verts or is_point[i]
                      or is_point[j] != point):
            raise Invalid("endpoint")
        xb, lb = int(key("x", 0)), int(key("l", 0))
        keys = [xb + i, (lb if point else xb) + j]
        if tag == "EDGE_SE2":
            meas = [math.cos(v[4]), math.sin(v[4]), v[2], v[3]]
            M = _sym(v[5:11], 3)[[2, 0, 1]][:, [2, 0, 1]]
        elif tag == "EDGE2":
            meas = [math.cos(v[4]), math.sin(v[4]), v[2], v[3]]
            if covariance:
                M = np.linalg.inv(_symmetric(v[5:11], 3))
                if not _is_pd(M):
                    raise Invalid("not PD")
            else:
                M = _sym(_toro_packed(v), 3)
            M = M[[2, 0, 1]][:, [2, 0, 1]]
        elif tag == "EDGE_SE2_XY":
            meas, M = v[2:4], _sym(v[4:7], 2)
        elif tag == "EDGE_SE3:QUAT":
            meas = _quat(v[5:9]) + v[2:5]
            p = [3, 4, 5, 0, 1, 2]
            M = _sym(v[9:30], 6)[p][:, p]
        else:
            off = 3 if len(v) == 12 else 2
            if off == 3:
                pid = _id(v[2])
                if params and pid not in params:
                    raise Invalid("param")
            meas, M = v[off:off + 3], _sym(v[off + 3:off + 9], 3)
        edges.append((n, point, keys, meas, M))
    fixed = set()
    for _n, tag, v in recs:
        if tag == "FIX":
            for x in v:
                i = _id(x)
                if verts and i not in verts:
                    raise Invalid("fix")
                fixed.add((int(key("l", 0)) if is_point.get(i) else int(key("x", 0))) + i)
    if not verts:
        return None
    keyed = {(int(key("l", 0)) if is_point[i] else int(key("x", 0))) + i: np.array(s)
             for i, s in verts.items()}
    return keyed, edges, fixed


def check_g2o(text: str, reader=None) -> bool:
    """One g2o / TORO input against the reference; True if the reader accepted it.

    ``reader``: ``() -> (graph, values)`` (default: ``read_g2o`` on the text's bytes)."""
    try:
        expected = reference_g2o(text)
    except Invalid:
        expected = "invalid"
    try:
        if reader is None:
            graph, values = read_g2o("fuzz.g2o", data=text.encode("utf-8"))
        else:
            graph, values = reader()
    except FgoptError:
        assert expected == "invalid", f"reader refused a valid file:\n{text}"
        return False
    assert expected != "invalid", f"reader accepted an invalid file:\n{text}"
    if expected is None:  # edges only: the reader made up a guess; check it is complete
        assert all(k in values for b in graph.batches for k in b.keys.reshape(-1).tolist())
        return True
    verts, edges, fixed = expected
    assert sorted(values.keys()) == sorted(verts)
    for k, s in verts.items():
        x = values.at(k)
        got = x.to_storage() if hasattr(x, "to_storage") else x
        assert np.allclose(got, s, rtol=1e-12, atol=1e-12)
    got_edges, got_fixed = [], set()
    for b in graph.batches:
        if b.kernel.name.startswith("prior"):
            got_fixed |= set(b.keys[:, 0].tolist())
            continue
        for r in range(len(b)):
            line = int(b._where(r).rsplit(":", 1)[1])
            got_edges.append((line, b.kernel.name.startswith("pose_point"), b.keys[r].tolist(),
                              b.constants[r], b.sqrt_information[r].T @ b.sqrt_information[r]))
    got_edges.sort(key=lambda e: e[0])
    assert len(got_edges) == len(edges)
    for g, e in zip(got_edges, edges):
        assert g[0] == e[0] and g[1] == e[1] and g[2] == e[2]
        assert np.allclose(g[3], e[3], rtol=1e-12, atol=1e-12)
        assert np.allclose(g[4], e[4], rtol=1e-9, atol=1e-9 * np.abs(e[4]).max())
    assert got_fixed == fixed
    return True


def reference_bal(text: str):
    lines = [(n, [t for t in re.split(r"[ \t\r\v\f]+", line) if t])
             for n, line in enumerate(text.split("\n"), 1)]
    lines = [(n, t) for n, t in lines if t]
    if not lines or len(lines[0][1]) != 3:
        raise Invalid("header")
    head = [_num(t) for t in lines[0][1]]
    if any(h != math.floor(h) or h < 1 or h >= 2 ** 40 for h in head):
        raise Invalid("header")
    nc, npt, nobs = (int(h) for h in head)
    if len(lines) < 1 + nobs:
        raise Invalid("obs")
    obs = []
    for _n, toks in lines[1:1 + nobs]:
        if len(toks) != 4:
            raise Invalid("obs")
        c, p, x, y = (_num(t) for t in toks)
        if c != math.floor(c) or not 0 <= c < nc or p != math.floor(p) or not 0 <= p < npt:
            raise Invalid("index")
        obs.append((int(c), int(p), x, y))
    rest = [_num(t) for _, toks in lines[1 + nobs:] for t in toks]
    if len(rest) != 9 * nc + 3 * npt:
        raise Invalid("params")
    return obs, np.array(rest[:9 * nc]).reshape(nc, 9), np.array(rest[9 * nc:]).reshape(npt, 3)


def check_bal(text: str, reader=None) -> bool:
    """One BAL input against the reference; True if the reader accepted it."""
    try:
        expected = reference_bal(text)
    except Invalid:
        expected = None
    try:
        if reader is None:
            graph, values = read_bal("fuzz.txt", data=text.encode("utf-8"))
        else:
            graph, values = reader()
    except FgoptError:
        assert expected is None, f"reader refused a valid file:\n{text}"
        return False
    assert expected is not None, f"reader accepted an invalid file:\n{text}"
    obs, cams, pts = expected
    (b,) = graph.batches
    cb, pb = int(key("c", 0)), int(key("p", 0))
    assert b.keys.tolist() == [[cb + c, pb + p] for c, p, _, _ in obs]
    assert np.array_equal(b.constants, np.array([[x, y] for _, _, x, y in obs]))
    assert all(np.array_equal(values.at(cb + i), cams[i]) for i in range(len(cams)))
    assert all(np.array_equal(values.at(pb + j), pts[j]) for j in range(len(pts)))
    return True


# ----------------------------------------------------------------------------- compressed
BASES = {"g2o2d": (POSE2, "g2o"), "g2o3d": (POSE3, "g2o"), "toro": (TORO, "graph"),
         "toro_cov": (TORO_COV, "graph"), "bal": (BAL, "txt")}


def mutated_toro():
    """A mutated TORO file: TORO's information order, or GTSAM's covariance layout."""
    return st.sampled_from([TORO, TORO_COV]).flatmap(mutated)
CODECS = {"gz": gzip.compress, "bz2": bz2.compress}
_DECOMPRESS = {"gz": gzip.decompress, "bz2": bz2.decompress}


@st.composite
def compressed(draw, codec: str):
    """``(base name, file name, bytes)``: a base file, mutated or not, compressed with
    ``codec``, then possibly damaged (bit flip, truncation, inserted / appended bytes, another
    header) - or random bytes."""
    name = draw(st.sampled_from(sorted(BASES)))
    text, ext = BASES[name]
    if draw(st.booleans()):
        text = draw(mutated(text))
    blob = bytearray(CODECS[codec](text.encode("utf-8")))
    damage = draw(st.sampled_from(["none", "none", "flip", "truncate", "insert", "append",
                                   "random", "double"]))
    if damage == "flip":
        i = draw(st.integers(0, len(blob) - 1))
        blob[i] ^= 1 << draw(st.integers(0, 7))
    elif damage == "truncate":
        del blob[draw(st.integers(0, len(blob) - 1)):]
    elif damage == "insert":
        i = draw(st.integers(0, len(blob)))
        blob[i:i] = draw(st.binary(min_size=1, max_size=4))
    elif damage == "append":
        blob += draw(st.binary(min_size=1, max_size=16))
    elif damage == "random":
        blob = bytearray(draw(st.binary(max_size=120)))
    elif damage == "double":  # two concatenated streams (valid for both codecs)
        blob += CODECS[codec](draw(st.sampled_from(["", "\n", text[: len(text) // 2]])).encode())
    return name, f"fuzz.{ext}.{codec}", bytes(blob)


_NUMBER = re.compile(r"[+-]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][+-]?[0-9]+)?")
_TAG = re.compile(r"[A-Za-z_][A-Za-z0-9_:]*")


def reference_format(text: str, name: str) -> str:
    """``"g2o"`` or ``"bal"`` from the first token (raises Invalid when neither fits)."""
    for line in text.split("\n"):
        m = re.match(r"[ \t\r\f\v]*([^ \t\r\f\v#]+)", line)
        if m is not None:
            tok = m.group(1)
            break
    else:
        raise Invalid("empty")
    if _NUMBER.fullmatch(tok):
        base = name.rsplit(".", 1)[0]
        if base.endswith((".g2o", ".graph")):
            raise Invalid("g2o extension, BAL content")
        return "bal"
    if _TAG.fullmatch(tok):
        return "g2o"
    raise Invalid("first token")


def check_compressed(path: Path, codec: str, blob: bytes) -> bool:
    """``fgopt.io.read(path)`` of a compressed file against decompress + detect + reference."""
    path.write_bytes(blob)
    try:
        raw = _DECOMPRESS[codec](blob)
        text = raw.decode("utf-8")
    except Exception:  # noqa: BLE001 - whatever Python's codec refuses, the reader must refuse
        text = None
    if text is not None:
        try:
            fmt = reference_format(text, path.name)
        except Invalid:
            fmt = None
    if text is None or fmt is None:
        try:
            read(path)
        except FgoptError:
            return False
        raise AssertionError(f"reader accepted a file Python cannot decompress / detect: {blob!r}")
    check = check_bal if fmt == "bal" else check_g2o
    return check(text, reader=lambda: read(path))
