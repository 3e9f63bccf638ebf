"""Refuse to start worker processes from a script's unguarded top-level code.

Dask's local workers are started with ``multiprocessing``'s *spawn* method, which re-imports the
caller's ``__main__`` module in every worker. A script that calls :func:`solve_many` at top level
(no ``if __name__ == "__main__":``) then runs its whole body again in each worker, which starts
workers of its own: the user sees the body run three times, multiprocessing's
``freeze_support`` message and "Nanny failed to start". fgopt checks before any process starts
and raises one :class:`FgoptError` that says what to add.
"""

from __future__ import annotations

import ast
import sys
from typing import Any

from ..errors import FgoptError


def _is_main_test(node: ast.expr) -> bool:
    """``__name__ == "__main__"`` (either side)."""
    if not (isinstance(node, ast.Compare) and len(node.ops) == 1
            and isinstance(node.ops[0], ast.Eq)):
        return False
    sides = [node.left, node.comparators[0]]
    name = any(isinstance(s, ast.Name) and s.id == "__name__" for s in sides)
    main = any(isinstance(s, ast.Constant) and s.value == "__main__" for s in sides)
    return name and main


def _guarded(source: str, line: int) -> bool:
    """Whether ``line`` of the module ``source`` lies in the body of an ``if __name__ ==
    "__main__":`` block (at any depth of top-level statements)."""
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.If) and _is_main_test(node.test) and node.body:
            if node.body[0].lineno <= line <= (node.body[-1].end_lineno or line):
                return True
    return False


def _main_module_frame() -> Any:
    """The frame running ``__main__``'s top-level code, if that is on the stack."""
    main = sys.modules.get("__main__")
    if main is None:
        return None
    frame = sys._getframe(1)
    while frame is not None:
        if frame.f_globals is main.__dict__ and frame.f_code.co_name == "<module>":
            return frame
        frame = frame.f_back
    return None


def check_main_guard(what: str = "solve_many") -> None:
    """Raise :class:`FgoptError` when called (directly or through functions) from a script's
    top-level code outside ``if __name__ == "__main__":``, where spawned workers would re-run it.
    Interactive sessions and notebooks (no ``__main__.__file__``) pass."""
    frame = _main_module_frame()
    path = getattr(sys.modules.get("__main__"), "__file__", None)
    if frame is None or not path or frame.f_code.co_filename != path:
        return
    try:
        with open(path, encoding="utf-8") as fh:
            source = fh.read()
        guarded = _guarded(source, frame.f_lineno)
    except (OSError, SyntaxError, ValueError):
        return  # cannot tell: let multiprocessing decide
    if not guarded:
        raise FgoptError(
            f"{what} at {path}:{frame.f_lineno} runs at the top level of the script: its worker "
            "processes start by re-importing the script, which would run its body again in each "
            "of them. Put the code that calls it under\n"
            "    if __name__ == \"__main__\":")
