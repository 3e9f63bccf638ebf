"""Scalar math for symbolic residuals: ``fgopt.symbolic.sin, cos, sqrt, atan2, ...``.

Each function takes a number, a SymPy expression or a :class:`~fgopt.symbolic.Matrix`
(applied entry-wise) and returns a SymPy expression (or a Matrix). Functions with singular
points are *epsilon-safe*: they shift or clamp their argument by the ``epsilon`` symbol so that
generated code never produces NaN there, without branches (SymForce paper, Sec. VI-A):

===================  ==============================================================
``sqrt(x)``          ``sqrt(max(x, epsilon**2))`` (no NaN for tiny negative rounding)
``log(x)``           ``log(max(x, epsilon))``
``acos(x)/asin(x)``  argument clamped to ``[-1, 1]``
``atan2(y, x)``      ``atan2(y, x + snz(x) epsilon)``: finite value and gradient at 0
``safe_div(a, b)``   ``a / (b + snz(b) epsilon)``
===================  ==============================================================

Pass ``epsilon=0`` to get the raw function. ``epsilon`` itself is :data:`fgopt.symbolic.epsilon`.

A clamp hides a start outside the domain (the value is constant there, the gradient zero, so a
solver "converges" at once). While a factor is derived (:func:`recording_clamps`), every clamp of
``sqrt``/``log``/``acos``/``asin`` is recorded with its argument, its bounds and the caller's
file:line; generated kernels then carry a ``clamp_arguments`` function, and the solvers report
factors whose final values sit on a clamp (``Result.clamps``). The kernels' hot path is unchanged.

SymPy is imported on first call, not on import: modules that define factors may import these
names freely and still load cached kernels without SymPy.
"""

from __future__ import annotations

import linecache
import os
import sys
from dataclasses import dataclass
from typing import Any

_DEFAULT = object()  # "use the epsilon symbol"
_HERE = os.path.dirname(os.path.abspath(__file__))


@dataclass(frozen=True)
class Clamp:
    """One clamped argument met while deriving a factor: hit when ``arg < low`` or ``> high``."""

    function: str
    arg: Any       # SymPy expression of the argument before clamping
    low: float
    high: float
    where: str     # the caller's "file:line"
    code: str      # that line's source


_RECORDING: list | None = None


class recording_clamps:
    """``with recording_clamps() as clamps:`` collects the :class:`Clamp` of every clamped
    function called inside (used while a factor function is traced)."""

    def __enter__(self) -> list:
        global _RECORDING
        self._previous, _RECORDING = _RECORDING, []
        return _RECORDING

    def __exit__(self, *exc: Any) -> None:
        global _RECORDING
        _RECORDING = self._previous


def _caller() -> tuple[str, str]:
    """("file:line", source) of the first frame outside fgopt.symbolic and SymPy (the factor's
    code; matrices reach a clamp through SymPy's applyfunc)."""
    skip = (_HERE + os.sep, os.path.dirname(os.path.abspath(_s().sp.__file__)) + os.sep)
    f = sys._getframe(2)
    while f is not None and os.path.abspath(f.f_code.co_filename).startswith(skip):
        f = f.f_back
    if f is None:
        return "?", ""
    name, line = f.f_code.co_filename, f.f_lineno
    return f"{name}:{line}", linecache.getline(name, line).strip()


def _note(function: str, a: Any, low: Any, high: Any) -> Any:
    """Record the clamp of ``a`` to ``[low, high]`` (when recording); returns ``a``."""
    if _RECORDING is not None:
        s = _s()
        bound = [float(s.as_expr(b).subs(s.epsilon, s.EPSILON_VALUE)) if b is not None else
                 (-float("inf") if k == 0 else float("inf")) for k, b in enumerate((low, high))]
        where, code = _caller()
        _RECORDING.append(Clamp(function, a, bound[0], bound[1], where, code))
    return a


def _s():
    from . import _sym

    return _sym


def _eps(epsilon: Any):
    return _s().epsilon if epsilon is _DEFAULT else _s().as_expr(epsilon)


def _map1(fn, x: Any):
    from .matrix import Matrix

    if isinstance(x, Matrix):
        return x.applyfunc(fn)
    return fn(_s().as_expr(x))


def _fn(name: str):
    def f(x: Any):
        return _map1(getattr(_s().sp, name), x)

    f.__name__ = name
    f.__qualname__ = name
    f.__doc__ = (f"``{name}(x)`` (entry-wise on matrices): SymPy's ``{name}`` for factor "
                 f"bodies and generated functions.\n\nExample::\n\n    from fgopt.symbolic import "
                 f"V2, {name}\n    {name}(V2(0.1, 0.2))   # a V2 of {name}(0.1), {name}(0.2)\n")
    return f


sin = _fn("sin")
cos = _fn("cos")
tan = _fn("tan")
atan = _fn("atan")
sinh = _fn("sinh")
cosh = _fn("cosh")
tanh = _fn("tanh")
exp = _fn("exp")
floor = _fn("floor")
sign = _fn("sign")


