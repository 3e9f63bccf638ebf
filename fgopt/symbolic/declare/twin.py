"""Symbolic values of declared manifolds: :class:`DeclaredManifold`, the base of every twin.

``@fgopt.manifold`` turns a declaration class into a subclass of :class:`DeclaredManifold`: a
symbolic type like ``Rot3`` or ``V3`` (usable in ``@fgopt.factor`` signatures and inside the
declaration's own methods), whose values hold their storage as a list of SymPy expressions.
The declaration's ``retract(x, d)``, ``local(x, y)``, ``identity()``, ``normalize(x)`` are kept
as ``_user_*`` functions; the public methods here call them and check the sizes of what they
return. Accessors (methods taking only ``self``) and other methods of the declaration are
copied onto the twin unchanged.

``storage_D_tangent()`` is ``d S(x (+) v) / dv`` at ``v = 0`` (what tangent-space factor
Jacobians need, see :mod:`fgopt.symbolic.jacobians`): the declaration's own
``storage_D_tangent(x)`` when it gives one (products do), else derived once per class from
``retract`` by SymPy (:func:`fgopt.symbolic.declare.derive.generic_storage_D_tangent`) and
substituted into each value's storage.

Importing this module does not import SymPy.
"""

from __future__ import annotations

from typing import Any

from ...errors import ManifoldDeclarationError


def _s():
    from .. import _sym

    return _sym


