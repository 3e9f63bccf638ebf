"""Straight-line programs, common-subexpression elimination and op counting.

A :class:`Program` is what generated kernels compute: ``stmts`` (``(symbol, expression)``
pairs, each expression over the inputs and earlier symbols) followed by output expressions.
:func:`optimize` runs ``sympy.cse`` over every statement and output at once, then orders the
result topologically and drops dead statements; :func:`total_ops` counts operations with
``sympy.count_ops`` (the SymForce paper's measure, Sec. VIII-B).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any


def _s():
    from . import _sym

    return _sym


@dataclass
class Program:
    """``stmts`` then ``outputs`` (lists of SymPy expressions, grouped by name)."""

    stmts: list = field(default_factory=list)
    outputs: dict = field(default_factory=dict)  # name -> list of expressions

    def all_outputs(self) -> list:
        return [e for exprs in self.outputs.values() for e in exprs]


def temp_symbols(prefix: str = "_tmp", start: int = 0) -> Iterable:
    """Real symbols ``_tmp0, _tmp1, ...`` for intermediate terms."""
    return _s().sp.numbered_symbols(prefix, start=start, real=True)


def _free(e: Any) -> set:
    return e.free_symbols if hasattr(e, "free_symbols") else set()


def prune(stmts: list, outputs: list) -> list:
    """Statements needed by ``outputs``, in their original order."""
    needed: set = set()
    for e in outputs:
        needed |= _free(e)
    keep = []
    for sym, e in reversed(stmts):
        if sym in needed:
            keep.append((sym, e))
            needed |= _free(e)
    keep.reverse()
    return keep


def toposort(defs: list) -> list:
    """Order ``(symbol, expr)`` definitions so every symbol is defined before it is used."""
    by_sym = {s: e for s, e in defs}
    order, state = [], {}
    for root, _ in defs:
        if root in state:
            continue
        stack = [(root, False)]
        while stack:
            sym, done = stack.pop()
            if done:
                state[sym] = 2
                order.append((sym, by_sym[sym]))
                continue
            if state.get(sym):
                continue
            state[sym] = 1
            stack.append((sym, True))
            for dep in _free(by_sym[sym]):
                if dep in by_sym and not state.get(dep):
                    stack.append((dep, False))
    return order


def optimize(prog: Program, prefix: str = "_tmp") -> Program:
    """Global CSE over a program; returns a new program with temporaries ``_tmpN``.

    Statements are renamed in order of first definition, so the output is deterministic.
    """
    sp = _s().sp
    names = list(prog.outputs)
    sizes = [len(prog.outputs[n]) for n in names]
    outs = prog.all_outputs()
    stmts = prune(prog.stmts, outs)
    exprs = [e for _, e in stmts] + outs
    taken = {s for s, _ in stmts}
    repl, reduced = sp.cse(exprs, symbols=sp.numbered_symbols("_cse", real=True, exclude=taken),
                           order="none")
    defs = list(repl) + [(s, reduced[k]) for k, (s, _) in enumerate(stmts)]
    red_outs = reduced[len(stmts):]
    defs = prune(toposort(defs), red_outs)
    # inline definitions that are plain symbols or numbers
    alias = {}
    final = []
    for s, e in defs:
        e = e.xreplace(alias) if alias else e
        if e.is_Atom:
            alias[s] = e
        else:
            final.append((s, e))
    red_outs = [e.xreplace(alias) if alias and hasattr(e, "xreplace") else e for e in red_outs]
    # deterministic names in order of definition
    rename = {s: sym for (s, _), sym in zip(final, temp_symbols(prefix))}
    final = [(rename[s], e.xreplace(rename)) for s, e in final]
    red_outs = [e.xreplace(rename) if hasattr(e, "xreplace") else e for e in red_outs]
    out, k = {}, 0
    for n, size in zip(names, sizes):
        out[n] = red_outs[k:k + size]
        k += size
    return Program(final, out)


def count_ops(exprs: Iterable) -> int:
    sp = _s().sp
    return int(sum(sp.count_ops(e) for e in exprs))


#: ``total_ops`` of recent programs, by identity: a factor's derivation asks for the count of
#: the same program up to four times (choosing the engine, META, the module header, the kernel
#: comment) and SymPy's ``count_ops`` took ~20 % of a Pose3 factor's cold derivation.
_OPS_MEMO: dict[int, tuple] = {}


def total_ops(prog: Program) -> int:
    """``count_ops`` over every statement and output (after CSE this is the paper's measure).

    >>> from fgopt.symbolic import V2, linearization_program, total_ops
    >>> p = V2.symbolic("p")
    >>> total_ops(linearization_program(p.squared_norm(), [p]))   # 2 pow + 1 add, 2 mul
    5
    """
    shape = (len(prog.stmts), tuple(len(v) for v in prog.outputs.values()))
    hit = _OPS_MEMO.get(id(prog))
    if hit is not None and hit[0] is prog and hit[1] == shape:
        return hit[2]
    n = count_ops([e for _, e in prog.stmts] + prog.all_outputs())
    if len(_OPS_MEMO) >= 64:
        _OPS_MEMO.clear()
    _OPS_MEMO[id(prog)] = (prog, shape, n)  # holds prog: its id cannot be reused meanwhile
    return n


def substitute_back(prog: Program) -> dict:
    """Outputs as full expressions (statements substituted); only for small programs/tests."""
    env: dict = {}
    for s, e in prog.stmts:
        env[s] = e.xreplace(env)
    return {n: [e.xreplace(env) if hasattr(e, "xreplace") else e for e in exprs]
            for n, exprs in prog.outputs.items()}

