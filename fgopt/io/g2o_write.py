"""Write a factor graph and its values as a g2o file (the inverse of :func:`read_g2o`).

Vertices: SE2 / SE3 values become ``VERTEX_SE2`` / ``VERTEX_SE3:QUAT``, 2- / 3-vectors
``VERTEX_XY`` / ``VERTEX_TRACKXYZ``; the g2o id is the key's index (``x7`` -> 7), so poses and
points must not share an index. Factors: between factors on SE2 / SE3 become ``EDGE_SE2`` /
``EDGE_SE3:QUAT`` and pose-to-point factors ``EDGE_SE2_XY`` / ``EDGE_SE3_TRACKXYZ``, with the
information ``R^T R`` permuted back to g2o's translation-first order; a prior with sigma
:data:`~fgopt.io.g2o.FIX_SIGMA` at its variable's value becomes ``FIX``. Numbers are written with
``repr`` (shortest round-trip form), so reading the file back gives the same graph. Edges read
with ``read_g2o(keep_edge_text=True)`` (as ``fgopt solve --out`` reads) whose batch still holds
what was read are written as the file's own records (:mod:`fgopt.io._records`): solving changes
the vertices, and the edges come back as written (``10``, not ``10.000000000000002`` after
``R^T R``), and sooner (sphere2500's result: the whole write 30 instead of 75 ms, ad hoc).
Factors g2o cannot express (other priors, custom factors) and robust losses are left out with a
warning.
"""

from __future__ import annotations

import logging
import os
from collections import Counter
from typing import Any

import numpy as np

from ..errors import FgoptError
from ..noise.models import RobustLoss, base_noise
from ..key import key_index, key_str
from ..manifolds.base import ops_for, vector_kind
from ..variables import Variables
from . import _information as im
from ._graph_build import FIX_SIGMA, pose_kind
from ._poses import se2_file, se3_file
from ._format import format_rows
from ._records import recall
from ._files import write_bytes

log = logging.getLogger("fgopt.io")

_ID_BITS = key_index(-1)  # key_index(k) == k & _ID_BITS: the index bits of a key


def _factor_blocks(graph: Any):
    """``(kernel, keys (n, k), constants (n, c), R (n, r, r) | None, robust count, batch)``
    for the graph's individually added factors (grouped by kernel; batch ``None``) and its
    batches."""
    groups: dict[int, list] = {}
    other = Counter()
    for f in graph.factors:
        if f.kernel is None:
            other[type(f).__name__] += 1
            continue
        groups.setdefault(id(f.kernel), []).append(f)
    for fs in groups.values():
        keys = np.array([[int(k) for k in f.keys] for f in fs], dtype=np.int64)
        consts = np.array([f.constants for f in fs], dtype=float)
        R = np.array([base_noise(f.loss).sqrt_information for f in fs], dtype=float)
        robust = sum(isinstance(f.loss, RobustLoss) for f in fs)
        yield fs[0].kernel, keys, consts, R, robust, None
    for b in graph.batches:
        yield b.kernel, b.keys, b.constants, b.sqrt_information, (len(b) if b.loss_code else 0), b
    if other:
        yield None, other, None, None, 0, None


