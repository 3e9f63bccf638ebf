"""Generated functions with tangent-space Jacobians (the role of SymForce's ``Codegen`` with
``with_jacobians`` / ``with_linearization``), for filters, controllers and user code.

    from fgopt.symbolic import Rot3, V3, Scalar, generate

    def propagate(R: Rot3, w: V3, dt: Scalar) -> Rot3:
        return R * Rot3.exp(w * dt)

    f = generate(propagate, which=["R", "w"])
    R1, J = f(SO3.random(), np.array([0.1, 0.2, 0.3]), 0.01)   # J: (3, 6) = [R1_D_R | R1_D_w]

The function is run once on symbolic arguments; its outputs (one value or a tuple of values:
Lie groups, vectors / matrices, scalars) are flattened, differentiated with respect to the
arguments named in ``which`` (:mod:`fgopt.symbolic.linearize`), CSE'd (:mod:`.cse`), printed
(:mod:`.printer`) into a module of ``@numba.njit`` functions and cached on disk (:mod:`.cache`),
exactly as factor kernels are.

Jacobians are tangent-to-tangent. Column block ``j`` is the derivative with respect to the
tangent space of ``which[j]`` (``x (+) d = x * Exp(d)`` for groups, ``x + d`` for vectors);
row block ``i`` is output ``i``'s tangent space: for a group output ``y = f(x)`` the rows are
``d local(y, f(x (+) d)) / d d`` at 0 (``local(a, b) = Log(a^-1 b)``), for vectors and scalars
the ordinary derivative of the entries (row-major for matrices). The stacked Jacobian has
``sum(dim(outputs))`` rows and ``sum(dim(which))`` columns; ``f.rows[i]`` and ``f.cols[name]``
are the slices of each block.

Calling conventions of the generated module (all float64, C-contiguous):

* ``flat(inp, out, jac)`` / ``flat_value(inp, out)``: one evaluation. ``inp`` is every
  argument's storage concatenated in signature order (``f.inputs[name]`` are the slices),
  ``out`` every output's storage concatenated (``f.outputs_storage[i]``), ``jac`` the stacked
  Jacobian. These are plain numba functions: other ``@numba.njit`` code may call them.
* ``batch(inp, out, jac)`` / ``batch_value(inp, out)``: the same over rows of ``(n, ...)``
  arrays (one loop, no Python per row).

:class:`GeneratedFunction` wraps them with argument checking and numeric types: ``f(*args)``
(group arguments as ``fgopt.manifolds`` values or storage vectors; group outputs come back as
``SO3`` / ``SE3`` / ... values), ``f.value(*args)`` (no Jacobian) and ``f.batch(*args)``.

This module does not import SymPy: on a cache hit nothing symbolic runs.
"""

from __future__ import annotations

import hashlib
import inspect
import sys
import typing
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DimensionMismatchError, FgoptError, NonFiniteError
from . import cache as _cache
from ._generate_values import (
    MANIFOLD_TYPES,
    _batch_storage,
    numeric_twin,
    numeric_value,
    value_storage,
)
from .codegen import RESERVED_NAMES
from .matrix import Matrix, Scalar
from .ops import normalize_type

#: Names generated modules define or use (argument names must differ).
_RESERVED = RESERVED_NAMES | {"epsilon", "NAME", "flat", "flat_value", "batch", "batch_value",
                              "INPUT_DIM", "OUTPUT_DIM", "JACOBIAN_SHAPE"}

__all__ = ["MANIFOLD_TYPES", "GeneratedFunction", "Slot", "generate", "numeric_twin",
           "numeric_value", "parameters", "type_hints", "value_storage"]

_SOURCES = ("generated.py", "_generate_source.py")


def _implementation_hash() -> str:
    """Hash of this module and its derivation module (editing either changes every key)."""
    h = hashlib.sha256()
    here = Path(__file__).parent
    for name in _SOURCES:
        h.update((here / name).read_bytes())
    return h.hexdigest()[:16]


@dataclass(frozen=True)
class Slot:
    """Where one argument or output of a generated function sits.

    ``storage`` slices the flat storage vector (``inp`` for arguments, ``out`` for outputs);
    ``tangent`` slices the stacked Jacobian (its columns for arguments in ``which``, its rows for
    outputs; ``None`` for arguments not differentiated by).
    """

    name: str
    type: type
    storage: slice
    tangent: slice | None


