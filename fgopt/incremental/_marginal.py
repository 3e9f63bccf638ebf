"""Marginalizing variables out of the Bayes tree (numba), as iSAM2's ``marginalizeLeaves``.

Variables ``M`` can be cut when they fill whole subtrees: every clique holding one of them, and
every descendant of such a clique, has only ``M`` variables as frontals. Then the marginal of
the rest is the tree without those subtrees, plus, for each subtree root, its cached marginal
``(C, c)`` on its separator: the Schur complement of every factor touching ``M`` onto their
Markov blanket, at the current linearization point. ``subtrees`` checks the condition (and
lists the subtrees' variables, which the caller re-eliminates with ``M`` first when it fails);
``cut`` removes the subtrees and returns the roots' separators and marginals.
"""

from __future__ import annotations

import numpy as np

from .._jit import njit
from ._pool import free
from ._state import M_CN_HEAD, M_CV_HEAD, M_CL_NFREE, M_NCLIQUES, M_STAMP, unpack_cs, unpack_vs
from ._top import _push, _unlink


@njit(cache=True)
def subtrees(vs, cs, cvpool, meta, M):
    """``(ok, variables)``: whether ``M`` fills whole subtrees, and all frontal variables of
    the subtrees rooted at the cliques holding ``M``."""
    V_ = unpack_vs(vs)
    var_clique, var_mark = V_[1], V_[2]
    C_ = unpack_cs(cs)
    cl_child, cl_next, cl_voff, cl_nf, cl_mark = C_[1], C_[2], C_[4], C_[5], C_[10]
    meta[M_STAMP] += 1
    sm = meta[M_STAMP]
    for v in M:
        var_mark[v] = sm
    meta[M_STAMP] += 1
    sc = meta[M_STAMP]
    ok = True
    out = np.empty(16, np.int64)
    n = 0
    stack = np.empty(16, np.int64)
    for v in M:
        c0 = var_clique[v]
        if c0 <= 0 or cl_mark[c0] == sc:
            continue
        ns = 0
        stack = _push(stack, ns, c0)
        ns += 1
        while ns > 0:
            ns -= 1
            c = stack[ns]
            if cl_mark[c] == sc:
                continue
            cl_mark[c] = sc
            vo = cl_voff[c]
            for k in range(cl_nf[c]):
                u = cvpool[vo + k]
                out = _push(out, n, u)
                n += 1
                if var_mark[u] != sm:
                    ok = False
            ch = cl_child[c]
            while ch != -1:
                stack = _push(stack, ns, ch)
                ns += 1
                ch = cl_next[ch]
    return ok, np.unique(out[:n])


@njit(cache=True)
def cut(vs, cs, cvpool, cnpool, meta, M):
    """Remove the subtrees ``M`` fills (see ``subtrees``). Returns the roots' separators
    ``(sep_ptr, sep_vars)`` and marginals ``(mat_ptr, C)`` (``sd x sd``, full, column-major)
    and ``(vec_ptr, c)``."""
    V_ = unpack_vs(vs)
    var_clique, var_mark = V_[1], V_[2]
    C_ = unpack_cs(cs)
    (cl_parent, cl_child, cl_next, cl_prev, cl_voff, cl_nf, cl_ns, cl_fdim, cl_sdim, cl_poff,
     cl_mark, cl_free) = C_
    meta[M_STAMP] += 1
    sm = meta[M_STAMP]
    for v in M:
        var_mark[v] = sm
    roots = np.empty(16, np.int64)
    nr = 0
    meta[M_STAMP] += 1
    sc = meta[M_STAMP]
    for v in M:
        c = var_clique[v]
        if c <= 0 or cl_mark[c] == sc:
            continue
        cl_mark[c] = sc
        p = cl_parent[c]
        if p == 0 or var_mark[cvpool[cl_voff[p]]] != sm:     # parent holds no M variable
            roots = _push(roots, nr, c)
            nr += 1
    sep_ptr = np.zeros(nr + 1, np.int64)
    mat_ptr = np.zeros(nr + 1, np.int64)
    vec_ptr = np.zeros(nr + 1, np.int64)
    for i in range(nr):
        r = roots[i]
        sep_ptr[i + 1] = sep_ptr[i] + cl_ns[r]
        mat_ptr[i + 1] = mat_ptr[i] + cl_sdim[r] * cl_sdim[r]
        vec_ptr[i + 1] = vec_ptr[i] + cl_sdim[r]
    sep = np.empty(sep_ptr[nr], np.int64)
    Cout = np.empty(mat_ptr[nr])
    cout = np.empty(vec_ptr[nr])
    stack = np.empty(16, np.int64)
    for i in range(nr):
        r = roots[i]
        fd, sd = cl_fdim[r], cl_sdim[r]
        vo = cl_voff[r]
        for k in range(cl_ns[r]):
            sep[sep_ptr[i] + k] = cvpool[vo + cl_nf[r] + k]
        p0 = cl_poff[r] + (fd + sd) * fd + fd
        for j in range(sd):
            for a in range(j, sd):
                x = cnpool[p0 + a + j * sd]
                Cout[mat_ptr[i] + a + j * sd] = x
                Cout[mat_ptr[i] + j + a * sd] = x
        for a in range(sd):
            cout[vec_ptr[i] + a] = cnpool[p0 + sd * sd + a]
        _unlink(cl_parent, cl_child, cl_next, cl_prev, r)
        ns = 0
        stack = _push(stack, ns, r)
        ns += 1
        while ns > 0:
            ns -= 1
            c = stack[ns]
            ch = cl_child[c]
            while ch != -1:
                stack = _push(stack, ns, ch)
                ns += 1
                ch = cl_next[ch]
            fdc, sdc = cl_fdim[c], cl_sdim[c]
            free(cvpool, meta, M_CV_HEAD, cl_voff[c], cl_nf[c] + cl_ns[c])
            free(cnpool, meta, M_CN_HEAD, cl_poff[c], (fdc + sdc) * fdc + fdc + sdc * sdc + sdc)
            for k in range(cl_nf[c]):
                var_clique[cvpool[cl_voff[c] + k]] = -1
            cl_parent[c] = -2
            cl_child[c] = -1
            cl_free[meta[M_CL_NFREE]] = c
            meta[M_CL_NFREE] += 1
            meta[M_NCLIQUES] -= 1
    return sep_ptr, sep, mat_ptr, Cout, vec_ptr, cout
