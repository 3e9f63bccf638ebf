"""Numeric values of :func:`fgopt.symbolic.generate`'s functions: arguments to storage vectors
(checked), storage back to numeric values (``SO3`` for ``Rot3``, a declared manifold's
``Value``, arrays, floats). NumPy only."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import DimensionMismatchError, FgoptError, NonFiniteError
from .declare.twin import DeclaredManifold
from .lie import LieGroupBase
from .matrix import Matrix, Scalar

#: Symbolic types whose tangent space is not their storage (groups, declared manifolds).
MANIFOLD_TYPES = (LieGroupBase, DeclaredManifold)
#: Numeric twins of the symbolic groups (module fgopt.manifolds), for outputs of ``f(...)``.
_NUMERIC_TWIN = {"Rot2": "SO2", "Pose2": "SE2", "Rot3": "SO3", "Pose3": "SE3"}


def numeric_twin(tp: type):
    """The numeric class of a symbolic manifold type (``fgopt.manifolds``' ``SO3`` for ``Rot3``,
    a declared manifold's ``Value``, or one registered by a higher layer in
    ``fgopt.symbolic.ops.NUMERIC_TWINS`` where that registry exists), or ``None``."""
    from . import ops

    registered = getattr(ops, "NUMERIC_TWINS", {}).get(tp)
    if registered is not None:
        return registered
    if issubclass(tp, DeclaredManifold):  # @fgopt.manifold types carry their value class
        return getattr(tp, "Value", None)
    twin = _NUMERIC_TWIN.get(tp.__name__)
    if twin is None:
        return None
    from .. import manifolds

    return getattr(manifolds, twin, None)


def numeric_value(tp: type, storage: np.ndarray):
    """Storage of a value of symbolic type ``tp`` as a numeric value.

    Groups with a numeric twin become ``SO3`` / ``SE3`` / ... values, other groups stay storage
    vectors; vectors are ``(n,)`` arrays, matrices ``(r, c)``, scalars floats.
    """
    if tp is Scalar:
        return float(storage[0])
    if issubclass(tp, Matrix):
        r, c = tp.SHAPE
        return storage.copy() if c == 1 else storage.reshape(r, c).copy()
    twin = numeric_twin(tp)
    return twin.from_storage(storage) if twin is not None else storage.copy()


def value_storage(fname: str, name: str, tp: type, value: Any) -> np.ndarray:
    """A numeric value of symbolic type ``tp`` as its storage vector (checked: size, finite,
    numeric twin type). ``fname`` and ``name`` go into error messages."""
    s = tp.storage_dim()
    if issubclass(tp, MANIFOLD_TYPES) and hasattr(value, "to_storage"):
        twin = numeric_twin(tp)
        if twin is not None and not isinstance(value, twin):
            raise FgoptError(f"{fname}: argument '{name}' is a {tp.__name__}; got a "
                             f"{type(value).__name__} (give a {twin.__module__}.{twin.__name__} "
                             "or its storage)")
        value = value.to_storage()
    try:
        arr = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise DimensionMismatchError(f"{fname}: argument '{name}' ({tp.__name__}) must be "
                                     f"{s} numbers, got {value!r}") from exc
    if arr.shape[0] != s:
        raise DimensionMismatchError(f"{fname}: argument '{name}' ({tp.__name__}) needs {s} "
                                     f"numbers (its storage), got {arr.shape[0]}")
    if not np.all(np.isfinite(arr)):
        raise NonFiniteError(f"{fname}: argument '{name}' is not finite: {arr}")
    return arr


def _batch_storage(fname: str, name: str, tp: type, value: Any) -> np.ndarray:
    """One batched argument as ``(n, storage_dim)`` (``n = 1``: the same for every row)."""
    s = tp.storage_dim()
    if isinstance(value, (list, tuple)) and len(value) > 0 and hasattr(value[0], "to_storage"):
        value = np.stack([value_storage(fname, name, tp, v) for v in value])
    elif hasattr(value, "to_storage"):
        value = value_storage(fname, name, tp, value)
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise DimensionMismatchError(f"{fname}: argument '{name}' ({tp.__name__}): cannot "
                                     f"read {value!r} as numbers") from exc
    if tp is Scalar and arr.ndim <= 1:
        return arr.reshape(-1, 1)
    if arr.ndim == 1 and arr.shape[0] == s:
        return arr.reshape(1, s)
    if arr.ndim == 2 and arr.shape[1] == s:
        return arr
    if arr.ndim == 3 and issubclass(tp, Matrix) and arr.shape[1:] == tp.SHAPE:
        return arr.reshape(arr.shape[0], s)
    raise DimensionMismatchError(f"{fname}: argument '{name}' ({tp.__name__}) must be "
                                 f"({s},) or (n, {s}), got shape {arr.shape}")
