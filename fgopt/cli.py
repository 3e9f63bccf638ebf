"""The ``fgopt`` command line: ``fgopt solve FILE``, ``fgopt info FILE`` and ``fgopt cache``.

``solve`` reads a g2o / TORO / BAL / Bundler file, fixes the gauge of pose graphs with a tight
prior on the lowest pose (GTSAM-style; BA relies on LM damping, as Ceres' BAL example), optimizes
while printing one row per iteration, then a summary. Costs in the summary are measured on the
file's own edges (``0.5 * sum`` of squared whitened residuals, no prior, no robust loss), the
yardstick GTSAM's ``graph.error`` uses. Exit status: 0 converged, 1 not converged (reason on
stderr), 2 bad input or usage (the error message on stderr).

``info`` prints variable and factor counts by type, the initial cost, connected components and
whether the gauge is fixed.

``cache info`` prints the private cache root (:mod:`fgopt._cache_root`), each generated kernel
entry with its size and whether it verifies against its signature, and the size of numba's cache;
``cache clear`` removes the entries and numba's cache (they are regenerated on next use).
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import time
from typing import Any

import numpy as np

from .errors import FgoptError

_LOSSES = {"huber": (1, 1.345), "cauchy": (2, 1.0), "tukey": (3, 4.685),
           "geman_mcclure": (4, 1.0), "gm": (4, 1.0), "barron": (5, 1.0)}


def _robust(spec: str) -> tuple[str, int, float, float]:
    """``name[:k]`` or ``barron[:k[:alpha]]`` -> (name, code, k, alpha)."""
    name, _, value = spec.partition(":")
    value, _, shape = value.partition(":")
    name = name.strip().lower()
    if name not in _LOSSES:
        raise argparse.ArgumentTypeError(
            f"unknown robust loss {name!r}: use huber, cauchy, tukey, geman_mcclure or barron, "
            "optionally with a threshold, e.g. huber:1.345 (barron:K:ALPHA)")
    code, default = _LOSSES[name]
    if shape and name != "barron":
        raise argparse.ArgumentTypeError(f"only barron takes a second parameter (alpha): {spec!r}")
    try:
        k = float(value) if value else default
        alpha = float(shape) if shape else 0.0
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"robust loss parameters in {spec!r} are not numbers") from None
    if not (np.isfinite(k) and k > 0):
        raise argparse.ArgumentTypeError(f"robust loss threshold must be positive, got {value}")
    if not np.isfinite(alpha):
        raise argparse.ArgumentTypeError(f"barron alpha must be finite, got {shape}")
    return name, code, k, alpha


def _positive_int(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {n}")
    return n


def build_parser() -> argparse.ArgumentParser:
    from ._cache_build import FAMILIES

    p = argparse.ArgumentParser(prog="fgopt", description="Factor-graph optimization on "
                                "manifolds: solve or inspect g2o / TORO / BAL files.")
    sub = p.add_subparsers(dest="command", required=True,
                           metavar="{solve,solve-many,info,cache}")

    def file_options(sp: argparse.ArgumentParser) -> None:
        sp.add_argument("file", help="g2o / TORO (.g2o, .graph, .txt) or BAL file, optionally "
                        ".gz / .bz2")
        sp.add_argument("--repair-information", choices=["clip"], default=None,
                        help="clip the eigenvalues of information matrices that are not "
                        "positive definite (default: refuse the file)")
        sp.add_argument("--skip-unknown", action="store_true",
                        help="skip lines with unknown tags (counted in a warning)")

    s = sub.add_parser("solve", help="optimize a file and print the iterations")
    file_options(s)
    s.add_argument("--method", choices=["lm", "gn", "dogleg", "gnc"], default="lm",
                   help="gnc: graduated non-convexity (truncated least squares) against "
                   "outlier edges")
    s.add_argument("--solver", choices=["auto", "cholmod", "ldlt", "pcg", "dense"],
                   default="auto", help="linear solver (default: chosen from the problem)")
    s.add_argument("--max-iterations", type=_positive_int, default=100)
    s.add_argument("--backend", choices=["auto", "numba", "numpy"], default="auto",
                   help="kernels: numba, or NumPy with a no-numba linear solver (CHOLMOD / "
                   "qdldl); auto: NumPy for problems of tangent dimension <= 30000 in a new "
                   "process (no numba import, compilation or cache load)")
    s.add_argument("--init", choices=["auto", "given", "chordal"], default="auto",
                   help="start: auto (the file's guess; also the chordal relaxation when the "
                   "result fails a chi-square test against the noise models, keeping the "
                   "lower cost), given (the file's guess only), chordal")
    s.add_argument("--robust", type=_robust, default=None, metavar="LOSS[:K]",
                   help="robust loss on the file's edges: huber, cauchy, tukey, geman_mcclure, "
                   "barron (e.g. huber:1.345; barron:K:ALPHA, e.g. barron:1:0.5)")
    s.add_argument("--out", default=None, help="write the optimized problem (same format as "
                   "the input; .gz / .bz2 compress)")
    s.add_argument("--plot", default=None, help="save a before/after and cost plot (PNG, PDF, "
                   "SVG)")
    s.add_argument("--quiet", action="store_true", help="no iteration table or log messages; "
                   "only the one-line summary")
    s.set_defaults(run=cmd_solve)

    m = sub.add_parser("solve-many", help="solve many files in parallel on Dask; write each "
                       "result and a summary table")
    m.add_argument("files", nargs="+", help="g2o / TORO / BAL files (optionally .gz / .bz2)")
    where = m.add_mutually_exclusive_group()
    where.add_argument("--workers", type=_positive_int, default=None,
                       help="worker processes of the local cluster (default: one per core)")
    where.add_argument("--scheduler", default=None, metavar="ADDRESS",
                       help="a running Dask scheduler (e.g. tcp://host:8786) instead of a local "
                       "cluster")
    m.add_argument("--out-dir", required=True, help="folder for the optimized files and "
                   "summary.md")
    m.add_argument("--method", choices=["lm", "gn", "dogleg", "gnc"], default="lm")
    m.add_argument("--max-iterations", type=_positive_int, default=100)
    m.add_argument("--quiet", action="store_true", help="no progress bar")
    m.set_defaults(run=cmd_solve_many)

    i = sub.add_parser("info", help="counts, initial cost, connectivity and gauge of a file")
    file_options(i)
    i.set_defaults(run=cmd_info)

    c = sub.add_parser("cache", help="the kernel cache: where it is, what it holds; build or "
                       "clear it")
    c.add_argument("action", choices=["info", "build", "clear"],
                   help="info: root, entries, sizes, verification; build: compile the built-in "
                   "families' kernels now (once per machine) instead of on their first use; "
                   "clear: remove every entry and numba's cache")
    c.add_argument("--jobs", type=_positive_int, default=None,
                   help="build: processes at a time (default: one per core)")
    c.add_argument("--only", default=None, metavar="FAMILY[,FAMILY...]",
                   help=f"build: these families only (default: all of {', '.join(FAMILIES)})")
    c.set_defaults(run=cmd_cache)
    return p


def _size(n: float) -> str:
    for unit in ("B", "KB", "MB"):
        if n < 1024:
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} GB"


def cmd_cache(args: argparse.Namespace) -> int:
    import os
    import stat

    from . import _cache_root
    from .symbolic import cache

    if args.action == "build":
        from ._cache_build import build

        build(only=args.only.split(",") if args.only else None, jobs=args.jobs)
        return 0
    root = _cache_root.root()
    if args.action == "clear":
        removed = cache.clear()
        print(f"removed {removed['entries']} kernel entries and {removed['numba_files']} numba "
              f"cache files ({_size(removed['bytes'])}) from {root}")
        return 0
    st = os.stat(root)
    print(f"root:     {root} (uid {st.st_uid}, mode {stat.S_IMODE(st.st_mode):04o}: private)")
    key = root / _cache_root.KEY_FILE
    print(f"key:      {key}" + (" (0600)" if key.exists() else " (not made yet)"))
    entries = cache.entries()
    failed = [e for e in entries if e["problem"] is not None]
    total = sum(e["bytes"] for e in entries)
    print(f"kernels:  {root / _cache_root.KERNELS}: {len(entries)} entries, {_size(total)}; "
          f"{len(entries) - len(failed)} verified, {len(failed)} failed")
    for e in entries:
        state = "ok" if e["problem"] is None else f"FAILED: {e['problem']}"
        print(f"  {e['name']:<60} {_size(e['bytes']):>9}  {state}")
    numba_dir = root / _cache_root.NUMBA
    files = [p for p in numba_dir.rglob("*") if p.is_file()] if numba_dir.is_dir() else []
    print(f"numba:    {numba_dir}: {len(files)} files, "
          f"{_size(sum(p.stat().st_size for p in files))}")
    if failed:
        print("entries that fail verification are discarded and regenerated on next use")
    return 0


def _load(args: argparse.Namespace) -> tuple[str, Any, Any, float]:
    from .io import detect_format, read

    t0 = time.perf_counter()
    fmt = detect_format(args.file)
    if fmt in ("bal", "bundler"):
        graph, values = read(args.file, format=fmt)
    else:
        # --out writes the file's unchanged edges back as the file had them
        graph, values = read(args.file, format="g2o", skip_unknown=args.skip_unknown,
                             repair_information=args.repair_information,
                             keep_edge_text=getattr(args, "out", None) is not None)
    return fmt, graph, values, time.perf_counter() - t0


def _counts(counter) -> str:
    return ", ".join(f"{n} {name}" for name, n in counter.most_common())


def _with_loss(graph: Any, robust: tuple[str, int, float] | None):
    """A new graph with the same batches (and ``robust`` on every non-prior batch)."""
    from .graph import FactorGraph

    out = FactorGraph(graph.factors)
    for b in graph.batches:
        code, k, shape = b.loss_code, b.loss_param, b.loss_shape
        if robust is not None and not b.kernel.name.startswith("prior"):
            code, k, shape = robust[1], robust[2], robust[3]
        out.add_batch(b.kernel, b.keys, b.constants, b.sqrt_information, code, k, b.origin,
                      loss_shape=shape)
    return out


def _check_writable(option: str, path: str | None) -> None:
    if path is None:
        return
    folder = os.path.dirname(os.path.abspath(path))
    if os.path.isdir(path) or not os.path.isdir(folder) or not os.access(folder, os.W_OK):
        why = ("is a directory" if os.path.isdir(path) else
               "its folder does not exist" if not os.path.isdir(folder) else
               "its folder is not writable")
        raise FgoptError(f"{option} {path}: cannot write there ({why})")


def cmd_solve(args: argparse.Namespace) -> int:
    from . import optimize
    from .io import add_gauge_prior
    from .key import key_str

    say = (lambda *a: None) if args.quiet else (lambda *a: print(*a, flush=True))
    for option, path in (("--out", args.out), ("--plot", args.plot)):
        _check_writable(option, path)  # before the solve, not after it
    fmt, graph, initial, t_read = _load(args)
    cost0 = graph.error(initial)
    say(f"{args.file}: {fmt}, {len(initial)} variables ({_counts(initial.type_counts())}), "
        f"{len(graph)} factors ({_counts(graph.type_counts())}); read in {t_read:.3f} s")
    problem = _with_loss(graph, args.robust)
    if fmt == "g2o":
        fixed = add_gauge_prior(problem, initial)
        if fixed is not None:
            say(f"gauge: tight prior on {key_str(fixed)} (the file's edges stay the cost "
                "yardstick)")
    if args.robust is not None:
        shape = f", alpha = {args.robust[3]:g}" if args.robust[0] == "barron" else ""
        say(f"robust loss: {args.robust[0]} (k = {args.robust[2]:g}{shape}) on the file's edges")
    say(f"initial cost {cost0:.6e}")
    from .solvers.result import IterationRecord

    say(IterationRecord.HEADER)
    extra = {} if args.backend == "auto" else {"backend": args.backend}
    result = optimize(problem, initial, method=args.method, linear_solver=args.solver,
                      max_iterations=args.max_iterations, initialization=args.init,
                      callback=lambda rec: say(rec.row()), **extra)
    cost1 = graph.error(result.values)
    reason = result.info.get("initialization_reason")
    say(f"initialization: {result.info.get('initialization', 'given')}"
        + (f" ({reason})" if reason else ""))
    t = result.timing
    status = result.status.value
    print(f"{status} after {result.iterations} iterations ({result.message}): cost "
          f"{cost0:.6e} -> {cost1:.6e} on the file's edges, {t.get('total', 0.0):.3f} s "
          f"({result.method}/{result.linear_solver}, {result.info.get('backend', 'numba')} "
          "kernels)", flush=True)
    if not args.quiet and t:
        say("time: " + ", ".join(f"{k} {v:.3f} s" for k, v in t.items()))
    if args.out is not None and fmt == "bundler":
        print("fgopt: --out: writing Bundler files is not supported", file=sys.stderr)
    elif args.out is not None:
        from . import io  # the writer's module only: write_bal loads the cameras package

        (io.write_bal if fmt == "bal" else io.write_g2o)(args.out, graph, result.values)
        say(f"wrote {args.out}")
    if args.plot is not None:
        from .plot import save_result_plot

        save_result_plot(args.plot, graph, initial, result, title=_short_name(args.file))
        say(f"wrote {args.plot}")
    if not result.success:
        print(f"fgopt: not converged: {result.status.value} ({result.message})", file=sys.stderr)
        return 1
    return 0


def cmd_solve_many(args: argparse.Namespace) -> int:
    from pathlib import Path

    from .distributed import solve_files, summary_table

    client = None
    if args.scheduler is not None:
        try:
            from dask.distributed import Client
        except ImportError:
            raise FgoptError("--scheduler needs dask.distributed: pip install "
                             "'fgopt[distributed]'") from None
        client = Client(args.scheduler)
    try:
        rows = solve_files(args.files, args.out_dir, method=args.method, client=client,
                           workers=args.workers, progress=not args.quiet,
                           max_iterations=args.max_iterations)
    finally:
        if client is not None:
            client.close()
    table = summary_table(rows)
    (Path(args.out_dir) / "summary.md").write_text(table)
    print(table, end="", flush=True)
    failed = sum(1 for r in rows if "error" in r)
    if failed:
        print(f"fgopt: {failed} of {len(rows)} files failed (see summary.md)", file=sys.stderr)
    return 1 if failed else 0


def _short_name(path: str) -> str:
    import os

    return os.path.basename(path)


def _components(graph: Any, values: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sorted variable keys, the component label of each, and whether any factor touches it."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    keys = np.array(sorted(int(k) for k in values.keys()), dtype=np.int64)
    rows, cols = [], []
    for kk in [b.keys for b in graph.batches] + [
            np.array([[int(k) for k in f.keys]]) for f in graph.factors]:
        pos = np.searchsorted(keys, kk)
        for c in range(1, kk.shape[1]):
            rows.append(pos[:, 0])
            cols.append(pos[:, c])
    n = keys.shape[0]
    r = np.concatenate(rows) if rows else np.zeros(0, np.int64)
    c = np.concatenate(cols) if cols else np.zeros(0, np.int64)
    A = sp.coo_matrix((np.ones(r.shape[0]), (r, c)), shape=(n, n))
    _, labels = connected_components(A, directed=False)
    used = np.zeros(n, dtype=bool)
    for kk in [b.keys for b in graph.batches] + [
            np.array([[int(k) for k in f.keys]]) for f in graph.factors]:
        used[np.searchsorted(keys, kk.reshape(-1))] = True
    return keys, labels, used


def cmd_info(args: argparse.Namespace) -> int:
    from .key import key_str

    fmt, graph, values, t_read = _load(args)
    missing = [k for k in graph.keys() if k not in values]
    if missing:
        raise FgoptError(f"{args.file}: factors use {len(missing)} keys without a value "
                         f"(first {key_str(missing[0])})")
    print(f"file:        {args.file} ({fmt}, read in {t_read:.3f} s)")
    print(f"variables:   {len(values)} ({_counts(values.type_counts())})")
    print(f"factors:     {len(graph)} ({_counts(graph.type_counts())})")
    print(f"initial cost {graph.error(values):.6e} (0.5 * sum of squared whitened residuals)")
    keys, labels, used = _components(graph, values)
    sizes = np.bincount(labels[used]) if used.any() else np.zeros(0, np.int64)
    sizes = np.sort(sizes[sizes > 0])[::-1]
    if sizes.shape[0] <= 1:
        print("components:  1 (connected)")
    else:
        big = ", ".join(map(str, sizes[:5].tolist()))
        print(f"components:  {sizes.shape[0]} disconnected parts (sizes {big}"
              f"{', ...' if sizes.shape[0] > 5 else ''}); each has its own gauge")
    isolated = keys[~used].tolist()
    if isolated:
        shown = ", ".join(key_str(k) for k in isolated[:5])
        print(f"isolated:    {len(isolated)} variables no factor touches ({shown}"
              f"{', ...' if len(isolated) > 5 else ''})")
    priors = sum(len(b) for b in graph.batches if b.kernel.name.startswith("prior"))
    priors += sum(1 for f in graph.factors if f.kernel is not None
                  and f.kernel.name.startswith("prior"))
    if fmt == "bal":
        print("gauge:       free (7-DoF similarity, no prior); LM damping handles it")
    elif priors:
        print(f"gauge:       fixed by {priors} prior(s) / FIX line(s)")
    else:
        dof = 6 if any(v == "SE3" for v in values.type_counts()) else 3
        print(f"gauge:       free ({dof}-DoF per component, no prior or FIX); `fgopt solve` adds "
              "a tight prior on the lowest pose")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    quiet = getattr(args, "quiet", False)
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("%(levelname)s: %(message)s"))
    logger = logging.getLogger("fgopt")
    logger.addHandler(handler)
    logger.setLevel(logging.ERROR if quiet else logging.INFO)
    try:
        return int(args.run(args))
    except FgoptError as exc:
        msg = str(exc).replace("repair_information='clip'", "--repair-information clip")
        msg = msg.replace("skip_unknown=True", "--skip-unknown")
        print(f"fgopt: error: {msg}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("fgopt: interrupted", file=sys.stderr)
        return 130
    finally:
        logger.removeHandler(handler)


if __name__ == "__main__":
    sys.exit(main())
