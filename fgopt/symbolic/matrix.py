"""Symbolic matrices and vectors: :class:`Matrix`, ``V1`` ... ``V9``, and :class:`Scalar`.

A :class:`Matrix` wraps a SymPy matrix. Fixed-shape subclasses (``V3``, ``Matrix.shaped(3, 3)``)
are manifold types for factor arguments: storage = entries in row-major order (numpy's
``reshape(-1)``), tangent = storage, ``retract(v) = self + v``. Arithmetic follows SymForce:
``*`` is the matrix product (or scaling by a scalar), ``+``/``-`` are entry-wise, and results
keep a fixed shape (an ``(n, 1)`` result is a ``V<n>``, a 3x3 one an ``M33``). Vectors index like sequences (``v[0]``, ``v.x``) and are built
from scalars or sequences: ``V3(a, b, c)``, ``V3([a, b, c])``, ``V3()`` (zeros).

:class:`Scalar` marks a scalar argument; its values are plain SymPy expressions.
"""

from __future__ import annotations

import numbers
from collections.abc import Iterator
from functools import cache
from typing import Any

from ..errors import DimensionMismatchError, FgoptIndexError, ManifoldError


def _s():
    from . import _sym

    return _sym


def _is_scalar(x: Any) -> bool:
    if isinstance(x, numbers.Number):
        return True
    sp = _s().sp
    return isinstance(x, sp.Basic) and not isinstance(x, sp.MatrixBase)


