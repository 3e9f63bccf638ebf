"""Symbolic analysis for the block supernodal Cholesky (numba kernels, run once per pattern).

Works on the *variable* (block) graph of H: ``rank`` numbers the variables in the pattern's
elimination order (offset order). The steps follow the classic supernodal set-up (Liu's
elimination tree, symbolic factorization by merging children's structures, fundamental
supernodes, relaxed amalgamation), at block granularity: one block column per variable.
"""

from __future__ import annotations

import numpy as np
from ..._jit import njit
from ..._structure_kernels import sort_range


@njit(cache=True)
def etree(n, ap, ai):
    """Elimination tree of a symmetric pattern given by its strict lower adjacency."""
    # transpose: for each k the columns j < k with an entry in row k
    tp = np.zeros(n + 1, np.int64)
    for p in range(ap[n]):
        tp[ai[p] + 1] += 1
    for k in range(n):
        tp[k + 1] += tp[k]
    tj = np.empty(ap[n], np.int64)
    fill = tp[:n].copy()
    for j in range(n):
        for p in range(ap[j], ap[j + 1]):
            i = ai[p]
            tj[fill[i]] = j
            fill[i] += 1
    parent = np.full(n, -1, np.int64)
    anc = np.full(n, -1, np.int64)
    for k in range(n):
        for p in range(tp[k], tp[k + 1]):
            i = tj[p]
            while i != -1 and i != k:  # walk to the root, compressing the path to k
                nxt = anc[i]
                anc[i] = k
                if nxt == -1:
                    parent[i] = k
                i = nxt
    return parent


@njit(cache=True)
def symbolic_columns(n, ap, ai, parent):
    """Block structure of every column of L (strictly below the diagonal), CSR-like.

    ``struct(j) = adj(j) | union of struct(c) - {j}`` over the children ``c`` of ``j``;
    children precede parents (``parent[j] > j``), so one pass in rank order suffices.
    """
    # child lists
    head = np.full(n, -1, np.int64)
    nxt = np.full(n, -1, np.int64)
    for j in range(n - 1, -1, -1):
        p = parent[j]
        if p >= 0:
            nxt[j] = head[p]
            head[p] = j
    cap = max(16, 2 * ap[n])
    lp = np.zeros(n + 1, np.int64)
    li = np.empty(cap, np.int64)
    mark = np.full(n, -1, np.int64)
    buf = np.empty(n, np.int64)
    for j in range(n):
        cnt = 0
        mark[j] = j
        for p in range(ap[j], ap[j + 1]):
            i = ai[p]
            if mark[i] != j:
                mark[i] = j
                buf[cnt] = i
                cnt += 1
        c = head[j]
        while c != -1:
            for p in range(lp[c], lp[c + 1]):
                i = li[p]
                if mark[i] != j:
                    mark[i] = j
                    buf[cnt] = i
                    cnt += 1
            c = nxt[c]
        if lp[j] + cnt > cap:
            cap = 2 * (lp[j] + cnt)
            new = np.empty(cap, np.int64)
            new[:lp[j]] = li[:lp[j]]
            li = new
        base = lp[j]
        for t in range(cnt):  # insertion sort into li: the lists are short
            v = buf[t]
            u = base + t
            while u > base and li[u - 1] > v:
                li[u] = li[u - 1]
                u -= 1
            li[u] = v
        lp[j + 1] = lp[j] + cnt
    return lp, li[:lp[n]].copy()


@njit(cache=True)
def postorder(n, parent, weight):
    """Postorder of a forest; children (and roots) visited in increasing ``weight``."""
    order = np.argsort(weight, kind="mergesort")
    head = np.full(n, -1, np.int64)
    nxt = np.full(n, -1, np.int64)
    for t in range(n - 1, -1, -1):   # push heaviest first: lists run lightest -> heaviest
        j = order[t]
        p = parent[j]
        if p >= 0:
            nxt[j] = head[p]
            head[p] = j
    post = np.empty(n, np.int64)
    stack = np.empty(n, np.int64)
    k = 0
    for t in range(n):
        r = order[t]
        if parent[r] != -1:
            continue
        top = 0
        stack[0] = r
        while top >= 0:
            j = stack[top]
            c = head[j]
            if c == -1:
                top -= 1
                post[k] = j
                k += 1
            else:
                head[j] = nxt[c]
                top += 1
                stack[top] = c
    return post


