"""Start-up benchmark (issue 11): fgopt as a new user meets it, side by side with GTSAM.

Every number is the wall time of a NEW process (``subprocess``; interpreter start included),
median of ``--repeats`` (5), fgopt and GTSAM interleaved so both see the same machine load:

* ``import``: ``python -c "import fgopt"`` vs ``"import gtsam"`` (and ``pass``: the interpreter;
  ``numba floor``: ``import numba``, paid by every process that runs a numba kernel);
* ``tiny 2D`` / ``tiny 3D``: the scripts in ``benchmarks/startup_scripts/`` (5 poses, LM);
* ``solve FILE``: ``fgopt solve FILE --out OUT --quiet`` vs ``startup_scripts/gtsam_solve.py``
  (read, LM with each library's default stopping rules, write) on M3500, sphere2500, Ladybug-49
  (``--ba-repeats``, 3: GTSAM runs its 100 iterations there);
* ``overheads``: inside one process, first read vs second read, first optimize vs second;
* ``empty caches``: ``fgopt solve`` of M3500 / sphere2500 and ``python -m fgopt.demo`` with an
  empty kernel cache (``FGOPT_CACHE_DIR``) AND an empty numba cache (``NUMBA_CACHE_DIR``): a fresh
  install (``--cold-repeats``, 1: each costs a cold compile). GTSAM has no cache: its figure is
  its (only) solve of the same file (for the demo: the demo's generated graph written as g2o);
* ``custom factor``: ``startup_scripts/custom_factor.py`` (range-bearing, a Pose3 between-like
  factor): definition to first optimized result with an empty ``FGOPT_CACHE_DIR`` (cold), warm
  (same definition, new process), edited (the body changed, built-ins cached); GTSAM: the same
  factor as a ``CustomFactor`` with numerical Jacobians;
* ``ports`` and ``first`` (issue 41): five ports of GTSAM's examples vs GTSAM's scripts (warm),
  and first use on a fresh install (empty caches, a copy of the package) vs the warm run of
  the same job; ``built``: the same first uses in one fresh install after ``fgopt cache
  build`` (whose own time is the one-time cost): see :mod:`benchmarks.startup_ports`.

"Warm caches" are the run's own: every process gets ``FGOPT_CACHE_DIR`` and ``NUMBA_CACHE_DIR``
in one folder made for the run, warmed by an untimed first run of each job (a cache shared
with other checkouts of fgopt would be rebuilt whenever their sources differ).

    python -m benchmarks.startup                      # everything (~15-30 min on 2 cores)
    python -m benchmarks.startup --only import,tiny   # a subset
    python -m benchmarks.startup --repeats 3 --cold-repeats 1
    python -m benchmarks.startup --only first --first-jobs imu,manifold   # some first uses

Results: ``benchmarks/results/startup-<date>.json`` and ``.md``. Child processes run without
``PYTHONDONTWRITEBYTECODE`` (an installed package has its bytecode; without it every fgopt module
is compiled from source in every process, ~0.3 s).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from . import startup_ports as ports

REPO = Path(__file__).resolve().parents[1]
SCRIPTS = REPO / "benchmarks" / "startup_scripts"
DATA = Path(os.environ.get("FGOPT_DATA", REPO.parent / "shared" / "data"))
if not DATA.is_dir():
    DATA = Path("/work/shared/data")
FILES = {
    "M3500": DATA / "pose2d" / "input_M3500_g2o.g2o",
    "sphere2500": DATA / "pose3d" / "sphere2500.g2o",
    "Ladybug-49": DATA / "bal" / "problem-49-7776-pre.txt",
}
PY = sys.executable
SECTIONS = ("import", "tiny", "ports", "solve", "overheads", "cold", "custom", "first",
            "built")
#: the run's warm cache folder (set by main; see the module docstring)
WARM: dict[str, str] = {}


def _env(**extra: str) -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO)  # this checkout's fgopt, whatever is installed
    # a user's install has bytecode (pip compiles at install): let the checkout get its .pyc
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    for var in ("OMP_NUM_THREADS", "OMP_THREAD_LIMIT", "OPENBLAS_NUM_THREADS",
                "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
        env.setdefault(var, "1")
    env.update(WARM)
    env.update(extra)
    return env


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


#: CPU seconds (user + system) of the last process :func:`run` waited for: on a loaded machine
#: a process's wall time is mostly waiting for a core, its CPU time is not
LAST_CPU = [0.0]


def run(cmd: list[str], env: dict, cwd: Path | None = None) -> tuple[float, str]:
    """Wall seconds of one new process, and its stdout (raises on failure)."""
    cpu, t = _children_cpu(), time.perf_counter()
    p = subprocess.run(cmd, env=env, cwd=cwd or REPO, capture_output=True, text=True)
    dt = time.perf_counter() - t
    LAST_CPU[0] = _children_cpu() - cpu
    if p.returncode not in (0, 1):  # fgopt solve exits 1 when not converged: still a result
        raise RuntimeError(f"{' '.join(map(str, cmd))} failed:\n{p.stdout[-2000:]}\n"
                           f"{p.stderr[-3000:]}")
    return dt, p.stdout


def interleaved(cmds: dict[str, tuple[list[str], dict]], repeats: int) -> dict[str, dict]:
    """Run every command ``repeats`` times, round robin; median and samples per name (wall
    seconds; ``cpu``: the CPU seconds of the same processes)."""
    samples: dict[str, list[float]] = {k: [] for k in cmds}
    cpu: dict[str, list[float]] = {k: [] for k in cmds}
    outs: dict[str, str] = {}
    for _ in range(repeats):
        for name, (cmd, env) in cmds.items():
            dt, out = run(cmd, env)
            samples[name].append(dt)
            cpu[name].append(LAST_CPU[0])
            outs[name] = out
    return {k: {"median": statistics.median(v), "samples": v, "cpu": statistics.median(cpu[k]),
                "cpu samples": cpu[k], "stdout": outs[k][-400:]} for k, v in samples.items()}


def section_import(results: dict, args) -> None:
    # numba's import alone: every process that runs a numba kernel pays it (fgopt loads cached
    # machine code without numba's lowering registries, so the import is the whole floor)
    probe = ([PY, "-c", "import numba"], _env())
    cmds = {"python": ([PY, "-c", "pass"], _env()),
            "numba floor": probe,
            "fgopt": ([PY, "-c", "import fgopt"], _env()),
            "gtsam": ([PY, "-c", "import gtsam"], _env()),
            "fgopt modules loaded": ([PY, "-c", "import sys, fgopt; print(sorted(m for m in "
                                      "('numba', 'scipy', 'sympy', 'numpy', 'llvmlite') "
                                      "if m in sys.modules))"], _env())}
    results["import"] = interleaved(cmds, args.repeats)


def section_tiny(results: dict, args) -> None:
    for dim in ("2d", "3d"):
        cmds = {lib: ([PY, str(SCRIPTS / f"tiny{dim}_{lib}.py")], _env())
                for lib in ("fgopt", "gtsam")}
        run(cmds["fgopt"][0], cmds["fgopt"][1])  # warm the caches (the warm-cache target)
        results[f"tiny {dim}"] = interleaved(cmds, args.repeats)


def section_solve(results: dict, args, out_dir: Path) -> None:
    for name, path in FILES.items():
        if not path.is_file():
            results[f"solve {name}"] = {"skipped": f"{path} is absent"}
            continue
        suffix = "".join(path.suffixes)
        cmds = {"fgopt": ([PY, "-m", "fgopt.cli", "solve", str(path), "--out",
                           str(out_dir / f"fgopt_{name}{suffix}"), "--quiet"], _env()),
                "gtsam": ([PY, str(SCRIPTS / "gtsam_solve.py"), str(path),
                           str(out_dir / f"gtsam_{name}{suffix}")], _env())}
        run(cmds["fgopt"][0], cmds["fgopt"][1])  # warm the caches
        reps = args.ba_repeats if name == "Ladybug-49" else args.repeats
        results[f"solve {name}"] = interleaved(cmds, reps)


def section_overheads(results: dict, args) -> None:
    for name, path in FILES.items():
        if not path.is_file():
            continue
        row = {}
        run([PY, str(SCRIPTS / "overheads_fgopt.py"), str(path)], _env())  # warm the caches
        for lib in ("fgopt", "gtsam"):
            per = []
            for _ in range(args.overhead_repeats):
                _, out = run([PY, str(SCRIPTS / f"overheads_{lib}.py"), str(path)], _env())
                per.append(json.loads(out.strip().splitlines()[-1]))
            row[lib] = {k: statistics.median([p[k] for p in per]) if isinstance(per[0][k], float)
                        else per[0][k] for k in per[0]}
        results[f"overheads {name}"] = row


def section_cold(results: dict, args, out_dir: Path) -> None:
    def cold_env() -> dict:
        root = Path(tempfile.mkdtemp(prefix="fgopt-cold-"))
        return _env(FGOPT_CACHE_DIR=str(root / "fgopt"), NUMBA_CACHE_DIR=str(root / "numba"))

    demo_g2o = out_dir / "demo_manhattan3500.g2o"
    run([PY, "-c", "from fgopt.datasets import manhattan_2d; from fgopt.io import write_g2o; "
         "d = manhattan_2d(3500, seed=0); "
         f"write_g2o({str(demo_g2o)!r}, d.graph, d.initial)"], _env())
    jobs = {"M3500": ([PY, "-m", "fgopt.cli", "solve", str(FILES["M3500"]), "--out",
                       str(out_dir / "cold_M3500.g2o"), "--quiet"], str(FILES["M3500"])),
            "sphere2500": ([PY, "-m", "fgopt.cli", "solve", str(FILES["sphere2500"]), "--out",
                            str(out_dir / "cold_sphere2500.g2o"), "--quiet"],
                           str(FILES["sphere2500"])),
            "demo": ([PY, "-m", "fgopt.demo"], str(demo_g2o))}
    for name, (cmd, gtsam_file) in jobs.items():
        fg = []
        for _ in range(args.cold_repeats):
            dt, out = run(cmd, cold_env())
            fg.append(dt)
        gt = [run([PY, str(SCRIPTS / "gtsam_solve.py"), gtsam_file,
                   str(out_dir / f"gtsam_cold_{name}.g2o")], _env())[0]
              for _ in range(args.cold_repeats)]
        results[f"empty caches {name}"] = {
            "fgopt": {"median": statistics.median(fg), "samples": fg, "stdout": out[-600:]},
            "gtsam": {"median": statistics.median(gt), "samples": gt}}


def section_custom(results: dict, args) -> None:
    for kind in ("range_bearing", "pose3_between"):
        root = Path(tempfile.mkdtemp(prefix="fgopt-custom-"))
        script = str(SCRIPTS / "custom_factor.py")
        rows: dict[str, list] = {"cold": [], "warm": [], "edited": [], "gtsam": []}
        for r in range(args.cold_repeats):
            env = _env(FGOPT_CACHE_DIR=str(root / f"cache{r}"))
            rows["cold"].append(json.loads(run([PY, script, kind, f"{r}"], env)[1]))
            for _ in range(args.repeats if r == 0 else 0):
                rows["warm"].append(json.loads(run([PY, script, kind, f"{r}"], env)[1]))
            rows["edited"].append(json.loads(run([PY, script, kind, f"{r + 1000}"], env)[1]))
        for _ in range(args.repeats):
            rows["gtsam"].append(json.loads(run([PY, str(SCRIPTS / "custom_factor_gtsam.py"),
                                                 kind], _env())[1]))
        results[f"custom {kind}"] = {
            k: {"median": statistics.median(x["definition to result"] for x in v),
                "samples": v} for k, v in rows.items()}


# ----------------------------------------------------------------------------------- report
def render(results: dict, meta: dict) -> str:
    """The run's markdown: the README's two start-up tables (the one renderer of
    :mod:`benchmarks.render_misc`, so the results file and the README read alike)."""
    from .render_misc import startup, startup_first_use, startup_overheads

    doc = {"results": {"meta": meta, "results": results}}
    lines = [f"# Start-up benchmark ({meta['date']}, commit `{meta['commit']}`)", "",
             f"`{meta['command']}`; {meta['machine']}; load average at start {meta['load']}.",
             "Seconds, wall clock of new processes, median of the samples.", "", startup(doc)]
    if any(k.startswith(("first use ", "built first use ")) for k in results):
        lines += ["", "First use:", "", startup_first_use(doc)]
    if any(k.startswith("overheads ") for k in results):
        lines += ["", "Per-process overheads (inside one process):", "", startup_overheads(doc)]
    if "import" in results:
        lines += ["", f"`python -c pass`: {results['import']['python']['median']:.2f} s; modules "
                  f"loaded by `import fgopt`: {results['import']['fgopt modules loaded']['stdout'].strip()}"]
    return "\n".join(lines) + "\n"


# What the README table's timings include and how runs stop (benchmarks/tables.py).
TABLE_PROTOCOL = {
    "includes": ("wall clock of a new process per sample for both libraries: interpreter start, "
        "imports, reading, solving and writing included."),
    "stopping": ("`fgopt solve` and the GTSAM script (`startup_scripts/gtsam_solve.py`) each use their "
        "library's default LM stopping rules (GTSAM at most 100 iterations); the stopping "
        "column says how each run ended."),
}


def _commit() -> str:
    """This checkout's short HEAD, ``+dirty`` when fgopt's or the benchmark's files differ."""
    git = ["git", "-C", str(REPO)]
    head = subprocess.run(git + ["rev-parse", "--short", "HEAD"], capture_output=True,
                          text=True).stdout.strip()
    dirty = subprocess.run(git + ["status", "--porcelain", "--", "fgopt", "benchmarks",
                                  ":(exclude)benchmarks/results"], capture_output=True,
                           text=True).stdout.strip()
    return head + ("+dirty" if dirty else "")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", default=",".join(SECTIONS), help=f"sections: {','.join(SECTIONS)}")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--ba-repeats", type=int, default=3)
    ap.add_argument("--cold-repeats", type=int, default=1)
    ap.add_argument("--overhead-repeats", type=int, default=3)
    ap.add_argument("--files", default="",
                    help=f"solve and first-use files (default all: {','.join(FILES)})")
    ap.add_argument("--warm-cache", default="",
                    help="folder of the warm caches (default: a new one, warmed by this run)")
    ap.add_argument("--first-jobs", default="",
                    help="first-use jobs whose name contains one of these (comma list)")
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results"))
    args = ap.parse_args(argv)
    only = set(args.only.split(","))
    if args.files:
        for name in set(FILES) - set(args.files.split(",")):
            del FILES[name]
    results: dict = {}
    meta = {"date": time.strftime("%Y-%m-%d %H:%M"), "commit": _commit(),
            "command": "python -m benchmarks.startup "
            + " ".join(argv if argv is not None else sys.argv[1:]),
            "machine": f"{os.cpu_count()} cores", "load": os.getloadavg()}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    stem = out / f"startup-{time.strftime('%Y-%m-%d-%H%M')}"
    partial = stem.with_name(stem.name + "-partial.json")
    with tempfile.TemporaryDirectory(prefix="fgopt-startup-") as tmp:
        out_dir = Path(tmp)
        warm = Path(args.warm_cache) if args.warm_cache else out_dir / "warm-cache"
        WARM.update(FGOPT_CACHE_DIR=str(warm / "fgopt"), NUMBA_CACHE_DIR=str(warm / "numba"))
        for name in SECTIONS:
            if name not in only:
                continue
            t = time.perf_counter()
            {"import": lambda: section_import(results, args),
             "tiny": lambda: section_tiny(results, args),
             "solve": lambda: section_solve(results, args, out_dir),
             "overheads": lambda: section_overheads(results, args),
             "cold": lambda: section_cold(results, args, out_dir),
             "custom": lambda: section_custom(results, args),
             "ports": lambda: ports.section_ports(results, args, interleaved, _env),
             "first": lambda: ports.section_first_use(
                 results, args, FILES, out_dir,
                 lambda: partial.write_text(json.dumps({"meta": meta, "results": results})))
             , "built": lambda: ports.section_first_use_built(
                 results, args, FILES, out_dir,
                 lambda: partial.write_text(json.dumps({"meta": meta, "results": results})))
             }[name]()
            print(f"[{name}: {time.perf_counter() - t:.0f} s]", file=sys.stderr, flush=True)
            # sections can take many minutes (cold compiles): keep what is measured so far
            partial.write_text(json.dumps({"meta": meta, "results": results}, indent=1))
    meta["load_end"] = os.getloadavg()
    md = render(results, meta)
    print(md)
    stem.with_suffix(".json").write_text(json.dumps({"meta": meta, "results": results}, indent=1))
    stem.with_suffix(".md").write_text(md)
    partial.unlink(missing_ok=True)  # the glob startup-*.json must find the full document
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
