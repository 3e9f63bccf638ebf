"""Runtime helpers imported by generated kernel modules (numpy only: no SymPy here)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from .._jit import charge_numpy, numpy_budget_left, numpy_only
from ..errors import DimensionMismatchError

__all__ = ["NUMPY_MAX_BATCH", "charge_numpy", "kernel_array", "numpy_budget_left", "prepare",
           "use_numpy"]

#: Batches up to this size run a generated kernel's NumPy twin (same program on whole columns)
#: while the process's twin budget lasts (``fgopt._jit.numpy_budget_left``): no numba
#: compilation or cache load for small problems and new custom factors; larger batches, and
#: every batch once the budget is spent, run the numba kernel (compiled once, then loaded from
#: numba's cache).
NUMPY_MAX_BATCH = 1000


def use_numpy(n: int) -> bool:
    """Whether a batch of ``n`` instances runs the NumPy twin: every batch inside
    :func:`fgopt._jit.numpy_mode` (a problem on the NumPy backend), and small batches while the
    process's twin budget lasts (:func:`fgopt._jit.numpy_budget_left`)."""
    return numpy_only() or (n <= NUMPY_MAX_BATCH and numpy_budget_left())


def kernel_array(a: Any) -> np.ndarray:
    """``a`` as a C-contiguous, writeable float64 array: one numba signature for every caller.
    numba types a read-only array apart from a writeable one and compiles the kernel again for
    it (the IMU kernel took 40 s per extra signature; read-only arrays come from values and
    noise parameters that fgopt freezes)."""
    a = np.ascontiguousarray(a, dtype=np.float64)
    return a if a.flags.writeable else a.copy()


def prepare(args: Sequence[Any], consts: Any, storage_dims: Sequence[int], num_consts: int,
            name: str) -> tuple[tuple, np.ndarray]:
    """Check shapes and return C-contiguous float64 ``(args, consts)`` for a kernel call.

    Args:
        args: one ``(n, s_i)`` array per variable argument.
        consts: ``(n, c)`` constants (``None`` or an empty array when ``c == 0``).
        storage_dims: expected ``s_i``.
        num_consts: expected ``c``.
        name: kernel name, for error messages.
    """
    if len(args) != len(storage_dims):
        raise DimensionMismatchError(
            f"{name}: kernel takes {len(storage_dims)} variable arrays, got {len(args)}")
    out = []
    n = None
    for k, (a, s) in enumerate(zip(args, storage_dims)):
        a = kernel_array(a)
        if a.ndim != 2 or a.shape[1] != s or (n is not None and a.shape[0] != n):
            raise DimensionMismatchError(
                f"{name}: variable array {k} has shape {a.shape}, expected "
                f"({n if n is not None else 'n'}, {s})")
        n = a.shape[0]
        out.append(a)
    if consts is None or (num_consts == 0 and np.size(consts) == 0):
        c = np.empty((n, 0))
    else:
        c = kernel_array(consts)
        if c.ndim == 1 and n == 1:
            c = c.reshape(1, -1)
        if c.ndim != 2 or c.shape != (n, num_consts):
            raise DimensionMismatchError(
                f"{name}: constants have shape {c.shape}, expected ({n}, {num_consts})")
    return tuple(out), c
