"""Block-aware supernodal Cholesky in numba (``linear_solver="block"``).

H's pattern is a block pattern (every coupled pair of variables stores a dense block), so all
symbolic work runs on the *variable* graph, which is 3-9x smaller than the scalar one:

* ``analyze`` (once): block elimination tree, postorder (heaviest child last), block column
  structures, fundamental supernodes plus CHOLMOD-style relaxed amalgamation, each supernode's
  row variables; then index maps so that ``factorize`` is pure array work: where every entry of
  H's data lands in the factor's panels, and, for every supernode, runs of rows along which its
  update is subtracted from its ancestors' panels.
* ``factorize`` (each iteration, one numba call): right-looking supernodal Cholesky. A panel is
  factored (LAPACK ``dpotrf`` + ``dtrsm``, or a fused numba loop when narrow), its whole update
  ``B B^T`` is formed by one ``dsyrk`` (+ ``dgemm`` per column chunk) and scattered straight into
  the ancestors' panels. A pivot not above ``pivot_tolerance`` times its diagonal entry of H
  raises :class:`NotPositiveDefiniteError` naming the variable (:func:`.base.pivot_failure`).
* ``solve``: forward / backward substitution by supernodes (numba), one or many right-hand sides.

Variables are permuted internally (etree postorder of the pattern's own order: same fill); the
permutation is applied inside ``solve``. Kernels: ``_block_kernels.py``; symbolic steps:
``_block_symbolic.py``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...errors import DimensionMismatchError, FgoptError, NotPositiveDefiniteError
from ...structure import HessianPattern
from . import _block_symbolic as sym
from .base import PIVOT_TOLERANCE, pivot_failure

# CHOLMOD-like relaxed amalgamation: (max merged width in scalar columns, max zero fraction)
DEFAULT_RELAX = ((4, 1.0), (16, 0.8), (48, 0.1), (1 << 62, 0.05))


@dataclass(eq=False)
class BlockSymbolic:
    n_var: int
    post_var: np.ndarray     # (V,) pattern variable of each postorder position
    dim: np.ndarray          # (V,) dims in postorder
    off: np.ndarray          # (V,) scalar offsets in postorder
    sn: np.ndarray           # (S+1,) first variable of each supernode
    rvp: np.ndarray          # (S+1,) CSR of supernode row variables
    rvi: np.ndarray
    rpos: np.ndarray         # scalar row offset of each row variable in its panel
    width: np.ndarray        # (S,) scalar columns
    rows: np.ndarray         # (S,) scalar rows (incl. the diagonal block)
    pstart: np.ndarray       # (S+1,) panel start in the factor's data array
    sparent: np.ndarray      # (S,) parent supernode (-1: root)


def analyze_blocks(pattern: HessianPattern, relax=DEFAULT_RELAX) -> BlockSymbolic:
    """Block elimination tree, postorder, column structures, relaxed supernodes and their row
    variables of ``pattern`` (one numba call: :func:`_block_symbolic.analyze_pattern`)."""
    var_offset = np.asarray(pattern.var_offset, np.int64)
    V = var_offset.shape[0]
    if V == 0 or pattern.size == 0:
        raise FgoptError("block Cholesky: the pattern has no variables")
    rc = np.array([r[0] for r in relax], np.int64)
    rz = np.array([r[1] for r in relax], np.float64)
    (post_var, dim_p, off_p, sn, rvp, rvi, rpos, width, rows, pstart,
     sparent) = sym.analyze_pattern(np.asarray(pattern.block_codes, np.int64), V,
                                    np.asarray(pattern.order, np.int64), var_offset,
                                    np.asarray(pattern.var_dim, np.int64), rc, rz)
    return BlockSymbolic(V, post_var, dim_p, off_p, sn, rvp, rvi, rpos, width, rows, pstart,
                         sparent)


def analyze_dense(pattern: HessianPattern) -> BlockSymbolic:
    """One supernode holding every variable in the pattern's order: a dense factor, no
    symbolic analysis (what a small system wants; see ``BlockCholeskySolver(dense=True)``)."""
    var_offset = np.asarray(pattern.var_offset, np.int64)
    V, n = var_offset.shape[0], int(pattern.size)
    if V == 0 or n == 0:
        raise FgoptError("block Cholesky: the pattern has no variables")
    vorder = np.argsort(var_offset, kind="stable")
    one = np.array([0, V], np.int64)
    return BlockSymbolic(V, vorder, np.asarray(pattern.var_dim, np.int64)[vorder],
                         var_offset[vorder], one, one.copy(), np.arange(V, dtype=np.int64),
                         var_offset[vorder], np.array([n], np.int64), np.array([n], np.int64),
                         np.array([0, n * n], np.int64), np.array([-1], np.int64))


class BlockCholeskySolver:
    """Supernodal Cholesky on the variable-block structure of H (numba + BLAS).

    Kernel choice by panel width ``w`` (scalar columns): the panel is factored by numba loops
    if ``w <= small_panel``, by register tiles if ``w <= tile_panel``, else by LAPACK ``dpotrf``
    + ``dtrsm``; its update is formed by register tiles if ``w <= small_syrk``, else by
    ``dsyrk`` / ``dgemm`` (BLAS call overhead dominates for narrow panels). ``chunk``: the
    update of a supernode is formed and scattered in column chunks of about this many columns
    (bounds the workspace). ``relax``: relaxed amalgamation thresholds ``((max width, max zero
    fraction), ...)``, CHOLMOD's by default.
    """

    name = "block"

    def __init__(self, small_panel: int = 8, tile_panel: int = 192, small_syrk: int = 96,
                 chunk: int = 512, relax=DEFAULT_RELAX, dense: bool = False,
                 pivot_tolerance: float = PIVOT_TOLERANCE):
        #: A pivot must exceed this times its diagonal entry of H (:data:`.base.PIVOT_TOLERANCE`).
        self.pivot_tolerance = float(pivot_tolerance)
        #: One supernode for the whole system (:func:`analyze_dense`): small systems.
        self.dense = bool(dense)
        self.tile_panel = int(tile_panel)
        self.chunk = int(chunk)
        self.small_panel = int(small_panel)
        self.small_syrk = int(small_syrk)
        self.relax = relax
        self.symbolic: BlockSymbolic | None = None
        self._ok = False
        self._sigma: np.ndarray | None = None  # selected inverse of the current factor

    def analyze(self, pattern: HessianPattern) -> None:
        from . import _block_kernels as k

        sy = analyze_dense(pattern) if self.dense else analyze_blocks(pattern, self.relax)
        self.symbolic = sy
        self._var_offset, self._var_dim = pattern.var_offset, pattern.var_dim
        self._diag0 = np.empty(int(pattern.size))   # H's diagonal in the factor's order
        sn_of, self._perm, new_var, self._col0, self._rix_ptr, self._rix = sym.factor_layout(
            sy.post_var, sy.dim, sy.off, sy.sn, sy.rvi, sy.rows,
            np.asarray(pattern.var_offset, np.int64), int(pattern.size))
        self._maps = sym.build_maps(sy.sn, sy.rvp, sy.rvi, sy.rpos, sy.dim, sy.off, sy.pstart,
                                    sy.rows, sy.width)
        # int32 positions when the factor's panels have fewer than 2^31 entries (H-sized: 4
        # bytes per entry of H saved)
        self._hmap = np.empty(pattern.nnz, np.int32 if sy.pstart[-1] < 2**31 - 16 else np.int64)
        sym.build_hmap_blocks(pattern.block_codes, sy.n_var, pattern.order, pattern.block_p00,
                              pattern.col_shift, np.asarray(pattern.var_offset, np.int64),
                              np.asarray(pattern.var_dim, np.int64), new_var, sn_of, sy.off,
                              sy.sn, sy.rvp, sy.rvi, sy.rpos, sy.pstart, sy.rows, self._hmap)
        self.L = np.zeros(int(sy.pstart[-1]) + 16)   # tail padding: register tiles read past
        r = sy.rows - sy.width
        # update chunks: at most r x (chunk + widest variable) doubles, plus the tiles' padding
        cols = np.minimum(r, self.chunk + sy.dim.max(initial=1)) + 4
        self._C = np.zeros(max(64, int(((r + 8) * cols).max(initial=0))))
        self._buf = np.zeros(max(1, int(r.max(initial=0))))
        self._iw, self._fw = k.blas_workspace()
        self._ok = False
        self._sigma = None

    @property
    def nnz_factor(self) -> int:
        """Stored entries of L (lower trapezoids of the panels, explicit zeros included)."""
        w, m = self.symbolic.width, self.symbolic.rows
        return int((w * m - w * (w - 1) // 2).sum())

    def factorize(self, H_data: np.ndarray) -> None:
        from . import _block_kernels as k

        sy = self.symbolic
        if sy is None:
            raise FgoptError("block Cholesky: call analyze(pattern) before factorize()")
        self._ok = False
        H_data = np.ascontiguousarray(H_data, dtype=np.float64)
        if H_data.shape != self._hmap.shape:
            raise DimensionMismatchError(
                f"block Cholesky: H has {H_data.shape} entries, the analyzed pattern "
                f"{self._hmap.shape[0]}")
        fail = k.factorize(H_data, self._hmap, self.L,
                           self._C, sy.pstart, sy.width, sy.rows, *self._maps, self._iw,
                           self._fw, self.small_panel, self.tile_panel,
                           self.small_syrk, self.chunk, self._diag0, self.pivot_tolerance)
        if fail >= 0:
            at = int(np.searchsorted(sy.off, fail, side="right")) - 1   # postorder variable
            v = int(sy.post_var[at])
            raise pivot_failure("block Cholesky", self._var_offset, self._var_dim,
                                int(self._var_offset[v] + fail - sy.off[at]),
                                self.pivot_tolerance)
        self._ok = True
        self._sigma = None

    def covariance_blocks(self, var_idx: np.ndarray, dims: np.ndarray,
                          loc: np.ndarray | None = None) -> np.ndarray:
        """``(c, D, D)``: the block of ``H^-1`` over each row of ``var_idx`` (``(c, k)`` pattern
        variables of dimensions ``dims``; variable ``p`` at rows / columns ``loc[p]:loc[p] +
        dims[p]``, by default one after the other, ``D = sum(dims)``), read from the selected
        inverse (:mod:`._selected_inverse`; computed once per factorization). Every pair of a
        row must be coupled in H (as a factor's variables are)."""
        from . import _selected_inverse as si

        if not self._ok:
            raise NotPositiveDefiniteError("block Cholesky: covariance_blocks() before a "
                                           "successful factorize()")
        sy = self.symbolic
        if self._sigma is None:
            S = sy.sn.shape[0] - 1
            self._sn_of = np.repeat(np.arange(S, dtype=np.int64), np.diff(sy.sn))
            self._ipost = np.empty(sy.n_var, np.int64)
            self._ipost[sy.post_var] = np.arange(sy.n_var)
            sigma = np.zeros_like(self.L)
            bad = si.selected_inverse(self.L, sy.pstart, sy.width, sy.rows, sy.sn, sy.rvp,
                                      sy.rvi, sy.rpos, sy.dim, sy.off, self._sn_of, sigma)
            if bad >= 0:
                raise FgoptError(f"block Cholesky: selected inverse: supernode {bad} misses an "
                                 "ancestor block (inconsistent symbolic factor)")
            self._sigma = sigma
        dims = np.asarray(dims, np.int64)
        if loc is None:
            loc = np.concatenate([[0], np.cumsum(dims)[:-1]])
        loc = np.asarray(loc, np.int64)
        var_p = np.ascontiguousarray(self._ipost[np.asarray(var_idx, np.int64)])
        out = np.empty((var_p.shape[0], int(dims.sum()), int(dims.sum())))
        bad = si.factor_covariances(self._sigma, sy.pstart, sy.rows, sy.sn, self._sn_of,
                                    sy.off, sy.rvp, sy.rvi, sy.rpos, sy.dim, var_p, loc, out)
        if bad >= 0:
            raise FgoptError("block Cholesky: covariance_blocks: variables "
                             f"{var_idx[bad].tolist()} are not coupled in H (not on the "
                             "factor's pattern)")
        return out

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        from . import _block_kernels as k

        if not self._ok:
            raise NotPositiveDefiniteError("block Cholesky: solve() before a successful "
                                           "factorize()")
        sy = self.symbolic
        b = np.asarray(rhs, dtype=np.float64)
        if b.ndim not in (1, 2) or b.shape[0] != self._perm.shape[0]:
            raise DimensionMismatchError(
                f"block Cholesky: rhs has shape {b.shape}, H is {self._perm.shape[0]} square")
        if b.ndim == 1:
            x = b[self._perm]
            k.solve_inplace(self.L, x, sy.pstart, sy.width, sy.rows, self._col0, self._rix_ptr,
                            self._rix, self._buf)
            out = np.empty_like(x)
            out[self._perm] = x
            return out
        cols = b.reshape(b.shape[0], -1)
        nrhs = cols.shape[1]
        X = np.ascontiguousarray(cols[self._perm])
        buf = np.empty(max(1, self._buf.shape[0]) * nrhs)
        k.solve_multi_inplace(self.L, X.reshape(-1), nrhs, sy.pstart, sy.width, sy.rows,
                              self._col0, self._rix_ptr, self._rix, buf, np.empty(nrhs))
        out = np.empty_like(X)
        out[self._perm] = X
        return out.reshape(b.shape)
