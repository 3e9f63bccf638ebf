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

The integer fields of each kind of slot are the rows of one 2-D array (``VI``, ``FI``, ``CI``,
``ADJ``), so a kernel call passes a dozen arrays, not fifty: numba's dispatch costs about
0.2 us per array argument, which counts when an update takes tens of microseconds. Kernels
unpack the rows with :func:`unpack_vs` / :func:`unpack_fs` / :func:`unpack_cs`.

Counters the kernels update (stamps, pool tops and free lists, free stacks) sit in the
``meta`` array, so an update that fails can be undone by restoring a copy of ``meta`` (see
``smoother.py``). The pools are block allocators (:mod:`._pool`).
"""

from __future__ import annotations

import numpy as np

from .._jit import njit
from ._pool import NCLASS

# indices into ``meta``: counters, then the free-list heads of the three pools (``_pool.py``)
M_STAMP, M_CV_TOP, M_CN_TOP, M_CL_NFREE, M_CL_HWM, M_ADJ_NFREE, M_ADJ_HWM, M_HP_TOP = range(8)
M_NCLIQUES = 8
M_CV_HEAD, M_CN_HEAD, M_HP_HEAD = 9, 9 + NCLASS, 9 + 2 * NCLASS
META_SIZE = 9 + 3 * NCLASS

# rows of VI, FI, CI, ADJ (and their fill values)
_VI_ROWS = ("var_dim", "var_clique", "var_mark", "var_loc", "var_pos", "var_fhead",
            "var_changed", "var_live", "var_repl", "var_stale", "var_xrepl", "var_out")
_VI_FILL = (0, -1, 0, 0, 0, -1, 0, 0, 0, 0, 0, 0)
#: the row of ``VI`` a kernel writes a list of variables into and returns its length (an array
#: returned from numba costs ~1.5 us to box; a number and a view of this row, a fraction)
VI_OUT = 11
_FI_ROWS = ("fac_nv", "fac_hoff", "fac_D", "fac_mark", "fac_alive")
_CI_ROWS = ("cl_parent", "cl_child", "cl_next", "cl_prev", "cl_voff", "cl_nf", "cl_ns",
            "cl_fdim", "cl_sdim", "cl_poff", "cl_mark", "cl_free")
_CI_FILL = (-1, -1, -1, -1, 0, 0, 0, 0, 0, 0, 0, 0)
_ADJ_ROWS = ("adj_next", "adj_fac", "adj_free")


@njit(cache=True, inline="always")
def unpack_vs(vs):
    """``(dim, clique, mark, loc, pos, fhead, changed, delta, thr, live, repl, stale, xrepl)``;
    ``repl`` / ``xrepl`` mark variables re-eliminated since the last back-substitution of
    ``delta`` / of the estimate's ``xdelta``, ``stale`` those whose ``xdelta`` or ``theta``
    changed since the estimate cache last retracted them (``_values.VariableStore._refresh``)."""
    VI, delta, thr = vs
    return (VI[0], VI[1], VI[2], VI[3], VI[4], VI[5], VI[6], delta, thr, VI[7], VI[8], VI[9],
            VI[10])


@njit(cache=True, inline="always")
def unpack_fs(fs):
    """``(nv, vars, hoff, D, mark, alive, adj_next, adj_fac, adj_free)``."""
    FI, fac_vars, ADJ = fs
    return FI[0], fac_vars, FI[1], FI[2], FI[3], FI[4], ADJ[0], ADJ[1], ADJ[2]


@njit(cache=True, inline="always")
def unpack_cs(CI):
    """``(parent, child, next, prev, voff, nf, ns, fdim, sdim, poff, mark, free)``."""
    return (CI[0], CI[1], CI[2], CI[3], CI[4], CI[5], CI[6], CI[7], CI[8], CI[9], CI[10],
            CI[11])


def _grow_cols(a: np.ndarray, n: int, fill) -> np.ndarray:
    """``a`` (rows x cap) with at least ``n`` columns (doubling), new columns = ``fill``."""
    if a.shape[1] >= n:
        return a
    cap = max(n, 2 * a.shape[1], 16)
    out = np.empty((a.shape[0], cap), a.dtype)
    out[:, :a.shape[1]] = a
    out[:, a.shape[1]:] = np.asarray(fill, a.dtype).reshape(-1, 1)
    return out


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
        self.VI = _grow_cols(np.zeros((len(_VI_ROWS), 0), np.int64), 16, _VI_FILL)
        self.delta = np.zeros((16, 1))
        self.thr = np.zeros((16, 1))
        # the estimate's back-substituted update, and each variable's value when its
        # dependents were last re-solved (``_solve.solve_estimate``)
        self.xdelta = np.zeros((16, 1))
        self.xprop = np.zeros((16, 1))
        self.FI = np.zeros((len(_FI_ROWS), 16), np.int64)
        self.fac_vars = np.full((16, 1), -1, np.int64)
        self.ADJ = np.full((3, 16), -1, np.int64)
        self.hpool = np.zeros(256)
        self.CI = _grow_cols(np.zeros((len(_CI_ROWS), 0), np.int64), 16, _CI_FILL)
        self.cvpool = np.zeros(256, np.int64)
        self.cnpool = np.zeros(1024)
        self.meta = np.zeros(META_SIZE, np.int64)
        self.meta[M_CL_HWM] = 1          # clique 0: the virtual root
        self.meta[M_CV_HEAD:] = -1       # empty free lists
        self._tuples = None

    # ------------------------------------------------------------------ capacity
    def ensure_vars(self, n: int, maxd: int) -> None:
        if maxd > self.maxd:
            for name in ("delta", "thr", "xdelta", "xprop"):
                old = getattr(self, name)
                new = np.zeros((old.shape[0], maxd))
                new[:, :self.maxd] = old
                setattr(self, name, new)
            self.maxd = maxd
            self._tuples = None
        if self.VI.shape[1] >= n:
            return
        self._tuples = None
        self.VI = _grow_cols(self.VI, n, _VI_FILL)
        self.delta = _grow(self.delta, n)
        self.thr = _grow(self.thr, n)
        self.xdelta = _grow(self.xdelta, n)
        self.xprop = _grow(self.xprop, n)

    def ensure_factors(self, n: int, kmax: int) -> None:
        if kmax > self.kmax:
            new = np.full((self.fac_vars.shape[0], kmax), -1, np.int64)
            new[:, :self.kmax] = self.fac_vars
            self.fac_vars = new
            self.kmax = kmax
            self._tuples = None
        if self.FI.shape[1] >= n:
            return
        self._tuples = None
        self.FI = _grow_cols(self.FI, n, 0)
        self.fac_vars = _grow(self.fac_vars, n, -1)

    def ensure_hpool(self, n: int) -> None:
        self.hpool = _grow(self.hpool, n)

    def ensure_adjacency(self, extra: int) -> None:
        """Room for ``extra`` more adjacency entries (beyond the free stack)."""
        need = int(self.meta[M_ADJ_HWM]) + extra
        if self.ADJ.shape[1] < need:
            self._tuples = None
            self.ADJ = _grow_cols(self.ADJ, need, -1)

    def ensure_cliques(self, n: int) -> None:
        if self.CI.shape[1] >= n:
            return
        self._tuples = None
        self.CI = _grow_cols(self.CI, n, _CI_FILL)

    # ------------------------------------------------------------------ numba argument tuples
    def _build_tuples(self) -> tuple:
        self._tuples = ((self.VI, self.delta, self.thr), (self.FI, self.fac_vars, self.ADJ),
                        self.CI)
        return self._tuples

    def tuples(self) -> tuple:
        """``(vs, fs, cs)``."""
        return self._tuples or self._build_tuples()

    @property
    def vs(self) -> tuple:
        return (self._tuples or self._build_tuples())[0]

    @property
    def fs(self) -> tuple:
        return (self._tuples or self._build_tuples())[1]

    @property
    def cs(self) -> np.ndarray:
        return (self._tuples or self._build_tuples())[2]

    # ------------------------------------------------------------------ statistics
    def nnz_factor(self) -> int:
        """Stored entries of the conditionals (panels), over all live cliques."""
        from ._top import factor_entries

        return int(factor_entries(self.cs))


# named views of the packed rows (``tree.var_dim`` is ``tree.VI[0]``, writable)
for _name, _rows in (("VI", _VI_ROWS), ("FI", _FI_ROWS), ("CI", _CI_ROWS), ("ADJ", _ADJ_ROWS)):
    for _i, _row in enumerate(_rows):
        setattr(TreeState, _row, property(lambda self, _a=_name, _k=_i: getattr(self, _a)[_k]))
