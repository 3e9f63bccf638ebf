"""numba kernels of :mod:`fgopt.structure`: the block layout of H's lower CSC, the whole pattern
in one call (used once numba is in use), row indices, the symmetric product and the scatter map;
and the small collection's numbering of a file's factors (:func:`block_var_idx`, also
into a given array: :func:`block_var_idx_into`).

Their vectorized NumPy forms (NumPy backend, and small work while the twin budget lasts) stay in
:mod:`fgopt.structure`, which picks between the two.
"""

from __future__ import annotations

import numpy as np

from ._jit import njit


@njit(cache=True, inline="always")
def lower_bound(a, lo, hi, v):
    """First position in the sorted ``a[lo:hi]`` whose value is not below ``v`` (``hi`` if
    none): bisection."""
    while lo < hi:
        mid = (lo + hi) // 2
        if a[mid] < v:
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit(cache=True)
def block_var_idx(block_keys, keys, used):
    """Each of ``keys (n, k)``'s row in ``block_keys``, marking the rows in ``used``:
    ``(var_idx (n, k), fresh)``, ``fresh`` the number of rows newly marked, or -1 when
    ``block_keys`` is not strictly ascending, a key is absent or a factor repeats a key (the
    caller's general path then says which)."""
    out = np.empty(keys.shape, dtype=np.int64)
    return out, block_var_idx_into(block_keys, keys, used, out)


@njit(cache=True)
def block_var_idx_into(block_keys, keys, used, out):
    """:func:`block_var_idx` writing ``var_idx`` into ``out (n, k)``; returns ``fresh`` (-1: as
    there). ``used``: flags, zero for rows not yet used (bool or integer)."""
    n, k = keys.shape
    N = block_keys.shape[0]
    for r in range(1, N):
        if block_keys[r] <= block_keys[r - 1]:
            return -1
    fresh = 0
    for i in range(n):
        for p in range(k):
            q = keys[i, p]
            r = lower_bound(block_keys, 0, N, q)
            if r == N or block_keys[r] != q:
                return -1
            for t in range(p):
                if out[i, t] == r:
                    return -1
            out[i, p] = r
            if not used[r]:
                used[r] = True
                fresh += 1
    return fresh


@njit(cache=True)
def sort_range(a, lo, hi):
    """Sort ``a[lo:hi]`` in place: insertion sort for short runs (no temporary; linear when
    already sorted), NumPy's sort above 32 entries."""
    if hi - lo > 32:
        a[lo:hi] = np.sort(a[lo:hi])
        return
    for u in range(lo + 1, hi):
        v = a[u]
        w = u
        while w > lo and a[w - 1] > v:
            a[w] = a[w - 1]
            w -= 1
        a[w] = v


