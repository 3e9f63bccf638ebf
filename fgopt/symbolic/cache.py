"""On-disk cache of generated kernel modules, verified before they are imported.

Generated source is written as ``<cache root>/kernels/<module>.py`` (the root is
:func:`fgopt._cache_root.root`: ``$FGOPT_CACHE_DIR``, ``$XDG_CACHE_HOME/fgopt`` or
``~/.cache/fgopt``, private); the kernels in it use ``numba.njit(cache=True)``, and numba keeps
their machine code under ``<cache root>/numba``. A second process that builds the same factor
type finds the file, imports it (no SymPy), and numba loads the compiled code: nothing is
re-derived or re-compiled.

Every entry is signed when fgopt writes it: ``<module>.sig`` holds
``HMAC-SHA256(key, module name + the exact bytes written)`` under the root's per-user key
(``<root>/key``, 0600). Before an entry is imported its bytes are read once, checked against the
signature and executed from that same buffer (never re-read from disk), so an edited, truncated,
emptied or replaced file - or a signature copied from another entry - is never executed: the
entry is discarded and regenerated, with one :class:`CacheWarning` naming it. An entry that is
intact but fails to import or lacks what its user needs is handled the same way. Python's own
bytecode cache is not used (it would run a ``.pyc`` nobody checked); fgopt keeps the compiled
code object beside the entry (``<module>.<python tag>.bc``), signed together with the source's
digest. A per-entry signature (rather than one signed index) needs no lock between processes that
write different entries at the same time, and binds the module name so signatures cannot be
swapped between entries.

The key hashes the factor function's code (its source, or bytecode when the source is not
available, plus the code / values of the globals it references), its argument types, the
variable pattern and options, fgopt's version and the source of the ``fgopt.symbolic``
modules that generate code (:data:`FINGERPRINT_MODULES`; editing them invalidates old entries).
"""

from __future__ import annotations

import hashlib
import hmac
import inspect
import linecache
import marshal
import os
import re
import sys
import textwrap
import types
import warnings
from collections.abc import Callable
from functools import lru_cache
from pathlib import Path
from typing import Any

from .. import _cache_root

#: Counters for tests and benchmarks: kernels ``derived`` (SymPy ran), ``loaded`` from disk,
#: ``shipped`` (a built-in factor's source came with the package).
STATS = {"derived": 0, "loaded": 0, "written": 0, "shipped": 0}


class CacheWarning(UserWarning):
    """A kernel cache entry failed verification or import; it was discarded and regenerated."""


def cache_dir() -> Path:
    """The kernel cache directory ``<root>/kernels`` (created private if missing)."""
    return _cache_root.subdir(_cache_root.KERNELS)


#: Modules whose source defines what generated kernels compute (hashed into every key). Other
#: files in this package (e.g. another back end) do not invalidate cached kernels.
FINGERPRINT_MODULES = ("_count", "_ir", "_sym", "cameras", "codegen", "cse", "derive",
                       "functions", "jacobians", "lie", "linearize", "matrix", "ops", "pose",
                       "printer", "rot", "runtime")


@lru_cache(maxsize=1)
def package_fingerprint() -> str:
    """Hash of fgopt's version and the sources of :data:`FINGERPRINT_MODULES` (read once per
    process: it is part of every generated module's key, looked up on every fixed solve)."""
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


# inspect's test for the first line of a definition (decorators included), as it backtracks
_DEFINITION_LINE = re.compile(r"^(\s*def\s)|(\s*async\s+def\s)|(.*(?<!\w)lambda(:|\s))|^(\s*@)")


def _last_code_line(code: types.CodeType) -> int:
    """The last source line any instruction of ``code`` (or of a code object nested in it)
    spans."""
    last = max((end for _, end, _, _ in code.co_positions() if end is not None),
               default=code.co_firstlineno)
    for c in code.co_consts:
        if isinstance(c, types.CodeType):
            last = max(last, _last_code_line(c))
    return last


