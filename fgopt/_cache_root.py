"""The private directory fgopt keeps its caches in, its signing key, and numba's cache routing.

Everything fgopt caches on disk lives under one root: generated kernel modules
(``kernels/``, see :mod:`fgopt.symbolic.cache`), numba's compiled machine code for fgopt's own
functions and for generated kernels (``numba/``), and the per-user key that signs kernel entries
(``key``). The root is

- ``$FGOPT_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/fgopt`` or ``~/.cache/fgopt``;
- ``<system temp dir>/fgopt-<uid>`` if that cannot be created or written.

Code found under the root is executed (kernel modules after their signature is checked, numba's
cache index is a pickle), so the root must be private: it is created with mode 0700, and a root
(or subfolder) owned by another user or writable by group or others is refused with an
:class:`~fgopt.errors.FgoptError` naming it. The key is 32 random bytes in ``key``, mode 0600;
someone who cannot read it cannot forge a kernel entry's signature.

numba's machine code for fgopt's own kernels (:func:`fgopt._jit.njit` with ``cache=True``) and
for generated kernels goes under ``<root>/numba``: :func:`cache_in_root` gives such a dispatcher a
cache of its own before its first compile (one dispatcher at a time: numba's global list of
cache locators, and so a user's own numba functions, are left alone). An entry's stamp covers
every fgopt module with numba code, not only the function's own file (numba's rule): a kernel
compiled against an older version of a kernel it calls is recompiled.
"""

from __future__ import annotations

import os
import stat
import sys
from pathlib import Path
from typing import Any

from .errors import FgoptError

#: Subfolder names under the root.
KERNELS, NUMBA, KEY_FILE = "kernels", "numba", "key"

_PACKAGE_DIR = os.path.dirname(os.path.realpath(__file__))
_KEYS: dict[str, bytes] = {}


def _uid() -> int | None:
    return os.getuid() if hasattr(os, "getuid") else None  # no ownership on Windows


def check_private(path: Path, what: str = "fgopt cache folder") -> None:
    """Refuse ``path`` (an existing folder) unless it is ours and not writable by others."""
    st = os.stat(path)
    uid = _uid()
    if not stat.S_ISDIR(st.st_mode):
        raise FgoptError(f"{what} {path} is not a folder; set FGOPT_CACHE_DIR to a private "
                         "folder of yours")
    if uid is None:
        return
    if st.st_uid != uid:
        raise FgoptError(
            f"{what} {path} is owned by uid {st.st_uid}, not by you (uid {uid}): fgopt runs code "
            "cached there, so it refuses it. Set FGOPT_CACHE_DIR to a folder of yours, or "
            "remove this one if you own its parent")
    if st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        raise FgoptError(
            f"{what} {path} is writable by group or others (mode {stat.S_IMODE(st.st_mode):04o}): "
            f"fgopt runs code cached there, so it refuses it. Run `chmod 700 {path}` (or "
            "`fgopt cache clear` after it), or set FGOPT_CACHE_DIR to a private folder")


def _make_private(path: Path) -> None:
    """Create ``path`` (and missing parents) with mode 0700; existing folders are checked."""
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        try:
            os.mkdir(path, 0o700)
            os.chmod(path, 0o700)  # mkdir's mode is masked by umask only downward; be explicit
        except FileExistsError:  # another process made it meanwhile: checked below
            pass
    check_private(path)


def _preferred() -> Path:
    env = os.environ.get("FGOPT_CACHE_DIR")
    if env:
        return Path(env).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "fgopt"


def fallback_root() -> Path:
    """``<system temp dir>/fgopt-<uid>``: the root when the preferred one is not writable."""
    import tempfile

    return Path(tempfile.gettempdir()) / f"fgopt-{_uid() if _uid() is not None else 'user'}"


def root() -> Path:
    """The cache root (created private, or checked private); see the module docstring."""
    path = _preferred()
    try:
        _make_private(path)
        if not os.access(path, os.W_OK | os.X_OK):
            raise PermissionError(str(path))
        return path
    except FgoptError:
        raise
    except OSError:
        pass
    path = fallback_root()
    try:
        _make_private(path)
    except FgoptError:
        raise
    except OSError as exc:
        raise FgoptError(f"cannot create a cache folder: neither {_preferred()} nor {path} is "
                         f"writable ({exc}); set FGOPT_CACHE_DIR to a writable folder") from None
    return path


def subdir(name: str, base: Path | None = None) -> Path:
    """``<root>/<name>``, created private (0700) and checked like the root."""
    path = (base or root()) / name
    _make_private(path)
    return path


def secret_key(base: Path | None = None) -> bytes:
    """The per-user signing key of the root (created on first use: 32 random bytes, 0600).

    When the key is created, kernel entries already in ``kernels/`` (written without a key, by
    an older fgopt) cannot be verified and are removed.
    """
    base = base or root()
    path = base / KEY_FILE
    cached = _KEYS.get(str(path))
    if cached is not None:
        return cached
    if not path.exists():
        tmp = base / f".{KEY_FILE}.{os.getpid()}.{os.urandom(4).hex()}.tmp"
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        try:
            os.write(fd, os.urandom(32))
        finally:
            os.close(fd)
        try:
            os.link(tmp, path)  # atomic; fails if another process made the key first
            created = True
        except FileExistsError:
            created = False
        finally:
            os.unlink(tmp)
        if created:
            _remove_unverifiable(base / KERNELS)
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0))
    try:
        st = os.fstat(fd)
        uid = _uid()
        if uid is not None and (st.st_uid != uid or st.st_mode & 0o077):
            raise FgoptError(
                f"fgopt cache key {path} is owned by uid {st.st_uid} with mode "
                f"{stat.S_IMODE(st.st_mode):04o}; it must be yours with mode 0600. Remove it "
                "(`fgopt cache clear` regenerates the cache)")
        key = os.read(fd, 64)
    finally:
        os.close(fd)
    if len(key) != 32:
        raise FgoptError(f"fgopt cache key {path} is damaged ({len(key)} bytes, expected 32); "
                         "remove it and run `fgopt cache clear`")
    _KEYS[str(path)] = key
    return key


