"""Shared machinery of the Lie group value classes: a small base class and the traits adapter.

:class:`LieGroup` implements every operation once, by calling the per-element numba
dispatchers of :mod:`fgopt.manifolds._kernels` with the class's group id; the concrete classes
(:class:`~fgopt.manifolds.so2.SO2`, ``SE2``, ``SO3``, ``SE3``, ``Sim3``) add constructors,
accessors, ``matrix()`` and ``__repr__``. :class:`LieGroupOps` is the :class:`ManifoldOps`
traits object registered for each class by :func:`register_group`; its ``batch_kind`` is one
cached :class:`BatchKind` per group whose ``retract`` / ``local`` are the batched numba kernels.

Conventions for all groups: ``retract(x, d) = x * Exp(d)``, ``local(x, y) = Log(x^-1 * y)``
(the true group exponential with right perturbations, as GTSAM's Pose2 / Pose3 defaults), so
``x.retract(x.local(y)) == y``; ``adjoint()`` is the matrix with ``x * Exp(v) = Exp(Adj v) * x``.
"""

from __future__ import annotations

from collections import deque
from itertools import repeat
from typing import Any

import numpy as np

from .. import _jit
from ..errors import DimensionMismatchError, FgoptError, ManifoldError, NonFiniteError
from . import _kernels as K
from .base import BatchKind, register



#: Per-value group operations run as plain Python until numba is in use in the process or this
#: many have run: a script's first values then cost no numba import (0.25-0.4 s) and no
#: initialization of its compiler (0.2-0.3 s); bulk construction still gets numba's speed.
#: Plain Python costs ~25 us per operation, numba's dispatch ~2 us after 0.7 s of import and cache
#: loads (seconds of compilation with an empty cache): generating the demo's 3500-pose graph
#: (21k operations) took 0.8 s in Python vs 1.4 s switching to numba after 2000 (warm cache).
PYTHON_ELEMENT_OPS = 50000
_element_ops = [0]


#: (kernel, group id) -> numba dispatcher of the group's entry, once built: one dict lookup per
#: operation instead of the entry lookup and its proxy (~1 us of a ~5 us compose)
_DISPATCHERS: dict = {}


def _element(kernel, gid: int, *args) -> None:
    d = _DISPATCHERS.get((kernel, gid))
    if d is not None and not _jit._mode.python:
        d(*args)
    elif _element_ops[0] < PYTHON_ELEMENT_OPS and not _jit.is_numba_loaded():
        _element_ops[0] += 1
        kernel.python(gid, *args)
    else:
        entry = _jit.specialize(kernel, gid)  # compiles this group's code only
        entry(*args)
        built = getattr(entry, "_dispatcher", None)
        if built is not None:
            _DISPATCHERS[(kernel, gid)] = built


class InvalidGroupElementError(FgoptError, ValueError):
    """A value given to a Lie group constructor is not a group element (e.g. scale <= 0).

    >>> from fgopt.manifolds import SO3, Sim3
    >>> Sim3(SO3(), np.zeros(3), -1.0)
    Traceback (most recent call last):
    fgopt.manifolds.lie.InvalidGroupElementError: Sim3: scale must be > 0, got -1.0
    """


def as_float(value: Any, what: str) -> float:
    """``float(value)``, or a DimensionMismatchError naming ``what``."""
    try:
        return float(value)
    except (TypeError, ValueError) as exc:
        raise DimensionMismatchError(f"{what}: expected a number, got {value!r}") from exc


