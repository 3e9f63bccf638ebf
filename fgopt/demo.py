"""``make demo``: solve a generated Manhattan-world 2D pose graph and show the result."""

from __future__ import annotations

import argparse
import time

import numpy as np

import fgopt
from fgopt.datasets import manhattan_2d


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--poses", type=int, default=3500)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--method", default="lm", choices=["lm", "gn", "dogleg"])
    ap.add_argument("--solver", default="auto",
                    choices=["auto", "block", "cholmod", "ldlt", "pcg", "dense"])
    ap.add_argument("--plot", default=None, help="write a before/after plot to this PNG")
    args = ap.parse_args(argv)

    t = time.perf_counter()
    data = manhattan_2d(args.poses, seed=args.seed)
    print(f"generated a Manhattan-world pose graph in {time.perf_counter() - t:.2f} s: "
          f"{args.poses} poses, {data.num_loop_closures} loop closures")
    print(data.graph)
    result = fgopt.optimize(data.graph, data.initial, method=args.method,
                            linear_solver=args.solver, verbose=True)
    print(result)
    err = [np.linalg.norm(result.values.at(k).translation() - data.truth.at(k).translation())
           for k in data.truth.keys()]
    err0 = [np.linalg.norm(data.initial.at(k).translation() - data.truth.at(k).translation())
            for k in data.truth.keys()]
    print(f"position error vs ground truth: initial guess mean {np.mean(err0):.3f} m "
          f"(max {np.max(err0):.3f}), optimized mean {np.mean(err):.3f} m (max {np.max(err):.3f})")
    print(f"final cost {result.final_cost:.6f} ({result.status.value})")
    if args.plot:
        from fgopt import plot

        plot.save_pose_graph(args.plot, data.graph, result.values, before=data.initial)
        print(f"wrote {args.plot}")
    return 0 if result.success else 1


if __name__ == "__main__":
    raise SystemExit(main())
