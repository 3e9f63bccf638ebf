"""The numba printer: printed source evaluates to SymPy's value (random expressions)."""

from __future__ import annotations

import math
import random

import numpy as np
import sympy as sp

from fgopt.symbolic import epsilon, sign_no_zero
from fgopt.symbolic.printer import to_source

X, Y, Z = sp.symbols("x y z", real=True)
VALUES = {X: 0.7, Y: 1.3, Z: -0.4}


def _random_expr(rng: random.Random, depth: int):
    if depth == 0 or rng.random() < 0.2:
        return rng.choice([X, Y, Z, sp.Integer(rng.randint(-3, 3)), sp.Rational(rng.randint(1, 5), 2),
                           sp.Float(rng.uniform(-2, 2)), epsilon])
    a = _random_expr(rng, depth - 1)
    b = _random_expr(rng, depth - 1)
    op = rng.randrange(13)
    if op == 0:
        return a + b
    if op == 1:
        return a - b
    if op == 2:
        return a * b
    if op == 3:
        return a / (b * b + 1)
    if op == 4:
        return (a * a + 1) ** rng.choice([-3, -2, -1, 2, 3, 5, -5])
    if op == 5:
        return (a * a + 1) ** sp.Rational(rng.choice([1, -1, 3, -3, 5, -5]), 2)
    if op == 6:
        return sp.sin(a) * sp.cos(b)
    if op == 7:
        return sp.atan2(a, b * b + 1)
    if op == 8:
        return sign_no_zero(a) * b
    if op == 9:
        return sp.Abs(a) - sp.Min(X, Z) * a + sp.Max(Y, 1) * b
    if op == 10:
        return sp.exp(a / (a * a + 4))
    if op == 11:
        return a / ((b * b + 1) * (a * a + 2) ** 2)
    return -a * b / (Y + 2)


def test_random_expressions_print_to_their_value():
    rng = random.Random(0)
    env = {"math": math, "np": np, "EPSILON": 2.220446049250313e-15,
           "x": VALUES[X], "y": VALUES[Y], "z": VALUES[Z]}
    subs = {**VALUES, epsilon: 2.220446049250313e-15}
    for _ in range(120):
        e = _random_expr(rng, 3)
        src = to_source(e)
        got = eval(src, env)
        want = complex(sp.N(e.xreplace(subs), 30))
        assert abs(want.imag) < 1e-12
        assert math.isclose(got, want.real, rel_tol=1e-11, abs_tol=1e-11), (e, src, got, want)


def test_special_forms():
    assert to_source(X**2) == "(x*x)"
    assert to_source(Y / X**2) == "y/(x*x)"
    assert to_source(X ** sp.Rational(-1, 2)) == "(1.0/math.sqrt(x))"
    assert to_source(sign_no_zero(X)) == "math.copysign(1.0, x)"
    assert to_source(epsilon) == "EPSILON"
    assert to_source(sp.Rational(1, 4)) == "0.25"
