"""Argument checks shared by the public API (solver parameters, noise models, generators,
cameras and their readers): one number, a float array, a positive number, a count. Callers
raise an :class:`~fgopt.errors.FgoptError` naming the argument when a check fails."""

from __future__ import annotations

from typing import Any

import numpy as np

from .errors import DimensionMismatchError


def number(x: Any) -> float | None:
    """``float(x)`` if ``x`` is one real number (not None, a bool, a string or an array), else
    None."""
    if type(x) is float or type(x) is int:  # the common case, without NumPy's ndim (~1 us)
        return float(x)
    if x is None or isinstance(x, (bool, str, bytes)) or np.ndim(x) != 0:
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
