"""Storage / tangent operations for every symbolic type, in one place (SymForce's *Ops* idea).

Types that can be factor arguments: ``Rot2, Rot3, Pose2, Pose3`` (Lie groups), fixed-shape
matrices and vectors (``V3``, ``Matrix.shaped(3, 3)``), :class:`~fgopt.symbolic.Scalar`
(``float`` / ``int`` annotations mean Scalar too) and manifolds declared with
``@fgopt.manifold`` (:mod:`fgopt.symbolic.declare`).
"""

from __future__ import annotations

from typing import Any

from ..errors import ManifoldError
from .declare.twin import DeclaredManifold
from .lie import LieGroupBase
from .matrix import Matrix, Scalar

#: Values with a tangent space of their own (storage_D_tangent is not the identity).
_MANIFOLD_VALUES = (LieGroupBase, DeclaredManifold)


def _s():
    from . import _sym

    return _sym


#: Symbolic type -> numeric value class (with ``batch_kind()``) for types whose numeric twin
#: lives above the symbolic layer (``fgopt.navigation.NavState``); the twin's package registers
#: itself on import (:func:`register_numeric_twin`).
NUMERIC_TWINS: dict = {}


def register_numeric_twin(symbolic_type: type, numeric_cls: type) -> None:
    """Variables of ``symbolic_type`` in ``@fgopt.factor`` hold ``numeric_cls`` values."""
    NUMERIC_TWINS[symbolic_type] = numeric_cls


def is_symbolic_type(tp: Any) -> bool:
    if tp in (float, int, Scalar):
        return True
    if not isinstance(tp, type):
        return False
    if issubclass(tp, LieGroupBase):
        return True
    if issubclass(tp, DeclaredManifold):
        return tp._DECLARED
    return issubclass(tp, Matrix) and tp.SHAPE is not None


def normalize_type(tp: Any) -> type:
    """``float``/``int`` -> :class:`Scalar`; other supported types unchanged."""
    if tp in (float, int):
        return Scalar
    if not is_symbolic_type(tp):
        name = getattr(tp, "__name__", repr(tp))
        raise ManifoldError(
            f"{name} is not a symbolic argument type: use Rot2, Rot3, Pose2, Pose3, NavState, "
            "V1..V9, Matrix.shaped(r, c), Scalar or a manifold declared with @fgopt.manifold")
    return tp


def has_own_tangent(value: Any) -> bool:
    """True for Lie group and declared-manifold values (their tangent is not their storage)."""
    return isinstance(value, _MANIFOLD_VALUES)


def type_key(tp: type) -> tuple:
    """What identifies an argument type in kernel cache keys (declared manifolds add their
    declaration key: editing the declaration changes the factors derived over it)."""
    tp = normalize_type(tp)
    return (tp.__module__, tp.__qualname__) + ((tp._KEY,) if issubclass(tp, DeclaredManifold)
                                               else ())


def type_storage_dim(tp: type) -> int:
    return normalize_type(tp).storage_dim()


def type_dim(tp: type) -> int:
    return normalize_type(tp).dim()


def type_name(tp: type) -> str:
    return normalize_type(tp).__name__


def symbolic_value(tp: type, name: str) -> Any:
    """A value of type ``tp`` whose storage entries are the real symbols ``name_k``.

    Scalars are the single symbol ``name``.
    """
    tp = normalize_type(tp)
    return tp.symbolic(name)


def from_storage(tp: type, data: Any) -> Any:
    return normalize_type(tp).from_storage(data)


def storage_of(value: Any) -> list:
    """The storage entries of a symbolic value (SymPy expressions)."""
    if isinstance(value, (LieGroupBase, DeclaredManifold, Matrix)):
        return [_s().as_expr(e) for e in value.to_storage()]
    if hasattr(value, "to_storage") and not isinstance(value, _s().sp.Basic):
        return [_s().as_expr(e) for e in value.to_storage()]
    return [_s().as_expr(value)]


#: ``storage_D_tangent`` by (type, storage): both derivative engines of a derivation ask for
#: each argument's (a Jacobian of the retraction: ~0.1 s of SymPy for a Pose3).
_SDT_MEMO: dict = {}


def storage_D_tangent_of(value: Any):
    """``d S(value (+) v) / dv`` at 0 as a SymPy matrix (identity for vectors and scalars)."""
    if not isinstance(value, _MANIFOLD_VALUES):
        return _s().sp.eye(len(storage_of(value)))
    key = (type(value), tuple(storage_of(value)))
    D = _SDT_MEMO.get(key)
    if D is None:
        if len(_SDT_MEMO) >= 64:
            _SDT_MEMO.clear()
        D = _SDT_MEMO[key] = value.storage_D_tangent()
    return D.copy()


def tangent_D_storage_of(value: Any):
    if isinstance(value, _MANIFOLD_VALUES):
        return value.tangent_D_storage()
    return _s().sp.eye(len(storage_of(value)))


def tangent_dim_of(value: Any) -> int:
    if isinstance(value, _MANIFOLD_VALUES):
        return value.dim()
    return len(storage_of(value))
