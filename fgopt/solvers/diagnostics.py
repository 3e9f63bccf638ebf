"""What a result must say besides its numbers: initial keys no factor uses, and factors that end
on a clamped domain.

Symbolic ``sqrt``/``log``/``acos``/``asin`` clamp their argument (:mod:`fgopt.symbolic.functions`)
so generated code never yields NaN; a value on the clamp is constant and its gradient zero, so a
start outside the domain "converges" at once. Generated kernels of such factors carry
``clamp_arguments``; after a solve, :func:`clamp_hits` evaluates it once per batch at the final
values (the solver's loop never does) and reports each factor whose argument lies outside
``[low, high]``, with the clamped call's file:line. Factors without clamped calls cost nothing.
"""

from __future__ import annotations

import os
import sys
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import FgoptWarning
from ..key import Key, key_str

#: At most this many hits are listed (all are counted).
MAX_LISTED = 100


@dataclass(frozen=True)
class ClampHit:
    """A factor whose clamped function's argument lies outside its domain at the final values."""

    factor: str
    function: str
    where: str
    """file:line of the clamped call in the factor's code."""
    code: str
    value: float
    low: float
    high: float

    def __str__(self) -> str:
        side = (f"below {self.low:.3g}" if self.value < self.low
                else f"above {self.high:.3g}")
        code = f" (`{self.code}`)" if self.code else ""
        return (f"{self.function} at {self.where}{code} in {self.factor}: argument "
                f"{self.value:.6g} {side}, clamped")


def _hits(kernel: Any, vals: np.ndarray, name_of: Any, out: list, count: list) -> None:
    for j, c in enumerate(kernel.clamps):
        v = vals[:, j]
        low = -np.inf if c["low"] is None else c["low"]   # None: unbounded (META is a literal)
        high = np.inf if c["high"] is None else c["high"]
        rows = np.nonzero((v < low) | (v > high) | ~np.isfinite(v))[0]
        count[0] += int(rows.shape[0])
        for row in rows[:max(0, MAX_LISTED - len(out))].tolist():
            out.append(ClampHit(name_of(row), c["function"], c["where"], c["code"],
                                float(v[row]), low, high))


def clamp_hits(problem: Any, state: Any) -> tuple[list[ClampHit], int]:
    """``(hits listed, total)`` of the compiled ``problem``'s kernel factors at ``state``."""
    out: list[ClampHit] = []
    count = [0]
    for b in problem.batches:
        k = b.kernel
        if k.clamp_arguments is None or len(k.clamps) == 0:
            continue
        vals = k.clamp_arguments(b.gather(state), b.source.constants)
        src = b.source

        def name_of(row: int, k=k, src=src) -> str:
            keys = ", ".join(key_str(Key(int(q))) for q in src.keys[row])
            return f"{k.name}({keys}) (factor {src._where(row)})"

        _hits(k, vals, name_of, out, count)
    return out, count[0]


def _warn(message: str) -> None:
    """A FgoptWarning attributed to the first caller outside the fgopt package."""
    pkg = os.path.dirname(os.path.dirname(os.path.abspath(__file__))) + os.sep
    level, f = 3, sys._getframe(2)  # stacklevel k+1 is frame _getframe(k)
    while f is not None and os.path.abspath(f.f_code.co_filename).startswith(pkg):
        level, f = level + 1, f.f_back
    warnings.warn(message, FgoptWarning, stacklevel=level)


def warn_unused(keys: list) -> None:
    """Warn that initial values hold keys no factor uses."""
    if len(keys) > 0:
        shown = ", ".join(key_str(k) for k in keys[:8]) + (", ..." if len(keys) > 8 else "")
        _warn(f"{len(keys)} key(s) in the initial values are used by no factor ({shown}): they "
              "are not optimized and are returned unchanged (result.unused_keys)")


def warn_clamps(hits: list[ClampHit], total: int) -> None:
    """Warn that factors end on a clamped domain (their value there ignores the variables)."""
    if total > 0:
        _warn(f"{total} factor(s) end with a clamped function argument outside its domain "
              f"(value and gradient there ignore the variables), e.g. {hits[0]}; see "
              "result.clamps")
