"""Final cost on every pose graph: fgopt's default vs its fixed starts vs GTSAM and C++ Ceres.

    python -m benchmarks.initialization [--files pose3d/torus3D.g2o,...] [--no-extra] [--out F.md]

For each g2o / TORO pose graph of the shared data folder (and of ``benchmarks.extra_data``'s
folder when present): fgopt to convergence with its defaults (``initialization="auto"``, see
:mod:`fgopt.solvers.initialization`), from the file's guess only (``"given"``, GTSAM's
behaviour) and from the chordal relaxation only (``"chordal"``); GTSAM's LM with its defaults
from the file's guess; C++ Ceres (``benchmarks/ceres_cpp/ceres_bench``, its defaults for pose
graphs: 200 iterations) from the file's guess. One cost yardstick: 0.5 * sum of squared whitened
residuals of the file's edges with GTSAM's residuals: every library's estimate is evaluated by
fgopt's ``graph.error`` over the file's edges as ``fgopt.io.read`` reads them (equal to GTSAM's
``graph.error`` where GTSAM reads the file alike), no gauge prior.
Files without an initial guess get the reader's odometry-chained guess in fgopt (GTSAM and
Ceres need vertices). Times are CPU seconds of this process (fgopt, GTSAM) or of the Ceres
program's solve (wall, single thread); a shared machine inflates them.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OMP_THREAD_LIMIT", "OPENBLAS_NUM_THREADS",
           "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_v] = "1"
# Warm-process figures: small batches on the compiled kernels from the first timed call (a
# process reaches this after 0.5 s of NumPy-twin work; see fgopt/_jit.py).
os.environ.setdefault("FGOPT_NUMPY_BUDGET", "0")

import argparse  # noqa: E402
import datetime as dt  # noqa: E402
import json  # noqa: E402
import subprocess  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

FILES = ["pose2d/input_M3500_g2o.g2o", "pose2d/manhattan.g2o", "pose2d/intel.g2o",
         "pose2d/FR079_P_toro.graph", "pose2d/w20000.txt", "pose3d/sphere2500.g2o",
         "pose3d/parking-garage.g2o", "pose3d/torus3D.g2o", "pose3d/cubicle.g2o",
         "pose3d/smallGrid3D.g2o", "small/pose3example-grid.txt", "small/w100.graph",
         "small/pose2example.txt"]
SLACK = 1e-6  # the relative slack


def data_dir() -> Path:
    return Path(os.environ.get("FGOPT_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))


def extra_files() -> list[str]:
    from .extra_data import FILES as EXTRA, extra_dir

    return [str(extra_dir() / f.name) for f in EXTRA if (extra_dir() / f.name).exists()]


def fgopt_runs(path: Path) -> tuple[dict, object, object]:
    import fgopt

    graph, initial = fgopt.io.read(str(path), repair_information="clip")
    problem = graph.copy()
    fgopt.io.add_gauge_prior(problem, initial)
    out = {"initial_cost": graph.error(initial), "poses": len(initial),
           "is3d": any(b.kernel.name.endswith("pose3") for b in graph.batches)}
    for init in ("auto", "given", "chordal"):
        t0 = time.process_time()
        r = fgopt.optimize(problem, initial, initialization=init)
        out[init] = {"cost": graph.error(r.values), "iterations": r.iterations,
                     "iterations_all": r.info.get("iterations_all_starts", r.iterations),
                     "status": r.status.value, "seconds": time.process_time() - t0,
                     "start": r.info.get("initialization")}
    return out, graph, initial


def _values_from_rows(initial, rows: np.ndarray, ids: np.ndarray, is3d: bool):
    """A peer's estimate (rows x y theta / x y z qx qy qz qw by vertex id) as fgopt values."""
    from fgopt import SE2, SE3, key

    out = initial.copy()
    for i, row in zip(ids.tolist(), rows):
        k = key("x", i)
        if is3d:
            q = row[3:7] / np.linalg.norm(row[3:7])
            out.update(k, SE3.from_storage(np.concatenate([q, row[:3]])))
        else:
            out.update(k, SE2.from_xytheta(*row[:3]))
    return out


