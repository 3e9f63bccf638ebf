"""Per-process overheads of fgopt, measured inside one new process (prints JSON): import, the
first file read vs a second read of the same file, the first optimize vs a second one, and
how much of the first optimize was kernel loading (numba's cache loads, generated modules)."""

import json
import sys
import time

t0 = time.perf_counter()
import fgopt  # noqa: E402
import fgopt.io  # noqa: E402

out = {"import fgopt (+ io)": time.perf_counter() - t0}
path = sys.argv[1]
t = time.perf_counter()
graph, values = fgopt.io.read(path)
out["first read"] = time.perf_counter() - t
t = time.perf_counter()
fgopt.io.read(path)
out["second read"] = time.perf_counter() - t
if not path.endswith(".txt"):  # pose graphs: the CLI's gauge prior
    from fgopt.io import add_gauge_prior

    add_gauge_prior(graph, values)
t = time.perf_counter()
fgopt.optimize(graph, values)
out["first optimize"] = time.perf_counter() - t
t = time.perf_counter()
fgopt.optimize(graph, values)
out["second optimize"] = time.perf_counter() - t
from fgopt.symbolic import cache  # noqa: E402

out["generated modules loaded"] = cache.STATS["loaded"]
out["numba imported"] = "numba" in sys.modules
print(json.dumps(out))
