"""Bayes-tree surgery (numba): remove the top, build its variable graph, commit the new top.

An update marks variables (those of new or removed factors and the relinearized ones). iSAM2
then removes every clique holding a marked variable as frontal, and all their ancestors: the
*top*. The subtrees hanging from the top (*orphans*) are kept with their cached marginals on
their separators, which lie inside the top. The top's variables are re-eliminated from the
factors wholly inside the top (their cached linearizations, or fresh ones) plus the orphans'
cached marginals; ``commit`` then links the new cliques, re-attaches the orphans and updates
the variable -> clique and variable -> factor maps. Nothing here changes existing state before
``commit``, which runs only once the numeric elimination has succeeded.

Array tuples ``vs``, ``fs``, ``cs`` are :class:`~fgopt.incremental._state.TreeState`'s.
"""

from __future__ import annotations

import numpy as np

from .._jit import njit
from ._pool import free
from ._state import (M_ADJ_HWM, M_ADJ_NFREE, M_CL_NFREE, M_CN_HEAD, M_CV_HEAD, M_HP_HEAD,
                     M_NCLIQUES, M_STAMP, unpack_cs, unpack_fs, unpack_vs)


@njit(cache=True)
def _push(a, n, x):
    if n >= a.shape[0]:
        b = np.empty(max(16, 2 * a.shape[0]), a.dtype)
        b[:n] = a[:n]
        a = b
    a[n] = x
    return a


@njit(cache=True)
def remove_top(vs, fs, cs, cvpool, meta, marked, new_facs, skip_facs, batch_frac, n_live):
    """Find the top for ``marked`` variables (slots; new variables included).

    Returns ``(T, R, O, FL, batch, stamp)``: top variables, removed cliques, orphans, factors
    wholly inside the top (new factors included, ``skip_facs`` excluded), whether the top grew
    past ``batch_frac`` of all variables (then everything is re-eliminated: iSAM2's batch step),
    and the stamp marking the top's variables in ``var_mark``.
    """
    V_ = unpack_vs(vs)
    var_clique, var_mark = V_[1], V_[2]
    var_fhead, var_live = V_[5], V_[9]
    F_ = unpack_fs(fs)
    fac_nv, fac_vars, fac_mark, fac_alive = F_[0], F_[1], F_[4], F_[5]
    adj_next, adj_fac = F_[6], F_[7]
    C_ = unpack_cs(cs)
    cl_parent, cl_child, cl_next = C_[0], C_[1], C_[2]
    cl_voff, cl_nf, cl_mark = C_[4], C_[5], C_[10]
    meta[M_STAMP] += 1
    s = meta[M_STAMP]
    T = np.empty(max(16, marked.shape[0]), np.int64)
    nt = 0
    R = np.empty(16, np.int64)
    nr = 0
    for v in marked:
        if var_mark[v] != s:
            var_mark[v] = s
            T = _push(T, nt, v)
            nt += 1
        c = var_clique[v]
        while c > 0 and cl_mark[c] != s:
            cl_mark[c] = s
            R = _push(R, nr, c)
            nr += 1
            o = cl_voff[c]
            for k in range(cl_nf[c]):
                u = cvpool[o + k]
                if var_mark[u] != s:
                    var_mark[u] = s
                    T = _push(T, nt, u)
                    nt += 1
            c = cl_parent[c]
    batch = n_live > 0 and nt >= batch_frac * n_live
    O = np.empty(16, np.int64)
    no = 0
    if batch:
        for v in range(var_live.shape[0]):
            if var_live[v] != 0 and var_mark[v] != s:
                var_mark[v] = s
                T = _push(T, nt, v)
                nt += 1
        nr = 0                                  # every live clique, by a walk from the root
        stack = np.empty(16, np.int64)
        ns = 0
        ch = cl_child[0]
        while ch != -1:
            stack = _push(stack, ns, ch)
            ns += 1
            ch = cl_next[ch]
        while ns > 0:
            ns -= 1
            c = stack[ns]
            cl_mark[c] = s
            R = _push(R, nr, c)
            nr += 1
            ch = cl_child[c]
            while ch != -1:
                stack = _push(stack, ns, ch)
                ns += 1
                ch = cl_next[ch]
    else:
        for i in range(nr):
            ch = cl_child[R[i]]
            while ch != -1:
                if cl_mark[ch] != s:
                    O = _push(O, no, ch)
                    no += 1
                ch = cl_next[ch]
    meta[M_STAMP] += 1
    s2 = meta[M_STAMP]
    for f in skip_facs:
        fac_mark[f] = s2
    FL = np.empty(16, np.int64)
    nf = 0
    for i in range(nt):
        e = var_fhead[T[i]]
        while e != -1:
            f = adj_fac[e]
            if fac_mark[f] != s2 and fac_alive[f] != 0:
                fac_mark[f] = s2
                inside = True
                for k in range(fac_nv[f]):
                    if var_mark[fac_vars[f, k]] != s:
                        inside = False
                        break
                if inside:
                    FL = _push(FL, nf, f)
                    nf += 1
            e = adj_next[e]
    for f in new_facs:
        FL = _push(FL, nf, f)
        nf += 1
    return T[:nt].copy(), R[:nr].copy(), O[:no].copy(), FL[:nf].copy(), batch, s


