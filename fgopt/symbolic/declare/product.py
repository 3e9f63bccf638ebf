"""``Product(A, B, ...)``: the product manifold of symbolic types, ready to declare.

    @fgopt.manifold
    class NavState(Product(Rot3, V3, V3, names=("attitude", "position", "velocity"))):
        '''Attitude, position and velocity.'''

    Plane = fgopt.manifold(Product(Unit3, Scalar, names=("normal", "distance")), name="Plane")

Storage and tangent are the components' in order; ``retract`` and ``local`` act component-wise
(``R Exp(w)`` for a rotation, ``+`` for vectors and scalars, the declaration's own for declared
components), so ``retract(x, d)`` is *not* a group exponential of the product (for SE_2(3) with
its coupled exponential see :mod:`fgopt.symbolic.geometry.se23`). ``storage_D_tangent`` is block
diagonal. ``normalize`` re-normalizes rotation storage and calls declared components'
``normalize``. Each name becomes an accessor (``x.position()``), also on numeric values
(``numeric.position()``, a numpy array / ``SO3`` / declared value), and ``repr`` shows them;
``x.component(i)`` reads component ``i``.

Components: ``Rot2, Rot3, Pose2, Pose3`` (or their numeric ``SO2, SO3, SE2, SE3``), fixed-shape
vectors and matrices (``V3``), ``Scalar`` (or ``float``) and declared manifolds (the twin or its
``.Value``).
"""

from __future__ import annotations

import sys
from typing import Any

from ...errors import ManifoldDeclarationError
from ..lie import LieGroupBase
from ..matrix import Matrix, Scalar
from .twin import DeclaredManifold


def _s():
    from .. import _sym

    return _sym


def _component_type(c: Any) -> type:
    from ..pose import Pose2, Pose3
    from ..rot import Rot2, Rot3

    if c in (float, int) or c is Scalar:
        return Scalar
    if isinstance(c, type):
        if issubclass(c, LieGroupBase) or (issubclass(c, Matrix) and c.SHAPE is not None):
            return c
        if issubclass(c, DeclaredManifold) and c._DECLARED:
            return c
        twin = getattr(getattr(c, "_spec", None), "twin", None)
        if twin is not None:
            return twin
        numeric = {"SO2": Rot2, "SE2": Pose2, "SO3": Rot3, "SE3": Pose3}.get(c.__name__)
        if numeric is not None and c.__module__.startswith("fgopt.manifolds"):
            return numeric
    raise ManifoldDeclarationError(
        f"Product: {getattr(c, '__name__', repr(c))} is not a component type: use Rot2, Rot3, "
        "Pose2, Pose3 (or SO2, SO3, SE2, SE3), V1..V9, Matrix.shaped(r, c), Scalar or a "
        "declared manifold")


def _layout(cls: type) -> list:
    """``(component, storage slice, tangent slice)`` of each component."""
    out, s, t = [], 0, 0
    for c in cls._COMPONENTS:
        n, d = c.storage_dim(), c.dim()
        out.append((c, slice(s, s + n), slice(t, t + d)))
        s, t = s + n, t + d
    return out


def _value(c: type, storage: list) -> Any:
    return c.from_storage(storage)


def component(x: Any, i: int) -> Any:
    """Component ``i`` of ``x`` as a value of its own type (a scalar is an expression)."""
    c, ss, _ = _layout(type(x))[i]
    return _value(c, x.to_storage()[ss])


def _flat(v: Any) -> list:
    if isinstance(v, (Matrix, LieGroupBase, DeclaredManifold)):
        return list(v.to_storage()) if not isinstance(v, Matrix) else list(v.mat)
    return [v]


def retract(x: Any, d: Any) -> list:
    out, dl = [], list(d)
    for c, ss, ts in _layout(type(x)):
        v = _value(c, x.to_storage()[ss])
        piece = dl[ts]
        if c is Scalar:
            out.append(v + piece[0])
        else:
            out += _flat(v.retract(piece))
    return out


def local(x: Any, y: Any) -> list:
    out = []
    for c, ss, _ in _layout(type(x)):
        a, b = _value(c, x.to_storage()[ss]), _value(c, y.to_storage()[ss])
        out += [b - a] if c is Scalar else list(a.local(b))
    return out


