"""Approximate minimum degree ordering (Amestoy, Davis & Duff 1996) as one numba kernel.

fgopt orders the *block* graph of a problem (one node per variable), a few hundred to a few
ten thousand nodes. CHOLMOD's AMD computes the same kind of ordering, but through
scikit-sparse it also runs a symbolic factorization and converts the matrix: on a 400-pose
2D graph that call cost ~0.24 ms inside a solve, plus ~0.1 ms to build its CSC input, of a
~3 ms 5-iteration solve. This kernel takes the coupled pairs directly.

The method, as in the paper: eliminate on the *quotient graph*, where each eliminated pivot
``k`` becomes an element ``L_k`` (the variables it couples) and absorbs the elements adjacent
to it, so the graph never grows beyond its initial size plus the new elements' lists. Each
variable ``i`` keeps an *approximate external degree*, an upper bound of its true degree:

    d_i = min(n - eliminated - |i|, d_i_old + |L_k \\ i|,
              |A_i \\ i| + |L_k \\ i| + sum_{e != k} |L_e \\ L_k|)

where ``|L_e \\ L_k|`` is computed for all elements at once by one pass over ``L_k``'s
variables. Indistinguishable variables are merged into supervariables (found by hashing their
lists), elements whose variables all lie in ``L_k`` are absorbed (aggressive absorption), a
variable whose only neighbour is the new element is eliminated with it (mass elimination), and
nodes of degree above ``max(16, 10 sqrt(n))`` are ordered last. The result is a postorder of
the assembly tree (children before parents, each pivot followed by the variables eliminated
with it), which keeps supernodes contiguous for the block Cholesky's analysis.
"""

from __future__ import annotations

import numpy as np

from ._jit import njit

# node states
_VARIABLE, _ELEMENT, _ABSORBED, _MERGED, _DENSE = 0, 1, 2, 3, 4


@njit(cache=True)
def _adjacency(n, pairs_i, pairs_j):
    """CSR ``(ptr, adj)`` of the symmetric graph of the pairs, without self loops and
    duplicates; ``ptr`` is empty when a pair names a node outside ``0..n-1``."""
    m = pairs_i.shape[0]
    cnt = np.zeros(n + 1, dtype=np.int64)
    for t in range(m):
        a, b = pairs_i[t], pairs_j[t]
        if a < 0 or a >= n or b < 0 or b >= n:
            return np.empty(0, dtype=np.int64), np.empty(0, dtype=np.int64)
        if a != b:
            cnt[a + 1] += 1
            cnt[b + 1] += 1
    for v in range(n):
        cnt[v + 1] += cnt[v]
    fill = cnt[:n].copy()
    raw = np.empty(cnt[n], dtype=np.int64)
    for t in range(m):
        a, b = pairs_i[t], pairs_j[t]
        if a != b:
            raw[fill[a]] = b
            fill[a] += 1
            raw[fill[b]] = a
            fill[b] += 1
    # drop duplicates with a per-node mark
    mark = np.full(n, -1, dtype=np.int64)
    ptr = np.zeros(n + 1, dtype=np.int64)
    adj = np.empty(cnt[n], dtype=np.int64)
    q = 0
    for v in range(n):
        for p in range(cnt[v], cnt[v + 1]):
            u = raw[p]
            if mark[u] != v:
                mark[u] = v
                adj[q] = u
                q += 1
        ptr[v + 1] = q
    return ptr, adj[:q]


@njit(cache=True)
def _compress(iw, pe, len_, status, n):
    """Move every live list (variables' and elements') to the front of ``iw``, keeping their
    order; returns the first free position."""
    live = np.empty(n, dtype=np.int64)
    c = 0
    for i in range(n):
        if (status[i] == _VARIABLE or status[i] == _ELEMENT) and len_[i] > 0:
            live[c] = i
            c += 1
    starts = np.empty(c, dtype=np.int64)
    for t in range(c):
        starts[t] = pe[live[t]]
    order = np.argsort(starts)
    dst = 0
    for t in range(c):
        i = live[order[t]]
        src = pe[i]
        pe[i] = dst
        for p in range(len_[i]):  # dst <= src: lists are disjoint and visited in place order
            iw[dst] = iw[src + p]
            dst += 1
    return dst