def sign_no_zero(x: Any):
    """``snz(x)``: 1 if ``x >= 0`` else -1 (never 0), branchless, derivative 0 (Eq. 11-12).

    ``snz`` is the same function. Example:

    >>> from fgopt.symbolic import sign_no_zero, snz, symbols
    >>> x = symbols("x")
    >>> [sign_no_zero(x).subs(x, v) for v in (-2.0, 0.0, 3.0)], snz is sign_no_zero
    ([-1, 1, 1], True)
    """
    return _map1(_s().snz, x)


snz = sign_no_zero


def Abs(x: Any):
    """``|x|`` (derivative ``sign(x)``).

    Example:

    >>> from fgopt.symbolic import Abs, symbols
    >>> x = symbols("x")
    >>> Abs(x).subs(x, -2.5), Abs(x).diff(x)
    (2.50000000000000, sign(x))
    """
    return _map1(_s().sp.Abs, x)


def Min(*args: Any):
    """The smallest argument, symbolically (SymPy's ``Min``; generated code keeps the branch).

    Example:

    >>> from fgopt.symbolic import Min, symbols
    >>> Min(symbols("x"), 1)
    Min(1, x)
    """
    return _s().sp.Min(*(_s().as_expr(a) for a in args))


def Max(*args: Any):
    """The largest argument, symbolically (SymPy's ``Max``; generated code keeps the branch).

    Example:

    >>> from fgopt.symbolic import Max, symbols
    >>> Max(symbols("x"), 0)
    Max(0, x)
    """
    return _s().sp.Max(*(_s().as_expr(a) for a in args))


def clamp(x: Any, lo: Any, hi: Any):
    """``min(max(x, lo), hi)``.

    Example:

    >>> from fgopt.symbolic import clamp, symbols
    >>> x = symbols("x")
    >>> [clamp(x, -1, 1).subs(x, v) for v in (-5, 0.25, 5)]
    [-1, 0.250000000000000, 1]
    """
    return Min(Max(x, lo), hi)


def sqrt(x: Any, epsilon: Any = _DEFAULT):
    """``sqrt(max(x, epsilon**2))``: never NaN, finite derivative at 0.

    Example:

    >>> from fgopt.symbolic import sqrt, symbols
    >>> x = symbols('x')
    >>> sqrt(x)
    sqrt(Max(epsilon**2, x))
    """
    e = _eps(epsilon)
    sp = _s().sp
    if e == 0:
        return _map1(sp.sqrt, x)
    return _map1(lambda a: sp.sqrt(Max(_note("sqrt", a, e**2, None), e**2)), x)


def log(x: Any, epsilon: Any = _DEFAULT):
    """``log(max(x, epsilon))``: finite at ``x = 0`` once ``epsilon > 0``.

    Example:

    >>> from fgopt.symbolic import epsilon, log, symbols
    >>> x = symbols("x")
    >>> log(x)
    log(Max(epsilon, x))
    >>> round(float(log(x).subs({x: 0, epsilon: 1e-9})), 6)   # log(1e-9), not -inf
    -20.723266
    """
    e = _eps(epsilon)
    sp = _s().sp
    if e == 0:
        return _map1(sp.log, x)
    return _map1(lambda a: sp.log(Max(_note("log", a, e, None), e)), x)


def acos(x: Any, epsilon: Any = _DEFAULT):
    """``acos`` of the argument clamped to ``[-1, 1]`` (rounding past 1 gives 0, not NaN).

    Example:

    >>> from fgopt.symbolic import acos, symbols
    >>> x = symbols("x")
    >>> float(acos(x).subs(x, 1.0000001)), round(float(acos(x).subs(x, 0.5)), 6)
    (0.0, 1.047198)
    """
    sp = _s().sp
    if _eps(epsilon) == 0:
        return _map1(sp.acos, x)
    return _map1(lambda a: sp.acos(Max(-1, Min(1, _note("acos", a, -1, 1)))), x)


def asin(x: Any, epsilon: Any = _DEFAULT):
    """``asin`` of the argument clamped to ``[-1, 1]`` (rounding past 1 gives pi/2, not NaN).

    Example:

    >>> from fgopt.symbolic import asin, symbols
    >>> x = symbols("x")
    >>> round(float(asin(x).subs(x, -1.0000001)), 6), round(float(asin(x).subs(x, 0.5)), 6)
    (-1.570796, 0.523599)
    """
    sp = _s().sp
    if _eps(epsilon) == 0:
        return _map1(sp.asin, x)
    return _map1(lambda a: sp.asin(Max(-1, Min(1, _note("asin", a, -1, 1)))), x)


