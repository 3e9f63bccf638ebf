"""Numeric kernels of the block supernodal Cholesky (numba).

Storage: supernode ``s`` owns a dense **column-major** panel of ``rows[s] x width[s]`` doubles
at ``L[pstart[s]:]``: the lower-trapezoidal columns of L for its variables, rows listed by its row
variables (own variables first). Factorization is right-looking: each panel is factored with
LAPACK/BLAS (``dpotrf`` on the diagonal block, ``dtrsm`` below), then its whole update
``C = B B^T`` (``dsyrk``) is subtracted from the ancestors' panels through precomputed runs of
contiguous rows. Narrow panels use numba loops (factorization) and LLVM-IR register tiles (update,
``_block_simd.py``) instead of BLAS calls.

BLAS/LAPACK are scipy's: the Fortran routines its ``cython_blas`` / ``cython_lapack`` wrap (its
bundled OpenBLAS in a wheel). They are bound as named external symbols, so the compiled kernels
stay cacheable (``cache=True``): the addresses are registered with LLVM when this module is
imported, before any kernel runs.
"""

from __future__ import annotations

import ctypes
import importlib.util
from pathlib import Path

import llvmlite.binding as _llvm
import numpy as np
from numba import njit, types
from numba.extending import get_cython_function_address

from ._block_simd import prefetch as _prefetch
from ._block_simd import syrk_tile as _syrk_tile
from ._block_simd import syrk_tile_sub as _syrk_tile_sub


def _scipy_openblas() -> ctypes.CDLL | None:
    """The OpenBLAS a scipy wheel bundles (``scipy.libs/libscipy_openblas-*.so``, 32-bit
    integers, symbols ``scipy_<routine>_``), loaded by path: the same library and routines as
    ``cython_lapack``'s, without importing ``scipy.linalg`` (0.2-0.4 s of a new process, most
    of a small incremental script's). ``None`` for a scipy built otherwise (conda, a distro):
    then the cython wrappers are used."""
    spec = importlib.util.find_spec("scipy")
    if spec is None or spec.origin is None:
        return None
    libs = sorted((Path(spec.origin).parents[1] / "scipy.libs").glob("libscipy_openblas-*.so"))
    try:
        lib = ctypes.CDLL(str(libs[0])) if len(libs) == 1 else None
        return lib if lib is not None and hasattr(lib, "scipy_dpotrf_") else None
    except OSError:
        return None


_OPENBLAS = _scipy_openblas()


def _bind(module: str, name: str, nargs: int) -> types.ExternalFunction:
    symbol = "fgopt_block_" + name
    if _OPENBLAS is not None:
        address = ctypes.cast(getattr(_OPENBLAS, f"scipy_{name}_"), ctypes.c_void_p).value
    else:
        address = get_cython_function_address(module, name)
    _llvm.add_symbol(symbol, address)
    return types.ExternalFunction(symbol, types.void(*([types.intp] * nargs)))


_dpotrf = _bind("scipy.linalg.cython_lapack", "dpotrf", 5)
_dtrsm = _bind("scipy.linalg.cython_blas", "dtrsm", 11)
_dsyrk = _bind("scipy.linalg.cython_blas", "dsyrk", 10)
_dgemm = _bind("scipy.linalg.cython_blas", "dgemm", 13)

# Argument block for the Fortran calls (every argument is passed by address):
# int32 slots 0..4 hold the characters L R N T U, 8.. integers; float slots 1.0, -1.0, 0.0.
_CL, _CR, _CN, _CT, _CU = 0, 1, 2, 3, 4
_I0 = 8
IW_SIZE = 16


def blas_workspace() -> tuple[np.ndarray, np.ndarray]:
    iw = np.zeros(IW_SIZE, np.int32)
    iw[:5] = [ord(c) for c in "LRNTU"]
    fw = np.array([1.0, -1.0, 0.0])
    return iw, fw


# ------------------------------------------------------------------ small dense kernels
# Indices are unsigned (``_u``) so that numba emits no negative-index wraparound and LLVM can
# vectorize the contiguous inner loops.
_u = np.uint64


@njit(cache=True, inline="always")
def _panel_small(L, p0, w, m):
    """Left-looking Cholesky of a whole ``m x w`` panel (diagonal block and the rows below).

    Returns 0, or ``c + 1`` when the pivot of column ``c`` is not positive.
    """
    mu = _u(m)
    for c in range(w):
        cu = _u(c)
        cc = _u(p0) + cu * mu
        for k in range(c):
            kk = _u(p0) + _u(k) * mu
            f = L[kk + cu]
            for i in range(cu, mu):
                L[cc + i] -= L[kk + i] * f
        d = L[cc + cu]
        if not d > 0.0:
            return c + 1
        d = np.sqrt(d)
        L[cc + cu] = d
        inv = 1.0 / d
        for i in range(cu + _u(1), mu):
            L[cc + i] *= inv
    return 0


