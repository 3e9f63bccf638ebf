"""NumPy backend vs numba backend (issue 11): per-iteration cost in a warm process, and
``fgopt solve FILE --out OUT`` end to end in new processes with warm caches.

Per iteration (one process, both backends warm, median of ``--repeats``): linearize (kernels +
assembly), factorize + solve of the damped system with each backend's default linear solver
(numba: fgopt's block Cholesky; NumPy: CHOLMOD when installed, and qdldl, the default without
it), retract. End to end: ``python -m fgopt.cli solve FILE --out OUT --quiet --backend B``,
interleaved, median of ``--repeats`` (each backend run once first to warm its caches).

    python -m benchmarks.numpy_backend                       # M3500, sphere2500, garage, torus3D
    python -m benchmarks.numpy_backend --files M3500 --repeats 3

Writes ``benchmarks/results/numpy-backend-<date>.{json,md}``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

from .startup import DATA, PY, REPO, _env, run

FILES = {"M3500": DATA / "pose2d" / "input_M3500_g2o.g2o",
         "intel": DATA / "pose2d" / "intel.g2o",
         "sphere2500": DATA / "pose3d" / "sphere2500.g2o",
         "garage": DATA / "pose3d" / "parking-garage.g2o",
         "torus3D": DATA / "pose3d" / "torus3D.g2o"}


def per_iteration(path: Path, repeats: int) -> dict:
    from fgopt.io import add_gauge_prior, read
    from fgopt.problem import Problem
    from fgopt.solvers.linear.base import make_linear_solver

    graph, initial = read(path, format="g2o")
    add_gauge_prior(graph, initial)
    out = {}
    for backend, solvers in (("numba", ["auto"]), ("numpy", ["auto", "ldlt"])):
        p = Problem(graph, initial, backend=backend)
        st = p.initial_state()
        for solver_name in solvers:
            solver = make_linear_solver(solver_name, pattern=p.pattern, backend=backend)
            solver.analyze(p.pattern)
            t_lin, t_fac, t_ret = [], [], []
            for _ in range(repeats + 1):  # the first round compiles / loads: dropped
                t0 = time.perf_counter()
                p.linearize(st)
                t1 = time.perf_counter()
                H = p.H_data.copy()
                H[p.pattern.diag_pos] += 1e-4
                solver.factorize(H)
                delta = solver.solve(-p.g)
                t2 = time.perf_counter()
                p.retract(st, delta)
                t3 = time.perf_counter()
                t_lin.append(t1 - t0)
                t_fac.append(t2 - t1)
                t_ret.append(t3 - t2)
            med = {k: statistics.median(v[1:]) for k, v in
                   (("linearize", t_lin), ("factorize+solve", t_fac), ("retract", t_ret))}
            med["total"] = sum(med.values())
            out[f"{backend}/{solver.name}"] = med
        out[f"{backend} size"] = int(p.pattern.size)
    return out


def end_to_end(path: Path, repeats: int, out_dir: Path) -> dict:
    cmds = {b: [PY, "-m", "fgopt.cli", "solve", str(path), "--out",
                str(out_dir / f"{b}.g2o"), "--quiet", "--backend", b] for b in ("numba", "numpy")}
    env = _env()
    for cmd in cmds.values():
        run(cmd, env)
    samples: dict[str, list] = {b: [] for b in cmds}
    outs = {}
    for _ in range(repeats):
        for b, cmd in cmds.items():
            dt, o = run(cmd, env)
            samples[b].append(dt)
            outs[b] = o.strip()
    return {b: {"median": statistics.median(v), "samples": v, "stdout": outs[b]}
            for b, v in samples.items()}


# What the README table's timings include and how runs stop (benchmarks/tables.py).
TABLE_PROTOCOL = {
    "includes": ("fgopt only (no peer): per-iteration medians in a warm process, setup excluded for "
        "both backends; `fgopt solve --backend B` end to end in a new process (start-up, "
        "read, compile, solve, write included, warm caches, no switch)."),
    "stopping": ("per iteration: a fixed number of LM iterations; end to end: fgopt's default stopping "
        "rules (how it ended in the last column)."),
}


def main(argv: list[str] | None = None) -> int:
    import tempfile

    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--files", default="M3500,intel,sphere2500,garage,torus3D")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results"))
    args = ap.parse_args(argv)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    os.environ.setdefault("OMP_THREAD_LIMIT", "1")
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    meta = {"date": time.strftime("%Y-%m-%d %H:%M"), "load": os.getloadavg(),
            "command": "python -m benchmarks.numpy_backend " + " ".join(
                argv if argv is not None else sys.argv[1:])}
    results = {}
    with tempfile.TemporaryDirectory(prefix="fgopt-npb-") as tmp:
        for name in args.files.split(","):
            path = FILES[name]
            if not path.is_file():
                continue
            results[name] = {"per iteration": per_iteration(path, args.repeats),
                             "end to end": end_to_end(path, args.repeats, Path(tmp))}
            print(name, json.dumps(results[name], default=str)[:600], file=sys.stderr, flush=True)
    meta["load_end"] = os.getloadavg()
    lines = [f"# NumPy backend vs numba backend ({meta['date']})", "",
             (f"`{meta['command']}`; load average {tuple(round(x, 1) for x in meta['load'])} "
             f"-> {tuple(round(x, 1) for x in meta['load_end'])}. Milliseconds per iteration "
             "(warm process, median); seconds end to end (new process, warm caches, median)."), "",
             ("| problem | N | numba: lin / fac+solve / retract = total (ms) | NumPy + CHOLMOD | "
             "NumPy + qdldl | `fgopt solve` numba (s) | `fgopt solve` NumPy (s) | iterations |"),
             "|---|---|---|---|---|---|---|---|"]

    def cell(d):
        return (f"{1e3 * d['linearize']:.1f} / {1e3 * d['factorize+solve']:.1f} / "
                f"{1e3 * d['retract']:.1f} = {1e3 * d['total']:.1f}")

    for name, r in results.items():
        it = r["per iteration"]
        e = r["end to end"]
        iters = e["numpy"]["stdout"].split("after ")[1].split(" ")[0] if "after " in \
            e["numpy"]["stdout"] else "?"
        lines.append(f"| {name} | {it['numpy size']} | {cell(it['numba/block'])} | "
                     f"{cell(it.get('numpy/cholmod', it['numpy/ldlt']))} | "
                     f"{cell(it['numpy/ldlt'])} | {e['numba']['median']:.2f} | "
                     f"{e['numpy']['median']:.2f} | {iters} |")
    md = "\n".join(lines) + "\n"
    print(md)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    stem = out / f"numpy-backend-{time.strftime('%Y-%m-%d-%H%M')}"
    stem.with_suffix(".json").write_text(json.dumps({"meta": meta, "results": results},
                                                    indent=1, default=str))
    stem.with_suffix(".md").write_text(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
