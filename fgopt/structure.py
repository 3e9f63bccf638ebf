"""Structure computed once per problem: variable ordering, the pattern of H, the scatter map.

H = J^T W J is stored as the **lower triangle in CSC** (what CHOLMOD reads). Variables are
given tangent offsets in a fill-reducing order computed on the *variable* (block) graph, which
is much smaller than the scalar matrix, and then expanded; the solvers then factor H in its
natural order. When a Schur-complement solver will factor H, no fill-reducing order is needed:
the eliminated variables simply come first (:func:`schur_order`). Each variable's diagonal
block and each coupled pair's block are stored dense: a block whose entry ``(0, 0)`` is at data
index ``p00`` has entry ``(a, b)`` at ``p00 + col_shift[c0 + b] + a`` (``c0`` = the first
column of its column variable; :func:`column_shift`).

The scatter map gives, for every factor instance and every ordered pair ``(p, q)`` of its
variables with ``rank(v_p) >= rank(v_q)``, that ``p00``: one integer per block (the assembly
kernel adds the factor's dense ``D x D`` Hessian block through it).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

ORDERINGS = ("amd", "mmd", "metis", "nesdis", "colamd", "natural", "default", "best",
             "cholmod_amd")
#: Orderings only CHOLMOD computes (the ``fgopt[cholmod]`` extra); ``"cholmod_amd"`` is
#: CHOLMOD's AMD on either backend (``"amd"`` is fgopt's own on the numba backend).
CHOLMOD_ORDERINGS = ("metis", "nesdis", "colamd", "default", "best", "cholmod_amd")



@dataclass(eq=False)
class HessianPattern:
    """Lower-triangular CSC pattern of H with per-variable block layout.

    The row ``indices`` (one int64 per stored entry: as large as H itself) are built on first
    use from the block list: the Schur solver never needs them.
    """

    size: int                 # N: total tangent dimension
    indptr: np.ndarray        # (N + 1,) int64
    diag_pos: np.ndarray      # (N,) data index of each diagonal entry
    var_offset: np.ndarray    # (V,) tangent offset of each variable
    var_dim: np.ndarray       # (V,) tangent dim of each variable
    block_codes: np.ndarray   # (nb,) sorted rank(column var) * V + rank(row var) of the blocks
    block_p00: np.ndarray     # (nb,) data index of each block's entry (0, 0)
    order: np.ndarray         # (V,) the variable of each rank (rank = position in H)
    var_kind: np.ndarray | None = None  # (V,) manifold kind id (-1: Python manifold), if known
    kind_names: tuple[str, ...] = ()    # names of the kind ids
    #: Kind ids no factor couples with themselves (no block joins two variables of the kind),
    #: when the builder knows them (the compiled problem does); None: unknown.
    independent_kinds: tuple[int, ...] | None = None
    col_shift: np.ndarray = None        # (N,) see column_shift (computed when not given)
    #: :func:`ba_shaped_kind` once known (``-1``: not BA-shaped), set by its first asker
    #: (:func:`fgopt.solvers.linear.schur.is_ba_shaped`) or the compiled problem; None: unknown.
    #: Set ``var_kind`` / ``independent_kinds`` before asking.
    ba_kind: int | None = None
    _indices: np.ndarray | None = field(default=None, repr=False)

    def __post_init__(self):
        if self.col_shift is None:
            self.col_shift = column_shift(self.indptr, self.var_offset, self.var_dim)

    @property
    def indices(self) -> np.ndarray:
        """``(nnz,)`` int64 row indices, sorted within each column (built once, then kept)."""
        return self.row_indices(cache=True)

    def row_indices(self, cache: bool = True) -> np.ndarray:
        """The row indices; ``cache=False`` does not keep them when they were not built yet
        (a solver that needs them only for its analysis)."""
        if self._indices is not None:
            return self._indices
        args = (self.block_codes, self.var_offset.shape[0], self.order, self.var_dim,
                self.var_offset, self.indptr)
        out = _layout_kernel(_block_rows, _block_rows_np, int(self.indptr[-1]), *args)
        if cache:
            self._indices = out
        return out

    def blocks(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(row var, column var, p00)`` of every stored block, diagonal blocks included."""
        V = self.var_offset.shape[0]
        return (self.order[self.block_codes % V], self.order[self.block_codes // V],
                self.block_p00)

    @property
    def nnz(self) -> int:
        return int(self.indptr[-1])

    def matrix(self, data: np.ndarray) -> "sp.csc_matrix":
        """The lower triangle as a scipy CSC matrix sharing ``data`` (no copy)."""
        import scipy.sparse as sp

        m = sp.csc_matrix((data, self.indices, self.indptr), shape=(self.size, self.size))
        m.has_sorted_indices = True
        return m

    def full(self, data: np.ndarray) -> "sp.csc_matrix":
        import scipy.sparse as sp

        L = self.matrix(data)
        return (L + L.T - sp.diags(data[self.diag_pos])).tocsc()

    def matvec(self, data: np.ndarray, x: np.ndarray) -> np.ndarray:
        """``H @ x`` from the lower triangle."""
        return _sym_matvec(self.indptr, self.indices, data, x)


#: Largest index distance of two coupled variables for which the given order is kept.
BANDED = 8


def _densely_banded(num_vars: int, pairs_i: np.ndarray, pairs_j: np.ndarray) -> bool:
    """Every coupling within ``BANDED`` positions, and at least half the band's block pairs
    coupled: eliminating in the given order then only fills what is mostly filled already (a
    chain of navigation states), unlike a thin 2-D grid's sparse band, where AMD does better."""
    if pairs_i.shape[0] == 0:
        return False
    a = np.asarray(pairs_i, dtype=np.int64)
    b = np.asarray(pairs_j, dtype=np.int64)
    width = int(np.max(np.abs(a - b)))
    if width == 0 or width > BANDED:
        return False
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    off = lo != hi
    # distinct coupled pairs: a pair is (lo, hi - lo) with 1 <= hi - lo <= width, so a mask of
    # num_vars x width cells counts them (no sort)
    mark = np.zeros(num_vars * width, dtype=bool)
    mark[lo[off] * width + (hi[off] - lo[off] - 1)] = True
    coupled = int(np.count_nonzero(mark))
    return coupled >= 0.5 * num_vars * width


def fill_reducing_order(num_vars: int, pairs_i: np.ndarray, pairs_j: np.ndarray,
                        method: str = "amd") -> np.ndarray:
    """A permutation of the variables (block graph) that reduces Cholesky fill.

    Returns ``perm`` with ``perm[k]`` = the variable eliminated ``k``-th. ``"amd"``, on the numba
    backend (outside :func:`fgopt._jit.numpy_mode`), is fgopt's own approximate minimum degree
    kernel (:func:`fgopt._amd.amd_order`, on the pairs directly: nnz(L) within 1.1 % of
    CHOLMOD's AMD on the shared pose graphs, ``benchmarks/ordering.py``; inside a 400-pose solve
    ~0.15 ms less than CHOLMOD's call, which also runs a symbolic factorization and needs a CSC
    matrix built first). On the NumPy backend it is CHOLMOD's AMD (``"cholmod_amd"``) when the
    ``fgopt[cholmod]`` extra is installed, else ``"mmd"``: the multiple minimum degree ordering
    of SuperLU (in scipy's wheels) on the block graph, which measured the same fill as AMD on
    M3500 and less on sphere2500 (``benchmarks/startup.py``, ordering table). The two backends
    then order differently: their results differ in the last bits.
    Tiny problems, and (for ``"amd"`` / ``"mmd"``) graphs densely banded in the given order
    (:func:`_densely_banded`, e.g. a navigation chain of states in time order), keep the given
    order: fill stays inside the band, and skipping the ordering measured 1.4 ms faster per
    solve of GTSAM's ImuFactorsExample (101 states; 2.9 -> 2.1 ms to compile).
    """
    from .errors import FgoptError, have_extra, missing_extra

    if method not in ORDERINGS:
        raise FgoptError(f"unknown ordering {method!r}: choose one of {', '.join(ORDERINGS)}")
    if method in CHOLMOD_ORDERINGS and not have_extra("sksparse"):
        # Checked before the shortcuts below: a missing extra is an error whatever the graph.
        raise missing_extra("sksparse", f"ordering={method!r}")
    pairs_i = np.ascontiguousarray(pairs_i, dtype=np.int64)
    pairs_j = np.ascontiguousarray(pairs_j, dtype=np.int64)
    if pairs_i.shape != pairs_j.shape or pairs_i.ndim != 1:
        raise FgoptError(f"ordering: pairs_i and pairs_j must be 1-D arrays of one length, got "
                         f"shapes {pairs_i.shape} and {pairs_j.shape}")
    if method == "natural" or num_vars <= 16:  # tiny problems: ordering costs more than fill
        return np.arange(num_vars)
    if method in ("amd", "mmd") and _densely_banded(num_vars, pairs_i, pairs_j):
        return np.arange(num_vars)
    if method == "amd" and not numpy_only():  # the numba backend (whose kernels load numba)
        perm = amd_order(num_vars, pairs_i, pairs_j)
        if perm.shape[0] != num_vars:  # (the kernel never loses a node: tests/core/test_amd.py)
            raise FgoptError(f"ordering: a pair names a variable outside 0..{num_vars - 1}")
        return perm
    A = _block_graph_csc(num_vars, pairs_i, pairs_j)
    if method == "amd" and not have_extra("sksparse"):
        method = "mmd"
    if method == "mmd":
        return minimum_degree_order(A)
    from sksparse.cholmod import analyze

    with np.errstate(all="ignore"):
        f = analyze(A, mode="simplicial",
                    ordering_method="amd" if method == "cholmod_amd" else method)
    return np.asarray(f.P(), dtype=np.int64)


def _block_graph_csc(num_vars: int, pairs_i: np.ndarray, pairs_j: np.ndarray) -> Any:
    """The symmetric pattern of the variable graph with its diagonal, as a CSC matrix (sorted,
    summed duplicates). Values only keep the pivots on the diagonal
    (:func:`minimum_degree_order`): the diagonal's exceeds any row's sum of ones. Once numba is
    in use, :func:`fgopt._structure_kernels._block_graph` builds it (400 poses: ~0.01 ms
    instead of the COO -> CSC conversion's ~0.09)."""
    import scipy.sparse as sp

    pairs_i = np.ascontiguousarray(pairs_i, dtype=np.int64)
    pairs_j = np.ascontiguousarray(pairs_j, dtype=np.int64)
    data, indices, indptr = _layout_kernel(_block_graph, _block_graph_np,
                                           4 * (pairs_i.shape[0] + num_vars), num_vars,
                                           pairs_i, pairs_j)
    return sp.csc_matrix((data, indices, indptr), shape=(num_vars, num_vars))


def _block_graph_np(num_vars: int, pairs_i: np.ndarray, pairs_j: np.ndarray) -> tuple:
    """:func:`_block_graph_csc`'s arrays from one COO -> CSC conversion (0.07 ms on 808
    variables instead of 0.16 for summing duplicates and adding an identity afterwards)."""
    import scipy.sparse as sp

    diag = np.arange(num_vars, dtype=np.int64)
    rows = np.concatenate([pairs_i, pairs_j, diag])
    cols = np.concatenate([pairs_j, pairs_i, diag])
    data = np.where(rows == cols, rows.shape[0] + 2.0, 1.0)
    A = sp.csc_matrix((data, (rows, cols)), shape=(num_vars, num_vars))
    return A.data, A.indices, A.indptr


#: ``"auto"`` factors systems of at most this many unknowns with a dense Cholesky when H is at
#: least ``DENSE_MIN_FILL`` full; sparser ones go to the block Cholesky (measured, 5 LM
#: iterations: equal at 26-100 % full, 0.98-0.43x the time at 15-3 % on 60-300 unknowns; w100,
#: 100 poses and 300 edges, 300 unknowns, 7 % full: 3.1 -> 1.4 ms).
DENSE_MAX_SIZE = 300
DENSE_MIN_FILL = 0.25


def independent_kinds(var_kind: np.ndarray, pairs_i: np.ndarray,
                      pairs_j: np.ndarray) -> tuple[int, ...]:
    """Kind ids (>= 0) of which no pair ``(pairs_i, pairs_j)`` joins two variables."""
    var_kind = np.asarray(var_kind)
    # per kind id: has variables / has a pair within the kind (bincounts: a few kinds)
    size = int(var_kind.max(initial=-1)) + 1
    present = np.bincount(var_kind[var_kind >= 0], minlength=size) > 0
    ki, kj = var_kind[pairs_i], var_kind[pairs_j]
    within = ki[(ki == kj) & (ki >= 0) & (np.asarray(pairs_i) != np.asarray(pairs_j))]
    joined = np.bincount(within, minlength=size) > 0
    return tuple(int(k) for k in np.flatnonzero(present & ~joined))


def kinds_by_count(var_kind: np.ndarray) -> list[int]:
    """Kind ids (>= 0), the most numerous first (ties: smaller id first)."""
    counts = np.bincount(var_kind[var_kind >= 0])
    ids = np.flatnonzero(counts)
    return [int(i) for i in ids[np.argsort(-counts[ids], kind="stable")]]


def ba_shaped_kind(var_kind: np.ndarray, var_dim: np.ndarray,
                   independent: tuple[int, ...]) -> int | None:
    """The kind to eliminate when a problem is BA-shaped, else None.

    BA-shaped: the kind with the most variables is independent (no factor couples two of its
    variables), has at least twice as many variables as all others together and at least half
    of the tangent dimension, so eliminating it leaves a much smaller reduced system.
    """
    var_kind = np.asarray(var_kind)
    by_count = kinds_by_count(var_kind)
    if not by_count or by_count[0] not in independent:
        return None
    mask = var_kind == by_count[0]
    n_e = int(mask.sum())
    if n_e == mask.shape[0]:  # one kind only (pose graphs): nothing would be left to reduce to
        return None
    if n_e < 2 * (mask.shape[0] - n_e) or 2 * int(var_dim[mask].sum()) < int(var_dim.sum()):
        return None
    return by_count[0]


def schur_order(var_kind: np.ndarray, eliminated_kind: int) -> np.ndarray:
    """Variables of ``eliminated_kind`` first, then the others (each in index order).

    The order of H for a Schur-complement solve: every block coupling an eliminated variable
    with a kept one lies in the eliminated variable's columns, next to its diagonal block, and
    the solver orders the reduced system itself, so H needs no fill-reducing order.
    """
    e = np.asarray(var_kind) == eliminated_kind
    return np.concatenate([np.nonzero(e)[0], np.nonzero(~e)[0]]).astype(np.int64)
def minimum_degree_order(A) -> np.ndarray:
    """Multiple minimum degree elimination order of the symmetric pattern of ``A`` (SuperLU's
    ``MMD_AT_PLUS_A``, shipped in scipy's wheels; no SuiteSparse).

    SuperLU factors ``A[:, c]`` with column permutation ``c``; in symmetric mode with diagonal
    pivots (``A`` must be strictly diagonally dominant) the elimination order is ``argsort(c)``.
    """
    from scipy.sparse.linalg import splu

    lu = splu(A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
              options={"SymmetricMode": True})
    return np.argsort(lu.perm_c).astype(np.int64)


def build_pattern(var_dim: np.ndarray, order: np.ndarray, pairs_i: np.ndarray,
                  pairs_j: np.ndarray) -> tuple[HessianPattern, dict]:
    """Pattern of H for variables with dims ``var_dim`` coupled by ``(pairs_i, pairs_j)``.

    ``order`` is the elimination order of the variables. Returns the pattern and a lookup used
    by :func:`scatter_positions`: ``codes`` (sorted ``rank(column var) * V + rank(row var)`` of
    every stored block, diagonal blocks included: the CSC order of the blocks), ``col_ptr``
    (blocks of column rank ``r`` are ``codes[col_ptr[r]:col_ptr[r + 1]]``) and ``p00`` (data index
    of each block's entry ``(0, 0)``).
    """
    var_dim = np.ascontiguousarray(var_dim, dtype=np.int64)
    order = np.ascontiguousarray(order, dtype=np.int64)
    pairs_i = np.ascontiguousarray(pairs_i, dtype=np.int64)
    pairs_j = np.ascontiguousarray(pairs_j, dtype=np.int64)
    V = var_dim.shape[0]
    N = int(var_dim.sum())
    if _use_numba(4 * (pairs_i.shape[0] + V)):
        # one numba call (small problems: the NumPy steps below cost ~100 us of call overhead)
        var_offset, codes, indptr, p00, col_ptr = _pattern_kernel(var_dim, order, pairs_i,
                                                                  pairs_j, N)
    else:
        var_offset, codes, indptr, p00, col_ptr = _pattern_np(var_dim, order, pairs_i,
                                                              pairs_j, N)
    diag_pos = indptr[:-1].copy()  # diagonal entry is the first of each lower column
    pattern = HessianPattern(N, indptr, diag_pos, var_offset, var_dim, codes, p00, order)
    lookup = {"codes": codes, "col_ptr": col_ptr, "p00": p00, "V": V}
    return pattern, lookup


def _pattern_np(var_dim, order, pairs_i, pairs_j, N):
    """``(var_offset, codes, indptr, p00, col_ptr)`` of :func:`build_pattern`, vectorized (the
    NumPy backend, and numba's twin budget; see :func:`_layout_kernel`)."""
    V = var_dim.shape[0]
    rank = np.empty(V, dtype=np.int64)
    rank[order] = np.arange(V)
    var_offset = np.zeros(V, dtype=np.int64)
    dims_in_order = var_dim[order]
    var_offset[order] = np.concatenate([[0], np.cumsum(dims_in_order)[:-1]]) if V else []
    # Blocks as rank codes (column = the smaller rank): one sort gives the CSC order, diagonal
    # blocks first in their columns.
    ri = rank[pairs_i]
    rj = rank[pairs_j]
    keep = ri != rj
    ri, rj = ri[keep], rj[keep]
    codes = np.concatenate([np.minimum(ri, rj) * V + np.maximum(ri, rj),
                            np.arange(V, dtype=np.int64) * (V + 1)])
    del ri, rj, keep
    codes = unique_int(codes)
    args = (codes, V, order, var_dim, var_offset, N)
    indptr, p00 = _layout_kernel(_block_layout, _block_layout_np, codes.shape[0] * 4, *args)
    col_ptr = np.searchsorted(codes, np.arange(V + 1, dtype=np.int64) * V)
    return var_offset, codes, indptr, p00, col_ptr


def unique_int(a: np.ndarray) -> np.ndarray:
    """Sorted unique values of an int64 array (sort-based: numpy's hash-based ``unique`` was
    6x slower on 10^7 codes)."""
    a = np.sort(a)
    if a.shape[0] < 2:
        return a
    keep = np.empty(a.shape[0], dtype=bool)
    keep[0] = True
    np.not_equal(a[1:], a[:-1], out=keep[1:])
    return a[keep]


def column_shift(indptr: np.ndarray, var_offset: np.ndarray, var_dim: np.ndarray) -> np.ndarray:
    """``shift[c] = indptr[c] - indptr[c0] - (c - c0)``, ``c0`` = first column of c's variable.

    A block whose entry ``(0, 0)`` is at data index ``p00`` has entry ``(a, b)`` at
    ``p00 + shift[c0 + b] + a`` (lower CSC, block-dense: each column of a variable holds the same
    blocks, the diagonal block's triangle one row shorter per column).
    """
    srt = np.argsort(var_offset, kind="stable")
    c0 = np.repeat(var_offset[srt], var_dim[srt])
    c = np.arange(c0.shape[0], dtype=np.int64)
    return indptr[:-1] - indptr[c0] - (c - c0)


def ranges(lengths: np.ndarray) -> np.ndarray:
    """concat(arange(l) for l in lengths), vectorized."""
    lengths = np.asarray(lengths, dtype=np.int64)
    total = int(lengths.sum())
    if total == 0:
        return np.zeros(0, dtype=np.int64)
    starts = np.repeat(np.cumsum(lengths) - lengths, lengths)
    return np.arange(total, dtype=np.int64) - starts


from ._amd import amd_order  # noqa: E402
from ._jit import charge_numpy, is_numba_loaded, numpy_budget_left, numpy_only  # noqa: E402
from ._structure_kernels import (_block_graph, _block_layout, _block_rows,  # noqa: E402,F401
                                 _pattern_kernel, _scatter_positions, _sym_matvec)


def _block_layout_np(codes, V, order, var_dim, var_offset, N):
    """:func:`_block_layout` vectorized (NumPy backend and small problems)."""
    c, r = order[codes // V], order[codes % V]
    dr = var_dim[r]
    grp = codes // V                                   # column rank of each block
    rows = np.bincount(grp, weights=dr, minlength=V).astype(np.int64)  # rows in column 0
    dims = var_dim[order]
    col_len = np.repeat(rows[:dims.shape[0]], dims) - ranges(dims)   # diagonal: triangular
    indptr = np.zeros(N + 1, dtype=np.int64)
    np.cumsum(col_len, out=indptr[1:])
    # within its column, a block starts after the rows of the blocks before it
    csum = np.cumsum(dr) - dr
    first = np.searchsorted(grp, grp, side="left")
    p00 = indptr[var_offset[c]] + csum - csum[first] if codes.shape[0] else \
        np.zeros(0, dtype=np.int64)
    p00 = np.where(var_dim[c] > 0, p00, 0)
    return indptr, p00.astype(np.int64)


def _block_rows_np(codes, V, order, var_dim, var_offset, indptr):
    """:func:`_block_rows` vectorized: one entry per (block, column of the block)."""
    c, r = order[codes // V], order[codes % V]
    _, p00 = _block_layout_np(codes, V, order, var_dim, var_offset, indptr.shape[0] - 1)
    shift = column_shift(indptr, var_offset, var_dim)
    dc = var_dim[c]
    b = np.repeat(np.arange(codes.shape[0], dtype=np.int64), dc)   # block of each entry
    cb = ranges(dc)                                                  # column within the block
    a0 = np.where((c == r)[b], cb, 0)                                # first stored row
    length = var_dim[r][b] - a0
    start = p00[b] + shift[var_offset[c][b] + cb] + a0
    indices = np.empty(int(indptr[-1]), dtype=np.int64)
    within = ranges(length)
    indices[np.repeat(start, length) + within] = np.repeat(var_offset[r][b] + a0, length) + within
    return indices


def _scatter_positions_np(codes, col_ptr, p00, V, var_rank, var_idx):
    """:func:`_scatter_positions` vectorized over instances (one pass per argument pair)."""
    n, k = var_idx.shape
    pos = np.full((n, k, k), -1, dtype=np.int64)
    rank = var_rank[var_idx]
    for p in range(k):
        for q in range(k):
            ok = rank[:, p] >= rank[:, q] if p == q else rank[:, p] > rank[:, q]
            rows = np.nonzero(ok)[0]
            if rows.shape[0] == 0:
                continue
            at = np.searchsorted(codes, rank[rows, q] * V + rank[rows, p])
            pos[rows, p, q] = p00[at]
    return pos


#: Layout work up to this size runs vectorized while numba is not in use in the process (the
#: NumPy backend's solvers analyze the pattern outside its kernel mode; its arrays take ~10
#: words per entry).
NUMPY_LAYOUT_MAX = 1 << 22


def _layout_kernel(kernel, twin, work: int, *args):
    """``twin(*args)`` (NumPy, vectorized) on the NumPy backend, while numba is not in use (up to
    ``NUMPY_LAYOUT_MAX``), or for about ``work`` steps while the process still rents
    (:func:`_small`, time charged); else the numba ``kernel``."""
    if numpy_only() or (work <= NUMPY_LAYOUT_MAX and not is_numba_loaded()):
        return twin(*args)
    if _small(work):
        t0 = time.perf_counter()
        try:
            return twin(*args)
        finally:
            charge_numpy(time.perf_counter() - t0)
    return kernel(*args)


def _small(work: int) -> bool:
    """Loops of about ``work`` steps run as plain Python while the process still rents
    (``fgopt._jit.numpy_budget_left``): numba's import, initialization and cache loads (~0.5 s)
    would cost more. Callers charge the time to the budget (:func:`_charged`)."""
    return work <= 20000 and numpy_budget_left()


def _charged(kernel, *args):
    """``kernel.python(*args)``, its time counted towards the switch to numba."""
    t0 = time.perf_counter()
    try:
        return kernel.python(*args)
    finally:
        charge_numpy(time.perf_counter() - t0)


def _use_numba(work: int) -> bool:
    """Whether layout work of about ``work`` steps runs in numba (the rule of
    :func:`_layout_kernel`, without running anything)."""
    if numpy_only() or (work <= NUMPY_LAYOUT_MAX and not is_numba_loaded()):
        return False
    return not _small(work)


def scatter_positions(lookup: dict, var_rank: np.ndarray, var_idx: np.ndarray) -> np.ndarray:
    """Per instance, where each stored block of its local Hessian sits in H's data array.

    ``var_idx``: ``(n, k)`` variable indices of each instance's arguments. Returns ``pos`` of shape
    ``(n, k, k)``: for pairs with ``rank[v_p] >= rank[v_q]`` the data index of entry ``(0, 0)`` of
    block ``(v_p, v_q)`` (rows of ``v_p``, columns of ``v_q``; ``p == q``: the diagonal block),
    else -1. Entry ``(a, b)`` is then at ``pos + col_shift[off[v_q] + b] + a``
    (:func:`column_shift`).
    """
    n, k = var_idx.shape
    # NumPy backend, or small problems before numba is in use: vectorized (no numba import)
    small = numpy_only() or (n * k * k <= 20000 and not is_numba_loaded())
    run = _scatter_positions_np if small else _scatter_positions
    return run(np.ascontiguousarray(lookup["codes"], dtype=np.int64),
               np.ascontiguousarray(lookup["col_ptr"], dtype=np.int64),
               np.ascontiguousarray(lookup["p00"], dtype=np.int64),
               int(lookup["V"]), np.ascontiguousarray(var_rank, dtype=np.int64),
               np.ascontiguousarray(var_idx, dtype=np.int64))