def generate(fn: Callable | None = None, which: Iterable[str] | None = None, *,
             name: str | None = None, method: str = "retraction", engine: str = "auto",
             cache: bool = True):
    """Compile a function over symbolic types into a numba function with tangent Jacobians.

    Args:
        fn: ``def f(x: Rot3, w: V3, dt: Scalar) -> Rot3``; every parameter annotated with a
            symbolic type (``Rot2, Rot3, Pose2, Pose3, V1..V9, Matrix.shaped(r, c), Scalar``).
            It returns one value or a tuple of values (groups, vectors / matrices, scalars).
        which: names of the arguments to differentiate by, in Jacobian column order (default:
            all, in signature order; ``()`` for no Jacobian).
        name: name of the generated module (default ``fn.__name__``).
        method: ``"retraction"`` or ``"chain"`` (see :mod:`fgopt.symbolic.jacobians`).
        engine: ``"auto"``, ``"tree"``, ``"dag"`` or ``"reverse"`` (see
            :mod:`fgopt.symbolic.linearize`).
        cache: use the on-disk cache of generated modules.

    Returns:
        A :class:`GeneratedFunction`. Also usable as a decorator, ``@generate`` or
        ``@generate(which=["x"])``.

    Example:

    >>> from fgopt.symbolic import Rot3, V3, Scalar, generate
    >>> def propagate(R: Rot3, w: V3, dt: Scalar) -> Rot3:
    ...     return R * Rot3.exp(w * dt)
    ...
    >>> f = generate(propagate, which=['R', 'w'])
    >>> R1, J = f(fgopt.SO3(), np.array([0.0, 0.0, 1.0]), 0.5)
    >>> np.round(R1.log(), 6), J.shape
    (array([0. , 0. , 0.5]), (3, 6))
    """
    scope = sys._getframe(1).f_locals

    def wrap(f: Callable) -> GeneratedFunction:
        return GeneratedFunction(f, which=which, name=name, method=method, engine=engine,
                                 cache=cache, scope=scope)

    return wrap if fn is None else wrap(fn)


def explain_derive_error(exc: ValueError) -> str:
    """The message of a code generation error, with what SymPy's special values in it mean
    for the user's function (``zoo``: complex infinity, e.g. ``x / 0``)."""
    text = str(exc)
    if any(v in text.split() or f"({v})" in text for v in ("zoo", "nan", "oo", "-oo")):
        text += (" (the function simplifies to an infinite or undefined value: a division by "
                 "zero or a log of 0)")
    return text


