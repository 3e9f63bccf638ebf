"""Solves on the Bayes tree (numba): back-substitution with wildfire, relinearization check,
marginal covariances.

*Back-substitution.* Each clique's conditional gives its frontal update from its separator's:
``x_F = L11^-T (y - L21^T x_S)``. After an update the new top is solved completely (parents
first); an orphan subtree is re-solved only where a separator variable changed by more than the
wildfire threshold (iSAM2's ``optimizeWildfire``): by the running-intersection property, if no
variable of a clique changed, none of its descendants' separators did. The estimate keeps its
own update ``xdelta`` the same way with a much smaller tolerance that does not accumulate
(:func:`solve_estimate`), so ``estimate()`` re-solves only what an update can have moved.

*Marginals.* The joint covariance of a clique's variables given its parent's is
``Sigma_FF = L11^-T L11^-1 + A Sigma_SS A^T``, ``Sigma_FS = A Sigma_SS`` with
``A = -L11^-T L21^T``; walking from the root to the clique holding a variable gives its
marginal (the separator of each clique lies in its parent's variables).
"""

from __future__ import annotations

import numpy as np

from .._jit import njit
from ._dense import back_substitute
from ._state import M_STAMP, VI_OUT, unpack_cs, unpack_vs


@njit(cache=True)
def solve_pending(vs, cs, cvpool, cnpool, wildfire, meta):
    """Back-substitute what changed since the last solve (iSAM2's ``optimizeWildfire``).

    Walks down from the roots: a clique is re-solved when one of its frontal variables was
    re-eliminated (``repl``) or one of its separator variables moved by more than
    ``wildfire`` in this pass (``var_changed`` equal to this pass's stamp, a new
    ``meta[M_STAMP]``); only then are its children visited. Returns the number of cliques
    solved.
    """
    meta[M_STAMP] += 1
    stamp = meta[M_STAMP]
    V_ = unpack_vs(vs)
    var_dim, var_changed, delta, var_repl = V_[0], V_[6], V_[7], V_[10]
    C_ = unpack_cs(cs)
    cl_child, cl_next, cl_voff, cl_nf, cl_ns, cl_fdim, cl_sdim, cl_poff = (
        C_[1], C_[2], C_[4], C_[5], C_[6], C_[7], C_[8], C_[9])
    solved = 0
    xs = np.empty(64)
    xf = np.empty(64)
    stack = np.empty(64, np.int64)
    ns = 0
    ch = cl_child[0]
    while ch != -1:
        if ns >= stack.shape[0]:
            grown = np.empty(2 * stack.shape[0], np.int64)
            grown[:ns] = stack[:ns]
            stack = grown
        stack[ns] = ch
        ns += 1
        ch = cl_next[ch]
    while ns > 0:
        ns -= 1
        c = stack[ns]
        vo = cl_voff[c]
        nf = cl_nf[c]
        hit = False
        for k in range(nf):
            if var_repl[cvpool[vo + k]] != 0:
                hit = True
                break
        if not hit:
            for k in range(cl_ns[c]):
                if var_changed[cvpool[vo + nf + k]] == stamp:
                    hit = True
                    break
        if not hit:
            continue
        w = cl_fdim[c] + cl_sdim[c]
        if w > xs.shape[0]:
            xs = np.empty(2 * w)
            xf = np.empty(2 * w)
        _mark_changes(c, var_dim, delta, var_changed, stamp, wildfire, cvpool, cnpool, cl_voff,
                      cl_nf, cl_ns, cl_fdim, cl_sdim, cl_poff, xs, xf)
        for k in range(nf):
            var_repl[cvpool[vo + k]] = 0
        solved += 1
        ch = cl_child[c]
        while ch != -1:
            if ns >= stack.shape[0]:
                grown = np.empty(2 * stack.shape[0], np.int64)
                grown[:ns] = stack[:ns]
                stack = grown
            stack[ns] = ch
            ns += 1
            ch = cl_next[ch]
    return solved