def function_source(fn: types.FunctionType) -> str:
    """The source lines of ``fn``: from its first decorator or ``def`` line (found as
    ``inspect.getsource`` finds it) to the last line its code spans. The same text as
    ``inspect.getsource`` except that comments after the last statement are left out, without
    the ``tokenize`` pass that costs ``getsource`` ~8 ms in a new process (its regular
    expressions compile on first use; two thirds of the kernel lookup of a fresh solve).

    Like ``getsource``, it follows ``__wrapped__`` (``functools.wraps``) to the function
    wrapped. Raises ``OSError`` when the source is not available, ``TypeError`` when what is
    wrapped is not a Python function."""
    fn = inspect.unwrap(fn)
    if not isinstance(fn, types.FunctionType):
        raise TypeError(f"{fn!r} is not a Python function")
    code = fn.__code__
    lines = linecache.getlines(code.co_filename, fn.__globals__)
    if not lines:
        raise OSError(f"no source for {code.co_filename}")
    start = min(code.co_firstlineno, len(lines)) - 1
    while start > 0 and not _DEFINITION_LINE.match(lines[start]):
        start -= 1
    return "".join(lines[start:_last_code_line(code)])


def _hash_function(h: Any, fn: Callable, seen: set) -> None:
    if id(fn) in seen:
        return
    seen.add(id(fn))
    code = fn.__code__
    try:
        h.update(textwrap.dedent(function_source(fn)).encode())
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


# ------------------------------------------------------------------------- signing, import
_SIG, _BC = ".sig", f".{sys.implementation.cache_tag}.bc"


def _sign(modname: str, data: bytes) -> str:
    key = _cache_root.secret_key()
    return hmac.new(key, b"fgopt-kernel\0" + modname.encode() + b"\0" + data,
                    hashlib.sha256).hexdigest()


def _bc_mac(modname: str, digest: bytes, code: bytes) -> bytes:
    msg = b"".join((b"fgopt-bytecode\0", modname.encode(), b"\0", _BC.encode(), b"\0", digest,
                    code))
    return hmac.new(_cache_root.secret_key(), msg, hashlib.sha256).digest()


def _read(path: Path) -> bytes | None:
    try:
        return path.read_bytes()
    except OSError:
        return None


def _write_atomic(path: Path, data: bytes) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{os.urandom(4).hex()}.tmp")  # threads
    with os.fdopen(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600), "wb") as fh:
        fh.write(data)
    os.replace(tmp, path)


def _code(path: Path, modname: str, data: bytes) -> types.CodeType:
    """The code object of verified ``data``: from the signed bytecode file, else compiled.

    Bytecode file: ``MAC (32 bytes) | sha256 of the source (32) | marshal data``. One made for
    other source bytes is stale and quietly replaced; one whose MAC fails is reported.
    """
    bc_path = path.with_name(modname + _BC)
    digest = hashlib.sha256(data).digest()
    blob = _read(bc_path)
    if blob is not None and blob[32:64] == digest:
        mac, body = blob[:32], blob[64:]
        if hmac.compare_digest(mac, _bc_mac(modname, digest, body)):
            code = marshal.loads(body)
            if code.co_filename == str(path):  # else the cache folder moved: recompile
                return code
        else:
            _warn(modname, bc_path, "its bytecode does not match its signature")
    code = compile(data, str(path), "exec", dont_inherit=True)
    body = marshal.dumps(code)
    try:
        _write_atomic(bc_path, _bc_mac(modname, digest, body) + digest + body)
    except OSError:
        pass  # a read-only cache still works, it only compiles each time
    return code


def _exec(path: Path, modname: str, data: bytes) -> types.ModuleType:
    if modname in sys.modules:
        return sys.modules[modname]
    code = _code(path, modname, data)
    module = types.ModuleType(modname)
    module.__file__ = str(path)
    module.__fgopt_source__ = data.decode()  # the verified text (the file may change later)
    sys.modules[modname] = module
    try:
        exec(code, module.__dict__)
        if "numba" in sys.modules:  # its @numba.njit(cache=True) kernels: cached under the root
            _cache_root.cache_module_in_root(module)
    except BaseException:
        del sys.modules[modname]
        raise
    return module


def _warn(modname: str, path: Path, problem: str) -> None:
    """One warning per discarded entry (the regenerated entry is then used silently)."""
    warnings.warn(f"fgopt kernel cache: entry {modname} ({path}): {problem}; it was discarded "
                  "and is regenerated", CacheWarning, stacklevel=4)


def _discard(path: Path, modname: str) -> None:
    for p in (path, path.with_name(modname + _SIG), path.with_name(modname + _BC)):
        try:
            p.unlink()
        except FileNotFoundError:
            pass


