"""Compile time per numba function on first use (empty caches), largest first (issue 41).

Every scenario runs in a NEW process with an empty kernel cache (``FGOPT_CACHE_DIR``) and an
empty numba cache (``NUMBA_CACHE_DIR``), as on a fresh install, then once more with the caches
it filled (warm). numba's ``numba:compile`` events give each compiled function's wall time; a
function compiled while another one is being typed (a kernel calling a kernel) is subtracted from
its caller, so the ``self`` column adds up to the process's total compile time. In the warm run
the time numba spends loading cached entries is counted per function instead. Times are CPU
seconds of the (single-threaded) compile, so a loaded machine inflates them less than wall time;
the process columns give both.

Scenarios (``--only`` takes a comma-separated subset):

* ``g2o-2d`` / ``g2o-3d`` / ``bal``: ``fgopt solve FILE`` on M3500, sphere2500, Ladybug-49;
* ``imu``: GTSAM's ImuFactorsExample (``fgopt.io.imu_gps.imu_factors_example``), LM;
* ``custom-factor``: ``startup_scripts/custom_factor.py pose3_between`` (a new 20-factor-class
  Pose3 ``@fgopt.factor``, definition to result);
* ``custom-manifold``: a new ``@fgopt.manifold`` (a sphere) with a factor over it, 40 factors.

    python -m benchmarks.compile_times                   # all scenarios, table on stdout
    python -m benchmarks.compile_times --only custom-factor --top 15 --json out.json
    python -m benchmarks.compile_times --compare before.json after.json   # two checkouts

Children run with ``FGOPT_NUMPY_BUDGET=0``, so every kernel
a solve uses is compiled in the process that is timed (a small problem takes the general path).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("FGOPT_DATA", "/work/shared/data"))

# The recorder: installed before the scenario runs, dumps JSON on exit.
RECORDER = textwrap.dedent('''
    import atexit, json, os, sys, time
    import numba.core.event as _ev
    import numba.core.caching as _caching

    _stack, _rows = [], {}

    def _name(data):
        d = data.get("dispatcher")
        f = getattr(d, "py_func", None)
        if f is None:
            return str(d)
        return f"{f.__module__}.{f.__qualname__}"

    def _row(name):
        return _rows.setdefault(name, {"self": 0.0, "total": 0.0, "compiles": 0,
                                       "load": 0.0, "loads": 0})

    class _L(_ev.Listener):
        def on_start(self, event):
            _stack.append([_name(event.data), time.process_time(), 0.0])

        def on_end(self, event):
            name, t0, children = _stack.pop()
            dt = time.process_time() - t0
            r = _row(name)
            r["self"] += dt - children
            r["total"] += dt
            r["compiles"] += 1
            if _stack:
                _stack[-1][2] += dt

    _ev.register("numba:compile", _L())
    _load = _caching.Cache.load_overload

    def _timed_load(self, sig, target_context):
        t0 = time.process_time()
        out = _load(self, sig, target_context)
        if out is not None:
            r = _row(self._name if hasattr(self, "_name") else str(self))
            r["load"] += time.process_time() - t0
            r["loads"] += 1
        return out

    _caching.Cache.load_overload = _timed_load
    @atexit.register
    def _dump():
        with open(os.environ["COMPILE_TIMES_OUT"], "w") as fh:
            json.dump({"cpu": time.process_time(), "rows": _rows}, fh)
''')

MANIFOLD = textwrap.dedent('''
    import numpy as np
    import fgopt
    from fgopt import key
    from fgopt.noise import Isotropic
    from fgopt.symbolic import V2, V3, Rot3, cos, sin, Matrix, Abs, where

    M32 = Matrix.shaped(3, 2)

    @fgopt.manifold
    class SphereNAME:
        storage_dim = 3
        dim = 2

        def identity():
            return V3(0, 0, 1)

        def point3(x):
            return V3(x[0], x[1], x[2])

        def basis(x):
            p = x.point3()
            ax, ay, az = Abs(p[0]), Abs(p[1]), Abs(p[2])
            hx = where((ax <= ay) & (ax <= az), 1, 0)
            hy = (1 - hx) * where((ay <= ax) & (ay <= az), 1, 0)
            b1 = p.cross(V3(hx, hy, 1 - hx - hy))
            b1 = b1 / b1.norm(0)
            b2 = p.cross(b1)
            return M32([[b1[0], b2[0]], [b1[1], b2[1]], [b1[2], b2[2]]])

        def retract(x, v):
            w = x.basis() * v
            t = w.norm()
            return cos(t) * x.point3() + (sin(t) / t) * w

        def local(x, y):
            p, q = x.point3(), y.point3()
            c = p.dot(q)
            s = p.cross(q).norm()
            theta = fgopt.symbolic.atan2(s, c)
            d = q - c * p
            return (theta / d.norm()) * (x.basis().T * d)

        def normalize(x):
            return x.storage / x.storage.norm(0)

    S = SphereNAME

    @fgopt.factor
    def direction_between(a: S, b: S, b_R_a: Rot3) -> V2:
        return b.local(S(b_R_a * a.point3()))

    rng = np.random.default_rng(0)
    n = 20
    truth = [S.Value(rng.normal(size=3)) for _ in range(n)]
    graph, initial = fgopt.FactorGraph(), fgopt.Variables()
    noise = Isotropic.sigma(2, 0.01)
    for i in range(n):
        for k in (1, 5):
            j = (i + k) % n
            graph.add(direction_between(key("u", i), key("u", j), fgopt.SO3(), loss=noise))
    graph.add(fgopt.PriorFactor(key("u", 0), truth[0], noise))
    for i, t in enumerate(truth):
        initial.add(key("u", i), t.retract(0.1 * rng.normal(size=2)))
    fgopt.optimize(graph, initial)
''')


def _solve(name: str) -> str:
    path = {"g2o-2d": DATA / "pose2d" / "input_M3500_g2o.g2o",
            "g2o-3d": DATA / "pose3d" / "sphere2500.g2o",
            "bal": DATA / "bal" / "problem-49-7776-pre.txt"}[name]
    return (f"from fgopt.cli import main\n"
            f"main(['solve', {str(path)!r}, '--out', '/dev/null', '--quiet'])\n")


SCENARIOS = {
    "g2o-2d": lambda: _solve("g2o-2d"),
    "g2o-3d": lambda: _solve("g2o-3d"),
    "bal": lambda: _solve("bal"),
    "imu": lambda: textwrap.dedent(f'''
        import fgopt
        from fgopt.io.imu_gps import imu_factors_example
        p = imu_factors_example({str(DATA / "navigation" / "imuAndGPSdata.csv")!r})
        fgopt.optimize(p.graph, p.initial)
    '''),
    "custom-factor": lambda: textwrap.dedent(f'''
        import sys
        sys.argv = ["custom_factor.py", "pose3_between", "1"]
        import runpy
        runpy.run_path({str(REPO / "benchmarks" / "startup_scripts" / "custom_factor.py")!r},
                       run_name="__main__")
    '''),
    "custom-manifold": lambda: MANIFOLD.replace("NAME", f"{os.getpid()}"),
}


def run_scenario(name: str, cache: str | None = None) -> dict:
    """Cold (empty caches) then warm process of scenario ``name``; rows per function."""
    out = {}
    with tempfile.TemporaryDirectory(prefix="fgopt-compile-times-") as tmp:
        cache = cache or tmp
        env = dict(os.environ, PYTHONPATH=str(REPO), FGOPT_CACHE_DIR=os.path.join(cache, "fg"),
                   NUMBA_CACHE_DIR=os.path.join(cache, "nb"), FGOPT_NUMPY_BUDGET="0",
                   COMPILE_TIMES_OUT=os.path.join(tmp, "rows.json"))
        env.pop("PYTHONDONTWRITEBYTECODE", None)
        code = RECORDER + SCENARIOS[name]()
        for label in ("cold", "warm"):
            t0 = time.perf_counter()
            p = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                               text=True, cwd=REPO, timeout=3600)
            wall = time.perf_counter() - t0
            if p.returncode != 0:
                raise RuntimeError(f"{name} ({label}) failed:\n{p.stderr[-4000:]}")
            with open(env["COMPILE_TIMES_OUT"]) as fh:
                got = json.load(fh)
            got["process wall"] = wall
            got["stderr"] = p.stderr[-2000:]
            out[label] = got
    return out


def table(results: dict, top: int) -> str:
    """Markdown: per scenario its totals, then the union of functions by cold self time."""
    lines = ["| scenario | cold process CPU s (wall) | compile CPU s | functions compiled | "
             "warm process CPU s (wall) | entries loaded | load CPU s |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    union: dict[str, dict] = {}
    for name, r in results.items():
        cold, warm = r["cold"]["rows"], r["warm"]["rows"]
        lines.append(
            f"| {name} | {r['cold']['cpu']:.2f} ({r['cold']['process wall']:.1f}) | "
            f"{sum(v['self'] for v in cold.values()):.2f} | "
            f"{sum(v['compiles'] for v in cold.values())} | "
            f"{r['warm']['cpu']:.2f} ({r['warm']['process wall']:.1f}) | "
            f"{sum(v['loads'] for v in warm.values())} | "
            f"{sum(v['load'] for v in warm.values()):.2f} |")
        for fn, v in cold.items():
            u = union.setdefault(fn, {"self": 0.0, "compiles": 0, "in": []})
            if v["self"] > u["self"]:
                u["self"], u["compiles"] = v["self"], v["compiles"]
            u["in"].append(name)
    lines += ["", "| function (largest self compile time over the scenarios) | CPU s | signatures | "
              "scenarios |", "|---|---:|---:|---|"]
    for fn, u in sorted(union.items(), key=lambda kv: -kv[1]["self"])[:top]:
        lines.append(f"| `{fn}` | {u['self']:.2f} | {u['compiles']} | {', '.join(u['in'])} |")
    return "\n".join(lines)


def compare(before: dict, after: dict, top: int) -> str:
    """Markdown: per scenario in both runs, compile CPU before / after; then the functions by
    their largest cold self time before, with the same function's time after."""
    lines = ["| scenario | compile CPU s before | after | functions compiled before | after |",
             "|---|---:|---:|---:|---:|"]
    rows: dict[str, list] = {}
    for name in before:
        if name not in after:
            continue
        b, a = before[name]["cold"]["rows"], after[name]["cold"]["rows"]
        lines.append(f"| {name} | {sum(v['self'] for v in b.values()):.2f} | "
                     f"{sum(v['self'] for v in a.values()):.2f} | "
                     f"{sum(v['compiles'] for v in b.values())} | "
                     f"{sum(v['compiles'] for v in a.values())} |")
        for fn, v in b.items():
            r = rows.setdefault(_generic(fn), [0.0, 0.0])
            r[0] = max(r[0], v["self"])
        for fn, v in a.items():
            r = rows.setdefault(_generic(fn), [0.0, 0.0])
            r[1] = max(r[1], v["self"])
    lines += ["", "| function | cold compile CPU s before | after |", "|---|---:|---:|"]
    for fn, (b, a) in sorted(rows.items(), key=lambda kv: -max(kv[1]))[:top]:
        lines.append(f"| `{fn}` | {b:.2f} | {a:.2f} |")
    return "\n".join(lines)


