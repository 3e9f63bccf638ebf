"""Base class of the symbolic Lie groups: storage, group and Lie-group operations defined once.

Every group states its layout in its class docstring; the layouts are those of the numeric
twins in :mod:`fgopt.manifolds` (``SO2/SE2/SO3/SE3``), so a symbolic value and a numeric value
with the same storage are the same group element, and tangent vectors mean the same thing:
``retract(x, d) = x * Exp(d)`` and ``local(x, y) = Log(x^-1 y)`` with the true group
exponential (right perturbation).

A subclass implements ``from_storage``, ``to_storage``, ``compose``, ``inverse``, ``exp``,
``log``, ``act``, ``matrix``, ``tangent_D_storage`` and ``_exp_first_order(v)``: the group
element whose storage is ``S(I) + d/dv S(Exp(v))|_0 v`` (Exp to first order, linear in v).
From these, this class derives

* ``retract_first_order(v) = x * Exp_1(v)``: the storage of ``x (+) v`` to first order in v
  (SymForce paper Eq. 8); storage is linear in v because ``compose`` is bilinear in storage;
* ``storage_D_tangent() = d S(x (+) v) / dv |_0`` (the ``(storage_dim, dim)`` matrix used by
  both tangent-space Jacobian methods of :mod:`fgopt.symbolic.jacobians`).
"""

from __future__ import annotations

from typing import Any

from ..errors import DimensionMismatchError, ManifoldError


def _s():
    from . import _sym

    return _sym


class LieGroupBase:
    """Shared operations of ``Rot2, Rot3, Pose2, Pose3`` (see the module docstring).

    Each group defines ``compose``, ``inverse``, ``exp`` and ``log``; ``between``, ``retract``
    and ``local`` (``a.local(b) = Log(a^-1 b)``) come from here:

    >>> from fgopt.symbolic import LieGroupBase, Rot2
    >>> a, b = Rot2.from_angle(0.3), Rot2.from_angle(1.0)
    >>> issubclass(Rot2, LieGroupBase), round(float(a.local(b, epsilon=0)[0]), 6)
    (True, 0.7)
    >>> round(float(a.retract([0.7], epsilon=0).angle()), 6)
    1.0
    """

    __slots__ = ()
    _DIM: int
    _STORAGE_DIM: int
    _IDENTITY: tuple

    # ------------------------------------------------------------------ storage
    @classmethod
    def dim(cls) -> int:
        """Tangent-space dimension."""
        return cls._DIM

    tangent_dim = dim

    @classmethod
    def storage_dim(cls) -> int:
        return cls._STORAGE_DIM

    @classmethod
    def from_storage(cls, data: Any):  # pragma: no cover - overridden
        raise NotImplementedError

    def to_storage(self) -> list:  # pragma: no cover - overridden
        raise NotImplementedError

    @classmethod
    def symbolic(cls, name: str):
        """An element with real symbols ``name_0 ... name_{storage_dim-1}`` as storage."""
        sym = _s().real_symbol
        return cls.from_storage([sym(f"{name}_{k}") for k in range(cls._STORAGE_DIM)])

    @classmethod
    def identity(cls):
        return cls.from_storage(list(cls._IDENTITY))

    def subs(self, *args: Any, **kwargs: Any):
        return type(self).from_storage([e.subs(*args, **kwargs) for e in self._storage_exprs()])

    def xreplace(self, mapping: dict):
        return type(self).from_storage([e.xreplace(mapping) for e in self._storage_exprs()])

    def _storage_exprs(self) -> list:
        return [_s().as_expr(e) for e in self.to_storage()]

    def to_numpy(self):
        """The storage as a float array (all entries must be numbers)."""
        import numpy as np

        return np.array([float(e) for e in self._storage_exprs()])

    # ------------------------------------------------------------------ group
    def compose(self, other):  # pragma: no cover - overridden
        raise NotImplementedError

    def inverse(self):  # pragma: no cover - overridden
        raise NotImplementedError

    def act(self, point: Any):  # pragma: no cover - overridden
        raise NotImplementedError

    def between(self, other):
        """``self^-1 * other``."""
        return self.inverse().compose(other)

    def __mul__(self, other: Any):
        if isinstance(other, type(self)):
            return self.compose(other)
        if isinstance(other, LieGroupBase):
            raise ManifoldError(f"cannot compose {type(self).__name__} with "
                                f"{type(other).__name__}")
        return self.act(other)

    # ------------------------------------------------------------------ Lie group
    @classmethod
    def exp(cls, v: Any, epsilon: Any = None):  # pragma: no cover - overridden
        raise NotImplementedError

    def log(self, epsilon: Any = None):  # pragma: no cover - overridden
        raise NotImplementedError

    @classmethod
    def from_tangent(cls, v: Any, epsilon: Any = None):
        """SymForce name of :meth:`exp`."""
        return cls.exp(v, epsilon)

    def to_tangent(self, epsilon: Any = None):
        """SymForce name of :meth:`log`."""
        return self.log(epsilon)

    def retract(self, v: Any, epsilon: Any = None):
        """``self * Exp(v)``."""
        return self.compose(type(self).exp(v, epsilon))

    def local(self, other, epsilon: Any = None):
        """``Log(self^-1 * other)``."""
        return self.between(other).log(epsilon)

    local_coordinates = local

    # ------------------------------------------------------------------ tangent <-> storage
    @classmethod
    def _exp_first_order(cls, v: Any):  # pragma: no cover - overridden
        raise NotImplementedError

    def retract_first_order(self, v: Any):
        """``self * Exp(v)`` to first order in ``v`` (storage linear in v)."""
        return self.compose(type(self)._exp_first_order(v))

    def storage_D_tangent(self):
        """``d S(self (+) v) / dv`` at ``v = 0``: SymPy matrix ``(storage_dim, dim)``."""
        sp = _s().sp
        xi = [sp.Dummy(f"xi{k}", real=True) for k in range(self._DIM)]
        s = sp.Matrix([_s().as_expr(e) for e in self.retract_first_order(xi).to_storage()])
        return s.jacobian(xi)  # linear in xi: no substitution needed

    def tangent_D_storage(self):  # pragma: no cover - overridden
        """A left inverse of :meth:`storage_D_tangent` on the group (``(dim, storage_dim)``)."""
        raise NotImplementedError

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.to_storage()})"


def as_vector(v: Any, n: int, what: str):
    """``v`` (Matrix, sequence, numpy array) as a symbolic ``V<n>``."""
    from .matrix import Matrix, vector_type

    if isinstance(v, Matrix):
        if len(v) != n:
            raise DimensionMismatchError(f"{what}: expected a {n}-vector, got shape {v.shape}")
        return v if v.SHAPE == (n, 1) else vector_type(n)(list(v))
    return vector_type(n)(v)
