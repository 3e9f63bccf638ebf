"""Structure computed once per problem: variable ordering, the pattern of H, the scatter map.

H = J^T W J is stored as the **lower triangle in CSC** (what CHOLMOD reads). Variables are
given tangent offsets in a fill-reducing order computed on the *variable* (block) graph, which
is much smaller than the scalar matrix, and then expanded; the solvers then factor H in its
natural order. Each variable's diagonal block and each coupled pair's block are stored dense,
so the position of entry ``(a, b)`` of block ``(i, j)`` is ``col_base[b] + a``.

The scatter map gives, for every factor instance and every ordered pair ``(p, q)`` of its
variables with ``off[v_p] >= off[v_q]``, the data index of the block's first row in each of its
columns; the assembly kernel adds the factor's dense ``D x D`` Hessian block there.
"""

from __future__ import annotations

from dataclasses import dataclass
import time

import numpy as np

ORDERINGS = ("amd", "mmd", "metis", "nesdis", "colamd", "natural", "default", "best")
#: Orderings only CHOLMOD computes (the ``fgopt[cholmod]`` extra).
CHOLMOD_ORDERINGS = ("metis", "nesdis", "colamd", "default", "best")



@dataclass(eq=False)
class HessianPattern:
    """Lower-triangular CSC pattern of H with per-variable block layout."""

    size: int                 # N: total tangent dimension
    indptr: np.ndarray        # (N + 1,) int64
    indices: np.ndarray       # (nnz,) int64 row indices, sorted within each column
    diag_pos: np.ndarray      # (N,) data index of each diagonal entry
    var_offset: np.ndarray    # (V,) tangent offset of each variable
    var_dim: np.ndarray       # (V,) tangent dim of each variable
    var_kind: np.ndarray | None = None  # (V,) manifold kind id (-1: Python manifold), if known
    kind_names: tuple[str, ...] = ()    # names of the kind ids

    @property
    def nnz(self) -> int:
        return int(self.indices.shape[0])

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
    coupled = np.unique(lo[lo != hi] * num_vars + hi[lo != hi]).shape[0]
    return coupled >= 0.5 * num_vars * width


