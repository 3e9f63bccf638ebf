"""Scatter kernels specialized to a batch's shape (residual size, argument dims, unit noise).

:func:`fgopt._assembly.scatter_batch` handles any shape with run-time loop bounds; for the
small fixed sizes of real factors (3 x (3 + 3) for SE(2) betweens, 6 x (6 + 6) in 3D, 2 x
(9 + 3) for BAL) the compiler can neither unroll its loops nor keep the whitened Jacobian in
registers. This module writes the same computation with the sizes as literals, one module per
shape in the kernel cache (:mod:`fgopt.symbolic.cache`, ``numba.njit(cache=True)``), so the
machine code is compiled once per machine and shape. Measured on intel (2,512 SE(2) betweens):
0.66 ms -> 0.13 ms per linearization's scatter.

Only batches with at most :data:`MAX_ARGS` arguments and :data:`MIN_FACTORS` factors are
specialized (the generic kernel serves the rest: a specialization costs a one-time compile of
about a second).
"""

from __future__ import annotations

from typing import Any, Callable

from ._assembly import WIDE_RESIDUAL

#: Set False to use the generic kernel everywhere (A/B measurements).
ENABLED = True
MAX_ARGS = 3
#: Arguments of a specialized kernel with a wide residual (its local product is one D x D
#: array; an IMU factor has 5 arguments, a combined one 6).
MAX_ARGS_WIDE = 6
MAX_DIM = 16
#: Batches smaller than this keep the generic kernel (its compile is already paid for).
MIN_FACTORS = 64
_VERSION = "5"
_cache: dict[tuple, Callable] = {}


def _source(m: int, dims: tuple[int, ...], unit: bool) -> str:
    k = len(dims)
    offs = [sum(dims[:p]) for p in range(k)]
    D = sum(dims)
    L = []
    a = L.append
    a("import numpy as np")
    a("from numba import njit")
    a("from fgopt.noise.robust import rho_and_weight")
    a("")
    a("")
    a("@njit(cache=True, nogil=True)")
    a("def scatter(res, jac, sqrt_info, loss_code, loss_param, loss_shape, toff, pos, col_shift, "
      "H_data, g, weights, cost):")
    a("    n = res.shape[0]")
    if m >= WIDE_RESIDUAL:
        a(f"    Hl = np.empty(({D}, {D}))")
    if not unit:
        a(f"    r = np.empty({m})")
        a(f"    J = np.empty(({m}, {D}))")
    a("    for i in range(n):")
    if unit:
        a("        r = res[i]")
        a("        J = jac[i]")
    else:
        a("        R = sqrt_info[i]")
        a("        e = res[i]")
        a("        Jr = jac[i]")
        if m >= WIDE_RESIDUAL:  # row by row, as _assembly._whiten_rows (same sums)
            a(f"        for t in range({m}):")
            a("            acc = 0.0")
            a(f"            for col in range({D}):")
            a("                J[t, col] = 0.0")
            a(f"            for c in range(t, {m}):")
            a("                coef = R[t, c]")
            a("                if coef == 0.0:")
            a("                    continue")
            a("                acc += coef * e[c]")
            a(f"                for col in range({D}):")
            a("                    J[t, col] += coef * Jr[c, col]")
            a("            r[t] = acc")
        else:
            a(f"        for t in range({m}):")
            a("            acc = 0.0")
            a(f"            for c in range(t, {m}):")
            a("                acc += R[t, c] * e[c]")
            a("            r[t] = acc")
            a(f"            for col in range({D}):")
            a("                acc = 0.0")
            a(f"                for c in range(t, {m}):")
            a("                    acc += R[t, c] * Jr[c, col]")
            a("                J[t, col] = acc")
    a("        s = 0.0")
    a(f"        for t in range({m}):")
    a("            s += r[t] * r[t]")
    a("        rho, w = rho_and_weight(loss_code, loss_param, loss_shape, s)")
    a("        cost += rho")
    a("        weights[i] = w")
    a("        if w == 0.0:")
    a("            continue")
    for p in range(k):
        a(f"        gb = toff[i, {p}]")
        a(f"        for x in range({dims[p]}):")
        a("            acc = 0.0")
        a(f"            for t in range({m}):")
        a(f"                acc += J[t, {offs[p]} + x] * r[t]")
        a("            g[gb + x] += w * acc")
    if m >= WIDE_RESIDUAL:
        _wide_blocks(a, m, dims, offs, D)
    else:  # each entry of the block: its column of J^T J summed in place
        def entry(ind: str, p: int, q: int) -> None:
            a(f"{ind}acc = 0.0")
            a(f"{ind}for t in range({m}):")
            a(f"{ind}    acc += J[t, {offs[p]} + x] * J[t, {offs[q]} + y]")
            a(f"{ind}H_data[base + x] += w * acc")

        _scatter_blocks(a, dims, entry)
    a("    return cost")
    return "\n".join(L) + "\n"


