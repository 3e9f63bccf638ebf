"""What a declared manifold computes, as SymPy: the programs its generated module is made of.

For a twin class ``T`` (storage symbols ``x_k``, ``a_k``, ``b_k``, tangent symbols ``d_k``):

* ``retract``: ``S(normalize(retract(x, d)))`` (the batched kernel's output);
* ``local``: ``local(a, b)``;
* ``storage_D_tangent``: ``D(x) = d S(retract(x, v)) / dv`` at ``v = 0``, row-major; the
  declaration's own ``storage_D_tangent`` when it has one, else SymPy differentiates
  ``retract`` and sets ``v = 0``. Declarations keep ``retract`` finite at ``v = 0`` by shifting
  norms with ``epsilon`` (``theta = sqrt(|v|^2 + epsilon^2)``), so the derivative at 0 holds
  terms like ``sin(epsilon) / epsilon``: each entry is taken to its limit ``epsilon -> 0``
  (``subs`` when that is finite, else ``sympy.limit``), which is exactly the derivative of the
  unshifted retraction;
* ``tangent_D_storage``: ``d local(x, y) / d S(y)`` at ``y = x`` (same limit rule), a left
  inverse of ``D`` on the manifold;
* ``normalize`` (when declared) and every accessor (methods taking only ``self``).

Results are memoized per class in this process (:func:`generic_storage_D_tangent` is also what
factor derivations substitute into their arguments).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from ...errors import ManifoldDeclarationError


def _s():
    from .. import _sym

    return _sym


_D_MEMO: dict = {}
_T_MEMO: dict = {}


def _limit(e: Any) -> Any:
    """``lim epsilon -> 0+`` of ``e`` (``e`` itself if SymPy cannot take it)."""
    s = _s()
    sp, eps = s.sp, s.epsilon
    z = e.subs(eps, 0)
    if z.is_finite is not False and not z.has(sp.nan, sp.zoo, sp.oo, -sp.oo):
        return z
    try:
        lim = sp.limit(e, eps, 0, "+")
    except Exception:  # noqa: BLE001 - SymPy gives up on some forms: keep the shifted value
        return e
    if lim.has(sp.nan, sp.zoo, sp.oo, -sp.oo, sp.Limit):
        return e
    return lim


def _at_zero_epsilon(e: Any) -> Any:
    """The limit ``epsilon -> 0+`` of an entry, taken term by term on the factors that hold
    ``epsilon`` (SymPy's ``limit`` is slow and fragile on large expressions)."""
    s = _s()
    sp, eps = s.sp, s.epsilon
    if not e.has(eps):
        return e
    out = []
    for t in sp.Add.make_args(e):
        if not t.has(eps):
            out.append(t)
            continue
        c, dep = t.as_independent(eps, as_Add=False)
        out.append(c * _limit(dep))
    return sp.Add(*out)


def derivative_at(exprs: list, wrt: list, point: dict):
    """``d exprs / d wrt`` evaluated at ``wrt = point``, as a SymPy matrix.

    Forward mode over the CSE'd program of ``exprs``: statements that do not depend on ``wrt``
    (e.g. a tangent basis built from ``x``) are never differentiated, and every partial is
    evaluated at the point right away; the statements' values at the point are inlined at the
    end. Much cheaper than differentiating the flattened expressions.
    """
    from ..cse import Program, optimize

    s = _s()
    sp, remove = s.sp, s.remove_distributions
    prog = optimize(Program([], {"out": list(exprs)}), prefix="_dz")
    deriv: dict = {v: {j: sp.S.One} for j, v in enumerate(wrt)}

    def directional(e) -> dict:
        acc: dict = {}
        for x in e.free_symbols:
            if x not in deriv:
                continue
            p = remove(e.diff(x)).xreplace(point)
            if p == 0:
                continue
            for j, dx in deriv[x].items():
                acc[j] = acc.get(j, sp.S.Zero) + p * dx
        return {j: v for j, v in acc.items() if v != 0}

    values = []
    for t, e in prog.stmts:
        values.append((t, e.xreplace(point)))
        d = directional(e)
        if len(d) > 0:
            deriv[t] = d
    rows = [directional(sp.sympify(e)) for e in prog.outputs["out"]]
    J = sp.Matrix(len(rows), len(wrt), lambda i, j: rows[i].get(j, sp.S.Zero))
    env: dict = {}
    for t, e0 in values:
        env[t] = e0.xreplace(env)
    return J.xreplace(env)


def generic_storage_D_tangent(cls: type) -> tuple:
    """``(storage symbols x_k, D)`` with ``D = d S(x (+) v) / dv`` at ``v = 0`` (memoized)."""
    hit = _D_MEMO.get(cls)
    if hit is not None:
        return hit
    sp = _s().sp
    x = cls.symbolic("x")
    gen = [_s().as_expr(e) for e in x.to_storage()]
    n, d = cls._STORAGE_DIM, cls._DIM
    user = getattr(cls, "_user_storage_D_tangent", None)
    if user is not None:
        from ..matrix import Matrix

        out = user(x)
        m = out.mat if isinstance(out, Matrix) else sp.Matrix(out)
        if m.shape != (n, d):
            raise ManifoldDeclarationError(
                f"{cls.__name__}.storage_D_tangent(x) returned a {m.shape[0]}x{m.shape[1]} "
                f"matrix; expected storage_dim x dim = {n}x{d}")
        D = m.applyfunc(_s().as_expr)
    else:
        xi = [sp.Dummy(f"xi{k}", real=True) for k in range(d)]
        J = derivative_at(x._raw_retract(xi), xi, {v: sp.S.Zero for v in xi})
        D = J.applyfunc(_at_zero_epsilon)
    _D_MEMO[cls] = (gen, D)
    return gen, D


def generic_tangent_D_storage(cls: type) -> tuple:
    """``(storage symbols x_k, T)`` with ``T = d local(x, y) / d S(y)`` at ``y = x``."""
    hit = _T_MEMO.get(cls)
    if hit is not None:
        return hit
    x = cls.symbolic("x")
    y = cls.symbolic("y")
    gen = [_s().as_expr(e) for e in x.to_storage()]
    ys = [_s().as_expr(e) for e in y.to_storage()]
    T = derivative_at(list(x.local(y)), ys, dict(zip(ys, gen)))
    T = T.applyfunc(_at_zero_epsilon)
    _T_MEMO[cls] = (gen, T)
    return gen, T


@dataclass
class Accessor:
    """One accessor's flat output and how to rebuild its numeric value."""

    name: str
    exprs: list
    kind: str            # "scalar" | "vector" | "matrix" | "group" | "declared"
    shape: tuple = ()
    type_name: str = ""  # numeric group name (SO3...) or the declared twin's key


@dataclass
class Programs:
    """Flat SymPy outputs of one declaration, over generic symbols (see the module docstring)."""

    x: list
    d: list
    a: list
    b: list
    retract: list
    local: list
    storage_D_tangent: list                 # row-major (storage_dim * dim)
    normalize: list | None
    identity: tuple | None
    accessors: list = field(default_factory=list)


_GROUP_TWINS = {"Rot2": "SO2", "Pose2": "SE2", "Rot3": "SO3", "Pose3": "SE3"}


def _accessor(cls: type, name: str, x: Any) -> Accessor:
    from ..lie import LieGroupBase
    from ..matrix import Matrix
    from .twin import DeclaredManifold

    try:
        out = getattr(x, name)()
    except ManifoldDeclarationError:
        raise
    except Exception as exc:  # noqa: BLE001 - name the accessor in the error
        raise ManifoldDeclarationError(f"{cls.__name__}.{name}(x) failed on symbolic storage: "
                                       f"{type(exc).__name__}: {exc}") from exc
    if isinstance(out, LieGroupBase):
        tp = _GROUP_TWINS.get(type(out).__name__)
        if tp is None:
            raise ManifoldDeclarationError(f"{cls.__name__}.{name}(x) returns a "
                                           f"{type(out).__name__}, which has no numeric twin")
        return Accessor(name, [_s().as_expr(e) for e in out.to_storage()], "group", (), tp)
    if isinstance(out, DeclaredManifold):
        return Accessor(name, out.to_storage(), "declared", (), type(out)._KEY)
    if isinstance(out, Matrix):
        kind = "vector" if out.shape[1] == 1 else "matrix"
        return Accessor(name, list(out.mat), kind, tuple(out.shape))
    if isinstance(out, (list, tuple)):
        raise ManifoldDeclarationError(f"{cls.__name__}.{name}(x) returns a {type(out).__name__};"
                                       " return a vector (V3(...)), a matrix, a scalar or a value")
    return Accessor(name, [_s().as_expr(out)], "scalar")


def derive_programs(cls: type) -> Programs:
    """Every output of the declaration ``cls`` (a :class:`DeclaredManifold` subclass)."""
    from ..matrix import vector_type

    sp = _s().sp
    n, dim = cls._STORAGE_DIM, cls._DIM
    x, a, b = cls.symbolic("x"), cls.symbolic("a"), cls.symbolic("b")
    dsyms = [_s().real_symbol(f"d_{k}") for k in range(dim)]
    raw = cls(x._raw_retract(vector_type(dim)(dsyms)))
    retract = raw.normalize().to_storage()
    local = [_s().as_expr(e) for e in a.local(b)]
    _, D = generic_storage_D_tangent(cls)
    normalize = x.normalize().to_storage() if getattr(cls, "_user_normalize", None) else None
    identity = None
    if getattr(cls, "_user_identity", None) is not None:
        ident = cls._identity_storage()
        try:
            identity = tuple(float(sp.sympify(e).evalf()) for e in ident)
        except TypeError as exc:
            raise ManifoldDeclarationError(f"{cls.__name__}.identity() must return numbers, got "
                                           f"{ident}") from exc
    accessors = [_accessor(cls, name, x) for name in cls._ACCESSORS]
    return Programs(x=x.to_storage(), d=dsyms, a=a.to_storage(), b=b.to_storage(),
                    retract=retract, local=local, storage_D_tangent=list(D),
                    normalize=normalize, identity=identity, accessors=accessors)
