"""Runtime helper of generated manifold modules (numpy only: no SymPy here)."""

from __future__ import annotations

from typing import Any

import numpy as np

from ...errors import DimensionMismatchError
from ..runtime import kernel_array


def as_rows(a: Any, cols: int, name: str, what: str, rows: int | None = None) -> np.ndarray:
    """``a`` as a C-contiguous, writeable float64 ``(n, cols)`` array (one numba signature for
    every caller), or a :class:`~fgopt.errors.DimensionMismatchError` naming the manifold."""
    a = kernel_array(a)
    if a.ndim == 1 and a.shape[0] == cols:
        a = a.reshape(1, cols)
    if a.ndim != 2 or a.shape[1] != cols or (rows is not None and a.shape[0] != rows):
        want = f"({rows if rows is not None else 'n'}, {cols})"
        raise DimensionMismatchError(f"{name}: {what} has shape {a.shape}, expected {want}")
    return a
