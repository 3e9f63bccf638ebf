"""GNC on real pose graphs with 10 % random wrong loop closures (issue 6).

    python -m benchmarks.gnc [--datasets m3500,sphere2500] [--loss gm,tls]

For each graph: solve the outlier-free graph with LM (the reference), add 10 % (of the edge
count) loop closures between random pose pairs with random relative poses (the file's median
noise model), then compare plain LM and GNC against the reference: max position error, number
of factors classified as outliers, time.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

import fgopt  # noqa: E402
from fgopt import SE2, SE3, BetweenFactor  # noqa: E402
from fgopt.solvers import GNCParams  # noqa: E402

DATA = os.environ.get("FGOPT_DATA", os.path.join(os.path.dirname(__file__), "..", "..", "shared",
                                                  "data"))
FILES = {"m3500": "pose2d/input_M3500_g2o.g2o", "sphere2500": "pose3d/sphere2500.g2o"}


def corrupt(graph, values, fraction, seed=0):
    rng = np.random.default_rng(seed)
    keys = values.keys()
    is3d = isinstance(values.at(keys[0]), SE3)
    out = fgopt.FactorGraph(list(graph))
    edge = next(f for f in graph if len(f.keys) == 2)
    n = int(fraction * len(graph))
    for _ in range(n):
        i, j = rng.choice(len(keys), 2, replace=False)
        while abs(int(i) - int(j)) <= 1:  # consecutive poses would pass for odometry
            i, j = rng.choice(len(keys), 2, replace=False)
        if is3d:
            m = SE3.exp(np.concatenate([rng.normal(size=3), rng.uniform(-10, 10, 3)]))
        else:
            m = SE2.from_xytheta(*rng.uniform(-10, 10, 2), rng.uniform(-np.pi, np.pi))
        out.add(BetweenFactor(keys[i], keys[j], m, edge.loss))
    return out, n


def max_error(values, reference):
    return max(float(np.linalg.norm(values.at(k).translation() - reference.at(k).translation()))
               for k in reference.keys())


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--datasets", default="m3500,sphere2500")
    ap.add_argument("--loss", default="gm,tls")
    args = ap.parse_args(argv)
    print("| graph | outliers added | method | flagged | max position error vs outlier-free (m) "
          "| time (s) |")
    print("|---|---|---|---|---|---|")
    for name in args.datasets.split(","):
        graph, values = fgopt.io.read(os.path.join(DATA, FILES[name]), add_prior=True)
        ref = fgopt.optimize(graph, values)
        bad, n = corrupt(graph, values, 0.10)
        t = time.perf_counter()
        plain = fgopt.optimize(bad, values)
        print(f"| {name} | {n} | LM | - | {max_error(plain.values, ref.values):.3g} | "
              f"{time.perf_counter() - t:.2f} |")
        for loss in args.loss.split(","):
            t = time.perf_counter()
            r = fgopt.optimize(bad, values, method="gnc", params=GNCParams(loss=loss))
            print(f"| {name} | {n} | GNC-{loss} | {r.info['outliers']} | "
                  f"{max_error(r.values, ref.values):.3g} | {time.perf_counter() - t:.2f} |",
                  flush=True)


if __name__ == "__main__":
    main()
