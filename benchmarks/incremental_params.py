"""How the defaults of ``IncrementalParams`` were chosen: fgopt alone on the streams of
``benchmarks/incremental.py``, one field changed at a time.

    python -m benchmarks.incremental_params [--datasets m3500,victoria] [--threshold 0.1]
"""

from __future__ import annotations

import argparse

import numpy as np

import fgopt
from benchmarks.incremental import FgoptAdapter, full_graph, load_stream, play

SWEEP = [dict(), dict(relinearize_skip=1), dict(relinearize_skip=3), dict(wildfire_threshold=0.0),
         dict(batch_threshold=0.5), dict(batch_threshold=0.8), dict(batch_threshold=2.0),
         dict(fill_refresh=float("inf")), dict(fill_refresh=1.5), dict(extra_steps=1)]


def sweep(name: str, threshold: float, skip: int, warm: int) -> str:
    """fgopt alone with one parameter changed at a time (measuring the defaults)."""
    s = load_stream(name)
    play(FgoptAdapter(s, threshold, skip), s, limit=warm)
    graph = None
    rows = [f"{name}: one IncrementalParams field changed from the defaults (threshold "
            f"{threshold:g}, skip {skip})", "",
            "| change | total CPU s | update p99 ms | step p99 ms | final cost | batch steps |",
            "|---|---|---|---|---|---|"]
    for change in SWEEP:
        lib = FgoptAdapter(s, threshold, skip)
        params = dict(relinearize_threshold=threshold, relinearize_skip=skip)
        params.update(change)
        lib.isam = fgopt.IncrementalSmoother(fgopt.IncrementalParams(**params))
        batches = []
        update = lib.isam.update

        def counted(*a, _u=update, **k):
            r = _u(*a, **k)
            batches.append(r.batch)
            return r

        lib.isam.update = counted
        r = play(lib, s)
        if graph is None:
            graph = full_graph(lib, s)
        label = ", ".join(f"{k}={v:g}" for k, v in change.items()) or "defaults"
        rows.append(f"| {label} | {r['total_cpu']:.2f} | "
                    f"{1e3 * np.percentile(r['update_cpu'], 99):.2f} | "
                    f"{1e3 * np.percentile(r['step_cpu'], 99):.2f} | "
                    f"{graph.error(lib.final()):.6f} | {sum(batches)} |")
        print(rows[-1], flush=True)
    return "\n".join(rows)



def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--datasets", default="m3500,victoria")
    ap.add_argument("--threshold", type=float, default=0.1)
    ap.add_argument("--skip", type=int, default=10)
    ap.add_argument("--warm", type=int, default=300)
    args = ap.parse_args(argv)
    for name in args.datasets.split(","):
        print(sweep(name.strip(), args.threshold, args.skip, args.warm) + "\n", flush=True)


if __name__ == "__main__":
    main()
