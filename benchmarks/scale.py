"""One machine at the edge: fgopt vs the C++ Ceres program on generated problems of Venice size.

    python -m benchmarks.scale [--cameras 1780 --points 1000000 --per-point 5] [--grid 100000]
                               [--workdir /tmp/fgopt-scale] [--out benchmarks/results/scale-<date>.md]

Generates (and keeps in ``--workdir``) a BAL file with ``fgopt.datasets.bal_synthetic`` (local
visibility: each point seen by neighbouring cameras on a circle, so the reduced camera system is
banded) and a 3D grid pose graph with ``fgopt.datasets.grid_3d`` written as g2o. Each library runs
in its own process (peak RSS per process), single-threaded, exactly 5 LM iterations:

- fgopt: ``fgopt.io.read`` time, setup (compiling the problem: ordering, pattern, scatter map;
  the linear solver's analysis) and the 5 iterations, from ``Result.timing``; CPU seconds of
  each; peak RSS;
- Ceres 2.1 (``benchmarks/ceres_cpp/ceres_bench``, SPARSE_SCHUR for BA, SPARSE_NORMAL_CHOLESKY
  for the grid; it reads the file itself, its warm-up solve is discarded): load time, its
  preprocessor and minimizer times of the 5-iteration solve, peak RSS of its process.

The grid (seconds per process) runs ``--grid-runs`` times per library, alternating, and each
library's run with the least CPU time (read + setup + iterations) is kept whole: one process's
read time on this VM swung 1.0-1.55 s. The BA (minutes per process) runs once.

Memory per observation = peak RSS / observations. The C++ program must be built first
(``bash benchmarks/ceres_cpp/build.sh``).
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OMP_THREAD_LIMIT", "OPENBLAS_NUM_THREADS",
           "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_v] = "1"

import argparse  # noqa: E402
import datetime as dt  # noqa: E402
import json  # noqa: E402
import resource  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

HERE = Path(__file__).resolve().parent
CERES = HERE / "ceres_cpp" / "ceres_bench"

FGOPT_WORKER = r"""
import json, resource, sys, time
t0 = time.perf_counter()
import fgopt
import fgopt.solvers._run as run_mod
from fgopt.solvers import LMParams
t_import = time.perf_counter() - t0
path, kind = sys.argv[1], sys.argv[2]


def peak_mb():
    # this process's own high-water mark: getrusage's ru_maxrss keeps the parent's resident size
    # at the fork (a parent that had just generated the 5M-observation file: 1.9 GB "peak"
    # reported for the grid), VmHWM is the exec'd image's alone
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
marks = {}
make = run_mod.make_linear_solver


def make_marked(*a, **k):  # CPU clock at the end of setup (after the solver's analysis)
    s = make(*a, **k)
    analyze = s.analyze

    def analyze_marked(pattern):
        analyze(pattern)
        marks["setup_end_cpu"] = time.process_time()
        marks["rss_setup_mb"] = peak_mb()
    s.analyze = analyze_marked
    return s


run_mod.make_linear_solver = make_marked
t0, c0 = time.perf_counter(), time.process_time()
graph, initial = fgopt.io.read(path)
t_read, c_read = time.perf_counter() - t0, time.process_time() - c0
rss_read = peak_mb()
if kind == "pose3d":
    fgopt.io.add_gauge_prior(graph, initial)
t0, c0 = time.perf_counter(), time.process_time()
r = fgopt.optimize(graph, initial, params=LMParams(
    max_iterations=5, relative_tolerance=0.0, absolute_tolerance=0.0, gradient_tolerance=0.0,
    step_tolerance=0.0))
t_total, c_end = time.perf_counter() - t0, time.process_time()
print(json.dumps({"import_s": t_import, "read_s": t_read, "read_cpu_s": c_read,
                  "optimize_s": t_total, "setup_s": r.timing.get("setup", 0.0),
                  "setup_cpu_s": marks["setup_end_cpu"] - c0,
                  "iterations_cpu_s": c_end - marks["setup_end_cpu"], "iterations": r.iterations,
                  "initial_cost": r.initial_cost, "final_cost": r.final_cost,
                  "linear_solver": r.linear_solver, "rss_after_read_mb": rss_read,
                  "rss_after_setup_mb": marks["rss_setup_mb"],
                  "peak_rss_mb": peak_mb()}))
