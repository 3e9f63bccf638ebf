"""numba kernels of the Schur-complement solver (see :mod:`fgopt.solvers.linear.schur`).

Notation: ``E`` = the eliminated variables (BA points), ``F`` = the kept ones (cameras). For
every eliminated variable ``e`` (dim ``de``) with diagonal block ``C_e`` and every edge ``k``
= ``(e, f)`` with block ``B_k = H[f, e]`` (``df x de``)::

    S = A_FF - sum_e sum_{k, l in edges(e)} W_k B_l^T,     W_k = B_k C_e^-1
    r_F' = r_F - sum_k W_k r_e,   S x_F = r_F',   x_e = C_e^-1 (r_e - sum_k B_k^T x_f)

Reading H (lower CSC, block-dense, see :mod:`fgopt.structure`): the diagonal block of a
variable comes first in each of its columns, so entry ``(a, b)`` (``a >= b``) of ``C_e`` is at
``indptr[off_e + b] + a - b``. An off-diagonal block is stored at the same row offset in each
column of its column variable, shifted by one per column (the diagonal part shortens), so with
``cshift[c] = indptr[c] - indptr[c0] - (c - c0)`` (``c0`` = first column of ``c``'s variable)
and ``p00`` = the position of the block's entry ``(0, 0)``:

* orientation 0 (``f`` after ``e``, stored in ``e``'s columns): ``B[a, b]`` at ``p00 + cshift[off_e + b] + a``
* orientation 1 (``f`` before ``e``, stored in ``f``'s columns): ``B[a, b]`` at ``p00 + cshift[off_f + a] + b``

The kernels read ``B_k`` through ``(X, bbase, bshift)``: entry ``(a, c)`` is at
``X[bbase[k] + bshift[off_e + c] + a]``. When every edge has orientation 0 (the Schur layout of
:func:`fgopt.structure.schur_order`) that is H itself (``bbase`` = ``p00``, ``bshift`` =
``cshift``): no copy of the camera-point blocks (27 doubles per BA observation) is made. Other
layouts gather the blocks into a copy laid out the same way (:func:`gather_blocks`).

Blocks of ``S`` are addressed by column bases: entry ``(a, b)`` of block ``blk`` is at
``blk_base[blk_ptr[blk] + b] + a`` (dense column-major S and CHOLMOD's lower CSC alike).
"""

from __future__ import annotations

import numpy as np
from ..._jit import njit
from .base import PIVOT_TOLERANCE

_FM = {"contract"}  # let LLVM fuse multiply-adds (no reassociation)


