"""numba pieces every small-problem driver calls (compiled once, shared by all drivers).

Storage and tangent layout: the problem's variables in its order, variable ``v``'s storage at
``x[soff[v]:soff[v] + s_v]`` and its tangent at ``delta[toff[v]:toff[v] + d_v]``; H is dense
``(N, N)`` with both triangles filled.

Those that take arrays and return none are compiled without numba's reference counting
(``_nrt=False``): the driver calls them on views of its arenas, and counting would add an atomic
increment and decrement per array per call (see
:func:`fgopt.solvers.small._lm_template.lm_source`).
"""

from __future__ import annotations

import numpy as np

from ..._jit import njit
from ...manifolds._kernels import retract_row


@njit(cache=True, error_model="numpy", nogil=True, _nrt=False)
def gather(x, soff, arg, out):
    """``out[i] = x[soff[i, arg]:soff[i, arg] + out.shape[1]]``: argument ``arg``'s storage rows."""
    s = out.shape[1]
    for i in range(out.shape[0]):
        o = soff[i, arg]
        for k in range(s):
            out[i, k] = x[o + k]


@njit(cache=True, error_model="numpy", nogil=True, _nrt=False)
def retract(x, delta, out, tmp, layout):
    """``out = x (+) delta`` per variable; ``layout (V, 5)``: storage offset, tangent offset,
    Lie group id (-1: a vector, added), storage dim, tangent dim. The common groups' exp and
    compose are inlined (:func:`~fgopt.manifolds._kernels.retract_row`, on views of the rows:
    4 SE(2) poses 0.4 us instead of 0.9 through ``lie_retract`` and copies); ``out`` must not
    be ``x``."""
    for v in range(layout.shape[0]):
        so, to, gid, s, d = layout[v, 0], layout[v, 1], layout[v, 2], layout[v, 3], layout[v, 4]
        if gid < 0:
            for k in range(s):
                out[so + k] = x[so + k] + delta[to + k]
            continue
        retract_row(gid, x[so:so + s], delta[to:to + d], out[so:so + s], tmp)


@njit(cache=True, error_model="numpy", nogil=True, _nrt=False)
def layout_into(var_kind, var_row, var_dim, kind_sdim, kind_gid, base, soff, toff, layout):
    """Variables' storage and tangent offsets ``soff, toff (V,)`` and the ``(V, 5)`` layout of
    :func:`retract`, written into the given arrays (``base (K + 1,)``: zeros on entry, scratch),
    for the kinds' storage arrays laid end to end (kind ``t``'s holds its variables' rows, so
    its size is their number times ``kind_sdim[t]``), each variable at its kind's row
    ``var_row``, tangents in variable order."""
    V, K = var_kind.shape[0], kind_sdim.shape[0]
    for v in range(V):
        base[var_kind[v] + 1] += kind_sdim[var_kind[v]]
    for t in range(1, K + 1):
        base[t] += base[t - 1]
    o = 0
    for v in range(V):
        t = var_kind[v]
        soff[v] = base[t] + var_row[v] * kind_sdim[t]
        toff[v] = o
        o += var_dim[v]
        layout[v, 0] = soff[v]
        layout[v, 1] = toff[v]
        layout[v, 2] = kind_gid[t]
        layout[v, 3] = kind_sdim[t]
        layout[v, 4] = var_dim[v]


@njit(cache=True, error_model="numpy", nogil=True, _nrt=False)
def envelope_into(toff, var_dim, first):
    """Each tangent row's own variable's first row, into ``first (n,)``: H's envelope before
    any factor widens it (:func:`widen_envelope`)."""
    for v in range(toff.shape[0]):
        for t in range(toff[v], toff[v] + var_dim[v]):
            first[t] = toff[v]


@njit(cache=True, error_model="numpy", nogil=True, _nrt=True)
def envelope_of(toff, var_dim, n):
    """:func:`envelope_into` in a new array."""
    first = np.empty(n, dtype=np.int64)
    envelope_into(toff, var_dim, first)
    return first


@njit(cache=True, error_model="numpy", nogil=True, _nrt=False)
def take_into(a, idx, out):
    """``out = a[idx]`` for ``idx, out (n, k)`` (no temporary: the driver's arena)."""
    for i in range(idx.shape[0]):
        for p in range(idx.shape[1]):
            out[i, p] = a[idx[i, p]]


@njit(cache=True, error_model="numpy", nogil=True, _nrt=False)
def widen_envelope(first, toffs, dims):
    """A factor couples its arguments: each one's rows of H reach back to the first row of the
    factor's earliest argument. ``toffs, dims (n, k)``: the arguments' tangent offsets and dims."""
    for i in range(toffs.shape[0]):
        m = toffs[i, 0]
        for p in range(1, toffs.shape[1]):
            m = min(m, toffs[i, p])
        for p in range(toffs.shape[1]):
            for t in range(toffs[i, p], toffs[i, p] + dims[i, p]):
                if m < first[t]:
                    first[t] = m


@njit(cache=True, error_model="numpy", nogil=True, _nrt=False)
def clear(H, g, env):
    """``g = 0`` and ``H = 0`` on its envelope (both triangles: the rest is never written)."""
    for i in range(H.shape[0]):
        g[i] = 0.0
        for j in range(env[i], i + 1):
            H[i, j] = 0.0
            H[j, i] = 0.0


@njit(cache=True, error_model="numpy", nogil=True, _nrt=True)
def stacked(x, soff, s):
    """A ``hessian`` call's storage and rows (:class:`~fgopt.factors.kernel.CompiledCall`): the
    batch's argument storages (all of dimension ``s``) stacked ``(n k, s)``, and ``rows (n, k)``
    into them."""
    n, k = soff.shape
    P = np.empty((n * k, s))
    rows = np.empty((n, k), dtype=np.int64)
    for i in range(n):
        for p in range(k):
            rows[i, p] = i * k + p
            o = soff[i, p]
            for c in range(s):
                P[i * k + p, c] = x[o + c]
    return P, rows
