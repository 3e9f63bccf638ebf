"""Sparse Cholesky with CHOLMOD (scikit-sparse, the optional ``fgopt[cholmod]`` extra): symbolic analysis once, numeric each step.

The problem already orders variables with a fill-reducing order of the block graph, so CHOLMOD
is told ``ordering_method="natural"`` by default; ``"amd"``, ``"metis"``... let CHOLMOD order the
scalar matrix instead. ``mode`` picks supernodal or simplicial factorization (``"auto"``: CHOLMOD's
own choice by flop count) is replaced by a measured rule: simplicial for problems whose variables
have at most 3 tangent dimensions on average (2D pose graphs: M3500 factors in 5.3 ms simplicial vs
7.4 ms supernodal), supernodal otherwise (sphere2500: 35 ms vs 195 ms simplicial, with OpenBLAS;
``python -m benchmarks.factorization``).

Every numeric factorization runs inside :func:`serial_openmp`: SuiteSparse 5's CHOLMOD asks for
a team of 4 OpenMP threads (a compile-time constant) for the scatter loops of its supernodal
factorization, whatever the machine has. On 2 cores those threads mostly wait on each other:
sphere2500's H factors in 30-45 ms with the loops serial, 60-150 ms with them threaded (the
dense updates still use the BLAS's own threads).
"""

from __future__ import annotations

import os
import threading
import warnings
from contextlib import contextmanager
from typing import Iterator

import numpy as np

from ...errors import NotPositiveDefiniteError, have_extra, missing_extra
from ...structure import HessianPattern
from .base import PIVOT_TOLERANCE, pivot_failure


# Held for the whole region: OpenMP 5 runtimes keep max-active-levels per thread, older ones
# per process, and holding the lock makes the save / set / restore right under both. It costs
# nothing: scikit-sparse holds the GIL while CHOLMOD factors, so factorizations never overlap.
_openmp_lock = threading.RLock()
_openmp_api = None  # (omp_get_max_active_levels, omp_set_max_active_levels), or False


def _openmp_levels_api():
    """The OpenMP runtime CHOLMOD is linked with, as its max-active-levels getter and setter
    (``False`` when CHOLMOD has no OpenMP, or the extra is not installed)."""
    global _openmp_api
    if _openmp_api is None:
        _openmp_api = False
        try:
            import ctypes

            import sksparse.cholmod as module

            # a handle on the (already loaded) extension: symbol lookups search its
            # dependencies too, so this finds the OpenMP runtime its libcholmod was linked with
            lib = ctypes.CDLL(module.__file__, mode=getattr(os, "RTLD_NOLOAD", 0))
            get, set_ = lib.omp_get_max_active_levels, lib.omp_set_max_active_levels
            get.restype, set_.argtypes = ctypes.c_int, [ctypes.c_int]
            _openmp_api = (get, set_)
        except (ImportError, OSError, AttributeError):
            pass
    return _openmp_api


@contextmanager
def serial_openmp() -> Iterator[None]:
    """Run CHOLMOD's OpenMP parallel regions with one thread while inside (``max-active-levels``
    0: every region is inactive, whatever its ``num_threads`` clause asks); the value found is
    restored on the way out (nesting and exceptions included)."""
    api = _openmp_levels_api()
    if not api:
        yield
        return
    get, set_ = api
    with _openmp_lock:
        saved = get()
        set_(0)
        try:
            yield
        finally:
            set_(saved)


class CholmodSolver:
    name = "cholmod"

    def __init__(self, mode: str = "auto", ordering_method: str = "natural",
                 pivot_tolerance: float = PIVOT_TOLERANCE):
        if not have_extra("sksparse"):
            raise missing_extra("sksparse", "linear_solver='cholmod'")
        #: A pivot must exceed this times its diagonal entry of H (:data:`.base.PIVOT_TOLERANCE`).
        self.pivot_tolerance = float(pivot_tolerance)
        self.mode = mode
        self.ordering_method = ordering_method
        self._factor = None
        self._pattern: HessianPattern | None = None

    def analyze(self, pattern: HessianPattern) -> None:
        from sksparse.cholmod import analyze

        self._pattern = pattern
        mode = self.mode
        if mode == "auto":
            mode = "simplicial" if float(np.mean(pattern.var_dim)) <= 3.0 else "supernodal"
        self._supernodal = mode == "supernodal"
        A = pattern.matrix(np.ones(pattern.nnz))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            self._factor = analyze(A, mode=mode, ordering_method=self.ordering_method)

    def factorize(self, H_data: np.ndarray) -> None:
        from sksparse.cholmod import CholmodNotPositiveDefiniteError

        pattern = self._pattern
        A = pattern.matrix(H_data)
        F = self._factor
        try:
            with warnings.catch_warnings(), serial_openmp():
                warnings.simplefilter("ignore")
                F.cholesky_inplace(A)
                # CHOLMOD fails on a pivot <= 0 only; the relative test needs the pivots: a
                # simplicial factor is L D L^T already, a supernodal one is converted on a copy
                # (the solves keep the factor CHOLMOD made; sphere2500: ~+10 % per factorization)
                D = (F.copy() if self._supernodal else F).D()
        except CholmodNotPositiveDefiniteError as e:   # a pivot <= 0 (e.column: where)
            column = getattr(e, "column", None)
            if column is None or not 0 <= column < pattern.size:
                raise NotPositiveDefiniteError(
                    f"CHOLMOD: H is not positive definite ({e})") from None
            bad = int(F.P()[column])
        else:
            P = F.P()   # A[P][:, P] = L D L^T
            ok = D > self.pivot_tolerance * H_data[pattern.diag_pos][P]   # (NaN fails)
            if np.all(ok):
                return
            bad = int(P[np.argmin(ok)])
        raise pivot_failure("CHOLMOD", pattern.var_offset, pattern.var_dim, bad,
                            self.pivot_tolerance)

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        return self._factor(rhs)
