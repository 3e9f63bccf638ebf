"""Argument checks shared by the camera API and its readers: one number, a float array, a
positive tolerance, an iteration count (each failure an :class:`~fgopt.errors.FgoptError`)."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import DimensionMismatchError


def number(x: Any) -> float | None:
    """``float(x)`` if ``x`` is one real number (not None, a bool or an array), else None."""
    if x is None or isinstance(x, bool) or np.ndim(x) != 0:
        return None
    try:
        return float(x)
    except (TypeError, ValueError):
        return None


def float_array(values: Any, what: str, expected: str) -> np.ndarray:
    """``np.asarray(values, dtype=float)``; non-numbers or ragged: DimensionMismatchError."""
    try:
        return np.asarray(values, dtype=float)
    except (TypeError, ValueError):
        raise DimensionMismatchError(f"{what}: expected {expected}, got {values!r:.80}") from None


def is_positive(x: Any) -> bool:
    """Whether ``x`` is one finite number > 0."""
    f = number(x)
    return f is not None and 0.0 < f < np.inf


def is_count(n: Any) -> bool:
    """Whether ``n`` is a whole number >= 0 (an int, or a float such as ``20.0``)."""
    f = number(n)
    return f is not None and 0.0 <= f < np.inf and f == int(f)
