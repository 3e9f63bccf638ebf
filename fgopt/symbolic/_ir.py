"""Generated kernel bodies as LLVM IR inside numba: compiled in milliseconds, not seconds.

numba's front end types and lowers every Python operator on its own (3-4 ms per operation,
measured: a Pose3 between factor's 1,808-op linearization took 6.6 s CPU to compile, the same
at ``NUMBA_OPT=0`` and 3, so it is not LLVM's time). A generated kernel is a straight-line
program, so its body does not need that front end: :func:`to_table` turns a
:class:`~fgopt.symbolic.cse.Program` into an instruction table at generation time (SymPy; the
table is written into the kernel module), and :func:`body` makes it a numba ``@intrinsic``
whose code generator writes the table straight into LLVM IR (a few microseconds per
instruction), then LLVM optimizes the function as usual. The kernel module's ``@njit`` loop
calls the intrinsic once per row (``body(*arrays, i)``): numba types one call, and caches the
kernel like any other (``cache=True``; a cache hit runs no code generation).

Instruction table (a tuple of tuples; instruction ``k`` defines register ``k``, SSA)::

    ("ld", arg, idx)    element [i, *idx] of the arg-th array argument (row i)
    ("c", value)        float constant
    (op, r1[, r2])      op in + - * / neg sqrt sin cos tan asin acos atan exp log sinh cosh
                        tanh abs floor cbrt atan2 pow copysign min max sign heaviside
    ("st", arg, idx, r) store register r at [i, *idx] of the arg-th array (slot unused)

Semantics are those of the Python source the printer writes (:mod:`.printer`): IEEE
operations without fast-math (numba's ``fastmath=False``), division by zero gives inf/nan
(``error_model="numpy"``), ``min(a, b)`` is ``b if b < a else a``, ``sign`` is 0 at 0,
``heaviside(x, h0)`` is ``h0`` at 0. Outside numba (``LazyKernel.python``) the same table runs
in :meth:`Body.__call__`, an interpreter.
"""

from __future__ import annotations

import math
from typing import Any

# ---------------------------------------------------------------------- SymPy -> table
_UNARY = {"sin": "sin", "cos": "cos", "tan": "tan", "asin": "asin", "acos": "acos",
          "atan": "atan", "exp": "exp", "log": "log", "sinh": "sinh", "cosh": "cosh",
          "tanh": "tanh", "Abs": "abs", "floor": "floor", "sign": "sign"}


