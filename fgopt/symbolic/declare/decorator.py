"""``@fgopt.manifold``: a small class over symbolic types becomes a manifold with batched kernels.

    @fgopt.manifold
    class Sphere:
        '''Unit vectors of R^3.'''
        storage_dim = 3
        dim = 2

        def identity():
            return V3(0, 0, 1)

        def basis(x):                 # an accessor: usable in factor bodies, numeric too
            ...
        def retract(x, d):
            ...
        def local(x, y):
            ...
        def normalize(x):             # optional: storage that drifts
            return x.storage / x.storage.norm(0)

The decorated name is the *symbolic twin* (a :class:`~fgopt.symbolic.declare.twin.
DeclaredManifold`): annotate ``@fgopt.factor`` arguments with it. ``Sphere.Value`` is the
numeric value type (``Sphere.Value([0, 0, 1])``, ``repr``, ``to_storage``, ``from_storage``,
``retract``, ``local``, the accessors), registered with :mod:`fgopt.manifolds` with a
:class:`~fgopt.manifolds.base.BatchKind` whose ``retract`` / ``local`` are generated numba
kernels. Optional class attributes: ``fields`` (accessor names ``repr`` shows) and an accessor
named ``position`` (a 2- or 3-vector) that plots use.

What runs where: on a cache miss the declaration is derived with SymPy
(:mod:`~fgopt.symbolic.declare.derive`), emitted (:mod:`~fgopt.symbolic.declare.codegen`),
checked numerically (:mod:`~fgopt.symbolic.declare.checks`; a failing check raises
:class:`~fgopt.errors.ManifoldDeclarationError` naming the method, and nothing is cached), then
written to the kernel cache. On a hit the module is imported (no SymPy); numba compiles the
kernels on first use and caches the machine code next to the module.
"""

from __future__ import annotations

import hashlib
import inspect
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from ...errors import FgoptError, ManifoldDeclarationError
from .. import cache as _cache
from .twin import DeclaredManifold

#: Methods a declaration may define, and where the twin keeps them.
_USER_FUNCTIONS = {"retract": "_user_retract", "local": "_user_local",
                   "identity": "_user_identity", "normalize": "_user_normalize",
                   "storage_D_tangent": "_user_storage_D_tangent"}
_SETTINGS = ("storage_dim", "dim", "fields")
#: Modules of this package whose source defines generated manifold code (hashed into keys).
_FINGERPRINT_FILES = ("twin.py", "derive.py", "codegen.py", "product.py", "runtime.py")

#: Declaration key -> twin class, for every manifold declared in this process.
DECLARED: dict[str, type] = {}
#: Counters (tests, benchmarks): declarations ``derived`` (SymPy ran) or ``loaded`` from disk.
STATS = {"derived": 0, "loaded": 0}


def manifold(cls: type | None = None, *, name: str | None = None, cache: bool = True):
    """Class decorator: declare a manifold (see the module docstring).

    Args:
        cls: the declaration: ``storage_dim``, ``dim``, ``retract(x, d)``, ``local(x, y)``;
            optionally ``identity()``, ``normalize(x)``, ``storage_D_tangent(x)``, accessors
            (methods of ``x`` only), other methods, ``fields``.
        name: the manifold's name (default the class name).
        cache: use the on-disk kernel cache.

    Example:

    >>> from fgopt.symbolic import Rot2, V2
    >>> @fgopt.manifold
    ... class Pose2Like(fgopt.Product(Rot2, V2, names=('heading', 'position'))):
    ...     pass
    ...
    >>> x = Pose2Like.Value()
    >>> np.round(x.local(x.retract([0.1, 0.2, 0.3])), 6)
    array([0.1, 0.2, 0.3])
    """
    def wrap(c: type) -> type:
        return declare(c, name=name, cache=cache)

    return wrap if cls is None else wrap(cls)


def _namespace(cls: type) -> dict:
    """Attributes of the declaration and its bases (e.g. a ``Product(...)`` template)."""
    ns: dict = {}
    for base in reversed(cls.__mro__):
        if base is object or (isinstance(base, type) and issubclass(base, DeclaredManifold)
                              and base.__module__ == DeclaredManifold.__module__):
            continue
        for k, v in vars(base).items():
            if k.startswith("__") and k != "__doc__":
                continue
            ns[k] = v
    return ns


def _plain(v: Any, where: str):
    if isinstance(v, staticmethod):
        return v.__func__
    if isinstance(v, classmethod):
        raise ManifoldDeclarationError(f"{where}: write it as a plain function (no @classmethod)")
    if not callable(v):
        raise ManifoldDeclarationError(f"{where} must be a function, got {type(v).__name__}")
    return v


def _is_accessor(v: Any) -> bool:
    if not inspect.isfunction(v):
        return False
    params = list(inspect.signature(v).parameters.values())
    return len(params) == 1 and params[0].kind in (params[0].POSITIONAL_ONLY,
                                                   params[0].POSITIONAL_OR_KEYWORD)


