"""Derivation and source of a :func:`fgopt.symbolic.generate` module (SymPy runs here).

Called by :class:`~fgopt.symbolic.generated.GeneratedFunction` on a cache miss. The function is
run on symbolic arguments, its outputs flattened to storage expressions, and two programs are
built: the value (``res``) and the value with the stacked tangent-space Jacobian (``res``,
``jac``). The storage Jacobian comes from :func:`~fgopt.symbolic.linearize.linearization_program`;
rows of group outputs are then mapped to the output's tangent space with
``tangent_D_storage`` at the output (block by block, so a tuple may mix groups and vectors),
and the whole program is CSE'd again so the map shares terms with the value.
"""

from __future__ import annotations

import inspect
from typing import Any

from ..errors import FgoptError
from .cse import Program, optimize, temp_symbols, total_ops
from .declare.twin import DeclaredManifold
from .lie import LieGroupBase
from .linearize import linearization_program
from .matrix import Matrix, Scalar
from .ops import has_own_tangent, storage_of, symbolic_value, tangent_D_storage_of


def _sp():
    from . import _sym

    return _sym.sp


def _origin(fn: Any) -> str:
    try:
        return f"{inspect.getsourcefile(fn)}:{inspect.getsourcelines(fn)[1]}"
    except (OSError, TypeError):
        return f"{getattr(fn, '__module__', '?')}.{getattr(fn, '__qualname__', '?')}"


def output_type(value: Any) -> type:
    """The symbolic type of one output value."""
    if has_own_tangent(value):
        return type(value)
    if isinstance(value, Matrix):
        return Matrix.shaped(*value.shape)
    return Scalar


def _describe(tp: type) -> tuple:
    if tp is Scalar:
        return ("scalar",)
    if issubclass(tp, Matrix):
        return ("matrix", *tp.SHAPE)
    return ("group", tp.__module__, tp.__qualname__)


def run_symbolic(gf: Any) -> tuple[dict, list, bool]:
    """``(arguments by name, outputs, returned a tuple)`` of ``gf.fn`` on symbolic arguments."""
    args = {n: symbolic_value(tp, n) for n, tp in gf.params}
    try:
        out = gf.fn(*args.values())
    except TypeError as exc:
        if "truth value" in str(exc) or "relational" in str(exc).lower():
            raise FgoptError(
                f"{gf.name}: the function branches on a symbolic value ({exc}). Python `if` "
                "runs once, at code generation; write branchless code with Min/Max/"
                "sign_no_zero (see fgopt.symbolic.functions)") from exc
        raise
    is_tuple = isinstance(out, (tuple, list))
    outputs = list(out) if is_tuple else [out]
    if len(outputs) == 0:
        raise FgoptError(f"{gf.name}: the function returns nothing")
    sp = _sp()
    for i, o in enumerate(outputs):
        ok = isinstance(o, (LieGroupBase, DeclaredManifold, Matrix, int, float)) or (
            isinstance(o, sp.Basic) and not isinstance(o, sp.MatrixBase))
        if not ok or (isinstance(o, Matrix) and o.SHAPE is None and len(o.to_storage()) == 0):
            raise FgoptError(f"{gf.name}: output {i} is a {type(o).__name__}; return groups, "
                             "vectors / matrices or scalars (or a tuple of them)")
    _check_return_annotation(gf, outputs, is_tuple)
    return args, outputs, is_tuple


def _check_return_annotation(gf: Any, outputs: list, is_tuple: bool) -> None:
    import typing

    from .generated import type_hints

    try:
        rt = type_hints(gf.fn, None).get("return")
    except Exception:  # noqa: BLE001 - unresolvable return annotation: nothing to check
        return
    if rt is None:
        return
    if typing.get_origin(rt) is tuple:
        expected = [a for a in typing.get_args(rt) if a is not Ellipsis]
        if not is_tuple or len(expected) != len(outputs):
            raise FgoptError(f"{gf.name}: annotated to return {len(expected)} values, returned "
                             f"{len(outputs) if is_tuple else 'one value'}")
    else:
        expected = [rt]
        if is_tuple and len(outputs) != 1:
            raise FgoptError(f"{gf.name}: annotated to return one {getattr(rt, '__name__', rt)}, "
                             f"returned a tuple of {len(outputs)}")
    for i, (tp, o) in enumerate(zip(expected, outputs)):
        if tp in (float, int):
            tp = Scalar
        got = output_type(o)
        same = got is tp or (isinstance(tp, type) and issubclass(tp, Matrix) and
                             issubclass(got, Matrix) and tp.SHAPE == got.SHAPE)
        if not same:
            raise FgoptError(f"{gf.name}: output {i} is annotated {getattr(tp, '__name__', tp)} "
                             f"but the function returned a {got.__name__}")


