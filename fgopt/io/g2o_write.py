"""Write a factor graph and its values as a g2o file (the inverse of :func:`read_g2o`).

Vertices: SE2 / SE3 values become ``VERTEX_SE2`` / ``VERTEX_SE3:QUAT``, 2- / 3-vectors
``VERTEX_XY`` / ``VERTEX_TRACKXYZ``; the g2o id is the key's index (``x7`` -> 7), so poses and
points must not share an index. Factors: between factors on SE2 / SE3 become ``EDGE_SE2`` /
``EDGE_SE3:QUAT`` and pose-to-point factors ``EDGE_SE2_XY`` / ``EDGE_SE3_TRACKXYZ``, with the
information ``R^T R`` permuted back to g2o's translation-first order; a prior with sigma
:data:`~fgopt.io.g2o.FIX_SIGMA` at its variable's value becomes ``FIX``. Numbers are written with
``repr`` (shortest round-trip form), so reading the file back gives the same graph. Factors
g2o cannot express (other priors, custom factors) and robust losses are left out with a warning.
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
from . import _information as im
from ._graph_build import FIX_SIGMA, pose_kind
from ._poses import se2_file, se3_file
from ._scan import write_text

log = logging.getLogger("fgopt.io")


def _fmt(tag: str, ids: np.ndarray, nums: np.ndarray) -> list[str]:
    return [f"{tag} {' '.join(map(str, i))} {' '.join(map(repr, r))}"
            for i, r in zip(ids.tolist(), nums.tolist())]


def _factor_blocks(graph: Any):
    """``(kernel, keys (n, k), constants (n, c), R (n, r, r) | None, robust count, origin)``
    for the graph's individually added factors (grouped by kernel) and its batches."""
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
        yield fs[0].kernel, keys, consts, R, robust
    for b in graph.batches:
        yield b.kernel, b.keys, b.constants, b.sqrt_information, (len(b) if b.loss_code else 0)
    if other:
        yield None, other, None, None, 0


def write_g2o(path: str | os.PathLike, graph: Any, values: Any) -> None:
    """Write ``graph`` and ``values`` to ``path`` in g2o format (see the module docstring)."""
    from ..factors.library.prior_between import between_kernel_for as between_kernel
    from ..factors.library.prior_between import prior_kernel_for as prior_kernel
    from ..factors.library.pose_point import pose_point_kernel

    dims = set()
    id_of: dict[int, int] = {}
    owner: dict[int, int] = {}
    vertex_lines: list[str] = []
    kinds = {}
    writable = {pose_kind(2): 2, vector_kind(2): 2, pose_kind(3): 3, vector_kind(3): 3}
    kind_of_type: dict = {}  # (type, shape) -> kind: traits looked up once per type, not per key
    for k, v in values.items():
        t = type(v)
        tkey = (t, v.shape) if t is np.ndarray else t
        kind = kind_of_type.get(tkey)
        if kind is None:
            kind = kind_of_type[tkey] = ops_for(v).batch_kind(v)
        d = writable.get(kind)
        if d is None:
            raise FgoptError(f"write_g2o: {key_str(k)} is a {type(v).__name__}; g2o stores SE2 / "
                             "SE3 poses and 2- / 3-vector points only")
        dims.add(d)
        vid = key_index(k)
        if vid in owner:
            raise FgoptError(f"write_g2o: {key_str(k)} and {key_str(owner[vid])} would both get "
                             f"g2o id {vid} (g2o has one id space); rename one of the keys")
        owner[vid] = int(k)
        id_of[int(k)] = vid
        kinds[int(k)] = kind
    if len(dims) > 1:
        raise FgoptError("write_g2o: the values mix 2D and 3D variables; g2o files are one or "
                         "the other")
    dim = dims.pop() if dims else 2
    pkind, vkind = pose_kind(dim), vector_kind(dim)
    keys_all = list(values.keys())
    for kind, tag in ((pkind, "VERTEX_SE2" if dim == 2 else "VERTEX_SE3:QUAT"),
                      (vkind, "VERTEX_XY" if dim == 2 else "VERTEX_TRACKXYZ")):
        ks = [int(k) for k in keys_all if kinds[int(k)] is kind]
        if not ks:
            continue
        rows = np.array([kind.to_storage(values.at(k)) for k in ks], dtype=float)
        if kind is pkind:
            rows = se2_file(rows) if dim == 2 else se3_file(rows)
        vertex_lines += _fmt(tag, np.array([[id_of[k]] for k in ks]), rows)

    def ids_of(keys: np.ndarray) -> np.ndarray:
        try:
            return np.array([[id_of[k] for k in row] for row in keys.tolist()], dtype=np.int64)
        except KeyError as exc:
            raise FgoptError(f"write_g2o: a factor uses {key_str(exc.args[0])}, which has no "
                             "value") from None

    edge_lines: list[str] = []
    fixed: list[int] = []
    params_needed = False
    skipped: Counter = Counter()
    robust_total = 0
    betw, pp = between_kernel(pkind), pose_point_kernel(dim)
    priors = {prior_kernel(pkind): pkind, prior_kernel(vkind): vkind}
    for kernel, keys, consts, R, robust in _factor_blocks(graph):
        if kernel is None:
            skipped.update(keys)
            continue
        n = keys.shape[0]
        r = kernel.residual_dim
        info = np.broadcast_to(np.eye(r), (n, r, r)) if R is None else im.information_of(R)
        if kernel is betw or kernel is pp:
            robust_total += robust
            ids = ids_of(keys)
            if kernel is betw and dim == 2:
                info = im.permute(info, im.inverse_permutation(im.PERM_SE2))
                nums, tag = np.hstack([se2_file(consts), im.pack_upper(info)]), "EDGE_SE2"
            elif kernel is betw:
                info = im.permute(info, im.inverse_permutation(im.PERM_SE3))
                nums, tag = np.hstack([se3_file(consts), im.pack_upper(info)]), "EDGE_SE3:QUAT"
            elif dim == 2:
                nums, tag = np.hstack([consts, im.pack_upper(info)]), "EDGE_SE2_XY"
            else:
                params_needed = True
                ids = np.column_stack([ids, np.zeros(n, np.int64)])
                nums, tag = np.hstack([consts, im.pack_upper(info)]), "EDGE_SE3_TRACKXYZ"
            edge_lines += _fmt(tag, ids, nums)
        elif kernel in priors and R is not None:
            kind = priors[kernel]
            fix_R = np.eye(r) / FIX_SIGMA
            for row in range(n):
                k = int(keys[row, 0])
                at_value = (k in kinds and kinds[k] is kind and np.allclose(
                    kind.to_storage(values.at(k)), consts[row], rtol=0, atol=1e-9))
                if at_value and np.allclose(R[row], fix_R, rtol=1e-9, atol=0):
                    fixed.append(id_of[k])
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
    out = []
    if params_needed:
        out.append("PARAMS_SE3OFFSET 0 0 0 0 0 0 0 1")
    out += vertex_lines
    if fixed:
        out.append("FIX " + " ".join(map(str, dict.fromkeys(fixed))))
    out += edge_lines
    write_text(path, "\n".join(out) + "\n")
