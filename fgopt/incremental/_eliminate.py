"""Re-eliminate the top of the Bayes tree into new cliques (numba): symbolic, then numeric.

Given the top's variables ``T`` in elimination order, the factors inside it and the orphans:

1. *Symbolic.* The elimination tree and column structures of the top's variable graph
   (:func:`fgopt.solvers.linear._block_symbolic.etree` / ``symbolic_columns``, the block
   Cholesky's own steps), then fundamental supernodes: rank ``j - 1`` joins ``j`` when its
   parent is ``j`` and its structure is ``j``'s plus ``j`` (never across ordering groups, so a
   fixed-lag smoother's marginalized variables end in cliques of their own). Each supernode
   becomes a clique; its separator is the structure of its last column, its parent the clique
   holding the first separator variable. A factor joins the clique of its first eliminated
   variable, an orphan the clique of its first eliminated separator variable.
2. *Numeric* (multifrontal, children first): assemble the front from the clique's factors and
   the cached marginals of its new children and orphans, eliminate the frontal block
   (:mod:`._dense`), store the panel, the forward-substituted rhs and the new cached marginal.

New cliques take free slots and new pool blocks (:mod:`._pool`), so nothing live is
overwritten and a failed elimination (a non-positive pivot) leaves the tree intact: it returns
the variable.
"""

from __future__ import annotations

import numpy as np

from .._jit import njit
from ..solvers.linear._block_symbolic import etree, symbolic_columns
from ._dense import add_cached, add_local_system, forward_rhs, partial_factor
from ._pool import alloc
from ._state import (M_CL_HWM, M_CL_NFREE, M_CN_HEAD, M_CN_TOP, M_CV_HEAD, M_CV_TOP, unpack_cs,
                     unpack_fs, unpack_vs)


@njit(cache=True)
def _csr(n, keys):
    """Counting sort of item indices by ``keys`` (in ``[0, n)``): ``(ptr, items)``."""
    ptr = np.zeros(n + 1, np.int64)
    for k in keys:
        ptr[k + 1] += 1
    for i in range(n):
        ptr[i + 1] += ptr[i]
    items = np.empty(keys.shape[0], np.int64)
    fill = ptr[:n].copy()
    for i in range(keys.shape[0]):
        items[fill[keys[i]]] = i
        fill[keys[i]] += 1
    return ptr, items


