"""``@fgopt.factor``: a typed residual function over symbolic types becomes a factor type.

    @fgopt.factor
    def range_bearing(pose: Pose2, landmark: V2, measured: V2) -> V2:
        d = pose.inverse() * landmark
        return V2(d.norm(), atan2(d[1], d[0])) - measured

    f = range_bearing(pose=key('x', 1), landmark=key('l', 3), measured=np.array([4.0, 0.3]),
                      loss=noise)

Calling the factor type makes an instance (an ordinary :class:`~fgopt.factors.base.KernelFactor`).
The rule for arguments, with no guessing:

* a :class:`fgopt.Key` (``fgopt.key('x', 1)``, or ``fgopt.Key(7)`` for a plain-int key) is a
  *variable*;
* a float, a numpy array, a sequence of numbers, a manifold value (``SE2``...) or anything
  wrapped in :func:`const` is a *constant* (its storage goes into the instance's constants row);
* a bare ``int`` (or ``bool``, numpy integer) is refused with an :class:`~fgopt.errors.FgoptError`:
  plain ints are keys elsewhere in fgopt (``Variables.add(7, x)``), so ``b=1`` could mean key 1
  or the number 1. Write ``fgopt.Key(1)`` or ``1.0`` / ``fgopt.const(1)``.
 One kernel is generated per pattern of
variables: the function is run once on symbolic arguments, its tangent-space Jacobians w.r.t.
the variables are derived (:mod:`fgopt.symbolic.linearize`), CSE'd and emitted as a batched
numba module (:mod:`fgopt.symbolic.codegen`), cached on disk (:mod:`fgopt.symbolic.cache`).
``factor_type.source`` shows the generated code.

Kernels compute the unwhitened residual and Jacobian; ``loss`` (a noise model or robust loss)
is applied by the problem, as for every kernel factor.

This module does not import SymPy: on a cache hit nothing symbolic runs.
"""

from __future__ import annotations

import functools
import inspect
import sys
import typing
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np

from ..errors import DimensionMismatchError, FgoptError, NonFiniteError
from ..key import Key
from ..noise._keyword import unknown_keyword_hint
from ..symbolic import cache as _cache
from ..symbolic.codegen import RESERVED_NAMES
from ..symbolic.declare.twin import DeclaredManifold
from ..symbolic.lie import LieGroupBase
from ..symbolic.matrix import Matrix, Scalar
from ..symbolic.ops import normalize_type, type_key
from .base import KernelFactor
from .kernel import CompiledCall, FactorKernel, module_trusted_linearize

_MISSING = object()
_NO_CONSTANTS = np.zeros(0)
_NUMERIC_TWIN = {"Rot2": "SO2", "Pose2": "SE2", "Rot3": "SO3", "Pose3": "SE3"}

#: id(kernel) -> (kernel, factor type, variable pattern) of every generated kernel, so a plain
#: KernelFactor (e.g. a row of a file reader's batch) can be traced back to its symbolic source.
KERNEL_ORIGINS: dict = {}


def factor(fn: Callable | None = None, *, name: str | None = None, method: str = "retraction",
           engine: str = "auto", hessian: bool = False, cache: bool = True,
           variables: Iterable[str] | None = None):
    """Decorator: make a factor type from a typed symbolic residual function.

    Args:
        fn: ``def f(a: Pose3, b: V3, ...) -> V3``; every parameter annotated with a symbolic
            type (``Rot2, Rot3, Pose2, Pose3, V1..V9, Matrix.shaped(r, c), Scalar``, or a
            manifold declared with ``@fgopt.manifold``).
        name: factor name (default ``fn.__name__``).
        method: tangent-space Jacobian method, ``"retraction"`` (first-order retraction, the
            default) or ``"chain"`` (symbolic chain rule).
        engine: ``"auto"``, ``"tree"``, ``"dag"`` or ``"reverse"`` (see
            :mod:`fgopt.symbolic.linearize`).
        hessian: also generate ``linearize_hessian`` (``J^T J`` and ``J^T r`` per instance).
        cache: use the on-disk kernel cache.
        variables: argument names that are variables in the default pattern shown by
            ``.source`` before any instance exists (default: all).

    Example:

    >>> from fgopt.symbolic import Pose2, V2, atan2
    >>> @fgopt.factor
    ... def range_bearing(pose: Pose2, landmark: V2, measured: V2) -> V2:
    ...     d = pose.inverse() * landmark
    ...     return V2(d.norm(), atan2(d[1], d[0])) - measured
    ...
    >>> f = range_bearing(pose=key('x', 0), landmark=key('l', 0), measured=np.array([2.0, 0.0]))
    >>> values = fgopt.Variables().add(key('x', 0), fgopt.SE2()).add(key('l', 0), np.array([3.0, 0.0]))
    >>> np.round(f.error(values), 6)
    array([1., 0.])
    """
    def wrap(f: Callable, scope: dict | None = None) -> SymbolicFactorType:
        if scope is None:  # the defining scope: resolves string annotations of local names
            scope = sys._getframe(1).f_locals
        return SymbolicFactorType(f, name=name, method=method, engine=engine, hessian=hessian,
                                  cache=cache, variables=variables, scope=scope)

    return wrap if fn is None else wrap(fn, sys._getframe(1).f_locals)


