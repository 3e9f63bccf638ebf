"""Straight-line programs, common-subexpression elimination and op counting.

A :class:`Program` is what generated kernels compute: ``stmts`` (``(symbol, expression)``
pairs, each expression over the inputs and earlier symbols) followed by output expressions.

:func:`optimize` is a CSE on a hash-consed DAG of integer node ids: every distinct SymPy
subexpression is visited once (SymPy expressions hash structurally, so equal subtrees meet in
one dict entry and trees are never re-expanded); a product with a negative coefficient is
``-(product)`` and a sum with mostly negative terms ``-(sum)``, so signs do not hide sharing;
``n``-ary sums and products then share common subsets of their terms (SymPy's
``match_common_args`` greedy rule, on sets of ids), and every node used more than once becomes
a temporary. Only the emitted statements are built back as SymPy objects, in SymPy's argument
order but without its evaluation. On the built-in, range/bearing, camera and NavState
factors the programs have -11 % .. +1.7 % of the operations ``sympy.cse`` leaves, and take
about a tenth of its time.

:func:`total_ops` counts operations as ``sympy.count_ops`` does (the SymForce paper's measure,
Sec. VIII-B), without building the intermediate products ``count_ops`` builds.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from ._count import count_ops


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


# ------------------------------------------------------------------------------------ the DAG
_ADD, _MUL, _POW, _NEG = "+", "*", "**", "-"


class _Dag:
    """Node ids for the SymPy atoms and operations of a program (each distinct one once).

    ``op[i]`` is ``None`` for an atom, ``_ADD`` / ``_MUL`` / ``_POW`` or the SymPy class of a
    function; ``args[i]`` are child ids; ``expr[i]`` the SymPy expression the node stands for
    while its children are the original ones (reused as is when nothing below it changed).
    A statement symbol is an atom whose definition is ``defs[i]``.
    """

    def __init__(self, stmts: list) -> None:
        self.op: list = []
        self.args: list = []
        self.expr: list = []
        self.key: dict = {}  # (op, args) -> id; args sorted for + and *
        self.ids: dict = {}  # SymPy expression -> id
        self.defs: dict = {}  # statement atom id -> definition id
        self._stmt_exprs = dict(stmts)

    def node(self, op: Any, args: Iterable, expr: Any = None) -> int:
        args = list(args)
        k = (op, tuple(sorted(args)) if op is _ADD or op is _MUL else tuple(args))
        i = self.key.get(k)
        if i is None:
            i = self._new(op, args, expr)
            self.key[k] = i
        return i

    def _new(self, op: Any, args: list, expr: Any) -> int:
        self.op.append(op)
        self.args.append(args)
        self.expr.append(expr)
        return len(self.op) - 1

    def atom(self, a: Any) -> int:
        i = self.ids.get(a)
        if i is None:
            i = self.ids[a] = self._new(None, [], a)
        return i

    def _negated(self, i: int) -> int:
        """Id of ``-node``."""
        if self.op[i] is _NEG:
            return self.args[i][0]
        if self.op[i] is None and self.expr[i].is_Number:
            return self.atom(-self.expr[i])
        return self.node(_NEG, [i])

    def _sum(self, kids: list, e: Any) -> int:
        """A sum, as ``-(sum of the negated terms)`` when most terms are negative (on a tie,
        when the term with the smallest magnitude id is): ``x - y`` and ``y - x`` share."""
        neg = [self.op[k] is _NEG or self.op[k] is None and self.expr[k].is_Number
               and self.expr[k].is_extended_negative for k in kids]
        flip = 2 * sum(neg) - len(kids)
        if flip == 0:
            mags = [self._negated(k) if n else k for k, n in zip(kids, neg)]
            flip = neg[mags.index(min(mags))]
        if flip <= 0:
            return self.node(_ADD, kids, e)
        return self.node(_NEG, [self.node(_ADD, [self._negated(k) for k in kids])])

    def _repeated(self, kids: list, is_sum: bool) -> int:
        sp = _s().sp
        times = {k: kids.count(k) for k in kids}
        terms = [k if n == 1 else self.node(_MUL, [self.atom(sp.Integer(n)), k]) if is_sum
                 else self.node(_POW, [k, self.atom(sp.Integer(n))]) for k, n in times.items()]
        return self._sum(terms, None) if is_sum else self.node(_MUL, terms)

    def intern(self, root: Any) -> int:
        """Id of ``root``, interning its subexpressions and the statements it reaches."""
        sp = _s().sp
        ids, stmts = self.ids, self._stmt_exprs
        stack, pending = [root], []
        while stack or pending:
            if not stack:
                stack.append(pending.pop())
            e = stack[-1]
            if isinstance(e, tuple):  # (statement atom id, definition) to intern
                i, d = e
                if d not in ids:
                    stack.append(d)
                    continue
                stack.pop()
                self.defs[i] = ids[d]
                continue
            if e in ids:
                stack.pop()
                continue
            if e.is_Atom:
                stack.pop()
                i = self.atom(e)
                d = stmts.get(e)
                if d is not None:
                    pending.append((i, d))
                continue
            todo = [a for a in e.args if a not in ids]
            if todo:
                stack.extend(reversed(todo))
                continue
            stack.pop()
            kids = [ids[a] for a in e.args]
            if (e.is_Add or e.is_Mul) and len(set(kids)) < len(kids):
                # terms SymPy tells apart but that are equal (x*y + y*x, unsorted): n*t, t**n
                ids[e] = self._repeated(kids, e.is_Add)
            elif e.is_Add:
                ids[e] = self._sum(kids, e)
            elif e.is_Mul and e.args[0].is_Number and e.args[0].is_extended_negative:
                # -c*x*y as -(c*x*y): shares c*x*y, and products share no sign
                c = e.args[0]
                pos = kids[1:] if c is sp.S.NegativeOne else [self.atom(-c), *kids[1:]]
                ids[e] = self.node(_NEG, [pos[0] if len(pos) == 1 else self.node(_MUL, pos)])
            elif e.is_Mul:
                ids[e] = self.node(_MUL, kids, e)
            elif e.is_Pow and e.exp.is_Number and e.exp.is_negative and e.exp != -1:
                # x**-k as 1/(x**k): shares x**k with the program's positive powers
                pos = self.node(_POW, (kids[0], self.atom(-e.exp)))
                ids[e] = self.node(_POW, (pos, self.atom(sp.S.NegativeOne)))
            else:
                ids[e] = self.node(_POW if e.is_Pow else e.func, kids, e)
        return ids[root]


def _share_common_args(dag: _Dag, op: str, funcs: list) -> None:
    """Rewrite the sums (or products) ``funcs`` so that every two sharing two or more terms
    use one node for the shared part (SymPy's ``match_common_args``: smallest first; a pair's
    common terms also replace that subset in every later candidate containing it)."""
    funcs = sorted(funcs, key=lambda f: len(dag.args[f]))
    argsets = [set(dag.args[f]) for f in funcs]
    holders: dict = {}  # arg id -> indices into funcs holding it
    for fi, s in enumerate(argsets):
        for a in s:
            holders.setdefault(a, set()).add(fi)
    changed = set()

    def update(fi: int, new: set) -> None:
        for a in argsets[fi] - new:
            holders[a].discard(fi)
        for a in new - argsets[fi]:
            holders.setdefault(a, set()).add(fi)
        argsets[fi] = new
        changed.add(fi)

    for i in range(len(funcs)):
        count: dict = {}
        for a in argsets[i]:
            for f in holders[a]:
                if f > i:
                    count[f] = count.get(f, 0) + 1
        order = sorted((f for f, c in count.items() if c >= 2), key=lambda f: (count[f], f))
        left = set(order)
        for j in order:
            if j not in left:
                continue
            left.discard(j)
            com = argsets[i] & argsets[j]
            if len(com) <= 1:
                continue
            rest_i = argsets[i] - com
            if rest_i:
                c = dag.node(op, sorted(com))
                update(i, rest_i | {c})
            else:
                c = funcs[i]
            it = iter(com)
            also = holders[next(it)] & left
            for a in it:
                also &= holders[a]
            for k in [j, *sorted(also)]:
                if funcs[k] != c:  # a node equal to the common part keeps its terms
                    update(k, (argsets[k] - com) | {c})
        for a in argsets[i]:
            holders[a].discard(i)
    for fi in changed:
        f = funcs[fi]
        dag.args[f] = sorted(argsets[fi])
        dag.expr[f] = None


def _build(dag: _Dag, i: int, new: dict, inline: Any) -> Any:
    """SymPy expression of node ``i`` over its children's built forms ``new``: sums and
    products in SymPy's order (the number first), not evaluated."""
    sp = _s().sp
    op, kids, e = dag.op[i], dag.args[i], dag.expr[i]
    built = [new[a] for a in kids]
    if e is not None and all(x is y for x, y in zip(built, e.args)):
        return e
    if op is _ADD or op is _MUL:
        cls = sp.Add if op is _ADD else sp.Mul
        terms = []
        for a, b in zip(kids, built):
            if dag.op[a] is op and inline(a) and b.func is cls:
                terms.extend(b.args)  # an inlined shared part: back into one sum / product
            else:
                terms.append(b)
        nums = [t for t in terms if t.is_Number]
        rest = [t for t in terms if not t.is_Number]
        if len(nums) > 1:  # -(2*x) inlined into a product: -2*x
            nums = [cls(*nums)]
            if nums[0] == cls.identity:
                nums = []
        if len(set(rest)) < len(rest):
            return cls(*terms)  # a term twice (x + x): SymPy combines it
        rest.sort(key=_sort_key())  # SymPy's order: equal sums compare equal downstream
        terms = nums + rest
        return cls._from_args(terms) if len(terms) > 1 else terms[0] if terms else cls.identity
    if op is _NEG:
        (b,) = built
        if not inline(kids[0]) or not (b.is_Mul or b.is_Add):
            return sp.Mul._from_args((sp.S.NegativeOne, b))
        if b.is_Add:  # an unshared sum: negate its terms, as SymPy's -(x - y) is y - x
            return sp.Add._from_args(_canonical([_negate(t) for t in b.args]))
        return _negate(b)
    if op is _POW:
        base, exp = built
        if exp is sp.S.NegativeOne and dag.op[kids[0]] is _POW and inline(kids[0]):
            return sp.Pow(base.base, -base.exp, evaluate=False)  # unshared 1/(x**k): x**-k
        return sp.Pow(base, exp, evaluate=False)
    return op(*built)


