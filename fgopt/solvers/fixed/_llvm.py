"""Straight-line programs as LLVM IR inside numba (the fixed formulation's back end).

Numba's front end types and lowers every Python operator separately (about 3-9 ms per
operation), so a flattened linearization of ~10^4 operations written as Python source takes
minutes to compile. Here the program becomes a compact instruction table instead
(:func:`to_instructions`, at derivation time, SymPy), and :func:`emit` writes it straight into
LLVM IR with llvmlite from a numba ``@intrinsic`` (:func:`make_intrinsic`): one typing step, a
few microseconds per instruction, then LLVM optimizes the function as usual. The njit function
calling the intrinsic is cached by numba like any other (``cache=True``); loading a cached
module imports neither SymPy nor this module's translator.

Instruction table: a tuple of tuples; instruction ``i`` defines register ``i`` (SSA)::

    ("ld", arg, k)      arg-th array argument, flat element k
    ("c", value)        float constant
    (op, r1[, r2])      op in + - * / neg sqrt sin cos tan asin acos atan exp log sinh cosh
                        tanh abs floor cbrt atan2 pow copysign min max sign heaviside(h0)
    ("st", arg, k, r)   store register r into arg-th array, flat element k (its slot is unused)
    ("ret", r)          the intrinsic's float64 result (its slot is unused)

Array arguments must be C-contiguous float64 (flat indexing).
"""

from __future__ import annotations

from typing import Any

# ----------------------------------------------------------------------------- SymPy -> table
_UNARY = {"sin": "sin", "cos": "cos", "tan": "tan", "asin": "asin", "acos": "acos",
          "atan": "atan", "exp": "exp", "log": "log", "sinh": "sinh", "cosh": "cosh",
          "tanh": "tanh", "Abs": "abs", "floor": "floor", "sign": "sign"}


