"""Symbolic analysis of the Schur solver (numpy, once per problem): which blocks of H are the
camera-point edges and where they sit, the block layout of the reduced system S, and the maps
from H's data array into S's packed block store and from there into the factored matrix.

Conventions of :mod:`fgopt.solvers.linear._schur_kernels`. ``E`` / ``F`` = eliminated / kept
variables; F variables are numbered by H offset and placed in S in ``order`` (``f_soff``).
"""

from __future__ import annotations

import numpy as np

from ..._jit import njit
from ...errors import FgoptError
from ...structure import HessianPattern, ba_shaped_kind, kinds_by_count, ranges
from . import _schur_kernels as K


def blocks(pattern: HessianPattern) -> tuple:
    """``(row vars, column vars, (0, 0) positions)`` of the off-diagonal blocks of H."""
    rv, cv, p00 = pattern.blocks()
    off = rv != cv
    return rv[off], cv[off], p00[off]


def is_independent(pattern: HessianPattern, mask: np.ndarray, blk: tuple | None = None) -> bool:
    """True when no stored block of H couples two variables of ``mask``."""
    brv, bcv, _ = blocks(pattern) if blk is None else blk
    return not np.any(mask[brv] & mask[bcv])


def edges(pattern: HessianPattern, is_e: np.ndarray, blk: tuple) -> dict:
    """E-F edges (orientation 0: block in e's columns, f after e; 1: in f's columns) and F-F
    couplings. F variables are numbered by H offset, E variables likewise."""
    var_off, V = pattern.var_offset, pattern.var_offset.shape[0]
    brv, bcv, p00 = blk
    if np.any(is_e[brv] & is_e[bcv]):
        raise FgoptError("SchurSolver: the variables chosen for elimination are not "
                         "independent (a factor couples two of them); pass eliminate=... "
                         "or choose another linear solver")
    f_vars = np.nonzero(~is_e)[0]
    f_vars = f_vars[np.argsort(var_off[f_vars], kind="stable")]
    e_vars = np.nonzero(is_e)[0]
    e_vars = e_vars[np.argsort(var_off[e_vars], kind="stable")]
    fidx = np.full(V, -1, dtype=np.int64)
    fidx[f_vars] = np.arange(f_vars.shape[0])
    eidx = np.full(V, -1, dtype=np.int64)
    eidx[e_vars] = np.arange(e_vars.shape[0])
    o0 = is_e[bcv] & ~is_e[brv]
    o1 = is_e[brv] & ~is_e[bcv]
    ff = ~is_e[brv] & ~is_e[bcv]
    return {
        "e_vars": e_vars, "f_vars": f_vars,
        "edge_e": np.concatenate([eidx[bcv[o0]], eidx[brv[o1]]]),
        "edge_f": np.concatenate([fidx[brv[o0]], fidx[bcv[o1]]]),
        "edge_p00": np.concatenate([p00[o0], p00[o1]]),
        "edge_orient": np.concatenate([np.zeros(int(o0.sum()), np.int64),
                                       np.ones(int(o1.sum()), np.int64)]),
        "ff_i": fidx[brv[ff]], "ff_j": fidx[bcv[ff]]}


def a_entries(pattern: HessianPattern, s_to_h: np.ndarray):
    """Entries of ``H_FF``: data positions in H and their lower (row, col) in S scalars."""
    h_to_s = np.full(pattern.size, -1, dtype=np.int64)
    h_to_s[s_to_h] = np.arange(s_to_h.shape[0])
    rv, cv, p00 = pattern.blocks()
    off = pattern.var_offset
    ff = (h_to_s[off[rv]] >= 0) & (h_to_s[off[cv]] >= 0)
    return _block_entries(rv[ff], cv[ff], p00[ff], off, pattern.var_dim, pattern.col_shift,
                          h_to_s)


@njit(cache=True)
def _block_entries(rv, cv, p00, var_off, var_dim, col_shift, h_to_s):
    """Every stored entry of the given blocks: data position, lower (row, col) via h_to_s."""
    n = 0
    for b in range(rv.shape[0]):
        dc, dr = var_dim[cv[b]], var_dim[rv[b]]
        n += dc * (dc + 1) // 2 if rv[b] == cv[b] else dc * dr
    pos = np.empty(n, dtype=np.int64)
    row = np.empty(n, dtype=np.int64)
    col = np.empty(n, dtype=np.int64)
    n = 0
    for b in range(rv.shape[0]):
        oc, orow = var_off[cv[b]], var_off[rv[b]]
        for c in range(var_dim[cv[b]]):
            for a in range(c if rv[b] == cv[b] else 0, var_dim[rv[b]]):
                pos[n] = p00[b] + col_shift[oc + c] + a
                sr, sc = h_to_s[orow + a], h_to_s[oc + c]
                row[n], col[n] = max(sr, sc), min(sr, sc)
                n += 1
    return pos, row, col


def co_observation_pairs(edge_ptr: np.ndarray, edge_f: np.ndarray, nF: int):
    """Unique pairs ``(f1 > f2)`` of F variables that share an E variable (sorted)."""
    codes = K.co_observation_codes(edge_ptr, np.ascontiguousarray(edge_f, dtype=np.int64), nF)
    return codes // nF, codes % nF


