"""GTSAM's ImuFactorsExample online (IMU + GPS, ``navigation/imuAndGPSdata.csv``), fgopt's
``IncrementalSmoother`` vs GTSAM's ``ISAM2`` in one run (issue 16).

    python -m benchmarks.incremental_imu

As the example with ``--use_isam``: iSAM2 with relinearize threshold 0.01 and skip 1; at each of
the 100 GPS fixes the IMU factor from the previous state (200 samples preintegrated), the bias
random walk and the GPS factor are added (the priors with the first), and the new state is
predicted from the current estimate of the previous one (``pim.predict``). The factors are the same least-squares problem
in both libraries (``benchmarks/peers/gtsam_navigation.py``). Reported: total CPU time of the
loop, median and 99th percentile per step, final cost (fgopt's yardstick) vs the batch optimum.
"""

from __future__ import annotations

import os
import time

import numpy as np

import fgopt
from fgopt.io.imu_gps import B, V, X, imu_factors_example, read_imu_gps_csv
from fgopt.key import key_index
from fgopt.navigation import ImuBias, NavState

DATA = os.environ.get("FGOPT_DATA", os.path.join(os.path.dirname(__file__), "..", "..", "shared",
                                                  "data"))


def _steps(factors):
    """Factors per GPS fix; the priors join the first fix's update (as in the example: GTSAM's
    ISAM2 calls the priors alone followed by the first IMU factor indeterminate)."""
    out: dict[int, list] = {}
    for f, keys in factors:
        out.setdefault(max(1, max(key_index(k) for k in keys)), []).append(f)
    return [out[k] for k in sorted(out)]


def run_fgopt(problem):
    isam = fgopt.IncrementalSmoother(fgopt.IncrementalParams(relinearize_threshold=0.01,
                                                             relinearize_skip=1))
    steps = _steps([(f, f.keys) for f in problem.graph])
    times = []
    t0 = time.thread_time()
    for k, fs in enumerate(steps, start=1):
        c0 = time.thread_time()
        if k == 1:
            values = {K(0): problem.initial.at(K(0)) for K in (X, V, B)}
            state = NavState.from_pose_velocity(values[X(0)], values[V(0)])
            bias = values[B(0)]
        else:
            state = NavState.from_pose_velocity(isam.estimate(X(k - 1)), isam.estimate(V(k - 1)))
            bias = isam.estimate(B(k - 1))
            values = {}
        s = problem.pims[k - 1].predict(state, ImuBias.from_vector(bias))
        values.update({X(k): s.pose(), V(k): s.velocity(), B(k): bias})
        isam.update(fs, values)
        times.append(time.thread_time() - c0)
    return time.thread_time() - t0, np.array(times), isam.estimate()


def run_gtsam(data, problem):
    import gtsam

    from benchmarks.peers import gtsam_navigation as GN

    graph, _ = GN.build(data, problem)
    factors = [(graph.at(i), graph.at(i).keys()) for i in range(graph.size())]
    pims = [f for f, keys in factors if isinstance(f, gtsam.ImuFactor)]
    p = gtsam.ISAM2Params()
    p.setRelinearizeThreshold(0.01)
    p.relinearizeSkip = 1
    isam = gtsam.ISAM2(p)
    times = []
    t0 = time.thread_time()
    for k, fs in enumerate(_steps(factors), start=1):
        c0 = time.thread_time()
        g, v = gtsam.NonlinearFactorGraph(), gtsam.Values()
        for f in fs:
            g.add(f)
        if k == 1:
            pose0 = GN.to_gtsam_pose(problem.initial.at(X(0)))
            v0 = np.asarray(problem.initial.at(V(0)), dtype=float)
            v.insert(X(0), pose0)
            v.insert(V(0), v0)
            bias = gtsam.imuBias.ConstantBias()
            v.insert(B(0), bias)
            prev = gtsam.NavState(pose0, v0)
        else:
            prev = gtsam.NavState(isam.calculateEstimatePose3(X(k - 1)),
                                  isam.calculateEstimateVector(V(k - 1)))
            bias = isam.calculateEstimateConstantBias(B(k - 1))
        s = pims[k - 1].preintegratedMeasurements().predict(prev, bias)
        v.insert(X(k), s.pose())
        v.insert(V(k), s.velocity())
        v.insert(B(k), bias)
        try:
            isam.update(g, v)
        except RuntimeError as e:      # a failure is a result: report where
            line = next(ln for ln in str(e).splitlines() if ln.strip())
            return f"fails at GPS fix {k}: {line.strip()}"
        times.append(time.thread_time() - c0)
    total = time.thread_time() - t0
    est = isam.calculateEstimate()
    out = fgopt.Variables()
    for k in range(problem.num_states):
        out.add(X(k), fgopt.SE3.from_matrix(est.atPose3(X(k)).matrix()))
        out.add(V(k), np.asarray(est.atVector(V(k))))
        b = est.atConstantBias(B(k))
        out.add(B(k), np.concatenate([b.accelerometer(), b.gyroscope()]))
    return total, np.array(times), out


def main() -> None:
    data = read_imu_gps_csv(os.path.join(DATA, "navigation/imuAndGPSdata.csv"))
    problem = imu_factors_example(data)
    run_fgopt(problem)                                   # warm-up: kernel loads
    rows = ["| library | total CPU s | step median / p99 ms | final cost | vs batch optimum |",
            "|---|---|---|---|---|"]
    best = fgopt.optimize(problem.graph, problem.initial, relative_tolerance=1e-12,
                          absolute_tolerance=0.0).final_cost
    for name, fn in (("GTSAM", lambda: run_gtsam(data, problem)), ("fgopt",
                                                                   lambda: run_fgopt(problem))):
        out = fn()
        if isinstance(out, str):
            rows.append(f"| {name} | {out} | | | |")
            continue
        total, times, est = out
        cost = problem.graph.error(est)
        rows.append(f"| {name} | {total:.3f} | {1e3 * np.median(times):.3f} / "
                    f"{1e3 * np.percentile(times, 99):.2f} | {cost:.6f} | "
                    f"{100 * (cost - best) / best:+.4f} % |")
    print(f"ImuFactorsExample online ({problem.num_states} states), batch optimum {best:.6f}\n")
    print("\n".join(rows))


if __name__ == "__main__":
    main()
