"""Every error the public API raises is an FgoptError (issue 10): wrong argument order in a
``Factor`` subclass, NumPy / ``math`` inside a symbolic factor body (with the user's file:line),
shape mismatches and index errors of symbolic vectors, graph indexing, bad numbers."""

from __future__ import annotations

import inspect
import math

import numpy as np
import pytest

import fgopt
from fgopt import SO2, Factor, FactorGraph, key
from fgopt.errors import DimensionMismatchError, FgoptError, FgoptIndexError
from fgopt.symbolic import V2, V3, Pose2


def test_factor_with_minisam_argument_order():
    """miniSAM's ``Factor(dim, keys, loss)`` order in a subclass used to raise a TypeError
    ('int' object is not iterable); now an FgoptError that says which order fgopt takes."""

    class Swapped(Factor):
        def __init__(self, k):
            super().__init__(2, [k])

    class LossAsDim(Factor):
        def __init__(self, k):
            super().__init__([k], fgopt.noise.Unit(2), 2)

    class BareKey(Factor):
        def __init__(self, k):
            super().__init__(k, 2)

    with pytest.raises(FgoptError, match=r"takes \(keys, dim, loss\).*miniSAM"):
        Swapped(key("x", 1))
    with pytest.raises(FgoptError, match="dim must be an int"):
        LossAsDim(key("x", 1))
    with pytest.raises(FgoptError, match="keys must be a list of keys"):
        BareKey(key("x", 1))


def _line_of(fn, text: str) -> int:
    lines, start = inspect.getsourcelines(fn)
    return start + next(i for i, ln in enumerate(lines) if text in ln)


def test_numpy_and_math_in_a_factor_body_name_the_line():
    """``np.sqrt`` / ``math.atan2`` on symbolic values used to fail inside NumPy or SymPy; the
    error names the factor, this file's line, and says to use fgopt.symbolic's functions."""

    def with_numpy(p: Pose2, q: V2) -> V2:
        d = p.inverse() * q
        return V2(np.sqrt(d.dot(d)), 0.0)

    def with_math(p: Pose2, q: V2) -> V2:
        d = p.inverse() * q
        return V2(math.atan2(d[1], d[0]), 0.0)

    for fn, text in ((with_numpy, "np.sqrt"), (with_math, "math.atan2")):
        ft = fgopt.factor(fn, cache=False)
        where = f"{__file__}:{_line_of(fn, text)}"
        with pytest.raises(FgoptError, match="use fgopt.symbolic's functions") as info:
            ft(key("x", 1), key("l", 1))
        assert where in str(info.value) and fn.__name__ in str(info.value)
        assert text in str(info.value)


def test_shape_mismatch_in_a_factor_body_is_a_dimension_error_with_the_line():
    """V2 + V3 inside a factor: a DimensionMismatchError naming both shapes and the line."""

    def mixed(p: V2, q: V3) -> V2:
        return p + q

    ft = fgopt.factor(mixed, cache=False)
    with pytest.raises(DimensionMismatchError, match=r"V2 \+ V3: shapes \(2, 1\) and \(3, 1\)") \
            as info:
        ft(key("p", 1), key("q", 1))
    assert f"{__file__}:{_line_of(mixed, 'p + q')}" in str(info.value)


def test_symbolic_vectors_shape_and_index_errors():
    """Shape mismatches (+, -, dot, products, construction) and out-of-range indices of
    symbolic vectors are FgoptErrors (DimensionMismatchError / FgoptIndexError); dot of
    different sizes used to truncate silently."""
    a, b = V2.symbolic("a"), V3.symbolic("b")
    m = fgopt.symbolic.Matrix.shaped(2, 2).symbolic("m")
    for bad in (lambda: a + b, lambda: b - a, lambda: a.dot(b), lambda: m * b, lambda: a @ b,
                lambda: V2(1, 2, 3), lambda: a.cross(b), lambda: a + [1, 2, 3]):
        with pytest.raises(DimensionMismatchError):
            bad()
    with pytest.raises(FgoptIndexError, match="index 5 is out of range"):
        a[5]
    assert isinstance(FgoptIndexError("x"), IndexError)
    with pytest.raises(FgoptError, match="cannot compose"):
        Pose2.symbolic("p") * fgopt.symbolic.Rot3.symbolic("r")


def test_graph_index_and_bad_numbers():
    """Graph indexing out of range / by a non-int, and a non-number angle, are FgoptErrors."""
    g = FactorGraph()
    with pytest.raises(FgoptIndexError):
        g[3]
    with pytest.raises(FgoptError, match="must be an int"):
        g["a"]
    with pytest.raises(FgoptError, match="SO2 angle"):
        SO2("x")


def test_unknown_derivation_options_and_undefined_residuals_are_fgopt_errors():
    """An unknown ``method`` / ``engine`` of ``@fgopt.factor``, and a residual SymPy reduces to
    complex infinity (``x / 0``), used to raise ValueErrors from the code generator; now an
    FgoptError naming the factor (and, for the latter, what the special value means)."""

    def make(name, **options):
        def body(landmark: V2, measured: V2) -> V2:
            return landmark - measured
        body.__name__ = name
        return fgopt.factor(**options)(body)

    with pytest.raises(FgoptError, match="bogus_engine: cannot generate.*engine"):
        make("bogus_engine", engine="bogus", cache=False)(key("l", 0), np.zeros(2))
    with pytest.raises(FgoptError, match="bogus_method: cannot generate.*method"):
        make("bogus_method", method="bogus", cache=False)(key("l", 0), np.zeros(2))

    @fgopt.factor(cache=False)
    def by_zero(landmark: V2) -> V2:
        return landmark / 0

    with pytest.raises(FgoptError, match="by_zero: cannot generate.*division by zero"):
        by_zero(key("l", 0))
