"""Array state of the incremental smoother: variables, factors, and the Bayes tree.

Everything the numba kernels touch lives in flat, growable numpy arrays indexed by *slots*
(small integers reused after removal, so memory stays bounded in a fixed-lag smoother):

* variable slot ``v``: tangent dim, the clique where it is frontal, its linearization-point
  update ``delta[v, :dim]`` (tangent at ``theta``), per-component relinearization thresholds,
  and the head of its list of factors (an intrusive linked list, ``adj_*``);
* factor slot ``f``: its variable slots and where its linearized local system (``D x D``
  Hessian, row-major, then the ``D`` gradient ``J^T W r``) starts in ``hpool``;
* clique slot ``c`` (slot 0 is a virtual root whose children are the tree's roots): parent,
  first child and sibling links, its variables (frontal first, then separator) in ``cvpool``,
  and its numbers in ``cnpool``: the panel ``[L11; L21]`` (``m x fd``, column-major), the
  forward-substituted right-hand side ``y`` (``fd``), then the cached marginal on its
  separator, ``C`` (``sd x sd``, column-major, lower triangle) and ``c`` (``sd``): the Schur
  complement the clique passes to its parent, reused when the parent is re-eliminated and the
  clique is not (iSAM2's cached factor).

Counters the kernels update (stamps, pool tops, free stacks) sit in the ``meta`` array, so an
update that fails can be undone by restoring a copy of ``meta`` (see ``smoother.py``).
"""

from __future__ import annotations

import numpy as np

# indices into ``meta``
M_STAMP, M_CV_TOP, M_CN_TOP, M_CL_NFREE, M_CL_HWM, M_ADJ_NFREE, M_ADJ_HWM, M_HP_TOP = range(8)
M_CV_GARBAGE, M_CN_GARBAGE, M_HP_GARBAGE, M_NCLIQUES = 8, 9, 10, 11
META_SIZE = 12


def _grow(a: np.ndarray, n: int, fill=0) -> np.ndarray:
    """``a`` with at least ``n`` rows (doubling), new rows set to ``fill``."""
    if a.shape[0] >= n:
        return a
    cap = max(n, 2 * a.shape[0], 16)
    out = np.full((cap,) + a.shape[1:], fill, dtype=a.dtype)
    out[:a.shape[0]] = a
    return out


