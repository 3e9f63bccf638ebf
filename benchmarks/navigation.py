"""Inertial navigation, fgopt vs GTSAM in one run: IMU preintegration and the batch
ImuFactorsExample problem.

    .venv/bin/python -m benchmarks.navigation [--repeats 7] [--samples 100000] [--out NAME]

1. **Preintegration** of ``--samples`` IMU samples (random specific force around 1 g and angular
   rates of ~1 rad/s, dt = 5 ms). fgopt: one ``PreintegratedImu.integrate(accel, gyro, dt)`` call
   on arrays (one numba loop). GTSAM's Python API has no batch call, so GTSAM runs
   ``integrateMeasurement`` in a Python loop (its default tangent-space
   ``PreintegratedImuMeasurements``, and ``PreintegratedImuMeasurementsManifold``, the same
   algorithm as fgopt's); the row "GTSAM binding floor" times a loop of ``deltaTij()`` calls
   (the cost of crossing into C++ once per sample, no work) for context.
2. **Batch optimization** of GTSAM's ImuFactorsExample (``../shared/data/navigation/
   imuAndGPSdata.csv``: 101 states, IMU factors between consecutive states, GPS on each, priors on
   the first; :func:`fgopt.io.imu_gps.imu_factors_example`), ImuFactor and CombinedImuFactor
   variants, from the same dead-reckoned initial values. fgopt: ``fgopt.optimize(graph,
   initial)`` with default parameters (includes compiling the problem), and the same LM on an
   already compiled problem; GTSAM: ``LevenbergMarquardtOptimizer(graph, initial,
   LevenbergMarquardtParams()).optimize()`` (default parameters; its graph is built outside the
   timing, as fgopt's).

Protocol: single thread (BLAS/numba thread variables = 1, set before imports); warm-up runs
first (numba compilation); then ``--repeats`` samples, fgopt and GTSAM interleaved, each sample
repeated until it lasts >= 50 ms; the median per run is reported, as wall time and as process CPU
time (the machine is shared: CPU time is less sensitive to load). Ratios are fgopt / GTSAM
(< 1: fgopt faster). Results go to ``benchmarks/results/<out>.json`` and ``.md``.
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
import datetime
import json
import subprocess
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def timed(fn, min_seconds: float = 0.05) -> tuple[float, float]:
    """(wall, cpu) seconds per call of ``fn``, repeating it until ``min_seconds`` of wall time."""
    n, w0, c0 = 0, time.perf_counter(), time.process_time()
    while True:
        fn()
        n += 1
        w = time.perf_counter() - w0
        if w >= min_seconds:
            return w / n, (time.process_time() - c0) / n


def interleaved(fns: dict, repeats: int) -> dict:
    """Median (wall, cpu) per name over ``repeats`` rounds, the functions interleaved."""
    samples = {k: [] for k in fns}
    for _ in range(repeats):
        for k, fn in fns.items():
            samples[k].append(timed(fn))
    return {k: {"wall_s": float(np.median([s[0] for s in v])),
                "cpu_s": float(np.median([s[1] for s in v]))} for k, v in samples.items()}


# ------------------------------------------------------------------------------ preintegration
def preintegration(n: int, repeats: int) -> dict:
    import gtsam

    from fgopt.navigation import PreintegratedImu, PreintegrationParams

    rng = np.random.default_rng(0)
    acc = rng.normal(size=(n, 3)) + np.array([0.0, 0.0, 9.81])
    gyro = rng.normal(size=(n, 3))
    dt = 0.005
    params = PreintegrationParams.make_u(9.81, accel_sigma=0.01, gyro_sigma=1e-3,
                                         integration_sigma=1e-4)
    gp = gtsam.PreintegrationParams.MakeSharedU(9.81)
    gp.setAccelerometerCovariance(1e-4 * np.eye(3))
    gp.setGyroscopeCovariance(1e-6 * np.eye(3))
    gp.setIntegrationCovariance(1e-8 * np.eye(3))

    def fgopt_run():
        return PreintegratedImu(params).integrate(acc, gyro, dt)

    def gtsam_run(cls):
        def run():
            pim = cls(gp)
            for k in range(n):
                pim.integrateMeasurement(acc[k], gyro[k], dt)
            return pim
        return run

    def floor():
        pim = gtsam.PreintegratedImuMeasurements(gp)
        for _ in range(n):
            pim.deltaTij()

    ours = fgopt_run()
    theirs = gtsam_run(gtsam.PreintegratedImuMeasurementsManifold)()
    check = {"max_abs_dp_vs_gtsam_manifold": float(np.abs(ours.delta_p - theirs.deltaPij()).max()),
             "max_abs_cov_vs_gtsam_manifold":
                 float(np.abs(ours.covariance - theirs.preintMeasCov()).max())}
    t = interleaved({"fgopt": fgopt_run,
                     "gtsam": gtsam_run(gtsam.PreintegratedImuMeasurements),
                     "gtsam_manifold": gtsam_run(gtsam.PreintegratedImuMeasurementsManifold),
                     "gtsam_binding_floor": floor}, repeats)
    return {"samples": n, "times": t, "check": check}


# ------------------------------------------------------------------------------ batch problem
def batch(repeats: int, combined: bool) -> dict:
    import gtsam

    import fgopt
    from benchmarks.peers import gtsam_navigation as GN
    from fgopt.io.imu_gps import B, V, X, imu_factors_example, read_imu_gps_csv
    from fgopt.solvers import LevenbergMarquardt, LMParams

    path = Path(os.environ.get("FGOPT_DATA", ROOT.parent / "shared" / "data"))
    data = read_imu_gps_csv(path / "navigation" / "imuAndGPSdata.csv")
    problem = imu_factors_example(data, combined=combined)
    graph, initial = GN.build(data, problem, combined=combined)
    params = gtsam.LevenbergMarquardtParams()

    def gtsam_run():
        opt = gtsam.LevenbergMarquardtOptimizer(graph, initial, params)
        return opt, opt.optimize()

    def fgopt_run():
        return fgopt.optimize(problem.graph, problem.initial)

    compiled = fgopt.Problem(problem.graph, problem.initial)
    lm = LevenbergMarquardt(LMParams())

    def fgopt_compiled():
        return lm.optimize_problem(compiled)

    ours = fgopt_run()
    opt, theirs = gtsam_run()
    n = problem.num_states
    diff = 0.0
    for k in range(n):
        pose, gpose = ours.values.at(X(k)), theirs.atPose3(X(k))
        diff = max(diff, float(np.abs(pose.translation() - gpose.translation()).max()),
                   float(np.abs(np.asarray(ours.values.at(V(k))) - theirs.atVector(V(k))).max()),
                   float(np.abs(np.asarray(ours.values.at(B(k)))
                                - theirs.atConstantBias(B(k)).vector()).max()))
    t = interleaved({"fgopt": fgopt_run, "fgopt_compiled": fgopt_compiled,
                     "gtsam": gtsam_run}, repeats)
    return {"factor": "CombinedImuFactor" if combined else "ImuFactor", "states": n,
            "factors": len(problem.graph), "times": t,
            "fgopt_iterations": ours.iterations, "gtsam_iterations": opt.iterations(),
            "fgopt_final_cost": ours.final_cost, "gtsam_final_error": graph.error(theirs),
            "initial_cost": ours.initial_cost, "max_abs_state_difference": diff,
            "linear_solver": ours.linear_solver}


# ------------------------------------------------------------------------------ report
def render(res: dict) -> str:
    lines = [f"# Navigation benchmark ({res['date']}, fgopt {res['fgopt_commit']}, "
             f"gtsam {res['gtsam_version']}, load {res['loadavg']})", ""]
    p = res["preintegration"]
    t = p["times"]
    g = t["gtsam"]
    lines += [f"## Preintegrating {p['samples']} samples (seconds; ratio = fgopt / GTSAM)", "",
              "| | wall | CPU | ratio (wall) | ratio (CPU) |", "|---|---|---|---|---|"]
    for k, label in (("fgopt", "fgopt (arrays, numba loop)"),
                     ("gtsam", "GTSAM PreintegratedImuMeasurements (Python loop)"),
                     ("gtsam_manifold", "GTSAM ...Manifold (Python loop)"),
                     ("gtsam_binding_floor", "GTSAM binding floor (no-op call per sample)")):
        v = t[k]
        lines.append(f"| {label} | {v['wall_s']:.4f} | {v['cpu_s']:.4f} | "
                     f"{v['wall_s'] / g['wall_s']:.2f} | {v['cpu_s'] / g['cpu_s']:.2f} |")
    lines += ["", f"fgopt vs GTSAM manifold preintegration: max |dp| difference "
              f"{p['check']['max_abs_dp_vs_gtsam_manifold']:.2e}, covariance "
              f"{p['check']['max_abs_cov_vs_gtsam_manifold']:.2e}", ""]
    for b in res["batch"]:
        t = b["times"]
        g = t["gtsam"]
        lines += [f"## ImuFactorsExample, {b['factor']} ({b['states']} states, {b['factors']} "
                  "factors; milliseconds; ratio = fgopt / GTSAM)", "",
                  "| | wall | CPU | ratio (wall) | ratio (CPU) | iterations | final cost |",
                  "|---|---|---|---|---|---|---|"]
        for k, label, its, cost in (
                ("fgopt", "fgopt.optimize (compile + LM)", b["fgopt_iterations"],
                 b["fgopt_final_cost"]),
                ("fgopt_compiled", "fgopt LM on a compiled problem", b["fgopt_iterations"],
                 b["fgopt_final_cost"]),
                ("gtsam", "GTSAM LevenbergMarquardtOptimizer", b["gtsam_iterations"],
                 b["gtsam_final_error"])):
            v = t[k]
            lines.append(f"| {label} | {1e3 * v['wall_s']:.2f} | {1e3 * v['cpu_s']:.2f} | "
                         f"{v['wall_s'] / g['wall_s']:.2f} | {v['cpu_s'] / g['cpu_s']:.2f} | "
                         f"{its} | {cost:.6f} |")
        lines += ["", f"Initial cost {b['initial_cost']:.6g}; largest state difference fgopt vs "
                  f"GTSAM {b['max_abs_state_difference']:.2e}; fgopt linear solver "
                  f"{b['linear_solver']}.", ""]
    return "\n".join(lines)


# What the README table's timings include and how runs stop (benchmarks/tables.py).
TABLE_PROTOCOL = {
    "includes": ("process CPU time, median; the factor graph is built outside the timing for both "
        "libraries; `fgopt.optimize` includes compiling the problem and GTSAM's time includes "
        "constructing its optimizer; the \"compiled\" rows exclude fgopt's setup only (stated "
        "in the row)."),
    "stopping": ("each library's default LM parameters and stopping rules (iterations in the last "
        "column)."),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--samples", type=int, default=100_000)
    ap.add_argument("--out", default=f"navigation-{datetime.date.today().isoformat()}")
    args = ap.parse_args()
    import gtsam  # noqa: F401  (fail early when the peer is missing)
    import importlib.metadata as md

    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                            text=True, cwd=ROOT, check=False).stdout.strip()
    res = {"date": datetime.datetime.now().isoformat(timespec="minutes"),
           "fgopt_commit": commit, "gtsam_version": md.version("gtsam"),
           "loadavg": "%.2f %.2f %.2f" % os.getloadavg(), "repeats": args.repeats,
           "preintegration": preintegration(args.samples, args.repeats),
           "batch": [batch(args.repeats, False), batch(args.repeats, True)]}
    res["loadavg_end"] = "%.2f %.2f %.2f" % os.getloadavg()
    text = render(res)
    print(text)
    out = ROOT / "benchmarks" / "results"
    out.mkdir(exist_ok=True)
    (out / f"{args.out}.json").write_text(json.dumps(res, indent=1))
    (out / f"{args.out}.md").write_text(text + "\n")


if __name__ == "__main__":
    main()
