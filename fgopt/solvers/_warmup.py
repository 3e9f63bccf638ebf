"""Is numba's cache warm for a problem's kernels?

A solve on the NumPy backend (:meth:`fgopt.problem.Problem.choose_backend`) needs no numba, but
its iterations are slower (sphere2500: ~0.2 s vs ~0.07 s). A long solve therefore switches to
the numba backend mid-run (:meth:`fgopt.solvers._run.Run.maybe_switch`) - but only when numba's
cache already holds the kernels this problem needs: loading them costs ~0.7 s, compiling them
20-60 s, which the NumPy path never pays.

"Warm" is a marker file ``<cache root>/numba/warm-<key>``, written after a solve of the problem's
kind has run on the numba backend (fgopt starts no process to do it). The key hashes what
numba's cache entries depend on: the kernel names and manifold kinds of the problem, the Python
version, numba's installed files, and the size and mtime of every fgopt source file (numba
invalidates an entry when its source changes; so does the key). ``fgopt cache clear`` removes the markers with
numba's cache. A stale marker costs time (numba compiles in the foreground), never a wrong
result.
"""

from __future__ import annotations

import hashlib
import os
import sys
from pathlib import Path
from typing import Any

_SOURCES: list[str] = []


def _source_stamp() -> str:
    """Size and mtime of fgopt's sources and numba's ``__init__`` (computed once per process)."""
    if not _SOURCES:
        import importlib.util

        pkg = Path(__file__).resolve().parents[1]
        h = hashlib.sha256(sys.version.encode())
        for p in sorted(pkg.rglob("*.py")):
            st = p.stat()
            h.update(f"{p}:{st.st_size}:{st.st_mtime_ns}".encode())
        spec = importlib.util.find_spec("numba")
        if spec is not None and spec.origin:
            st = os.stat(spec.origin)
            h.update(f"{spec.origin}:{st.st_size}:{st.st_mtime_ns}".encode())
        _SOURCES.append(h.hexdigest())
    return _SOURCES[0]


def marker(problem: Any) -> Path:
    """The marker file of ``problem``'s kernels (see the module docstring)."""
    from .. import _cache_root

    h = hashlib.sha256(_source_stamp().encode())
    from ..problem import NUMPY_MAX_BATCH

    for b in problem.batches:  # which kernels run on numba (small batches use NumPy twins)
        k = b.kernel
        h.update(f"{k.name}:{hashlib.sha256(k.source.encode()).hexdigest()}:"
                 f"{len(b.source) > NUMPY_MAX_BATCH}".encode())
    for kind in problem.kinds:
        h.update(kind.name.encode())
    pattern = problem.pattern
    h.update(str(pattern is not None and pattern.size > 300).encode())  # dense / sparse solver
    return _cache_root.subdir(_cache_root.NUMBA) / f"warm-{h.hexdigest()[:32]}"


def is_warm(problem: Any) -> bool:
    """Whether numba's cache holds ``problem``'s kernels (a marker exists)."""
    try:
        return marker(problem).exists()
    except Exception:  # noqa: BLE001 - an unusable cache root: treat as cold
        return False


#: Problem shapes this process has already marked warm (see :func:`mark_warm`) -> the kernels
#: and kinds of the shape, held so that their ids are not reused while the entry exists.
_MARKED: dict = {}


def mark_warm(problem: Any) -> None:
    """Record that ``problem``'s kernels are in numba's cache (after a numba-backend solve).

    Once per process, cache location and problem shape: hashing the kernels' sources and
    touching the file cost ~0.2 ms, a tenth of a small problem's whole solve when repeated on
    every call. (A marker removed by ``fgopt cache clear`` meanwhile is written again by the next
    process; a missing marker only costs time.)"""
    from ..problem import NUMPY_MAX_BATCH

    pattern = problem.pattern
    where = tuple(os.environ.get(v) for v in ("FGOPT_CACHE_DIR", "XDG_CACHE_HOME", "HOME"))
    shape = (where, tuple((id(b.kernel), len(b.source) > NUMPY_MAX_BATCH) for b in problem.batches),
             tuple(id(kind) for kind in problem.kinds), pattern is not None and pattern.size > 300)
    if shape in _MARKED:
        return
    try:
        marker(problem).touch()
    except Exception:  # noqa: BLE001, S110 - best effort
        return
    _MARKED[shape] = ([b.kernel for b in problem.batches], list(problem.kinds))
