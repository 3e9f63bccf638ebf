"""Generated source of a small-problem driver: one module per *set of kernels*.

A driver linearizes a problem made of the kernels it was generated for, whatever the number of
factors and variables (the structure comes in as arrays), and runs the dense LM of
:data:`fgopt.solvers.small._lm_template.LM_TEMPLATE` (the general path's
:func:`fgopt.solvers._lm_loop.lm_loop` on dense operations) around it, all compiled: no Python between
iterations. Each kernel is called once per linearization on its whole batch (the kernel's own
numba function, :class:`~fgopt.factors.kernel.CompiledCall`), then whitened and added into a
dense H by an ``_acc<slot>`` function generated with the kernel's sizes as literals (or, for a
``hessian`` call such as a smart factor's Schur complement, the kernel adds its own ``J^T J``).

The entry point is ``_solve(x0, problem, prm, iw, fw, hist)`` (it writes the final storage
into ``x0``, the caller's scratch copy, and the iterations into ``hist``): ``problem`` is
``(block_keys, var_kind, var_row, var_dim, kind_sdim, kind_gid, slots)``: the variables' keys
(strictly ascending), kinds, rows and dims as :class:`~fgopt.problem.Problem` numbers them
(storage dims and Lie group ids per kind), with one ``(keys, consts, R)`` tuple per kernel in
the driver's kernel order (each factor's keys, constants, square-root information ``(0 | 1 |
n, r, r)``; the argument dims are literals of the generated code). ``_solve`` finds each
factor's variables among ``block_keys``
(:func:`fgopt._structure_kernels.block_var_idx_into`: a missing or repeated key, keys not
ascending, a factor of another arity or a variable no factor uses return status -2 before any
work; a compiled Problem passes ``block_keys = arange(V)`` and its factors' variable indices as
keys), lays the variables out (:func:`fgopt.solvers.small._common.layout_into`) and runs
``_lm_core`` on ``aux``:
``(slots, layout)`` with per kernel ``(soff, toff, consts, R, work)``, each argument's storage /
tangent offsets and the kernel's work arrays (its arguments' rows, residuals and Jacobians: made
once per solve, not per linearization), the ``(V, 5)`` layout of
:func:`fgopt.solvers.small._common.retract` and H's envelope (per row, the first column a factor
can fill: the dense Cholesky skips what lies before it) -- in the compiled call, not as Python
work per solve. All of these, and ``_lm_core``'s scratch, are views of the two arenas the
caller passes (``iw`` integers, ``fw`` floats, of at least ``arena_sizes(V, K, n, nx,
counts)``, a plain Python function of the module).

``_solve`` and everything it calls but a ``_lin`` over kernels that return new arrays count no
references (numba's ``_nrt=False``): on this machine each atomic increment or decrement is
~7 ns, and the driver took hundreds per solve (a 2-pose solve's compiled part 9.1 -> 8.0 us,
5 iterations 32 -> 28 us, measured before the arenas moved to the caller). So nothing in them
may return a new array (its reference would never be released: a test counts numba's
allocations).

Modules live in fgopt's kernel cache (:mod:`fgopt.symbolic.cache`), keyed by the kernels' calls
and shapes, this template and fgopt's version; numba caches their machine code.
"""

from __future__ import annotations

import hashlib
from typing import Any


#: Bumped when the emitted source changes meaning (part of the cache key).
SMALL_CODEGEN_VERSION = "14"
#: ``_acc`` functions with at most this many whitened Jacobian entries (``r * D``) are inlined.
INLINE_MAX_WORK = 18
#: What a loaded module must define (else it is regenerated).
REQUIRED = ("_lin", "_retract", "_lm", "_solve", "arena_sizes", "KERNELS")


def signature(kernel: Any) -> tuple:
    """What a driver's code depends on for one kernel: its call and its shapes."""
    c = kernel.compiled_call
    return ((c.module, c.function, c.prefix, c.suffix, c.fills, c.hessian, c.specialized),
            tuple(k.storage_dim for k in kernel.arg_kinds), kernel.residual_dim,
            kernel.tangent_dim, tuple(k.dim for k in kernel.arg_kinds))


def module_key(signatures: tuple) -> str:
    # (imported here: only small problems need them)
    from ...symbolic import cache as _cache
    from ._lm_template import lm_source

    h = hashlib.sha256(repr(signatures).encode())
    h.update(SMALL_CODEGEN_VERSION.encode())
    h.update(lm_source("n").encode())
    h.update(_cache.package_fingerprint().encode())
    return h.hexdigest()[:20]