def _identity_of(c: type) -> list | None:
    """The component's identity storage as numbers (no SymPy), ``None`` if it has none."""
    if c is Scalar:
        return [0]
    if issubclass(c, Matrix):
        return [0] * c.storage_dim()
    if issubclass(c, LieGroupBase):
        return list(c._IDENTITY)
    ident = c.Value._spec.identity
    return None if ident is None else list(ident)


def _normalize_value(c: type, v: Any) -> list:
    from ..pose import Pose2, Pose3
    from ..rot import Rot2, Rot3

    if c in (Rot2, Rot3, Pose2, Pose3):
        st = list(v.to_storage())
        k = 2 if c in (Rot2, Pose2) else 4
        n = _s().sp.sqrt(sum(e * e for e in st[:k]))
        return [e / n for e in st[:k]] + st[k:]
    if issubclass(c, DeclaredManifold):
        return list(v.normalize().to_storage())
    return _flat(v)


def normalize(x: Any) -> list:
    out = []
    for c, ss, _ in _layout(type(x)):
        out += _normalize_value(c, _value(c, x.to_storage()[ss]))
    return out


def storage_D_tangent(x: Any):
    """Block diagonal: each component's ``storage_D_tangent`` (identity for vectors)."""
    sp = _s().sp
    cls = type(x)
    D = sp.zeros(cls._STORAGE_DIM, cls._DIM)
    for c, ss, ts in _layout(cls):
        v = _value(c, x.to_storage()[ss])
        n, d = ss.stop - ss.start, ts.stop - ts.start
        D[ss, ts] = sp.eye(n) if c is Scalar or issubclass(c, Matrix) else v.storage_D_tangent()
        assert D[ss, ts].shape == (n, d)
    return D


def _needs_normalize(c: type) -> bool:
    from ..pose import Pose2, Pose3
    from ..rot import Rot2, Rot3

    if c in (Rot2, Rot3, Pose2, Pose3):
        return True
    return issubclass(c, DeclaredManifold) and getattr(c, "_user_normalize", None) is not None


def _accessor(i: int, name: str):
    def get(x):
        return component(x, i)

    get.__name__ = get.__qualname__ = name
    get.__doc__ = f"Component {i} ({name})."
    return get


def Product(*components: Any, names: tuple | list | None = None) -> type:
    """A declaration template of the product of ``components`` (see the module docstring).

    Args:
        components: two or more component types.
        names: one accessor name per component (default none: use ``x.component(i)``).

    Example:

    >>> from fgopt.symbolic import Rot3, V3
    >>> @fgopt.manifold
    ... class RotPos(fgopt.Product(Rot3, V3, names=('attitude', 'position'))):
    ...     pass
    ...
    >>> RotPos.Value().retract(np.arange(6) * 0.1).position()
    array([0.3, 0.4, 0.5])
    """
    if len(components) < 1:
        raise ManifoldDeclarationError("Product needs at least one component")
    comps = tuple(_component_type(c) for c in components)
    names = tuple(names) if names is not None else ()
    if len(names) not in (0, len(comps)):
        raise ManifoldDeclarationError(f"Product: {len(names)} names for {len(comps)} "
                                       "components")
    bad = [n for n in names if not n.isidentifier() or n.startswith("_")]
    if len(bad) > 0:
        raise ManifoldDeclarationError(f"Product: names {bad} are not public identifiers")
    ns: dict = {
        "storage_dim": sum(c.storage_dim() for c in comps),
        "dim": sum(c.dim() for c in comps),
        "_COMPONENTS": comps,
        "retract": retract, "local": local, "storage_D_tangent": storage_D_tangent,
        "component": component,
        "__doc__": f"Product of {', '.join(c.__name__ for c in comps)}.",
    }
    idents = [_identity_of(c) for c in comps]
    if all(i is not None for i in idents):
        ident = [e for i in idents for e in i]
        ns["identity"] = lambda: list(ident)
    if any(_needs_normalize(c) for c in comps):
        ns["normalize"] = normalize
    for i, nm in enumerate(names):
        ns[nm] = _accessor(i, nm)
    if len(names) > 0:
        ns["fields"] = names
    cls = type("Product", (), ns)
    cls.__qualname__ = f"Product({', '.join(c.__name__ for c in comps)})"
    cls.__module__ = sys._getframe(1).f_globals.get("__name__", __name__)
    return cls
