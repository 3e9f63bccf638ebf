"""Generated source of a small-problem driver: one module per *set of kernels*.

A driver linearizes a problem made of the kernels it was generated for, whatever the number of
factors and variables (the structure comes in as arrays), and runs the dense LM of
:data:`fgopt.solvers.fixed._codegen.LM_TEMPLATE` around it, all compiled: no Python between
iterations. Each kernel is called once per linearization on its whole batch (the kernel's own
numba function, :class:`~fgopt.factors.kernel.CompiledCall`), then whitened and added into a
dense H by an ``_acc<slot>`` function generated with the kernel's sizes as literals (or, for a
``hessian`` call such as a smart factor's Schur complement, the kernel adds its own ``J^T J``).

The entry point is ``_solve(x0, problem, prm)`` (it writes the final storage into ``x0``, the
caller's scratch copy): ``problem`` is ``(block_keys, var_kind,
var_row, var_dim, kind_sdim, kind_gid, slots)``: the variables' keys (strictly ascending), kinds,
rows and dims as :class:`~fgopt.problem.Problem` numbers them (storage dims and Lie group ids per
kind), with one ``(keys, consts, R)`` tuple per kernel in the driver's kernel order (each factor's
keys, constants, square-root information ``(0 | 1 | n, r, r)``; the argument dims are literals of
the generated code). ``_solve`` finds each factor's variables among ``block_keys``
(:func:`fgopt._structure_kernels.block_var_idx`: a missing or repeated key, keys not ascending or
a variable no factor uses return status -2 before any work; a compiled Problem passes
``block_keys = arange(V)`` and its factors' variable indices as keys), lays the variables out
(:func:`fgopt.solvers.small._common.layout_of`) and runs ``_lm`` on ``aux``:
``(slots, layout)`` with per kernel ``(soff, toff, consts, R, work)``, each argument's storage /
tangent offsets and the kernel's work arrays (its arguments' rows, residuals and Jacobians: made
once per solve, not per linearization), the ``(V, 5)`` layout of
:func:`fgopt.solvers.small._common.retract` and H's envelope (per row, the first column a factor
can fill: the dense Cholesky skips what lies before it) -- in the compiled call, not as Python
work per solve.

Modules live in fgopt's kernel cache (:mod:`fgopt.symbolic.cache`), keyed by the kernels' calls
and shapes, this template and fgopt's version; numba caches their machine code.
"""

from __future__ import annotations

import hashlib
from typing import Any

from ..fixed._codegen import LM_TEMPLATE

#: Bumped when the emitted source changes meaning (part of the cache key).
SMALL_CODEGEN_VERSION = "11"
#: ``_acc`` functions with at most this many whitened Jacobian entries (``r * D``) are inlined.
INLINE_MAX_WORK = 18
#: What a loaded module must define (else it is regenerated).
REQUIRED = ("_lin", "_retract", "_lm", "_solve", "KERNELS")


def signature(kernel: Any) -> tuple:
    """What a driver's code depends on for one kernel: its call and its shapes."""
    c = kernel.compiled_call
    return ((c.module, c.function, c.prefix, c.suffix, c.fills, c.hessian),
            tuple(k.storage_dim for k in kernel.arg_kinds), kernel.residual_dim,
            kernel.tangent_dim, tuple(k.dim for k in kernel.arg_kinds))


def module_key(signatures: tuple) -> str:
    from ...symbolic import cache as _cache

    h = hashlib.sha256(repr(signatures).encode())
    h.update(SMALL_CODEGEN_VERSION.encode())
    h.update(LM_TEMPLATE.encode())
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
            f'nogil=True{inline})')
    return "\n".join([deco] + L)


