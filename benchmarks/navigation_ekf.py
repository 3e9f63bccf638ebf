"""ManifoldEKF speed and accuracy, side by side with GTSAM 4.3's NavStateImuEKF.

1. **Real data**: GTSAM's ImuFactorsExample input (``navigation/imuAndGPSdata.csv`` of
   ``$FGOPT_DATA``: 20000 IMU samples at dt = 0.005 s, 100 GPS fixes; NED with zero gravity,
   as the example's ``MakeSharedD(0.0)``, and its noise parameters). Filters: fgopt 15-state
   (attitude, position, velocity, gyro and accelerometer biases), fgopt 9-state with GTSAM's
   exact NavState dynamics, GTSAM NavStateImuEKF (9-state). One pass each (predict every IMU
   sample, update at every fix; fgopt also with ``predict_many`` over the samples between two
   fixes), timed after a warm-up pass; position error against the fixes.
2. **Per-step cost** (synthetic inputs, the 15-state filter): predict alone, update alone, and
   predict + update at every sample (the issue's target: under 20 us), against GTSAM's
   predict + updateWithVector (9-state). Median of 5 repeats of 20000 steps each.

Times are CPU seconds of this process (``time.process_time``), which a busy shared machine
inflates far less than wall time; the load average is printed before and after. Single thread
(BLAS / numba pinned as the other benchmarks). Run:

    .venv/bin/python -m benchmarks.navigation_ekf
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OMP_THREAD_LIMIT", "OPENBLAS_NUM_THREADS",
             "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import math
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from fgopt.filters import ManifoldEKF
from fgopt.manifolds import SO3
from fgopt.symbolic import M33, V3, Rot3, Scalar

DATA = Path(os.environ.get("FGOPT_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))
DT = 0.005
# ImuFactorsExample's sensor model (continuous-time densities) and GPS noise
ACC_SIGMA, GYRO_SIGMA = 0.0003924, 0.000205689024915
ACC_BIAS_RW, GYRO_BIAS_RW = 0.004905, 0.000001454441043
INTEGRATION_VAR, GPS_SIGMA = 1e-8, 1.0
NED_ZERO_GRAVITY = (0.0, 0.0, 0.0)


def ins(R: Rot3, p: V3, v: V3, bg: V3, ba: V3, gyro: V3, accel: V3, dt: Scalar):
    """Strapdown step with biases (NED, the example's zero gravity)."""
    a = R * (accel - ba) + V3(*NED_ZERO_GRAVITY)
    return R * Rot3.exp((gyro - bg) * dt), p + v * dt + a * (dt * dt / 2), v + a * dt, bg, ba


def navstate(R: Rot3, p: V3, v: V3, gyro: V3, accel: V3, dt: Scalar):
    """GTSAM NavStateImuEKF's dynamics: exact integration of constant body rate and force."""
    w = gyro * dt
    W = M33([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    Jl, N, Wk = M33.eye(), M33.eye() * 0.5, M33.eye()
    for k in range(1, 5):  # |w dt| <= 0.05 here: the W^5 term is below 1e-9 relative
        Wk = Wk * W
        Jl = Jl + Wk * (1.0 / math.factorial(k + 1))
        N = N + Wk * (1.0 / math.factorial(k + 2))
    g = V3(*NED_ZERO_GRAVITY)
    return (R * Rot3.exp(w), p + v * dt + g * (dt * dt / 2) + R * (N * accel) * (dt * dt),
            v + g * dt + R * (Jl * accel) * dt)


def gps(p: V3) -> V3:
    return p


def read(path: Path):
    """``(initial [x y z qx qy qz qw vx vy vz], events)``; events: (0, accel, gyro), (1, xyz)."""
    events, init = [], None
    with open(path) as fh:
        for line in fh:
            f = line.strip().split(",")
            if f[0] == "i":
                init = np.array(f[1:], dtype=float)
            elif f[0] == "0":
                v = np.array(f[1:7], dtype=float)
                events.append((0, v[:3], v[3:]))
            elif f[0] == "1":
                events.append((1, np.array(f[1:4], dtype=float)))
    return init, events


def prior(init):
    """Initial attitude, position, velocity. The file's ``i`` line is zeros except its last
    entry (1.0); read in the example's documented order (N, E, D, qx, qy, qz, qw, vN, vE, vD)
    it would be a zero quaternion and a 1 m/s down velocity, which the GPS track (at rest at
    the origin, moving along N only) contradicts: the data are identity attitude, rest."""
    return SO3(), init[:3], np.zeros(3)


def run_fgopt(ekf, events, Q, Q_state):
    u = np.empty(6)
    Rg = np.eye(3) * GPS_SIGMA**2
    errs = []
    for ev in events:
        if ev[0] == 0:
            u[:3], u[3:] = ev[2], ev[1]
            ekf.predict(u, DT, Q, Q_state)
        else:
            errs.append(np.linalg.norm(ekf["p"] - ev[1]))
            ekf.update(ev[1], Rg, "gps")
    return errs


def blocks(events):
    """The events as ("imu", (k, 6) inputs [gyro, accel]) and ("gps", xyz) items."""
    out, run = [], []
    for ev in events:
        if ev[0] == 0:
            run.append(np.r_[ev[2], ev[1]])
        else:
            if len(run) > 0:
                out.append(("imu", np.array(run)))
                run = []
            out.append(("gps", ev[1]))
    if len(run) > 0:
        out.append(("imu", np.array(run)))
    return out


def run_fgopt_blocks(ekf, items, Q, Q_state):
    """predict_many over the IMU samples between fixes (one compiled loop per block)."""
    Rg = np.eye(3) * GPS_SIGMA**2
    errs = []
    for kind, data in items:
        if kind == "imu":
            ekf.predict_many(data, DT, Q, Q_state)
        else:
            errs.append(np.linalg.norm(ekf["p"] - data))
            ekf.update(data, Rg, "gps")
    return errs


def run_gtsam(gtsam, X0, P0, events):
    p = gtsam.PreintegrationParams.MakeSharedD(0.0)
    p.setAccelerometerCovariance(np.eye(3) * ACC_SIGMA**2)
    p.setGyroscopeCovariance(np.eye(3) * GYRO_SIGMA**2)
    p.setIntegrationCovariance(np.eye(3) * INTEGRATION_VAR)
    ekf = gtsam.NavStateImuEKF(X0, P0, p)
    Rg = np.eye(3) * GPS_SIGMA**2
    errs = []
    H = np.zeros((3, 9))
    for ev in events:
        if ev[0] == 0:
            ekf.predict(ev[2], ev[1], DT)
        else:
            X = ekf.state()
            errs.append(np.linalg.norm(X.position() - ev[1]))
            H[:, 3:6] = X.attitude().matrix()
            ekf.updateWithVector(X.position(), H, ev[1], Rg, False)
    return ekf, errs


def timed(fn, repeats=3):
    """Median CPU time of ``repeats`` calls, and the last result."""
    out, times = None, []
    for _ in range(repeats):
        t = time.process_time()
        out = fn()
        times.append(time.process_time() - t)
    return statistics.median(times), out


def real_data(gtsam):
    path = DATA / "navigation" / "imuAndGPSdata.csv"
    if not path.is_file():
        print(f"(skipped: {path} is absent; set FGOPT_DATA)")
        return []
    init, events = read(path)
    n_imu = sum(1 for e in events if e[0] == 0)
    R0, p0, v0 = prior(init)
    P9 = np.diag([0.01**2] * 3 + [0.5**2] * 3 + [0.1**2] * 3)
    P15 = np.diag([0.01**2] * 3 + [0.5**2] * 3 + [0.1**2] * 3 + [1e-3**2] * 6)
    Q = np.diag([GYRO_SIGMA**2] * 3 + [ACC_SIGMA**2] * 3) / DT
    Q15 = np.diag([0.0] * 3 + [INTEGRATION_VAR] * 3 + [0.0] * 3 + [GYRO_BIAS_RW**2] * 3
                  + [ACC_BIAS_RW**2] * 3) * DT
    rows = []
    ekf15 = ManifoldEKF(ins, [gps], x0=(R0, p0, v0, np.zeros(3), np.zeros(3)), P0=P15)
    run_fgopt(ekf15, events[:200], Q, Q15)  # warm-up (numba cache load)

    def one15():
        ekf15.set_state((R0, p0, v0, np.zeros(3), np.zeros(3)), P15)
        return run_fgopt(ekf15, events, Q, Q15)

    t15, e15 = timed(one15)
    rows.append(("fgopt ManifoldEKF, 15-state", t15, e15, n_imu))
    ekf9 = ManifoldEKF(navstate, [gps], x0=(R0, p0, v0), P0=P9, reset=False)
    Q9 = np.diag([GYRO_SIGMA**2] * 3 + [INTEGRATION_VAR] * 3 + [ACC_SIGMA**2] * 3) * DT
    zero6 = np.zeros((6, 6))

    def one9():
        ekf9.set_state((R0, p0, v0), P9)
        return run_fgopt(ekf9, events, zero6, Q9)

    run_fgopt(ekf9, events[:200], zero6, Q9)
    t9, e9 = timed(one9)
    rows.append(("fgopt ManifoldEKF, 9-state (GTSAM's dynamics)", t9, e9, n_imu))
    items = blocks(events)
    run_fgopt_blocks(ekf15, items[:4], Q, Q15)
    run_fgopt_blocks(ekf9, items[:4], zero6, Q9)

    def many15():
        ekf15.set_state((R0, p0, v0, np.zeros(3), np.zeros(3)), P15)
        return run_fgopt_blocks(ekf15, items, Q, Q15)

    def many9():
        ekf9.set_state((R0, p0, v0), P9)
        return run_fgopt_blocks(ekf9, items, zero6, Q9)

    tm15, em15 = timed(many15)
    rows.append(("fgopt ManifoldEKF, 15-state, predict_many between fixes", tm15, em15, n_imu))
    tm9, em9 = timed(many9)
    rows.append(("fgopt ManifoldEKF, 9-state, predict_many between fixes", tm9, em9, n_imu))
    if gtsam is not None:
        X0 = gtsam.NavState(gtsam.Rot3(R0.matrix()), p0, v0)
        tg, (g_ekf, eg) = timed(lambda: run_gtsam(gtsam, X0, P9, events))
        rows.append(("GTSAM NavStateImuEKF, 9-state", tg, eg, n_imu))
        X = g_ekf.state()
        diff = max(np.abs(ekf9["p"] - X.position()).max(), np.abs(ekf9["v"] - X.velocity()).max())
        print(f"fgopt 9-state vs GTSAM after the pass: max |position, velocity difference| "
              f"{diff:.2e}")
    print(f"\nReal data: {path.name}, {n_imu} IMU samples, "
          f"{sum(1 for e in events if e[0] == 1)} GPS fixes (median of 3 passes)\n")
    print("| filter | pass (CPU s) | per IMU sample (CPU us) | position error at fixes: RMS / max (m) |")
    print("|---|---|---|---|")
    for name, t, errs, n in rows:
        print(f"| {name} | {t:.3f} | {1e6 * t / n:.2f} | {np.sqrt(np.mean(np.square(errs))):.2e}"
              f" / {np.max(errs):.2e} |")
    return rows


def per_step(gtsam):
    rng = np.random.default_rng(0)
    steps = 20000
    U = np.column_stack([rng.normal(size=(steps, 3)) * 0.1,
                         rng.normal(size=(steps, 3)) + [0.0, 0.0, 9.81]])
    Z = rng.normal(size=(steps, 3))
    Q = np.eye(6) * 1e-4
    Q15 = np.diag([0.0] * 9 + [1e-10] * 6)
    Rg = np.eye(3)
    x0 = (SO3(), np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3))
    ekf = ManifoldEKF(ins, [gps], x0=x0, P0=np.eye(15))

    def loop(pred, upd):
        ekf.set_state(x0, np.eye(15))
        t = time.process_time()
        for k in range(steps):
            if pred:
                ekf.predict(U[k], 0.01, Q, Q15)
            if upd:
                ekf.update(Z[k], Rg, "gps")
        return (time.process_time() - t) / steps * 1e6

    loop(True, True)
    results = {}
    for label, pred, upd in (("predict", True, False), ("update", False, True),
                             ("predict + update", True, True)):
        results[label] = statistics.median(loop(pred, upd) for _ in range(5))
    g = None
    if gtsam is not None:
        p = gtsam.PreintegrationParams.MakeSharedU(9.81)
        H = np.zeros((3, 9))
        H[:, 3:6] = np.eye(3)

        def gloop():
            g_ekf = gtsam.NavStateImuEKF(gtsam.NavState(), np.eye(9), p)
            t = time.process_time()
            for k in range(steps):
                g_ekf.predict(U[k, :3], U[k, 3:], 0.01)
                X = g_ekf.state()
                H[:, 3:6] = X.attitude().matrix()
                g_ekf.updateWithVector(X.position(), H, Z[k], Rg, False)
            return (time.process_time() - t) / steps * 1e6

        gloop()
        g = statistics.median(gloop() for _ in range(5))
    print(f"\nPer step, synthetic inputs, {steps} steps (median of 5), CPU microseconds\n")
    print("| step | fgopt 15-state | GTSAM 9-state (predict + updateWithVector) | ratio |")
    print("|---|---|---|---|")
    for label, us in results.items():
        peer = f"{g:.2f}" if (g is not None and label == "predict + update") else "-"
        ratio = f"x{g / us:.2f}" if (g is not None and label == "predict + update") else "-"
        print(f"| {label} | {us:.2f} | {peer} | {ratio} |")
    return results, g


def main() -> int:
    try:
        import gtsam
        if not hasattr(gtsam, "NavStateImuEKF"):
            gtsam = None
    except ImportError:
        gtsam = None
    print(f"load average (1 min) {os.getloadavg()[0]:.2f}; GTSAM "
          f"{'present' if gtsam is not None else 'absent'}")
    real_data(gtsam)
    per_step(gtsam)
    print(f"\nload average (1 min) {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