@njit(cache=True)
def top_graph(vs, fs, cs, cvpool, T, FL, O):
    """Symmetric adjacency (CSR, local indices of ``T``) of the top's variables: pairs sharing a
    factor of ``FL`` or the separator of an orphan of ``O``. Sets ``var_loc`` for ``T``."""
    V_ = unpack_vs(vs)
    var_loc = V_[3]
    F_ = unpack_fs(fs)
    fac_nv, fac_vars = F_[0], F_[1]
    C_ = unpack_cs(cs)
    cl_voff, cl_nf, cl_ns = C_[4], C_[5], C_[6]
    t = T.shape[0]
    for i in range(t):
        var_loc[T[i]] = i
    deg = np.zeros(t + 1, np.int64)
    for f in FL:
        k = fac_nv[f]
        for a in range(k):
            deg[var_loc[fac_vars[f, a]]] += k - 1
    for o in O:
        ns = cl_ns[o]
        base = cl_voff[o] + cl_nf[o]
        for a in range(ns):
            deg[var_loc[cvpool[base + a]]] += ns - 1
    ap = np.zeros(t + 1, np.int64)
    for i in range(t):
        ap[i + 1] = ap[i] + deg[i]
    ai = np.empty(ap[t], np.int64)
    fill = ap[:t].copy()
    for f in FL:
        k = fac_nv[f]
        for a in range(k):
            la = var_loc[fac_vars[f, a]]
            for b in range(k):
                if a != b:
                    ai[fill[la]] = var_loc[fac_vars[f, b]]
                    fill[la] += 1
    for o in O:
        ns = cl_ns[o]
        base = cl_voff[o] + cl_nf[o]
        for a in range(ns):
            la = var_loc[cvpool[base + a]]
            for b in range(ns):
                if a != b:
                    ai[fill[la]] = var_loc[cvpool[base + b]]
                    fill[la] += 1
    # remove duplicates (and self loops) row by row
    mark = np.full(t, -1, np.int64)
    out_p = np.zeros(t + 1, np.int64)
    n = 0
    for i in range(t):
        mark[i] = i
        for p in range(ap[i], ap[i + 1]):
            j = ai[p]
            if mark[j] != i:
                mark[j] = i
                ai[n] = j
                n += 1
        out_p[i + 1] = n
    return out_p, ai[:n].copy()


@njit(cache=True, inline="always")
def _link(cl_child, cl_next, cl_prev, c, p):
    cl_prev[c] = -1
    h = cl_child[p]
    cl_next[c] = h
    if h != -1:
        cl_prev[h] = c
    cl_child[p] = c


