"""Keep numpy's test and Fortran tooling unloaded while scipy builds its numpy namespace.

numpy loads ``numpy.f2py``, ``numpy.testing`` and ``numpy.ma`` only when first touched (PEP 562).
scipy (1.17 here) vendors array-api-compat, whose numpy namespace
(``scipy._lib.array_api_compat.numpy``, imported by ``scipy.sparse``) is a clone made with
``from numpy import *`` and ``getattr`` over ``dir(numpy)``, which touches all three: f2py's
Fortran parser compiles ~60 regular expressions and numpy.testing imports unittest, ~60 ms of
the ~100 ms ``import scipy.sparse`` costs (scipy 1.17, ``python -X importtime``) in
every process that solves a sparse problem, e.g. ``fgopt solve``.

While (and only while) that one module executes, the three names on numpy are bound to stand-ins
that import the real submodule on first attribute access; afterwards numpy's own attributes are
restored, so numpy itself is unchanged and only the clone holds stand-ins (it forwards every
attribute to the real module).  Installed by ``import fgopt``: a one-shot import hook
(:mod:`fgopt._import_hook`).
"""

from __future__ import annotations

import importlib
import sys
import types
from typing import Any

from ._import_hook import on_import

#: The module whose execution clones numpy's namespace.
CLONING_MODULE = "scipy._lib.array_api_compat.numpy"
#: numpy submodules the clone touches that scipy never uses through it (f2py, testing ~25-30 ms
#: each, ma ~14 ms; polynomial, char, strings, ctypeslib, rec ~4 ms together).  numpy.random and
#: numpy.fft are not here: scipy itself imports them.
DEFERRED = ("f2py", "testing", "ma", "polynomial", "char", "strings", "ctypeslib", "rec")


class DeferredModule(types.ModuleType):
    """A module that imports ``name`` on first attribute access and forwards to it."""

    def __getattr__(self, attr: str) -> Any:
        return getattr(importlib.import_module(self.__name__), attr)

    def __dir__(self) -> list[str]:
        return dir(importlib.import_module(self.__name__))

    def __repr__(self) -> str:
        return f"<module {self.__name__!r} (imported on first use)>"


def _bind_stand_ins() -> dict[str, DeferredModule]:
    numpy = sys.modules.get("numpy")
    if numpy is None:
        return {}
    bound = {}
    for short in DEFERRED:
        full = f"numpy.{short}"
        if full in sys.modules or short in vars(numpy):
            continue  # already imported (or bound): nothing to save
        bound[short] = DeferredModule(full)
        setattr(numpy, short, bound[short])
    return bound


def _unbind(bound: dict[str, DeferredModule]) -> None:
    numpy = sys.modules.get("numpy")
    for short, stand_in in bound.items():
        if vars(numpy).get(short) is stand_in:  # the real import replaces it: keep that
            delattr(numpy, short)


def _with_stand_ins(run, module: Any) -> None:
    bound = _bind_stand_ins()
    try:
        run()
    finally:
        _unbind(bound)


def install() -> None:
    """Defer the three submodules when scipy's numpy clone is first imported (idempotent)."""
    if CLONING_MODULE not in sys.modules:
        on_import(CLONING_MODULE, _with_stand_ins)
