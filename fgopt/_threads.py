"""Multi-threaded linearization (the ``threads`` option; off by default).

A batch is split into ``threads`` contiguous chunks whose kernels run concurrently in a thread
pool (generated kernels are compiled with ``nogil=True``, so chunks really run in parallel;
kernels holding the GIL just run one after another, still correctly). The weighted local
``J^T J`` / ``J^T r`` blocks are then formed in a numba ``prange`` loop, and added into H by one
serial scatter, so no two threads ever write the same entry of H: results are bitwise the same
as the serial path's up to summation order within a factor (none).
"""

from __future__ import annotations

import contextlib
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

from . import _assembly as asm

#: Batches smaller than this are linearized serially (threads would cost more than they save).
PARALLEL_MIN_BATCH = 512

_pools: dict[int, ThreadPoolExecutor] = {}


def _pool(threads: int) -> ThreadPoolExecutor:
    pool = _pools.get(threads)
    if pool is None:
        pool = _pools[threads] = ThreadPoolExecutor(max_workers=threads,
                                                    thread_name_prefix="fgopt-linearize")
    return pool


def linearize_batch_threaded(problem: Any, b: Any, state: Any, H: np.ndarray, g: np.ndarray,
                             lo: int = 0, hi: int | None = None) -> float:
    """Linearize instances ``lo:hi`` of batch ``b`` with ``problem.threads`` threads; add them
    into ``H``/``g``; return their cost."""
    threads = problem.threads
    hi = len(b.source) if hi is None else hi
    n = hi - lo
    args = b.gather(state, lo, hi)
    consts = b.source.constants[lo:hi]
    bounds = np.linspace(0, n, threads + 1).astype(int)

    def run(c: int):
        s, e = bounds[c], bounds[c + 1]
        return b.kernel.linearize(tuple(a[s:e] for a in args), consts[s:e])

    parts = list(_pool(threads).map(run, range(threads)))
    res = np.concatenate([p[0] for p in parts])
    jac = np.concatenate([p[1] for p in parts])
    D = jac.shape[2]
    if getattr(b, "_Hl", None) is None or b._Hl.shape[0] < n:
        b._Hl, b._gl = np.empty((n, D, D)), np.empty((n, D))
    Hl, gl = b._Hl[:n], b._gl[:n]
    import numba

    previous = numba.get_num_threads()
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    try:
        cost = asm.local_blocks_parallel(res, jac, b.sqrt_info_of(lo, hi), b.unit,
                                         b.source.loss_code, b.source.loss_param,
                                         b.source.loss_shape, Hl, gl, b.weights[lo:hi])
    finally:
        numba.set_num_threads(previous)
    asm.scatter_local_blocks(Hl, gl, b.arg_dims, b.arg_local_off, b.toff[lo:hi], b.pos[lo:hi],
                             problem.assembly_shift, H, g)
    return float(cost)


#: Problems with fewer unknowns than this call the BLAS as it is set: OpenBLAS keeps a call this
#: small on one thread itself (its GEMM threads from ``m n k`` ~ 64^3 on), and taking the limit
#: (~50 us) would cost a tiny solve up to a third of its time.
BLAS_LIMIT_MIN_SIZE = 64
_controller: list = [None, -1]  # threadpoolctl's controller, len(sys.modules) when it was made


def blas_threads(size: int, threads: int = 1) -> Any:
    """A context in which the BLAS libraries loaded in this process use ``threads`` threads,
    restored on exit (a problem of ``size`` unknowns; below :data:`BLAS_LIMIT_MIN_SIZE`, a no-op).

    fgopt's own calls only: a BLAS that spins threads beside numba kernels made LM on
    Ladybug-49 5.5x slower on 2 cores (12.7 s vs 2.3 s), but a user's numpy code outside
    fgopt keeps the process's settings."""
    if size < BLAS_LIMIT_MIN_SIZE:
        return contextlib.nullcontext()
    import sys

    from threadpoolctl import ThreadpoolController

    if _controller[1] != len(sys.modules):  # a new extension may have loaded another BLAS
        _controller[:] = [ThreadpoolController(), len(sys.modules)]
    return _controller[0].limit(limits=max(1, int(threads)), user_api="blas")