def accumulate_source(slot: int, r: int, tdims: tuple) -> str:
    """``_acc<slot>(res, jac, toff, R, H, g, wr, wJ)``: add one batch's whitened ``J^T J`` to ``H`` (both
    triangles) and ``J^T r`` to ``g``, return its cost ``0.5 sum |R_i r_i|^2``.

    ``res (n, r)``, ``jac (n, r, D)``: the kernel's unwhitened residuals and Jacobians (argument
    ``p``'s columns at ``sum(tdims[:p])``); ``toff (n, k)``: each argument's tangent offset in H;
    ``R``: ``(0, r, r)`` for unit noise, ``(1, r, r)`` one square-root information for all rows,
    or ``(n, r, r)``; ``wr (r,)``, ``wJ (D, r)``: scratch (the driver's, made once per solve).
    Sizes are literals, so LLVM unrolls the small products, and each ``(p, q)``
    block with ``p <= q`` is computed once and mirrored (toyExample's 6 Pose3 between rows with
    full square-root information: 3.5 us, 8.5 us in a runtime-sized loop).
    """
    offs = [sum(tdims[:p]) for p in range(len(tdims))]
    D = sum(tdims)
    L = [f"def _acc{slot}(res, jac, toff, R, H, g, wr, wJ):",
         "    # wJ is transposed: column c of R_i J_i is its row c",
         "    n = res.shape[0]",
         "    cost = 0.0",
         "    for i in range(n):",
         "        if R.shape[0] == 0:",
         f"            for a in range({r}):",
         "                wr[a] = res[i, a]",
         f"                for c in range({D}):",
         "                    wJ[c, a] = jac[i, a, c]",
         "        else:",
         "            Ri = R[i] if R.shape[0] > 1 else R[0]",
         f"            for a in range({r}):",
         "                s = 0.0",
         f"                for b in range({r}):",
         "                    s += Ri[a, b] * res[i, b]",
         "                wr[a] = s",
         f"                for c in range({D}):",
         "                    s = 0.0",
         f"                    for b in range({r}):",
         "                        s += Ri[a, b] * jac[i, b, c]",
         "                    wJ[c, a] = s",
         f"        for a in range({r}):",
         "            cost += 0.5 * wr[a] * wr[a]"]
    for p, dp in enumerate(tdims):
        L += [f"        t{p} = toff[i, {p}]",
              f"        for u in range({dp}):",
              "            s = 0.0",
              f"            for a in range({r}):",
              f"                s += wJ[{offs[p]} + u, a] * wr[a]",
              f"            g[t{p} + u] += s"]
    for p, dp in enumerate(tdims):
        for q in range(p, len(tdims)):
            first = "u" if q == p else "0"
            L += [f"        for u in range({dp}):",
                  f"            for v in range({first}, {tdims[q]}):",
                  "                s = 0.0",
                  f"                for a in range({r}):",
                  f"                    s += wJ[{offs[p]} + u, a] * wJ[{offs[q]} + v, a]",
                  f"                H[t{p} + u, t{q} + v] += s"]
            L += ([f"                if v != u:", f"                    H[t{q} + v, t{p} + u] += s"]
                  if q == p else [f"                H[t{q} + v, t{p} + u] += s"])
    L += ["    return cost", "", ""]
    # a small batch's accumulation is inlined into _lin (numba IR): the call with its eight
    # array arguments cost more than the work (noisyToyGraph's SE(2) factors: 5 iterations
    # 22.0 -> 20.9 us); 3D kernels' larger ones gained nothing (tinyGrid3D: 2 % slower)
    inline = ', inline="always"' if r * D <= INLINE_MAX_WORK else ""
    deco = ('@numba.njit(cache=True, fastmath={"reassoc", "contract"}, error_model="numpy", '
            f'nogil=True, _nrt=False{inline})')
    return "\n".join([deco] + L)


