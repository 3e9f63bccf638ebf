"""Operation counts of SymPy expressions: ``sympy.count_ops`` without its rebuilding.

``count_ops`` (the SymForce paper's measure, Sec. VIII-B) walks an expression and, for every
negative product, numerator and denominator, builds a new SymPy product (SymPy's evaluation:
most of its time). :func:`count_ops` walks the same way and counts the same, keeping such
products as tuples of their factors; only ``number * sum``, which SymPy distributes, is built.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any


def _s():
    from . import _sym

    return _sym


def _split(terms: list) -> Any:
    """``fraction`` of a product of ``terms``: (numerator terms, denominator terms), or
    ``None`` for a factor this counter leaves to SymPy (a symbolic exponent, ``exp``)."""
    sp = _s().sp
    numer, denom = [], []
    for t in terms:
        if t.is_Pow:
            b, ex = t.args
            if not ex.is_Number:
                return None
            if ex.is_negative:
                denom.append(b if ex is sp.S.NegativeOne else sp.Pow(b, -ex))
            else:
                numer.append(t)
        elif isinstance(t, sp.exp):
            return None
        elif t.is_Rational and not t.is_Integer:
            if t.p != 1:
                numer.append(sp.Integer(t.p))
            denom.append(sp.Integer(t.q))
        else:
            numer.append(t)
    return numer, denom


def _product(terms: list) -> Any:
    """``Mul(*terms)`` as ``count_ops`` would see it: a tuple stands for a product SymPy leaves
    as it is (only ``Mul(number, sum)`` is built: SymPy distributes it)."""
    sp = _s().sp
    if len(terms) == 0:
        return sp.S.One
    if len(terms) == 1:
        return terms[0]
    if len(terms) == 2 and terms[0].is_Number and terms[1].is_Add:
        return sp.Mul(*terms)
    return tuple(terms)


def _negated(terms: Any) -> Any:
    """``-Mul(*terms)`` (``terms[0]`` a negative number) as ``count_ops`` sees it."""
    c = terms[0]
    if c is _s().sp.S.NegativeOne:
        return terms[1] if len(terms) == 2 else tuple(terms[1:])
    return _product([-c, *terms[1:]])


def _count(expr: Any) -> int:
    """``sympy.count_ops(expr)`` of one expression: the same walk, with products that SymPy
    would build (negations, numerators, denominators) kept as tuples of their factors."""
    sp = _s().sp
    neg_one, exp1 = sp.S.NegativeOne, sp.S.Exp1
    n = 0
    stack = [expr]
    while stack:
        a = stack.pop()
        is_mul = isinstance(a, tuple) or a.is_Mul
        if not is_mul and a.is_Rational:
            n += (a.p < 0) + (a.q != 1)
            continue
        if not is_mul and a.is_Add:
            negs = 0
            for t in a.args:
                c = t.args[0] if t.is_Mul else t
                if c.is_Number and c.is_extended_negative:
                    negs += 1
                    stack.append(_negated(t.args) if t.is_Mul else -t)
                else:
                    stack.append(t)
            n += len(a.args) - 1 + (negs == len(a.args))
            continue
        if is_mul:
            terms = a if isinstance(a, tuple) else a.args
            c = terms[0]
            if c.is_Number and c.is_extended_negative:
                n += 1
                a = _negated(terms)
                is_mul = isinstance(a, tuple) or a.is_Mul
            terms = a if isinstance(a, tuple) else a.args if is_mul else (a,)
            split = _split(terms)
            if split is None:
                n += int(sp.count_ops(sp.Mul(*terms)))
                continue
            num, den = _product(split[0]), _product(split[1])
            if not isinstance(num, tuple) and num.is_Integer:
                n += 1
                stack.append(den)
                continue
            if den is not sp.S.One:
                if isinstance(den, tuple) or not den.is_Integer:
                    stack.append(den)
                n += 1
                stack.append(num)
                continue
            if is_mul:
                n += len(terms) - 1
                stack.extend(terms)
                continue
        if a.is_Pow and a.exp is neg_one:
            n += 1
            stack.append(a.base)
        elif a is exp1:
            n += 1
        elif a.is_Pow and a.base is exp1:
            n += 1
            stack.append(a.exp)
        elif not isinstance(a, sp.Expr) or isinstance(a, (sp.Derivative, sp.Integral)):
            n += int(sp.count_ops(a))
        else:
            if isinstance(a, sp.core.operations.LatticeOp):
                n += len(a.args) - 1
            elif a.args and (a.is_Pow or a.is_Function):
                n += 1
            if not a.is_Symbol:
                stack.extend(a.args)
    return n


def count_ops(exprs: Iterable) -> int:
    """``sum(sympy.count_ops(e) for e in exprs)``, computed without SymPy's rebuilding."""
    return sum(_count(e) if hasattr(e, "is_Atom") else 0 for e in exprs)