def packed_blocks(nF, f_dim, f_soff, f_rank, edge_ptr, edge_f, co_i, co_j, ff_i, ff_j, a_row,
                  a_col):
    """The packed block store of S and the maps into it.

    Blocks ``(row var br, column var bc)`` with ``rank(br) >= rank(bc)``: every diagonal block,
    every pair of F variables sharing an E variable (``co_i, co_j``), every F-F coupling of H.
    Block ``b`` is a column-major ``dr x dc`` array at ``pk_off[b]``; its code ``bc * nF + br``
    is ``codes[b]`` (sorted; column ``bc``'s blocks are ``codes[col_ptr[bc]:col_ptr[bc + 1]]``).
    ``pair_blk[pair_ptr[e] + t]`` is the block of e's t-th pair of edges ``(ki >= kj)`` (edges
    sorted by ``(e, rank of f)``), int32 while the blocks allow (12 bytes per pair fewer than
    int64 indices; looked up once here by bisection in ``codes``, not per iteration).
    Returns a dict with the kernels' arrays (``pair_ptr``, ``pair_blk``, ``blk_ptr``, ``blk_base``),
    ``a_dst`` (H_FF -> packed), the lower entries of the store (``pk_src``) with their S
    ``srow`` / ``scol``, and the pairs ``fi, fj`` (for a sparse pattern).
    """
    def lower_first(i, j):  # (row, column) with rank(row) >= rank(column)
        lo = f_rank[i] >= f_rank[j]
        return np.where(lo, i, j), np.where(lo, j, i)

    ci, cj = lower_first(co_i, co_j)
    fi, fj = lower_first(ff_i, ff_j)
    codes = np.unique(np.concatenate([cj * nF + ci, fj * nF + fi,
                                      np.arange(nF, dtype=np.int64) * (nF + 1)]))
    bc, br = codes // nF, codes % nF
    dr, dc = f_dim[br], f_dim[bc]
    pk_off = np.concatenate([[0], np.cumsum(dr * dc)]).astype(np.int64)
    blk_of = np.repeat(np.arange(codes.shape[0]), dr * dc)
    loc = ranges(dr * dc)
    srow = f_soff[br][blk_of] + loc % dr[blk_of]
    scol = f_soff[bc][blk_of] + loc // dr[blk_of]
    pk_src = np.nonzero(srow >= scol)[0]
    f_of_s = np.repeat(np.argsort(f_rank), f_dim[np.argsort(f_rank)])
    fr, fc = f_of_s[a_row], f_of_s[a_col]
    blk = np.searchsorted(codes, fc * nF + fr)
    k = np.diff(edge_ptr)
    pair_ptr = np.zeros(k.shape[0] + 1, dtype=np.int64)
    np.cumsum(k * (k + 1) // 2, out=pair_ptr[1:])
    pair_blk = np.empty(int(pair_ptr[-1]),
                        dtype=np.int32 if codes.shape[0] < 2**31 else np.int64)
    col_ptr = np.searchsorted(codes, np.arange(nF + 1, dtype=np.int64) * nF)
    K.pair_blocks(edge_ptr, edge_f, codes, col_ptr, nF, pair_ptr, pair_blk)
    return {
        "pair_ptr": pair_ptr, "pair_blk": pair_blk,
        "blk_ptr": np.concatenate([[0], np.cumsum(dc)]).astype(np.int64),
        "blk_base": np.repeat(pk_off[:-1], dc) + ranges(dc) * np.repeat(dr, dc),
        "pk_off": pk_off, "br": br, "bc": bc,
        "a_dst": pk_off[blk] + (a_col - f_soff[fc]) * f_dim[fr] + (a_row - f_soff[fr]),
        "pk_src": pk_src, "srow": srow[pk_src], "scol": scol[pk_src],
        "ci": ci, "cj": cj, "fi": fi, "fj": fj}


def csc_positions(pat: HessianPattern, row: np.ndarray, col: np.ndarray) -> np.ndarray:
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


def is_ba_shaped(pattern: HessianPattern) -> bool:
    """True when the kind with the most variables is independent (no factor couples two of
    its variables), has at least twice as many variables as all others together and at least
    half of the tangent dimension: eliminating it leaves a much smaller reduced system
    (:func:`fgopt.structure.ba_shaped_kind`)."""
    kinds = pattern.var_kind
    if kinds is None or pattern.size == 0:
        return False
    if pattern.ba_kind is not None:  # asked before (the solver choice, LM's policy, ...)
        return pattern.ba_kind >= 0
    kinds = np.asarray(kinds)
    known = pattern.independent_kinds
    if known is None:  # a pattern not built by a Problem: look at its blocks
        by_count = kinds_by_count(kinds)
        if not by_count or not is_independent(pattern, kinds == by_count[0]):
            pattern.ba_kind = -1
            return False
        known = (by_count[0],)
    kind = ba_shaped_kind(kinds, pattern.var_dim, known)
    pattern.ba_kind = -1 if kind is None else kind
    return kind is not None
