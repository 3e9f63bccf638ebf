"""Fixed-lag smoothing on w20000: is the update time flat over a long run? (issue 16)

    python -m benchmarks.incremental_lag [--lag 100] [--gtsam]

w20000 is played one pose at a time (as ``benchmarks/incremental.py``) through fgopt's
``FixedLagSmoother``, timestamps = pose index, keeping the measurements whose older pose is
still inside the window (a loop closure to a pose already marginalized cannot be added: that
is what a fixed-lag smoother gives up). Reported: median and mean update time (CPU) of the
first and last 10 % of the run, and the size of the smoother's arrays at 10 % and at the end
(memory must not grow). ``--gtsam`` runs GTSAM's ``IncrementalFixedLagSmoother`` on the same
stream for reference.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import fgopt
from benchmarks.incremental import FgoptAdapter, GtsamAdapter, load_stream, play


def window_stream(lag: float):
    s = load_stream("w20000")
    steps = []
    for pose, ids in s.steps:
        keep = [(kind, idx) for kind, idx in ids
                if pose - min(s.between[idx][0], s.between[idx][1]) < lag]
        steps.append((pose, keep))
    s.steps = steps
    return s


class _FgoptLag(FgoptAdapter):
    def __init__(self, s, lag):
        super().__init__(s, 0.1, 10)
        self.lag = fgopt.FixedLagSmoother(lag, fgopt.IncrementalParams())
        self.sizes = []

    def estimate(self, k):
        return self.lag.estimate(k)

    def update(self, ids, values):
        fs = [self.factors[i] if i != "prior" else self.prior for i in ids]
        stamps = {k: float(k & ((1 << 56) - 1)) for k in values}
        r = self.lag.update(fs, values, stamps)
        t = self.lag.smoother._tree
        self.sizes.append(t.VI.nbytes + t.FI.nbytes + t.CI.nbytes + t.ADJ.nbytes + t.cnpool.nbytes
                          + t.cvpool.nbytes + t.hpool.nbytes + t.delta.nbytes + t.fac_vars.nbytes)
        return r


class _GtsamLag(GtsamAdapter):
    def __init__(self, s, lag):
        super().__init__(s, 0.1, 10)
        g = self.g
        self.lag = g.IncrementalFixedLagSmoother(lag, g.ISAM2Params())

    def estimate(self, k):
        return self.lag.calculateEstimatePose2(k)

    def update(self, ids, values):
        g = self.g
        graph = g.NonlinearFactorGraph()
        for i in ids:
            graph.add(self.factors[i] if i != "prior" else self.prior)
        v = g.Values()
        stamps = g.FixedLagSmootherKeyTimestampMap()
        for k, x in values.items():
            v.insert(k, x)
            stamps.insert((k, float(k & ((1 << 56) - 1))))
        return self.lag.update(graph, v, stamps)


def flatness(r: dict) -> dict:
    u = r["update_cpu"]
    n = len(u) // 10
    return {"first10_median_ms": 1e3 * float(np.median(u[:n])),
            "last10_median_ms": 1e3 * float(np.median(u[-n:])),
            "first10_mean_ms": 1e3 * float(u[:n].mean()),
            "last10_mean_ms": 1e3 * float(u[-n:].mean()),
            "p99_ms": 1e3 * float(np.percentile(u, 99)), "total_cpu": r["total_cpu"]}


def run_fixed_lag(lag: float, gtsam: bool = False, warm: int = 500) -> dict:
    s = window_stream(lag)
    play(_FgoptLag(s, lag), s, limit=warm)            # warm-up: kernel loads
    lib = _FgoptLag(s, lag)
    r = play(lib, s)
    out = {"fixed_lag": lag, "steps": len(s.steps), "fgopt": flatness(r)}
    n = len(lib.sizes) // 10
    out["fgopt"]["bytes_at_10pct"] = int(lib.sizes[n])
    out["fgopt"]["bytes_at_50pct"] = int(lib.sizes[5 * n])
    out["fgopt"]["bytes_at_end"] = int(lib.sizes[-1])
    out["fgopt"]["window"] = len(lib.lag)
    if gtsam:
        g = _GtsamLag(s, lag)
        try:
            out["GTSAM"] = flatness(play(g, s))
        except RuntimeError as e:        # its failure is a result too
            out["GTSAM"] = {"error": str(e).strip().splitlines()[0] + " " +
                            str(e).strip().splitlines()[1]}
    return out


def report(out: dict) -> str:
    rows = [f"Fixed lag {out['fixed_lag']:g} poses on w20000 ({out['steps']} updates)", "",
            "| library | first 10 % median / mean ms | last 10 % median / mean ms | p99 ms | "
            "total CPU s | arrays at 10 % / 50 % / end |", "|---|---|---|---|---|---|"]
    for lib in ("fgopt", "GTSAM"):
        f = out.get(lib)
        if f is None:
            continue
        if "error" in f:
            rows.append(f"| {lib} | {f['error']} | | | | |")
            continue
        mem = (f"{f['bytes_at_10pct'] / 1e6:.2f} / {f['bytes_at_50pct'] / 1e6:.2f} / "
               f"{f['bytes_at_end'] / 1e6:.2f} MB" if "bytes_at_end" in f else "-")
        rows.append(f"| {lib} | {f['first10_median_ms']:.3f} / {f['first10_mean_ms']:.3f} | "
                    f"{f['last10_median_ms']:.3f} / {f['last10_mean_ms']:.3f} | "
                    f"{f['p99_ms']:.2f} | "
                    f"{f['total_cpu']:.2f} | {mem} |")
    return "\n".join(rows)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--lag", type=float, default=100.0)
    ap.add_argument("--gtsam", action="store_true")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    out = run_fixed_lag(args.lag, args.gtsam)
    print(report(out))
    print(f"({time.perf_counter() - t0:.0f} s wall)")


if __name__ == "__main__":
    main()