class GeneratedFunction:
    """A function compiled by :func:`generate` (see the module docstring).

    >>> from fgopt.symbolic import V1, V2, generate
    >>> def sq(x: V2) -> V1:
    ...     return V1(x.squared_norm())
    ...
    >>> f = generate(sq)
    >>> f(np.array([3.0, 4.0]))                      # value and Jacobian
    (array([25.]), array([[6., 8.]]))
    >>> out, J = f.batch(np.array([[3.0, 4.0], [1.0, 0.0]]))   # two inputs in one call
    >>> out.ravel(), J.shape
    (array([25.,  1.]), (2, 1, 2))
    """

    def __init__(self, fn: Callable, *, which: Iterable[str] | None, name: str | None,
                 method: str, engine: str, cache: bool, scope: dict | None = None):
        self.fn = fn
        self.name = name or getattr(fn, "__name__", "generated")
        if not self.name.isidentifier():
            self.name = "generated"
        from .jacobians import METHODS
        from .linearize import ENGINES

        if method not in METHODS or engine not in ENGINES:
            raise FgoptError(f"generate {self.name}: method must be one of {METHODS} and engine "
                             f"one of {ENGINES}; got {method!r}, {engine!r}")
        self.method, self.engine = method, engine
        self.params = parameters(fn, self.name, scope)
        names = [n for n, _ in self.params]
        self.which: tuple[str, ...] = tuple(names) if which is None else _which(which, names,
                                                                                 self.name)
        self.module = self._load_module(cache)
        meta = self.module.META
        out_types = [_resolve_type(d) for d in meta["outputs"]]
        if any(t is None for t in out_types):  # an output type defined in a local scope
            self.module = self._load_module(False)
            out_types = self._symbolic_output_types()
        types = dict(self.params)
        col_slices, col = {}, 0
        for n in self.which:  # Jacobian column blocks in the order of ``which``
            col_slices[n] = slice(col, col + types[n].dim())
            col += types[n].dim()
        pos = 0
        inputs = []
        for n, tp in self.params:
            s = tp.storage_dim()
            inputs.append(Slot(n, tp, slice(pos, pos + s), col_slices.get(n)))
            pos += s
        self.input_dim = pos
        #: One :class:`Slot` per argument, in signature order.
        self.arguments: tuple[Slot, ...] = tuple(inputs)
        outputs = []
        pos = row = 0
        for i, tp in enumerate(out_types):
            s, d = tp.storage_dim(), tp.dim()
            outputs.append(Slot(f"output{i}", tp, slice(pos, pos + s), slice(row, row + d)))
            pos, row = pos + s, row + d
        #: One :class:`Slot` per output.
        self.outputs: tuple[Slot, ...] = tuple(outputs)
        self.output_dim = pos
        self.tuple_output = bool(meta["tuple_output"])
        #: Shape of the stacked Jacobian: (sum of output dims, sum of dims of ``which``).
        self.jacobian_shape = (row, col)
        #: Row slice of each output's block in the stacked Jacobian.
        self.rows: tuple[slice, ...] = tuple(o.tangent for o in outputs)
        #: Column slice of each argument of ``which`` in the stacked Jacobian.
        self.cols: dict[str, slice] = col_slices
        #: Storage slice of each argument in the flat input vector.
        self.inputs: dict[str, slice] = {a.name: a.storage for a in inputs}
        self._index = {n: i for i, n in enumerate(names)}
        self.flat = self.module.flat
        self.flat_value = self.module.flat_value

    # ------------------------------------------------------------------ derivation / cache
    def _load_module(self, use_cache: bool):
        parts = ("generate", _implementation_hash(), self.name,
                 tuple((n, tp.__module__, tp.__qualname__) for n, tp in self.params),
                 self.which, self.method, self.engine)
        key = _cache.kernel_key(self.fn, parts) if use_cache else None
        modname = f"gen_{self.name}"
        if key is not None:
            module = _cache.load(modname, key)
            if module is not None:
                return module
        from ._generate_source import derive_source

        try:
            source = derive_source(self)
        except FgoptError:  # already names the user's function
            raise
        except ValueError as exc:  # no code for a value (SymPy's zoo, nan)
            raise FgoptError(f"{self.name}: cannot generate its code: "
                             f"{explain_derive_error(exc)}") from None
        _cache.STATS["derived"] += 1
        if key is None:
            key = "nocache_" + hashlib.sha256(source.encode()).hexdigest()[:16]
        return _cache.store(modname, key, source)

    def _symbolic_output_types(self) -> list:
        from ._generate_source import run_symbolic

        _, outputs, _ = run_symbolic(self)
        from ._generate_source import output_type

        return [output_type(o) for o in outputs]

    def symbolic(self):
        """Run the function on symbolic arguments: ``(arguments, outputs)`` (outputs a list)."""
        from ._generate_source import run_symbolic

        args, outputs, _ = run_symbolic(self)
        return args, outputs

    @property
    def source(self) -> str:
        """The generated module's source (the verified text the cache executed)."""
        text = getattr(self.module, "__fgopt_source__", None)
        if text is not None:
            return text
        with open(self.module.__file__) as fh:
            return fh.read()

    @property
    def ops(self) -> dict:
        """Operation counts of the generated code (``value`` and ``jacobian``)."""
        return dict(self.module.META["ops"])

    # ------------------------------------------------------------------ evaluation
    def __call__(self, *args: Any, **kwargs: Any):
        """``(value, jacobian)`` at numeric arguments (only ``value`` if ``which`` is empty).

        ``value`` is the output, or a tuple of outputs if the function returns a tuple.
        """
        inp = self.pack(*args, **kwargs)
        out = np.empty(self.output_dim)
        if len(self.which) == 0:
            self.flat_value(inp, out)
            return self._unpack(out)
        jac = np.empty(self.jacobian_shape)
        self.flat(inp, out, jac)
        if not np.all(np.isfinite(jac)):
            raise NonFiniteError(f"{self.name}: the Jacobian is not finite at these arguments")
        return self._unpack(out), jac

    def value(self, *args: Any, **kwargs: Any):
        """The output(s) only (no Jacobian is computed)."""
        inp = self.pack(*args, **kwargs)
        out = np.empty(self.output_dim)
        self.flat_value(inp, out)
        return self._unpack(out)

    def batch(self, *args: Any, **kwargs: Any):
        """Evaluate ``n`` instances in one call: ``(outputs, jacobians)``.

        Each argument is an ``(n, storage_dim)`` array (``(n,)`` for scalars), or one value
        used for every row. ``outputs`` is an ``(n, storage_dim)`` array per output (a tuple
        if the function returns a tuple), ``jacobians`` is ``(n, rows, cols)`` (omitted if
        ``which`` is empty).
        """
        values = self._bind(args, kwargs)
        cols, n = [], None
        for (name, tp), v in zip(self.params, values):
            arr = _batch_storage(self.name, name, tp, v)
            if arr.shape[0] != 1:
                if n is not None and arr.shape[0] != n:
                    raise DimensionMismatchError(
                        f"{self.name}: argument '{name}' has {arr.shape[0]} rows, another "
                        f"argument has {n}")
                n = arr.shape[0]
            cols.append(arr)
        n = 1 if n is None else n
        inp = np.empty((n, self.input_dim))
        for a, arr in zip(self.arguments, cols):
            inp[:, a.storage] = arr
        if not np.all(np.isfinite(inp)):
            row, col = np.argwhere(~np.isfinite(inp))[0]
            arg = next(a for a in self.arguments if a.storage.start <= col < a.storage.stop)
            raise NonFiniteError(f"{self.name}: argument '{arg.name}' is not finite in row {row}")
        out = np.empty((n, self.output_dim))
        if len(self.which) == 0:
            self.module.batch_value(inp, out)
            return self._split_rows(out)
        jac = np.empty((n, *self.jacobian_shape))
        self.module.batch(inp, out, jac)
        return self._split_rows(out), jac

    def _split_rows(self, out: np.ndarray):
        if not self.tuple_output:
            return out
        return tuple(out[:, o.storage] for o in self.outputs)

    def pack(self, *args: Any, **kwargs: Any) -> np.ndarray:
        """The flat input vector of numeric arguments (checked), as ``flat`` takes it."""
        values = self._bind(args, kwargs)
        inp = np.empty(self.input_dim)
        for a, v in zip(self.arguments, values):
            inp[a.storage] = value_storage(self.name, a.name, a.type, v)
        return inp

    def _bind(self, args: tuple, kwargs: dict) -> list:
        n = len(self.params)
        if len(args) > n:
            raise FgoptError(f"{self.name}: takes {n} arguments, got {len(args)}")
        values = list(args) + [_MISSING] * (n - len(args))
        for k, v in kwargs.items():
            i = self._index.get(k)
            if i is None:
                raise FgoptError(f"{self.name}: unknown argument '{k}' "
                                 f"(arguments: {', '.join(n for n, _ in self.params)})")
            if values[i] is not _MISSING:
                raise FgoptError(f"{self.name}: argument '{k}' given twice")
            values[i] = v
        missing = [self.params[i][0] for i, v in enumerate(values) if v is _MISSING]
        if len(missing) > 0:
            raise FgoptError(f"{self.name}: missing argument(s) {', '.join(missing)}")
        return values

    def _unpack(self, out: np.ndarray):
        if not np.all(np.isfinite(out)):
            raise NonFiniteError(f"{self.name}: the output is not finite at these arguments")
        vals = tuple(numeric_value(o.type, out[o.storage]) for o in self.outputs)
        return vals if self.tuple_output else vals[0]

    def __repr__(self) -> str:
        sig = ", ".join(f"{n}: {tp.__name__}" for n, tp in self.params)
        outs = ", ".join(o.type.__name__ for o in self.outputs)
        if self.tuple_output:
            outs = f"({outs})"
        jac = (f"; jacobian d/d({', '.join(self.which)}) {self.jacobian_shape[0]}x"
               f"{self.jacobian_shape[1]}" if len(self.which) > 0 else "; no jacobian")
        ops = self.ops
        return (f"<fgopt generated {self.name}({sig}) -> {outs}{jac}; ops value "
                f"{ops['value']}, jacobian {ops['jacobian']}>")