class TreeState:
    """The arrays described in the module docstring, with capacity management."""

    def __init__(self) -> None:
        self.maxd = 1       # columns of delta / thr (largest tangent dim seen)
        self.kmax = 1       # columns of fac_vars (largest factor arity seen)
        self.var_dim = np.zeros(16, np.int64)
        self.var_clique = np.full(16, -1, np.int64)
        self.var_mark = np.zeros(16, np.int64)
        self.var_loc = np.zeros(16, np.int64)
        self.var_pos = np.zeros(16, np.int64)
        self.var_fhead = np.full(16, -1, np.int64)
        self.var_changed = np.zeros(16, np.int64)
        self.delta = np.zeros((16, 1))
        self.thr = np.zeros((16, 1))
        self.adj_next = np.full(16, -1, np.int64)
        self.adj_fac = np.full(16, -1, np.int64)
        self.adj_free = np.zeros(16, np.int64)
        self.fac_nv = np.zeros(16, np.int64)
        self.fac_vars = np.full((16, 1), -1, np.int64)
        self.fac_hoff = np.zeros(16, np.int64)
        self.fac_D = np.zeros(16, np.int64)
        self.fac_mark = np.zeros(16, np.int64)
        self.fac_alive = np.zeros(16, np.int8)
        self.hpool = np.zeros(256)
        self.cl_parent = np.full(16, -1, np.int64)
        self.cl_child = np.full(16, -1, np.int64)
        self.cl_next = np.full(16, -1, np.int64)
        self.cl_prev = np.full(16, -1, np.int64)
        self.cl_voff = np.zeros(16, np.int64)
        self.cl_nf = np.zeros(16, np.int64)
        self.cl_ns = np.zeros(16, np.int64)
        self.cl_fdim = np.zeros(16, np.int64)
        self.cl_sdim = np.zeros(16, np.int64)
        self.cl_poff = np.zeros(16, np.int64)
        self.cl_mark = np.zeros(16, np.int64)
        self.cl_free = np.zeros(16, np.int64)
        self.cvpool = np.zeros(256, np.int64)
        self.cnpool = np.zeros(1024)
        self.meta = np.zeros(META_SIZE, np.int64)
        self.meta[M_CL_HWM] = 1          # clique 0: the virtual root
        self.meta[M_NCLIQUES] = 0

    # ------------------------------------------------------------------ capacity
    def ensure_vars(self, n: int, maxd: int) -> None:
        if maxd > self.maxd:
            for name in ("delta", "thr"):
                old = getattr(self, name)
                new = np.zeros((old.shape[0], maxd))
                new[:, :self.maxd] = old
                setattr(self, name, new)
            self.maxd = maxd
        if self.var_dim.shape[0] >= n:
            return
        self.var_dim = _grow(self.var_dim, n)
        self.var_clique = _grow(self.var_clique, n, -1)
        self.var_mark = _grow(self.var_mark, n)
        self.var_loc = _grow(self.var_loc, n)
        self.var_pos = _grow(self.var_pos, n)
        self.var_fhead = _grow(self.var_fhead, n, -1)
        self.var_changed = _grow(self.var_changed, n)
        self.delta = _grow(self.delta, n)
        self.thr = _grow(self.thr, n)

    def ensure_factors(self, n: int, kmax: int) -> None:
        if kmax > self.kmax:
            new = np.full((self.fac_vars.shape[0], kmax), -1, np.int64)
            new[:, :self.kmax] = self.fac_vars
            self.fac_vars = new
            self.kmax = kmax
        if self.fac_nv.shape[0] >= n:
            return
        self.fac_nv = _grow(self.fac_nv, n)
        self.fac_vars = _grow(self.fac_vars, n, -1)
        self.fac_hoff = _grow(self.fac_hoff, n)
        self.fac_D = _grow(self.fac_D, n)
        self.fac_mark = _grow(self.fac_mark, n)
        self.fac_alive = _grow(self.fac_alive, n)

    def ensure_hpool(self, n: int) -> None:
        self.hpool = _grow(self.hpool, n)

    def ensure_adjacency(self, extra: int) -> None:
        """Room for ``extra`` more adjacency entries (beyond the free stack)."""
        need = int(self.meta[M_ADJ_HWM]) + extra
        if self.adj_next.shape[0] < need:
            self.adj_next = _grow(self.adj_next, need, -1)
            self.adj_fac = _grow(self.adj_fac, need, -1)
            self.adj_free = _grow(self.adj_free, need)

    def ensure_cliques(self, n: int) -> None:
        if self.cl_parent.shape[0] >= n:
            return
        self.cl_parent = _grow(self.cl_parent, n, -1)
        self.cl_child = _grow(self.cl_child, n, -1)
        self.cl_next = _grow(self.cl_next, n, -1)
        self.cl_prev = _grow(self.cl_prev, n, -1)
        self.cl_voff = _grow(self.cl_voff, n)
        self.cl_nf = _grow(self.cl_nf, n)
        self.cl_ns = _grow(self.cl_ns, n)
        self.cl_fdim = _grow(self.cl_fdim, n)
        self.cl_sdim = _grow(self.cl_sdim, n)
        self.cl_poff = _grow(self.cl_poff, n)
        self.cl_mark = _grow(self.cl_mark, n)
        self.cl_free = _grow(self.cl_free, n)

    # ------------------------------------------------------------------ numba argument tuples
    @property
    def vs(self) -> tuple:
        return (self.var_dim, self.var_clique, self.var_mark, self.var_loc, self.var_pos,
                self.var_fhead, self.var_changed, self.delta, self.thr)

    @property
    def fs(self) -> tuple:
        return (self.fac_nv, self.fac_vars, self.fac_hoff, self.fac_D, self.fac_mark,
                self.fac_alive, self.adj_next, self.adj_fac, self.adj_free)

    @property
    def cs(self) -> tuple:
        return (self.cl_parent, self.cl_child, self.cl_next, self.cl_prev, self.cl_voff,
                self.cl_nf, self.cl_ns, self.cl_fdim, self.cl_sdim, self.cl_poff, self.cl_mark,
                self.cl_free)

    # ------------------------------------------------------------------ statistics
    def nnz_factor(self) -> int:
        """Stored entries of the conditionals (panels), over all live cliques."""
        from ._top import factor_entries

        return int(factor_entries(self.cs))
