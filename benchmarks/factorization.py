"""Sparse factorization of LM's damped J^T J at the initial guess: block Cholesky vs CHOLMOD.

    python -m benchmarks.factorization [--datasets sphere2500,torus3D] [--orderings amd,metis]
                                       [--reps 9]

Datasets: the 3D / 2D pose graphs of BENCHMARKS.md and Ladybug-49's full BA system. For every
dataset and every fill-reducing ordering of the variable graph (``Problem(ordering=)``),
H (with LM damping ``diag *= 1.0001``, plus ``1e-6``) is factored by CHOLMOD simplicial, CHOLMOD
supernodal (both told ``natural``: the problem already ordered the variables) and fgopt's
``BlockCholeskySolver``, interleaved, ``--reps`` times after a warm-up. CHOLMOD runs as fgopt
calls it, its OpenMP loops serial (``fgopt.solvers.linear.cholmod.serial_openmp``); the column
``super omp`` is the supernodal factorization with CHOLMOD's own team of 4 OpenMP threads (what
a plain scikit-sparse call gets: ``OMP_NUM_THREADS`` does not limit it). Printed: medians of the
wall time (ms) and of the thread CPU time (the machine is shared: CPU time is the steadier
figure), block / CHOLMOD-supernodal ratios, exact ``nnz(L)`` and the block solver's stored
entries (relaxed supernodes hold explicit zeros), its multiply-adds, solve times, and the
agreement of the two solutions.
Single-threaded (``OMP/OPENBLAS/NUMBA_NUM_THREADS=1`` unless already set).
"""

from __future__ import annotations

import os

# No OMP_THREAD_LIMIT here (the other benchmarks set it): the "super omp" column times CHOLMOD
# with its own OpenMP team, which that limit would make serial too.
for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse
import time
import warnings
from pathlib import Path

import numpy as np

DATASETS = {
    "sphere2500": "pose3d/sphere2500.g2o",
    "torus3D": "pose3d/torus3D.g2o",
    "garage": "pose3d/parking-garage.g2o",
    "cubicle": "pose3d/cubicle.g2o",
    "M3500": "pose2d/input_M3500_g2o.g2o",
    "ladybug49": "bal/problem-49-7776-pre.txt",   # the full BA system (no Schur complement)
}
ORDERINGS = ("amd", "metis", "nesdis", "colamd")


def data_dir() -> Path:
    env = os.environ.get("FGOPT_DATA")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[1].parent / "shared" / "data"


def damped_system(graph, values, ordering):
    """H at the initial guess with LM damping (BA has no gauge prior: a tiny shift keeps it PD)."""
    import fgopt

    p = fgopt.Problem(graph, values, ordering=ordering)
    p.linearize(p.initial_state())
    H = p.H_data.copy()
    H[p.pattern.diag_pos] *= 1.0001
    H[p.pattern.diag_pos] += 1e-6
    return p.pattern, H, p.g.copy()


def _timed(fn):
    w, c = time.perf_counter(), time.thread_time()
    out = fn()
    return time.perf_counter() - w, time.thread_time() - c, out


