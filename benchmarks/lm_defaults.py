"""Iterations of LM with its default ("auto") parameters, one problem per class.

    .venv/bin/python -m benchmarks.lm_defaults [--policies]

Pose graphs (M3500, sphere2500, garage: damping/lambda class "pose"), BA (Ladybug-49: "scaled")
and navigation (GTSAM's ImuFactorsExample with a GPS fix on every state and on every 5th state:
"mixed"). ``--policies`` also runs every damping x lambda-policy pair on each problem (how the
per-class choice of :func:`fgopt.solvers.lm.auto_policy` was measured). Data from
``$FGOPT_DATA`` (default ``../shared/data``). Prints iterations, final cost, status.
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
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def problems(data: Path):
    import fgopt.io
    from fgopt.io.imu_gps import imu_factors_example

    yield "M3500", fgopt.io.read(data / "pose2d" / "input_M3500_g2o.g2o", add_prior=True)
    yield "sphere2500", fgopt.io.read(data / "pose3d" / "sphere2500.g2o", add_prior=True)
    yield "garage", fgopt.io.read(data / "pose3d" / "parking-garage.g2o", add_prior=True)
    yield "Ladybug-49", fgopt.io.read(data / "bal" / "problem-49-7776-pre.txt")
    csv = data / "navigation" / "imuAndGPSdata.csv"
    for every in (1, 5):
        p = imu_factors_example(csv, gps_every=every)
        yield f"ImuFactorsExample (GPS every {every})", (p.graph, p.initial)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--policies", action="store_true")
    args = ap.parse_args()
    import fgopt
    from fgopt.solvers import LMParams
    from fgopt.solvers.lm import problem_class

    data = Path(os.environ.get("FGOPT_DATA", ROOT.parent / "shared" / "data"))
    print("| problem | class | setting | iterations | final cost | status |")
    print("|---|---|---|---|---|---|")
    settings = [("auto", {})]
    if args.policies:
        settings += [(f"{d} + {lp}", {"damping": d, "lambda_policy": lp})
                     for d in ("identity", "diagonal") for lp in ("factor", "nielsen")]
    for name, (graph, initial) in problems(data):
        cls = problem_class(fgopt.Problem(graph, initial))
        for label, opts in settings:
            r = fgopt.optimize(graph, initial, params=LMParams(max_iterations=200, **opts))
            print(f"| {name} | {cls} | {label} | {r.iterations} | {r.final_cost:.6f} | "
                  f"{r.status.value} |", flush=True)


if __name__ == "__main__":
    main()
