"""Numeric value types of declared manifolds (``@fgopt.manifold``), one class per declaration.

A declaration is written over symbolic types (:mod:`fgopt.symbolic.declare`); deriving it yields
a generated module with batched numba ``retract`` / ``local`` kernels and plain-Python functions
for one value. The symbolic layer hands those functions to :func:`make_value_type`, which builds
the numeric value class, its :class:`~fgopt.manifolds.base.BatchKind` and its traits, and
registers them like the built-in groups: variables of the new kind live in one ``(n,
storage_dim)`` array, factors over them batch, and nothing here knows anything symbolic.

A value is immutable and holds its storage (``to_storage()``, a fresh copy); ``from_storage``
and the constructor apply the declaration's ``normalize`` (storage that drifts, e.g. a unit
vector), ``retract`` / ``local`` on one value run the generated plain-Python twins of the batched
kernels (same printed code). Pickling goes through the symbolic declaration class (importable by
name), so a value pickled in one process loads in another that can import the declaration.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from ..errors import DimensionMismatchError, ManifoldError
from .base import BatchKind, register
from .lie import as_float_vector


@dataclass(frozen=True, eq=False)
class ValueSpec:
    """What :func:`make_value_type` needs: sizes, generated functions, presentation.

    Per-value functions take and return flat sequences of floats (storage or tangent order).
    """

    name: str
    dim: int
    storage_dim: int
    key: str
    twin: Any                                            # the symbolic class (pickling)
    retract_batch: Callable[[np.ndarray, np.ndarray], np.ndarray]
    local_batch: Callable[[np.ndarray, np.ndarray], np.ndarray]
    retract_one: Callable[[Any, Any], Any]
    local_one: Callable[[Any, Any], Any]
    storage_D_tangent_one: Callable[[Any], Any]
    normalize_one: Callable[[Any], Any] | None = None
    identity: tuple | None = None
    #: name -> function(storage array) -> numeric value (vector, matrix, float, group value)
    accessors: dict = field(default_factory=dict)
    #: accessor names shown by ``repr`` (empty: the storage)
    fields: tuple = ()
    #: accessor giving a 2-D / 3-D position (plots), or ``None``; and that dimension
    position: str | None = None
    position_dim: int = 0
    #: printed retract code (fixed formulation): ``{"stmts": [(name, src)], "out": [src]}``
    retract_code: dict = field(default_factory=dict)
    doc: str = ""
    module: str = __name__
    qualname: str = ""


class DeclaredValue:
    """Base of the numeric value classes made by :func:`make_value_type` (see module docstring).

    ``Value(storage)`` normalizes; ``Value()`` is the identity when the declaration has one.
    """

    __slots__ = ("_buf", "_data")
    _spec: ValueSpec
    _kind: BatchKind

    def __init__(self, storage: Any = None):
        spec = self._spec
        if storage is None:
            if spec.identity is None:
                raise ManifoldError(f"{spec.name}() needs a storage vector: the declaration has "
                                    "no identity()")
            data = np.array(spec.identity, dtype=np.float64)
        else:
            data = as_float_vector(storage, spec.storage_dim, spec.name)
        self._set(self._normalized(data))

    # ---------------------------------------------------------------- construction
    @classmethod
    def _normalized(cls, data: np.ndarray) -> np.ndarray:
        fn = cls._spec.normalize_one
        if fn is None:
            return data
        out = np.array(fn(*data.tolist()), dtype=np.float64)
        if not np.all(np.isfinite(out)):
            raise ManifoldError(f"{cls._spec.name}: storage {data} cannot be normalized "
                                f"(normalize gave {out})")
        return out

    @classmethod
    def _wrap(cls, data: np.ndarray):
        """Wrap an owned float64 array already on the manifold (no checks; becomes read-only)."""
        obj = object.__new__(cls)
        obj._set(data)
        return obj

    def _set(self, data: np.ndarray) -> None:
        view = data.view()
        view.flags.writeable = False
        object.__setattr__(self, "_buf", data)
        object.__setattr__(self, "_data", view)

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError(f"{type(self).__name__} values are immutable")

    @classmethod
    def from_storage(cls, data: Any):
        """The value stored as ``data`` (``(storage_dim,)``), normalized."""
        return cls._wrap(cls._normalized(as_float_vector(data, cls._spec.storage_dim,
                                                         f"{cls._spec.name}.from_storage")))

    def to_storage(self) -> np.ndarray:
        """A fresh copy of the storage vector, shape ``(storage_dim,)``."""
        return self._data.copy()

    @classmethod
    def identity(cls):
        if cls._spec.identity is None:
            raise ManifoldError(f"{cls._spec.name} declares no identity()")
        return cls._wrap(np.array(cls._spec.identity, dtype=np.float64))

    @classmethod
    def dim(cls) -> int:
        """Tangent-space dimension."""
        return cls._spec.dim

    @classmethod
    def storage_dim(cls) -> int:
        return cls._spec.storage_dim

    @classmethod
    def batch_kind(cls) -> BatchKind:
        return cls._kind

    @classmethod
    def symbolic_type(cls) -> Any:
        """The symbolic twin (the declaration class, usable in ``@fgopt.factor`` signatures)."""
        return cls._spec.twin

    # ---------------------------------------------------------------- manifold
    def retract(self, delta: Any):
        """``self (+) delta`` (normalized), ``delta`` of shape ``(dim,)``."""
        spec = self._spec
        d = np.asarray(delta, dtype=np.float64).reshape(-1)
        if d.shape[0] != spec.dim:
            raise DimensionMismatchError(f"{spec.name}.retract: delta of dim {d.shape[0]}, "
                                         f"expected {spec.dim}")
        return self._wrap(np.array(spec.retract_one(*self._buf.tolist(), *d.tolist()),
                                   dtype=np.float64))

    def local(self, other: Any) -> np.ndarray:
        """``other (-) self`` in this value's tangent space, shape ``(dim,)``."""
        if not isinstance(other, type(self)):
            raise ManifoldError(f"{self._spec.name}.local: expected a {self._spec.name}, got "
                                f"{type(other).__name__}")
        return np.array(self._spec.local_one(*self._buf.tolist(), *other._buf.tolist()),
                        dtype=np.float64)

    def storage_D_tangent(self) -> np.ndarray:
        """``d storage(self (+) v) / dv`` at 0, shape ``(storage_dim, dim)``."""
        s = self._spec
        return np.array(s.storage_D_tangent_one(*self._buf.tolist()),
                        dtype=np.float64).reshape(s.storage_dim, s.dim)

    def equals(self, other: Any, tol: float = 1e-9) -> bool:
        """Same type and ``max |local(self, other)| <= tol``."""
        if not isinstance(other, type(self)):
            return False
        return bool(np.max(np.abs(self.local(other)), initial=0.0) <= tol)

    # ---------------------------------------------------------------- python protocol
    def __reduce__(self):
        return (restore_value, (self._spec.twin, self._data.copy()))

    def __copy__(self):
        return self

    def __deepcopy__(self, memo: dict):
        return self

    def __repr__(self) -> str:
        spec = self._spec
        if len(spec.fields) == 0:
            return f"{spec.name}({_fmt(self._data)})"
        parts = ", ".join(f"{n}={_fmt(getattr(self, n)())}" for n in spec.fields)
        return f"{spec.name}({parts})"

    @classmethod
    def position_dim(cls) -> int:
        """2 or 3 when the declaration says where a value is (a ``position`` accessor), else 0."""
        return cls._spec.position_dim

    def plot_position(self) -> np.ndarray:
        """The position plots draw (the declaration's ``position`` accessor)."""
        if self._spec.position is None:
            raise ManifoldError(f"{self._spec.name} declares no position accessor")
        return np.asarray(getattr(self, self._spec.position)(), dtype=np.float64)