@njit(cache=True, inline="always")
def _panel_tiles(L, p0, w, m, T):
    """Left-looking Cholesky of an ``m x w`` panel by blocks of 4 columns (register tiles).

    Each block is first updated by all the columns left of it (8 x 4 tiles of ``syrk_tile_sub``,
    in place; partial tiles at the panel's edges go through the scratch ``T``), then factored
    right-looking within the block. Returns 0 or ``c + 1`` for a non-positive pivot in column c.
    """
    mu = _u(m)
    for c0 in range(0, w, 4):
        nb = min(4, w - c0)
        if c0 > 0:
            for i0 in range(c0, m, 8):
                if i0 + 8 <= m and nb == 4:
                    _syrk_tile_sub(L, _u(p0 + i0), _u(p0 + c0), mu, _u(c0), L,
                                   _u(p0 + i0 + c0 * m), mu)
                else:
                    _syrk_tile(L, _u(p0 + i0), _u(p0 + c0), mu, _u(c0), T, _u(0), _u(8))
                    nt = min(8, m - i0)
                    for j in range(nb):
                        col = p0 + (c0 + j) * m + i0
                        for t in range(nt):
                            L[col + t] -= T[t + j * 8]
        for j in range(nb):
            c = _u(c0 + j)
            cc = _u(p0) + c * mu
            d = L[cc + c]
            if not d > 0.0:
                return c0 + j + 1
            d = np.sqrt(d)
            L[cc + c] = d
            inv = 1.0 / d
            for i in range(c + _u(1), mu):
                L[cc + i] *= inv
            for j2 in range(j + 1, nb):
                c2 = _u(c0 + j2)
                f = L[cc + c2]
                cc2 = _u(p0) + c2 * mu
                for i in range(c2, mu):
                    L[cc2 + i] -= L[cc + i] * f
    return 0


@njit(cache=True, inline="always")
def _update_tiles(L, b0, w, m, n, k, C, ldc):
    """Columns ``0..k`` of the lower part of ``C = B B^T`` in 8 x 4 register tiles.

    ``B`` is the ``n x w`` block at ``L[b0]`` (``ld m``); ``C`` is column-major with ``ldc``
    (``n`` rounded up to 8). Tiles overhanging ``n`` / ``k`` read past ``B`` (into L's
    padding at worst) and write into ``C``'s padding; those entries are never used.
    """
    for j0 in range(0, k, 4):
        for i0 in range(j0 & ~7, n, 8):
            _syrk_tile(L, _u(b0 + i0), _u(b0 + j0), _u(m), _u(w), C, _u(i0 + j0 * ldc),
                       _u(ldc))


