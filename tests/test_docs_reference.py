"""The API reference (docs/api/*.rst) covers every public name, and every entry's docstring has
an example that runs.

Public names are ``fgopt.__all__`` and the ``__all__`` of each public package (the modules
``fgopt.datasets``, ``fgopt.plot`` and ``fgopt.errors`` included). Each is listed on its
package's reference page: an autosummary entry (autodoc renders its signature and docstring), a
``py:data`` entry for a constant, a link for a subpackage, or, on the ``fgopt`` page, an alias
line pointing at the same object's entry in its package. An entry's docstring must show an
example (``>>>`` lines, a ``::`` literal block or a fenced block); the ``>>>`` examples run here
as doctests.
"""

from __future__ import annotations

import ast
import doctest
import importlib
import inspect
import os
import re
import types
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
API = REPO / "docs" / "api"
PACKAGES = ["fgopt", "fgopt.noise", "fgopt.manifolds", "fgopt.factors", "fgopt.solvers",
            "fgopt.symbolic", "fgopt.io", "fgopt.cameras", "fgopt.navigation",
            "fgopt.incremental", "fgopt.filters", "fgopt.distributed", "fgopt.datasets",
            "fgopt.plot", "fgopt.errors"]

_EXAMPLE = re.compile(r"^\s*>>>|::\s*$|^\s*```", re.M)


def _page(package: str) -> str:
    return (API / f"{package}.rst").read_text()


def entries(package: str) -> dict[str, str]:
    """``{name: how}`` listed on a package's page: ``autosummary``, ``data``, ``module`` or
    ``alias:<target>``."""
    text = _page(package)
    out: dict[str, str] = {}
    for block in re.finditer(r"^\.\. autosummary::\n((?:   .*\n|\n)*)", text, re.M):
        for line in block.group(1).splitlines():
            name = line.strip()
            if name and not name.startswith(":"):
                out[name] = "autosummary"
    for m in re.finditer(r"^\.\. py:data:: (\w+)$", text, re.M):
        out[m.group(1)] = "data"
    for m in re.finditer(r":doc:`fgopt\.(\w+)`", text):
        out[m.group(1)] = "module"
    for m in re.finditer(r"^\.\. py:(?:class|function|exception):: (\w+)\n   :no-index-entry:\n\n"
                         r"   Re-exported: the same object as :py:obj:`([\w.]+)`\.$", text, re.M):
        out[m.group(1)] = "alias:" + m.group(2)
    return out


def public(package: str) -> list[str]:
    return list(importlib.import_module(package).__all__)


def _resolve(dotted: str):
    module, _, name = dotted.rpartition(".")
    return getattr(importlib.import_module(module), name)


def documented() -> list[tuple[str, object]]:
    """Every reference entry rendered by autodoc, as (dotted name, object)."""
    out = []
    for package in PACKAGES:
        mod = importlib.import_module(package)
        for name, how in entries(package).items():
            if how == "autosummary":
                out.append((f"{package}.{name}", getattr(mod, name)))
    return out


@pytest.mark.parametrize("package", PACKAGES)
def test_every_public_name_has_a_reference_entry(package):
    """Each name of the package's ``__all__`` is listed on its reference page in the form its
    kind needs, and the page lists nothing the package does not export."""
    mod = importlib.import_module(package)
    listed = entries(package)
    names = public(package)
    missing = [n for n in names if n not in listed]
    assert not missing, f"docs/api/{package}.rst lacks {missing}: add them to its autosummary"
    extra = [n for n in listed if n not in names]
    assert not extra, f"docs/api/{package}.rst lists {extra}, which {package}.__all__ lacks"
    for name, how in listed.items():
        obj = getattr(mod, name)
        if how == "module":
            assert isinstance(obj, types.ModuleType), name
            assert (API / f"fgopt.{name}.rst").is_file(), f"no reference page for fgopt.{name}"
        elif how == "data":
            assert not (inspect.isclass(obj) or callable(obj)), f"{name} is not a constant"
        elif how.startswith("alias:"):
            target = how[len("alias:"):]
            assert _resolve(target) is obj, f"fgopt.{name} is not {target}"
            tpkg, _, tname = target.rpartition(".")
            assert entries(tpkg).get(tname) == "autosummary", f"{target} has no entry"


@pytest.mark.parametrize("package", PACKAGES[1:])
def test_reexports_are_public(package):
    """A name a package's ``__init__`` re-exports (``from .x import Y as Y``; submodules aside) is
    in its ``__all__``, so it cannot escape the reference."""
    path = REPO / (package.replace(".", "/") + "/__init__.py")
    if not path.is_file():
        path = path.parent.with_suffix(".py")
    reexported = {a.asname for node in ast.parse(path.read_text()).body
                  if isinstance(node, ast.ImportFrom) for a in node.names
                  if a.asname and a.asname == a.name}
    mod = importlib.import_module(package)
    reexported = {n for n in reexported if not isinstance(getattr(mod, n), types.ModuleType)}
    assert reexported <= set(public(package)), sorted(reexported - set(public(package)))


def test_api_index_lists_every_page():
    """The reference's table of contents has a page per package."""
    index = (API / "index.md").read_text()
    for package in PACKAGES:
        assert re.search(rf"^{re.escape(package)}$", index, re.M), package


def test_every_entry_has_a_docstring_with_an_example():
    """autodoc renders each entry's docstring: it must exist and show an example."""
    no_doc, no_example = [], []
    for dotted, obj in documented():
        doc = inspect.getdoc(obj) or ""
        if not doc.strip():
            no_doc.append(dotted)
        elif not _EXAMPLE.search(doc):
            no_example.append(dotted)
    assert not no_doc, f"entries without a docstring: {no_doc}"
    assert not no_example, f"entries whose docstring has no example: {sorted(no_example)}"


def _doctests():
    finder = doctest.DocTestFinder(recurse=False)
    tests = []
    for dotted, obj in documented():
        for t in finder.find(obj, dotted, globs={}):
            if t.examples:
                tests.append(t)
    return tests


@pytest.mark.skipif(os.environ.get("FGOPT_DOCTESTS") != "1",
                    reason="docstring examples run with FGOPT_DOCTESTS=1 (make docs): ~1.5 min "
                           "of kernels a test run need not compile")
@pytest.mark.parametrize("test", _doctests(), ids=lambda t: t.name)
def test_docstring_examples_run(test):
    """The ``>>>`` example of an entry's docstring runs and prints what it shows."""
    import numpy as np

    import fgopt

    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    # what every example may assume (docs/api/index.md says so)
    test.globs = {"np": np, "fgopt": fgopt, "key": fgopt.key}
    report: list[str] = []  # doctest swaps sys.stdout while it runs: print() would be lost
    runner.run(test, out=report.append)
    assert runner.failures == 0, f"{test.name}: {runner.failures} failing example(s):\n" + \
        "".join(report)
