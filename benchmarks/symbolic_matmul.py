"""SymForce paper Sec. VIII-A: the sparse matrix-product experiment, ``X^T Y``.

``X`` and ``Y`` share a random sparsity pattern (sizes / densities of the paper's SuiteSparse
matrices: b1_ss 7x7 31 %, n3c4-b2 20x15 20 %, lp_sc105-like 100x100 7 %; the SuiteSparse files
are not used, patterns are drawn with a fixed seed). Their nonzeros are random expressions of 5
scalar symbols with about 5 arithmetic operations each (random trees of ``+ - * /``, in the
spirit of Lample and Charton's generator). Per product we time

* **flattened**: one generated numba kernel (CSE over entries and product) computing the
  nonzeros of ``X^T Y`` directly from the 5 symbols, batched over ``n`` symbol vectors;
* **scipy.sparse**: a numba kernel evaluates the nonzeros of X and of Y (batched), then per
  product ``csr(X).T @ csr(Y)`` (scipy's per-call overhead included, as Eigen's in the paper);
* **dense numpy**: the same entry kernel, then ``X.T @ Y`` per product, and batched
  (``np.matmul`` over a ``(n, rows, cols)`` stack: numpy's best case).

Times are ns per product (wall time / n). The 100x100 flattened program has ~1.3 10^4 ops; numba
types and lowers every operation (~5-9 ms each), so it is compiled as chunks of <= 2500 ops and
takes minutes to build.

    .venv/bin/python -m benchmarks.symbolic_matmul [--sizes 7x7:0.31,20x15:0.20,100x100:0.07]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OMP_THREAD_LIMIT", "OPENBLAS_NUM_THREADS",
             "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # single thread, as the other benchmarks (README)

import argparse
import random
import time

import numpy as np


def random_expr(rng: random.Random, syms: list, ops: int):
    """A random expression tree over ``syms`` with about ``ops`` operations."""
    if ops <= 0:
        return rng.choice(syms) if rng.random() < 0.8 else rng.choice([2, 3, -1, 0.5])
    op = rng.randrange(4)
    left = rng.randint(0, ops - 1)
    a, b = random_expr(rng, syms, left), random_expr(rng, syms, ops - 1 - left)
    if op == 0:
        return a + b
    if op == 1:
        return a - b
    if op == 2:
        return a * b
    return a / (b * b + 1)


def _pattern(rows: int, cols: int, density: float, seed: int) -> np.ndarray:
    rs = np.random.default_rng(seed)
    mask = rs.random((rows, cols)) < density
    mask[rs.integers(rows), :] |= ~mask.any(axis=0)  # no empty column
    return mask


def _kernel(symbols: list, exprs: list, name: str, max_ops: int = 2500):
    """Batched numba kernel: (n, 5) symbol values -> (n, len(exprs)) outputs.

    Programs above ``max_ops`` operations are split into several njit functions by output
    chunks (each with the statements it needs; numba's compile time and memory grow quickly
    with function size), called one after the other.
    """
    import numba

    from fgopt.symbolic.cse import Program, optimize, prune, total_ops
    from fgopt.symbolic.printer import to_source

    prog = optimize(Program([], {"out": exprs}))
    ops = total_ops(prog)
    nchunks = max(1, -(-ops // max_ops))
    size = -(-len(exprs) // nchunks)
    funcs = []
    for c in range(nchunks):
        outs = prog.outputs["out"][c * size:(c + 1) * size]
        stmts = prune(prog.stmts, outs)
        fname = f"{name}_{c}"
        lines = ["import math", "import numba", "EPSILON = 2.220446049250313e-15",
                 "@numba.njit(cache=False, fastmath=False, error_model='numpy')",
                 f"def {fname}(v, out):", "    for _i in range(v.shape[0]):"]
        lines += [f"        {s.name} = v[_i, {k}]" for k, s in enumerate(symbols)]
        lines += [f"        {s.name} = {to_source(e)}" for s, e in stmts]
        lines += [f"        out[_i, {c * size + k}] = {to_source(e)}" for k, e in enumerate(outs)]
        env: dict = {}
        exec(compile("\n".join(lines) + "\n", f"<{fname}>", "exec"), env)  # noqa: S102
        funcs.append(env[fname])
    del numba
    if len(funcs) == 1:
        return funcs[0], ops

    def run(v, out):
        for f in funcs:
            f(v, out)

    return run, ops


def _sparse_product(nz: np.ndarray, xs: list, ys: list) -> dict:
    """Nonzeros of X^T Y: ``{(i, j): sum_k X[k, i] Y[k, j]}`` over the shared pattern."""
    import sympy

    by_row: dict = {}
    for (k, i), ex in zip(nz, xs):
        by_row.setdefault(int(k), []).append((int(i), ex))
    terms: dict = {}
    for (k, j), ey in zip(nz, ys):
        for i, ex in by_row.get(int(k), []):
            terms.setdefault((i, int(j)), []).append(ex * ey)
    return {ij: sympy.Add(*t) for ij, t in sorted(terms.items())}


def run_case(rows: int, cols: int, density: float, n: int, seed: int = 0) -> dict:
    import scipy.sparse as sps
    import sympy

    from fgopt.symbolic import symbols

    syms = list(symbols("s0 s1 s2 s3 s4"))
    mask = _pattern(rows, cols, density, seed)
    nz = np.argwhere(mask)
    rng = random.Random(seed)
    xs = [sympy.sympify(random_expr(rng, syms, 5)) for _ in nz]
    ys = [sympy.sympify(random_expr(rng, syms, 5)) for _ in nz]
    t0 = time.perf_counter()
    P = _sparse_product(nz, xs, ys)
    out_nz = list(P)
    flat, flat_ops = _kernel(syms, [P[ij] for ij in out_nz], "flat")
    entries, entry_ops = _kernel(syms, xs + ys, "entries")
    vals = np.random.default_rng(1).normal(size=(n, 5))
    out = np.empty((n, len(out_nz)))
    flat(vals, out)
    ent = np.empty((n, 2 * len(nz)))
    entries(vals, ent)
    build = time.perf_counter() - t0

    t = time.perf_counter()
    flat(vals, out)
    t_flat = (time.perf_counter() - t) / n * 1e9

    k = len(nz)
    csr_x = sps.csr_matrix((np.ones(k), (nz[:, 0], nz[:, 1])), shape=(rows, cols))
    order = np.lexsort((nz[:, 1], nz[:, 0]))  # csr data order
    m = min(n, 2000)
    t = time.perf_counter()
    entries(vals[:m], ent[:m])
    for i in range(m):
        Xs = sps.csr_matrix((ent[i, :k][order], csr_x.indices, csr_x.indptr), shape=(rows, cols))
        Ys = sps.csr_matrix((ent[i, k:][order], csr_x.indices, csr_x.indptr), shape=(rows, cols))
        prod = Xs.T @ Ys
    t_sparse = (time.perf_counter() - t) / m * 1e9

    Xd = np.zeros((max(m, min(n, int(4e7 // (rows * cols * 8)))), rows, cols))
    Yd = np.zeros_like(Xd)
    t = time.perf_counter()
    entries(vals[:m], ent[:m])
    for i in range(m):
        Xd[i, nz[:, 0], nz[:, 1]] = ent[i, :k]
        Yd[i, nz[:, 0], nz[:, 1]] = ent[i, k:]
        prod_d = Xd[i].T @ Yd[i]
    t_dense = (time.perf_counter() - t) / m * 1e9
    mb = min(n, max(m, int(4e7 // (rows * cols * 8))))  # stacks of at most ~40 MB
    t = time.perf_counter()
    entries(vals[:mb], ent[:mb])
    Xd[:mb, nz[:, 0], nz[:, 1]] = ent[:mb, :k]
    Yd[:mb, nz[:, 0], nz[:, 1]] = ent[:mb, k:]
    prod_b = np.matmul(Xd[:mb].transpose(0, 2, 1), Yd[:mb])
    t_batched = (time.perf_counter() - t) / mb * 1e9
    # all agree
    ref = np.array([prod_b[mb - 1][i, j] for i, j in out_nz])
    np.testing.assert_allclose(out[mb - 1], ref, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(prod_d, prod_b[m - 1], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(prod.toarray(), prod_b[m - 1], rtol=1e-9, atol=1e-9)
    return {"size": f"{rows}x{cols}", "density": f"{mask.mean():.0%}", "nnz": k,
            "out nnz": len(out_nz), "flat ops": flat_ops, "entry ops": entry_ops,
            "flattened": t_flat, "scipy.sparse": t_sparse, "dense numpy": t_dense,
            "dense batched": t_batched, "build s": build}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="7x7:0.31,20x15:0.20,100x100:0.07")
    ap.add_argument("--n", type=int, default=20000)
    args = ap.parse_args()
    cols = ["size", "density", "nnz", "out nnz", "flat ops", "entry ops", "flattened",
            "scipy.sparse", "dense numpy", "dense batched", "build s"]
    print("## X^T Y, ns per product\n")
    print("| " + " | ".join(cols) + " |")
    print("|" + "---|" * len(cols))
    for spec in args.sizes.split(","):
        shape, dens = spec.split(":")
        r, c = (int(v) for v in shape.split("x"))
        row = run_case(r, c, float(dens), args.n)
        print("| " + " | ".join(f"{row[k]:.1f}" if isinstance(row[k], float) else str(row[k])
                                for k in cols) + " |", flush=True)


if __name__ == "__main__":
    main()