# ------------------------------------------------------------------ factorization
@njit(cache=True)
def factorize(H, hmap, L, C, pstart, width, rows, cb_ptr, cb_base, cb_ld, cb_src, cb_dim,
              run_ptr, run_src, run_dst, run_len, iw, fw, small_panel, tile_panel, small_syrk,
              chunk, diag0, tol):
    """Numeric factorization; returns -1, or the (postorder) scalar column whose pivot failed.

    A pivot ``d_j`` (``L_jj^2``) fails unless ``d_j > tol * H_jj``, ``H_jj`` the assembled
    diagonal (kept in ``diag0``): in a direction H does not constrain, elimination leaves only
    rounding noise of either sign, which a test for ``d_j > 0`` alone passes about half the time.
    """
    L[:] = 0.0
    for p in range(H.shape[0]):
        L[hmap[p]] = H[p]
    S = width.shape[0]
    j = 0
    for s in range(S):
        p0 = pstart[s]
        m = rows[s]
        for c in range(width[s]):
            diag0[j] = L[p0 + c * m + c]
            j += 1
    base = L.ctypes.data
    cbase = C.ctypes.data
    ip = iw.ctypes.data
    fp = fw.ctypes.data
    col = 0   # the supernode's first scalar column (postorder)
    for s in range(S):
        w = width[s]
        m = rows[s]
        r = m - w
        p0 = pstart[s]
        iw[_I0] = w
        iw[_I0 + 1] = m
        iw[_I0 + 3] = r
        if w <= small_panel:
            bad = _panel_small(L, p0, w, m)
            if bad != 0:
                return col + bad - 1
        elif w <= tile_panel:
            bad = _panel_tiles(L, p0, w, m, C)   # C is free until the update: scratch
            if bad != 0:
                return col + bad - 1
        else:
            iw[_I0 + 2] = 0
            _dpotrf(ip + 4 * _CL, ip + 4 * _I0, base + 8 * p0, ip + 4 * (_I0 + 1),
                    ip + 4 * (_I0 + 2))
            if iw[_I0 + 2] != 0:
                return col + iw[_I0 + 2] - 1
            if r > 0:
                # B <- B L11^-T : side R, lower, transposed, non-unit; B is r x w at p0 + w
                _dtrsm(ip + 4 * _CR, ip + 4 * _CL, ip + 4 * _CT, ip + 4 * _CN,
                       ip + 4 * (_I0 + 3), ip + 4 * _I0, fp, base + 8 * p0, ip + 4 * (_I0 + 1),
                       base + 8 * (p0 + w), ip + 4 * (_I0 + 1))
        # relative to the assembled diagonal (OpenBLAS's potf2 tests ``ajj <= 0``, which lets
        # NaN through: this test does not)
        for c in range(w):
            d = L[p0 + c * m + c]
            if not d * d > tol * diag0[col + c]:
                return col + c
        col += w
        if r > 0:   # the update B B^T, formed and scattered in chunks of whole column blocks
            jb = cb_ptr[s]
            jb_end = cb_ptr[s + 1]
            while jb < jb_end:
                c0 = cb_src[jb]
                je = jb + 1
                while je < jb_end and cb_src[je] + cb_dim[je] - c0 <= chunk:
                    je += 1
                k = cb_src[je - 1] + cb_dim[je - 1] - c0
                n = r - c0
                if w <= small_syrk:
                    ldc = (n + 7) & ~7
                    _update_tiles(L, p0 + w + c0, w, m, n, k, C, ldc)
                else:
                    ldc = n
                    iw[_I0 + 4] = k
                    iw[_I0 + 5] = n
                    iw[_I0 + 6] = n - k
                    b = base + 8 * (p0 + w + c0)
                    _dsyrk(ip + 4 * _CL, ip + 4 * _CN, ip + 4 * (_I0 + 4), ip + 4 * _I0, fp,
                           b, ip + 4 * (_I0 + 1), fp + 16, cbase, ip + 4 * (_I0 + 5))
                    if n > k:
                        _dgemm(ip + 4 * _CN, ip + 4 * _CT, ip + 4 * (_I0 + 6),
                               ip + 4 * (_I0 + 4), ip + 4 * _I0, fp, b + 8 * k,
                               ip + 4 * (_I0 + 1), b, ip + 4 * (_I0 + 1), fp + 16, cbase + 8 * k,
                               ip + 4 * (_I0 + 5))
                _scatter_update(L, C, ldc, c0, jb, je, cb_base, cb_ld, cb_src, cb_dim, run_ptr,
                                run_src, run_dst, run_len)
                jb = je
    return -1


@njit(cache=True, inline="always")
def _prefetch_block(L, jb, cb_base, cb_ld, cb_dim, run_ptr, run_dst, run_len):
    """Prefetch the target lines of update column block ``jb``."""
    tb = cb_base[jb]
    ldt = cb_ld[jb]
    for c in range(cb_dim[jb]):
        dcol = _u(tb + c * ldt)
        for q in range(run_ptr[jb], run_ptr[jb + 1]):
            d = dcol + _u(run_dst[q])
            e = d + _u(run_len[q])
            while d < e:
                _prefetch(L, d)
                d += _u(8)
            _prefetch(L, e - _u(1))


@njit(cache=True, inline="always")
def _scatter_update(L, C, ldc, c0, jb_start, jb_end, cb_base, cb_ld, cb_src, cb_dim, run_ptr,
                    run_src, run_dst, run_len):
    """Subtract a chunk of the update from the ancestors' panels (runs of rows).

    The chunk holds update rows and columns ``c0..`` of column blocks ``jb_start..jb_end``,
    column-major with ``ldc``. The targets of the next column block are prefetched while one
    is being subtracted.
    """
    for jb in range(jb_start, jb_end):
        if jb == jb_start:
            _prefetch_block(L, jb, cb_base, cb_ld, cb_dim, run_ptr, run_dst, run_len)
        if jb + 1 < jb_end:
            _prefetch_block(L, jb + 1, cb_base, cb_ld, cb_dim, run_ptr, run_dst, run_len)
        tb = cb_base[jb]
        ldt = cb_ld[jb]
        oj = cb_src[jb]
        q0 = run_ptr[jb]
        q1 = run_ptr[jb + 1]
        for c in range(cb_dim[jb]):
            scol = (oj + c - c0) * ldc - c0
            dcol = _u(tb + c * ldt)
            for q in range(q0, q1):
                sr = _u(scol + run_src[q])
                dr = dcol + _u(run_dst[q])
                k0 = _u(c) if q == q0 else _u(0)
                for k in range(k0, _u(run_len[q])):
                    L[dr + k] -= C[sr + k]


