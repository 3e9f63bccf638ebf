"""SymPy expression -> numba-compatible Python source (one scalar expression per line).

Rules: ``epsilon`` prints as the module constant ``EPSILON``; rationals and floats as float
literals; small integer powers of atoms as products (``x*x``), ``x**(k/2)`` through
``math.sqrt``; ``sign_no_zero(x)`` as ``math.copysign(1.0, x)`` (branchless); ``Heaviside`` /
``sign`` / ``Min`` / ``Max`` as selects the compiler lowers without branches; ``DiracDelta`` as 0.
"""

from __future__ import annotations

from typing import Any

from sympy.printing.pycode import PythonCodePrinter


class NumbaPrinter(PythonCodePrinter):
    """Prints expressions for ``@numba.njit`` kernels (``import math`` and ``numpy as np``)."""

    printmethod = "_fgopt_numba"

    def __init__(self, settings: dict | None = None):
        # order "none": terms in their argument order (SymPy's, which the CSE keeps), not
        # sorted again per expression (that sort was 60 % of printing a kernel's twin)
        super().__init__({"fully_qualified_modules": True, "standard": "python3",
                          "order": "none", **(settings or {})})

    # -- atoms
    def _print_Symbol(self, expr: Any) -> str:
        if expr.name == "epsilon":
            return "EPSILON"
        return expr.name

    _print_Dummy = _print_Symbol

    def _print_Rational(self, expr: Any) -> str:
        return repr(float(expr.p) / float(expr.q))

    _print_Half = _print_Rational

    def _print_Float(self, expr: Any) -> str:
        return repr(float(expr))

    def _print_Integer(self, expr: Any) -> str:
        return str(int(expr))

    def _print_Pi(self, expr: Any) -> str:
        return "math.pi"

    def _print_Exp1(self, expr: Any) -> str:
        return "math.e"

    # -- powers
    def _print_Pow(self, expr: Any, rational: bool = False) -> str:
        # Every compound result is parenthesized: the Mul printer treats a Pow as one factor.
        base, e = expr.base, expr.exp
        b = self._paren(base)
        if e.is_Integer:
            k = int(e)
            if k == 0:
                return "1.0"
            if k == 1:
                return self._print(base)
            if 2 <= k <= 3 and base.is_Atom:
                return "(" + "*".join([b] * k) + ")"
            if k == -1:
                return f"(1.0/{b})"
            if -3 <= k <= -2 and base.is_Atom:
                return f"(1.0/({'*'.join([b] * -k)}))"
            return f"{b}**{k}" if k > 0 else f"{b}**({k})"
        if e.is_Rational and e.q == 2:
            root = f"math.sqrt({self._print(base)})"
            k = int(e.p)
            if k == 1:
                return root
            if k == -1:
                return f"(1.0/{root})"
            if k > 0:
                return f"({b}**{(k - 1) // 2}*{root})" if k > 3 else f"({b}*{root})"
            return f"(1.0/({b}**{(-k - 1) // 2}*{root}))" if k < -3 else f"(1.0/({b}*{root}))"
        if e.is_Rational and e.q == 3 and e.p == 1:
            return f"math.cbrt({self._print(base)})"
        return f"{b}**{self._paren(e)}"

    def _paren(self, item: Any) -> str:
        s = self._print(item)
        if item.is_Atom and not (item.is_Number and item < 0):
            return s
        return f"({s})"

    # -- branchless primitives
    def _print_SignNoZero(self, expr: Any) -> str:
        return f"math.copysign(1.0, {self._print(expr.args[0])})"

    def _print_sign(self, expr: Any) -> str:
        return f"np.sign({self._print(expr.args[0])})"

    def _print_Heaviside(self, expr: Any) -> str:
        x = self._print(expr.args[0])
        h0 = float(expr.args[1]) if len(expr.args) > 1 else 0.5
        return f"(1.0 if {x} > 0.0 else ({h0!r} if {x} == 0.0 else 0.0))"

    def _print_DiracDelta(self, expr: Any) -> str:
        return "0.0"

    def _print_Min(self, expr: Any) -> str:
        out = self._print(expr.args[0])
        for a in expr.args[1:]:
            out = f"min({out}, {self._print(a)})"
        return out

    def _print_Max(self, expr: Any) -> str:
        out = self._print(expr.args[0])
        for a in expr.args[1:]:
            out = f"max({out}, {self._print(a)})"
        return out

    def _print_Abs(self, expr: Any) -> str:
        return f"abs({self._print(expr.args[0])})"


_PRINTER: NumbaPrinter | None = None


def to_source(expr: Any) -> str:
    """Source of one expression (numbers print as float literals)."""
    global _PRINTER
    if _PRINTER is None:
        _PRINTER = NumbaPrinter()
    if isinstance(expr, (int, float)):
        return repr(float(expr))
    if getattr(expr, "is_Number", False):
        return repr(float(expr))
    return _PRINTER.doprint(expr)


class NumpyPrinter(NumbaPrinter):
    """Prints the same expressions for whole columns (NumPy arrays): selects as ``np.where``,
    ``min`` / ``max`` / ``abs`` as their elementwise ufuncs; ``math.f`` becomes ``np.f`` by
    :func:`to_numpy_source`."""

    def _print_Heaviside(self, expr: Any) -> str:
        x = self._print(expr.args[0])
        h0 = float(expr.args[1]) if len(expr.args) > 1 else 0.5
        return f"np.where({x} > 0.0, 1.0, np.where({x} == 0.0, {h0!r}, 0.0))"

    def _print_Min(self, expr: Any) -> str:
        out = self._print(expr.args[0])
        for a in expr.args[1:]:
            out = f"np.minimum({out}, {self._print(a)})"
        return out

    def _print_Max(self, expr: Any) -> str:
        out = self._print(expr.args[0])
        for a in expr.args[1:]:
            out = f"np.maximum({out}, {self._print(a)})"
        return out

    def _print_Abs(self, expr: Any) -> str:
        return f"np.abs({self._print(expr.args[0])})"


#: ``math`` functions the printer emits and their NumPy ufuncs (same IEEE semantics).
NUMPY_NAMES = {"sin": "sin", "cos": "cos", "tan": "tan", "sqrt": "sqrt", "cbrt": "cbrt",
               "exp": "exp", "log": "log", "atan2": "arctan2", "atan": "arctan",
               "asin": "arcsin", "acos": "arccos", "sinh": "sinh", "cosh": "cosh",
               "tanh": "tanh", "copysign": "copysign", "floor": "floor", "ceil": "ceil",
               "fabs": "abs", "log1p": "log1p", "expm1": "expm1", "hypot": "hypot",
               "pi": "pi", "e": "e"}

_NUMPY_PRINTER: NumpyPrinter | None = None


def to_numpy_source(expr: Any) -> str | None:
    """Source of one expression over NumPy columns, or ``None`` when it uses a function with no
    NumPy ufunc (the module then keeps only its numba kernels)."""
    import re

    global _NUMPY_PRINTER
    if isinstance(expr, (int, float)) or getattr(expr, "is_Number", False):
        return repr(float(expr))
    if _NUMPY_PRINTER is None:
        _NUMPY_PRINTER = NumpyPrinter()
    src = _NUMPY_PRINTER.doprint(expr)
    missing = []

    def sub(m: "re.Match") -> str:
        name = NUMPY_NAMES.get(m.group(1))
        if name is None:
            missing.append(m.group(1))
            return m.group(0)
        return f"np.{name}"

    src = re.sub(r"\bmath\.(\w+)", sub, src)
    if missing or re.search(r"(?<![\w.])(min|max|abs)\(| if ", src):
        return None
    return src