@njit(cache=True, inline="always")
def _unlink(cl_parent, cl_child, cl_next, cl_prev, c):
    p = cl_parent[c]
    if cl_prev[c] != -1:
        cl_next[cl_prev[c]] = cl_next[c]
    else:
        cl_child[p] = cl_next[c]
    if cl_next[c] != -1:
        cl_prev[cl_next[c]] = cl_prev[c]


@njit(cache=True)
def commit(vs, fs, cs, meta, cvpool, cnpool, hpool, R, newcl, O, orphan_parent, T, T_clique,
           removed_facs, new_facs):
    """Make the new top current (see the module docstring). Cannot fail."""
    V_ = unpack_vs(vs)
    var_clique, var_fhead = V_[1], V_[5]
    F_ = unpack_fs(fs)
    fac_nv, fac_vars, fac_hoff, fac_D, fac_alive, adj_next, adj_fac, adj_free = (
        F_[0], F_[1], F_[2], F_[3], F_[5], F_[6], F_[7], F_[8])
    C_ = unpack_cs(cs)
    cl_parent, cl_child, cl_next, cl_prev = C_[0], C_[1], C_[2], C_[3]
    cl_voff, cl_nf, cl_ns, cl_fdim, cl_sdim, cl_poff, cl_free = (
        C_[4], C_[5], C_[6], C_[7], C_[8], C_[9], C_[11])
    for c in R:
        if cl_parent[c] == 0:
            _unlink(cl_parent, cl_child, cl_next, cl_prev, c)
        fd, sd = cl_fdim[c], cl_sdim[c]
        free(cvpool, meta, M_CV_HEAD, cl_voff[c], cl_nf[c] + cl_ns[c])
        free(cnpool, meta, M_CN_HEAD, cl_poff[c], (fd + sd) * fd + fd + sd * sd + sd)
        cl_parent[c] = -2
        cl_child[c] = -1
        cl_free[meta[M_CL_NFREE]] = c
        meta[M_CL_NFREE] += 1
    meta[M_NCLIQUES] += newcl.shape[0] - R.shape[0]
    for c in newcl:
        cl_child[c] = -1
    for c in newcl:
        _link(cl_child, cl_next, cl_prev, c, cl_parent[c])
    for i in range(O.shape[0]):
        o = O[i]
        cl_parent[o] = orphan_parent[i]
        _link(cl_child, cl_next, cl_prev, o, orphan_parent[i])
    for i in range(T.shape[0]):
        var_clique[T[i]] = T_clique[i]
    for f in removed_facs:
        fac_alive[f] = 0
        D = fac_D[f]
        free(hpool, meta, M_HP_HEAD, fac_hoff[f], D * D + D)
        for k in range(fac_nv[f]):
            v = fac_vars[f, k]
            prev = -1
            e = var_fhead[v]
            while e != -1:
                if adj_fac[e] == f:
                    if prev == -1:
                        var_fhead[v] = adj_next[e]
                    else:
                        adj_next[prev] = adj_next[e]
                    adj_free[meta[M_ADJ_NFREE]] = e
                    meta[M_ADJ_NFREE] += 1
                    break
                prev = e
                e = adj_next[e]
    for f in new_facs:
        fac_alive[f] = 1
        for k in range(fac_nv[f]):
            v = fac_vars[f, k]
            if meta[M_ADJ_NFREE] > 0:
                meta[M_ADJ_NFREE] -= 1
                e = adj_free[meta[M_ADJ_NFREE]]
            else:
                e = meta[M_ADJ_HWM]
                meta[M_ADJ_HWM] += 1
            adj_fac[e] = f
            adj_next[e] = var_fhead[v]
            var_fhead[v] = e


