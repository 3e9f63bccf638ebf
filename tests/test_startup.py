"""Start-up: ``import fgopt`` loads no heavy dependency, and deferred numba kernels behave as
numba kernels (compiled on first call, callable from other kernels, parallel ``prange``)."""

import subprocess
import sys
from pathlib import Path

import numpy as np

from fgopt._jit import LazyKernel, njit, prange

REPO = Path(__file__).resolve().parents[1]


def _modules_after(code: str) -> set:
    out = subprocess.run([sys.executable, "-c", code + "\nimport sys; print(' '.join(sorted("
                          "m for m in ('numba', 'scipy', 'sympy', 'numpy', 'llvmlite') "
                          "if m in sys.modules)))"], capture_output=True, text=True, cwd=REPO,
                         check=True)
    return set(out.stdout.split())


def test_import_fgopt_loads_no_heavy_dependency():
    """``import fgopt`` imports neither numba, llvmlite, scipy, SymPy nor even numpy."""
    assert _modules_after("import fgopt; fgopt.key('x', 1); fgopt.FgoptError") == set()


def test_building_values_and_graphs_needs_no_numba_or_sympy():
    """Public names load on first use; making SE(2) values, a graph and Variables does not
    import numba or SymPy (they load when a kernel first runs)."""
    mods = _modules_after("import fgopt\nfrom fgopt import SE2, FactorGraph, Variables, key\n"
                          "v = Variables(); v.add(key('x', 1), SE2.from_xytheta(1, 2, 0.3))\n"
                          "g = FactorGraph()")
    assert "numba" not in mods and "sympy" not in mods and "numpy" in mods


@njit(cache=False)
def _square(x):
    return x * x


@njit(cache=False)
def _sum_squares(a):
    s = 0.0
    for i in range(a.shape[0]):
        s += _square(a[i])
    return s


@njit(cache=False, parallel=True)
def _parallel_double(a, out):
    for i in prange(a.shape[0]):
        out[i] = 2.0 * a[i]


def test_lazy_kernels_compile_on_first_call_and_call_each_other():
    """A deferred kernel is built on its first call; a kernel calling another deferred kernel
    compiles (the callee types as its numba dispatcher) and gives numba's result."""
    k = njit(cache=False)(lambda x: x + 1.0)
    assert isinstance(k, LazyKernel) and not k.compiled
    assert k(1.5) == 2.5 and k.compiled
    a = np.arange(5.0)
    assert _sum_squares(a) == 30.0
    assert len(_sum_squares.signatures) == 1  # attributes of the dispatcher pass through


def test_parallel_kernel_uses_numba_prange():
    """``prange`` of a deferred ``parallel=True`` kernel is numba's (bound when it is built)."""
    a = np.arange(1000.0)
    out = np.empty_like(a)
    _parallel_double(a, out)
    assert np.array_equal(out, 2.0 * a)
    import numba

    assert _parallel_double.py_func.__globals__["prange"] is numba.prange



def _run(code: str) -> str:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          cwd=REPO, check=True).stdout.strip()


def test_scipy_sparse_leaves_numpys_test_and_fortran_tooling_unloaded():
    """After ``import fgopt``, importing scipy.sparse (whose array-API shim clones numpy's
    namespace) does not load numpy.f2py / numpy.testing / numpy.ma (~60 ms); numpy's own
    attributes are numpy's again afterwards, and the clone's stand-ins forward to the real
    submodules."""
    out = _run(
        "import sys, fgopt, numpy, scipy.sparse\n"
        "print(sorted(m for m in ('numpy.f2py', 'numpy.testing', 'numpy.ma') if m in sys.modules))\n"
        "print(sorted(n for n in ('f2py', 'testing', 'ma') if n in vars(numpy)))\n"
        "from scipy._lib.array_api_compat import numpy as xp\n"
        "xp.testing.assert_allclose(1.0, 1.0)\n"
        "print(xp.ma.masked_array([1, 2], [0, 1]).sum(), numpy.testing is sys.modules['numpy.testing'])\n"
        "print(numpy.ma.MaskedArray is xp.ma.MaskedArray, callable(numpy.f2py.run_main))\n")
    assert out.splitlines() == ["[]", "[]", "1 True", "True True"]


def test_scipy_sparse_leaves_numpys_other_unused_submodules_unloaded():
    """numpy.polynomial / char / strings / ctypeslib / rec (cloned by scipy's array-API shim,
    never used by scipy.sparse or CHOLMOD) stay unloaded through a sparse solve's imports, and
    load on first use through numpy and through the clone."""
    import pytest

    pytest.importorskip("sksparse")
    out = _run(
        "import sys, fgopt, numpy, scipy.sparse, sksparse.cholmod\n"
        "names = ('polynomial', 'char', 'strings', 'ctypeslib', 'rec')\n"
        "print(sorted(n for n in names if 'numpy.' + n in sys.modules))\n"
        "print(sorted(n for n in names if n in vars(numpy)))\n"
        "from scipy._lib.array_api_compat import numpy as xp\n"
        "print(xp.polynomial.Polynomial([1, 2])(1.0), numpy.char.upper('a'))\n")
    assert out.splitlines() == ["[]", "[]", "3.0 A"]


def test_numpy_submodules_imported_before_scipy_stay_as_they_are():
    """A submodule already imported is left alone (nothing to save) and scipy.sparse works."""
    out = _run("import numpy.testing, fgopt, numpy, scipy.sparse, sys\n"
               "print(numpy.testing is sys.modules['numpy.testing'], "
               "scipy.sparse.eye(3).tocsc().nnz)")
    assert out == "True 3"
