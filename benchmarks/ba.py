"""Bundle-adjustment benchmark: fgopt's Schur solvers vs Ceres (C++ and pyceres) and GTSAM.

    .venv/bin/python -m benchmarks.ba [--problems ladybug,trafalgar,dubrovnik3,synthetic:21x11315]
        [--rounds 3]
        [--peers fgopt,ceres_cpp,pyceres,gtsam] [--profile] [--json out.json]

Per problem and configuration it reports, from the same interleaved rounds (the machine drifts;
BENCHMARKS.md: compare ratios measured in one run), medians of

* ``5it``: wall and CPU seconds of exactly five LM iterations (every stopping test off),
  seconds per iteration, cost after five iterations;
* ``converge``: wall / CPU seconds, iterations and final cost with the library's stopping rules
  (fgopt: Ceres-like ``initial_lambda=1e-4``, ``relative_tolerance=1e-6``, plus a row with
  fgopt's defaults);
* ``to Ceres cost``: seconds until the cost first reaches C++ Ceres' converged cost (pyceres'
  if the C++ program is not built), from each library's own per-iteration clock.

Single thread for everyone: the BLAS / OpenMP / numba thread variables are set to 1 before numpy
is imported; Ceres ``num_threads = 1``. Costs are the BAL cost ``0.5 sum |e|^2`` of every
observation (GTSAM's estimate is re-evaluated with :mod:`benchmarks.yardstick`, which counts points
behind a camera too). ``--profile`` splits one fgopt LM iteration on each problem into
linearize / assemble / Schur elimination / factor S / reduce / solve S / back-substitute /
retract / cost (CPU seconds, best of 15).
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OMP_THREAD_LIMIT", "OPENBLAS_NUM_THREADS",
           "MKL_NUM_THREADS", "NUMBA_NUM_THREADS",
           "VECLIB_MAXIMUM_THREADS"):
    os.environ[_v] = "1"
# Warm-process figures: small batches on the compiled kernels from the first timed call (a
# process reaches this after 0.5 s of NumPy-twin work; see fgopt/_jit.py).
os.environ.setdefault("FGOPT_NUMPY_BUDGET", "0")

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks import problems, yardstick

BAL_PROBLEMS = {"ladybug": "bal/problem-49-7776-pre.txt",
                "dubrovnik3": "bal/dubrovnik-3-7-pre.txt",
                "dubrovnik1": "bal/dubrovnik-1-1-pre.txt"}
# Real BAL problems of Ladybug's size outside the shared folder (benchmarks/extra_data.py).
EXTRA_BAL_PROBLEMS = {"trafalgar": "problem-21-11315-pre.txt"}
CERES_BIN = Path(__file__).resolve().parent / "ceres_cpp" / "ceres_bench"
QUOTED_CERES = {"ladybug": {"5it": 0.298, "converge": 1.58, "iterations": 31, "final": 13344.3}}
FGOPT_CONFIGS = ("schur_dense", "schur_sparse", "schur_pcg", "cholmod")


def _clock():
    return time.perf_counter(), time.process_time()


def _since(t):
    w, c = _clock()
    return w - t[0], c - t[1]


# ------------------------------------------------------------------------------------ fgopt
def fgopt_load(path: Path, kernel: str = "official"):
    """``fgopt.io.read_bal`` (official kernel) or the same graph with the hand-written kernel."""
    import fgopt.io

    graph, values = fgopt.io.read_bal(path)
    if kernel == "handwritten":
        import fgopt
        from fgopt.factors.library.bal_kernel import bal_kernel

        b = graph.batches[0]
        g2 = fgopt.FactorGraph()
        g2.add_batch(bal_kernel(), b.keys, b.constants)
        graph = g2
    return graph, values


def fgopt_solver(config: str):
    from fgopt.solvers.linear.cholmod import CholmodSolver
    from fgopt.solvers.linear.schur import SchurSolver

    if config == "cholmod":
        return CholmodSolver()
    return SchurSolver(reduced=config.split("_", 1)[1])


def fgopt_params(mode: str, defaults: bool = False):
    from fgopt.solvers import LMParams

    if mode == "5it":
        return LMParams(max_iterations=5, relative_tolerance=0.0, absolute_tolerance=0.0,
                        gradient_tolerance=0.0, step_tolerance=0.0, initial_lambda=1e-4)
    if mode == "converge" and defaults:
        return LMParams()
    if mode == "converge":  # Ceres' defaults: function / gradient / parameter tolerances
        return LMParams(initial_lambda=1e-4, relative_tolerance=1e-6, absolute_tolerance=0.0,
                        gradient_tolerance=1e-10, step_tolerance=1e-8, max_iterations=50)
    # "trace": run until the target cost (the callback stops it)
    return LMParams(initial_lambda=1e-4, relative_tolerance=0.0, absolute_tolerance=0.0,
                    gradient_tolerance=0.0, step_tolerance=0.0, max_iterations=100)


def fgopt_run(graph, values, config: str, mode: str, target: float | None = None,
              defaults: bool = False) -> dict:
    import fgopt

    solver = fgopt_solver(config)
    reached = {}

    def cb(rec):
        if target is not None and rec.accepted and rec.cost <= target and not reached:
            reached["wall"], reached["cpu"] = _since(t0)
            reached["iterations"] = rec.iteration
            return True
        return None

    t0 = _clock()
    r = fgopt.optimize(graph, values, method="lm", linear_solver=solver,
                       params=fgopt_params(mode, defaults), callback=cb)
    wall, cpu = _since(t0)
    out = {"wall": wall, "cpu": cpu, "iterations": r.iterations, "final": r.final_cost,
           "status": r.status.value, "setup": r.timing["setup"]}
    if target is not None:
        out["to_target"] = reached or None
    if hasattr(solver, "last_pcg_iterations"):
        out["solver_timing"] = dict(solver.timing)
    return out


# ------------------------------------------------------------------------------------ Ceres
def _ceres_cpp_once(path: Path, mode: str, repeats: int) -> tuple[dict, float]:
    import resource

    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    with tempfile.TemporaryDirectory() as tmp:
        proc = subprocess.run([str(CERES_BIN), "bal", str(path), mode, str(repeats),
                               str(Path(tmp) / "e")], capture_output=True, text=True, check=True)
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (r1.ru_utime + r1.ru_stime) - (r0.ru_utime + r0.ru_stime)
    return json.loads(proc.stdout.strip().splitlines()[-1]), cpu


def ceres_cpp_run(path: Path, mode: str) -> dict | None:
    """The C++ program (``benchmarks/ceres_cpp``, SPARSE_SCHUR): it times its own solves after a
    warm-up. Its CPU time per solve is the difference of the process CPU with 2 and 1 timed
    solves (load and warm-up cancel)."""
    if not CERES_BIN.exists():
        return None
    rec1, cpu1 = _ceres_cpp_once(path, mode, 1)
    rec2, cpu2 = _ceres_cpp_once(path, mode, 2)
    return {"wall": statistics.median([rec1["solve_s"], *rec2["samples"]]),
            "cpu": max(cpu2 - cpu1, 0.0), "iterations": rec2["iterations"],
            "final": rec2["final_cost"], "linear_solver_s": rec2["linear_solver_s"],
            "status": rec2["termination"]}


def pyceres_run(bal, mode: str, linear: str, target: float | None = None) -> dict:
    import pyceres

    from benchmarks.peers.ceres_runner import cost_classes

    Snavely = cost_classes()[2]
    cams, pts = bal.cameras.copy(), bal.points.copy()
    prob = pyceres.Problem()
    costs = [Snavely(bal.obs[k]) for k in range(len(bal.obs))]
    for k, c in enumerate(costs):
        prob.add_residual_block(c, None, [cams[bal.cam_idx[k]], pts[bal.pt_idx[k]]])
    o = pyceres.SolverOptions()
    o.num_threads = 1
    o.logging_type = pyceres.LoggingType.SILENT
    o.linear_solver_type = getattr(pyceres.LinearSolverType, linear)
    o.max_num_iterations = 50
    if mode == "5it":
        o.max_num_iterations = 5
        o.function_tolerance = o.gradient_tolerance = o.parameter_tolerance = 0.0
    trace = []

    class Trace(pyceres.IterationCallback):
        def __call__(self, s):
            trace.append((s.iteration, s.cost, s.cumulative_time_in_seconds))
            return pyceres.CallbackReturnType.SOLVER_CONTINUE

    tr = Trace()
    o.callbacks = [tr]
    summary = pyceres.SolverSummary()
    t0 = _clock()
    pyceres.solve(o, prob, summary)
    wall, cpu = _since(t0)
    out = {"wall": wall, "cpu": cpu, "final": summary.final_cost,
           "iterations": summary.num_successful_steps + summary.num_unsuccessful_steps - 1,
           "linear_solver_s": summary.linear_solver_time_in_seconds,
           "status": str(summary.termination_type).split(".")[-1]}
    if target is not None:
        hit = [(it, t) for it, c, t in trace if c <= target]
        out["to_target"] = {"wall": hit[0][1], "iterations": hit[0][0]} if hit else None
    return out


# ------------------------------------------------------------------------------------ GTSAM
def gtsam_run(spec, bal, mode: str, target: float | None = None) -> dict:
    import gtsam

    from benchmarks.peers.gtsam_runner import RUNNER, cameras_to_bal, lm_params

    st = RUNNER.load(spec)
    params = lm_params(mode)

    def yard(values):
        cams = [values.atPinholeCameraCal3Bundler(gtsam.symbol("c", i))
                for i in range(st["ncam"])]
        return yardstick.bal_cost(bal, cameras_to_bal(cams),
                                  gtsam.utilities.extractPoint3(values).reshape(-1, 3))

    opt = gtsam.LevenbergMarquardtOptimizer(st["graph"], st["initial"], params)
    if target is None:
        t0 = _clock()
        values = opt.optimize()
        wall, cpu = _since(t0)
        return {"wall": wall, "cpu": cpu, "iterations": opt.iterations(), "final": yard(values),
                "lib_final": opt.error()}
    # trace: iterate() one at a time, the yardstick cost evaluated off the clock
    spent = 0.0
    prev = opt.error()
    for it in range(1, params.getMaxIterations() + 1):
        t = time.perf_counter()
        opt.iterate()
        spent += time.perf_counter() - t
        if yard(opt.values()) <= target:
            return {"to_target": {"wall": spent, "iterations": it}}
        err = opt.error()
        if prev - err < 1e-5 * prev:
            break
        prev = err
    return {"to_target": None}


# ------------------------------------------------------------------------------------ profile
def profile_iteration(graph, values, config: str = "schur_dense", reps: int = 15) -> dict:
    """CPU seconds (best of ``reps``) of each stage of one LM iteration at the initial guess."""
    from fgopt.problem import Problem

    P = Problem(graph, values)
    s = P.initial_state()
    P.linearize(s)
    solver = fgopt_solver(config)
    solver.analyze(P.pattern)
    H = P.H_data.copy()
    d = P.pattern.diag_pos
    H[d] += 1e-4 * np.clip(H[d], 1e-6, 1e32)
    rhs = -P.g.copy()
    b = P.batches[0]

    def best(f):
        ts = []
        for _ in range(reps):
            t = time.process_time()
            f()
            ts.append(time.process_time() - t)
        return min(ts)

    out = {"linearize (kernels)": best(lambda: b.kernel.linearize(b.gather(s),
                                                                  b.source.constants))}
    out["linearize + assemble"] = best(lambda: P.linearize(s))
    out["assemble"] = out["linearize + assemble"] - out["linearize (kernels)"]
    if hasattr(solver, "timing"):
        solver.clock = time.process_time
        stages: dict = {}
        for _ in range(reps):
            solver.timing = dict.fromkeys(solver.timing, 0.0)
            solver.factorize(H)
            solver.solve(rhs)
            for k, v in solver.timing.items():
                stages.setdefault(k, []).append(v)
        for k, v in stages.items():
            out[f"schur: {k}"] = min(v)
    out["factorize + solve"] = best(lambda: (solver.factorize(H), solver.solve(rhs)))
    delta = solver.solve(rhs)
    out["retract"] = best(lambda: P.retract(s, delta))
    out["cost"] = best(lambda: P.cost(s))
    out["iteration total"] = (out["linearize + assemble"] + out["factorize + solve"]
                              + out["retract"] + out["cost"])
    return out


# ------------------------------------------------------------------------------------ driver
def synthetic_path(name: str) -> Path:
    """``synthetic:CxP[:K]`` -> a BAL file of ``fgopt.datasets.bal_synthetic(C, P, K)`` (seed 0)
    in the temp folder: BAL problems of Ladybug's size beyond the one shared file, readable by
    every peer."""
    from fgopt.datasets import bal_synthetic
    from fgopt.io.bal import write_bal_arrays

    spec = name.split(":", 1)[1]
    size, _, k = spec.partition(":")
    c, p = (int(x) for x in size.split("x"))
    path = Path(tempfile.gettempdir()) / f"fgopt-bal-synthetic-{c}x{p}x{k or 5}.txt"
    if not path.exists():
        d = bal_synthetic(c, p, int(k or 5), seed=0)
        write_bal_arrays(path, d.camera_index, d.point_index, d.observations, d.cameras,
                         d.points)
    return path


def problem_path(name: str) -> Path:
    if name.startswith("synthetic:"):
        return synthetic_path(name)
    if name in EXTRA_BAL_PROBLEMS:
        from benchmarks import extra_data

        return extra_data.ensure(EXTRA_BAL_PROBLEMS[name])
    return problems.data_dir() / BAL_PROBLEMS[name]


def run_problem(name: str, peers: list[str], rounds: int, kernel: str, configs: list[str],
                slow_rounds: int) -> dict:
    path = problem_path(name)
    spec = problems.ProblemSpec(name, "bal", str(path), name)
    bal = problems.read_bal(path, name)
    graph, values = fgopt_load(path, kernel)
    print(f"\n== {name}: {len(bal.cameras)} cameras, {len(bal.points)} points, "
          f"{len(bal.obs)} observations", flush=True)
    res: dict = {"problem": name, "runs": {}}
    runs = res["runs"]

    def add(key, rec):
        if rec is not None:
            runs.setdefault(key, []).append(rec)
            w, c = rec.get("wall"), rec.get("cpu")
            print(f"    {key}: wall {w if w is None else round(w, 3)} cpu "
                  f"{c if c is None else round(c, 3)} its {rec.get('iterations')} final "
                  f"{rec.get('final')} to_target {rec.get('to_target', '-')}", flush=True)

    # warm-up (JIT, caches) and the target cost
    for c in configs:
        fgopt_run(graph, values, c, "5it")
    target_src, target = None, None
    if "ceres_cpp" in peers and CERES_BIN.exists():
        rec = ceres_cpp_run(path, "converge")
        target_src, target = "ceres_cpp", rec["final"]
    elif "pyceres" in peers:
        rec = pyceres_run(bal, "converge", "SPARSE_SCHUR")
        target_src, target = "pyceres", rec["final"]
    res["target"] = {"source": target_src, "cost": target}
    print(f"target (Ceres converged cost, {target_src}): {target!r}", flush=True)
    for r in range(rounds):
        for c in configs:
            add(f"fgopt {c} 5it", fgopt_run(graph, values, c, "5it"))
            if c != "cholmod" or r == 0:
                add(f"fgopt {c} converge", fgopt_run(graph, values, c, "converge"))
                if target is not None:
                    add(f"fgopt {c} trace", fgopt_run(graph, values, c, "trace", target))
        add("fgopt schur_dense converge (fgopt defaults)",
            fgopt_run(graph, values, "schur_dense", "converge", defaults=True))
        if "ceres_cpp" in peers:
            add("ceres_cpp SPARSE_SCHUR 5it", ceres_cpp_run(path, "5it"))
            add("ceres_cpp SPARSE_SCHUR converge", ceres_cpp_run(path, "converge"))
        if r < slow_rounds and "pyceres" in peers:
            for lin in ("SPARSE_SCHUR", "DENSE_SCHUR"):
                add(f"pyceres {lin} 5it", pyceres_run(bal, "5it", lin))
            add("pyceres SPARSE_SCHUR converge", pyceres_run(bal, "converge", "SPARSE_SCHUR",
                                                            target))
        if r < slow_rounds and "gtsam" in peers:
            add("gtsam 5it", gtsam_run(spec, bal, "5it"))
            add("gtsam converge", gtsam_run(spec, bal, "converge"))
            if target is not None:
                add("gtsam trace", gtsam_run(spec, bal, "converge", target))
        print(f"  round {r + 1}/{rounds} done", flush=True)
    res["summary"] = summarize(runs)
    return res


def _med(xs):
    xs = [x for x in xs if x is not None]
    return statistics.median(xs) if xs else None


def summarize(runs: dict) -> dict:
    out = {}
    for key, recs in runs.items():
        s = {}
        for f in ("wall", "cpu", "iterations", "final", "linear_solver_s", "setup"):
            s[f] = _med([r.get(f) for r in recs])
        tt = [r.get("to_target") for r in recs if "to_target" in r]
        if tt:
            hit = [t for t in tt if t]
            s["to_target_wall"] = _med([t["wall"] for t in hit]) if hit else None
            s["to_target_cpu"] = _med([t.get("cpu") for t in hit]) if hit else None
            s["to_target_iterations"] = _med([t["iterations"] for t in hit]) if hit else None
        s["n"] = len(recs)
        out[key] = s
    return out


def summary_lines(res: dict) -> list[str]:
    out = [(f"### {res['problem']} (target cost {res['target']['cost']!r} from "
           f"{res['target']['source']})"), "",
           ("| run | wall s | CPU s | its | CPU s/it | final cost | to target: wall / CPU s (its) "
           "| n |"), "|---|---|---|---|---|---|---|---|"]

    def f(x, fmt="{:.3f}"):
        return "—" if x is None else fmt.format(x)

    for key, s in res["summary"].items():
        per = (s["cpu"] / s["iterations"]) if s.get("cpu") and s.get("iterations") else None
        tt = "—"
        if s.get("to_target_wall") is not None:
            tt = (f"{s['to_target_wall']:.3f} / {f(s.get('to_target_cpu'))} "
                  f"({s['to_target_iterations']:.0f})")
        elif "to_target_wall" in s:
            tt = "not reached"
        out.append(f"| {key} | {f(s.get('wall'))} | {f(s.get('cpu'))} | "
                   f"{f(s.get('iterations'), '{:.0f}')} | {f(per, '{:.4f}')} | "
                   f"{f(s.get('final'), '{:.6f}')} | {tt} | {s['n']} |")
    if "profile" in res:
        out += ["", "One LM iteration at the initial guess (CPU ms, best of 15):", ""]
        out += [f"    {k:28s} {v * 1e3:8.2f}" for k, v in res["profile"].items()]
    if res["problem"] in QUOTED_CERES:
        out += ["", (f"Quoted C++ Ceres (BENCHMARKS.md, quieter machine): "
                    f"{QUOTED_CERES[res['problem']]}")]
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--problems", default="ladybug,dubrovnik3,dubrovnik1",
                    help="names of shared files and synthetic:CxP[:K] (fgopt.datasets."
                         "bal_synthetic, C cameras, P points, K observations per point)")
    ap.add_argument("--peers", default="fgopt,ceres_cpp,pyceres,gtsam")
    ap.add_argument("--configs", default="schur_dense,schur_sparse,schur_pcg,cholmod",
                    help=f"fgopt linear solvers among {', '.join(FGOPT_CONFIGS)}")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--slow-rounds", type=int, default=1,
                    help="rounds for pyceres (Python callbacks) and GTSAM")
    ap.add_argument("--kernel", default="official", choices=("official", "handwritten"))
    ap.add_argument("--profile", action="store_true")
    ap.add_argument("--json", default=None)
    ap.add_argument("--markdown", default=None, help="also write the tables to this file")
    a = ap.parse_args(argv)
    peers = a.peers.split(",")
    configs = [c for c in a.configs.split(",") if c]
    results, lines = [], []
    for name in a.problems.split(","):
        if not problem_path(name).exists():
            print(f"skip {name}: data file missing", file=sys.stderr)
            continue
        res = run_problem(name, peers, a.rounds, a.kernel, configs, a.slow_rounds)
        if a.profile:
            g, v = fgopt_load(problem_path(name), a.kernel)
            res["profile"] = profile_iteration(g, v)
        results.append(res)
        lines += summary_lines(res) + [""]
        print("\n" + "\n".join(summary_lines(res)), flush=True)
    if a.json:
        Path(a.json).write_text(json.dumps(results, indent=1, default=str))
    if a.markdown:
        load = os.getloadavg()
        head = [(f"# BA benchmark ({time.strftime('%Y-%m-%d %H:%M')}, `python -m benchmarks.ba "
                f"{' '.join(argv if argv is not None else sys.argv[1:])}`)"), "",
                (f"{os.cpu_count()} CPUs, load average {load[0]:.1f} / {load[1]:.1f} / "
                f"{load[2]:.1f} at the end; medians over interleaved rounds; single thread."), ""]
        Path(a.markdown).write_text("\n".join(head + lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