@njit(cache=True)
def _block_layout(codes, V, order, var_dim, var_offset, N):
    """``indptr`` of the scalar CSC of blocks given as sorted rank codes, and the data index of
    each block's entry ``(0, 0)``."""
    nb = codes.shape[0]
    indptr = np.zeros(N + 1, dtype=np.int64)
    for b in range(nb):
        c, r = order[codes[b] // V], order[codes[b] % V]
        oc, dc, dr = var_offset[c], var_dim[c], var_dim[r]
        for cb in range(dc):
            indptr[oc + cb + 1] += dc - cb if c == r else dr
    for j in range(N):
        indptr[j + 1] += indptr[j]
    p00 = np.empty(nb, dtype=np.int64)
    fill = indptr[:-1].copy()  # per column: where the next block's rows go
    for b in range(nb):
        c, r = order[codes[b] // V], order[codes[b] % V]
        oc, dc, dr = var_offset[c], var_dim[c], var_dim[r]
        p00[b] = fill[oc] if dc else 0
        for cb in range(dc):
            fill[oc + cb] += dc - cb if c == r else dr
    return indptr, p00

@njit(cache=True)
def _pattern_kernel(var_dim, order, pairs_i, pairs_j, N):
    """:func:`fgopt.structure._pattern_np` in one numba call."""
    V = var_dim.shape[0]
    rank = np.empty(V, np.int64)
    var_offset = np.empty(V, np.int64)
    acc = 0
    for k in range(V):
        rank[order[k]] = k
        var_offset[order[k]] = acc
        acc += var_dim[order[k]]
    # bucket the blocks by column rank (the diagonal block first), then sort and deduplicate
    # each column's rows in place: O(pairs + V), no global sort
    m = pairs_i.shape[0]
    cnt = np.ones(V + 1, np.int64)
    cnt[V] = 0
    for e in range(m):
        a, b = rank[pairs_i[e]], rank[pairs_j[e]]
        if a != b:
            cnt[min(a, b)] += 1
    start = np.empty(V + 1, np.int64)
    start[0] = 0
    for k in range(V):
        start[k + 1] = start[k] + cnt[k]
    rows = np.empty(start[V], np.int64)
    fill = start[:V].copy()
    for k in range(V):
        rows[fill[k]] = k
        fill[k] += 1
    for e in range(m):
        a, b = rank[pairs_i[e]], rank[pairs_j[e]]
        if a != b:
            c = min(a, b)
            rows[fill[c]] = max(a, b)
            fill[c] += 1
    col_ptr = np.zeros(V + 1, np.int64)
    nb = 0
    for k in range(V):
        lo, hi = start[k], start[k + 1]
        sort_range(rows, lo, hi)
        for u in range(lo, hi):
            if u == lo or rows[u] != rows[u - 1]:
                rows[nb] = rows[u]  # nb <= u: writes never overtake reads
                nb += 1
        col_ptr[k + 1] = nb
    codes = np.empty(nb, np.int64)
    for k in range(V):
        for u in range(col_ptr[k], col_ptr[k + 1]):
            codes[u] = k * V + rows[u]
    indptr, p00 = _block_layout(codes, V, order, var_dim, var_offset, N)
    return var_offset, codes, indptr, p00, col_ptr

@njit(cache=True)
def _block_rows(codes, V, order, var_dim, var_offset, indptr):
    """Row indices of the scalar CSC (see :func:`_block_layout`)."""
    indices = np.empty(indptr[-1], dtype=np.int64)
    fill = indptr[:-1].copy()
    for b in range(codes.shape[0]):
        c, r = order[codes[b] // V], order[codes[b] % V]
        oc, orow, dc, dr = var_offset[c], var_offset[r], var_dim[c], var_dim[r]
        for cb in range(dc):
            col = oc + cb
            for a in range(cb if c == r else 0, dr):
                indices[fill[col]] = orow + a
                fill[col] += 1
    return indices


@njit(cache=True)
def _sym_matvec(indptr, indices, data, x):
    n = indptr.shape[0] - 1
    y = np.zeros(n)
    for j in range(n):
        xj = x[j]
        acc = 0.0
        for p in range(indptr[j], indptr[j + 1]):
            i = indices[p]
            v = data[p]
            y[i] += v * xj
            if i != j:
                acc += v * x[i]
        y[j] += acc
    return y

@njit(cache=True)
def _scatter_positions(codes, col_ptr, p00, V, var_rank, var_idx):
    # one pass per instance; each block is found by bisection within its column's blocks
    n, k = var_idx.shape
    pos = np.full((n, k, k), -1, dtype=np.int64)
    for i in range(n):
        for p in range(k):
            rp = var_rank[var_idx[i, p]]
            for q in range(k):
                rq = var_rank[var_idx[i, q]]
                if rp < rq or (p != q and rp == rq):
                    continue
                pos[i, p, q] = p00[lower_bound(codes, col_ptr[rq], col_ptr[rq + 1],
                                               rq * V + rp)]
    return pos


@njit(cache=True)
def _block_graph(num_vars, pairs_i, pairs_j):
    """:func:`fgopt.structure._block_graph_np` in one pass per step: the CSC ``(data, indices,
    indptr)`` of the symmetric variable graph with its diagonal, indices sorted, duplicates
    summed (each pair adds 1 at ``(i, j)`` and at ``(j, i)``; the diagonal holds
    ``2 * pairs + num_vars + 2``)."""
    V, P = num_vars, pairs_i.shape[0]
    count = np.ones(V + 1, dtype=np.int64)  # per column, entries before merging (diagonal: 1)
    count[V] = 0
    for p in range(P):
        count[pairs_j[p]] += 1
        count[pairs_i[p]] += 1
    start = np.zeros(V + 1, dtype=np.int64)
    for v in range(V):
        start[v + 1] = start[v] + count[v]
    rows = np.empty(start[V], dtype=np.int64)
    fill = start[:V].copy()
    for v in range(V):
        rows[fill[v]] = v
        fill[v] += 1
    for p in range(P):
        i, j = pairs_i[p], pairs_j[p]
        rows[fill[j]] = i
        fill[j] += 1
        rows[fill[i]] = j
        fill[i] += 1
    big = 2.0 * P + V + 2.0
    indptr = np.zeros(V + 1, dtype=np.int32)
    indices = np.empty(start[V], dtype=np.int32)
    data = np.empty(start[V])
    o = 0
    for v in range(V):
        sort_range(rows, start[v], start[v + 1])
        last = -1
        for u in range(start[v], start[v + 1]):
            r = rows[u]
            w = big if r == v else 1.0
            if r == last:
                data[o - 1] += w
            else:
                indices[o] = r
                data[o] = w
                o += 1
                last = r
        indptr[v + 1] = o
    return data[:o].copy(), indices[:o].copy(), indptr