@njit(cache=True)
def eliminate(vs, fs, cs, meta, cvpool, cnpool, hpool, T, order, group, ap, ai, FL, O, tol,
              iw, fw):
    """Steps 1-2 of the module docstring.

    Returns ``(status, newcl, orphan_parent, T_clique, cvpool, cnpool)``: ``status`` is -1 on
    success or the slot of the variable whose pivot failed; ``newcl`` the new clique slots,
    children before parents; ``T_clique[i]`` the clique of ``T[i]``.
    """
    V_ = unpack_vs(vs)
    var_dim, var_loc, var_pos = V_[0], V_[3], V_[4]
    F_ = unpack_fs(fs)
    fac_nv, fac_vars, fac_hoff, fac_D = F_[0], F_[1], F_[2], F_[3]
    C_ = unpack_cs(cs)
    cl_parent, cl_voff, cl_nf, cl_ns, cl_fdim, cl_sdim, cl_poff, cl_free = (
        C_[0], C_[4], C_[5], C_[6], C_[7], C_[8], C_[9], C_[11])
    t = T.shape[0]
    rank = np.empty(t, np.int64)
    for k in range(t):
        rank[order[k]] = k
    vr = np.empty(t, np.int64)               # variable slot at each rank
    gr = np.empty(t, np.int64)
    for k in range(t):
        vr[k] = T[order[k]]
        gr[k] = group[order[k]]
    # strict lower adjacency in rank space
    lcnt = np.zeros(t + 1, np.int64)
    for l in range(t):
        rl = rank[l]
        for p in range(ap[l], ap[l + 1]):
            if rank[ai[p]] > rl:
                lcnt[rl + 1] += 1
    for k in range(t):
        lcnt[k + 1] += lcnt[k]
    lai = np.empty(lcnt[t], np.int64)
    fill = lcnt[:t].copy()
    for l in range(t):
        rl = rank[l]
        for p in range(ap[l], ap[l + 1]):
            rq = rank[ai[p]]
            if rq > rl:
                lai[fill[rl]] = rq
                fill[rl] += 1
    parent = etree(t, lcnt, lai)
    lp, li = symbolic_columns(t, lcnt, lai, parent)
    # fundamental supernodes
    first = np.empty(t + 1, np.int64)
    S = 0
    for j in range(t):
        if j == 0 or not (parent[j - 1] == j and lp[j] - lp[j - 1] == lp[j + 1] - lp[j] + 1
                          and gr[j - 1] == gr[j]):
            first[S] = j
            S += 1
    first[S] = t
    sn_of = np.empty(t, np.int64)
    for s in range(S):
        for j in range(first[s], first[s + 1]):
            sn_of[j] = s
    # new clique slots and their variable lists
    cid = np.empty(S, np.int64)
    for s in range(S):
        if meta[M_CL_NFREE] > 0:
            meta[M_CL_NFREE] -= 1
            cid[s] = cl_free[meta[M_CL_NFREE]]
        else:
            cid[s] = meta[M_CL_HWM]
            meta[M_CL_HWM] += 1
    sparent = np.full(S, -1, np.int64)
    maxm = 1
    for s in range(S):
        last = first[s + 1] - 1
        fd = 0
        for j in range(first[s], first[s + 1]):
            fd += var_dim[vr[j]]
        sd = 0
        for p in range(lp[last], lp[last + 1]):
            sd += var_dim[vr[li[p]]]
        if lp[last + 1] > lp[last]:
            sparent[s] = sn_of[li[lp[last]]]
        c = cid[s]
        cl_nf[c] = first[s + 1] - first[s]
        cl_ns[c] = lp[last + 1] - lp[last]
        cl_fdim[c] = fd
        cl_sdim[c] = sd
        if fd + sd > maxm:
            maxm = fd + sd
    for s in range(S):
        c = cid[s]
        cl_parent[c] = cid[sparent[s]] if sparent[s] >= 0 else 0
        o, cvpool = alloc(cvpool, meta, M_CV_TOP, M_CV_HEAD, cl_nf[c] + cl_ns[c])
        cl_voff[c] = o
        for j in range(first[s], first[s + 1]):
            cvpool[o] = vr[j]
            o += 1
        last = first[s + 1] - 1
        for p in range(lp[last], lp[last + 1]):
            cvpool[o] = vr[li[p]]
            o += 1
        fd, sd = cl_fdim[c], cl_sdim[c]
        cl_poff[c], cnpool = alloc(cnpool, meta, M_CN_TOP, M_CN_HEAD,
                                   (fd + sd) * fd + fd + sd * sd + sd)
    # who joins which front
    nfl = FL.shape[0]
    fsn = np.empty(nfl, np.int64)
    for i in range(nfl):
        f = FL[i]
        r = t
        for k in range(fac_nv[f]):
            rk = rank[var_loc[fac_vars[f, k]]]
            if rk < r:
                r = rk
        fsn[i] = sn_of[r]
    fptr, fitems = _csr(S, fsn)
    no = O.shape[0]
    osn = np.empty(no, np.int64)
    orphan_parent = np.empty(no, np.int64)
    for i in range(no):
        o = O[i]
        base = cl_voff[o] + cl_nf[o]
        r = t
        for k in range(cl_ns[o]):
            rk = rank[var_loc[cvpool[base + k]]]
            if rk < r:
                r = rk
        osn[i] = sn_of[r]
        orphan_parent[i] = cid[osn[i]]
    optr, oitems = _csr(S, osn)
    ckeys = np.empty(S, np.int64)
    for s in range(S):
        ckeys[s] = sparent[s] if sparent[s] >= 0 else S
    cptr, citems = _csr(S + 1, ckeys)
    # numeric, children first (supernodes are numbered in elimination order)
    W = np.empty(maxm * maxm)
    b = np.empty(maxm)
    P = np.empty(maxm, np.int64)
    diag0 = np.empty(maxm)
    for s in range(S):
        c = cid[s]
        fd, sd = cl_fdim[c], cl_sdim[c]
        m = fd + sd
        vo = cl_voff[c]
        pos = 0
        for k in range(cl_nf[c] + cl_ns[c]):
            v = cvpool[vo + k]
            var_pos[v] = pos
            pos += var_dim[v]
        W[:m * m] = 0.0
        b[:m] = 0.0
        for q in range(fptr[s], fptr[s + 1]):
            f = FL[fitems[q]]
            D = fac_D[f]
            o = 0
            for k in range(fac_nv[f]):
                v = fac_vars[f, k]
                p0 = var_pos[v]
                for a in range(var_dim[v]):
                    P[o + a] = p0 + a
                o += var_dim[v]
            h0 = fac_hoff[f]
            add_local_system(W, m, b, hpool[h0:h0 + D * D], hpool[h0 + D * D:h0 + D * D + D], P, D)
        for q in range(optr[s], optr[s + 1]):
            _add_child(W, m, b, O[oitems[q]], P, var_dim, var_pos, cvpool, cnpool, cl_voff,
                       cl_nf, cl_ns, cl_fdim, cl_sdim, cl_poff)
        for q in range(cptr[s], cptr[s + 1]):
            _add_child(W, m, b, cid[citems[q]], P, var_dim, var_pos, cvpool, cnpool, cl_voff,
                       cl_nf, cl_ns, cl_fdim, cl_sdim, cl_poff)
        bad = partial_factor(W, m, fd, diag0, tol, iw, fw)
        if bad >= 0:
            acc = 0
            for k in range(cl_nf[c]):
                v = cvpool[vo + k]
                acc += var_dim[v]
                if bad < acc:
                    return v, cid, orphan_parent, cid, cvpool, cnpool
            return cvpool[vo], cid, orphan_parent, cid, cvpool, cnpool
        forward_rhs(W, m, fd, b)
        p0 = cl_poff[c]
        cnpool[p0:p0 + m * fd] = W[:m * fd]
        p0 += m * fd
        cnpool[p0:p0 + fd] = b[:fd]
        p0 += fd
        for j in range(sd):
            src = fd + (fd + j) * m
            dst = p0 + j * sd
            for i in range(j, sd):
                cnpool[dst + i] = W[src + i]
        p0 += sd * sd
        cnpool[p0:p0 + sd] = b[fd:m]
    T_clique = np.empty(t, np.int64)
    for k in range(t):
        T_clique[order[k]] = cid[sn_of[k]]
    return -1, cid, orphan_parent, T_clique, cvpool, cnpool


@njit(cache=True)
def _add_child(W, m, b, ch, P, var_dim, var_pos, cvpool, cnpool, cl_voff, cl_nf, cl_ns, cl_fdim,
               cl_sdim, cl_poff):
    fd, sd = cl_fdim[ch], cl_sdim[ch]
    base = cl_voff[ch] + cl_nf[ch]
    o = 0
    for k in range(cl_ns[ch]):
        v = cvpool[base + k]
        p0 = var_pos[v]
        for a in range(var_dim[v]):
            P[o + a] = p0 + a
        o += var_dim[v]
    c0 = cl_poff[ch] + (fd + sd) * fd + fd
    add_cached(W, m, b, cnpool[c0:c0 + sd * sd], cnpool[c0 + sd * sd:c0 + sd * sd + sd], P, sd)
