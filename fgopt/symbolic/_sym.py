"""The SymPy side of :mod:`fgopt.symbolic`: the ``epsilon`` symbol and branchless primitives.

This is the only module of the package that imports SymPy at import time; every other module
reaches it lazily (inside functions), so that loading a cached kernel never imports SymPy.

Branchless primitives (SymForce paper, Sec. VI):

* ``SignNoZero(x)`` -- ``snz(x) = 1 if x >= 0 else -1`` (Eq. 11); printed as
  ``math.copysign(1.0, x)`` (a bit operation, no branch); its derivative is zero.
* ``epsilon`` -- a positive symbol that shifts arguments away from removable singularities,
  ``f(x + snz(x) * epsilon)`` (Eq. 13). Generated code binds it to :data:`EPSILON_VALUE`
  (10x double machine epsilon, SymForce's default).
"""

from __future__ import annotations

import sympy as sp

#: Numeric value of ``epsilon`` in generated code: 10x the double machine epsilon.
EPSILON_VALUE = 2.220446049250313e-15

#: The epsilon symbol (positive, so SymPy may simplify ``sqrt(epsilon**2)`` to ``epsilon``).
epsilon = sp.Symbol("epsilon", positive=True)


class SignNoZero(sp.Function):
    """``snz(x)``: 1 for ``x >= 0``, -1 for ``x < 0`` (never 0); derivative 0."""

    nargs = 1

    @classmethod
    def eval(cls, x):
        if x.is_extended_nonnegative:
            return sp.S.One
        if x.is_extended_negative:
            return sp.S.NegativeOne
        if isinstance(x, SignNoZero):  # snz(snz(x)) = snz(x)
            return x
        if x.is_Mul and x.args[0].is_number and x.args[0].is_positive:  # snz(c x) = snz(x), c > 0
            return cls(sp.Mul(*x.args[1:]))
        return None

    def fdiff(self, argindex=1):
        return sp.S.Zero

    def _eval_is_real(self):
        return True

    def _eval_is_zero(self):
        return False

    def _eval_is_integer(self):
        return True

    def _eval_power(self, exp):
        if exp.is_integer and exp.is_even:
            return sp.S.One
        if exp.is_integer and exp.is_odd:
            return self
        return None


def snz(x):
    """``sign_no_zero(x)`` as a SymPy expression."""
    return SignNoZero(sp.sympify(x))


def real_symbol(name: str) -> sp.Symbol:
    return sp.Symbol(name, real=True)


def as_expr(x):
    """SymPy expression of a number / expression (floats stay floats)."""
    return sp.sympify(x)


def remove_distributions(expr):
    """Replace ``DiracDelta`` terms (derivatives of ``sign``, ``Heaviside``) by zero.

    They appear when differentiating ``sign``/``Abs``/``Max``; everywhere except on a
    measure-zero set their value is 0, which is what branchless generated code computes.
    """
    if not expr.has(sp.DiracDelta):
        return expr
    return expr.replace(lambda e: isinstance(e, sp.DiracDelta), lambda e: sp.S.Zero)
