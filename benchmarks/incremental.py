"""Incremental smoothing, side by side with GTSAM's ISAM2 (issue 16).

    python -m benchmarks.incremental [--datasets m3500,sphere2500,w20000,victoria]
                                     [--threshold 0.1] [--skip 10] [--fixed-lag 100] [--out F]

Each dataset is played one pose at a time, as GTSAM's examples do (``timeIncremental.cpp``):
a measurement joins the step of its latest pose (a loop closure arrives with its later pose, a
landmark sighting with its pose); a new pose is initialized from the current estimate of an
older pose composed with the odometry edge between them, a new landmark from its first
sighting. Both libraries get the same measurements and noise models (built here from one
parse) and the same prior on the first pose; both run with default parameters and the same
relinearization threshold and skip. Factor objects are built before the timed loop.

Per library: the loop's total time, the median and 99th percentile of ``update`` alone and of a
whole step (the estimate queries that initialize new variables, then ``update``: GTSAM does its
back-substitution lazily inside ``calculateEstimate``, fgopt likewise, so only whole steps
compare the same work), CPU time of this thread (``time.thread_time``; the machine is shared)
and wall time. The *full estimate per update* rows repeat the replay reading the whole estimate
after every update (fgopt ``estimate()``, GTSAM ``calculateEstimate()``), as GTSAM's
VisualISAM2Example does. Final cost: ``0.5 sum |r|^2`` of the whole graph at each library's last
estimate, evaluated by fgopt for both (one yardstick; GTSAM's own ``error`` is checked equal),
against the batch optimum (fgopt LM from the last estimate to convergence).

``benchmarks/incremental_params.py`` measures fgopt's defaults (one field changed at a time).
``--fixed-lag L``: also fgopt's ``FixedLagSmoother`` on w20000 with a lag of ``L`` poses
(``benchmarks/incremental_lag.py``): update time over the run (first vs last 10 %), memory.

w20000 (``EDGE2`` lines only) is read as iSAM's square-root information (the format of the
library the file comes from); GTSAM's ``load2D`` guesses a covariance from its zero pattern,
and its ISAM2 then fails at the first loop closure (pose 1195, "indeterminate system").
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import sys
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OMP_THREAD_LIMIT", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

import fgopt  # noqa: E402
from fgopt import SE2, SE3, key  # noqa: E402

DATA = os.environ.get("FGOPT_DATA", os.path.join(os.path.dirname(__file__), "..", "..", "shared",
                                                  "data"))
FILES = {"m3500": "pose2d/input_M3500_g2o.g2o", "sphere2500": "pose3d/sphere2500.g2o",
         "w20000": "pose2d/w20000.txt", "victoria": "slam/victoria_park.txt"}
#: fgopt SE2 tangent [theta, x, y] -> GTSAM Pose2 [x, y, theta]
_PERM2 = np.array([1, 2, 0])


# ------------------------------------------------------------------ one stream for both
class Stream:
    """Measurements of a dataset grouped into steps (see the module docstring)."""

    def __init__(self, name: str):
        self.name = name
        self.dim = 2
        self.between = []        # (i, j, storage, sqrt_info in fgopt tangent order)
        self.br = []             # (pose, landmark, bearing, range, sigma_bearing, sigma_range)
        self.steps = []          # [(pose id, [("b", idx) | ("r", idx), ...])]
        self.prior_sigmas = None
        self.first_pose = None
        self.first_value = None


def load_stream(name: str) -> Stream:
    path = os.path.join(DATA, FILES[name])
    s = Stream(name)
    if name in ("m3500", "sphere2500"):
        graph, init = fgopt.io.read(path)
        s.dim = 3 if name == "sphere2500" else 2
        for b in graph.batches:
            R = b.sqrt_information
            for r in range(len(b)):
                i, j = (int(k) & ((1 << 56) - 1) for k in b.keys[r])
                s.between.append((i, j, b.constants[r].copy(),
                                  R[r] if R is not None else np.eye(R.shape[1])))
        s.prior_sigmas = np.full(6 if s.dim == 3 else 3, 1e-3)
        s.first_pose = 0
        s.first_value = init.at(key("x", 0))
    else:
        d = fgopt.io.parse_load2d(path, "sqrt_information" if name == "w20000" else "auto")
        for i, j, m, R in zip(d.edge_i.tolist(), d.edge_j.tolist(), d.edge_meas, d.edge_sqrt_info):
            s.between.append((i, j, SE2.from_xytheta(*m).to_storage(), R))
        for p, lm, b, r, sg in zip(d.br_pose.tolist(), d.br_landmark.tolist(),
                                   d.br_bearing.tolist(), d.br_range.tolist(), d.br_sigmas):
            s.br.append((p, lm, b, r, float(sg[0]), float(sg[1])))
        s.prior_sigmas = np.ones(3)      # timeIncremental.cpp: unit prior on pose 0
        s.first_pose = 0
        s.first_value = SE2.identity()
    groups: dict[int, list] = {}
    for idx, (i, j, _, _) in enumerate(s.between):
        groups.setdefault(max(i, j), []).append(("b", idx))
    for idx, m in enumerate(s.br):
        groups.setdefault(m[0], []).append(("r", idx))
    s.steps = sorted(groups.items())
    return s


def group_of(s: Stream):
    return SE3 if s.dim == 3 else SE2


# ------------------------------------------------------------------ library adapters
class FgoptAdapter:
    name = "fgopt"

    def __init__(self, s: Stream, threshold: float, skip: int):
        from fgopt.factors import BetweenFactor, PriorFactor
        from fgopt.factors.library.range_bearing import range_bearing_factor
        from fgopt.noise import Diagonal, Gaussian

        self.s = s
        self.G = group_of(s)
        self.isam = fgopt.IncrementalSmoother(fgopt.IncrementalParams(
            relinearize_threshold=threshold, relinearize_skip=skip))
        self.prior = PriorFactor(key("x", s.first_pose), s.first_value,
                                 Diagonal.sigmas(s.prior_sigmas))
        noise_cache: dict = {}

        def noise(R):
            k = R.tobytes()
            if k not in noise_cache:
                noise_cache[k] = Gaussian.from_sqrt_information(R)
            return noise_cache[k]

        self.meas = {}
        self.factors = {}
        for idx, (i, j, st, R) in enumerate(s.between):
            m = self.G.from_storage(st)
            self.meas[("b", idx)] = m
            self.factors[("b", idx)] = BetweenFactor(key("x", i), key("x", j), m, noise(R))
        for idx, (p, lm, b, r, sb, sr) in enumerate(s.br):
            self.factors[("r", idx)] = range_bearing_factor(
                pose=key("x", p), landmark=key("l", lm), measured=np.array([r, b]),
                loss=Diagonal.sigmas([sr, sb]))

    def between_measurement(self, idx):
        return self.meas[("b", idx)]

    def estimate(self, k):
        return self.isam.estimate(k)

    def compose(self, a, m):
        return a * m

    def inverse(self, m):
        return m.inverse()

    def landmark(self, pose, bearing, range_):
        return pose.act(np.array([range_ * math.cos(bearing), range_ * math.sin(bearing)]))

    def update(self, ids, values):
        fs = [self.factors[i] if i != "prior" else self.prior for i in ids]
        return self.isam.update(fs, values)

    def full_estimate(self):
        return self.isam.estimate()

    def final(self):
        return self.isam.estimate()


class GtsamAdapter:
    name = "GTSAM"

    def __init__(self, s: Stream, threshold: float, skip: int):
        import gtsam

        self.g = gtsam
        self.s = s
        p = gtsam.ISAM2Params()
        p.setRelinearizeThreshold(threshold)
        p.relinearizeSkip = skip
        self.isam = gtsam.ISAM2(p)
        self.P = gtsam.Pose3 if s.dim == 3 else gtsam.Pose2
        self.factors = {}
        self.meas = {}
        cache: dict = {}

        def noise(R):
            k = R.tobytes()
            if k not in cache:
                info = R.T @ R
                if s.dim == 2:
                    info = info[_PERM2][:, _PERM2]
                cache[k] = gtsam.noiseModel.Gaussian.Information(info)
            return cache[k]

        for idx, (i, j, st, R) in enumerate(s.between):
            m = self._pose(st)
            self.meas[("b", idx)] = m
            Between = gtsam.BetweenFactorPose3 if s.dim == 3 else gtsam.BetweenFactorPose2
            self.factors[("b", idx)] = Between(key("x", i), key("x", j), m, noise(R))
        for idx, (p_, lm, b, r, sb, sr) in enumerate(s.br):
            self.factors[("r", idx)] = gtsam.BearingRangeFactor2D(
                key("x", p_), key("l", lm), gtsam.Rot2(b), r,
                gtsam.noiseModel.Diagonal.Sigmas(np.array([sb, sr])))
        sig = s.prior_sigmas
        Prior = gtsam.PriorFactorPose3 if s.dim == 3 else gtsam.PriorFactorPose2
        self.prior = Prior(key("x", s.first_pose), self._value(s.first_value),
                           gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sig)))

    def _pose(self, st):
        g = self.g
        if self.s.dim == 2:
            return g.Pose2(st[2], st[3], math.atan2(st[1], st[0]))
        q = st[:4]
        return g.Pose3(g.Rot3.Quaternion(q[3], q[0], q[1], q[2]), st[4:7])

    def _value(self, v):
        return self._pose(v.to_storage())

    def between_measurement(self, idx):
        return self.meas[("b", idx)]

    def estimate(self, k):
        if k >> 56 == ord("l"):
            return self.isam.calculateEstimatePoint2(k)
        return (self.isam.calculateEstimatePose3(k) if self.s.dim == 3
                else self.isam.calculateEstimatePose2(k))

    def compose(self, a, m):
        return a.compose(m)

    def inverse(self, m):
        return m.inverse()

    def landmark(self, pose, bearing, range_):
        local = np.array([range_ * math.cos(bearing), range_ * math.sin(bearing)])
        return pose.transformFrom(local)

    def update(self, ids, values):
        g = self.g
        graph = g.NonlinearFactorGraph()
        for i in ids:
            graph.add(self.factors[i] if i != "prior" else self.prior)
        v = g.Values()
        for k, x in values.items():
            v.insert(k, x)
        return self.isam.update(graph, v)

    def full_estimate(self):
        return self.isam.calculateEstimate()

    def final(self, best: bool = False):
        """The estimate as fgopt Variables (for the common cost yardstick); ``best``:
        ``calculateBestEstimate`` (a full back-substitution instead of the wildfire delta)."""
        est = self.isam.calculateBestEstimate() if best else self.isam.calculateEstimate()
        out = fgopt.Variables()
        for k in est.keys():
            if k >> 56 == ord("l"):
                out.add(k, np.asarray(est.atPoint2(k)))
            elif self.s.dim == 2:
                p = est.atPose2(k)
                out.add(k, SE2.from_xytheta(p.x(), p.y(), p.theta()))
            else:
                p = est.atPose3(k)
                out.add(k, SE3.from_matrix(p.matrix()))
        return out


# ------------------------------------------------------------------ the online loop
def play(lib, s: Stream, limit: int | None = None, full: bool = False) -> dict:
    """Run the stream through ``lib``; per-step CPU / wall times of update and whole steps.
    ``full``: read the whole estimate after every update (timed within the step)."""
    known: set = set()
    upd_cpu, upd_wall, step_cpu, step_wall = [], [], [], []
    tc, tw = time.thread_time, time.perf_counter
    first = True
    t_all_c, t_all_w = tc(), tw()
    for n, (pose, ids) in enumerate(s.steps):
        if limit is not None and n >= limit:
            break
        c0, w0 = tc(), tw()
        values = {}
        ids = list(ids)
        if first:
            k0 = key("x", s.first_pose)
            values[k0] = s.first_value if lib.name == "fgopt" else lib._value(s.first_value)
            known.add(k0)
        kp = key("x", pose)
        if kp not in known:
            for kind, idx in ids:
                if kind != "b":
                    continue
                i, j = s.between[idx][0], s.between[idx][1]
                ki, kj = key("x", i), key("x", j)
                if kj == kp and ki in known:
                    base = values[ki] if ki in values else lib.estimate(ki)
                    values[kp] = lib.compose(base, lib.between_measurement(idx))
                    break
                if ki == kp and kj in known:
                    base = values[kj] if kj in values else lib.estimate(kj)
                    values[kp] = lib.compose(base, lib.inverse(lib.between_measurement(idx)))
                    break
            if kp not in values:
                raise RuntimeError(f"{s.name}: pose {pose} has no odometry from a known pose")
            known.add(kp)
        for kind, idx in ids:
            if kind != "r":
                continue
            p, lm, b, r = s.br[idx][:4]
            kl = key("l", lm)
            if kl not in known:
                kx = key("x", p)
                base = values[kx] if kx in values else lib.estimate(kx)
                values[kl] = lib.landmark(base, b, r)
                known.add(kl)
        if first:
            ids = ["prior"] + ids
        c1, w1 = tc(), tw()
        lib.update(ids, values)
        c2, w2 = tc(), tw()
        if full:
            lib.full_estimate()
            c2, w2 = tc(), tw()
        first = False
        upd_cpu.append(c2 - c1)
        upd_wall.append(w2 - w1)
        step_cpu.append(c2 - c0)
        step_wall.append(w2 - w0)
    return {"total_cpu": tc() - t_all_c, "total_wall": tw() - t_all_w,
            "update_cpu": np.array(upd_cpu), "update_wall": np.array(upd_wall),
            "step_cpu": np.array(step_cpu), "step_wall": np.array(step_wall)}


def full_graph(lib: FgoptAdapter, s: Stream) -> fgopt.FactorGraph:
    g = fgopt.FactorGraph([lib.prior])
    for _, ids in s.steps:
        for i in ids:
            g.add(lib.factors[i])
    return g


def loadavg() -> float:
    try:
        return os.getloadavg()[0]
    except OSError:
        return float("nan")


def compile_all(s: Stream, threshold: float, warm: int) -> None:
    """Untimed: run every path of fgopt's update once, so no timed step compiles a kernel (or
    loads it from numba's cache): a short replay relinearizing at every step, with the
    bitset-ordering limit at 0 so every top goes through the AMD path (``NEED_ORDER``) that
    otherwise only tops over ``BITSET_LIMIT`` variables take, far into a long replay."""
    from fgopt.incremental import _ordering

    limit = _ordering.BITSET_LIMIT
    _ordering.BITSET_LIMIT = 0
    try:
        play(FgoptAdapter(s, threshold, 1), s, limit=min(warm, 60), full=True)
    finally:
        _ordering.BITSET_LIMIT = limit


def run_dataset(name: str, threshold: float, skip: int, warm: int) -> dict:
    s = load_stream(name)
    out = {"dataset": name, "steps": len(s.steps), "threshold": threshold, "skip": skip,
           "load_start": loadavg()}
    # warm-up (numba kernel loads, GTSAM allocations) on a prefix, untimed
    compile_all(s, threshold, warm)
    for cls in (FgoptAdapter, GtsamAdapter):
        play(cls(s, threshold, skip), s, limit=warm)
    libs = {}
    for cls in (GtsamAdapter, FgoptAdapter):
        lib = cls(s, threshold, skip)
        try:
            r = play(lib, s)
        except Exception as e:  # a library failing is a result, not a crash of the benchmark
            out[lib.name] = {"error": f"{type(e).__name__}: {e}".splitlines()[0]}
            continue
        libs[lib.name] = lib
        out[lib.name] = r
    fg = FgoptAdapter(s, threshold, skip)
    graph = full_graph(fg, s)
    for name_, lib in libs.items():
        est = lib.final()
        out[name_]["cost"] = graph.error(est)
        if name_ == "GTSAM":
            out[name_]["cost_gtsam_own"] = float(lib.isam.getFactorsUnsafe().error(
                lib.isam.calculateEstimate()))
            out[name_]["cost_best"] = graph.error(lib.final(best=True))
    start = libs["fgopt"].final() if "fgopt" in libs else None
    if start is not None:
        res = fgopt.optimize(graph, start, method="lm", max_iterations=200,
                             relative_tolerance=1e-12, absolute_tolerance=1e-12)
        out["batch_optimum"] = res.final_cost
        out["batch_iterations"] = res.iterations
    out["load_end"] = loadavg()
    return out


def run_full_estimate(spec: str, threshold: float, skip: int, warm: int) -> dict:
    """The replay of ``spec`` (``name`` or ``name:steps``, the first steps only) reading the
    whole estimate after every update, both libraries (costs O(poses) per step: O(n^2) in all)."""
    name, _, steps = spec.partition(":")
    s = load_stream(name)
    limit = int(steps) if steps else None
    label = f"{name} (first {limit} poses)" if limit else name
    out = {"dataset": label, "steps": limit or len(s.steps), "load_start": loadavg()}
    compile_all(s, threshold, warm)
    for cls in (FgoptAdapter, GtsamAdapter):
        play(cls(s, threshold, skip), s, limit=min(warm, limit or warm), full=True)
    for cls in (GtsamAdapter, FgoptAdapter):
        lib = cls(s, threshold, skip)
        try:
            out[lib.name + " full"] = play(lib, s, limit=limit, full=True)
        except Exception as e:  # a library failing is a result, not a crash of the benchmark
            out[lib.name + " full"] = {"error": f"{type(e).__name__}: {e}".splitlines()[0]}
    out["load_end"] = loadavg()
    return out


def summary(r: dict) -> dict:
    """Numbers of one library run for the table."""
    if "error" in r:
        return r
    return {"total_cpu": r["total_cpu"], "total_wall": r["total_wall"],
            "update_sum_cpu": float(r["update_cpu"].sum()),
            "update_median_ms": 1e3 * float(np.median(r["update_cpu"])),
            "update_p99_ms": 1e3 * float(np.percentile(r["update_cpu"], 99)),
            "step_median_ms": 1e3 * float(np.median(r["step_cpu"])),
            "step_p99_ms": 1e3 * float(np.percentile(r["step_cpu"], 99)),
            "update_p99_wall_ms": 1e3 * float(np.percentile(r["update_wall"], 99)),
            "cost": r.get("cost"), "cost_gtsam_own": r.get("cost_gtsam_own"),
            "cost_best": r.get("cost_best")}


def table(results: list[dict]) -> str:
    rows = ["| dataset | library | total CPU s (wall) | update median / p99 ms | step median / "
            "p99 ms | final cost | vs batch optimum |",
            "|---|---|---|---|---|---|---|"]
    for res in results:
        opt = res.get("batch_optimum")
        for lib in ("GTSAM", "fgopt"):
            r = res.get(lib)
            if r is None:
                continue
            if "error" in r:
                rows.append(f"| {res['dataset']} | {lib} | {r['error']} | | | | |")
                continue
            s = summary(r)
            rel = f"{100 * (s['cost'] - opt) / opt:+.3f} %" if opt else "-"
            cost = f"{s['cost']:.6g}"
            if s.get("cost_best") is not None:
                cost += f" (best {s['cost_best']:.6g})"
                rel += f" ({100 * (s['cost_best'] - opt) / opt:+.3f} %)" if opt else ""
            rows.append(
                f"| {res['dataset']} | {lib} | {s['total_cpu']:.2f} ({s['total_wall']:.2f}) | "
                f"{s['update_median_ms']:.3f} / {s['update_p99_ms']:.2f} | "
                f"{s['step_median_ms']:.3f} / {s['step_p99_ms']:.2f} | {cost} | {rel} |")
        g, f = res.get("GTSAM full"), res.get("fgopt full")
        if g and f and "error" not in g and "error" not in f:
            sg, sf = summary(g), summary(f)
            rows.append(f"| {res['dataset']} | full estimate per update: fgopt / GTSAM | "
                        f"{sf['total_cpu']:.2f} / {sg['total_cpu']:.2f} = "
                        f"{sf['total_cpu'] / sg['total_cpu']:.2f} | "
                        f"{sf['update_median_ms']:.3f} / {sg['update_median_ms']:.3f} | "
                        f"{sf['step_median_ms']:.3f} / {sg['step_median_ms']:.3f} | | |")
        g, f = res.get("GTSAM"), res.get("fgopt")
        if g and f and "error" not in g and "error" not in f:
            sg, sf = summary(g), summary(f)
            rows.append(f"| {res['dataset']} | ratio fgopt/GTSAM | "
                        f"{sf['total_cpu'] / sg['total_cpu']:.2f} | "
                        f"{sf['update_median_ms'] / sg['update_median_ms']:.2f} / "
                        f"{sf['update_p99_ms'] / sg['update_p99_ms']:.2f} | "
                        f"{sf['step_median_ms'] / sg['step_median_ms']:.2f} / "
                        f"{sf['step_p99_ms'] / sg['step_p99_ms']:.2f} | | |")
    return "\n".join(rows)


# What the README table's timings include and how runs stop (benchmarks/tables.py).
TABLE_PROTOCOL = {
    "includes": ("CPU time of the thread over the whole replay, for both libraries: per step the "
        "estimate queries that initialize new variables plus `update`; factor objects built "
        "before the timed loop and the warm-up steps untimed for both."),
    "stopping": ("no stopping rule: one `update` per pose in both libraries, default parameters "
        "(relinearize threshold 0.1, relinearize skip 10)."),
}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--datasets", default="m3500,sphere2500,w20000,victoria",
                    help="replays of whole datasets ('' for none: e.g. only --full-estimate)")
    ap.add_argument("--threshold", type=float, default=0.1)
    ap.add_argument("--skip", type=int, default=10)
    ap.add_argument("--warm", type=int, default=300, help="untimed warm-up steps per library")
    ap.add_argument("--full-estimate", default="m3500:434,m3500,sphere2500",
                    help="replays reading the whole estimate after every update ('name' or "
                         "'name:steps'; '' for none)")
    ap.add_argument("--fixed-lag", type=float, default=0.0,
                    help="also run fgopt's FixedLagSmoother on w20000 with this lag (poses)")
    ap.add_argument("--out", default=None, help="write the table (.md) and numbers (.json)")
    args = ap.parse_args(argv)
    results = []
    for name in filter(None, args.datasets.split(",")):   # '' runs none
        r = run_dataset(name.strip(), args.threshold, args.skip, args.warm)
        results.append(r)
        print(table([r]), flush=True)
    for spec in filter(None, args.full_estimate.split(",")):
        r = run_full_estimate(spec.strip(), args.threshold, args.skip, args.warm)
        results.append(r)
        print(table([r]), flush=True)
    text = table(results)
    if args.fixed_lag > 0:
        from benchmarks.incremental_lag import report, run_fixed_lag

        lag = run_fixed_lag(args.fixed_lag)
        results.append(lag)
        text += "\n\n" + report(lag)
    print("\n" + text)
    if args.out:
        base = args.out[:-3] if args.out.endswith(".md") else args.out
        stamp = datetime.datetime.now().isoformat(timespec="seconds")
        with open(base + ".md", "w") as fh:
            fh.write(f"# Incremental smoothing, fgopt vs GTSAM ISAM2 ({stamp})\n\n")
            fh.write("`python -m benchmarks.incremental " + " ".join(sys.argv[1:]) + "`\n\n")
            fh.write(text + "\n")
        with open(base + ".json", "w") as fh:
            json.dump([_jsonable(r) for r in results], fh, indent=1)


def _jsonable(r):
    if isinstance(r, dict):
        return {k: _jsonable(v) for k, v in r.items()}
    if isinstance(r, np.ndarray):        # per-step times: a summary (the full lists are MBs)
        n = r.shape[0] // 10
        return {"n": int(r.shape[0]), "sum": float(r.sum()), "median": float(np.median(r)),
                "p90": float(np.percentile(r, 90)), "p99": float(np.percentile(r, 99)),
                "max": float(r.max()), "first10pct_mean": float(r[:n].mean()),
                "last10pct_mean": float(r[-n:].mean())}
    if isinstance(r, (np.floating, np.integer)):
        return r.item()
    return r


if __name__ == "__main__":
    main()
