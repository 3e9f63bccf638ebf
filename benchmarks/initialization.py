"""Final cost from the file's initial guess vs from the chordal relaxation, on every pose graph.

    python -m benchmarks.initialization [--files pose3d/torus3D.g2o,...] [--out FILE.md]

For each g2o / TORO pose graph in the shared data folder: LM to convergence with fgopt's defaults
from the file's own initial guess (odometry chaining for files without vertices, as the reader
does), and from ``fgopt.chordal_initialization`` (``initialization="chordal"``); and GTSAM's LM
with its defaults from the file's guess, in the same run. Costs are 0.5 * sum of squared whitened
residuals of the file's edges (GTSAM's ``graph.error``; fgopt's between residual is GTSAM's
``Log(m^-1 a^-1 b)``), gauge by a tight prior on the first pose in both libraries.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_v] = "1"
# Warm-process figures: small batches on the compiled kernels from the first timed call (a
# process reaches this after 0.5 s of NumPy-twin work; see fgopt/_jit.py).
os.environ.setdefault("FGOPT_NUMPY_BUDGET", "0")

import argparse  # noqa: E402
import datetime as dt  # noqa: E402
import subprocess  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

FILES = ["pose2d/input_M3500_g2o.g2o", "pose2d/manhattan.g2o", "pose2d/intel.g2o",
         "pose2d/FR079_P_toro.graph", "pose2d/w20000.txt", "pose3d/sphere2500.g2o",
         "pose3d/parking-garage.g2o", "pose3d/torus3D.g2o", "pose3d/cubicle.g2o",
         "pose3d/smallGrid3D.g2o", "small/pose3example-grid.txt", "small/w100.graph"]


def data_dir() -> Path:
    return Path(os.environ.get("FGOPT_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))


def fgopt_runs(path: Path) -> dict:
    import fgopt

    graph, initial = fgopt.io.read(str(path), repair_information="clip")
    problem = graph.copy()
    fgopt.io.add_gauge_prior(problem, initial)
    out = {"initial_cost": graph.error(initial)}
    for init in ("given", "chordal"):
        t0 = time.perf_counter()
        r = fgopt.optimize(problem, initial, initialization=init, max_iterations=300)
        out[init] = {"cost": graph.error(r.values), "iterations": r.iterations,
                     "status": r.status.value, "seconds": time.perf_counter() - t0}
    return out


def gtsam_run(path: Path) -> dict:
    try:
        import gtsam
    except ImportError:
        return {"error": "gtsam not installed"}
    is3d = "pose3d" in str(path) or "pose3example" in str(path)
    try:
        if is3d or str(path).endswith(".g2o"):
            graph, initial = gtsam.readG2o(str(path), is3d)
        else:  # TORO / GTSAM EDGE2 files: GTSAM's own reader guesses their noise layout
            graph, initial = gtsam.load2D(str(path))
    except Exception as exc:  # TORO files without VERTEX lines etc.
        return {"error": f"readG2o: {exc}"}
    if initial.size() == 0:
        return {"error": "no initial guess in the file"}
    cost_graph = gtsam.NonlinearFactorGraph(graph)
    first = min(initial.keys())
    if is3d:
        graph.add(gtsam.PriorFactorPose3(first, initial.atPose3(first),
                                         gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
    else:
        graph.add(gtsam.PriorFactorPose2(first, initial.atPose2(first),
                                         gtsam.noiseModel.Isotropic.Sigma(3, 1e-6)))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(300)
    t0 = time.perf_counter()
    opt = gtsam.LevenbergMarquardtOptimizer(graph, initial, params)
    res = opt.optimize()
    return {"cost": cost_graph.error(res), "iterations": opt.iterations(),
            "seconds": time.perf_counter() - t0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--files", default=",".join(FILES))
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                            text=True, cwd=Path(__file__).parent).stdout.strip()
    lines = [f"# Final cost: file's guess vs chordal initialization (commit {commit})", "",
             f"`python -m benchmarks.initialization`; LM to convergence (limit 300 iterations), "
             f"seconds include chordal initialization; load average {os.getloadavg()[0]:.1f} "
             "at the start.", "",
             "| file | initial cost | fgopt from file's guess | fgopt from chordal | GTSAM from "
             "file's guess |", "|---|---|---|---|---|"]
    for rel in args.files.split(","):
        path = data_dir() / rel
        if not path.is_file():
            continue
        f = fgopt_runs(path)
        g = gtsam_run(path)

        def cell(r):
            if "error" in r:
                return r["error"]
            return f"{r['cost']:.6g} ({r['iterations']} it, {r['seconds']:.2f} s)"

        lines.append(f"| {rel} | {f['initial_cost']:.4g} | {cell(f['given'])} | "
                     f"{cell(f['chordal'])} | {cell(g)} |")
        print(lines[-1], flush=True)
    md = "\n".join(lines) + "\n"
    out = args.out or str(Path(__file__).parent / "results" / f"initialization-{dt.date.today()}.md")
    Path(out).write_text(md)
    print(md)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