def as_float_vector(value: Any, n: int, what: str) -> np.ndarray:
    """``value`` as a fresh float64 array of shape ``(n,)``, or a clear error."""
    try:
        arr = np.array(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise DimensionMismatchError(f"{what}: expected {n} numbers, got {value!r}") from exc
    if arr.shape[0] != n:
        raise DimensionMismatchError(f"{what}: expected {n} numbers, got shape "
                                     f"{np.shape(value)}")
    if not np.all(np.isfinite(arr)):
        raise NonFiniteError(f"{what}: got non-finite values {arr}")
    return arr


class LieGroup:
    """Base of the Lie group value classes (immutable; one level of inheritance only).

    Subclasses set ``_GID`` (group id in :mod:`._kernels`), ``_DIM``, ``_STORAGE_DIM``,
    ``_POINT_DIM`` and implement ``_normalize(data)`` (projects raw storage onto the group,
    in place, raising :class:`InvalidGroupElementError` if impossible), ``matrix()``,
    ``random(rng)`` and ``__repr__``.

    The groups share its API: ``compose`` (``*``), ``inverse``, ``between``, ``exp`` / ``log``,
    ``retract`` / ``local``, ``act`` on points, ``adjoint``, ``matrix``:

    >>> from fgopt.manifolds import SE2, SO3, LieGroup
    >>> issubclass(SE2, LieGroup), issubclass(SO3, LieGroup)
    (True, True)
    >>> a, b = SE2.from_xytheta(1.0, 0.0, 0.5), SE2.from_xytheta(2.0, 1.0, -0.2)
    >>> (a * a.between(b)).equals(b), np.allclose(SE2.exp(a.log()).matrix(), a.matrix())
    (True, True)
    """

    # ``_buf`` and ``_data`` are the same read-only array (two slots because the C-level row
    # wrapper below sets them). Every value's storage is read-only, new values' and values read
    # from a Variables alike: numba types a read-only array apart from a writable one, and a
    # mix would compile every element operation twice.
    __slots__ = ("_buf", "_data")
    _GID: int
    _DIM: int
    _STORAGE_DIM: int
    _POINT_DIM: int
    _IDENTITY: np.ndarray
    _kind: BatchKind | None = None

    # ---------------------------------------------------------------- construction
    @classmethod
    def _wrap(cls, data: np.ndarray):
        """Wrap an owned float64 array as a value without checks (it becomes read-only)."""
        obj = object.__new__(cls)
        data.setflags(write=False)  # (half the cost of ``flags.writeable = False``)
        _SET_BUF(obj, data)
        _SET_DATA(obj, data)
        return obj

    @classmethod
    def _wrap_readonly(cls, data: np.ndarray):
        """:meth:`_wrap` of an owned array that is already read-only (``BatchKind.wrap``'s
        contract): no flag to set (Problem.values, Variables.add_rows)."""
        obj = object.__new__(cls)
        object.__setattr__(obj, "_buf", data)
        object.__setattr__(obj, "_data", data)
        return obj

    @classmethod
    def _wrap_readonly_rows(cls, rows: np.ndarray) -> list:
        """:meth:`_wrap_readonly` of every row of an owned read-only ``(n, storage_dim)`` array,
        with no Python call per row (objects allocated and their slots set by C-level ``map``
        loops): 808 SE(2) rows in 0.17 ms instead of 0.31 (a pose graph's result values)."""
        objs = list(map(object.__new__, repeat(cls, rows.shape[0])))
        views = list(rows)  # row views of the read-only array: read-only themselves
        deque(map(_SET_BUF, objs, views), maxlen=0)
        deque(map(_SET_DATA, objs, views), maxlen=0)
        return objs

    def _set(self, data: np.ndarray) -> None:
        data.setflags(write=False)  # an owned array (see the slots' comment)
        object.__setattr__(self, "_buf", data)
        object.__setattr__(self, "_data", data)

    @classmethod
    def _normalize(cls, data: np.ndarray) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError(f"{type(self).__name__} values are immutable")

    @classmethod
    def from_storage(cls, data: Any):
        """The value stored as ``data`` (shape ``(storage_dim,)``, see the class docstring)."""
        arr = as_float_vector(data, cls._STORAGE_DIM, f"{cls.__name__}.from_storage")
        cls._normalize(arr)
        return cls._wrap(arr)

    def to_storage(self) -> np.ndarray:
        """A fresh copy of the storage vector, shape ``(storage_dim,)``."""
        return self._data.copy()

    @classmethod
    def identity(cls):
        return cls._wrap(cls._IDENTITY.copy())

    @classmethod
    def dim(cls) -> int:
        """Tangent-space dimension."""
        return cls._DIM

    @classmethod
    def storage_dim(cls) -> int:
        """Number of stored floats."""
        return cls._STORAGE_DIM

    @classmethod
    def batch_kind(cls) -> BatchKind:
        """The :class:`BatchKind` of this group (one object per group)."""
        assert cls._kind is not None, f"{cls.__name__} is not registered"
        return cls._kind

    # ---------------------------------------------------------------- group operations
    def _check_same(self, other: Any, op: str) -> None:
        if not isinstance(other, type(self)):
            raise ManifoldError(f"{type(self).__name__}.{op}: expected a {type(self).__name__}, "
                             f"got {type(other).__name__}")

    def compose(self, other):
        """The group product ``self * other``."""
        self._check_same(other, "compose")
        out = np.empty(self._STORAGE_DIM)
        _element(K.lie_compose, self._GID, self._buf, other._buf, out)
        return self._wrap(out)

    def inverse(self):
        out = np.empty(self._STORAGE_DIM)
        _element(K.lie_inverse, self._GID, self._buf, out)
        return self._wrap(out)

    def between(self, other):
        """``self.inverse() * other`` (the pose of ``other`` seen from ``self``)."""
        self._check_same(other, "between")
        return self.inverse().compose(other)

    @classmethod
    def exp(cls, v: Any):
        """The group exponential ``Exp(v)`` of a tangent vector (shape ``(dim,)``)."""
        v = as_float_vector(v, cls._DIM, f"{cls.__name__}.exp")
        out = np.empty(cls._STORAGE_DIM)
        _element(K.lie_exp, cls._GID, v, out)
        return cls._wrap(out)

    def log(self) -> np.ndarray:
        """The group logarithm ``Log(self)``, shape ``(dim,)``; rotation angle in [0, pi]."""
        out = np.empty(self._DIM)
        _element(K.lie_log, self._GID, self._buf, out)
        return out

    def adjoint(self) -> np.ndarray:
        """``Adj``, shape ``(dim, dim)``, with ``self * Exp(v) = Exp(Adj v) * self``."""
        out = np.empty((self._DIM, self._DIM))
        _element(K.lie_adjoint, self._GID, self._buf, out)
        return out

    def retract(self, delta: Any):
        """``self * Exp(delta)``."""
        return self.compose(self.exp(delta))

    def local(self, other) -> np.ndarray:
        """``Log(self^-1 * other)``, so ``self.retract(self.local(other)) == other``."""
        self._check_same(other, "local")
        return self.between(other).log()

    def act(self, points: Any) -> np.ndarray:
        """Transform a point ``(k,)`` or points ``(n, k)`` (``k`` = 2 or 3): ``self * p``."""
        p = np.asarray(points, dtype=np.float64)
        k = self._POINT_DIM
        if p.shape[-1:] != (k,) or p.ndim > 2:
            raise DimensionMismatchError(
                f"{type(self).__name__} acts on points of shape ({k},) or (n, {k}); "
                f"got shape {p.shape}")
        m = self.matrix()
        if m.shape[0] == k:
            return p @ m.T
        return p @ m[:k, :k].T + m[:k, k]

    def __mul__(self, other: Any):
        if isinstance(other, LieGroup):
            return self.compose(other)
        if isinstance(other, (np.ndarray, list, tuple)):
            return self.act(other)
        return NotImplemented

    def matrix(self) -> np.ndarray:  # pragma: no cover - overridden
        raise NotImplementedError

    def equals(self, other: Any, tol: float = 1e-9) -> bool:
        """True if ``other`` is the same group element up to ``tol`` (max abs matrix entry)."""
        if not isinstance(other, type(self)):
            return False
        return bool(np.max(np.abs(self.matrix() - other.matrix())) <= tol)

    # ---------------------------------------------------------------- python protocol
    def __reduce__(self):
        return (type(self).from_storage, (self._data.copy(),))

    def __copy__(self):
        return self

    def __deepcopy__(self, memo: dict):
        return self

    @staticmethod
    def _rng(rng: Any) -> np.random.Generator:
        return rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)