"""


def _child_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024


def run_fgopt(path: Path, kind: str) -> dict:
    out = subprocess.run([sys.executable, "-c", FGOPT_WORKER, str(path), kind],
                         capture_output=True, text=True, cwd=HERE.parent)
    if out.returncode != 0:
        return {"error": out.stderr[-2000:]}
    return json.loads(out.stdout.strip().splitlines()[-1])


def run_ceres(path: Path, kind: str, workdir: Path) -> dict:
    if not CERES.is_file():
        return {"error": f"{CERES} is not built (bash benchmarks/ceres_cpp/build.sh)"}
    # a wrapper process per run, so RUSAGE_CHILDREN is this program's peak alone
    wrapper = ("import json, resource, subprocess, sys; o = subprocess.run(sys.argv[1:], "
               "capture_output=True, text=True); r = json.loads(o.stdout.strip().splitlines()[-1])"
               " if o.returncode == 0 else {'error': o.stderr[-2000:]}; r['peak_rss_mb'] = "
               "resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024; print(json.dumps(r))")
    out = subprocess.run([sys.executable, "-c", wrapper, str(CERES), kind, str(path), "5it", "1",
                          str(workdir / "ceres_estimate.txt")], capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


#: The CPU seconds a run's figures add up to, per library: the run kept is the least of these.
RUN_CPU = {"fgopt": ("read_cpu_s", "setup_cpu_s", "iterations_cpu_s"),
           "ceres": ("load_cpu_s", "solve_cpu_s")}


def least_cpu(runs: list[dict], library: str) -> dict:
    """The run (whole, not mixed with others) with the least total CPU time of ``library``'s
    figures (:data:`RUN_CPU`), noting each run's total; the first error if every run failed."""
    ok = [r for r in runs if "error" not in r]
    if not ok:
        return runs[0]
    totals = [sum(r[k] for k in RUN_CPU[library]) for r in ok]
    best = dict(ok[totals.index(min(totals))])
    best["runs_cpu_s"] = totals
    best["runs_failed"] = len(runs) - len(ok)
    return best


def generate(args, workdir: Path) -> dict:
    from fgopt.datasets import bal_synthetic, grid_3d
    from fgopt.io import write_g2o

    files = {}
    ba = workdir / f"bal-{args.cameras}-{args.points}-{args.per_point}.txt"
    if not ba.is_file():
        t0 = time.perf_counter()
        bal_synthetic(args.cameras, args.points, args.per_point, seed=0).write(ba)
        print(f"generated {ba} in {time.perf_counter() - t0:.1f} s", flush=True)
    files["ba"] = ba
    if args.grid > 0:
        grid = workdir / f"grid3d-{args.grid}.g2o"
        if not grid.is_file():
            t0 = time.perf_counter()
            g = grid_3d(args.grid, seed=0)
            write_g2o(grid, g.graph, g.initial)
            print(f"generated {grid} in {time.perf_counter() - t0:.1f} s", flush=True)
        files["grid"] = grid
    return files