def gtsam_run(path: Path, is3d: bool, graph_f, initial_f) -> dict:
    """GTSAM's LM with defaults; cost of its estimate on fgopt's reading of the file (equal to
    GTSAM's own ``graph.error`` where both read the file alike; cubicle's non-PD information
    and GTSAM's guesses at TORO noise layouts differ, so one yardstick for all)."""
    try:
        import gtsam
    except ImportError:
        return {"error": "gtsam not installed"}
    try:
        if str(path).endswith(".g2o"):
            graph, initial = gtsam.readG2o(str(path), is3d)
        else:  # TORO / GTSAM EDGE2 files: GTSAM's own reader guesses their noise layout
            graph, initial = gtsam.load2D(str(path))
    except Exception as exc:  # noqa: BLE001  (report, keep going)
        return {"error": f"reader: {str(exc)[:60]}"}
    if initial.size() == 0:
        return {"error": "no initial guess in the file"}
    first = min(initial.keys())
    if is3d:
        graph.add(gtsam.PriorFactorPose3(first, initial.atPose3(first),
                                         gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
    else:
        graph.add(gtsam.PriorFactorPose2(first, initial.atPose2(first),
                                         gtsam.noiseModel.Isotropic.Sigma(3, 1e-6)))
    params = gtsam.LevenbergMarquardtParams()
    t0 = time.process_time()
    opt = gtsam.LevenbergMarquardtOptimizer(graph, initial, params)
    res = opt.optimize()
    seconds = time.process_time() - t0
    ids = np.array(sorted(res.keys()), dtype=np.int64)
    if is3d:
        rows = np.array([np.concatenate([p.translation(), _xyzw(p.rotation())])
                         for p in (res.atPose3(int(i)) for i in ids)])
    else:
        rows = np.array([[p.x(), p.y(), p.theta()] for p in (res.atPose2(int(i)) for i in ids)])
    values = _values_from_rows(initial_f, rows, ids, is3d)
    return {"cost": graph_f.error(values), "iterations": opt.iterations(), "seconds": seconds}


def _xyzw(rot) -> np.ndarray:
    q = rot.toQuaternion()
    return np.array([q.x(), q.y(), q.z(), q.w()])


def ceres_run(path: Path, is3d: bool, graph_f, initial_f) -> dict:
    from . import problems
    from .peers.ceres_cpp_runner import BINARY

    if not BINARY.exists():
        return {"error": "ceres_bench not built"}
    try:
        data = problems.read_g2o(path)
    except ValueError as exc:
        return {"error": str(exc).split(": ", 1)[-1][:60]}
    kind = "pose3d" if is3d else "pose2d"
    with tempfile.TemporaryDirectory() as tmp:
        est = Path(tmp) / "est.txt"
        proc = subprocess.run([str(BINARY), kind, str(path), "converge", "1", str(est)],
                              capture_output=True, text=True)
        if proc.returncode != 0:
            return {"error": proc.stderr.strip()[-60:]}
        rec = json.loads(proc.stdout.strip().splitlines()[-1])
        rows = np.loadtxt(est, ndmin=2)
    values = _values_from_rows(initial_f, rows, data.ids, is3d)
    return {"cost": graph_f.error(values), "iterations": rec["iterations"],
            "seconds": rec.get("solve_cpu_s", rec["solve_s"]), "status": rec["termination"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--files", default=None, help="comma list (relative to FGOPT_DATA or absolute)")
    ap.add_argument("--no-extra", action="store_true", help="skip benchmarks.extra_data's files")
    ap.add_argument("--no-peers", action="store_true")
    ap.add_argument("--out", default=None)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    files = args.files.split(",") if args.files else FILES + ([] if args.no_extra
                                                             else extra_files())
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                            text=True, cwd=Path(__file__).parent).stdout.strip()
    lines = [f"# Final cost on every pose graph (commit {commit}, {dt.date.today()})", "",
             "`python -m benchmarks.initialization`: each library to convergence with its "
             "defaults; cost = 0.5 Σ squared whitened residuals of the file's edges "
             "(GTSAM's residuals), no prior; CPU seconds in parentheses with iterations "
             f"(fgopt default: both runs when it ran two); load average "
             f"{os.getloadavg()[0]:.1f} at the start.", "",
             "| file | poses | initial | fgopt default (start) | fgopt given | fgopt chordal | "
             "GTSAM | Ceres C++ | default ≤ best peer |", "|---|---|---|---|---|---|---|---|---|"]
    records = []
    for rel in files:
        path = data_dir() / rel
        if not path.is_file():
            continue
        f, graph_f, initial_f = fgopt_runs(path)
        g = c = {"error": "--no-peers"}
        if not args.no_peers:
            g = gtsam_run(path, f["is3d"], graph_f, initial_f)
            c = ceres_run(path, f["is3d"], graph_f, initial_f)
        records.append({"file": rel, "fgopt": f, "gtsam": g, "ceres_cpp": c})

        def cell(r, start=False):
            if "error" in r:
                return r["error"]
            its = r.get("iterations_all", r["iterations"])
            s = f"{r['cost']:.6g} ({its} it, {r['seconds']:.2f} s)"
            return s + (f" {r['start']}" if start else "")

        peers = [r["cost"] for r in (g, c) if "cost" in r]
        if peers:
            best = min(peers)
            ok = "yes" if f["auto"]["cost"] <= best * (1 + SLACK) else \
                f"**no** ({f['auto']['cost'] / best - 1:+.2%})"
        else:
            best_start = min(f["given"]["cost"], f["chordal"]["cost"])
            ok = "no peer; " + ("= best start" if f["auto"]["cost"] <= best_start * (1 + SLACK)
                                else "**above best start**")
        lines.append(f"| {Path(rel).name} | {f['poses']} | {f['initial_cost']:.4g} | "
                     f"{cell(f['auto'], True)} | {cell(f['given'])} | {cell(f['chordal'])} | "
                     f"{cell(g)} | {cell(c)} | {ok} |")
        print(lines[-1], flush=True)
    md = "\n".join(lines) + "\n"
    out = args.out or str(Path(__file__).parent / "results" / f"initialization-{dt.date.today()}.md")
    Path(out).write_text(md)
    if args.json:
        Path(args.json).write_text(json.dumps(records, indent=1, default=float))
    print(md)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