def _sort_key() -> Any:
    from sympy.core.basic import _args_sortkey

    return _args_sortkey


def _canonical(terms: list) -> list:
    """``terms`` of a sum or product in SymPy's order (the number first)."""
    nums = [t for t in terms if t.is_Number]
    return nums + sorted((t for t in terms if not t.is_Number), key=_sort_key())


def _negate(t: Any) -> Any:
    """``-t`` for a term of a sum or a product (coefficient first), built without SymPy's
    evaluation."""
    sp = _s().sp
    if t.is_Number:
        return -t
    if t.is_Mul and t.args[0].is_Number:
        c = -t.args[0]
        if c is sp.S.One:
            return t.args[1] if len(t.args) == 2 else sp.Mul._from_args(t.args[1:])
        return sp.Mul._from_args((c, *t.args[1:]))
    return sp.Mul._from_args((sp.S.NegativeOne, *(t.args if t.is_Mul else (t,))))


def optimize(prog: Program, prefix: str = "_tmp") -> Program:
    """Global CSE over a program; returns a new program with temporaries ``_tmpN``.

    Statements not needed by an output are dropped; statements whose value is a symbol or a
    number are substituted. Temporaries are numbered in order of definition (the input's
    statements in order, then the outputs, each after what it needs), so the output is
    deterministic.

    >>> from fgopt.symbolic import V3
    >>> a, b = V3.symbolic("a"), V3.symbolic("b")
    >>> from fgopt.symbolic import cos, sin
    >>> optimize(Program([], {"out": [sin(a.dot(b)), cos(a.dot(b))]}))
    Program(stmts=[(_tmp0, a_0*b_0 + a_1*b_1 + a_2*b_2)], outputs={'out': [sin(_tmp0), cos(_tmp0)]})
    """
    sp = _s().sp
    Basic, Expr = sp.Basic, sp.Expr
    stmts, outs = prog.stmts, prog.all_outputs()
    if any(e.is_Atom for _, e in stmts):  # substituted first: SymPy simplifies 0*x, 1*x
        alias: dict = {}
        kept = []
        for s, e in stmts:
            e = e.xreplace(alias) if alias else e
            if e.is_Atom:
                alias[s] = e
            else:
                kept.append((s, e))
        stmts = kept
        outs = [e.xreplace(alias) if isinstance(e, Basic) else e for e in outs]
    dag = _Dag(stmts)
    roots = [dag.intern(e) if isinstance(e, Basic) else None for e in outs]
    for op in (_ADD, _MUL):
        funcs = [i for i, o in enumerate(dag.op) if o is op and len(dag.args[i]) > 1]
        _share_common_args(dag, op, funcs)
    uses: dict = {}  # references from the live program
    stack = [r for r in roots if r is not None]
    while stack:
        i = stack.pop()
        n = uses.get(i, 0)
        uses[i] = n + 1
        if n == 0:
            stack.extend(dag.args[i])
            if i in dag.defs:
                stack.append(dag.defs[i])

    def inline(i: int) -> bool:
        return uses[i] == 1

    new: dict = {}
    emitted = []
    names = temp_symbols(prefix)
    # the input's statements first, in their order, then the outputs: the program keeps the
    # input's order of evaluation (a depth-first walk from the outputs alone made kernels
    # ~5-10 % slower for the same operations)
    live = [dag.ids[s] for s, _ in stmts if dag.ids.get(s) in uses]
    for r in live + roots:
        stack = [] if r is None else [r]
        active = set()
        while stack:
            i = stack[-1]
            if i in new:
                stack.pop()
                continue
            d = dag.defs.get(i)
            kids = dag.args[i] if d is None else [d]
            todo = [a for a in kids if a not in new]
            if todo:
                if i in active:
                    raise RuntimeError(f"optimize: cycle through node {i}")  # a bug, not input
                active.add(i)
                stack.extend(reversed(todo))
                continue
            stack.pop()
            if d is not None:  # a statement: keeps a name unless its value is an atom
                b, share = new[d], True
            elif dag.op[i] is None:
                b, share = dag.expr[i], False
            elif (dag.op[i] is _ADD or dag.op[i] is _MUL) and len(kids) == 1:
                b, share = new[kids[0]], False  # a sum reduced to one shared part
            else:
                b = _build(dag, i, new, inline)
                share = uses[i] > 1 and isinstance(b, Expr)
            if share and not b.is_Atom:
                t = next(names)
                emitted.append((t, b))
                b = t
            new[i] = b
    red = [e if r is None else new[r] for e, r in zip(outs, roots)]
    out, k = {}, 0
    for name, exprs in prog.outputs.items():
        out[name] = red[k:k + len(exprs)]
        k += len(exprs)
    return Program(emitted, out)


#: ``total_ops`` of recent programs, by identity: a factor's derivation asks for the count of
#: the same program up to four times (choosing the engine, META, the module header, the kernel
#: comment).
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