@njit(cache=True, fastmath=_FM)
def _chol_inverse(C, d, L, out):
    """``out = C^-1`` for a symmetric ``d x d`` block (lower triangle read); False if a pivot is
    not above ``PIVOT_TOLERANCE`` x its diagonal entry. ``L``: work array, >= ``d x d``."""
    for j in range(d):
        s = C[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if not s > PIVOT_TOLERANCE * C[j, j]:
            return False
        ljj = np.sqrt(s)
        L[j, j] = ljj
        for i in range(j + 1, d):
            t = C[i, j]
            for k in range(j):
                t -= L[i, k] * L[j, k]
            L[i, j] = t / ljj
    # L <- L^-1 in place, column by column (entries right of / below are still L's)
    for j in range(d):
        L[j, j] = 1.0 / L[j, j]
        for i in range(j + 1, d):
            t = 0.0
            for k in range(j, i):
                t -= L[i, k] * L[k, j]
            L[i, j] = t / L[i, i]
    for a in range(d):  # out = L^-T L^-1
        for b in range(a + 1):
            t = 0.0
            for k in range(a, d):
                t += L[k, a] * L[k, b]
            out[a, b] = t
            out[b, a] = t
    return True


@njit(cache=True)
def gather_blocks(H, cshift, e_off, e_dim, edge_ptr, edge_f, f_hoff, f_dim, edge_p00,
                  edge_orient, bbase, bshift, X):
    """Copy every ``B_k`` from H (either orientation) into ``X`` (addressed by bbase/bshift)."""
    for i in range(e_off.shape[0]):
        d, o = e_dim[i], e_off[i]
        for k in range(edge_ptr[i], edge_ptr[i + 1]):
            f = edge_f[k]
            df, fo, p00, bb = f_dim[f], f_hoff[f], edge_p00[k], bbase[k]
            for c in range(d):
                dst = bb + bshift[o + c]
                for a in range(df):
                    if edge_orient[k] == 0:
                        X[dst + a] = H[p00 + cshift[o + c] + a]
                    else:
                        X[dst + a] = H[p00 + cshift[fo + a] + c]


@njit(cache=True, inline="always")
def _block_of(codes, col_ptr, nF, fc, fr):
    """Index of S's block (rows fr, columns fc) among the sorted block codes ``fc * nF + fr``
    (bisection within column fc's blocks)."""
    want = fc * nF + fr
    lo, hi = col_ptr[fc], col_ptr[fc + 1]
    while lo < hi:
        mid = (lo + hi) >> 1
        if codes[mid] < want:
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit(cache=True, fastmath=_FM)
def eliminate(H, indptr, e_off, e_dim, c_ptr, edge_ptr, edge_f, f_dim, X, bbase, bshift,
              pair_ptr, pair_blk, blk_ptr, blk_base, Cinv, W, S, accumulate):
    """Invert every ``C_e`` (read from H), subtract ``W_k B_l^T`` from S.

    ``W`` is scratch for one e's ``W_k = B_k C_e^-1`` (column-major ``df x de`` per edge, one
    after the other): the solve only needs ``B`` and ``C_e^-1``.
    ``S`` must already hold ``A_FF``; with ``accumulate=False`` S is left alone (implicit
    Schur). Returns -1, or the index of an ``e`` whose ``C_e`` is not positive definite.
    """
    nE = e_off.shape[0]
    maxd = 1
    for i in range(nE):
        maxd = max(maxd, e_dim[i])
    C = np.empty((maxd, maxd))
    L = np.empty((maxd, maxd))
    Ci = np.empty((maxd, maxd))
    for i in range(nE):
        d = e_dim[i]
        o = e_off[i]
        for b in range(d):
            base = indptr[o + b] - b
            for a in range(b, d):
                C[a, b] = H[base + a]
        if not _chol_inverse(C, d, L, Ci):
            return i
        cp = c_ptr[i]
        for a in range(d):
            for b in range(d):
                Cinv[cp + a * d + b] = Ci[a, b]
        k0, k1 = edge_ptr[i], edge_ptr[i + 1]
        ww = 0
        for k in range(k0, k1):
            df = f_dim[edge_f[k]]
            bb = bbase[k]
            for b in range(d):
                for a in range(df):
                    t = 0.0
                    for c in range(d):
                        t += X[bb + bshift[o + c] + a] * Ci[c, b]
                    W[ww + b * df + a] = t
            ww += df * d
        if not accumulate:
            continue
        p = pair_ptr[i]
        wi = 0
        if d == 3:  # points: one pass over each column of S, not three (pose + calibration
            # variables, SE3 + landmark SfM)
            s0, s1, s2 = bshift[o], bshift[o + 1], bshift[o + 2]
            for ki in range(k0, k1):
                dfi = f_dim[edge_f[ki]]
                w1, w2 = wi + dfi, wi + 2 * dfi
                for kj in range(k0, ki + 1):
                    dfj = f_dim[edge_f[kj]]
                    bj = bbase[kj]
                    bp = blk_ptr[pair_blk[p]]
                    p += 1
                    diag = ki == kj
                    for b in range(dfj):
                        base = blk_base[bp + b]
                        x0, x1, x2 = X[bj + s0 + b], X[bj + s1 + b], X[bj + s2 + b]
                        for a in range(b if diag else 0, dfi):
                            S[base + a] -= W[wi + a] * x0 + W[w1 + a] * x1 + W[w2 + a] * x2
                wi += dfi * 3
            continue
        for ki in range(k0, k1):
            dfi = f_dim[edge_f[ki]]
            for kj in range(k0, ki + 1):
                dfj = f_dim[edge_f[kj]]
                bj = bbase[kj]
                bp = blk_ptr[pair_blk[p]]
                p += 1
                diag = ki == kj
                for b in range(dfj):
                    base = blk_base[bp + b]
                    for c in range(d):
                        x = X[bj + bshift[o + c] + b]
                        wc = wi + c * dfi
                        for a in range(b if diag else 0, dfi):
                            S[base + a] -= W[wc + a] * x
            wi += dfi * d
    return -1


@njit(cache=True, fastmath=_FM)
def eliminate_e3f9(H, indptr, e_off, c_ptr, edge_ptr, X, bbase, bshift, pair_ptr, pair_blk,
                   blk_ptr, blk_base, Cinv, W, S, accumulate):
    """:func:`eliminate` for ``de = 3``, ``df = 9`` (BAL), with fixed-size unrolled loops.

    S must be the *packed* block store: block ``blk`` is a full column-major 9x9 at
    ``blk_base[blk_ptr[blk]]`` (diagonal blocks too: both triangles are accumulated).
    """
    nE = e_off.shape[0]
    C = np.empty((3, 3))
    L = np.empty((3, 3))
    Ci = np.empty((3, 3))
    for i in range(nE):
        o = e_off[i]
        for b in range(3):
            base = indptr[o + b] - b
            for a in range(b, 3):
                C[a, b] = H[base + a]
        if not _chol_inverse(C, 3, L, Ci):
            return i
        cp = c_ptr[i]
        for a in range(3):
            for b in range(3):
                Cinv[cp + a * 3 + b] = Ci[a, b]
        s0, s1, s2 = bshift[o], bshift[o + 1], bshift[o + 2]
        k0, k1 = edge_ptr[i], edge_ptr[i + 1]
        for k in range(k0, k1):
            bb = bbase[k]
            ww = 27 * (k - k0)
            for b in range(3):
                c0, c1, c2 = Ci[0, b], Ci[1, b], Ci[2, b]
                for a in range(9):
                    W[ww + b * 9 + a] = (X[bb + s0 + a] * c0 + X[bb + s1 + a] * c1
                                         + X[bb + s2 + a] * c2)
        if not accumulate:
            continue
        p = pair_ptr[i]
        for ki in range(k0, k1):
            wi = 27 * (ki - k0)
            # W_ki in registers (numba does not SLP-vectorize: unrolled scalar code
            # with operands in locals is ~2.5x faster than loops over memory)
            w00, w10, w20, w30, w40, w50, w60, w70, w80 = W[wi:wi + 9]
            w01, w11, w21, w31, w41, w51, w61, w71, w81 = W[wi + 9:wi + 18]
            w02, w12, w22, w32, w42, w52, w62, w72, w82 = W[wi + 18:wi + 27]
            for kj in range(k0, ki + 1):
                bj = bbase[kj]
                base = blk_base[blk_ptr[pair_blk[p]]]
                p += 1
                blk = S[base:base + 81]  # packed column-major 9x9
                for b in range(9):
                    x0, x1, x2 = X[bj + s0 + b], X[bj + s1 + b], X[bj + s2 + b]
                    col = blk[9 * b:9 * b + 9]
                    col[0] -= w00 * x0 + w01 * x1 + w02 * x2
                    col[1] -= w10 * x0 + w11 * x1 + w12 * x2
                    col[2] -= w20 * x0 + w21 * x1 + w22 * x2
                    col[3] -= w30 * x0 + w31 * x1 + w32 * x2
                    col[4] -= w40 * x0 + w41 * x1 + w42 * x2
                    col[5] -= w50 * x0 + w51 * x1 + w52 * x2
                    col[6] -= w60 * x0 + w61 * x1 + w62 * x2
                    col[7] -= w70 * x0 + w71 * x1 + w72 * x2
                    col[8] -= w80 * x0 + w81 * x1 + w82 * x2
    return -1


@njit(cache=True, fastmath=_FM)
def reduce_rhs(rhs, rS, e_off, e_dim, c_ptr, Cinv, edge_ptr, edge_f, f_soff, f_dim, X, bbase,
               bshift):
    """``rS -= sum_k B_k C_e^-1 rhs_e`` (``rS`` holds ``rhs_F`` in S order on entry)."""
    maxd = 1
    for i in range(e_off.shape[0]):
        maxd = max(maxd, e_dim[i])
    y = np.empty(maxd)
    for i in range(e_off.shape[0]):
        d = e_dim[i]
        o = e_off[i]
        cp = c_ptr[i]
        for a in range(d):
            t = 0.0
            for c in range(d):
                t += Cinv[cp + a * d + c] * rhs[o + c]
            y[a] = t
        for k in range(edge_ptr[i], edge_ptr[i + 1]):
            f = edge_f[k]
            df = f_dim[f]
            so = f_soff[f]
            bb = bbase[k]
            for c in range(d):
                yc = y[c]
                col = bb + bshift[o + c]
                for a in range(df):
                    rS[so + a] -= X[col + a] * yc


@njit(cache=True, fastmath=_FM)
def back_substitute(rhs, xS, x, e_off, e_dim, c_ptr, Cinv, edge_ptr, edge_f, f_soff, f_dim,
                    X, bbase, bshift):
    """``x_e = C_e^-1 (rhs_e - sum_k B_k^T x_f)`` into ``x`` (H order)."""
    maxd = 1
    for i in range(e_off.shape[0]):
        maxd = max(maxd, e_dim[i])
    y = np.empty(maxd)
    for i in range(e_off.shape[0]):
        d = e_dim[i]
        o = e_off[i]
        for c in range(d):
            y[c] = rhs[o + c]
        for k in range(edge_ptr[i], edge_ptr[i + 1]):
            f = edge_f[k]
            df = f_dim[f]
            so = f_soff[f]
            bb = bbase[k]
            for c in range(d):
                col = bb + bshift[o + c]
                t = 0.0
                for a in range(df):
                    t += X[col + a] * xS[so + a]
                y[c] -= t
        cp = c_ptr[i]
        for a in range(d):
            t = 0.0
            for c in range(d):
                t += Cinv[cp + a * d + c] * y[c]
            x[o + a] = t


@njit(cache=True, fastmath=_FM)
def implicit_schur_matvec(xS, out, e_off, e_dim, c_ptr, Cinv, edge_ptr, edge_f, f_soff, f_dim,
                          X, bbase, bshift):
    """``out -= sum_e B_e C_e^-1 B_e^T xS`` (``out`` holds ``A_FF xS`` on entry)."""
    maxd = 1
    for i in range(e_dim.shape[0]):
        maxd = max(maxd, e_dim[i])
    y = np.empty(maxd)
    z = np.empty(maxd)
    for i in range(e_dim.shape[0]):
        d = e_dim[i]
        o = e_off[i]
        for c in range(d):
            y[c] = 0.0
        k0, k1 = edge_ptr[i], edge_ptr[i + 1]
        for k in range(k0, k1):
            f = edge_f[k]
            df = f_dim[f]
            so = f_soff[f]
            bb = bbase[k]
            for c in range(d):
                col = bb + bshift[o + c]
                t = 0.0
                for a in range(df):
                    t += X[col + a] * xS[so + a]
                y[c] += t
        cp = c_ptr[i]
        for a in range(d):
            t = 0.0
            for c in range(d):
                t += Cinv[cp + a * d + c] * y[c]
            z[a] = t
        for k in range(k0, k1):
            f = edge_f[k]
            df = f_dim[f]
            so = f_soff[f]
            bb = bbase[k]
            for c in range(d):
                zc = z[c]
                col = bb + bshift[o + c]
                for a in range(df):
                    out[so + a] -= X[col + a] * zc


@njit(cache=True, fastmath=_FM)
def schur_block_diagonal(Dg, dg_ptr, e_off, e_dim, c_ptr, Cinv, edge_ptr, edge_f, f_dim, X,
                         bbase, bshift):
    """``Dg[f] -= sum_{k: f} B_k C_e^-1 B_k^T`` (full ``df x df`` blocks, row-major; holds
    ``A_ff`` on entry)."""
    maxd = 1
    for i in range(e_dim.shape[0]):
        maxd = max(maxd, e_dim[i])
    w = np.empty(16 * maxd)
    for i in range(e_dim.shape[0]):
        d = e_dim[i]
        o = e_off[i]
        cp = c_ptr[i]
        for k in range(edge_ptr[i], edge_ptr[i + 1]):
            f = edge_f[k]
            df = f_dim[f]
            dp = dg_ptr[f]
            bb = bbase[k]
            if w.shape[0] < df * d:
                w = np.empty(df * d)
            for c in range(d):  # w = B_k C_e^-1 (column-major)
                for a in range(df):
                    t = 0.0
                    for q in range(d):
                        t += X[bb + bshift[o + q] + a] * Cinv[cp + q * d + c]
                    w[c * df + a] = t
            for b in range(df):
                for c in range(d):
                    x = X[bb + bshift[o + c] + b]
                    for a in range(df):
                        Dg[dp + b * df + a] -= w[c * df + a] * x


@njit(cache=True)
def invert_blocks(Dg, dg_ptr, f_dim, out):
    """Invert every symmetric block of ``Dg`` into ``out``; -1 or the first non-PD block."""
    maxd = 1
    for f in range(f_dim.shape[0]):
        maxd = max(maxd, f_dim[f])
    M = np.empty((maxd, maxd))
    L = np.empty((maxd, maxd))
    Mi = np.empty((maxd, maxd))
    for f in range(f_dim.shape[0]):
        df = f_dim[f]
        dp = dg_ptr[f]
        for a in range(df):
            for b in range(df):
                M[a, b] = Dg[dp + a * df + b]
        if not _chol_inverse(M, df, L, Mi):
            return f
        for a in range(df):
            for b in range(df):
                out[dp + a * df + b] = Mi[a, b]
    return -1


@njit(cache=True)
def apply_blocks(Minv, dg_ptr, f_soff, f_dim, r, z):
    """``z_f = Minv_f r_f`` for every block."""
    for f in range(f_dim.shape[0]):
        df = f_dim[f]
        dp = dg_ptr[f]
        so = f_soff[f]
        for a in range(df):
            t = 0.0
            for b in range(df):
                t += Minv[dp + a * df + b] * r[so + b]
            z[so + a] = t


@njit(cache=True)
def pair_blocks(edge_ptr, edge_f, codes, col_ptr, nF, pair_ptr, out):
    """Per e, the packed block of every pair ``(f_ki, f_kj)``, ``kj <= ki`` (edges sorted by
    rank), found once here so that :func:`eliminate` reads one small integer per pair."""
    for i in range(edge_ptr.shape[0] - 1):
        p = pair_ptr[i]
        for ki in range(edge_ptr[i], edge_ptr[i + 1]):
            for kj in range(edge_ptr[i], ki + 1):
                out[p] = _block_of(codes, col_ptr, nF, edge_f[kj], edge_f[ki])
                p += 1


@njit(cache=True)
def co_observation_codes(edge_ptr, edge_f, nF):
    """Codes ``f1 * nF + f2`` (``f1 > f2``) of the F pairs that share an E variable, each once
    (a marker per F variable: no array of all (e, f1, f2) triples)."""
    nK = edge_f.shape[0]
    f_ptr = np.zeros(nF + 1, dtype=np.int64)  # edges by F variable: their E variables
    for k in range(nK):
        f_ptr[edge_f[k] + 1] += 1
    for f in range(nF):
        f_ptr[f + 1] += f_ptr[f]
    f_e = np.empty(nK, dtype=np.int64)
    fill = f_ptr[:-1].copy()
    for e in range(edge_ptr.shape[0] - 1):
        for k in range(edge_ptr[e], edge_ptr[e + 1]):
            f_e[fill[edge_f[k]]] = e
            fill[edge_f[k]] += 1
    mark = np.full(nF, -1, dtype=np.int64)
    count = 0
    for f in range(nF):
        for p in range(f_ptr[f], f_ptr[f + 1]):
            e = f_e[p]
            for k in range(edge_ptr[e], edge_ptr[e + 1]):
                g = edge_f[k]
                if g < f and mark[g] != f:
                    mark[g] = f
                    count += 1
    codes = np.empty(count, dtype=np.int64)
    mark[:] = -1
    count = 0
    for f in range(nF):
        for p in range(f_ptr[f], f_ptr[f + 1]):
            e = f_e[p]
            for k in range(edge_ptr[e], edge_ptr[e + 1]):
                g = edge_f[k]
                if g < f and mark[g] != f:
                    mark[g] = f
                    codes[count] = f * nF + g
                    count += 1
    return np.sort(codes)


@njit(cache=True, fastmath=_FM)
def packed_matvec(packed, pk_off, r_off, c_off, dr, dc, x, y):
    """``y = S x`` from the packed block store (lower blocks; a diagonal block's upper
    triangle is not read)."""
    for i in range(y.shape[0]):
        y[i] = 0.0
    for blk in range(pk_off.shape[0] - 1):
        p = pk_off[blk]
        ro, co, m, n = r_off[blk], c_off[blk], dr[blk], dc[blk]
        diag = ro == co
        for b in range(n):
            xb = x[co + b]
            acc = 0.0
            col = p + b * m
            if diag:
                y[ro + b] += packed[col + b] * xb
            for a in range(b + 1 if diag else 0, m):
                v = packed[col + a]
                y[ro + a] += v * xb
                acc += v * x[ro + a]
            y[co + b] += acc


@njit(cache=True)
def diagonal_blocks(packed, pk_off, diag_blk, f_dim, dg_ptr, Dg):
    """Full row-major diagonal blocks of S (from their lower triangles in the packed store)."""
    for f in range(f_dim.shape[0]):
        p = pk_off[diag_blk[f]]
        d = f_dim[f]
        q = dg_ptr[f]
        for b in range(d):
            for a in range(b, d):
                v = packed[p + b * d + a]
                Dg[q + a * d + b] = v
                Dg[q + b * d + a] = v