def module_source(signatures: tuple, names: tuple) -> str:
    """The driver module for kernels with these :func:`signature` s (in slot order)."""
    from ._lm_template import lm_source

    imports, body, accs, work = [], [], [], []
    for j, ((mod, fn, prefix, suffix, fills, hessian, specialized), sdims, r, D, tdims) in \
            enumerate(signatures):
        imports.append(f"_k{j} = sys.modules[{mod!r}].{fn}" if specialized is None else
                       f"_k{j} = specialized_copy(sys.modules[{mod!r}].{fn}, {specialized})")
        body.append(f"    # slot {j}: {names[j]}")
        body.append(f"    soff, toff, consts, R, work = slots[{j}]")
        if hessian:  # the kernel adds its own J^T J (unit noise: R unused)
            work.append([])
            body.append(f"    P, rows = stacked(x, soff, {sdims[0]})")
            body.append(f"    cost = _k{j}({prefix}P, rows, consts{suffix}, toff, H, g, cost)")
            continue
        # the arguments' storage rows (and the kernel's outputs when it fills them): made once
        # per solve by _solve, not per linearization
        args = [f"a{a}" for a in range(len(sdims))]
        shapes = [(f"n{j}", s) for s in sdims]
        if fills:
            args_out = args + ["res", "jac"]
            shapes += [(f"n{j}", r), (f"n{j}", r, D)]
        else:
            args_out = args
        shapes += [(r,), (D, r)]  # _acc's scratch
        work.append(shapes)
        body.append(f"    {', '.join(args_out)}, wr, wJ = work")
        for a in range(len(sdims)):
            body.append(f"    gather(x, soff, {a}, a{a})")
        if fills:
            body.append(f"    _k{j}({prefix}{', '.join(args)}, consts, res, jac)")
        else:
            body.append(f"    res, jac = _k{j}({prefix}{', '.join(args)}, consts{suffix})")
        body.append(f"    cost += _acc{j}(res, jac, toff, R, H, g, wr, wJ)")
        accs.append(accumulate_source(j, r, tdims))
    # without reference counting where nothing returns a new array (see lm_source): everything
    # but _solve, which allocates, and a _lin calling kernels that return their outputs
    counted = any(not fills or hessian for (_, _, _, _, fills, hessian, _), *_ in signatures)
    # (explicit both ways: numba compiles a callee without its own _nrt with its caller's)
    lin_flags = ", _nrt=True" if counted else ", _nrt=False"
    head = [
        "# " + "-" * 98,
        "# Autogenerated by fgopt.solvers.small (template: fgopt/solvers/small/_driver.py and",
        "# fgopt/solvers/small/_lm_template.py's LM_TEMPLATE). Do NOT modify by hand.",
        "# " + "-" * 98,
        "# ruff: noqa",
        "# fmt: off",
        f'"""Small-problem driver: dense LM over kernels {", ".join(names)}."""',
        "",
        "import math",
        "import sys",
        "",
        "import numba",
        "import numpy as np",
        "",
        "from fgopt._jit import specialized_copy",
        "from fgopt._structure_kernels import block_var_idx_into",
        "from fgopt.solvers.small._common import (clear, envelope_into, gather, layout_into,",
        "                                         retract, stacked, take_into, widen_envelope)",
        "",
        *imports,
        f"KERNELS = {names!r}",
        "",
        *accs,
        "",
        # (the accumulators' flags: an inlined one is compiled with _lin's)
        '@numba.njit(cache=True, fastmath={"reassoc", "contract"}, error_model="numpy", '
        f'nogil=True{lin_flags})',
        "def _lin(x, aux, H, g):",
        '    """Dense H (both triangles), g and the cost at storage x."""',
        "    slots = aux[0]",
        "    clear(H, g, aux[2])",
        "    cost = 0.0",
        *body,
        "    return cost",
        "",
        "",
        '@numba.njit(cache=True, error_model="numpy", nogil=True, _nrt=False)',
        "def _retract(x, delta, out, tmp, aux):",
        "    retract(x, delta, out, tmp, aux[1])",
        "",
        "",
        "# (inlined: a call returning an array would hold a reference _lm_core never releases)",
        '@numba.njit(cache=True, error_model="numpy", nogil=True, inline="always")',
        "def _envelope(aux, n):",
        "    return aux[2]",
        "",
    ]
    k = len(signatures)
    arity = [len(sig[1]) for sig in signatures]
    floats, carve = [], []
    for j in range(k):
        names_j = []
        for b, shape in enumerate(work[j]):
            size = " * ".join(str(d) for d in shape)
            floats.append(size)
            view = f"fw[q:q + {size}]" + ("" if len(shape) == 1 else
                                          f".reshape(({', '.join(str(d) for d in shape)}))")
            carve += [f"    w{j}_{b} = {view}", f"    q += {size}"]
            names_j.append(f"w{j}_{b}")
        work[j] = f"({', '.join(names_j)},)" if names_j else "()"
    tup = "," if k == 1 else ""
    slots = ", ".join(f"(so{j}, to{j}, s{j}[1], s{j}[2], {work[j]})" for j in range(k))
    unpack = ", ".join(f"s{j}" for j in range(k))
    counts = ", ".join(f"n{j}" for j in range(k))
    fail = "        return -2, 0, 0.0, 0, 0.0, 0.0"
    numbering = []
    for j in range(k):
        numbering += [f"    v{j} = iw[o:o + n{j} * {arity[j]}].reshape((n{j}, {arity[j]}))",
                      f"    o += n{j} * {arity[j]}",
                      f"    fresh = block_var_idx_into(block_keys, s{j}[0], used, v{j})",
                      "    if fresh < 0:", fail,
                      "    seen += fresh"]
    per_factor = []
    for j in range(k):
        for name, src in (("so", "soff"), ("to", "toff"), ("dm", "var_dim")):
            per_factor += [f"    {name}{j} = iw[o:o + n{j} * {arity[j]}].reshape((n{j}, {arity[j]}))",
                           f"    o += n{j} * {arity[j]}",
                           f"    take_into({src}, v{j}, {name}{j})"]
        per_factor.append(f"    widen_envelope(first, to{j}, dm{j})")
    work_size = " + ".join(floats) if floats else "0"
    ints = "8 * V + K + 1 + n + " + " + ".join(f"4 * n{j} * {arity[j]}" for j in range(k))
    # work arrays, H and g, _lm_core's zw (Hc, L, gc) and ew (x, xc, Hd, Dg, rhs, delta, tmp)
    floats_total = f"{work_size} + 4 * n * n + 5 * n + 2 * nx + 8"
    solve = [
        "",
        "",
        "def arena_sizes(V, K, n, nx, counts):",
        '    """(integers, floats) of _solve\'s arenas for V variables of K kinds, tangent and',
        '    storage dimensions n and nx, counts[j] factors of kernel j."""',
        f"    {counts}{tup} = counts",
        f"    return {ints}, {floats_total}",
        "",
        "",
        '@numba.njit(cache=True, error_model="numpy", nogil=True, _nrt=False)',
        "def _solve(x0, problem, prm, iw, fw, hist):",
        '    """_lm on a problem given as variables and per-kernel factors (see the module',
        '    docstring of fgopt.solvers.small._driver), everything laid out in the arenas iw',
        '    and fw (arena_sizes; any contents) with the history in hist: the final storage',
        '    written into x0, _lm\'s tuple without x (status -1: x0 kept, not finite there; -2:',
        '    the factors\' keys do not number the variables, or arenas too small)."""',
        "    block_keys, var_kind, var_row, var_dim, kind_sdim, kind_gid, slots = problem",
        f"    {unpack}{tup} = slots",
        *[f"    n{j} = s{j}[0].shape[0]" for j in range(k)],
        "    V = block_keys.shape[0]",
        "    K = kind_sdim.shape[0]",
        "    nx = x0.shape[0]",
        "    n = 0",
        "    for v in range(var_dim.shape[0]):",
        "        n += var_dim[v]",
        "    if (" + " or ".join(f"s{j}[0].shape[1] != {arity[j]}" for j in range(k))
        + f" or iw.shape[0] < {ints}",
        f"            or fw.shape[0] < {floats_total}):",
        fail,
        "    used = iw[:V]",
        "    for v in range(V):",
        "        used[v] = 0",
        "    o = V",
        "    seen = 0",
        *numbering,
        "    if seen != V:",
        fail,
        "    base = iw[o:o + K + 1]",
        "    for t in range(K + 1):",
        "        base[t] = 0",
        "    soff = iw[o + K + 1:o + K + 1 + V]",
        "    toff = iw[o + K + 1 + V:o + K + 1 + 2 * V]",
        "    layout = iw[o + K + 1 + 2 * V:o + K + 1 + 7 * V].reshape((V, 5))",
        "    o += K + 1 + 7 * V",
        "    layout_into(var_kind, var_row, var_dim, kind_sdim, kind_gid, base, soff, toff, layout)",
        "    first = iw[o:o + n]",
        "    o += n",
        "    envelope_into(toff, var_dim, first)",
        *per_factor,
        "    q = 0",
        *carve,
        "    H = fw[q:q + n * n].reshape((n, n))  # (read only on the envelope)",
        "    g = fw[q + n * n:q + n * n + n]",
        "    q += n * n + n",
        f"    aux = (({slots}{tup}), layout, first)",
        "    # (_lm_core's zw need not be zeros: _lin clears H and g on the envelope first, and",
        "    # the Cholesky reads L only where it has written it)",
        "    zw = fw[q:q + 2 * n * n + n]",
        "    q += 2 * n * n + n",
        "    status, msg, val, its, cost, init = _lm_core(x0, aux, prm, hist, H, g, zw, fw[q:])",
        "    if status >= 0:",
        "        for i in range(nx):",
        "            x0[i] = fw[q + i]",
        "    return status, msg, val, its, cost, init",
        "",
    ]
    return "\n".join(head) + lm_source("H.shape[0]", counted=False) + "\n".join(solve)