def module_source(signatures: tuple, names: tuple) -> str:
    """The driver module for kernels with these :func:`signature` s (in slot order)."""
    imports, body, accs, work = [], [], [], []
    for j, ((mod, fn, prefix, suffix, fills, hessian), sdims, r, D, tdims) in enumerate(
            signatures):
        imports.append(f"_k{j} = sys.modules[{mod!r}].{fn}")
        body.append(f"    # slot {j}: {names[j]}")
        body.append(f"    soff, toff, consts, R, work = slots[{j}]")
        if hessian:  # the kernel adds its own J^T J (unit noise: R unused)
            work.append("()")
            body.append(f"    P, rows = stacked(x, soff, {sdims[0]})")
            body.append(f"    cost = _k{j}({prefix}P, rows, consts{suffix}, toff, H, g, cost)")
            continue
        # the arguments' storage rows (and the kernel's outputs when it fills them): made once
        # per solve by _solve, not per linearization
        args = [f"a{a}" for a in range(len(sdims))]
        bufs = [f"np.empty((n{j}, {s}))" for s in sdims]
        if fills:
            args_out = args + ["res", "jac"]
            bufs += [f"np.empty((n{j}, {r}))", f"np.empty((n{j}, {r}, {D}))"]
        else:
            args_out = args
        bufs += [f"np.empty({r})", f"np.empty(({D}, {r}))"]  # _acc's scratch
        work.append(f"({', '.join(bufs)},)")
        body.append(f"    {', '.join(args_out)}, wr, wJ = work")
        for a in range(len(sdims)):
            body.append(f"    gather(x, soff, {a}, a{a})")
        if fills:
            body.append(f"    _k{j}({prefix}{', '.join(args)}, consts, res, jac)")
        else:
            body.append(f"    res, jac = _k{j}({prefix}{', '.join(args)}, consts{suffix})")
        body.append(f"    cost += _acc{j}(res, jac, toff, R, H, g, wr, wJ)")
        accs.append(accumulate_source(j, r, tdims))
    head = [
        "# " + "-" * 98,
        "# Autogenerated by fgopt.solvers.small (template: fgopt/solvers/small/_driver.py and",
        "# fgopt/solvers/fixed/_codegen.py's LM_TEMPLATE). Do NOT modify by hand.",
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
        "from fgopt._structure_kernels import block_var_idx",
        "from fgopt.solvers.small._common import (clear, envelope_of, gather, layout_of, retract,",
        "                                         stacked, widen_envelope)",
        "",
        *imports,
        f"KERNELS = {names!r}",
        "",
        *accs,
        "",
        # (the accumulators' flags: an inlined one is compiled with _lin's)
        '@numba.njit(cache=True, fastmath={"reassoc", "contract"}, error_model="numpy", '
        'nogil=True)',
        "def _lin(x, aux, H, g):",
        '    """Dense H (both triangles), g and the cost at storage x."""',
        "    slots = aux[0]",
        "    clear(H, g, aux[2])",
        "    cost = 0.0",
        *body,
        "    return cost",
        "",
        "",
        '@numba.njit(cache=True, error_model="numpy", nogil=True)',
        "def _retract(x, delta, out, tmp, aux):",
        "    retract(x, delta, out, tmp, aux[1])",
        "",
        "",
        '@numba.njit(cache=True, error_model="numpy", nogil=True)',
        "def _envelope(aux, n):",
        "    return aux[2]",
        "",
    ]
    slots = ", ".join(f"(soff[v{j}], to{j}, s{j}[1], s{j}[2], {work[j]})"
                      for j in range(len(signatures)))
    unpack = ", ".join(f"s{j}" for j in range(len(signatures)))
    numbering = []
    for j in range(len(signatures)):
        numbering += [f"    v{j}, fresh = block_var_idx(block_keys, s{j}[0], used)",
                      "    if fresh < 0:",
                      "        return -2, 0, 0.0, 0, 0.0, 0.0, np.empty((1, 8))",
                      "    seen += fresh"]
    solve = [
        "",
        "",
        '@numba.njit(cache=True, error_model="numpy", nogil=True)',
        "def _solve(x0, problem, prm):",
        '    """_lm on a problem given as variables and per-kernel factors (see the module',
        '    docstring of fgopt.solvers.small._driver): the final storage written into x0,',
        '    _lm\'s tuple without x and the history (status -1: x0 kept, not finite there; -2:',
        '    the factors\' keys do not number the variables)."""',
        "    block_keys, var_kind, var_row, var_dim, kind_sdim, kind_gid, slots = problem",
        f"    {unpack}{',' if len(signatures) == 1 else ''} = slots",
        "    used = np.zeros(block_keys.shape[0], dtype=np.bool_)",
        "    seen = 0",
        *numbering,
        "    if seen != block_keys.shape[0]:",
        "        return -2, 0, 0.0, 0, 0.0, 0.0, np.empty((1, 8))",
        "    soff, toff, layout = layout_of(var_kind, var_row, var_dim, kind_sdim, kind_gid)",
        *[f"    n{j} = v{j}.shape[0]" for j in range(len(signatures))],
        "    n = 0",
        "    for v in range(var_dim.shape[0]):",
        "        n += var_dim[v]",
        "    first = envelope_of(toff, var_dim, n)",
        *[f"    to{j} = toff[v{j}]" for j in range(len(signatures))],
        *[f"    widen_envelope(first, to{j}, var_dim[v{j}])" for j in range(len(signatures))],
        f"    aux = (({slots}{',' if len(signatures) == 1 else ''}), layout, first)",
        "    hist = np.empty((max(int(prm[0]), 1), 8))",
        "    H = np.zeros((n, n))  # (zero outside the envelope)",
        "    g = np.empty(n)",
        "    x, status, msg, val, its, cost, init = _lm(x0, aux, prm, hist, H, g)",
        "    if status >= 0:",
        "        for i in range(x0.shape[0]):  # (returning x would box a second array)",
        "            x0[i] = x[i]",
        "    return status, msg, val, its, cost, init, hist",
        "",
    ]
    return "\n".join(head) + LM_TEMPLATE.replace("{n}", "H.shape[0]") + "\n".join(solve)
