"""One module per library. Each defines ``RUNNER``, an object with:

* ``name``, ``version()``, ``pinning`` (how it is held to one thread), ``note`` (table footnote)
* ``supports(problem) -> str | None``: ``None`` if it can run the problem, else why not
* ``load(spec) -> state``: read the file / build the problem the library's own way (timed as
  "load"); ``spec`` is a :class:`benchmarks.problems.ProblemSpec`
* ``reset(state)``: undo whatever a solve changed in place (untimed, before every solve)
* ``solve(state, mode) -> SolveOutput`` (timed): ``mode`` is ``"5it"`` (exactly five LM
  iterations, every stopping test off) or ``"converge"`` (the library's default stopping rules)
* ``estimate(state, out) -> dict``: the final estimate in :mod:`benchmarks.problems` layout, for
  :mod:`benchmarks.yardstick` (untimed)

A runner with ``self_timed = True`` (the C++ Ceres program) instead implements
``run_self_timed(spec, mode, repeats) -> dict`` with the load/solve figures and ``estimate``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

MODES = ("5it", "converge")
PEERS = ("fgopt", "gtsam", "ceres", "ceres_cpp", "symforce", "scipy")


@dataclass
class SolveOutput:
    raw: Any  # whatever the library returned (kept for estimate())
    iterations: int | None
    lib_initial_cost: float | None = None  # the library's own cost, its own definition
    lib_final_cost: float | None = None
    status: str = ""
    extra: dict = field(default_factory=dict)


def get_runner(name: str):
    import importlib

    mod = importlib.import_module(f"benchmarks.peers.{name}_runner")
    return mod.RUNNER