def atan2(y: Any, x: Any, epsilon: Any = _DEFAULT):
    """``atan2(y, x + snz(x) epsilon)``: finite value and gradient at ``x = y = 0``.

    Example:

    >>> from fgopt.symbolic import V2, atan2
    >>> @fgopt.factor
    ... def bearing(p: V2, measured: V2) -> V2:
    ...     return V2(atan2(p[1], p[0]), 0) - measured
    ...
    >>> np.round(bearing(p=key('p', 0), measured=np.zeros(2)).error(fgopt.Variables().add(key('p', 0), np.array([0.0, 1.0]))), 6)
    array([ 1.570796, -0.      ])
    """
    s = _s()
    y, x = s.as_expr(y), s.as_expr(x)
    e = _eps(epsilon)
    return s.sp.atan2(y, x + s.snz(x) * e if e != 0 else x)


def safe_div(a: Any, b: Any, epsilon: Any = _DEFAULT):
    """``a / (b + snz(b) epsilon)``: finite at ``b = 0`` once ``epsilon > 0``.

    Example:

    >>> from fgopt.symbolic import epsilon, safe_div, symbols
    >>> a, b = symbols("a b")
    >>> safe_div(a, b).subs({a: 1, b: 0, epsilon: 1e-6})
    1000000.00000000
    >>> safe_div(a, b).subs({a: 1, b: 4, epsilon: 0})
    1/4
    """
    s = _s()
    b = s.as_expr(b)
    return s.as_expr(a) / (b + s.snz(b) * _eps(epsilon))


def _indicator(cond: Any):
    """0/1 expression of a condition: relations ``<= < >= >`` (SymPy relationals), ``&``, ``|``,
    ``~`` of those, or an expression already 0 or 1. ``Heaviside`` underneath: the generated
    code is a select, and its derivative is 0 (as for ``sign_no_zero``)."""
    sp = _s().sp
    if isinstance(cond, (bool, int)) and not isinstance(cond, sp.Basic):
        return sp.S.One if cond else sp.S.Zero
    if cond is sp.true or cond is sp.false:
        return sp.S.One if cond is sp.true else sp.S.Zero
    if isinstance(cond, (sp.LessThan, sp.StrictLessThan, sp.GreaterThan, sp.StrictGreaterThan)):
        lhs, rhs = cond.lhs, cond.rhs
        if isinstance(cond, (sp.GreaterThan, sp.StrictGreaterThan)):
            lhs, rhs = rhs, lhs  # a >= b  <=>  b <= a
        strict = isinstance(cond, (sp.StrictLessThan, sp.StrictGreaterThan))
        return sp.Heaviside(rhs - lhs, 0 if strict else 1)
    if isinstance(cond, sp.And):
        return sp.Mul(*[_indicator(c) for c in cond.args])
    if isinstance(cond, sp.Or):
        return 1 - sp.Mul(*[1 - _indicator(c) for c in cond.args])
    if isinstance(cond, sp.Not):
        return 1 - _indicator(cond.args[0])
    if isinstance(cond, (sp.Equality, sp.Unequality)):
        raise TypeError("where(): == and != conditions are not supported (they are measure-zero "
                        "events in floating point); use <= / >=")
    return _s().as_expr(cond)


def where(cond: Any, a: Any, b: Any):
    """``a`` where ``cond`` holds, else ``b`` (entry-wise on matrices), without a branch.

    ``cond`` is a relation of expressions (``Abs(x) <= Abs(y)``), combined with ``&``, ``|``,
    ``~``. Evaluates ``h a + (1 - h) b`` with ``h`` the 0/1 indicator of ``cond``, so both
    branches must be finite everywhere. The derivative follows the selected branch.

    Example:

    >>> from fgopt.symbolic import where, symbols
    >>> x = symbols('x')
    >>> where(x > 0, x, -x)
    -x*(1 - Heaviside(x, 0)) + x*Heaviside(x, 0)
    """
    from .matrix import Matrix, _as_matrix

    h = _indicator(cond)
    if isinstance(a, Matrix) or isinstance(b, Matrix):
        shape = a.shape if isinstance(a, Matrix) else b.shape
        am, bm = _as_matrix(a, shape), _as_matrix(b, shape)
        return am * h + bm * (1 - h)
    return h * _s().as_expr(a) + (1 - h) * _s().as_expr(b)


def pow(x: Any, p: Any):
    return _s().as_expr(x) ** _s().as_expr(p)


def symbols(names: str):
    """Real SymPy symbols, ``a, b = symbols("a b")``.

    Example (real symbols let SymPy simplify what it could not for complex ones):

    >>> from fgopt.symbolic import symbols
    >>> a, b = symbols("a b")
    >>> a.is_real, (a**2).is_nonnegative
    (True, True)
    """
    return _s().sp.symbols(names, real=True)


def __getattr__(name: str) -> Any:
    if name == "epsilon":
        return _s().epsilon
    if name == "pi":
        return _s().sp.pi
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "Abs",
    "Max",
    "Min",
    "acos",
    "asin",
    "atan",
    "atan2",
    "clamp",
    "cos",
    "cosh",
    "exp",
    "floor",
    "log",
    "pow",
    "safe_div",
    "sign",
    "sign_no_zero",
    "sin",
    "sinh",
    "snz",
    "sqrt",
    "symbols",
    "tan",
    "tanh",
    "where",
]