def _size(ns: dict, attr: str, name: str) -> int:
    v = ns.get(attr)
    if v is None:
        raise ManifoldDeclarationError(f"@fgopt.manifold {name}: state {attr} = <int> in the "
                                       "class body")
    if callable(v):
        v = v()
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
        raise ManifoldDeclarationError(f"@fgopt.manifold {name}: {attr} must be a positive "
                                       f"int, got {v!r}")
    return int(v)


def declare(cls: type, name: str | None = None, cache: bool = True) -> type:
    """Declare ``cls`` (see :func:`manifold`); returns the symbolic twin class."""
    if not isinstance(cls, type):
        raise ManifoldDeclarationError(f"@fgopt.manifold decorates a class, got {cls!r}")
    name = name or cls.__name__
    ns = _namespace(cls)
    n, dim = _size(ns, "storage_dim", name), _size(ns, "dim", name)
    if dim > n:
        raise ManifoldDeclarationError(f"@fgopt.manifold {name}: dim {dim} exceeds storage_dim "
                                       f"{n} (the tangent space cannot be larger than storage)")
    for required in ("retract", "local"):
        if required not in ns:
            raise ManifoldDeclarationError(f"@fgopt.manifold {name}: define {required}(x, "
                                           f"{'d' if required == 'retract' else 'y'})")
    twin_ns: dict = {"__slots__": (), "__doc__": ns.get("__doc__") or cls.__doc__,
                     "__module__": cls.__module__, "_STORAGE_DIM": n, "_DIM": dim}
    for k, v in ns.items():
        if k in _USER_FUNCTIONS:
            twin_ns[_USER_FUNCTIONS[k]] = staticmethod(_plain(v, f"{name}.{k}"))
        elif k not in _SETTINGS and k != "__doc__":
            twin_ns[k] = v
    twin = type(name, (DeclaredManifold,), twin_ns)
    twin.__qualname__ = cls.__qualname__ if name == cls.__name__ else name
    twin._ACCESSORS = tuple(k for k, v in ns.items()
                            if not k.startswith("_") and k not in _USER_FUNCTIONS
                            and k not in _SETTINGS and _is_accessor(v))
    fields = tuple(ns.get("fields", ()))
    unknown = [f for f in fields if f not in twin._ACCESSORS]
    if len(unknown) > 0:
        raise ManifoldDeclarationError(f"@fgopt.manifold {name}: fields {unknown} are not "
                                       f"accessors (methods taking only x): {twin._ACCESSORS}")
    twin._FIELDS = fields
    twin._KEY = declaration_key(twin, ns)
    same = DECLARED.get(twin._KEY)
    if same is not None and (same.__module__, same.__qualname__) == (twin.__module__,
                                                                      twin.__qualname__):
        return same  # the same declaration again (a re-run cell): keep values compatible
    module = _module(twin, cache)
    twin.Value = _value_type(twin, module)
    twin._DECLARED = True
    DECLARED[twin._KEY] = twin
    return twin


# ------------------------------------------------------------------------------- cache key
@lru_cache(maxsize=1)
def _generator_fingerprint() -> str:
    here = Path(__file__).parent
    h = hashlib.sha256()
    for f in _FINGERPRINT_FILES:
        h.update(f.encode())
        h.update((here / f).read_bytes())
    return h.hexdigest()


def type_token(tp: Any) -> str:
    """What identifies a type in a cache key: its name, plus its declaration key if declared."""
    return f"{tp.__module__}.{tp.__qualname__}" + (f"#{tp._KEY}" if getattr(
        tp, "_DECLARED", False) else "")


def _names(code: Any) -> set:
    """Global names a code object (and the functions nested in it) refers to."""
    names = set(code.co_names)
    for c in code.co_consts:
        if hasattr(c, "co_names"):
            names |= _names(c)
    return names


def _declared_globals(fn: Any) -> list:
    """Keys of declared twins a function refers to by global name (their code is inlined)."""
    code = getattr(fn, "__code__", None)
    if code is None:
        return []
    out = []
    for nm in sorted(_names(code)):
        v = fn.__globals__.get(nm)
        if isinstance(v, type) and getattr(v, "_DECLARED", False):
            out.append(type_token(v))
    return out