class const:
    """Marks a value given to an ``@fgopt.factor`` argument as a constant: ``fgopt.const(1)``.

    Only needed where a value could be read as a key (a bare int); floats, arrays and manifold
    values are constants already.

    Example:

    >>> from fgopt.symbolic import Scalar, V1
    >>> @fgopt.factor
    ... def scaled(x: Scalar, gain: Scalar) -> V1:
    ...     return V1(gain * x - 1)
    ...
    >>> f = scaled(x=key('s', 0), gain=fgopt.const(2))
    >>> f.error(fgopt.Variables().add(key('s', 0), 1.0))
    array([1.])
    """

    __slots__ = ("value",)

    def __init__(self, value: Any):
        if isinstance(value, Key):
            raise FgoptError(f"fgopt.const({value!r}): a Key is a variable; pass the key itself, "
                             "or a number for a constant")
        self.value = value

    def __repr__(self) -> str:
        return f"fgopt.const({self.value!r})"


def _ambiguous(value: Any) -> bool:
    """A bare int / bool / numpy integer: a key or a number? (``Key`` is not ambiguous.)"""
    return (isinstance(value, (int, np.integer)) and not isinstance(value, Key)) or isinstance(
        value, np.bool_)


class SymbolicFactor(KernelFactor):
    """An instance of a :class:`SymbolicFactorType` (a kernel factor).

    >>> from fgopt.factors import SymbolicFactor
    >>> from fgopt.symbolic import V1
    >>> @fgopt.factor
    ... def offset(x: V1, m: V1) -> V1:
    ...     return x - m
    ...
    >>> f = offset(x=key('x', 0), m=np.array([2.0]))      # m: a constant
    >>> isinstance(f, SymbolicFactor), f.keys, f.error(fgopt.Variables().add(key('x', 0), np.array([5.0])))
    (True, (x0,), array([3.]))
    """

    def __init__(self, factor_type: SymbolicFactorType, kernel: FactorKernel, keys: list,
                 constants: np.ndarray, loss: Any):
        self.factor_type = factor_type
        super().__init__(kernel, keys, constants, loss)

    def describe(self) -> str:
        keys = ", ".join(repr(k) for k in self.keys) if hasattr(self, "keys") else "?"
        return f"{self.factor_type.name}({keys})"