class Matrix:
    """A symbolic matrix (see the module docstring). ``m.mat`` is the SymPy matrix.

    Example:

    >>> from fgopt.symbolic import Matrix, V2
    >>> M = Matrix.shaped(2, 2)([[1, 2], [3, 4]])
    >>> M * V2(1, 1)
    V2([[3], [7]])
    """

    __slots__ = ("mat",)
    #: Fixed ``(rows, cols)`` of shaped subclasses (``V3``: ``(3, 1)``); ``None`` for ``Matrix``.
    SHAPE: tuple[int, int] | None = None

    def __init__(self, *args: Any):
        sp = _s().sp
        shape = type(self).SHAPE
        if len(args) == 1 and isinstance(args[0], Matrix):
            m = args[0].mat
        elif len(args) == 1 and isinstance(args[0], sp.MatrixBase):
            m = args[0]
        elif shape is None:
            if len(args) != 1:
                raise ManifoldError("Matrix(rows) takes one nested sequence, e.g. "
                                    "Matrix([[a, b], [c, d]])")
            data = _to_list(args[0])
            m = sp.Matrix(data) if len(data) > 0 else sp.zeros(0, 0)
        else:
            r, c = shape
            if len(args) == 0:
                m = sp.zeros(r, c)
            else:
                flat = _flatten(args[0] if len(args) == 1 and not _is_scalar(args[0]) else args)
                if len(flat) != r * c:
                    raise DimensionMismatchError(
                        f"{type(self).__name__} needs {r * c} entries, got {len(flat)}")
                m = sp.Matrix(r, c, [_s().as_expr(v) for v in flat])
        m = sp.MutableDenseMatrix(m)
        if shape is not None and m.shape != shape:
            raise DimensionMismatchError(
                f"{type(self).__name__} has shape {shape}, got a {m.shape} matrix")
        self.mat = m

    # ------------------------------------------------------------------ construction
    @classmethod
    def shaped(cls, rows: int, cols: int) -> type[Matrix]:
        """The fixed-shape subclass ``rows x cols`` (``V<n>`` for a column of n <= 9)."""
        return _shaped(rows, cols)

    @classmethod
    def zeros(cls, rows: int | None = None, cols: int | None = None) -> Matrix:
        r, c = _shape_arg(cls, rows, cols)
        return _wrap(_s().sp.zeros(r, c))

    zero = zeros

    @classmethod
    def eye(cls, n: int | None = None) -> Matrix:
        r, c = _shape_arg(cls, n, n)
        return _wrap(_s().sp.eye(r, c))

    identity = eye

    @classmethod
    def diag(cls, entries: Any) -> Matrix:
        return _wrap(_s().sp.diag(*_flatten(entries)))

    @classmethod
    def symbolic(cls, name: str) -> Matrix:
        """Entries are real symbols ``name_0``, ``name_1``, ... (storage order)."""
        r, c = _shape_arg(cls, None, None)
        sym = _s().real_symbol
        return _wrap(_s().sp.Matrix(r, c, [sym(f"{name}_{k}") for k in range(r * c)]))

    # ------------------------------------------------------------------ storage / manifold
    @classmethod
    def storage_dim(cls) -> int:
        r, c = _shape_arg(cls, None, None)
        return r * c

    dim = storage_dim

    @classmethod
    def from_storage(cls, data: Any) -> Matrix:
        r, c = _shape_arg(cls, None, None)
        flat = _flatten(data)
        if len(flat) != r * c:
            raise DimensionMismatchError(
                f"{cls.__name__}.from_storage needs {r * c} entries, got {len(flat)}")
        return _wrap(_s().sp.Matrix(r, c, [_s().as_expr(v) for v in flat]))

    def to_storage(self) -> list:
        return list(self.mat)  # SymPy iterates row-major

    def retract(self, v: Any) -> Matrix:
        return self + _as_matrix(v, self.shape)

    def local(self, b: Any) -> Matrix:
        diff = _as_matrix(b, self.shape).mat - self.mat
        return _wrap(diff.reshape(len(diff), 1))

    local_coordinates = local

    def storage_D_tangent(self):
        return _s().sp.eye(self.mat.rows * self.mat.cols)

    def tangent_D_storage(self):
        return _s().sp.eye(self.mat.rows * self.mat.cols)

    # ------------------------------------------------------------------ shape and access
    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.mat.shape)

    @property
    def rows(self) -> int:
        return self.mat.rows

    @property
    def cols(self) -> int:
        return self.mat.cols

    def __len__(self) -> int:
        return len(self.mat)

    def __iter__(self) -> Iterator:
        return iter(list(self.mat))

    def __getitem__(self, idx: Any):
        if isinstance(idx, slice):  # flat slice: a vector of the selected entries
            items = list(self.mat)[idx]
            sp = _s().sp
            return _wrap(sp.Matrix(1, len(items), items) if self.mat.rows == 1
                         else sp.Matrix(len(items), 1, items))
        try:
            out = self.mat[idx]
        except IndexError:
            raise FgoptIndexError(f"{type(self).__name__}{list(self.shape)}: index {idx!r} is out "
                                  f"of range ({len(self.mat)} entries)") from None
        return _wrap(out) if isinstance(out, _s().sp.MatrixBase) else out

    def __setitem__(self, idx: Any, value: Any) -> None:
        try:
            self.mat[idx] = value.mat if isinstance(value, Matrix) else value
        except IndexError:
            raise FgoptIndexError(f"{type(self).__name__}{list(self.shape)}: index {idx!r} is out "
                                  f"of range ({len(self.mat)} entries)") from None

    def _component(i: int):
        return property(lambda self: self.mat[i], doc=f"entry {i}")

    x = _component(0)
    y = _component(1)
    z = _component(2)
    w = _component(3)
    del _component

    @property
    def T(self) -> Matrix:
        return _wrap(self.mat.T)

    def transpose(self) -> Matrix:
        return self.T

    def reshape(self, rows: int, cols: int) -> Matrix:
        return _wrap(self.mat.reshape(rows, cols))

    def to_list(self) -> list:
        return self.mat.tolist()

    def to_flat_list(self) -> list:
        return list(self.mat)

    # ------------------------------------------------------------------ arithmetic
    def __add__(self, other: Any) -> Matrix:
        return _wrap(self.mat + _same_shape(self, other, "+").mat)

    def __radd__(self, other: Any) -> Matrix:
        return _wrap(_same_shape(self, other, "+", right=True).mat + self.mat)

    def __sub__(self, other: Any) -> Matrix:
        return _wrap(self.mat - _same_shape(self, other, "-").mat)

    def __rsub__(self, other: Any) -> Matrix:
        return _wrap(_same_shape(self, other, "-", right=True).mat - self.mat)

    def __neg__(self) -> Matrix:
        return _wrap(-self.mat)

    def __mul__(self, other: Any):
        if _is_scalar(other):
            return _wrap(self.mat * _s().as_expr(other))
        if isinstance(other, Matrix):
            return _wrap(self.mat * _inner(self, other, "*").mat)
        return NotImplemented

    def __rmul__(self, other: Any):
        if _is_scalar(other):
            return _wrap(_s().as_expr(other) * self.mat)
        return NotImplemented

    def __matmul__(self, other: Any):
        return _wrap(self.mat * _inner(self, _as_matrix(other, None), "@").mat)

    def __truediv__(self, other: Any) -> Matrix:
        if not _is_scalar(other):
            return NotImplemented
        return _wrap(self.mat / _s().as_expr(other))

    def dot(self, other: Any):
        o = _same_shape(self, other, "dot")
        return sum((a * b for a, b in zip(self.mat, o.mat)), _s().sp.S.Zero)

    def cross(self, other: Any) -> Matrix:
        a, b = list(self.mat), list(_as_matrix(other, None).mat)
        if len(a) != 3:
            raise DimensionMismatchError(f"cross needs 3-vectors, got {len(a)} and {len(b)} entries")
        return _wrap(_s().sp.Matrix([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                                     a[0] * b[1] - a[1] * b[0]]))

    def squared_norm(self):
        return sum((v * v for v in self.mat), _s().sp.S.Zero)

    def norm(self, epsilon: Any = None):
        """``sqrt(|v|^2 + epsilon**2)``: finite gradient at 0 (``epsilon=0`` for the raw norm)."""
        e = _s().epsilon if epsilon is None else _s().as_expr(epsilon)
        return _s().sp.sqrt(self.squared_norm() + e**2)

    def normalized(self, epsilon: Any = None) -> Matrix:
        """``v / norm(epsilon)``."""
        return self / self.norm(epsilon)

    def applyfunc(self, fn) -> Matrix:
        return _wrap(self.mat.applyfunc(fn))

    def subs(self, *args: Any, **kwargs: Any) -> Matrix:
        return _wrap(self.mat.subs(*args, **kwargs))

    def xreplace(self, mapping: dict) -> Matrix:
        return _wrap(self.mat.xreplace(mapping))

    def simplify(self) -> Matrix:
        return _wrap(self.mat.applyfunc(_s().sp.simplify))

    def jacobian(self, wrt: Any) -> Matrix:
        """Plain (storage) Jacobian w.r.t. a Matrix, symbol list or symbolic type's storage.

        For tangent-space Jacobians of Lie group arguments use
        :func:`fgopt.symbolic.tangent_jacobians`.
        """
        if hasattr(wrt, "to_storage"):
            wrt = wrt.to_storage()
        return _wrap(self.mat.reshape(len(self.mat), 1).jacobian(list(wrt)))

    def to_numpy(self):
        import numpy as np

        return np.array(self.mat.evalf(), dtype=float).reshape(self.shape)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.mat.tolist()})"