def _problem(path: Path, modname: str, data: bytes) -> str | None:
    sig = _read(path.with_name(modname + _SIG))
    if sig is None:
        return "it has no signature (not written by this fgopt)"
    if len(data) == 0:
        return "it is empty"
    if not hmac.compare_digest(sig.strip(), _sign(modname, data).encode()):
        return "its bytes differ from what fgopt wrote (edited, truncated or replaced)"
    return None


def verify(path: Path) -> str | None:
    """``None`` if the entry at ``path`` holds exactly the bytes fgopt signed, else the problem."""
    data = _read(path)
    return "unreadable" if data is None else _problem(path, path.stem, data)


def load(name: str, key: str, required: tuple[str, ...] = ()) -> types.ModuleType | None:
    """The cached module for ``key``, verified; ``None`` if there is none or it was discarded.

    ``required``: names the module must define (else it is treated as broken).
    """
    modname = module_name(name, key)
    if modname in sys.modules:
        return sys.modules[modname]
    path = module_path(name, key)
    _cache_root.secret_key()  # made on first use; that removes entries no key ever signed
    data = _read(path)
    if data is None:
        return None
    problem = _problem(path, modname, data)  # the very bytes that will run
    module = None
    if problem is None:
        try:
            module = _exec(path, modname, data)
        except Exception as exc:  # noqa: BLE001 - any failure of a cached entry: regenerate it
            problem = f"it does not import ({type(exc).__name__}: {exc})"
        else:
            missing = [n for n in required if not hasattr(module, n)]
            if missing:
                sys.modules.pop(modname, None)
                problem = f"it lacks {', '.join(missing)}"
    if problem is not None:
        _discard(path, modname)
        _warn(modname, path, problem)
        return None
    STATS["loaded"] += 1
    return module


def store(name: str, key: str, source: str) -> types.ModuleType:
    """Sign and write ``source`` (atomically; an identical entry is left as it is), then import
    it from memory."""
    modname = module_name(name, key)
    path = module_path(name, key)
    data = source.encode()
    sig = _sign(modname, data).encode()
    sig_path = path.with_name(modname + _SIG)
    if _read(path) != data or _read(sig_path) != sig:
        # signature first: a reader between the two writes sees a mismatch, never an unsigned
        # file it could mistake for a legacy entry
        _write_atomic(sig_path, sig)
        _write_atomic(path, data)
        STATS["written"] += 1
    return _exec(path, modname, data)


# ------------------------------------------------------------------------------ inspection
def entries() -> list[dict]:
    """Each kernel entry: ``name``, ``path``, ``bytes`` (source + signature + bytecode) and
    ``problem`` (``None`` when it verifies)."""
    out = []
    d = cache_dir()
    for path in sorted(d.glob("fgk_*.py")):
        size = sum(p.stat().st_size for p in (path, path.with_name(path.stem + _SIG),
                                              path.with_name(path.stem + _BC)) if p.exists())
        out.append({"name": path.stem, "path": path, "bytes": size, "problem": verify(path)})
    return out


def clear() -> dict:
    """Remove every kernel entry and numba's cache under the root; returns counts and bytes."""
    root = _cache_root.root()
    removed = {"entries": 0, "numba_files": 0, "bytes": 0}
    kernels = root / _cache_root.KERNELS
    if kernels.is_dir():
        _cache_root.check_private(kernels)
        stale = list(kernels.glob(".fgk_*.tmp")) + list(kernels.glob("__pycache__/fgk_*.pyc"))
        for p in list(kernels.glob("fgk_*")) + stale:  # .pyc: left by older fgopt versions
            removed["bytes"] += p.stat().st_size
            removed["entries"] += p.suffix == ".py"
            p.unlink()
    numba_dir = root / _cache_root.NUMBA
    if numba_dir.is_dir():
        _cache_root.check_private(numba_dir)
        for p in sorted(numba_dir.rglob("*"), reverse=True):
            if p.is_file() and p.suffix in (".nbi", ".nbc"):
                removed["bytes"] += p.stat().st_size
                removed["numba_files"] += 1
                p.unlink()
            elif p.is_dir() and not any(p.iterdir()):
                p.rmdir()
    return removed
