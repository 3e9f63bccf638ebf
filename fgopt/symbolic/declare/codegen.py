"""Generated module of a declared manifold: programs -> batched numba kernels + per-value Python.

One module per declaration (cached on disk like factor kernels, :mod:`fgopt.symbolic.cache`):

* ``_retract_kernel(_x, _d, _out)``, ``_local_kernel(_a, _b, _out)``,
  ``_storage_D_tangent_kernel(_x, _out)`` and ``_normalize_kernel(_x, _out)`` (when declared):
  one loop over rows with flat CSE'd code, compiled with ``numba.njit(cache=True)`` through
  :func:`fgopt._jit.njit` (numba is imported, and the kernel compiled or loaded, on first call);
* their NumPy twins ``_retract_numpy`` ... (the same program on whole columns), run by the
  wrappers under the same rule as factor kernels (:func:`fgopt.symbolic.runtime.use_numpy`:
  small batches while the process's twin budget lasts), so declaring a manifold and solving its
  first small graph imports no numba and compiles nothing; a kernel whose program has no NumPy
  form (:func:`~fgopt.symbolic.printer.to_numpy_source`) keeps its numba kernel only;
* wrappers ``retract_batch(x, d)``, ``local_batch(a, b)``, ``storage_D_tangent_batch(x)``,
  ``normalize_batch(x)`` over ``(n, storage_dim)`` / ``(n, dim)`` arrays (the
  :class:`~fgopt.manifolds.base.BatchKind` entries);
* plain-Python functions of one value, same printed code: ``retract_one(x_0, ..., d_0, ...)``,
  ``local_one``, ``storage_D_tangent_one``, ``normalize_one``, ``accessor_<name>`` (no compile
  at import: the numeric value type calls these);
* ``IDENTITY``, ``RETRACT_CODE`` (the retract's printed statements, for code that inlines it,
  e.g. the fixed formulation) and ``META``.

:func:`module_source` also returns the Python-only part alone, which the declaration checks
execute before anything is written to the cache.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from ..cse import Program, optimize, total_ops
from .derive import Programs

#: Bump when the layout of generated manifold modules changes (part of every declaration key).
DECLARE_CODEGEN_VERSION = "3"  # 2: deferred numba, NumPy twins; 3: bodies as LLVM IR


def _program(exprs: list) -> Program:
    return optimize(Program([], {"out": list(exprs)}))


def _used(prog: Program) -> set:
    used: set = set()
    for _, e in prog.stmts:
        used |= e.free_symbols
    for e in prog.all_outputs():
        used |= getattr(e, "free_symbols", set())
    return used


def _kernel(name: str, prog: Program, inputs: Sequence[tuple[str, list]], out: str,
            index: Any, doc: str) -> str:
    from .._ir import kernel_source

    params = [arr for arr, _ in inputs] + [out]
    loads = {s: (j, (k,)) for j, (_, syms) in enumerate(inputs) for k, s in enumerate(syms)}
    stores = {"out": (len(inputs), lambda k: tuple(int(x) for x in str(index(k)).split(",")))}
    return kernel_source(name, prog, params, loads, stores, doc, total_ops(prog))


def _numpy_twin(name: str, prog: Program, inputs: Sequence[tuple[str, list]], out: str,
                index: Any, kernel: str) -> str | None:
    """The NumPy twin of :func:`_kernel`'s loop (rows -> whole columns), or ``None`` when an
    expression has no NumPy form."""
    from ..printer import to_numpy_source

    used = _used(prog)
    params = ", ".join([arr for arr, _ in inputs] + [out])
    lines = [f"def {name}({params}):", f'    """NumPy twin of ``{kernel}`` (small batches)."""']
    for arr, syms in inputs:
        lines += [f"    {s.name} = {arr}[:, {k}]" for k, s in enumerate(syms) if s in used]
    for s, e in prog.stmts:
        src = to_numpy_source(e)
        if src is None:
            return None
        lines.append(f"    {s.name} = {src}")
    for k, e in enumerate(prog.outputs["out"]):
        src = to_numpy_source(e)
        if src is None:
            return None
        lines.append(f"    {out}[:, {index(k)}] = {src}")
    return "\n".join(lines) + "\n"


def _python(name: str, prog: Program, params: list, doc: str) -> str:
    from ..printer import to_source

    lines = [f"def {name}({', '.join(s.name for s in params)}):", f'    """{doc}"""']
    lines += [f"    {s.name} = {to_source(e)}" for s, e in prog.stmts]
    lines.append("    return [" + ", ".join(to_source(e) for e in prog.outputs["out"]) + "]")
    return "\n".join(lines) + "\n"


def _wrapper(name: str, kernel: str, args: Sequence[tuple[str, str]], out_shape: str,
             doc: str, twin: str | None = None) -> str:
    lines = [f"def {name}({', '.join(a for a, _ in args)}):", f'    """{doc}"""']
    first = args[0][0]
    for a, cols in args:
        rows = "None" if a == first else f"{first}.shape[0]"
        lines.append(f"    {a} = as_rows({a}, {cols}, NAME, {a!r}, {rows})")
    lines.append(f"    _out = np.empty(({first}.shape[0], {out_shape}))")
    call = f"({', '.join(a for a, _ in args)}, _out)"
    if twin is None:
        lines.append(f"    {kernel}{call}")
    else:
        lines += [f"    if use_numpy({first}.shape[0]):",
                  "        t0 = perf_counter()",
                  "        with np.errstate(all='ignore'):  # as numba's error_model='numpy'",
                  f"            {twin}{call}",
                  "        charge_numpy(perf_counter() - t0)",
                  "    else:",
                  f"        {kernel}{call}"]
    lines.append("    return _out")
    return "\n".join(lines) + "\n"


def module_source(cls: type, progs: Programs, origin: str) -> tuple[str, str, dict]:
    """``(full module source, Python-only part, META)`` of declaration ``cls``."""
    from .._sym import EPSILON_VALUE
    from ..printer import to_source

    n, dim, name = cls._STORAGE_DIM, cls._DIM, cls.__name__
    retract = _program(progs.retract)
    local = _program(progs.local)
    sdt = _program(progs.storage_D_tangent)
    normalize = _program(progs.normalize) if progs.normalize is not None else None
    ops = {"retract": total_ops(retract), "local": total_ops(local),
           "storage_D_tangent": total_ops(sdt)}
    if normalize is not None:
        ops["normalize"] = total_ops(normalize)
    retract_code = {"stmts": [(s.name, to_source(e)) for s, e in retract.stmts],
                    "out": [to_source(e) for e in retract.outputs["out"]],
                    "x": [s.name for s in progs.x], "d": [s.name for s in progs.d]}
    meta = {"name": name, "storage_dim": n, "dim": dim, "ops": ops,
            "normalize": normalize is not None, "identity": progs.identity,
            "accessors": {a.name: {"kind": a.kind, "shape": list(a.shape), "type": a.type_name}
                          for a in progs.accessors},
            "fields": list(cls._FIELDS)}
    py = [
        "import math",
        "",
        "import numpy as np",
        "",
        f"EPSILON = {EPSILON_VALUE!r}",
        "nan, inf = math.nan, math.inf  # SymPy's nan / oo print as these names",
        f"IDENTITY = {progs.identity!r}",
        f"RETRACT_CODE = {retract_code!r}",
        "",
        _python("retract_one", retract, progs.x + progs.d,
                "x (+) d of one value (normalized); storage list."),
        _python("local_one", local, progs.a + progs.b, "b (-) a of one value; tangent list."),
        _python("storage_D_tangent_one", sdt, progs.x,
                f"d S(x (+) v)/dv at 0, row-major ({n} x {dim})."),
    ]
    if normalize is not None:
        py.append(_python("normalize_one", normalize, progs.x, "normalize(x); storage list."))
    for a in progs.accessors:
        py.append(_python(f"accessor_{a.name}", _program(a.exprs), progs.x,
                          f"{a.name}(x), flat ({a.kind})."))
    python_part = "\n".join(py)
    header = [
        "# " + "-" * 98,
        "# Autogenerated by fgopt.symbolic.declare.codegen (template: "
        "fgopt/symbolic/declare/codegen.py).",
        f"# Declared manifold: {name} (storage {n}, tangent {dim})",
        f"#   at {origin}",
        "# Do NOT modify by hand: edit the declaration instead.",
        "# " + "-" * 98,
        f"# total ops: {', '.join(f'{k} {v}' for k, v in ops.items())}",
        "# ruff: noqa",
        "# fmt: off",
        f'"""Generated kernels of the declared manifold ``{name}``."""',
        "",
        "from time import perf_counter",
        "",
        "from fgopt._jit import njit",
        "from fgopt.symbolic._ir import Body",
        "from fgopt.symbolic.declare.runtime import as_rows",
        "from fgopt.symbolic.runtime import charge_numpy, use_numpy",
        "",
        f"NAME = {name!r}",
        f"STORAGE_DIM = {n}",
        f"DIM = {dim}",
        f"META = {meta!r}",
        "",
    ]
    row = f"Rows: _x (n, {n}), _d (n, {dim})"
    # (op, program, inputs, output index, kernel doc, wrapper args, output shape, wrapper doc)
    specs = [
        ("retract", retract, [("_x", progs.x), ("_d", progs.d)], lambda k: k,
         f"{row} -> _out (n, {n}) = normalize(retract(x, d)).",
         [("x", "STORAGE_DIM"), ("d", "DIM")], "STORAGE_DIM",
         "Batched retract: (n, storage_dim), (n, dim) -> (n, storage_dim)."),
        ("local", local, [("_a", progs.a), ("_b", progs.b)], lambda k: k,
         f"_a, _b (n, {n}) -> _out (n, {dim}) = local(a, b).",
         [("a", "STORAGE_DIM"), ("b", "STORAGE_DIM")], "DIM",
         "Batched local: (n, storage_dim) x 2 -> (n, dim)."),
        ("storage_D_tangent", sdt, [("_x", progs.x)], lambda k: f"{k // dim}, {k % dim}",
         f"_x (n, {n}) -> _out (n, {n}, {dim}).", [("x", "STORAGE_DIM")], "STORAGE_DIM, DIM",
         "Batched storage_D_tangent: (n, storage_dim) -> (n, storage_dim, dim)."),
    ]
    if normalize is not None:
        specs.append(("normalize", normalize, [("_x", progs.x)], lambda k: k,
                      f"_x (n, {n}) -> _out (n, {n}) = normalize(x).", [("x", "STORAGE_DIM")],
                      "STORAGE_DIM", "Batched normalize: (n, storage_dim) -> (n, storage_dim)."))
    parts = ["\n".join(header), python_part]
    for op, prog, inputs, index, kdoc, wargs, shape, wdoc in specs:
        kernel = f"_{op}_kernel"
        parts.append(_kernel(kernel, prog, inputs, "_out", index, kdoc))
        twin = _numpy_twin(f"_{op}_numpy", prog, inputs, "_out", index, kernel)
        if twin is not None:
            parts.append(twin)
        parts.append(_wrapper(f"{op}_batch", kernel, wargs, shape, wdoc,
                              f"_{op}_numpy" if twin is not None else None))
    return "\n\n".join(parts), python_part, meta
