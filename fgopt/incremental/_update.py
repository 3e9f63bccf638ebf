"""One Bayes-tree update in as few numba calls as possible (the per-update overhead matters:
most updates of an online problem re-eliminate a handful of variables).

``tree_update`` removes the top for the marked variables, assigns ordering groups, builds the
top's graph and, when the top is small enough for the bitset minimum degree, orders it and
calls ``tree_finish`` (re-eliminate, commit, mark the top for back-substitution) itself. A
larger top returns ``NEED_ORDER`` with its graph; the caller orders it (AMD) and calls
``tree_finish``. A non-positive pivot returns ``FAILED`` before anything is committed.

``tree_finish`` returns ``(status, info, cvpool, cnpool)``, the pools possibly grown.
``info`` (int64): ``[t, nnz change, new cliques, (unused), batch, failed variable]``.
``tree_update`` returns ``(status, *info, top, cvpool, cnpool, hpool)``: ``info``'s six
numbers, then ``None`` for each pool that did not grow, and for ``top`` unless ``NEED_ORDER``
(then ``info`` followed by the top's arrays, which :func:`unpack_top` splits). Each array a
numba call returns costs ~1-2 us to box (more than the rest of an empty update), a ``None``
next to nothing: the common update returns no array.
Back-substitution is deferred to the next read of the estimate, as in iSAM2
(:func:`._solve.solve_pending`).
"""

from __future__ import annotations

import numpy as np

from .._jit import njit
from ._eliminate import eliminate
from ._factors import _local_systems
from ._ordering import min_degree
from ._state import M_STAMP, unpack_vs
from ._top import commit, panel_entries, remove_top, top_graph

OK, NEED_ORDER, FAILED, NONFINITE = 0, 1, 2, 3
I_T, I_NNZ, I_NEW, _, I_BATCH, I_FAIL = range(6)
N_INFO = 6


@njit(cache=True)
def tree_update(vs, fs, cs, meta, cvpool, cnpool, hpool, more_marked, unused, new_facs,
                removed, observed, first, n_live, batch_frac, tol, iw, fw, bitset_limit, lin):
    """See the module docstring. ``observed``: the variables of the new factors (repeats
    allowed); they and ``more_marked`` are re-eliminated. ``first``: variables ordered before
    all others (group 0). ``lin``: local systems to write first (``FactorStore.linearize``'s
    deferred batch); a non-finite one returns ``NONFINITE`` before anything else changes."""
    cv0, cn0, hp0 = cvpool, cnpool, hpool
    observed = np.sort(observed)   # without repeats (the top's order follows it)
    n = 0
    for i in range(observed.shape[0]):
        if n == 0 or observed[i] != observed[n - 1]:
            observed[n] = observed[i]
            n += 1
    observed = observed[:n]
    marked = observed
    if more_marked.shape[0]:
        marked = np.concatenate((observed, more_marked))
    ok, hpool = _local_systems(lin[0], lin[1], lin[2], lin[3], lin[4], lin[5], hpool, meta,
                               fs[0][1], lin[6])
    if not ok:
        return (NONFINITE, 0, 0, 0, 0, 0, 0, None, None, None,
                hpool if hpool.shape[0] != hp0.shape[0] else None)
    V_ = unpack_vs(vs)
    var_mark, var_changed = V_[2], V_[6]
    T, R, O, FL, batch, s = remove_top(vs, fs, cs, cvpool, meta, marked, new_facs, removed,
                                       batch_frac, n_live)
    if unused.shape[0]:
        meta[M_STAMP] += 1
        su = meta[M_STAMP]
        for v in unused:
            var_changed[v] = su
            var_mark[v] = 0
        keep = np.empty(T.shape[0], np.int64)
        n = 0
        for v in T:
            if var_changed[v] != su:
                keep[n] = v
                n += 1
        T = keep[:n].copy()
    t = T.shape[0]
    meta[M_STAMP] += 1
    so = meta[M_STAMP]
    for v in observed:
        var_changed[v] = so
    meta[M_STAMP] += 1
    sf = meta[M_STAMP]
    for v in first:
        var_changed[v] = sf
    nobs = 0
    for v in T:
        if var_changed[v] == so:
            nobs += 1
    group = np.ones(t, np.int64)
    for i in range(t):
        c = var_changed[T[i]]
        if c == sf:
            group[i] = 0
        elif c == so and nobs < t:
            group[i] = 2
    ap, ai = top_graph(vs, fs, cs, cvpool, T, FL, O)
    if t > bitset_limit:  # info, then the sizes of the top's 7 arrays, then the arrays
        top = (T, R, O, FL, ap, ai, group)
        n = N_INFO + 7
        for a in top:
            n += a.shape[0]
        info = np.zeros(n, np.int64)
        o = N_INFO + 7
        for i in range(7):
            a = top[i]
            info[N_INFO + i] = a.shape[0]
            info[o:o + a.shape[0]] = a
            o += a.shape[0]
        info[I_T] = t
        info[I_BATCH] = batch
        return (NEED_ORDER, info[0], info[1], info[2], info[3], info[4], info[5], info, None,
                None, hpool if hpool.shape[0] != hp0.shape[0] else None)
    info = np.zeros(N_INFO, np.int64)
    info[I_T] = t
    info[I_BATCH] = batch
    order = min_degree(t, ap, ai, group)
    status, info, cvpool, cnpool = tree_finish(vs, fs, cs, meta, cvpool, cnpool, hpool, T, R,
                                               O, FL, ap, ai, group, order, new_facs, removed,
                                               tol, iw, fw, info)
    # a pool that grew is a new, longer array (``_pool``)
    return (status, info[0], info[1], info[2], info[3], info[4], info[5], None,
            cvpool if cvpool.shape[0] != cv0.shape[0] else None,
            cnpool if cnpool.shape[0] != cn0.shape[0] else None,
            hpool if hpool.shape[0] != hp0.shape[0] else None)


def unpack_top(info: np.ndarray) -> tuple:
    """``(T, R, O, FL, ap, ai, group)`` from the ``info`` of ``NEED_ORDER`` (views)."""
    out, o = [], N_INFO + 7
    for n in info[N_INFO:N_INFO + 7].tolist():
        out.append(info[o:o + n])
        o += n
    return tuple(out)


@njit(cache=True)
def tree_finish(vs, fs, cs, meta, cvpool, cnpool, hpool, T, R, O, FL, ap, ai, group, order,
                new_facs, removed, tol, iw, fw, info):
    """Re-eliminate the ordered top and commit it (see the module docstring); writes ``info``
    in place."""
    if T.shape[0] == 0:
        newcl = np.zeros(0, np.int64)
        commit(vs, fs, cs, meta, cvpool, cnpool, hpool, R, newcl, O, newcl, T, newcl, removed,
               new_facs)
        return OK, info, cvpool, cnpool
    status, newcl, oparent, T_clique, cvpool, cnpool = eliminate(
        vs, fs, cs, meta, cvpool, cnpool, hpool, T, order, group, ap, ai, FL, O, tol, iw, fw)
    if status >= 0:
        info[I_FAIL] = status
        return FAILED, info, cvpool, cnpool
    info[I_NNZ] = panel_entries(cs, newcl) - panel_entries(cs, R)
    commit(vs, fs, cs, meta, cvpool, cnpool, hpool, R, newcl, O, oparent, T, T_clique, removed,
           new_facs)
    V_ = unpack_vs(vs)
    var_repl, var_xrepl = V_[10], V_[12]
    for v in T:
        var_repl[v] = 1
        var_xrepl[v] = 1
    info[I_NEW] = newcl.shape[0]
    return OK, info, cvpool, cnpool
