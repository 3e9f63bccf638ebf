"""Solving a compiled problem restricted to some of its factors (GNC's inner solves).

A factor with (near) zero weight adds nothing to ``H`` but its block, and a wrong loop closure
between two far-apart poses makes Cholesky fill in that block's whole elimination path: with
30 % random wrong closures on M3500, every factorization of the full pattern is dense enough
to take seconds. :class:`Restricted` compiles a second problem with only the factors that
matter (weight >= a threshold), re-compiling only when that set changes, and maps states
between it and the full problem by variable key; the full problem keeps evaluating every
factor's residual (no structure needed for that).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..graph import FactorGraph
from ..problem import Problem, State
from .linear.base import make_linear_solver


def subgraph(problem: Problem, keep: list[np.ndarray]) -> tuple[FactorGraph, list[int]]:
    """The factors of ``problem`` selected by ``keep`` (one mask per batch, then one for the
    Python factors) as a graph, and for each batch of the result the index of its source batch
    (-1 for the Python factors)."""
    g = FactorGraph()
    order = []
    for i, (b, m) in enumerate(zip(problem.batches, keep)):
        if not np.any(m):
            continue
        src = b.source
        R = None if src.sqrt_information is None else src.sqrt_information[m]
        g.add_batch(src.kernel, src.keys[m], src.constants[m], R, src.loss_code, src.loss_param,
                    loss_shape=src.loss_shape)
        order.append(i)
    slow_keep = keep[len(problem.batches)] if len(keep) > len(problem.batches) else []
    for s, k in zip(problem._slow, slow_keep):
        if k:
            g.add(s.factor)
    return g, order


class Restricted:
    """The weighted problem over the factors with weight >= ``threshold`` (see module doc)."""

    def __init__(self, full: Problem, params: Any, threshold: float):
        self.full = full
        self.params = params
        self.threshold = float(threshold)
        self.keep: list[np.ndarray] | None = None
        self.problem: Problem | None = None
        self.solver = None
        self.rebuilds = 0

    def _masks(self, weights: list[np.ndarray]) -> list[np.ndarray]:
        return [np.asarray(w) >= self.threshold for w in weights]

    def prepare(self, state: State, weights: list[np.ndarray]) -> tuple[Problem, State]:
        """The restricted problem for ``weights`` (re-compiled if the kept set changed), its
        weights set, and ``state`` mapped to it."""
        keep = self._masks(weights)
        if self.keep is None or any(not np.array_equal(a, b) for a, b in zip(keep, self.keep)):
            graph, order = subgraph(self.full, keep)
            values = self.full.values(state)
            p = self.params
            self.problem = Problem(graph, values, ordering=p.ordering, threads=p.threads)
            self.solver = make_linear_solver(p.linear_solver, pattern=self.problem.pattern)
            self.solver.analyze(self.problem.pattern)
            self.keep, self.order = keep, order
            self._maps = _row_maps(self.problem, self.full)
            self.rebuilds += 1
        sub = self.problem
        w = [np.asarray(weights[i])[self.keep[i]] for i in self.order]
        if sub._slow:
            w.append(np.asarray(weights[-1])[self.keep[-1]])
        else:
            w.append(np.zeros(0))
        sub.set_weights(w)
        self.sub_weights = w
        return sub, self.to_sub(state)

    def to_sub(self, state: State) -> State:
        storages = [state.storages[kf][rows_f] for kf, rows_f in self._maps["rows"]]
        objects = {vs: state.objects[vf] for vs, vf in self._maps["objects"]}
        return State([np.ascontiguousarray(s) for s in storages], objects)

    def to_full(self, sub_state: State, base: State) -> State:
        """``base`` with the restricted problem's variables replaced by ``sub_state``'s."""
        storages = [s.copy() for s in base.storages]
        for ks, (kf, rows_f) in enumerate(self._maps["rows"]):
            storages[kf][rows_f] = sub_state.storages[ks]
        objects = dict(base.objects)
        for vs, vf in self._maps["objects"]:
            objects[vf] = sub_state.objects[vs]
        return State(storages, objects)


def _row_maps(sub: Problem, full: Problem) -> dict:
    """For each kind of ``sub``: the full problem's kind id and, in ``sub``'s row order, the
    full problem's rows of the same variables; and (sub var, full var) of Python-manifold
    variables."""
    rows = []
    for ks, kind in enumerate(sub.kinds):
        kf = full._kind_id[id(kind)]
        vars_s = sub._kind_vars[ks]
        order = np.empty_like(vars_s)
        order[sub.var_row[vars_s]] = vars_s   # sub var of each sub row
        vars_f = full._vars_of(sub.var_keys[order])
        rows.append((kf, full.var_row[vars_f]))
    objects = [(int(v), int(full._vars_of(sub.var_keys[[v]])[0])) for v in sub._slow_vars]
    return {"rows": rows, "objects": objects}