def markdown(rows: dict, args, commit: str) -> str:
    lines = [f"# One machine at the edge: fgopt vs C++ Ceres (commit {commit})", "",
             f"`python -m benchmarks.scale --cameras {args.cameras} --points {args.points} "
             f"--per-point {args.per_point} --grid {args.grid} --grid-runs {args.grid_runs}`; "
             "single thread, exactly 5 LM iterations, one process per library and run (the "
             "grid: each library's least-CPU run of the alternating runs; load average at the end "
             f"{os.getloadavg()[0]:.1f}). Times are wall seconds, CPU seconds in parentheses "
             "(the machine is shared: CPU time is the steadier comparison).", "",
             "| problem | library | read / load s | setup s | s per iteration | peak RSS MB | "
             "bytes per observation / edge | final cost |", "|---|---|---|---|---|---|---|---|"]
    for name, r in rows.items():
        n = r["size"]
        f, c = r["fgopt"], r["ceres"]
        if "error" not in f:
            it = max(f["iterations"], 1)
            lines.append(f"| {name} | fgopt ({f['linear_solver']}) | {f['read_s']:.2f} "
                         f"({f['read_cpu_s']:.2f}) | {f['setup_s']:.2f} ({f['setup_cpu_s']:.2f}) | "
                         f"{(f['optimize_s'] - f['setup_s']) / it:.3f} "
                         f"({f['iterations_cpu_s'] / it:.3f}) | {f['peak_rss_mb']:.0f} | "
                         f"{f['peak_rss_mb'] * 2**20 / n:.0f} | {f['final_cost']:.6g} |")
        else:
            lines.append(f"| {name} | fgopt | error: {f['error'][-200:]} | | | | | |")
        if "error" not in c:
            it = max(c["iterations"], 1)
            # CPU of the minimizer alone: the solve's CPU scaled by the minimizer's wall share
            share = c["minimizer_s"] / c["solve_s"] if c["solve_s"] > 0 else 1.0
            lines.append(f"| {name} | Ceres {c.get('ceres', '')} | {c['load_s']:.2f} "
                         f"({c['load_cpu_s']:.2f}) | {c['preprocessor_s']:.2f} | "
                         f"{c['minimizer_s'] / it:.3f} ({c['solve_cpu_s'] * share / it:.3f}) | "
                         f"{c['peak_rss_mb']:.0f} | {c['peak_rss_mb'] * 2**20 / n:.0f} | "
                         f"{c['final_cost']:.6g} |")
        else:
            lines.append(f"| {name} | Ceres | error: {c['error'][-200:]} | | | | | |")
    lines.append("")
    lines.append("Setup: fgopt compiles the problem (ordering, pattern, scatter map) and analyzes "
                 "the linear solver; Ceres' is its preprocessor time (Solver::Summary). Per "
                 "iteration: fgopt's time after setup (the initial linearization included) / "
                 "iterations; Ceres' minimizer time / iterations (Jacobian evaluations and its "
                 "sparse Schur / normal Cholesky solves). Peak RSS is the whole process, reading "
                 "included.")
    return "\n".join(lines) + "\n"


# What the README table's timings include and how runs stop (benchmarks/tables.py).
TABLE_PROTOCOL = {
    "includes": ("one process per library and run (the grid: 3 runs per library, alternating, "
        "each library's run with the least CPU time kept whole; the BA: one run); read = the "
        "library's file reader; setup = fgopt's problem "
        "compile vs Ceres' preprocessor; per iteration = fgopt's time after setup (initial "
        "linearization included) vs Ceres' minimizer time, divided by the iterations."),
    "stopping": ("exactly 5 LM iterations with the stopping tests off, both libraries."),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cameras", type=int, default=1780)
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--per-point", type=int, default=5)
    ap.add_argument("--grid", type=int, default=100_000)
    ap.add_argument("--grid-runs", type=int, default=3,
                    help="processes per library on the grid, alternating (see least_cpu)")
    ap.add_argument("--workdir", default="/tmp/fgopt-scale")
    ap.add_argument("--out", default=None)
    ap.add_argument("--json", default=None, help="also write the numbers to this JSON file")
    args = ap.parse_args()
    workdir = Path(args.workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    files = generate(args, workdir)
    rows = {}
    nobs = args.points * args.per_point
    rows[f"BA {args.cameras} cameras, {args.points} points, {nobs} observations"] = {
        "size": nobs, "fgopt": run_fgopt(files["ba"], "bal"),
        "ceres": run_ceres(files["ba"], "bal", workdir)}
    if "grid" in files:
        from fgopt.io import read

        n_edges = len(read(files["grid"])[0])
        runs: dict[str, list] = {"fgopt": [], "ceres": []}
        for _ in range(max(1, args.grid_runs)):
            runs["fgopt"].append(run_fgopt(files["grid"], "pose3d"))
            runs["ceres"].append(run_ceres(files["grid"], "pose3d", workdir))
        rows[f"3D grid, {args.grid} poses, {n_edges} edges"] = {
            "size": n_edges, "fgopt": least_cpu(runs["fgopt"], "fgopt"),
            "ceres": least_cpu(runs["ceres"], "ceres")}
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                            text=True, cwd=HERE).stdout.strip()
    md = markdown(rows, args, commit)
    print(md)
    print(json.dumps(rows, indent=1, default=str))
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1, default=str))
    out = args.out or str(HERE / "results" / f"scale-{dt.date.today()}.md")
    Path(out).write_text(md)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