class _Translator:
    def __init__(self, inputs: dict) -> None:
        from ...symbolic import _sym

        self.sp = _sym.sp
        self.s = _sym
        self.code: list = []
        self.memo: dict = {}   # expression -> register
        self.imemo: dict = {}  # instruction -> register
        self.env = dict(inputs)  # symbol -> register

    def _new(self, ins: tuple) -> int:
        self.code.append(ins)
        return len(self.code) - 1

    def const(self, v: float) -> int:
        return self.op("c", float(v))

    def op(self, *ins: Any) -> int:
        r = self.imemo.get(ins)
        if r is None:
            r = self.imemo[ins] = self._new(ins)
        return r

    def pow_int(self, b: int, k: int) -> int:
        if k == 1:
            return b
        half = self.pow_int(b, k // 2)
        sq = self.op("*", half, half)
        return sq if k % 2 == 0 else self.op("*", sq, b)

    def expr(self, e: Any) -> int:
        if e in self.env:
            return self.env[e]
        r = self.memo.get(e)
        if r is not None:
            return r
        r = self._expr(e)
        self.memo[e] = r
        return r

    def _expr(self, e: Any) -> int:
        sp = self.sp
        if e.is_Symbol:
            if e.name == "epsilon":
                return self.const(self.s.EPSILON_VALUE)
            raise ValueError(f"unbound symbol {e}")
        if e.is_Number or e in (sp.pi, sp.E):
            return self.const(float(e))
        if e.is_Add:
            pos, neg = [], []
            for t in e.args:
                c, rest = t.as_coeff_Mul()
                if c.is_Number and c < 0:
                    neg.append(self.expr(-t))
                else:
                    pos.append(self.expr(t))
            if len(pos) == 0:
                acc = self.op("neg", neg[0])
                neg = neg[1:]
            else:
                acc = pos[0]
                for r in pos[1:]:
                    acc = self.op("+", acc, r)
            for r in neg:
                acc = self.op("-", acc, r)
            return acc
        if e.is_Mul:
            c, rest = e.as_coeff_Mul()
            if c.is_Number and c != 1:
                inner = self.expr(rest)
                if c == -1:
                    return self.op("neg", inner)
                return self.op("*", self.const(float(c)), inner)
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
                k = int(x.p)
                p = root if abs(k) == 1 else self.op("*", self.pow_int(self.expr(b), (abs(k) - 1) // 2), root)
                return p if k > 0 else self.op("/", self.const(1.0), p)
            if x.is_Rational and x == sp.Rational(1, 3):
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
        raise ValueError(f"fixed formulation: cannot translate {name} ({e})")


def to_instructions(stmts: list, stores: list, inputs: dict, ret: Any = None) -> tuple:
    """Instruction table of ``stmts`` then ``stores`` (``(arg, k, expr)``) then ``ret``.

    ``inputs`` maps input symbols to ``(arg, k)`` loads.
    """
    t = _Translator({})
    for sym, (arg, k) in inputs.items():
        t.env[sym] = t.op("ld", arg, k)
    for sym, e in stmts:
        t.env[sym] = t.expr(e)
    for arg, k, e in stores:
        t.code.append(("st", arg, k, t.expr(t.sp.sympify(e))))
    if ret is not None:
        t.code.append(("ret", t.expr(t.sp.sympify(ret))))
    return _compact(t.code)


def _compact(code: list) -> tuple:
    """Drop dead instructions; registers become positions in the result."""
    live = set()
    for ins in reversed(range(len(code))):
        i = code[ins]
        if i[0] in ("st", "ret") or ins in live:
            live.add(ins)
            for a in _reg_args(i):
                live.add(a)
    remap, out = {}, []
    for idx, ins in enumerate(code):
        if idx not in live:
            continue
        new = _map_regs(ins, remap)
        remap[idx] = len(out)
        out.append(new)
    return tuple(out)


def _reg_args(ins: tuple) -> tuple:
    op = ins[0]
    if op in ("ld", "c"):
        return ()
    if op == "st":
        return (ins[3],)
    return ins[1:]


def _map_regs(ins: tuple, remap: dict) -> tuple:
    op = ins[0]
    if op in ("ld", "c"):
        return ins
    if op == "st":
        return ins[:3] + (remap[ins[3]],)
    return (op,) + tuple(remap[a] for a in ins[1:])


def count_instructions(code: tuple) -> dict:
    """Arithmetic / transcendental / memory instruction counts."""
    out = {"arith": 0, "func": 0, "load": 0, "store": 0, "const": 0}
    for ins in code:
        op = ins[0]
        if op in ("+", "-", "*", "/", "neg"):
            out["arith"] += 1
        elif op == "ld":
            out["load"] += 1
        elif op == "st":
            out["store"] += 1
        elif op == "c":
            out["const"] += 1
        elif op != "ret":
            out["func"] += 1
    return out


# ----------------------------------------------------------------------------- table -> LLVM IR
_INTRINSIC1 = {"sqrt": "llvm.sqrt", "sin": "llvm.sin", "cos": "llvm.cos", "exp": "llvm.exp",
               "log": "llvm.log", "abs": "llvm.fabs", "floor": "llvm.floor"}
_EXTERN1 = {"tan": "tan", "asin": "asin", "acos": "acos", "atan": "atan", "sinh": "sinh",
            "cosh": "cosh", "tanh": "tanh", "cbrt": "cbrt"}
_EXTERN2 = {"atan2": "atan2", "pow": "pow"}


def emit(context: Any, builder: Any, sig: Any, args: tuple, code: tuple) -> Any:
    """Write ``code`` at the builder's position; returns the ``ret`` value (or a dummy 0.0)."""
    from llvmlite import ir
    from numba.core import cgutils

    dbl = ir.DoubleType()
    i64 = ir.IntType(64)
    mod = builder.module
    ptrs = [context.make_array(ty)(context, builder, a).data for ty, a in zip(sig.args, args)]
    regs: list = []
    fns: dict = {}

    def fn(name: str, nargs: int) -> Any:
        f = fns.get(name)
        if f is None:
            if name.startswith("llvm."):
                f = mod.declare_intrinsic(name, [dbl], ir.FunctionType(dbl, [dbl] * nargs))
            else:
                f = cgutils.insert_pure_function(mod, ir.FunctionType(dbl, [dbl] * nargs),
                                                 name=name)
            fns[name] = f
        return f

    zero, one = ir.Constant(dbl, 0.0), ir.Constant(dbl, 1.0)
    result = zero
    for ins in code:
        op = ins[0]
        if op == "ld":
            v = builder.load(builder.gep(ptrs[ins[1]], [ir.Constant(i64, ins[2])]))
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
        elif op in _EXTERN1:
            v = builder.call(fn(_EXTERN1[op], 1), [regs[ins[1]]])
        elif op in _EXTERN2:
            v = builder.call(fn(_EXTERN2[op], 2), [regs[ins[1]], regs[ins[2]]])
        elif op == "copysign":
            v = builder.call(fn("llvm.copysign", 2), [regs[ins[1]], regs[ins[2]]])
        elif op == "min":  # Python's min(a, b): b if b < a else a
            a, b = regs[ins[1]], regs[ins[2]]
            v = builder.select(builder.fcmp_ordered("<", b, a), b, a)
        elif op == "max":
            a, b = regs[ins[1]], regs[ins[2]]
            v = builder.select(builder.fcmp_ordered(">", b, a), b, a)
        elif op == "sign":
            a = regs[ins[1]]
            pos = builder.select(builder.fcmp_ordered(">", a, zero), one, zero)
            v = builder.select(builder.fcmp_ordered("<", a, zero), ir.Constant(dbl, -1.0), pos)
        elif op == "heaviside":
            a, h0 = regs[ins[1]], regs[ins[2]]
            v = builder.select(builder.fcmp_ordered(">", a, zero), one,
                               builder.select(builder.fcmp_ordered("==", a, zero), h0, zero))
        elif op == "st":
            builder.store(regs[ins[3]], builder.gep(ptrs[ins[1]], [ir.Constant(i64, ins[2])]))
            v = None
        elif op == "ret":
            result = regs[ins[1]]
            v = None
        else:
            raise ValueError(f"unknown instruction {op!r}")
        regs.append(v)  # one slot per instruction (None for st / ret)
    return result


def make_intrinsic(code: tuple, nargs: int, name: str = "program"):
    """A numba ``@intrinsic`` ``f(a0, ..., a{nargs-1}) -> float64`` running ``code``."""
    from numba import types
    from numba.extending import intrinsic

    def impl(typingctx, *arrays):
        if len(arrays) != nargs:
            raise TypeError(f"expected {nargs} arrays")
        for a in arrays:
            if not (isinstance(a, types.Array) and a.dtype == types.float64 and a.layout == "C"):
                raise TypeError("fixed-formulation intrinsics take C-contiguous float64 arrays")

        def codegen(context, builder, sig, args):
            return emit(context, builder, sig, args, code)

        return types.float64(*arrays), codegen

    params = ", ".join(f"a{i}" for i in range(nargs))
    ns: dict = {"impl": impl}
    exec(f"def {name}(typingctx, {params}):\n    return impl(typingctx, {params})\n", ns)  # noqa: S102
    return intrinsic(ns[name])
