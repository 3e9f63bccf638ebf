"""Derivation of one factor kernel module: symbolic residual -> programs -> source.

Called by :class:`~fgopt.factors.decorator.SymbolicFactorType` on a cache miss (this is where
SymPy gets imported).
"""

from __future__ import annotations

import inspect
import linecache
import math
import traceback
from pathlib import Path
from typing import Any

from ..errors import FgoptError
from ._sym import as_expr
from .codegen import ArgLayout, module_source
from .cse import Program, optimize, total_ops
from .functions import recording_clamps
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


def trace(ftype: Any, sym_args: list) -> Any:
    """Run the factor function on symbolic arguments. Every failure becomes an FgoptError naming
    the factor and the user's file:line (the innermost frame in the function's own file)."""
    try:
        return ftype.fn(*sym_args)
    except Exception as exc:  # noqa: BLE001 - re-raised as an FgoptError with the user's line
        raise _traced_error(ftype, exc) from exc


_FOREIGN_HINTS = ("ufunc", "convert expression to float", "has no callable", "can't convert",
                  "cannot convert")


def _traced_error(ftype: Any, exc: Exception) -> FgoptError:
    where, code = _user_line(ftype.fn, exc.__traceback__)
    at = f" at {where}" + (f" (`{code}`)" if code else "")
    msg = str(exc)
    if isinstance(exc, TypeError) and ("truth value" in msg or "relational" in msg.lower()):
        return FgoptError(
            f"{ftype.name}{at}: the residual function branches on a symbolic value ({msg}). "
            "Python `if` runs once, at code generation; write branchless code with "
            "Min/Max/sign_no_zero (see fgopt.symbolic.functions)")
    if isinstance(exc, FgoptError):
        try:
            return type(exc)(f"{ftype.name}{at}: {msg}")
        except TypeError:  # an error class with another constructor
            return FgoptError(f"{ftype.name}{at}: {msg}")
    foreign = any(h in msg for h in _FOREIGN_HINTS) or any(
        m in code for m in ("np.", "numpy.", "math.", "scipy."))
    if isinstance(exc, (TypeError, AttributeError, ValueError)) and foreign:
        return FgoptError(
            f"{ftype.name}{at}: NumPy / math functions cannot take the symbolic values a factor "
            "body works on; use fgopt.symbolic's functions (sqrt, sin, cos, atan2, exp, log, "
            "Abs, Max, ...) and methods (v.norm(), v.dot(w), R * v) instead "
            f"({type(exc).__name__}: {msg})")
    return FgoptError(f"{ftype.name}{at}: the residual function raised {type(exc).__name__}: "
                      f"{msg}")


def _user_line(fn: Any, tb: Any) -> tuple[str, str]:
    """("file:line", source) of the innermost traceback frame in ``fn``'s file."""
    target = getattr(getattr(fn, "__code__", None), "co_filename", None)
    found = None
    for frame, lineno in traceback.walk_tb(tb):
        if frame.f_code.co_filename == target:
            found = (frame.f_code.co_filename, lineno)
    if found is None:
        return _origin(fn), ""
    return f"{found[0]}:{found[1]}", linecache.getline(found[0], found[1]).strip()


def residual_of(ftype: Any, sym_args: list) -> list:
    """Run the factor function on symbolic arguments; the flat residual expressions."""
    out = trace(ftype, sym_args)
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
    with recording_clamps() as clamps:
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
    res_prog = optimize(Program([], {"res": [as_expr(e) for e in res]}))
    lin_prog = linearization_program(res, var_args, method=ftype.method, engine=ftype.engine,
                                     value=res_prog)
    hess_prog = None
    if ftype.hessian:
        hess_prog = linearization_program(res, var_args, method=ftype.method,
                                          engine=ftype.engine, hessian=True, value=res_prog)
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
    clamp_prog = None
    if len(clamps) > 0:
        clamp_prog = optimize(Program([], {"clamp": [c.arg for c in clamps]}))
        meta["clamps"] = [{"function": c.function, "where": c.where, "code": c.code,
                           "low": c.low if math.isfinite(c.low) else None,
                           "high": c.high if math.isfinite(c.high) else None} for c in clamps]
    sig = ", ".join(f"{n}: {tp.__name__}" for n, tp in ftype.params)
    rt = ftype.return_type
    signature = f"{ftype.name}({sig})" + (f" -> {rt.__name__}" if rt is not None else "")
    return module_source(ftype.name, signature, _origin(ftype.fn), layouts, res_prog, lin_prog,
                         meta, hess_prog, clamp_prog)