def declaration_key(twin: type, ns: dict) -> str:
    """Hash of everything the generated module depends on (see :func:`declare`)."""
    from .codegen import DECLARE_CODEGEN_VERSION

    parts: list = [twin.__name__, twin._STORAGE_DIM, twin._DIM, twin._ACCESSORS, twin._FIELDS,
                   DECLARE_CODEGEN_VERSION, _generator_fingerprint()]
    for k in sorted(ns):
        v = ns[k]
        if isinstance(v, (staticmethod, classmethod)):
            v = v.__func__
        if inspect.isfunction(v):
            parts.append((k, _cache.function_fingerprint(v), _declared_globals(v)))
        elif isinstance(v, type):
            parts.append((k, type_token(v)))
        elif isinstance(v, tuple) and all(isinstance(t, type) for t in v):
            parts.append((k, tuple(type_token(t) for t in v)))
        elif isinstance(v, (int, float, str, tuple, type(None))):
            parts.append((k, repr(v)))
    return _cache.kernel_key(twin._user_retract, tuple(parts))


# ------------------------------------------------------------------------------- module
def _origin(twin: type) -> str:
    fn = twin._user_retract
    try:
        return f"{inspect.getsourcefile(fn)}:{inspect.getsourcelines(fn)[1]}"
    except (OSError, TypeError):
        return f"{twin.__module__}.{twin.__qualname__}"


def _module(twin: type, use_cache: bool):
    mname = f"manifold_{twin.__name__}"
    if use_cache:
        m = _cache.load(mname, twin._KEY)
        if m is not None:
            STATS["loaded"] += 1
            return m
    from .checks import check_declaration
    from .codegen import module_source
    from .derive import derive_programs

    from ..._first_use import preparing

    try:
        with preparing(f"deriving the manifold {twin.__name__} (SymPy)"):
            progs = derive_programs(twin)
    except FgoptError:
        raise
    except Exception as exc:  # noqa: BLE001 - the user's methods failed on symbolic input
        raise ManifoldDeclarationError(
            f"@fgopt.manifold {twin.__name__}: running the declaration on symbolic storage "
            f"failed ({type(exc).__name__}: {exc}). Methods must be written over fgopt.symbolic "
            "types and functions, without Python branches on symbolic values") from exc
    source, python_part, _ = module_source(twin, progs, _origin(twin))
    check_declaration(twin, python_part)
    STATS["derived"] += 1
    key = twin._KEY if use_cache else \
        "nocache_" + hashlib.sha256(source.encode()).hexdigest()[:16]
    return _cache.store(mname, key, source)


# ------------------------------------------------------------------------------- numeric
def _converter(twin: type, name: str, fn: Any, info: dict):
    kind, shape = info["kind"], tuple(info["shape"])
    if kind == "scalar":
        return lambda s: float(fn(*s.tolist())[0])
    if kind == "vector":
        return lambda s: np.array(fn(*s.tolist()), dtype=np.float64)
    if kind == "matrix":
        return lambda s: np.array(fn(*s.tolist()), dtype=np.float64).reshape(shape)
    if kind == "group":
        from ... import manifolds as M

        group = getattr(M, info["type"])
        return lambda s: group.from_storage(np.array(fn(*s.tolist()), dtype=np.float64))
    target = next((t for t in DECLARED.values() if t._KEY == info["type"]), None)
    if target is None:
        target = twin if info["type"] == twin._KEY else None
    if target is None:
        return lambda s: np.array(fn(*s.tolist()), dtype=np.float64)
    return lambda s: target.Value.from_storage(np.array(fn(*s.tolist()), dtype=np.float64))


def _value_type(twin: type, module: Any) -> type:
    from ...manifolds.declared import ValueSpec, make_value_type

    meta = module.META
    accessors = {nm: _converter(twin, nm, getattr(module, f"accessor_{nm}"), info)
                 for nm, info in meta["accessors"].items()}
    pos = meta["accessors"].get("position")
    position = "position" if pos is not None and pos["kind"] == "vector" and \
        pos["shape"][0] in (2, 3) else None
    spec = ValueSpec(
        name=twin.__name__, dim=twin._DIM, storage_dim=twin._STORAGE_DIM, key=twin._KEY,
        twin=twin, retract_batch=module.retract_batch, local_batch=module.local_batch,
        retract_one=module.retract_one, local_one=module.local_one,
        storage_D_tangent_one=module.storage_D_tangent_one,
        normalize_one=getattr(module, "normalize_one", None),
        identity=None if module.IDENTITY is None else tuple(module.IDENTITY),
        accessors=accessors, fields=tuple(meta["fields"]), position=position,
        position_dim=pos["shape"][0] if position is not None else 0,
        retract_code=module.RETRACT_CODE, doc=twin.__doc__ or "", module=twin.__module__,
        qualname=f"{twin.__qualname__}.Value")
    return make_value_type(spec)


def is_declared(tp: Any) -> bool:
    """True for twin classes made by ``@fgopt.manifold``."""
    return isinstance(tp, type) and issubclass(tp, DeclaredManifold) and tp._DECLARED


def declared_twin_of(value: Any) -> type | None:
    """The twin class of a numeric declared value (or of its class), else ``None``."""
    spec = getattr(value, "_spec", None)
    twin = getattr(spec, "twin", None)
    return twin if is_declared(twin) else None
