"""Cold (derive + compile) and warm (cached, new process) load time of generated factors.

For the Pose3 between factor and the BAL reprojection factor, two fresh Python processes share
an empty cache directory (``FGOPT_CACHE_DIR``). Each imports fgopt, makes one instance and calls
``linearize`` and ``residual`` once. Reported per process:

* ``import``: ``import fgopt`` + the library module (numpy, numba, scipy, fgopt);
* ``numba init``: the process's first call of any cached numba function (a manifold retract);
  numba pays this once per process whatever fgopt does;
* ``factor ready``: from creating the instance until both kernels have run once -- derivation,
  code generation and compilation when cold; reading the cached module and loading numba's
  cached machine code when warm (target: warm < 0.5 s);
* ``sympy``: whether SymPy was imported (it must not be on a warm start).

    .venv/bin/python -m benchmarks.symbolic_load_time
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OMP_THREAD_LIMIT", "OPENBLAS_NUM_THREADS",
             "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # single thread, as the other benchmarks (README)

import json
import subprocess
import sys
import tempfile
import textwrap

CHILD = textwrap.dedent('''
    import json, sys, time
    t0 = time.perf_counter()
    import numpy as np
    import fgopt
    from fgopt.manifolds import SE3
    from fgopt.symbolic import cache
    from fgopt.factors.library import generated, reprojection
    t_import = time.perf_counter() - t0
    t = time.perf_counter()
    SE3.identity().retract(np.zeros(6))
    t_numba = time.perf_counter() - t
    which = sys.argv[1]
    t = time.perf_counter()
    if which == "between_pose3":
        f = generated.between_pose3(fgopt.key("x", 0), fgopt.key("x", 1), SE3.random(0))
        args = (np.array([SE3.random(1).to_storage()]), np.array([SE3.random(2).to_storage()]))
    else:
        f = reprojection.bal_reprojection(fgopt.key("c", 0), fgopt.key("p", 0), [1.0, 2.0])
        args = (np.array([[0.1, 0.2, 0.3, 0.1, 0.2, -5.0, 500.0, 1e-7, 1e-13]]),
                np.array([[0.5, -0.2, 1.0]]))
    c = f.constants.reshape(1, -1)
    f.kernel.linearize(args, c)
    f.kernel.residual(args, c)
    t_ready = time.perf_counter() - t
    mod = sys.modules[f.kernel.linearize.__module__]
    print(json.dumps({"import": t_import, "numba init": t_numba, "factor ready": t_ready,
                      "derived": cache.STATS["derived"], "sympy": "sympy" in sys.modules,
                      "ops": mod.META["ops"]}))
''')


def run(which: str, cache_dir: str) -> dict:
    env = {**os.environ, "FGOPT_CACHE_DIR": cache_dir}
    out = subprocess.run([sys.executable, "-c", CHILD, which], env=env, capture_output=True,
                         text=True, timeout=1800, check=False)
    if out.returncode != 0:
        raise RuntimeError(out.stderr)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    print("## Generated factors: cold vs warm load (seconds)\n")
    print("| factor | start | import | numba init | factor ready | derived | sympy | ops |")
    print("|---|---|---|---|---|---|---|---|")
    for which in ("between_pose3", "bal_reprojection"):
        with tempfile.TemporaryDirectory() as d:
            for start in ("cold", "warm"):
                r = run(which, d)
                print(f"| {which} | {start} | {r['import']:.2f} | {r['numba init']:.2f} | "
                      f"{r['factor ready']:.3f} | {r['derived']} | {r['sympy']} | "
                      f"{r['ops']['residual']} / {r['ops']['linearize']} |", flush=True)


if __name__ == "__main__":
    main()