@njit(cache=True)
def supernode_partition(n, parent, cnt, dim, below, relax_cols, relax_zeros):
    """Column partition into supernodes, in postorder numbering (``parent[j] > j``).

    Fundamental step: ``j`` joins ``j + 1`` when ``parent[j] == j + 1`` and ``cnt[j] ==
    cnt[j + 1] + 1`` (block counts below the diagonal), i.e. the structures nest exactly.
    Relaxed amalgamation then merges a supernode into the group of supernodes that follows it
    when that group holds its parent, if the fraction of explicit zeros of the merged panel is
    below ``relax_zeros[t]`` for the first ``t`` with ``width <= relax_cols[t]``.
    ``below[j]``: scalar rows of column ``j``'s structure below its diagonal block.
    Returns the first column of every supernode (plus ``n``).
    """
    first = np.empty(n + 1, np.int64)
    nsn = 0
    for j in range(n):
        if j == 0 or not (parent[j - 1] == j and cnt[j - 1] == cnt[j] + 1):
            first[nsn] = j
            nsn += 1
    first[nsn] = n
    sn_of = np.empty(n, np.int64)
    w = np.zeros(nsn, np.int64)
    sparent = np.full(nsn, -1, np.int64)
    for s in range(nsn):
        for j in range(first[s], first[s + 1]):
            sn_of[j] = s
            w[s] += dim[j]
    m = np.empty(nsn, np.int64)
    for s in range(nsn):
        top = first[s + 1] - 1
        m[s] = w[s] + below[top]
        if parent[top] >= 0:
            sparent[s] = sn_of[parent[top]]
    # amalgamate, scanning supernodes from the last one down
    keep = np.zeros(nsn + 1, np.bool_)
    keep[nsn] = True
    cs, ce = nsn - 1, nsn            # current group [cs, ce)
    cw, cm, cz = w[nsn - 1], m[nsn - 1], 0.0
    for s in range(nsn - 2, -1, -1):
        ps = sparent[s]
        merged = False
        if ps >= cs and ps < ce:
            wn = w[s] + cw
            mn = w[s] + cm
            zn = cz + w[s] * (w[s] + cm - m[s])
            total = wn * mn - wn * (wn - 1) // 2
            frac = zn / total
            for t in range(relax_cols.shape[0]):
                if wn <= relax_cols[t]:
                    merged = frac <= relax_zeros[t]
                    break
            if merged:
                cs, cw, cm, cz = s, wn, mn, zn
        if not merged:
            keep[cs] = True
            cs, ce, cw, cm, cz = s, cs, w[s], m[s], 0.0
    keep[cs] = True
    out = np.empty(nsn + 1, np.int64)
    k = 0
    for s in range(nsn + 1):
        if keep[s]:
            out[k] = first[s]
            k += 1
    return out[:k].copy()


@njit(cache=True)
def supernode_rows(sn, post, ipost, lp, li, dim_p):
    """Row variables of each supernode (its own, then the ones below, in postorder labels).

    Returns ``rvp, rvi`` (CSR over supernodes) and ``rpos``: the scalar row offset of each
    listed variable inside its supernode's panel.
    """
    nsn = sn.shape[0] - 1
    rvp = np.zeros(nsn + 1, np.int64)
    for s in range(nsn):
        top = post[sn[s + 1] - 1]
        rvp[s + 1] = rvp[s] + (sn[s + 1] - sn[s]) + (lp[top + 1] - lp[top])
    rvi = np.empty(rvp[nsn], np.int64)
    rpos = np.empty(rvp[nsn], np.int64)
    for s in range(nsn):
        k = rvp[s]
        for j in range(sn[s], sn[s + 1]):
            rvi[k] = j
            k += 1
        top = post[sn[s + 1] - 1]
        nb = lp[top + 1] - lp[top]
        for p in range(nb):
            rvi[k + p] = ipost[li[lp[top] + p]]
        sort_range(rvi, k, k + nb)
        acc = 0
        for p in range(rvp[s], rvp[s + 1]):
            rpos[p] = acc
            acc += dim_p[rvi[p]]
    return rvp, rvi, rpos


