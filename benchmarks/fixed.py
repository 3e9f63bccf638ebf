"""Fixed vs dynamic formulation (SymForce paper, Sec. VIII-C): robot localization, 5 poses, 20 landmarks.

    .venv/bin/python -m benchmarks.fixed [--reps 2000] [--skip-cold] [--json out.json]

Problem: ``benchmarks.problems.robot_localization()`` as built by the fgopt runner (SE2 poses
from the origin, 100 bearing/range factors to known landmarks (``@fgopt.factor``), 4
odometry ``BetweenFactor``\\ s).

* **fixed**: :mod:`fgopt.solvers.fixed` -- ONE generated function for the whole linearization
  (dense 15x15 H, g, cost; CSE across factors; constant terms hoisted), dense LM in numba.
* **dynamic**: ``fgopt.optimize`` / ``LevenbergMarquardt`` (batched generated kernels, sparse
  assembly, linear solver "auto"), from the graph (includes compiling the ``Problem``) and on an
  already compiled ``Problem``.
* **GTSAM** (PyPI wheel): ``LevenbergMarquardtOptimizer``, (a) ``BetweenFactorPose2`` +
  ``BearingRangeFactor2D`` with the landmarks as variables pinned by tight priors (GTSAM has no
  known-landmark bearing-range factor; this is what ``benchmarks/peers/gtsam_runner.py`` does:
  40 extra variables), (b) ``BetweenFactorPose2`` + a Python ``CustomFactor`` for bearing/range to
  a known landmark (the same problem as fgopt's; callback overhead per factor).

"5 it" = exactly 5 LM iterations with every stopping test off; "conv" = default tolerances.
Times are medians over ``--reps`` runs, single-threaded (OMP/OPENBLAS/MKL/NUMBA threads = 1,
set before any import). Cold / warm generation run in fresh processes (cold: empty cache dir).
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OMP_THREAD_LIMIT", "OPENBLAS_NUM_THREADS",
           "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_v] = "1"
# Warm-process figures: small batches on the compiled kernels from the first timed call (a
# process reaches this after 0.5 s of NumPy-twin work; see fgopt/_jit.py).
os.environ.setdefault("FGOPT_NUMPY_BUDGET", "0")

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def median_us(fn, reps: int, warmup: int = 3) -> float:
    for _ in range(warmup):
        fn()
    ts = np.empty(reps)
    for i in range(reps):
        t0 = time.perf_counter_ns()
        fn()
        ts[i] = time.perf_counter_ns() - t0
    return float(np.median(ts)) / 1e3


def five_it_params():
    from fgopt.solvers import LMParams

    return LMParams(max_iterations=5, relative_tolerance=0.0, absolute_tolerance=0.0,
                    gradient_tolerance=0.0, step_tolerance=0.0)


# ------------------------------------------------------------------------------ generation
def _generate_child() -> None:
    """Child process: compile the fixed problem, print timings as JSON."""
    t0 = time.perf_counter()
    from benchmarks.peers.fgopt_runner import _robot_graph
    from fgopt.solvers import fixed as fx

    graph, init = _robot_graph()
    t1 = time.perf_counter()
    fp = fx.compile_fixed(graph, init)
    t2 = time.perf_counter()
    print(json.dumps({"import+graph_s": t1 - t0, "compile_fixed_s": t2 - t1,
                      "source": fp.generation.get("source"),
                      "generation": {k: v for k, v in fp.generation.items()
                                     if isinstance(v, (int, float))},
                      "sympy_imported": "sympy" in sys.modules}))


def generation_times(cache_dir: str | None) -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    if cache_dir is not None:
        env["FGOPT_CACHE_DIR"] = cache_dir
    out = subprocess.run([sys.executable, "-m", "benchmarks.fixed", "--generate-child"],
                         capture_output=True, text=True, env=env, cwd=ROOT, timeout=3600,
                         check=False)
    if out.returncode != 0:
        raise RuntimeError(out.stderr[-3000:])
    return json.loads(out.stdout.strip().splitlines()[-1])


# ------------------------------------------------------------------------------ GTSAM
def gtsam_problems():
    import gtsam
    from gtsam.symbol_shorthand import L, X

    from benchmarks.problems import robot_localization

    p = robot_localization()
    br_noise = gtsam.noiseModel.Diagonal.Sigmas(p.br_sigmas)
    odo_noise = gtsam.noiseModel.Diagonal.Sigmas(p.odom_sigmas)
    # (a) native factors, landmarks as variables pinned by priors (as the gtsam runner)
    ga, va = gtsam.NonlinearFactorGraph(), gtsam.Values()
    lm_noise = gtsam.noiseModel.Isotropic.Sigma(2, 1e-4)
    for j, lm in enumerate(p.landmarks):
        va.insert(L(j), lm.copy())
        ga.add(gtsam.PriorFactorPoint2(L(j), lm.copy(), lm_noise))
    for i, x in enumerate(p.poses):
        va.insert(X(i), gtsam.Pose2(*x))
    for k in range(len(p.br_meas)):
        b, r = p.br_meas[k]
        ga.add(gtsam.BearingRangeFactor2D(X(int(p.br_pose[k])), L(int(p.br_lm[k])),
                                          gtsam.Rot2(b), float(r), br_noise))
    for k, z in enumerate(p.odom_meas):
        ga.add(gtsam.BetweenFactorPose2(X(k), X(k + 1), gtsam.Pose2(*z), odo_noise))
    # (b) CustomFactor: bearing/range to a known landmark (same problem as fgopt's)
    gb, vb = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for i, x in enumerate(p.poses):
        vb.insert(X(i), gtsam.Pose2(*x))

    def make_error(lm, z):
        def error(this, values, H):
            pose = values.atPose2(this.keys()[0])
            c, s = np.cos(pose.theta()), np.sin(pose.theta())
            d = lm - np.array([pose.x(), pose.y()])
            lx, ly = c * d[0] + s * d[1], -s * d[0] + c * d[1]
            b = np.arctan2(ly, lx) - z[0]
            e = np.array([np.arctan2(np.sin(b), np.cos(b)), np.hypot(lx, ly) - z[1]])
            if H is not None:
                r2 = lx * lx + ly * ly
                r = np.sqrt(r2)
                # GTSAM Pose2 tangent (vx, vy, omega), right perturbation
                H[0] = np.array([[ly / r2, -lx / r2, -1.0], [-lx / r, -ly / r, 0.0]])
            return e
        return error

    for k in range(len(p.br_meas)):
        gb.add(gtsam.CustomFactor(br_noise, [X(int(p.br_pose[k]))],
                                  make_error(p.landmarks[p.br_lm[k]].copy(), p.br_meas[k].copy())))
    for k, z in enumerate(p.odom_meas):
        gb.add(gtsam.BetweenFactorPose2(X(k), X(k + 1), gtsam.Pose2(*z), odo_noise))
    return (ga, va), (gb, vb)


def gtsam_times(reps: int) -> dict:
    import gtsam

    out = {}
    (ga, va), (gb, vb) = gtsam_problems()

    def lm(graph, values, five):
        params = gtsam.LevenbergMarquardtParams()
        if five:
            params.setMaxIterations(5)
            params.setRelativeErrorTol(0.0)
            params.setAbsoluteErrorTol(0.0)
            params.setErrorTol(0.0)
        opt = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
        res = opt.optimize()
        return opt, res

    for name, (g, v), r in (("native+pinned landmarks", (ga, va), reps),
                            ("CustomFactor (Python)", (gb, vb), max(20, reps // 10))):
        opt, _ = lm(g, v, False)
        out[name] = {
            "linearize_us": median_us(lambda g=g, v=v: g.linearize(v), r),
            "5it_us": median_us(lambda g=g, v=v: lm(g, v, True), r),
            "conv_us": median_us(lambda g=g, v=v: lm(g, v, False), r),
            "conv_iterations": opt.iterations(),
            "final_error": opt.error(),
        }
    return out


# ------------------------------------------------------------------------------ fgopt
def fgopt_times(reps: int) -> dict:
    import fgopt
    from benchmarks.peers.fgopt_runner import _robot_graph
    from fgopt.solvers import LevenbergMarquardt
    from fgopt.solvers import fixed as fx

    graph, init = _robot_graph()
    fp = fx.compile_fixed(graph, init)
    p5 = five_it_params()
    x0 = fp.flatten(init)
    H, g = np.zeros((fp.size, fp.size)), np.zeros(fp.size)
    prm0 = np.array([0.0, 0, 0, -1.0, 0, 1e-5, 1e-12, 1e12, 1e-6, 1e32, 1e-3, 0, 0, 10.0])
    hist = np.empty((1, 8))
    lm_fn, aux = fp.module._lm, fp._aux

    rf = fp.optimize(init)
    rd = fgopt.optimize(graph, init, method="lm")
    problem = fgopt.Problem(graph, init)
    state = problem.initial_state()
    out = {
        "fixed": {
            "linearize_us": median_us(lambda: lm_fn(x0, aux, prm0, hist, H, g), reps),
            "5it_us": median_us(lambda: fp.optimize(init, params=p5), reps),
            "conv_us": median_us(lambda: fp.optimize(init), reps),
            "from_graph_conv_us": median_us(lambda: fx.optimize_fixed(graph, init), reps // 4),
            "conv_iterations": rf.iterations, "final_cost": rf.final_cost,
        },
        "dynamic": {
            "linearize_us": median_us(lambda: problem.linearize(state), reps),
            "5it_us": median_us(lambda: LevenbergMarquardt(p5).optimize(graph, init),
                                reps // 4),
            "conv_us": median_us(lambda: fgopt.optimize(graph, init, method="lm"), reps // 4),
            "compiled_problem_5it_us": median_us(
                lambda: LevenbergMarquardt(p5).optimize_problem(problem,
                                                                problem.initial_state()),
                reps // 4),
            "conv_iterations": rd.iterations, "final_cost": rd.final_cost,
            "linear_solver": rd.linear_solver,
        },
        "ops": fp.ops,
        "tangent_dim": fp.size,
        "factors": len(graph),
    }
    # op counts of the dynamic kernels (per factor type, generated code)
    kernels = {}
    for f in graph.factors:
        k = f.kernel
        if k.name in kernels:
            kernels[k.name]["count"] += 1
            continue
        ops = None
        for line in k.source.splitlines():
            if line.startswith("# total ops:"):
                ops = line.split(":", 1)[1].strip()
                break
        kernels[k.name] = {"count": 1, "ops": ops}
    out["dynamic_kernels"] = kernels
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--reps", type=int, default=2000)
    ap.add_argument("--skip-cold", action="store_true")
    ap.add_argument("--skip-gtsam", action="store_true")
    ap.add_argument("--json", type=str, default=None)
    ap.add_argument("--generate-child", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.generate_child:
        _generate_child()
        return
    res: dict = {}
    if not a.skip_cold:
        with tempfile.TemporaryDirectory() as d:
            res["generation_cold"] = generation_times(d)
            res["generation_warm"] = generation_times(d)
    res.update(fgopt_times(a.reps))
    if not a.skip_gtsam:
        res["gtsam"] = gtsam_times(max(50, a.reps // 10))
    _print(res)
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=2, default=str))


def _print(res: dict) -> None:
    print("robot localization (5 SE2 poses, 20 known landmarks, 104 factors), single thread")
    for k in ("generation_cold", "generation_warm"):
        if k in res:
            r = res[k]
            print(f"  {k}: compile_fixed {r['compile_fixed_s']:.2f} s ({r['source']}), "
                  f"sympy imported: {r['sympy_imported']}, details {r['generation']}")
    o = res["ops"]
    print(f"  flattened function: {o['linearize']} ops (sympy count_ops after CSE) + "
          f"{o['precompute']} hoisted constant ops; instructions {o['instructions']}")
    print(f"  dynamic kernels: {res['dynamic_kernels']}")
    rows = [("fixed", res["fixed"]), ("dynamic", res["dynamic"])]
    rows += [(f"gtsam {k}", v) for k, v in res.get("gtsam", {}).items()]
    print(f"  {'method':34s} {'linearize':>10s} {'5 it':>10s} {'conv':>10s} {'iters':>6s}"
          "   (µs, median)")
    for name, r in rows:
        print(f"  {name:34s} {r['linearize_us']:10.1f} {r['5it_us']:10.1f} {r['conv_us']:10.1f} "
              f"{r['conv_iterations']:6d}")
    print(f"  fixed from graph (collect + optimize, conv): {res['fixed']['from_graph_conv_us']:.1f}"
          f" µs; dynamic on a compiled Problem, 5 it: "
          f"{res['dynamic']['compiled_problem_5it_us']:.1f} µs")
    print(f"  final cost: fixed {res['fixed']['final_cost']:.9f}, dynamic "
          f"{res['dynamic']['final_cost']:.9f}")


if __name__ == "__main__":
    main()
