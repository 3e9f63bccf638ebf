"""Sphinx configuration of fgopt's documentation site (``make docs``; see docs/README.md).

Every page is a MyST-NB text notebook: its ``{code-cell}`` blocks run at build time in a kernel
that imports *this* checkout of fgopt, so an example that stops working fails the build (``-W``).
The gallery pages are the notebooks of ``examples/``, copied into ``docs/gallery/notebooks/`` at
build start; where ``FGOPT_EXECUTED_NOTEBOOKS`` names a folder that holds an executed copy of a
notebook whose code cells are exactly the current ones (``make test`` writes such copies when
``FGOPT_NOTEBOOK_OUTPUT_DIR`` is set, as ``.ci/run`` does), that copy is shown and not executed
again; otherwise the notebook is executed here.
"""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

import nbformat

DOCS = Path(__file__).resolve().parent
REPO = DOCS.parent
sys.path.insert(0, str(REPO))
# code cells and notebooks run in kernels that must import this checkout and find the data
os.environ["PYTHONPATH"] = os.pathsep.join(
    p for p in (str(REPO), os.environ.get("PYTHONPATH", "")) if p)
os.environ.setdefault("FGOPT_DATA", str(REPO.parent / "shared" / "data"))
os.environ.setdefault("MPLBACKEND", "module://matplotlib_inline.backend_inline")
os.environ.setdefault("PYDEVD_DISABLE_FILE_VALIDATION", "1")

import fgopt  # noqa: E402

project = "fgopt"
author = "fgopt contributors"
copyright = "fgopt contributors"
release = version = fgopt.__version__

extensions = [
    "myst_nb",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "sphinx_copybutton",
]

exclude_patterns = ["_build", "README.md", "Thumbs.db", ".DS_Store", "**.ipynb_checkpoints",
                    "jupyter_execute"]
source_suffix = {".rst": "restructuredtext", ".md": "myst-nb", ".ipynb": "myst-nb"}

html_theme = "furo"
html_title = f"fgopt {release}"
html_static_path = []

# -- MyST / MyST-NB -------------------------------------------------------------------------
myst_enable_extensions = ["colon_fence", "dollarmath", "deflist"]
myst_heading_anchors = 3
nb_execution_mode = "force"            # every code cell of every page runs at build time
nb_execution_timeout = 600
nb_execution_raise_on_error = True     # a failing example fails the build
nb_execution_show_tb = True
nb_merge_streams = True
nb_kernel_rgx_aliases = {".*": "python3"}

# -- autodoc / autosummary ------------------------------------------------------------------
autosummary_generate = True
autosummary_imported_members = True
autodoc_default_options = {"members": False, "show-inheritance": False}
autodoc_typehints = "signature"
autodoc_member_order = "bysource"
napoleon_google_docstring = True
napoleon_numpy_docstring = False

# Broken internal links fail the build: links between pages (MyST reports a missing document or
# anchor) and cross-references to fgopt's public names (``fgopt.X``, ``fgopt.<package>.X``) must
# resolve (``nitpicky``). Not checked: other projects' names (numpy, scipy ...), and docstrings'
# mentions of implementation modules and their members (``fgopt.solvers.fixed``,
# ``fgopt.symbolic.cse.Program``), which have no reference page.
nitpicky = True
nitpick_ignore_regex = [(r"py:.*", r"(?!fgopt\b).*"), (r"py:mod", r"fgopt\..*"),
                        (r"py:.*", r"fgopt\.\w+\.\w+\..*"), (r"py:.*", r"fgopt\.\w+\._.*"),
                        (r"py:.*", r"fgopt\.(?!(?:%s)\.)\w+\..*" % "|".join(
                            ("noise", "manifolds", "factors", "solvers", "symbolic", "io", "cameras",
                             "navigation", "incremental", "filters", "distributed", "datasets",
                             "plot", "errors")))]
# a notebook's "###" under its "#" title is a style choice, not a broken page
suppress_warnings = ["myst.header"]


# -- the gallery: examples/*.ipynb ----------------------------------------------------------
GALLERY = DOCS / "gallery" / "notebooks"


def _code(nb) -> list[str]:
    return [c.source for c in nb.cells if c.cell_type == "code"]


def _prepare_gallery() -> list[str]:
    """Copy examples/*.ipynb into the gallery; take an executed copy where one matches."""
    GALLERY.mkdir(parents=True, exist_ok=True)
    executed_dir = os.environ.get("FGOPT_EXECUTED_NOTEBOOKS")
    reused = []
    for src in sorted((REPO / "examples").glob("[0-9][0-9]_*.ipynb")):
        dst = GALLERY / src.name
        nb = nbformat.read(src, as_version=4)
        done = Path(executed_dir) / src.name if executed_dir else None
        if done is not None and done.is_file():
            ran = nbformat.read(done, as_version=4)
            if _code(ran) == _code(nb) and all(
                    c.get("execution_count") for c in ran.cells if c.cell_type == "code"):
                nb, reused = ran, reused + [src.name]
        text = nbformat.writes(nb)
        if not dst.is_file() or dst.read_text() != text:
            dst.write_text(text)
    for stale in GALLERY.glob("*.ipynb"):
        if not (REPO / "examples" / stale.name).is_file():
            stale.unlink()
    if reused:
        print(f"gallery: showing the test suite's executed copies of {', '.join(reused)}")
    return [f"gallery/notebooks/{n}" for n in reused]


nb_execution_excludepatterns = _prepare_gallery()
templates_path = ['_templates']


# -- the sidebar lists pages, not the ~230 reference entries ---------------------------------
# autosummary's ``:toctree:`` puts every generated entry page in the site's table of contents;
# furo renders that whole tree into every page's sidebar, which cost ~90 s of a 2-core build
# (an O(pages^2) write). The entry pages stay reachable from their package page's summary
# table and the search; they leave the tree and are marked orphan (no "not in any toctree").
GENERATED = "api/generated/"


def _entries_off_the_sidebar(app, doctree) -> None:
    from sphinx.ext.autosummary import autosummary_toc

    docname = app.env.docname
    if docname.startswith(GENERATED):
        app.env.metadata[docname]["orphan"] = True
    for node in list(doctree.findall(autosummary_toc)):
        node.parent.remove(node)


def setup(app) -> None:
    # before the toctree collector (priority 500) reads the document's toctrees
    app.connect("doctree-read", _entries_off_the_sidebar, priority=400)
