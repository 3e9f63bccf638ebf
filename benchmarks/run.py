"""Side-by-side benchmark: fgopt vs GTSAM, Ceres (pyceres), SymForce and scipy on the same problems.

    python -m benchmarks.run [--datasets m3500,intel,...] [--peers gtsam,ceres,symforce,scipy]
                             [--repeats 3] [--quick]
    python -m benchmarks.run --all | --only TABLE[,TABLE] | --render-only | --list
                             (regenerate the README's tables: benchmarks/pipeline.py)

Every library x problem x mode runs in a fresh ``python -m benchmarks.worker`` subprocess (thread
pools pinned to one thread before numpy loads; peak RSS per process) under a time cap. Problems are
interleaved (for each problem: for each mode: every library) so the ratios to fgopt come from
measurements minutes apart, not hours (the machine drifts). Prints markdown tables and writes
``benchmarks/results/<date>.json`` (+ ``.md``). See ``benchmarks/README.md``.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import platform
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from .peers import MODES
from .problems import DEFAULT_DATASETS, PROBLEMS, data_dir

REPO = Path(__file__).resolve().parent.parent

# What the README table's timings include and how runs stop (benchmarks/tables.py).
TABLE_PROTOCOL = {
    "includes": ("the solve from the file's initial guess, setup included for every library: fgopt's "
        "`optimize` with compiling the problem (ordering, pattern, scatter map) and its "
        "default `initialization=\"auto\"` (a second, chordal start only where its chi-square "
        "test fires), GTSAM's optimizer construction + `optimize`, Ceres' `Solve` with its "
        "preprocessor; reading the file and building factor objects excluded for every "
        "library (the load time, kept in the JSON)."),
    "stopping": ("\"5 it\": exactly 5 LM iterations with every stopping test off in every library; "
        "\"converge\": each library's own default stopping rules and iteration limit (fgopt "
        "100, GTSAM 100, Ceres 50, 200 on pose graphs as Ceres' examples), and \"converged\" "
        "only where the library's own convergence test stopped the run. fgopt and Ceres count "
        "every trial step as an iteration, GTSAM its outer iterations."),
}
RESULTS = Path(__file__).resolve().parent / "results"
ALL_PEERS = ["gtsam", "ceres", "ceres_cpp", "symforce", "scipy"]
THREAD_VARS = ("OMP_NUM_THREADS", "OMP_THREAD_LIMIT", "OPENBLAS_NUM_THREADS",
               "MKL_NUM_THREADS", "NUMBA_NUM_THREADS",
               "VECLIB_MAXIMUM_THREADS", "BLIS_NUM_THREADS")

LABEL = {"fgopt": "fgopt", "gtsam": "GTSAM", "ceres": "pyceres (Python callback costs)",
         "ceres_cpp": "Ceres C++ (measured, AutoDiff)",
         "symforce": "SymForce (Python Optimizer)", "scipy": "scipy least_squares"}

# C++ Ceres 2.1.0 (Debian libceres-dev, AutoDiff costs), from /work/shared/BENCHMARKS.md:
# QUOTED, not measured by this harness. (5 it s, converge s, converge iterations)
QUOTED_CERES_CPP = {
    "m3500": (0.070, 0.356, 25),
    "intel": (0.021, 0.026, 6),
    "sphere2500": (0.763, 2.07, 13),
    "torus3d": (1.56, 24.6, 77),
    "garage": (0.252, 0.882, 19),
    "ladybug": (0.298, 1.58, 31),
}
# Final costs quoted in BENCHMARKS.md, for a sanity check of the yardstick.
QUOTED_FINAL = {"m3500": "68.957", "intel": "22.96", "sphere2500": "675.70",
                "torus3d": "GTSAM 29954, Ceres 22584", "garage": "0.634", "ladybug": "13344.3"}


def default_cap(peer: str, problem: str, mode: str, args) -> float:
    """Seconds before a worker is killed (reported as "timeout")."""
    if peer == "scipy":
        return args.scipy_cap
    if peer == "symforce":
        return args.symforce_cap
    return args.timeout


def skip_reason(peer: str, problem: str, args) -> str | None:
    spec = PROBLEMS[problem]
    if args.quick:
        if peer == "symforce" and not spec.small:
            return "skipped in --quick (slow: Python call per factor)"
        if peer == "scipy" and not (spec.small or problem == "m3500"):
            return "skipped in --quick"
    return None


def run_worker(peer: str, problem: str, mode: str, args, cap: float) -> dict:
    env = dict(os.environ)
    for v in THREAD_VARS:
        env[v] = "1"
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    if args.fgopt_options:
        env["FGOPT_BENCH_OPTIONS"] = args.fgopt_options
    fd, out = tempfile.mkstemp(prefix=f"bench-{peer}-{problem}-{mode}-", suffix=".json")
    os.close(fd)
    os.unlink(out)
    log = open(out + ".log", "w+")
    cmd = [sys.executable, "-m", "benchmarks.worker", "--peer", peer, "--problem", problem,
           "--mode", mode, "--repeats", str(args.repeats), "--out", out,
           "--long", str(args.long)]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=log, stderr=subprocess.STDOUT,
                            start_new_session=True)
    timed_out = False
    ru = None
    while True:
        pid, status, ru = os.wait4(proc.pid, os.WNOHANG)
        if pid:
            proc.returncode = os.waitstatus_to_exitcode(status)
            break
        if time.perf_counter() - t0 > cap:
            timed_out = True
            os.killpg(proc.pid, signal.SIGKILL)
            _, status, ru = os.wait4(proc.pid, 0)
            proc.returncode = os.waitstatus_to_exitcode(status)
            break
        time.sleep(0.05)
    wall = time.perf_counter() - t0
    rec = {"peer": peer, "problem": problem, "mode": mode}
    if os.path.exists(out):
        with open(out) as fh:
            rec.update(json.load(fh))
        os.unlink(out)
    rec["wall_s"] = wall
    rec["cap_s"] = cap
    rec["peak_rss_process_mb"] = ru.ru_maxrss / 1024.0 if ru is not None else None
    if timed_out:
        stage = rec.get("status", "not started")
        rec["status"] = "timeout"
        rec["error"] = f"killed at the {cap:.0f} s cap (last finished stage: {stage})"
    elif rec.get("status") not in ("ok", "unsupported", "error"):
        rec["status"] = "error"
        log.seek(0)
        rec["error"] = f"worker exited {proc.returncode}: " + log.read()[-2000:]
    log.close()
    os.unlink(out + ".log")
    return rec


# ----------------------------------------------------------------------------------------------
# tables
# ----------------------------------------------------------------------------------------------
def _fmt_t(x):
    if x is None:
        return "—"
    return f"{x:.3g}" if x < 100 else f"{x:.0f}"


def _fmt_c(x):
    if x is None:
        return "—"
    if abs(x) >= 1e5:
        return f"{x:.4g}"
    return f"{x:.6g}"


def _cell_status(r):
    s = r.get("status")
    if s == "timeout":
        return f"timeout ({r['cap_s']:.0f} s)"
    if s == "skipped":
        return "skipped"
    if s == "unsupported":
        return "n/a"
    return "error"


def _time_cell(r, ref, with_iters=False):
    if r is None:
        return "—"
    if r.get("status") != "ok":
        return _cell_status(r)
    t = r["solve_s"]
    s = _fmt_t(t)
    if with_iters:
        s += f" ({r.get('iterations')})"
    if ref is not None and ref.get("status") == "ok" and r["peer"] != "fgopt":
        s += f" ×{t / ref['solve_s']:.2g}"
        if ref.get("run", 0) != by_first_run.get((r["problem"], r["mode"]), 0):
            s += "²"
    if r.get("timing_note"):
        s += "¹"
    return s


by_first_run: dict = {}


def markdown(records: list[dict], meta: dict) -> str:
    """Tables from worker records. Records merged from several runs carry ``run``: the fgopt
    column shows the first run's fgopt, every ×N uses the fgopt of the record's own run (²)."""
    by = {}
    fg = {}
    for r in records:
        key = (r["problem"], r["peer"], r["mode"])
        if r["peer"] == "fgopt":
            fg[(r["problem"], r["mode"], r.get("run", 0))] = r
            by.setdefault(key, r)
        else:
            by[key] = r
    by_first_run.clear()
    by_first_run.update({(k[0], k[2]): v.get("run", 0) for k, v in by.items() if k[1] == "fgopt"})
    problems = list(dict.fromkeys(r["problem"] for r in records))
    peers = list(dict.fromkeys(r["peer"] for r in records))
    peers = (["fgopt"] if "fgopt" in peers else []) + [p for p in peers if p != "fgopt"]
    lines = []
    a = lines.append
    a(f"## fgopt vs peers — {meta['date']} ({meta['host']['cpu']}, {meta['host']['cores']} cores)")
    a("")
    a("Seconds, median of {r} runs after a warm-up (¹ = one run: the warm-up itself took > {l} s); "
      "×N = time / fgopt's time in the same run (>1: fgopt faster). Single-threaded everywhere: "
      "OMP/OPENBLAS/MKL/NUMBA_NUM_THREADS=1 and OMP_THREAD_LIMIT=1 set before numpy is imported; "
      "per library: {p}. "
      "The \"Ceres C++ (quoted, not measured)\" column is copied from BENCHMARKS.md; "
      "\"Ceres C++ (measured)\" is benchmarks/ceres_cpp/ceres_bench run here."
      .format(r=meta["args"]["repeats"], l=meta["args"]["long"],
              p="; ".join(f"{LABEL.get(k, k)}: {v}" for k, v in meta["pinning"].items())))
    for mode, title in (("5it", "Exactly 5 LM iterations (stopping tests off, file's initial "
                                "guess)"),
                        ("converge", "To convergence (each library's default stopping rules; "
                                     "iterations in parentheses)")):
        if not any(r["mode"] == mode for r in records):
            continue
        a("")
        a(f"### {title}")
        a("")
        head = ["problem"] + [LABEL.get(p, p) for p in peers] + ["Ceres C++ (quoted, not measured)"]
        a("| " + " | ".join(head) + " |")
        a("|" + "---|" * len(head))
        for pb in problems:
            row = [PROBLEMS[pb].label]
            for p in peers:
                r = by.get((pb, p, mode))
                ref = fg.get((pb, mode, r.get("run", 0))) if r else None
                row.append(_time_cell(r, ref, with_iters=(mode == "converge")))
            q = QUOTED_CERES_CPP.get(pb)
            if q is None:
                row.append("—")
            elif mode == "5it":
                row.append(_fmt_t(q[0]))
            else:
                row.append(f"{_fmt_t(q[1])} ({q[2]})")
            a("| " + " | ".join(row) + " |")
    a("")
    a("### Final cost, one yardstick (0.5 Σ squared whitened residuals, GTSAM's residuals over "
      "the problem's own measurements, no gauge prior; BAL: every observation)")
    a("")
    head = ["problem", "initial"] + [f"{LABEL.get(p, p)} 5 it / converged" for p in peers] + [
        "BENCHMARKS.md"]
    a("| " + " | ".join(head) + " |")
    a("|" + "---|" * len(head))
    for pb in problems:
        init = next((r.get("initial_cost") for r in records
                     if r["problem"] == pb and r.get("initial_cost") is not None), None)
        row = [PROBLEMS[pb].label, _fmt_c(init)]
        for p in peers:
            cells = []
            for mode in MODES:
                r = by.get((pb, p, mode))
                cells.append(_fmt_c(r.get("final_cost")) if r and r.get("status") == "ok"
                             else ("—" if r is None else _cell_status(r)))
            row.append(" / ".join(cells))
        row.append(QUOTED_FINAL.get(pb, "—"))
        a("| " + " | ".join(row) + " |")
    a("")
    a("### Load time (s, the library's own reader / problem build) and peak RSS (MB, whole "
      "process, converge run)")
    a("")
    head = ["problem"] + [LABEL.get(p, p) for p in peers]
    a("| " + " | ".join(head) + " |")
    a("|" + "---|" * len(head))
    for pb in problems:
        row = [PROBLEMS[pb].label]
        for p in peers:
            r = by.get((pb, p, "converge")) or by.get((pb, p, "5it"))
            if r is None or r.get("load_s") is None:
                row.append("—" if r is None else _cell_status(r))
                continue
            rss = r.get("peak_rss_solve_mb") or r.get("peak_rss_process_mb")
            row.append(f"{_fmt_t(r['load_s'])} s, {rss:.0f} MB" if rss else _fmt_t(r["load_s"]))
        a("| " + " | ".join(row) + " |")
    notes = [f"- {PROBLEMS[pb].label}: {PROBLEMS[pb].note}" for pb in problems if PROBLEMS[pb].note]
    errs = [f"- {LABEL.get(r['peer'], r['peer'])} on {PROBLEMS[r['problem']].label} "
            f"({r['mode']}): {r['status']}: {str(r.get('error', ''))[:300]}"
            for r in records if r.get("status") not in ("ok",)]
    if len({r.get("run", 0) for r in records}) > 1:
        a("")
        a("² merged from several runs: ×N uses the fgopt time measured in that peer's own run "
          "(the fgopt column shows the first run's).")
    a("")
    a("Notes:")
    a("- Iterations: GTSAM counts outer LM iterations; fgopt, pyceres and scipy count every "
      "trial step (accepted or not); SymForce counts its iterations.")
    a("- Residual charts differ at a bad guess (Ceres' 2·vec(dq), SymForce's SO(3)×R³, GTSAM/fgopt "
      "SE(n) Log); the yardstick re-evaluates each final estimate with GTSAM's.")
    a("- GTSAM's BAL factor zeroes points behind the camera; the yardstick counts them.")
    notes and lines.extend(notes)
    if errs:
        a("")
        a("Not measured / failed:")
        lines.extend(errs)
    if meta.get("loadavg_1min_range"):
        lo, hi = meta["loadavg_1min_range"]
        a("")
        a(f"Machine load while measuring (1-min load average, {meta['host']['cores']} cores): "
          f"{lo:.1f}–{hi:.1f}; above the core count, other processes shared the CPU and times are "
          "inflated and noisy.")
    versions = ", ".join(f"{LABEL.get(k, k)} {v}" for k, v in meta["versions"].items())
    a("")
    a(f"Versions: {versions}; Python {meta['host']['python']}; data {meta['data_dir']}.")
    return "\n".join(lines)


def render(paths: list[str]) -> int:
    """Print the tables of one or more saved result files (later files win per peer)."""
    records, meta = [], None
    for i, path in enumerate(paths):
        with open(path) as fh:
            d = json.load(fh)
        for r in d["runs"]:
            r["run"] = i
            records.append(r)
        if meta is None:
            meta = d["meta"]
        else:
            meta["versions"].update(d["meta"].get("versions", {}))
            meta["pinning"].update(d["meta"].get("pinning", {}))
            lav = [x for x in (meta.get("loadavg_1min_range"), d["meta"].get("loadavg_1min_range"))
                   if x]
            if lav:
                meta["loadavg_1min_range"] = [min(x[0] for x in lav), max(x[1] for x in lav)]
            meta["date"] += " + " + d["meta"]["date"]
    print(markdown(records, meta))
    return 0


def cpu_name() -> str:
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "?"


def main(argv=None) -> int:
    table_flags = ("--all", "--only", "--skip", "--render-only", "--list")
    if any(a.split("=")[0] in table_flags for a in (sys.argv[1:] if argv is None else argv)):
        from .pipeline import main as tables_main  # README tables (benchmarks/tables.py)

        return tables_main(argv)
    ap = argparse.ArgumentParser(prog="python -m benchmarks.run", description=__doc__.split("\n")[0])
    ap.add_argument("--datasets", default=",".join(DEFAULT_DATASETS),
                    help=f"comma list of {', '.join(PROBLEMS)}")
    ap.add_argument("--peers", default=",".join(ALL_PEERS),
                    help="comma list of gtsam,ceres,ceres_cpp,symforce,scipy (fgopt always runs; "
                         "ceres_cpp needs bash benchmarks/ceres_cpp/build.sh)")
    ap.add_argument("--no-fgopt", action="store_true", help="measure the peers only")
    ap.add_argument("--modes", default=",".join(MODES))
    ap.add_argument("--repeats", type=int, default=None, help="timed runs after the warm-up "
                    "(default 3; 1 with --quick)")
    ap.add_argument("--quick", action="store_true",
                    help="1 timed run; SymForce only on small problems, scipy only on M3500 and "
                         "small ones; shorter caps")
    ap.add_argument("--timeout", type=float, default=None,
                    help="cap per worker in s (default 900; 300 with --quick)")
    ap.add_argument("--scipy-cap", type=float, default=120.0)
    ap.add_argument("--symforce-cap", type=float, default=None,
                    help="default 600; 120 with --quick")
    ap.add_argument("--long", type=float, default=30.0,
                    help="a warm-up solve longer than this (s) is taken as the only sample")
    ap.add_argument("--fgopt-options", default="",
                    help='LMParams overrides for fgopt, e.g. "linear_solver=ldlt,ordering=metis"')
    ap.add_argument("--out", default=None, help="JSON path (default benchmarks/results/<date>.json)")
    ap.add_argument("--no-save", action="store_true")
    ap.add_argument("--render", nargs="+", metavar="JSON",
                    help="only print the tables of saved result files (merged in order)")
    args = ap.parse_args(argv)
    if args.render:
        return render(args.render)
    if args.repeats is None:
        args.repeats = 1 if args.quick else 3
    if args.timeout is None:
        args.timeout = 300.0 if args.quick else 900.0
    if args.symforce_cap is None:
        args.symforce_cap = 120.0 if args.quick else 600.0
    if args.quick:
        args.scipy_cap = min(args.scipy_cap, 60.0)

    datasets = [d.strip() for d in args.datasets.split(",") if d.strip()]
    peers = [p.strip() for p in args.peers.split(",") if p.strip()]
    modes = [m.strip() for m in args.modes.split(",") if m.strip()]
    bad = [d for d in datasets if d not in PROBLEMS] + [p for p in peers if p not in ALL_PEERS
                                                         and p != "fgopt"]
    bad += [m for m in modes if m not in MODES]
    if bad:
        ap.error(f"unknown: {bad}")
    from .peers.ceres_cpp_runner import BINARY as CERES_BINARY
    if "ceres_cpp" in peers and not CERES_BINARY.exists():
        # a table without its Ceres columns would read as if Ceres had not been compared
        ap.error(f"{CERES_BINARY} is not built: run `bash benchmarks/ceres_cpp/build.sh`, or "
                 "leave ceres_cpp out of --peers")
    order = ([] if args.no_fgopt else ["fgopt"]) + [p for p in peers if p != "fgopt"]
    for d in datasets:
        spec = PROBLEMS[d]
        if spec.path is not None and not spec.path.exists():
            ap.error(f"{spec.path} not found (set FGOPT_DATA)")

    started = dt.datetime.now()
    records = []
    out = None
    if not args.no_save:
        if args.out:
            out = Path(args.out)
        else:
            RESULTS.mkdir(parents=True, exist_ok=True)
            out = RESULTS / f"{started:%Y-%m-%d}.json"
            if out.exists():
                out = RESULTS / f"{started:%Y-%m-%d-%H%M%S}.json"

    def save(final: bool):
        meta = make_meta(records, args, started, final)
        if out is not None:
            slim = [{k: v for k, v in r.items() if k not in ("traceback", "threads")}
                    for r in records]
            tmp = out.with_suffix(".json.tmp")
            with open(tmp, "w") as fh:
                json.dump({"meta": meta, "runs": slim}, fh, indent=1, default=float)
            os.replace(tmp, out)
        return meta

    for pb in datasets:
        for mode in modes:
            for peer in order:
                why = skip_reason(peer, pb, args)
                if why:
                    records.append({"peer": peer, "problem": pb, "mode": mode,
                                    "status": "skipped", "error": why})
                    continue
                cap = default_cap(peer, pb, mode, args)
                print(f"[{dt.datetime.now():%H:%M:%S}] {peer:9s} {pb:18s} {mode:8s} ...",
                      end="", flush=True, file=sys.stderr)
                r = run_worker(peer, pb, mode, args, cap)
                records.append(r)
                if r.get("status") == "ok":
                    print(f" {r['solve_s']:.4g} s, {r.get('iterations')} it, cost "
                          f"{r.get('final_cost'):.6g}", file=sys.stderr)
                else:
                    print(f" {r.get('status')}: {str(r.get('error', ''))[:200]}", file=sys.stderr)
                save(final=False)  # a killed run keeps what it measured

    meta = save(final=True)
    md = markdown(records, meta)
    print(md)
    if out is not None:
        out.with_suffix(".md").write_text(md + "\n")
        print(f"\nwrote {out} and {out.with_suffix('.md')}", file=sys.stderr)
    return 0


def make_meta(records, args, started, final: bool) -> dict:
    lav = [r["loadavg_1min"] for r in records if r.get("loadavg_1min") is not None]
    versions, pinning = {}, {}
    for r in records:
        if r.get("version"):
            versions.setdefault(r["peer"], r["version"])
        if r.get("pinning"):
            pinning.setdefault(r["peer"], r["pinning"])
    return {"date": started.strftime("%Y-%m-%d %H:%M"), "complete": final,
            "host": {"cpu": cpu_name(), "cores": os.cpu_count(),
                     "python": platform.python_version(), "platform": platform.platform()},
            "args": vars(args), "versions": versions, "pinning": pinning,
            "thread_env": {v: "1" for v in THREAD_VARS}, "data_dir": str(data_dir()),
            "quoted_ceres_cpp": {k: {"5it_s": v[0], "converge_s": v[1], "converge_iterations": v[2],
                                     "source": "BENCHMARKS.md (quoted, not measured)"}
                                 for k, v in QUOTED_CERES_CPP.items()},
            "wall_s": (dt.datetime.now() - started).total_seconds(),
            "loadavg_1min_range": [min(lav), max(lav)] if lav else None}


if __name__ == "__main__":
    sys.exit(main())