def bench_one(pattern, H, g, reps):
    from sksparse.cholmod import analyze

    from fgopt.solvers.linear.block_cholesky import BlockCholeskySolver
    from fgopt.solvers.linear.cholmod import serial_openmp

    def serial(fn):
        def run():
            with serial_openmp():
                return fn()
        return run

    A = pattern.matrix(H)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t_an = time.perf_counter()
        block = BlockCholeskySolver()
        block.analyze(pattern)
        t_an = time.perf_counter() - t_an
        sup = analyze(A, mode="supernodal", ordering_method="natural")
        simp = analyze(A, mode="simplicial", ordering_method="natural")
        block.factorize(H)
        serial(lambda: sup.cholesky_inplace(A))()
        t_simp = _timed(serial(lambda: simp.cholesky_inplace(A)))[0]
        simp_reps = reps if t_simp < 0.3 else min(reps, 3)  # simplicial takes seconds on torus
        times = {k: ([], []) for k in ("block", "super", "super_omp", "simpl", "block_solve",
                                       "super_solve")}
        for r in range(reps):
            for key, fn in (("block", lambda: block.factorize(H)),
                            ("block_solve", lambda: block.solve(g)),
                            ("super", serial(lambda: sup.cholesky_inplace(A))),
                            ("super_omp", lambda: sup.cholesky_inplace(A)),
                            ("super_solve", lambda: sup(g)),
                            ("simpl", serial(lambda: simp.cholesky_inplace(A)))):
                if key == "simpl" and r >= simp_reps:
                    continue
                w, c, _ = _timed(fn)
                times[key][0].append(w)
                times[key][1].append(c)
        x_block, x_sup = block.solve(g), sup(g)
    nnz_chol = int(simp.L().nnz)  # exact nnz(L): simplicial stores no explicit zeros
    med = {k: (1e3 * float(np.median(v[0])), 1e3 * float(np.median(v[1])))
           for k, v in times.items()}
    agree = float(np.linalg.norm(x_block - x_sup) / np.linalg.norm(x_sup))
    return {"med": med, "nnz_chol": nnz_chol, "nnz_block": block.nnz_factor,
            "flops": _flops(block), "analyze": t_an, "agree": agree,
            "supernodes": int(block.symbolic.width.shape[0])}


def _flops(block) -> float:
    """Multiply-adds of the supernodal factorization (explicit zeros included)."""
    w = block.symbolic.width.astype(float)
    m = block.symbolic.rows.astype(float)
    r = m - w
    return float((w ** 3 / 6 + r * w * w / 2 + r * r * w / 2).sum())


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--datasets", default=",".join(DATASETS))
    ap.add_argument("--orderings", default=",".join(ORDERINGS))
    ap.add_argument("--reps", type=int, default=9)
    args = ap.parse_args(argv)
    from fgopt.io.g2o import read_g2o

    print(f"load average at start: {os.getloadavg()[0]:.2f} (2-core machine)")
    print("times in ms, median of", args.reps, "(wall / thread CPU); ratio = block / CHOLMOD "
          "supernodal (wall, CPU)")
    header = (f"{'dataset':10s} {'order':6s} {'nnzL':>9s} {'stored':>9s} {'MFMA':>6s} "
              f"{'simplicial':>13s} {'supernodal':>13s} {'super omp':>13s} {'block':>13s} "
              f"{'ratio':>10s} "
              f"{'solve blk':>9s} {'solve chol':>10s} {'agree':>7s}")
    print(header)
    best = {}
    for name in args.datasets.split(","):
        path = data_dir() / DATASETS[name]
        if not path.is_file():
            print(f"{name}: {path} not found (set FGOPT_DATA)")
            continue
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if path.suffix == ".txt":
                from fgopt.io.bal import read_bal

                graph, values = read_bal(path)
            else:
                graph, values = read_g2o(path, add_prior=True, repair_information="clip")
        for order in args.orderings.split(","):
            pattern, H, g = damped_system(graph, values, order)
            r = bench_one(pattern, H, g, args.reps)
            m = r["med"]
            ratio = (m["block"][0] / m["super"][0], m["block"][1] / m["super"][1])
            pair = {k: f"{v[0]:6.1f}/{v[1]:6.1f}" for k, v in m.items()}
            print(f"{name:10s} {order:6s} {r['nnz_chol']:9d} {r['nnz_block']:9d} "
                  f"{r['flops'] / 1e6:6.0f} {pair['simpl']} {pair['super']} {pair['super_omp']} "
                  f"{pair['block']} "
                  f"{ratio[0]:4.2f}/{ratio[1]:4.2f} {m['block_solve'][1]:9.2f} "
                  f"{m['super_solve'][1]:10.2f} {r['agree']:7.0e}", flush=True)
            if name not in best or m["block"][1] < best[name][1]:
                best[name] = (order, m["block"][1])
    print("best ordering for the block solver (CPU time):",
          ", ".join(f"{k}: {v[0]}" for k, v in best.items()))
    print(f"load average at end: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
