"""Deferred numba: ``@njit`` kernels that import and compile numba only when first called.

``import numba`` costs 0.25-0.4 s and its first compile initializes numba's target context
(another ~0.7 s; loading cached machine code skips that, :mod:`fgopt._cache_root`), so fgopt's
modules must not touch numba at import time.
:func:`njit` has numba's ``njit`` signature but returns a :class:`LazyKernel`: a proxy that
builds the real dispatcher (``numba.njit(**options)(py_func)``) on its first call. Inside other
jitted code the proxy types as that dispatcher (numba reads ``_numba_type_``), so kernels call
kernels exactly as before, and ``cache=True`` keeps working: numba's cache is keyed on the
function's source file and qualified name, which the proxy does not change.

:func:`prange` is ``numba.prange`` for kernels compiled with ``parallel=True``: numba recognizes
it by identity, so a module that uses it resolves the name when the kernel is built (the proxy
re-binds ``prange`` in the kernel's globals before compiling).

Small inputs can skip numba altogether: :meth:`LazyKernel.python` (or :func:`python_mode`)
runs the same function as plain Python, calls to other kernels included. Callers use it where
the work is tiny (a 5-pose retract, the per-value group operations of a script's first values),
where numba's 0.5 s of import and initialization per process would dominate.

Which path a small batch takes is a rent-or-buy choice, decided once per process: NumPy twins
("renting": no start-up, ~4x slower per call) until the process has spent
:data:`NUMPY_BUDGET_SECONDS` in them, then numba ("buying": its start-up is paid once, every
later call is fast). A script that solves one small problem never pays numba's start-up; a
notebook or benchmark that solves many switches to the compiled kernels after about that much
extra time (at most twice what knowing the future would have cost). ImuFactorsExample (303
factors) measured 22-26 ms per ``optimize`` on the twins and 6.1 ms on numba.
"""

from __future__ import annotations

import os
import sys
import threading
from collections.abc import Callable
from contextlib import contextmanager
from typing import Any

_lock = threading.RLock()


class _Mode(threading.local):
    """Per-thread flags; the class defaults make a read of an unset flag an attribute hit
    (``getattr(threading.local(), name, False)`` raises and catches inside: ~2.5 us, paid on
    every kernel call)."""

    python = False
    numpy = False


_mode = _Mode()


@contextmanager
def _thread_flag(name: str):
    """Set the per-thread flag ``name`` inside the block (restored after, also when nested)."""
    previous = getattr(_mode, name)
    setattr(_mode, name, True)
    try:
        yield
    finally:
        setattr(_mode, name, previous)


def python_mode():
    """Inside, every :class:`LazyKernel` runs its pure-Python function (nested kernel calls
    too): small inputs then need no numba import, compilation or cache load."""
    return _thread_flag("python")


def _budget_from_environment(default: float = 0.5) -> float:
    """``FGOPT_NUMPY_BUDGET`` seconds (``0``: always numba; ``inf``: small batches always NumPy)."""
    text = os.environ.get("FGOPT_NUMPY_BUDGET", "").strip()
    if not text:
        return default
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not value >= 0.0:
        from .errors import FgoptError

        raise FgoptError(f"FGOPT_NUMPY_BUDGET={text!r}: give seconds >= 0 (0: always numba, "
                         "inf: small batches always on their NumPy twins)")
    return value


#: Seconds a process spends in NumPy twins of small batches before they switch to numba
#: (about numba's import, initialization and a few cache loads; see the module docstring).
#: ``FGOPT_NUMPY_BUDGET`` overrides it (benchmarks of warm processes set 0).
NUMPY_BUDGET_SECONDS = _budget_from_environment()
_numpy_seconds = [0.0]


def numpy_budget_left() -> bool:
    """Whether small batches should still run their NumPy twins in this process."""
    return _numpy_seconds[0] < NUMPY_BUDGET_SECONDS


def charge_numpy(seconds: float) -> None:
    """Record ``seconds`` spent in NumPy twins (towards :data:`NUMPY_BUDGET_SECONDS`)."""
    _numpy_seconds[0] += seconds


def numpy_mode():
    """Inside, fgopt's kernels that have a NumPy form use it for every batch size (generated
    factor kernels' NumPy twins, the NumPy assembly, vectorized retracts, the NumPy reader):
    a solve that needs no numba import, compilation or cache load (see ``Problem(backend=)``)."""
    return _thread_flag("numpy")


def numpy_only() -> bool:
    """Whether this thread is inside :func:`numpy_mode`."""
    return _mode.numpy


def _numba_prange(*args: int) -> range:
    """Plain ``range`` until numba compiles the kernel (see the module docstring)."""
    return range(*args)


prange = _numba_prange


