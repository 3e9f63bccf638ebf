"""Start-up: ``import fgopt`` loads no heavy dependency, and deferred numba kernels behave as
numba kernels (compiled on first call, callable from other kernels, parallel ``prange``)."""

import os
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


def test_numpy_budget_environment_variable():
    """``FGOPT_NUMPY_BUDGET=0`` runs even a 2-pose solve on numba (what warm-process benchmarks
    set); a value that is not seconds >= 0 is an FgoptError naming the variable."""
    solve = ("import fgopt\n"
             "from fgopt import key, SE2, PriorFactor, BetweenFactor\n"
             "from fgopt.noise import Diagonal\n"
             "g, v = fgopt.FactorGraph(), fgopt.Variables()\n"
             "n = Diagonal.sigmas([0.1, 0.5, 0.5])\n"
             "g.add(PriorFactor(key('x', 1), SE2.from_xytheta(0, 0, 0), n))\n"
             "g.add(BetweenFactor(key('x', 1), key('x', 2), SE2.from_xytheta(5, 0, 0), n))\n"
             "v.add(key('x', 1), SE2.from_xytheta(0.2, -0.3, 0.2))\n"
             "v.add(key('x', 2), SE2.from_xytheta(5.1, 0.3, -0.1))\n"
             "assert fgopt.optimize(g, v).final_cost < 1e-12\n")
    env = {**os.environ, "FGOPT_NUMPY_BUDGET": "0"}
    out = subprocess.run([sys.executable, "-c", solve + "import sys; print('numba' in sys.modules)"],
                         capture_output=True, text=True, cwd=REPO, env=env)
    assert out.returncode == 0 and out.stdout.split() == ["True"], out.stdout + out.stderr
    env["FGOPT_NUMPY_BUDGET"] = "-1"
    out = subprocess.run([sys.executable, "-c", solve], capture_output=True, text=True, cwd=REPO,
                         env=env)
    assert out.returncode != 0 and "FgoptError: FGOPT_NUMPY_BUDGET='-1'" in out.stderr