def _scatter_blocks(a: Callable, dims: tuple[int, ...], entry: Callable) -> None:
    """The loops adding each argument pair's block of ``w J^T J`` into H through the scatter map
    (diagonal blocks: lower triangle; off-diagonal ones stored in one orientation only, ``pos <
    0`` in the other); ``entry(indent, p, q)`` emits the statements for entry ``(x, y)``."""
    k = len(dims)
    for p in range(k):
        for q in range(k):
            if p == q:  # diagonal block: lower triangle, column y starts at the diagonal
                a(f"        pq = pos[i, {p}, {p}]")
                a(f"        tq = toff[i, {q}]")
                a(f"        for y in range({dims[q]}):")
                a("            base = pq + col_shift[tq + y]")
                a(f"            for x in range(y, {dims[p]}):")
                entry("                ", p, q)
            else:
                a(f"        pq = pos[i, {p}, {q}]")
                a("        if pq >= 0:")
                a(f"            tq = toff[i, {q}]")
                a(f"            for y in range({dims[q]}):")
                a("                base = pq + col_shift[tq + y]")
                a(f"                for x in range({dims[p]}):")
                entry("                    ", p, q)


def _wide_blocks(a: Callable, m: int, dims: tuple[int, ...], offs: list[int], D: int) -> None:
    """The H part for residuals of ``WIDE_RESIDUAL`` rows or more, as the generic kernel's wide
    path (``_assembly._scatter_wide``): the lower triangle of the local ``D x D`` product
    ``J^T J`` by row outer products (zeros of J skipped; same summation order), then its blocks
    scattered, an upper block read transposed (the same products: half the work of the full
    square, IMU factor 9 x 24: 79 -> 67 us per 100 factors)."""
    a("        for x in range(%d):" % D)
    a("            for y in range(x + 1):")
    a("                Hl[x, y] = 0.0")
    a(f"        for t in range({m}):")
    a(f"            for x in range({D}):")
    a("                jx = J[t, x]")
    a("                if jx == 0.0:")
    a("                    continue")
    a("                for y in range(x + 1):")
    a("                    Hl[x, y] += jx * J[t, y]")

    def entry(ind: str, p: int, q: int) -> None:
        if p >= q:
            a(f"{ind}H_data[base + x] += w * Hl[{offs[p]} + x, {offs[q]} + y]")
        else:
            a(f"{ind}H_data[base + x] += w * Hl[{offs[q]} + y, {offs[p]} + x]")

    _scatter_blocks(a, dims, entry)


def scatter_kernel(m: int, dims: tuple[int, ...], unit: bool, n: int) -> Callable | None:
    """The specialized scatter for this shape, or ``None`` (use the generic kernel).

    Signature: ``(res, jac, sqrt_info, loss_code, loss_param, loss_shape, toff, pos, col_shift,
    H_data, g, weights, cost) -> cost`` plus this slice's cost, the same computation as
    ``scatter_batch`` (scatter map ``(pos, col_shift)``, :func:`fgopt.structure.scatter_positions`).
    """
    max_args = MAX_ARGS_WIDE if m >= WIDE_RESIDUAL else MAX_ARGS
    if (not ENABLED or n < MIN_FACTORS or not 0 < len(dims) <= max_args or max(dims) > MAX_DIM
            or m > MAX_DIM):
        return None
    shape = (int(m), tuple(int(d) for d in dims), bool(unit))
    fn = _cache.get(shape)
    if fn is None:
        from .symbolic import cache

        name = f"scatter_m{shape[0]}_d{'_'.join(map(str, shape[1]))}_{'u' if unit else 'w'}"
        key = cache.kernel_key(scatter_kernel, (shape, _VERSION), fingerprint=_fingerprint())
        module = cache.load(name, key) or cache.store(name, key, _source(*shape))
        fn = _cache[shape] = module.scatter
    return fn


def _fingerprint() -> str:
    import hashlib
    from pathlib import Path

    return hashlib.sha256(Path(__file__).read_bytes()).hexdigest()


def specialize(batch: Any) -> Callable | None:
    """:func:`scatter_kernel` for a compiled problem's batch."""
    return scatter_kernel(batch.kernel.residual_dim, tuple(int(d) for d in batch.arg_dims),
                          batch.unit, len(batch.source))