def write_g2o(path: str | os.PathLike, graph: Any, values: Any) -> None:
    """Write ``graph`` and ``values`` to ``path`` in g2o format (see the module docstring).

    Example:

    >>> import tempfile, pathlib
    >>> sample = fgopt.datasets.manhattan_2d(num_poses=5, seed=0)
    >>> path = pathlib.Path(tempfile.mkdtemp()) / 'out.g2o'
    >>> fgopt.io.write_g2o(path, sample.graph, sample.initial)
    >>> path.read_text().splitlines()[0].split()[:2]
    ['VERTEX_SE2', '0']
    """
    from ..factors.library.prior_between import between_kernel_for as between_kernel
    from ..factors.library.prior_between import prior_kernel_for as prior_kernel
    from ..factors.library.pose_point import pose_point_kernel

    # kinds looked up once per value type, storage rows stacked per kind (no per-key lookups);
    # bulk blocks (a file's or a result's poses) are taken as their key and row arrays
    writable = {pose_kind(2): 2, vector_kind(2): 2, pose_kind(3): 3, vector_kind(3): 3}
    kind_of_type: dict = {}  # (type, shape) -> kind
    members: dict = {}  # kind -> ([key arrays], [row arrays]), in the values' order

    def member(kind, what: str) -> tuple[list, list]:
        if kind not in writable:
            raise FgoptError(f"write_g2o: {what}; g2o stores SE2 / SE3 poses and 2- / 3-vector "
                             "points only")
        return members.setdefault(kind, ([], []))

    held = values._dict.items() if isinstance(values, Variables) else values.items()
    blocks = values._pending if isinstance(values, Variables) else ()
    per_key: dict = {}  # kind -> ([keys], [values]) of the values held one by one
    for k, v in held:
        t = type(v)
        tkey = (t, v.shape) if t is np.ndarray else t
        kind = kind_of_type.get(tkey)
        if kind is None:
            kind = kind_of_type[tkey] = ops_for(v).batch_kind(v)
            member(kind, f"{key_str(k)} is a {type(v).__name__}")
        ks, vs = per_key.setdefault(kind, ([], []))
        ks.append(k)
        vs.append(v)
    for kind, (ks, vs) in per_key.items():
        members[kind][0].append(ks)
        members[kind][1].append(np.array([kind.to_storage(v) for v in vs], dtype=float))
    for blk in blocks:
        ks, rows = member(blk.kind, f"{key_str(int(blk.keys[0]))} is a {blk.kind.name}")
        ks.append(blk.keys)
        rows.append(blk.rows)
    dims = {writable[kind] for kind in members}
    if len(dims) > 1:
        raise FgoptError("write_g2o: the values mix 2D and 3D variables; g2o files are one or "
                         "the other")
    dim = dims.pop() if dims else 2
    pkind, vkind = pose_kind(dim), vector_kind(dim)

    def ids_and_keys(parts: list) -> tuple[np.ndarray, np.ndarray]:
        """g2o ids of a kind's keys, and the keys that fit int64 (keys past it, possible one
        by one, have no factor)."""
        ids, fit = [], []
        for part in parts:
            if isinstance(part, np.ndarray):  # a bulk block's int64 keys
                ids.append(part & _ID_BITS)
                fit.append(part)
            else:
                ids.append(np.array([key_index(k) for k in part], dtype=np.int64))
                fit.append(np.array([k for k in part if k < 2 ** 63], dtype=np.int64))
        return np.concatenate(ids), np.concatenate(fit)

    ids_of_kind = {kind: ids_and_keys(ks) for kind, (ks, _) in members.items()}
    all_ids = np.concatenate([i for i, _ in ids_of_kind.values()] or [np.zeros(0, np.int64)])
    srt = np.sort(all_ids)
    same = srt[1:][srt[1:] == srt[:-1]]
    if same.shape[0]:
        twins = [k for ks, _ in members.values() for part in ks for k in
                 (part.tolist() if isinstance(part, np.ndarray) else part)
                 if key_index(k) == int(same[0])]
        a, b = twins[0], twins[1]
        raise FgoptError(f"write_g2o: {key_str(b)} and {key_str(a)} would both get g2o id "
                         f"{key_index(a)} (g2o has one id space); rename one of the keys")
    sorted_keys = np.sort(np.concatenate([f for _, f in ids_of_kind.values()]
                                         or [np.zeros(0, np.int64)]))
    vertex_parts: list[bytes] = []
    for kind, tag in ((pkind, "VERTEX_SE2" if dim == 2 else "VERTEX_SE3:QUAT"),
                      (vkind, "VERTEX_XY" if dim == 2 else "VERTEX_TRACKXYZ")):
        if kind not in members:
            continue
        ks, parts = members[kind]
        rows = np.concatenate(parts) if len(parts) > 1 else np.asarray(parts[0], dtype=float)
        if kind is pkind:
            rows = se2_file(rows) if dim == 2 else se3_file(rows)
        ids = ids_of_kind[kind][0]
        vertex_parts.append(format_rows(tag, ids[:, None], rows))

    def ids_of(keys: np.ndarray) -> np.ndarray:
        keys = np.asarray(keys, dtype=np.int64)
        at = np.minimum(np.searchsorted(sorted_keys, keys), max(sorted_keys.shape[0] - 1, 0))
        missing = ~(sorted_keys[at] == keys) if sorted_keys.shape[0] else np.ones(keys.shape, bool)
        if missing.any():
            raise FgoptError(f"write_g2o: a factor uses {key_str(int(keys[missing][0]))}, which "
                             "has no value")
        return keys & _ID_BITS

    edge_parts: list[bytes] = []
    fixed: list[int] = []
    params_needed = False
    skipped: Counter = Counter()
    robust_total = 0
    betw, pp = between_kernel(pkind), pose_point_kernel(dim)
    priors = {prior_kernel(pkind): pkind, prior_kernel(vkind): vkind}
    for kernel, keys, consts, R, robust, batch in _factor_blocks(graph):
        if kernel is None:
            skipped.update(keys)
            continue
        n = keys.shape[0]
        r = kernel.residual_dim
        if kernel is betw or kernel is pp:
            robust_total += robust
            ids = ids_of(keys)
            tag = (("EDGE_SE2" if dim == 2 else "EDGE_SE3:QUAT") if kernel is betw
                   else "EDGE_SE2_XY" if dim == 2 else "EDGE_SE3_TRACKXYZ")
            text = None if batch is None else recall(batch, tag)
            if text is not None:  # read from a file and unchanged: the file's own records
                edge_parts.append(text)
                continue
            info = np.broadcast_to(np.eye(r), (n, r, r)) if R is None else im.information_of(R)
            if kernel is betw and dim == 2:
                info = im.permute(info, im.inverse_permutation(im.PERM_SE2))
                nums = np.hstack([se2_file(consts), im.pack_upper(info)])
            elif kernel is betw:
                info = im.permute(info, im.inverse_permutation(im.PERM_SE3))
                nums = np.hstack([se3_file(consts), im.pack_upper(info)])
            elif dim == 2:
                nums = np.hstack([consts, im.pack_upper(info)])
            else:
                params_needed = True
                ids = np.column_stack([ids, np.zeros(n, np.int64)])
                nums = np.hstack([consts, im.pack_upper(info)])
            edge_parts.append(format_rows(tag, ids, nums))
        elif kernel in priors and R is not None:
            kind = priors[kernel]
            fix_R = np.eye(r) / FIX_SIGMA
            for row in range(n):
                k = int(keys[row, 0])
                v = values.at(k) if k in values else None
                at_value = (v is not None and ops_for(v).batch_kind(v) is kind and np.allclose(
                    kind.to_storage(v), consts[row], rtol=0, atol=1e-9))
                if at_value and np.allclose(R[row], fix_R, rtol=1e-9, atol=0):
                    fixed.append(key_index(k))
                else:
                    skipped[kernel.name] += 1
        else:
            skipped[kernel.name] += n
    if skipped:
        parts = ", ".join(f"{n} {t}" for t, n in skipped.most_common())
        log.warning("write_g2o: g2o cannot express %d factor(s) (%s); they were not written",
                    sum(skipped.values()), parts)
    if robust_total:
        log.warning("write_g2o: %d factor(s) have robust losses; g2o files have no loss field, "
                    "the losses were not written", robust_total)
    out = [b"PARAMS_SE3OFFSET 0 0 0 0 0 0 0 1\n"] if params_needed else []
    out += vertex_parts
    if fixed:
        out.append(("FIX " + " ".join(map(str, dict.fromkeys(fixed))) + "\n").encode())
    out += edge_parts
    write_bytes(path, b"".join(out) if out else b"\n")