# ------------------------------------------------------------------ solve
@njit(cache=True, fastmath={"reassoc", "contract"})
def solve_inplace(L, x, pstart, width, rows, col0, rix_ptr, rix, buf):
    """Solve ``L L^T x = b`` in place (``x`` holds ``b`` in the factor's order).

    ``reassoc`` lets LLVM vectorize the dot products of the backward sweep (the summation order
    is fixed by the compiled code, so results are reproducible run to run).
    """
    S = width.shape[0]
    for s in range(S):                       # forward: L y = b
        w = _u(width[s])
        m = _u(rows[s])
        r = m - w
        p0 = _u(pstart[s])
        c0 = _u(col0[s])
        g0 = _u(rix_ptr[s]) + w
        for i in range(r):
            buf[i] = 0.0
        for c in range(w):
            cc = p0 + c * m
            xc = x[c0 + c] / L[cc + c]
            x[c0 + c] = xc
            for i in range(c + _u(1), w):
                x[c0 + i] -= L[cc + i] * xc
            cb = cc + w
            for i in range(r):
                buf[i] += L[cb + i] * xc
        for i in range(r):
            x[rix[g0 + i]] -= buf[i]
    for s in range(S - 1, -1, -1):           # backward: L^T x = y
        w = _u(width[s])
        m = _u(rows[s])
        r = m - w
        p0 = _u(pstart[s])
        c0 = _u(col0[s])
        g0 = _u(rix_ptr[s]) + w
        for i in range(r):
            buf[i] = x[rix[g0 + i]]
        for c in range(w - _u(1), -1, -1):
            cc = p0 + _u(c) * m
            cb = cc + w
            acc = 0.0
            for i in range(r):
                acc += L[cb + i] * buf[i]
            for i in range(_u(c) + _u(1), w):
                acc += L[cc + i] * x[c0 + i]
            x[c0 + _u(c)] = (x[c0 + _u(c)] - acc) / L[cc + _u(c)]


@njit(cache=True, fastmath={"contract"})
def solve_multi_inplace(L, X, nrhs, pstart, width, rows, col0, rix_ptr, rix, buf, acc):
    """``solve_inplace`` for ``nrhs`` right-hand sides: ``X`` is ``(n, nrhs)`` C-order, flat.

    Every inner loop runs over the right-hand sides (contiguous), so it vectorizes.
    """
    S = width.shape[0]
    k = _u(nrhs)
    for s in range(S):                       # forward
        w = _u(width[s])
        m = _u(rows[s])
        r = m - w
        p0 = _u(pstart[s])
        c0 = _u(col0[s])
        g0 = _u(rix_ptr[s]) + w
        for i in range(r * k):
            buf[i] = 0.0
        for c in range(w):
            cc = p0 + c * m
            xc = (c0 + c) * k
            inv = 1.0 / L[cc + c]
            for t in range(k):
                X[xc + t] *= inv
            for i in range(c + _u(1), w):
                f = L[cc + i]
                xi = (c0 + i) * k
                for t in range(k):
                    X[xi + t] -= f * X[xc + t]
            for i in range(r):
                f = L[cc + w + i]
                bi = i * k
                for t in range(k):
                    buf[bi + t] += f * X[xc + t]
        for i in range(r):
            xi = _u(rix[g0 + i]) * k
            bi = i * k
            for t in range(k):
                X[xi + t] -= buf[bi + t]
    for s in range(S - 1, -1, -1):           # backward
        w = _u(width[s])
        m = _u(rows[s])
        r = m - w
        p0 = _u(pstart[s])
        c0 = _u(col0[s])
        g0 = _u(rix_ptr[s]) + w
        for i in range(r):
            xi = _u(rix[g0 + i]) * k
            bi = i * k
            for t in range(k):
                buf[bi + t] = X[xi + t]
        for c in range(w - _u(1), -1, -1):
            cu = _u(c)
            cc = p0 + cu * m
            xc = (c0 + cu) * k
            for t in range(k):
                acc[t] = X[xc + t]
            for i in range(r):
                f = L[cc + w + i]
                bi = i * k
                for t in range(k):
                    acc[t] -= f * buf[bi + t]
            for i in range(cu + _u(1), w):
                f = L[cc + i]
                xi = (c0 + i) * k
                for t in range(k):
                    acc[t] -= f * X[xi + t]
            inv = 1.0 / L[cc + cu]
            for t in range(k):
                X[xc + t] = acc[t] * inv


def _cache_under_root() -> None:
    import sys

    from ..._cache_root import cache_module_in_root

    cache_module_in_root(sys.modules[__name__])  # numba's cache of these: fgopt's cache root


_cache_under_root()
