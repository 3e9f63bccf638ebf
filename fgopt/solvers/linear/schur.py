"""Schur-complement linear solver for problems with many small independent blocks (BA points).

The eliminated variables ``E`` (by default the manifold kind with the most variables, if no
factor couples two of them: the 3D points of bundle adjustment) have block-diagonal ``H_EE``.
Writing H and the right-hand side as ``[[A, B], [B^T, C]]`` and ``[r_F, r_E]``::

    S = A - B C^-1 B^T            (the reduced camera system)
    S x_F = r_F - B C^-1 r_E,     x_E = C^-1 (r_E - B^T x_F)

``analyze`` does all symbolic work once: which variables to eliminate, where every point block
``C_e`` and camera-point block ``B_k`` sit in H's data array, the sparsity pattern of S and a
scatter map from every (point, camera, camera) triple to S's data. ``factorize`` runs one numba
pass (invert each ``C_e``, form ``W_k = B_k C_e^-1``, subtract ``W_k B_l^T`` from S) and factors
S; ``solve`` reduces the rhs, solves S and back-substitutes.

The reduced system is solved by ``reduced=``

* ``"dense"``: LAPACK Cholesky of S (column-major, lower) -- fastest for up to ~1000 unknowns
  (Ladybug-49: 441), as Ceres' DENSE_SCHUR;
* ``"sparse"``: CHOLMOD supernodal on S in a fill-reducing order of the camera graph (SPARSE_SCHUR);
* ``"pcg"``: conjugate gradients on S with the Schur-Jacobi preconditioner (block diagonal of S),
  as Ceres' ITERATIVE_SCHUR, for problems whose S is too large to factor. S is applied from its
  packed blocks when their number is moderate (``pcg_explicit``), else implicitly as
  ``A x - B C^-1 B^T x`` (S never formed: memory ~ observations);
* ``"auto"``: dense up to ``dense_max`` unknowns in S (or a nearly full S), PCG from ``pcg_min``
  on, else sparse.

Names for :func:`fgopt.solvers.make_linear_solver`: ``"schur"`` (auto), ``"schur_dense"``,
``"schur_sparse"``, ``"schur_pcg"``. :func:`choose_linear_solver` answers whether a pattern is
BA-shaped (and returns the solver if so).
"""

from __future__ import annotations

import time

import numpy as np

from ...errors import FgoptError, NotPositiveDefiniteError
from ...structure import (HessianPattern, _sym_matvec, build_pattern, fill_reducing_order,
                          kinds_by_count)
from . import _schur_kernels as K
from . import _schur_layout as L
from .base import PIVOT_TOLERANCE, pivot_failure
from ._schur_layout import is_ba_shaped as is_ba_shaped

REDUCED = ("auto", "dense", "sparse", "pcg")
TIMING_KEYS = ("eliminate", "factor_S", "reduce_rhs", "solve_S", "back_substitute")