@njit(cache=True)
def _mark_changes(c, var_dim, delta, var_changed, stamp, wildfire, cvpool, cnpool, cl_voff,
                  cl_nf, cl_ns, cl_fdim, cl_sdim, cl_poff, xs, xf):
    fd, sd = cl_fdim[c], cl_sdim[c]
    m = fd + sd
    vo = cl_voff[c]
    nf = cl_nf[c]
    o = 0
    for k in range(cl_ns[c]):
        v = cvpool[vo + nf + k]
        for a in range(var_dim[v]):
            xs[o + a] = delta[v, a]
        o += var_dim[v]
    p0 = cl_poff[c]
    back_substitute(cnpool[p0:p0 + m * fd], cnpool[p0 + m * fd:p0 + m * fd + fd], m, fd, xs, xf)
    o = 0
    for k in range(nf):
        v = cvpool[vo + k]
        big = False
        for a in range(var_dim[v]):
            if abs(xf[o + a] - delta[v, a]) > wildfire:
                big = True
            delta[v, a] = xf[o + a]
        if big:
            var_changed[v] = stamp
        o += var_dim[v]


@njit(cache=True)
def solve_estimate(vs, cs, cvpool, cnpool, x, xprop, tol, meta, pending, wildfire):
    """:func:`solve_pending` first when ``pending`` (one call for both: the smoother brings
    ``delta`` up to date with the estimate), then back-substitute the estimate's update ``x``
    where it can have changed since the last call: cliques with a frontal variable
    re-eliminated since (``xrepl``), and cliques below a separator variable that moved by more
    than ``tol`` (any component) from ``xprop``, its value when its dependents were last
    re-solved; ``xprop`` is reset only when that happens,
    so changes below ``tol`` do not add up over calls (unlike the wildfire ``delta``): every
    clique's solution is exact for separator values within ``tol`` of the stored ones.
    ``tol`` 0 is the exact solve. Returns the number of cliques solved, the number ``n`` of
    variables to retract again, written in ``VI[VI_OUT, :n]`` (those whose ``x`` changed, and
    those marked ``stale`` (relinearized), whose flag it clears), and the number of cliques
    :func:`solve_pending` solved (-1: not run)."""
    pending_solved = -1
    if pending:
        pending_solved = solve_pending(vs, cs, cvpool, cnpool, wildfire, meta)
    meta[M_STAMP] += 1
    stamp = meta[M_STAMP]
    V_ = unpack_vs(vs)
    var_dim, var_changed, var_stale, var_xrepl = V_[0], V_[6], V_[11], V_[12]
    C_ = unpack_cs(cs)
    cl_child, cl_next, cl_voff, cl_nf, cl_ns, cl_fdim, cl_sdim, cl_poff = (
        C_[1], C_[2], C_[4], C_[5], C_[6], C_[7], C_[8], C_[9])
    solved = 0
    out = vs[0][VI_OUT]   # (each variable is frontal in one clique: at most once)
    nout = 0
    xs = np.empty(64)
    xf = np.empty(64)
    stack = np.empty(64, np.int64)
    ns = 0
    ch = cl_child[0]
    while ch != -1:
        if ns >= stack.shape[0]:
            grown = np.empty(2 * stack.shape[0], np.int64)
            grown[:ns] = stack[:ns]
            stack = grown
        stack[ns] = ch
        ns += 1
        ch = cl_next[ch]
    while ns > 0:
        ns -= 1
        c = stack[ns]
        vo = cl_voff[c]
        nf = cl_nf[c]
        hit = False
        for k in range(nf):
            if var_xrepl[cvpool[vo + k]] != 0:
                hit = True
                break
        if not hit:
            for k in range(cl_ns[c]):
                if var_changed[cvpool[vo + nf + k]] == stamp:
                    hit = True
                    break
        if not hit:
            continue
        fd, sd = cl_fdim[c], cl_sdim[c]
        m = fd + sd
        if m > xs.shape[0]:
            xs = np.empty(2 * m)
            xf = np.empty(2 * m)
        o = 0
        for k in range(cl_ns[c]):
            v = cvpool[vo + nf + k]
            for a in range(var_dim[v]):
                xs[o + a] = x[v, a]
            o += var_dim[v]
        p0 = cl_poff[c]
        back_substitute(cnpool[p0:p0 + m * fd], cnpool[p0 + m * fd:p0 + m * fd + fd], m, fd, xs,
                        xf)
        o = 0
        for k in range(nf):
            v = cvpool[vo + k]
            var_xrepl[v] = 0
            big = False
            moved = var_stale[v] != 0
            var_stale[v] = 0
            for a in range(var_dim[v]):
                if xf[o + a] != x[v, a]:
                    moved = True
                    x[v, a] = xf[o + a]
                if abs(xf[o + a] - xprop[v, a]) > tol:
                    big = True
            if moved:
                out[nout] = v
                nout += 1
            if big:
                var_changed[v] = stamp
                for a in range(var_dim[v]):
                    xprop[v, a] = xf[o + a]
            o += var_dim[v]
        solved += 1
        ch = cl_child[c]
        while ch != -1:
            if ns >= stack.shape[0]:
                grown = np.empty(2 * stack.shape[0], np.int64)
                grown[:ns] = stack[:ns]
                stack = grown
            stack[ns] = ch
            ns += 1
            ch = cl_next[ch]
    return solved, nout, pending_solved