# ------------------------------------------------------------------ symbolic maps
@njit(cache=True)
def build_maps(sn, rvp, rvi, rpos, dim, off, pstart, rows, width):
    """Scatter runs of every supernode's update into its ancestors' panels.

    For supernode ``s`` and each of its below variables ``b_j`` (a column block of the update
    ``C``): the target panel column base and leading dimension, ``C``'s column offset and the
    runs ``(C row offset, target row offset, length)`` of rows ``b_i, i >= j`` that are
    contiguous in both ``C`` and the target panel.
    """
    S = sn.shape[0] - 1
    V = dim.shape[0]
    sn_of = np.empty(V, np.int64)
    for s in range(S):
        for j in range(sn[s], sn[s + 1]):
            sn_of[j] = s
    ncb = 0
    for s in range(S):
        ncb += (rvp[s + 1] - rvp[s]) - (sn[s + 1] - sn[s])
    cb_ptr = np.zeros(S + 1, np.int64)
    cb_base = np.empty(ncb, np.int64)
    cb_ld = np.empty(ncb, np.int64)
    cb_src = np.empty(ncb, np.int64)
    cb_dim = np.empty(ncb, np.int64)
    run_ptr = np.zeros(ncb + 1, np.int64)
    cap = 4 * ncb + 16
    run_src = np.empty(cap, np.int64)
    run_dst = np.empty(cap, np.int64)
    run_len = np.empty(cap, np.int64)
    jb = 0
    nr = 0
    for s in range(S):
        q_lo = rvp[s] + (sn[s + 1] - sn[s])    # first below variable of s
        q_hi = rvp[s + 1]
        w = width[s]
        for qj in range(q_lo, q_hi):
            bj = rvi[qj]
            t = sn_of[bj]
            t_lo, t_hi = rvp[t], rvp[t + 1]
            col = off[bj] - off[sn[t]]
            cb_base[jb] = pstart[t] + col * rows[t]
            cb_ld[jb] = rows[t]
            cb_src[jb] = rpos[qj] - w
            cb_dim[jb] = dim[bj]
            pt = t_lo
            last_src = -1
            last_end = -1
            for qi in range(qj, q_hi):
                bi = rvi[qi]
                while rvi[pt] != bi:           # both lists are sorted; t's holds s's below rows
                    pt += 1
                    if pt >= t_hi:
                        raise ValueError("block Cholesky: inconsistent supernode structures")
                src = rpos[qi] - w
                dst = rpos[pt]
                if nr > 0 and run_ptr[jb] < nr and src == last_src and dst == last_end:
                    run_len[nr - 1] += dim[bi]
                else:
                    if nr >= cap:
                        cap *= 2
                        run_src = _grow(run_src, cap)
                        run_dst = _grow(run_dst, cap)
                        run_len = _grow(run_len, cap)
                    run_src[nr] = src
                    run_dst[nr] = dst
                    run_len[nr] = dim[bi]
                    nr += 1
                last_src = src + dim[bi]
                last_end = dst + dim[bi]
            jb += 1
            run_ptr[jb] = nr
        cb_ptr[s + 1] = jb
    return (cb_ptr, cb_base, cb_ld, cb_src, cb_dim, run_ptr, run_src[:nr].copy(),
            run_dst[:nr].copy(), run_len[:nr].copy())


@njit(cache=True)
def _grow(a, cap):
    out = np.empty(cap, a.dtype)
    out[:a.shape[0]] = a
    return out