# the slots' setters (C-level callables) for LieGroup._wrap_readonly_rows
_SET_BUF = LieGroup._buf.__set__
_SET_DATA = LieGroup._data.__set__


class LieGroupOps:
    """:class:`~fgopt.manifolds.base.ManifoldOps` traits of one :class:`LieGroup` class."""

    def __init__(self, cls: type[LieGroup]):
        self.cls = cls
        self.kind = BatchKind(
            name=cls.__name__,
            dim=cls._DIM,
            storage_dim=cls._STORAGE_DIM,
            retract=K.RETRACT_BATCH[cls._GID],
            local=K.LOCAL_BATCH[cls._GID],
            from_storage=cls.from_storage,
            to_storage=self.to_storage,
            wrap=cls._wrap_readonly,
            wrap_rows=cls._wrap_readonly_rows,
        )

    def dim(self, x: Any) -> int:
        return self.cls._DIM

    def storage_dim(self, x: Any) -> int:
        return self.cls._STORAGE_DIM

    def to_storage(self, x: Any) -> np.ndarray:
        if not isinstance(x, self.cls):
            raise ManifoldError(f"{self.cls.__name__} storage requested for a "
                                f"{type(x).__name__} value")
        return x.to_storage()

    def from_storage(self, like: Any, data: np.ndarray) -> Any:
        return type(like).from_storage(data)

    def retract(self, x: Any, delta: np.ndarray) -> Any:
        return x.retract(delta)

    def local(self, x: Any, y: Any) -> np.ndarray:
        return x.local(y)

    def batch_kind(self, x: Any) -> BatchKind:
        return self.kind


_GROUP_ID_BY_KIND: dict[BatchKind, int] = {}  # kinds hash by identity


def register_group(cls: type[LieGroup]) -> None:
    """Register ``cls`` with :func:`fgopt.manifolds.register` and give it its BatchKind."""
    ops = LieGroupOps(cls)
    cls._kind = ops.kind
    _GROUP_ID_BY_KIND[ops.kind] = cls._GID
    register(cls, ops)


def group_id(kind: BatchKind) -> int | None:
    """The group id (``_kernels.SO2_ID`` ...) of a Lie group batch kind, else ``None``."""
    return _GROUP_ID_BY_KIND.get(kind)
