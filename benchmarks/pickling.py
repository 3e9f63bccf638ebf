"""What a solved problem costs to ship: pickling a ``Result`` (and its ``Variables``).

    python -m benchmarks.pickling [--repeat 5]

For M3500 and sphere2500 (perturbed as in :mod:`benchmarks.many`, seed 0), solved with LM on the
numba backend as ``solve_many``'s workers do. Reported per file, best of ``--repeat``:

- dump: ``pickle.dumps`` of a fresh ``Result`` (its values not yet built, as on a worker), ms;
- load: ``pickle.loads`` of that blob in this process, ms; and load followed by reading every
  value once (``values.at`` of each key: what a client that uses all values pays), ms;
- size of the blob, and of the final values' raw storage floats (what cannot be avoided).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import pickle
import time

os.environ.setdefault("FGOPT_NUMPY_BUDGET", "0")


def measure(name: str, repeat: int) -> dict:
    import numpy as np

    import fgopt

    from .many import perturbed

    result = fgopt.optimize(*perturbed(name, 0), backend="numba")
    dump, load, use = [], [], []
    for _ in range(repeat):
        fresh = dataclasses.replace(result, _values=None)  # as the worker holds it
        t0 = time.perf_counter()
        blob = pickle.dumps(fresh, protocol=pickle.HIGHEST_PROTOCOL)
        dump.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        back = pickle.loads(blob)
        load.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        back = pickle.loads(blob)
        vals = back.values
        for k in vals:
            vals.at(k)
        use.append(time.perf_counter() - t0)
    raw = sum(np.asarray(s).nbytes for s in result.state.storages)
    same = all(np.array_equal(np.asarray(result.values.at(k).to_storage()),
                              np.asarray(back.values.at(k).to_storage()))
               for k in result.values)
    return {"file": name, "variables": len(result.values), "dump_ms": min(dump) * 1e3,
            "load_ms": min(load) * 1e3, "load_use_ms": min(use) * 1e3, "bytes": len(blob),
            "raw_bytes": raw, "bitwise_equal": same}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    print("| file | variables | dump ms | load ms | load + read all ms | MB | raw MB | "
          "bitwise equal |")
    print("|---|---|---|---|---|---|---|---|")
    for name in ("m3500", "sphere2500"):
        r = measure(name, args.repeat)
        print(f"| {r['file']} | {r['variables']} | {r['dump_ms']:.1f} | {r['load_ms']:.1f} | "
              f"{r['load_use_ms']:.1f} | {r['bytes'] / 1e6:.3f} | {r['raw_bytes'] / 1e6:.3f} | "
              f"{r['bitwise_equal']} |")


if __name__ == "__main__":
    main()