def _fmt(v: Any) -> str:
    if isinstance(v, np.ndarray):
        return np.array2string(v, precision=4, suppress_small=True, separator=", ",
                               max_line_width=200)
    if isinstance(v, float):
        return f"{v:.6g}"
    return repr(v)


def restore_value(twin: Any, data: np.ndarray) -> DeclaredValue:
    """Unpickling: the value of declaration ``twin`` stored as ``data``."""
    return twin.Value.from_storage(data)


class DeclaredOps:
    """:class:`~fgopt.manifolds.base.ManifoldOps` traits of one declared value class."""

    def __init__(self, cls: type[DeclaredValue]):
        self.cls = cls

    def dim(self, x: Any) -> int:
        return self.cls._spec.dim

    def storage_dim(self, x: Any) -> int:
        return self.cls._spec.storage_dim

    def to_storage(self, x: Any) -> np.ndarray:
        if not isinstance(x, self.cls):
            raise ManifoldError(f"{self.cls._spec.name} storage requested for a "
                                f"{type(x).__name__} value")
        return x.to_storage()

    def from_storage(self, like: Any, data: np.ndarray) -> Any:
        return type(like).from_storage(data)

    def retract(self, x: Any, delta: np.ndarray) -> Any:
        return x.retract(delta)

    def local(self, x: Any, y: Any) -> np.ndarray:
        return x.local(y)

    def batch_kind(self, x: Any) -> BatchKind:
        return self.cls._kind


_VALUE_TYPE_OF_KIND: dict[BatchKind, type] = {}  # kinds hash by identity


def _accessor(name: str, fn: Callable) -> Callable:
    def get(self):
        return fn(self._buf)

    get.__name__ = get.__qualname__ = name
    get.__doc__ = f"``{name}`` of the declaration, evaluated numerically."
    return get


def make_value_type(spec: ValueSpec) -> type[DeclaredValue]:
    """Build, register and return the numeric value class of a declaration."""
    ns: dict = {"__slots__": (), "__doc__": spec.doc or f"Values of the declared manifold "
                f"{spec.name} (storage {spec.storage_dim}, tangent {spec.dim}).",
                "__module__": spec.module, "_spec": spec}
    for name, fn in spec.accessors.items():
        ns[name] = _accessor(name, fn)
    cls = type(spec.name, (DeclaredValue,), ns)
    cls.__qualname__ = spec.qualname or spec.name
    ops = DeclaredOps(cls)
    to_storage = ops.to_storage
    cls._kind = BatchKind(name=spec.name, dim=spec.dim, storage_dim=spec.storage_dim,
                          retract=spec.retract_batch, local=spec.local_batch,
                          from_storage=cls.from_storage, to_storage=to_storage, wrap=cls._wrap,
                          key=spec.key)
    _VALUE_TYPE_OF_KIND[cls._kind] = cls
    register(cls, ops)
    return cls


def declared_type(kind: BatchKind) -> type[DeclaredValue] | None:
    """The declared value class of ``kind``, or ``None`` (built-in groups and vectors)."""
    return _VALUE_TYPE_OF_KIND.get(kind)