def fill_reducing_order(num_vars: int, pairs_i: np.ndarray, pairs_j: np.ndarray,
                        method: str = "amd") -> np.ndarray:
    """A permutation of the variables (block graph) that reduces Cholesky fill.

    Returns ``perm`` with ``perm[k]`` = the variable eliminated ``k``-th. ``"amd"`` is CHOLMOD's
    AMD when the ``fgopt[cholmod]`` extra is installed, else ``"mmd"``: the multiple minimum
    degree ordering of SuperLU (in scipy's wheels) on the block graph, which measured the same
    fill as AMD on M3500 and less on sphere2500 (``benchmarks/startup.py``, ordering table).
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
    if method == "natural" or num_vars <= 16:  # tiny problems: ordering costs more than fill
        return np.arange(num_vars)
    if method in ("amd", "mmd") and _densely_banded(num_vars, pairs_i, pairs_j):
        return np.arange(num_vars)
    import scipy.sparse as sp

    rows = np.concatenate([pairs_i, pairs_j, np.arange(num_vars)])
    cols = np.concatenate([pairs_j, pairs_i, np.arange(num_vars)])
    A = sp.csc_matrix((np.ones(rows.shape[0]), (rows, cols)), shape=(num_vars, num_vars))
    A.sum_duplicates()
    # Values only matter to keep the factorization's pivots on the diagonal: |diag| > row sums.
    A = (A + sp.identity(num_vars, format="csc") * (num_vars + 1.0)).tocsc()
    if method == "amd" and not have_extra("sksparse"):
        method = "mmd"
    if method == "mmd":
        return minimum_degree_order(A)
    from sksparse.cholmod import analyze

    with np.errstate(all="ignore"):
        f = analyze(A, mode="simplicial", ordering_method=method)
    return np.asarray(f.P(), dtype=np.int64)


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
    by :func:`scatter_positions`: ``block_keys`` (sorted ``lo * V + hi`` codes of stored blocks,
    ``hi`` = the variable with the larger offset) and ``block_col_base`` (per block, per column
    of the block's column variable, the data index of its first row).
    """
    V = var_dim.shape[0]
    rank = np.empty(V, dtype=np.int64)
    rank[order] = np.arange(V)
    var_offset = np.zeros(V, dtype=np.int64)
    dims_in_order = var_dim[order]
    var_offset[order] = np.concatenate([[0], np.cumsum(dims_in_order)[:-1]]) if V else []
    N = int(var_dim.sum())

    # Unique off-diagonal blocks as (column var = smaller offset, row var = larger offset).
    pi, pj = np.asarray(pairs_i, np.int64), np.asarray(pairs_j, np.int64)
    keep = pi != pj
    pi, pj = pi[keep], pj[keep]
    col_var = np.where(rank[pi] < rank[pj], pi, pj)
    row_var = np.where(rank[pi] < rank[pj], pj, pi)
    codes = np.unique(col_var * V + row_var)
    col_var, row_var = codes // V, codes % V
    # Diagonal blocks for every variable.
    all_col = np.concatenate([np.arange(V), col_var])
    all_row = np.concatenate([np.arange(V), row_var])
    # Sort blocks by (column rank, row rank): the CSC order.
    sort = np.lexsort((rank[all_row], rank[all_col]))
    all_col, all_row = all_col[sort], all_row[sort]
    indptr, indices, col_base_flat, block_start = _expand_blocks(
        V, N, var_dim, var_offset, rank, all_col, all_row)
    diag_pos = indptr[:-1].copy()  # diagonal entry is the first of each lower column
    pattern = HessianPattern(N, indptr, indices, diag_pos, var_offset, var_dim.astype(np.int64))
    block_codes = all_col * V + all_row
    srt = np.argsort(block_codes)
    lookup = {"codes": block_codes[srt], "block": srt, "block_start": block_start,
              "col_base": col_base_flat, "V": V}
    return pattern, lookup


def _expand_blocks(V, N, var_dim, var_offset, rank, blk_col, blk_row):
    """Scalar CSC (indptr, indices) from blocks sorted in CSC order, plus column bases."""
    nb = blk_col.shape[0]
    dc = var_dim[blk_col]
    dr = var_dim[blk_row]
    is_diag = blk_col == blk_row
    # rows each block contributes to each of its columns: diagonal blocks are triangular
    # col-length contributions: for column b of a diagonal block: dr - b; else dr.
    col_len = np.zeros(N, dtype=np.int64)
    # Accumulate off-diagonal contributions: every column of the column variable gets dr rows.
    off_cols = np.repeat(var_offset[blk_col[~is_diag]], dc[~is_diag]) + ranges(dc[~is_diag])
    np.add.at(col_len, off_cols, np.repeat(dr[~is_diag], dc[~is_diag]))
    diag_vars = blk_col[is_diag]
    dcols = np.repeat(var_offset[diag_vars], var_dim[diag_vars]) + ranges(var_dim[diag_vars])
    col_len[dcols] += np.repeat(var_dim[diag_vars], var_dim[diag_vars]) - ranges(var_dim[diag_vars])
    indptr = np.zeros(N + 1, dtype=np.int64)
    np.cumsum(col_len, out=indptr[1:])
    nnz = int(indptr[-1])
    indices = np.empty(nnz, dtype=np.int64)
    block_start = np.zeros(nb + 1, dtype=np.int64)
    np.cumsum(dc, out=block_start[1:])
    col_base = np.empty(int(block_start[-1]), dtype=np.int64)
    if indices.shape[0] <= 20000 and numpy_budget_left():
        # small, in a process still renting (fgopt._jit): plain Python beats numba's import
        # and cache load; its time counts towards the switch to numba
        t0 = time.perf_counter()
        _fill_indices.python(blk_col, blk_row, var_dim, var_offset, indptr, indices, block_start,
                             col_base)
        charge_numpy(time.perf_counter() - t0)
    else:
        _fill_indices(blk_col, blk_row, var_dim, var_offset, indptr, indices, block_start,
                      col_base)
    return indptr, indices, col_base, block_start


