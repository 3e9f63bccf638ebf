"""One line when first-use work on this machine takes a while (deriving or compiling kernels).

A kernel fgopt has not seen on this machine is derived (SymPy) and compiled (numba) once, then
loaded from fgopt's cache (:mod:`fgopt._cache_root`). When that work runs longer than
:data:`NOTICE_AFTER_SECONDS`, the ``fgopt`` logger says so, at most once per process::

    fgopt: compiling machine code for pose3_between (first use on this machine, cached in
    /home/me/.cache/fgopt; later runs load it; `fgopt cache build` compiles the built-in
    families at once)

Logging, not ``print``: with no logging configured Python prints a WARNING on stderr (its
last-resort handler), so a script's user sees the line, and an application silences or
routes it like any other library message (``logging.getLogger("fgopt")``). Nothing is logged
when everything comes from the cache. The line is written by a timer (a thread of this
process) while the work runs, not after it.
"""

from __future__ import annotations

import logging
import threading
from contextlib import contextmanager
from typing import Any

#: Work that ends sooner says nothing.
NOTICE_AFTER_SECONDS = 1.0

_log = logging.getLogger("fgopt")
_state = {"said": False, "depth": 0, "listening": False}
_lock = threading.Lock()
_active = threading.local()


def _say(what: str) -> None:
    with _lock:
        if _state["said"]:
            return
        _state["said"] = True
    try:
        from ._cache_root import root

        where = f"cached in {root()}"
    except Exception:  # noqa: BLE001 - the notice never fails the work it describes
        where = "cached"
    _log.warning("fgopt: %s (first use on this machine, %s; later runs load it; `fgopt cache "
                 "build` compiles the built-in families at once)", what, where)


@contextmanager
def preparing(what: str):
    """Inside, first-use work named ``what`` ("deriving the kernels of range_bearing"); the
    notice is logged if the outermost such block runs past :data:`NOTICE_AFTER_SECONDS`."""
    depth = getattr(_active, "depth", 0)
    _active.depth = depth + 1
    timer = None
    if depth == 0 and not _state["said"]:
        timer = threading.Timer(NOTICE_AFTER_SECONDS, _say, (what,))
        timer.daemon = True
        timer.start()
    try:
        yield
    finally:
        _active.depth = depth
        if timer is not None:
            timer.cancel()


def _name(data: Any) -> str | None:
    """The fgopt function a numba compile event is about, or ``None`` (a user's function)."""
    func = getattr(data.get("dispatcher"), "py_func", None)
    module = getattr(func, "__module__", "") or ""
    if module.startswith("fgk_"):
        return module[4:].rsplit("_", 1)[0]  # generated kernel: its factor's name
    if module == "fgopt" or module.startswith("fgopt."):
        return f"{module}.{func.__qualname__}"
    return None


def watch_numba() -> None:
    """Time numba's compiles of fgopt's functions (numba's event API; a user's own numba
    functions are not looked at). Called once numba is imported."""
    with _lock:
        if _state["listening"]:
            return
        _state["listening"] = True
    from numba.core import event

    class _Listener(event.Listener):
        def on_start(self, ev: Any) -> None:
            name = _name(ev.data)
            stack = getattr(_active, "compiles", None)
            if stack is None:
                stack = _active.compiles = []
            cm = preparing(f"compiling machine code for {name}") if name else None
            if cm is not None:
                cm.__enter__()
            stack.append(cm)

        def on_end(self, ev: Any) -> None:
            stack = getattr(_active, "compiles", None)
            cm = stack.pop() if stack else None
            if cm is not None:
                cm.__exit__(None, None, None)

    event.register("numba:compile", _Listener())
