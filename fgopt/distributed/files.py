"""Many files, one task each: read, solve and write on the worker (``fgopt solve-many``)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from .many import _as_fgopt_error, run_tasks

#: Columns of the summary table, in order.
COLUMNS = ("file", "status", "initial cost", "final cost", "iterations", "seconds", "output")


def output_name(path: str) -> str:
    """``dir/name.g2o.bz2`` -> ``name.g2o`` (outputs are written uncompressed)."""
    name = Path(path).name
    for ext in (".gz", ".bz2"):
        if name.endswith(ext):
            name = name[: -len(ext)]
    return name


def solve_file(path: str, index: int, out_dir: str | None, method: str, options: dict) -> dict:
    """Worker task: one file's summary row; a failure is a row with its error (never raises)."""
    from ..io import add_gauge_prior, detect_format, read, write_bal, write_g2o
    from ..solvers import optimize

    row: dict = {"file": path, "status": "error", "initial cost": None, "final cost": None,
                 "iterations": None, "seconds": None, "output": None}
    t0 = time.perf_counter()
    try:
        fmt = detect_format(path)
        graph, initial = read(path, format=fmt)
        cost0 = graph.error(initial)
        problem = graph
        if fmt == "g2o":  # as `fgopt solve`: a gauge prior; the file's edges stay the yardstick
            problem = graph.copy()
            add_gauge_prior(problem, initial)
        result = optimize(problem, initial, method=method, **options)
        row.update({"status": result.status.value, "initial cost": cost0,
                    "final cost": graph.error(result.values), "iterations": result.iterations})
        if out_dir is not None:
            out = str(Path(out_dir) / output_name(path))
            (write_bal if fmt == "bal" else write_g2o)(out, graph, result.values)
            row["output"] = out
    except Exception as exc:
        row["error"] = str(_as_fgopt_error(exc, path))
    row["seconds"] = time.perf_counter() - t0
    return row


def solve_files(paths: list[str], out_dir: str | None = None, *, method: str = "lm",
                client: Any = None, workers: int | None = None, progress: bool = True,
                **options: Any) -> list[dict]:
    """Solve each file on Dask (see :func:`~fgopt.distributed.solve_many`); one summary row per
    file, in order. A malformed file's row carries its ``file:line`` error; the rest are solved.

    Example:

    >>> summary = fgopt.distributed.solve_files(['a.g2o', 'b.g2o'], out_dir='solved', workers=2)  # doctest: +SKIP
    """
    if out_dir is not None:
        Path(out_dir).mkdir(parents=True, exist_ok=True)
    return run_tasks(solve_file, list(paths), client=client, workers=workers, progress=progress,
                     label="solve-many", args=(out_dir, method, options))


def summary_table(rows: list[dict]) -> str:
    """The rows as a markdown table (errors listed under it).

    >>> from fgopt.distributed import summary_table
    >>> print(summary_table([
    ...     {"file": "a.g2o", "status": "converged", "initial cost": 12.5, "final cost": 0.25,
    ...      "iterations": 4, "seconds": 0.0123, "output": "a_opt.g2o"},
    ...     {"file": "b.g2o", "error": "b.g2o:3: bad line"}]))
    | file | status | initial cost | final cost | iterations | seconds | output |
    |---|---|---|---|---|---|---|
    | a.g2o | converged | 12.5 | 0.25 | 4 | 0.012 | a_opt.g2o |
    | b.g2o | — | — | — | — | — | — |
    <BLANKLINE>
    Errors:
    - b.g2o: b.g2o:3: bad line
    <BLANKLINE>
    """
    def cell(row: dict, col: str) -> str:
        v = row.get(col)
        if v is None:
            return "—"
        if col in ("initial cost", "final cost"):
            return f"{v:.6g}"
        if col == "seconds":
            return f"{v:.3f}"
        return str(v)

    lines = ["| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    lines += ["| " + " | ".join(cell(r, c) for c in COLUMNS) + " |" for r in rows]
    errors = [f"- {r['file']}: {r['error']}" for r in rows if "error" in r]
    if errors:
        lines += ["", "Errors:"] + errors
    return "\n".join(lines) + "\n"
