"""Fill-reducing orderings: fgopt's own AMD kernel (``"amd"`` once numba is in use,
:mod:`fgopt._amd`) against CHOLMOD's AMD (``"cholmod_amd"``, what ``"amd"`` is before), SuperLU's
multiple minimum degree (``"mmd"``, what ``"amd"`` falls back to without numba and without the
``fgopt[cholmod]`` extra) and METIS.

Per problem and ordering (of the variable graph, as fgopt orders): time to compute the ordering
(median of 5), nnz of the Cholesky factor of the scalar H in that order, and fgopt's block
Cholesky ``analyze`` and ``factorize`` time (median of 5) on H at the file's initial guess.

    python -m benchmarks.ordering            # needs scikit-sparse for the CHOLMOD rows
"""

from __future__ import annotations

import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("FGOPT_DATA", REPO.parent / "shared" / "data"))
if not DATA.is_dir():
    DATA = Path("/work/shared/data")
FILES = {"M3500": "pose2d/input_M3500_g2o.g2o", "intel": "pose2d/intel.g2o",
         "sphere2500": "pose3d/sphere2500.g2o", "torus3D": "pose3d/torus3D.g2o",
         "Ladybug-49": "bal/problem-49-7776-pre.txt"}


def _median_time(fn, repeats=5):
    out = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t)
    return statistics.median(out)


def main() -> int:
    import fgopt.io
    from fgopt.io import add_gauge_prior
    from fgopt.problem import Problem
    from fgopt.solvers.linear.block_cholesky import BlockCholeskySolver
    from fgopt.structure import fill_reducing_order
    from sksparse.cholmod import cholesky

    import numba  # noqa: F401  (in use: "amd" is fgopt's own kernel)

    rows = ["| problem | ordering | order time (ms) | nnz(L) | block analyze (ms) | "
            "block factorize (ms) |", "|---|---|---|---|---|---|"]
    for name, rel in FILES.items():
        path = DATA / rel
        if not path.is_file():
            continue
        graph, values = fgopt.io.read(str(path))
        if not rel.startswith("bal"):
            add_gauge_prior(graph, values)
        base = Problem(graph, values, ordering="natural")
        V = base.num_variables
        pi, pj = [], []
        for b in base.batches:
            vi = b.var_idx
            for p in range(vi.shape[1]):
                for q in range(p + 1, vi.shape[1]):
                    pi.append(vi[:, p])
                    pj.append(vi[:, q])
        pi, pj = np.concatenate(pi), np.concatenate(pj)
        for method in ("amd", "cholmod_amd", "mmd", "metis"):
            t_order = _median_time(lambda: fill_reducing_order(V, pi, pj, method))
            p = Problem(graph, values, ordering=method)
            p.linearize(p.initial_state())
            H = p.H_data.copy()
            H[p.pattern.diag_pos] += 1e-6 * np.abs(H[p.pattern.diag_pos]).max()
            L = cholesky(p.pattern.matrix(H), ordering_method="natural").L()
            solver = BlockCholeskySolver()
            solver.analyze(p.pattern)
            solver.factorize(H)
            t_an = _median_time(lambda: solver.analyze(p.pattern))
            t_fa = _median_time(lambda: solver.factorize(H))
            rows.append(f"| {name} | {method} | {1e3 * t_order:.1f} | {L.nnz} | "
                        f"{1e3 * t_an:.1f} | {1e3 * t_fa:.1f} |")
            print(rows[-1], file=sys.stderr, flush=True)
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
