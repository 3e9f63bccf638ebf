"""Derivation of one factor kernel module: symbolic residual -> programs -> source.

Called by :class:`~fgopt.factors.decorator.SymbolicFactorType` on a cache miss (this is where
SymPy gets imported).
"""

from __future__ import annotations

import inspect
from pathlib import Path
from typing import Any

from ..errors import FgoptError
from .codegen import ArgLayout, module_source
from .cse import Program, optimize, total_ops
from .jacobians import output_storage
from .linearize import linearization_program
from .ops import has_own_tangent, storage_of, symbolic_value


def _origin(fn: Any) -> str:
    """``file:line`` of the factor function; relative (``fgopt/...``) inside the package, so the
    generated source of a built-in factor is the same bytes in every checkout (it is shipped)."""
    try:
        path = Path(inspect.getsourcefile(fn)).resolve()
        package_parent = Path(__file__).resolve().parents[2]
        if path.is_relative_to(package_parent / "fgopt"):
            path = path.relative_to(package_parent)
        return f"{path.as_posix()}:{inspect.getsourcelines(fn)[1]}"
    except (OSError, TypeError):
        return f"{getattr(fn, '__module__', '?')}.{getattr(fn, '__qualname__', '?')}"


def residual_of(ftype: Any, sym_args: list) -> list:
    """Run the factor function on symbolic arguments; the flat residual expressions."""
    try:
        out = ftype.fn(*sym_args)
    except TypeError as exc:
        if "truth value" in str(exc) or "relational" in str(exc).lower():
            raise FgoptError(
                f"{ftype.name}: the residual function branches on a symbolic value ({exc}). "
                "Python `if` runs once, at code generation; write branchless code with "
                "Min/Max/sign_no_zero (see fgopt.symbolic.functions)") from exc
        raise
    if has_own_tangent(out):
        raise FgoptError(f"{ftype.name}: returns a {type(out).__name__}; a residual must be a "
                         "vector (e.g. a.local(b) or pose.log())")
    res = output_storage(out)
    rt = ftype.return_type
    if rt is not None and hasattr(rt, "storage_dim") and rt.storage_dim() != len(res):
        raise FgoptError(f"{ftype.name}: annotated to return {rt.__name__} but returned "
                         f"{len(res)} values")
    if len(res) == 0:
        raise FgoptError(f"{ftype.name}: the residual is empty")
    return res, out


def derive_source(ftype: Any, pattern: tuple) -> str:
    """Generated module source of ``ftype`` for the variable pattern ``pattern``."""
    sym_args = [symbolic_value(tp, name) for name, tp in ftype.params]
    res, _ = residual_of(ftype, sym_args)
    layouts, offset = [], 0
    for (name, tp), arg, is_var in zip(ftype.params, sym_args, pattern):
        symbols = tuple(storage_of(arg))
        layouts.append(ArgLayout(name=name, type_name=tp.__name__, symbols=symbols,
                                 is_variable=is_var, offset=0 if is_var else offset,
                                 tangent_dim=tp.dim()))
        if not is_var:
            offset += len(symbols)
    var_args = [a for a, v in zip(sym_args, pattern) if v]
    res_prog = optimize(Program([], {"res": res}))
    lin_prog = linearization_program(res, var_args, method=ftype.method, engine=ftype.engine)
    hess_prog = None
    if ftype.hessian:
        hess_prog = linearization_program(res, var_args, method=ftype.method,
                                          engine=ftype.engine, hessian=True)
    variables = [n for (n, _), v in zip(ftype.params, pattern) if v]
    meta = {
        "name": ftype.name,
        "residual_dim": len(res),
        "variables": variables,
        "constants": [n for (n, _), v in zip(ftype.params, pattern) if not v],
        "types": [tp.__name__ for _, tp in ftype.params],
        "tangent_dim": sum(a.tangent_dim for a in layouts if a.is_variable),
        "method": ftype.method,
        "engine": ftype.engine,
        "ops": {"residual": total_ops(res_prog), "linearize": total_ops(lin_prog),
                **({"linearize_hessian": total_ops(hess_prog)} if hess_prog is not None else {})},
    }
    sig = ", ".join(f"{n}: {tp.__name__}" for n, tp in ftype.params)
    rt = ftype.return_type
    signature = f"{ftype.name}({sig})" + (f" -> {rt.__name__}" if rt is not None else "")
    return module_source(ftype.name, signature, _origin(ftype.fn), layouts, res_prog, lin_prog,
                         meta, hess_prog)