@njit(cache=True)
def build_hmap_blocks(codes, V, order, p00, col_shift, var_offset, var_dim, new_var, sn_of, off,
                      sn, rvp, rvi, rpos, pstart, rows, hmap):
    """Position in the panels of every stored entry of H's lower CSC (pattern order), written
    into ``hmap`` (int32 when the panels allow: half the bytes), block by block from the
    pattern's block list (``codes``, ``p00``; :class:`fgopt.structure.HessianPattern`): each
    column of a block is a run of consecutive entries of H and, unless the new order transposes
    the block, of its panel too.
    ``new_var``: the postorder label of each pattern variable."""
    for b in range(codes.shape[0]):
        c = order[codes[b] // V]
        r = order[codes[b] % V]
        J = new_var[c]
        I = new_var[r]
        flip = I < J
        if flip:
            I, J = J, I
        s = sn_of[J]
        lo, hi = rvp[s], rvp[s + 1]
        while hi - lo > 1:                 # binary search of I in s's sorted rows
            mid = (lo + hi) // 2
            if rvi[mid] <= I:
                lo = mid
            else:
                hi = mid
        m = rows[s]
        base = pstart[s] + (off[J] - off[sn[s]]) * m + rpos[lo]
        oc = var_offset[c]
        for cb in range(var_dim[c]):
            h = p00[b] + col_shift[oc + cb]
            a0 = cb if c == r else 0
            if flip:   # entry (a, cb) is (cb, a) of the panel's block
                for a in range(a0, var_dim[r]):
                    hmap[h + a] = base + a * m + cb
            else:
                t = base + cb * m
                for a in range(a0, var_dim[r]):
                    hmap[h + a] = t + a
    return hmap


# ------------------------------------------------------------------ one call
@njit(cache=True)
def _lower_adjacency(codes, V, order, rank_of_var):
    """:func:`block_graph_of_codes` in numba: bucket the strict lower blocks by column rank,
    rows sorted within each column."""
    nb = codes.shape[0]
    ap = np.zeros(V + 1, np.int64)
    col = np.empty(nb, np.int64)
    row = np.empty(nb, np.int64)
    m = 0
    for b in range(nb):
        c = rank_of_var[order[codes[b] // V]]
        r = rank_of_var[order[codes[b] % V]]
        if r != c:
            col[m] = c
            row[m] = r
            ap[c + 1] += 1
            m += 1
    for k in range(V):
        ap[k + 1] += ap[k]
    ai = np.empty(m, np.int64)
    fill = ap[:V].copy()
    for t in range(m):
        ai[fill[col[t]]] = row[t]
        fill[col[t]] += 1
    for k in range(V):  # already sorted when the ranks follow the order
        sort_range(ai, ap[k], ap[k + 1])
    return ap, ai


@njit(cache=True)
def analyze_pattern(codes, V, order, var_offset, var_dim, relax_cols, relax_zeros):
    """The whole symbolic analysis of a block pattern in one call (the steps of
    ``block_cholesky.analyze_blocks``): returns ``(post_var, dim_p, off_p, sn, rvp, rvi, rpos,
    width, rows, pstart, sparent)``."""
    vorder = np.argsort(var_offset, kind="mergesort")
    dim_r = var_dim[vorder]
    rank_of_var = np.empty(V, np.int64)
    for k in range(V):
        rank_of_var[vorder[k]] = k
    ap, ai = _lower_adjacency(codes, V, order, rank_of_var)
    parent = etree(V, ap, ai)
    lp, li = symbolic_columns(V, ap, ai, parent)
    cnt = np.empty(V, np.int64)
    below = np.zeros(V, np.int64)
    for j in range(V):
        cnt[j] = lp[j + 1] - lp[j]
        for p in range(lp[j], lp[j + 1]):
            below[j] += dim_r[li[p]]
    post = postorder(V, parent, cnt)
    ipost = np.empty(V, np.int64)
    for k in range(V):
        ipost[post[k]] = k
    par_p = np.empty(V, np.int64)
    dim_p = np.empty(V, np.int64)
    cnt_p = np.empty(V, np.int64)
    below_p = np.empty(V, np.int64)
    for k in range(V):
        q = parent[post[k]]
        par_p[k] = ipost[q] if q >= 0 else -1
        dim_p[k] = dim_r[post[k]]
        cnt_p[k] = cnt[post[k]]
        below_p[k] = below[post[k]]
    sn = supernode_partition(V, par_p, cnt_p, dim_p, below_p, relax_cols, relax_zeros)
    rvp, rvi, rpos = supernode_rows(sn, post, ipost, lp, li, dim_p)
    off_p = np.zeros(V, np.int64)
    for k in range(1, V):
        off_p[k] = off_p[k - 1] + dim_p[k - 1]
    S = sn.shape[0] - 1
    width = np.zeros(S, np.int64)
    rows = np.empty(S, np.int64)
    pstart = np.zeros(S + 1, np.int64)
    sparent = np.full(S, -1, np.int64)
    sn_of = np.empty(V, np.int64)
    for s in range(S):
        for j in range(sn[s], sn[s + 1]):
            width[s] += dim_p[j]
            sn_of[j] = s
    for s in range(S):
        last = rvp[s + 1] - 1
        rows[s] = rpos[last] + dim_p[rvi[last]]
        pstart[s + 1] = pstart[s] + width[s] * rows[s]
    for s in range(S):
        first_below = rvp[s] + sn[s + 1] - sn[s]
        if first_below < rvp[s + 1]:
            sparent[s] = sn_of[rvi[first_below]]
    post_var = np.empty(V, np.int64)
    for k in range(V):
        post_var[k] = vorder[post[k]]
    return post_var, dim_p, off_p, sn, rvp, rvi, rpos, width, rows, pstart, sparent


@njit(cache=True)
def factor_layout(post_var, dim, off, sn, rvi, rows, var_offset, size):
    """Index arrays of the factor's layout: ``(sn_of, perm, new_var, col0, rix_ptr, rix)`` --
    each variable's supernode, the scalar permutation (factor order -> pattern order), each
    pattern variable's postorder label, each supernode's first scalar column, and the global
    scalar index of every panel row (CSR over supernodes)."""
    V = post_var.shape[0]
    S = sn.shape[0] - 1
    sn_of = np.empty(V, np.int64)
    for s in range(S):
        for j in range(sn[s], sn[s + 1]):
            sn_of[j] = s
    perm = np.empty(size, np.int64)
    new_var = np.empty(V, np.int64)
    for k in range(V):
        new_var[post_var[k]] = k
        o = var_offset[post_var[k]]
        for a in range(dim[k]):
            perm[off[k] + a] = o + a
    col0 = np.empty(S, np.int64)
    rix_ptr = np.zeros(S + 1, np.int64)
    for s in range(S):
        col0[s] = off[sn[s]]
        rix_ptr[s + 1] = rix_ptr[s] + rows[s]
    rix = np.empty(rix_ptr[S], np.int64)
    t = 0
    for q in range(rvi.shape[0]):
        v = rvi[q]
        for a in range(dim[v]):
            rix[t] = off[v] + a
            t += 1
    return sn_of, perm, new_var, col0, rix_ptr, rix
