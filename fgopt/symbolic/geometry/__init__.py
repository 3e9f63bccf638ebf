"""Manifolds declared with ``@fgopt.manifold`` that ship with fgopt (one module each).

``Unit3`` (directions, GTSAM's chart), ``OrientedPlane3`` (unit normal and distance, GTSAM's)
and ``SE23`` (extended poses: rotation, velocity, position; the group of invariant filtering).
Each name is the symbolic type (for ``@fgopt.factor`` signatures); ``.Value`` is the numeric
value type, also exported as ``fgopt.Unit3`` etc. Modules load on first access: declaring
reads the kernel cache (deriving with SymPy on a miss).
"""

from __future__ import annotations

from typing import Any

_MODULES = {"Unit3": ".unit3", "OrientedPlane3": ".oriented_plane3", "SE23": ".se23"}


def __getattr__(name: str) -> Any:
    if name in _MODULES:
        import importlib

        return getattr(importlib.import_module(_MODULES[name], __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