def ranges(lengths: np.ndarray) -> np.ndarray:
    """concat(arange(l) for l in lengths), vectorized."""
    lengths = np.asarray(lengths, dtype=np.int64)
    total = int(lengths.sum())
    if total == 0:
        return np.zeros(0, dtype=np.int64)
    starts = np.repeat(np.cumsum(lengths) - lengths, lengths)
    return np.arange(total, dtype=np.int64) - starts


from ._jit import (charge_numpy, is_numba_loaded, njit,  # noqa: E402  (numba kernels below)
                   numpy_budget_left)


@njit(cache=True)
def _fill_indices(blk_col, blk_row, var_dim, var_offset, indptr, indices, block_start, col_base):
    fill = indptr[:-1].copy()
    for b in range(blk_col.shape[0]):
        c, r = blk_col[b], blk_row[b]
        dc, dr = var_dim[c], var_dim[r]
        oc, orow = var_offset[c], var_offset[r]
        for cb in range(dc):
            col = oc + cb
            col_base[block_start[b] + cb] = fill[col]
            start = cb if c == r else 0
            for a in range(start, dr):
                indices[fill[col]] = orow + a
                fill[col] += 1


@njit(cache=True)
def _sym_matvec(indptr, indices, data, x):
    n = indptr.shape[0] - 1
    y = np.zeros(n)
    for j in range(n):
        xj = x[j]
        acc = 0.0
        for p in range(indptr[j], indptr[j + 1]):
            i = indices[p]
            v = data[p]
            y[i] += v * xj
            if i != j:
                acc += v * x[i]
        y[j] += acc
    return y


def scatter_positions(lookup: dict, var_rank: np.ndarray, var_idx: np.ndarray,
                      arg_dims: np.ndarray) -> np.ndarray:
    """Per-instance column bases of every stored block of a batch's local Hessian.

    ``var_idx``: ``(n, k)`` variable indices of each instance's arguments. Returns ``pos`` of shape
    ``(n, k, k, maxd)``: for pairs with ``rank[v_p] >= rank[v_q]`` the data index of the first
    row of block ``(v_p, v_q)`` in each of its columns (for ``p == q``: the diagonal's position),
    else -1.
    """
    n, k = var_idx.shape
    maxd = int(arg_dims.max()) if k else 1
    # small problems before numba is in use: the same loop as plain Python (no numba import)
    run = _scatter_positions.python if n * k * k <= 20000 and not is_numba_loaded() \
        else _scatter_positions
    return run(np.ascontiguousarray(lookup["codes"], dtype=np.int64),
               np.ascontiguousarray(lookup["block"], dtype=np.int64),
               np.ascontiguousarray(lookup["block_start"], dtype=np.int64),
               np.ascontiguousarray(lookup["col_base"], dtype=np.int64),
               int(lookup["V"]), np.ascontiguousarray(var_rank, dtype=np.int64),
               np.ascontiguousarray(var_idx, dtype=np.int64),
               np.ascontiguousarray(arg_dims, dtype=np.int64), maxd)


@njit(cache=True)
def _scatter_positions(codes, block, block_start, col_base, V, var_rank, var_idx, arg_dims,
                       maxd):
    # one pass per instance (a numpy pass per argument pair cost ~k^2 Python steps per batch:
    # 30 ms of set-up for 1500 smart factors of up to 10 poses)
    n, k = var_idx.shape
    pos = np.full((n, k, k, maxd), -1, dtype=np.int64)
    for i in range(n):
        for p in range(k):
            vp = var_idx[i, p]
            for q in range(k):
                vq = var_idx[i, q]
                if var_rank[vp] < var_rank[vq] or (p != q and vp == vq):
                    continue
                at = np.searchsorted(codes, vq * V + vp)
                start = block_start[block[at]]
                for c in range(arg_dims[q]):
                    pos[i, p, q, c] = col_base[start + c]
    return pos
