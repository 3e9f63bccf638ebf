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
* ``"pcg"``: conjugate gradients on S applied implicitly (``A x - B C^-1 B^T x``, S is never
  formed) with the Schur-Jacobi preconditioner (block diagonal of S), as Ceres' ITERATIVE_SCHUR:
  for problems whose S is too large to factor;
* ``"auto"``: dense up to ``dense_max`` unknowns in S, PCG from ``pcg_min`` on, else sparse.

Names for :func:`fgopt.solvers.make_linear_solver`: ``"schur"`` (auto), ``"schur_dense"``,
``"schur_sparse"``, ``"schur_pcg"``. :func:`choose_linear_solver` answers whether a pattern is
BA-shaped (and returns the solver if so).
"""

from __future__ import annotations

import time

import numpy as np
from scipy.linalg import lapack

from ...errors import FgoptError, NotPositiveDefiniteError
from ...structure import HessianPattern, _sym_matvec, build_pattern, fill_reducing_order
from . import _schur_kernels as K

REDUCED = ("auto", "dense", "sparse", "pcg")
TIMING_KEYS = ("eliminate", "factor_S", "reduce_rhs", "solve_S", "back_substitute")


class SchurSolver:
    """``SchurSolver(reduced="auto", eliminate=None, ...)``; see the module docstring.

    Args:
        reduced: how to solve S: ``"auto" | "dense" | "sparse" | "pcg"``.
        eliminate: which variables to eliminate: ``None`` (the largest independent kind), a kind
            name (``"R3"``), or a boolean mask / index array over the pattern's variables. The set
            must be independent (no block of H couples two of its variables).
        dense_max: ``"auto"`` picks the dense Cholesky of S up to this many unknowns, PCG from
            ``pcg_min`` unknowns on (S is then never formed), CHOLMOD in between.
        ordering: fill-reducing order of the camera graph for ``"sparse"`` (``amd | metis | ...``).
        pcg_rtol, pcg_max_iterations: PCG stops when ``|r| <= pcg_rtol |b|`` (Ceres' ITERATIVE_SCHUR
            uses a loose forcing sequence; a tight default keeps LM's step near exact).
    """

    def __init__(self, reduced: str = "auto", eliminate=None, dense_max: int = 1000,
                 pcg_min: int = 100_000, ordering: str = "amd", pcg_rtol: float = 1e-8,
                 pcg_max_iterations: int | None = None):
        if reduced not in REDUCED:
            raise FgoptError(f"SchurSolver: unknown reduced={reduced!r}; choose one of "
                             f"{', '.join(REDUCED)}")
        self.reduced = reduced
        self.eliminate = eliminate
        self.dense_max = int(dense_max)
        self.pcg_min = int(pcg_min)
        self.ordering = ordering
        self.pcg_rtol = float(pcg_rtol)
        self.pcg_max_iterations = pcg_max_iterations
        self.name = "schur" if reduced == "auto" else f"schur_{reduced}"
        self.mode: str | None = None       # the resolved reduced-system solver
        self.last_pcg_iterations = 0
        self.timing = dict.fromkeys(TIMING_KEYS, 0.0)  # seconds, accumulated over calls

    # ------------------------------------------------------------------ analyze
    def analyze(self, pattern: HessianPattern) -> None:
        self._pattern = pattern
        N, V = pattern.size, pattern.var_offset.shape[0]
        var_off, var_dim = pattern.var_offset, pattern.var_dim
        is_e = eliminated_mask(pattern, self.eliminate)
        var_at = _scalar_to_var(var_off, var_dim, N)
        # every stored block once, by its (0, 0) entry
        cols = np.repeat(np.arange(N, dtype=np.int64), np.diff(pattern.indptr))
        rows = pattern.indices
        rv, cv = var_at[rows], var_at[cols]
        first = (rows == var_off[rv]) & (cols == var_off[cv]) & (rv != cv)
        p00 = np.nonzero(first)[0]
        brv, bcv = rv[p00], cv[p00]
        if np.any(is_e[brv] & is_e[bcv]):
            raise FgoptError("SchurSolver: the variables chosen for elimination are not "
                             "independent (a factor couples two of them); pass eliminate=... "
                             "or choose another linear solver")
        f_vars = np.nonzero(~is_e)[0]
        f_vars = f_vars[np.argsort(var_off[f_vars])]
        e_vars = np.nonzero(is_e)[0]
        e_vars = e_vars[np.argsort(var_off[e_vars])]
        nF = f_vars.shape[0]
        fidx = np.full(V, -1, dtype=np.int64)
        fidx[f_vars] = np.arange(nF)
        eidx = np.full(V, -1, dtype=np.int64)
        eidx[e_vars] = np.arange(e_vars.shape[0])
        f_dim = var_dim[f_vars].astype(np.int64)
        # E-F edges: orientation 0 = block stored in e's columns (f after e)
        o0 = is_e[bcv] & ~is_e[brv]
        o1 = is_e[brv] & ~is_e[bcv]
        ff = ~is_e[brv] & ~is_e[bcv]
        edge_e = np.concatenate([eidx[bcv[o0]], eidx[brv[o1]]])
        edge_fv = np.concatenate([brv[o0], bcv[o1]])
        edge_p00 = np.concatenate([p00[o0], p00[o1]])
        edge_orient = np.concatenate([np.zeros(int(o0.sum()), np.int64),
                                      np.ones(int(o1.sum()), np.int64)])
        ff_i, ff_j = fidx[brv[ff]], fidx[bcv[ff]]  # F-F couplings of H itself
        edge_f = fidx[edge_fv]
        # reduced-system order (rank of each F variable in S)
        mode = self.reduced
        nS = int(f_dim.sum())
        if mode == "auto":
            mode = ("dense" if nS <= self.dense_max else
                    "pcg" if nS >= self.pcg_min else "sparse")
        self.mode = mode
        if mode == "sparse" and nF > 2:
            co_i, co_j = _co_observation_pairs(edge_e, edge_f, e_vars.shape[0], nF)
            order = fill_reducing_order(nF, np.concatenate([co_i, ff_i]),
                                        np.concatenate([co_j, ff_j]), self.ordering)
        else:
            order = np.arange(nF)
        f_rank = np.empty(nF, dtype=np.int64)
        f_rank[order] = np.arange(nF)
        # sort edges by (e, rank of f): pairs (ki >= kj) then have rank(f_ki) >= rank(f_kj)
        srt = np.lexsort((f_rank[edge_f], edge_e))
        edge_e, edge_f = edge_e[srt], edge_f[srt]
        self._edge_p00 = np.ascontiguousarray(edge_p00[srt])
        self._edge_orient = np.ascontiguousarray(edge_orient[srt])
        self._edge_f = np.ascontiguousarray(edge_f)
        nE = e_vars.shape[0]
        e_dim = var_dim[e_vars].astype(np.int64)
        self._e_off = var_off[e_vars].astype(np.int64)
        self._e_dim = e_dim
        self._edge_ptr = np.zeros(nE + 1, dtype=np.int64)
        np.cumsum(np.bincount(edge_e, minlength=nE), out=self._edge_ptr[1:])
        self._c_ptr = np.concatenate([[0], np.cumsum(e_dim * e_dim)]).astype(np.int64)
        w_sizes = f_dim[edge_f] * e_dim[edge_e]
        self._w_ptr = np.concatenate([[0], np.cumsum(w_sizes)]).astype(np.int64)
        self._f_hoff = var_off[f_vars].astype(np.int64)
        self._f_dim = f_dim
        self._cshift = _column_shift(pattern, var_at)
        self._Cinv = np.empty(int(self._c_ptr[-1]))
        self._B = np.empty(int(self._w_ptr[-1]))
        self._W = np.empty(int(self._w_ptr[-1]))
        self._fast = bool(nE and np.all(e_dim == 3) and np.all(f_dim[edge_f] == 9))
        # S layout: offsets in S order
        f_soff = np.zeros(nF, dtype=np.int64)
        f_soff[order] = np.concatenate([[0], np.cumsum(f_dim[order])[:-1]]) if nF else []
        self._f_soff = f_soff
        self._nS = nS
        self._s_to_h = np.empty(nS, dtype=np.int64)  # H index of each S scalar
        s_idx = f_soff[:, None] + np.arange(int(f_dim.max(initial=1)))[None, :]
        h_idx = self._f_hoff[:, None] + np.arange(int(f_dim.max(initial=1)))[None, :]
        valid = np.arange(s_idx.shape[1])[None, :] < f_dim[:, None]
        self._s_to_h[s_idx[valid]] = h_idx[valid]
        h_to_s = np.full(N, -1, dtype=np.int64)
        h_to_s[self._s_to_h] = np.arange(nS)
        # A = H_FF entries: source positions in H, scalar (row, col) in S, lower
        a_mask = (h_to_s[rows] >= 0) & (h_to_s[cols] >= 0)
        self._a_src = np.nonzero(a_mask)[0]
        sr, sc = h_to_s[rows[a_mask]], h_to_s[cols[a_mask]]
        a_row, a_col = np.maximum(sr, sc), np.minimum(sr, sc)
        if mode == "pcg":
            self._analyze_pcg(nF, f_dim, order, ff_i, ff_j, a_row, a_col)
        else:
            self._analyze_direct(mode, nF, f_dim, order, f_rank, ff_i, ff_j, a_row, a_col)

    def _pairs(self, nF):
        k = np.diff(self._edge_ptr)
        self._pair_ptr = np.concatenate([[0], np.cumsum(k * (k + 1) // 2)]).astype(np.int64)
        npairs = int(self._pair_ptr[-1])
        pi = np.empty(npairs, dtype=np.int64)
        pj = np.empty(npairs, dtype=np.int64)
        K.enumerate_pairs(self._edge_ptr, self._edge_f, self._pair_ptr, pi, pj)
        return pi, pj

    def _analyze_direct(self, mode, nF, f_dim, order, f_rank, ff_i, ff_j, a_row, a_col):
        """Blocks of S (row var rank >= column var rank) in a packed store, and the maps
        H_FF -> packed and packed (lower triangle) -> the dense / CSC matrix that is factored."""
        pi, pj = self._pairs(nF)  # row var pi, column var pj (rank(pi) >= rank(pj))
        lo = f_rank[ff_i] >= f_rank[ff_j]  # F-F couplings of H, oriented lower in S order
        fi = np.where(lo, ff_i, ff_j)
        fj = np.where(lo, ff_j, ff_i)
        codes = np.unique(np.concatenate([pj * nF + pi, fj * nF + fi,
                                          np.arange(nF, dtype=np.int64) * (nF + 1)]))
        bc, br = codes // nF, codes % nF
        self._pair_blk = np.searchsorted(codes, pj * nF + pi)
        dr, dc = f_dim[br], f_dim[bc]
        pk_off = np.concatenate([[0], np.cumsum(dr * dc)]).astype(np.int64)
        self._blk_ptr = np.concatenate([[0], np.cumsum(dc)]).astype(np.int64)
        self._blk_base = np.repeat(pk_off[:-1], dc) + _ranges(dc) * np.repeat(dr, dc)
        self._packed = np.zeros(int(pk_off[-1]))
        # packed entries (a, b) of every block -> scalar (row, col) of S; keep the lower ones
        blk_of = np.repeat(np.arange(codes.shape[0]), dr * dc)
        loc = _ranges(dr * dc)
        a, b = loc % dr[blk_of], loc // dr[blk_of]
        srow = self._f_soff[br][blk_of] + a
        scol = self._f_soff[bc][blk_of] + b
        self._pk_src = np.nonzero(srow >= scol)[0]
        srow, scol = srow[self._pk_src], scol[self._pk_src]
        # H_FF entries -> packed positions
        f_of_s = np.repeat(order, f_dim[order]) if nF else np.zeros(0, np.int64)
        fr, fc = f_of_s[a_row], f_of_s[a_col]
        blk = np.searchsorted(codes, fc * nF + fr)
        self._a_dst = (pk_off[blk] + (a_col - self._f_soff[fc]) * f_dim[fr]
                       + (a_row - self._f_soff[fr]))
        nS = self._nS
        if mode == "dense":
            self._pk_dst = scol * nS + srow
            self._S = np.zeros((nS, nS), order="F")
            self._S_flat = self._S.reshape(-1, order="F")  # a view (Fortran-contiguous)
        else:
            from .cholmod import CholmodSolver

            all_i, all_j = np.concatenate([pi, fi]), np.concatenate([pj, fj])
            keep = all_i != all_j
            spat, _ = build_pattern(f_dim, order, all_i[keep], all_j[keep])
            assert np.array_equal(spat.var_offset, self._f_soff)
            self._pk_dst = _csc_positions(spat, srow, scol)
            if self._pk_dst.shape[0] != spat.nnz:
                raise AssertionError("Schur: packed blocks do not cover the reduced pattern")
            self._spattern = spat
            self._S_flat = np.zeros(spat.nnz)
            self._chol = CholmodSolver(mode="supernodal", ordering_method="natural")
            self._chol.analyze(spat)

    def _analyze_pcg(self, nF, f_dim, order, ff_i, ff_j, a_row, a_col):
        self._pair_ptr = np.zeros(self._edge_ptr.shape[0], dtype=np.int64)
        self._pair_blk = np.zeros(0, dtype=np.int64)
        self._blk_ptr = np.zeros(1, dtype=np.int64)
        self._blk_base = np.zeros(0, dtype=np.int64)
        keep = ff_i != ff_j
        apat, _ = build_pattern(f_dim, order, ff_i[keep], ff_j[keep])
        self._apattern = apat
        self._a_dst = _csc_positions(apat, a_row, a_col)
        self._A = np.zeros(apat.nnz)
        self._dg_ptr = np.concatenate([[0], np.cumsum(f_dim * f_dim)]).astype(np.int64)
        # diagonal blocks of A, full (row-major): scalar (a, b) of F var f -> A position
        d = f_dim
        f = np.repeat(np.arange(nF), d * d)
        loc = _ranges(d * d)
        a, b = loc // d[f], loc % d[f]
        sr, sc = self._f_soff[f] + a, self._f_soff[f] + b
        self._dg_src = _csc_positions(apat, np.maximum(sr, sc), np.minimum(sr, sc))
        self._Dg = np.zeros(int(self._dg_ptr[-1]))
        self._Minv = np.zeros(int(self._dg_ptr[-1]))

    # ------------------------------------------------------------------ factorize / solve
    def factorize(self, H_data: np.ndarray) -> None:
        t0 = time.perf_counter()
        pcg = self.mode == "pcg"
        S = self._A if pcg else self._packed
        S[:] = 0.0
        S[self._a_dst] = H_data[self._a_src]
        if self._fast:
            bad = K.eliminate_e3f9(
                H_data, self._pattern.indptr, self._cshift, self._e_off, self._c_ptr,
                self._edge_ptr, self._edge_f, self._edge_p00, self._edge_orient, self._f_hoff,
                self._w_ptr, self._pair_ptr, self._pair_blk, self._blk_ptr, self._blk_base,
                self._Cinv, self._B, self._W, S, not pcg)
        else:
            bad = K.eliminate(
                H_data, self._pattern.indptr, self._cshift, self._e_off, self._e_dim,
                self._c_ptr, self._edge_ptr, self._edge_f, self._edge_p00, self._edge_orient,
                self._f_hoff, self._f_dim, self._w_ptr, self._pair_ptr, self._pair_blk,
                self._blk_ptr, self._blk_base, self._Cinv, self._B, self._W, S, not pcg)
        if bad >= 0:
            raise NotPositiveDefiniteError(
                f"Schur: the diagonal block of eliminated variable #{bad} is not positive "
                "definite (a point seen too few times / too little damping)")
        t1 = time.perf_counter()
        self.timing["eliminate"] += t1 - t0
        try:
            self._factor_reduced()
        finally:
            self.timing["factor_S"] += time.perf_counter() - t1

    def _factor_reduced(self) -> None:
        if self.mode == "dense":
            if self._nS:
                self._S_flat[:] = 0.0
                self._S_flat[self._pk_dst] = self._packed[self._pk_src]
                # in place (Fortran-contiguous float64); keep the returned array to be safe
                self._L, info = lapack.dpotrf(self._S, lower=1, clean=0, overwrite_a=1)
                if info != 0:
                    raise NotPositiveDefiniteError(
                        f"Schur: the reduced camera system is not positive definite (LAPACK "
                        f"dpotrf info={info})")
        elif self.mode == "sparse":
            self._S_flat[self._pk_dst] = self._packed[self._pk_src]
            self._chol.factorize(self._S_flat)
        else:
            self._Dg[:] = self._A[self._dg_src]
            K.schur_block_diagonal(self._Dg, self._dg_ptr, self._e_dim, self._edge_ptr,
                                   self._edge_f, self._f_dim, self._w_ptr, self._B, self._W)
            bad = K.invert_blocks(self._Dg, self._dg_ptr, self._f_dim, self._Minv)
            if bad >= 0:
                raise NotPositiveDefiniteError(
                    f"Schur-PCG: block {bad} of the reduced system's diagonal is not positive "
                    "definite")

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        t0 = time.perf_counter()
        rhs = np.ascontiguousarray(rhs, dtype=np.float64)
        rS = rhs[self._s_to_h]
        K.reduce_rhs(rhs, rS, self._e_off, self._e_dim, self._edge_ptr, self._edge_f,
                     self._f_soff, self._f_dim, self._w_ptr, self._W)
        t1 = time.perf_counter()
        if self._nS == 0:
            xS = rS
        elif self.mode == "dense":
            xS, info = lapack.dpotrs(self._L, rS, lower=1)
            if info != 0:
                raise FgoptError(f"Schur: LAPACK dpotrs failed (info={info})")
        elif self.mode == "sparse":
            xS = self._chol.solve(rS)
        else:
            xS = self._pcg(rS)
        t2 = time.perf_counter()
        x = np.empty(self._pattern.size)
        x[self._s_to_h] = xS
        K.back_substitute(rhs, xS, x, self._e_off, self._e_dim, self._c_ptr, self._Cinv,
                          self._edge_ptr, self._edge_f, self._f_soff, self._f_dim, self._w_ptr,
                          self._B)
        tm = self.timing
        tm["reduce_rhs"] += t1 - t0
        tm["solve_S"] += t2 - t1
        tm["back_substitute"] += time.perf_counter() - t2
        return x

    def _schur_matvec(self, x: np.ndarray) -> np.ndarray:
        ap = self._apattern
        out = _sym_matvec(ap.indptr, ap.indices, self._A, x)
        K.implicit_schur_matvec(x, out, self._e_dim, self._c_ptr, self._Cinv, self._edge_ptr,
                                self._edge_f, self._f_soff, self._f_dim, self._w_ptr, self._B)
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
        maxit = self.pcg_max_iterations or max(10 * b.shape[0], 100)
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
def eliminated_mask(pattern: HessianPattern, eliminate=None) -> np.ndarray:
    """Boolean mask over the pattern's variables of the set to eliminate (not checked here)."""
    V = pattern.var_offset.shape[0]
    if eliminate is None:
        kinds = pattern.var_kind
        if kinds is None:
            raise FgoptError("SchurSolver: the pattern carries no variable kinds; pass "
                             "eliminate=<boolean mask or variable indices>")
        for kid in _kinds_by_count(kinds):
            mask = kinds == kid
            if is_independent(pattern, mask):
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


def _kinds_by_count(kinds: np.ndarray) -> list[int]:
    ids, counts = np.unique(kinds[kinds >= 0], return_counts=True)
    return [int(i) for i in ids[np.argsort(-counts, kind="stable")]]


def is_independent(pattern: HessianPattern, mask: np.ndarray) -> bool:
    """True when no stored off-diagonal block of H couples two variables of ``mask``."""
    off, dim = pattern.var_offset, pattern.var_dim
    var_at = _scalar_to_var(off, dim, pattern.size)
    cols = off[mask]  # first column of every masked variable: all its couplings appear there
    starts, ends = pattern.indptr[cols], pattern.indptr[cols + 1]
    idx = np.repeat(starts, ends - starts) + _ranges(ends - starts)
    rv = var_at[pattern.indices[idx]]
    cv = np.repeat(np.nonzero(mask)[0], ends - starts)
    return not np.any(mask[rv] & (rv != cv))


def choose_linear_solver(pattern: HessianPattern) -> SchurSolver | None:
    """A :class:`SchurSolver` when the problem is BA-shaped, else None.

    BA-shaped: some variable kind is independent (no factor couples two of its variables) and
    holds at least half of the tangent dimension, with at least twice as many variables as the
    rest -- eliminating it leaves a reduced system much smaller than H.
    """
    kinds = pattern.var_kind
    if kinds is None or pattern.size == 0:
        return None
    for kid in _kinds_by_count(kinds):
        mask = kinds == kid
        n_e = int(mask.sum())
        if n_e < 2 * (mask.shape[0] - n_e) or 2 * int(pattern.var_dim[mask].sum()) < pattern.size:
            return None
        if is_independent(pattern, mask):
            return SchurSolver()
    return None


def _scalar_to_var(var_off: np.ndarray, var_dim: np.ndarray, N: int) -> np.ndarray:
    order = np.argsort(var_off, kind="stable")
    return np.repeat(order, var_dim[order]).astype(np.int64)


def _column_shift(pattern: HessianPattern, var_at: np.ndarray) -> np.ndarray:
    """``cshift[c] = indptr[c] - indptr[c0] - (c - c0)``, ``c0`` = first column of c's variable."""
    c = np.arange(pattern.size, dtype=np.int64)
    c0 = pattern.var_offset[var_at]
    return pattern.indptr[:-1] - pattern.indptr[c0] - (c - c0)


def _csc_positions(pat: HessianPattern, row: np.ndarray, col: np.ndarray) -> np.ndarray:
    """Data positions of lower entries ``(row, col)`` (``row >= col``) in a CSC pattern."""
    n = pat.size
    cols = np.repeat(np.arange(n, dtype=np.int64), np.diff(pat.indptr))
    keys = cols * n + pat.indices  # sorted: columns ascending, rows sorted within
    want = col * n + row
    pos = np.searchsorted(keys, want)
    if want.shape[0] and (pos.max(initial=0) >= keys.shape[0]
                          or not np.array_equal(keys[pos], want)):
        raise AssertionError("Schur: an entry is missing from the reduced pattern")
    return pos


def _co_observation_pairs(edge_e, edge_f, nE, nF):
    """Unique pairs ``(f1 > f2)`` of reduced variables sharing an eliminated variable."""
    srt = np.argsort(edge_e, kind="stable")
    ptr = np.zeros(nE + 1, dtype=np.int64)
    np.cumsum(np.bincount(edge_e, minlength=nE), out=ptr[1:])
    k = np.diff(ptr)
    pair_ptr = np.concatenate([[0], np.cumsum(k * (k + 1) // 2)]).astype(np.int64)
    pi = np.empty(int(pair_ptr[-1]), dtype=np.int64)
    pj = np.empty_like(pi)
    K.enumerate_pairs(ptr, np.ascontiguousarray(edge_f[srt]), pair_ptr, pi, pj)
    keep = pi != pj
    codes = np.unique(np.maximum(pi, pj)[keep] * nF + np.minimum(pi, pj)[keep])
    return codes // nF, codes % nF


def _ranges(lengths: np.ndarray) -> np.ndarray:
    lengths = np.asarray(lengths, dtype=np.int64)
    total = int(lengths.sum())
    if total == 0:
        return np.zeros(0, dtype=np.int64)
    starts = np.repeat(np.cumsum(lengths) - lengths, lengths)
    return np.arange(total, dtype=np.int64) - starts