class Scalar:
    """A scalar argument type: ``def f(x: V3, w: Scalar)``. Values are SymPy expressions.

    Example:

    >>> from fgopt.symbolic import Scalar, V1, sqrt
    >>> @fgopt.factor
    ... def root(x: Scalar, target: Scalar) -> V1:
    ...     return V1(sqrt(x) - target)
    ...
    >>> round(float(root(x=key('s', 0), target=2.0).error(fgopt.Variables().add(key('s', 0), 9.0))[0]), 6)
    1.0
    """

    def __new__(cls, value: Any = 0):
        return _s().as_expr(value)

    @classmethod
    def symbolic(cls, name: str):
        return _s().real_symbol(name)

    @classmethod
    def storage_dim(cls) -> int:
        return 1

    dim = storage_dim

    @classmethod
    def from_storage(cls, data: Any):
        flat = _flatten(data)
        if len(flat) != 1:
            raise DimensionMismatchError(f"Scalar.from_storage needs 1 entry, got {len(flat)}")
        return _s().as_expr(flat[0])


# ---------------------------------------------------------------------- helpers


def _to_list(x: Any) -> list:
    if hasattr(x, "tolist"):
        return x.tolist()
    return [(_to_list(v) if isinstance(v, (list, tuple)) or hasattr(v, "tolist") else v) for v in x]


def _flatten(x: Any) -> list:
    if isinstance(x, Matrix):
        return list(x.mat)
    if _is_scalar(x):
        return [x]
    if hasattr(x, "to_storage") and not isinstance(x, (list, tuple)):
        return list(x.to_storage())
    out = []
    for v in (x.tolist() if hasattr(x, "tolist") and not _is_scalar(x) else x):
        out.extend(_flatten(v) if not _is_scalar(v) else [v])
    return out


def _shape_arg(cls: type, rows: int | None, cols: int | None) -> tuple[int, int]:
    if rows is not None:
        return rows, (cols if cols is not None else 1)
    if cls.SHAPE is None:
        raise ManifoldError(f"{cls.__name__} has no fixed shape: pass the shape or use "
                            "Matrix.shaped")
    return cls.SHAPE