@njit(cache=True)
def factor_entries(cs):
    """Stored entries of all live cliques' panels (a fill measure)."""
    C_ = unpack_cs(cs)
    cl_parent, cl_fdim, cl_sdim = C_[0], C_[7], C_[8]
    total = 0
    for c in range(1, cl_parent.shape[0]):
        if cl_parent[c] >= 0:
            fd = cl_fdim[c]
            total += (fd + cl_sdim[c]) * fd
    return total


@njit(cache=True)
def live_cliques(cs):
    """Slots of all live cliques, parents before children."""
    C_ = unpack_cs(cs)
    cl_child, cl_next = C_[1], C_[2]
    out = np.empty(16, np.int64)
    n = 0
    stack = np.empty(16, np.int64)
    ns = 0
    ch = cl_child[0]
    while ch != -1:
        stack = _push(stack, ns, ch)
        ns += 1
        ch = cl_next[ch]
    while ns > 0:
        ns -= 1
        c = stack[ns]
        out = _push(out, n, c)
        n += 1
        ch = cl_child[c]
        while ch != -1:
            stack = _push(stack, ns, ch)
            ns += 1
            ch = cl_next[ch]
    return out[:n].copy()


@njit(cache=True)
def adjacent(vs, fs, meta, J, removed):
    """Live factors touching variables ``J`` (minus ``removed``), and all their variables."""
    V_ = unpack_vs(vs)
    var_fhead = V_[5]
    F_ = unpack_fs(fs)
    fac_nv, fac_vars, fac_mark, fac_alive = F_[0], F_[1], F_[4], F_[5]
    adj_next, adj_fac = F_[6], F_[7]
    var_mark = V_[2]
    meta[M_STAMP] += 1
    s = meta[M_STAMP]
    for f in removed:
        fac_mark[f] = s
    facs = np.empty(16, np.int64)
    nf = 0
    out = np.empty(16, np.int64)
    no = 0
    for v in J:
        e = var_fhead[v]
        while e != -1:
            f = adj_fac[e]
            if fac_mark[f] != s and fac_alive[f] != 0:
                fac_mark[f] = s
                facs = _push(facs, nf, f)
                nf += 1
                for k in range(fac_nv[f]):
                    u = fac_vars[f, k]
                    if var_mark[u] != s:
                        var_mark[u] = s
                        out = _push(out, no, u)
                        no += 1
            e = adj_next[e]
    return facs[:nf].copy(), out[:no].copy()


@njit(cache=True)
def factor_vars(fs, facs):
    """Distinct variables of factors ``facs``."""
    F_ = unpack_fs(fs)
    fac_nv, fac_vars = F_[0], F_[1]
    n = 0
    for f in facs:
        n += fac_nv[f]
    out = np.empty(n, np.int64)
    n = 0
    for f in facs:
        for k in range(fac_nv[f]):
            out[n] = fac_vars[f, k]
            n += 1
    return np.unique(out)


@njit(cache=True)
def remaining_factors(vs, fs, meta, vars_, removed):
    """For each of ``vars_``: live factors left once ``removed`` are gone."""
    V_ = unpack_vs(vs)
    var_fhead = V_[5]
    F_ = unpack_fs(fs)
    fac_mark, fac_alive, adj_next, adj_fac = F_[4], F_[5], F_[6], F_[7]
    meta[M_STAMP] += 1
    s = meta[M_STAMP]
    for f in removed:
        fac_mark[f] = s
    counts = np.zeros(vars_.shape[0], np.int64)
    for i in range(vars_.shape[0]):
        e = var_fhead[vars_[i]]
        while e != -1:
            f = adj_fac[e]
            if fac_mark[f] != s and fac_alive[f] != 0:
                counts[i] += 1
            e = adj_next[e]
    return counts


@njit(cache=True)
def panel_entries(cs, cliques):
    """Stored panel entries of ``cliques``."""
    C_ = unpack_cs(cs)
    cl_fdim, cl_sdim = C_[7], C_[8]
    total = 0
    for c in cliques:
        fd = cl_fdim[c]
        total += (fd + cl_sdim[c]) * fd
    return total
