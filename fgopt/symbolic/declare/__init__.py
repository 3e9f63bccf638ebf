"""User-declared manifolds: ``@fgopt.manifold``, ``Product`` and ``check_manifold``.

Module map (one job each): ``twin`` (:class:`DeclaredManifold`, the symbolic values),
``decorator`` (``@manifold``: cache key, load or derive, numeric value type), ``derive`` (the
SymPy programs, ``storage_D_tangent``), ``codegen`` (the generated module), ``checks``
(declaration-time checks), ``report`` (:func:`check_manifold`), ``product`` (:func:`Product`),
``runtime`` (helper of generated modules).

Importing this package does not import SymPy; declaring a manifold whose module is cached does
not either.
"""

from __future__ import annotations

from .decorator import manifold as manifold
from .twin import DeclaredManifold as DeclaredManifold


def __getattr__(name: str):
    if name == "Product":
        from .product import Product

        return Product
    if name == "check_manifold":
        from .report import check_manifold

        return check_manifold
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
