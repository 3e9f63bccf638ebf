"""Block allocator for the growing pools (numba): power-of-two size classes with free lists.

A pool holds variable-size blocks (a clique's numbers, a clique's variables, a factor's local
system). A block of ``n`` entries takes ``2^k + 1`` slots, ``k = ceil(log2 n)``: one header and
its data. A freed block goes on the free list of its class, threaded through the headers, and
the next request of that class takes it back; a request with no free block extends the pool's
``top``. So an update never copies live data (a compacting pool stalled updates for
milliseconds), memory stays within twice the live data, and it stays bounded when a fixed-lag
smoother frees as much as it allocates.

Allocation only reads headers and moves a list head or ``top``; data are written after the
header. So restoring the list heads and ``top`` (both in ``meta``) undoes every allocation of a
failed update. Blocks are freed only after an update has succeeded.
"""

from __future__ import annotations

import numpy as np

from .._jit import njit

#: Size classes per pool (blocks up to 2^47 entries).
NCLASS = 48


@njit(cache=True, inline="always")
def size_class(n):
    k = 0
    while (1 << k) < n:
        k += 1
    return k


@njit(cache=True)
def _grown(pool, need):
    out = np.zeros(max(need, 2 * pool.shape[0]), pool.dtype)
    out[:pool.shape[0]] = pool
    return out


@njit(cache=True)
def alloc(pool, meta, top_index, head_base, n):
    """Offset of the data of a new block of ``n`` entries, and the (possibly grown) pool."""
    k = size_class(max(n, 1))
    h = meta[head_base + k]
    if h >= 0:
        meta[head_base + k] = np.int64(pool[h])
        return h + 1, pool
    h = meta[top_index]
    end = h + (1 << k) + 1
    if end > pool.shape[0]:
        pool = _grown(pool, end)
    meta[top_index] = end
    return h + 1, pool


@njit(cache=True)
def free(pool, meta, head_base, off, n):
    """Return the block whose data start at ``off`` (``n`` entries) to its free list."""
    k = size_class(max(n, 1))
    h = off - 1
    pool[h] = meta[head_base + k]
    meta[head_base + k] = h


@njit(cache=True)
def alloc_many(pool, meta, top_index, head_base, sizes):
    """:func:`alloc` for each of ``sizes``; returns ``(offsets, pool)``."""
    out = np.empty(sizes.shape[0], np.int64)
    for i in range(sizes.shape[0]):
        out[i], pool = alloc(pool, meta, top_index, head_base, sizes[i])
    return out, pool


@njit(cache=True)
def free_many(pool, meta, head_base, offsets, sizes):
    for i in range(offsets.shape[0]):
        free(pool, meta, head_base, offsets[i], sizes[i])


def capacity(pool: np.ndarray, meta: np.ndarray, top_index: int) -> tuple[int, int]:
    """``(slots used by blocks, pool length)`` for statistics."""
    return int(meta[top_index]), int(pool.shape[0])
