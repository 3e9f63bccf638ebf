"""Pose conversions between file vectors and fgopt storage rows, and the spanning-tree initial
guess for files without vertices.

File vectors: 2D ``(x, y, theta)``; 3D ``(x, y, z, qx, qy, qz, qw)``. Storage rows: SE2
``[cos, sin, x, y]``; SE3 ``[qx, qy, qz, qw, tx, ty, tz]`` (see :mod:`fgopt.manifolds`).
"""

from __future__ import annotations

from .._jit import njit, specialize
import numpy as np

from ..manifolds._kernels import MAX_STORAGE_DIM, lie_compose, lie_inverse

#: A quaternion whose norm is further than this from 1 is an error, not a rounding artefact.
QUATERNION_NORM_TOLERANCE = 1e-3


def se2_storage(xyt: np.ndarray) -> np.ndarray:
    """``(n, 3)`` ``(x, y, theta)`` -> ``(n, 4)`` SE2 storage."""
    out = np.empty((xyt.shape[0], 4))
    out[:, 0] = np.cos(xyt[:, 2])
    out[:, 1] = np.sin(xyt[:, 2])
    out[:, 2:] = xyt[:, :2]
    return out


def se2_file(storage: np.ndarray) -> np.ndarray:
    """``(n, 4)`` SE2 storage -> ``(n, 3)`` ``(x, y, theta)``."""
    return np.column_stack([storage[:, 2], storage[:, 3],
                            np.arctan2(storage[:, 1], storage[:, 0])])


def se3_storage(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(n, 7)`` ``(x, y, z, qx, qy, qz, qw)`` -> ``((n, 7)`` SE3 storage, ``(n,)`` quaternion
    norms before normalization)."""
    q = v[:, 3:7]
    norm = np.linalg.norm(q, axis=1)
    out = np.empty((v.shape[0], 7))
    out[:, :4] = q / np.where(norm > 0, norm, 1.0)[:, None]
    out[:, 4:] = v[:, :3]
    return out, norm


def se3_file(storage: np.ndarray) -> np.ndarray:
    """``(n, 7)`` SE3 storage -> ``(n, 7)`` ``(x, y, z, qx, qy, qz, qw)``."""
    return np.column_stack([storage[:, 4:7], storage[:, :4]])


@njit(cache=True, inline="always")  # specialize()d per group
def _compose_tree(gid, poses, order, parent, rel, flip):
    """``poses[c] = poses[parent[c]] * (rel[c] or rel[c]^-1)`` in BFS ``order`` (root first)."""
    inv = np.empty(MAX_STORAGE_DIM)
    for c in order:
        p = parent[c]
        if p < 0:
            continue
        r = rel[c]
        if flip[c]:
            lie_inverse(gid, rel[c], inv)
            r = inv[:rel.shape[1]]
        lie_compose(gid, poses[p], r, poses[c])


def spanning_tree_guess(gid: int, identity: np.ndarray, num_nodes: int, src: np.ndarray,
                        dst: np.ndarray, meas: np.ndarray) -> tuple[np.ndarray, int]:
    """Poses ``(num_nodes, s)`` from relative measurements ``dst = src * meas`` composed along a
    BFS spanning tree from node 0; every further component starts at identity from its lowest
    node. Returns the poses and the number of components.
    """
    import scipy.sparse as sp  # here: scipy.sparse.csgraph costs ~0.3 s to import
    from scipy.sparse.csgraph import breadth_first_order

    n = num_nodes
    ones = np.ones(2 * src.shape[0])
    A = sp.csr_matrix((ones, (np.concatenate([src, dst]), np.concatenate([dst, src]))),
                      shape=(n, n))
    poses = np.tile(identity, (n, 1))
    parent = np.full(n, -1, dtype=np.int64)
    rel = np.tile(identity, (n, 1))
    flip = np.zeros(n, dtype=np.bool_)
    seen = np.zeros(n, dtype=bool)
    components = 0
    pair_edge = {}
    for e, (a, b) in enumerate(zip(src.tolist(), dst.tolist())):
        pair_edge.setdefault((a, b), e)
    for root in range(n):
        if seen[root]:
            continue
        components += 1
        order, pred = breadth_first_order(A, root, directed=False, return_predecessors=True)
        seen[order] = True
        kids = order[1:]
        par = pred[kids]
        parent[kids] = par
        for c, p in zip(kids.tolist(), par.tolist()):
            e = pair_edge.get((p, c))
            if e is not None:
                rel[c] = meas[e]
            else:
                rel[c] = meas[pair_edge[(c, p)]]
                flip[c] = True
        specialize(_compose_tree, gid)(poses, order.astype(np.int64), parent, rel, flip)
    return poses, components