class _Translator:
    """SymPy expressions -> instructions, one register per distinct (sub)expression."""

    def __init__(self) -> None:
        from . import _sym

        self.s = _sym
        self.sp = _sym.sp
        self.code: list = []
        self.memo: dict = {}   # expression -> register
        self.imemo: dict = {}  # instruction -> register
        self.env: dict = {}    # symbol -> register

    def op(self, *ins: Any) -> int:
        r = self.imemo.get(ins)
        if r is None:
            self.code.append(ins)
            r = self.imemo[ins] = len(self.code) - 1
        return r

    def const(self, v: float) -> int:
        return self.op("c", float(v))

    def pow_int(self, b: int, k: int) -> int:
        if k == 1:
            return b
        half = self.pow_int(b, k // 2)
        sq = self.op("*", half, half)
        return sq if k % 2 == 0 else self.op("*", sq, b)

    def expr(self, e: Any) -> int:
        if isinstance(e, (int, float)):
            return self.const(e)
        r = self.env.get(e)
        if r is None:
            r = self.memo.get(e)
        if r is None:
            r = self.memo[e] = self._expr(e)
        return r

    def _expr(self, e: Any) -> int:
        sp = self.sp
        if e.is_Symbol:
            if e.name == "epsilon":
                return self.const(self.s.EPSILON_VALUE)
            raise ValueError(f"generated kernel: unbound symbol {e}")
        if e.is_Number or e in (sp.pi, sp.E):
            return self.const(float(e))
        if e.is_Add:
            pos, neg = [], []
            for t in e.args:
                c, _ = t.as_coeff_Mul()
                if c.is_Number and c < 0:
                    neg.append(self.expr(-t))
                else:
                    pos.append(self.expr(t))
            acc = pos[0] if pos else self.op("neg", neg.pop(0))
            for r in pos[1:]:
                acc = self.op("+", acc, r)
            for r in neg:
                acc = self.op("-", acc, r)
            return acc
        if e.is_Mul:
            c, rest = e.as_coeff_Mul()
            if c.is_Number and c != 1:
                inner = self.expr(rest)
                return self.op("neg", inner) if c == -1 else self.op("*", self.const(c), inner)
            num, den = [], []
            for f in e.args:
                if f.is_Pow and f.exp.is_Integer and f.exp < 0:
                    den.append(self.expr(f.base ** (-f.exp)))
                else:
                    num.append(self.expr(f))
            acc = num[0] if num else self.const(1.0)
            for r in num[1:]:
                acc = self.op("*", acc, r)
            if den:
                d = den[0]
                for r in den[1:]:
                    d = self.op("*", d, r)
                acc = self.op("/", acc, d)
            return acc
        if e.is_Pow:
            b, x = e.base, e.exp
            if x.is_Integer:
                k = int(x)
                if k == 0:
                    return self.const(1.0)
                p = self.pow_int(self.expr(b), abs(k))
                return p if k > 0 else self.op("/", self.const(1.0), p)
            if x.is_Rational and x.q == 2:
                root = self.op("sqrt", self.expr(b))
                k = abs(int(x.p))
                p = root if k == 1 else self.op("*", self.pow_int(self.expr(b), k // 2), root)
                return p if x > 0 else self.op("/", self.const(1.0), p)
            if x == sp.Rational(1, 3):
                return self.op("cbrt", self.expr(b))
            return self.op("pow", self.expr(b), self.expr(x))
        name = type(e).__name__
        if name in _UNARY:
            return self.op(_UNARY[name], self.expr(e.args[0]))
        if name == "atan2":
            return self.op("atan2", self.expr(e.args[0]), self.expr(e.args[1]))
        if name == "SignNoZero":
            return self.op("copysign", self.const(1.0), self.expr(e.args[0]))
        if name in ("Min", "Max"):
            acc = self.expr(e.args[0])
            for a in e.args[1:]:
                acc = self.op(name.lower(), acc, self.expr(a))
            return acc
        if name == "Heaviside":
            h0 = float(e.args[1]) if len(e.args) > 1 else 0.5
            return self.op("heaviside", self.expr(e.args[0]), self.const(h0))
        if name == "DiracDelta":
            return self.const(0.0)
        raise ValueError(f"generated kernel: no machine code for {name} ({e})")


def to_table(prog: Any, loads: dict, stores: dict) -> tuple:
    """The instruction table of ``prog``: ``loads`` maps an input symbol to ``(arg, idx)``,
    ``stores`` an output name to ``(arg, index(k))`` (``index(k)``: the tuple ``idx`` of its
    ``k``-th expression). Dead instructions are dropped."""
    t = _Translator()
    for sym, (arg, idx) in loads.items():
        t.env[sym] = t.op("ld", arg, tuple(idx))
    for sym, e in prog.stmts:
        t.env[sym] = t.expr(e)
    for name, (arg, index) in stores.items():
        for k, e in enumerate(prog.outputs[name]):
            t.code.append(("st", arg, tuple(index(k)), t.expr(t.sp.sympify(e))))
    return _compact(t.code)


def kernel_source(fn_name: str, prog: Any, params: list, loads: dict, stores: dict, doc: str,
                  ops: int) -> str:
    """Source of one generated ``@njit`` kernel ``fn_name(*params)``: its :class:`Body` (the
    table of :func:`to_table`, written as a literal) and the loop over the rows of
    ``params[-1]`` calling it. The module imports ``njit`` and ``Body``."""
    table = to_table(prog, loads, stores)
    body = f"{fn_name}_body"
    rows = [", ".join(repr(ins) for ins in table[j:j + 6]) for j in range(0, len(table), 6)]
    return "\n".join(
        [f"# {fn_name}: {ops} ops of the program, {len(table)} instructions",
         f"{body} = Body((", *(f"    {r}," for r in rows), f"), {len(params)}, {body!r})",
         "",
         "",
         '@njit(cache=True, error_model="numpy", nogil=True)',
         f"def {fn_name}({', '.join(params)}):",
         f'    """{doc}"""',
         f"    for _i in range({params[-1]}.shape[0]):",
         f"        {body}({', '.join(params)}, _i)"]) + "\n"


def _args_of(ins: tuple) -> tuple:
    if ins[0] in ("ld", "c"):
        return ()
    return (ins[3],) if ins[0] == "st" else ins[1:]


def _compact(code: list) -> tuple:
    live = set()
    for k in range(len(code) - 1, -1, -1):
        if code[k][0] == "st" or k in live:
            live.add(k)
            live.update(_args_of(code[k]))
    remap: dict = {}
    out: list = []
    for k, ins in enumerate(code):
        if k not in live:
            continue
        if ins[0] == "st":
            ins = ins[:3] + (remap[ins[3]],)
        elif ins[0] not in ("ld", "c"):
            ins = (ins[0],) + tuple(remap[a] for a in ins[1:])
        remap[k] = len(out)
        out.append(ins)
    return tuple(out)


# ---------------------------------------------------------------------- table -> LLVM IR
_INTRINSIC1 = {"sqrt": "llvm.sqrt", "sin": "llvm.sin", "cos": "llvm.cos", "exp": "llvm.exp",
               "log": "llvm.log", "abs": "llvm.fabs", "floor": "llvm.floor"}
_LIBM1 = {"tan": "tan", "asin": "asin", "acos": "acos", "atan": "atan", "sinh": "sinh",
          "cosh": "cosh", "tanh": "tanh", "cbrt": "cbrt"}
_LIBM2 = {"atan2": "atan2", "pow": "pow"}


def emit(context: Any, builder: Any, sig: Any, args: tuple, code: tuple) -> None:
    """Write ``code`` at the builder's position (``args``: the arrays, then the row index)."""
    from llvmlite import ir
    from numba.core import cgutils

    dbl = ir.DoubleType()
    mod = builder.module
    row = args[-1]
    arrays = [context.make_array(ty)(context, builder, a)
              for ty, a in zip(sig.args[:-1], args[:-1])]
    layouts = [ty.layout for ty in sig.args[:-1]]
    shapes = [cgutils.unpack_tuple(builder, a.shape) for a in arrays]
    strides = [cgutils.unpack_tuple(builder, a.strides) for a in arrays]
    fns: dict = {}

    def fn(name: str, nargs: int) -> Any:
        f = fns.get(name)
        if f is None:
            fty = ir.FunctionType(dbl, [dbl] * nargs)
            f = fns[name] = (mod.declare_intrinsic(name, [dbl], fty) if name.startswith("llvm.")
                             else cgutils.insert_pure_function(mod, fty, name=name))
        return f

    def ptr(arg: int, idx: tuple) -> Any:
        inds = [row] + [context.get_constant(sig.args[-1], j) for j in idx]
        return cgutils.get_item_pointer2(context, builder, arrays[arg].data, shapes[arg],
                                         strides[arg], layouts[arg], inds)

    zero, one = ir.Constant(dbl, 0.0), ir.Constant(dbl, 1.0)
    regs: list = []
    for ins in code:
        op, v = ins[0], None
        if op == "ld":
            v = builder.load(ptr(ins[1], ins[2]))
        elif op == "c":
            v = ir.Constant(dbl, ins[1])
        elif op == "+":
            v = builder.fadd(regs[ins[1]], regs[ins[2]])
        elif op == "-":
            v = builder.fsub(regs[ins[1]], regs[ins[2]])
        elif op == "*":
            v = builder.fmul(regs[ins[1]], regs[ins[2]])
        elif op == "/":
            v = builder.fdiv(regs[ins[1]], regs[ins[2]])
        elif op == "neg":
            v = builder.fneg(regs[ins[1]])
        elif op in _INTRINSIC1:
            v = builder.call(fn(_INTRINSIC1[op], 1), [regs[ins[1]]])
        elif op in _LIBM1:
            v = builder.call(fn(_LIBM1[op], 1), [regs[ins[1]]])
        elif op in _LIBM2:
            v = builder.call(fn(_LIBM2[op], 2), [regs[ins[1]], regs[ins[2]]])
        elif op == "copysign":
            v = builder.call(fn("llvm.copysign", 2), [regs[ins[1]], regs[ins[2]]])
        elif op in ("min", "max"):
            a, b = regs[ins[1]], regs[ins[2]]
            v = builder.select(builder.fcmp_ordered("<" if op == "min" else ">", b, a), b, a)
        elif op == "sign":
            a = regs[ins[1]]
            pos = builder.select(builder.fcmp_ordered(">", a, zero), one, zero)
            v = builder.select(builder.fcmp_ordered("<", a, zero), ir.Constant(dbl, -1.0), pos)
        elif op == "heaviside":
            a, h0 = regs[ins[1]], regs[ins[2]]
            v = builder.select(builder.fcmp_ordered(">", a, zero), one,
                               builder.select(builder.fcmp_ordered("==", a, zero), h0, zero))
        elif op == "st":
            builder.store(regs[ins[3]], ptr(ins[1], ins[2]))
        else:
            raise ValueError(f"generated kernel: unknown instruction {op!r}")
        regs.append(v)


_PY = {"+": lambda a, b: a + b, "-": lambda a, b: a - b, "*": lambda a, b: a * b,
       "/": lambda a, b: _div(a, b), "neg": lambda a: -a, "sqrt": lambda a: _f(math.sqrt, a),
       "sin": math.sin, "cos": math.cos, "tan": math.tan, "asin": lambda a: _f(math.asin, a),
       "acos": lambda a: _f(math.acos, a), "atan": math.atan, "exp": lambda a: _f(math.exp, a),
       "log": lambda a: _f(math.log, a), "sinh": math.sinh, "cosh": math.cosh,
       "tanh": math.tanh, "abs": abs, "floor": lambda a: float(math.floor(a)),
       "cbrt": math.cbrt, "atan2": math.atan2, "pow": lambda a, b: _f(math.pow, a, b),
       "copysign": math.copysign, "min": lambda a, b: b if b < a else a,
       "max": lambda a, b: b if b > a else a,
       "sign": lambda a: 1.0 if a > 0 else (-1.0 if a < 0 else 0.0),
       "heaviside": lambda a, h0: 1.0 if a > 0 else (h0 if a == 0 else 0.0)}


def _div(a: float, b: float) -> float:
    if b != 0.0:
        return a / b
    return math.nan if a == 0.0 or a != a else math.copysign(math.inf, a) * math.copysign(1, b)


def _f(f: Any, *a: float) -> float:
    try:
        return f(*a)
    except (ValueError, OverflowError):  # IEEE results, as the compiled code gives
        import numpy as np

        with np.errstate(all="ignore"):
            return float(getattr(np, {"pow": "power", "sqrt": "sqrt", "log": "log",
                                      "exp": "exp", "asin": "arcsin",
                                      "acos": "arccos"}[f.__name__])(*a))


class Body:
    """A kernel body: ``body(*arrays, i)`` runs the table on row ``i``. In numba code it is an
    ``@intrinsic`` (built, with numba's import, the first time a kernel using it is typed);
    in Python an interpreter of the same table."""

    def __init__(self, code: tuple, nargs: int, name: str):
        self.code, self.nargs, self.name = code, nargs, name
        self._intrinsic: Any = None

    @property
    def _numba_type_(self) -> Any:
        from numba.core.registry import cpu_target

        intrinsic = self.intrinsic()
        ctx = cpu_target.typing_context
        ctx.refresh()  # the intrinsic's typing template, registered when it was made
        return ctx.resolve_value_type(intrinsic)

    def intrinsic(self) -> Any:
        if self._intrinsic is None:
            self._intrinsic = _make_intrinsic(self.code, self.nargs, self.name)
        return self._intrinsic

    def __call__(self, *args: Any) -> None:
        *arrays, i = args
        regs: list = []
        for ins in self.code:
            op = ins[0]
            if op == "ld":
                regs.append(float(arrays[ins[1]][(i, *ins[2])]))
            elif op == "c":
                regs.append(ins[1])
            elif op == "st":
                arrays[ins[1]][(i, *ins[2])] = regs[ins[3]]
                regs.append(None)
            else:
                regs.append(_PY[op](*(regs[r] for r in ins[1:])))


def _make_intrinsic(code: tuple, nargs: int, name: str) -> Any:
    from numba import types
    from numba.extending import intrinsic

    def typer(typingctx: Any, *args: Any) -> Any:
        *arrays, i = args
        if len(arrays) != nargs or not isinstance(i, types.Integer) or not all(
                isinstance(a, types.Array) and a.dtype == types.float64 for a in arrays):
            raise TypeError(f"{name}: takes {nargs} float64 arrays and a row index")

        def codegen(context: Any, builder: Any, sig: Any, llargs: tuple) -> Any:
            emit(context, builder, sig, llargs, code)
            return context.get_dummy_value()

        return types.void(*arrays, types.intp), codegen

    params = ", ".join(f"a{k}" for k in range(nargs + 1))
    ns: dict = {"typer": typer}
    exec(f"def {name}(typingctx, {params}):\n    return typer(typingctx, {params})\n", ns)  # noqa: S102
    return intrinsic(ns[name])