class SchurSolver:
    """``SchurSolver(reduced="auto", eliminate=None, ...)``; see the module docstring.

    Args:
        reduced: how to solve S: ``"auto" | "dense" | "sparse" | "pcg"``.
        eliminate: which variables to eliminate: ``None`` (the largest independent kind), a kind
            name (``"R3"``), or a boolean mask / index array over the pattern's variables. The set
            must be independent (no block of H couples two of its variables).
        dense_max: ``"auto"`` picks the dense Cholesky of S up to this many unknowns (and up to
            4x more when at least half of S's blocks are nonzero), PCG from ``pcg_min`` unknowns
            on, CHOLMOD in between. Measured (CPU, factorize): 900 unknowns full S dense 24 ms /
            sparse 26; 1350 banded 39 / 27; 2700 full 252 / 279; 2700 banded 197 / 68.
        ordering: fill-reducing order of the camera graph for ``"sparse"`` (``amd | metis | ...``).
        pcg_rtol, pcg_max_iterations: PCG stops when ``|r| <= pcg_rtol |b|`` or after
            ``pcg_max_iterations`` (Ceres' ITERATIVE_SCHUR defaults: 0.1 and 500; LM tolerates
            inexact steps -- Ladybug-49 reaches Ceres' cost in 33 instead of 30 iterations).
        pcg_explicit: apply S from its packed blocks (True), implicitly (False) or decide by the
            number of (point, camera, camera) triples (None: explicit up to ``20e6``).
    """

    def __init__(self, reduced: str = "auto", eliminate=None, dense_max: int = 1000,
                 pcg_min: int = 100_000, ordering: str = "amd", pcg_rtol: float = 0.1,
                 pcg_max_iterations: int = 500, pcg_explicit: bool | None = None):
        if reduced not in REDUCED:
            raise FgoptError(f"SchurSolver: unknown reduced={reduced!r}; choose one of "
                             f"{', '.join(REDUCED)}")
        self.reduced = reduced
        self.eliminate = eliminate
        self.dense_max = int(dense_max)
        self.pcg_min = int(pcg_min)
        self.ordering = ordering
        self.pcg_rtol = float(pcg_rtol)
        self.pcg_max_iterations = int(pcg_max_iterations)
        self.pcg_explicit = pcg_explicit
        self.name = "schur" if reduced == "auto" else f"schur_{reduced}"
        self.mode: str | None = None       # the resolved reduced-system solver
        self.last_pcg_iterations = 0
        self.timing = dict.fromkeys(TIMING_KEYS, 0.0)  # seconds, accumulated over calls
        self.clock = time.perf_counter  # profilers may set time.process_time

    # ------------------------------------------------------------------ analyze
    def analyze(self, pattern: HessianPattern) -> None:
        self._pattern = pattern
        var_off, var_dim = pattern.var_offset, pattern.var_dim
        blk = L.blocks(pattern)
        is_e = eliminated_mask(pattern, self.eliminate, blk)
        ed = L.edges(pattern, is_e, blk)
        e_vars, f_vars = ed["e_vars"], ed["f_vars"]
        nE, nF = e_vars.shape[0], f_vars.shape[0]
        f_dim = var_dim[f_vars].astype(np.int64)
        e_dim = var_dim[e_vars].astype(np.int64)
        edge_e, edge_f, ff_i, ff_j = ed["edge_e"], ed["edge_f"], ed["ff_i"], ed["ff_j"]
        edge_ptr = np.zeros(nE + 1, dtype=np.int64)
        np.cumsum(np.bincount(edge_e, minlength=nE), out=edge_ptr[1:])
        nS = int(f_dim.sum())
        mode, co = self.reduced, None
        if mode in ("auto", "sparse") and nF > 2 and nS < self.pcg_min:
            co = L.co_observation_pairs(edge_ptr, edge_f[np.argsort(edge_e, kind="stable")], nF)
        if mode == "auto":  # measured: dense wins up to ~1000 unknowns, or when S is full
            full = co is not None and len(co[0]) + len(ff_i) >= 0.5 * nF * (nF - 1) / 2
            mode = ("dense" if nS <= self.dense_max or (full and nS <= 4 * self.dense_max)
                    else "pcg" if nS >= self.pcg_min else "sparse")
        self.mode = mode
        if mode == "sparse" and co is not None:  # fill-reducing order of the camera graph
            order = fill_reducing_order(nF, np.concatenate([co[0], ff_i]),
                                        np.concatenate([co[1], ff_j]), self.ordering)
        else:
            order = np.arange(nF)
        f_rank = np.empty(nF, dtype=np.int64)
        f_rank[order] = np.arange(nF)
        # edges sorted by (e, rank of f): then pairs (ki >= kj) have rank(f_ki) >= rank(f_kj)
        srt = np.argsort(edge_e * max(nF, 1) + f_rank[edge_f])  # one sort of distinct codes
        edge_e, edge_f = edge_e[srt], np.ascontiguousarray(edge_f[srt])
        self._edge_ptr, self._edge_f = edge_ptr, edge_f
        self._e_off, self._e_dim = var_off[e_vars].astype(np.int64), e_dim
        self._e_vars = e_vars
        self._f_hoff, self._f_dim = var_off[f_vars].astype(np.int64), f_dim
        self._c_ptr = np.concatenate([[0], np.cumsum(e_dim * e_dim)]).astype(np.int64)
        self._Cinv = np.empty(int(self._c_ptr[-1]))
        self._block_access(pattern, edge_e, ed["edge_p00"][srt], ed["edge_orient"][srt])
        del ed
        w_size = np.bincount(edge_e, weights=f_dim[edge_f], minlength=nE) * e_dim
        self._W = np.empty(int(w_size.max(initial=1)))  # one e's W_k = B_k C_e^-1 (scratch)
        self._fast = bool(nE and np.all(e_dim == 3) and np.all(f_dim[edge_f] == 9))
        f_soff = np.zeros(nF, dtype=np.int64)  # offsets in S (rank order)
        f_soff[order] = np.concatenate([[0], np.cumsum(f_dim[order])[:-1]]) if nF else []
        self._f_soff, self._nS = f_soff, nS
        self._s_to_h = (np.repeat(self._f_hoff[order], f_dim[order])
                        + L.ranges(f_dim[order]))  # H index of each S scalar
        self._a_src, a_row, a_col = L.a_entries(pattern, self._s_to_h)
        k = np.diff(edge_ptr)
        self._explicit = mode != "pcg" or (
            self.pcg_explicit if self.pcg_explicit is not None
            else int(np.sum(k * (k + 1) // 2)) <= 20_000_000)
        if self._explicit:
            if co is None:
                co = L.co_observation_pairs(edge_ptr, edge_f, nF)
            self._analyze_packed(mode, nF, f_dim, order, f_rank, co, ff_i, ff_j, a_row, a_col)
        else:
            self._analyze_implicit(nF, f_dim, order, ff_i, ff_j, a_row, a_col)
        if mode == "pcg":
            self._dg_ptr = np.concatenate([[0], np.cumsum(f_dim * f_dim)]).astype(np.int64)
            self._Dg = np.zeros(int(self._dg_ptr[-1]))
            self._Minv = np.zeros(int(self._dg_ptr[-1]))

    def _block_access(self, pattern, edge_e, edge_p00, edge_orient) -> None:
        """How the kernels read ``B_k`` (see :mod:`._schur_kernels`): from H itself when every
        block lies in its eliminated variable's columns (the Schur layout), else from a copy
        with the same addressing, refreshed at each factorization."""
        if not np.any(edge_orient):
            self._bbase, self._bshift, self._gather = np.ascontiguousarray(edge_p00), \
                pattern.col_shift, None
            return
        nE, e_dim, f_dim = self._e_off.shape[0], self._e_dim, self._f_dim
        df = f_dim[self._edge_f]
        rows = np.bincount(edge_e, weights=df, minlength=nE).astype(np.int64)  # per e: sum df
        start = np.concatenate([[0], np.cumsum(rows * e_dim)[:-1]]).astype(np.int64)
        cum = np.concatenate([[0], np.cumsum(df)[:-1]]).astype(np.int64)
        self._bbase = start[edge_e] + cum - cum[self._edge_ptr[edge_e]]
        self._bshift = np.zeros(pattern.size, dtype=np.int64)
        cols = np.repeat(self._e_off, e_dim) + L.ranges(e_dim)
        self._bshift[cols] = L.ranges(e_dim) * np.repeat(rows, e_dim)
        self._gather = (np.ascontiguousarray(edge_p00), np.ascontiguousarray(edge_orient),
                        np.empty(int(np.sum(rows * e_dim))))

    def _analyze_packed(self, mode, nF, f_dim, order, f_rank, co, ff_i, ff_j, a_row, a_col):
        """S accumulated in a packed block store (contiguous blocks: ~2x faster than writing
        into the dense / CSC matrix), then copied (lower entries) into the factored matrix."""
        pk = L.packed_blocks(nF, f_dim, self._f_soff, f_rank, self._edge_ptr, self._edge_f,
                             co[0], co[1], ff_i, ff_j, a_row, a_col)
        self._pair_ptr, self._pair_blk = pk["pair_ptr"], pk["pair_blk"]
        self._blk_ptr, self._blk_base, self._a_dst = pk["blk_ptr"], pk["blk_base"], pk["a_dst"]
        self._packed = np.zeros(int(pk["pk_off"][-1]))
        self._pk_src = pk["pk_src"]
        srow, scol, nS = pk["srow"], pk["scol"], self._nS
        if mode == "dense":
            self._pk_dst = scol * nS + srow
            self._S = np.zeros((nS, nS), order="F")
            self._S_flat = self._S.reshape(-1, order="F")  # a view (Fortran-contiguous)
        elif mode == "sparse":
            from ...errors import have_extra
            from .block_cholesky import BlockCholeskySolver
            from .cholmod import CholmodSolver

            all_i = np.concatenate([pk["ci"], pk["fi"]])
            all_j = np.concatenate([pk["cj"], pk["fj"]])
            keep = all_i != all_j
            spat, _ = build_pattern(f_dim, order, all_i[keep], all_j[keep])
            self._pk_dst = L.csc_positions(spat, srow, scol)
            if self._pk_dst.shape[0] != spat.nnz:
                raise AssertionError("Schur: packed blocks do not cover the reduced pattern")
            self._S_flat = np.zeros(spat.nnz)
            # CHOLMOD when the fgopt[cholmod] extra is installed, else fgopt's block Cholesky
            self._chol = (CholmodSolver(mode="supernodal", ordering_method="natural")
                          if have_extra("sksparse") else BlockCholeskySolver())
            self._chol.analyze(spat)
        else:  # explicit PCG: products with the packed blocks
            br, bc, pk_off = pk["br"], pk["bc"], pk["pk_off"]
            self._pk_off = pk_off
            self._blk_roff, self._blk_coff = self._f_soff[br], self._f_soff[bc]
            self._blk_dr, self._blk_dc = f_dim[br], f_dim[bc]
            self._diag_blk = np.nonzero(br == bc)[0][np.argsort(br[br == bc])]

    def _analyze_implicit(self, nF, f_dim, order, ff_i, ff_j, a_row, a_col):
        self._pair_ptr = np.zeros(self._edge_ptr.shape[0], dtype=np.int64)
        self._pair_blk = np.zeros(0, dtype=np.int32)
        self._blk_ptr = np.zeros(1, dtype=np.int64)
        self._blk_base = np.zeros(0, dtype=np.int64)
        keep = ff_i != ff_j
        apat, _ = build_pattern(f_dim, order, ff_i[keep], ff_j[keep])
        self._apattern = apat
        self._a_dst = L.csc_positions(apat, a_row, a_col)
        self._A = np.zeros(apat.nnz)
        d = f_dim
        f = np.repeat(np.arange(nF), d * d)  # full diagonal blocks of A (row-major) -> A data
        loc = L.ranges(d * d)
        sr, sc = self._f_soff[f] + loc // d[f], self._f_soff[f] + loc % d[f]
        self._dg_src = L.csc_positions(apat, np.maximum(sr, sc), np.minimum(sr, sc))

    # ------------------------------------------------------------------ factorize / solve
    def factorize(self, H_data: np.ndarray) -> None:
        t0 = self.clock()
        S = self._packed if self._explicit else self._A
        S[:] = 0.0
        H_data = np.ascontiguousarray(H_data, dtype=np.float64)
        S[self._a_dst] = H_data[self._a_src]
        if self._gather is None:
            X = H_data  # the blocks are read in place: keep H until the solve
        else:
            p00, orient, X = self._gather
            K.gather_blocks(H_data, self._pattern.col_shift, self._e_off, self._e_dim,
                            self._edge_ptr, self._edge_f, self._f_hoff, self._f_dim, p00, orient,
                            self._bbase, self._bshift, X)
        self._X = X
        if self._fast:
            bad = K.eliminate_e3f9(
                H_data, self._pattern.indptr, self._e_off, self._c_ptr, self._edge_ptr, X,
                self._bbase, self._bshift, self._pair_ptr, self._pair_blk, self._blk_ptr,
                self._blk_base, self._Cinv, self._W, S, self._explicit)
        else:
            bad = K.eliminate(
                H_data, self._pattern.indptr, self._e_off, self._e_dim, self._c_ptr,
                self._edge_ptr, self._edge_f, self._f_dim, X, self._bbase, self._bshift,
                self._pair_ptr, self._pair_blk, self._blk_ptr, self._blk_base, self._Cinv,
                self._W, S, self._explicit)
        if bad >= 0:
            v = int(self._e_vars[bad])
            raise NotPositiveDefiniteError(
                f"Schur: the diagonal block of eliminated variable #{v} is not positive "
                "definite (a point seen too few times / too little damping)", variable=v)
        t1 = self.clock()
        self.timing["eliminate"] += t1 - t0
        try:
            self._factor_reduced()
        finally:
            self.timing["factor_S"] += self.clock() - t1

    def _factor_reduced(self) -> None:
        if self.mode == "dense":
            if self._nS:
                self._S_flat[:] = 0.0
                self._S_flat[self._pk_dst] = self._packed[self._pk_src]
                # in place (Fortran-contiguous float64); keep the returned array to be safe
                from scipy.linalg import lapack  # here: scipy.linalg costs ~0.1 s to import

                d0 = self._S.diagonal().copy()
                self._L, info = lapack.dpotrf(self._S, lower=1, clean=0, overwrite_a=1)
                if info < 0:
                    raise FgoptError(f"Schur: LAPACK dpotrf info={info}")
                d = self._L.diagonal()
                ok = d * d > PIVOT_TOLERANCE * d0   # (NaN fails)
                if info > 0 or not np.all(ok):
                    bad = info - 1 if info > 0 else int(np.argmin(ok))
                    raise pivot_failure("Schur (reduced system)", self._pattern.var_offset,
                                        self._pattern.var_dim, int(self._s_to_h[bad]))
        elif self.mode == "sparse":
            self._S_flat[self._pk_dst] = self._packed[self._pk_src]
            self._chol.factorize(self._S_flat)
        else:
            if self._explicit:
                K.diagonal_blocks(self._packed, self._pk_off, self._diag_blk, self._f_dim,
                                  self._dg_ptr, self._Dg)
            else:
                self._Dg[:] = self._A[self._dg_src]
                K.schur_block_diagonal(self._Dg, self._dg_ptr, self._e_off, self._e_dim,
                                       self._c_ptr, self._Cinv, self._edge_ptr, self._edge_f,
                                       self._f_dim, self._X, self._bbase, self._bshift)
            bad = K.invert_blocks(self._Dg, self._dg_ptr, self._f_dim, self._Minv)
            if bad >= 0:
                raise NotPositiveDefiniteError(
                    f"Schur-PCG: block {bad} of the reduced system's diagonal is not positive "
                    "definite")

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        t0 = self.clock()
        rhs = np.ascontiguousarray(rhs, dtype=np.float64)
        rS = rhs[self._s_to_h]
        K.reduce_rhs(rhs, rS, self._e_off, self._e_dim, self._c_ptr, self._Cinv,
                     self._edge_ptr, self._edge_f, self._f_soff, self._f_dim, self._X,
                     self._bbase, self._bshift)
        t1 = self.clock()
        if self._nS == 0:
            xS = rS
        elif self.mode == "dense":
            from scipy.linalg import lapack

            xS, info = lapack.dpotrs(self._L, rS, lower=1)
            if info != 0:
                raise FgoptError(f"Schur: LAPACK dpotrs failed (info={info})")
        elif self.mode == "sparse":
            xS = self._chol.solve(rS)
        else:
            xS = self._pcg(rS)
        t2 = self.clock()
        x = np.empty(self._pattern.size)
        x[self._s_to_h] = xS
        K.back_substitute(rhs, xS, x, self._e_off, self._e_dim, self._c_ptr, self._Cinv,
                          self._edge_ptr, self._edge_f, self._f_soff, self._f_dim, self._X,
                          self._bbase, self._bshift)
        tm = self.timing
        tm["reduce_rhs"] += t1 - t0
        tm["solve_S"] += t2 - t1
        tm["back_substitute"] += self.clock() - t2
        return x

    def _schur_matvec(self, x: np.ndarray) -> np.ndarray:
        out = np.empty_like(x)
        if self._explicit:
            K.packed_matvec(self._packed, self._pk_off, self._blk_roff, self._blk_coff,
                            self._blk_dr, self._blk_dc, x, out)
            return out
        ap = self._apattern
        out = _sym_matvec(ap.indptr, ap.indices, self._A, x)
        K.implicit_schur_matvec(x, out, self._e_off, self._e_dim, self._c_ptr, self._Cinv,
                                self._edge_ptr, self._edge_f, self._f_soff, self._f_dim,
                                self._X, self._bbase, self._bshift)
        return out

    def _precondition(self, r: np.ndarray) -> np.ndarray:
        z = np.empty_like(r)
        K.apply_blocks(self._Minv, self._dg_ptr, self._f_soff, self._f_dim, r, z)
        return z

    def _pcg(self, b: np.ndarray) -> np.ndarray:
        x = np.zeros_like(b)
        bn = float(np.linalg.norm(b))
        self.last_pcg_iterations = 0
        if bn == 0.0:
            return x
        r = b.copy()
        z = self._precondition(r)
        p = z.copy()
        rz = float(r @ z)
        tol = self.pcg_rtol * bn
        maxit = self.pcg_max_iterations
        for it in range(1, maxit + 1):
            q = self._schur_matvec(p)
            pq = float(p @ q)
            if not pq > 0.0:
                raise NotPositiveDefiniteError("Schur-PCG: the reduced system is not positive "
                                               "definite (p^T S p <= 0)")
            alpha = rz / pq
            x += alpha * p
            r -= alpha * q
            self.last_pcg_iterations = it
            if float(np.linalg.norm(r)) <= tol:
                break
            z = self._precondition(r)
            rz_new = float(r @ z)
            p *= rz_new / rz
            p += z
            rz = rz_new
        return x


# ---------------------------------------------------------------------- helpers
def eliminated_mask(pattern: HessianPattern, eliminate=None, blk=None) -> np.ndarray:
    """Boolean mask over the pattern's variables of the set to eliminate (not checked here)."""
    V = pattern.var_offset.shape[0]
    if eliminate is None:
        kinds = pattern.var_kind
        if kinds is None:
            raise FgoptError("SchurSolver: the pattern carries no variable kinds; pass "
                             "eliminate=<boolean mask or variable indices>")
        known = pattern.independent_kinds
        for kid in kinds_by_count(np.asarray(kinds)):
            mask = kinds == kid
            if kid in known if known is not None else L.is_independent(pattern, mask, blk):
                return mask
        raise FgoptError("SchurSolver: no variable kind is independent (every kind has two "
                         "variables coupled by a factor): nothing to eliminate")
    if isinstance(eliminate, str):
        if eliminate not in pattern.kind_names:
            raise FgoptError(f"SchurSolver: eliminate={eliminate!r} is not a variable kind of "
                             f"this problem ({', '.join(pattern.kind_names)})")
        return np.asarray(pattern.var_kind) == pattern.kind_names.index(eliminate)
    arr = np.asarray(eliminate)
    if arr.dtype == bool:
        if arr.shape != (V,):
            raise FgoptError(f"SchurSolver: eliminate mask has shape {arr.shape}, expected ({V},)")
        return arr.copy()
    mask = np.zeros(V, dtype=bool)
    mask[arr.astype(np.int64)] = True
    return mask


def choose_linear_solver(pattern: HessianPattern) -> SchurSolver | None:
    """A :class:`SchurSolver` (``reduced="auto"``) for BA-shaped problems
    (:func:`is_ba_shaped`), else None."""
    return SchurSolver() if is_ba_shaped(pattern) else None