_MISSING = object()


# ---------------------------------------------------------------------- helpers
def parameters(fn: Callable, name: str, scope: dict | None) -> tuple:
    """``((name, symbolic type), ...)`` of a function's parameters, checked: every one annotated
    with a symbolic type, no reserved names, no two storage symbols alike."""
    try:
        sig = inspect.signature(fn)
    except (TypeError, ValueError) as exc:
        raise FgoptError(f"generate {name}: cannot read the signature: {exc}") from None
    try:
        hints = type_hints(fn, scope)
    except Exception as exc:
        raise FgoptError(f"generate {name}: cannot resolve annotations: {exc}") from exc
    params = []
    for p in sig.parameters.values():
        if p.kind not in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY):
            raise FgoptError(f"generate {name}: *args / **kwargs are not supported")
        if p.name not in hints:
            raise FgoptError(f"generate {name}: argument '{p.name}' needs a type annotation "
                             "(Rot3, Pose3, V3, Scalar, ...)")
        if p.name.startswith("_") or p.name in _RESERVED:
            raise FgoptError(f"generate {name}: argument name '{p.name}' is reserved")
        try:
            tp = normalize_type(hints[p.name])
        except TypeError as exc:
            raise FgoptError(f"generate {name}: argument '{p.name}': {exc}") from None
        params.append((p.name, tp))
    if len(params) == 0:
        raise FgoptError(f"generate {name}: the function takes no arguments")
    symbols: dict = {}
    for n, tp in params:  # storage symbols are named n_0, n_1, ... (scalars: n)
        names = [n] if tp is Scalar else [f"{n}_{k}" for k in range(tp.storage_dim())]
        for s in names:
            if s in symbols:
                raise FgoptError(f"generate {name}: arguments '{symbols[s]}' and '{n}' both "
                                 f"define the symbol {s}; rename one")
            symbols[s] = n
    return tuple(params)


