"""Tangent-space Jacobians of symbolic functions (SymForce paper, Sec. V-B).

For an argument ``x`` with storage symbols ``s = S(x)`` and a function value ``f``, the
tangent-space Jacobian is ``d f(x (+) v) / dv`` at ``v = 0``. Two methods:

* ``"retraction"`` (default, Sec. V-B2, first-order retraction): substitute
  ``s -> s + D v`` into ``f`` with ``D = storage_D_tangent(x)`` (Eq. 8, the storage of
  ``x * Exp(v)`` to first order), differentiate the result w.r.t. ``v``, then set ``v = 0``;
* ``"chain"`` (Sec. V-B1, symbolic chain rule, Eq. 7): ``(d f / d s) D``.

Both give the same function; the expression shapes (and so the generated op counts) differ.
If ``f`` is itself a Lie group element, its storage Jacobian is mapped to its tangent space by
``tangent_D_storage(f)`` (a left inverse of ``storage_D_tangent``), i.e. the result is
``d Log(f(x)^-1 f(x (+) v)) / dv``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from .ops import (has_own_tangent, storage_D_tangent_of, storage_of, symbolic_value,
                  tangent_D_storage_of)

METHODS = ("retraction", "chain")


def _s():
    from . import _sym

    return _sym


def output_storage(output: Any) -> list:
    """The flat list of output expressions of a function value (vector, matrix, scalar, group)."""
    if isinstance(output, (list, tuple)):
        flat = []
        for o in output:
            flat.extend(storage_of(o))
        return flat
    return storage_of(output)


def tangent_jacobians(output: Any, args: Sequence[Any], method: str = "retraction") -> list:
    """Jacobians of ``output`` w.r.t. the tangent space of each value in ``args``.

    Args:
        output: the function value (Matrix / vector, scalar, sequence of those, or a group).
        args: symbolic values whose storage entries are distinct symbols.
        method: ``"retraction"`` or ``"chain"``.

    Returns:
        One SymPy matrix ``(len(output_storage), dim(arg))`` per argument (rows are the output's
        tangent dimension instead when ``output`` is a Lie group element).

    Example: the inverse of a planar rotation has the tangent Jacobian ``-1`` (the storage
    ``[cos, sin]`` has unit norm):

    >>> from fgopt.symbolic import Rot2, tangent_jacobians
    >>> a = Rot2.symbolic("a")
    >>> tangent_jacobians(a.inverse(), [a])
    [Matrix([[-a_0**2 - a_1**2]])]
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    sp = _s().sp
    out = sp.Matrix(output_storage(output))
    out_map = tangent_D_storage_of(output) if has_own_tangent(output) else None
    jacs = []
    for arg in args:
        s = storage_of(arg)
        if not all(isinstance(e, sp.Symbol) for e in s):
            raise ValueError("tangent_jacobians: every argument's storage must be plain symbols "
                             "(build it with T.symbolic(name))")
        D = storage_D_tangent_of(arg)
        if method == "chain":
            J = out.jacobian(s) * D
        else:
            xi = [sp.Dummy(f"xi{k}", real=True) for k in range(D.shape[1])]
            delta = D * sp.Matrix(xi)
            perturbed = out.xreplace({sk: sk + delta[k] for k, sk in enumerate(s)})
            J = perturbed.jacobian(xi).xreplace({x: sp.S.Zero for x in xi})
        if out_map is not None:
            J = out_map * J
        jacs.append(J.applyfunc(_s().remove_distributions))
    return jacs


def jacobians_of(fn: Callable, arg_types: Sequence[type], wrt: Sequence[int] | None = None,
                 method: str = "retraction", names: Sequence[str] | None = None):
    """Build ``fn`` on symbolic arguments and return ``(args, output, jacobians)``.

    Args:
        fn: a function of symbolic values.
        arg_types: one symbolic type per positional argument.
        wrt: indices of the arguments to differentiate by (default all).
        method: see :func:`tangent_jacobians`.
        names: storage symbol prefixes (default ``a0``, ``a1``, ...).

    Example: a rotated point; at the identity, turning by ``dtheta`` moves ``p`` along its
    perpendicular ``(-p_y, p_x)``:

    >>> from fgopt.symbolic import Rot2, V2, jacobians_of
    >>> (R, p), Rp, (J_R, J_p) = jacobians_of(lambda R, p: R * p, [Rot2, V2], names=["R", "p"])
    >>> J_R.subs({R.c: 1, R.s: 0})
    Matrix([
    [-p_1],
    [ p_0]])
    """
    names = list(names) if names is not None else [f"a{i}" for i in range(len(arg_types))]
    args = [symbolic_value(tp, n) for tp, n in zip(arg_types, names)]
    output = fn(*args)
    wrt = list(range(len(args))) if wrt is None else list(wrt)
    return args, output, tangent_jacobians(output, [args[i] for i in wrt], method)
