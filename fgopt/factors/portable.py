"""How ``@fgopt.factor`` types travel to other processes (pickle, Dask workers).

A factor type is sent as what it was made from, never as compiled code:

- by its ``recipe`` (a function and arguments that make it) when it has one;
- by reference (``module``, ``qualname``) when the type is importable, i.e. defined at module
  level; the receiver imports that module;
- otherwise (``__main__``, a notebook cell, a function body) as the residual function's source
  text, the globals its code reads (modules by name, other values pickled) and its closure
  values, plus the decorator's options and the sender's function fingerprint.

The receiver rebuilds the type once per process (memoized by fingerprint and options), so every
factor of that type unpickled there shares one type and one kernel per variable pattern (kernels
compare by identity). The kernels then come from the receiver's disk cache under the sender's
cache key, or are derived there.
"""

from __future__ import annotations

import importlib
import inspect
import pickle
import textwrap
import types
from typing import Any

from ..errors import FgoptError

#: (fingerprint, options) -> factor type rebuilt from source in this process.
_FROM_SOURCE: dict = {}


def _by_reference(ftype: Any) -> tuple | None:
    module = getattr(ftype, "__module__", None)
    qualname = getattr(ftype, "__qualname__", "")
    if module in (None, "__main__") or "<locals>" in qualname:
        return None
    try:
        obj = importlib.import_module(module)
        for part in qualname.split("."):
            obj = getattr(obj, part)
    except (ImportError, AttributeError):
        return None
    return (module, qualname) if obj is ftype else None


def import_attribute(module: str, qualname: str) -> Any:
    """``module.qualname`` after importing ``module``."""
    obj = importlib.import_module(module)
    for part in qualname.split("."):
        obj = getattr(obj, part)
    return obj


def _code_names(code: types.CodeType) -> set:
    names = set(code.co_names)
    for c in code.co_consts:
        if isinstance(c, types.CodeType):
            names |= _code_names(c)
    return names


def _portable_globals(fn: Any) -> dict:
    """The globals and closure values ``fn`` reads: modules by name, other values as they are
    (they must pickle)."""
    out: dict = {}
    for name in sorted(_code_names(fn.__code__)):
        if name not in fn.__globals__:
            continue  # a builtin, or a name resolved at call time
        value = fn.__globals__[name]
        out[name] = ("module", value.__name__) if isinstance(value, types.ModuleType) \
            else ("value", value)
    for name, cell in zip(fn.__code__.co_freevars, fn.__closure__ or ()):
        out[name] = ("value", cell.cell_contents)
    for name, (tag, value) in out.items():
        if tag == "value":
            try:
                pickle.dumps(value)
            except Exception as exc:
                raise FgoptError(f"@fgopt.factor {fn.__name__}: cannot send the factor type to "
                                 f"another process: the global {name!r} it reads does not pickle "
                                 f"({exc}); define the factor in an importable module") from None
    return out


def _source_of(fn: Any) -> str:
    try:
        source = textwrap.dedent(inspect.getsource(fn))
    except (OSError, TypeError) as exc:
        raise FgoptError(f"@fgopt.factor {fn.__name__}: cannot send the factor type to another "
                         f"process: its source is not available ({exc}); define it in a file, a "
                         "notebook cell or an importable module") from None
    lines = source.splitlines()
    start = next(i for i, ln in enumerate(lines) if ln.lstrip().startswith(("def ", "async def ")))
    return "\n".join(lines[start:]) + "\n"


def reduce_factor_type(ftype: Any) -> tuple:
    """``__reduce__`` of a :class:`~fgopt.factors.decorator.SymbolicFactorType`."""
    if ftype.recipe is not None:
        return ftype.recipe
    ref = _by_reference(ftype)
    if ref is not None:
        return (import_attribute, ref)
    fn = ftype.fn
    payload = {"source": _source_of(fn), "function": fn.__name__,
               "globals": _portable_globals(fn), "options": dict(ftype._options),
               "fingerprint": ftype.fingerprint}
    return (factor_type_from_source, (payload,))


def factor_type_from_source(payload: dict) -> Any:
    """Rebuild (once per process) a factor type sent by :func:`reduce_factor_type`."""
    from .. import symbolic
    from .decorator import SymbolicFactorType

    options = payload["options"]
    memo_key = (payload["fingerprint"], repr(sorted(options.items())))
    ftype = _FROM_SOURCE.get(memo_key)
    if ftype is not None:
        return ftype
    namespace: dict = {k: getattr(symbolic, k) for k in dir(symbolic) if not k.startswith("_")}
    for name, (tag, value) in payload["globals"].items():
        namespace[name] = importlib.import_module(value) if tag == "module" else value
    try:
        exec(compile(payload["source"], f"<fgopt factor {payload['function']}>", "exec"), namespace)
    except Exception as exc:
        raise FgoptError(f"@fgopt.factor {payload['function']}: rebuilding the factor type from "
                         f"its source failed: {exc}") from exc
    if "inequality" in options:  # a constraint type (fgopt.factors.constraint)
        from .constraint import SymbolicConstraintType as SymbolicFactorType
    ftype = SymbolicFactorType(namespace[payload["function"]], scope=namespace, **options)
    ftype._fingerprint = payload["fingerprint"]  # the sender's: same cache keys, same kernels
    _FROM_SOURCE[memo_key] = ftype
    return ftype
