"""Start-up: ``import fgopt`` loads no heavy dependency, and deferred numba kernels behave as
numba kernels (compiled on first call, callable from other kernels, parallel ``prange``)."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fgopt._jit import LazyKernel, njit, prange, specialize

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



@njit(cache=False, inline="always")
def _switch(which, x):
    if which == 0:
        return x + 1.0
    return x + "a"  # does not type: the entry for 0 compiles only because it is pruned


@njit(cache=False)
def _outer(which, x):
    return 2.0 * _switch(which, x)


def test_specialize_compiles_only_the_branch_of_its_constant():
    """``specialize(kernel, 0)`` is ``kernel(0, ...)`` compiled with the branches 0 rules out
    pruned before typing, where a run-time 0 types every branch (and here fails); a kernel
    that is not inlined passes the constant on to the inlined kernel it calls."""
    import numba

    assert specialize(_switch, 0)(1.5) == 2.5
    assert specialize(_switch, 0) is specialize(_switch, 0)
    assert specialize(_outer, 0)(1.5) == 5.0
    for kernel in (_switch, _outer):
        with pytest.raises(numba.core.errors.TypingError):
            kernel(0, 1.5)


_CACHED_ENTRY = (
    "import sys\nimport numpy as np\nfrom fgopt._jit import specialize\n"
    "from fgopt.manifolds._kernels import dispatch, SE2_ID\n"
    "entry = specialize(dispatch.batch_retract, SE2_ID)\n"
    "x = np.array([[1.0, 0.0, 2.0, 3.0]])\n"
    "assert np.allclose(entry(x, np.array([[0.0, 0.5, -1.0]])), [[1.0, 0.0, 2.5, 2.0]])\n"
    "s = entry.stats\nprint(sum(s.cache_hits.values()), sum(s.cache_misses.values()),\n"
    "      'numba.np.arraymath' in sys.modules)\n")


@pytest.fixture(scope="module")
def cached_entry_twice(tmp_path_factory) -> list:
    """(hits, misses, lowering registries imported) of :data:`_CACHED_ENTRY` in two processes
    sharing an empty cache (run once for the tests that read it)."""
    cache = tmp_path_factory.mktemp("entry-cache")
    env = dict(os.environ, FGOPT_CACHE_DIR=str(cache), PYTHONPATH=str(REPO))
    return [subprocess.run([sys.executable, "-c", _CACHED_ENTRY], capture_output=True,
                           text=True, cwd=REPO, check=True, env=env).stdout.split()
            for _ in range(2)]


def test_a_specialized_entry_loads_from_the_cache_in_a_new_process(cached_entry_twice):
    """A per-group entry compiled in one process is loaded from numba's cache in the next (a
    cache key that changed per process would compile it again every run)."""
    runs = cached_entry_twice
    assert runs[0][:2] == ["0", "1"] and runs[1][:2] == ["1", "0"]  # (hits, misses)


def test_loading_cached_machine_code_imports_no_lowering_registries(cached_entry_twice):
    """A new process that only loads cached kernels skips numba's lowering registries (~0.7 s
    of imports that only a compile needs), and the loaded kernel, which allocates its result
    through numba's runtime, still computes the retraction (a pure translation step here)."""
    runs = cached_entry_twice
    assert runs[0][2] == "True"  # compiling needs them
    assert runs[1] == ["1", "0", "False"]


def _run(code: str) -> str:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          cwd=REPO, check=True).stdout.strip()


_SNAPSHOT = (
    "import os, sys, numpy, scipy, scipy.sparse, threadpoolctl\n"
    "def snapshot():\n"
    "    return (dict(os.environ), list(sys.meta_path), list(sys.path_hooks),\n"
    "            {k: id(v) for k, v in vars(numpy).items()},\n"
    "            {k: id(v) for k, v in vars(scipy).items()},\n"
    "            {k: id(v) for k, v in vars(scipy.sparse).items()},\n"
    "            {i['filepath']: i['num_threads'] for i in threadpoolctl.threadpool_info()})\n"
    "before = snapshot()\n")


def test_import_fgopt_changes_no_environment_hook_or_numpy_scipy_state():
    """``import fgopt`` (after numpy and scipy) leaves ``os.environ``, ``sys.meta_path`` and
    ``sys.path_hooks``, numpy's and scipy's module dictionaries and the BLAS thread counts
    exactly as they were."""
    out = _run(_SNAPSHOT + "import fgopt\nfgopt.FactorGraph, fgopt.Variables\n"
               "after = snapshot()\n"
               "print([i for i, (a, b) in enumerate(zip(before, after)) if a != b])")
    assert out == "[]"


def test_a_solve_leaves_the_environment_hooks_and_blas_threads_as_they_were():
    """A sparse solve (numba backend, BLAS limited inside it) leaves ``os.environ``, the import
    hooks, the entries numpy and scipy had and the thread counts of the BLAS libraries loaded
    before it as it found them."""
    out = _run(
        _SNAPSHOT + "import fgopt\n"
        "from fgopt.datasets import manhattan_2d\n"
        "m = manhattan_2d(200); graph, initial = m.graph, m.initial\n"
        "r = fgopt.optimize(graph, initial, max_iterations=3, backend='numba')\n"
        "after = snapshot()\n"
        "same = [a == b for a, b in zip(before, after)]\n"
        "same[3:] = [all(after[i].get(k) == v for k, v in before[i].items()) for i in (3, 4, 5, 6)]\n"
        "print(r.iterations > 0, same)")
    assert out == "True " + str([True] * 7)
