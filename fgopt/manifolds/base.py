"""Manifold traits: how fgopt reads any value type as a point on a manifold.

A *manifold ops* object (the traits idea of miniSAM and SymForce's LieGroupOps) answers, for
values of one Python type:

- ``dim(x)``: tangent dimension; ``storage_dim(x)``: floats stored;
- ``to_storage(x)`` -> 1-D float array, ``from_storage(like, data)`` -> value shaped like ``like``;
- ``retract(x, delta)`` = x (+) delta, ``local(x, y)`` = y (-) x in x's tangent space
  (so ``retract(x, local(x, y)) == y``);
- ``batch_kind(x)`` -> a :class:`BatchKind` when values of this type can live in one contiguous
  ``(n, storage_dim)`` array with numba-batched retract / local (the optimizer's fast path), or
  ``None`` (the slow path: the optimizer calls the Python methods one value at a time).

Types are found by :func:`ops_for`: registered classes first (:func:`register`), then ``float`` /
``int`` (1-D vector space), 1-D numpy arrays (R^n), and finally any object with miniSAM-style
``dim()``, ``local(other)`` and ``retract(vec)`` methods, which works without registering.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any, Callable, Protocol, runtime_checkable

from .._jit import njit
import numpy as np

from ..errors import DimensionMismatchError, ManifoldError


@dataclass(frozen=True, eq=False)
class BatchKind:
    """A manifold type whose values are stored as rows of one ``(n, storage_dim)`` float array.

    ``retract(x (n, s), delta (n, d)) -> (n, s)`` and ``local(a (n, s), b (n, s)) -> (n, d)`` are
    batched (numba) functions. ``from_storage(row)`` and ``to_storage(value)`` convert one value.
    Kinds compare by identity: there is one object per kind (``vector_kind(3)`` is cached).

    >>> from fgopt.manifolds import SE2, ops_for
    >>> kind = ops_for(SE2()).batch_kind(SE2())
    >>> kind.name, kind.dim, kind.storage_dim               # SE(2) stored as (x, y, cos, sin)
    ('SE2', 3, 4)
    """

    name: str
    dim: int
    storage_dim: int
    retract: Callable[[np.ndarray, np.ndarray], np.ndarray] = field(repr=False)
    local: Callable[[np.ndarray, np.ndarray], np.ndarray] = field(repr=False)
    from_storage: Callable[[np.ndarray], Any] = field(repr=False)
    to_storage: Callable[[Any], np.ndarray] = field(repr=False)
    #: Build a value from an owned, read-only storage row already on the manifold (no checks,
    #: no normalization): the fast path for bulk construction. ``None``: use ``from_storage``.
    wrap: Callable[[np.ndarray], Any] | None = field(default=None, repr=False)
    #: ``wrap`` of every row of an owned, read-only ``(n, storage_dim)`` array, as a list (a
    #: kind may build them faster than one ``wrap`` call per row). ``None``: ``wrap`` per row.
    wrap_rows: Callable[[np.ndarray], list] | None = field(default=None, repr=False)
    #: What the kernels compute, for cache keys of code generated over this kind (declared
    #: manifolds: their declaration key; built-in kinds: empty, their name says it all).
    key: str = field(default="", repr=False)

    def __post_init__(self) -> None:
        _KINDS.setdefault(self.name, self)

    def wrap_all(self, rows: np.ndarray) -> list:
        """``[wrap(row) for row in rows]`` (``rows`` owned and read-only; ``wrap`` required)."""
        if self.wrap_rows is not None:
            return self.wrap_rows(rows)
        return list(map(self.wrap, rows))

    def __reduce__(self):
        # Kinds compare by identity, so a pickled kind is the same-named kind of the receiving
        # process (its batched functions are that process's compiled code, never shipped).
        if _KINDS.get(self.name) is not self:
            raise ManifoldError(f"manifold kind {self.name!r} cannot be pickled: another kind of "
                                "that name was made first in this process")
        return (kind_named, (self.name,))


#: Every kind made in this process, by name (the first of a name wins).
_KINDS: dict[str, BatchKind] = {}


def kind_named(name: str) -> BatchKind:
    """The kind called ``name`` in this process (how pickled kinds are restored)."""
    kind = _KINDS.get(name)
    if kind is None:
        from .. import manifolds  # noqa: F401  (registers the built-in groups' kinds)

        kind = _KINDS.get(name)
    if kind is None and name.startswith("R") and name[1:].isdigit():
        kind = vector_kind(int(name[1:]))
    if kind is None:
        raise ManifoldError(f"no manifold kind named {name!r} in this process: import the module "
                            "that defines it before unpickling values or factors of that kind")
    return kind


@runtime_checkable
class ManifoldOps(Protocol):
    """The traits protocol; see the module docstring. Every value type has one
    (:func:`ops_for`); a new type gets one with :func:`register`.

    >>> from fgopt.manifolds import SE2, ops_for
    >>> ops = ops_for(SE2())
    >>> ops.dim(SE2()), ops.storage_dim(SE2())
    (3, 4)
    >>> np.round(ops.local(SE2(), SE2.from_xytheta(1.0, 2.0, 0.5)), 6)   # [theta, x, y]
    array([0.5     , 1.479079, 1.708159])
    """

    def dim(self, x: Any) -> int: ...

    def storage_dim(self, x: Any) -> int: ...

    def to_storage(self, x: Any) -> np.ndarray: ...

    def from_storage(self, like: Any, data: np.ndarray) -> Any: ...

    def retract(self, x: Any, delta: np.ndarray) -> Any: ...

    def local(self, x: Any, y: Any) -> np.ndarray: ...

    def batch_kind(self, x: Any) -> BatchKind | None: ...


_registry: dict[type, ManifoldOps] = {}


def register(cls: type, ops: ManifoldOps) -> None:
    """Register ``ops`` as the manifold traits of ``cls`` (and its subclasses).

    A heading angle as a 1-dimensional manifold (no batch kind: the optimizer's Python path):

    >>> from fgopt.manifolds import ops_for, register
    >>> class Heading:
    ...     def __init__(self, angle):
    ...         self.angle = float(angle)
    >>> class HeadingOps:
    ...     def dim(self, x): return 1
    ...     def storage_dim(self, x): return 1
    ...     def to_storage(self, x): return np.array([x.angle])
    ...     def from_storage(self, like, data): return Heading(data[0])
    ...     def retract(self, x, delta): return Heading(x.angle + delta[0])
    ...     def local(self, x, y): return np.array([(y.angle - x.angle + np.pi) % (2 * np.pi) - np.pi])
    >>> register(Heading, HeadingOps())
    >>> np.round(ops_for(Heading(3.0)).local(Heading(3.0), Heading(-3.0)), 6)   # across +-pi
    array([0.283185])
    """
    missing = [m for m in ("dim", "storage_dim", "to_storage", "from_storage", "retract", "local")
               if not callable(getattr(ops, m, None))]
    if missing:
        raise ManifoldError(f"manifold ops for {cls.__name__} lack {', '.join(missing)}")
    _registry[cls] = ops
    _lookup.cache_clear()


# ----------------------------------------------------------------------------- vector spaces


def _vector_retract(x, delta):
    """``x + delta`` row-wise (NumPy: nothing to compile for vector spaces)."""
    return np.asarray(x, dtype=np.float64) + delta


_vector_retract.numpy = True  # no numba: the NumPy backend can use it


def _vector_local(a, b):
    """``b - a`` row-wise."""
    return np.asarray(b, dtype=np.float64) - a


@lru_cache(maxsize=None)
def vector_kind(n: int) -> BatchKind:
    """The batch kind of R^n values (1-D float arrays of length n).

    >>> from fgopt.manifolds import vector_kind
    >>> kind = vector_kind(3)
    >>> kind.name, kind.dim, kind is vector_kind(3)
    ('R3', 3, True)
    """
    return BatchKind(
        name=f"R{n}",
        dim=n,
        storage_dim=n,
        retract=_vector_retract,
        local=_vector_local,
        from_storage=lambda row: np.array(row, dtype=float),
        to_storage=lambda v: np.asarray(v, dtype=float).reshape(n),
        wrap=lambda row: row,  # rows handed to wrap are owned and read-only
    )


def is_vector_kind(kind: BatchKind) -> bool:
    """True for the vector-space kinds (``vector_kind(n)`` and ``SCALAR_KIND``)."""
    return kind is SCALAR_KIND or kind is vector_kind(kind.dim)


SCALAR_KIND = BatchKind(
    name="scalar",
    dim=1,
    storage_dim=1,
    retract=_vector_retract,
    local=_vector_local,
    from_storage=lambda row: float(row[0]),
    to_storage=lambda v: np.array([float(v)]),
)


class _ScalarOps:
    """``float`` as the 1-D vector space."""

    def dim(self, x: Any) -> int:
        return 1

    def storage_dim(self, x: Any) -> int:
        return 1

    def to_storage(self, x: Any) -> np.ndarray:
        return np.array([float(x)])

    def from_storage(self, like: Any, data: np.ndarray) -> float:
        return float(np.asarray(data).reshape(-1)[0])

    def retract(self, x: Any, delta: np.ndarray) -> float:
        return float(x) + float(np.asarray(delta).reshape(-1)[0])

    def local(self, x: Any, y: Any) -> np.ndarray:
        return np.array([float(y) - float(x)])

    def batch_kind(self, x: Any) -> BatchKind:
        return SCALAR_KIND


class _VectorOps:
    """1-D numpy arrays as R^n."""

    def dim(self, x: Any) -> int:
        return int(np.shape(x)[0])

    storage_dim = dim

    def to_storage(self, x: Any) -> np.ndarray:
        return np.asarray(x, dtype=float).copy()

    def from_storage(self, like: Any, data: np.ndarray) -> np.ndarray:
        return np.array(data, dtype=float).reshape(np.shape(like))

    def retract(self, x: Any, delta: np.ndarray) -> np.ndarray:
        delta = np.asarray(delta, dtype=float).reshape(-1)
        if delta.shape[0] != np.shape(x)[0]:
            raise DimensionMismatchError(
                f"retract: vector of dim {np.shape(x)[0]} got a delta of dim {delta.shape[0]}")
        return np.asarray(x, dtype=float) + delta

    def local(self, x: Any, y: Any) -> np.ndarray:
        return np.asarray(y, dtype=float) - np.asarray(x, dtype=float)

    def batch_kind(self, x: Any) -> BatchKind:
        return vector_kind(int(np.shape(x)[0]))


class _DuckOps:
    """miniSAM-style Python classes with ``dim()``, ``local(other)``, ``retract(vec)``.

    They have no storage layout, so they always take the optimizer's slow path.
    """

    def dim(self, x: Any) -> int:
        return int(x.dim())

    def storage_dim(self, x: Any) -> int:
        return int(x.dim())

    def to_storage(self, x: Any) -> np.ndarray:
        raise ManifoldError(f"{type(x).__name__} has no storage layout (it is duck-typed)")

    def from_storage(self, like: Any, data: np.ndarray) -> Any:
        raise ManifoldError(f"{type(like).__name__} has no storage layout (it is duck-typed)")

    def retract(self, x: Any, delta: np.ndarray) -> Any:
        return x.retract(np.asarray(delta, dtype=float))

    def local(self, x: Any, y: Any) -> np.ndarray:
        return np.asarray(x.local(y), dtype=float).reshape(-1)

    def batch_kind(self, x: Any) -> None:
        return None


_SCALAR_OPS = _ScalarOps()
_VECTOR_OPS = _VectorOps()
_DUCK_OPS = _DuckOps()


@lru_cache(maxsize=256)
def _lookup(cls: type) -> ManifoldOps | None:
    for base in cls.__mro__:
        if base in _registry:
            return _registry[base]
    if issubclass(cls, (float, int, np.floating, np.integer)) and not issubclass(cls, bool):
        return _SCALAR_OPS
    if all(callable(getattr(cls, m, None)) for m in ("dim", "local", "retract")):
        return _DUCK_OPS
    return None


def ops_for(x: Any) -> ManifoldOps:
    """The manifold traits of value ``x``; raises :class:`ManifoldError` if it has none.

    >>> from fgopt.manifolds import SE3, ops_for
    >>> ops_for(SE3()).dim(SE3()), ops_for(np.zeros(4)).dim(np.zeros(4)), ops_for(2.0).dim(2.0)
    (6, 4, 1)
    """
    if isinstance(x, np.ndarray):
        if x.ndim == 1 and np.issubdtype(x.dtype, np.number):
            return _VECTOR_OPS
        raise ManifoldError(
            f"a numpy array of shape {x.shape} is not a manifold value: use a 1-D float array")
    ops = _lookup(type(x))
    if ops is None:
        raise ManifoldError(
            f"{type(x).__name__} is not a manifold: register it with "
            "fgopt.manifolds.register(cls, ops) or give it dim(), local(other), retract(vec)")
    return ops


def is_manifold_value(x: Any) -> bool:
    try:
        ops_for(x)
    except ManifoldError:
        return False
    return True
