"""Generated kernel modules: programs -> batched ``@numba.njit`` kernels and NumPy twins.

One module per factor type and variable pattern. It holds

* ``_residual_kernel(<vars>, _consts, _res)`` and ``_linearize_kernel(..., _res, _jac)``
  (plus ``_linearize_hessian_kernel(..., _hess, _rhs)`` on request): one ``for _i in range(n)``
  loop over instances calling the CSE'd program's body once per row, writing into preallocated
  arrays, compiled with ``numba.njit(cache=True, error_model="numpy")`` through
  :func:`fgopt._jit.njit` (numba is imported and the kernel compiled or loaded on first call).
  The body is an instruction table written straight into LLVM IR (:mod:`._ir`): a Pose3
  factor's kernels compile in ~0.2 s where numba's front end took ~6.6 s for the same program
  as Python source, and run as fast;
* ``_residual_numpy`` / ``_linearize_numpy``: NumPy twins, the same CSE'd program on whole
  columns (``a_0 = _a[:, 0]``...), when every expression has a NumPy form. Batches of at most
  ``fgopt.symbolic.runtime.NUMPY_MAX_BATCH`` instances run the twin while the process's twin
  budget lasts (:func:`fgopt._jit.numpy_budget_left`), so a small problem or a new custom
  factor needs no numba compilation and no cache load, and a
  process that keeps solving switches to the faster compiled kernels; inside
  :func:`fgopt._jit.numpy_mode` (a problem on the NumPy backend) every batch does
  (``runtime.use_numpy``);
* Python wrappers ``residual(args, consts)`` / ``linearize(args, consts)`` with the
  :class:`~fgopt.factors.kernel.FactorKernel` signature (they check shapes, allocate outputs and
  make one kernel call per batch, twin or numba kernel by batch size);
* ``META``: what the kernel computes (names, dims, op counts), read back on cache hits;
* for factors that call clamped functions (``sqrt``/``log``/``acos``/``asin`` of
  :mod:`fgopt.symbolic.functions`): ``_clamp_kernel`` / ``clamp_arguments(args, consts)`` with the
  clamped arguments, and ``META["clamps"]`` (function, bounds, the user's file:line).

The readable form of a program is its NumPy twin (input loads, intermediate terms ``_tmpN``,
output terms, as SymForce's templates). Kernels compute the *unwhitened*
residual and Jacobian: noise models and robust losses are applied by the problem.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from .cse import Program, total_ops

#: Bump when the layout of generated modules changes (part of every cache key).
CODEGEN_VERSION = "4"

RESERVED_NAMES = frozenset({"math", "np", "numba", "abs", "min", "max", "range", "EPSILON",
                            "META", "residual", "linearize", "linearize_hessian", "prepare"})


@dataclass(frozen=True)
class ArgLayout:
    """One function argument: where its storage comes from in the kernel."""

    name: str
    type_name: str
    symbols: tuple  # storage symbols (SymPy), storage order
    is_variable: bool
    offset: int  # column offset in the constants array (constants only)
    tangent_dim: int


def _loads(layouts: Sequence[ArgLayout], used: set) -> list[str]:
    lines = []
    for a in layouts:
        src = f"_{a.name}" if a.is_variable else "_consts"
        for k, s in enumerate(a.symbols):
            if s in used:
                col = k if a.is_variable else a.offset + k
                lines.append(f"{s.name} = {src}[_i, {col}]")
    return lines


def _kernel_source(fn_name: str, prog: Program, layouts: Sequence[ArgLayout], outputs: dict,
                   doc: str) -> str:
    """One njit kernel (:func:`._ir.kernel_source`). ``outputs`` maps program output name ->
    (array name, index builder)."""
    from ._ir import kernel_source

    var_params = [f"_{a.name}" for a in layouts if a.is_variable]
    out_params = [arr for arr, _ in outputs.values()]
    params = var_params + ["_consts"] + out_params
    loads, arg = {}, 0
    for a in layouts:
        for k, s in enumerate(a.symbols):
            loads[s] = (arg, (k,)) if a.is_variable else (len(var_params), (a.offset + k,))
        arg += a.is_variable
    stores = {name: (params.index(arr), _index_tuple(index))
              for name, (arr, index) in outputs.items()}
    return kernel_source(fn_name, prog, params, loads, stores, doc, total_ops(prog))


def _index_tuple(index: Any) -> Any:
    """``index(k)`` of the printed source (``"3"`` or ``"1, 4"``) as a tuple of ints."""
    return lambda k: tuple(int(x) for x in str(index(k)).split(","))


def _numpy_source(fn_name: str, prog: Program, layouts: Sequence[ArgLayout], outputs: dict,
                  kernel: str) -> str | None:
    """The NumPy twin of a kernel: the same program on whole columns (``_i`` -> ``:``), or
    ``None`` when an expression has no NumPy form. Used for small batches, where it needs no
    numba compilation or cache load (see the module docstring)."""
    from .printer import to_numpy_source

    used: set = set()
    for _, e in prog.stmts:
        used |= e.free_symbols
    for e in prog.all_outputs():
        used |= getattr(e, "free_symbols", set())
    var_params = [f"_{a.name}" for a in layouts if a.is_variable]
    out_params = [arr for arr, _ in outputs.values()]
    body = [f"    # the program of {kernel}, on columns"]
    body += [f"    {ln.replace('[_i, ', '[:, ')}" for ln in _loads(layouts, used)]
    for sym, e in prog.stmts:
        src = to_numpy_source(e)
        if src is None:
            return None
        body.append(f"    {sym.name} = {src}")
    for name, (arr, index) in outputs.items():
        for k, e in enumerate(prog.outputs[name]):
            src = to_numpy_source(e)
            if src is None:
                return None
            body.append(f"    {arr}[:, {index(k)}] = {src}")
    head = [f"def {fn_name}({', '.join(var_params + ['_consts'] + out_params)}):",
            f'    """NumPy twin of ``{kernel}`` (small batches)."""']
    return "\n".join(head + body) + "\n"


def _wrapper_source(fn_name: str, kernel: str, layouts: Sequence[ArgLayout],
                    outs: Sequence[tuple[str, str]], twin: str | None = None) -> str:
    var_names = [f"_{a.name}" for a in layouts if a.is_variable]
    lines = [f"def {fn_name}(args, consts):",
             f'    """Batched {fn_name} of ``n`` instances; see the module docstring."""',
             "    args, consts = prepare(args, consts, STORAGE_DIMS, NUM_CONSTANTS, NAME)",
             f"    {', '.join(var_names)}{',' if len(var_names) == 1 else ''} = args",
             "    n = consts.shape[0]"]
    for arr, shape in outs:
        lines.append(f"    {arr} = np.empty((n, {shape}))")
    call_args = ", ".join(var_names + ["consts"] + [arr for arr, _ in outs])
    if twin is not None:
        lines.append("    if use_numpy(n):")
        lines.append("        t0 = perf_counter()")
        lines.append("        with np.errstate(all='ignore'):  # as numba's error_model='numpy'")
        lines.append(f"            {twin}({call_args})")
        lines.append("        charge_numpy(perf_counter() - t0)")
        lines.append("    else:")
        lines.append(f"        {kernel}({call_args})")
    else:
        lines.append(f"    {kernel}({call_args})")
    ret = ", ".join(arr for arr, _ in outs)
    lines.append(f"    return {ret}")
    return "\n".join(lines) + "\n"


def module_source(name: str, signature: str, origin: str, layouts: Sequence[ArgLayout],
                  res_prog: Program, lin_prog: Program, meta: dict,
                  hess_prog: Program | None = None, clamp_prog: Program | None = None) -> str:
    """The full generated module (see the module docstring)."""
    from ._sym import EPSILON_VALUE

    r = len(res_prog.outputs["res"])
    D = sum(a.tangent_dim for a in layouts if a.is_variable)
    variables = ", ".join(f"{a.name} ({a.type_name})" for a in layouts if a.is_variable)
    constants = ", ".join(f"{a.name} ({a.type_name}, cols {a.offset}:{a.offset + len(a.symbols)})"
                          for a in layouts if not a.is_variable) or "none"
    ops_res, ops_lin = total_ops(res_prog), total_ops(lin_prog)
    header = [
        "# " + "-" * 98,
        "# Autogenerated by fgopt.symbolic.codegen (template: fgopt/symbolic/codegen.py).",
        f"# Source: {signature}",
        f"#   at {origin}",
        f"# Variables: {variables}. Constants: {constants}.",
        "# Kernels return the UNWHITENED residual and tangent-space Jacobian; the problem applies",
        "# the noise model's square-root information and robust weights.",
        "# Do NOT modify by hand: edit the factor function instead.",
        "# " + "-" * 98,
        f"# total ops: residual {ops_res}, linearize {ops_lin}"
        + (f", linearize_hessian {total_ops(hess_prog)}" if hess_prog is not None else ""),
        "# ruff: noqa",
        "# fmt: off",
        f'"""Generated batched kernels of ``{name}`` (residual dim {r}, tangent dim {D})."""',
        "",
        "import math",
        "from time import perf_counter",
        "",
        "import numpy as np",
        "",
        "from fgopt._jit import njit",
        "from fgopt.symbolic._ir import Body",
        "from fgopt.symbolic.runtime import charge_numpy, prepare, use_numpy",
        "",
        f"EPSILON = {EPSILON_VALUE!r}",
        f"NAME = {name!r}",
        f"STORAGE_DIMS = {tuple(len(a.symbols) for a in layouts if a.is_variable)!r}",
        f"NUM_CONSTANTS = {sum(len(a.symbols) for a in layouts if not a.is_variable)}",
        f"META = {meta!r}",
        "",
    ]
    shapes = "; ".join(f"_{a.name} (n, {len(a.symbols)}) {a.type_name} storage"
                       for a in layouts if a.is_variable)
    parts = ["\n".join(header), ""]
    parts.append(_kernel_source(
        "_residual_kernel", res_prog, layouts, {"res": ("_res", lambda k: f"{k}")},
        f"Inputs: {shapes}; _consts (n, c). Writes _res (n, {r})."))
    parts.append("")
    parts.append(_kernel_source(
        "_linearize_kernel", lin_prog, layouts,
        {"res": ("_res", lambda k: f"{k}"),
         "jac": ("_jac", lambda k: f"{k // D}, {k % D}" if D > 0 else "0")},
        f"Inputs: {shapes}; _consts (n, c). Writes _res (n, {r}), _jac (n, {r}, {D})."))
    parts.append("")
    if hess_prog is not None:
        parts.append(_kernel_source(
            "_linearize_hessian_kernel", hess_prog, layouts,
            {"res": ("_res", lambda k: f"{k}"),
             "jac": ("_jac", lambda k: f"{k // D}, {k % D}"),
             "hess": ("_hess", lambda k: f"{k // D}, {k % D}"),
             "rhs": ("_rhs", lambda k: f"{k}")},
            f"Writes _res (n, {r}), _jac (n, {r}, {D}), _hess = J^T J (n, {D}, {D}), "
            f"_rhs = J^T r (n, {D}) (unwhitened)."))
        parts.append("")
    res_twin = _numpy_source("_residual_numpy", res_prog, layouts,
                             {"res": ("_res", lambda k: f"{k}")}, "_residual_kernel")
    lin_twin = _numpy_source(
        "_linearize_numpy", lin_prog, layouts,
        {"res": ("_res", lambda k: f"{k}"),
         "jac": ("_jac", lambda k: f"{k // D}, {k % D}" if D > 0 else "0")}, "_linearize_kernel")
    for twin in (res_twin, lin_twin):
        if twin is not None:
            parts.append(twin)
            parts.append("")
    parts.append(_wrapper_source("residual", "_residual_kernel", layouts, [("res", str(r))],
                                 "_residual_numpy" if res_twin is not None else None))
    parts.append("")
    parts.append(_wrapper_source("linearize", "_linearize_kernel", layouts,
                                 [("res", str(r)), ("jac", f"{r}, {D}")],
                                 "_linearize_numpy" if lin_twin is not None else None))
    if hess_prog is not None:
        parts.append("")
        parts.append(_wrapper_source(
            "linearize_hessian", "_linearize_hessian_kernel", layouts,
            [("res", str(r)), ("jac", f"{r}, {D}"), ("hess", f"{D}, {D}"), ("rhs", str(D))]))
    if clamp_prog is not None:
        m = len(clamp_prog.outputs["clamp"])
        parts.append("")
        parts.append(_kernel_source(
            "_clamp_kernel", clamp_prog, layouts, {"clamp": ("_clamp", lambda k: f"{k}")},
            f"Writes _clamp (n, {m}): the arguments of the clamped functions in META['clamps'] "
            "(checked after a solve, never in the solver's loop)."))
        parts.append("")
        parts.append(_wrapper_source("clamp_arguments", "_clamp_kernel", layouts,
                                     [("clamp", str(m))]))
    return "\n".join(parts)


def python_function(symbols: Sequence[Any], exprs: Any, name: str = "f"):
    """A plain-Python (no numba) scalar function of ``symbols``, for tests and quick checks.

    ``exprs`` is a list of expressions (returns a list of floats) or a
    :class:`~fgopt.symbolic.cse.Program` (returns a dict output name -> list). Uses the same
    CSE and printer as generated kernels.

    >>> from fgopt.symbolic import V2, linearization_program, python_function
    >>> p = V2.symbolic("p")
    >>> f = python_function(list(p), linearization_program(p.squared_norm(), [p]))
    >>> f(3.0, 4.0)
    {'res': [25.0], 'jac': [6.0, 8.0]}
    """
    import math

    import numpy as np

    from ._sym import EPSILON_VALUE
    from .cse import optimize
    from .printer import to_source

    is_prog = isinstance(exprs, Program)
    prog = exprs if is_prog else optimize(Program([], {"out": list(exprs)}))
    params = ", ".join(s.name for s in symbols)
    lines = [f"def {name}({params}):"]
    lines += [f"    {s.name} = {to_source(e)}" for s, e in prog.stmts]
    outs = ", ".join(f"{k!r}: [" + ", ".join(to_source(e) for e in v) + "]"
                     for k, v in prog.outputs.items())
    lines.append(f"    return {{{outs}}}")
    env = {"math": math, "np": np, "EPSILON": EPSILON_VALUE}
    exec(compile("\n".join(lines) + "\n", f"<fgopt python_function {name}>", "exec"), env)  # noqa: S102
    fn = env[name]
    if is_prog:
        return fn
    return lambda *vals: fn(*vals)["out"]
