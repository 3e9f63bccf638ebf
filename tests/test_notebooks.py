"""Execute every notebook in ``examples/`` (they assert their own results), so they cannot rot.

Each notebook runs in a fresh ``python3`` kernel of *this* interpreter (the venv's ipykernel,
whatever kernel specs are installed elsewhere), with ``examples/`` as working directory and
``FGOPT_DATA`` passed through (default ``../shared/data`` next to the repository; notebooks that
need data fall back to smaller or synthetic problems when it is absent). Set
``FGOPT_NOTEBOOK_OUTPUT_DIR`` to keep the executed notebooks (with outputs and plots). Committed
notebooks must have their outputs cleared.
"""

from __future__ import annotations

import os
import re
import sys
import time
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")
pytest.importorskip("matplotlib")

from jupyter_client.kernelspec import KernelSpec, KernelSpecManager, NoSuchKernel
from jupyter_client.manager import KernelManager

REPO = Path(__file__).resolve().parents[1]
EXAMPLES = REPO / "examples"
NOTEBOOKS = sorted(EXAMPLES.glob("[0-9][0-9]_*.ipynb"))
#: Per-cell limit; the notebooks are meant to finish in well under a minute each.
CELL_TIMEOUT = 600
_ANSI = re.compile(r"\x1b\[[0-9;]*m")


class _ThisInterpreter(KernelSpecManager):
    """Every kernel name resolves to ipykernel on ``sys.executable`` (the venv running pytest),
    whatever ``python3`` kernel spec a user or system Jupyter installation provides."""

    def get_kernel_spec(self, kernel_name: str) -> KernelSpec:
        argv = [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"]
        try:  # keep the installed spec's metadata (e.g. its transport encryption support)
            spec = super().get_kernel_spec(kernel_name)
        except NoSuchKernel:
            return KernelSpec(argv=argv, display_name=f"Python ({sys.executable})",
                              language="python", resource_dir=str(EXAMPLES))
        spec.argv = argv
        return spec


def _kernel_manager() -> KernelManager:
    return KernelManager(kernel_name="python3", kernel_spec_manager=_ThisInterpreter())


def _kernel_env() -> dict:
    env = dict(os.environ)
    env.setdefault("FGOPT_DATA", str(REPO.parent / "shared" / "data"))
    env["MPLBACKEND"] = "module://matplotlib_inline.backend_inline"
    env.setdefault("PYDEVD_DISABLE_FILE_VALIDATION", "1")
    # the kernel must import *this* checkout of fgopt
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO), env.get("PYTHONPATH", "")) if p)
    return env


def test_examples_are_present():
    names = {p.name for p in NOTEBOOKS}
    assert {"01_minisam_pose_graph.ipynb", "02_custom_factor.ipynb", "03_custom_manifold.ipynb",
            "04_g2o_pose_graph.ipynb", "05_bundle_adjustment.ipynb",
            "06_on_manifold_ekf.ipynb"} <= names, sorted(names)


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_outputs_are_cleared(path):
    nb = nbformat.read(path, as_version=4)
    dirty = [i for i, c in enumerate(nb.cells)
             if c.cell_type == "code" and (c.get("outputs") or c.get("execution_count"))]
    assert not dirty, f"{path.name}: cells {dirty} have outputs; clear them before committing"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_runs(path):
    nb = nbformat.read(path, as_version=4)
    km = _kernel_manager()
    client = nbclient.NotebookClient(
        nb, km=km, timeout=CELL_TIMEOUT, kernel_name="python3",
        resources={"metadata": {"path": str(EXAMPLES)}}, allow_errors=False)
    t0 = time.perf_counter()
    try:
        client.execute(env=_kernel_env(), cwd=str(EXAMPLES))
    except nbclient.exceptions.CellExecutionError as exc:
        pytest.fail(f"{path.name} failed:\n{_ANSI.sub('', str(exc))}", pytrace=False)
    finally:
        if km.has_kernel:  # a kernel manager we pass in is not shut down by nbclient
            km.shutdown_kernel(now=True)
    print(f"{path.name}: {time.perf_counter() - t0:.1f} s")
    out_dir = os.environ.get("FGOPT_NOTEBOOK_OUTPUT_DIR")
    if out_dir:  # keep the executed notebook (outputs, plots) for inspection, e.g. in CI
        Path(out_dir).mkdir(parents=True, exist_ok=True)
        nbformat.write(nb, Path(out_dir) / path.name)