def _which(which: Iterable[str], names: Sequence[str], name: str) -> tuple[str, ...]:
    if isinstance(which, str):
        which = [which]
    out = tuple(which)
    unknown = [w for w in out if w not in names]
    if len(unknown) > 0:
        raise FgoptError(f"generate {name}: which names unknown argument(s) {unknown} "
                         f"(arguments: {', '.join(names)})")
    if len(set(out)) != len(out):
        raise FgoptError(f"generate {name}: which lists an argument twice: {list(out)}")
    return out


class _SymbolicNames(dict):
    """The calling scope, then any public name of ``fgopt.symbolic`` (lazy ones included, e.g.
    ``SE23``: loaded only if an annotation names them)."""

    def __missing__(self, key: str):
        from .. import symbolic

        if key.startswith("_"):
            raise KeyError(key)
        try:
            return getattr(symbolic, key)
        except AttributeError:
            raise KeyError(key) from None


def type_hints(fn: Callable, scope: dict | None) -> dict:
    """Annotations, string ones resolved in the function's globals, the calling scope and
    ``fgopt.symbolic``'s names."""
    try:
        return typing.get_type_hints(fn)
    except NameError:
        globalns = dict(getattr(fn, "__globals__", {}))
        return typing.get_type_hints(fn, globalns=globalns, localns=_SymbolicNames(scope or {}))


def _resolve_type(desc: Sequence) -> type | None:
    """A symbolic type from its description in ``META["outputs"]`` (``None`` if not found)."""
    kind = desc[0]
    if kind == "scalar":
        return Scalar
    if kind == "matrix":
        return Matrix.shaped(int(desc[1]), int(desc[2]))
    module = sys.modules.get(desc[1])
    if module is None:
        try:
            import importlib

            module = importlib.import_module(desc[1])
        except ImportError:
            return None
    obj: Any = module
    for part in desc[2].split("."):
        obj = getattr(obj, part, None)
        if obj is None:
            return None
    return obj if isinstance(obj, type) and issubclass(obj, MANIFOLD_TYPES) else None
