"""Turn the parsed record groups of a g2o / TORO file into ``(FactorGraph, Variables)``.

Every check names the offending line: duplicate or missing vertices, self-loops, wrong vertex
types, non-unit quaternions, information matrices that are not positive definite. Files without
vertex lines get an initial guess by composing edge measurements along a BFS spanning tree.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from ..graph import FactorGraph
from ..key import Key, key, key_str
from ..manifolds.base import vector_kind
from ..variables import Variables
from . import _information as im
from ._poses import QUATERNION_NORM_TOLERANCE, se2_storage, se3_storage, spanning_tree_guess

log = logging.getLogger("fgopt.io")

#: Sigma of the prior written for ``FIX`` lines and of the optional gauge prior.
FIX_SIGMA = 1e-6

#: g2o upper-triangle position k of (x, y, theta) holds TORO entry TORO_TO_G2O[k]
#: (TORO writes xx xy yy tt xt yt).
TORO_TO_G2O = np.array([0, 1, 4, 2, 5, 3])


def pose_kind(dim: int):
    """The batch kind of SE2 (``dim=2``) or SE3 (``dim=3``) poses."""
    from ..manifolds import SE2, SE3

    return SE2.batch_kind() if dim == 2 else SE3.batch_kind()


def key_base(char: str) -> int:
    """``key(char, id) == key_base(char) + id``."""
    return int(key(char, 0))


def check_quaternions(rd, g, norms: np.ndarray) -> None:
    bad = np.abs(norms - 1.0) > QUATERNION_NORM_TOLERANCE
    if bad.any():
        i = int(np.nonzero(bad)[0][0])
        raise rd.error(f"{g.tag}: quaternion norm is {norms[i]:.6g}, expected 1 (within "
                       f"{QUATERNION_NORM_TOLERANCE:g})", g.lines[i])


def pose_rows(rd, g, values: np.ndarray, dim: int) -> np.ndarray:
    if dim == 2:
        return se2_storage(values)
    rows, norms = se3_storage(values)
    check_quaternions(rd, g, norms)
    return rows


@dataclass(eq=False)
class _Vertices:
    ids: np.ndarray  # (n,) file ids, in file order
    is_point: np.ndarray  # (n,) bool
    pose_rows: np.ndarray  # (poses, storage) the poses' storage rows, in file order
    point_rows: np.ndarray  # (points, dim) the points' positions, in file order
    lines: np.ndarray  # (n,) line numbers; 0 for guessed vertices

    def index(self) -> tuple[np.ndarray, np.ndarray]:
        order = np.argsort(self.ids, kind="stable")
        return self.ids[order], order


@dataclass(eq=False)
class _Edges:
    group: object  # _Group
    what: str  # between | point
    i: np.ndarray
    j: np.ndarray
    meas: np.ndarray  # (n, c) kernel constants
    info: np.ndarray  # (n, r, r) information in fgopt tangent order
    param: np.ndarray | None = None  # TRACKXYZ param ids (-1: none)


def _edges_of(rd, g, dim: int) -> _Edges:
    ids = rd.ids(g, [0, 1])
    d = g.data
    loops = ids[:, 0] == ids[:, 1]
    if loops.any():
        r = int(np.nonzero(loops)[0][0])
        raise rd.error(f"{g.tag} connects vertex {ids[r, 0]} to itself", g.lines[r])
    param = None
    if g.spec.what == "between" and dim == 2:
        meas = se2_storage(d[:, 2:5])
        packed = d[:, 5:11][:, TORO_TO_G2O] if g.spec.toro else d[:, 5:11]
        info = im.unpack_upper(packed, 3, im.PERM_SE2)
        if g.spec.toro and im.not_positive_definite(info).any():
            # GTSAM's example files w10000 / w20000 write EDGE2 entries as a *covariance* in g2o's
            # order (cxx cxy cxt cyy cyt ctt); GTSAM's load2D recognizes them by that layout
            # (NoiseFormatCOV). Read them the same way when every line fits it and none fits
            # TORO's information order: the file then means what GTSAM reads.
            cov = im.unpack_upper(d[:, 5:11], 3)
            if not im.not_positive_definite(cov).any():
                log.warning("%s: %s entries are covariances in g2o order (as GTSAM's load2D "
                            "reads this layout), not TORO information; read them so",
                            rd.path, g.tag)
                info = im.permute(np.linalg.inv(cov), im.PERM_SE2)
    elif g.spec.what == "between":
        meas, norms = se3_storage(d[:, 2:9])
        check_quaternions(rd, g, norms)
        info = im.unpack_upper(d[:, 9:30], 6, im.PERM_SE3)
    elif dim == 2:
        meas = d[:, 2:4].copy()
        info = im.unpack_upper(d[:, 4:7], 2)
    else:  # EDGE_SE3_TRACKXYZ with or without a parameter id
        has_param = ~np.isnan(d[:, 11]) if d.shape[1] == 12 else np.zeros(d.shape[0], bool)
        start = np.where(has_param, 3, 2)
        cols = start[:, None] + np.arange(9)
        vals = np.take_along_axis(d, cols, axis=1)
        meas = vals[:, :3].copy()
        info = im.unpack_upper(vals[:, 3:9], 3)
        param = np.full(d.shape[0], -1, dtype=np.int64)
        with_id = np.nonzero(has_param)[0]  # column 2 is mx on the other lines
        param[with_id] = rd.ids(g, [2], with_id)[:, 0]
    return _Edges(g, g.spec.what, ids[:, 0], ids[:, 1], meas, info, param)


def _vertices_of(rd, dim: int) -> _Vertices | None:
    ids, is_point, lines = [], [], []
    rows: dict[bool, list] = {False: [], True: []}  # is_point -> [(rows, lines)]
    for g in rd.groups.values():
        if g.spec.role != "vertex":
            continue
        vid = rd.ids(g, [0])[:, 0]
        point = g.spec.what == "point"
        if point:
            r = g.data[:, 1:1 + dim]
        else:
            r = pose_rows(rd, g, g.data[:, 1:], dim)
        ids.append(vid)
        is_point.append(np.full(vid.shape[0], point))
        rows[point].append((r, g.lines))
        lines.append(g.lines)
    if not ids:
        return None
    in_file_order = {}
    for point, parts in rows.items():
        if not parts:
            in_file_order[point] = np.zeros((0, dim if point else pose_kind(dim).storage_dim))
            continue
        r = np.concatenate([p[0] for p in parts])
        order = np.argsort(np.concatenate([p[1] for p in parts]), kind="stable")
        in_file_order[point] = r[order]  # a copy: the rows are the graph's to normalize
    all_lines = np.concatenate(lines)
    order = np.argsort(all_lines, kind="stable")  # file order
    v = _Vertices(np.concatenate(ids)[order], np.concatenate(is_point)[order],
                  in_file_order[False], in_file_order[True], all_lines[order])
    sorted_ids, perm = v.index()
    dup = np.nonzero(sorted_ids[1:] == sorted_ids[:-1])[0]
    if dup.shape[0] > 0:
        a, b = perm[dup], perm[dup + 1]
        k = int(np.argmin(np.maximum(v.lines[a], v.lines[b])))  # earliest second definition
        first, second = sorted((int(v.lines[a[k]]), int(v.lines[b[k]])))
        raise rd.error(f"vertex id {sorted_ids[dup[k]]} is defined twice (first at line "
                       f"{first})", second)
    return v


def _check_endpoints(rd, v: _Vertices, edges: list[_Edges]) -> None:
    sorted_ids, perm = v.index()
    for e in edges:
        for col, ids in (("first", e.i), ("second", e.j)):
            pos = np.clip(np.searchsorted(sorted_ids, ids), 0, sorted_ids.shape[0] - 1)
            found = sorted_ids[pos] == ids
            if not found.all():
                r = int(np.nonzero(~found)[0][0])
                raise rd.error(f"{e.group.tag} refers to vertex {ids[r]}, which has no VERTEX "
                               "line", e.group.lines[r])
            want_point = col == "second" and e.what == "point"
            wrong = v.is_point[perm[pos]] != want_point
            if wrong.any():
                r = int(np.nonzero(wrong)[0][0])
                need = "a point" if want_point else "a pose"
                raise rd.error(f"{e.group.tag}: vertex {ids[r]} must be {need}", e.group.lines[r])


def _rotate(rows: np.ndarray, m: np.ndarray, dim: int) -> np.ndarray:
    """Points ``m`` (n, dim) in the frames of poses ``rows`` -> world frame."""
    if dim == 2:
        c, s, t = rows[:, 0], rows[:, 1], rows[:, 2:4]
        return t + np.column_stack([c * m[:, 0] - s * m[:, 1], s * m[:, 0] + c * m[:, 1]])
    q, t = rows[:, :3], rows[:, 4:7]
    w = rows[:, 3:4]
    uv = np.cross(q, m)
    return t + m + 2.0 * (w * uv + np.cross(q, uv))


def _guess_vertices(rd, dim: int, edges: list[_Edges]) -> _Vertices:
    """Initial guess for a file without vertex lines (spanning tree over the edges)."""
    from ..manifolds.lie import group_id

    betw = [e for e in edges if e.what == "between"]
    pts = [e for e in edges if e.what == "point"]
    cat = lambda xs: np.concatenate(xs) if xs else np.zeros(0, np.int64)  # noqa: E731
    pose_ids = np.unique(np.concatenate([cat([e.i for e in betw]), cat([e.j for e in betw]),
                                         cat([e.i for e in pts])]))
    point_ids = np.unique(cat([e.j for e in pts]))
    both = np.intersect1d(pose_ids, point_ids)
    if both.shape[0] > 0:
        raise rd.error(f"vertex {both[0]} is used both as a pose and as a point", None)
    kind = pose_kind(dim)
    src = np.searchsorted(pose_ids, cat([e.i for e in betw]))
    dst = np.searchsorted(pose_ids, cat([e.j for e in betw]))
    meas = (np.concatenate([e.meas for e in betw]) if betw
            else np.zeros((0, kind.storage_dim)))
    identity = np.eye(1, kind.storage_dim, 0 if dim == 2 else 3)[0]  # storage of identity
    poses, comps = spanning_tree_guess(group_id(kind), identity, pose_ids.shape[0], src, dst,
                                       meas)
    log.info("%s has no VERTEX lines: initial guess by composing %d edge measurements along a "
             "BFS spanning tree from pose %d (%d pose(s), %d point(s))", rd.path, len(meas),
             int(pose_ids[0]), pose_ids.shape[0], point_ids.shape[0])
    if comps > 1:
        log.warning("%s: the edges form %d disconnected components; each extra component "
                    "starts at the identity", rd.path, comps)
    ids = [pose_ids]
    world = np.zeros((0, dim))
    if point_ids.shape[0] > 0:
        pi = cat([e.i for e in pts])
        pj = cat([e.j for e in pts])
        pm = np.concatenate([e.meas for e in pts])
        first_obs = np.unique(pj, return_index=True)[1]  # first edge observing each point
        world = _rotate(poses[np.searchsorted(pose_ids, pi[first_obs])], pm[first_obs], dim)
        ids.append(pj[first_obs])
    all_ids = np.concatenate(ids)
    is_point = np.arange(all_ids.shape[0]) >= pose_ids.shape[0]
    return _Vertices(all_ids, is_point, np.asarray(poses, dtype=float), world,
                     np.zeros(all_ids.shape[0], np.int64))


def _checked_sqrt_information(rd, edges: list[_Edges], repair: str | None,
                              floor: float) -> tuple[list[np.ndarray], list[bool]]:
    """The square-root information of each edge group, and whether any of its rows was
    repaired."""
    checked = [im.checked_sqrt_information(e.info) for e in edges]
    bad = [b for _, b in checked]
    num_bad = sum(int(b.sum()) for b in bad)
    total = sum(b.shape[0] for b in bad)
    if num_bad > 0 and repair is None:
        lines = sorted(int(x) for e, b in zip(edges, bad) for x in e.group.lines[b][:5])[:5]
        raise rd.error(
            f"{num_bad} of {total} edges have information matrices that are not positive "
            f"definite (lines {', '.join(map(str, lines))}{', ...' if num_bad > 5 else ''}); "
            "pass repair_information='clip' to clip their eigenvalues to a small positive "
            "floor", lines[0])
    out = []
    worst = 0.0
    for e, (R, b) in zip(edges, checked):
        rows = np.nonzero(b)[0]
        if rows.shape[0] > 0:
            e.info, change = im.clip_eigenvalues(e.info, rows, floor)
            worst = max(worst, change)
            R = im.sqrt_information(e.info)
        out.append(R)
    if num_bad > 0:
        log.warning("%s: repaired %d of %d information matrices that were not positive definite "
                    "(eigenvalues clipped to %g x the largest; largest relative change %.3g in "
                    "Frobenius norm)", rd.path, num_bad, total, floor, worst)
    return out, [bool(b.any()) for b in bad]


def build_graph(rd, dim: int, add_prior: bool, repair: str | None, floor: float,
                keep_edge_text: bool = False) -> tuple[FactorGraph, Variables]:
    from ..factors.library.prior_between import between_kernel_for as between_kernel
    from ..factors.library.pose_point import pose_point_kernel
    kind = pose_kind(dim)
    groups = sorted(rd.groups.values(), key=lambda g: int(g.lines[0]))
    edges = [_edges_of(rd, g, dim) for g in groups if g.spec.role == "edge"]
    _check_params(rd, edges)
    v = _vertices_of(rd, dim)
    if v is None:
        if not edges:
            raise rd.error("the file has no vertices and no edges", None)
        v = _guess_vertices(rd, dim, edges)
    else:
        _check_endpoints(rd, v, edges)
    xb, lb = key_base("x"), key_base("l")
    vkeys = np.where(v.is_point, lb, xb) + v.ids
    values = Variables()
    pkind = vector_kind(dim)
    pts = np.asarray(v.is_point, dtype=bool)
    if np.any(~pts):
        pose_rows = np.asarray(v.pose_rows, dtype=float)  # _vertices_of's copy: normalized here
        nrot = 2 if dim == 2 else 4  # (cos, sin) or the quaternion: project onto the group
        pose_rows[:, :nrot] /= np.linalg.norm(pose_rows[:, :nrot], axis=1, keepdims=True)
        values.add_rows(vkeys[~pts].tolist(), kind, pose_rows)
    if np.any(pts):
        values.add_rows(vkeys[pts].tolist(), pkind, np.array(v.point_rows, dtype=float))
    graph = FactorGraph()
    sqrt_infos, repaired = _checked_sqrt_information(rd, edges, repair, floor)
    for e, R, changed in zip(edges, sqrt_infos, repaired):
        if e.what == "between":
            kern, keys = between_kernel(kind), np.column_stack([xb + e.i, xb + e.j])
        else:
            kern, keys = pose_point_kernel(dim), np.column_stack([xb + e.i, lb + e.j])
        graph.add_batch(kern, keys, e.meas, R, origin=(str(rd.path), e.group.lines))
        if keep_edge_text and e.group.tag in VERBATIM_TAGS and not changed and e.i.shape[0]:
            _remember_records(rd.sc, graph.batches[-1], e.group)
    fixed = _fixed_keys(rd, v, vkeys)
    add_fixing_priors(graph, values, fixed, f"{rd.path}: FIX")
    if add_prior:
        add_gauge_prior(graph, values)
    if "EQUIV" in rd.groups:
        log.warning("%s: skipped %d EQUIV lines (TORO vertex equivalences are not supported)",
                    rd.path, rd.groups["EQUIV"].data.shape[0])
    return graph, values


#: Edge records written back as the file had them while their batch is unchanged
#: (:mod:`fgopt.io._records`): the tags the g2o writer writes, in the layout it writes. (TORO's
#: ``EDGE2`` is written as ``EDGE_SE2``; ``EDGE_SE3_TRACKXYZ`` lines may name a parameter id
#: that the writer's single ``PARAMS_SE3OFFSET 0`` would not define.)
VERBATIM_TAGS = ("EDGE_SE2", "EDGE_SE3:QUAT", "EDGE_SE2_XY")


def _remember_records(sc, batch, group) -> None:
    """Remember where ``batch``'s rows (``group``'s records, in order) are in the file."""
    from ._records import remember, token_ends

    rec = group.rec
    last = sc.first[rec] + sc.count[rec] - 1  # every edge record has numbers
    remember(batch, group.tag, sc.buf, sc.tag_start[rec],
             token_ends(sc.buf, sc.tok_start[last], sc.comment))


def add_fixing_priors(graph: FactorGraph, values: Variables, keys: list[int], label: str) -> None:
    """Tight priors (sigma ``FIX_SIGMA``) holding ``keys`` at their ``values``."""
    from ..factors.library.prior_between import prior_kernel_for as prior_kernel
    from ..manifolds.base import ops_for

    by_kind: dict = {}
    for k in keys:
        x = values.at(k)
        by_kind.setdefault(ops_for(x).batch_kind(x), []).append(k)
    for kind, ks in by_kind.items():
        rows = np.array([kind.to_storage(values.at(k)) for k in ks], dtype=float)
        R = np.broadcast_to(np.eye(kind.dim) / FIX_SIGMA, (len(ks), kind.dim, kind.dim))
        graph.add_batch(prior_kernel(kind), np.array(ks, dtype=np.int64)[:, None], rows, R,
                        origin=[f"{label} {key_str(k)}" for k in ks])


def add_gauge_prior(graph: FactorGraph, values: Variables) -> int | None:
    """Fix the gauge GTSAM-style: a tight prior (sigma ``FIX_SIGMA``) on the SE2 / SE3 pose
    with the lowest key, unless some factor already is a pose prior. Returns the key or None.

    Example:

    >>> sample = fgopt.datasets.manhattan_2d(num_poses=5, seed=0)
    >>> graph = sample.graph.copy()
    >>> n = len(graph)
    >>> fgopt.io.add_gauge_prior(graph, sample.initial)
    >>> len(graph) - n
    0
    """
    from ..factors.library.prior_between import prior_kernel_for as prior_kernel

    kinds = {pose_kind(2), pose_kind(3)}
    priors = {prior_kernel(k) for k in kinds}
    if any(b.kernel in priors for b in graph.batches) or any(
            f.kernel in priors for f in graph.factors):
        return None
    poses = values.keys_of_kinds(kinds)  # bulk pose rows stay arrays (100k poses: 32 MB)
    if not poses.shape[0]:
        return None
    k = Key(int(poses.min()))
    add_fixing_priors(graph, values, [k], "gauge prior on")
    return k


def _fixed_keys(rd, v: _Vertices, vkeys: np.ndarray) -> list[int]:
    g = rd.groups.get("FIX")
    if g is None:
        return []
    ids = rd.ids(g, slice(None))
    sorted_ids, perm = v.index()
    out: dict[int, None] = {}
    for r in range(ids.shape[0]):
        for vid in ids[r][ids[r] >= 0].tolist():
            pos = int(np.searchsorted(sorted_ids, vid))
            if pos >= sorted_ids.shape[0] or sorted_ids[pos] != vid:
                raise rd.error(f"FIX refers to vertex {vid}, which does not exist", g.lines[r])
            out.setdefault(int(vkeys[perm[pos]]), None)
    return list(out)


def _check_params(rd, edges: list[_Edges]) -> None:
    g = rd.groups.get("PARAMS_SE3OFFSET")
    known = set()
    if g is not None:
        pid = rd.ids(g, [0])[:, 0]
        ident = np.array([0, 0, 0, 0, 0, 0, 1.0])
        off = np.abs(np.abs(g.data[:, 1:]) - ident).max(axis=1) > 1e-9
        if off.any():
            r = int(np.nonzero(off)[0][0])
            raise rd.error("PARAMS_SE3OFFSET: only the identity sensor offset is supported",
                           g.lines[r])
        known = set(pid.tolist())
    for e in edges:
        if e.param is None or g is None:
            continue
        missing = (e.param >= 0) & ~np.isin(e.param, list(known))
        if missing.any():
            r = int(np.nonzero(missing)[0][0])
            raise rd.error(f"{e.group.tag} uses parameter {e.param[r]}, which no "
                           "PARAMS_SE3OFFSET line defines", e.group.lines[r])
