"""Elimination order of the re-eliminated top of the Bayes tree, with ordering groups.

iSAM2 orders the variables it re-eliminates with constrained COLAMD: the variables of the new
factors go last, so the next update finds them near the root (GTSAM's
``Ordering::ColamdConstrained``). Here a variable's *group* says when it may be eliminated:
all of group 0 (variables being marginalized by the fixed-lag smoother), then group 1, then
group 2 (the new factors' variables); inside a group the order is minimum degree.

Two implementations, chosen by size:

* ``min_degree``: exact minimum degree on an explicit elimination graph kept as bitsets (one
  row of ``ceil(t / 64)`` words per variable) with degree buckets. Eliminating ``p`` ORs its
  row into each neighbour's; the cost is ``O(t^2 / 64 + sum deg(p) t / 64)``, small for the
  tops of typical updates (tens to a few thousand variables).
* ``amd_groups`` (large tops, e.g. iSAM2's batch step): AMD (fgopt's kernel, :mod:`fgopt._amd`)
  on the whole top, then a stable partition by group (CAMD's constraint, applied after the
  fact).
"""

from __future__ import annotations

import numpy as np

from .._jit import njit
from ..structure import fill_reducing_order

#: Tops up to this many variables are ordered by the bitset minimum degree.
BITSET_LIMIT = 1500


@njit(cache=True)
def _popcount(x):
    x = x - ((x >> np.uint64(1)) & np.uint64(0x5555555555555555))
    x = (x & np.uint64(0x3333333333333333)) + ((x >> np.uint64(2)) & np.uint64(0x3333333333333333))
    x = (x + (x >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return (x * np.uint64(0x0101010101010101)) >> np.uint64(56)


@njit(cache=True)
def min_degree(t, ap, ai, group):
    """Minimum-degree order of ``t`` variables (symmetric adjacency ``ap, ai``), by group.

    Returns ``order`` with ``order[k]`` = the local variable eliminated ``k``-th. The variables
    of the group being ordered sit in doubly linked lists by degree, so the next pivot is found
    without scanning; ties go to the most recently (re)inserted variable (deterministic).
    """
    W = (t + 63) // 64
    adj = np.zeros((t, W), np.uint64)
    one = np.uint64(1)
    for u in range(t):
        for p in range(ap[u], ap[u + 1]):
            v = ai[p]
            if v != u:
                adj[u, v >> 6] |= one << np.uint64(v & 63)
    deg = np.zeros(t, np.int64)
    for u in range(t):
        s = 0
        for w in range(W):
            s += _popcount(adj[u, w])
        deg[u] = s
    done = np.zeros(t, np.bool_)
    head = np.full(t + 1, -1, np.int64)
    nxt = np.full(t, -1, np.int64)
    prv = np.full(t, -1, np.int64)
    order = np.empty(t, np.int64)
    gmax = 0
    for u in range(t):
        if group[u] > gmax:
            gmax = group[u]
    k = 0
    for g in range(gmax + 1):
        left = 0
        mind = t
        for u in range(t - 1, -1, -1):
            if group[u] == g:
                _bucket_insert(head, nxt, prv, deg, u)
                left += 1
                if deg[u] < mind:
                    mind = deg[u]
        while left > 0:
            while head[mind] == -1:
                mind += 1
            p = head[mind]
            _bucket_remove(head, nxt, prv, deg, p)
            done[p] = True
            order[k] = p
            k += 1
            left -= 1
            rowp = adj[p]
            bitp = one << np.uint64(p & 63)
            wp = p >> 6
            for w in range(W):
                word = rowp[w]
                while word != 0:
                    low = word & (~word + one)
                    u = w * 64 + np.int64(_popcount(low - one))  # index of the lowest set bit
                    word ^= low
                    # u's neighbours gain p's (the fill of eliminating p); u loses p and itself
                    for x in range(W):
                        adj[u, x] |= rowp[x]
                    adj[u, wp] &= ~bitp
                    adj[u, u >> 6] &= ~(one << np.uint64(u & 63))
                    s = 0
                    for x in range(W):
                        s += _popcount(adj[u, x])
                    if group[u] == g and not done[u]:
                        _bucket_remove(head, nxt, prv, deg, u)
                        deg[u] = s
                        _bucket_insert(head, nxt, prv, deg, u)
                        if s < mind:
                            mind = s
                    else:
                        deg[u] = s
    return order


@njit(cache=True, inline="always")
def _bucket_insert(head, nxt, prv, deg, u):
    d = deg[u]
    prv[u] = -1
    nxt[u] = head[d]
    if head[d] != -1:
        prv[head[d]] = u
    head[d] = u


@njit(cache=True, inline="always")
def _bucket_remove(head, nxt, prv, deg, u):
    if prv[u] != -1:
        nxt[prv[u]] = nxt[u]
    else:
        head[deg[u]] = nxt[u]
    if nxt[u] != -1:
        prv[nxt[u]] = prv[u]


def amd_groups(t: int, ap: np.ndarray, ai: np.ndarray, group: np.ndarray) -> np.ndarray:
    """AMD on the whole graph, then stably partitioned by group (large tops)."""
    rows = np.repeat(np.arange(t, dtype=np.int64), np.diff(ap))
    keep = rows < ai
    order = fill_reducing_order(t, rows[keep], ai[keep], "amd")
    return order[np.argsort(group[order], kind="stable")]


def elimination_order(t: int, ap: np.ndarray, ai: np.ndarray, group: np.ndarray) -> np.ndarray:
    """Order of the ``t`` top variables (see the module docstring)."""
    if t <= BITSET_LIMIT:
        return min_degree(t, ap, ai, group)
    return amd_groups(t, ap, ai, group)
