"""C++ Ceres (Debian libceres-dev 2.1.0) through the benchmark-only program
``benchmarks/ceres_cpp/ceres_bench`` (build it with ``bash benchmarks/ceres_cpp/build.sh``).

AutoDiff costs with the residuals of Ceres' examples (as the pyceres runner's Python callbacks),
``num_threads = 1``. The program times itself (parse + problem build = load; one warm-up solve,
then ``repeats`` solves, median) and writes its final estimate for the yardstick, so the worker
calls :meth:`run_self_timed` instead of load/solve.
"""

from __future__ import annotations

import json
import subprocess
import tempfile
from pathlib import Path

import numpy as np

BINARY = Path(__file__).resolve().parent.parent / "ceres_cpp" / "ceres_bench"


class CeresCppRunner:
    name = "ceres_cpp"
    pinning = "Solver::Options::num_threads = 1"
    note = "C++ AutoDiff costs, benchmark-only program"
    self_timed = True

    def version(self) -> str:
        return "Ceres C++ (libceres-dev)" if BINARY.exists() else "not built"

    def supports(self, spec) -> str | None:
        if not BINARY.exists():
            return "benchmarks/ceres_cpp/ceres_bench not built (bash benchmarks/ceres_cpp/build.sh)"
        if spec.kind not in ("pose2d", "pose3d", "bal"):
            return "only g2o and BAL files"
        return None

    def run_self_timed(self, spec, mode: str, repeats: int) -> dict:
        with tempfile.TemporaryDirectory() as tmp:
            est_path = Path(tmp) / "estimate.txt"
            proc = subprocess.run([str(BINARY), spec.kind, str(spec.path), mode, str(repeats),
                                   str(est_path)], capture_output=True, text=True, check=True)
            rec = json.loads(proc.stdout.strip().splitlines()[-1])
            lines = est_path.read_text().split("\n")
        if spec.kind == "bal":
            with open(spec.path) as fh:
                nc = int(fh.readline().split()[0])
            rows = [np.array(ln.split(), dtype=float) for ln in lines if ln.strip()]
            est = {"cameras": np.array(rows[:nc]), "points": np.array(rows[nc:])}
            return self._rec(rec, est)
        rows = np.array([ln.split() for ln in lines if ln.strip()], dtype=float)
        if spec.kind == "pose3d":
            q = rows[:, 3:7] / np.linalg.norm(rows[:, 3:7], axis=1, keepdims=True)
            est = {"poses": np.concatenate([rows[:, :3], q], 1)}
        else:
            est = {"poses": rows}
        return self._rec(rec, est)

    @staticmethod
    def _rec(rec, est):
        return {"load_s": rec["load_s"], "solve_s": rec["solve_s"],
                "solve_samples": rec["samples"], "iterations": rec["iterations"],
                "lib_initial_cost": rec["initial_cost"], "lib_final_cost": rec["final_cost"],
                "lib_status": rec["termination"], "version": "Ceres " + rec.get("ceres", "?"),
                "extra": {"linear_solver_s": rec.get("linear_solver_s"),
                          "repaired_information": rec.get("repaired_information")},
                "estimate": est}


RUNNER = CeresCppRunner()