class LazyKernel:
    """A numba kernel compiled (or loaded from numba's cache) on first use."""

    def __init__(self, py_func: Callable, options: dict):
        self.py_func = py_func
        self.options = options
        self._dispatcher = None
        self.__name__ = py_func.__name__
        self.__qualname__ = py_func.__qualname__
        self.__doc__ = py_func.__doc__
        self.__module__ = py_func.__module__
        self.__wrapped__ = py_func

    @property
    def dispatcher(self) -> Any:
        """The real ``numba`` dispatcher (built on first access)."""
        d = self._dispatcher
        if d is None:
            with _lock:
                d = self._dispatcher
                if d is None:
                    import numba

                    from ._first_use import watch_numba

                    watch_numba()  # one line if compiling on first use takes long
                    g = self.py_func.__globals__
                    if g.get("prange") is _numba_prange:
                        g["prange"] = numba.prange
                    options = dict(self.options)
                    cache = options.pop("cache", False)
                    d = numba.njit(**options)(self.py_func)
                    if cache:  # under fgopt's cache root, not beside the package's sources
                        from ._cache_root import cache_in_root

                        cache_in_root(d)
                    self._dispatcher = d
        return d

    @property
    def compiled(self) -> bool:
        """True once numba has built the dispatcher (not necessarily any specialization)."""
        return self._dispatcher is not None

    @property
    def _numba_type_(self) -> Any:
        return self.dispatcher._numba_type_

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        if _mode.python:
            return self.py_func(*args, **kwargs)
        d = self._dispatcher
        if d is None:
            d = self.dispatcher
        return d(*args, **kwargs)

    def python(self, *args: Any, **kwargs: Any) -> Any:
        """Run the pure-Python function (nested kernels too); see :func:`python_mode`."""
        with python_mode():
            return self.py_func(*args, **kwargs)

    def __getattr__(self, name: str) -> Any:  # signatures, overloads, inspect_types, ...
        return getattr(self.dispatcher, name)

    def __repr__(self) -> str:
        state = "built" if self._dispatcher is not None else "not built yet"
        return f"<fgopt lazy numba kernel {self.__module__}.{self.__qualname__} ({state})>"


def njit(*args: Any, **options: Any) -> Any:
    """``numba.njit`` without importing numba: ``@njit`` or ``@njit(cache=True, ...)``."""
    if len(args) == 1 and callable(args[0]) and not options:
        return LazyKernel(args[0], {})
    if args:
        raise TypeError("fgopt._jit.njit takes keyword options only (no explicit signatures)")

    def wrap(fn: Callable) -> LazyKernel:
        return LazyKernel(fn, options)

    return wrap


_SPECIALIZED: dict = {}


def specialize(kernel: LazyKernel, value: int) -> Callable:
    """``kernel`` with its first argument, an integer id, fixed: ``specialize(k, 3)(a, b)`` is
    ``k(3, a, b)``, compiled for that id only.

    An id passed at run time makes numba type and compile every branch that switches on it (a
    calibration model's or Lie group's code, for every model or group). Here numba sees a
    constant and prunes the other branches before typing them:

    - an ``inline="always"`` kernel is inlined into a new entry where the id is a constant
      (so are the inlined kernels it passes the id to);
    - another kernel is copied with every kernel it calls under the same first parameter name
      specialized in turn (their id argument is then ignored), so only the inlined leaves that
      branch on the id need it constant.

    Each entry has its own numba cache files (``<kernel>[value]``).
    """
    entry = _SPECIALIZED.get((kernel, value))
    if entry is None:
        if kernel.options.get("inline") == "always":
            entry = _entry(kernel, value, keep_id=False)
        else:
            import functools

            entry = functools.partial(_with_id(kernel, value), value)
        entry = _SPECIALIZED.setdefault((kernel, value), entry)
    return entry


def specialized_copy(kernel: LazyKernel, value: int) -> LazyKernel:
    """The copy of non-inlined ``kernel`` that :func:`specialize` runs for id ``value``, still
    called with an id (which it ignores): for numba code that calls it (a small-problem
    driver), so that both share its machine code."""
    return _with_id(kernel, value)


def _first_parameter(fn: Callable) -> str | None:
    code = fn.__code__
    return code.co_varnames[0] if code.co_argcount else None


def _with_id(kernel: LazyKernel, value: int) -> LazyKernel:
    """``kernel`` for id ``value``, still called with an id (which it ignores)."""
    key = (kernel, value, "id")
    entry = _SPECIALIZED.get(key)
    if entry is None:
        if kernel.options.get("inline") == "always":
            entry = _entry(kernel, value, keep_id=True)
        else:
            import types

            fn = kernel.py_func
            first = _first_parameter(fn)
            g = dict(fn.__globals__)
            for name in fn.__code__.co_names:
                callee = g.get(name)
                if isinstance(callee, LazyKernel) and _first_parameter(callee.py_func) == first:
                    g[name] = _with_id(callee, value)
            copy = types.FunctionType(fn.__code__, g, fn.__name__, fn.__defaults__,
                                      fn.__closure__)
            copy.__qualname__ = f"{fn.__qualname__}[{value}]"
            copy.__module__, copy.__doc__ = fn.__module__, fn.__doc__
            entry = LazyKernel(copy, kernel.options)
        entry = _SPECIALIZED.setdefault(key, entry)
    return entry


def _entry(kernel: LazyKernel, value: int, keep_id: bool) -> LazyKernel:
    """``entry(args) = kernel(value, args)`` (``keep_id``: ``entry(id, args)``, inlined too)."""
    import inspect

    names = list(inspect.signature(kernel.py_func).parameters)
    args = ", ".join(names[1:])
    params = ", ".join(names if keep_id else names[1:])
    ns = {"KERNEL": kernel, "VALUE": value, "__name__": kernel.__module__}
    # under the kernel's file name: numba's cache names its files after the source file and
    # the qualified name, and stamps them with the file
    exec(compile(f"def entry({params}):\n    return KERNEL(VALUE, {args})\n",
                 inspect.getfile(kernel.py_func), "exec"), ns)
    fn = ns["entry"]
    fn.__qualname__ = f"{kernel.__qualname__}[{value}]"
    fn.__module__, fn.__doc__ = kernel.__module__, kernel.__doc__
    options = dict(kernel.options)
    if not keep_id:
        del options["inline"]
    return LazyKernel(fn, options)


def is_numba_loaded() -> bool:
    """Whether numba has been imported in this process."""
    return "numba" in sys.modules