def _to_output_tangents(prog: Program, outputs: list) -> Program:
    """Map the storage-Jacobian rows of group outputs to their tangent spaces."""
    sp = _sp()
    res, jac = list(prog.outputs["res"]), list(prog.outputs["jac"])
    ncols = len(jac) // len(res) if len(res) > 0 else 0
    syms = temp_symbols("_gen")
    stmts = list(prog.stmts)
    res_syms = []
    for e in res:
        s = next(syms)
        stmts.append((s, e))
        res_syms.append(s)
    jac_syms = []
    for e in jac:
        s = next(syms)
        stmts.append((s, e))
        jac_syms.append(s)
    J = sp.Matrix(len(res), ncols, jac_syms)
    blocks, r0 = [], 0
    for o in outputs:
        s = len(storage_of(o))
        rows = J[r0:r0 + s, :]
        if has_own_tangent(o):
            rows = tangent_D_storage_of(type(o).from_storage(res_syms[r0:r0 + s])) * rows
        blocks.append(rows)
        r0 += s
    Jt = sp.Matrix.vstack(*blocks)
    return optimize(Program(stmts, {"res": res_syms, "jac": list(Jt)}))


def programs(gf: Any) -> tuple[Program, Program | None, list, bool, dict]:
    """``(value program, linearization program or None, outputs, is_tuple, arguments)``."""
    args, outputs, is_tuple = run_symbolic(gf)
    res = []
    for o in outputs:
        res.extend(storage_of(o))
    value = optimize(Program([], {"res": res}))
    lin = None
    if len(gf.which) > 0:
        lin = linearization_program(res, [args[n] for n in gf.which], method=gf.method,
                                    engine=gf.engine)
        if any(has_own_tangent(o) for o in outputs):
            lin = _to_output_tangents(lin, outputs)
    return value, lin, outputs, is_tuple, args


# ---------------------------------------------------------------------- source
def _body(prog: Program, args: dict, offsets: dict, outputs: dict, batched: bool) -> list:
    """Statements of one kernel body (without the loop header), indented by 4."""
    from .printer import to_source

    ind = "        " if batched else "    "
    row = "_i, " if batched else ""
    used: set = set()
    for _, e in prog.stmts:
        used |= e.free_symbols
    for e in prog.all_outputs():
        used |= getattr(e, "free_symbols", set())
    lines = [f"{ind}# input arrays"]
    for n, value in args.items():
        for k, s in enumerate(storage_of(value)):
            if s in used:
                lines.append(f"{ind}{s.name} = _inp[{row}{offsets[n] + k}]")
    if len(prog.stmts) > 0:
        lines.append(f"{ind}# intermediate terms ({len(prog.stmts)})")
        lines += [f"{ind}{s.name} = {to_source(e)}" for s, e in prog.stmts]
    lines.append(f"{ind}# output terms")
    for name, (arr, ncols) in outputs.items():
        exprs = prog.outputs[name]
        zero = [getattr(e, "is_zero", False) is True or e == 0 for e in exprs]
        if ncols is not None and any(zero):
            lines.append(f"{ind}{arr}[{row}:, :] = 0.0")
        for k, e in enumerate(exprs):
            if ncols is not None and zero[k]:
                continue
            idx = f"{k}" if ncols is None else f"{k // ncols}, {k % ncols}"
            lines.append(f"{ind}{arr}[{row}{idx}] = {to_source(e)}")
    return lines


def _function(fn_name: str, params: str, doc: str, ops: int, body: list, batched: bool) -> str:
    head = ['@njit(cache=True, fastmath=False, error_model="numpy", nogil=True)',
            f"def {fn_name}({params}):",
            f'    """{doc}"""',
            f"    # total ops: {ops}"]
    if batched:
        head.append("    for _i in range(_inp.shape[0]):")
    return "\n".join(head + body) + "\n"


