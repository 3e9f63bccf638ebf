"""Run Python as if the optional packages named in ``FGOPT_HIDE_EXTRAS`` were not installed.

``FGOPT_HIDE_EXTRAS=sksparse`` (comma-separated top-level names) makes ``import sksparse`` raise
``ModuleNotFoundError`` and ``importlib.util.find_spec("sksparse")`` return ``None``, which is
what :func:`fgopt.errors.have_extra` sees when the ``fgopt[cholmod]`` extra is absent. Test-suite
machinery only: ``tests/conftest.py`` applies it to the pytest process and puts this folder on
``PYTHONPATH`` so every subprocess a test starts (Dask workers, scripts) hides the same packages.
"""

from __future__ import annotations

import importlib.abc
import os
import sys


class HiddenExtras(importlib.abc.MetaPathFinder):
    """Refuses the hidden packages (and their submodules) before any other finder sees them."""

    def __init__(self, names: frozenset[str]):
        self.names = names

    def find_spec(self, fullname, path=None, target=None):
        if fullname.partition(".")[0] in self.names:
            raise ModuleNotFoundError(f"No module named {fullname!r} (hidden by FGOPT_HIDE_EXTRAS)",
                                      name=fullname)
        return None


def hide(names: str) -> frozenset[str]:
    """Hide the comma-separated top-level package ``names`` in this process; returns them."""
    hidden = frozenset(n.strip() for n in names.split(",") if n.strip())
    for name in hidden:
        if name in sys.modules and sys.modules[name] is not None:
            raise RuntimeError(f"FGOPT_HIDE_EXTRAS: {name} was imported before it could be hidden")
        # a None entry makes find_spec() answer None (as for an absent package) and imports fail;
        # the finder is the backstop should a test drop that entry from sys.modules
        sys.modules[name] = None
    if hidden and not any(isinstance(f, HiddenExtras) for f in sys.meta_path):
        sys.meta_path.insert(0, HiddenExtras(hidden))
    return hidden


def _chain_shadowed_sitecustomize() -> None:
    """Run the sitecustomize this file shadows on sys.path, if there is one."""
    import importlib.machinery
    import importlib.util

    here = os.path.dirname(os.path.abspath(__file__))
    rest = [p for p in sys.path if os.path.abspath(p or ".") != here]
    spec = importlib.machinery.PathFinder.find_spec("sitecustomize", rest)
    if spec is not None and spec.loader is not None:
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)


if __name__ == "sitecustomize":
    hide(os.environ.get("FGOPT_HIDE_EXTRAS", ""))
    _chain_shadowed_sitecustomize()