class SymbolicFactorType:
    """A factor type made by :func:`factor`; call it to make instances.

    Arguments given a key are variables; numbers are constants. One kernel is derived per
    pattern of variables:

    >>> from fgopt.factors import SymbolicFactorType
    >>> from fgopt.symbolic import V1
    >>> @fgopt.factor
    ... def offset(x: V1, m: V1) -> V1:
    ...     return x - m
    ...
    >>> isinstance(offset, SymbolicFactorType)
    True
    >>> offset(x=key('x', 0), m=np.array([2.0])).kernel is offset.kernel(["x"])
    True
    >>> f = offset(x=key('x', 0), m=key('m', 0))         # both variables: another kernel
    >>> values = fgopt.Variables().add(key('x', 0), np.array([5.0])).add(key('m', 0), np.array([2.0]))
    >>> f.error(values), [J.tolist() for J in f.jacobians(values)]
    (array([3.]), [[[1.0]], [[-1.0]]])
    """

    def __init__(self, fn: Callable, *, name: str | None, method: str, engine: str,
                 hessian: bool, cache: bool, variables: Iterable[str] | None,
                 scope: dict | None = None):
        functools.update_wrapper(self, fn)
        self.fn = fn
        self.name = name or fn.__name__
        self.method, self.engine, self.hessian, self.use_cache = method, engine, hessian, cache
        sig = inspect.signature(fn)
        try:
            hints = _type_hints(fn, scope)
        except Exception as exc:
            raise FgoptError(f"@fgopt.factor {self.name}: cannot resolve annotations: {exc}") from exc
        params = []
        for p in sig.parameters.values():
            if p.kind not in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY):
                raise FgoptError(f"@fgopt.factor {self.name}: *args / **kwargs are not supported")
            if p.name not in hints:
                raise FgoptError(f"@fgopt.factor {self.name}: argument '{p.name}' needs a type "
                                 "annotation (Pose2, Pose3, Rot3, V3, Scalar, ...)")
            if p.name.startswith("_") or p.name in RESERVED_NAMES or p.name == "loss":
                raise FgoptError(f"@fgopt.factor {self.name}: argument name '{p.name}' is reserved")
            try:
                tp = normalize_type(hints[p.name])
            except TypeError as exc:
                raise FgoptError(f"@fgopt.factor {self.name}: argument '{p.name}': {exc}") from None
            params.append((p.name, tp))
        if len(params) == 0:
            raise FgoptError(f"@fgopt.factor {self.name}: the function takes no arguments")
        self.params: tuple = tuple(params)
        self.return_type = hints.get("return")
        self._index = {n: i for i, (n, _) in enumerate(params)}
        self._storage_dims = tuple(tp.storage_dim() for _, tp in params)
        self._kernels: dict = {}
        self._sources: dict = {}
        self._modules: dict = {}
        self._default_variables = tuple(variables) if variables is not None else None
        self._options = dict(name=name, method=method, engine=engine, hessian=hessian,
                             cache=cache, variables=variables)
        self._fingerprint: str | None = None
        #: ``(function, args)`` returning this type in any process, for types made by code
        #: rather than defined at module level (see :mod:`fgopt.factors.portable`).
        self.recipe: tuple | None = None

    @property
    def fingerprint(self) -> str:
        """Hash of the residual function's code and the globals it uses (part of cache keys)."""
        if self._fingerprint is None:
            self._fingerprint = _cache.function_fingerprint(self.fn)
        return self._fingerprint

    def __reduce__(self):
        # By reference when the type is importable (a module-level definition), else by the
        # function's source text and the globals it reads; either way the receiving process
        # loads or derives its own kernels (see fgopt.factors.portable).
        from .portable import reduce_factor_type

        return reduce_factor_type(self)

    # ------------------------------------------------------------------ instances
    def __call__(self, *args: Any, loss: Any = None, **kwargs: Any) -> SymbolicFactor:
        n = len(self.params)
        if len(args) > n:
            raise FgoptError(f"{self.name}: takes {n} arguments, got {len(args)}")
        values = list(args) + [_MISSING] * (n - len(args))
        for k, v in kwargs.items():
            i = self._index.get(k)
            if i is None:
                raise FgoptError(f"{self.name}: unknown argument '{k}' "
                                 f"(arguments: {', '.join(p for p, _ in self.params)}"
                                 f"{unknown_keyword_hint(k)})")
            if values[i] is not _MISSING:
                raise FgoptError(f"{self.name}: argument '{k}' given twice")
            values[i] = v
        missing = [self.params[i][0] for i, v in enumerate(values) if v is _MISSING]
        if len(missing) > 0:
            raise FgoptError(f"{self.name}: missing argument(s) {', '.join(missing)}")
        for i, v in enumerate(values):
            if _ambiguous(v):
                name, tp = self.params[i]
                raise FgoptError(
                    f"{self.name}: argument '{name}' ({tp.__name__}) got the int {v!r}, which could "
                    f"be a key or a number: pass fgopt.key(...) / fgopt.Key({int(v)}) for a "
                    f"variable, or {float(v)!r} / fgopt.const({int(v)}) for a constant")
        pattern = tuple(isinstance(v, Key) for v in values)
        kernel = self._kernels.get(pattern)
        if kernel is None:
            if not any(pattern):
                raise FgoptError(f"{self.name}: no argument is a variable; pass fgopt.key(...) "
                                 "for the variables")
            kernel = self.kernel(pattern)
        keys = [v for v, is_var in zip(values, pattern) if is_var]
        consts = [self._constant(i, v) for i, v in enumerate(values) if not pattern[i]]
        if len(consts) == 1:
            c = consts[0]
        else:
            c = np.concatenate(consts) if len(consts) > 0 else _NO_CONSTANTS
        try:
            return SymbolicFactor(self, kernel, keys, c, loss)
        except NonFiniteError:  # (checked once, on all constants): name the argument
            for i, arr in zip((i for i in range(n) if not pattern[i]), consts):
                if not np.all(np.isfinite(arr)):
                    raise NonFiniteError(
                        f"{self.name}: argument '{self.params[i][0]}' has a NaN or inf: "
                        f"{arr}") from None
            raise

    def _constant(self, i: int, value: Any) -> np.ndarray:
        s = self._storage_dims[i]
        if type(value) is const:
            value = value.value
        if type(value) is np.ndarray and value.shape == (s,) and value.dtype == np.float64:
            return value  # fast path (KernelFactor copies it)
        name, tp = self.params[i]
        if issubclass(tp, DeclaredManifold) and hasattr(value, "to_storage"):
            if type(value) is not tp.Value:
                raise FgoptError(f"{self.name}: argument '{name}' is a {tp.__name__}; got a "
                                 f"{type(value).__name__} (give a {tp.__name__}.Value, its "
                                 "storage, or a key)")
            value = value.to_storage()
        elif issubclass(tp, LieGroupBase) and hasattr(value, "to_storage"):
            twin = _NUMERIC_TWIN.get(tp.__name__)
            if twin is not None and type(value).__name__ != twin:
                raise FgoptError(f"{self.name}: argument '{name}' is a {tp.__name__}; got a "
                                 f"{type(value).__name__} (give an fgopt.manifolds.{twin}, its "
                                 f"storage, or a key)")
            value = value.to_storage()
        try:
            arr = np.asarray(value, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError) as exc:
            raise DimensionMismatchError(
                f"{self.name}: argument '{name}' ({tp.__name__}) must be a key or "
                f"{s} numbers, got {value!r}") from exc
        if arr.shape[0] != s:
            raise DimensionMismatchError(
                f"{self.name}: argument '{name}' ({tp.__name__}) needs {s} numbers "
                f"(its storage), got {arr.shape[0]}")
        return arr

    # ------------------------------------------------------------------ kernels
    def _pattern(self, variables: Any) -> tuple:
        if variables is None:
            if self._default_variables is None:
                return tuple(True for _ in self.params)
            variables = self._default_variables
        if isinstance(variables, tuple) and all(isinstance(v, bool) for v in variables):
            if len(variables) != len(self.params):
                raise FgoptError(f"{self.name}: pattern needs {len(self.params)} booleans")
            return variables
        names = set(variables)
        unknown = names - set(self._index)
        if len(unknown) > 0:
            raise FgoptError(f"{self.name}: unknown argument(s) {sorted(unknown)}")
        return tuple(n in names for n, _ in self.params)

    def kernel(self, variables: Any = None) -> FactorKernel:
        """The :class:`FactorKernel` for a variable pattern (argument names or booleans)."""
        pattern = self._pattern(variables)
        k = self._kernels.get(pattern)
        if k is None:
            module = self._module(pattern)
            k = _kernel_from_module(module, self.params, pattern, self.name,
                                    recipe=(SymbolicFactorType.kernel, (self, pattern)))
            KERNEL_ORIGINS[id(k)] = (k, self, pattern)
            self._kernels[pattern] = k
            self._sources[pattern] = k.source
            self._modules[pattern] = module
        return k

    def generated_module(self, variables: Any = None):
        """The generated (imported) module of a pattern: kernels, wrappers and ``META``."""
        self.kernel(variables)
        return self._modules[self._pattern(variables)]

    def linearize_hessian(self, variables: Any = None):
        """``f(args, consts) -> (res, jac, J^T J, J^T r)`` (unwhitened); needs ``hessian=True``."""
        module = self.generated_module(variables)
        if not hasattr(module, "linearize_hessian"):
            raise FgoptError(f"{self.name}: declare @fgopt.factor(hessian=True) to generate "
                             "J^T J and J^T r")
        return module.linearize_hessian

    def cache_key(self, pattern: tuple) -> str:
        """The kernel cache key of a variable pattern (function, pattern, options, package)."""
        parts = (self.name, tuple((n,) + type_key(tp) for n, tp in self.params),
                 pattern, self.method, self.engine, self.hessian)
        return _cache.kernel_key(self.fn, parts, self.fingerprint)

    def _module(self, pattern: tuple):
        key = self.cache_key(pattern) if self.use_cache else None
        if key is not None:
            module = _cache.load(self.name, key, required=self._required())
            if module is not None:
                return module
            # built-in factors ship their generated source: nothing is derived at first use
            from .library.shipped import shipped_source

            source = shipped_source(self.name, key)
            if source is not None:
                _cache.STATS["shipped"] += 1
                return _cache.store(self.name, key, source)
        from .._first_use import preparing
        from ..symbolic.derive import derive_source

        with preparing(f"deriving the kernels of {self.name} (SymPy)"):
            try:
                source = derive_source(self, pattern)
            except FgoptError:  # already names the user's function
                raise
            except ValueError as exc:  # an unknown method / engine, or no code for a value
                from ..symbolic.generated import explain_derive_error

                raise FgoptError(f"{self.name}: cannot generate its kernels: "
                                 f"{explain_derive_error(exc)}") from None
        _cache.STATS["derived"] += 1
        if key is None:
            import hashlib

            key = "nocache_" + hashlib.sha256(source.encode()).hexdigest()[:16]
        return _cache.store(self.name, key, source)

    def _required(self) -> tuple[str, ...]:
        """What a generated module of this type must define (else its cache entry is redone)."""
        base = ("META", "NUM_CONSTANTS", "residual", "linearize")
        return base + ("linearize_hessian",) if self.hessian else base

    @property
    def source(self) -> str:
        """Generated source of every kernel made so far (of the default pattern if none)."""
        if len(self._sources) == 0:
            self.kernel()
        return "\n\n".join(self._sources.values())

    def symbolic(self, *names: str):
        """Run the function on symbolic arguments; returns ``(args, output)``."""
        from ..symbolic.ops import symbolic_value

        from ..symbolic.derive import trace

        names = names or tuple(n for n, _ in self.params)
        args = [symbolic_value(tp, n) for n, (_, tp) in zip(names, self.params)]
        return args, trace(self, args)

    def __repr__(self) -> str:
        sig = ", ".join(f"{n}: {tp.__name__}" for n, tp in self.params)
        return f"<fgopt factor {self.name}({sig})>"


