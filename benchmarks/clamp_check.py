"""Cost of reporting clamped symbolic functions (issue 10): the post-solve check vs a solve.

    .venv/bin/python -m benchmarks.clamp_check [--n 40000] [--reps 5]

Problem: ``n`` range factors ``sqrt(|q - p|^2) - r`` (an ``@fgopt.factor`` using the clamped
``fgopt.symbolic.sqrt``) between ``n / 4`` random 2-D points and their index neighbours, plus a
prior per point. Measured, medians of
``--reps`` runs on the compiled problem: one linearization (kernels + scatter), the whole LM
solve (``fgopt.optimize``), and ``clamp_hits`` (one ``clamp_arguments`` kernel call per batch
with clamps, at the final values: what every solve now adds once). The generated
``linearize`` kernel is unchanged: the clamp arguments are evaluated only by the check.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OMP_THREAD_LIMIT", "OPENBLAS_NUM_THREADS",
           "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_v] = "1"
# Warm-process figures: small batches on the compiled kernels from the first timed call (a
# process reaches this after 0.5 s of NumPy-twin work; see fgopt/_jit.py).
os.environ.setdefault("FGOPT_NUMPY_BUDGET", "0")

import argparse
import time

import numpy as np

import fgopt
from fgopt import FactorGraph, PriorFactor, Variables, key
from fgopt.noise import Isotropic
from fgopt.solvers.diagnostics import clamp_hits
from fgopt.symbolic import V2, Scalar, sqrt


@fgopt.factor
def clamp_bench_range(p: V2, q: V2, measured: Scalar) -> Scalar:
    d = q - p
    return Scalar(sqrt(d.dot(d)) - measured)


def build(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    m = max(2, n // 4)
    pts = rng.uniform(-50, 50, size=(m, 2))
    g, v = FactorGraph(), Variables()
    for i in range(m):
        v.add(key("p", i), pts[i] + rng.normal(size=2) * 0.1)
        g.add(PriorFactor(key("p", i), pts[i], Isotropic.sigma(2, 1.0)))
    # each point ranged to a few index neighbours: a banded graph (random pairs would make the
    # factorization dense and the benchmark about fill-in)
    a = rng.integers(0, m, size=n)
    b = (a + 1 + rng.integers(0, 4, size=n)) % m
    for i, j in zip(a.tolist(), b.tolist()):
        g.add(clamp_bench_range(p=key("p", i), q=key("p", j),
                                measured=float(np.linalg.norm(pts[j] - pts[i]))))
    return g, v


def median_s(fn, reps: int) -> float:
    ts = []
    for _ in range(reps):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return float(np.median(ts))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=40_000)
    ap.add_argument("--reps", type=int, default=5)
    args = ap.parse_args()
    g, v = build(args.n)
    problem = fgopt.Problem(g, v)
    state = problem.initial_state()
    problem.linearize(state)
    clamp_hits(problem, state)  # warm-up (numba loads the kernels)
    r = fgopt.optimize(g, v)
    t_lin = median_s(lambda: problem.linearize(state), args.reps)
    t_check = median_s(lambda: clamp_hits(problem, state), args.reps)
    t_solve = median_s(lambda: fgopt.optimize(g, v), max(1, args.reps // 2))
    print(f"{args.n} range factors (+{len(v)} priors), LM {r.iterations} iterations, "
          f"{r.num_clamped} clamp hits")
    print(f"  linearize      {1e3 * t_lin:9.2f} ms")
    print(f"  clamp check    {1e3 * t_check:9.2f} ms  ({t_check / t_lin:.2f}x one linearization)")
    print(f"  whole solve    {1e3 * t_solve:9.2f} ms  (check = {100 * t_check / t_solve:.2f} %)")


if __name__ == "__main__":
    main()