def _generic(fn: str) -> str:
    """A generated kernel's name without its cache key (the key changes with the generator)."""
    head, _, tail = fn.partition(".")
    if head.startswith("fgk_"):
        return head.rsplit("_", 1)[0] + "." + tail
    return fn


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", default=",".join(SCENARIOS))
    ap.add_argument("--top", type=int, default=25)
    ap.add_argument("--json", default=None)
    ap.add_argument("--table", default=None, help="only print the table of this --json file")
    ap.add_argument("--compare", nargs=2, metavar=("BEFORE", "AFTER"), default=None,
                    help="only print the before/after table of two --json files")
    args = ap.parse_args()
    if args.compare:
        b, a = (json.loads(Path(f).read_text()) for f in args.compare)
        print(compare(b, a, args.top))
        return
    if args.table:
        print(table(json.loads(Path(args.table).read_text()), args.top))
        return
    results = {}
    for name in args.only.split(","):
        results[name] = run_scenario(name)
        print(f"{name}: cold {results[name]['cold']['process wall']:.1f} s, warm "
              f"{results[name]['warm']['process wall']:.1f} s", file=sys.stderr, flush=True)
        if args.json:  # after every scenario: a long run leaves what it measured
            Path(args.json).write_text(json.dumps(results, indent=1))
    print(table(results, args.top))


if __name__ == "__main__":
    main()