def _same_shape(a: Matrix, other: Any, op: str, right: bool = False) -> Matrix:
    """``other`` as a Matrix of ``a``'s shape, or a DimensionMismatchError naming both."""
    try:
        b = _as_matrix(other, a.shape)
    except (ValueError, TypeError) as exc:  # SymPy: wrong number of entries for the shape
        names = (type(other).__name__, type(a).__name__) if right else (
            type(a).__name__, type(other).__name__)
        raise DimensionMismatchError(
            f"{names[0]} {op} {names[1]}: cannot read the {type(other).__name__} as a "
            f"{a.shape[0]}x{a.shape[1]} matrix ({exc})") from None
    if b.shape != a.shape:
        x, y = (b, a) if right else (a, b)
        raise DimensionMismatchError(
            f"{type(x).__name__} {op} {type(y).__name__}: shapes {x.shape} and {y.shape} differ")
    return b


def _inner(a: Matrix, b: Matrix, op: str) -> Matrix:
    """``b`` if the product ``a b`` is defined, else a DimensionMismatchError."""
    if a.shape[1] != b.shape[0]:
        raise DimensionMismatchError(
            f"{type(a).__name__} {op} {type(b).__name__}: a {a.shape[0]}x{a.shape[1]} matrix "
            f"times a {b.shape[0]}x{b.shape[1]} one (inner sizes {a.shape[1]} and {b.shape[0]} "
            "differ)")
    return b


def _as_matrix(x: Any, shape: tuple[int, int] | None) -> Matrix:
    if isinstance(x, Matrix):
        return x
    sp = _s().sp
    if isinstance(x, sp.MatrixBase):
        return _wrap(x)
    flat = _flatten(x)
    if shape is None:
        shape = (len(flat), 1)
    return _wrap(sp.Matrix(shape[0], shape[1], [_s().as_expr(v) for v in flat]))


def _wrap(m: Any) -> Matrix:
    cls = _shaped(m.rows, m.cols) if 1 <= m.rows <= 16 and 1 <= m.cols <= 16 else Matrix
    obj = object.__new__(cls)
    obj.mat = _s().sp.MutableDenseMatrix(m)
    return obj


@cache
def _shaped(rows: int, cols: int) -> type[Matrix]:
    name = f"V{rows}" if cols == 1 else f"M{rows}{cols}" if rows < 10 and cols < 10 \
        else f"M{rows}x{cols}"
    # the example of the types fgopt.symbolic exports (V1 ... V9, M22, M33, M44)
    if cols == 1 and rows <= 9:
        doc = (f"A symbolic {rows}-vector (column); storage = tangent = its {rows} entries.\n\n"
               f">>> from fgopt.symbolic import {name}\n"
               f">>> v = {name}.symbolic('v')   # entries v_0 ... v_{rows - 1}\n"
               f">>> {name}.storage_dim(), v.retract([1] * {rows})[{rows - 1}]\n"
               f"({rows}, v_{rows - 1} + 1)\n")
    elif cols == 1:
        doc = f"A symbolic {rows}-vector (column); storage = tangent = its {rows} entries."
    else:
        doc = f"A symbolic {rows}x{cols} matrix (row-major storage)."
        if rows == cols <= 4:
            doc += (f"\n\n>>> from fgopt.symbolic import {name}\n"
                    f">>> K = {name}.from_storage(range({rows * cols}))\n"
                    f">>> K[0, 1], K[1, 0], (K * {name}.eye())[{rows - 1}, 0]\n"
                    f"(1, {rows}, {(rows - 1) * cols})\n")
    return type(name, (Matrix,), {"__slots__": (), "SHAPE": (rows, cols), "__doc__": doc,
                                  "__module__": __name__})


def vector_type(n: int) -> type[Matrix]:
    """The symbolic ``n``-vector type (``V3`` for 3).

    >>> from fgopt.symbolic import V3, vector_type
    >>> vector_type(3) is V3, vector_type(12).storage_dim()
    (True, 12)
    """
    return _shaped(n, 1)


V1 = _shaped(1, 1)
V2 = _shaped(2, 1)
V3 = _shaped(3, 1)
V4 = _shaped(4, 1)
V5 = _shaped(5, 1)
V6 = _shaped(6, 1)
V7 = _shaped(7, 1)
V8 = _shaped(8, 1)
V9 = _shaped(9, 1)
M22 = _shaped(2, 2)
M33 = _shaped(3, 3)
M44 = _shaped(4, 4)