def derive_source(gf: Any) -> str:
    """The generated module of ``gf`` (a :class:`~fgopt.symbolic.generated.GeneratedFunction`)."""
    from ._sym import EPSILON_VALUE

    value, lin, outputs, is_tuple, args = programs(gf)
    offsets, pos = {}, 0
    for n, tp in gf.params:
        offsets[n] = pos
        pos += tp.storage_dim()
    in_dim = pos
    out_dim = sum(len(storage_of(o)) for o in outputs)
    types = [output_type(o) for o in outputs]
    rows = sum(t.dim() for t in types)
    cols = sum(dict(gf.params)[n].dim() for n in gf.which)
    ops_value = total_ops(value)
    ops_jac = total_ops(lin) if lin is not None else 0
    meta = {"name": gf.name, "arguments": [(n, tp.__name__) for n, tp in gf.params],
            "which": list(gf.which), "outputs": [_describe(t) for t in types],
            "tuple_output": is_tuple, "input_dim": in_dim, "output_dim": out_dim,
            "jacobian_shape": (rows, cols), "method": gf.method, "engine": gf.engine,
            "ops": {"value": ops_value, "jacobian": ops_jac}}
    sig = ", ".join(f"{n}: {tp.__name__}" for n, tp in gf.params)
    outs = ", ".join(t.__name__ for t in types)
    signature = f"{gf.name}({sig}) -> {f'({outs})' if is_tuple else outs}"
    layout = "; ".join(f"{n} [{offsets[n]}:{offsets[n] + tp.storage_dim()}]"
                       for n, tp in gf.params)
    header = [
        "# " + "-" * 98,
        "# Autogenerated by fgopt.symbolic.generate (template: fgopt/symbolic/_generate_source.py).",
        f"# Source: {signature}",
        f"#   at {_origin(gf.fn)}",
        f"# Input storage layout: {layout}.",
        (f"# Jacobian: {rows}x{cols}, rows = output tangent spaces, columns = tangent spaces of "
         f"({', '.join(gf.which)})."),
        "# Do NOT modify by hand: edit the function instead.",
        "# " + "-" * 98,
        f"# total ops: value {ops_value}, jacobian {ops_jac}",
        "# ruff: noqa",
        "# fmt: off",
        (f'"""Generated function ``{gf.name}`` (input {in_dim}, output {out_dim}, '
         f'jacobian {rows}x{cols})."""'),
        "",
        "import math",
        "",
        "from fgopt._jit import njit",
        "import numpy as np",
        "",
        f"EPSILON = {EPSILON_VALUE!r}",
        f"NAME = {gf.name!r}",
        f"INPUT_DIM = {in_dim}",
        f"OUTPUT_DIM = {out_dim}",
        f"JACOBIAN_SHAPE = {(rows, cols)!r}",
        f"META = {meta!r}",
        "",
    ]
    parts = ["\n".join(header), ""]
    res_only = {"res": ("_out", None)}
    parts.append(_function(
        "flat_value", "_inp, _out", f"One evaluation: _inp ({in_dim},) -> _out ({out_dim},).",
        ops_value, _body(value, args, offsets, res_only, False), False))
    parts.append("")
    parts.append(_function(
        "batch_value", "_inp, _out",
        f"n evaluations: _inp (n, {in_dim}) -> _out (n, {out_dim}).",
        ops_value, _body(value, args, offsets, res_only, True), True))
    if lin is None:  # no Jacobian: the linearized entry points are the value ones
        parts += ["", "flat = flat_value", "batch = batch_value", ""]
        return "\n".join(parts)
    with_jac = {"res": ("_out", None), "jac": ("_jac", cols)}
    parts.append("")
    parts.append(_function(
        "flat", "_inp, _out, _jac",
        f"One evaluation: _inp ({in_dim},) -> _out ({out_dim},), _jac ({rows}, {cols}).",
        ops_jac, _body(lin, args, offsets, with_jac, False), False))
    parts.append("")
    parts.append(_function(
        "batch", "_inp, _out, _jac",
        f"n evaluations: _inp (n, {in_dim}) -> _out (n, {out_dim}), _jac (n, {rows}, {cols}).",
        ops_jac, _body(lin, args, offsets, with_jac, True), True))
    return "\n".join(parts)
