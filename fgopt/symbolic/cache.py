"""On-disk cache of generated kernel modules.

Generated source is written as ``<cache dir>/kernels/<name>_<key>.py`` and imported with
importlib; the kernels in it use ``numba.njit(cache=True)``, so numba keeps their machine code
next to it (``__pycache__``). A second process that builds the same factor type finds the file,
imports it (no SymPy), and numba loads the compiled code: nothing is re-derived or re-compiled.

The key hashes the factor function's code (its source, or bytecode when the source is not
available, plus the code / values of the globals it references), its argument types, the
variable pattern and options, fgopt's version and the source of the ``fgopt.symbolic``
modules that generate code (:data:`FINGERPRINT_MODULES`; editing them invalidates old entries).

Cache directory: ``$FGOPT_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/fgopt`` or
``~/.cache/fgopt``; a temporary directory if that is not writable.
"""

from __future__ import annotations

import hashlib
import importlib.util
import inspect
import marshal
import os
import sys
import tempfile
import textwrap
import types
from collections.abc import Callable
from functools import lru_cache
from pathlib import Path
from typing import Any

#: Counters for tests and benchmarks: kernels ``derived`` (SymPy ran), ``loaded`` from disk.
STATS = {"derived": 0, "loaded": 0, "written": 0}


def cache_dir() -> Path:
    """The kernel cache directory (created if missing)."""
    env = os.environ.get("FGOPT_CACHE_DIR")
    if env:
        base = Path(env).expanduser()
    else:
        xdg = os.environ.get("XDG_CACHE_HOME")
        base = (Path(xdg) if xdg else Path.home() / ".cache") / "fgopt"
    path = base / "kernels"
    try:
        path.mkdir(parents=True, exist_ok=True)
        if not os.access(path, os.W_OK):
            raise PermissionError(str(path))
    except OSError:
        path = Path(tempfile.gettempdir()) / f"fgopt-{os.getuid() if hasattr(os, 'getuid') else 0}" \
            / "kernels"
        path.mkdir(parents=True, exist_ok=True)
    return path


#: Modules whose source defines what generated kernels compute (hashed into every key). Other
#: files in this package (e.g. another back end) do not invalidate cached kernels.
FINGERPRINT_MODULES = ("_sym", "cameras", "codegen", "cse", "derive", "functions", "jacobians",
                       "lie", "linearize", "matrix", "ops", "pose", "printer", "rot", "runtime")


@lru_cache(maxsize=1)
def package_fingerprint() -> str:
    """Hash of fgopt's version and the sources of :data:`FINGERPRINT_MODULES`."""
    from .._version import __version__

    h = hashlib.sha256(__version__.encode())
    here = Path(__file__).parent
    for name in FINGERPRINT_MODULES:
        h.update(name.encode())
        h.update((here / f"{name}.py").read_bytes())
    return h.hexdigest()


def _code_names(code: types.CodeType) -> set:
    names = set(code.co_names)
    for c in code.co_consts:
        if isinstance(c, types.CodeType):
            names |= _code_names(c)
    return names


def _hash_value(h: Any, v: Any, seen: set) -> None:
    if isinstance(v, types.FunctionType):
        _hash_function(h, v, seen)
    elif isinstance(v, (int, float, complex, str, bytes, bool, type(None))) or isinstance(v, tuple) and all(isinstance(x, (int, float, str, bool)) for x in v):
        h.update(repr(v).encode())
    elif type(v).__module__ == "numpy" and hasattr(v, "tobytes"):
        h.update(v.tobytes())
    elif isinstance(v, type):
        h.update(f"{v.__module__}.{v.__qualname__}".encode())
    else:  # other objects: by type only (their repr may hold a memory address)
        h.update(f"<{type(v).__module__}.{type(v).__qualname__}>".encode())


def _hash_function(h: Any, fn: Callable, seen: set) -> None:
    if id(fn) in seen:
        return
    seen.add(id(fn))
    code = fn.__code__
    try:
        h.update(textwrap.dedent(inspect.getsource(fn)).encode())
    except (OSError, TypeError):
        h.update(marshal.dumps(code))
    for d in (fn.__defaults__ or ()) + tuple((fn.__kwdefaults__ or {}).values()):
        _hash_value(h, d, seen)
    module = getattr(fn, "__module__", "") or ""
    if module.startswith("fgopt.symbolic.") and module.rsplit(".", 1)[1] in FINGERPRINT_MODULES:
        return  # covered by package_fingerprint
    for name in sorted(_code_names(code)):
        if name in fn.__globals__:
            h.update(name.encode())
            _hash_value(h, fn.__globals__[name], seen)
    for cell in fn.__closure__ or ():
        try:
            _hash_value(h, cell.cell_contents, seen)
        except ValueError:  # empty cell
            pass


def function_fingerprint(fn: Callable) -> str:
    """Hash of a function's code and of the code / values of the globals it uses."""
    h = hashlib.sha256()
    _hash_function(h, fn, set())
    return h.hexdigest()


def kernel_key(fn: Callable, parts: tuple, fingerprint: str | None = None) -> str:
    """Cache key of one generated module: function fingerprint (``fingerprint`` when the caller
    already knows it) + ``parts`` + package."""
    from .codegen import CODEGEN_VERSION

    h = hashlib.sha256()
    h.update((fingerprint or function_fingerprint(fn)).encode())
    h.update(repr(parts).encode())
    h.update(package_fingerprint().encode())
    h.update(CODEGEN_VERSION.encode())
    return h.hexdigest()[:20]


def module_path(name: str, key: str) -> Path:
    return cache_dir() / f"{module_name(name, key)}.py"


def module_name(name: str, key: str) -> str:
    safe = "".join(c if c.isalnum() or c == "_" else "_" for c in name)
    return f"fgk_{safe}_{key}"


def _import(path: Path, modname: str) -> types.ModuleType:
    if modname in sys.modules:
        return sys.modules[modname]
    spec = importlib.util.spec_from_file_location(modname, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[modname] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[modname]
        raise
    return module


def load(name: str, key: str) -> types.ModuleType | None:
    """The cached module for ``key``, or ``None`` if there is none (or it is unreadable)."""
    path = module_path(name, key)
    if not path.exists():
        return None
    try:
        module = _import(path, module_name(name, key))
    except Exception:  # noqa: BLE001 - a corrupt / partial file: regenerate it
        return None
    STATS["loaded"] += 1
    return module


def store(name: str, key: str, source: str) -> types.ModuleType:
    """Write ``source`` atomically (never overwriting an existing entry) and import it."""
    path = module_path(name, key)
    if not path.exists():
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        tmp.write_text(source)
        try:
            os.link(tmp, path)  # atomic, fails if another process won the race
        except FileExistsError:
            pass
        except OSError:
            if not path.exists():
                os.replace(tmp, path)
        finally:
            if tmp.exists():
                tmp.unlink()
        STATS["written"] += 1
    return _import(path, module_name(name, key))