def _type_hints(fn: Callable, scope: dict | None) -> dict:
    """Annotations, with string ones (``from __future__ import annotations``) resolved in the
    function's globals, then the defining scope, then ``fgopt.symbolic``'s names."""
    try:
        return typing.get_type_hints(fn)
    except NameError:
        from .. import symbolic

        ns = {k: getattr(symbolic, k) for k in dir(symbolic) if not k.startswith("_")}
        ns.update(fn.__globals__)
        ns.update(scope or {})
        return typing.get_type_hints(fn, globalns=ns)


def batch_kind_of(tp: type):
    """The :class:`~fgopt.manifolds.base.BatchKind` of variables of symbolic type ``tp``."""
    from .. import manifolds as M

    if tp is Scalar:
        return M.SCALAR_KIND
    if issubclass(tp, Matrix):
        return M.vector_kind(tp.storage_dim())
    if issubclass(tp, DeclaredManifold):
        return tp.Value.batch_kind()
    from ..symbolic.ops import NUMERIC_TWINS

    registered = NUMERIC_TWINS.get(tp)
    if registered is not None:
        return registered.batch_kind()
    if tp.__name__ == "NavState":
        raise FgoptError("symbolic NavState variables hold fgopt.navigation.NavState values: "
                         "import fgopt.navigation first")
    twin = _NUMERIC_TWIN.get(tp.__name__)
    if twin is None or not hasattr(M, twin):
        raise FgoptError(f"no numeric manifold for symbolic type {tp.__name__}")
    return getattr(M, twin).batch_kind()


def _kernel_from_module(module: Any, params: tuple, pattern: tuple, name: str,
                        recipe: tuple | None = None) -> FactorKernel:
    meta = module.META
    kinds = tuple(batch_kind_of(tp) for (_, tp), v in zip(params, pattern) if v)
    source = module.__fgopt_source__  # the verified text that ran, not a re-read of the file
    raw = getattr(module, "_linearize_kernel", None)
    trusted = None if raw is None else module_trusted_linearize(
        raw, meta["residual_dim"], sum(k.dim for k in kinds))
    return FactorKernel(name=name, arg_kinds=kinds, residual_dim=meta["residual_dim"],
                        num_constants=module.NUM_CONSTANTS, residual=module.residual,
                        linearize=module.linearize, source=source, recipe=recipe,
                        clamps=tuple(meta.get("clamps", ())),
                        clamp_arguments=getattr(module, "clamp_arguments", None),
                        numpy_twin=all(hasattr(module, a) for a in
                                       ("use_numpy", "_residual_numpy", "_linearize_numpy")),
                        trusted_linearize=trusted,
                        compiled_call=None if raw is None else CompiledCall(
                            module.__name__, "_linearize_kernel", fills=True))