class DeclaredManifold:
    """Base of the symbolic twins made by ``@fgopt.manifold`` (see the module docstring).

    ``T(storage)`` wraps storage entries (numbers, expressions, a Matrix); ``T()`` is the
    identity. ``x[i]`` is storage entry ``i`` (a slice gives a vector), ``x.storage`` the
    storage as a ``V<storage_dim>``.

    >>> from fgopt.symbolic import SE23, DeclaredManifold, symbols
    >>> issubclass(SE23, DeclaredManifold)
    True
    >>> SE23()[3], SE23().storage.shape                # the identity: quaternion w = 1
    (1, (10, 1))
    >>> x = SE23(list(symbols("q0:4")) + [0] * 6)
    >>> x[0:4]
    V4([[q0], [q1], [q2], [q3]])
    """

    __slots__ = ("_s",)
    _STORAGE_DIM: int = 0
    _DIM: int = 0
    #: set by ``@fgopt.manifold``: declaration key (hash of the declaration and of the code
    #: generator), the numeric value class, the names of accessors and the ``repr`` fields.
    _KEY: str = ""
    _ACCESSORS: tuple = ()
    _FIELDS: tuple = ()
    _DECLARED: bool = False
    Value: type

    def __init__(self, storage: Any = None):
        if storage is None:
            storage = type(self)._identity_storage()
        object.__setattr__(self, "_s", as_storage(storage, self._STORAGE_DIM,
                                                  f"{type(self).__name__}(storage)"))

    # ------------------------------------------------------------------ storage
    @classmethod
    def storage_dim(cls) -> int:
        return cls._STORAGE_DIM

    @classmethod
    def dim(cls) -> int:
        """Tangent-space dimension."""
        return cls._DIM

    tangent_dim = dim

    @classmethod
    def from_storage(cls, data: Any):
        return cls(data)

    def to_storage(self) -> list:
        return list(self._s)

    @property
    def storage(self):
        """The storage as a symbolic ``V<storage_dim>``."""
        from ..matrix import vector_type

        return vector_type(self._STORAGE_DIM)(list(self._s))

    def __getitem__(self, idx: Any):
        if isinstance(idx, slice):
            from ..matrix import vector_type

            items = self._s[idx]
            return vector_type(len(items))(items)
        return self._s[idx]

    @classmethod
    def symbolic(cls, name: str):
        """A value whose storage entries are the real symbols ``name_0, name_1, ...``."""
        sym = _s().real_symbol
        return cls([sym(f"{name}_{k}") for k in range(cls._STORAGE_DIM)])

    @classmethod
    def _identity_storage(cls) -> list:
        fn = getattr(cls, "_user_identity", None)
        if fn is None:
            raise ManifoldDeclarationError(f"{cls.__name__} declares no identity()")
        return as_storage(fn(), cls._STORAGE_DIM, f"{cls.__name__}.identity()")

    @classmethod
    def identity(cls):
        return cls(cls._identity_storage())

    def subs(self, *args: Any, **kwargs: Any):
        return type(self)([_s().as_expr(e).subs(*args, **kwargs) for e in self._s])

    def xreplace(self, mapping: dict):
        return type(self)([_s().as_expr(e).xreplace(mapping) for e in self._s])

    def to_numpy(self):
        """The storage as a float array (all entries must be numbers)."""
        import numpy as np

        return np.array([float(_s().as_expr(e)) for e in self._s])

    # ------------------------------------------------------------------ manifold
    def _raw_retract(self, v: Any) -> list:
        """Storage of the declaration's ``retract(self, v)`` (before ``normalize``)."""
        cls = type(self)
        out = cls._user_retract(self, as_tangent(v, cls._DIM, f"{cls.__name__}.retract"))
        return as_storage(out, cls._STORAGE_DIM, f"{cls.__name__}.retract(x, d)")

    def retract(self, v: Any, epsilon: Any = None):
        """``self (+) v``: the declaration's ``retract``, then its ``normalize`` if any.

        ``epsilon`` is accepted for the Lie group API; declarations use ``epsilon`` directly.
        """
        out = type(self)(self._raw_retract(v))
        return out.normalize() if getattr(type(self), "_user_normalize", None) else out

    def local(self, other: Any, epsilon: Any = None):
        """``other (-) self`` in this value's tangent space, a ``V<dim>``."""
        from ..matrix import vector_type

        cls = type(self)
        if not isinstance(other, cls):
            raise TypeError(f"{cls.__name__}.local: expected a {cls.__name__}, got "
                            f"{type(other).__name__}")
        out = cls._user_local(self, other)
        return vector_type(cls._DIM)(as_storage(out, cls._DIM, f"{cls.__name__}.local(x, y)",
                                                what="tangent entries", size="dim"))

    local_coordinates = local

    def normalize(self):
        """The declaration's ``normalize`` (identity when it has none)."""
        cls = type(self)
        fn = getattr(cls, "_user_normalize", None)
        if fn is None:
            return self
        return cls(as_storage(fn(self), cls._STORAGE_DIM, f"{cls.__name__}.normalize(x)"))

    def storage_D_tangent(self):
        """``d S(self (+) v) / dv`` at 0: SymPy matrix ``(storage_dim, dim)``."""
        from .derive import generic_storage_D_tangent

        cls = type(self)
        gen, D = generic_storage_D_tangent(cls)
        return D.xreplace(dict(zip(gen, (_s().as_expr(e) for e in self._s))))

    def tangent_D_storage(self):
        """``d local(self, y) / d S(y)`` at ``y = self``: a left inverse of
        :meth:`storage_D_tangent` (``(dim, storage_dim)``)."""
        from .derive import generic_tangent_D_storage

        cls = type(self)
        gen, T = generic_tangent_D_storage(cls)
        return T.xreplace(dict(zip(gen, (_s().as_expr(e) for e in self._s))))

    # ------------------------------------------------------------------ group (optional)
    def between(self, other: Any):
        """``self^-1 * other`` when the declaration has ``compose`` and ``inverse``."""
        return self.inverse().compose(other)

    def compose(self, other: Any):  # pragma: no cover - replaced by declarations that have it
        raise TypeError(f"{type(self).__name__} declares no compose()")

    def inverse(self):  # pragma: no cover - replaced by declarations that have it
        raise TypeError(f"{type(self).__name__} declares no inverse()")

    @classmethod
    def is_group(cls) -> bool:
        return "compose" in cls.__dict__ and "inverse" in cls.__dict__

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self._s})"


def as_storage(out: Any, n: int, where: str, what: str = "storage entries",
               size: str = "storage_dim") -> list:
    """Flat list of SymPy expressions of a method's result, or a declaration error naming it."""
    from ..matrix import _flatten

    try:
        flat = _flatten(out)
    except TypeError as exc:
        raise ManifoldDeclarationError(f"{where} returned a {type(out).__name__}; expected "
                                       f"{n} {what} (a V{n}, a list or a value)") from exc
    if len(flat) != n:
        raise ManifoldDeclarationError(f"{where} returned {len(flat)} {what}, but {size} is "
                                       f"{n}: wrong size")
    return [_s().as_expr(e) for e in flat]


def as_tangent(v: Any, n: int, where: str):
    """A tangent argument as a ``V<n>``."""
    from ..matrix import vector_type

    return vector_type(n)(as_storage(v, n, where, what="tangent entries", size="dim"))