@njit(cache=True)
def amd_order(n, pairs_i, pairs_j, dense_factor=10.0, elbow=-1):
    """Elimination order ``perm`` (``perm[k]`` = the ``k``-th eliminated node) of the graph on
    ``n`` nodes with edges ``(pairs_i[t], pairs_j[t])`` (any order, duplicates and self pairs
    allowed; ``pairs_j`` at least as long as ``pairs_i``). Empty when a pair names a node
    outside ``0..n-1``. ``elbow``: free room after the graph's lists for new elements
    (default ``nnz / 2 + 4 n``; less only makes the lists compacted more often)."""
    if n == 0:
        return np.empty(0, dtype=np.int64)
    ptr, adj = _adjacency(n, pairs_i, pairs_j)
    if ptr.shape[0] == 0:
        return np.empty(0, dtype=np.int64)
    nnz = ptr[n]
    iwlen = nnz + (nnz // 2 + 4 * n + 16 if elbow < 0 else elbow)
    iw = np.empty(iwlen, dtype=np.int64)
    iw[:nnz] = adj
    pfree = nnz
    pe = ptr[:n].copy()
    len_ = np.empty(n, dtype=np.int64)
    elen = np.zeros(n, dtype=np.int64)   # number of elements at the head of a variable's list
    nv = np.ones(n, dtype=np.int64)      # supervariable sizes (negative: in L_k this step)
    degree = np.empty(n, dtype=np.int64)
    status = np.zeros(n, dtype=np.int64)
    parent = np.full(n, -1, dtype=np.int64)  # element -> absorbing element; merged var -> node
    head = np.full(n + 1, -1, dtype=np.int64)
    nxt = np.full(n, -1, dtype=np.int64)
    last = np.full(n, -1, dtype=np.int64)
    w = np.ones(n, dtype=np.int64)       # element marks (0: dead), list marks
    hhead = np.full(n, -1, dtype=np.int64)
    hnext = np.full(n, -1, dtype=np.int64)
    hkey = np.zeros(n, dtype=np.int64)
    pivots = np.empty(n, dtype=np.int64)  # elements in the order they were made
    npiv = 0
    wflg = 2
    nel = 0
    dense = max(16.0, dense_factor * np.sqrt(float(n)))
    for i in range(n):
        len_[i] = ptr[i + 1] - ptr[i]
        degree[i] = len_[i]
    for i in range(n):
        if n > 16 and degree[i] > dense:
            status[i] = _DENSE   # dropped from every list it is in (nv 0), ordered last
            nv[i] = 0
            nel += 1
            len_[i] = 0
    for i in range(n):
        if status[i] == _VARIABLE:
            d = degree[i]
            nxt[i] = head[d]
            if head[d] != -1:
                last[head[d]] = i
            head[d] = i
    mindeg = 0
    while nel < n:
        # ---- the pivot: a variable of least approximate degree
        k = -1
        while mindeg <= n:
            k = head[mindeg]
            if k != -1:
                break
            mindeg += 1
        if k == -1:
            break
        if nxt[k] != -1:
            last[nxt[k]] = -1
        head[mindeg] = nxt[k]
        elenk = elen[k]
        nvk = nv[k]
        nel += nvk
        # ---- L_k: k's variables and those of the elements adjacent to k (which it absorbs)
        need = n - nel + nvk  # L_k has at most this many variables
        if elenk > 0 and pfree + need > iwlen:
            pfree = _compress(iw, pe, len_, status, n)
            if pfree + need > iwlen:  # (live lists never exceed nnz: kept as a guard)
                iwlen = pfree + need + n
                grown = np.empty(iwlen, dtype=np.int64)
                grown[:pfree] = iw[:pfree]
                iw = grown
        nv[k] = -nvk
        p = pe[k]
        pk1 = p if elenk == 0 else pfree
        pk2 = pk1
        dk = 0
        for kk in range(elenk + 1):
            if kk < elenk:
                e = iw[p]
                p += 1
                pj = pe[e]
                ln = len_[e]
            else:
                e = k
                pj = p
                ln = len_[k] - elenk
            for _ in range(ln):
                i = iw[pj]
                pj += 1
                nvi = nv[i]
                if nvi <= 0:
                    continue  # in L_k already, merged, or dense
                dk += nvi
                nv[i] = -nvi
                iw[pk2] = i
                pk2 += 1
                # out of its degree list
                if nxt[i] != -1:
                    last[nxt[i]] = last[i]
                if last[i] != -1:
                    nxt[last[i]] = nxt[i]
                else:
                    head[degree[i]] = nxt[i]
            if e != k:
                status[e] = _ABSORBED
                parent[e] = k
                w[e] = 0
                len_[e] = 0
        if elenk != 0:
            pfree = pk2
        status[k] = _ELEMENT
        elen[k] = 0
        pe[k] = pk1
        len_[k] = pk2 - pk1
        pivots[npiv] = k
        npiv += 1
        # ---- |L_e \ L_k| for every element e adjacent to L_k, in w[e] - wflg
        for pk in range(pk1, pk2):
            i = iw[pk]
            eln = elen[i]
            if eln <= 0:
                continue
            nvi = -nv[i]
            for p in range(pe[i], pe[i] + eln):
                e = iw[p]
                we = w[e]
                if we >= wflg:
                    w[e] = we - nvi
                elif we != 0:
                    w[e] = degree[e] + wflg - nvi
        # ---- degree update, aggressive absorption, mass elimination, hashes
        for pk in range(pk1, pk2):
            i = iw[pk]
            p1 = pe[i]
            p2 = p1 + elen[i]
            pn = p1
            h = 0
            d = 0
            for p in range(p1, p2):
                e = iw[p]
                if w[e] != 0:
                    dext = w[e] - wflg
                    if dext > 0:
                        d += dext
                        iw[pn] = e
                        pn += 1
                        h += e
                    else:  # L_e inside L_k: e is absorbed into k
                        status[e] = _ABSORBED
                        parent[e] = k
                        w[e] = 0
                        len_[e] = 0
            elen[i] = pn - p1 + 1  # the kept elements, and k
            p3 = pn
            for p in range(p2, p1 + len_[i]):
                j = iw[p]
                nvj = nv[j]
                if nvj <= 0:
                    continue
                d += nvj
                iw[pn] = j
                pn += 1
                h += j
            if elen[i] == 1 and p3 == pn:
                # only k is adjacent: i is eliminated together with k
                nvi = -nv[i]
                dk -= nvi
                nvk += nvi
                nel += nvi
                nv[i] = 0
                elen[i] = 0
                len_[i] = 0
                status[i] = _MERGED
                parent[i] = k
            else:
                degree[i] = min(degree[i], d)
                # k first: move the first variable to the end and the first element in its place
                iw[pn] = iw[p3]
                iw[p3] = iw[p1]
                iw[p1] = k
                len_[i] = pn - p1 + 1
                h = h % n
                hkey[i] = h
                hnext[i] = hhead[h]
                hhead[h] = i
        degree[k] = dk
        wflg += n + 1
        # ---- supervariables: variables of L_k with identical lists are merged
        for pk in range(pk1, pk2):
            i = iw[pk]
            if nv[i] >= 0:
                continue
            h = hkey[i]
            i2 = hhead[h]
            if i2 == -1:
                continue
            hhead[h] = -1
            while i2 != -1 and hnext[i2] != -1:
                ln = len_[i2]
                eln = elen[i2]
                for p in range(pe[i2] + 1, pe[i2] + ln):
                    w[iw[p]] = wflg
                jlast = i2
                j = hnext[i2]
                while j != -1:
                    same = len_[j] == ln and elen[j] == eln
                    p = pe[j] + 1
                    while same and p < pe[j] + ln:
                        if w[iw[p]] != wflg:
                            same = False
                        p += 1
                    if same:
                        nv[i2] += nv[j]  # both negative
                        nv[j] = 0
                        elen[j] = 0
                        len_[j] = 0
                        status[j] = _MERGED
                        parent[j] = i2
                        hnext[jlast] = hnext[j]
                    else:
                        jlast = j
                    j = hnext[j]
                wflg += 1
                i2 = hnext[i2]
        wflg += 1
        # ---- final degrees of L_k's variables; L_k keeps its principal variables
        p = pk1
        for pk in range(pk1, pk2):
            i = iw[pk]
            nvi = -nv[i]
            if nvi <= 0:
                continue
            nv[i] = nvi
            d = min(degree[i] + dk - nvi, n - nel - nvi)
            nxt[i] = head[d]
            last[i] = -1
            if head[d] != -1:
                last[head[d]] = i
            head[d] = i
            if d < mindeg:
                mindeg = d
            degree[i] = d
            iw[p] = i
            p += 1
        nv[k] = nvk
        len_[k] = p - pk1
        if len_[k] == 0:
            pe[k] = -1
    return _postorder(n, status, parent, pivots, npiv)


@njit(cache=True)
def _postorder(n, status, parent, pivots, npiv):
    """Children before parents in the assembly tree (siblings in the order they were made),
    each pivot followed by the variables merged into it; dense nodes last."""
    # merged variables -> the pivot they were eliminated with (a chain: merged into a variable
    # that was itself merged or became a pivot)
    owner = np.full(n, -1, dtype=np.int64)
    for i in range(n):
        if status[i] == _MERGED:
            r = i
            while status[r] == _MERGED:
                r = parent[r]
            owner[i] = r
    mhead = np.full(n, -1, dtype=np.int64)
    mnext = np.full(n, -1, dtype=np.int64)
    for i in range(n - 1, -1, -1):
        if owner[i] >= 0:
            mnext[i] = mhead[owner[i]]
            mhead[owner[i]] = i
    # children lists of the element tree, in creation order
    chead = np.full(n, -1, dtype=np.int64)
    cnext = np.full(n, -1, dtype=np.int64)
    for t in range(npiv - 1, -1, -1):
        e = pivots[t]
        pa = parent[e]
        if pa >= 0:
            cnext[e] = chead[pa]
            chead[pa] = e
    perm = np.empty(n, dtype=np.int64)
    q = 0
    stack = np.empty(n, dtype=np.int64)
    for t in range(npiv):
        root = pivots[t]
        if parent[root] >= 0:
            continue
        top = 0
        stack[0] = root
        while top >= 0:
            e = stack[top]
            c = chead[e]
            if c != -1:
                chead[e] = cnext[c]  # descend into the next unvisited child
                top += 1
                stack[top] = c
            else:
                top -= 1
                perm[q] = e
                q += 1
                m = mhead[e]
                while m != -1:
                    perm[q] = m
                    q += 1
                    m = mnext[m]
    for i in range(n):
        if status[i] == _DENSE:
            perm[q] = i
            q += 1
    return perm[:q]