@njit(cache=True)
def relinearize_candidates(var_live, var_dim, delta, thr):
    """Live variables with some ``|delta_i| >= thr_i`` (iSAM2's relinearization check)."""
    out = np.empty(var_live.shape[0], np.int64)
    n = 0
    for v in range(var_live.shape[0]):
        if var_live[v] == 0:
            continue
        for a in range(var_dim[v]):
            if abs(delta[v, a]) >= thr[v, a]:
                out[n] = v
                n += 1
                break
    return out[:n].copy()


@njit(cache=True)
def clique_covariance(path, var_dim, cvpool, cnpool, cl_voff, cl_nf, cl_ns, cl_fdim, cl_sdim,
                      cl_poff, var_pos):
    """Joint covariance of the variables of the last clique of ``path`` (root first)."""
    prev = np.zeros((0, 0))
    for i in range(path.shape[0]):
        c = path[i]
        fd, sd = cl_fdim[c], cl_sdim[c]
        m = fd + sd
        vo = cl_voff[c]
        nf = cl_nf[c]
        p0 = cl_poff[c]
        panel = cnpool[p0:p0 + m * fd]
        # Sigma_SS from the parent's joint covariance (positions set by the previous step)
        Sss = np.empty((sd, sd))
        idx = np.empty(sd, np.int64)
        o = 0
        for k in range(cl_ns[c]):
            v = cvpool[vo + nf + k]
            for a in range(var_dim[v]):
                idx[o + a] = var_pos[v] + a
            o += var_dim[v]
        for a in range(sd):
            for bb in range(sd):
                Sss[a, bb] = prev[idx[a], idx[bb]]
        L11 = np.zeros((fd, fd))
        L21 = np.zeros((sd, fd))
        for j in range(fd):
            for r in range(j, fd):
                L11[r, j] = panel[r + j * m]
            for r in range(sd):
                L21[r, j] = panel[fd + r + j * m]
        Linv = np.linalg.inv(L11)
        A = -(Linv.T @ (L21.T))                  # fd x sd
        joint = np.empty((m, m))
        Sff = Linv.T @ Linv + A @ Sss @ A.T
        Sfs = A @ Sss
        joint[:fd, :fd] = Sff
        joint[:fd, fd:] = Sfs
        joint[fd:, :fd] = Sfs.T
        joint[fd:, fd:] = Sss
        o = 0
        for k in range(nf + cl_ns[c]):
            v = cvpool[vo + k]
            var_pos[v] = o
            o += var_dim[v]
        prev = joint
    return prev