def _remove_unverifiable(kernels: Path) -> None:
    if not kernels.is_dir():
        return
    for p in kernels.glob("fgk_*"):
        try:
            p.unlink()
        except OSError:
            pass


# ---------------------------------------------------------------------------- numba's cache
_NUMBA_DIRS: dict[tuple, str] = {}
_REAL: dict[str, str] = {}
#: Words that mark a module with numba code (kernels, and what kernels call or inline).
_NUMBA_MARKS = (b"njit", b"intrinsic", b"overload")
_DIGESTS: dict[str, bytes] = {}


def numba_sources_digest(package_dir: str = _PACKAGE_DIR) -> bytes:
    """sha256 of the path and content of every module under ``package_dir`` with numba code
    (:data:`_NUMBA_MARKS`), read once per process (~5 ms for fgopt's 55 such modules)."""
    digest = _DIGESTS.get(package_dir)
    if digest is None:
        import hashlib

        h = hashlib.sha256()
        for path in sorted(Path(package_dir).rglob("*.py")):
            text = path.read_bytes()
            if any(mark in text for mark in _NUMBA_MARKS):
                h.update(path.relative_to(package_dir).as_posix().encode() + b"\0")
                h.update(hashlib.sha256(text).digest())
        digest = _DIGESTS[package_dir] = h.digest()
    return digest


def _numba_dir() -> str:
    """``<root>/numba`` (checked once per process and cache location: ~150 decorations)."""
    where = tuple(os.environ.get(v) for v in ("FGOPT_CACHE_DIR", "XDG_CACHE_HOME", "HOME"))
    d = _NUMBA_DIRS.get(where)
    if d is None:
        d = _NUMBA_DIRS[where] = str(subdir(NUMBA))
    return d


def _is_fgopt_file(py_file: str) -> bool:
    real = _REAL.get(py_file)
    if real is None:
        real = _REAL[py_file] = os.path.realpath(py_file)
    if real.startswith(_PACKAGE_DIR + os.sep):
        return True
    parent = os.path.dirname(real)
    if os.path.basename(parent) != KERNELS or not os.path.basename(real).startswith("fgk_"):
        return False
    try:
        return parent == os.path.realpath(os.path.join(root(), KERNELS))
    except FgoptError:  # the kernel cache refuses this root before any kernel is decorated
        return False


_CACHE_CLASS: list = []


def _root_cache_class() -> Any:
    """numba's ``FunctionCache`` with one locator: ``<root>/numba``, stamped with the package's
    numba sources (built on first use: numba is imported by then)."""
    if _CACHE_CLASS:
        return _CACHE_CLASS[0]
    from numba.core import caching

    class FgoptCacheLocator(caching._SourceFileBackedLocatorMixin, caching._CacheLocator):
        """numba cache of fgopt's code and generated kernels: ``<fgopt cache root>/numba``."""

        def __init__(self, py_func: Any, py_file: str):
            self._py_file = py_file
            self._lineno = py_func.__code__.co_firstlineno
            self._cache_path = os.path.join(_numba_dir(), self.get_suitable_cache_subpath(py_file))

        def get_cache_path(self) -> str:
            return self._cache_path

        def get_source_stamp(self) -> Any:
            # numba stamps an entry with its own file only: a kernel that calls (and inlines) a
            # kernel of another file would load stale machine code once that file changed (a
            # git pull into an editable install, a kernel edited during development). So every
            # fgopt module with numba code is part of every entry's stamp.
            return super().get_source_stamp(), numba_sources_digest()

        @classmethod
        def from_function(cls, py_func: Any, py_file: str) -> Any:
            if not _is_fgopt_file(py_file):
                return None
            return super().from_function(py_func, py_file)

    class Impl(caching.CompileResultCacheImpl):
        _locator_classes = [FgoptCacheLocator, *caching.CompileResultCacheImpl._locator_classes]

    class RootCache(caching.FunctionCache):
        _impl_class = Impl

        def load_overload(self, sig: Any, target_context: Any) -> Any:
            # numba refreshes its whole target context before every load, importing every
            # lowering registry (~0.7 s per process). Machine code from the cache needs only
            # the runtime it links against; a compile refreshes the context itself.
            from numba.core.runtime import rtsys

            rtsys.initialize(target_context)
            with self._guard_against_spurious_io_errors():
                return self._load_overload(sig, target_context)

    _CACHE_CLASS.append(RootCache)
    return RootCache


def cache_in_root(dispatcher: Any) -> Any:
    """Give ``dispatcher`` (a numba dispatcher of fgopt's code or of a generated kernel, not
    compiled yet) its cache under ``<root>/numba``; returns it."""
    dispatcher._cache = _root_cache_class()(dispatcher.py_func)
    return dispatcher


def cache_module_in_root(module: Any) -> None:
    """:func:`cache_in_root` for every caching dispatcher defined in ``module`` (a generated
    kernel module, right after it executed)."""
    from numba.core.caching import NullCache
    from numba.core.dispatcher import Dispatcher

    for value in list(vars(module).values()):
        if isinstance(value, Dispatcher) and not isinstance(value._cache, NullCache):
            cache_in_root(value)
