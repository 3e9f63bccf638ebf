"""A one-shot import hook: run code around one third-party module's execution.

``on_import(name, around)``: the first time ``name`` is imported, its loader's ``exec_module``
runs as ``around(run, module)``, where ``run()`` executes the module; the hook then removes
itself. Used to route numba's cache of fgopt's functions (:mod:`fgopt._cache_root`) and to keep
numpy's test tooling unloaded while scipy clones numpy (:mod:`fgopt._lazy_numpy`), neither of
which may import the module early.
"""

from __future__ import annotations

import sys
from typing import Any, Callable


class _Hook:
    """Finds ``name``'s spec through the other finders and wraps its loader (once)."""

    def __init__(self, name: str, around: Callable[[Callable[[], None], Any], None]):
        self.name, self.around = name, around

    def find_spec(self, fullname: str, path: Any, target: Any = None) -> Any:
        if fullname != self.name:
            return None
        sys.meta_path[:] = [f for f in sys.meta_path if f is not self]  # one shot
        for finder in sys.meta_path:
            if not hasattr(finder, "find_spec"):
                continue
            spec = finder.find_spec(fullname, path, target)
            if spec is not None and spec.loader is not None:
                spec.loader = _Loader(spec.loader, self.around)
                return spec
        return None


class _Loader:
    """The module's own loader, its ``exec_module`` run through ``around`` (other attributes
    pass through)."""

    def __init__(self, inner: Any, around: Callable[[Callable[[], None], Any], None]):
        self._inner, self._around = inner, around

    def create_module(self, spec: Any) -> Any:
        return self._inner.create_module(spec)

    def exec_module(self, module: Any) -> None:
        self._around(lambda: self._inner.exec_module(module), module)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._inner, name)


def on_import(name: str, around: Callable[[Callable[[], None], Any], None]) -> None:
    """Run ``around(run, module)`` when ``name`` is first imported (no-op if a hook for
    ``name`` is already installed; the caller checks ``sys.modules`` for an imported one)."""
    if not any(isinstance(f, _Hook) and f.name == name for f in sys.meta_path):
        sys.meta_path.insert(0, _Hook(name, around))
